"""The Gait-DR half of the engine: low-rate step stream, online calibration against the ZUPT-KF, dead reckoning.

Runs on a low-rate copy of the accelerometer/magnetometer streams (anti-aliased to ``pdr_rate_hz`` whatever
the device sends), so its step events do not change when the device is de-sampled (004 Section 4.3). Step
events wait in a queue; the engine (:mod:`energy.engine`) hands each one either to a ZUPT-KF stance of the
same stance (step-length calibration 004 eq. 15 and Table 3, KF II 004 eq. 17-20, magnetometer calibration,
examination) or to dead reckoning (004 eq. 14, 16) with the heading following the stance compass
(:class:`models.compass.CompassFollower`: on a clean field small disagreements averaged and turns taken whole;
through a magnetic disturbance the heading held and only turns taken, from the compass change between stances),
or the last heading where no calibrated field is there. :attr:`GaitPipeline.horizon` bounds how late an event can
still appear.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
from numba import njit

from models.compass import CompassFollower, MagCalibrator
from models.fir import Decimator
from models.gait_pdr import GaitDeadReckoner, PdrStep
from models.heading_deviation import HeadingDeviationKF, gamma_from_increment, wrap_angle
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
_HANDON_WORSE, _HANDON_SLACK_RAD = 1.5, math.radians(0.5)  # compass_state: a refit worse than both is not handed on
_MIN_CAL_STEP_M = 0.3  # shorter ZUPT-KF displacements are shuffles, not calibration steps
_BEHAVIOURS = ("walk", "run")
_RECENT_STEPS = 8  # ZUPT-KF strides whose median stands in for an unfitted step model
_RECENT_CADENCES = 5  # measured strides of a behaviour whose median cadence a paused stride of it takes
_BOOT_STEPS = 3  # KF II updates before Gait-DR may place steps
_KF2_TURN_RAD = math.radians(10.0)  # strides whose ZUPT-KF heading turned more than this do not update KF II
_ANCHOR_STANCES = 3  # clean stances whose offset is averaged to re-anchor a compass loaded from a profile
_HELD_MAX = 48  # Gait-DR stances kept while the compass does not lead (GaitPipeline._missed_turn)
# Run wake (energy.scheduler): the device's high-g interrupt wakes the gyroscope when its accelerometer exceeds
# this factor times the largest absolute specific force on an axis (25-Hz samples) of this person's latest
# walking strides. Largest |a| on an axis over 2-s windows of 40-ms means (synthetic, 6 seeds each): walks
# <= 30.8 m/s^2, fast walks <= 39.3, runs >= 43.4 (median 47.1); with 1.25 the fast walks woke it (mixed day
# energy_ratio up to 0.253). VICON walk trials <= 36.1, run trials median 41.0: a slow jog may not wake (the
# behaviour recognition still catches it).
RUN_WAKE_MARGIN = 1.4
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
        prev = np.concatenate([[self.prev_t], t_s[:-1]])
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
        return self._newer(np.concatenate(outs_t), np.concatenate(outs_x))

    def _newer(self, out_s: np.ndarray, out_x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The output samples after the last one returned (outputs never go back in time)."""
        keep = out_s > self.last_t
        if not keep.all():
            out_s, out_x = out_s[keep], out_x[keep]
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
    """Step events, calibration and dead reckoning for one session.

    The engine drives it in data-time order: step events wait in :attr:`queue` until either a ZUPT-KF stance
    claims them (:meth:`take_pair`: calibration, examination) or Gait-DR reckons them (:meth:`reckon`).
    :attr:`horizon` says up to when the event list is final, so both decisions are independent of how the
    stream was cut into batches.

    Parameters
    ----------
    rate_hz : float
        Rate of the low-rate stream the step segmentation runs on [Hz].
    conventional : bool
        "Conventional PDR" of 004 Table 6, the baseline that shows what the online calibration buys: the
        generic step model (:func:`models.step_length.default_prior`, never fitted to this person) and no
        heading-deviation compensation (KF II still runs, its estimate is not applied). Same hand-over and
        heading as Gait-PDR.
    """

    def __init__(self, rate_hz: float, conventional: bool = False) -> None:
        self.rate_hz = float(rate_hz)
        self.conventional = bool(conventional)
        self._low = _LowRate(rate_hz)
        self._seg = StepSegmenter(rate_hz)
        self.cal = StepLengthCalibrator()
        self._generic = StepLengthCalibrator(self.cal.model)  # the generic prior model, never fitted
        self.kf2 = {b: HeadingDeviationKF() for b in _BEHAVIOURS}
        self.mag = MagCalibrator()  # the compass in use: this session's own fit, or one loaded from a profile
        self.mag_anchored = True  # compass in this session's frame (False: loaded from a profile, not re-anchored yet)
        # clean stances that anchor a loaded compass in this session's frame: [heading (rad), acc (3), mag (3)]
        self._anchor_rows: list[list[float]] = []
        self.own_mag: MagCalibrator | None = None  # this session's own fit while a loaded compass is in use
        self.mag_placed = True  # gate reference checked against this place's field (False: loaded, not yet)
        self._place: list[tuple[float, float]] = []  # (|m| uT, dip rad) of this session's stances, loaded compass
        self.follower = CompassFollower()
        self.dr: GaitDeadReckoner | None = None
        self.queue: list[StepEvent] = []
        self._mag_t = np.zeros(0)
        self._mag_v = np.zeros((0, 3))
        self._mag_a = np.zeros((0, 3))  # low-rate specific force at the same samples as _mag_v [m/s^2]
        self.stance_mag: dict[int, np.ndarray | None] = {}
        self.stance_acc: dict[int, np.ndarray] = {}  # specific force over the same window as stance_mag
        self.stance_swing: dict[int, np.ndarray] = {}  # field samples of the swing before each stance [uT]
        self.stride_peak: dict[int, float] = {}  # largest |specific force| on an axis over each stride [m/s^2]
        self.walk_peaks: list[float] = []  # the same for the latest walking ZUPT-KF strides [m/s^2]
        self._window_end = -math.inf  # last sample time of the previous stance's field window [s]
        self._cal_last = -1  # index of the last step event whose stance joined a compass calibration
        self.heading = float("nan")  # last good heading of the sensor x axis [rad]
        self.t_in = -math.inf  # newest input sample time [s]
        self.has_mag = False  # the device has sent magnetometer samples in this session
        self._mag_fit_n = -1  # magnetometer stances at the last calibration fit
        self.recent_d: dict[str, list[float]] = {b: [] for b in _BEHAVIOURS}  # last ZUPT-KF strides [m]
        self.recent_scale: dict[str, list[float]] = {b: [] for b in _BEHAVIOURS}  # the same / generic model's
        self.recent_f: dict[str, list[float]] = {b: [] for b in _BEHAVIOURS}  # cadences of measured strides [Hz]
        self.compass_steps = 0
        self.held_steps = 0
        # Gait-DR stances since the absolute compass last led: (onset [s], compass - heading [rad]) (_missed_turn)
        self._held: list[tuple[float, float]] = []
        # set by reckon, taken by the engine after every reckon: a turn missed inside a disturbance, (from onset [s],
        # turn [rad])
        self.missed_turn: tuple[float, float] | None = None
        self._prev_stance = (-math.inf, math.nan)  # (onset [s], heading [rad]) of the last calibration stance

    # ------------------------------------------------------------------ streams
    def feed(self, t_s: np.ndarray, acc: np.ndarray, mag: np.ndarray) -> None:
        """Consume full- or low-rate samples; new step events join :attr:`queue`."""
        if len(t_s):
            self.t_in = float(t_s[-1])
        has_mag = ~np.isnan(mag[:, 0])
        self.has_mag = self.has_mag or bool(has_mag.any())
        # [acc(3), mag(3) (0 where none), mag flag], as np.c_ builds it (without its generic machinery)
        x = np.empty((len(t_s), 7))
        x[:, 0:3] = acc
        x[:, 3:6] = np.where(has_mag[:, None], mag, 0.0)
        x[:, 6] = has_mag
        lt, lx = self._low.process(t_s, x)
        if len(lt):
            self._append_low(lt, lx)

    def _append_low(self, lt: np.ndarray, lx: np.ndarray) -> None:
        """Low-rate samples ``[acc(3), mag(3), mag flag]`` to the field buffer and the step segmentation."""
        valid = lx[:, 6] > 0.999
        if valid.any():
            self._mag_t = np.concatenate([self._mag_t, lt[valid]])
            self._mag_v = np.concatenate([self._mag_v, lx[valid, 3:6]])
            self._mag_a = np.concatenate([self._mag_a, lx[valid, :3]])
        for e in self._seg.feed(lt, lx[:, :3]):
            self._queue_event(e)
        # the field of the last _MAG_KEEP_S (_mag_t increases: one slice, the rows of t >= the start)
        cut = int(self._mag_t.searchsorted(lt[-1] - _MAG_KEEP_S, "left"))
        if cut:
            self._mag_t, self._mag_v, self._mag_a = self._mag_t[cut:], self._mag_v[cut:], self._mag_a[cut:]
        if self.stance_mag or self.stance_acc or self.stance_swing or self.stride_peak:
            live = {e.index for e in self.queue}
            self.stance_mag = {k: v for k, v in self.stance_mag.items() if k in live}
            self.stance_acc = {k: v for k, v in self.stance_acc.items() if k in live}
            self.stance_swing = {k: v for k, v in self.stance_swing.items() if k in live}
            self.stride_peak = {k: v for k, v in self.stride_peak.items() if k in live}

    def _queue_event(self, e: StepEvent) -> None:
        """A new step event joins the queue with the stance field and specific force of its stillest window,
        and the field samples of the swing since the previous stance's window (:meth:`_swing_field`)."""
        self.queue.append(e)
        fa = self._stance_field(e.t_s)
        self.stance_mag[e.index] = None if fa is None else fa[1]
        if fa is not None and np.all(np.isfinite(fa[0])):  # (restored states carry no specific force: NaN)
            self.stance_acc[e.index] = fa[0]
            sw = self._swing_field(e.t_s)
            if sw is not None:
                self.stance_swing[e.index] = sw
        self._window_end = -math.inf if fa is None else fa[2]
        peak = self._stride_peak(e)
        if peak is not None:
            self.stride_peak[e.index] = peak

    def _stride_peak(self, e: StepEvent) -> float | None:
        """Largest absolute low-rate specific force on an axis [m/s^2] over the stride that ends at ``e`` (at
        most ``_SWING_MAX_S`` before its onset, up to the end of its stance's field window): what a high-g
        interrupt at this rate sees of it. None where the stride's samples are not all there (magnetometer
        off or paused)."""
        t0 = e.t_s - min(e.period_s, _SWING_MAX_S)
        tm = self._mag_t
        lo, hi = int(tm.searchsorted(t0 - 1e-6, "left")), int(tm.searchsorted(self._window_end + 1e-6, "right"))
        gap = 1.5 / self.rate_hz
        if hi - lo < 2 or tm[lo] - t0 > gap or float(np.diff(tm[lo:hi]).max()) > gap:
            return None
        return float(np.abs(self._mag_a[lo:hi]).max())

    def _swing_field(self, t_s: float) -> np.ndarray | None:
        """Up to ``_SWING_SAMPLES`` low-rate field samples [uT] (body), evenly spread over the swing between the
        previous stance's field window and this stance's onset ``t_s`` [s]; None when there was no such window
        within ``_SWING_MAX_S`` or the magnetometer paused in between. For the magnitude constraint of the
        compass calibration (:meth:`models.compass.MagCalibrator.add_swing`)."""
        t0 = self._window_end
        if not t_s - t0 <= _SWING_MAX_S:
            return None
        tm = self._mag_t  # increasing: the rows strictly inside (t0, t_s) are one range
        lo, hi = int(tm.searchsorted(t0 + 1e-6, "right")), int(tm.searchsorted(t_s - 1e-6, "left"))
        gap = 1.5 / self.rate_hz
        if hi - lo < 2 or tm[lo] - t0 > gap or t_s - tm[hi - 1] > gap or float(np.diff(tm[lo:hi]).max()) > gap:
            return None  # too few samples, or the magnetometer paused
        if hi - lo <= _SWING_SAMPLES:
            return self._mag_v[lo:hi].copy()
        keep = np.unique(np.round(np.linspace(0, hi - lo - 1, _SWING_SAMPLES)).astype(int))
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

    def _stance_field(self, t_s: float) -> tuple[np.ndarray, np.ndarray, float] | None:
        """Mean low-rate specific force [m/s^2] and field [uT] (body) over the stance's stillest window.

        Windows of the step segmentation's ``window_s`` (:class:`models.steps.StepSegmenter`) start at the onset
        ``t_s`` [s] and move on one sample at a time while the foot stays quiet (the segmenter's quietness
        statistic, vector variance plus the squared departure of the mean magnitude from g, below its stance
        threshold) and the window ends within ``context_s`` of the onset's quiet window (always received when
        the event is emitted, so the choice does not depend on batch cuts); the quietest one is taken. Both
        means come from the same samples, so the compass's tilt is the attitude the field was measured in.

        Before, the field was the mean over the 0.12 s *before* the onset (the end of the swing: the foot
        pitched -1.9 deg on average and still rotating; synthetic mixed day, seed 1000) and the tilt the
        segmenter's 8-Hz-FIR-filtered specific force over the first quiet window after it (heel-strike
        accelerations smeared in: pitch std 1.35 deg on stances that are exactly level). That tilt error grew
        with the tilt (slope 0.53), which the hard-iron fit took for a vertical hard iron of 15-17 uT, and its
        mean (+1.6 deg) for a horizontal one of 1.7 uT (b = [1.77, -0.09, 14.8] uT fitted, none there). The
        first quiet window right after the heel strike still carries the decimation filter's ringing (pitch
        error std 1.0 deg while walking); the stillest window in the stance, 0.08 deg.
        Returns (specific force, field, time of the window's last sample [s]); None without magnetometer
        samples at the onset.
        """
        seg = self._seg
        n = seg._w
        dt = 1.0 / self.rate_hz
        hi = t_s + (n - 1 + round(seg.context_s * self.rate_hz)) * dt + 1e-6
        tm = self._mag_t  # increasing: the rows of [t_s, hi] are one range
        idx = np.arange(int(tm.searchsorted(t_s - 1e-6, "left")), int(tm.searchsorted(hi, "right")))
        if idx.size == 0 or self._mag_t[idx[0]] > t_s + 0.5 * dt:
            return None  # no field at the onset (magnetometer off): not one from later in the stride
        gaps = np.flatnonzero(np.diff(self._mag_t[idx]) > 1.5 * dt)
        if gaps.size:
            idx = idx[: gaps[0] + 1]  # only the samples that follow the onset without a gap
        best = idx[:n]
        if idx.size > n:
            k = _stillest_window(self._mag_a[idx[0]:idx[-1] + 1], n, seg.stance_threshold, _G0)
            best = idx[k:k + n]
        return self._mag_a[best].mean(axis=0), self._mag_v[best].mean(axis=0), float(self._mag_t[best[-1]])

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

    def learn(self, st: Stance, e: StepEvent, behaviour: str) -> float | None:
        """Calibration pair: ZUPT-KF stride ``st`` and its step event ``e`` (004 eq. 15, 19, 20, Table 3).

        KF II skips strides over which the ZUPT-KF heading turned by more than 10 deg (eq. 20's chord mixes
        the directions before and after the turn), and observes the others against the heading half-way through
        the swing (the mean of the stance headings before and after it): the chord lies between them. Against
        the heading at heel strike, gamma - psi followed the stride's heading change (spread per recording 2.8
        deg median on gdin; 2.5 deg against the mid-swing heading, lower on 25 of 26 recordings). Measured over
        whole gdin walks (ZUPT-KF throughout, tests/energy/test_gait_dr.py): 10 of 26 recordings reach the
        filter's convergence (std < 1 deg), 1 then moves by more than 2 deg (exp23, 3.0 deg; 3.2 against the
        heel-strike heading), whose legs themselves differ (see that test); without the turn gate 12 converge
        and 2 move by more (exp23 2.4, exp37 5.6 deg).

        Returns the KF II observation ``gamma - psi`` [rad] of the stride (None when it gave none), so that the
        engine can test a stored deviation against it (:meth:`energy.engine.Engine`, sensor re-mounted).
        """
        m = self.mag_at(e)
        if m is not None:
            acc_st = self.acc_at(e)
            if self.mag.ready and not self.mag_placed:
                self._check_place(acc_st, m)
            clean = self.mag.ready and not self.mag.disturbed(acc_st, m)
            if clean and self.mag_placed and self._observe_dip(acc_st, m):
                self._reanchor()
            if self.mag.ready and not self.mag_anchored and clean:
                self._anchor_compass(float(st.heading), acc_st, m)
            # the swing before this stance joins with it when the previous stance joined too (its field is then
            # the Earth's at both ends, as far as the gate can tell)
            swing = self.stance_swing.get(e.index) if self._cal_last == e.index - 1 else None
            if self.own_mag is not None:
                # a loaded compass is not refitted with this session's stances (its stances' headings are in the
                # frame of the session that fitted them, and its field may be another place's): they go to this
                # session's own fit, which supersedes it once ready (_fit_compass)
                self.own_mag.add(acc_st, m, float(st.heading), swing)
                self._cal_last = e.index
            elif not self.mag.trusted or (clean and self._settled(self.mag.field_shape(acc_st, m))):
                # once the compass is trusted, only stances whose field is the Earth's (settled: magnitude and dip
                # within their noise, tighter than the disturbance gate) join: a steel edge that passed the gate
                # pulls m_n and the hard iron (and the compass's agreement measure) towards the steel (synthetic
                # mixed day, seeds 16 and 18: |m_n| 7.7 and 8.5 % low, hard iron 4.9 and 6.1 uT, against at most
                # 1.9 % and 1.7 uT on the other 30 days; all within that with this test). An untrusted calibration
                # (indoors) cannot tell; it keeps averaging every stance.
                self.mag.add(acc_st, m, float(st.heading), swing)
                self._cal_last = e.index
            if self.mag.ready:
                # a trusted compass's change between the segment's stances is tested against the gyroscope's
                # (CompassFollower.observe: a disturbance the gate let through turns the compass, not the foot)
                sigma = self._compass_sigma() if self.mag.trusted else math.nan
                self.follower.observe(self.mag.heading(acc_st, m), clean, *self.mag.field_shape(acc_st, m),
                                      psi=float(st.heading), sigma=sigma)
        prev, self._prev_stance = self._prev_stance, (float(st.t_start_s), float(st.heading))
        if behaviour not in _BEHAVIOURS or st.step_length < _MIN_CAL_STEP_M or e.after_rest:
            return None
        features = self.features(e, behaviour)
        self.cal.add(behaviour, features, st.step_length)
        self._note_cadence(e, behaviour)
        peak = self.stride_peak.get(e.index)
        if behaviour == "walk" and peak is not None and math.isfinite(peak):
            self.walk_peaks = (self.walk_peaks + [peak])[-_PEAK_STRIDES:]
        self.recent_d[behaviour] = (self.recent_d[behaviour] + [st.step_length])[-_RECENT_STEPS:]
        generic = self._generic.predict(behaviour, features)[0]
        if generic > 0.0:
            self.recent_scale[behaviour] = (self.recent_scale[behaviour] + [st.step_length / generic])[-_RECENT_STEPS:]
        gamma = gamma_from_increment(float(st.delta[0]), float(st.delta[1]))  # 004 eq. (20)
        psi = float(st.heading)
        if math.isfinite(prev[0]) and st.t_start_s - prev[0] <= 2.0 * e.period_s:
            turned = wrap_angle(psi - prev[1])
            if abs(turned) > _KF2_TURN_RAD:
                return None  # a turning stride: eq. (20) mixes two walking directions
            psi -= 0.5 * turned  # the heading half-way through the swing, whose chord eq. (20) measures
        z = wrap_angle(gamma - psi)
        self.kf2[behaviour].update(z, dt=e.period_s)  # 004 eq. (19)
        return z

    def _observe_dip(self, acc_stance: np.ndarray, mag_stance: np.ndarray) -> bool:
        """A loaded compass's tilt offset in this session (:meth:`~models.compass.MagCalibrator.observe_dip`) from
        a stance whose field is the Earth's as far as its magnitude and dip tell
        (:meth:`~models.compass.MagCalibrator.settled`), not merely within the disturbance gate: the edges of steel
        that passed the gate moved the fitted tilt offset by 1.1 deg and the compass by 5 deg at one heading for
        100 s (synthetic mixed day, returning seed 8: mean error 4.39 -> 2.51 m with this test). True when the
        offset was refitted."""
        if not self.mag.session_on:
            return False
        return self._settled(self.mag.field_shape(acc_stance, mag_stance)) and self.mag.observe_dip(acc_stance,
                                                                                                    mag_stance)

    def _settled(self, shape: tuple[float, float]) -> bool:
        """The field's magnitude [uT] and dip [rad] (:meth:`~models.compass.MagCalibrator.field_shape`) are the
        Earth's within the tolerances by which the compass may lead (:class:`~models.compass.CompassFollower`)."""
        return self.mag.settled(*shape, self.follower.lead_mag_tol, self.follower.rot_dip_tol)

    def _anchor_compass(self, heading: float, acc_stance: np.ndarray, mag_stance: np.ndarray) -> None:
        """Turn a compass calibration loaded from a profile into this session's navigation frame.

        The stored field m_n is expressed in the frame of the session that fitted it, whose heading 0 was the
        sensor's x axis at that session's first stance; this session's frame began wherever the foot pointed
        this time. The hard/soft iron belongs to the sensor and is kept; the field's azimuth is re-found from
        this session's first ``_ANCHOR_STANCES`` clean stances (``heading`` [rad], this session's) by
        :meth:`_reanchor`, and found again whenever the compass's tilt offset for this session is refitted.
        """
        self._anchor_rows.append([float(heading), *np.asarray(acc_stance, dtype=float).reshape(3).tolist(),
                                  *np.asarray(mag_stance, dtype=float).reshape(3).tolist()])
        if len(self._anchor_rows) >= _ANCHOR_STANCES:
            self.mag_anchored = True
            self._reanchor()

    def _reanchor(self) -> None:
        """Turn the loaded compass's frame by the circular mean of (this session's heading - compass) over the
        anchor stances. Found once, it was in error by the tilt offset's heading error (``tan(dip)`` times the
        change of the accelerometer's offset between the two power-ons, which differs by heading): on the
        mixed day's returning users (seeds 2, 10, 12, 15, 18, 21) the compass was then 1.4-3.6 deg off (median
        over the day's Gait-DR stances). The anchor stances are therefore read again with the compass whenever
        :meth:`MagCalibrator.observe_dip` refits its tilt offset, and the frame is turned whatever the size of
        the offset (the synthetic returning days start facing their earlier day's way, so the offsets found once
        had been left unapplied under the compass's 5-deg accuracy: 2.44 / 2.23 m mean error, seeds 0-15 /
        16-31; applied once, 3.16 / 2.64 m; read again, 2.06 / 1.98 m)."""
        if not (self.mag_anchored and self._anchor_rows):
            return
        a = np.asarray(self._anchor_rows, dtype=float)
        off = [wrap_angle(r[0] - self.mag.heading(r[1:4], r[4:7])) for r in a]
        delta = math.atan2(float(np.mean(np.sin(off))), float(np.mean(np.cos(off))))
        self.mag.rotate_frame(delta)

    def _check_place(self, acc_stance: np.ndarray, mag_stance: np.ndarray) -> None:
        """Test a loaded compass's field against this place's: the median magnitude [uT] and dip [rad] of its
        calibrated field over this session's first ``_ANCHOR_STANCES`` stances. When that median fails the
        loaded compass's own disturbance gate, the compass was fitted where the field differs (another
        building; on gdin a profile session's compass fitted in 84 stances): its gate is moved to this place's
        field (:meth:`~models.compass.MagCalibrator.relocate`) so that the stances here can re-anchor it, rather
        than every stance counting as disturbed and the heading being held for the whole session."""
        self._place.append(self.mag.field_shape(acc_stance, mag_stance))
        if len(self._place) >= _ANCHOR_STANCES:
            a = np.asarray(self._place)
            norm, dip = float(np.median(a[:, 0])), float(np.median(a[:, 1]))
            if self.mag.shape_disturbed(norm, dip):
                self.mag.relocate(norm, dip)
            self.mag_placed = True
            self._place = []

    def _adopt_own(self) -> None:
        """This session's own compass fit is ready (and trusted, or the loaded one is not): it supersedes the
        loaded one (same frame once anchored, and this place's field and this mount's hard iron)."""
        assert self.own_mag is not None
        own, self.own_mag = self.own_mag, None
        self._use_compass(own, loaded=False)
        self.follower.forget()  # the compass changed: no stance-to-stance change across the two
        self.follower.clean_run = 0  # nor a clean run counted by the other calibration's gate

    def _use_compass(self, cal: MagCalibrator, loaded: bool) -> None:
        """Make ``cal`` the compass in use; a ``loaded`` one (from a profile) still has to be checked against
        this place's field and re-anchored to this session's frame."""
        self.mag = cal
        self.mag_anchored = self.mag_placed = not loaded
        self._anchor_rows, self._place = [], []

    def ready(self, behaviour: str) -> bool:
        """Enough calibration steps, and a calibrated compass when a magnetometer is there.

        With a magnetometer the hand-over waits until the stances span enough headings for the
        hard-iron fit (otherwise Gait-DR would have to hold one heading through every turn).
        """
        if self.cal.n_pairs(model_behaviour(behaviour)) < self.cal.min_pairs:
            return False
        return self.compass_ready()

    def compass_ready(self) -> bool:
        """True without a magnetometer, or once its hard-iron calibration is fitted."""
        return self._fit_compass() if self.has_mag else True

    def _fit_compass(self) -> bool:
        """Refit the magnetometer calibration when the stances grew by a tenth since the last fit, by a quarter
        once it is trusted.

        A fit costs time linear in the stances, so refitting at every stance would cost quadratic time over a
        session; growth by a fraction keeps the total linear. A trusted fit is only replaced by a trusted refit
        (:meth:`models.compass.MagCalibrator.refit`) and changes little with a tenth more stances; its joint
        stance/swing refits (4-9 ms each) were a third of the scheduler's computation of a synthetic mixed day
        at a tenth (seed 0: 18 fits, 93 ms).
        """
        cal = self.mag if self.own_mag is None else self.own_mag
        n = cal.n_added
        if n >= self._mag_fit_n + max(1, n // (4 if cal.ready and cal.trusted else 10)):
            was_trusted = cal.ready and cal.trusted
            cal.refit()
            self._mag_fit_n = n
            if cal is self.mag and cal.trusted and not was_trusted:
                self.follower.forget()  # readings of the untrusted fit are no previous compass of this one
        own = self.own_mag
        if own is not None and own.ready and (
                not self.mag.trusted or (own.trusted and own.heading_scale <= self.mag.heading_scale)):
            # a trusted loaded compass stays until the own fit is trusted too and agrees with the ZUPT-KF at least as
            # well: an early own fit, from the few stances of a returning user's examinations, is often not trusted
            # (auto would then keep the gyroscope on), or noisier (returning seed 26: 3.8 deg from 15 stances, some
            # running; the compass was 8-10 deg off through the run that followed)
            self._adopt_own()
        return self.mag.ready

    def heading_source(self) -> bool:
        """Gait-DR can follow turns with the gyroscope off: a magnetometer with a fitted calibration that agrees
        with the ZUPT-KF heading (:attr:`models.compass.MagCalibrator.trusted`)."""
        return self.has_mag and self.compass_ready() and self.mag.trusted

    def fit(self, behaviour: str) -> dict:
        self._fit_compass()
        return self.cal.fit(model_behaviour(behaviour))

    def calibration_state(self) -> dict[str, Any]:
        """What a profile keeps of this session's step-length calibration (opaque ``step_model`` of the
        profile). The compass is the sensor's, not the behaviour's: :meth:`energy.engine.Engine.profile_dict`
        adds the one in use when the profile is handed out (:meth:`compass_state`), so the engine state does
        not carry a copy of it per calibrated behaviour (10.7 of 42.6 kB after a stand of one minute)."""
        return {"calibrator": self.cal.get_state()}

    def compass_state(self) -> dict[str, Any]:
        """The compass calibration to hand on in a profile: the one in use, fitted on every stance it holds.

        The compass in use is refitted only when its stances have grown by a tenth (:meth:`_fit_compass`), so its
        last fit can leave out the latest stances; a copy is refitted here, so what the engine does in this
        session does not depend on when a profile is asked for. A compass loaded from a profile is handed on as
        it came (this session's stances are in its own fit)."""
        if self.own_mag is not None or not self.mag.ready or self.mag.n_added <= self._mag_fit_n:
            return self.mag.get_state()
        cal = MagCalibrator.from_state(self.mag.get_state())
        cal.refit()  # never an untrusted one where the one in use is trusted
        if self.mag.trusted:
            # nor one the latest stances pulled off the stances of the fit in use: three stances 21-30 deg off the
            # ZUPT-KF heading (a later segment restarted from a held heading) put a refit's hard iron 4.5 uT off
            # (synthetic mixed day seed 1023: 1.10 deg in use, 2.31 refitted on the 57 stances of the fit in use;
            # 0.56-1.83 times on the other 31 days), and the next day's compass was 0-5 deg off by heading (seed
            # 23, returning: mean error 9.2 m)
            used = self.mag.heading_scale_on(0, self._mag_fit_n)
            refit = cal.heading_scale_on(0, self._mag_fit_n)
            if refit > max(_HANDON_WORSE * used, used + _HANDON_SLACK_RAD):
                return self.mag.get_state()
        return cal.get_state()

    def _note_cadence(self, e: StepEvent, behaviour: str) -> None:
        """Keep the cadence of a stride whose period was measured (not after a rest or a pause)."""
        b = model_behaviour(behaviour)
        if not (e.after_rest or e.paused) and math.isfinite(e.f_s):
            self.recent_f[b] = (self.recent_f[b] + [float(e.f_s)])[-_RECENT_CADENCES:]

    def features(self, e: StepEvent, behaviour: str) -> StepFeatures:
        """Step-model features of ``e`` as a stride of ``behaviour`` (004 eq. 15).

        A stride after a short pause or a rest has no period of its own: the segmentation gives it the running
        estimate (the pace before the pause) or a nominal one (its swing plus a nominal stance). Where the pause
        parted two behaviours that pace is the other one's (the first walking stride after a run and a 1.2-s stop
        took the run's 1.35 Hz, and the walking model placed it 1.98 m for 1.37 m: synthetic mixed day, seed 0,
        246 s); the nominal period after a rest was 1.21 Hz for a 0.87-Hz walk (the same day, 336 s: 1.63 m for
        1.35 m). Such a stride takes the median cadence of its own behaviour's latest measured strides instead.
        """
        b = model_behaviour(behaviour)
        if (e.paused or e.after_rest) and self.recent_f[b]:
            return StepFeatures(float(np.median(self.recent_f[b])), e.acc_mean, e.acc_max, e.acc_min)
        return _features(e)

    def step_length(self, e: StepEvent, behaviour: str) -> tuple[float, float]:
        """Model step length [m] and its sigma_d [m] for a step event (004 eq. 15).

        Before the behaviour's model is fitted, the median of the latest ZUPT-KF strides stands in for it
        (a person's stride is far better known from their own last strides than from a generic prior).
        """
        b = model_behaviour(behaviour)
        f = self.features(e, b)
        if self.conventional:
            return self._generic.predict(b, f)  # generic model (never fitted)
        if not self.cal.calibrated(b) and self.recent_scale[b]:
            # the generic model's cadence dependence at this person's scale (median ratio of the latest ZUPT-KF
            # strides to it): a walk that speeds up before its model is fitted gets longer strides
            return self._generic.predict(b, f)[0] * float(np.median(self.recent_scale[b])), float("nan")
        if not self.cal.calibrated(b) and self.recent_d[b]:
            return float(np.median(self.recent_d[b])), float("nan")
        return self.cal.predict(b, f)

    def deviation(self, behaviour: str) -> float:
        """Heading deviation [rad] Gait-DR applies to a behaviour's steps (004 eq. 16).

        The deviation is mostly the sensor-to-foot mount, plus gait: a behaviour without an estimate of its own
        (no KF II update, e.g. ``run`` steps in a walk before a run was calibrated) borrows the one with the most
        updates instead of 0 (gdin leave-one-out exp35: run-labelled steps placed 180 deg off).
        """
        kf = self.kf2[model_behaviour(behaviour)]
        if kf.n_updates == 0:
            kf = max(self.kf2.values(), key=lambda k: k.n_updates)
        return kf.deviation

    def forget_mount(self, behaviours: list[str]) -> None:
        """The sensor was re-mounted (a stored heading deviation failed its test): drop the KF II estimates of
        ``behaviours`` (loaded from the profile) and the compass calibration (the hard/soft iron includes the
        shoe the sensor sat on); both are learned again from this session's ZUPT-KF strides."""
        for b in behaviours:
            self.kf2[model_behaviour(b)] = HeadingDeviationKF()
        self.own_mag = None
        self._use_compass(MagCalibrator(), loaded=False)
        self._mag_fit_n = -1
        self.follower.forget()

    def run_wake_threshold(self) -> float | None:
        """High-g threshold [m/s^2] per axis above this person's walking (``RUN_WAKE_MARGIN`` times the largest
        absolute specific force on an axis of their latest walking ZUPT-KF strides): a device asked to wake the
        gyroscope on it does so on the first strides of a run, before the host has recognised one. None until
        enough walking strides were seen."""
        if len(self.walk_peaks) < _PEAK_MIN_STRIDES:
            return None
        return RUN_WAKE_MARGIN * max(self.walk_peaks)

    def bootstrapped(self) -> bool:
        """Gait-DR can place a step: some behaviour has a heading deviation (KF II) and a stride estimate."""
        return any(self.kf2[b].n_updates >= _BOOT_STEPS and (self.recent_d[b] or self.cal.calibrated(b))
                   for b in _BEHAVIOURS)

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
        if isinstance(compass, dict) and not self.mag.ready:
            loaded = MagCalibrator.from_state(compass)  # the same sensor's hard-iron calibration
            if loaded.ready:
                # used until this session's own fit is ready (_fit_compass), once re-anchored to this session's
                # frame (its field azimuth is in the earlier session's) and its gate checked against this place
                self.own_mag = self.mag if self.own_mag is None else self.own_mag
                if self.own_mag.n_swing == 0:
                    # the swings' field magnitudes tell the sensor's hard and soft iron whatever the session's frame,
                    # place or tilt offset: this session's own fit starts with them (its stances are its own)
                    self.own_mag.add_swing(np.asarray(loaded.swing_samples()))
                loaded.start_session()  # its axis alignment holds another power-on's accelerometer tilt offset
                self._use_compass(loaded, loaded=True)
        kf = self.kf2[b]
        if math.isfinite(deviation_rad) and math.isfinite(deviation_var) and deviation_var > 0:
            kf.x = np.array([0.0, wrap_angle(float(deviation_rad))])
            kf.p = np.diag([kf.p0_rate**2, float(deviation_var)])
            kf.n_updates = max(kf.n_updates, _BOOT_STEPS)

    # ------------------------------------------------------------------ dead reckoning
    @property
    def active(self) -> bool:
        return self.dr is not None

    def start(self, position: np.ndarray, heading: float) -> None:
        """(Re)start Gait-DR at a ZUPT-KF stance: NED position [m], sensor heading [rad]."""
        self.dr = GaitDeadReckoner(position, compensate=not self.conventional)
        self.heading = float(heading)
        self.follower.restart(self._h_ref() if self.mag.ready else math.nan)  # turns are counted from here on
        self._held = []  # a missed turn is looked for within one Gait-DR run

    def reckon(self, before_s: float, label_at: Callable[[float], str],
               weak_h: float = 0.0) -> list[tuple[PdrStep, StepEvent, str]]:
        """Dead-reckon the queued step events with onset before ``before_s`` [s] (dropped when not active).
        ``weak_h``: a disturbed stance field whose horizontal part is below this fraction of the Earth's turns
        nothing (:meth:`models.compass.CompassFollower.step`'s ``weak``).

        Returns ``(step, event, heading source)`` with source ``"compass"`` (the field passed the disturbance
        test), ``"disturbed"`` (it failed) or ``"none"`` (no calibrated field in this session's frame at that
        stance: the last heading is held). How the compass moves the heading:
        :meth:`models.compass.CompassFollower.step`.
        """
        out: list[tuple[PdrStep, StepEvent, str]] = []
        todo = [e for e in self.queue if e.t_s < before_s]
        self.queue = [e for e in self.queue if e.t_s >= before_s]
        if self.dr is None:
            return out
        for e in todo:
            b = model_behaviour(label_at(e.t_s))
            d, _ = self.step_length(e, b)
            self._note_cadence(e, b)
            m = self.mag_at(e)
            acc_st = self.acc_at(e)
            source = "none"
            if m is not None and self.mag.ready:
                if not self.mag_placed:
                    self._check_place(acc_st, m)
                clean = not self.mag.disturbed(acc_st, m)
                if clean and self.mag_placed and self._observe_dip(acc_st, m):
                    self._reanchor()
                if not self.mag_anchored and clean:
                    self._anchor_compass(self.heading, acc_st, m)
                if self.mag_anchored:
                    source = "compass" if clean else "disturbed"
            direction = before = self.heading
            if source == "none":
                self.held_steps += 1  # no calibrated field in this session's frame: hold the last heading
                self.follower.forget()
                self._held = []
            else:
                shape = self.mag.field_shape(acc_st, m)
                compass = self.mag.heading(acc_st, m)
                led = self.follower.established
                self.heading = self.follower.step(self.heading, compass, source == "compass",
                                                  *shape, self.mag.trusted, self._compass_sigma(),
                                                  self._settled(shape), self._h_ref(), self._weak(shape, weak_h))
                self._missed_turn(e.t_s, compass, before, led)
                self.compass_steps += 1
                direction = self.heading
                if self.mag.trusted:
                    # a trusted compass's change from stance to stance is the foot turning during the swing:
                    # the stride's chord lies half-way (the heading KF II's deviation is measured against, learn).
                    # An untrusted one's change is mostly its own scatter being averaged (gdin --mode pdr with
                    # the half-way heading there: stride median 1.015 -> 1.082 m)
                    direction = before + 0.5 * wrap_angle(self.heading - before)
            out.append((self.dr.step(e.t_s, max(d, 0.0), direction, self.deviation(b), b), e, source))
        return out

    def _missed_turn(self, t_s: float, compass: float, before: float, led: bool) -> None:
        """Tell a turn missed inside a disturbance when the absolute compass leads again (:attr:`missed_turn`).

        While the compass does not lead (the follower is not ``established``), the heading is held and turns are
        taken only from compass changes that look like the foot's; a turn whose strides the field's own drift
        hid is missed, and the compass takes it whole (beyond ``turn``) at the first stance where it leads
        again, seconds and metres later. Where that jump is what the compass's disagreement with the heading grew
        by over the held stretch (within a third of it, at least 10 deg), the turn happened inside it: from the
        first held stance whose disagreement had grown by half the jump (held-out random day, seed 5, 124-128 s:
        a 45-deg turn in steel whose dip drifted by 2-5 deg a stride; the compass took it at 140 s, and the walk
        between stayed 46 deg off). A disagreement that was there when the compass stopped leading (steel
        already deflecting it) is no turn of this stretch. Kept for a trusted compass only, the first stance and the
        latest ``_HELD_MAX`` - 1 (the engine keeps the last ``_DR_LOG`` strides to re-place)."""
        jump = wrap_angle(self.heading - before)
        held = self._held
        if self.mag.trusted and not led and self.follower.established and abs(jump) > self.follower.turn and len(held) >= 2:
            grown = wrap_angle(wrap_angle(compass - before) - held[0][1])
            if abs(wrap_angle(grown - jump)) <= max(math.radians(10.0), abs(jump) / 3.0):
                self.missed_turn = next(((t_k, jump) for t_k, nu_k in held
                                         if wrap_angle(nu_k - held[0][1]) * math.copysign(1.0, jump) >= 0.5 * abs(jump)),
                                        None)
        if self.follower.established or not self.mag.trusted:
            self._held = []
            return
        held.append((float(t_s), wrap_angle(compass - self.heading)))
        if len(held) > _HELD_MAX:  # the first (the reference) and the latest: only those strides can be re-placed
            del held[1 : len(held) - _HELD_MAX + 1]

    def _h_ref(self) -> float:
        """Horizontal magnitude [uT] of the field the compass is calibrated to (m_n's)."""
        norm, dip = self.mag.field_reference()
        return norm * math.cos(dip)

    def _compass_sigma(self) -> float:
        """Noise [rad] of one compass reading: the robust scale of its disagreement with the ZUPT-KF on the
        calibration stances (its RMS, or the trust limit, where that is unknown)."""
        cal = self.mag
        for s in (cal.heading_scale, cal.heading_rms, cal.max_heading_rms):
            if math.isfinite(s):
                return float(s)
        return math.nan

    def turn_to(self, t_start_s: float) -> tuple[float, float] | None:
        """Turn of the foot [rad] by the compass from the last Gait-DR stance to the step event of the stance
        starting at ``t_start_s`` [s], and its standard deviation [rad]; None where the compass cannot tell.

        Only by :class:`models.compass.CompassFollower`'s rules for letting the absolute compass lead: a
        trusted calibration in this session's frame, an established clean field before and a clean field at the
        event (or a disturbed field whose horizontal part is at least ``strong_h`` of the Earth's), and the same
        field magnitude and dip at both stances (the foot rotated, the field did not; :meth:`CompassFollower.
        turn_since`). A
        change, not the absolute compass: inside steel the gated compass erred by up to 45 deg on such stances
        (synthetic mixed day, seed 4), its change from one stance to the next by under 8 deg. The standard
        deviation is that of a difference of two readings, each with the compass's RMS disagreement with the
        ZUPT-KF on its calibration stances.
        """
        cal = self.mag
        if not (cal.ready and cal.trusted and self.mag_anchored):
            return None
        near = [q for q in self.queue if abs(q.t_s - t_start_s) <= PAIR_TOL_S]
        if not near:
            return None
        e = min(near, key=lambda q: abs(q.t_s - t_start_s))
        m = self.mag_at(e)
        acc = self.acc_at(e)
        if m is None:
            return None
        shape = cal.field_shape(acc, m)
        clean = self.follower.established and not cal.disturbed(acc, m)
        # or steel whose horizontal field is strong: a few uT of change turn it by a few degrees (held-out random
        # day, seed 2, 503 s: 45 of a 90-deg turn made before the gyroscope came were lost in a 46-uT field)
        if not clean and not self.follower.strong(*shape, self._h_ref()):
            return None
        turn = self.follower.turn_since(cal.heading(acc, m), *shape)
        if turn is None:
            return None
        sigma = cal.heading_rms if math.isfinite(cal.heading_rms) else cal.max_heading_rms
        return turn, math.sqrt(2.0) * sigma

    def earth_compass(self, e: StepEvent) -> float | None:
        """Heading [rad] a trusted compass reads at a step's stance where its field is the Earth's (passes the
        gate and is :meth:`_settled`) and steady since the previous stance (the follower's, within its
        ``steady_tol``: not the edge of a disturbance); None anywhere else or without such a compass in this
        session's frame."""
        cal = self.mag
        if not (self.has_mag and cal.ready and cal.trusted and self.mag_anchored):
            return None
        m = self.mag_at(e)
        if m is None:
            return None
        acc = self.acc_at(e)
        if cal.disturbed(acc, m):
            return None
        shape = cal.field_shape(acc, m)
        prev = self.follower.prev
        if not self._settled(shape) or prev is None or abs(shape[0] - prev[1]) > self.follower.steady_tol * max(prev[1], 1e-9):
            return None
        return cal.heading(acc, m)

    def weak_wake(self, frac: float) -> tuple[float, tuple[float, ...], tuple[float, ...]] | None:
        """What a device needs to wake its gyroscope itself where the field's horizontal part drops below ``frac``
        of the Earth's (``SensorConfig.wake_mode == "weak_field"``): the threshold [uT] and the trusted compass's
        calibration, hard-iron offset b [uT] and soft-iron matrix W (row-major; calibrated field = W (m - b));
        None without a trusted compass or with ``frac`` 0."""
        cal = self.mag
        if not (frac > 0 and self.has_mag and cal.ready and cal.trusted):
            return None
        return (frac * self._h_ref(), tuple(cal.b.tolist()), tuple(np.asarray(cal.w).reshape(9).tolist()))

    def field_weak(self, e: StepEvent, frac: float) -> bool:
        """The horizontal part of the field at a step's stance is below ``frac`` of the Earth's (m_n's, the
        compass's reference): False without a trusted compass anchored in this session's frame."""
        m = self.mag_at(e)
        if m is None or not self.mag.ready or not self.mag.trusted or not self.mag_anchored:
            return False
        return self._weak(self.mag.field_shape(self.acc_at(e), m), frac)

    def _weak(self, shape: tuple[float, float], frac: float) -> bool:
        """A field of magnitude [uT] and dip [rad] ``shape`` whose horizontal part is below ``frac`` of m_n's."""
        return shape[0] * math.cos(shape[1]) < frac * self._h_ref()

    def field_clean(self, e: StepEvent) -> bool:
        """The field at a step's stance passes the disturbance test (False without a calibrated compass)."""
        m = self.mag_at(e)
        return m is not None and self.mag.ready and not self.mag.disturbed(self.acc_at(e), m)

    # ------------------------------------------------------------------ state
    def get_state(self) -> dict[str, Any]:
        return {
            "rate_hz": self.rate_hz,
            "conventional": self.conventional,
            "low": self._low.get_state(),
            "seg": self._seg.get_state(),
            "cal": self.cal.get_state(),
            "kf2": {b: k.get_state() for b, k in self.kf2.items()},
            "mag": self.mag.get_state(),
            "dr": None if self.dr is None else self.dr.get_state(),
            "queue": [e.to_row() for e in self.queue],
            "mag_t": self._mag_t, "mag_v": self._mag_v, "mag_a": self._mag_a,
            "stance_mag": [[k, None if v is None else np.asarray(v)] for k, v in self.stance_mag.items()],
            "stance_acc": [[k, np.asarray(v)] for k, v in self.stance_acc.items()],
            "stance_swing": [[k, np.asarray(v)] for k, v in self.stance_swing.items()],
            "stride_peak": [[k, v] for k, v in self.stride_peak.items()], "walk_peaks": list(self.walk_peaks),
            "window_end": self._window_end, "cal_last": self._cal_last,
            "heading": self.heading, "t_in": self.t_in, "mag_fit_n": self._mag_fit_n, "has_mag": self.has_mag, "recent_d": {b: list(v) for b, v in self.recent_d.items()},
            "recent_scale": {b: list(v) for b, v in self.recent_scale.items()},
            "recent_f": {b: list(v) for b, v in self.recent_f.items()},
            "compass_steps": self.compass_steps, "held_steps": self.held_steps,
            "held": [list(h) for h in self._held],
            "prev_stance": list(self._prev_stance),
            "mag_anchored": self.mag_anchored, "anchor_rows": [list(r) for r in self._anchor_rows],
            "follower": self.follower.get_state(),
            "own_mag": None if self.own_mag is None else self.own_mag.get_state(),
            "mag_placed": self.mag_placed, "place": [list(p) for p in self._place],
        }

    @classmethod
    def from_state(cls, d: dict[str, Any]) -> GaitPipeline:
        obj = cls(d["rate_hz"], bool(d.get("conventional", False)))
        obj._low = _LowRate.from_state(d["low"])
        obj._seg = StepSegmenter.from_state(d["seg"])
        obj.cal = StepLengthCalibrator.from_state(d["cal"])
        obj._generic = StepLengthCalibrator(obj.cal.model)
        obj.kf2 = {b: HeadingDeviationKF.from_state(k) for b, k in d["kf2"].items()}
        obj.mag = MagCalibrator.from_state(d["mag"])
        obj.dr = None if d["dr"] is None else GaitDeadReckoner.from_state(d["dr"])
        obj.queue = [StepEvent.from_row(q) for q in d["queue"]]
        obj._mag_t = np.asarray(d["mag_t"], dtype=float)
        obj._mag_v = np.asarray(d["mag_v"], dtype=float).reshape(-1, 3)
        # states stored before the tilt was taken from the field's own samples: no specific force kept (NaN rows,
        # never inside a new stance's window once 2 s have passed) and the events' own tilt for queued stances
        obj._mag_a = np.asarray(d.get("mag_a", np.full((obj._mag_t.size, 3), np.nan)), dtype=float).reshape(-1, 3)
        obj.stance_mag = {int(k): (None if v is None else np.asarray(v, dtype=float)) for k, v in d["stance_mag"]}
        obj.stance_acc = {int(k): np.asarray(v, dtype=float) for k, v in d.get("stance_acc", [])}
        obj.stance_swing = {int(k): np.asarray(v, dtype=float).reshape(-1, 3) for k, v in d.get("stance_swing", [])}
        obj.stride_peak = {int(k): float(v) for k, v in d.get("stride_peak", [])}  # older states: none
        obj.walk_peaks = [float(x) for x in d.get("walk_peaks", [])]
        obj._window_end = float(d.get("window_end", -math.inf))
        obj._cal_last = int(d.get("cal_last", -1))
        obj.heading, obj.t_in, obj.has_mag = float(d["heading"]), float(d["t_in"]), bool(d["has_mag"])
        obj._mag_fit_n = int(d["mag_fit_n"])
        obj.recent_d = {b: [float(x) for x in v] for b, v in d["recent_d"].items()}
        scales = d.get("recent_scale", {b: [] for b in _BEHAVIOURS})  # states stored before it existed: none
        obj.recent_scale = {b: [float(x) for x in v] for b, v in scales.items()}
        cadences = d.get("recent_f", {b: [] for b in _BEHAVIOURS})  # states stored before it existed: none
        obj.recent_f = {b: [float(x) for x in v] for b, v in cadences.items()}
        obj.compass_steps, obj.held_steps = int(d["compass_steps"]), int(d["held_steps"])
        obj._held = [(float(t), float(nu)) for t, nu in d.get("held", [])]  # older states: none
        ps = d.get("prev_stance", [-math.inf, math.nan])  # states stored before the turn gate existed
        obj._prev_stance = (float(ps[0]), float(ps[1]))
        obj.mag_anchored = bool(d.get("mag_anchored", True))  # states stored before the re-anchoring existed
        # states stored before the anchor stances were kept (only the offsets while anchoring): none, so a compass
        # not anchored yet starts its anchoring again and an anchored one is not read again
        obj._anchor_rows = [[float(x) for x in r] for r in d.get("anchor_rows", [])]
        if "follower" in d:
            obj.follower = CompassFollower.from_state(d["follower"])
        own = d.get("own_mag")  # states stored before the session's own fit was kept apart: none
        obj.own_mag = None if own is None else MagCalibrator.from_state(own)
        obj.mag_placed = bool(d.get("mag_placed", True))
        obj._place = [(float(p[0]), float(p[1])) for p in d.get("place", [])]
        return obj
