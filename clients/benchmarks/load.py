"""``pednav bench load``: N simulated devices against ONE uvicorn worker on 127.0.0.1.

Each device opens a session and sends one 1-s batch of 100 Hz 9-axis samples (accelerometer, gyroscope,
magnetometer; compact msgpack body, float32 values) every second, waiting for each answer before the next
batch (sequence numbers must follow each other). ``--batch-seconds S`` makes that one S-s batch every S seconds
(the same samples per second): the engine asks a calibrated foot device for 4-s uploads with the gyroscope off
(``energy.config`` ``low_power_batch_s``), and a deployer plans with the mix of periods the fleet uses. The
samples are a synthetic walk (stand, walk, turn, walk, stand); device ``i`` starts ``i mod (60 / S)`` batches into
it, so the devices are not in lockstep, and the send instants are spread evenly over the period. The
benchmark starts the server itself (``uvicorn server.app:app_from_env --factory``, 1 worker) on a free port,
warms it up (numba compilation of the engine) with one session that is not measured, then runs for
``--seconds``. It reports latency percentiles of the batch uploads, throughput, late sends (a device could
not keep its cadence because an answer came late), and — checked against the server's stored batches
afterwards — lost batches (sent but not stored/acknowledged) and duplicated batches (stored more than once).

The traffic goes to 127.0.0.1 only and the run is bounded by ``--seconds``.
"""

from __future__ import annotations

import argparse
import asyncio
import os
import socket
import subprocess
import sys
import time
import uuid
from typing import Any

import numpy as np

__all__ = ["add_arguments", "run"]


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--devices", type=int, default=200, help="simulated devices (default 200)")
    p.add_argument("--seconds", type=float, default=60.0, help="measured duration [s] (default 60)")
    p.add_argument("--rate-hz", type=float, default=100.0, help="sample rate of every stream [Hz] (default 100)")
    p.add_argument("--batch-seconds", type=_period, default=1.0,
                   help="upload period of every device [s], one batch of that many seconds each time (default 1; "
                        "a calibrated foot device uploads every 4 s)")
    p.add_argument("--database-url", default=None,
                   help="SQLAlchemy URL (default: a fresh SQLite file in a temporary folder); for PostgreSQL a "
                        "unique schema is created and dropped")
    p.add_argument("--encoding", choices=("msgpack", "json"), default="msgpack")
    p.add_argument("--workers", type=int, default=1, help="uvicorn worker processes of the server (default 1)")
    p.add_argument("--sweep", action="store_true",
                   help="sweep --sweep-devices x --sweep-workers x --sweep-databases, each run --seconds long, and "
                        "report devices per core at p99 <= --p99-ms (0 lost, 0 duplicated)")
    p.add_argument("--sweep-devices", type=int, nargs="+", default=[100, 500, 1000, 2000])
    p.add_argument("--sweep-workers", type=int, nargs="+", default=[1, 2, 4])
    p.add_argument("--sweep-databases", nargs="+", default=["postgresql+psycopg://postgres@127.0.0.1:5432/test", "sqlite"],
                   help="database URLs ('sqlite': a fresh file per run)")
    p.add_argument("--p99-ms", type=float, default=250.0, help="latency bound of the sweep's capacity figure")
    p.add_argument("--plot", default=None, help="PNG of p99 latency against devices per database and workers (sweep)")


def _period(text: str) -> float:
    """``--batch-seconds``: a positive number of seconds, at most a minute (argparse names the option on error)."""
    v = float(text)
    if not 0.0 < v <= 60.0:
        raise argparse.ArgumentTypeError(f"{text} s: must be above 0 and at most 60")
    return v


def _proc_stats() -> dict[int, tuple[int, str, float]]:
    """pid -> (parent pid, command name, CPU seconds used so far) of every process (Linux /proc)."""
    tick = os.sysconf("SC_CLK_TCK")
    out = {}
    for d in os.listdir("/proc"):
        if not d.isdigit():
            continue
        try:
            with open(f"/proc/{d}/stat") as f:
                raw = f.read()
        except OSError:
            continue
        comm = raw[raw.index("(") + 1: raw.rindex(")")]
        fields = raw[raw.rindex(")") + 2:].split()
        out[int(d)] = (int(fields[1]), comm, (int(fields[11]) + int(fields[12])) / tick)
    return out


