"""``pednav bench engine``: CPU per batch of the server's engine path (restore -> feed -> serialise).

The server runs each session's engine in a helper process (:mod:`server.engine_pool`): per 1-s batch the
helper unpickles the streams, builds and validates the :class:`~models.batch.SensorBatch`, feeds the
engine, encodes the answer, the canonical raw batch and its digest and the new state, and pickles all of it
back. This benchmark drives exactly that code on a real recording (a 200 Hz 9-axis gdin foot walk; a
synthetic walk when the data is absent, reported in ``"data"``), ``--sessions`` sessions round-robin like
the load benchmark's devices, and reports per engine mode:

- ``helper_cached``: CPU time of the helper process [ms per batch] when it holds the session's engine
  (the steady state of the server), serialising the state when a checkpoint is due (every ``state_every``
  batches);
- ``helper_restore``: the same with a helper that keeps no engine, so every batch restores the engine from
  the stored checkpoint and replays the raw batches after it first (a server restart, another worker, an
  evicted engine);
- ``stages_us``: the same work in this process, split into stages and engine components (thread CPU time,
  components metered as in ``pednav energy simulate``; ``engine_other`` is the rest of ``Engine.feed``;
  ``state_compress`` the zlib of a complete state, ``state_checkpoint`` the checkpoint form uploads store);
- ``server_cached`` / ``server_restore``: the whole server path of a batch upload in this process
  (:class:`server.upload.Uploader` on a temporary SQLite database, engines in process, the session's engine
  cached or restored from the stored checkpoint and batches every time; the start-up objects frozen out of the
  garbage collector's reach after the warm-up, as the server's processes do): CPU [ms per batch, all threads] and the
  split by phase (``read``, ``decode``, ``load_state``, ``engine`` incl. the answer and the state's bytes when a
  checkpoint is due, ``write`` incl. the commit) [ms per batch, wall], with ``state_every`` (``--state-every``,
  default the server's ``PEDNAV_STATE_EVERY``).

The CPU times are absolute, so the ``ahrs`` Madgwick ``updateIMU`` peer (as in ``pednav bench speed``) is
measured in the same run, before and after, and each figure is also given in peer samples (machine speed
cancels out), with the load average alongside.
"""

from __future__ import annotations

import argparse
import gc
import os
import pickle
import time
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["add_arguments", "run"]


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--modes", nargs="+", choices=("zupt", "pdr", "auto"), default=["zupt", "auto"],
                   help="engine modes to measure (default: zupt auto)")
    p.add_argument("--sessions", type=int, default=200, help="sessions fed round-robin (default 200)")
    p.add_argument("--batches", type=int, default=20, help="1-s batches per session (default 20)")
    p.add_argument("--file", type=Path, default=None, help="a SensorConnect CSV to use instead of the default gdin walk")
    p.add_argument("--peer-samples", type=int, default=4000, help="samples fed to the Madgwick peer")
    p.add_argument("--state-every", type=int, default=None,
                   help="server path: a state checkpoint every N batches (default: the server's PEDNAV_STATE_EVERY)")
    p.add_argument("--server-sessions", type=int, default=50, help="sessions of the server-path measurement")


def _default_file() -> Path | None:
    """The longest 9-axis (format A) gdin walk, or None without the data."""
    from clients.datasets import dataset_dir
    from clients.importers._common import is_hidden
    from clients.importers.sensorconnect import read_header

    d = dataset_dir("gdin")
    if d is None:
        return None
    files = [f for f in sorted((d / "own").glob("*.csv")) if not is_hidden(f.name) and "scaledMagX" in read_header(f)]
    return max(files, key=lambda f: f.stat().st_size) if files else None


def _recording(path: Path | None) -> tuple[str, Any]:
    """(name, SensorBatch) of the benchmark recording."""
    if path is None:
        path = _default_file()
    if path is not None:
        from clients.importers.sensorconnect import load_sensorconnect

        rec = load_sensorconnect(path)
        return f"gdin/{path.stem}", rec.batch
    from clients.synth import synthesize

    return "synthetic/walk", synthesize("walk", seed=11, rate_hz=200.0).batch


