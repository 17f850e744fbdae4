"""A device that obeys the engine's sensor configuration, and the replay loop built on it.

Replaying a recording through :func:`replay` behaves like a real phone or foot sensor talking to the server:
samples go out in batches of ``batch_seconds`` (or as long as the engine's ``SensorConfig.batch_s`` says); after
each batch the engine's :class:`~energy.types.SensorConfig` applies from the next batch on. A gyroscope switched off sends nothing; a lower output data rate is produced by
anti-aliased decimation of the recorded stream (004 Section 4.3), as a sensor's own digital filter would.

Wake-on-motion (``SensorConfig.gyro_wake_on_motion``): the device manages its gyroscope itself between
uploads, as the LSM9DS1's activity/inactivity function does (register ``ACT_THS`` 04h: 7-bit inactivity
threshold ``ACT_THS[6:0]`` and ``SLEEP_ON_INACT_EN``, "gyroscope operating mode during inactivity",
0 = power-down, 1 = sleep; ``ACT_DUR`` 05h: inactivity duration, counted in output-data-rate cycles; the
``INACT`` flag in ``STATUS_REG``), see :class:`DeviceEmulator`.
"""

from __future__ import annotations

import copy
import math
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Callable

import numpy as np

from energy.compass_swing import SWING_TAU_S, CompassSwing
from energy.types import Position, SensorConfig, Update
from models.batch import STREAMS, SensorBatch
from models.fir import Decimator
from models.steps import G0

if TYPE_CHECKING:
    from energy.engine import Engine, Trace

__all__ = ["GYRO_TURN_ON_S", "Desampler", "DeviceEmulator", "ReplayResult", "Span", "desample", "replay"]

# Gyroscope turn-on time [s]: from power-down to the first valid sample. The LSM9DS1 datasheet (DocID025715
# Rev 3) copies searched do not state it; the ST LSM6DS3 datasheet (same ST MEMS gyroscope family, its
# Table 16 "turn-on time", quoted by ST's community answer "LSM6DS3 gyroscope current consumption while in
# sleep mode", 2020) gives 80 ms maximum from power-down to active. The device below powers the gyroscope
# down (SLEEP_ON_INACT_EN = 0: the power-down current the profiles charge), so it takes this maximum.
GYRO_TURN_ON_S = 0.080

# Weak-field wake (SensorConfig.wake_mode "weak_field"): a still stance as the device's controller tells it from its
# accelerometer outputs (25 Hz in Gait-DR: 3 outputs = 120 ms, under a walking stance's flat foot of 0.3-0.6 s)
STILL_SAMPLES = 3
STILL_MS2 = 0.5  # [m/s^2] from 1 g in magnitude, and between consecutive outputs on every axis

_EVENT_MODES = ("weak_field", "compass_swing")  # wake modes whose events are not accelerometer departures

