"""The energy-aware state machine (004 Section 4): which navigation runs and which sensors the device uses.

States (``docs/engine.md`` draws them): *initialisation* (``working == "zupt"``: the ZUPT-KF calibrates a
behaviour's step model and KF II over L0, 004 Table 2) and *Gait-DR* (``working == "pdr"``), in which the
gyroscope is on only while it is needed:

- an *examination* (004 Tables 1 and 3, every T0): one stride of the ZUPT-KF against the step model, and
  against the heading deviation while a stored one is unconfirmed;
- the *heading*: the cross-track drift the heading estimator's forecast uncertainty one gyroscope-off
  stride ahead would cause exceeds the budget (``SchedulerConfig.cross_track_pct``); the gyroscope is
  released after ``release_strides`` strides within it. Without a magnetometer the forecast never comes back: the
  gyroscope stays on;
- standing, the device keeps the gyroscope off and wakes it itself on motion (wake-on-motion) where the walk
  that may follow needs it from its first stride.

Pure decisions: the engine tells the scheduler what happened and asks it for the device's configuration.
Every change of whether the gyroscope is wanted is an event (``gyroscope_requested`` /
``gyroscope_released``) with its reason; the engine announces a ``mode_switch`` when the positions' mode
actually changes, with that reason.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from typing import Any

from energy.config import EngineConfig
from energy.profile import Profile
from energy.types import Event, SensorConfig

__all__ = ["Scheduler"]

_MOVING = ("walk", "run")


@functools.lru_cache(maxsize=64, typed=True)
def _sensor_config(*args: Any, **kwargs: Any) -> SensorConfig:
    """``SensorConfig(*args, **kwargs)``, built and validated once per distinct configuration (frozen: one
    instance serves every engine; the scheduler asks for it twice per batch, and a scheduler holds only a
    handful of configurations). ``typed``: an int rate is not served the float one's instance."""
    return SensorConfig(*args, **kwargs)