def _thread_cpu(pid: int) -> float:
    """CPU seconds used so far by the main thread of process ``pid`` (a uvicorn worker's event loop: HTTP parsing,
    middleware, hand-off to and from the ingest threads); 0 when it cannot be read."""
    try:
        with open(f"/proc/{pid}/task/{pid}/stat") as f:
            raw = f.read()
    except OSError:
        return 0.0
    fields = raw[raw.rindex(")") + 2:].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _cpu_probe(server_pid: int, workers: int = 1) -> dict[str, float]:
    """CPU seconds used so far by this load generator, the server's worker processes (the uvicorn process itself
    with one worker; its children, plus the supervising parent, with several), their descendants (the engine
    helpers) and all postgres processes (on a shared machine the latter include other clients of the database).
    ``server_worker_event_loop``: the part of ``server_worker`` spent in the workers' main threads (the event
    loop); the rest is their ingest threads (authentication, decoding, the engine helper round trip, the database
    round trips, on SQLite the group commit, which runs in the ingest thread that leads it)."""
    if not os.path.isdir("/proc"):
        return {}
    st = _proc_stats()
    kids: dict[int, list[int]] = {}
    for pid, (ppid, _, _) in st.items():
        kids.setdefault(ppid, []).append(pid)
    top = [server_pid] if workers <= 1 else [server_pid, *kids.get(server_pid, [])]
    desc, todo = [], [k for p in top for k in kids.get(p, []) if k not in top]
    while todo:
        p = todo.pop()
        desc.append(p)
        todo += kids.get(p, [])
    me = os.times()
    return {
        "load_generator": me.user + me.system,  # this process (all its threads)
        "server_worker": sum(st.get(p, (0, "", 0.0))[2] for p in top),
        "server_worker_event_loop": sum(_thread_cpu(p) for p in top),
        "engine_helpers": sum(st[p][2] for p in desc if p in st),
        "postgres_all": sum(c for _, n, c in st.values() if n.startswith("postgres")),
    }


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


_WARM_SESSIONS = 4  # warm-up sessions (covers up to 4 engine helper processes)
_SPREAD_S = 60  # devices start at different points of the recording (independent people, not in lockstep)


def _spread(period: float) -> int:
    """Batches of ``period`` s in the first ``_SPREAD_S`` seconds of the recording (the devices' starting points)."""
    return max(1, int(round(_SPREAD_S / period)))


def _bodies(count: int, rate_hz: float, encoding: str, batch_s: float) -> list[tuple[bytes, str]]:
    """``count`` consecutive ``batch_s``-s batches of a synthetic walk (foot IMU, all three streams at
    ``rate_hz``)."""
    from clients.sdk import encode_batch
    from clients.synth import synthesize

    rec = synthesize("walk", seed=11, rate_hz=rate_hz)
    parts = rec.batch.split_seconds(batch_s)
    out = []
    for k in range(count):
        # loop the recording if the run is longer: shift time so it keeps increasing
        base = parts[k % len(parts)]
        shift = (k // len(parts)) * (int(rec.batch.t_end_ns) - int(rec.batch.t_start_ns) + 10_000_000)
        from models.batch import SensorBatch

        b = SensorBatch(**{key: (v + shift if key.endswith("_t_ns") else v) for key, v in base._kwargs().items()})
        out.append(encode_batch(b, encoding, "<f4"))  # type: ignore[arg-type]
    return out


class _Server:
    def __init__(self, database_url: str, schema: str | None, workers: int = 1) -> None:
        self.port = _free_port()
        env = {**os.environ, "PEDNAV_DATABASE_URL": database_url, "PEDNAV_MIGRATE_ON_STARTUP": "true"}
        if schema:
            env["PEDNAV_DB_SCHEMA"] = schema
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "uvicorn", "server.app:app_from_env", "--factory", "--host", "127.0.0.1",
             "--port", str(self.port), "--workers", str(workers), "--log-level", "warning", "--no-access-log"],
            env=env,
        )

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    def wait(self, timeout: float = 900.0, workers: int = 1) -> None:
        """Until ``/healthz`` is 200 (the engines compiled or loaded) on every worker: with several workers each
        answers for itself and a new connection meets any of them, so 10 answers per worker in a row must be 200."""
        import httpx2

        deadline = time.monotonic() + timeout
        in_a_row = 0
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"server exited with {self.proc.returncode}")
            try:
                ok = httpx2.get(self.url + "/healthz", timeout=1.0, headers={"Connection": "close"}).status_code == 200
            except httpx2.TransportError:
                ok = False
            in_a_row = in_a_row + 1 if ok else 0
            if in_a_row >= 10 * workers:
                return
            time.sleep(0.02 if ok else 0.2)
        raise RuntimeError("server did not start")

    def stop(self) -> None:
        self.proc.terminate()
        try:
            self.proc.wait(timeout=15)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()


