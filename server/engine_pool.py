"""Engines in helper processes, so one uvicorn worker uses a second core for the navigation work.

The worker keeps HTTP, authentication and the database; a helper process (one per ``engine_processes``,
chosen by session id so a session always meets its cached engine) restores, feeds and serialises the engine
and sends back everything the worker stores: the answer (as a dict and as its JSON text), the canonical raw
batch and its digest, and the new state (the worker compresses it). Results are identical to in-process feeding
(same engine code, same bytes), and the worker still commits state and outputs in one versioned write transaction.

A helper keeps the engine it fed last per session, under the version the worker is about to commit; the worker
continues that engine only when it committed exactly that version from it (:meth:`EnginePool.committed`,
used up by :meth:`EnginePool.take`), and otherwise sends the stored state, which the helper then always
restores. The helper caches before the worker writes, and the write can fail: another worker (process) commits
that version first with other content (a different batch under the same number, a Sensor Logger piece that
took newer messages), or the write transaction is refused or breaks. The helper's engine is then not the
stored one for that version, and continuing it gave wrong positions for the rest of the session. Vouching
after the commit (as :class:`server.ingest.EngineHost` re-caches in-process engines only after the commit)
covers every way a write can fail without naming them; a "forget" message on failure would have to reach the
helper from each failure path, and a content digest in the key would need the stored state's digest, which the
hot path does not read.

Each worker thread talks to a helper over its own pipe (a fixed set of ``channels`` per helper, one per
ingest thread): a request is one ``send`` and one blocking ``recv`` in the calling thread, both without the
GIL while they wait. (A ``ProcessPoolExecutor`` needs a feeder thread, a result thread and a future per call:
three more GIL hand-overs per batch in a worker whose GIL is its bottleneck.)
"""

from __future__ import annotations

import multiprocessing
import os
import queue
import threading
import time
from collections import OrderedDict
from typing import Any

import numpy as np

from models.batch import STREAMS

__all__ = ["EngineHelperDied", "EngineHelperError", "EnginePool"]

_CACHE: OrderedDict[int, tuple[int, Any]] = OrderedDict()
_CACHE_SIZE = 512


class EngineHelperError(RuntimeError):
    """The helper process failed outside the engine's own validation (an error inside it, or it died)."""


class EngineHelperDied(EngineHelperError):
    """The helper process died (killed, out of memory) while or before it answered: the request was not fed
    for good (the worker commits nothing without an answer), and a fresh helper takes the next one."""


def _watch_parent() -> None:
    parent = os.getppid()

    def watch() -> None:  # a helper never outlives its server process (e.g. after SIGKILL)
        while True:
            time.sleep(1.0)
            if os.getppid() != parent:
                os._exit(0)

    threading.Thread(target=watch, daemon=True, name="watch-parent").start()


def _pack_streams(streams: dict[str, np.ndarray]) -> tuple[tuple[int, ...], bytearray]:
    """The worker's side of a request: per stream the sample count, and all timestamps (int64) and values
    (float64, rows of 3) in one buffer. Pickling six arrays instead costs ~16 us of the worker's GIL per batch."""
    counts = []
    buf = bytearray()
    for name in STREAMS:
        t = np.ascontiguousarray(streams[f"{name}_t_ns"], dtype=np.int64).reshape(-1)
        v = np.ascontiguousarray(streams[name], dtype=np.float64).reshape(-1, 3)
        if len(t) != len(v):
            raise ValueError(f"{name}: {len(v)} samples but {len(t)} timestamps")
        counts.append(len(t))
        buf += t.tobytes()
        buf += v.tobytes()
    return tuple(counts), buf


def _unpack_streams(counts: tuple[int, ...], buf: bytearray) -> dict[str, np.ndarray]:
    """The helper's side: the stream arrays as views of the (writable) buffer."""
    out: dict[str, np.ndarray] = {}
    off = 0
    for name, n in zip(STREAMS, counts):
        out[f"{name}_t_ns"] = np.frombuffer(buf, dtype=np.int64, count=n, offset=off)
        off += 8 * n
        out[name] = np.frombuffer(buf, dtype=np.float64, count=3 * n, offset=off).reshape(n, 3)
        off += 24 * n
    return out


