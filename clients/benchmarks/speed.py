"""``pednav bench speed``: per-sample cost of each engine mode vs two AHRS peers.

Peers: the ``ahrs`` package's Madgwick ``updateIMU`` (pure Python) and ``imufusion`` (x-io's Fusion AHRS, C,
attitude only, ``update_no_magnetometer`` called once per sample from Python: the strongest widely used peer;
the optional ``bench`` extra installs it, and its figures are null with ``peer_imufusion_missing`` saying why
without it). Everything is measured in the same run on the same real recording (a VICON trial from
``PEDNAV_DATA``; a synthetic walk when the data is absent, reported in ``"data"``), so the ratios are
meaningful on a noisy, shared machine. Compilation is excluded (one warm-up run); each figure is the best of
``--repeat`` runs, and the peers are measured before and after the engines (the better of the two is kept).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

__all__ = ["add_arguments", "run"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--repeat", type=int, default=3, help="timed runs per measurement (best is kept)")
    parser.add_argument("--pairs", type=int, default=7,
                        help="back-to-back ZUPT-KF / imufusion runs for the paired cost ratio (median reported)")
    parser.add_argument("--peer-samples", type=int, default=4000, help="samples fed to the Madgwick peer")
    parser.add_argument("--file", type=Path, default=None, help="a VICON .mat to use instead of the default trial")


def _load() -> tuple[str, np.ndarray, np.ndarray, np.ndarray]:
    """(name, t [s], acc [m/s^2], gyr [rad/s]) of the benchmark recording."""
    from clients.datasets import dataset_dir
    from clients.evaluation.harness import vicon_files

    d = dataset_dir("vicon")
    if d is not None:
        files = vicon_files(d)  # the trials eval vicon sees (no ._*.mat resource forks)
        if files:
            return _load_file(files[len(files) // 4])
    # synthetic fallback: 60 s of alternating rest and swing-like motion at 200 Hz
    rng = np.random.default_rng(0)
    t = np.arange(0, 60.0, 0.005)
    ph = (t % 1.1) / 1.1
    s = np.where(ph > 0.5, np.sin(np.pi * (ph - 0.5) / 0.5), 0.0)
    acc = np.column_stack([8 * s, np.zeros_like(s), -9.8 + 3 * s]) + rng.normal(0, 0.02, (t.size, 3))
    gyr = np.column_stack([np.zeros_like(s), 5 * s, np.zeros_like(s)]) + rng.normal(0, 0.005, (t.size, 3))
    return "synthetic", t, acc, gyr


def _load_file(path: Path) -> tuple[str, np.ndarray, np.ndarray, np.ndarray]:
    import scipy.io as sio

    m = sio.loadmat(path)
    t = m["ts"].ravel().astype(np.float64)
    imu = m["imu"].astype(np.float64)
    return f"vicon/{path.stem}", t - t[0], imu[:, :3].copy(), imu[:, 3:].copy()


def _best(fn, repeat: int) -> float:
    best = float("inf")
    for _ in range(max(1, repeat)):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def _paired_ratio(fa, fb, pairs: int) -> list[float]:
    """Time ``fa`` and ``fb`` back to back ``pairs`` times (alternating which goes first) and return the ratios
    time(fa) / time(fb), one per pair: a change of the machine's load between two blocks of runs (a shared
    machine) cancels out of each ratio, which it does not between two best-of-N figures taken apart."""
    ratios = []
    for k in range(max(1, pairs)):
        times = {}
        for name, fn in ((("a", fa), ("b", fb)) if k % 2 == 0 else (("b", fb), ("a", fa))):
            t0 = time.perf_counter()
            fn()
            times[name] = time.perf_counter() - t0
        ratios.append(times["a"] / times["b"])
    return ratios


def _imufusion_run(t: np.ndarray, acc: np.ndarray, gyr: np.ndarray):
    """A function running imufusion over the recording (None: not installed); see :func:`_imufusion_us`."""
    try:
        import imufusion
    except ImportError:
        return None
    g_dps = np.ascontiguousarray(np.degrees(gyr))
    a_g = np.ascontiguousarray(acc / 9.80665)
    dt = float(np.median(np.diff(t)))
    n = t.size

    def go() -> None:
        ahrs = imufusion.Ahrs()
        ahrs.set_sample_period(dt)
        upd = ahrs.update_no_magnetometer
        for k in range(n):
            upd(g_dps[k], a_g[k])

    return go


def _engine_us(mode: str, t: np.ndarray, acc: np.ndarray, gyr: np.ndarray, repeat: int) -> float | None:
    try:
        from energy.engine import Engine
        from models.batch import SensorBatch
    except ImportError:
        return None
    t_ns = np.round(t * 1e9).astype(np.int64)
    batch = SensorBatch(acc_t_ns=t_ns, acc=acc, gyr_t_ns=t_ns, gyr=gyr)

    def go() -> None:
        e = Engine(mode=mode)
        e.feed(batch)
        e.flush()

    go()  # warm-up (compilation)
    return _best(go, repeat) / t.size * 1e6


def _imufusion_us(t: np.ndarray, acc: np.ndarray, gyr: np.ndarray, repeat: int) -> float | None:
    """imufusion ``Ahrs.update_no_magnetometer`` [us per sample] over the whole recording (None: not installed).

    Fusion takes the gyroscope in deg/s and the accelerometer in g; the conversion is done once beforehand (not
    timed), the per-sample calls are."""
    go = _imufusion_run(t, acc, gyr)
    if go is None:
        return None
    go()
    return _best(go, repeat) / t.size * 1e6


def run(args: argparse.Namespace) -> dict:
    from ahrs.filters import Madgwick

    from models.zupt_nav import ZuptNavigator

    name, t, acc, gyr = _load_file(args.file) if args.file else _load()
    n = t.size

    def zupt() -> None:
        ZuptNavigator().run(t, acc, gyr)

    zupt()  # compile / load cache
    zupt_us = _best(zupt, args.repeat) / n * 1e6

    m = min(args.peer_samples, n)
    dt = float(np.median(np.diff(t)))

    def peer() -> None:
        f = Madgwick(frequency=1.0 / dt)
        q = np.array([1.0, 0.0, 0.0, 0.0])
        for k in range(m):
            q = f.updateIMU(q, gyr[k], acc[k])

    peer_us = _best(peer, args.repeat) / m * 1e6
    fusion_us = [_imufusion_us(t, acc, gyr, args.repeat)]
    out: dict = {"zupt_us_per_sample": round(zupt_us, 3)}
    for mode in ("pdr", "auto"):
        us = _engine_us(mode, t, acc, gyr, args.repeat)
        if us is not None:
            out[f"{mode}_us_per_sample"] = round(us, 3)
    out["peer_madgwick_us_per_sample"] = round(peer_us, 3)
    out["zupt_speedup_vs_peer"] = round(peer_us / zupt_us, 2)
    fusion_us.append(_imufusion_us(t, acc, gyr, args.repeat))
    if fusion_us[0] is None:
        out["peer_imufusion_us_per_sample"] = None
        out["peer_imufusion_missing"] = "imufusion is not installed (pip install 'pednav[bench]')"
    else:
        f_us = min(x for x in fusion_us if x is not None)
        out["peer_imufusion_us_per_sample"] = round(f_us, 3)
        out["peer_imufusion_us_before_after"] = [round(x, 3) for x in fusion_us if x is not None]
        # cost per sample as a multiple of imufusion's (1.0 = as fast; the target for the ZUPT-KF: <= 1.0)
        out["zupt_cost_vs_imufusion"] = round(zupt_us / f_us, 2)
        for mode in ("pdr", "auto"):
            if f"{mode}_us_per_sample" in out:
                out[f"{mode}_cost_vs_imufusion"] = round(out[f"{mode}_us_per_sample"] / f_us, 2)
        # the same ratio from back-to-back pairs (robust to the load changing during the run): median and all
        ratios = _paired_ratio(zupt, _imufusion_run(t, acc, gyr), args.pairs)
        out["zupt_cost_vs_imufusion_paired"] = round(float(np.median(ratios)), 2)
        out["zupt_cost_vs_imufusion_pairs"] = [round(r, 2) for r in ratios]
    out["data"] = name
    out["samples"] = int(n)
    return out
