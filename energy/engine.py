"""The streaming engine: one object per (user, device) session (DESIGN.md, "The engine contract").

``Engine.feed(batch)`` pairs the sensor streams on the accelerometer's time axis, recognises behaviour, and
navigates: where gyroscope samples arrived the ZUPT-aided MARG Kalman filter, elsewhere calibrated gait dead
reckoning (004 Sections 2, 4); the two hand over at stances. One heading estimator
(:class:`models.heading.HeadingEstimator`, inside :class:`energy.gait_dr.GaitPipeline`) follows the heading
through both, stride by stride, with its uncertainty; the scheduler (:mod:`energy.scheduler`) decides from it
and from 004 Tables 1-3 which sensors the device should use next. The complete state serialises to bytes
(:meth:`Engine.to_bytes`) through the safe codec of :mod:`energy.codec`. ``docs/engine.md`` has the design.
"""

from __future__ import annotations

import logging
import math
from bisect import bisect_right
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
from numba import njit

from energy import codec
from energy.config import EngineConfig
from energy.gait_dr import PAIR_TOL_S, GaitPipeline, model_behaviour
from energy.profile import BehaviourCalibration, Profile
from energy.scheduler import Scheduler
from energy.types import Event, Position, SensorConfig, Update
from models.attitude import align_at_rest
from models.batch import BatchError, SensorBatch
from models.behaviour import BehaviourRecognizer
from models.detectors import first_still_run
from models.heading_deviation import HeadingDeviationKF, wrap_angle
from models.rotations import dcm_heading, dcm_to_quat, euler_to_dcm
from models.steps import StepEvent
from models.strapdown import integrate
from models.zupt_nav import NavOutput, Stance, ZuptNavigator

log = logging.getLogger(__name__)

__all__ = ["Engine", "EngineConfig", "EngineMode", "Trace"]  # EngineConfig re-exported from energy.config

EngineMode = Literal["zupt", "pdr", "auto"]
_MODES: tuple[str, ...] = ("zupt", "pdr", "auto")
_STATE_VERSION = 3
_LABEL_KEEP_S = 60.0  # behaviour decisions kept behind the newest sample (>> any detector look-ahead)
_FIRST_SLICE = 50  # samples per ZUPT-KF call before a segment's hand-over stance sets its turn
_DR_LOG = 24  # Gait-DR strides kept for a walking pattern's correction (Engine._correct_pattern)
_NORTH_STEP = math.radians(1.0)  # a change of magnetic north's azimuth in the session frame announced again


def _heading_test(z: float, kf: HeadingDeviationKF, sigmas: float) -> dict[str, Any]:
    """Direction examination: does a stride's ``z = gamma - psi`` [rad] (004 eq. 19-20) fit the deviation
    ``kf`` held before it within ``sigmas`` of KF II's innovation standard deviation (the deviation's
    variance plus the per-stride spread R^II)? Backward or sideways walking, a re-mounted sensor move gamma -
    psi far beyond it."""
    sigma = math.sqrt(kf.variance + kf.r_var)
    nu = wrap_angle(z - kf.deviation)
    return {"passed": abs(nu) <= sigmas * sigma, "gamma_psi_rad": float(z), "deviation_rad": kf.deviation,
            "sigma_rad": sigma}


@dataclass
class Trace:
    """Per processed accelerometer sample (and per Gait-DR step) output, kept only with ``trace=True``.

    Attributes
    ----------
    t_ns : ndarray of int64, shape (n,)
    pos : ndarray, shape (n, 3)
        NED position [m].
    behaviour : ndarray of str, shape (n,)
    mode : ndarray of str, shape (n,)
        ``zupt`` (ZUPT-KF sample), ``pdr`` (gyroscope off, Gait-DR) or ``idle`` (standing, gyroscope off).
    gyro_on : ndarray of bool, shape (n,)
        Whether a gyroscope sample was paired with the accelerometer sample.
    """

    _t: list[np.ndarray] = field(default_factory=list)
    _pos: list[np.ndarray] = field(default_factory=list)
    _beh: list[np.ndarray] = field(default_factory=list)
    _mode: list[np.ndarray] = field(default_factory=list)
    _gyro: list[np.ndarray] = field(default_factory=list)

    def append(self, t_ns: np.ndarray, pos: np.ndarray, behaviour: np.ndarray, mode: np.ndarray, gyro_on: np.ndarray) -> None:
        if len(t_ns):
            self._t.append(t_ns)
            self._pos.append(pos)
            self._beh.append(behaviour)
            self._mode.append(mode)
            self._gyro.append(gyro_on)

    def _cat(self, parts: list[np.ndarray], empty: np.ndarray) -> np.ndarray:
        if not parts:
            return empty
        return np.concatenate(parts)[self._order()]

    def _order(self) -> np.ndarray:
        """Rows are appended as each pipeline finalises them; read out in time order."""
        return np.argsort(np.concatenate(self._t), kind="stable")

    @property
    def t_ns(self) -> np.ndarray:
        return self._cat(self._t, np.zeros(0, dtype=np.int64))

    @property
    def pos(self) -> np.ndarray:
        """NED position [m]; rows without a position of their own (gyroscope off, before the first stance of a
        ZUPT-KF segment) hold the last known one."""
        p = self._cat(self._pos, np.zeros((0, 3)))
        ok = ~np.isnan(p[:, 0])
        idx = np.where(ok, np.arange(len(p)), -1)
        np.maximum.accumulate(idx, out=idx)
        out = np.zeros_like(p)
        out[idx >= 0] = p[idx[idx >= 0]]
        return out

    @property
    def behaviour(self) -> np.ndarray:
        return self._cat(self._beh, np.zeros(0, dtype="<U5"))

    @property
    def mode(self) -> np.ndarray:
        return self._cat(self._mode, np.zeros(0, dtype="<U4"))

    @property
    def gyro_on(self) -> np.ndarray:
        return self._cat(self._gyro, np.zeros(0, dtype=bool))


def _samples_op(parts: tuple, sl: slice) -> tuple:
    """A ``("samples", t, acc, gyr, mag)`` queue entry of the rows ``sl`` of ``parts = (t, acc, gyr, mag)``
    (``mag`` may be None)."""
    t, acc, gyr, mag = parts
    return ("samples", t[sl], acc[sl], gyr[sl], None if mag is None else mag[sl])


@njit(cache=True)
def _zoh_pair(ts: np.ndarray, vs: np.ndarray, t_acc: np.ndarray, max_age_ns: int) -> tuple[np.ndarray, int]:
    """Causal zero-order hold of ``(ts, vs)`` at the increasing times ``t_acc`` [ns] in one merge pass: rows
    with no sample at most ``max_age_ns`` old are NaN. Also returns the index of the last sample at or before
    ``t_acc[-1]`` (0 when none). Same as ``searchsorted(ts, t_acc, "right") - 1`` per row."""
    out = np.full((t_acc.size, 3), np.nan)
    j = -1
    for i in range(t_acc.size):
        while j + 1 < ts.size and ts[j + 1] <= t_acc[i]:
            j += 1
        if j >= 0 and t_acc[i] - ts[j] <= max_age_ns:
            out[i, 0] = vs[j, 0]
            out[i, 1] = vs[j, 1]
            out[i, 2] = vs[j, 2]
    return out, max(j, 0)


