"""Engine warm-up at server start: compile (first start after an install) or load (later starts) the engine's
numba kernels before the server reports ready, so no upload waits for a compilation.

On a fresh install the first batch waited ~64 s for numba to compile the engine (a client with a 60-s timeout
gave up although its batch was stored) and the first walking batch took 14.9 s. Now each engine helper (or the
server process, without helpers) feeds :func:`warm_signal` through every engine mode in 1-s batches, with the
state serialised and restored between batches as the server does, as soon as it starts; until that is done
``/healthz`` answers 503 and uploads are refused with 503 ``Retry-After`` (nothing stored; the SDK waits it out),
so the first answer to a device comes within milliseconds and the first accepted batch within the normal latency.

The warm-up signal is built here, not taken from ``clients.synth`` (the server does not import clients): a foot
that stands, walks a few dozen strides with a turn, and stands again, with a magnetometer, at 100 Hz.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from models.batch import SensorBatch

__all__ = ["warm_signal", "warm_up", "warm_worker"]

_G = 9.80665
_MODES = ("auto", "zupt", "pdr")


def warm_signal(seconds: float = 45.0, rate_hz: float = 100.0) -> SensorBatch:
    """A foot-mounted IMU: 3 s still, strides of 1.1 s (0.55 s stance, 0.55 s swing with a forward push and
    a pitch rotation there and back), a 90 deg turn spread over strides in the middle, 3 s still at the end.

    Units: specific force [m/s^2] (z up when still reads -g in this NED-like body frame, as ``still_batch`` of
    the tests), angular rate [rad/s], field [uT] (a 48 uT field with 60 deg dip turning with the heading)."""
    t = np.arange(0.0, seconds, 1.0 / rate_hz)
    walk = (t > 3.0) & (t < seconds - 3.0)
    ph = ((t - 3.0) % 1.1) / 1.1
    swing = walk & (ph > 0.5)
    s = np.where(swing, np.sin(np.pi * (ph - 0.5) / 0.5), 0.0)
    pitch_rate = np.where(swing, 6.0 * np.sin(2.0 * np.pi * (ph - 0.5) / 0.5), 0.0)
    turn = walk & (t > seconds / 2 - 4.0) & (t < seconds / 2 + 4.0)
    yaw_rate = np.where(turn & swing, (np.pi / 2) / (8.0 * 0.5 / 1.1), 0.0)  # 90 deg over the turn's swings
    heading = np.cumsum(yaw_rate) / rate_hz
    rng = np.random.default_rng(7)
    acc = np.column_stack([9.0 * s, 0.3 * s, -_G + 4.0 * s]) + rng.normal(0, 0.03, (t.size, 3))
    gyr = np.column_stack([0.2 * pitch_rate * 0.1, pitch_rate, yaw_rate]) + rng.normal(0, 0.003, (t.size, 3))
    h, z = 48.0 * np.cos(np.radians(60)), 48.0 * np.sin(np.radians(60))
    mag = np.column_stack([h * np.cos(-heading), h * np.sin(-heading), np.full(t.size, z)]) + rng.normal(0, 0.3, (t.size, 3))
    t_ns = 1_600_000_000_000_000_000 + np.round(t * 1e9).astype(np.int64)
    return SensorBatch(acc_t_ns=t_ns, acc=acc, gyr_t_ns=t_ns.copy(), gyr=gyr, mag_t_ns=t_ns.copy(), mag=mag)


def warm_worker() -> float:
    """The server worker's own compiled code on the upload path (:mod:`server.plausibility`'s pre-test), which
    runs where the request is decoded, also when the engines run in helper processes; returns the seconds it
    took."""
    from server.plausibility import STILL_GYRO

    t0 = time.perf_counter()
    for part in warm_signal(seconds=8.0).split_seconds(1.0):  # still and walking batches
        STILL_GYRO.examine(part)
    return time.perf_counter() - t0


def warm_up(engine_cls: Any, modes: tuple[str, ...] = _MODES) -> float:
    """Feed :func:`warm_signal` through ``engine_cls`` in each mode as the server would (1-s batches, state to
    bytes and back after each, flush at the end); returns the seconds it took (compilation included)."""
    from energy.gait_dr import warm_kernels

    t0 = time.perf_counter()
    warm_kernels()  # the step-event kernels: the signal below yields no step event
    parts = warm_signal().split_seconds(1.0)
    for mode in modes:
        engine = engine_cls(mode=mode)
        for part in parts:
            engine.feed(part)
            engine = engine_cls.from_bytes(engine.to_bytes())
        engine.flush()
    return time.perf_counter() - t0
