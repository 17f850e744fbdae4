"""A device that obeys the engine's sensor configuration, and the replay loop built on it.

Replaying a recording through :func:`replay` behaves like a real phone or foot sensor talking to the server:
samples go out in batches of ``batch_seconds`` (or as long as the engine's ``SensorConfig.batch_s`` says); after
each batch the engine's :class:`~energy.types.SensorConfig` applies from the next batch on. A gyroscope switched off sends nothing; a lower output data rate is produced by
anti-aliased decimation of the recorded stream (004 Section 4.3), as a sensor's own digital filter would.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Callable

import numpy as np

from energy.types import Position, SensorConfig, Update
from models.batch import STREAMS, SensorBatch
from models.fir import Decimator

if TYPE_CHECKING:
    from energy.engine import Engine, Trace

__all__ = ["Desampler", "DeviceEmulator", "ReplayResult", "replay"]


class Desampler:
    """One sensor stream as a device delivers it at a requested output data rate.

    Wraps :class:`models.fir.Decimator` (Hamming-window anti-aliasing FIR + integer decimation, group delay
    compensated); a rate change starts a new decimator, and outputs never go back in time across the change.

    Parameters
    ----------
    native_rate_hz : float
        Rate of the recorded stream [Hz].
    """

    def __init__(self, native_rate_hz: float) -> None:
        self.native_rate_hz = float(native_rate_hz)
        self._dec = Decimator(self.native_rate_hz, self.native_rate_hz)
        self._last_out_t = np.iinfo(np.int64).min

    @property
    def factor(self) -> int:
        return self._dec.factor

    def set_rate(self, target_rate_hz: float) -> None:
        """Change the output rate [Hz]; applies from the next call to :meth:`process`."""
        factor = max(1, int(round(self.native_rate_hz / max(target_rate_hz, 1e-9))))
        if factor != self._dec.factor:
            self._dec = Decimator(self.native_rate_hz, self.native_rate_hz / factor)

    def process(self, t_ns: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Filter and decimate a chunk; returns the output samples ``(t_ns, values)``."""
        out_t, out_v = self._dec.process(t_ns, v)
        m = out_t > self._last_out_t
        out_t, out_v = out_t[m], out_v[m]
        if len(out_t):
            self._last_out_t = int(out_t[-1])
        return out_t, out_v


class DeviceEmulator:
    """Turns a full-rate recording into what a device obeying a :class:`SensorConfig` would send.

    Parameters
    ----------
    recording : SensorBatch
        The recorded streams at their native rates.
    """

    def __init__(self, recording: SensorBatch) -> None:
        self.recording = recording
        self._desamplers: dict[str, Desampler] = {}
        for name in STREAMS:
            t, _ = recording.stream(name)
            if t.size > 1:
                self._desamplers[name] = Desampler(recording.rate_hz(name))

    def emit(self, t0_ns: int, t1_ns: int, config: SensorConfig) -> SensorBatch:
        """The batch the device sends for ``t0_ns <= t < t1_ns`` under ``config``."""
        piece = self.recording.time_slice(t0_ns, t1_ns)
        rates = {"acc": config.acc_rate_hz, "gyr": config.gyr_rate_hz if config.gyro_on else 0.0, "mag": config.mag_rate_hz}
        kw: dict[str, np.ndarray] = {}
        for name in STREAMS:
            t, v = piece.stream(name)
            des = self._desamplers.get(name)
            if des is None:
                kw[f"{name}_t_ns"], kw[name] = t, v
                continue
            des.set_rate(rates[name] if rates[name] > 0 else des.native_rate_hz)
            out_t, out_v = des.process(t, v)  # filter state runs on even while the sensor is off
            if rates[name] <= 0:
                out_t, out_v = out_t[:0], out_v[:0]
            kw[f"{name}_t_ns"], kw[name] = out_t, out_v
        return SensorBatch(**kw)


@dataclass
class ReplayResult:
    """What a replay produced.

    Attributes
    ----------
    updates : list of Update
        One per batch sent (plus the final flush).
    positions : list of Position
        All positions, in order.
    trace : Trace
        Per processed accelerometer sample: time, NED position, behaviour, mode, gyroscope state.
    gyro_on_fraction : float
        Fraction of the recording's time during which the gyroscope was on.
    mean_rate_hz : float
        Mean accelerometer rate actually sent [Hz] (samples sent / duration).
    samples_sent : dict of str to int
        Samples sent per stream.
    batches : int
        Requests made.
    compute_s : float
        Wall-clock seconds spent inside ``Engine.feed``/``flush`` (for information; energy accounting uses
        deterministic per-mode costs, see :mod:`energy.power`).
    configs : list of (int, SensorConfig)
        Batch start time [ns] and the configuration the device used for that batch.
    """

    updates: list[Update]
    positions: list[Position]
    trace: Trace
    gyro_on_fraction: float
    mean_rate_hz: float
    samples_sent: dict[str, int]
    batches: int
    compute_s: float
    configs: list[tuple[int, SensorConfig]] = field(default_factory=list)


def replay(
    engine: Engine,
    recording: SensorBatch,
    batch_seconds: float | None = 1.0,
    progress: Callable[[float], None] | None = None,
) -> ReplayResult:
    """Stream ``recording`` through ``engine`` as a device obeying the engine's sensor configuration.

    Parameters
    ----------
    engine : Engine
        A fresh or restored engine (created with ``trace=True`` for per-sample output).
    recording : SensorBatch
        Native-rate streams.
    batch_seconds : float or None
        Duration of each uploaded batch [s]; None: the ``batch_s`` of the configuration the engine asked for
        (the device batches as long as it is told).
    progress : callable, optional
        Called with the fraction done after each batch.
    """
    device = DeviceEmulator(recording)
    t_start, t_end = recording.t_start_ns, recording.t_end_ns
    if t_start is None or t_end is None:
        raise ValueError("recording: no samples")
    if batch_seconds is not None and batch_seconds <= 0:
        raise ValueError("batch_seconds must be positive")
    updates: list[Update] = []
    positions: list[Position] = []
    sent = {name: 0 for name in STREAMS}
    configs: list[tuple[int, SensorConfig]] = []
    gyro_on_ns = 0
    compute = 0.0
    t0 = t_start
    while t0 <= t_end:
        config = engine.sensor_config
        step = int(round((config.batch_s if batch_seconds is None else batch_seconds) * 1e9))
        if step <= 0:
            raise ValueError(f"batch duration must be positive, got {step} ns")
        t1 = min(t0 + step, t_end + 1)
        configs.append((t0, config))
        batch = device.emit(t0, t1, config)
        for name in STREAMS:
            sent[name] += len(batch.stream(name)[0])
        if config.gyro_on:
            gyro_on_ns += t1 - t0
        c0 = time.perf_counter()
        upd = engine.feed(batch)
        compute += time.perf_counter() - c0
        updates.append(upd)
        positions.extend(upd.positions)
        if progress is not None:
            progress((t1 - t_start) / max(t_end + 1 - t_start, 1))
        t0 = t1
    c0 = time.perf_counter()
    upd = engine.flush()
    compute += time.perf_counter() - c0
    updates.append(upd)
    positions.extend(upd.positions)
    duration_s = max((t_end - t_start) / 1e9, 1e-9)
    return ReplayResult(
        updates=updates,
        positions=positions,
        trace=engine.trace,
        gyro_on_fraction=gyro_on_ns / max(t_end + 1 - t_start, 1),
        mean_rate_hz=sent["acc"] / duration_s,
        samples_sent=sent,
        batches=len(updates) - 1,
        compute_s=compute,
        configs=configs,
    )
