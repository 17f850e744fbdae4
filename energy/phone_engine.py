"""The step-and-heading engine: phones (in the hand, in a pocket) and watches (DESIGN.md, "Placement").

Same contract as :class:`energy.engine.Engine` (DESIGN.md, "The engine contract"): ``feed(batch) -> Update``
with one position per detected step, events and the sensor configuration the device should use next;
``flush()``; deterministic and chunk-invariant; complete state to bytes and back; a per-user profile in and
out. What it does per step (003 Figure 5, eq. 24):

1. the front end (:mod:`models.pdr`) runs the MARG filter, the step detector and the walking-direction
   statistics over the merged samples, in time order, up to the newest time every stream has reached (a
   stream that delivered nothing for ``stream_wait_s``, e.g. a gyroscope that is off, is not waited for; one
   still delivering is, while its time stamps lag by at most ``stream_max_lag_s``);
2. the placement (given, or recognised between hand and pocket for a phone, :mod:`models.placement`) picks the
   walking direction: the device's forward axis held in front, the horizontal acceleration's principal
   direction otherwise;
3. the walking heading is the project's one heading estimator (:class:`models.heading.HeadingEstimator`, the
   foot engine's; its parameters for a hand-held phone per step in :data:`PHONE_HEADING`): with the gyroscope
   it turns by the MARG filter's change of the walking direction over the step once that filter has settled
   (``gyro_min_steps`` steps with the gyroscope and its heading standard deviation below
   ``marg_settled_std_rad``), and takes the MARG filter's heading as an observation while it is still
   converging; without the gyroscope its straight and turn models and the compass carry it (a compass change
   only a turn explains is taken as the turn; after a stand at one place the compass's change is the turn made
   standing; a step whose interval the gyroscope saw only in part, as when it came on during a stand, adds the
   free turn of the unseen time, so the compass can supply a turn made there). The compass reads ``theta + d``:
   the local field's deflection ``d`` is learnt while the gyroscope carries the heading and held, as the
   compass's spatially correlated error, when it is off;
4. the building's dominant directions (:mod:`models.dominant_directions`, learnt from the walk's own compass)
   pull straight steps along them onto them (:meth:`models.heading.HeadingEstimator.update_dominant`, 003
   Section 6.1);
5. the step length (:mod:`models.pdr_step_length`, Weinberg 000 eq. 35 or 003 eq. 28), calibrated per user and
   placement from known distances (:meth:`PhoneEngine.calibrate_distance`), places the step.

Energy (``mode="auto"``): walking, the gyroscope runs at 25 Hz with the accelerometer at 25 Hz and the
magnetometer at 5 Hz (``walk_gyro="on"``); standing (no step for ``stand_after_s`` with a still accelerometer) the
gyroscope is off once the MARG filter's vertical bias has settled (:func:`models.marg.bias_settled`: after the start
and after the device was waved about it stays on, the quasi-static field settling the bias), the turn made standing
coming from the compass's change at that one place. With ``walk_gyro="on-demand"`` the gyroscope runs walking only
while the heading needs it (first steps, until the compass's noise is known; after a turn; whenever the estimator's
forecast standard deviation one gyroscope-off step ahead (:meth:`models.heading.HeadingEstimator.forecast`) would
exceed ``max_heading_std_rad``, except straight along the building's dominant directions); a gyroscope that comes
back with a settled bias carries the heading by its own measured turn (``gyro_dyaw``) until the MARG filter has
settled again, and with ``gyro_duty_period_s`` (off by default) the walking gyroscope-off batches ask for a
duty-cycled gyroscope instead, whose gaps :class:`_DutyFill` fills. ``mode="always-on"``: every sensor at its
full rate, the baseline the energy is compared with.
North is magnetic (:attr:`PhoneEngine.NORTH_REFERENCE`): the declination is applied where the track is
geo-referenced (:func:`models.geo.georeference`, server and replay alike). An anchor gives the engine the World
Magnetic Model's field there (in the magnetic frame), against which a still device's compass is weighed.
"""

from __future__ import annotations

import datetime as _dt
import math
from dataclasses import asdict, dataclass, field
from dataclasses import replace as _replace
from typing import Any

import numpy as np

from energy import codec
from energy.compass_swing import SWING_RAD, SWING_WINDOW_S
from energy.types import Event, Position, SensorConfig, Update
from models.batch import STREAMS, BatchError, SensorBatch
from models.dominant_directions import DominantDirections, DominantDirectionsConfig
from models.heading import CompassNoise, HeadingConfig, HeadingEstimator, wrap
from models.marg import MargConfig, MargState, merge_streams
from models.pdr import STEP_RECORD, PdrState, run_pdr
from models.pdr_step_length import PdrStepLength, StepLengthConfig
from models.placement import STEP_AND_HEADING, PlacementConfig, PlacementRecognizer
from models.step_detector import StepDetectorConfig

__all__ = ["PhoneEngine", "PhoneEngineConfig", "PHONE_HEADING", "PHONE_MODES", "PROFILE_KEY", "WALK_GYRO", "steady_step"]

PHONE_MODES: tuple[str, ...] = ("auto", "always-on")
WALK_GYRO: tuple[str, ...] = ("on", "on-demand")  # PhoneEngineConfig.walk_gyro
PROFILE_KEY = "pdr"  # the profile's entry of the step-and-heading engines (energy.profile.PROFILE_BEHAVIOURS)
_STATE_VERSION = 2
_F = {k: i for i, k in enumerate(STEP_RECORD)}
_LOG_STEPS = 4000  # steps kept for a known-distance calibration (about 40 min of walking)
# a mean angular rate over a step above this [rad/s] is a device waved about, not carried along (hand-held walking:
# 0.3 rad/s on the IPIN trials; their calibration manoeuvre: 3-7 rad/s)
_WAVED_RAD_S = 1.5
_FIELD_STEPS = 50  # steps whose fields are the reference without an anchor (about 25 s of walking)


def steady_step(period_s: float, rate_rad_s: float) -> bool:
    """A step of a steady gait: a walking cadence (period 0.3-1 s), and a device that is not being waved about (a
    calibration wave's "steps" turn the device with the compass, which then looks perfect)."""
    return (math.isfinite(period_s) and 0.3 <= period_s <= 1.0
            and not (math.isfinite(rate_rad_s) and rate_rad_s > _WAVED_RAD_S))


def _magnetic_reference(anchor: tuple[float, float, float], date: _dt.date | None) -> np.ndarray:
    """The World Magnetic Model's field at the anchor in the engine's magnetic-north NED frame [uT]
    (:func:`models.geo.magnetic_elements`: no east component)."""
    from models.geo import Anchor, magnetic_elements

    kw = {"date": date} if date is not None else {}
    el = magnetic_elements(Anchor(anchor[0], anchor[1], anchor[2], **kw))
    return np.asarray(el.field_magnetic_ned_ut, dtype=float)


# The heading estimator's parameters for a hand-held phone, per step (models.heading.HeadingConfig): statistics of
# the sensors on the IPIN 2023 T3 dev trials (16 walks, 8 routes, steps between the first and last landmark; no
# landmark position used), each within the range of its leave-one-route-out folds (in brackets), reproduced by
# `python -m clients.evaluation.phone_heading` (its docstring gives the definitions).
PHONE_HEADING = HeadingConfig(
    straight_sigma_rad=math.radians(3.4),  # MARG direction change of steps turning < 10 deg: robust SD 3.41 [3.27, 3.74]
    turn_sigma_rad=math.radians(52.0),  # RMS of the steps turning more: 52.6 deg [51.1, 54.6]
    p_turn_start=0.06,  # a straight step followed by a turning one: 0.063 [0.055, 0.068]
    p_turn_stay=0.52,  # a turning step followed by another: 0.52 [0.51, 0.53] (a turn takes two steps)
    gyro_sigma_rad=math.radians(0.5),  # vertical gyroscope drift unseen by the filter: 0.25-0.42 deg/s x 0.55 s/step (docs/phone.md)
    gyro_scale=0.01,  # a MEMS gyroscope's scale-factor error (the foot's)
    # compass minus MARG direction as an AR(1) process (11.2 deg SD, correlation 0.91 per step) is a random walk of
    # 3.9 deg [3.6, 4.2] per step held by the pseudo-observation "no deflection" at 28.7 deg [26.1, 33.1]
    deflection_walk_rad=math.radians(3.9),
    deflection_floor_rad=math.radians(28.0),
    offset_prior_rad=0.0,  # the compass reads in the heading's own frame (magnetic north): no frame offset
    compass_floor_rad=math.radians(2.0),  # the white part, at most lag-1 change / sqrt(2): 2.18 deg [2.07, 2.35]
    consistency_window=24,  # steps (12 strides, the foot's 12)
    consistency_max_var=math.radians(5.0) ** 2,  # a heading the gyroscope carries: the estimator's 3-5 deg
    outlier_sigmas=3.0,
    dominant_on=True,  # (the phone's own ``PhoneEngineConfig.directions`` decides)
)


