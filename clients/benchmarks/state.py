"""``pednav bench state``: engine state size and CPU per batch against standing time.

Streams the synthetic scenario walk 60 s / stand ``--stand-min`` minutes / walk 60 s through an engine the way
``energy.device.replay`` does (the device obeys the engine's sensor configuration), and after every batch
records the thread CPU time of ``Engine.feed``, of ``Engine.to_bytes`` (the server stores the state after every
batch) and the size of the state and of its parts. A state that grows with the time a person stands would be
written, whole, after every upload.
"""

from __future__ import annotations

import argparse
import time
from typing import TYPE_CHECKING, Any

import numpy as np

from energy import codec

if TYPE_CHECKING:
    from clients.synth import Scenario

__all__ = ["add_arguments", "run", "measure"]

WALK_S = 60.0  # walking before and after the stand [s]
MARKS_MIN = (1.0, 10.0, 60.0)  # standing times at which the state is reported [min]


def scenario(stand_min: float) -> Scenario:
    from clients.synth import Scenario, Segment  # imported when used: `pednav --help` must not load the synthesiser

    """Walk, a long stand, walk (a short stand at both ends so the engine starts and ends at rest)."""
    return Scenario(f"stand-{stand_min:g}min", (Segment("stand", 10.0), Segment("walk", WALK_S, 90.0),
                                                 Segment("stand", 60.0 * stand_min), Segment("walk", WALK_S),
                                                 Segment("stand", 10.0)))


def _size(x: Any) -> int:
    return len(codec.dumps({"x": x}))


def parts(state: dict[str, Any]) -> dict[str, int]:
    """Encoded size [bytes] of the engine state's larger parts (segmenter and navigator buffers separately)."""
    out = {k: _size(v) for k, v in state.items() if k not in ("gait", "nav")}
    nav = state["nav"]
    out["nav.buf"] = sum(_size(nav[k]) for k in ("buf_t", "buf_acc", "buf_gyr", "buf_mag"))
    out["nav.rest"] = _size({k: v for k, v in nav.items() if not k.startswith("buf_")})
    gait = state["gait"]
    if gait is not None:
        seg = gait["seg"]
        out["gait.seg.buf"] = _size(seg["bt"]) + _size(seg["bm"])
        out["gait.seg.rest"] = _size({k: v for k, v in seg.items() if k not in ("bt", "bm")})
        for k, v in gait.items():
            if k != "seg":
                out["gait." + k] = _size(v)
    return out


def measure(mode: str, batch_s: float | None, stand_min: float, seed: int = 0) -> dict[str, Any]:
    """State size at 1, 10 and 60 min of standing (those reached) and per-batch CPU [ms] per phase.

    Parameters
    ----------
    mode : {"zupt", "pdr", "auto"}
        Engine mode.
    batch_s : float or None
        Upload length [s]; None: as long as the engine's sensor configuration asks.
    stand_min : float
        Length of the stand [min].
    seed : int
        Synthesiser seed.
    """
    from clients.synth import synthesize
    from energy.device import DeviceEmulator
    from energy.engine import Engine

    rec = synthesize(scenario(stand_min), seed=seed)
    segs = rec.truth.extra["segments"]
    t_stand0 = min(t0 for t0, _, lab in segs if lab == "stand" and t0 > 5.0)  # start of the long stand [s]
    t_stand1 = t_stand0 + 60.0 * stand_min
    eng = Engine(mode=mode)
    dev = DeviceEmulator(rec.batch)
    t_start, t_end = rec.batch.t_start_ns, rec.batch.t_end_ns
    rows: list[tuple[float, float, float, int]] = []  # (standing time [s], feed CPU [s], to_bytes CPU [s], bytes)
    marks: dict[str, Any] = {}
    todo = [m for m in MARKS_MIN if m <= stand_min]
    t0 = t_start
    peak = (0, 0.0)
    while t0 <= t_end:
        cfg = eng.sensor_config
        step = int(round((cfg.batch_s if batch_s is None else batch_s) * 1e9))
        t1 = min(t0 + step, t_end + 1)
        batch = dev.emit(t0, t1, cfg)
        c0 = time.thread_time()
        eng.feed(batch)
        c1 = time.thread_time()
        blob = eng.to_bytes()
        c2 = time.thread_time()
        t_rel = (t1 - t_start) / 1e9
        stood = t_rel - t_stand0
        rows.append((stood, c1 - c0, c2 - c1, len(blob)))
        if len(blob) > peak[0]:
            peak = (len(blob), t_rel)
        if todo and stood >= 60.0 * todo[0]:
            m = todo.pop(0)
            marks[f"{m:g}"] = {"t_s": t_rel, "bytes": len(blob), "parts": parts(codec.loads(blob))}
        t0 = t1
    eng.flush()
    stand = np.array([r for r in rows if 60.0 <= r[0] <= t_stand1 - t_stand0])  # after the first minute
    early = np.array([r for r in rows if 0.0 <= r[0] <= 60.0])
    late = np.array([r for r in rows if t_stand1 - t_stand0 - 60.0 <= r[0] <= t_stand1 - t_stand0])
    walk = np.array([r for r in rows if r[0] < -10.0 and r[0] > -WALK_S + 10.0])

    def cpu(a: np.ndarray) -> dict[str, float]:
        if not len(a):
            return {}
        return {"batches": int(len(a)), "feed_ms_median": float(np.median(a[:, 1]) * 1e3),
                "to_bytes_ms_median": float(np.median(a[:, 2]) * 1e3), "bytes_median": float(np.median(a[:, 3]))}

    return {"mode": mode, "batch_s": batch_s, "stand_min": stand_min, "seed": seed, "marks": marks,
            "peak_bytes": peak[0], "peak_at_s": peak[1],
            "cpu": {"walk_before": cpu(walk), "stand_first_min": cpu(early), "stand_last_min": cpu(late),
                    "stand_after_first_min": cpu(stand)}}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--mode", choices=("zupt", "pdr", "auto"), default="pdr", help="engine mode")
    parser.add_argument("--batch", default="auto", help="upload length [s], or 'auto': what the engine asks for")
    parser.add_argument("--stand-min", type=float, default=60.0, help="length of the stand [min]")
    parser.add_argument("--seed", type=int, default=0, help="synthesiser seed")


def run(args: argparse.Namespace) -> dict[str, Any]:
    """Entry point of ``pednav bench state``."""
    batch_s = None if args.batch == "auto" else float(args.batch)
    return measure(args.mode, batch_s, args.stand_min, args.seed)
