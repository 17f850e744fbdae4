"""Engines in helper processes, so one uvicorn worker uses a second core for the navigation work.

The worker keeps HTTP, authentication and the database; a helper process (one per ``engine_processes``,
chosen by session id so a session always meets its cached engine) restores, feeds and serialises the engine
and sends back the answer and the new state bytes. Helpers cache engines by ``(session id, version)``; on a
miss the worker sends the stored state. Results are identical to in-process feeding (same engine code, same
bytes), and the worker still commits state and outputs in one versioned write transaction.
"""

from __future__ import annotations

import multiprocessing
import os
import threading
import time
from collections import OrderedDict
from concurrent.futures import ProcessPoolExecutor
from typing import Any

import numpy as np

__all__ = ["EnginePool"]

_CACHE: OrderedDict[int, tuple[int, Any]] = OrderedDict()
_CACHE_SIZE = 512


def _init(cache_size: int) -> None:
    global _CACHE_SIZE
    _CACHE_SIZE = cache_size
    parent = os.getppid()

    def watch_parent() -> None:  # a helper never outlives its server process (e.g. after SIGKILL)
        while True:
            time.sleep(1.0)
            if os.getppid() != parent:
                os._exit(0)

    threading.Thread(target=watch_parent, daemon=True, name="watch-parent").start()


def _feed(
    session_id: int, version: int, state: bytes | None, seq: int, streams: dict[str, np.ndarray]
) -> tuple[Any, ...]:
    """In the helper: feed one batch; ("ok", response, state, behaviour, mode) | ("miss",) | ("batch_error", field, problem)."""
    from energy.engine import Engine
    from models.batch import BatchError, SensorBatch
    from server.ingest import _update_dict

    hit = _CACHE.pop(session_id, None)
    if hit is not None and hit[0] == version:
        engine = hit[1]
    elif state is None:
        return ("miss",)
    else:
        engine = Engine.from_bytes(state)
    try:
        upd = engine.feed(SensorBatch(**streams))
    except BatchError as exc:  # sent back as plain values (the worker raises its own BatchError from them)
        return ("batch_error", exc.field, exc.problem)
    resp = _update_dict(session_id, seq, seq + 1, upd)
    blob = engine.to_bytes()
    _CACHE[session_id] = (version + 1, engine)
    while len(_CACHE) > _CACHE_SIZE:
        _CACHE.popitem(last=False)
    return ("ok", resp, blob, upd.behaviour, upd.mode)


class EnginePool:
    """``processes`` single-process executors (spawned lazily on first use).

    Parameters
    ----------
    processes : int
        Helper processes (>= 1).
    cache_size : int
        Engines each helper keeps in memory.
    """

    def __init__(self, processes: int, cache_size: int) -> None:
        self.processes = processes
        self.cache_size = cache_size
        self._pools: list[ProcessPoolExecutor] | None = None
        self._lock = threading.Lock()

    def _pool(self, session_id: int) -> ProcessPoolExecutor:
        with self._lock:  # ingest threads may arrive together on the first request
            if self._pools is None:
                ctx = multiprocessing.get_context("spawn")  # never fork a threaded server
                self._pools = [
                    ProcessPoolExecutor(max_workers=1, mp_context=ctx, initializer=_init, initargs=(self.cache_size,))
                    for _ in range(self.processes)
                ]
            return self._pools[session_id % self.processes]

    def feed(self, session_id: int, version: int, state: bytes | None, seq: int, streams: dict[str, np.ndarray]) -> tuple[Any, ...]:
        return self._pool(session_id).submit(_feed, session_id, version, state, seq, streams).result()

    def shutdown(self) -> None:
        if self._pools is not None:
            for p in self._pools:
                p.shutdown(wait=True, cancel_futures=True)
            self._pools = None