def _feed(
    session_id: int, version: int, state: bytes | tuple[bytes, list[bytes]] | None, seq: int, counts: tuple[int, ...],
    buf: bytearray, want_state: bool = True, encode_raw: bool = True,
) -> tuple[Any, ...]:
    """In the helper: feed one batch; ("ok", Fed) | ("miss",) | ("batch_error", field, problem).

    ``state`` None: continue the cached engine at ``version`` ("miss" without one); else restore ``state`` (a
    stored blob, or a blob and the stored raw batches after its checkpoint, :func:`server.ingest.replay_engine`),
    also when an engine is cached at ``version`` (the worker does not vouch for it, see the module docstring).
    ``want_state``: the answer carries the engine's new state (a checkpoint is due). ``encode_raw`` False: the
    worker has the batch's canonical bytes (:func:`server.formats.decode_upload`); the answer's ``raw`` and
    ``digest`` are left empty for it to fill in (nor are the bytes sent back).
    """
    from energy.engines import engine_from_bytes
    from models.batch import BatchError, SensorBatch
    from server.ingest import feed_engine, replay_engine
    from server.statecodec import unpack_state

    hit = _CACHE.pop(session_id, None)
    if state is not None:
        blob, raws = (state, []) if isinstance(state, (bytes, bytearray)) else state
        engine = replay_engine(engine_from_bytes(unpack_state(blob)), raws)
    elif hit is not None and hit[0] == version:
        engine = hit[1]
    else:
        return ("miss",)
    try:
        fed = feed_engine(engine, SensorBatch(**_unpack_streams(counts, buf)), session_id, seq, want_state,
                          None if encode_raw else b"")
        if not encode_raw:
            fed = fed._replace(digest="")
    except BatchError as exc:  # sent back as plain values (the worker raises its own BatchError from them)
        return ("batch_error", exc.field, exc.problem)
    _CACHE[session_id] = (version + 1, engine)
    while len(_CACHE) > _CACHE_SIZE:
        _CACHE.popitem(last=False)
    return ("ok", fed)


def _serve(conns: list[Any], cache_size: int, ready: Any = None, warm: bool = False) -> None:
    """Helper process main loop: answer requests on any of ``conns`` until all are closed. With ``warm``, the
    engine's kernels are compiled or loaded first (:func:`server.warmup.warm_up`); ``ready`` is set then."""
    import gc
    import selectors

    import energy.engine  # noqa: F401 - loaded before the freeze below
    import energy.phone_engine  # noqa: F401

    global _CACHE_SIZE
    _CACHE_SIZE = cache_size
    _watch_parent()
    if warm:
        from server.warmup import warm_up

        warm_up(energy.engine.Engine)
    if ready is not None:
        ready.set()
    gc.collect()
    gc.freeze()  # module objects out of the collector's reach (full collections stall every session's feed)
    # one selector for the helper's life (multiprocessing.connection.wait builds one and registers every
    # channel on each call: ~1 us per channel per request)
    sel = selectors.DefaultSelector()
    for c in conns:
        sel.register(c, selectors.EVENT_READ)
    while sel.get_map():
        for key, _ in sel.select():
            c = key.fileobj
            try:
                args = c.recv()
            except (EOFError, OSError):
                sel.unregister(c)
                continue
            try:
                out: tuple[Any, ...] = _feed(*args)
            except Exception as exc:  # noqa: BLE001 - answered, so the channel stays in step
                out = ("error", f"{type(exc).__name__}: {exc}")
            c.send(out)


class _Helper:
    def __init__(self, ctx: Any, channels: int, cache_size: int, warm: bool = False) -> None:
        pairs = [ctx.Pipe(duplex=True) for _ in range(channels)]
        self.ready = ctx.Event()
        self.proc = ctx.Process(target=_serve, args=([b for _, b in pairs], cache_size, self.ready, warm),
                                daemon=True, name="pednav-engine")
        self.proc.start()
        for _, b in pairs:
            b.close()
        self.free: queue.SimpleQueue[Any] = queue.SimpleQueue()
        self.broken = False  # a pipe failed: the helper is replaced on the next request
        self.conns = [a for a, _ in pairs]
        for a in self.conns:
            self.free.put(a)

    def stop(self) -> None:
        for c in self.conns:
            c.close()
        self.proc.join(timeout=10)
        if self.proc.is_alive():
            self.proc.kill()
            self.proc.join()