class _Conn:
    """A minimal keep-alive HTTP/1.1 client on asyncio streams (one per device): the load generator must cost
    far less CPU than the server it measures, which a general-purpose async HTTP client does not."""

    def __init__(self, host: str, port: int) -> None:
        self.host, self.port = host, port
        self.reader: asyncio.StreamReader | None = None
        self.writer: asyncio.StreamWriter | None = None

    async def _open(self) -> None:
        self.reader, self.writer = await asyncio.open_connection(self.host, self.port)

    async def request(self, method: str, path: str, body: bytes, headers: dict[str, str]) -> tuple[int, dict[str, str], bytes]:
        if self.writer is None:
            await self._open()
        assert self.reader is not None and self.writer is not None
        head = f"{method} {path} HTTP/1.1\r\nHost: {self.host}\r\nContent-Length: {len(body)}\r\n"
        head += "".join(f"{k}: {v}\r\n" for k, v in headers.items()) + "\r\n"
        try:
            self.writer.write(head.encode() + body)
            await self.writer.drain()
            status_line = await self.reader.readline()
            if not status_line:
                raise ConnectionError("connection closed")
            status = int(status_line.split()[1])
            hdrs: dict[str, str] = {}
            while True:
                line = await self.reader.readline()
                if line in (b"\r\n", b""):
                    break
                k, _, v = line.decode().partition(":")
                hdrs[k.strip().lower()] = v.strip()
            data = await self.reader.readexactly(int(hdrs.get("content-length", "0")))
        except (ConnectionError, asyncio.IncompleteReadError, OSError):
            self.close()
            raise ConnectionError("transport error") from None
        if hdrs.get("connection", "").lower() == "close":
            self.close()
        return status, hdrs, data

    def close(self) -> None:
        if self.writer is not None:
            self.writer.close()
        self.reader = self.writer = None


def _server_timing(h: str) -> dict[str, float]:
    """``Server-Timing: a;dur=1.2, b;dur=3`` -> {"a": 1.2, "b": 3.0} [ms]."""
    out: dict[str, float] = {}
    for part in h.split(","):
        name, _, rest = part.strip().partition(";dur=")
        try:
            out[name] = float(rest)
        except ValueError:
            continue
    return out


def _phase_report(lat_ms: np.ndarray, timings: list[dict[str, float]]) -> dict[str, Any]:
    """Server phase durations: median and p99 over all requests, and the mean over the slowest 1 % of requests
    (what the tail is made of; client latency minus the phases = event loop, HTTP and network)."""
    if not timings:
        return {}
    names = sorted({k for t in timings for k in t})
    cols = {k: np.array([t.get(k, 0.0) for t in timings]) for k in names}
    slow = lat_ms >= np.percentile(lat_ms, 99)
    return {
        "p50": {k: round(float(np.percentile(v, 50)), 2) for k, v in cols.items()},
        "p99": {k: round(float(np.percentile(v, 99)), 2) for k, v in cols.items()},
        "slowest_1pct_mean": {**{k: round(float(v[slow].mean()), 2) for k, v in cols.items()},
                              "client_latency": round(float(lat_ms[slow].mean()), 2)},
    }