Span = tuple[int, int, float, float, float]  # (t0_ns, t1_ns, acc, gyr, mag rate [Hz]) of constant sensor state


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
        self._pending: tuple[np.ndarray, np.ndarray] | None = None  # the old filter's tail after a rate change

    @property
    def factor(self) -> int:
        return self._dec.factor

    @property
    def latency_ns(self) -> int:
        """How long after its time stamp an output sample exists [ns]: the filter's group delay."""
        d = self._dec
        half = d.taps_per_factor * d.factor / 2 if d.factor > 1 else 0.0  # (numtaps - 1) / 2, see models.fir.Decimator
        return int(round(half / self.native_rate_hz * 1e9))

    def factor_for(self, target_rate_hz: float) -> int:
        """Whole decimation factor that delivers ``target_rate_hz`` [Hz]: the nearest to native / target, >= 1."""
        return max(1, int(round(self.native_rate_hz / max(target_rate_hz, 1e-9))))

    def output_rate_hz(self, target_rate_hz: float) -> float:
        """Rate [Hz] actually delivered when ``target_rate_hz`` is asked for (0: off): native / :meth:`factor_for`."""
        return self.native_rate_hz / self.factor_for(target_rate_hz) if target_rate_hz > 0 else 0.0

    def set_rate(self, target_rate_hz: float) -> None:
        """Change the output rate [Hz]; applies from the next call to :meth:`process`."""
        factor = self.factor_for(target_rate_hz)
        if factor != self._dec.factor:
            # the samples the old filter still holds back (its group delay) go out with the next chunk, as a
            # sensor's FIFO keeps what it has measured: dropping them left a 0.32-0.36 s hole at every change
            self._pending = self._dec.flush()
            self._dec = Decimator(self.native_rate_hz, self.native_rate_hz / factor)

    def process(self, t_ns: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Filter and decimate a chunk; returns the output samples ``(t_ns, values)``."""
        out_t, out_v = self._dec.process(t_ns, v)
        if self._pending is not None:
            (p_t, p_v), self._pending = self._pending, None
            out_t, out_v = np.concatenate([p_t, out_t]), np.concatenate([p_v, out_v])
        m = out_t > self._last_out_t
        out_t, out_v = out_t[m], out_v[m]
        if len(out_t):
            self._last_out_t = int(out_t[-1])
        return out_t, out_v


def desample(recording: SensorBatch, rate_hz: float) -> SensorBatch:
    """The recording as a sensor set to ``rate_hz`` would have delivered it: each stream faster than that is
    low-passed and decimated by :class:`models.fir.Decimator` (Hamming-window anti-aliasing FIR, group delay
    compensated, the whole stream including the filter's tail) by the whole factor nearest to its rate /
    ``rate_hz``, as :class:`Desampler` does live; a stream at or below ``rate_hz`` is kept as it is (nothing
    is up-sampled). The actual rates are ``recording.rate_hz(name) / factor``.
    """
    if not rate_hz > 0:
        raise ValueError(f"rate_hz must be positive, got {rate_hz}")
    kw: dict[str, np.ndarray] = {}
    for name in STREAMS:
        t, v = recording.stream(name)
        if t.size > 1:
            dec = Decimator(recording.rate_hz(name), rate_hz)
            if dec.factor > 1:
                (t1, v1), (t2, v2) = dec.process(t, v), dec.flush()
                t, v = np.concatenate([t1, t2]), np.concatenate([v1, v2])
        kw[f"{name}_t_ns"], kw[name] = t, v
    return SensorBatch(**kw)


class DeviceEmulator:
    """Turns a full-rate recording into what a device obeying a :class:`SensorConfig` would send.

    Parameters
    ----------
    recording : SensorBatch
        The recorded streams at their native rates.
    gyro_turn_on_s : float
        Gyroscope turn-on time [s] after a wake-on-motion activity (:data:`GYRO_TURN_ON_S`).

    Notes
    -----
    Wake-on-motion (``config.gyro_wake_on_motion``), per accelerometer output sample, in time order:

    - asleep: the accelerometer samples at ``acc_rate_hz``. The first sample that departs from the reference
      (the first sample after the gyroscope went down) by more than ``wake_threshold_ms2`` on any axis is the
      activity: the gyroscope powers up there and is charged from that sample; its samples are delivered from
      ``GYRO_TURN_ON_S`` later, and from then on the accelerometer shares its output data rate
      (``gyr_rate_hz``, as the LSM9DS1's accelerometer does while its gyroscope runs). The on-chip detector
      sees the sensor's own samples at ``acc_rate_hz``, each the mean of its output period, decided at the
      period's end (causal: at most one period, 40 ms at 25 Hz, after the motion); the host receives the
      emulator's anti-aliased decimation, whose group delay (:attr:`Desampler.latency_ns`, 0.32 s at 25 Hz
      from 200 Hz) is compensated in its time stamps and has no place in an on-chip decision;
    - awake: every departure from the reference moves the reference to that sample; ``sleep_after_s`` after
      the last departure the gyroscope powers down (the device's inactivity), the accelerometer returns to
      ``acc_rate_hz`` and the detector re-arms.

    With ``config.wake_mode == "high_g"`` an event is a sample whose absolute value exceeds the threshold on
    some axis (the IMU's high-g interrupt) instead of a departure from the reference; the rest is the same.
    With ``"weak_field"`` an event is a still stance whose calibrated field is horizontally weaker than
    ``wake_field_ut`` (:meth:`_weak_field_stances`, the device's controller on its accelerometer and magnetometer
    outputs); the gyroscope sleeps ``sleep_after_s`` after the last one, and one the host left on when this
    configuration arrives (an examination's) goes down at once. With ``"compass_swing"`` (a phone) an event is a
    magnetometer output at which the device's tilt-compensated compass azimuth has changed by more than
    ``wake_swing_rad`` within ``wake_window_s`` (:meth:`_compass_swings`, :class:`energy.compass_swing.CompassSwing` on
    the detectors' accelerometer and magnetometer outputs); the rest is as with ``"weak_field"``.

    A duty-cycled gyroscope (``config.gyr_duty_period_s`` ``P`` > 0, with ``gyro_on``): the device powers the gyroscope
    up at ``e + k P`` (``e``: the start of the first batch under this duty cycle, kept across batches while the
    configurations keep it: the phase is the device's, not the uploads'), it delivers its samples in
    ``[e + k P + GYRO_TURN_ON_S, e + k P + GYRO_TURN_ON_S + gyr_duty_on_s)`` and nothing else, and is charged from each
    power-up to the window's end (:attr:`last_spans`); the accelerometer and magnetometer run at their rates
    throughout. The delivered fraction is ``gyr_duty_on_s / P``, the charged one ``(gyr_duty_on_s + GYRO_TURN_ON_S) / P``.

    The decision is made by the device on the samples it actually produces, between uploads; the engine just
    sees gyroscope samples start (or stop) in the middle of a batch. A configuration with ``gyro_on`` keeps
    the gyroscope awake; a switch to wake-on-motion then lets it sleep only after the inactivity duration.
    :attr:`last_spans` holds the stretches of constant sensor state of the last batch (what the energy
    accounting charges: the gyroscope from its activity sample on), each sensor at the rate it delivered
    (:meth:`delivered_rate_hz`: a 250-Hz recording asked for 200 Hz runs at 250 Hz; a stream the recording does
    not have is off).
    """

    def __init__(self, recording: SensorBatch, gyro_turn_on_s: float = GYRO_TURN_ON_S) -> None:
        self.recording = recording
        self.gyro_turn_on_ns = int(round(float(gyro_turn_on_s) * 1e9))
        self._desamplers: dict[str, Desampler] = {}
        for name in STREAMS:
            t, _ = recording.stream(name)
            if t.size > 1:
                self._desamplers[name] = Desampler(recording.rate_hz(name))
        acc = self._desamplers.get("acc")
        self._acc_fast = copy.deepcopy(acc)  # the accelerometer at the gyroscope's rate while it runs (wake mode)
        self._awake = False  # wake-on-motion: gyroscope powered
        self._deliver_ns = np.iinfo(np.int64).min  # ... delivering from this time [ns]
        self._ref: np.ndarray | None = None  # activity reference sample [m/s^2]
        self._quiet_ns = 0  # time of the last departure from the reference [ns]
        self._armed_ns = np.iinfo(np.int64).min  # the activity detector looks at samples from this time on [ns]
        # native samples of the unfinished output-data-rate period, per stream (the on-chip detectors' view)
        self._blk: dict[str, tuple[np.ndarray, np.ndarray]] = {
            name: (np.zeros(0, dtype=np.int64), np.zeros((0, 3))) for name in ("acc", "mag")}
        self._still: list[np.ndarray] = []  # weak-field wake: the still accelerometer samples of the current run
        self._still_prev: np.ndarray | None = None  # ... and the sample before
        self._mag_last: np.ndarray | None = None  # ... the latest magnetometer output [uT]
        self._event_mode: str | None = None  # the last batch's event-driven wake mode (weak field, compass swing)
        self._swing: CompassSwing | None = None  # compass-swing wake: the device's detector, while the mode is on
        self._duty_epoch_ns: int | None = None  # duty-cycled gyroscope: the power-up of its period 0 [ns], device clock
        self._duty_key: tuple[int, int] | None = None  # ... its (period, on) [ns]
        self._duty_pre_on = False  # ... the gyroscope was fully on before it began
        self._gyro_full = False  # the last batch's configuration had the gyroscope fully on
        self._last_acc_ns = np.iinfo(np.int64).min
        self.last_spans: list[Span] = []

    def delivered_rate_hz(self, name: str, rate_hz: float) -> float:
        """Output data rate [Hz] of stream ``name`` when ``rate_hz`` is asked for: the recorded rate divided by the
        whole decimation factor (:meth:`Desampler.output_rate_hz`); 0 when off or when the recording has no such
        stream (the device it stands for has no such sensor)."""
        des = self._desamplers.get(name)
        return des.output_rate_hz(rate_hz) if des is not None else 0.0

    def emit(self, t0_ns: int, t1_ns: int, config: SensorConfig) -> SensorBatch:
        """The batch the device sends for ``t0_ns <= t < t1_ns`` under ``config``."""
        piece = self.recording.time_slice(t0_ns, t1_ns)
        wake = bool(config.gyro_wake_on_motion)
        rates = {"acc": config.acc_rate_hz, "gyr": config.gyr_rate_hz if (config.gyro_on or wake) else 0.0,
                 "mag": config.mag_rate_hz}
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
        fast_t, fast_v = kw["acc_t_ns"][:0], kw["acc"][:0]
        if self._acc_fast is not None:  # runs on all the time, like the other filters
            self._acc_fast.set_rate(config.gyr_rate_hz if config.gyr_rate_hz > 0 else self._acc_fast.native_rate_hz)
            fast_t, fast_v = self._acc_fast.process(*piece.stream("acc"))
        blk_t, blk_v = self._odr_samples("acc", *piece.stream("acc"), config.acc_rate_hz)
        mblk_t, mblk_v = self._odr_samples("mag", *piece.stream("mag"), config.mag_rate_hz)
        event_mode = config.wake_mode if wake and config.wake_mode in _EVENT_MODES else None
        events = None
        if event_mode == "weak_field":
            events = self._weak_field_stances(blk_t, blk_v, mblk_t, mblk_v, config)
        else:
            self._still, self._still_prev, self._mag_last = [], None, None
        if event_mode == "compass_swing":
            events = self._compass_swings(blk_t, blk_v, mblk_t, mblk_v, config)
        else:
            self._swing = None
        if event_mode is not None and event_mode != self._event_mode:
            # the host's gyroscope (an examination's, or the phone's on its own schedule) goes down at once: the host
            # said so; the device's own event wakes it
            self._awake, self._armed_ns = False, t0_ns
        self._event_mode = event_mode
        if not config.gyr_duty:
            self._duty_epoch_ns = self._duty_key = None
        if config.gyr_duty:
            self._awake = True  # a configuration without the duty cycle keeps it as the host says
            self._armed_ns = t1_ns
            self._deliver_ns = np.iinfo(np.int64).min
            self._ref = None
            windows = self._duty_windows(t0_ns, t1_ns, config)
            s_t, s_v = kw["gyr_t_ns"], kw["gyr"]
            # by time stamp, not by batch: the filter's delay hands a window's last samples out with the next batch
            period, on = self._duty_key or (1, 0)
            e = self._duty_epoch_ns or 0
            ph = (s_t - e) % period
            keep = (ph >= self.gyro_turn_on_ns) & (ph < self.gyro_turn_on_ns + on) & (s_t >= e)
            keep |= (s_t < e) & self._duty_pre_on  # the previous configuration's gyroscope, fully on
            kw["gyr_t_ns"], kw["gyr"] = s_t[keep], s_v[keep]
            self.last_spans = self._spans(t0_ns, t1_ns, windows, config, acc_follows_gyro=False)
        elif not wake:
            self._awake = bool(config.gyro_on)
            self._armed_ns = t1_ns
            self._deliver_ns = np.iinfo(np.int64).min
            self._ref = None
            self.last_spans = [(t0_ns, t1_ns, self.delivered_rate_hz("acc", config.acc_rate_hz),
                                self.delivered_rate_hz("gyr", rates["gyr"]), self.delivered_rate_hz("mag", config.mag_rate_hz))]
        else:
            kw["acc_t_ns"], kw["acc"], windows = self._wake_on_motion(t0_ns, t1_ns, kw["acc_t_ns"], kw["acc"], fast_t, fast_v,
                                                                      blk_t, blk_v, config, events)
            for name in ("gyr", "mag") if config.mag_follows_gyro else ("gyr",):
                s_t, s_v = kw[f"{name}_t_ns"], kw[name]
                keep = np.zeros(len(s_t), dtype=bool)
                for _, deliver, off in windows:
                    keep |= (s_t >= deliver) & (s_t < off)
                kw[f"{name}_t_ns"], kw[name] = s_t[keep], s_v[keep]
            self.last_spans = self._spans(t0_ns, t1_ns, windows, config)
        self._gyro_full = bool(config.gyro_on and not config.gyr_duty and not wake)
        newer = kw["acc_t_ns"] > self._last_acc_ns  # across a rate switch the outputs never go back in time
        kw["acc_t_ns"], kw["acc"] = kw["acc_t_ns"][newer], kw["acc"][newer]
        if len(kw["acc_t_ns"]):
            self._last_acc_ns = int(kw["acc_t_ns"][-1])
        return SensorBatch(**kw)

    # ------------------------------------------------------------------ duty-cycled gyroscope
    def _duty_windows(self, t0: int, t1: int, config: SensorConfig) -> list[tuple[int, int, int]]:
        """The duty-cycled gyroscope's windows ``(powered up at, delivers from, off at)`` [ns] that overlap
        ``[t0, t1)``: powered up at ``e + k P`` (``e``: the start of the first batch of this duty cycle, kept
        across batches while the configuration keeps the same cycle: the device's own timer, not the uploads'),
        delivering from ``GYRO_TURN_ON_S`` later for ``gyr_duty_on_s``, then powered down."""
        key = (int(round(config.gyr_duty_period_s * 1e9)), int(round(config.gyr_duty_on_s * 1e9)))
        if self._duty_epoch_ns is None or self._duty_key != key:
            self._duty_epoch_ns, self._duty_key = int(t0), key
            self._duty_pre_on = self._gyro_full
        period, on = key
        e = self._duty_epoch_ns
        length = self.gyro_turn_on_ns + on
        k = max(0, (t0 - e - length) // period)
        out: list[tuple[int, int, int]] = []
        while e + k * period < t1:
            up = e + k * period
            if up + length > t0:
                out.append((up, up + self.gyro_turn_on_ns, up + length))
            k += 1
        return out

    # ------------------------------------------------------------------ wake-on-motion
    def _departs(self, v: np.ndarray, thr: float, high_g: bool) -> bool:
        """An activity event: ``v`` departs from the reference (``high_g``: from zero, i.e. its absolute
        value) by more than ``thr`` [m/s^2] on some axis."""
        if high_g:
            return bool(np.max(np.abs(v)) > thr)
        assert self._ref is not None
        return bool(np.max(np.abs(v - self._ref)) > thr)

    def _odr_samples(self, name: str, t: np.ndarray, v: np.ndarray, rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
        """The samples the sensor's own detector sees of stream ``name`` at ``rate_hz``: the mean of the native
        samples of each output period, available at the period's last sample (causal). Returns
        ``(t_available_ns, mean)``."""
        b_t, b_v = self._blk[name]
        t = np.concatenate([b_t, np.asarray(t, dtype=np.int64)])
        v = np.concatenate([b_v, np.asarray(v, dtype=np.float64).reshape(-1, 3)])
        des = self._desamplers.get(name)
        k = 1 if des is None or rate_hz <= 0 else max(1, int(round(des.native_rate_hz / rate_hz)))
        n = (len(t) // k) * k
        self._blk[name] = (t[n:], v[n:])
        return t[k - 1 : n : k], v[:n].reshape(-1, k, 3).mean(axis=1)

    def _weak_field_stances(self, acc_t: np.ndarray, acc_v: np.ndarray, mag_t: np.ndarray, mag_v: np.ndarray,
                            config: SensorConfig) -> np.ndarray:
        """Times [ns] of the still stances whose calibrated field is horizontally weaker than
        ``config.wake_field_ut`` (``wake_mode == "weak_field"``), from the detectors' samples: a stance is
        ``STILL_SAMPLES`` consecutive accelerometer outputs within ``STILL_MS2`` of 1 g in magnitude and of the
        output before on every axis; it is decided once, at its ``STILL_SAMPLES``-th output, on their mean (the
        vertical) and the latest magnetometer output."""
        b = np.asarray(config.mag_offset_ut, dtype=np.float64)
        w = np.asarray(config.mag_matrix, dtype=np.float64).reshape(3, 3)
        out: list[int] = []
        j = 0
        for i in range(len(acc_t)):
            a = acc_v[i]
            while j < len(mag_t) and mag_t[j] <= acc_t[i]:
                self._mag_last = mag_v[j]
                j += 1
            prev, self._still_prev = self._still_prev, a
            if (abs(float(np.linalg.norm(a)) - G0) > STILL_MS2
                    or prev is None or float(np.max(np.abs(a - prev))) > STILL_MS2):
                self._still = []
                continue
            self._still.append(a)
            if len(self._still) != STILL_SAMPLES or self._mag_last is None:
                continue
            m = w @ (self._mag_last - b)
            f = np.mean(self._still, axis=0)
            down = -float(m @ f) / max(float(np.linalg.norm(f)), 1e-9)
            if math.sqrt(max(float(m @ m) - down * down, 0.0)) < config.wake_field_ut:
                out.append(int(acc_t[i]))
        return np.asarray(out, dtype=np.int64)

    def _compass_swings(self, acc_t: np.ndarray, acc_v: np.ndarray, mag_t: np.ndarray, mag_v: np.ndarray,
                        config: SensorConfig) -> np.ndarray:
        """Times [ns] of the magnetometer outputs at which the device's tilt-compensated compass azimuth has changed
        by more than ``config.wake_swing_rad`` within ``config.wake_window_s`` (``wake_mode == "compass_swing"``,
        :class:`energy.compass_swing.CompassSwing`), from the detectors' samples at the rates the accelerometer and
        magnetometer run. The detector starts when the mode does (its window empty, its vertical from the first
        accelerometer output)."""
        sw = self._swing
        if sw is None or sw.swing_rad != config.wake_swing_rad or sw.window_ns != int(round(config.wake_window_s * 1e9)):
            sw = self._swing = CompassSwing(config.wake_swing_rad, config.wake_window_s, SWING_TAU_S)
        t, _, swing = sw.process(acc_t, acc_v, mag_t, mag_v)
        return t[swing]

    def _wake_on_motion(
        self, t0: int, t1: int, low_t: np.ndarray, low_v: np.ndarray, fast_t: np.ndarray, fast_v: np.ndarray,
        blk_t: np.ndarray, blk_v: np.ndarray, config: SensorConfig, events: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray, list[tuple[int, int, int]]]:
        """Splice the low-rate (asleep) and shared-rate (awake) accelerometer outputs and find the gyroscope's
        windows ``(charged from, delivers from, off at)`` [ns] within ``[t0, t1)``. ``events``: the times of
        the activity events where they are not departures of the accelerometer (``"weak_field"``)."""
        thr = float(config.wake_threshold_ms2)
        high_g = config.wake_mode == "high_g"
        dur = int(round(float(config.sleep_after_s) * 1e9))
        out_t: list[np.ndarray] = []
        out_v: list[np.ndarray] = []
        windows: list[tuple[int, int, int]] = []
        cur = self._last_acc_ns + 1  # output times never go back
        charged = t0 if self._awake else None
        assert self._acc_fast is not None
        while True:
            if not self._awake and events is not None:
                later = events[events >= max(self._armed_ns, cur)]
                if not len(later):
                    self._armed_ns = t1
                    m = low_t >= cur
                    out_t.append(low_t[m])
                    out_v.append(low_v[m])
                    break
                self._awake, self._quiet_ns = True, int(later[0])
                charged = max(int(later[0]), t0)
                self._deliver_ns = charged + self.gyro_turn_on_ns
            elif not self._awake:
                # the detector: the sensor's own samples at its rate, each decided when it exists
                m = blk_t >= self._armed_ns
                ts, vs = blk_t[m], blk_v[m]
                hit = -1
                for i in range(len(ts)):
                    if self._ref is None and not high_g:
                        self._ref, self._quiet_ns = vs[i].copy(), int(ts[i])
                    elif self._departs(vs[i], thr, high_g):
                        self._ref, self._quiet_ns = vs[i].copy(), int(ts[i])
                        hit = i
                        break
                if hit < 0:
                    self._armed_ns = t1
                    m = low_t >= cur
                    out_t.append(low_t[m])
                    out_v.append(low_v[m])
                    break
                self._awake = True
                charged = max(int(ts[hit]), t0)
                self._deliver_ns = charged + self.gyro_turn_on_ns
            else:
                # turning on: the accelerometer keeps its low rate until the gyroscope delivers
                m = (low_t >= cur) & (low_t < self._deliver_ns)
                out_t.append(low_t[m])
                out_v.append(low_v[m])
                m = fast_t >= max(cur, self._deliver_ns)
                ts, vs = fast_t[m], fast_v[m]
                hit = -1
                if events is None:
                    for i in range(len(ts)):
                        if (self._ref is None and not high_g) or self._departs(vs[i], thr, high_g):
                            self._ref, self._quiet_ns = vs[i].copy(), int(ts[i])
                        elif int(ts[i]) - self._quiet_ns >= dur:
                            hit = i
                            break
                elif len(ts):
                    # the latest event at or before each sample keeps the gyroscope awake
                    k = np.searchsorted(events, ts, side="right") - 1
                    last = events[np.maximum(k, 0)] if len(events) else np.zeros(len(ts), dtype=np.int64)
                    quiet = np.maximum(self._quiet_ns, np.where(k >= 0, last, self._quiet_ns))
                    late = np.flatnonzero(ts - quiet >= dur)
                    hit = int(late[0]) if len(late) else -1
                    self._quiet_ns = int(quiet[hit if hit >= 0 else -1])
                if hit < 0:
                    out_t.append(ts)
                    out_v.append(vs)
                    windows.append((int(charged if charged is not None else t0), self._deliver_ns, t1))
                    break
                out_t.append(ts[: hit + 1])
                out_v.append(vs[: hit + 1])
                off = min(max(int(ts[hit]) + self._acc_fast.latency_ns + 1, t0), t1)
                windows.append((int(charged if charged is not None else t0), self._deliver_ns, off))
                self._awake, charged = False, None
                self._ref = None  # re-armed on the next sample
                self._armed_ns = off
                cur = int(ts[hit]) + 1
        t = np.concatenate(out_t) if out_t else low_t[:0]
        v = np.concatenate(out_v).reshape(-1, 3) if out_v else low_v[:0]
        return t, v, windows

    def _spans(self, t0: int, t1: int, windows: list[tuple[int, int, int]], config: SensorConfig,
               acc_follows_gyro: bool = True) -> list[Span]:
        """Stretches of constant sensor state in ``[t0, t1)``: gyroscope charged from activity (or power-up) to
        power-down, accelerometer at the shared rate while the gyroscope delivers (``acc_follows_gyro``; False:
        at ``acc_rate_hz`` throughout, the duty cycle)."""
        cuts = sorted({t0, t1, *[min(max(x, t0), t1) for w in windows for x in w]})
        spans: list[Span] = []
        for a, b in zip(cuts[:-1], cuts[1:]):
            if b <= a:
                continue
            charged = any(w[0] <= a and b <= w[2] for w in windows)
            delivering = any(w[1] <= a and b <= w[2] for w in windows)
            acc = config.gyr_rate_hz if delivering and acc_follows_gyro else config.acc_rate_hz
            mag = config.mag_rate_hz if (charged or not config.mag_follows_gyro) else 0.0
            spans.append((a, b, self.delivered_rate_hz("acc", acc), self.delivered_rate_hz("gyr", config.gyr_rate_hz if charged else 0.0),
                          self.delivered_rate_hz("mag", mag)))
        return spans


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
        Fraction of the recording's time during which the gyroscope was on (powered: from a wake-on-motion
        activity on, turn-on time included).
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
    spans : list of list of Span
        Per batch (parallel to ``configs``), the stretches of constant sensor state the device really had
        (:attr:`DeviceEmulator.last_spans`; with wake-on-motion the gyroscope runs for part of a batch).
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
    spans: list[list[Span]] = field(default_factory=list)


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
    spans: list[list[Span]] = []
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
        spans.append(device.last_spans)
        for name in STREAMS:
            sent[name] += len(batch.stream(name)[0])
        gyro_on_ns += sum(b - a for a, b, _, gyr, _ in device.last_spans if gyr > 0)
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
        spans=spans,
    )
