"""The energy-aware state machine of 004 Section 4: gyroscope strategy (Table 1), ZUPT-KF <-> Gait-DR switching
(Table 2), step-length model examination (Table 3) and de-sampling (Section 4.3).

Pure decisions: the engine tells the scheduler what happened (behaviour label, ZUPT-KF distance, calibration
ready, examination result, heading-deviation test of a stored calibration) and asks it which navigation mode
to run and which sensor configuration the device must use next. No numerics here.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from energy.config import EngineConfig
from energy.profile import Profile
from energy.types import Event, SensorConfig

__all__ = ["Scheduler"]

_MOVING = ("walk", "run")
BATCH_S = 1.0  # upload period while the ZUPT-KF runs or the navigation is not ready [s]
LOW_POWER_BATCH_S = 4.0  # upload period with the gyroscope off once Gait-DR can navigate (auto mode) [s]
EXAM_STRIDES_TO_FAIL = 2  # consecutive examination strides outside 3 sigma_d before re-initialising
# An examination of a behaviour whose stored heading deviation has not been confirmed in this session goes on
# (gyroscope on) over strides that observe no gamma - psi (turning strides), up to this many strides in all
EXAM_MAX_STRIDES = 4
# 004 Table 2 (ii), Section 4.2: a walking pattern (step frequency) the step-length model was not fitted on.
# Hysteresis: the median cadence of this many consecutive Gait-DR strides (more than half of them: not one or
# two odd strides) must lie outside the cadences of the model's calibration pairs
PATTERN_STRIDES = 5
# ZUPT-KF strides of the new pattern that join the behaviour's calibration before its model is refitted, far
# shorter than L0. The new strides' mean is then known to sigma_d / sqrt(6) (~1 % of a stride). 8 (the
# calibrator's min_pairs) took the new user's energy_ratio over 0.25 on the synthetic mixed day (seeds 2, 3:
# 0.2505; 7: 0.2502 on seed 0 with measured compute costs); 6 is the longest within that budget.
PATTERN_INIT_STRIDES = 6
# Wake-on-motion (SensorConfig.gyro_wake_on_motion), the device's activity/inactivity function (LSM9DS1 ACT_THS /
# ACT_DUR). Threshold: per axis, 0.5 m/s^2 (51 mg): >= 10x the still foot's accelerometer noise (per-axis std
# 0.01-0.04 m/s^2 over the first 0.6 s of the gdin recordings at 200 Hz, 0.03 on the synthetic foot), far below
# a heel-off. Inactivity: 1 s, longer than any stance of a walk (so a walk never puts the gyroscope down).
WAKE_THRESHOLD_MS2 = 0.5
SLEEP_AFTER_S = 1.0
# Weak-field wake (SensorConfig.wake_mode "weak_field"): the gyroscope the device woke on a weak field powers down
# again this long after the last weak stance [s] (about two strides: the host has asked for it by then where the
# field stays weak, see Scheduler.request_heading_assist)
WEAK_SLEEP_AFTER_S = 2.0


class Scheduler:
    """Decides navigation mode and sensor configuration.

    Parameters
    ----------
    mode : {"zupt", "pdr", "auto"}
        Engine mode (see :class:`energy.engine.Engine`).
    config : EngineConfig
        Rates, L0, T0.
    profile : Profile
        Per-user calibrations; a calibrated behaviour resumes in Gait-DR after one examination.

    A stored calibration is examined for step length (004 Table 3) and, until one stride has confirmed it in
    this session, for its heading deviation: a sensor re-mounted since the profile was made (other shoe,
    turned around) keeps the step lengths but turns every Gait-DR stride by the change of the mount.
    """

    def __init__(self, mode: str, config: EngineConfig, profile: Profile) -> None:
        self.mode = mode
        self.config = config
        self.profile = profile
        self.working = "zupt"  # navigation mode: "zupt" or "pdr"
        self.behaviour = "stand"
        self.calibrating: str | None = None  # behaviour whose initialisation runs
        self.l_zupt_m = 0.0  # 004 Table 2, L_ZUPT-KF of the running initialisation
        self.progress_m: dict[str, float] = {}  # L_ZUPT-KF of interrupted initialisations, per behaviour
        self.last_exam_s = 0.0
        self.exam_active = False  # 004 Table 1: gyro on till a whole step is completed
        self.exam_started_s = 0.0
        self.nav_ready = False  # ZUPT-KF aligned and Gait-DR able to place a step (gyroscope needed until then)
        self.compass_ready = True  # Gait-DR has a heading source (a magnetometer with a fitted calibration)
        self.assist_active = False  # gyroscope carries the heading through a magnetic disturbance
        self.assist_weak = False  # ... asked for because the field was too weak horizontally (weak_field_h)
        self.failed: set[str] = set()  # behaviours whose examination failed in this session
        self.zupt_aligned = False  # the ZUPT-KF has levelled on a still foot once in this session
        self.device_gyro_awake = False  # the device woke the gyroscope itself (wake-on-motion) and it still runs
        self.step_t_s = 0.0  # time of the latest Gait-DR step [s]
        self.exam_misses = 0  # strides of the running examination outside 3 sigma_d so far
        self.exam_strides = 0  # strides of the running examination so far
        # behaviours whose heading deviation comes from the profile and no ZUPT-KF stride of this session has
        # confirmed yet (mode auto/pdr: Gait-DR applies it)
        self.deviation_pending: set[str] = (
            {b for b, c in profile.behaviours.items() if c.calibrated} if mode != "zupt" else set())
        self.heading_misses = 0  # consecutive heading-deviation misses outside an examination
        self.cadences: list[float] = []  # step frequencies of the latest Gait-DR strides of this behaviour [Hz]
        self.pattern_left: int | None = None  # ZUPT-KF strides still wanted by a walking-pattern initialisation
        # high-g threshold above this person's walking [m/s^2] (energy.gait_dr.GaitPipeline.run_wake_threshold)
        self.run_wake_ms2: float | None = None
        # the compass's calibration and weak-field threshold the device needs to wake the gyroscope itself on a
        # weak field in Gait-DR (energy.gait_dr.GaitPipeline.weak_wake): (threshold [uT], b [uT], W row-major)
        self.weak_wake: tuple[float, tuple[float, ...], tuple[float, ...]] | None = None

    # ------------------------------------------------------------------ inputs
    def on_behaviour(self, label: str, t_s: float, t_ns: int) -> list[Event]:
        """A new behaviour label (004 Table 2: a new motion behaviour sends Gait-DR back to ZUPT-KF)."""
        events: list[Event] = []
        if label == self.behaviour:
            return events
        events.append(Event(t_ns, "behaviour", {"from": self.behaviour, "to": label}))
        previous, self.behaviour = self.behaviour, label
        self.cadences = []
        if self.mode != "auto" or label not in _MOVING:
            return events
        if self.working == "pdr" and not self._resumable(label):
            # 004 Table 2 (i), also after a stand: Gait-DR had only the generic prior for these strides (the
            # first run strides of the synthetic mixed day, after a stand, came out 23 % short until an
            # examination failed on them)
            self._calibrate(label)
            events += self._switch("zupt", t_ns, reason=f"new behaviour {label}")
        elif self.working == "pdr" and previous in _MOVING and label != previous:
            events += self._start_exam(t_s, t_ns, reason="calibrated behaviour resumed")
        elif self.working == "zupt" and self.calibrating != label:
            if self._resumable(label):
                events += self._switch("pdr", t_ns, reason=f"profile has {label} calibration")
                events += self._start_exam(t_s, t_ns, reason="check stored calibration")
            else:
                self._calibrate(label)
        return events

    def on_zupt_distance(self, d_m: float, t_ns: int) -> list[Event]:
        """ZUPT-KF moved ``d_m`` metres horizontally (one stance to the next)."""
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
        return self.l_zupt_m >= self.config.l0_m or (self.pattern_left is not None and self.pattern_left <= 0)

    def on_cadence(self, f_s: float, fitted: Sequence[tuple[float, float]] | None, t_ns: int) -> list[Event]:
        """A Gait-DR stride of step frequency ``f_s`` [Hz]; ``fitted`` the ranges of cadences [Hz] the current
        behaviour's step-length model was fitted on (:meth:`models.step_length.StepLengthCalibrator.cadence_ranges`:
        a model fitted on a slow and a fast walk has not seen the paces between them).

        004 Table 2 (ii): when the median cadence of the latest ``PATTERN_STRIDES`` strides leaves those ranges, and
        so does the mean of their middle periods, the model would extrapolate to a walking pattern it has not seen
        (a walk fitted at 0.87 Hz put the 0.98 Hz strides of a faster walk 5-11 % short, and the 3-sigma
        examination passed them): the ZUPT-KF takes ``PATTERN_INIT_STRIDES`` strides of the new pattern, which
        join the behaviour's calibration (its refit covers both patterns), then Gait-DR resumes. Auto mode only.

        Both tests: the median keeps a pair of odd strides out; periods come in whole samples (0.04 s at 25 Hz),
        so a pace between two of them reads as a mix of both, and the median alone took three 1.08-s strides out
        of 1.08/1.16-s ones for a pace beyond a range fitted on 1.12-s ones (synthetic mixed day, seed 16: the
        ZUPT-KF restarted for 10 s, and the strides it measured were 1.12-1.20 s).
        """
        if self.mode != "auto" or self.working != "pdr" or self.behaviour not in _MOVING or fitted is None:
            self.cadences = []
            return []
        self.cadences = (self.cadences + [float(f_s)])[-PATTERN_STRIDES:]
        if len(self.cadences) < PATTERN_STRIDES:
            return []
        f = sorted(self.cadences)[PATTERN_STRIDES // 2]  # median (PATTERN_STRIDES odd)
        periods = sorted(1.0 / c for c in self.cadences)
        f_mid = (len(periods) - 2) / sum(periods[1:-1])  # 1 / the mean of the middle periods
        if any(lo <= f <= hi or lo <= f_mid <= hi for lo, hi in fitted):
            return []
        b = self.behaviour
        events = [Event(t_ns, "walking_pattern_changed", {"behaviour": b, "f_s_hz": f,
                                                           "fitted_hz": [fitted[0][0], fitted[-1][1]],
                                                           "fitted_ranges_hz": [list(r) for r in fitted]})]
        return events + self._pattern_init(b, t_ns)

    def _pattern_init(self, b: str, t_ns: int) -> list[Event]:
        """Initialise a new walking pattern of ``b``: ``PATTERN_INIT_STRIDES`` ZUPT-KF strides."""
        self._calibrate(b)
        self.progress_m.pop(b, None)
        self.l_zupt_m = 0.0
        self.exam_active = False
        self.exam_misses = 0
        self.pattern_left = PATTERN_INIT_STRIDES
        return self._switch("zupt", t_ns, reason=f"walking pattern of {b} changed")

    def on_calibrated(self, t_s: float, t_ns: int, detail: dict[str, Any] | None = None) -> list[Event]:
        """The engine fitted the step model and KF II after L0: switch to Gait-DR. ``detail`` joins the event."""
        info = {"behaviour": self.calibrating or self.behaviour, "l_zupt_m": self.l_zupt_m, **(detail or {})}
        self.failed.discard(info["behaviour"])
        self.deviation_pending.discard(info["behaviour"])  # learned in this session
        events = [Event(t_ns, "calibration_done", info)]
        self.progress_m.pop(info["behaviour"], None)
        self.calibrating = None
        self.pattern_left = None
        self.last_exam_s = t_s
        events += self._switch("pdr", t_ns, reason="initialisation complete")
        return events

    def exam_due(self, t_s: float) -> bool:
        """004 Table 1: Delta T_G >= T0 turns the gyroscope on for one step (auto mode, Gait-DR, moving)."""
        return (
            self.mode == "auto"
            and self.working == "pdr"
            and not self.exam_active
            and self.behaviour in _MOVING
            and t_s - self.last_exam_s >= self.config.t0_s
        )

    def start_exam(self, t_s: float, t_ns: int) -> list[Event]:
        return self._start_exam(t_s, t_ns, reason="T0 elapsed")

    def request_heading_assist(self, t_ns: int, weak_field: bool = False) -> list[Event]:
        """Gait-DR is holding its heading on a disturbed field (``heading_assist``), or its stance field is too
        weak horizontally for the compass to tell turns (``weak_field``, ``weak_field_h``): the gyroscope carries
        the heading (auto mode)."""
        wanted = self.config.weak_field_h > 0 if weak_field else self.config.heading_assist
        if self.mode != "auto" or self.assist_active or not wanted or self.working != "pdr":
            return []
        self.assist_active, self.assist_weak = True, weak_field
        return [Event(t_ns, "gyroscope_requested", {"reason": "weak magnetic field" if weak_field else "magnetic disturbance"})]

    def release_heading_assist(self, t_ns: int, reason: str | None = None) -> list[Event]:
        """The field is clean again (a weak-field assist: the Earth's, settled): the compass takes the heading
        back."""
        if not self.assist_active:
            return []
        self.assist_active = False
        if reason is None:
            reason = "Earth's magnetic field back" if self.assist_weak else "magnetic field clean"
        return [Event(t_ns, "gyroscope_released", {"reason": reason})]

    def tick(self, t_s: float, t_ns: int) -> list[Event]:
        """Data time advanced to ``t_s`` (a Gait-DR step): start a due examination, give up a stale one."""
        self.step_t_s = t_s
        if self.exam_due(t_s):
            return self.start_exam(t_s, t_ns)
        if self.exam_active and t_s - self.exam_started_s > self.config.exam_timeout_s:
            self.exam_active = False
            self.last_exam_s = t_s
            return [Event(t_ns, "examination_skipped", {"reason": "no gyroscope stride arrived", "behaviour": self.behaviour})]
        return []

    def on_exam_result(self, passed: bool, d_kf: float, d_sl: float, t_s: float, t_ns: int,
                       heading: dict[str, Any] | None = None, new_pattern: bool = False) -> list[Event]:
        """004 Table 3: |d_KF - d_SL| <= 3 sigma_d keeps Gait-DR, otherwise re-initialise.

        Unlike 004 (one stride), a miss is confirmed on the next stride before the L0 re-initialisation: the
        gyroscope is on anyway, one more stride costs about a second of it, a re-initialisation 20-30 s, and
        single strides miss often where a walk starts or follows a run (d_SL 1.61 m vs d_KF 1.35 m seen on the
        synthetic mixed day).

        ``heading`` is the stride's heading-deviation test (:meth:`energy.engine.Engine`; keys ``passed``,
        ``gamma_psi_rad``, ``deviation_rad``, ``sigma_rad``), None when the stride observed no gamma - psi or
        the behaviour's deviation is not tested. A stride fits when both tests pass. While the stored deviation
        is unconfirmed, a stride without a heading observation decides nothing (up to ``EXAM_MAX_STRIDES``).

        ``new_pattern``: the deciding stride's cadence lies outside the cadences the model was fitted on. A
        step-length failure there is a walking pattern the model has not seen (004 Table 2 (ii)), not a model
        gone wrong: the ZUPT-KF takes ``PATTERN_INIT_STRIDES`` strides of it (as :meth:`on_cadence` does)
        instead of a whole L0 (the demo's walk after its run: a fast walk failed the examination before five
        Gait-DR strides had told its cadence, and the ZUPT-KF then ran the 40 m of an initialisation).
        """
        b = self.behaviour
        detail: dict[str, Any] = {"d_kf_m": d_kf, "d_sl_m": d_sl, "behaviour": b}
        if heading is not None:
            detail["heading"] = dict(heading)
            if heading["passed"]:
                self.deviation_pending.discard(b)
        self.exam_strides += 1
        heading_ok = heading is None or bool(heading["passed"])
        if (passed and heading is None and b in self.deviation_pending and self.exam_misses == 0
                and self.exam_strides < EXAM_MAX_STRIDES):
            return [Event(t_ns, "examination_repeated", {**detail, "reason": "heading deviation not observed"})]
        ok = passed and heading_ok
        if not ok and self.exam_misses + 1 < EXAM_STRIDES_TO_FAIL:
            self.exam_misses += 1
            return [Event(t_ns, "examination_repeated", detail)]  # still active: the next stride decides
        self.exam_active = False
        self.exam_misses = 0
        self.last_exam_s = t_s
        if ok:
            return [Event(t_ns, "examination_passed", detail)]
        if heading_ok and new_pattern and b in _MOVING:
            return [Event(t_ns, "examination_failed", {**detail, "cause": "walking_pattern",
                                                       "reason": "a walking pattern the model was not fitted on"}),
                    *self._pattern_init(b, t_ns)]
        return self._fail(b, t_ns, detail, "heading_deviation" if not heading_ok else "step_length")

    def on_heading_check(self, heading: dict[str, Any], t_s: float, t_ns: int) -> list[Event]:
        """A ZUPT-KF stride outside an examination tested the unconfirmed stored deviation of the current
        behaviour (an initialisation, a heading assist): confirmed by one fit, failed by
        ``EXAM_STRIDES_TO_FAIL`` consecutive misses like an examination (the sensor was re-mounted)."""
        b = self.behaviour
        if b not in self.deviation_pending:
            return []
        if heading["passed"]:
            self.deviation_pending.discard(b)
            self.heading_misses = 0
            return []
        self.heading_misses += 1
        if self.heading_misses < EXAM_STRIDES_TO_FAIL:
            return []
        self.heading_misses = 0
        self.last_exam_s = t_s
        return self._fail(b, t_ns, {"behaviour": b, "heading": dict(heading)}, "heading_deviation")

    def _fail(self, behaviour: str, t_ns: int, detail: dict[str, Any], cause: str) -> list[Event]:
        """A stored or learned calibration no longer fits: re-initialise ``behaviour`` from scratch.

        ``cause`` ``heading_deviation`` means the sensor was re-mounted: every deviation still unconfirmed
        from the profile is as stale as the failed one (the engine drops them and the compass calibration).
        """
        reason = ("heading deviation no longer fits (sensor re-mounted)" if cause == "heading_deviation"
                  else "step-length model no longer fits")
        events = [Event(t_ns, "examination_failed", {**detail, "cause": cause, "reason": reason})]
        self.failed.add(behaviour)  # not resumed in this session until re-calibrated
        if cause == "heading_deviation":
            self.deviation_pending.clear()
        self.progress_m.pop(behaviour, None)  # re-initialise from scratch
        self.calibrating, self.l_zupt_m = None, 0.0
        self.exam_active = False
        self._calibrate(behaviour)
        events += self._switch("zupt", t_ns, reason=reason)
        return events

    # ------------------------------------------------------------------ outputs
    def gyro_wanted(self) -> bool:
        """004 Table 1, plus: on until Gait-DR can place a step, and (auto) while Gait-DR has no heading source.

        A returning user standing at the start of a session needs the gyroscope only until the ZUPT-KF has
        levelled on the still foot (that stance becomes the origin and Gait-DR's starting point); the profile's
        calibration places the first steps once its heading deviation is confirmed in the session (until then
        the gyroscope wakes on the first motion: :meth:`_gait_dr_can_start`). A new user needs it until the
        ZUPT-KF has walked a few strides: nothing else could place the first steps (with the gyroscope simply
        asleep they were lost: on gdin the median stride error rose from 0.9 to 17 m). Standing, such a gyroscope is left to the device, which
        turns it on by itself on motion (:meth:`wake_on_motion`; the configuration then says ``gyro_on``
        False with ``gyro_wake_on_motion``).

        Without a calibrated magnetometer Gait-DR could only hold one heading through every turn; the fixed
        ``pdr`` scheme accepts that (it is what 004 evaluates), the energy-aware scheduler keeps the ZUPT-KF.
        """
        if self.mode == "zupt":
            return True
        if self.mode == "auto" and self.behaviour == "stand" and self._gait_dr_can_start():
            # the gyroscope is left to the device (wake-on-motion) while a motion may follow that Gait-DR has no
            # model for, and while the device has it awake: "stand" is the label of data up to a second and a
            # half old, and a gyroscope woken by a foot that already walks was switched off (gdin
            # leave-one-out exp43: Gait-DR placed 9 running strides with one held heading, stride error 10.9 m)
            return self._walk_needs_gyro() or self.device_gyro_awake
        if not self.nav_ready:
            return True
        if self.working == "zupt" or (self.mode == "auto" and not self.compass_ready):
            return True
        return self.exam_active or self.assist_active

    def wake_on_motion(self) -> bool:
        """Standing with the gyroscope wanted only for the walk that may follow: let the device keep it off and
        turn it on by itself when its accelerometer sees motion (auto mode).

        Applies once the ZUPT-KF has levelled on the still foot in this session (its attitude is what a
        segment that starts on its own restarts from, see :meth:`energy.engine.Engine`): a new user's first
        stand, a returning user's first stand on a stored heading deviation not yet confirmed, and stands during
        an initialisation or an examination. The host would hear "walking" only
        after its next upload and a recognition delay (with the gyroscope simply off through the first stand
        the first strides on gdin were lost: median stride error 0.9 -> 17 m); the device hears it at the
        first accelerometer sample past the threshold and delivers after the gyroscope's turn-on time.
        """
        return self.mode == "auto" and self.behaviour == "stand" and self.zupt_aligned and self.gyro_wanted()

    def _gait_dr_can_start(self) -> bool:
        """Gait-DR can place the next steps: the navigation is ready, or (a returning user at a session start)
        the ZUPT-KF has aligned, its first stance will be Gait-DR's starting point, and the profile holds a
        calibration to place the first steps with whose heading deviation has been confirmed in this session.

        A stored deviation is unconfirmed at a session start: the first strides are then the ZUPT-KF's (the
        device wakes the gyroscope on the first motion, :meth:`wake_on_motion`) and examine it. Placed by
        Gait-DR until the examination's verdict, they kept the error of a re-mounted sensor's stored deviation
        (gdin leave-one-out exp41: one stride placed 180 deg off, stride error 16.7 m after a failed test).
        """
        return self.nav_ready or (self.zupt_aligned and any(self._resumable(b) and b not in self.deviation_pending
                                                            for b in _MOVING))

    def _unmodelled_motion(self) -> bool:
        """A moving behaviour Gait-DR has no model for (never calibrated, or its examination failed in this
        session): standing, the motion that follows may be it, and its first strides need the ZUPT-KF."""
        return any(not self._resumable(b) for b in _MOVING)

    def _walk_needs_gyro(self) -> bool:
        """Standing, the motion that may follow needs the gyroscope from its first stride: Gait-DR has no model
        for it (:meth:`_unmodelled_motion`), or no heading source to follow its turns (auto mode: the compass is
        not trusted). Woken by the host after the recognition delay and a long upload instead, the gyroscope
        came on 9 s into a walk; Gait-DR had held its heading through a 90-deg turn the untrusted compass half
        saw, and the ZUPT-KF went on 48 deg off, in which frame the compass was then fitted (held-out synthetic
        day, seed 7: 36 m mean error)."""
        return self._unmodelled_motion() or (self.mode == "auto" and not self.compass_ready)

    def run_wake(self) -> bool:
        """Gait-DR of a walk while running has no model: let the device wake the gyroscope by itself when its
        accelerometer goes beyond this person's walking (``run_wake_ms2``), as it does on the first motion of a
        stand (auto mode).

        The host hears "run" only after the recognition delay (~2 s of running) and the rest of a long upload:
        in the demo's first walk the device sent 4-s batches and the gyroscope came on 5.4 s after the run began,
        and Gait-DR placed the 8 running strides in between with the walking model (1.1-1.8 m for 2.2-2.4 m).
        Woken by the device, the gyroscope delivers one turn-on time after the first running stride's impact;
        the ZUPT-KF takes over at the next stance. Once the host has recognised the run it keeps the gyroscope
        on (its initialisation); a false wake puts it down after ``SLEEP_AFTER_S`` without such an event.
        """
        return (self.mode == "auto" and self.working == "pdr" and self.behaviour == "walk"
                and self.run_wake_ms2 is not None and not self._resumable("run"))

    def idle(self) -> bool:
        """Standing with the gyroscope off (auto mode)."""
        return self.mode == "auto" and self.behaviour == "stand" and not self.gyro_wanted()

    def batch_s(self, gyro_on: bool) -> float:
        """Upload period [s]: short while the ZUPT-KF runs (its results end examinations and initialisations,
        and each answer may switch the gyroscope off) or before the navigation is ready (the start of the walk
        must reach the scheduler quickly); long in auto mode once the gyroscope is off and Gait-DR can navigate
        (fewer radio wake-ups and fewer per-batch computations; nothing is waiting for the answer)."""
        # a stand whose gyroscope is wanted only for a motion Gait-DR has no model for: the device wakes it itself
        for_unmodelled = self.behaviour == "stand" and self._walk_needs_gyro()
        if self.mode == "auto" and (not gyro_on or for_unmodelled) and self._gait_dr_can_start() and not self._exam_near():
            return LOW_POWER_BATCH_S
        return BATCH_S

    def _exam_near(self) -> bool:
        """An examination falls due within one long upload: upload briefly again so that the gyroscope
        arrives within about a second of the request (a late examination stride lands more often at the end
        of a walk, where it fails more often and a failure costs a whole L0 re-initialisation)."""
        return self.behaviour in _MOVING and self.step_t_s - self.last_exam_s >= self.config.t0_s - LOW_POWER_BATCH_S

    def sensor_config(self) -> SensorConfig:
        return self.config_and_idle()[0]

    def config_and_idle(self) -> tuple[SensorConfig, bool]:
        """:meth:`sensor_config` and :meth:`idle` together, :meth:`gyro_wanted` evaluated once for both (the
        engine asks for both after every batch)."""
        c = self.config
        gyro = self.gyro_wanted()
        batch = self.batch_s(gyro)
        standing = self.mode == "auto" and self.behaviour == "stand"
        if standing and not gyro:  # idle()
            return SensorConfig(gyro_on=False, acc_rate_hz=c.stand_rate_hz, gyr_rate_hz=0.0, mag_rate_hz=0.0, batch_s=batch), True
        if standing and self.zupt_aligned:  # wake_on_motion(): the device wakes the gyroscope (and the full rate) on motion
            return SensorConfig(gyro_on=False, acc_rate_hz=c.stand_rate_hz, gyr_rate_hz=c.full_rate_hz, mag_rate_hz=c.mag_rate_hz,
                                batch_s=batch, gyro_wake_on_motion=True, wake_threshold_ms2=WAKE_THRESHOLD_MS2,
                                sleep_after_s=SLEEP_AFTER_S, mag_follows_gyro=True), False
        if gyro:  # ZUPT-KF (initialisation or a one-step examination) needs the full rate
            return SensorConfig(gyro_on=True, acc_rate_hz=c.full_rate_hz, gyr_rate_hz=c.full_rate_hz, mag_rate_hz=c.mag_rate_hz,
                                batch_s=batch), False
        if self.run_wake():  # de-sampled Gait-DR; the device wakes the gyroscope on a run
            return SensorConfig(gyro_on=False, acc_rate_hz=c.pdr_rate_hz, gyr_rate_hz=c.full_rate_hz, mag_rate_hz=c.pdr_rate_hz,
                                batch_s=batch, gyro_wake_on_motion=True, wake_threshold_ms2=float(self.run_wake_ms2 or 0.0),
                                sleep_after_s=SLEEP_AFTER_S, wake_mode="high_g"), False
        if self.mode == "auto" and self.weak_wake is not None:  # de-sampled Gait-DR; the device wakes it on a weak field
            thr, b, w = self.weak_wake
            return SensorConfig(gyro_on=False, acc_rate_hz=c.pdr_rate_hz, gyr_rate_hz=c.full_rate_hz, mag_rate_hz=c.pdr_rate_hz,
                                batch_s=batch, gyro_wake_on_motion=True, sleep_after_s=WEAK_SLEEP_AFTER_S,
                                wake_mode="weak_field", wake_field_ut=thr, mag_offset_ut=b, mag_matrix=w), False
        # 004 Section 4.3: de-sampled Gait-DR
        return SensorConfig(gyro_on=False, acc_rate_hz=c.pdr_rate_hz, gyr_rate_hz=0.0, mag_rate_hz=c.pdr_rate_hz, batch_s=batch), False

    # ------------------------------------------------------------------ internals
    def _calibrate(self, behaviour: str) -> None:
        """Initialise ``behaviour``; an interrupted initialisation of it continues where it stopped (the step
        pairs it gathered are kept too), so a brief mislabelled stretch does not restart L0."""
        if self.calibrating is not None:
            self.progress_m[self.calibrating] = self.l_zupt_m
        self.calibrating, self.l_zupt_m = behaviour, self.progress_m.get(behaviour, 0.0)
        self.pattern_left = None  # a full initialisation (a walking pattern's sets it again after this)

    def _resumable(self, behaviour: str) -> bool:
        """Calibrated (profile or this session) and not failed an examination since."""
        return self.profile.is_calibrated(behaviour) and behaviour not in self.failed

    def _switch(self, working: str, t_ns: int, reason: str) -> list[Event]:
        if working == self.working:
            return []
        previous, self.working = self.working, working
        self.cadences = []
        if working == "pdr":
            self.pattern_left = None
        if working == "zupt":
            self.exam_active = False
            self.assist_active = False
        return [Event(t_ns, "mode_switch", {"from": previous, "to": working, "reason": reason})]

    def _start_exam(self, t_s: float, t_ns: int, reason: str) -> list[Event]:
        self.exam_active = True
        self.exam_misses = 0
        self.exam_strides = 0
        self.exam_started_s = t_s
        return [Event(t_ns, "examination_started", {"reason": reason, "behaviour": self.behaviour})]

    def get_state(self) -> dict[str, Any]:
        return {
            "mode": self.mode,
            "config": self.config.to_dict(),
            "profile": self.profile.to_dict(copy=False),
            "working": self.working,
            "behaviour": self.behaviour,
            "calibrating": self.calibrating,
            "l_zupt_m": self.l_zupt_m,
            "last_exam_s": self.last_exam_s,
            "exam_active": self.exam_active,
            "exam_started_s": self.exam_started_s,
            "nav_ready": self.nav_ready,
            "compass_ready": self.compass_ready,
            "assist_active": self.assist_active,
            "assist_weak": self.assist_weak,
            "zupt_aligned": self.zupt_aligned,
            "device_gyro_awake": self.device_gyro_awake,
            "step_t_s": self.step_t_s,
            "exam_misses": self.exam_misses,
            "exam_strides": self.exam_strides,
            "deviation_pending": sorted(self.deviation_pending),
            "heading_misses": self.heading_misses,
            "failed": sorted(self.failed),
            "progress_m": dict(self.progress_m),
            "cadences": list(self.cadences),
            "pattern_left": self.pattern_left,
            "run_wake_ms2": self.run_wake_ms2,
            "weak_wake": None if self.weak_wake is None else [self.weak_wake[0], list(self.weak_wake[1]), list(self.weak_wake[2])],
        }

    @classmethod
    def from_state(cls, d: dict[str, Any]) -> Scheduler:
        obj = cls(d["mode"], EngineConfig.from_dict(d["config"]), Profile.from_dict(d["profile"]))
        for key in ("working", "behaviour", "calibrating", "l_zupt_m", "last_exam_s", "exam_active", "exam_started_s",
                    "nav_ready", "compass_ready", "assist_active"):
            setattr(obj, key, d[key])
        obj.zupt_aligned = bool(d.get("zupt_aligned", False))  # absent in states stored before it existed
        obj.assist_weak = bool(d.get("assist_weak", False))
        obj.device_gyro_awake = bool(d.get("device_gyro_awake", False))
        obj.step_t_s = float(d.get("step_t_s", 0.0))
        obj.exam_misses = int(d.get("exam_misses", 0))
        obj.exam_strides = int(d.get("exam_strides", 0))
        obj.deviation_pending = {str(b) for b in d.get("deviation_pending", [])}  # older states: none to test
        obj.heading_misses = int(d.get("heading_misses", 0))
        obj.failed = set(d["failed"])
        obj.progress_m = {str(k): float(v) for k, v in d["progress_m"].items()}
        obj.cadences = [float(f) for f in d.get("cadences", [])]  # older states: none yet
        left = d.get("pattern_left")
        obj.pattern_left = None if left is None else int(left)
        wake = d.get("run_wake_ms2")  # older states: none
        obj.run_wake_ms2 = None if wake is None else float(wake)
        ww = d.get("weak_wake")  # older states: none
        obj.weak_wake = None if ww is None else (float(ww[0]), tuple(float(x) for x in ww[1]), tuple(float(x) for x in ww[2]))
        return obj