def _by_window(sent_s: np.ndarray, lat_ms: np.ndarray, window_s: float) -> list[float]:
    """p99 latency [ms] of the requests sent in each ``window_s`` of the run (where in time the tail is)."""
    if not len(lat_ms):
        return []
    k = (sent_s // window_s).astype(int)
    return [round(float(np.percentile(lat_ms[k == i], 99)), 1) for i in range(int(k.max()) + 1) if np.any(k == i)]


async def _device(port: int, token: str, sid: int, bodies: list[tuple[bytes, str]], t0: float, phase: float,
                  lat: list[float], stats: dict[str, int], timings: list[dict[str, float]], sent: list[float],
                  period: float) -> None:
    conn = _Conn("127.0.0.1", port)
    for k, (body, ctype) in enumerate(bodies):
        due = t0 + phase + k * period
        now = time.perf_counter()
        if now < due:
            await asyncio.sleep(due - now)
        elif now - due > 0.5:
            stats["late_sends"] += 1
        start = time.perf_counter()
        for attempt in range(5):  # same sequence number on every retry
            try:
                status, hdrs, _ = await conn.request(
                    "PUT", f"/v1/sessions/{sid}/batches/{k}", body,
                    {"Authorization": f"Bearer {token}", "Content-Type": ctype},
                )
            except ConnectionError:
                stats["transport_errors"] += 1
                await asyncio.sleep(0.05 * (attempt + 1))
                continue
            if status in (429, 503) and attempt < 4:  # refused, nothing stored: wait as asked, same number
                stats[f"retried_{status}"] = stats.get(f"retried_{status}", 0) + 1
                await asyncio.sleep(float(hdrs.get("retry-after", "1")))
                continue
            if status == 200:
                lat.append(time.perf_counter() - start)
                sent.append(start - t0)
                timings.append(_server_timing(hdrs.get("server-timing", "")))
                stats["acked"] += 1
                if hdrs.get("x-pednav-replayed") == "true":
                    stats["replayed"] += 1
            else:
                stats[f"http_{status}"] = stats.get(f"http_{status}", 0) + 1
            break
        else:
            stats["gave_up"] += 1
    conn.close()


async def _run_async(url: str, tokens: list[str], devices: int, bodies: list[tuple[bytes, str]],
                     cpu: Any, period: float) -> dict[str, Any]:
    import httpx2

    port = int(url.rsplit(":", 1)[1])
    limits = httpx2.Limits(max_connections=devices + 10, max_keepalive_connections=devices + 10)
    async with httpx2.AsyncClient(base_url=url, timeout=60.0, limits=limits) as client:
        token = tokens[-1]  # warm-up; every device is a user of its own (the rate limit is per user)
        h = {"Authorization": f"Bearer {token}"}
        # warm-up sessions (engine JIT compilation), not measured: consecutive session ids, so each of up to
        # _WARM_SESSIONS engine helper processes (chosen by session id) runs its kernels once
        async def warm_up() -> None:
            warm = (await client.post("/v1/sessions", json={"device_kind": "foot"}, headers=h)).json()["id"]
            for k, (body, ctype) in enumerate(bodies[:spread]):  # every phase of the walk (stand, walk, turns)
                # the first batch may wait for numba to compile the engine (about 30 s, more on a busy machine)
                # a worker still warming up answers 503 Retry-After, and the warm-up sessions share one user, whose
                # rate limit answers 429 Retry-After: wait as a device does, same sequence number (nothing stored)
                for _ in range(300):
                    r = await client.put(f"/v1/sessions/{warm}/batches/{k}", content=body,
                                         headers={**h, "content-type": ctype}, timeout=600.0)
                    if r.status_code not in (429, 503):
                        break
                    await asyncio.sleep(float(r.headers.get("retry-after", "1")))
                r.raise_for_status()

        spread = _spread(period)
        await asyncio.gather(*[warm_up() for _ in range(_WARM_SESSIONS)])
        sids = []
        for i in range(devices):
            r = await client.post("/v1/sessions", json={"device_kind": "foot"}, headers={"Authorization": f"Bearer {tokens[i]}"})
            r.raise_for_status()
            sids.append(r.json()["id"])
        lat: list[float] = []
        timings: list[dict[str, float]] = []
        sent: list[float] = []
        stats = {"acked": 0, "replayed": 0, "late_sends": 0, "transport_errors": 0, "gave_up": 0}
        t0 = time.perf_counter() + 0.5
        n = len(bodies) - spread
        cpu0 = cpu()
        await asyncio.gather(*[
            _device(port, tokens[i], sid, bodies[i % spread: i % spread + n], t0, period * i / devices, lat, stats,
                    timings, sent, period)
            for i, sid in enumerate(sids)
        ])
        wall = time.perf_counter() - t0
        cpu1 = cpu()
        # verify against what the server stored
        stored_total, lost, dup = 0, 0, 0
        for i, sid in enumerate(sids):
            r = await client.get(f"/v1/sessions/{sid}/batches", headers={"Authorization": f"Bearer {tokens[i]}"})
            r.raise_for_status()
            seqs = [b["seq"] for b in r.json()]
            stored_total += len(seqs)
            dup += len(seqs) - len(set(seqs))
            lost += len(set(range(n)) - set(seqs))
    a = np.array(lat) * 1e3
    pct = {f"p{q}": float(np.percentile(a, q)) if len(a) else None for q in (50, 95, 99)}
    return {
        "requests_sent": devices * n,
        "acked": stats["acked"],
        "stored": stored_total,
        "lost_batches": lost,
        "duplicated_batches": dup,
        "replayed_answers": stats["replayed"],
        "late_sends": stats["late_sends"],
        "transport_errors": stats["transport_errors"],
        "other_statuses": {k: v for k, v in stats.items() if k.startswith("http_")},
        "retried_after": {k: v for k, v in stats.items() if k.startswith("retried_")},
        "latency_ms": {**pct, "max": float(a.max()) if len(a) else None, "mean": float(a.mean()) if len(a) else None},
        "server_phases_ms": _phase_report(a, timings),
        "latency_p99_ms_by_10s": _by_window(np.array(sent), a, 10.0),
        # CPU time per acknowledged batch [ms]: the cost that decides capacity, independent of other load
        "cpu_ms_per_batch": {k: round(1e3 * (cpu1[k] - cpu0[k]) / max(stats["acked"], 1), 3) for k in cpu1},
        "throughput_rps": stats["acked"] / wall if wall > 0 else None,
        "wall_s": wall,
    }


def run(args: argparse.Namespace) -> dict[str, Any]:
    if args.sweep:
        return _sweep(args)
    return _run_one(args)


def _sweep(args: argparse.Namespace) -> dict[str, Any]:
    """Every (database, workers, devices) point, one run each; the capacity figure per (database, workers)."""
    points = []
    for db in args.sweep_databases:
        for w in args.sweep_workers:
            for n in args.sweep_devices:
                one = argparse.Namespace(**{**vars(args), "devices": n, "workers": w,
                                            "database_url": None if db == "sqlite" else db})
                try:
                    r = _run_one(one)
                except Exception as exc:  # noqa: BLE001 - a point that could not run is reported, the sweep goes on
                    points.append({"database": "sqlite" if db == "sqlite" else "postgresql", "workers": w,
                                   "devices": n, "error": f"{type(exc).__name__}: {exc}"})
                    continue
                points.append({k: r[k] for k in ("database", "server_workers", "devices", "acked", "lost_batches",
                                                 "duplicated_batches", "late_sends", "other_statuses", "throughput_rps",
                                                 "cpu_ms_per_batch", "loadavg_1_5_15_at_end")}
                              | {"p50_ms": r["latency_ms"]["p50"], "p99_ms": r["latency_ms"]["p99"],
                                 "max_ms": r["latency_ms"]["max"], "workers": w})
    cores = os.cpu_count() or 1
    capacity = {}
    for db in {p["database"] for p in points}:
        for w in args.sweep_workers:
            ok = [p["devices"] for p in points if p["database"] == db and p["workers"] == w and "error" not in p
                  and p["p99_ms"] is not None and p["p99_ms"] <= args.p99_ms and p["lost_batches"] == 0
                  and p["duplicated_batches"] == 0]
            best = max(ok, default=0)
            # cores the server could use: each worker has an engine helper; never more than the machine has
            used = min(cores, 2 * w)
            capacity[f"{db}/{w}"] = {"devices": best, "cores_usable": used, "devices_per_core": round(best / used, 1)}
    out = {"p99_bound_ms": args.p99_ms, "seconds_per_point": args.seconds, "rate_hz": args.rate_hz,
           "batch_seconds": args.batch_seconds, "cpus": cores,
           "points": points, "capacity": capacity}
    if args.plot:
        _plot(points, args.plot, args.p99_ms, args.batch_seconds)
        out["plot"] = args.plot
    return out


def _plot(points: list[dict[str, Any]], path: str, bound_ms: float, period: float) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.5))
    for db in sorted({p["database"] for p in points}):
        for w in sorted({p["workers"] for p in points}):
            xs = [(p["devices"], p["p99_ms"]) for p in points if p["database"] == db and p["workers"] == w
                  and p.get("p99_ms") is not None]
            if xs:
                xs.sort()
                ax.plot([x for x, _ in xs], [y for _, y in xs], marker="o", ls="-" if db == "postgresql" else "--",
                        label=f"{db}, {w} worker{'s' * (w > 1)}")
    ax.axhline(bound_ms, color="k", lw=0.8, ls=":")
    ax.set_xlabel(f"devices (one {period:g}-s batch every {period:g} s each)")
    ax.set_ylabel("p99 upload latency [ms]")
    ax.set_yscale("log")
    ax.set_title("pednav bench load --sweep")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _run_one(args: argparse.Namespace) -> dict[str, Any]:
    import tempfile

    from server.db import drop_schema, make_engine
    from server.settings import Settings

    period = args.batch_seconds
    seconds = max(1, int(round(args.seconds)))
    n = max(1, int(round(seconds / period)))  # uploads per device
    bodies = _bodies(n + _spread(period), args.rate_hz, args.encoding, period)
    schema = None
    tmp = None
    if args.database_url:
        url = args.database_url
        if url.startswith("postgresql"):
            schema = f"bench_{uuid.uuid4().hex[:10]}"
    else:
        tmp = tempfile.TemporaryDirectory(prefix="pednav-load-")
        url = f"sqlite:///{tmp.name}/load.db"
    load_start = os.getloadavg()
    srv = _Server(url, schema, args.workers)
    try:
        srv.wait(workers=args.workers)
        settings = Settings(database_url=url, db_schema=schema)
        eng = make_engine(settings)
        from server import crud
        from server.db import make_sessionmaker

        with make_sessionmaker(eng)() as db:
            # one user per device (independent people): the rate limit is per user, shared by a user's tokens,
            # so one user's 200 devices at 1 batch/s would be held to 50 requests/s; the last one warms up
            run_id = uuid.uuid4().hex[:8]
            tokens = [crud.create_user(db, f"load-{run_id}-{i}")[1] for i in range(args.devices + 1)]
            db.commit()
        eng.dispose()
        res = asyncio.run(_run_async(srv.url, tokens, args.devices, bodies, lambda: _cpu_probe(srv.proc.pid, args.workers),
                                     period))
    finally:
        srv.stop()
        if schema:
            e = make_engine(Settings(database_url=url))
            drop_schema(e, schema)
            e.dispose()
        if tmp is not None:
            tmp.cleanup()
    backend = "postgresql" if url.startswith("postgresql") else "sqlite"
    return {
        "devices": args.devices,
        "seconds": seconds,
        "rate_hz": args.rate_hz,
        "batch_seconds": period,
        "encoding": args.encoding,
        "body_bytes": len(bodies[0][0]),
        "database": backend,
        "server_workers": args.workers,
        "engine_processes": Settings(database_url=url).engine_processes,  # what the server read (env or default)
        "cpus": os.cpu_count(),
        "loadavg_1_5_15_at_start": [round(x, 2) for x in load_start],
        "loadavg_1_5_15_at_end": [round(x, 2) for x in os.getloadavg()],
        **res,
    }