@dataclass(frozen=True)
class PhoneEngineConfig:
    """Configuration of :class:`PhoneEngine` (rates in Hz, times in s, angles in rad).

    Attributes
    ----------
    marg, steps, step_length, heading, placement, directions
        The parts' own configurations (``directions``: None switches the dominant directions off).
    acc_rate_hz, gyr_rate_hz, mag_rate_hz : float
        Full rates (the always-on baseline: a phone's usual 50 / 100 / 50 Hz).
    walk_gyro : str
        ``auto`` while walking: ``"on"`` (the default), the gyroscope runs whenever the walker is not standing;
        ``"on-demand"``, only while the heading needs it (the rules below: first steps, after a turn, a forecast
        above ``max_heading_std_rad``; off straight along the building's directions). Measured on the IPIN dev
        trials (docs/phone.md, "The gyroscope while walking, at the low rates"): with the gyroscope off walking
        the compass must find the turns, which it does late and with its place errors; at 25 Hz the gyroscope
        walking costs less than the errors it saves.
    auto_acc_rate_hz : float
        Accelerometer rate walking in ``auto``: 25 Hz, the low end of a phone's rates and ten times a walker's step
        frequency (the Weinberg feature's peaks are taken at this rate; the always-on fit of its constant is at
        ``acc_rate_hz``, the path comes out 0.7 % shorter).
    walk_mag_rate_hz : float
        Magnetometer rate walking in ``auto``: 5 Hz (the MARG filter reads the compass at most every
        ``marg.compass_interval_s``, 0.1 s; the compass's error is correlated over seconds, so fewer readings
        lose little).
    auto_gyr_rate_hz : float
        Gyroscope rate in ``auto`` when on: 25 Hz, the BMI270's lowest gyroscope output rate; a hand-held walk
        has little rotation above a few hertz. Its current being flat in rate, what the lower rate saves is the
        samples' upload and compute.
    stand_acc_rate_hz, stand_mag_rate_hz : float
        Rates while standing in ``auto``.
    stand_after_s : float
        No step for this long with a still accelerometer: standing (the gyroscope goes off in ``auto``); also,
        a step this long after the previous one comes after a stand at one place.
    max_heading_std_rad : float
        ``auto`` asks for the gyroscope when the heading's standard deviation one step ahead without it would
        exceed this.
    gyro_min_steps : int
        Once on, the gyroscope stays on for at least this many steps (and this many compass innovations measure
        the compass's noise before it may go off at all); the MARG filter's heading changes count as the
        gyroscope's after this many steps with it.
    marg_settled_std_rad : float
        ... and while the MARG filter's heading standard deviation is below this: above its settled range (walking
        with the gyroscope, its 95th percentile is 14.7 deg on the IPIN trials, 14.4-15.1 leaving out each route);
        converging after the gyroscope was off it starts at 30-75 deg, and its changes are then its compass
        corrections, not the walker's turns.
    orientation_rho : float
        The compass's error correlation from one step to the next (AR(1); the IPIN dev trials' compass minus MARG
        walking direction: 0.906, 0.890-0.921 leaving out each route, ``python -m
        clients.evaluation.phone_heading``). The building's orientation voted by the compass of straight steps is
        known to its votes' spread over the square root of the independent votes
        (:meth:`models.dominant_directions.DominantDirections.orientation_std_rad`), and the pull onto its
        directions weighs that error with the walk's own (``directions.sigma_rad``): votes from a few places
        carry those places' compass errors (the orientation erred by 10-17 deg on some trials) and pulled every
        straight step onto them with 4 deg. 0: the walk's own only.
    swing_wake : bool
        ``auto``: when the gyroscope goes off while walking, ask the device to wake it by itself when its compass
        azimuth swings (``SensorConfig.wake_mode == "compass_swing"``): the host learns of a turn only from its next
        upload, the device within a magnetometer period. Off by default: measured on the IPIN dev trials it made
        ``auto`` worse (8 batch phases: 2.84 -> 3.10 m at energy 0.591 -> 0.611; docs/phone.md, "The device wakes
        its gyroscope on a compass swing"): the swing shows only once the device has turned by 34 deg (median), and
        the turn's start, taken from the compass, is what the compass gets wrong there.
    swing_rad, swing_window_s : float
        The swing: an azimuth change of more than ``swing_rad`` within ``swing_window_s`` (the IPIN trials' sensor
        statistics, :mod:`energy.compass_swing`).
    swing_sleep_s : float
        The device powers the gyroscope it woke down this long after the last swing: the host's reaction time
        (``batch_s`` plus ``stream_wait_s``), after which the host has seen the turn and decides itself.
    gyro_duty_period_s, gyro_duty_on_s : float
        ``auto``: where it switches the gyroscope off while walking, ask for it duty-cycled instead
        (``SensorConfig.gyr_duty_period_s`` ``P``, ``gyr_duty_on_s``: the device delivers ``gyr_duty_on_s`` of every
        ``P``), and fill each gap of at most ``1.5 P`` between two delivered windows with the straight line between
        the windows' mean rates (:class:`_DutyFill`), so that the MARG filter integrates a continuous rate and the
        step is a gyroscope step. 0, 0 (the default): off. Measured on the IPIN dev trials in docs/phone.md, "A
        duty-cycled gyroscope".
    gyro_duty_only : bool
        With the duty cycle: walking, the heading's forecast that decides whether ``auto`` asks for the full gyroscope
        is one duty-cycled step ahead, the heading's standard deviation grown by ``gyro_duty_sigma_rad`` (0: never
        above ``max_heading_std_rad``), not one gyroscope-off step ahead (the compass's, which must find the turns
        the duty cycle measures: docs/phone.md, 8.5 deg RMS per turn against the compass's 15.6); the full gyroscope
        still while the compass's noise is unknown. False: full where the default asks.
    gyro_duty_sigma_rad : float
        With the duty cycle: a step whose gyroscope samples were partly filled turns with this much more noise
        [rad] (times the filled fraction of the step, squared into the variance) than a gyroscope step, and its
        compass innovation does not teach the compass's noise (the heading it is measured against is not the full
        gyroscope's). 0 (the default): a filled step is a gyroscope step. docs/phone.md's measurement: 2.5 deg
        robust SD per straight step at ``P`` 0.5 s, ``d`` 0.3 (``python -m clients.evaluation.phone_duty``).
    batch_s : float
        Upload period asked of the device.
    stream_wait_s : float
        How long the accelerometer waits for a gyroscope or magnetometer stream that has gone silent (nothing
        arrived for this long of the accelerometer's time) before it is taken as off. A stream still delivering is
        waited for while its time stamps lag by at most ``stream_max_lag_s`` (the emulated 10-Hz magnetometer's
        filter delay is 0.8 s).
    stream_max_lag_s : float
        The most a delivering stream's time stamps may lag the accelerometer's and still be waited for: beyond it
        the merge goes on without the stream (its samples then come too late and are counted in
        ``late_samples``), so a stream whose clock falls ever further behind cannot hold the accelerometer's
        samples, and with them the answers, back without bound (10 s: 1000 accelerometer samples at 100 Hz held
        at most). A safety bound, far above the longest filter delay known (0.8 s), not a fitted value.
    run_step_hz : float
        Steps at this frequency or faster are labelled ``run``.
    """

    marg: MargConfig = field(default_factory=MargConfig)
    steps: StepDetectorConfig = field(default_factory=StepDetectorConfig)
    step_length: StepLengthConfig = field(default_factory=StepLengthConfig)
    heading: HeadingConfig = field(default_factory=lambda: PHONE_HEADING)
    placement: PlacementConfig = field(default_factory=PlacementConfig)
    directions: DominantDirectionsConfig | None = field(default_factory=DominantDirectionsConfig)
    acc_rate_hz: float = 50.0
    gyr_rate_hz: float = 100.0
    mag_rate_hz: float = 50.0
    walk_gyro: str = "on"
    auto_acc_rate_hz: float = 25.0
    walk_mag_rate_hz: float = 5.0
    auto_gyr_rate_hz: float = 25.0
    stand_acc_rate_hz: float = 25.0
    stand_mag_rate_hz: float = 5.0
    stand_after_s: float = 1.0
    max_heading_std_rad: float = math.radians(6.0)
    gyro_min_steps: int = 6
    marg_settled_std_rad: float = math.radians(20.0)
    orientation_rho: float = 0.91
    swing_wake: bool = False
    swing_rad: float = SWING_RAD
    swing_window_s: float = SWING_WINDOW_S
    swing_sleep_s: float = 1.5
    gyro_duty_period_s: float = 0.0
    gyro_duty_on_s: float = 0.0
    gyro_duty_only: bool = False
    gyro_duty_sigma_rad: float = 0.0
    batch_s: float = 1.0
    stream_wait_s: float = 0.5
    stream_max_lag_s: float = 10.0
    run_step_hz: float = 2.4

    def __post_init__(self) -> None:
        if self.walk_gyro not in WALK_GYRO:
            raise ValueError(f"PhoneEngineConfig: walk_gyro must be one of {', '.join(WALK_GYRO)}, got {self.walk_gyro!r}")
        for name in ("acc_rate_hz", "gyr_rate_hz", "mag_rate_hz", "auto_acc_rate_hz", "walk_mag_rate_hz", "auto_gyr_rate_hz",
                     "stand_acc_rate_hz",
                     "stand_mag_rate_hz", "stand_after_s", "max_heading_std_rad", "marg_settled_std_rad", "swing_rad",
                     "swing_window_s", "swing_sleep_s", "batch_s", "stream_wait_s", "stream_max_lag_s", "run_step_hz"):
            v = float(getattr(self, name))
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"PhoneEngineConfig: {name} must be a positive finite number, got {v!r}")
        if int(self.gyro_min_steps) < 1:
            raise ValueError("PhoneEngineConfig: gyro_min_steps must be >= 1")
        p, on = float(self.gyro_duty_period_s), float(self.gyro_duty_on_s)
        if not (math.isfinite(p) and math.isfinite(on) and p >= 0 and on >= 0 and (p > 0) == (on > 0)
                and (p == 0 or on < p)):
            raise ValueError("PhoneEngineConfig: gyro_duty_period_s and gyro_duty_on_s must both be 0 or both positive "
                             f"with gyro_duty_on_s below gyro_duty_period_s, got {p!r}, {on!r}")
        sd = float(self.gyro_duty_sigma_rad)
        if not (math.isfinite(sd) and sd >= 0):
            raise ValueError(f"PhoneEngineConfig: gyro_duty_sigma_rad must be finite and >= 0, got {sd!r}")
        if not 0.0 <= float(self.orientation_rho) < 1.0:
            raise ValueError(f"PhoneEngineConfig: orientation_rho must lie in [0, 1), got {self.orientation_rho!r}")

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> PhoneEngineConfig:
        d = dict(d)
        parts = {"marg": MargConfig.from_dict, "steps": StepDetectorConfig.from_dict,
                 "step_length": StepLengthConfig.from_dict, "heading": lambda x: HeadingConfig(**x),
                 "placement": lambda x: PlacementConfig(**x), "directions": DominantDirectionsConfig.from_dict}
        for k, f in parts.items():
            if d.get(k) is not None:
                d[k] = f(d[k])
        d["gyro_min_steps"] = int(d.get("gyro_min_steps", 6))
        return cls(**d)