class Scheduler:
    """Decides navigation mode and sensor configuration.

    Parameters
    ----------
    mode : {"zupt", "pdr", "auto"}
        ``zupt``: gyroscope always. ``pdr``: the 004 scheme (ZUPT-KF for L0, then Gait-DR with the gyroscope
        off; refused until a calibrated compass can hold the heading, for good without a magnetometer). ``auto``: the full energy-aware scheduler.
    config : EngineConfig
    profile : Profile
        Per-user calibrations; a calibrated behaviour resumes in Gait-DR after one examination.
    """

    def __init__(self, mode: str, config: EngineConfig, profile: Profile) -> None:
        self.mode = mode
        self.config = config
        self.profile = profile
        self.working = "zupt"  # "zupt": initialisation (or always, mode zupt); "pdr": Gait-DR
        self.behaviour = "stand"
        self.calibrating: str | None = None  # behaviour whose initialisation runs
        self.l_zupt_m = 0.0  # 004 Table 2, L_ZUPT-KF of the running initialisation
        self.progress_m: dict[str, float] = {}  # L_ZUPT-KF of interrupted initialisations, per behaviour
        self.last_exam_s = 0.0
        self.exam_active = False
        self.exam_started_s = 0.0
        self.exam_misses = 0  # strides of the running examination outside 3 sigma so far
        self.exam_strides = 0
        self.nav_ready = False  # Gait-DR can place a step (KF II and a stride estimate)
        self.compass_ready = False  # a calibrated compass reads the heading (pdr mode keeps the gyroscope without)
        self.has_mag = False  # the device sends a magnetometer
        self.heading_gyro = True  # the heading needs the gyroscope (forecast beyond the budget)
        self.heading_ok = 0  # consecutive strides whose forecast was within the budget
        self.heading_drift_pct = float("inf")  # latest forecast cross-track drift [% of distance]
        self.failed: set[str] = set()  # behaviours whose examination failed in this session
        self.zupt_aligned = False  # the ZUPT-KF has levelled on a still foot in this session
        self.device_gyro_awake = False  # the device woke the gyroscope itself and it still runs
        self.step_t_s = 0.0  # time of the latest Gait-DR step [s]
        # behaviours whose heading deviation comes from the profile and no ZUPT-KF stride of this session has
        # confirmed yet
        self.deviation_pending: set[str] = (
            {b for b, c in profile.behaviours.items() if c.calibrated} if mode != "zupt" else set())
        self.heading_misses = 0  # consecutive heading-deviation misses outside an examination
        self.cadences: list[float] = []  # step frequencies of the latest Gait-DR strides [Hz]
        self.pattern_left: int | None = None  # ZUPT-KF strides still wanted by a walking-pattern initialisation
        self.run_wake_ms2: float | None = None  # high-g threshold above this person's walking [m/s^2]
        self.gyro = True  # gyro_wanted() as last announced
        self.reason = "session start"  # why the gyroscope is (not) wanted, as last announced

    # ------------------------------------------------------------------ inputs
    def on_behaviour(self, label: str, t_s: float, t_ns: int) -> list[Event]:
        """A new behaviour label (004 Table 2 (i): a behaviour without a model sends Gait-DR back to the
        ZUPT-KF; a calibrated one is examined when it resumes)."""
        if label == self.behaviour:
            return []
        events = [Event(t_ns, "behaviour", {"from": self.behaviour, "to": label})]
        previous, self.behaviour = self.behaviour, label
        self.cadences = []
        if self.mode == "auto" and label in _MOVING:
            if self.working == "pdr" and not self._resumable(label):
                self._calibrate(label)
                self.working = "zupt"
            elif self.working == "pdr" and previous in _MOVING:
                events += self._start_exam(t_s, t_ns, "calibrated behaviour resumed")
            elif self.working == "zupt" and self.calibrating != label:
                if self._resumable(label):
                    self.working = "pdr"
                    events += self._start_exam(t_s, t_ns, "check stored calibration")
                else:
                    self._calibrate(label)
        return events + self._announce(f"behaviour {label}", t_ns)

    def on_zupt_distance(self, d_m: float, t_ns: int) -> list[Event]:
        """The ZUPT-KF moved ``d_m`` metres horizontally (one stance to the next)."""
        if self.working != "zupt" or self.mode == "zupt":
            return []
        if self.calibrating is None and self.behaviour in _MOVING:
            self._calibrate(self.behaviour)
        self.l_zupt_m += d_m
        if self.pattern_left is not None:
            self.pattern_left -= 1
        return []

    def ready_for_pdr(self) -> bool:
        """004 Table 2: L_ZUPT-KF >= L0 ends the initialisation (a walking pattern's: its strides)."""
        if self.mode == "zupt" or self.working != "zupt":
            return False
        return self.l_zupt_m >= self.config.scheduler.l0_m or (self.pattern_left is not None and self.pattern_left <= 0)

    def on_heading(self, drift_pct: float, gyro_on: bool, t_ns: int) -> list[Event]:
        """A stride's forecast cross-track drift [% of distance] if the gyroscope were off
        (:meth:`energy.gait_dr.GaitPipeline.forecast_drift_pct`); ``gyro_on``: the stride was the ZUPT-KF's.
        Beyond the budget in Gait-DR the gyroscope is requested; within it for ``release_strides`` strides
        running it is released."""
        c = self.config.scheduler
        self.heading_drift_pct = float(drift_pct)
        within = drift_pct <= c.cross_track_pct
        self.heading_ok = self.heading_ok + 1 if within else 0
        if not gyro_on and not self.heading_gyro and not within:
            self.heading_gyro = True
            return self._announce(f"heading uncertain (drift {drift_pct:.1f} % > {c.cross_track_pct:g} %)", t_ns)
        if gyro_on and self.heading_gyro and self.heading_ok >= c.release_strides:
            self.heading_gyro = False
            return self._announce(f"compass holds the heading (drift {drift_pct:.1f} %)", t_ns)
        return []

    def on_cadence(self, f_s: float, fitted: Sequence[tuple[float, float]] | None, t_ns: int) -> list[Event]:
        """A Gait-DR stride of step frequency ``f_s`` [Hz]; ``fitted`` the cadence ranges [Hz] the behaviour's
        model was fitted on (:meth:`models.step_length.StepLengthCalibrator.cadence_ranges`).

        004 Table 2 (ii): when both the median cadence of the latest ``pattern_strides`` strides and the mean
        of their middle periods (periods come in whole samples) leave those ranges, the model would
        extrapolate to a walking pattern it has not seen: the ZUPT-KF takes ``pattern_init_strides`` strides of
        it, which join the calibration, then Gait-DR resumes. Auto mode only.
        """
        n = self.config.scheduler.pattern_strides
        if self.mode != "auto" or self.working != "pdr" or self.behaviour not in _MOVING or fitted is None:
            self.cadences = []
            return []
        self.cadences = (self.cadences + [float(f_s)])[-n:]
        if len(self.cadences) < n:
            return []
        f = sorted(self.cadences)[n // 2]
        periods = sorted(1.0 / c for c in self.cadences)
        f_mid = (len(periods) - 2) / sum(periods[1:-1]) if n > 2 else f
        if any(lo <= f <= hi or lo <= f_mid <= hi for lo, hi in fitted):
            return []
        b = self.behaviour
        events = [Event(t_ns, "walking_pattern_changed", {"behaviour": b, "f_s_hz": f,
                                                           "fitted_hz": [fitted[0][0], fitted[-1][1]],
                                                           "fitted_ranges_hz": [list(r) for r in fitted]})]
        self._pattern_init(b)
        return events + self._announce(f"walking pattern of {b} changed", t_ns)

    def on_calibrated(self, t_s: float, t_ns: int, detail: dict[str, Any] | None = None) -> list[Event]:
        """The engine fitted the step model and KF II: Gait-DR. ``detail`` joins the event."""
        info = {"behaviour": self.calibrating or self.behaviour, "l_zupt_m": self.l_zupt_m, **(detail or {})}
        self.failed.discard(info["behaviour"])
        self.deviation_pending.discard(info["behaviour"])  # learned in this session
        self.progress_m.pop(info["behaviour"], None)
        self.calibrating = None
        self.pattern_left = None
        self.last_exam_s = t_s
        self.working = "pdr"
        events = [Event(t_ns, "calibration_done", info)]
        if self.mode == "pdr" and not self.compass_ready:
            why = "no calibrated compass yet" if self.has_mag else "no magnetometer"
            events.append(Event(t_ns, "gyroscope_off_refused", {"reason": f"{why}: nothing would hold the heading"}))
        return events + self._announce("initialisation complete", t_ns)

    def on_compass(self, ready: bool, t_ns: int) -> list[Event]:
        """Whether a calibrated compass reads the heading (the ``pdr`` scheme turns the gyroscope off only then)."""
        if ready == self.compass_ready:
            return []
        self.compass_ready = ready
        return self._announce("compass calibrated" if ready else "compass lost", t_ns)

    def tick(self, t_s: float, t_ns: int) -> list[Event]:
        """A Gait-DR step at ``t_s`` [s]: start a due examination (004 Table 1: Delta T_G >= T0), give up a
        stale one."""
        c = self.config.scheduler
        self.step_t_s = t_s
        if (self.mode == "auto" and self.working == "pdr" and not self.exam_active and self.behaviour in _MOVING
                and t_s - self.last_exam_s >= c.t0_s):
            return self._start_exam(t_s, t_ns, "T0 elapsed")
        if self.exam_active and t_s - self.exam_started_s > c.exam_timeout_s:
            self.exam_active = False
            self.last_exam_s = t_s
            return [Event(t_ns, "examination_skipped", {"reason": "no gyroscope stride arrived",
                                                         "behaviour": self.behaviour})] + self._announce(
                "examination skipped", t_ns)
        return []

    def on_exam_result(self, passed: bool, d_kf: float, d_sl: float, t_s: float, t_ns: int,
                       heading: dict[str, Any] | None = None, new_pattern: bool = False) -> list[Event]:
        """004 Table 3: ``|d_KF - d_SL| <= 3 sigma_d`` keeps Gait-DR; ``heading`` (keys ``passed``,
        ``gamma_psi_rad``, ``deviation_rad``, ``sigma_rad``) the direction examination of the same stride
        (KF II innovation within 3 sigma: the walking direction relative to the foot has not changed). A
        miss is confirmed on the next stride; two fail. A failed step length at a cadence outside the
        fitted ones (``new_pattern``) is a walking pattern the model has not seen (004 Table 2 (ii))."""
        c = self.config.scheduler
        b = self.behaviour
        detail: dict[str, Any] = {"d_kf_m": d_kf, "d_sl_m": d_sl, "behaviour": b}
        if heading is not None:
            detail["heading"] = dict(heading)
            if heading["passed"]:
                self.deviation_pending.discard(b)
        self.exam_strides += 1
        heading_ok = heading is None or bool(heading["passed"])
        if (passed and heading is None and b in self.deviation_pending and self.exam_misses == 0
                and self.exam_strides < c.exam_max_strides):
            return [Event(t_ns, "examination_repeated", {**detail, "reason": "heading deviation not observed"})]
        ok = passed and heading_ok
        if not ok and self.exam_misses + 1 < c.exam_strides_to_fail:
            self.exam_misses += 1
            return [Event(t_ns, "examination_repeated", detail)]
        self.exam_active = False
        self.exam_misses = 0
        self.last_exam_s = t_s
        if ok:
            return [Event(t_ns, "examination_passed", detail)] + self._announce("examination passed", t_ns)
        if heading_ok and new_pattern and b in _MOVING:
            self._pattern_init(b)
            return [Event(t_ns, "examination_failed", {**detail, "cause": "walking_pattern",
                                                       "reason": "a walking pattern the model was not fitted on"})
                    ] + self._announce(f"walking pattern of {b} changed", t_ns)
        return self._fail(b, t_ns, detail, "heading_deviation" if not heading_ok else "step_length")

    def on_heading_check(self, heading: dict[str, Any], t_s: float, t_ns: int) -> list[Event]:
        """A ZUPT-KF stride outside an examination tested the unconfirmed stored deviation of the current
        behaviour: confirmed by one fit, failed by ``exam_strides_to_fail`` misses running (re-mounted)."""
        b = self.behaviour
        if b not in self.deviation_pending:
            return []
        if heading["passed"]:
            self.deviation_pending.discard(b)
            self.heading_misses = 0
            return []
        self.heading_misses += 1
        if self.heading_misses < self.config.scheduler.exam_strides_to_fail:
            return []
        self.heading_misses = 0
        self.last_exam_s = t_s
        return self._fail(b, t_ns, {"behaviour": b, "heading": dict(heading)}, "heading_deviation")

    def _fail(self, behaviour: str, t_ns: int, detail: dict[str, Any], cause: str) -> list[Event]:
        """A calibration no longer fits: re-initialise ``behaviour`` from scratch (``heading_deviation``: the
        sensor was re-mounted, every unconfirmed stored deviation is as stale)."""
        reason = ("heading deviation no longer fits (sensor re-mounted or gait direction changed)"
                  if cause == "heading_deviation" else "step-length model no longer fits")
        events = [Event(t_ns, "examination_failed", {**detail, "cause": cause, "reason": reason})]
        self.failed.add(behaviour)
        if cause == "heading_deviation":
            self.deviation_pending.clear()
        self.progress_m.pop(behaviour, None)
        self.calibrating, self.l_zupt_m = None, 0.0
        self.exam_active = False
        self._calibrate(behaviour)
        self.working = "zupt"
        return events + self._announce(reason, t_ns)

    # ------------------------------------------------------------------ outputs
    def gyro_wanted(self, device: bool = True) -> bool:
        """004 Table 1 plus the heading: on while the ZUPT-KF initialises or examines, until Gait-DR can place
        a step, and (auto) while the heading needs it; ``pdr`` keeps it until a calibrated compass reads.
        Standing it is left to the device (:meth:`wake_on_motion`) where the walk that may follow needs it, and
        kept while the device has it awake (``device``: a fact of the upload, not of the data, so the events
        announced leave it out and stay independent of how the data were cut)."""
        awake = device and self.device_gyro_awake
        if self.mode == "zupt":
            return True
        if self.mode == "auto" and self.behaviour == "stand" and self._gait_dr_can_start():
            return self._walk_needs_gyro() or awake
        if self.working == "zupt" or not self.nav_ready:
            return True
        if self.mode == "auto" and self.behaviour == "other":
            return True  # backward, sideways, shuffling: no step model, no known walking direction; never Gait-DR
        if self.mode == "pdr":
            return not self.compass_ready
        return self.exam_active or self.heading_gyro

    def wake_on_motion(self) -> bool:
        """Standing with the gyroscope wanted only for the walk that may follow: the device keeps it off and
        turns it on by itself when its accelerometer sees motion (auto mode, once the ZUPT-KF has levelled)."""
        return self.mode == "auto" and self.behaviour == "stand" and self.zupt_aligned and self.gyro_wanted()

    def _gait_dr_can_start(self) -> bool:
        """Gait-DR can place the next steps: the navigation is ready, or the ZUPT-KF has aligned and the
        profile holds a calibration whose heading deviation was confirmed in this session."""
        return self.nav_ready or (self.zupt_aligned and any(self._resumable(b) and b not in self.deviation_pending
                                                            for b in _MOVING))

    def _walk_needs_gyro(self) -> bool:
        """Standing, the motion that may follow needs the gyroscope from its first stride: a moving behaviour
        has no model, or the heading needs it."""
        return any(not self._resumable(b) for b in _MOVING) or self.heading_gyro

    def run_wake(self) -> bool:
        """Gait-DR of a walk while running has no model: the device wakes the gyroscope itself when its
        accelerometer goes beyond this person's walking (``run_wake_ms2``), before the host recognises the
        run."""
        return (self.mode == "auto" and self.working == "pdr" and self.behaviour == "walk"
                and self.run_wake_ms2 is not None and not self._resumable("run"))

    def batch_s(self, gyro_on: bool) -> float:
        """Upload period [s]: short while the ZUPT-KF runs or the navigation is not ready, long in auto mode
        once the gyroscope is off and Gait-DR can navigate, short again when an examination falls due within
        one long upload."""
        r, c = self.config.rates, self.config.scheduler
        exam_near = self.behaviour in _MOVING and self.step_t_s - self.last_exam_s >= c.t0_s - r.low_power_batch_s
        if self.mode == "auto" and not gyro_on and self._gait_dr_can_start() and not exam_near:
            return r.low_power_batch_s
        return r.batch_s

    def idle(self) -> bool:
        """Standing with the gyroscope off (auto mode)."""
        return self.mode == "auto" and self.behaviour == "stand" and not self.gyro_wanted()

    def sensor_config(self) -> SensorConfig:
        return self.config_and_idle()[0]

    def _config_case(self) -> str:
        """Which of :meth:`config_and_idle`'s configurations applies: ``stand`` (standing, gyroscope off),
        ``stand_wake`` (standing, the device wakes the gyroscope on motion), ``gyro`` (on), ``run_wake``
        (de-sampled Gait-DR, the device wakes the gyroscope on a run) or ``pdr``."""
        gyro = self.gyro_wanted()
        standing = self.mode == "auto" and self.behaviour == "stand"
        if standing and not gyro:
            return "stand"
        if standing and self.zupt_aligned:
            return "stand_wake"
        if gyro:
            return "gyro"
        return "run_wake" if self.run_wake() else "pdr"

    def gyro_wake_on_motion(self) -> bool:
        """``sensor_config().gyro_wake_on_motion`` without building the configuration (the engine asks at every
        batch)."""
        return self._config_case() in ("stand_wake", "run_wake")

    def config_and_idle(self) -> tuple[SensorConfig, bool]:
        """:meth:`sensor_config` and :meth:`idle` together."""
        r, c = self.config.rates, self.config.scheduler
        case = self._config_case()
        if case == "stand":
            return _sensor_config(False, r.stand_rate_hz, 0.0, 0.0, batch_s=self.batch_s(False)), True
        if case == "stand_wake":  # wake-on-motion: the device wakes the gyroscope (and the full rate)
            return _sensor_config(False, r.stand_rate_hz, r.full_rate_hz, r.mag_rate_hz, batch_s=self.batch_s(False),
                                  gyro_wake_on_motion=True, wake_threshold_ms2=c.wake_threshold_ms2,
                                  sleep_after_s=c.sleep_after_s, mag_follows_gyro=True), False
        if case == "gyro":
            return _sensor_config(True, r.full_rate_hz, r.full_rate_hz, r.mag_rate_hz, batch_s=self.batch_s(True)), False
        if case == "run_wake":  # de-sampled Gait-DR; the device wakes the gyroscope on a run
            return _sensor_config(False, r.pdr_rate_hz, r.full_rate_hz, r.pdr_rate_hz, batch_s=self.batch_s(False),
                                  gyro_wake_on_motion=True, wake_threshold_ms2=float(self.run_wake_ms2 or 0.0),
                                  sleep_after_s=c.sleep_after_s, wake_mode="high_g"), False
        return _sensor_config(False, r.pdr_rate_hz, 0.0, r.pdr_rate_hz, batch_s=self.batch_s(False)), False  # 004 Sec. 4.3

    # ------------------------------------------------------------------ internals
    def _announce(self, reason: str, t_ns: int) -> list[Event]:
        """An event when the gyroscope's wanted state changed with this input, saying why."""
        gyro = self.gyro_wanted(device=False)
        if gyro == self.gyro:
            return []
        self.gyro, self.reason = gyro, reason
        kind = "gyroscope_requested" if gyro else "gyroscope_released"
        return [Event(t_ns, kind, {"reason": reason, "working": self.working, "heading_drift_pct": self.heading_drift_pct})]

    def _pattern_init(self, b: str) -> None:
        """Initialise a new walking pattern of ``b``: ``pattern_init_strides`` ZUPT-KF strides."""
        self._calibrate(b)
        self.progress_m.pop(b, None)
        self.l_zupt_m = 0.0
        self.exam_active = False
        self.exam_misses = 0
        self.pattern_left = self.config.scheduler.pattern_init_strides
        self.working = "zupt"

    def _calibrate(self, behaviour: str) -> None:
        """Initialise ``behaviour``; an interrupted initialisation of it continues where it stopped."""
        if self.calibrating is not None:
            self.progress_m[self.calibrating] = self.l_zupt_m
        self.calibrating, self.l_zupt_m = behaviour, self.progress_m.get(behaviour, 0.0)
        self.pattern_left = None

    def _resumable(self, behaviour: str) -> bool:
        """Calibrated (profile or this session) and not failed an examination since."""
        return self.profile.is_calibrated(behaviour) and behaviour not in self.failed

    def _start_exam(self, t_s: float, t_ns: int, reason: str) -> list[Event]:
        self.exam_active = True
        self.exam_misses = 0
        self.exam_strides = 0
        self.exam_started_s = t_s
        return [Event(t_ns, "examination_started", {"reason": reason, "behaviour": self.behaviour})] + self._announce(
            f"examination ({reason})", t_ns)

    _KEYS = ("working", "behaviour", "calibrating", "l_zupt_m", "last_exam_s", "exam_active", "exam_started_s",
             "exam_misses", "exam_strides", "nav_ready", "compass_ready", "has_mag", "heading_gyro", "heading_ok", "heading_drift_pct",
             "zupt_aligned", "device_gyro_awake", "step_t_s", "heading_misses", "pattern_left", "run_wake_ms2",
             "gyro", "reason")

    def get_state(self) -> dict[str, Any]:
        d = {k: getattr(self, k) for k in self._KEYS}
        d.update(mode=self.mode, profile=self.profile.to_dict(copy=False), failed=sorted(self.failed),
                 deviation_pending=sorted(self.deviation_pending), progress_m=dict(self.progress_m),
                 cadences=list(self.cadences))
        return d

    @classmethod
    def from_state(cls, config: EngineConfig, d: dict[str, Any]) -> Scheduler:
        obj = cls(d["mode"], config, Profile.from_dict(d["profile"]))
        for k in cls._KEYS:
            setattr(obj, k, d[k])
        obj.failed = set(d["failed"])
        obj.deviation_pending = set(d["deviation_pending"])
        obj.progress_m = {str(k): float(v) for k, v in d["progress_m"].items()}
        obj.cadences = [float(f) for f in d["cadences"]]
        return obj