class EnginePool:
    """``processes`` helper processes (spawned lazily on first use), ``channels`` pipes to each.

    Parameters
    ----------
    processes : int
        Helper processes (>= 1).
    cache_size : int
        Engines each helper keeps in memory.
    channels : int
        Pipes per helper: the most requests in flight to one helper (one per ingest thread); further callers
        wait for a free pipe.
    warm : bool
        Each helper compiles or loads the engine's kernels before it takes requests (:mod:`server.warmup`).
    """

    def __init__(self, processes: int, cache_size: int, channels: int = 16, warm: bool = False) -> None:
        self.processes = processes
        self.cache_size = cache_size
        self.channels = channels
        self.warm = warm
        self._helpers: list[_Helper | None] | None = None
        self._lock = threading.Lock()
        # session id -> version this worker committed from its helper's cached engine (LRU, as the helpers')
        self._committed: OrderedDict[int, int] = OrderedDict()
        self._committed_lock = threading.Lock()

    def _helper(self, session_id: int) -> _Helper:
        i = session_id % self.processes
        with self._lock:  # ingest threads may arrive together on the first request
            ctx = multiprocessing.get_context("spawn")  # never fork a threaded server
            if self._helpers is None:  # all helpers start together (each imports the engine at start)
                self._helpers = [_Helper(ctx, self.channels, self.cache_size, self.warm) for _ in range(self.processes)]
            h = self._helpers[i]
            if h is None or h.broken or not h.proc.is_alive():
                if h is not None:
                    h.stop()
                h = self._helpers[i] = _Helper(ctx, self.channels, self.cache_size, self.warm)
            return h

    def start(self) -> None:
        """Spawn the helpers now (at server start), so their warm-up runs before the first upload."""
        self._helper(0)

    def ready(self) -> bool:
        """Every helper has been spawned and finished its warm-up (one replaced after a death warms up again;
        the server stays ready meanwhile: its kernels are cached on disk by then and load in about a second)."""
        with self._lock:
            helpers = self._helpers
        return helpers is not None and all(h is None or h.ready.is_set() or h.broken for h in helpers) and any(
            h is not None and h.ready.is_set() for h in helpers)

    def committed(self, session_id: int, version: int) -> None:
        """The worker committed ``version`` of the session from the state its helper fed last (the helper's
        cached engine may continue it); call only after the commit."""
        if self.cache_size <= 0:
            return
        with self._committed_lock:
            self._committed[session_id] = version
            self._committed.move_to_end(session_id)
            while len(self._committed) > self.cache_size:
                self._committed.popitem(last=False)

    def take(self, session_id: int, version: int) -> bool:
        """True when this worker committed ``version`` from the helper's cached engine (see :meth:`committed`).
        Used up: the feed that follows changes that engine, and its write may fail."""
        with self._committed_lock:
            return self._committed.pop(session_id, None) == version

    def forget(self, session_id: int) -> None:
        """Do not continue the helper's cached engine of the session (its next feed sends the stored state)."""
        with self._committed_lock:
            self._committed.pop(session_id, None)

    def feed(self, session_id: int, version: int, state: bytes | tuple[bytes, list[bytes]] | None, seq: int,
             streams: dict[str, np.ndarray], want_state: bool = True, encode_raw: bool = True) -> tuple[Any, ...]:
        """Feed one batch in the session's helper: ("ok", Fed) | ("miss",) | ("batch_error", field, problem).

        ``state`` None: the helper's cached engine at ``version`` (only after :meth:`take`); else the engine
        restored from ``state`` (a stored blob, or a blob and the stored raw batches after its checkpoint; the
        helper's cached one is then never used). ``want_state``: the answer carries the new engine state.
        ``encode_raw`` False: the answer's ``raw`` and ``digest`` are empty (the caller has the canonical bytes)."""
        h = self._helper(session_id)
        waited = 0.0
        while True:  # a free channel; give up at once when the helper died meanwhile (its channels never free)
            try:
                conn = h.free.get(timeout=0.5)
                break
            except queue.Empty:
                waited += 0.5
                if h.broken or not h.proc.is_alive():
                    raise EngineHelperDied("engine helper process died") from None
                if waited >= 120.0:
                    raise EngineHelperError("no engine helper channel free for 120 s") from None
        try:
            conn.send((session_id, version, state, seq, *_pack_streams(streams), want_state, encode_raw))
            out: tuple[Any, ...] = conn.recv()
        except (EOFError, OSError) as exc:  # the helper died: this pipe is out of step, do not reuse it
            h.broken = True
            raise EngineHelperDied(f"engine helper process died ({type(exc).__name__})") from None
        h.free.put(conn)
        if out[0] == "error":
            raise EngineHelperError(f"engine helper: {out[1]}")
        return out

    def pids(self) -> list[int]:
        """Process ids of the running helpers (none before the first request)."""
        with self._lock:
            return [h.proc.pid for h in self._helpers or [] if h is not None and h.proc.pid is not None]

    def shutdown(self) -> None:
        with self._lock:
            helpers, self._helpers = self._helpers, None
        for h in helpers or []:
            if h is not None:
                h.stop()