class _Streams:
    """Samples waiting until every stream has reached their time (the merge horizon).

    A stream is waited for while it is delivering: while a sample of it arrived within the wait (``wait_ns`` of
    :meth:`horizon`) of the accelerometer's newest time, while its time stamps lag by at most ``max_lag_ns`` (a
    decimating filter's group delay: the emulated 10-Hz magnetometer's is 0.8 s). Only a stream that has gone silent (a gyroscope
    that is off, a device without magnetometer) is left behind after the wait. Silence is measured in arrival,
    the accelerometer's time at the upload that brought the stream's latest sample, not in time-stamp lag: with
    the lag, a stream lagging by ``L`` > ``wait_ns`` lost ``min(1, (L - wait) / batch)`` of its samples, every
    magnetometer sample with 0.25-s uploads (docs/phone.md, "Shorter batches do not buy the turns back").
    """

    def __init__(self) -> None:
        self.t = {n: np.zeros(0, dtype=np.int64) for n in STREAMS}
        self.v = {n: np.zeros((0, 3)) for n in STREAMS}
        self.last = {n: -(2 ** 62) for n in STREAMS}  # newest time received [ns]
        self.arrived = {n: -(2 ** 62) for n in STREAMS}  # the accelerometer's newest time when it last delivered [ns]
        self.done = -(2 ** 62)  # everything up to here was processed [ns]
        self.dropped = 0  # samples that came after their time had been processed
        self.dropped_by = {n: 0 for n in STREAMS}  # ... per stream

    def push(self, batch: SensorBatch, raw: SensorBatch | None = None) -> None:
        """Queue ``batch``'s samples; a stream delivered in this upload if it has samples in ``raw`` (default
        ``batch``: the upload as it came, before the duty cycle's gaps were filled)."""
        raw = batch if raw is None else raw
        first = self.last["acc"] == -(2 ** 62)
        for n in STREAMS:
            t, v = batch.stream(n)
            if not len(t):
                continue
            keep = t > self.done
            self.dropped += int(len(t) - keep.sum())
            self.dropped_by[n] += int(len(t) - keep.sum())
            t, v = t[keep], v[keep]
            if len(t):
                self.t[n] = np.concatenate([self.t[n], t])
                self.v[n] = np.concatenate([self.v[n], v])
                self.last[n] = max(self.last[n], int(t[-1]))
        for n in STREAMS:
            # the session's first upload presumes every stream delivering: one whose first samples are still in its
            # filter is waited for as one that went silent would be
            if len(raw.stream(n)[0]) or (first and self.last["acc"] > -(2 ** 62)):
                self.arrived[n] = self.last["acc"]

    def horizon(self, wait_ns: int, max_lag_ns: int) -> int:
        """Newest time [ns] every stream still delivering has reached, but no more than ``max_lag_ns`` behind the
        accelerometer's newest time (those silent for ``wait_ns``: the accelerometer's newest time less ``wait_ns``)."""
        la = self.last["acc"]
        h = la
        for n in ("gyr", "mag"):
            live = self.arrived[n] >= la - wait_ns
            h = min(h, max(self.last[n], la - max_lag_ns) if live else max(self.last[n], la - wait_ns))
        return h

    def take(self, upto_ns: int | None) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        out = {}
        for n in STREAMS:
            t = self.t[n]
            k = len(t) if upto_ns is None else int(np.searchsorted(t, upto_ns, side="right"))
            out[n] = (t[:k], self.v[n][:k])
            self.t[n], self.v[n] = t[k:], self.v[n][k:]
            if k:
                self.done = max(self.done, int(t[k - 1]))
        if upto_ns is not None:
            self.done = max(self.done, upto_ns)
        return out

    def get_state(self) -> dict[str, Any]:
        return {"t": {n: self.t[n] for n in STREAMS}, "v": {n: self.v[n] for n in STREAMS}, "last": dict(self.last),
                "arrived": dict(self.arrived),
                "done": self.done, "dropped": self.dropped, "dropped_by": dict(self.dropped_by)}

    @classmethod
    def from_state(cls, d: dict[str, Any]) -> _Streams:
        obj = cls()
        for n in STREAMS:
            obj.t[n] = np.asarray(d["t"][n], dtype=np.int64).reshape(-1)
            obj.v[n] = np.asarray(d["v"][n], dtype=np.float64).reshape(-1, 3)
            obj.last[n] = int(d["last"][n])
            obj.arrived[n] = int((d.get("arrived") or d["last"])[n])  # older states: time stamps as arrival
        obj.done, obj.dropped = int(d["done"]), int(d["dropped"])
        obj.dropped_by.update({n: int(v) for n, v in (d.get("dropped_by") or {}).items() if n in obj.dropped_by})
        return obj


