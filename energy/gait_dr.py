"""The Gait-DR half of the engine: low-rate step stream, online calibration against the ZUPT-KF, dead reckoning.

Runs on a low-rate copy of the accelerometer/magnetometer streams (anti-aliased to the Gait-DR rate whatever
the device sends), so its step events do not change when the device is de-sampled (004 Section 4.3). Step
events wait in a queue; the engine (:mod:`energy.engine`) hands each one either to a ZUPT-KF stance of the
same stance (step-length calibration 004 eq. 15 and Table 3, KF II 004 eq. 17-20, magnetometer calibration,
examination) or to dead reckoning (004 eq. 14, 16). Every stride, whichever navigates, also goes through the
heading estimator (:class:`models.heading.HeadingEstimator`): with the ZUPT-KF's heading change where the
gyroscope ran, without one where it did not, then the stance compass with its estimated noise.
:attr:`GaitPipeline.horizon` bounds how late an event can still appear.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
from numba import njit

from energy.config import EngineConfig
from models.compass import MagCalibrator
from models.fir import Decimator
from models.gait_pdr import GaitDeadReckoner, PdrStep
from models.heading import CompassNoise, HeadingEstimator
from models.heading_deviation import HeadingDeviationKF, gamma_from_increment, wrap_angle
from models.rows import RowBuffer
from models.stats import median
from models.step_length import FORM, StepFeatures, StepLengthCalibrator
from models.steps import StepEvent, StepSegmenter
from models.zupt_nav import Stance

__all__ = ["GaitPipeline", "PAIR_TOL_S", "SEGMENTER_LATENCY_S", "model_behaviour"]

PAIR_TOL_S = 0.3  # a step event and a ZUPT-KF stance onset closer than this [s] are the same stance
SEGMENTER_LATENCY_S = 1.5  # bound on (input time when a step event is emitted) - (its onset) [s]; tested
_MAG_KEEP_S = 4.0  # low-rate field samples kept [s]: a swing (<= _SWING_MAX_S) before an event emitted up to
# SEGMENTER_LATENCY_S after its onset, whatever the batch cuts
_SWING_MAX_S = 2.0  # swing field samples are taken from at most this long before a stance onset [s]
_SWING_SAMPLES = 8  # field samples kept per swing for the magnetometer calibration (evenly spread)
_G0 = 9.80665  # standard gravity [m/s^2] (the step segmentation's quietness statistic)
_BEHAVIOURS = ("walk", "run")
_RECENT_CADENCES = 5  # measured strides of a behaviour whose median cadence a paused stride of it takes
_SCALE_TIE = 1.25  # an own compass fit is as good as a profile's within this factor of its robust scale
_REF_STANCES = 30  # this session's stance fields whose median is a loaded compass's reference field
_PEAK_STRIDES = 16  # walking strides whose largest peak sets the run-wake threshold
_PEAK_MIN_STRIDES = 8  # ... and at least this many before there is a threshold


def model_behaviour(label: str) -> str:
    """Behaviour whose step model serves a label (``stand``/``other`` steps use the walking model)."""
    return label if label in _BEHAVIOURS else "walk"


def _features(e: StepEvent) -> StepFeatures:
    return StepFeatures(e.f_s, e.acc_mean, e.acc_max, e.acc_min)


@njit(cache=True)
def _stillest_window(a, n, threshold, g0):
    """First index of the quietest ``n``-row window of ``a`` (rows: specific force [m/s^2]) by the step
    segmentation's quietness (vector variance plus the squared departure of the mean magnitude from ``g0``),
    searching until the first later window at or over ``threshold`` (the foot moves again)."""
    best, best_q = 0, math.inf
    for k in range(a.shape[0] - n + 1):
        m0 = m1 = m2 = ss = 0.0
        for i in range(k, k + n):
            m0 += a[i, 0]
            m1 += a[i, 1]
            m2 += a[i, 2]
            ss += a[i, 0] * a[i, 0] + a[i, 1] * a[i, 1] + a[i, 2] * a[i, 2]
        m0, m1, m2, ss = m0 / n, m1 / n, m2 / n, ss / n
        mu2 = m0 * m0 + m1 * m1 + m2 * m2
        q = math.sqrt(max(ss - mu2, 0.0) + (math.sqrt(mu2) - g0) ** 2)
        if k > 0 and q >= threshold:
            break
        if q < best_q:
            best, best_q = k, q
    return best


@njit(cache=True)
def _no_gap(tm, lo, hi, gap):
    """Whether the consecutive times ``tm[lo:hi]`` (two or more) are all at most ``gap`` [s] apart."""
    for i in range(lo + 1, hi):
        if tm[i] - tm[i - 1] > gap:
            return False
    return True


@njit(cache=True)
def _stance_rows(tm, a, t_s, hi_s, dt, n, threshold, g0):
    """Rows ``[b0, b1)`` of the stance's stillest window (:meth:`GaitPipeline._queue_event`): among the rows of
    ``tm`` in ``[t_s - 1e-6, hi_s]`` that follow the onset without a gap (> 1.5 ``dt``), the first ``n``, or the
    quietest ``n`` by :func:`_stillest_window` when there are more; ``(-1, -1)`` without a sample within
    ``dt / 2`` of the onset. The same comparisons as the array form it replaced, without its ~15 us of calls."""
    i0 = np.searchsorted(tm, t_s - 1e-6, side="left")
    i1 = np.searchsorted(tm, hi_s, side="right")
    if i1 <= i0 or tm[i0] > t_s + 0.5 * dt:
        return -1, -1
    end = i1
    for i in range(i0 + 1, i1):
        if tm[i] - tm[i - 1] > 1.5 * dt:
            end = i  # only the samples that follow the onset without a gap
            break
    if end - i0 > n:
        k = _stillest_window(a[i0:end], n, threshold, g0)
        return i0 + k, i0 + k + n
    return i0, min(i0 + n, end)


@njit(cache=True)
def _swing_rows(tm, t0, t_s, gap):
    """Rows ``[lo, hi)`` strictly inside ``(t0, t_s)`` (1e-6 s margins) when there are two or more, the first
    within ``gap`` of ``t0``, the last within ``gap`` of ``t_s`` and none ``gap`` apart (:meth:`GaitPipeline.
    _queue_event`); ``(-1, -1)`` otherwise."""
    lo = np.searchsorted(tm, t0 + 1e-6, side="right")
    hi = np.searchsorted(tm, t_s - 1e-6, side="left")
    if hi - lo < 2 or tm[lo] - t0 > gap or t_s - tm[hi - 1] > gap or not _no_gap(tm, lo, hi, gap):
        return -1, -1
    return lo, hi


@njit(cache=True)
def _stride_peak_of(tm, a, t0, t_end, gap):
    """Largest ``|a|`` over the rows of ``tm`` in ``[t0 - 1e-6, t_end + 1e-6]`` (:meth:`GaitPipeline._queue_event`);
    ``(False, 0)`` when there are fewer than two, the first is more than ``gap`` after ``t0`` or two are more than
    ``gap`` apart."""
    lo = np.searchsorted(tm, t0 - 1e-6, side="left")
    hi = np.searchsorted(tm, t_end + 1e-6, side="right")
    if hi - lo < 2 or tm[lo] - t0 > gap or not _no_gap(tm, lo, hi, gap):
        return False, 0.0
    m = abs(a[lo, 0])
    for i in range(lo, hi):
        for k in range(a.shape[1]):
            v = abs(a[i, k])
            if v > m or v != v:  # NaN propagates as in ndarray.max
                m = v
                if v != v:
                    return True, m
    return True, m


@njit(cache=True)
def _row_mean(a, b0, b1):
    """``a[b0:b1].mean(axis=0)`` as numpy computes it for rows of a C-ordered array (the first row, then each next
    added in order, divided by the count), without its call overhead."""
    out = a[b0].copy()
    for i in range(b0 + 1, b1):
        for k in range(a.shape[1]):
            out[k] += a[i, k]
    return out / (b1 - b0)


@njit(cache=True)
def _event_fields(tm, ma, mv, t_s, hi_s, dt, n, threshold, g0, prev_end, swing_max_s, peak_t0, gap):
    """The low-rate field buffer's part of a new step event (:meth:`GaitPipeline._queue_event`) in one call, the
    steps of the separate calls it replaced in their order: the stance's stillest window (:func:`_stance_rows`
    over ``tm`` [s], ``ma`` [m/s^2]) and its mean specific force and field (``mv`` [uT], :func:`_row_mean`); where
    there is one and its specific force is finite, the swing rows since the previous window's end ``prev_end``
    [s] if within ``swing_max_s`` (:func:`_swing_rows`); the stride's peak from ``peak_t0`` [s] to the new
    window's end (:func:`_stride_peak_of`; to ``-inf`` without a window).

    Returns ``(b0, acc, mag, t_end, lo, hi, peak_ok, peak)``: ``b0 < 0`` without a window (``acc``, ``mag`` NaN,
    ``t_end = -inf``), ``lo < 0`` without swing rows."""
    acc = np.full(3, np.nan)
    mag = np.full(3, np.nan)
    t_end = -np.inf
    lo, hi = -1, -1
    b0, b1 = _stance_rows(tm, ma, t_s, hi_s, dt, n, threshold, g0)
    if b0 >= 0:
        acc = _row_mean(ma, b0, b1)
        mag = _row_mean(mv, b0, b1)
        t_end = tm[b1 - 1]
        if np.isfinite(acc[0]) and np.isfinite(acc[1]) and np.isfinite(acc[2]) and t_s - prev_end <= swing_max_s:
            lo, hi = _swing_rows(tm, prev_end, t_s, gap)
    ok, peak = _stride_peak_of(tm, ma, peak_t0, t_end, gap)
    return b0, acc, mag, t_end, lo, hi, ok, peak


@njit(cache=True)
def _field_append(tb, vb, ab, lo, hi, lt, lx, keep_s):
    """Append the low-rate rows of ``lx`` (``[acc(3), mag(3), mag flag]``) whose flag is > 0.999 to the field
    buffers ``tb`` (time [s]), ``vb`` (field [uT]) and ``ab`` (specific force [m/s^2]) after row ``hi``, then drop
    the rows before ``lt[-1] - keep_s`` (the buffer's times increase: the first row kept is the ``"left"``
    search position). Returns the new ``(lo, hi)``; the caller guarantees room for ``len(lt)`` rows. The same
    values as the concatenate-and-slice form it replaced (:meth:`GaitPipeline._append_low`), in one call."""
    for i in range(lt.shape[0]):
        if lx[i, 6] > 0.999:
            tb[hi] = lt[i]
            for k in range(3):
                vb[hi, k] = lx[i, 3 + k]
                ab[hi, k] = lx[i, k]
            hi += 1
    lo += np.searchsorted(tb[lo:hi], lt[-1] - keep_s, side="left")
    return lo, hi


@njit(cache=True)
def _low_input(acc, mag):
    """The rows ``[acc (3), mag (3), 1]`` where the magnetometer's first axis has a sample, ``[acc (3), 0, 0, 0,
    0]`` where it is NaN (:meth:`GaitPipeline.feed`'s input to the low-rate stream; ``acc`` [m/s^2], ``mag``
    [uT], (N, 3) each), and whether any row has a field sample."""
    n = acc.shape[0]
    x = np.empty((n, 7))
    any_mag = False
    for i in range(n):
        has = not np.isnan(mag[i, 0])
        any_mag = any_mag or has
        for k in range(3):
            x[i, k] = acc[i, k]
            x[i, 3 + k] = mag[i, k] if has else 0.0
        x[i, 6] = 1.0 if has else 0.0
    return x, any_mag


@njit(cache=True)
def _fast_run(t_s, prev_t, fast_s):
    """Whether every interval before a sample of ``t_s`` [s] (the first one from ``prev_t``) is shorter than
    ``fast_s`` [s] (:meth:`_LowRate.process`'s fast run), and then the median of those intervals [s] (the mean
    of the two middle ones for an even count, as ``np.median``; NaN when not all are fast). The median by
    selection (numba's ``np.median``: the same middle values as a sort, in a third of the time)."""
    n = t_s.size
    step = np.empty(n)
    prev = prev_t
    for i in range(n):
        step[i] = t_s[i] - prev
        if not step[i] < fast_s:
            return False, np.nan
        prev = t_s[i]
    return True, np.median(step)


def warm_kernels() -> None:
    """Compile (or load) the step-event kernels with the argument types the pipeline passes: the server's
    warm-up signal (:func:`server.warmup.warm_signal`) yields no step event, so they would otherwise compile
    under the first stride of a session."""
    t = np.arange(12) * 0.04
    a = np.zeros((12, 3))
    a[:, 2] = _G0
    _event_fields(t, a, a, 0.2, 0.4, 0.04, 3, 1.0, _G0, 0.0, _SWING_MAX_S, 0.0, 0.06)


_SWING_KEEP: dict[int, np.ndarray] = {}  # rows kept of a swing of m samples (they depend on m only)


class _LowRate:
    """Accelerometer (+magnetometer) at a fixed low rate, whatever rate arrives."""

    def __init__(self, rate_hz: float) -> None:
        self.rate_hz = float(rate_hz)
        self.in_rate_hz = 0.0
        self.dec: Decimator | None = None
        self.last_t = -math.inf
        self.prev_t = -math.inf

    def process(self, t_s: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Samples at the low rate: runs faster than 1.6 x the rate are decimated, slower runs pass through.

        The decision is per sample (its spacing to the previous one), so a batch that mixes the full and the
        de-sampled rate gives the same output whether it arrives in one piece or in many.
        """
        if len(t_s) == 0:
            return t_s, x
        if self.dec is not None:
            # the steady state of a full-rate stream (every sample fast, the same factor): one compiled scan
            # instead of the array steps below (the same comparisons and the same median)
            all_fast, dt = _fast_run(t_s, self.prev_t, 1.0 / (1.6 * self.rate_hz))
            if all_fast and max(1, int(round(1.0 / (dt * self.rate_hz)))) == self.dec.factor:
                ot_s, ox = self.dec.process_seconds(t_s, x)
                self.prev_t = float(t_s[-1])
                if not len(ot_s) or ot_s[0] > self.last_t:  # one decimator's output times increase: all newer
                    return self._newer_all(ot_s, ox)
                return self._newer(ot_s, ox)
        prev = np.empty(len(t_s))  # = np.concatenate([[self.prev_t], t_s[:-1]]), without its generic machinery
        prev[0] = self.prev_t
        prev[1:] = t_s[:-1]
        step = t_s - prev  # interval before each sample [s]
        fast = step < 1.0 / (1.6 * self.rate_hz)
        if self.dec is None and not fast.any():
            # the whole chunk already is at the low rate (Gait-DR, standing): it passes through as it is
            self.prev_t = float(t_s[-1])
            return self._newer(t_s, x)
        outs_t, outs_x = [], []
        # runs of fast and of slow samples (np.flatnonzero(np.diff(fast.astype(np.int8))) + 1, without the casts)
        cuts = [] if fast.all() else (np.flatnonzero(fast[1:] != fast[:-1]) + 1).tolist()
        for lo, hi in zip([0, *cuts], [*cuts, len(t_s)]):
            if fast[lo]:
                dt = median(step[lo:hi])  # = np.median(np.diff(t_s[lo:hi], prepend=prev[lo]))
                factor = max(1, int(round(1.0 / (dt * self.rate_hz))))
                if self.dec is None or factor != self.dec.factor:
                    self.dec = Decimator(self.rate_hz * factor, self.rate_hz, channels=x.shape[1])
                    self.in_rate_hz = self.rate_hz * factor
                ot, ox = self.dec.process(np.round(t_s[lo:hi] * 1e9).astype(np.int64), x[lo:hi])
                outs_t.append(ot / 1e9)
                outs_x.append(ox)
            else:
                if self.dec is not None:
                    # the fast run ended (the device lowered its rate): the decimator's last group delay of
                    # output (0.32 s at 200 -> 25 Hz) would otherwise never come out; a stance in that gap was
                    # lost and its stride merged into the next (mixed-day seed 0: 9 such gaps, one lost stride)
                    ft, fx = self.dec.flush()
                    outs_t.append(ft / 1e9)
                    outs_x.append(fx)
                self.dec = None  # a slow run already is at (or below) the low rate
                outs_t.append(t_s[lo:hi])
                outs_x.append(x[lo:hi])
        self.prev_t = float(t_s[-1])
        if len(outs_t) == 1:  # one run (the common case): its output as it is
            return self._newer(outs_t[0], outs_x[0])
        return self._newer(np.concatenate(outs_t), np.concatenate(outs_x))

    def _newer(self, out_s: np.ndarray, out_x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The output samples after the last one returned (outputs never go back in time)."""
        keep = out_s > self.last_t
        if not keep.all():
            out_s, out_x = out_s[keep], out_x[keep]
        return self._newer_all(out_s, out_x)

    def _newer_all(self, out_s: np.ndarray, out_x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Output samples all after the last one returned: returned as they are, the newest remembered."""
        if len(out_s):
            self.last_t = float(out_s[-1])
        return out_s, out_x

    def get_state(self) -> dict[str, Any]:
        return {"rate_hz": self.rate_hz, "in_rate_hz": self.in_rate_hz, "last_t": self.last_t, "prev_t": self.prev_t,
                "dec": None if self.dec is None else self.dec.get_state()}

    @classmethod
    def from_state(cls, d: dict[str, Any]) -> _LowRate:
        obj = cls(d["rate_hz"])
        obj.in_rate_hz, obj.last_t, obj.prev_t = float(d["in_rate_hz"]), float(d["last_t"]), float(d["prev_t"])
        obj.dec = None if d["dec"] is None else Decimator.from_state(d["dec"])
        return obj


class GaitPipeline:
    """Step events, calibration, the heading estimator and dead reckoning for one session.

    The engine drives it in data-time order: step events wait in :attr:`queue` until either a ZUPT-KF stance
    claims them (:meth:`take_pair`: calibration, examination) or Gait-DR reckons them (:meth:`reckon`).
    :attr:`horizon` says up to when the event list is final, so both decisions are independent of how the
    stream was cut into batches.

    Parameters
    ----------
    config : EngineConfig
        ``rates.pdr_rate_hz`` is the rate of the low-rate stream; ``pdr_conventional`` the "conventional
        PDR" of 004 Table 6 (generic step model, no heading deviation), the baseline that shows what the
        online calibration buys.
    """

    def __init__(self, config: EngineConfig) -> None:
        self.config = config
        self.rate_hz = float(config.rates.pdr_rate_hz)
        self.conventional = bool(config.pdr_conventional)
        self._low = _LowRate(self.rate_hz)
        self._seg = self._new_segmenter()
        self.cal = self._new_calibrator()
        self._generic = self._new_calibrator()  # the generic prior model, never fitted
        self.kf2 = {b: self._new_kf2() for b in _BEHAVIOURS}
        self.mag = self._new_compass()  # this session's own compass fit
        self.loaded: MagCalibrator | None = None  # a profile's compass, used until the own fit is as good
        self.in_use = ""  # which compass the estimator's offset refers to: "", "own" or "loaded"
        self.est = HeadingEstimator(config.heading)
        # the latest compass reading's variance [rad^2], field anomaly and change [rad] (None: no reading)
        self.last_reading: tuple[float, float, float] | None = None
        self._prev_field: tuple[float, float] | None = None  # vertical, horizontal field of that reading [uT]
        self._fields: list[list[float]] = []  # [vertical, horizontal] field [uT] of this session's stances
        self.dr: GaitDeadReckoner | None = None
        self.queue: list[StepEvent] = []
        # low-rate field [uT] and specific force [m/s^2] of the last _MAG_KEEP_S, with their times [s], in place
        # (read through _mag_t, _mag_v, _mag_a)
        self._field = RowBuffer(np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3)))
        self.stance_mag: dict[int, np.ndarray | None] = {}
        self.stance_acc: dict[int, np.ndarray] = {}  # specific force over the same window as stance_mag
        self.stance_swing: dict[int, np.ndarray] = {}  # field samples of the swing before each stance [uT]
        self.stride_peak: dict[int, float] = {}  # largest |specific force| on an axis over each stride [m/s^2]
        self.walk_peaks: list[float] = []  # the same for the latest walking ZUPT-KF strides [m/s^2]
        self._window_end = -math.inf  # last sample time of the previous stance's field window [s]
        self._cal_last = -1  # index of the last step event whose stance joined the compass calibration
        self.t_in = -math.inf  # newest input sample time [s]
        self.has_mag = False  # the device has sent magnetometer samples in this session
        self._mag_fit_n = -1  # compass stances at the last calibration fit
        self.recent_d: dict[str, list[float]] = {b: [] for b in _BEHAVIOURS}  # last ZUPT-KF strides [m]
        self.recent_scale: dict[str, list[float]] = {b: [] for b in _BEHAVIOURS}  # the same / generic model's
        self.recent_f: dict[str, list[float]] = {b: [] for b in _BEHAVIOURS}  # cadences of measured strides [Hz]
        self._prev_stance = (-math.inf, math.nan)  # (onset [s], heading [rad]) of the last calibration stance
        self.step_s = -math.inf  # onset of the latest stride the estimator took [s]
        self.dominant: float | None = None  # the building's dominant direction in the session frame [rad]

    def _new_kf2(self) -> HeadingDeviationKF:
        d = self.config.deviation
        return HeadingDeviationKF(q_rate=d.q_rate, q_dev=d.q_dev, r_obs=d.r_obs_rad, p0_rate=d.p0_rate_rad_s,
                                  gate_sigma=d.gate_sigma)

    def _new_segmenter(self) -> StepSegmenter:
        s = self.config.steps
        return StepSegmenter(self.rate_hz, s.window_s, s.stance_threshold, s.swing_min, s.refractory_frac,
                             s.min_period_s, s.max_period_s, s.fir_cutoff_hz, s.fir_length_s, s.swing_frac,
                             s.min_swing_s, s.context_s, s.level_s, s.rel_threshold, s.k_duration, s.duration_cap_s,
                             s.k_quiet, s.period_min_s, s.period_max_s, s.default_period_s, s.long_stance_s,
                             s.max_latency_s)

    def _new_calibrator(self) -> StepLengthCalibrator:
        s = self.config.step_length
        return StepLengthCalibrator(s.model, s.band_hz, s.min_pairs, s.height_m, s.sigma_floor_m, s.band_prior_scale,
                                    s.run_model)

    def _new_compass(self) -> MagCalibrator:
        c = self.config.compass
        return MagCalibrator(c.soft_iron, c.min_stances, c.min_heading_spread_rad, c.mag_tol, c.dip_tol_rad,
                             c.soft_iron_std, c.hard_iron_std_ut, c.vertical_hard_iron_std_ut, c.max_heading_rms_rad,
                             c.min_swing, c.alignment_std_rad)

    # ------------------------------------------------------------------ field buffer
    @property
    def _mag_t(self) -> np.ndarray:
        """Times of the kept low-rate field samples [s] (increasing; a view of the buffer)."""
        f = self._field
        return f.storage[0][f.lo:f.hi]

    @property
    def _mag_v(self) -> np.ndarray:
        """Field at :attr:`_mag_t` [uT], shape (n, 3) (a view of the buffer)."""
        f = self._field
        return f.storage[1][f.lo:f.hi]

    @property
    def _mag_a(self) -> np.ndarray:
        """Low-rate specific force at :attr:`_mag_t` [m/s^2], shape (n, 3) (a view of the buffer)."""
        f = self._field
        return f.storage[2][f.lo:f.hi]

    # ------------------------------------------------------------------ streams
    def feed(self, t_s: np.ndarray, acc: np.ndarray, mag: np.ndarray) -> None:
        """Consume full- or low-rate samples; new step events join :attr:`queue`."""
        if len(t_s):
            self.t_in = float(t_s[-1])
        # [acc(3), mag(3) (0 where none), mag flag], as np.c_ builds it (in one compiled pass)
        x, any_mag = _low_input(acc, mag)
        self.has_mag = self.has_mag or any_mag
        lt, lx = self._low.process(t_s, x)
        if len(lt):
            self._append_low(lt, lx)

    def _append_low(self, lt: np.ndarray, lx: np.ndarray) -> None:
        """Low-rate samples ``[acc(3), mag(3), mag flag]`` to the field buffer and the step segmentation."""
        f = self._field
        f.reserve(len(lt))
        # the rows with a field sample join the buffer in one compiled call, which also finds the first row of
        # the last _MAG_KEEP_S; the new step events still see the rows before it (as before): the trim is
        # applied after them
        lo, hi = _field_append(*f.storage, f.lo, f.hi, lt, lx, _MAG_KEEP_S)
        f.hi = int(hi)
        for e in self._seg.feed(lt, lx[:, :3]):
            self._queue_event(e)
        f.drop(int(lo) - f.lo)  # the field of the last _MAG_KEEP_S
        if self.stance_mag or self.stance_acc or self.stance_swing or self.stride_peak:
            live = {e.index for e in self.queue}
            # (a table is rebuilt only when it holds a step no longer queued: same entries, same order)
            for name in ("stance_mag", "stance_acc", "stance_swing", "stride_peak"):
                table = getattr(self, name)
                if not table.keys() <= live:  # (a subset test: no set of the difference built)
                    setattr(self, name, {k: v for k, v in table.items() if k in live})

    def _queue_event(self, e: StepEvent) -> None:
        """A new step event joins the queue with the stance field and specific force of its stillest window, the
        field samples of the swing since the previous stance's window (:meth:`_swing_samples`) and the stride's
        peak specific force, from the low-rate field buffer in one compiled call (:func:`_event_fields`).

        The stance field: the mean low-rate specific force [m/s^2] and field [uT] (body) over the stance's
        stillest window. Windows of the step segmentation's ``window_s`` (:class:`models.steps.StepSegmenter`)
        start at the onset ``e.t_s`` [s] and move on one sample at a time while the foot stays quiet (the
        segmenter's quietness statistic, vector variance plus the squared departure of the mean magnitude from
        g, below its stance threshold) and the window ends within ``context_s`` of the onset's quiet window
        (always received when the event is emitted, so the choice does not depend on batch cuts); the quietest
        one is taken. Both means come from the same samples, so the compass's tilt is the attitude the field
        was measured in. None (no field) without magnetometer samples at the onset, not one from later in the
        stride.

        The swing (only after a window whose specific force is finite: restored states carry none, NaN): the
        rows strictly between the previous stance's window and this onset, when that window ended within
        ``_SWING_MAX_S`` and the magnetometer did not pause in between.

        The stride's peak: the largest absolute low-rate specific force on an axis [m/s^2] over the stride that
        ends at ``e`` (at most ``_SWING_MAX_S`` before its onset, up to the end of its stance's window): what a
        high-g interrupt at this rate sees of it; none where the stride's samples are not all there
        (magnetometer off or paused).
        """
        self.queue.append(e)
        seg = self._seg
        n = seg.window_samples
        dt = 1.0 / self.rate_hz
        hi_s = e.t_s + (n - 1 + round(seg.context_s * self.rate_hz)) * dt + 1e-6  # the last window's end [s]
        b0, acc, mag, t_end, lo, hi, peak_ok, peak = _event_fields(
            self._mag_t, self._mag_a, self._mag_v, float(e.t_s), float(hi_s), float(dt), int(n),
            float(seg.stance_threshold), _G0, float(self._window_end), _SWING_MAX_S,
            float(e.t_s - min(e.period_s, _SWING_MAX_S)), 1.5 / self.rate_hz)
        self.stance_mag[e.index] = None if b0 < 0 else mag
        if b0 >= 0 and all(map(math.isfinite, acc.tolist())):
            self.stance_acc[e.index] = acc
            if lo >= 0:
                self.stance_swing[e.index] = self._swing_samples(int(lo), int(hi))
        self._window_end = -math.inf if b0 < 0 else float(t_end)
        if peak_ok:
            self.stride_peak[e.index] = float(peak)

    def _swing_samples(self, lo: int, hi: int) -> np.ndarray:
        """Up to ``_SWING_SAMPLES`` low-rate field samples [uT] (body) of the field buffer's rows ``lo .. hi - 1``
        (a swing), evenly spread over them. For the magnitude constraint of the compass calibration
        (:meth:`models.compass.MagCalibrator.add_swing`)."""
        if hi - lo <= _SWING_SAMPLES:
            return self._mag_v[lo:hi].copy()
        keep = _SWING_KEEP.get(hi - lo)
        if keep is None:
            keep = np.unique(np.round(np.linspace(0, hi - lo - 1, _SWING_SAMPLES)).astype(int))
            if len(_SWING_KEEP) < 1024:
                _SWING_KEEP[hi - lo] = keep
        return self._mag_v[lo + keep]

    def flush(self) -> None:
        """End of the session: the step events the filters and the segmenter's look-ahead still hold."""
        low = self._low
        if low.dec is not None:
            ft, fx = low.dec.flush()
            fs = ft / 1e9
            keep = fs > low.last_t
            if np.any(keep):
                self._append_low(fs[keep], fx[keep])
                low.last_t = float(fs[keep][-1])
        for e in self._seg.flush():
            self._queue_event(e)
        self.t_in = math.inf

    @property
    def horizon(self) -> float:
        """Every step event with a stance onset before this time [s] is in :attr:`queue` (or was taken): the step
        segmentation's own bound (:attr:`models.steps.StepSegmenter.final_before_s`): 0.6 s behind ``t_in`` at the
        median instead of the fixed ``SEGMENTER_LATENCY_S`` (1.5 s, still its tested upper bound), so a hand-over
        to Gait-DR is decided about a batch sooner."""
        return self._seg.final_before_s if math.isfinite(self.t_in) else self.t_in

    def mag_at(self, e: StepEvent) -> np.ndarray | None:
        """Mean field [uT] (body) over the stance's quiet window; None without magnetometer."""
        return self.stance_mag.get(e.index)

    def acc_at(self, e: StepEvent) -> np.ndarray:
        """Mean specific force [m/s^2] (body) over the same samples as :meth:`mag_at`: the compass's tilt.
        The event's own (filtered) stance force where none was kept (states stored before it existed)."""
        a = self.stance_acc.get(e.index)
        return np.asarray(e.acc_stance, dtype=np.float64) if a is None else a

    # ------------------------------------------------------------------ pairing with ZUPT-KF stances
    def take_pair(self, t_start_s: float) -> StepEvent | None:
        """Remove the events up to a ZUPT-KF stance onset [s] from the queue; return the one of that stance."""
        near = [q for q in self.queue if abs(q.t_s - t_start_s) <= PAIR_TOL_S]
        self.queue = [q for q in self.queue if q.t_s > t_start_s + PAIR_TOL_S]
        return min(near, key=lambda q: abs(q.t_s - t_start_s)) if near else None

    # ------------------------------------------------------------------ compass
    def compass(self) -> MagCalibrator | None:
        """The compass calibration in use: this session's own fit once it is ready and, against a profile's,
        trusted and as consistent with the ZUPT-KF (its robust scale within ``_SCALE_TIE`` of the profile's:
        either scale, from a few tens of stances, is known to ~15 %); else the profile's; None before either."""
        own, loaded = self.mag, self.loaded
        if loaded is None or not loaded.ready:
            return own if own.ready else None
        if own.ready and (not loaded.trusted or (own.trusted and own.heading_scale <= _SCALE_TIE * loaded.heading_scale)):
            return own
        return loaded

    def _refresh_compass(self) -> None:
        """Refit the own calibration when its stances grew by a tenth (a quarter once trusted: a fit costs
        time linear in the stances, so refitting every stance would cost quadratic time), and tell the heading
        estimator when the compass in use changed: the own fit reads in the session frame (offset 0 to its
        prior), a profile's in its own session's frame (offset unknown until the next reading)."""
        n = self.mag.n_added
        if n >= self._mag_fit_n + max(1, n // (4 if self.mag.ready and self.mag.trusted else 10)):
            self.mag.refit()
            self._mag_fit_n = n
        cal = self.compass()
        which = "" if cal is None else ("own" if cal is self.mag else "loaded")
        if which != self.in_use:
            self.in_use = which
            self._prev_field = self.last_reading = None
            if which == "own":
                self.est.set_offset_prior(0.0, self.config.heading.offset_prior_rad)
            else:
                self.est.forget_offset()

    def _reference_field(self, cal: MagCalibrator) -> tuple[float, float] | None:
        """Vertical and horizontal magnitude [uT] of the Earth's field a reading is compared with: the own
        fit's m_n (fitted here), or for a profile's compass the median of this session's stance fields (it
        was fitted at another place)."""
        if cal is self.mag:
            norm, dip = cal.field_reference()
            return norm * math.sin(dip), norm * math.cos(dip)
        if len(self._fields) < 3:
            return None
        a = np.asarray(self._fields)
        return median(a[:, 0]), median(a[:, 1])

    def compass_reading(self, e: StepEvent) -> tuple[float, float, float, float] | None:
        """At the stance of ``e``: compass heading [rad], its variance [rad^2] without the place term, and the
        heading [rad] the field's anomaly against the Earth's and its change since the last reading could cause
        (:class:`models.heading.CompassNoise`); None without a calibrated compass or a field there."""
        cal = self.compass()
        m = self.mag_at(e)
        if cal is None or m is None:
            return None
        acc = self.acc_at(e)
        norm, dip = cal.field_shape(acc, m)
        b_v, b_h = norm * math.sin(dip), norm * math.cos(dip)
        if cal is self.loaded:
            self._fields = (self._fields + [[b_v, b_h]])[-_REF_STANCES:]
            if cal.session_on and not cal.disturbed(acc, m):
                cal.observe_dip(acc, m)  # this power-on's accelerometer tilt offset (MagCalibrator.observe_dip)
        ref = self._reference_field(cal)
        if ref is None:
            return None
        prev, self._prev_field = self._prev_field, (b_v, b_h)
        anomaly = CompassNoise.field_sigma(b_v, b_h, *ref)
        change = anomaly if prev is None else CompassNoise.field_sigma(b_v, b_h, *prev)
        s_cal = next((s for s in (cal.heading_scale, cal.heading_rms) if math.isfinite(s)), cal.max_heading_rms)
        return cal.heading(acc, m), self.est.noise.reading_variance(s_cal), anomaly, change

    # ------------------------------------------------------------------ heading
    def start_frame(self, heading: float) -> None:
        """The session's first ZUPT-KF stance: its heading [rad] defines the navigation frame."""
        self.est.start(heading)

    def track(self, e: StepEvent | None, delta: float, unseen: float) -> float:
        """One stride through the heading estimator: the gyroscope saw the heading change ``delta`` [rad]
        over all but ``unseen`` (0..1) of it; then the stance compass of ``e`` and, without the gyroscope, the
        building's dominant directions. Returns the heading [rad]."""
        est = self.est
        self._refresh_compass()
        reading = self.compass_reading(e) if e is not None and self.has_mag else None
        change = 0.0 if reading is None else reading[3]
        if unseen <= 0.0:
            est.predict_gyro(delta, change)
        else:
            est.predict_free(delta, unseen, change)
        if reading is not None:
            self.last_reading = reading[1:]
        if reading is not None:
            est.update_compass(reading[0], reading[1], reading[2], learn=unseen <= 0.0)
        h = self.config.heading
        if unseen > 0.0 and self.dominant is not None and h.dominant_on:
            est.update_dominant(self.dominant, h.straight_sigma_rad, self.config.zupt.dom_delta)
        if e is not None:
            self.step_s = e.t_s
        return est.heading

    def magnetic_north(self) -> tuple[float, float] | None:
        """Azimuth [rad] of magnetic north in the session frame and its standard deviation [rad]: the horizontal
        direction of the compass's fitted field, less the compass's frame offset the heading estimator holds;
        None before a compass has read."""
        cal = self.compass()
        if cal is None or not self.est.offset_known:
            return None
        x, p = self.est.combined()
        az = math.atan2(float(cal.m_n[1]), float(cal.m_n[0]))
        return wrap_angle(az - float(x[1])), math.sqrt(max(float(p[1, 1]), 0.0))

    def forecast_drift_pct(self, behaviour: str) -> float:
        """Cross-track drift [% of distance] over the next 100 m if the gyroscope went off now.

        Infinite without a calibrated compass (no magnetometer, or its fit not ready): nothing would observe the
        heading. Otherwise from the heading estimator's forecast one gyroscope-off stride ahead (with a compass
        reading as noisy as the latest): a persistent heading error ``s_p`` (the compass's offsets, KF II's
        deviation, 004 eq. 16) moves the path aside by ``100 s_p`` metres per 100 m; an error ``s_w`` that
        changes from stride to stride (the compass's own noise) by ``s_w sqrt(100 L)`` (a random walk of
        ``100 / L`` strides of length ``L``: the latest ZUPT-KF strides' median, 1.4 m before there is one).
        """
        if not self.est.started or self.last_reading is None or self.compass() is None:
            return math.inf
        kf = self.kf2[model_behaviour(behaviour)]
        dev_var = kf.variance if kf.n_updates else math.pi**2
        total, persistent = self.est.forecast(*self.last_reading)
        white = max(total**2 - persistent**2, 0.0)
        recent = self.recent_d[model_behaviour(behaviour)]
        stride = max(float(np.median(recent)), 0.5) if recent else 1.4
        return 100.0 * math.sqrt(persistent**2 + dev_var + white * stride / 100.0)

    # ------------------------------------------------------------------ calibration
    def learn(self, st: Stance, e: StepEvent, behaviour: str, step_model: bool = True) -> float | None:
        """Calibration pair: ZUPT-KF stride ``st`` (session frame) and its step event ``e`` (004 eq. 15, 19, 20,
        Table 3), and the stance for this session's compass fit.

        KF II skips strides over which the ZUPT-KF heading turned by more than ``turn_gate_rad`` (eq. 20's chord
        mixes the directions before and after the turn) and observes the others against the heading half-way
        through the swing (the chord lies between the stance headings before and after it).

        ``step_model``: the stride joins the step-length calibration (an initialisation's or an examination's:
        004 calibrates in the initialisation; the strides the gyroscope runs for the heading alone, in disturbed
        fields and their odd gaits, stay out). Returns the KF II observation ``gamma - psi`` [rad] of the stride
        (None when it gave none), so that the engine can test a stored deviation against it (sensor re-mounted).
        """
        m = self.mag_at(e)
        if m is not None:
            acc_st = self.acc_at(e)
            # once trusted, only stances whose field is settled on its reference join (steel edges that pass the
            # disturbance gate pull m_n and the hard iron towards the steel); an untrusted calibration (indoors)
            # cannot tell and averages every stance. The swing before a stance joins when the stance before did.
            cc = self.config.compass
            if not (self.mag.ready and self.mag.trusted) or self.mag.settled(
                    *self.mag.field_shape(acc_st, m), cc.settled_mag_tol, cc.settled_dip_tol_rad):
                swing = self.stance_swing.get(e.index) if self._cal_last == e.index - 1 else None
                self.mag.add(acc_st, m, float(st.heading), swing)
                self._cal_last = e.index
            self._refresh_compass()
        prev, self._prev_stance = self._prev_stance, (float(st.t_start_s), float(st.heading))
        sl = self.config.step_length
        if behaviour not in _BEHAVIOURS or st.step_length < sl.min_stride_m or e.after_rest:
            return None
        features = self.features(e, behaviour)
        if step_model:
            self.cal.add(behaviour, features, st.step_length)
        self._note_cadence(e, behaviour)
        peak = self.stride_peak.get(e.index)
        if behaviour == "walk" and peak is not None and math.isfinite(peak):
            self.walk_peaks = (self.walk_peaks + [peak])[-_PEAK_STRIDES:]
        self.recent_d[behaviour] = (self.recent_d[behaviour] + [st.step_length])[-sl.recent_strides:]
        generic = self._generic.predict(behaviour, features)[0]
        if generic > 0.0:
            self.recent_scale[behaviour] = (self.recent_scale[behaviour] + [st.step_length / generic])[-sl.recent_strides:]
        gamma = gamma_from_increment(float(st.delta[0]), float(st.delta[1]))  # 004 eq. (20)
        psi = float(st.heading)
        if math.isfinite(prev[0]) and st.t_start_s - prev[0] <= 2.0 * e.period_s:
            turned = wrap_angle(psi - prev[1])
            if abs(turned) > self.config.deviation.turn_gate_rad:
                return None  # a turning stride: eq. (20) mixes two walking directions
            psi -= 0.5 * turned  # the heading half-way through the swing, whose chord eq. (20) measures
        z = wrap_angle(gamma - psi)
        self.kf2[behaviour].update(z, dt=e.period_s)  # 004 eq. (19)
        return z

    def ready(self, behaviour: str) -> bool:
        """Enough calibration strides for the behaviour's step model."""
        return self.cal.n_pairs(model_behaviour(behaviour)) >= self.cal.min_pairs

    def fit(self, behaviour: str) -> dict:
        return self.cal.fit(model_behaviour(behaviour))

    def calibration_state(self) -> dict[str, Any]:
        """What a profile keeps of this session's step-length calibration (opaque ``step_model``); the compass
        is the sensor's and joins when the profile is handed out (:meth:`compass_state`)."""
        return {"calibrator": self.cal.get_state()}

    def compass_state(self) -> dict[str, Any] | None:
        """The compass calibration to hand on in a profile: the one in use (the own fit refitted on every
        stance it holds, unless that makes it untrusted), None before there is one."""
        cal = self.compass()
        if cal is None:
            return None
        if cal is self.mag and self.mag.n_added > self._mag_fit_n:
            fresh = MagCalibrator.from_state(self.mag.get_state())
            fresh.refit()
            return fresh.get_state()
        return cal.get_state()

    def _note_cadence(self, e: StepEvent, behaviour: str) -> None:
        """Keep the cadence of a stride whose period was measured (not after a rest or a pause)."""
        b = model_behaviour(behaviour)
        if not (e.after_rest or e.paused) and math.isfinite(e.f_s):
            self.recent_f[b] = (self.recent_f[b] + [float(e.f_s)])[-_RECENT_CADENCES:]

    def features(self, e: StepEvent, behaviour: str) -> StepFeatures:
        """Step-model features of ``e`` as a stride of ``behaviour`` (004 eq. 15): a stride after a short pause or
        a rest has no period of its own (the segmentation gives it the pace before the pause or a nominal one)
        and takes the median cadence of its own behaviour's latest measured strides."""
        b = model_behaviour(behaviour)
        if (e.paused or e.after_rest) and self.recent_f[b]:
            return StepFeatures(float(np.median(self.recent_f[b])), e.acc_mean, e.acc_max, e.acc_min)
        return _features(e)

    def step_length(self, e: StepEvent, behaviour: str) -> tuple[float, float]:
        """Model step length [m] and its sigma_d [m] for a step event (004 eq. 15). Before the behaviour's model
        is fitted, the generic model at this person's scale (median ratio of the latest ZUPT-KF strides to it)
        stands in for it."""
        b = model_behaviour(behaviour)
        f = self.features(e, b)
        if self.conventional:
            return self._generic.predict(b, f)  # generic model (never fitted)
        if not self.cal.calibrated(b) and self.recent_scale[b]:
            return self._generic.predict(b, f)[0] * float(np.median(self.recent_scale[b])), float("nan")
        if not self.cal.calibrated(b) and self.recent_d[b]:
            return float(np.median(self.recent_d[b])), float("nan")
        return self.cal.predict(b, f)

    def deviation_kf(self, behaviour: str) -> HeadingDeviationKF:
        """KF II serving a behaviour's steps: its own, or the best-estimated one where it has no update (the
        deviation is mostly the sensor-to-foot mount)."""
        kf = self.kf2[model_behaviour(behaviour)]
        return kf if kf.n_updates else max(self.kf2.values(), key=lambda k: k.n_updates)

    def forget_mount(self, behaviours: list[str]) -> None:
        """The sensor was re-mounted (a stored heading deviation failed its test): drop the KF II estimates of
        ``behaviours`` and the profile's compass (its hard/soft iron includes the shoe)."""
        for b in behaviours:
            self.kf2[model_behaviour(b)] = self._new_kf2()
        self.loaded = None
        self._refresh_compass()

    def run_wake_threshold(self) -> float | None:
        """High-g threshold [m/s^2] per axis above this person's walking (``run_wake_margin`` times the largest
        absolute specific force on an axis of their latest walking ZUPT-KF strides); None until enough."""
        if len(self.walk_peaks) < _PEAK_MIN_STRIDES:
            return None
        return self.config.scheduler.run_wake_margin * max(self.walk_peaks)

    def bootstrapped(self) -> bool:
        """Gait-DR can place a step: some behaviour has a heading deviation (KF II) and a stride estimate."""
        boot = self.config.deviation.boot_updates
        return any(self.kf2[b].n_updates >= boot and (self.recent_d[b] or self.cal.calibrated(b)) for b in _BEHAVIOURS)

    def load_calibration(self, behaviour: str, step_model: dict[str, Any], deviation_rad: float,
                         deviation_var: float) -> None:
        """Take a behaviour's calibration from a user profile (:class:`energy.profile.BehaviourCalibration`)."""
        b = model_behaviour(behaviour)
        stored = step_model.get("calibrator")
        if isinstance(stored, dict):
            state = self.cal.get_state()
            state["pairs"][b] = list(stored.get("pairs", {}).get(b, []))
            state["fits"] = {k: v for k, v in state["fits"].items() if not (k == b or k.startswith(b + "/"))}
            state["fits"].update({k: v for k, v in stored.get("fits", {}).items() if k == b or k.startswith(b + "/")})
            self.cal = StepLengthCalibrator.from_state(state)
            if stored.get("form") != FORM or stored.get("run_model", "eq15_run") != self.cal.run_model:
                self.cal.refit_stale()  # a profile fitted with other regressors than this session's
        compass = step_model.get("compass")
        if isinstance(compass, dict) and self.loaded is None:
            loaded = MagCalibrator.from_state(compass)  # the same sensor's hard/soft-iron calibration
            if loaded.ready:
                if self.mag.n_swing == 0:
                    # the swings' field magnitudes tell the sensor's hard and soft iron whatever the session's
                    # frame or place: this session's own fit starts with them (its stances are its own)
                    self.mag.add_swing(np.asarray(loaded.swing_samples()))
                loaded.start_session()  # its axis alignment holds another power-on's accelerometer tilt offset
                self.loaded = loaded
        kf = self.kf2[b]
        if math.isfinite(deviation_rad) and math.isfinite(deviation_var) and deviation_var > 0:
            kf.x = np.array([0.0, wrap_angle(float(deviation_rad))])
            kf.p = np.diag([kf.p0_rate**2, float(deviation_var)])
            kf.n_updates = max(kf.n_updates, self.config.deviation.boot_updates)

    # ------------------------------------------------------------------ dead reckoning
    @property
    def active(self) -> bool:
        return self.dr is not None

    def start(self, position: np.ndarray) -> None:
        """(Re)start Gait-DR at a ZUPT-KF stance: NED position [m]."""
        self.dr = GaitDeadReckoner(position, compensate=not self.conventional)

    def reckon(self, before_s: float, label_at: Callable[[float], str]) -> list[tuple[PdrStep, StepEvent, float]]:
        """Dead-reckon the queued step events with onset before ``before_s`` [s] (dropped when not active): each
        stride goes through the heading estimator without the gyroscope, then :meth:`place`. Returns each
        step with its event and the drift forecast right after it (:meth:`forecast_drift_pct`)."""
        out: list[tuple[PdrStep, StepEvent, float]] = []
        todo = [e for e in self.queue if e.t_s < before_s]
        self.queue = [e for e in self.queue if e.t_s >= before_s]
        if self.dr is None:
            return out
        for e in todo:
            before = self.est.heading
            self.track(e, 0.0, 1.0)
            label = label_at(e.t_s)
            out.append((self.place(e, label, before), e, self.forecast_drift_pct(label)))
        return out

    def place(self, e: StepEvent, label: str, before: float) -> PdrStep:
        """Place the stride ending at ``e`` whose heading estimate went from ``before`` [rad] to the estimator's
        current one: along their chord plus the gait deviation (004 eq. 16), the step model's length (004
        eq. 15, 14)."""
        assert self.dr is not None
        b = model_behaviour(label)
        d, _ = self.step_length(e, b)
        self._note_cadence(e, b)
        chord = before + 0.5 * wrap_angle(self.est.heading - before)
        return self.dr.step(e.t_s, max(d, 0.0), chord, self.deviation_kf(b).deviation, b)

    # ------------------------------------------------------------------ state
    def get_state(self) -> dict[str, Any]:
        return {
            "low": self._low.get_state(),
            "seg": self._seg.get_state(),
            "cal": self.cal.get_state(),
            "kf2": {b: k.get_state() for b, k in self.kf2.items()},
            "mag": self.mag.get_state(),
            "loaded": None if self.loaded is None else self.loaded.get_state(),
            "in_use": self.in_use,
            "est": self.est.get_state(),
            "last_reading": None if self.last_reading is None else list(self.last_reading),
            "prev_field": None if self._prev_field is None else list(self._prev_field),
            "fields": [list(r) for r in self._fields],
            "dr": None if self.dr is None else self.dr.get_state(),
            "queue": [e.to_row() for e in self.queue],
            "mag_t": self._mag_t.copy(), "mag_v": self._mag_v.copy(), "mag_a": self._mag_a.copy(),
            "stance_mag": [[k, None if v is None else np.asarray(v)] for k, v in self.stance_mag.items()],
            "stance_acc": [[k, np.asarray(v)] for k, v in self.stance_acc.items()],
            "stance_swing": [[k, np.asarray(v)] for k, v in self.stance_swing.items()],
            "stride_peak": [[k, v] for k, v in self.stride_peak.items()], "walk_peaks": list(self.walk_peaks),
            "window_end": self._window_end, "cal_last": self._cal_last, "t_in": self.t_in,
            "mag_fit_n": self._mag_fit_n, "has_mag": self.has_mag,
            "recent_d": {b: list(v) for b, v in self.recent_d.items()},
            "recent_scale": {b: list(v) for b, v in self.recent_scale.items()},
            "recent_f": {b: list(v) for b, v in self.recent_f.items()},
            "prev_stance": list(self._prev_stance), "step_s": self.step_s, "dominant": self.dominant,
        }

    @classmethod
    def from_state(cls, config: EngineConfig, d: dict[str, Any]) -> GaitPipeline:
        obj = cls(config)
        obj._low = _LowRate.from_state(d["low"])
        obj._seg = StepSegmenter.from_state(d["seg"])
        obj.cal = StepLengthCalibrator.from_state(d["cal"])
        obj._generic = obj._new_calibrator()
        obj.kf2 = {b: HeadingDeviationKF.from_state(k) for b, k in d["kf2"].items()}
        obj.mag = MagCalibrator.from_state(d["mag"])
        obj.loaded = None if d["loaded"] is None else MagCalibrator.from_state(d["loaded"])
        obj.in_use = str(d["in_use"])
        obj.est = HeadingEstimator.from_state(config.heading, d["est"])
        lr, pf = d["last_reading"], d["prev_field"]
        obj.last_reading = None if lr is None else (float(lr[0]), float(lr[1]), float(lr[2]))
        obj._prev_field = None if pf is None else (float(pf[0]), float(pf[1]))
        obj._fields = [[float(x) for x in r] for r in d["fields"]]
        obj.dr = None if d["dr"] is None else GaitDeadReckoner.from_state(d["dr"])
        obj.queue = [StepEvent.from_row(q) for q in d["queue"]]
        obj._field = RowBuffer(np.asarray(d["mag_t"], dtype=float), np.asarray(d["mag_v"], dtype=float).reshape(-1, 3),
                               np.asarray(d["mag_a"], dtype=float).reshape(-1, 3))
        obj.stance_mag = {int(k): (None if v is None else np.asarray(v, dtype=float)) for k, v in d["stance_mag"]}
        obj.stance_acc = {int(k): np.asarray(v, dtype=float) for k, v in d["stance_acc"]}
        obj.stance_swing = {int(k): np.asarray(v, dtype=float).reshape(-1, 3) for k, v in d["stance_swing"]}
        obj.stride_peak = {int(k): float(v) for k, v in d["stride_peak"]}
        obj.walk_peaks = [float(x) for x in d["walk_peaks"]]
        obj._window_end = float(d["window_end"])
        obj._cal_last = int(d["cal_last"])
        obj.t_in, obj.has_mag = float(d["t_in"]), bool(d["has_mag"])
        obj._mag_fit_n = int(d["mag_fit_n"])
        obj.recent_d = {b: [float(x) for x in v] for b, v in d["recent_d"].items()}
        obj.recent_scale = {b: [float(x) for x in v] for b, v in d["recent_scale"].items()}
        obj.recent_f = {b: [float(x) for x in v] for b, v in d["recent_f"].items()}
        ps = d["prev_stance"]
        obj._prev_stance = (float(ps[0]), float(ps[1]))
        obj.step_s = float(d["step_s"])
        obj.dominant = None if d["dominant"] is None else float(d["dominant"])
        return obj
