"""The engine helper process: several channels in flight, cache misses restored from the stored state, and
answers identical to feeding the engine in this process."""

from __future__ import annotations

import threading

import numpy as np

from clients.synth import synthesize
from energy.engine import Engine
from models.batch import STREAMS, SensorBatch
from server.engine_pool import EnginePool
from server.ingest import feed_engine
from server.statecodec import pack_state


def _streams(b: SensorBatch) -> dict[str, np.ndarray]:
    out: dict[str, np.ndarray] = {}
    for name in STREAMS:
        out[f"{name}_t_ns"], out[name] = b.stream(name)
    return out


def test_helper_serves_channels_concurrently_and_restores_evicted_engines() -> None:
    batches = synthesize("walk", seed=4).batch.split_seconds(1.0)[:12]
    sessions = (1, 2, 3)
    ref: dict[int, list[tuple[str, bytes]]] = {}
    for sid in sessions:  # in this process
        e = Engine(mode="auto")
        ref[sid] = [(f.resp_json, f.state) for f in (feed_engine(e, b, sid, k) for k, b in enumerate(batches))]
    new_state = pack_state(Engine(mode="auto").to_bytes())
    pool = EnginePool(1, cache_size=2, channels=3)  # 3 sessions, 2 cached engines: evictions and restores
    got: dict[int, list[tuple[str, bytes]]] = {sid: [] for sid in sessions}
    misses = {sid: 0 for sid in sessions}
    errors: list[BaseException] = []

    def run(sid: int) -> None:
        try:
            state = new_state
            for k, b in enumerate(batches):
                out = pool.feed(sid, k, None, k, _streams(b))
                if out[0] == "miss":
                    misses[sid] += 1
                    out = pool.feed(sid, k, state, k, _streams(b))
                assert out[0] == "ok", out
                got[sid].append((out[1].resp_json, out[1].state))
                state = pack_state(out[1].state)
        except BaseException as exc:  # noqa: BLE001 - reported by the main thread
            errors.append(exc)

    try:
        threads = [threading.Thread(target=run, args=(sid,)) for sid in sessions]
        for t in threads:
            t.start()
        for t in threads:
            t.join(timeout=300)
        assert not errors, errors
        assert got == ref
        assert all(m >= 1 for m in misses.values())  # first batch of each session at least
        # a malformed batch comes back as the engine's own error, and the channel stays usable
        bad = _streams(batches[0])
        bad["acc_t_ns"] = bad["acc_t_ns"][::-1].copy()
        out = pool.feed(9, 0, new_state, 0, bad)
        assert out[0] == "batch_error" and out[1] == "acc_t_ns"
        assert pool.feed(9, 0, new_state, 0, _streams(batches[0]))[0] == "ok"
        proc = pool._helper(0).proc
    finally:
        pool.shutdown()
    assert not proc.is_alive()
