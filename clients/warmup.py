"""The navigation kernels' first compilation, announced as such.

The engine's hot loops are numba kernels compiled on first use and cached (``cache=True``: in ``__pycache__``
beside their modules), so only the first run of a fresh install compiles them, for a minute or two. A command
that is about to use the engine calls :func:`warm_up` first: it runs the engine on the recording in a worker
thread while the terminal shows what is being compiled (numba's ``numba:compile`` events, which fire on a cache
miss only), so a first run does not look hung and the progress bars that follow measure the work itself.
"""

from __future__ import annotations

import sys
import threading
import time
from dataclasses import dataclass, field
from typing import Any, TextIO

__all__ = ["CompileWatch", "WarmUp", "warm_up"]


_OWN = ("models.", "energy.", "clients.", "server.")


@dataclass
class CompileWatch:
    """Counts numba compilations (cache misses) while registered: ``compiled`` every function (numba's own
    overloads included), ``own`` pednav's kernels; ``current`` the outermost pednav kernel being compiled."""

    compiled: int = 0
    own: int = 0
    current: str = ""
    names: list[str] = field(default_factory=list)
    _stack: list[str] = field(default_factory=list)

    @property
    def busy(self) -> bool:
        return bool(self._stack)

    def __enter__(self) -> CompileWatch:
        from numba.core import event

        watch = self

        class _Listener(event.Listener):
            def on_start(self, ev: Any) -> None:
                disp = ev.data.get("dispatcher") if isinstance(ev.data, dict) else None
                py = getattr(disp, "py_func", None)
                name = f"{getattr(py, '__module__', '?')}.{getattr(py, '__qualname__', '?')}"
                watch._stack.append(name)
                own = [n for n in watch._stack if n.startswith(_OWN)]
                if own:
                    watch.current = own[0]

            def on_end(self, ev: Any) -> None:
                name = watch._stack.pop() if watch._stack else "?"
                watch.compiled += 1
                watch.own += name.startswith(_OWN)
                watch.names.append(name)

        self._listener = _Listener()
        event.register("numba:compile", self._listener)
        return self

    def __exit__(self, *exc: object) -> None:
        from numba.core import event

        event.unregister("numba:compile", self._listener)


@dataclass(frozen=True)
class WarmUp:
    """``compiled``: kernels compiled (0: all came from the cache); ``seconds``: wall time of the warm-up."""

    compiled: int
    seconds: float


def _run_engine(batches: list[Any]) -> None:
    from energy.device import replay
    from energy.engine import Engine

    profile = None
    for b in batches:  # a new user, then the same user on the profile the first walk handed out
        eng = Engine(mode="auto", profile=profile)
        replay(eng, b, 1.0)
        profile = eng.profile_dict()


def warm_up(batches: list[Any], show: bool = True, out: TextIO | None = None, refresh_s: float = 0.5) -> WarmUp:
    """Run the engine (``auto``, then again on the profile it handed out) over ``batches`` so every kernel the
    work ahead needs is compiled or loaded from the cache; with ``show``, a status line on ``out`` (stderr)
    while kernels compile, said to be the first run's compilation, and one line at the end."""
    out = out or sys.stderr
    t0 = time.monotonic()
    err: list[BaseException] = []

    def work() -> None:
        try:
            _run_engine(batches)
        except BaseException as exc:  # noqa: BLE001 - re-raised in the calling thread
            err.append(exc)

    with CompileWatch() as watch:
        th = threading.Thread(target=work, name="pednav-warmup", daemon=True)
        th.start()
        announced = False
        while th.is_alive():
            th.join(refresh_s)
            if show and (watch.compiled > 0 or watch.busy):
                if not announced:
                    print("first run: compiling the navigation kernels (numba; cached for the next runs, "
                          "typically 1-2 minutes) ...", file=out, flush=True)
                    announced = True
                line = (f"  {watch.own} pednav kernels compiled ({watch.compiled} functions with numba's own) in "
                        f"{time.monotonic() - t0:3.0f} s, now {watch.current[-45:]}")
                print("\r" + line.ljust(100)[:100], end="", file=out, flush=True)
        if err:
            raise err[0]
    res = WarmUp(watch.compiled, time.monotonic() - t0)
    if show:
        if announced:
            print(f"\r  compiled {watch.own} pednav kernels ({res.compiled} functions) in {res.seconds:.0f} s; cached "
                  "now, the next run loads them in seconds".ljust(100), file=out, flush=True)
        else:
            print(f"navigation kernels loaded from the cache in {res.seconds:.1f} s", file=out, flush=True)
    return res
