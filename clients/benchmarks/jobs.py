"""``pednav bench jobs``: throughput of re-processing N stored sessions through a job engine with 1, 2, 4 local
worker processes, against a single process running the same jobs one after the other.

The benchmark stores ``--sessions`` sessions of a synthetic walk (``--seconds`` 1-s batches each) through the
API (an in-process app on the given database; default PostgreSQL on 127.0.0.1 when it answers, in a schema of
its own that is dropped afterwards), then re-processes every one of them (:func:`server.jobs.reprocess_job`,
dry run: the engine and the reads are the work, nothing is stored, so every engine meets the same sessions):

- ``single_process``: the jobs called one after the other in this process (after one warm-up job);
- ``dramatiq``: ``dramatiq server.jobs_worker --processes W --threads 1`` over Redis (the chosen engine);
- ``dask``: a ``distributed.LocalCluster`` of W single-threaded worker processes (``client.map``), when Dask
  distributed is installed.

Each engine's workers are warmed up before the clock starts (Dramatiq: 2W jobs; Dask: one job on every worker); the clock stops when the
N jobs are counted done in Redis (Dramatiq) or gathered (Dask). Reported: sessions per second and the speed-up
over the single process measured in the same run, with the load average (the machine is shared). Traffic stays
on 127.0.0.1; every worker is stopped at the end.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
import uuid
from typing import Any

__all__ = ["add_arguments", "run"]

_PG = "postgresql+psycopg://postgres@127.0.0.1:5432/test"
# An idle Dramatiq worker polls Redis with a back-off capped at ``dramatiq_worker_timeout`` (default 1000 ms), so
# the first job of a run waited up to 1 s (0.6 s measured: 12 % of a 5-s run of 100 sessions). The deployment
# sets 100 ms (docs/deployment.md: ten Redis round trips a second per idle worker); the benchmark does the same.
IDLE_POLL_MS = int(os.environ.get("dramatiq_worker_timeout", "100"))


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--sessions", type=int, default=100, help="stored sessions re-processed (default 100)")
    p.add_argument("--seconds", type=int, default=60, help="1-s batches per stored session (default 60)")
    p.add_argument("--workers", type=int, nargs="+", default=[1, 2, 4], help="worker processes (default 1 2 4)")
    p.add_argument("--engines", nargs="+", choices=("dramatiq", "dask"), default=["dramatiq", "dask"])
    p.add_argument("--database-url", default=None, help=f"SQLAlchemy URL (default {_PG} when it answers, else SQLite)")
    p.add_argument("--redis-url", default="redis://127.0.0.1:6379/0")


def _store(url: str, schema: str | None, n: int, seconds: int) -> tuple[list[int], dict[str, str]]:
    """N sessions of a synthetic walk stored through the API; returns their ids and the worker environment."""
    from fastapi.testclient import TestClient

    from clients.sdk import encode_batch
    from clients.synth import synthesize
    from server import crud
    from server.app import create_app
    from server.settings import Settings

    settings = Settings(database_url=url, db_schema=schema, engine_processes=0, engine_warmup=False,
                        rate_limit_per_s=0.0)
    app = create_app(settings)
    with app.state.sessionmaker() as db:
        _, token = crud.create_user(db, f"jobs-{uuid.uuid4().hex[:8]}")
        db.commit()
    parts = synthesize("walk", seed=11, rate_hz=100.0).batch.split_seconds(1.0)[:seconds]
    bodies = [encode_batch(p, "msgpack", "<f8") for p in parts]
    h = {"Authorization": f"Bearer {token}"}
    sids = []
    with TestClient(app) as c:
        for _ in range(n):
            sid = c.post("/v1/sessions", json={"device_kind": "foot"}, headers=h).json()["id"]
            for k, (body, ctype) in enumerate(bodies):
                c.put(f"/v1/sessions/{sid}/batches/{k}", content=body, headers={**h, "content-type": ctype}).raise_for_status()
            sids.append(sid)
    app.state.db_engine.dispose()
    env = {**os.environ, "PEDNAV_DATABASE_URL": url}
    if schema:
        env["PEDNAV_DB_SCHEMA"] = schema
    return sids, env


def _single(sids: list[int], env: dict[str, str], redis_url: str) -> float:
    from server.jobs import reprocess_job

    old = {k: os.environ.get(k) for k in ("PEDNAV_DATABASE_URL", "PEDNAV_DB_SCHEMA")}
    os.environ.update({k: v for k, v in env.items() if k in old})
    try:
        run = uuid.uuid4().hex
        reprocess_job(sids[0], run, None, True, redis_url)  # warm-up
        t = time.perf_counter()
        for sid in sids:
            reprocess_job(sid, run, None, True, redis_url)
        return time.perf_counter() - t
    finally:
        for k, v in old.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def _wait_done(run: str, n: int, redis_url: str, timeout: float) -> None:
    from server.jobs import outcomes

    deadline = time.monotonic() + timeout
    while outcomes(run, redis_url).done < n:
        if time.monotonic() > deadline:
            raise TimeoutError(f"jobs of run {run} not done in {timeout:.0f} s")
        time.sleep(0.02)


def _dramatiq(sids: list[int], env: dict[str, str], workers: int, redis_url: str) -> float:
    from server.jobs import declare, enqueue_reprocess, make_broker

    broker = make_broker(redis_url)
    broker.flush_all()
    actor = declare(broker)
    proc = subprocess.Popen([sys.executable, "-m", "dramatiq", "server.jobs_worker", "--processes", str(workers),
                             "--threads", "1", "--queues", "pednav"],
                            env={**env, "PEDNAV_REDIS_URL": redis_url, "dramatiq_worker_timeout": str(IDLE_POLL_MS)},
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        warm = uuid.uuid4().hex
        enqueue_reprocess(actor, [sids[0]] * (2 * workers), warm, None, True, redis_url)
        _wait_done(warm, 2 * workers, redis_url, 600)
        run = uuid.uuid4().hex
        t = time.perf_counter()
        enqueue_reprocess(actor, sids, run, None, True, redis_url)
        _wait_done(run, len(sids), redis_url, 1800)
        return time.perf_counter() - t
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        broker.close()


def _dask_job(sid: int, run: str, redis_url: str, env: dict[str, str]) -> str:
    os.environ.update({k: v for k, v in env.items() if k.startswith("PEDNAV_")})
    from server.jobs import reprocess_job

    return reprocess_job(sid, run, None, True, redis_url)


def _dask(sids: list[int], env: dict[str, str], workers: int, redis_url: str) -> float | None:
    try:
        from distributed import Client, LocalCluster
    except ImportError:
        return None
    penv = {k: v for k, v in env.items() if k.startswith("PEDNAV_")}
    with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None) as cluster, \
            Client(cluster) as client:
        # one warm-up job on every worker (client.run): mapped warm-up jobs may all land on one worker and leave
        # another to load the engine's kernels inside the timed run
        client.run(_dask_job, sids[0], uuid.uuid4().hex, redis_url, penv)
        run = uuid.uuid4().hex
        t = time.perf_counter()
        client.gather(client.map(_dask_job, sids, [run] * len(sids), [redis_url] * len(sids), [penv] * len(sids),
                                 pure=False))
        return time.perf_counter() - t


def run(args: argparse.Namespace) -> dict[str, Any]:
    from server.db import drop_schema, make_engine
    from server.settings import Settings

    url = args.database_url
    if url is None:
        try:
            import psycopg

            with psycopg.connect(_PG.replace("+psycopg", ""), connect_timeout=3):
                url = _PG
        except Exception:  # noqa: BLE001 - no PostgreSQL: SQLite
            import tempfile

            url = f"sqlite:///{tempfile.mkdtemp(prefix='pednav-jobs-')}/jobs.db"
    schema = f"jobs_{uuid.uuid4().hex[:10]}" if url.startswith("postgresql") else None
    load0 = os.getloadavg()
    try:
        t = time.perf_counter()
        sids, env = _store(url, schema, args.sessions, args.seconds)
        store_s = time.perf_counter() - t
        single = _single(sids, env, args.redis_url)
        out: dict[str, Any] = {"sessions": len(sids), "batches_per_session": args.seconds,
                               "database": url.split(":", 1)[0].split("+")[0], "store_s": round(store_s, 1),
                               "single_process": {"s": round(single, 2), "sessions_per_s": round(len(sids) / single, 2)}}
        for eng in args.engines:
            rows = {}
            for w in args.workers:
                s = _dramatiq(sids, env, w, args.redis_url) if eng == "dramatiq" else _dask(sids, env, w, args.redis_url)
                if s is None:
                    rows = {"missing": f"{eng} is not installed"}
                    break
                rows[str(w)] = {"s": round(s, 2), "sessions_per_s": round(len(sids) / s, 2),
                                "speedup_vs_single_process": round(single / s, 2)}
            out[eng] = rows
    finally:
        if schema:
            e = make_engine(Settings(database_url=url))
            drop_schema(e, schema)
            e.dispose()
    out.update({"dramatiq_worker_timeout_ms": IDLE_POLL_MS, "cpus": os.cpu_count(), "loadavg_1_5_15_at_start": [round(x, 2) for x in load0],
                "loadavg_1_5_15_at_end": [round(x, 2) for x in os.getloadavg()]})
    return out