def _session_batches(batch: Any, sessions: int, batches: int) -> list[list[dict[str, np.ndarray]]]:
    """Per session, ``batches`` consecutive 1-s batches as the worker hands them to the helper (stream dicts).

    Session ``i`` starts ``7 i`` seconds into the recording (looped with a time shift so time keeps
    increasing), so sessions are in different phases of the walk as the load benchmark's devices are."""
    parts = batch.split_seconds(1.0)
    n = len(parts)
    span = int(batch.t_end_ns) - int(batch.t_start_ns) + 10_000_000
    looped: list[dict[str, np.ndarray]] = []
    for k in range(n + batches):
        shift = (k // n) * span
        looped.append({key: (v + shift if key.endswith("_t_ns") else v) for key, v in parts[k % n]._kwargs().items()})
    return [looped[(7 * i) % n: (7 * i) % n + batches] for i in range(sessions)]


def _cpu_s(pid: int) -> float:
    """CPU seconds (user + system) used so far by process ``pid`` (Linux /proc)."""
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _peer_us(acc: np.ndarray, gyr: np.ndarray, dt: float, m: int) -> float:
    """ahrs Madgwick updateIMU [us per sample] (best of 3)."""
    from ahrs.filters import Madgwick

    best = float("inf")
    for _ in range(3):
        f = Madgwick(frequency=1.0 / dt)
        q = np.array([1.0, 0.0, 0.0, 0.0])
        t0 = time.thread_time_ns()
        for k in range(m):
            q = f.updateIMU(q, gyr[k], acc[k])
        best = min(best, (time.thread_time_ns() - t0) / 1e3 / m)
    return best


def _helper_ms(mode: str, sess: list[list[dict[str, np.ndarray]]], cache: bool,
               state_every: int | None = None) -> dict[str, float]:
    """Feed every session's batches through one engine helper process as the server does (a state checkpoint
    every ``state_every`` batches; a restore sends the last checkpoint and the raw batches after it); its CPU
    time per batch [ms]."""
    from models.batch import SensorBatch
    from server.engine_pool import EnginePool
    from server.formats import canonical_bytes
    from server.settings import Settings
    from server import statecodec

    # as the server builds it: one channel per ingest thread, the configured engine cache
    fields = Settings.model_fields
    every = int(state_every or fields["state_every"].default) if "state_every" in fields else 1
    pool = EnginePool(1, fields["engine_cache_size"].default if cache else 0, fields["ingest_threads"].default)
    try:
        ckpt: dict[int, tuple[bytes, int | None]] = {}
        raws: dict[int, list[bytes]] = {}

        def feed(sid: int, seq: int, streams: dict[str, np.ndarray]) -> None:
            if every == 1:  # the server before checkpoints: the complete state after every batch
                out = pool.feed(sid, seq, None, seq, streams)
                if out[0] == "miss":
                    out = pool.feed(sid, seq, ckpt.get(sid, (_NEW[mode], None))[0], seq, streams)
                if out[0] != "ok":
                    raise RuntimeError(f"engine helper answered {out[:2]}")
                ckpt[sid] = (statecodec.pack_state(out[1].state), None)
                return
            out = pool.feed(sid, seq, None, seq, streams, (seq + 1) % every == 0)
            if out[0] == "miss":
                blob, held = ckpt.get(sid, (_NEW[mode], None))
                stored = blob if held is None else (blob, raws[sid][held:])
                due = (seq + 1) % every == 0 or held is None or seq + 1 - held >= every
                out = pool.feed(sid, seq, stored, seq, streams, due)
            if out[0] != "ok":
                raise RuntimeError(f"engine helper answered {out[:2]}")
            raws.setdefault(sid, []).append(canonical_bytes(SensorBatch(**streams)))
            if out[1].state is not None:
                ckpt[sid] = (statecodec.pack_checkpoint(out[1].state, seq + 1), seq + 1)

        for seq, streams in enumerate(sess[0]):  # warm-up session (kernels loaded), not measured
            feed(-1, seq, streams)
        pid = pool._helper(0).proc.pid
        c0, w0 = _cpu_s(pid), time.perf_counter()
        n = 0
        for k in range(len(sess[0])):
            for i, batches in enumerate(sess):
                feed(i, k, batches[k])
                n += 1
        c1, w1 = _cpu_s(pid), time.perf_counter()
    finally:
        pool.shutdown()
    return {"cpu_ms_per_batch": round(1e3 * (c1 - c0) / n, 3), "wall_ms_per_batch": round(1e3 * (w1 - w0) / n, 3),
            "batches": n, "state_every": every}


_NEW: dict[str, bytes] = {}  # packed state of a fresh engine per mode (what a session's first batch restores)


def _stages_us(mode: str, sess: list[list[dict[str, np.ndarray]]]) -> dict[str, float]:
    """The helper's work in this process, by stage and engine component [us per batch, thread CPU]."""
    from energy.engine import Engine
    from energy.simulate import component_meter
    from models.batch import SensorBatch
    from server.engine_pool import _pack_streams, _unpack_streams
    from server.formats import canonical_bytes, digest
    from server.ingest import Fed, _answer
    from server.statecodec import pack_checkpoint, pack_state, unpack_state

    clock = time.thread_time_ns
    tot: dict[str, int] = {}

    def add(k: str, v: int) -> None:
        tot[k] = tot.get(k, 0) + v

    warm = Engine(mode=mode)
    for streams in sess[0]:
        warm.feed(SensorBatch(**streams))
    engines = [Engine(mode=mode) for _ in sess]
    n = 0
    with component_meter() as meter:
        for k in range(len(sess[0])):
            for i, batches in enumerate(sess):
                msg = pickle.dumps((i, k, None, k, *_pack_streams(batches[k])), protocol=pickle.HIGHEST_PROTOCOL)
                meter.ns.clear()
                t0 = clock()
                streams = _unpack_streams(*pickle.loads(msg)[4:])
                t1 = clock()
                b = SensorBatch(**streams)
                t2 = clock()
                upd = engines[i].feed(b)
                t3 = clock()
                resp, text = _answer(i, k, k + 1, upd)
                t4 = clock()
                raw = canonical_bytes(b)
                dg = digest(raw)
                t5 = clock()
                state = engines[i].to_bytes()
                t6 = clock()
                fed = Fed(resp, text, raw, dg, state, len(b.acc_t_ns), len(b.gyr_t_ns), len(b.mag_t_ns))
                pickle.dumps(("ok", fed), protocol=pickle.HIGHEST_PROTOCOL)
                t7 = clock()
                blob = pack_state(state)  # a complete state (session start and close)
                t8 = clock()
                Engine.from_bytes(unpack_state(blob))
                t9 = clock()
                pack_checkpoint(state, k + 1)  # what a batch upload stores when a checkpoint is due
                t10 = clock()
                comp = 0
                for (name, _), ns in meter.ns.items():
                    add(name, ns)
                    comp += ns
                add("ipc_unpickle", t1 - t0)
                add("batch_construct", t2 - t1)
                add("engine_other", t3 - t2 - comp)
                add("answer_json", t4 - t3)
                add("canonical_digest", t5 - t4)
                add("state_to_bytes", t6 - t5)
                add("ipc_pickle", t7 - t6)
                add("state_restore", t9 - t8)
                add("state_compress", t8 - t7)
                add("state_checkpoint", t10 - t9)
                n += 1
    out = {k: round(v / n / 1e3, 1) for k, v in sorted(tot.items())}
    out["total_cached"] = round(sum(v for k, v in out.items() if k not in ("state_restore", "state_compress",
                                                                          "state_checkpoint")), 1)
    return out


def _server_ms(mode: str, sess: list[list[dict[str, np.ndarray]]], cache: bool, state_every: int | None,
               n_sessions: int) -> dict[str, Any]:
    """The server's upload path in this process (module docstring): CPU per batch and the split by phase."""
    import tempfile

    from models.batch import SensorBatch
    from server import crud
    from server.app import create_app
    from server.formats import MSGPACK_TYPE, encode_msgpack
    from server.settings import Settings
    from server.timing import Phases

    sess = sess[:max(1, n_sessions)]
    with tempfile.TemporaryDirectory() as tmp:
        kw: dict[str, Any] = {} if state_every is None else {"state_every": state_every}
        settings = Settings(database_url=f"sqlite:///{tmp}/bench.db", engine_processes=0, engine_warmup=False,
                            engine_mode=mode, engine_cache_size=Settings.model_fields["engine_cache_size"].default
                            if cache else 0, rate_limit_per_s=0.0, **kw)
        app = create_app(settings)
        try:
            with app.state.sessionmaker() as db:
                _, token = crud.create_user(db, "bench")
                db.commit()
            from fastapi.testclient import TestClient

            with TestClient(app) as c:
                sids = [c.post("/v1/sessions", json={"device_kind": "foot"},
                               headers={"Authorization": f"Bearer {token}"}).json()["id"] for _ in range(len(sess) + 1)]
                up = app.state.uploader
                bodies = [[encode_msgpack(SensorBatch(**b)) for b in batches] for batches in sess]
                for seq, b in enumerate(sess[0]):  # warm-up session, not measured
                    up.upload(token, sids[-1], seq, encode_msgpack(SensorBatch(**b)), MSGPACK_TYPE, 10**6)
                # the start-up objects out of the collector's reach, as the server's workers and helpers do
                # (server.app.app_from_env, server.engine_pool): a full collection over them is ~0.1-0.2 s
                gc.collect()
                gc.freeze()
                phases: dict[str, float] = {}
                n = 0
                c0, w0 = time.process_time(), time.perf_counter()
                for k in range(len(sess[0])):
                    for i in range(len(sess)):
                        with Phases() as ph:
                            up.upload(token, sids[i], k, bodies[i][k], MSGPACK_TYPE, 10**6)
                        for name, ms in ph.ms.items():
                            phases[name] = phases.get(name, 0.0) + ms
                        n += 1
                c1, w1 = time.process_time(), time.perf_counter()
        finally:
            gc.unfreeze()
            app.state.db_engine.dispose()
    return {"cpu_ms_per_batch": round(1e3 * (c1 - c0) / n, 3), "wall_ms_per_batch": round(1e3 * (w1 - w0) / n, 3),
            "phases_ms": {k: round(v / n, 3) for k, v in phases.items()}, "state_every": getattr(settings, "state_every", 1),
            "batches": n}


def run(args: argparse.Namespace) -> dict[str, Any]:
    from energy.engine import Engine
    from server.statecodec import pack_state

    load_start = os.getloadavg()
    name, batch = _recording(args.file)
    sess = _session_batches(batch, max(1, args.sessions), max(1, args.batches))
    t = (batch.acc_t_ns - batch.acc_t_ns[0]) / 1e9
    m = min(args.peer_samples, len(t))
    dt = float(np.median(np.diff(t)))
    peer = [_peer_us(batch.acc, batch.gyr, dt, m)]
    modes: dict[str, Any] = {}
    for mode in args.modes:
        _NEW[mode] = pack_state(Engine(mode=mode).to_bytes())
        every = getattr(args, "state_every", None)
        cached = _helper_ms(mode, sess, cache=True, state_every=every)
        restore = _helper_ms(mode, sess, cache=False, state_every=every)
        stages = _stages_us(mode, sess)
        n_srv = getattr(args, "server_sessions", 50)
        modes[mode] = {"helper_cached": cached, "helper_restore": restore, "stages_us": stages,
                       "server_cached": _server_ms(mode, sess, True, every, n_srv),
                       "server_restore": _server_ms(mode, sess, False, every, n_srv)}
    peer.append(_peer_us(batch.acc, batch.gyr, dt, m))
    peer_us = min(peer)
    for r in modes.values():
        for k in ("helper_cached", "helper_restore", "server_cached", "server_restore"):
            r[k]["cpu_in_peer_samples"] = round(1e3 * r[k]["cpu_ms_per_batch"] / peer_us, 1)
    return {
        "data": name,
        "rate_hz": round(float(batch.rate_hz("acc")), 1),
        "streams": [s for s in ("acc", "gyr", "mag") if batch.stream(s)[0].size],
        "sessions": len(sess),
        "batches_per_session": len(sess[0]),
        "modes": modes,
        "peer_madgwick_us_per_sample": round(peer_us, 3),
        "peer_madgwick_us_before_after": [round(x, 3) for x in peer],
        "cpus": os.cpu_count(),
        "loadavg_1_5_15_at_start": [round(x, 2) for x in load_start],
        "loadavg_1_5_15_at_end": [round(x, 2) for x in os.getloadavg()],
    }