@njit(cache=True)
def _gyro_rows(t_s: np.ndarray, g0: np.ndarray, m0: np.ndarray, missing: bool, last_s: float, gap_s: float,
               off_s: float) -> tuple[np.ndarray, int, int]:
    """The gyroscope rows of a paired chunk and where ZUPT-KF segments break (:meth:`Engine._ingest`'s array
    steps in one compiled pass, the same comparisons).

    ``t_s`` [s] the rows' times (``n`` of them), ``g0``/``m0`` the first gyroscope/magnetometer axis (NaN: no
    sample), ``missing`` the previous chunk ended without a gyroscope sample, ``last_s`` [s] the last gyroscope
    row's time. Returns ``(out, m, ng)``, three results in one array (one array to hand back instead of three):
    ``out[:m]`` the rows with a gyroscope sample (``idx``), ``out[n:n + ng]`` the positions in ``idx`` that
    start a new segment (the interval before the row exceeds ``gap_s`` [s], or ``off_s`` [s] after accelerometer
    rows without a gyroscope sample) and ``out[2 n:2 n + m + 1]`` how many of ``idx[:k]`` have a magnetometer
    sample, ``k = 0 .. m``."""
    n = t_s.shape[0]
    out = np.empty(3 * n + 1, dtype=np.int64)
    m = 0
    for i in range(n):
        if not np.isnan(g0[i]):
            out[m] = i
            m += 1
    ng = 0
    out[2 * n] = 0
    for k in range(m):
        i = out[k]
        if k == 0:
            off = missing or i > 0
            dt = t_s[i] - last_s
        else:
            off = i - out[k - 1] > 1
            dt = t_s[i] - t_s[out[k - 1]]
        if dt > gap_s or (off and dt > off_s):
            out[n + ng] = k
            ng += 1
        out[2 * n + k + 1] = out[2 * n + k] + (0 if np.isnan(m0[i]) else 1)
    return out, m, ng


class _StreamPairing:
    """Pairs gyroscope/magnetometer samples with accelerometer samples by causal zero-order hold.

    For an accelerometer sample at ``t`` the paired value is the latest sample of the stream at or before ``t``,
    if it is at most ``max_age_ns`` old; otherwise the row is NaN (stream off or gap). The engine pairs a sample
    only once every stream is complete up to it (:meth:`complete_until`; devices deliver each stream with its
    own lag), so the pairing does not depend on where the batches were cut.
    """

    def __init__(self, max_age_ns: int) -> None:
        self.max_age_ns = int(max_age_ns)
        self.t = np.zeros(0, dtype=np.int64)
        self.v = np.zeros((0, 3))
        self.newest: int | None = None  # newest sample time received [ns]

    def push(self, t: np.ndarray, v: np.ndarray) -> None:
        if len(t):
            self.newest = int(t[-1]) if self.newest is None else max(self.newest, int(t[-1]))
            if len(self.t) and t[0] <= self.t[-1]:
                keep = t > self.t[-1]
                t, v = t[keep], v[keep]
            self.t = np.concatenate([self.t, t])
            self.v = np.concatenate([self.v, v])

    def pair(self, t_acc: np.ndarray) -> np.ndarray:
        if len(self.t) == 0 or len(t_acc) == 0:
            return np.full((len(t_acc), 3), np.nan)
        out, last = _zoh_pair(self.t, self.v, t_acc, self.max_age_ns)
        # keep the last sample at or before the newest accelerometer sample, and everything after it
        self.t, self.v = self.t[last:], self.v[last:]
        return out

    def complete_until(self, newest_acc_ns: int, wait_ns: int) -> int:
        """Accelerometer samples up to this time [ns] can be paired for good: the stream has reached them, or
        it has been silent for ``wait_ns`` behind the accelerometer (off, or a gap)."""
        reached = self.newest if self.newest is not None else np.iinfo(np.int64).min
        return max(reached, newest_acc_ns - wait_ns)

    def get_state(self) -> dict[str, Any]:
        return {"max_age_ns": self.max_age_ns, "t": self.t, "v": self.v, "newest": self.newest}

    @classmethod
    def from_state(cls, d: dict[str, Any]) -> _StreamPairing:
        obj = cls(d["max_age_ns"])
        obj.t = np.asarray(d["t"], dtype=np.int64)
        obj.v = np.asarray(d["v"], dtype=np.float64).reshape(-1, 3)
        obj.newest = None if d["newest"] is None else int(d["newest"])
        return obj


class _LabelHistory:
    """Recent behaviour decisions, to label samples and stances by the decision in force at their time."""

    def __init__(self) -> None:
        self.t: list[float] = []
        self.labels: list[str] = []

    def add(self, t_s: float, label: str) -> None:
        if self.labels and self.labels[-1] == label:
            return  # a repeated decision changes nothing the lookups return
        self.t.append(float(t_s))
        self.labels.append(label)

    def prune(self, before_s: float) -> None:
        """Forget decisions superseded before ``before_s`` (keeps the one in force then)."""
        cut = bisect_right(self.t, before_s) - 1  # the times increase: searchsorted(t, before_s, "right") - 1
        if cut > 0:
            del self.t[:cut], self.labels[:cut]

    def at(self, t_s: float) -> str:
        i = bisect_right(self.t, t_s) - 1
        return self.labels[i] if i >= 0 else "stand"

    def at_many(self, t_s: np.ndarray) -> np.ndarray:
        if not self.t:
            return np.full(len(t_s), "stand")
        i = np.searchsorted(np.asarray(self.t), t_s, side="right") - 1
        lab = np.asarray(self.labels + ["stand"])
        return lab[np.where(i >= 0, i, len(self.labels))]

    def get_state(self) -> dict[str, Any]:
        return {"t": list(self.t), "labels": list(self.labels)}

    @classmethod
    def from_state(cls, d: dict[str, Any]) -> _LabelHistory:
        obj = cls()
        obj.t, obj.labels = [float(x) for x in d["t"]], [str(x) for x in d["labels"]]
        return obj


def _stance_row(st: Stance) -> list[float]:
    return [st.t_start_s, st.t_end_s, *map(float, st.position), st.heading, *map(float, st.delta), st.peak_speed,
            float(st.samples), float(st.mag_used)]


def _stance_from_row(r: list[float]) -> Stance:
    return Stance(float(r[0]), float(r[1]), np.asarray(r[2:5], dtype=float), float(r[5]), np.asarray(r[6:9], dtype=float),
                  float(r[9]), int(r[10]), bool(r[11]))


