"""Per-request phase timings of batch uploads, sent back in a ``Server-Timing`` header (cheap: a few clock
reads per request). The load benchmark collects them to explain its latency tail: queueing for an ingest
thread, authentication, the read, the engine (helper process round trip), the write and the commit."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager

__all__ = ["Phases", "current", "phase", "since"]

_local = threading.local()


class Phases:
    """Durations [ms] of named phases of one request, in order."""

    def __init__(self) -> None:
        self.ms: dict[str, float] = {}

    def add(self, name: str, seconds: float) -> None:
        self.ms[name] = self.ms.get(name, 0.0) + seconds * 1e3

    def header(self) -> str:
        return ", ".join(f"{k};dur={v:.2f}" for k, v in self.ms.items())

    def __enter__(self) -> Phases:
        _local.phases = self
        return self

    def __exit__(self, *exc: object) -> None:
        _local.phases = None


def current() -> Phases | None:
    return getattr(_local, "phases", None)


@contextmanager
def phase(name: str) -> Iterator[None]:
    """Time the block as ``name`` in the current thread's :class:`Phases` (no-op when none is active)."""
    ph = current()
    if ph is None:
        yield
        return
    t = time.perf_counter()
    try:
        yield
    finally:
        ph.add(name, time.perf_counter() - t)


def since(name: str, t0: float) -> None:
    """Record ``now - t0`` [s] as ``name`` (e.g. the wait for a lock that was just acquired)."""
    ph = current()
    if ph is not None:
        ph.add(name, time.perf_counter() - t0)