class _DutyFill:
    """A duty-cycled gyroscope's stream made continuous (``PhoneEngineConfig.gyro_duty_period_s``).

    The samples arrive in runs (consecutive samples less than ``gap_ns`` apart: the on-windows, or a gyroscope that
    is fully on). Each gap of at most ``fill_ns`` (``1.5 P``) between two runs is filled at the earlier run's sample
    interval with the straight line between the earlier run's mean rate over its last ``on_ns`` and the later
    run's over its first ``on_ns`` (docs/phone.md, "A duty-cycled gyroscope": the ``interp`` estimator; the knots
    at the earlier run's last and the later run's first sample), so the MARG filter integrates a rate without
    holes. A gap's line needs the later window: its samples are held until its first ``on_ns`` is complete (a
    sample that late, or a gap), and :meth:`bound` tells the merge not to pass the samples given out while a
    successor within ``fill_ns`` may still come. The output depends on the samples only, not on how they were cut
    into batches (the close in :meth:`close` comes when no sample within ``fill_ns`` can still arrive).

    Parameters
    ----------
    period_s, on_s : float
        The duty cycle's period ``P`` and delivered time per period [s].
    rate_hz : float
        The gyroscope's rate when on [Hz]: a gap is an interval above 2.5 sample periods; the fill's interval
        when the earlier run has a single sample.
    """

    def __init__(self, period_s: float, on_s: float, rate_hz: float) -> None:
        self.on_ns = int(round(on_s * 1e9))
        self.fill_ns = int(round(1.5 * period_s * 1e9))
        self.gap_ns = int(round(2.5 / rate_hz * 1e9))
        self.dt0_ns = int(round(1e9 / rate_hz))
        self.last_t: int | None = None  # newest sample received [ns]
        self.out_last: int | None = None  # newest sample given out [ns]
        self.run_start = 0  # the current run's first sample [ns]
        self.run_dt = 0  # ... its latest interval [ns] (0: one sample so far)
        self.run_sum = np.zeros(3)  # ... sum and count of its samples within on_ns of its start
        self.run_n = 0
        self.run_done = False  # ... that mean is known
        self.run_mean = np.zeros(3)
        self.tail_t = np.zeros(0, dtype=np.int64)  # ... its samples within on_ns of its newest [ns, rad/s]
        self.tail_v = np.zeros((0, 3))
        self.gap: tuple[int, np.ndarray, int] | None = None  # a gap before the current run: (t, mean rate, interval)
        self.held_t = np.zeros(0, dtype=np.int64)  # the current run's samples held for the gap's line
        self.held_v = np.zeros((0, 3))
        self.fills: list[list[int]] = []  # the gaps filled [t_a, t_b] [ns] (pruned by the engine)

    def filled_ns(self, t0: int, t1: int) -> int:
        """How much of ``[t0, t1)`` [ns] was filled (not measured)."""
        return int(sum(max(0, min(b, t1) - max(a, t0)) for a, b in self.fills))

    def prune(self, before_ns: int) -> None:
        """Forget the fills that ended before ``before_ns``."""
        self.fills = [f for f in self.fills if f[1] >= before_ns]

    def _resolve(self, out_t: list[np.ndarray], out_v: list[np.ndarray]) -> None:
        """The current run's mean is known: give out the gap's line and the held samples."""
        if self.gap is not None and len(self.held_t):
            ta, ma, dt = self.gap
            tb = int(self.held_t[0])
            n = max(0, int(np.ceil((tb - dt / 2 - ta) / dt)) - 1)
            ft = ta + dt * np.arange(1, n + 1, dtype=np.int64)
            w = ((ft - ta) / (tb - ta))[:, None]
            out_t.append(ft)
            out_v.append(ma[None, :] + (self.run_mean - ma)[None, :] * w)
            self.fills.append([int(ta), tb])
        out_t.append(self.held_t)
        out_v.append(self.held_v)
        self.gap = None
        self.held_t, self.held_v = self.held_t[:0], self.held_v[:0]

    def _complete(self, out_t: list[np.ndarray], out_v: list[np.ndarray]) -> None:
        if not self.run_done:
            self.run_done = True
            self.run_mean = self.run_sum / max(self.run_n, 1)
            self._resolve(out_t, out_v)

    def push(self, t: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Take new samples (time order) and return those given out, fills included."""
        out_t: list[np.ndarray] = []
        out_v: list[np.ndarray] = []
        for i in range(len(t)):
            ti, vi = int(t[i]), np.asarray(v[i], dtype=np.float64)
            if self.last_t is not None and ti <= self.last_t:
                continue
            if self.last_t is None or ti - self.last_t > self.gap_ns:
                gap = None
                if self.last_t is not None:
                    self._complete(out_t, out_v)  # the run ended: its first on_ns is what it has
                    if ti - self.last_t <= self.fill_ns:
                        m = self.tail_v.mean(axis=0) if len(self.tail_v) else self.run_mean
                        gap = (self.last_t, m, self.run_dt or self.dt0_ns)
                self.gap, self.run_start, self.run_dt = gap, ti, 0
                self.run_sum, self.run_n, self.run_done = np.zeros(3), 0, False
                self.tail_t, self.tail_v = self.tail_t[:0], self.tail_v[:0]
            else:
                self.run_dt = ti - self.last_t
            if not self.run_done and ti >= self.run_start + self.on_ns:
                self._complete(out_t, out_v)
            if not self.run_done:
                self.run_sum += vi
                self.run_n += 1
            keep = self.tail_t > ti - self.on_ns
            self.tail_t = np.append(self.tail_t[keep], ti)
            self.tail_v = np.vstack([self.tail_v[keep], vi[None, :]])
            if self.gap is not None and not self.run_done:
                self.held_t = np.append(self.held_t, ti)
                self.held_v = np.vstack([self.held_v, vi[None, :]])
            else:
                out_t.append(np.array([ti], dtype=np.int64))
                out_v.append(vi[None, :])
            self.last_t = ti
        return self._out(out_t, out_v)

    def _out(self, out_t: list[np.ndarray], out_v: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        ot = np.concatenate(out_t).astype(np.int64) if out_t else np.zeros(0, dtype=np.int64)
        ov = np.concatenate(out_v).reshape(-1, 3) if out_v else np.zeros((0, 3))
        if len(ot):
            self.out_last = int(ot[-1])
        return ot, ov

    def close(self, now_ns: int | None) -> tuple[np.ndarray, np.ndarray]:
        """``now_ns`` (the accelerometer's newest time less the stream wait; None: the session's end) is more than
        ``fill_ns`` past the newest sample: no gap after it will be filled; give out what is held."""
        out_t: list[np.ndarray] = []
        out_v: list[np.ndarray] = []
        if self.last_t is not None and (now_ns is None or now_ns > self.last_t + self.fill_ns):
            self._complete(out_t, out_v)
            if len(self.held_t):
                self._resolve(out_t, out_v)
        return self._out(out_t, out_v)

    def bound(self, now_ns: int) -> int | None:
        """The newest time [ns] the merge may reach: the newest sample given out while a gap after it may still be
        filled (``now_ns``, the accelerometer's newest time less the stream wait, within ``fill_ns`` of the newest
        sample received); None: no bound."""
        if self.last_t is None or now_ns > self.last_t + self.fill_ns:
            return None
        if self.out_last is None:
            return (int(self.held_t[0]) - 1) if len(self.held_t) else self.last_t
        return self.out_last

    def get_state(self) -> dict[str, Any]:
        return {"on_ns": self.on_ns, "fill_ns": self.fill_ns, "gap_ns": self.gap_ns, "dt0_ns": self.dt0_ns,
                "last_t": self.last_t, "out_last": self.out_last, "run_start": self.run_start, "run_dt": self.run_dt,
                "run_sum": self.run_sum, "run_n": self.run_n, "run_done": self.run_done, "run_mean": self.run_mean,
                "tail_t": self.tail_t, "tail_v": self.tail_v,
                "gap": None if self.gap is None else [self.gap[0], self.gap[1], self.gap[2]],
                "held_t": self.held_t, "held_v": self.held_v,
                "fills": np.asarray(self.fills, dtype=np.int64).reshape(-1, 2)}

    @classmethod
    def from_state(cls, d: dict[str, Any]) -> _DutyFill:
        obj = cls.__new__(cls)
        for k in ("on_ns", "fill_ns", "gap_ns", "dt0_ns", "run_start", "run_dt", "run_n"):
            setattr(obj, k, int(d[k]))
        obj.last_t = None if d["last_t"] is None else int(d["last_t"])
        obj.out_last = None if d["out_last"] is None else int(d["out_last"])
        obj.run_done = bool(d["run_done"])
        obj.run_sum = np.asarray(d["run_sum"], dtype=np.float64).reshape(3).copy()
        obj.run_mean = np.asarray(d["run_mean"], dtype=np.float64).reshape(3).copy()
        obj.tail_t = np.asarray(d["tail_t"], dtype=np.int64).reshape(-1)
        obj.tail_v = np.asarray(d["tail_v"], dtype=np.float64).reshape(-1, 3)
        g = d["gap"]
        obj.gap = None if g is None else (int(g[0]), np.asarray(g[1], dtype=np.float64).reshape(3).copy(), int(g[2]))
        obj.held_t = np.asarray(d["held_t"], dtype=np.int64).reshape(-1)
        obj.held_v = np.asarray(d["held_v"], dtype=np.float64).reshape(-1, 3)
        obj.fills = np.asarray(d.get("fills", []), dtype=np.int64).reshape(-1, 2).tolist()
        return obj


class PhoneEngine:
    """One step-and-heading navigation session (see the module docstring).

    ``NORTH_REFERENCE = "magnetic"``: positions and headings are in NED about the first step with magnetic north
    (the compass's), as :func:`models.geo.engine_north` reads it.

    Parameters
    ----------
    mode : {"auto", "always-on"}
        Energy-aware sensor scheduling, or every sensor at its full rate.
    config : PhoneEngineConfig, optional
    profile : dict, optional
        The user's calibration profile (``behaviours["pdr"]``: step length per placement).
    device_kind : {"phone", "watch"}
    placement : str, optional
        Given by the client; None: recognised (a phone: hand or pocket).
    anchor : (latitude_deg, longitude_deg, altitude_m), optional
        The session's geodetic start: the WMM field there weighs the compass (north stays magnetic).
    date : datetime.date, optional
        Date for the WMM (default: today, UTC).
    trace : bool
        Keep the positions in :attr:`trace` (evaluation); not part of the state.
    """

    NORTH_REFERENCE = "magnetic"

    def __init__(
        self,
        mode: str = "auto",
        config: PhoneEngineConfig | None = None,
        profile: dict[str, Any] | None = None,
        device_kind: str = "phone",
        placement: str | None = None,
        anchor: tuple[float, float, float] | None = None,
        date: _dt.date | None = None,
        trace: bool = False,
    ) -> None:
        if mode not in PHONE_MODES:
            raise ValueError(f"mode: expected one of {PHONE_MODES}, got {mode!r}")
        if device_kind not in ("phone", "watch"):
            raise ValueError(f"device_kind: the step-and-heading engine serves phones and watches, got {device_kind!r}")
        if placement is not None and (placement not in STEP_AND_HEADING or (device_kind == "watch") != (placement == "watch")):
            raise ValueError(f"placement: the step-and-heading engine serves a {device_kind} as "
                             f"{'watch' if device_kind == 'watch' else 'phone-hand or phone-pocket'}, got {placement!r}")
        self.mode = mode
        self.config = config or PhoneEngineConfig()
        self.trace = _new_trace() if trace else None
        self.anchor = None if anchor is None else tuple(float(x) for x in anchor)
        self.date = date
        ref = None if self.anchor is None else _magnetic_reference(self.anchor, date)
        self.declination_rad = 0.0  # magnetic north: the declination is applied when geo-referenced
        self._pdr = PdrState.new(MargState.new(self.config.marg, ref, 0.0))
        self._placement = PlacementRecognizer(device_kind, placement, self.config.placement)
        self._profile_in = profile
        self._lengths = {p: self._new_length(p, profile) for p in STEP_AND_HEADING}
        self._heading = HeadingEstimator(self.config.heading)
        self._directions = None if self.config.directions is None else DominantDirections(self.config.directions)
        self._streams = _Streams()
        c = self.config
        self._duty = (_DutyFill(c.gyro_duty_period_s, c.gyro_duty_on_s, c.auto_gyr_rate_hz)
                      if mode == "auto" and c.gyro_duty_period_s > 0 else None)
        self._t0_ns: int | None = None
        self._pos = np.zeros(2)  # [north, east] m
        self._prev_dir = math.nan  # the gyroscope-carried walking direction of the previous step [rad]
        self._prev_gyro = False
        self._gyro_run = 0  # consecutive gyroscope-carried steps
        self._cadence = 0  # consecutive steps of a steady gait
        self._fields: list[list[float]] = []  # [vertical, horizontal] field of the latest steps [uT]
        self._reading: tuple[float, float, float] | None = None  # the latest compass reading's noise terms
        self._turned = False  # the latest step took a turn the gyroscope did not see
        self._locked = False  # the latest step was straight along the building's dominant directions
        self._last_step_s = -math.inf
        self._gyro_want = True
        self._gyro_steps = 0  # steps since the gyroscope was last asked for
        self._bias_pending = True  # the vertical gyroscope bias has not settled since the start or the last wave
        self._returning = False  # the gyroscope came back and its own turns carry the heading until the filter settles
        self._behaviour = "other"  # not known before the first step or stand
        self._started = False
        self._log: list[list[float]] = []  # [t_ns, unscaled length, placement index] of the latest steps
        self._config_now = self._sensor_config()

    # ------------------------------------------------------------------ contract
    @property
    def sensor_config(self) -> SensorConfig:
        """The configuration the device must use for its next batch."""
        return self._config_now

    @property
    def placement(self) -> str:
        return self._placement.placement

    @property
    def late_samples(self) -> dict[str, int]:
        """Samples per stream that arrived after the merge had passed their time and were not used (a stream
        that was silent for longer than ``stream_wait_s`` and then delivered samples older than the merge's time;
        at the session's start, a stream whose first samples come more than ``stream_wait_s`` after the first
        upload)."""
        return dict(self._streams.dropped_by)

    def feed(self, batch: SensorBatch) -> Update:
        """Consume one batch.

        Raises
        ------
        models.batch.BatchError
            Malformed batch (non-finite values, timestamps not increasing, implausible units, or accelerometer
            samples older than ones already processed); the engine is then unchanged.
        """
        batch.validate()
        t_acc = batch.acc_t_ns
        if len(t_acc) and int(t_acc[0]) <= self._streams.done:
            raise BatchError("acc_t_ns", f"sample at {int(t_acc[0])} ns is not after the last one processed ({self._streams.done} ns)")
        if self._t0_ns is None and batch.t_start_ns is not None:
            self._t0_ns = int(batch.t_start_ns)
        wait_ns = int(self.config.stream_wait_s * 1e9)
        if self._duty is None:
            self._streams.push(batch)
        else:
            la = max(self._streams.last["acc"], int(t_acc[-1]) if len(t_acc) else -(2 ** 62))
            gt, gv = self._duty.push(batch.gyr_t_ns, batch.gyr)
            ct, cv = self._duty.close(la - wait_ns)
            self._streams.push(_replace(batch, gyr_t_ns=np.concatenate([gt, ct]), gyr=np.concatenate([gv, cv])), raw=batch)
        if not len(self._streams.t["acc"]):
            return self._update([], [])
        h = self._streams.horizon(wait_ns, int(self.config.stream_max_lag_s * 1e9))
        if self._duty is not None:
            b = self._duty.bound(self._streams.last["acc"] - wait_ns)
            h = h if b is None else min(h, b)
        return self._process(self._streams.take(h))

    def flush(self) -> Update:
        """End of the session: process what waits for lagging streams."""
        if self._duty is not None:
            ct, cv = self._duty.close(None)
            if len(ct):
                e = np.zeros(0, dtype=np.int64)
                self._streams.push(SensorBatch(acc_t_ns=e, acc=np.zeros((0, 3)), gyr_t_ns=ct, gyr=cv,
                                               mag_t_ns=e, mag=np.zeros((0, 3))))
        return self._process(self._streams.take(None))

    def profile_dict(self) -> dict[str, Any]:
        """The user's profile with this session's step-length calibration, JSON-serialisable."""
        placements = {p: L.calibration() for p, L in self._lengths.items() if L.calibrated}
        base = ((self._profile_in or {}).get("behaviours") or {}).get(PROFILE_KEY) or {}
        stored = dict((base.get("step_model") or {}).get("placements") or {})
        stored.update(placements)
        n = int(sum(v.get("n_steps", 0) for v in stored.values()))
        cal = {"step_model": {"placements": stored, "height_m": self.config.step_length.height_m,
                              "model": self.config.step_length.model},
               "sigma_d_m": float("nan"), "heading_deviation_rad": 0.0, "heading_deviation_var": float("nan"),
               "n_steps": n, "calibrated": bool(stored)}
        return {"version": 1, "behaviours": {PROFILE_KEY: cal} if stored else {}}

    def calibrate_distance(self, t0_ns: int, t1_ns: int, distance_m: float) -> Event:
        """A known distance [m] walked between two times [ns] (user-entered, a foot-sensor session, a GNSS
        stretch): calibrates the step length of the placement of those steps (000 Section 5.2: "by walking a
        distance"). Returns the ``calibration`` event.

        Raises
        ------
        ValueError
            Bad distance or times, or too few steps between the times.
        """
        if not t1_ns > t0_ns:
            raise ValueError(f"t1_ns: must be after t0_ns ({t0_ns}), got {t1_ns}")
        rows = [r for r in self._log if t0_ns < r[0] <= t1_ns]
        if not rows:
            raise ValueError("steps: no step of this session lies between t0_ns and t1_ns")
        placement = STEP_AND_HEADING[int(np.bincount([int(r[2]) for r in rows]).argmax())]
        out = self._lengths[placement].calibrate(float(distance_m), np.array([r[1] for r in rows]))
        return Event(int(t1_ns), "calibration", {"placement": placement, "distance_m": float(distance_m), **out})

    # ------------------------------------------------------------------ processing
    def _new_length(self, placement: str, profile: dict[str, Any] | None) -> PdrStepLength:
        cal = ((profile or {}).get("behaviours") or {}).get(PROFILE_KEY) or {}
        stored = ((cal.get("step_model") or {}).get("placements") or {}).get(placement)
        return PdrStepLength(self.config.step_length, stored if isinstance(stored, dict) else None)

    def _process(self, streams: dict[str, tuple[np.ndarray, np.ndarray]]) -> Update:
        events: list[Event] = []
        positions: list[Position] = []
        if not self._started and self._t0_ns is not None:
            self._started = True
            events.append(Event(self._t0_ns, "heading_reference", {
                "north": "magnetic", "wmm_field": self.anchor is not None, "placement": self.placement,
                "recognised": not self._placement.fixed}))
        t, kind, v = merge_streams(streams["acc"], streams["gyr"], streams["mag"])
        if len(t) and self._t0_ns is not None:
            ts = (t - self._t0_ns).astype(np.float64) * 1e-9
            recs = run_pdr(self._pdr, self.config.marg.as_array(), self.config.steps.as_array(), ts, kind, v)
            for r in recs:
                self._step(r, positions, events)
            last_acc = streams["acc"][0]
            if len(last_acc):
                self._stand_check(float((int(last_acc[-1]) - self._t0_ns) * 1e-9), events)
            self._bias_check(float(ts[-1]), events)
        return self._update(positions, events)

    def _bias_check(self, now_s: float, events: list[Event]) -> None:
        """Has the vertical gyroscope bias settled since the start and the device's latest wave
        (:func:`models.marg.bias_settled`)? ``auto`` keeps the gyroscope on while standing until it has."""
        from models import marg as M

        pending = not M.bias_settled(self._pdr.marg.s)
        if self._bias_pending and not pending and self._t0_ns is not None:
            events.append(Event(self._t0_ns + int(round(now_s * 1e9)), "gyro_bias",
                                {"settled": True, "std_rad_s": self._pdr.marg.vertical_bias_std_rad_s}))
        self._bias_pending = pending

    def _direction(self, r: np.ndarray) -> tuple[float, float]:
        """Walking direction of a step in the filter's frame and as the compass sees it [rad]."""
        if self.placement == "phone-hand":
            d = float(r[_F["fwd_az"]])
        else:
            d = float(r[_F["pca_az"]])
            if not math.isfinite(d):
                d = float(r[_F["fwd_az"]])
            elif r[_F["pca_sign"]] < 0 or (r[_F["pca_sign"]] == 0 and math.isfinite(self._prev_dir)
                                           and abs(wrap(d - self._prev_dir)) > math.pi / 2):
                d = wrap(d + math.pi)
        fa = float(r[_F["field_az"]])
        compass = wrap(d + self.declination_rad - fa) if math.isfinite(fa) and r[_F["n_mag"]] > 0 else math.nan
        return d, compass

    def _step(self, r: np.ndarray, positions: list[Position], events: list[Event]) -> None:
        assert self._t0_ns is not None
        t_s = float(r[_F["t_s"]])
        t_ns = self._t0_ns + int(round(t_s * 1e9))
        changed = self._placement.step(float(r[_F["tilt_r"]]), float(r[_F["rate_rad_s"]]))
        if changed is not None:
            events.append(Event(t_ns, "placement_changed", {"placement": changed}))
            self._prev_dir = math.nan  # the direction's source changed: no increment across it
        period = float(r[_F["period_s"]])
        f_hz = 1.0 / period if math.isfinite(period) and period > 0 else math.nan
        direction, compass = self._direction(r)
        gyro = bool(r[_F["gyro_frac"]] >= 0.9)
        self._cadence = self._cadence + 1 if steady_step(period, float(r[_F["rate_rad_s"]])) else 0
        walking = self._cadence >= 2
        stood = t_s - self._last_step_s >= self.config.stand_after_s
        self._track(r, direction, compass, gyro, walking, stood, t_ns, events)
        self._prev_dir = direction if gyro else math.nan
        self._prev_gyro = gyro
        self._gyro_run = self._gyro_run + 1 if gyro else 0
        self._gyro_steps += 1
        hd = self._heading
        if not hd.started:
            return  # no heading yet: neither gyroscope nor compass has said anything
        L = self._lengths[self.placement]
        length = L.length(float(r[_F["a_max"]]), float(r[_F["a_min"]]), f_hz)
        self._log.append([float(t_ns), L.unscaled(float(r[_F["a_max"]]), float(r[_F["a_min"]]), f_hz),
                          float(STEP_AND_HEADING.index(self.placement))])
        if len(self._log) > _LOG_STEPS:
            del self._log[: len(self._log) - _LOG_STEPS]
        heading = hd.heading
        self._pos += length * np.array([math.cos(heading), math.sin(heading)])
        self._behaviour = "run" if math.isfinite(f_hz) and f_hz >= self.config.run_step_hz else "walk"
        self._last_step_s = t_s
        p = Position(t_ns, float(self._pos[0]), float(self._pos[1]), 0.0, float(heading), self._behaviour, "pdr",
                     float(length), gyro)
        positions.append(p)
        if self.trace is not None:
            self.trace.append(np.array([t_ns], dtype=np.int64), np.array([[p.north, p.east, 0.0]]),
                              np.array([p.behaviour]), np.array(["pdr"]), np.array([gyro]))
        self._schedule(t_ns, events)

    def _field_noise(self, r: np.ndarray) -> tuple[float, float]:
        """The heading [rad] the step's field could be turned by (:meth:`models.heading.CompassNoise.field_sigma`):
        its anomaly against the Earth's field (the WMM's at the anchor; without one, the median of the recent
        steps' fields) and its change since the previous step's field."""
        f_ut, dip = float(r[_F["field_ut"]]), float(r[_F["dip_rad"]])
        if not (r[_F["n_mag"]] > 0 and math.isfinite(f_ut) and math.isfinite(dip)):
            return math.inf, math.inf
        b_v, b_h = f_ut * math.sin(dip), f_ut * math.cos(dip)
        ref_h, ref_v = float(self._pdr.marg.ref[0]), float(self._pdr.marg.ref[1])
        recent = self._fields
        if not ref_h > 0.0:
            ref_v, ref_h = (float(np.median([x[0] for x in recent])), float(np.median([x[1] for x in recent]))) \
                if recent else (b_v, b_h)
        anomaly = CompassNoise.field_sigma(b_v, b_h, ref_v, ref_h)
        change = anomaly if not recent else CompassNoise.field_sigma(b_v, b_h, *recent[-1])
        recent.append([b_v, b_h])
        del recent[:-_FIELD_STEPS]
        return anomaly, change

    def _track(self, r: np.ndarray, direction: float, compass: float, gyro: bool, walking: bool, stood: bool,
               t_ns: int, events: list[Event]) -> None:
        """One step through the heading estimator (:class:`models.heading.HeadingEstimator`), then the building's
        dominant directions."""
        hd = self._heading
        c = self.config
        anomaly, change = self._field_noise(r)
        r_c = hd.noise.reading_variance(0.0)  # the compass's own noise; the estimator adds the place's
        has_c = math.isfinite(compass) and math.isfinite(anomaly)
        self._reading = (r_c, anomaly, change if math.isfinite(change) else 0.0) if has_c else None
        yaw_std = float(r[_F["yaw_std"]])
        self._turned = False
        if not hd.started:
            if gyro and yaw_std < 1.0:
                hd.start(direction, yaw_std ** 2)  # the MARG filter's heading (its compass updates included)
            elif has_c:
                hd.start(compass, r_c + hd.noise.place_var)
            elif gyro and math.isfinite(direction) and math.isfinite(yaw_std):
                # no compass reading (a device without magnetometer, or none yet): the MARG filter's heading, as
                # uncertain as it says (its prior: unknown); the gyroscope carries the turns, a later compass sets it
                hd.start(direction, yaw_std ** 2)
                events.append(Event(t_ns, "heading_reference", {
                    "north": "initial-heading", "reason": "no magnetometer reading: headings are relative to the "
                    "device's first attitude until one arrives", "placement": self.placement}))
            else:
                return
            hd.set_offset_prior(0.0, c.heading.offset_prior_rad)  # the compass reads in theta's frame (magnetic north)
            return
        dc = 0.0 if not math.isfinite(change) else change
        dyaw = float(r[_F["gyro_dyaw"]])
        extra = self._duty_var(r, t_ns) if gyro else 0.0
        if gyro:  # the time since the previous step the gyroscope did not see (after a stand, part of it) turns freely
            frac = float(r[_F["gyro_frac"]])
            since = float(r[_F["t_s"]]) - self._last_step_s if math.isfinite(self._last_step_s) else 0.0
            unseen = (1.0 - frac) * since
            if unseen > c.marg.gyro_gap_s:
                extra += c.marg.no_gyro_rad_s ** 2 * unseen
                if stood:
                    dc = 0.0  # one place: the compass's change is the turn
        learn = walking and extra == 0.0
        settled = (gyro and self._prev_gyro and math.isfinite(self._prev_dir) and self._gyro_run >= c.gyro_min_steps
                   and yaw_std < c.marg_settled_std_rad)
        # the gyroscope has come back (after a stretch without it) and its bias has settled: until the MARG
        # filter has settled again, the heading turns by the gyroscope's own measured turn over the step, not by
        # the filter's heading, which is converging onto its compass (a re-snap to the compass's place error)
        follow = (gyro and not settled and r[_F["bias_settled"]] > 0.5 and math.isfinite(dyaw)
                  and (not self._prev_gyro or self._returning))
        self._returning = follow
        if settled:
            hd.predict_gyro(wrap(direction - self._prev_dir), dc, extra)  # the MARG filter's change over the step
            if has_c:
                hd.update_compass(compass, r_c, anomaly, learn=learn)
        elif follow:
            hd.predict_gyro(dyaw, dc, extra)
            if has_c:
                hd.update_compass(compass, r_c, anomaly, learn=learn)
        elif gyro and self._prev_gyro and math.isfinite(self._prev_dir):
            # the MARG filter is still converging (the session just began, or the gyroscope came back before its
            # bias settled): its heading moves with its compass corrections, so its changes are not the walker's;
            # its heading is an observation with the variance it states
            hd.predict_free(field_change=dc)
            hd.update_heading(direction, yaw_std ** 2)
            if has_c:
                hd.update_compass(compass, r_c, anomaly, learn=walking)
        else:
            # without the gyroscope; after a stand at one place the field's change is nil, so the compass's
            # change is the turn made standing
            hd.predict_free(field_change=0.0 if stood else dc)
            if has_c:
                hd.update_compass(compass, r_c, anomaly)
                self._turned = hd.turn_prob > 0.5
                if self._turned:
                    events.append(Event(t_ns, "turn", {"heading_rad": hd.heading, "source": "compass"}))
        self._locked = False
        if self._directions is not None:
            ref = self._directions.step(hd.heading, compass, walking)
            if ref is not None:
                dd = c.directions
                assert dd is not None
                off_grid = (wrap(hd.heading - ref) + math.pi / 4) % (math.pi / 2) - math.pi / 4
                self._locked = abs(off_grid) < dd.gate_rad
                sigma = dd.sigma_rad
                if c.orientation_rho > 0:  # the orientation's own error adds to how straight people walk
                    sigma = math.hypot(sigma, self._directions.orientation_std_rad(c.orientation_rho))
                hd.update_dominant(ref, sigma, dd.gate_rad)

    def _duty_var(self, r: np.ndarray, t_ns: int) -> float:
        """The added turn variance [rad^2] of a step whose gyroscope samples were partly filled
        (``gyro_duty_sigma_rad`` squared, times the step's filled fraction over the duty cycle's off fraction, at
        most 1); 0 without the duty cycle or its noise."""
        c = self.config
        if self._duty is None or not c.gyro_duty_sigma_rad > 0:
            return 0.0
        period = float(r[_F["period_s"]])
        span = int(round((period if math.isfinite(period) and period > 0 else 0.5) * 1e9))
        self._duty.prune(t_ns - 10 * span)
        frac = self._duty.filled_ns(t_ns - span, t_ns) / span
        off = 1.0 - c.gyro_duty_on_s / c.gyro_duty_period_s
        return c.gyro_duty_sigma_rad ** 2 * min(1.0, frac / off)

    def _schedule(self, t_ns: int, events: list[Event]) -> None:
        """Gyroscope on demand (``auto``, ``walk_gyro="on-demand"``): after each step."""
        c = self.config
        if self.mode != "auto" or c.walk_gyro != "on-demand":
            return
        hd = self._heading
        locked = self._locked
        learnt = len(hd.noise.samples)
        if self._reading is None:
            forecast = math.inf
        else:
            forecast = hd.forecast(*self._reading)[0]
        if c.gyro_duty_period_s > 0 and c.gyro_duty_only:
            # the step ahead is a duty-cycled one: its heading grows by the duty cycle's own noise, not by a turn the
            # compass must find (without that noise the duty cycle is taken as the gyroscope: never uncertain)
            forecast = math.hypot(hd.std, c.gyro_duty_sigma_rad) if c.gyro_duty_sigma_rad > 0 else 0.0
        uncertain = forecast > c.max_heading_std_rad and not locked
        want = (self._turned or learnt < c.gyro_min_steps
                or uncertain
                or (self._gyro_want and self._gyro_steps < c.gyro_min_steps))
        if want != self._gyro_want:
            reason = ("turn" if self._turned else "compass noise unknown" if learnt < c.gyro_min_steps
                      else "heading uncertain" if want else "straight along the building" if locked
                      else "compass consistent")
            events.append(Event(t_ns, "gyro", {"on": want, "reason": reason, "heading_std_rad": hd.std,
                                               "compass_std_rad": math.sqrt(hd.noise.reading_variance(0.0)
                                                                            + hd.noise.place_var)}))
            self._gyro_want = want
            self._gyro_steps = 0

    def _stand_check(self, now_s: float, events: list[Event]) -> None:
        """Standing: no step for ``stand_after_s`` with a still accelerometer."""
        from models import marg as M

        still = bool(self._pdr.marg.s[M.S_STILL] > 0.5)
        standing = still and now_s - self._last_step_s >= self.config.stand_after_s
        if standing and self._behaviour != "stand":
            self._behaviour = "stand"
        elif not standing and self._behaviour == "stand" and now_s - self._last_step_s < self.config.stand_after_s:
            self._behaviour = "walk"

    def _sensor_config(self) -> SensorConfig:
        c = self.config
        if self.mode == "always-on":
            return SensorConfig(True, c.acc_rate_hz, c.gyr_rate_hz, c.mag_rate_hz, c.batch_s)
        if self._behaviour == "stand":
            if self._bias_pending:  # the quasi-static field settles the gyroscope's bias: keep it on
                return SensorConfig(True, c.stand_acc_rate_hz, c.auto_gyr_rate_hz, c.stand_mag_rate_hz, c.batch_s)
            return SensorConfig(False, c.stand_acc_rate_hz, 0.0, c.stand_mag_rate_hz, c.batch_s)
        if c.walk_gyro == "on" or self._gyro_want:
            return SensorConfig(True, c.auto_acc_rate_hz, c.auto_gyr_rate_hz, c.walk_mag_rate_hz, c.batch_s)
        if c.gyro_duty_period_s > 0:  # the device duty-cycles the gyroscope by itself
            return SensorConfig(True, c.auto_acc_rate_hz, c.auto_gyr_rate_hz, c.walk_mag_rate_hz, c.batch_s,
                                gyr_duty_period_s=c.gyro_duty_period_s, gyr_duty_on_s=c.gyro_duty_on_s)
        if c.swing_wake:  # the device wakes the gyroscope itself on a turn (compass swing)
            return SensorConfig(False, c.auto_acc_rate_hz, c.auto_gyr_rate_hz, c.walk_mag_rate_hz, c.batch_s,
                                gyro_wake_on_motion=True, sleep_after_s=c.swing_sleep_s, wake_mode="compass_swing",
                                wake_swing_rad=c.swing_rad, wake_window_s=c.swing_window_s)
        return SensorConfig(False, c.auto_acc_rate_hz, 0.0, c.walk_mag_rate_hz, c.batch_s)

    def _update(self, positions: list[Position], events: list[Event]) -> Update:
        self._config_now = self._sensor_config()
        mode = "idle" if self._behaviour == "stand" else "pdr"
        return Update(positions, events, self._config_now, self._behaviour, mode)

    # ------------------------------------------------------------------ state
    def get_state(self) -> dict[str, Any]:
        return {
            "version": _STATE_VERSION,
            "engine": "step-and-heading",
            "mode": self.mode,
            "config": self.config.to_dict(),
            "anchor": None if self.anchor is None else list(self.anchor),
            "date": None if self.date is None else self.date.isoformat(),
            "declination_rad": self.declination_rad,
            "pdr": self._pdr.get_state(),
            "placement": self._placement.get_state(),
            "profile_in": self._profile_in,
            "lengths": {p: L.get_state() for p, L in self._lengths.items()},
            "heading": self._heading.get_state(),
            "directions": None if self._directions is None else self._directions.get_state(),
            "streams": self._streams.get_state(),
            "duty": None if self._duty is None else self._duty.get_state(),
            "t0_ns": self._t0_ns,
            "pos": self._pos,
            "prev_dir": self._prev_dir,
            "prev_gyro": self._prev_gyro,
            "gyro_run": self._gyro_run,
            "cadence": self._cadence,
            "fields": np.asarray(self._fields, dtype=np.float64).reshape(-1, 2),
            "reading": None if self._reading is None else list(self._reading),
            "turned": self._turned,
            "locked": self._locked,
            "last_step_s": self._last_step_s,
            "gyro_want": self._gyro_want,
            "gyro_steps": self._gyro_steps,
            "bias_pending": self._bias_pending,
            "returning": self._returning,
            "behaviour": self._behaviour,
            "started": self._started,
            "log": np.asarray(self._log, dtype=np.float64).reshape(-1, 3),
        }

    @classmethod
    def from_state(cls, d: dict[str, Any], trace: bool = False) -> PhoneEngine:
        if d.get("engine") != "step-and-heading" or d.get("version") != _STATE_VERSION:
            raise ValueError(f"not a step-and-heading engine state of version {_STATE_VERSION}")
        pl = d["placement"]
        date = None if d["date"] is None else _dt.date.fromisoformat(d["date"])
        obj = cls(mode=d["mode"], config=PhoneEngineConfig.from_dict(d["config"]), profile=None,
                  device_kind=pl["device_kind"], placement=None, anchor=None, date=date, trace=trace)
        obj.anchor = None if d["anchor"] is None else tuple(float(x) for x in d["anchor"])
        obj.declination_rad = float(d["declination_rad"])
        obj._pdr = PdrState.from_state(d["pdr"])
        obj._placement = PlacementRecognizer.from_state(pl)
        obj._profile_in = d["profile_in"]
        obj._lengths = {p: PdrStepLength.from_state(s) for p, s in d["lengths"].items()}
        obj._heading = HeadingEstimator.from_state(obj.config.heading, d["heading"])
        obj._directions = None if d["directions"] is None else DominantDirections.from_state(d["directions"])
        obj._streams = _Streams.from_state(d["streams"])
        if d.get("duty") is not None:  # older states: no duty cycle (the default), the new engine's own filler
            obj._duty = _DutyFill.from_state(d["duty"])
        obj._t0_ns = None if d["t0_ns"] is None else int(d["t0_ns"])
        obj._pos = np.asarray(d["pos"], dtype=float).reshape(2).copy()
        obj._prev_dir = float(d["prev_dir"])
        obj._prev_gyro = bool(d["prev_gyro"])
        obj._gyro_run = int(d["gyro_run"])
        obj._cadence = int(d["cadence"])
        obj._fields = np.asarray(d["fields"], dtype=np.float64).reshape(-1, 2).tolist()
        obj._reading = None if d["reading"] is None else tuple(float(x) for x in d["reading"])  # type: ignore[assignment]
        obj._turned, obj._locked = bool(d["turned"]), bool(d["locked"])
        obj._last_step_s = float(d["last_step_s"])
        obj._gyro_want = bool(d["gyro_want"])
        obj._gyro_steps = int(d["gyro_steps"])
        obj._bias_pending = bool(d.get("bias_pending", True))
        obj._returning = bool(d.get("returning", False))
        obj._behaviour = str(d["behaviour"])
        obj._started = bool(d["started"])
        obj._log = np.asarray(d["log"], dtype=np.float64).reshape(-1, 3).tolist()
        obj._config_now = obj._sensor_config()
        return obj

    def to_bytes(self) -> bytes:
        """Complete state as bytes (safe codec, no pickle)."""
        return codec.dumps(self.get_state())

    @classmethod
    def from_bytes(cls, blob: bytes, trace: bool = False) -> PhoneEngine:
        return cls.from_state(codec.loads(blob), trace=trace)


def _new_trace() -> Any:
    from energy.engine import Trace

    return Trace()
