"""``pednav bench engine``: CPU per batch of the server's engine path (restore -> feed -> serialise).

The server runs each session's engine in a helper process (:mod:`server.engine_pool`): per 1-s batch the
helper unpickles the streams, builds and validates the :class:`~models.batch.SensorBatch`, feeds the
engine, encodes the answer, the canonical raw batch and its digest and the new state, and pickles all of it
back. This benchmark drives exactly that code on a real recording (a 200 Hz 9-axis gdin foot walk; a
synthetic walk when the data is absent, reported in ``"data"``), ``--sessions`` sessions round-robin like
the load benchmark's devices, and reports per engine mode:

- ``helper_cached``: CPU time of the helper process [ms per batch] when it holds the session's engine
  (the steady state of the server);
- ``helper_restore``: the same with a helper that keeps no engine, so every batch restores the engine from
  the stored (compressed) state first (a server restart, another worker, an evicted engine);
- ``stages_us``: the same work in this process, split into stages and engine components (thread CPU time,
  components metered as in ``pednav energy simulate``; ``engine_other`` is the rest of ``Engine.feed``).

The CPU times are absolute, so the ``ahrs`` Madgwick ``updateIMU`` peer (as in ``pednav bench speed``) is
measured in the same run, before and after, and each figure is also given in peer samples (machine speed
cancels out), with the load average alongside.
"""

from __future__ import annotations

import argparse
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


def _helper_ms(mode: str, sess: list[list[dict[str, np.ndarray]]], cache: bool) -> dict[str, float]:
    """Feed every session's batches through one engine helper process; its CPU time per batch [ms]."""
    from server.engine_pool import EnginePool
    from server.settings import Settings
    from server.statecodec import pack_state

    # as the server builds it: one channel per ingest thread, the configured engine cache
    fields = Settings.model_fields
    pool = EnginePool(1, fields["engine_cache_size"].default if cache else 0, fields["ingest_threads"].default)
    try:
        states: dict[int, bytes] = {}

        def feed(sid: int, seq: int, streams: dict[str, np.ndarray]) -> None:
            out = pool.feed(sid, seq, None, seq, streams)
            if out[0] == "miss":
                out = pool.feed(sid, seq, states.get(sid, _NEW[mode]), seq, streams)
            if out[0] != "ok":
                raise RuntimeError(f"engine helper answered {out[:2]}")
            states[sid] = pack_state(out[1].state)

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
            "batches": n}


_NEW: dict[str, bytes] = {}  # packed state of a fresh engine per mode (what a session's first batch restores)


def _stages_us(mode: str, sess: list[list[dict[str, np.ndarray]]]) -> dict[str, float]:
    """The helper's work in this process, by stage and engine component [us per batch, thread CPU]."""
    from energy.engine import Engine
    from energy.simulate import component_meter
    from models.batch import SensorBatch
    from server.engine_pool import _pack_streams, _unpack_streams
    from server.formats import canonical_bytes, digest
    from server.ingest import Fed, _answer
    from server.statecodec import pack_state, unpack_state

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
                blob = pack_state(state)  # compressed by the worker
                t8 = clock()
                Engine.from_bytes(unpack_state(blob))
                t9 = clock()
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
                n += 1
    out = {k: round(v / n / 1e3, 1) for k, v in sorted(tot.items())}
    out["total_cached"] = round(sum(v for k, v in out.items() if k != "state_restore"), 1)
    return out


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
        cached = _helper_ms(mode, sess, cache=True)
        restore = _helper_ms(mode, sess, cache=False)
        stages = _stages_us(mode, sess)
        modes[mode] = {"helper_cached": cached, "helper_restore": restore, "stages_us": stages}
    peer.append(_peer_us(batch.acc, batch.gyr, dt, m))
    peer_us = min(peer)
    for r in modes.values():
        for k in ("helper_cached", "helper_restore"):
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