class Engine:
    """One navigation session: feed batches, get positions, events and the next sensor configuration.

    Where the gyroscope is on, the ZUPT-KF navigates; where it is off, Gait-DR does. Each ZUPT-KF segment
    (a run of gyroscope samples) takes over at its first stance from where Gait-DR had put the foot, turned to
    the heading estimator's heading there, and Gait-DR restarts from the segment's last stance. The scheduler
    decides which sensors the device should use; the engine follows whatever data actually arrive. Both halves
    are worked through in data-time order, waiting where needed for the step segmentation's look-ahead
    (:attr:`energy.gait_dr.GaitPipeline.horizon`), so the output does not depend on how batches are cut.

    Parameters
    ----------
    mode : {"zupt", "pdr", "auto"}
        ``zupt``: ZUPT-KF all the time at the full rate. ``pdr``: the 004 scheme, ZUPT-KF for the first L0
        metres, then calibrated Gait-DR with the gyroscope off (refused without a magnetometer). ``auto``: the
        full energy-aware scheduler.
    config : EngineConfig, optional
    profile : dict, optional
        Per-user calibration profile (:mod:`energy.profile`); a calibrated behaviour skips the initialisation.
    trace : bool
        Keep per-sample output in :attr:`trace` (evaluation, plots). Not part of the serialised state.
    """

    def __init__(self, mode: EngineMode = "auto", config: EngineConfig | None = None,
                 profile: dict[str, Any] | None = None, trace: bool = False) -> None:
        if mode not in _MODES:
            raise ValueError(f"mode: expected one of {_MODES}, got {mode!r}")
        self.mode: EngineMode = mode
        self.config = config or EngineConfig.default()
        self.trace = Trace() if trace else None
        self._t0_ns: int | None = None
        self._last_acc_t: int | None = None
        max_age = int(self.config.rates.max_sample_age_s * 1e9)
        self._acc_t = np.zeros(0, dtype=np.int64)  # accelerometer samples waiting for the other streams
        self._acc_v = np.zeros((0, 3))
        self._gyr = _StreamPairing(max_age)
        self._mag = _StreamPairing(max_age)
        prof = Profile.from_dict(profile) if profile else Profile()
        self._sched = Scheduler(mode, self.config, prof)
        self._nav = ZuptNavigator(self.config.zupt)
        self._behaviour = BehaviourRecognizer()
        self._labels = _LabelHistory()
        self._gait = GaitPipeline(self.config) if mode != "zupt" else None
        if self._gait is not None:
            for b, cal in prof.behaviours.items():
                if cal.calibrated:
                    self._gait.load_calibration(b, cal.step_model, cal.heading_deviation_rad, cal.heading_deviation_var)
            # only a deviation KF II took from the profile is there to be tested
            self._sched.deviation_pending = {b for b in self._sched.deviation_pending if self._gait.kf2[b].n_updates}
        # ZUPT-KF segments: ingest side
        self._last_gyr_s = -math.inf
        self._gyro_missing = False  # accelerometer rows without gyroscope since the last gyroscope sample
        self._seg_open = False
        # work queue in data-time order: ("start", t) | ("samples", t, acc, gyr, mag) | ("stance", Stance)
        # | ("trace", t, pos) | ("end",) | ("handover",)
        self._ops: list[tuple] = []
        # processing side
        self._in_seg = False
        self._seg_t = -math.inf  # start of the current segment [s]
        self._seg_first = True  # the segment's first stance (the hand-over stance) is still to come
        self._offset = np.zeros(3)  # ZUPT-KF frame of this segment -> session frame [m] (after _yaw)
        self._yaw = 0.0  # ... and its turn about the vertical [rad]: estimator heading - ZUPT-KF heading
        self._pos: np.ndarray | None = None  # last output position [m NED]
        self._head = math.nan  # sensor heading at the last output [rad]
        self._zupt_head = math.nan  # session-frame heading of the last ZUPT-KF stance [rad]
        self._out_mode = ""  # mode of the last output position ("" before the first)
        self._north = math.nan  # magnetic north's azimuth in the session frame as last announced [rad]
        self._nav_t = -math.inf  # last sample the ZUPT-KF has output [s]
        self._await_rest = False  # a restarting segment waits for a still foot
        self._pre: tuple | None = None  # its candidate still samples (t, acc, gyr, mag)
        self._pre_rot = np.zeros(3)  # sum of gyro rate x interval over the segment's samples before it [rad]
        self._pre_t = math.nan  # time of the last sample summed into _pre_rot [s]
        # a segment the device started on its own (wake-on-motion) from a still foot: its samples before the
        # first stance are integrated back from that stance to place the first, partial stride
        self._moved = False  # Gait-DR placed a step since the last ZUPT-KF segment ended
        self._step_s = -math.inf  # time of Gait-DR's latest step [s]
        self._lead: tuple | None = None  # collected samples (t, acc, gyr) of such a segment before its stance
        self._lead_d: np.ndarray | None = None  # their displacement, segment start -> still foot [m NED]
        self._rest_p = np.zeros(3)  # the ZUPT-KF's position at a segment's still foot (its frame) [m NED]
        self._rest_t = math.nan  # ... its time [s]
        self._rest_head = math.nan  # ... and the heading it restarted with [rad]
        # behaviour decisions reach the scheduler in data-time order with the stances and steps
        self._labels_pending: list[tuple[float, str]] = []
        # the latest Gait-DR strides: [behaviour, step event row, length [m], unit direction north, east]
        self._dr_log: list[list[Any]] = []
        # (behaviour, time [s] of its first stride) of a walking pattern the ZUPT-KF is initialising
        self._pattern: tuple[str, float] | None = None

    # ------------------------------------------------------------------ contract
    @property
    def sensor_config(self) -> SensorConfig:
        """The configuration the device must use for its next batch."""
        return self._sched.sensor_config()

    def profile_dict(self) -> dict[str, Any]:
        """The (possibly updated) per-user calibration profile, JSON-serialisable. The compass calibration
        belongs to the sensor, not to a behaviour: every calibrated behaviour hands on the one in use now."""
        d = self._sched.profile.to_dict()
        compass = self._gait.compass_state() if self._gait is not None else None
        if compass is not None:
            for cal in d["behaviours"].values():
                if cal.get("calibrated") and isinstance(cal.get("step_model"), dict):
                    cal["step_model"]["compass"] = compass
        return d

    @property
    def heading_std_rad(self) -> float:
        """Standard deviation [rad] of the heading estimator's current heading (NaN in mode ``zupt``)."""
        gait = self._gait
        return gait.est.std if gait is not None and gait.est.started else math.nan

    def feed(self, batch: SensorBatch) -> Update:
        """Consume one batch; see the module docstring.

        Raises
        ------
        models.batch.BatchError
            Malformed batch (non-finite values, timestamps not increasing, implausible units, or samples of a
            stream not after the last one of it already received).
        """
        batch.validate()
        t_acc, acc = batch.acc_t_ns, batch.acc
        # a gyroscope the device woke by itself (wake-on-motion) and still runs at the batch's end: the scheduler
        # leaves it to the device while the labels it decides on still say "stand"
        g_t, m_t = batch.gyr_t_ns, batch.mag_t_ns
        sched = self._sched
        sched.device_gyro_awake = bool(
            sched.gyro_wake_on_motion() and len(g_t) and len(t_acc)
            and int(g_t[-1]) >= int(t_acc[-1]) - int(self.config.segments.gyro_off_s * 1e9))
        if len(t_acc) and self._last_acc_t is not None and t_acc[0] <= self._last_acc_t:
            raise BatchError("acc_t_ns", f"sample at {int(t_acc[0])} ns is not after the last one processed ({self._last_acc_t} ns)")
        for name, t_s, pairing in (("gyr", g_t, self._gyr), ("mag", m_t, self._mag)):
            if len(t_s) and pairing.newest is not None and int(t_s[0]) <= pairing.newest:
                # a late sample cannot be paired any more: refused rather than dropped without a word
                raise BatchError(f"{name}_t_ns", f"sample at {int(t_s[0])} ns is not after the last one received "
                                                 f"({pairing.newest} ns)")
        self._gyr.push(g_t, batch.gyr)
        self._mag.push(m_t, batch.mag)
        if len(t_acc) == 0:
            return self._update([], [])
        if self._t0_ns is None:
            self._t0_ns = int(t_acc[0])
        self._last_acc_t = int(t_acc[-1])
        self._acc_t = np.concatenate([self._acc_t, t_acc])
        self._acc_v = np.concatenate([self._acc_v, acc])
        wait = int(self.config.rates.stream_wait_s * 1e9)
        limit = min(self._gyr.complete_until(self._last_acc_t, wait), self._mag.complete_until(self._last_acc_t, wait))
        return self._pair_and_process(int(self._acc_t.searchsorted(limit, side="right")), final=False)

    def flush(self) -> Update:
        """End of the session: process what the detectors' look-ahead still holds."""
        return self._pair_and_process(len(self._acc_t), final=True)

    # ------------------------------------------------------------------ processing
    def _pair_and_process(self, n: int, final: bool) -> Update:
        """Pair and process the first ``n`` waiting accelerometer samples."""
        t_acc, acc = self._acc_t[:n], self._acc_v[:n]
        self._acc_t, self._acc_v = self._acc_t[n:], self._acc_v[n:]
        if n == 0 and not final:
            return self._update([], [])
        return self._process(t_acc, acc, self._gyr.pair(t_acc), self._mag.pair(t_acc), final=final)

    # ------------------------------------------------------------------ processing
    def _ns(self, t_s: float) -> int:
        return (self._t0_ns or 0) + int(round(t_s * 1e9))

    def _ns_many(self, t_s: np.ndarray) -> np.ndarray:
        return (self._t0_ns or 0) + np.round(np.asarray(t_s) * 1e9).astype(np.int64)

    def _process(self, t_acc: np.ndarray, acc: np.ndarray, gyr: np.ndarray, mag: np.ndarray, final: bool) -> Update:
        events: list[Event] = []
        positions: list[Position] = []
        t0 = self._t0_ns if self._t0_ns is not None else 0
        t_s = (t_acc - t0) / 1e9
        for td, label in self._behaviour.process(t_s, acc):
            self._labels.add(td, label)
            self._labels_pending.append((td, label))
        if self._gait is not None and len(t_s):
            self._gait.feed(t_s, acc, mag)
            self._sched.has_mag = self._gait.has_mag
        if self._gait is not None and final:
            self._gait.flush()
        self._ingest(t_s, acc, gyr, mag, final)
        self._drain(final, positions, events)
        if len(t_s):
            self._labels.prune(float(t_s[-1]) - _LABEL_KEEP_S)
        return self._update(positions, events)

    def _ingest(self, t_s: np.ndarray, acc: np.ndarray, gyr: np.ndarray, mag: np.ndarray, final: bool) -> None:
        """Cut the gyroscope samples into ZUPT-KF segments and queue them."""
        sc = self.config.segments
        # the rows with a gyroscope sample and the segment breaks: accelerometer rows without a gyroscope sample
        # before a gyroscope row mean the gyroscope was off (a wake-on-motion device powers it down and up within
        # a fraction of a second); a data dropout loses the accelerometer too and splits only beyond gyro_gap_s
        rows, m_gyr, n_cuts = _gyro_rows(t_s, gyr[:, 0], mag[:, 0], bool(self._gyro_missing),
                                         float(self._last_gyr_s), sc.gyro_gap_s, sc.gyro_off_s)
        n = len(t_s)
        idx, cuts, mag_n = rows[:m_gyr], rows[n:n + n_cuts], rows[2 * n:2 * n + m_gyr + 1]
        if len(idx):
            every = len(idx) == len(t_s)
            ts = t_s if every else t_s[idx]
            gaps = cuts.tolist()
            for lo, hi in zip([0, *gaps], [*gaps, len(ts)]):
                if hi <= lo:
                    continue
                if lo in gaps or not self._seg_open:
                    if self._seg_open:
                        self._ops.append(("end",))
                    self._ops.append(("start", float(ts[lo])))
                    self._seg_open = True
                sel = slice(lo, hi) if every else idx[lo:hi]  # (a gyroscope sample on every row: views)
                m = mag[sel]
                self._ops.append(("samples", ts[lo:hi], acc[sel], gyr[sel], m if mag_n[hi] > mag_n[lo] else None))
            self._last_gyr_s = float(ts[-1])
            self._gyro_missing = bool(idx[-1] < len(t_s) - 1)
        elif len(t_s):
            self._gyro_missing = True
        if self._seg_open and (final or (len(t_s) and t_s[-1] - self._last_gyr_s > self.config.segments.gyro_gap_s)):
            self._ops.append(("end",))
            self._seg_open = False
        if self.trace is not None and len(idx) < len(t_s):
            has = ~np.isnan(gyr[:, 0])
            tt = t_s[~has]
            lab = self._labels.at_many(tt)
            self.trace.append(self._ns_many(tt), np.full((len(tt), 3), np.nan), lab,
                              np.where(lab == "stand", "idle", "pdr"), np.zeros(len(tt), dtype=bool))

    def _horizon(self, final: bool) -> float:
        return math.inf if (final or self._gait is None) else self._gait.horizon

    def _drain(self, final: bool, positions: list[Position], events: list[Event]) -> None:
        """Work through the queue as far as the step segmentation's look-ahead allows."""
        gait = self._gait
        horizon = self._horizon(final)
        while self._ops:
            op = self._ops[0]
            kind = op[0]
            if kind == "start" and not self._op_start(op[1], horizon, positions, events):
                break
            if kind == "samples" and self._await_rest:
                self._op_restart(op)
            elif kind == "samples":
                self._op_samples(op)
            elif kind == "end":
                self._ops[0:1] = self._nav_ops(self._nav.flush()) + [("handover",)]
            elif kind == "trace":
                self._trace_nav(op[1], op[2])
                self._ops.pop(0)
            elif kind == "stance":
                if horizon < op[1].t_start_s + PAIR_TOL_S:
                    break
                self._stance(op[1], positions, events)
                self._ops.pop(0)
            elif kind == "handover":
                self._op_handover()
        if gait is not None and not self._in_seg:
            limit = horizon
            if self._ops and self._ops[0][0] == "start":
                limit = min(limit, self._ops[0][1])
            self._reckon(limit, positions, events)
        self._apply_labels(self._processed_through(horizon), events)

    def _op_start(self, t_b: float, horizon: float, positions: list[Position], events: list[Event]) -> bool:
        """A segment starts at ``t_b`` [s]: Gait-DR's steps before it first (False: not yet final)."""
        gait, nav = self._gait, self._nav
        if gait is not None and gait.active:
            if horizon < t_b:
                return False
            self._reckon(t_b, positions, events)
            self._head = gait.est.heading
        self._apply_labels(t_b, events)
        self._seg_t = t_b
        self._await_rest = nav.initialised  # a restart waits for the foot to be still
        # a segment that starts while the person is (still) known to stand, with no step since the last segment or
        # none for longer than the device's inactivity time: the device woke the gyroscope on the first motion
        # (wake-on-motion); the host turns it on only for a behaviour it has recognised, i.e. mid-walk, where
        # Gait-DR places the first step
        own = (nav.initialised and self._labels.at(t_b) == "stand"
               and (not self._moved or t_b - self._step_s > self.config.scheduler.sleep_after_s))
        empty = np.zeros((0, 3))
        self._lead = (np.zeros(0), empty, empty) if own else None
        self._lead_d = None
        self._pre = None
        self._pre_rot, self._pre_t = np.zeros(3), math.nan
        self._in_seg, self._seg_first = True, True
        self._ops.pop(0)
        return True

    def _op_restart(self, op: tuple) -> None:
        """Samples of a restarting segment: look for the still foot the ZUPT-KF restarts on."""
        nav = self._nav
        rest = self._rest_start(op)
        self._ops.pop(0)
        if rest is None:
            return
        i, j = rest
        pre = self._pre
        assert pre is not None
        self._pre = None
        self._await_rest = False
        acc_rest = pre[1][i : j + 1].mean(axis=0)
        self._sum_rotation(pre[0][:i], pre[2][:i])
        heading = self._restart_heading(acc_rest)
        self._collect_lead(pre[0][: i + 1], pre[1][: i + 1], pre[2][: i + 1])
        self._lead_d = self._lead_displacement(acc_rest, heading)
        nav.restart(nav.position, heading, acc_rest)
        self._rest_p, self._rest_t, self._rest_head = nav.position, float(pre[0][i]), heading
        self._ops.insert(0, _samples_op(pre, slice(i, None)))

    def _op_samples(self, op: tuple) -> None:
        """Samples through the ZUPT-KF; its stances join the queue in their place. Until the hand-over stance
        has set the segment's turn (:meth:`_set_yaw`), the ZUPT-KF advances in short slices so that it is set
        before the drift reduction's dominant-direction snap, three strides on, whatever the upload length."""
        nav = self._nav
        rest = None
        if self._seg_first and len(op[1]) > _FIRST_SLICE:
            rest = _samples_op(op[1:], slice(_FIRST_SLICE, None))
            op = _samples_op(op[1:], slice(None, _FIRST_SLICE))
        out = nav.process(op[1], op[2], op[3], op[4])
        self._sched.zupt_aligned = self._sched.zupt_aligned or nav.initialised  # may let the gyro sleep
        if len(out.t_s):
            self._nav_t = float(out.t_s[-1])
        self._ops[0:1] = self._nav_ops(out) + ([rest] if rest is not None else [])

    def _op_handover(self) -> None:
        """The segment ended: Gait-DR continues from its last stance."""
        if self._gait is not None and not self._seg_first and self._pos is not None:
            self._gait.start(self._pos)
        self._moved = self._seg_first  # a segment without a stance placed no foot to start from
        self._in_seg = False
        self._ops.pop(0)

    def _processed_through(self, horizon: float) -> float:
        """Data time before which every stance and step has been worked through [s]."""
        t = horizon
        if self._ops:
            op = self._ops[0]
            kind = op[0]
            if kind == "start":
                t = min(t, op[1])
            elif kind == "samples":
                t = min(t, float(op[1][0]))
            elif kind == "stance":
                t = min(t, op[1].t_start_s)
        elif self._in_seg:
            t = min(t, self._seg_t if self._seg_first else self._nav_t)
        return t

    def _apply_labels(self, upto_s: float, events: list[Event]) -> None:
        """Hand the scheduler the behaviour decisions up to ``upto_s`` [s].

        A decision that repeats the scheduler's behaviour changes nothing (``Scheduler.on_behaviour`` returns at
        once), so it is only taken off the queue (most decisions: one every 0.25 s)."""
        pending, sched = self._labels_pending, self._sched
        while pending and pending[0][0] <= upto_s:
            td, label = pending.pop(0)
            if label != sched.behaviour:
                events += sched.on_behaviour(label, td, self._ns(td))

    def _rest_start(self, op: tuple) -> tuple[int, int] | None:
        """Look for the first still stretch of a restarting segment (the foot on the ground).

        Samples before it are dropped (Gait-DR covers them); the trailing candidate stretch is kept in
        ``self._pre`` across calls. Returns its first and last index in ``self._pre``.
        """
        t, a, g, m = op[1], op[2], op[3], op[4]
        if self._pre is not None:
            p = self._pre
            pm = p[3] if p[3] is not None else np.full((len(p[0]), 3), np.nan)
            mm = m if m is not None else np.full((len(t), 3), np.nan)
            t, a, g = np.concatenate([p[0], t]), np.concatenate([p[1], a]), np.concatenate([p[2], g])
            m = np.concatenate([pm, mm]) if (p[3] is not None or op[4] is not None) else None
        sc = self.config.segments
        start, end = first_still_run(t, a, g, sc.rest_s, sc.rest_gyr_rad_s, sc.rest_acc_ms2)
        if end >= 0:
            self._pre = (t, a, g, m)
            return start, end
        self._sum_rotation(t[:start], g[:start])
        self._collect_lead(t[:start], a[:start], g[:start])
        self._pre = (t[start:], a[start:], g[start:], None if m is None else m[start:])
        return None

    def _collect_lead(self, t: np.ndarray, acc: np.ndarray, gyr: np.ndarray) -> None:
        """Keep the samples of a self-started segment before its first still foot (up to ``SegmentsConfig.lead_max_s``)."""
        if self._lead is None or not len(t):
            return
        lt, la, lg = self._lead
        if len(lt) and float(t[-1]) - float(lt[0]) > self.config.segments.lead_max_s:
            self._lead = None  # no still foot soon after the wake: not a first stride, Gait-DR places the steps
            return
        self._lead = (np.concatenate([lt, t]), np.concatenate([la, acc]), np.concatenate([lg, gyr]))

    def _lead_displacement(self, acc_rest: np.ndarray, heading: float) -> np.ndarray | None:
        """Displacement [m NED] from the first sample of a self-started segment to its first still foot.

        The gyroscope woke on the foot's first motion (wake-on-motion), so the segment's samples before the
        still foot are most of the first stride. They are integrated backwards in time (004 eq. 1 with time
        reversed: rates negated, velocity sign flipped) from the still foot, where the attitude is known (roll
        and pitch levelled from ``acc_rest``, ``heading`` as the restarted ZUPT-KF gets it) and the velocity
        is zero, with the ZUPT-KF's bias estimates removed. What the foot did before the gyroscope delivered
        (the detector's period plus the turn-on time, about 0.1 s of heel-off) is not seen. A foot still from
        the first sample on (a gentle start, a turn on the spot that begins slowly) has none: zero (gaitmap-mag,
        6.7 s: taken for a host-started segment, Gait-DR had placed the first step 1.7 m off the ZUPT-KF's).
        None where the segment did not start on its own or found no still foot within ``lead_max_s``.
        """
        lead, self._lead = self._lead, None
        if lead is None or not len(lead[0]):
            return None
        if len(lead[0]) == 1:
            return np.zeros(3)  # the still foot is the segment's first sample: the whole first stride is its own
        t, a, g = lead
        if float(t[-1]) - float(t[0]) > self.config.segments.lead_max_s:
            return None
        c = align_at_rest(acc_rest)
        rz = euler_to_dcm(0.0, 0.0, heading - float(dcm_heading(c)))  # levelled attitude turned to ``heading``
        q0 = dcm_to_quat(rz @ c)
        nav = self._nav
        _, _, p = integrate(-t[::-1], a[::-1] - nav.acc_bias, -(g[::-1] - nav.gyro_bias), q0)
        return -p[-1]  # p[-1]: the segment's first sample relative to the still foot

    def _sum_rotation(self, t: np.ndarray, gyr: np.ndarray) -> None:
        """Add the rotation of samples a restarting segment drops (before its still foot) to ``_pre_rot``."""
        if len(t):
            dt = np.diff(np.concatenate([[self._pre_t if math.isfinite(self._pre_t) else t[0]], t]))
            self._pre_rot = self._pre_rot + (gyr * dt[:, None]).sum(axis=0)
            self._pre_t = float(t[-1])

    def _restart_heading(self, acc_rest: np.ndarray) -> float:
        """Sensor heading [rad] for a restarting ZUPT-KF: the heading estimator's, turned by what the
        gyroscope saw from the segment's first sample to the still foot (a segment often starts mid-turn),
        projected on the still foot's vertical."""
        gait = self._gait
        held = gait.est.heading if gait is not None and gait.est.started else self._nav.heading
        down = -np.asarray(acc_rest, dtype=float) / max(float(np.linalg.norm(acc_rest)), 1e-9)  # NED down, body
        return wrap_angle(held + float(self._pre_rot @ down))

    def _nav_ops(self, out: NavOutput) -> list[tuple]:
        """ZUPT-KF output as queue entries: per-sample trace pieces and stances, in time order."""
        ops: list[tuple] = []
        keep_trace = self.trace is not None
        lo = 0
        for st in out.stances:
            if keep_trace:
                hi = int(np.searchsorted(out.t_s, st.t_end_s, side="right"))
                if hi > lo:
                    ops.append(("trace", out.t_s[lo:hi], out.pos[lo:hi]))
                lo = max(lo, hi)
            ops.append(("stance", st))
        if keep_trace and lo < len(out.t_s):
            ops.append(("trace", out.t_s[lo:], out.pos[lo:]))
        return ops

    def _trace_nav(self, t: np.ndarray, pos: np.ndarray) -> None:
        assert self.trace is not None
        p = np.full_like(pos, np.nan) if self._seg_first else self._turn(pos) + self._offset
        self.trace.append(self._ns_many(t), p, self._labels.at_many(t),
                          np.full(len(t), "zupt"), np.ones(len(t), dtype=bool))

    def _set_yaw(self, yaw: float) -> None:
        """Turn this segment's ZUPT-KF frame to the session frame by ``yaw`` [rad] from now on, and the ZUPT-KF's
        dominant directions against it, so that they stay the session's (mixed day, seed 17: a segment turned by
        a missed 13-deg turn was snapped back by 6 deg to a direction 13 deg off, its positions 0.8 m aside)."""
        self._nav.turn_dominant(self._yaw - yaw)
        self._yaw = yaw

    def _turn(self, p: np.ndarray, yaw: float | None = None) -> np.ndarray:
        """NED vectors [m] (last axis 3) of this segment's ZUPT-KF frame turned by ``_yaw`` (or ``yaw`` [rad])
        about the vertical."""
        yaw = self._yaw if yaw is None else yaw
        if yaw == 0.0:
            return p
        c, s = math.cos(yaw), math.sin(yaw)
        if p.ndim == 1:  # one vector (a stance's position or stride): the same products, on floats
            x, y = float(p[0]), float(p[1])
            return np.array([c * x - s * y, s * x + c * y, float(p[2])])
        q = np.array(p, dtype=float, copy=True)
        q[..., 0] = c * p[..., 0] - s * p[..., 1]
        q[..., 1] = s * p[..., 0] + c * p[..., 1]
        return q

    def _session_stance(self, st: Stance) -> Stance:
        """A ZUPT-KF stance in the session frame: turned by ``_yaw``, translated by ``_offset``."""
        if self._yaw == 0.0:
            return st.placed(st.position + self._offset, st.heading, st.delta)
        return st.placed(self._turn(st.position) + self._offset, wrap_angle(st.heading + self._yaw),
                         self._turn(st.delta))

    def _emit(self, pos: Position, positions: list[Position], events: list[Event]) -> None:
        """Output a position; where its mode differs from the last one's, a ``mode_switch`` event says so with
        the scheduler's reason for the sensors that produced it (events follow the positions)."""
        if self._out_mode and pos.mode != self._out_mode:
            events.append(Event(pos.t_ns, "mode_switch", {"from": self._out_mode, "to": pos.mode,
                                                           "reason": self._sched.reason}))
        self._out_mode = pos.mode
        positions.append(pos)

    def _place_rest(self, p: np.ndarray, d: float, positions: list[Position], events: list[Event]) -> None:
        """Output the still foot a self-started segment restarted on, at ``p`` [m NED], ``d`` [m] from the last
        position, where the ZUPT-KF's detector found no stance of its own."""
        t_ns = self._ns(self._rest_t)
        label = self._labels.at(self._rest_t)
        self._emit(Position(t_ns, float(p[0]), float(p[1]), float(p[2]), self._rest_head, label, "zupt", d, True),
                   positions, events)
        events += self._sched.on_zupt_distance(d, t_ns)
        if self.trace is not None:
            self.trace.append(np.array([t_ns], dtype=np.int64), np.array([p]), np.array([label]), np.array(["zupt"]),
                              np.ones(1, dtype=bool))
        self._pos = p

    def _stance(self, st: Stance, positions: list[Position], events: list[Event]) -> None:
        """One ZUPT-KF stance, in data-time order."""
        gait, sched = self._gait, self._sched
        self._apply_labels(st.t_end_s, events)
        label = self._labels.at(st.t_end_s)
        t_ns = self._ns(st.t_end_s)
        if self._seg_first:
            self._seg_first = False
            self._handover(st, label, t_ns, positions, events)
            return
        st = self._session_stance(st)
        p, d = st.position, st.step_length
        self._pos, self._head = p, float(st.heading)
        self._emit(Position(t_ns, float(p[0]), float(p[1]), float(p[2]), float(st.heading), label, "zupt", d, True),
                   positions, events)
        events += sched.on_zupt_distance(d, t_ns)
        if gait is None:
            sched.nav_ready = True
            return
        e = gait.take_pair(st.t_start_s)
        gait.track(e, wrap_angle(float(st.heading) - self._zupt_head), 0.0)
        self._zupt_head = float(st.heading)
        events += sched.on_compass(gait.compass() is not None, t_ns)
        events += self._north_event(t_ns)
        ref = self._nav.dominant_ref
        gait.dominant = None if ref is None else wrap_angle(ref + self._yaw)
        if e is not None:
            self._learn_stride(st, e, label, t_ns, events)
        events += sched.on_heading(gait.forecast_drift_pct(label), True, t_ns)

    def _handover(self, st: Stance, label: str, t_ns: int, positions: list[Position], events: list[Event]) -> None:
        """A segment's first stance: the ZUPT-KF takes over where Gait-DR (or the lead of a self-started
        segment) put the foot, turned so that its heading is the heading estimator's there.

        The hand-over stride goes through the estimator with the turn the gyroscope saw (the ZUPT-KF restarted
        from the estimator's heading, so its heading here is that plus what it saw) and, for the part of the
        stride before the gyroscope's first sample, the gyroscope-off motion models; then the stance compass.
        A turn made before the gyroscope came on is thus taken from the compass as far as its noise allows.
        """
        gait = self._gait
        lead, self._lead_d = self._lead_d, None
        placed = False
        yaw = 0.0
        if gait is not None and not gait.est.started:
            gait.take_pair(st.t_start_s)
            gait.start_frame(float(st.heading))  # the session's first stance defines the navigation frame
        elif gait is not None:
            host_started = gait.active and lead is None
            if host_started:
                self._reckon(st.t_start_s - PAIR_TOL_S, positions, events)  # Gait-DR's strides before this stance
            e = gait.take_pair(st.t_start_s)
            before = gait.est.heading
            span = st.t_start_s - gait.step_s
            unseen = (self._seg_t - gait.step_s) / span if host_started and 0.0 < span < math.inf else 0.0
            yaw = wrap_angle(gait.track(e, wrap_angle(float(st.heading) - before), unseen) - float(st.heading))
            if host_started and e is not None:
                self._emit_step(gait.place(e, label, before), e, gait.forecast_drift_pct(label), positions, events)
                placed = True
        self._set_yaw(yaw)
        self._zupt_head = wrap_angle(float(st.heading) + yaw)
        if lead is not None and self._pos is not None:
            p = self._pos + lead
            if st.t_start_s > self._rest_t + PAIR_TOL_S:
                # the detector found no stance at that still foot (a slow, rolling first step): it is placed by
                # itself, and the ZUPT-KF's way from it to this stance is added
                self._place_rest(p, float(math.hypot(lead[0], lead[1])), positions, events)
                p = p + self._turn(st.position - self._rest_p)
            self._offset = p - self._turn(st.position)
            d = float(math.hypot(p[0] - self._pos[0], p[1] - self._pos[1]))
            self._pos, self._head = p, self._zupt_head
            self._emit(Position(t_ns, float(p[0]), float(p[1]), float(p[2]), self._head, label, "zupt", d, True),
                       positions, events)
            events += self._sched.on_zupt_distance(d, t_ns)
            return
        if self._pos is not None:
            self._offset = self._pos - self._turn(st.position)
        self._head = self._zupt_head
        if not placed:
            p = self._turn(st.position) + self._offset
            self._pos = p
            self._emit(Position(t_ns, float(p[0]), float(p[1]), float(p[2]), self._head, label, "zupt", 0.0, True),
                       positions, events)

    def _north_event(self, t_ns: int) -> list[Event]:
        """``north_reference`` when magnetic north's azimuth in the session frame is first known or has moved by
        more than ``_NORTH_STEP`` since announced: the session frame's heading 0 is where the sensor pointed at the
        first stance; geo-referencing (:func:`models.geo.georeference`) turns the track by it to magnetic north."""
        gait = self._gait
        north = gait.magnetic_north() if gait is not None else None
        if north is None or (math.isfinite(self._north) and abs(wrap_angle(north[0] - self._north)) <= _NORTH_STEP):
            return []
        self._north = north[0]
        return [Event(t_ns, "north_reference", {"magnetic_north_rad": north[0], "std_rad": north[1]})]

    def _learn_stride(self, st: Stance, e: StepEvent, label: str, t_ns: int, events: list[Event]) -> None:
        """A ZUPT-KF stride with its step event: calibration pairs, KF II, examinations (004 Table 3 and the
        direction examination), and the hand-over to Gait-DR once the initialisation is complete."""
        gait, sched = self._gait, self._sched
        assert gait is not None
        c = self.config.scheduler
        exam = sched.exam_active and st.t_start_s >= sched.exam_started_s and not e.after_rest
        fitted = None
        if exam:
            b = model_behaviour(label)
            d_sl, _ = gait.step_length(e, b)
            passed = gait.cal.examine(st.step_length, d_sl, b, e.f_s)  # 004 Table 3
            fitted = gait.cal.cadence_ranges(b, 1.0 / gait.rate_hz)
            new_pattern = fitted is not None and not any(lo <= e.f_s <= hi for lo, hi in fitted)
        # the direction examination: KF II's innovation before it takes the stride (a stored deviation not yet
        # confirmed in this session, and every examination stride)
        tested = (label in sched.deviation_pending or exam) and label == sched.behaviour
        prior = HeadingDeviationKF.from_state(gait.kf2[model_behaviour(label)].get_state()) if tested else None
        pending = sorted(sched.deviation_pending)
        z = gait.learn(st, e, label, step_model=sched.working == "zupt" or exam)
        heading = None if prior is None or z is None or not prior.n_updates else _heading_test(z, prior, c.exam_sigmas)
        verdict: list[Event] = []
        if exam:
            verdict = sched.on_exam_result(passed, st.step_length, d_sl, st.t_end_s, t_ns, heading, new_pattern)
        elif heading is not None:
            verdict = sched.on_heading_check(heading, st.t_end_s, t_ns)
        events += verdict
        causes = {ev.detail.get("cause") for ev in verdict if ev.kind == "examination_failed"}
        if "walking_pattern" in causes:
            self._note_pattern(sched.behaviour, fitted)
        if "heading_deviation" in causes:
            gait.forget_mount(pending)  # the sensor was re-mounted: its stored deviations and compass are stale
        sched.nav_ready = gait.bootstrapped()
        sched.run_wake_ms2 = gait.run_wake_threshold()
        if sched.ready_for_pdr() and gait.ready(label):
            fits = gait.fit(label)
            cal = self._store_calibration(label, fits)
            pattern, self._pattern = self._pattern, None
            if pattern is not None and pattern[0] == model_behaviour(label):
                events += self._correct_pattern(pattern, t_ns)
            events += sched.on_calibrated(st.t_end_s, t_ns, {
                "heading_deviation_rad": cal.heading_deviation_rad,
                "heading_deviation_var": cal.heading_deviation_var,
                "sigma_d_m": cal.sigma_d_m,
                "n_steps": cal.n_steps,
            })

    def _reckon(self, before_s: float, positions: list[Position], events: list[Event]) -> None:
        """Gait-DR steps with onset before ``before_s`` [s]."""
        gait = self._gait
        assert gait is not None
        if not gait.queue:  # nothing to reckon (standing, or every step taken): nothing changes
            return
        for step, e, drift in gait.reckon(before_s, self._labels.at):
            self._emit_step(step, e, drift, positions, events)

    def _emit_step(self, step: Any, e: StepEvent, drift: float, positions: list[Position], events: list[Event]) -> None:
        """Output one Gait-DR step and tell the scheduler (T0, walking pattern, the heading's drift forecast)."""
        gait, sched = self._gait, self._sched
        assert gait is not None
        self._apply_labels(step.t_s, events)
        t_ns = self._ns(step.t_s)
        pos = step.position
        self._emit(Position(t_ns, pos[0], pos[1], pos[2], step.direction, step.behaviour, "pdr", step.length, False),
                   positions, events)
        self._log_stride(step, e, self._pos)
        self._moved = True
        self._step_s = float(step.t_s)
        self._pos = np.asarray(pos, dtype=float)
        self._head = gait.est.heading
        events += sched.tick(step.t_s, t_ns)
        if not e.after_rest:  # 004 Table 2 (ii): a walking pattern the step-length model has not seen
            fitted = gait.cal.cadence_ranges(sched.behaviour, 1.0 / gait.rate_hz)  # step periods in samples
            found = sched.on_cadence(e.f_s, fitted, t_ns)
            if any(ev.kind == "walking_pattern_changed" for ev in found):
                self._note_pattern(sched.behaviour, fitted)
            events += found
        events += sched.on_heading(drift, False, t_ns)
        if self.trace is not None:
            self.trace.append(np.array([t_ns], dtype=np.int64), np.array([pos]), np.array([step.behaviour]),
                              np.array(["pdr"]), np.zeros(1, dtype=bool))

    def _store_calibration(self, behaviour: str, fits: dict) -> BehaviourCalibration:
        """Put what the initialisation learned into the per-user profile (handed out by profile_dict)."""
        b = model_behaviour(behaviour)
        gait = self._gait
        assert gait is not None
        pooled = fits.get(b, {})
        kf = gait.kf2[b]
        cal = BehaviourCalibration(
            step_model=gait.calibration_state(),
            sigma_d_m=float(pooled.get("sigma_d", float("nan"))),
            heading_deviation_rad=kf.deviation,
            heading_deviation_var=kf.variance,
            n_steps=int(pooled.get("n", 0)),
            calibrated=True,
        )
        self._sched.profile.behaviours[b] = cal
        return cal

    def _update(self, positions: list[Position], events: list[Event]) -> Update:
        """The answer to a batch; its ``mode`` is what the device is told to run next (``zupt`` with the
        gyroscope on, ``pdr`` with it off while moving, ``idle`` standing with it off, the device perhaps left to
        wake it), so it never contradicts
        the sensor configuration beside it."""
        sched = self._sched
        config, idle = sched.config_and_idle()
        if config.gyro_on or self.mode == "zupt":
            mode = "zupt"
        else:
            mode = "idle" if idle or sched.behaviour == "stand" else "pdr"
        return Update(positions, events, config, sched.behaviour, mode)

    def _log_stride(self, step: Any, e: Any, prev: np.ndarray | None) -> None:
        """Keep a placed Gait-DR stride (its event, length and direction) for :meth:`_correct_pattern`."""
        if prev is None:
            return
        dn, de = float(step.position[0] - prev[0]), float(step.position[1] - prev[1])
        n = math.hypot(dn, de)
        if not (step.length > 0.0 and n > 0.0):
            return
        self._dr_log.append([model_behaviour(step.behaviour), e.to_row(), float(step.length), dn / n, de / n])
        del self._dr_log[:-_DR_LOG]

    def _note_pattern(self, behaviour: str, fitted: Any) -> None:
        """A walking pattern of ``behaviour`` the step model was not fitted on was detected: remember where its
        strides began, the first of the latest cadence-tested Gait-DR strides (the scheduler's detection window)
        whose cadence lies outside the ``fitted`` ranges."""
        b = model_behaviour(behaviour)
        events = [StepEvent.from_row(r[1]) for r in self._dr_log if r[0] == b]
        window = [e for e in events if not e.after_rest][-self.config.scheduler.pattern_strides:]
        out = [e.t_s for e in window if fitted and not any(lo <= e.f_s <= hi for lo, hi in fitted)]
        self._pattern = (b, float(out[0]) if out else math.inf)

    def _correct_pattern(self, pattern: tuple[str, float], t_ns: int) -> list[Event]:
        """The ZUPT-KF has initialised a new walking pattern and its step model is refitted: re-place the Gait-DR
        strides of that pattern placed before (while the detection window filled and until the gyroscope came on)
        with the refitted model, moving the position by the sum of the changes along their directions.

        Those strides had the old model's extrapolation to a cadence it was not fitted on (synthetic mixed day:
        walk_fast strides placed 8 % short on average, 2-13 % either way, 8-13 strides per seed); the ZUPT-KF's
        strides of the new pattern now fit it."""
        gait = self._gait
        if gait is None or self._pos is None:
            return []
        b, t_from = pattern
        rows = [r for r in self._dr_log if r[0] == b and StepEvent.from_row(r[1]).t_s >= t_from]
        if not rows:
            return []
        strides = [StepEvent.from_row(r[1]) for r in rows]
        d_new = [max(gait.step_length(e, b)[0], 0.0) for e in strides]
        periods = [e.period_s for e in strides]
        per = float(np.median(periods))
        paced = [d for d, q in zip(d_new, periods) if q <= self.config.step_length.pause_period * per]
        if paced:
            # a stride far longer than its pattern's holds a pause (the segmenter takes one as such only when the
            # stance before lasted most of a stride): its cadence and mean force describe the pause, not the
            # stride, the first of the new pace (mixed day seed 12: 1.48 s among 1.00-s strides, placed 1.25 m,
            # re-placed at its own cadence 1.13 m, for 1.66 m); it gets the pattern's median stride
            d_new = [d if q <= self.config.step_length.pause_period * per else float(np.median(paced)) for d, q in zip(d_new, periods)]
        delta = np.zeros(3)
        for (_, _, d_old, un, ue), d in zip(rows, d_new):
            delta[0] += (d - d_old) * un
            delta[1] += (d - d_old) * ue
        if not np.all(np.isfinite(delta)):
            return []
        self._pos = self._pos + delta
        self._offset = self._offset + delta
        first = strides[0]
        before = [t for t in (StepEvent.from_row(r[1]).t_s for r in self._dr_log) if t < first.t_s]
        start = before[-1] if before else first.t_s - first.period_s  # onset of the stride before the first
        self._dr_log = [r for r in self._dr_log if r not in rows]
        return [Event(t_ns, "strides_corrected", {"behaviour": b, "cause": "walking_pattern", "n_strides": len(rows),
                                                   "from_s": t_from, "start_s": float(start), "to_s": float(strides[-1].t_s),
                                                   "placed_m": float(math.fsum(d_new)),
                                                   "moved_m": [float(delta[0]), float(delta[1])]})]

    # ------------------------------------------------------------------ state
    def _ops_state(self) -> list[list[Any]]:
        out: list[list[Any]] = []
        for op in self._ops:
            k = op[0]
            if k == "samples":
                out.append([k, op[1], op[2], op[3], op[4]])
            elif k == "stance":
                out.append([k, _stance_row(op[1])])
            elif k == "start":
                out.append([k, op[1]])
            elif k in ("end", "handover"):
                out.append([k])
            # "trace" entries are not state (the trace is not serialised)
        return out

    @staticmethod
    @staticmethod
    def _ops_from_state(rows: list[list[Any]]) -> list[tuple]:
        ops: list[tuple] = []
        for r in rows:
            k = r[0]
            if k == "samples":
                ops.append((k, np.asarray(r[1], dtype=float), np.asarray(r[2], dtype=float).reshape(-1, 3),
                            np.asarray(r[3], dtype=float).reshape(-1, 3), None if r[4] is None else np.asarray(r[4], dtype=float).reshape(-1, 3)))
            elif k == "stance":
                ops.append((k, _stance_from_row(r[1])))
            elif k == "start":
                ops.append((k, float(r[1])))
            else:
                ops.append((k,))
        return ops

    _SCALARS = ("t0_ns", "last_acc_t", "last_gyr_s", "gyro_missing", "seg_open", "in_seg", "seg_t", "seg_first",
                "yaw", "head", "zupt_head", "out_mode", "north", "nav_t", "await_rest", "pre_t", "moved", "step_s",
                "rest_t", "rest_head")

    def get_state(self) -> dict[str, Any]:
        d: dict[str, Any] = {k: getattr(self, "_" + k) for k in self._SCALARS}
        d.update({
            "version": _STATE_VERSION,
            "mode": self.mode,
            "config": self.config.changes(),
            "acc_t": self._acc_t,
            "acc_v": self._acc_v,
            "gyr": self._gyr.get_state(),
            "mag": self._mag.get_state(),
            "sched": self._sched.get_state(),
            "nav": self._nav.get_state(),
            "behaviour": self._behaviour.get_state(),
            "labels": self._labels.get_state(),
            "gait": None if self._gait is None else self._gait.get_state(),
            "ops": self._ops_state(),
            "offset": self._offset,
            "pos": self._pos,
            "pre": None if self._pre is None else list(self._pre),
            "pre_rot": self._pre_rot,
            "lead": None if self._lead is None else list(self._lead),
            "lead_d": self._lead_d,
            "rest_p": self._rest_p,
            "labels_pending": [[t, lab] for t, lab in self._labels_pending],
            "dr_log": [list(r) for r in self._dr_log],
            "pattern": None if self._pattern is None else list(self._pattern),
        })
        return d

    @classmethod
    def from_state(cls, d: dict[str, Any], trace: bool = False) -> Engine:
        if d.get("version") != _STATE_VERSION:
            raise ValueError(f"engine state version {d.get('version')!r} is not {_STATE_VERSION}")
        config = EngineConfig.default().override(d["config"])
        obj = cls(mode=d["mode"], config=config, trace=trace)
        for k in cls._SCALARS:
            setattr(obj, "_" + k, d[k])
        obj._acc_t = np.asarray(d["acc_t"], dtype=np.int64)
        obj._acc_v = np.asarray(d["acc_v"], dtype=np.float64).reshape(-1, 3)
        obj._gyr = _StreamPairing.from_state(d["gyr"])
        obj._mag = _StreamPairing.from_state(d["mag"])
        obj._sched = Scheduler.from_state(config, d["sched"])
        obj._nav = ZuptNavigator.from_state(d["nav"])
        obj._behaviour = BehaviourRecognizer.from_state(d["behaviour"])
        obj._labels = _LabelHistory.from_state(d["labels"])
        obj._gait = None if d["gait"] is None else GaitPipeline.from_state(config, d["gait"])
        obj._ops = cls._ops_from_state(d["ops"])
        obj._offset = np.asarray(d["offset"], dtype=float).reshape(3)
        obj._pos = None if d["pos"] is None else np.asarray(d["pos"], dtype=float).reshape(3)
        pre = d["pre"]
        obj._pre = None if pre is None else (
            np.asarray(pre[0], dtype=float), np.asarray(pre[1], dtype=float).reshape(-1, 3),
            np.asarray(pre[2], dtype=float).reshape(-1, 3), None if pre[3] is None else np.asarray(pre[3], dtype=float).reshape(-1, 3))
        obj._pre_rot = np.asarray(d["pre_rot"], dtype=float).reshape(3)
        lead = d["lead"]
        obj._lead = None if lead is None else (np.asarray(lead[0], dtype=float), np.asarray(lead[1], dtype=float).reshape(-1, 3),
                                               np.asarray(lead[2], dtype=float).reshape(-1, 3))
        obj._lead_d = None if d["lead_d"] is None else np.asarray(d["lead_d"], dtype=float).reshape(3)
        obj._rest_p = np.asarray(d["rest_p"], dtype=float).reshape(3)
        obj._labels_pending = [(float(t), str(lab)) for t, lab in d["labels_pending"]]
        obj._dr_log = [[str(r[0]), [float(v) for v in r[1]], float(r[2]), float(r[3]), float(r[4])] for r in d["dr_log"]]
        pat = d["pattern"]
        obj._pattern = None if pat is None else (str(pat[0]), float(pat[1]))
        return obj

    def to_bytes(self) -> bytes:
        """Complete state as bytes (safe codec, no pickle)."""
        return codec.dumps(self.get_state())

    @classmethod
    def from_bytes(cls, blob: bytes, trace: bool = False) -> Engine:
        return cls.from_state(codec.loads(blob), trace=trace)
