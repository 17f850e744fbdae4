"""The scheduler as a specification of 004 Tables 1-3."""

from __future__ import annotations

import pytest

from energy.config import EngineConfig
from energy.profile import BehaviourCalibration, Profile
from energy.scheduler import LOW_POWER_BATCH_S, WEAK_SLEEP_AFTER_S, Scheduler

CFG = EngineConfig(l0_m=20.0, t0_s=30.0)
# a stride's heading-deviation test (energy.engine._heading_test) that fits / misses the stored deviation
FITS = {"passed": True, "gamma_psi_rad": 3.10, "deviation_rad": 3.12, "sigma_rad": 0.07}
MISSES = {"passed": False, "gamma_psi_rad": -0.27, "deviation_rad": 3.12, "sigma_rad": 0.07}


def walk_to(s: Scheduler, metres: float, step: float = 1.4) -> None:
    done = 0.0
    while done < metres:
        s.on_zupt_distance(step, 0)
        done += step


def calibrated(*behaviours: str) -> Profile:
    return Profile({b: BehaviourCalibration(sigma_d_m=0.05, calibrated=True, n_steps=30) for b in behaviours})


def aligned(mode: str, config: EngineConfig, profile: Profile) -> Scheduler:
    """A scheduler whose ZUPT-KF has aligned once (before that the gyroscope is always wanted)."""
    s = Scheduler(mode, config, profile)
    s.nav_ready = True
    return s


def standing(profile: Profile) -> Scheduler:
    """An auto scheduler whose ZUPT-KF has levelled on the still foot, no stored deviation pending, standing."""
    s = aligned("auto", CFG, profile)
    s.zupt_aligned = True
    s.deviation_pending.clear()
    s.on_behaviour("stand", 1.0, 1)
    return s


# ---------------------------------------------------------------- Table 1: gyroscope strategy
@pytest.mark.parametrize("working", ["zupt", "pdr"])
def test_table1_static_behaviour_turns_gyro_off(working: str) -> None:
    s = aligned("auto", CFG, calibrated("walk", "run"))
    s.working = working
    s.on_behaviour("stand", 1.0, 1)
    assert not s.gyro_wanted()
    cfg = s.sensor_config()
    assert not cfg.gyro_on and cfg.gyr_rate_hz == 0 and cfg.acc_rate_hz == CFG.stand_rate_hz


@pytest.mark.parametrize("profile", [Profile(), calibrated("walk")])
def test_table1_standing_while_a_moving_behaviour_has_no_model_leaves_the_gyro_to_the_device(profile) -> None:
    """Off, but woken by the device on the first motion: the motion that follows may be one Gait-DR has no
    model for (the mixed day's first run after a stand: five strides on the generic prior, 2.5 m short)."""
    from energy.scheduler import LOW_POWER_BATCH_S

    s = standing(profile)
    cfg = s.sensor_config()
    assert not cfg.gyro_on and cfg.gyro_wake_on_motion and cfg.mag_follows_gyro and not s.idle()
    assert cfg.batch_s == LOW_POWER_BATCH_S  # the device needs no answer to wake it
    s.profile = calibrated("walk", "run")
    assert s.idle()


def test_table1_standing_without_a_heading_source_leaves_the_gyro_to_the_device() -> None:
    """Every behaviour calibrated, but the compass not trusted: the walk that may follow needs the gyroscope for its
    turns from the first stride, so the device wakes it on motion instead of the host after a long upload."""
    from energy.scheduler import LOW_POWER_BATCH_S

    s = standing(calibrated("walk", "run"))
    assert s.idle()
    s.compass_ready = False
    cfg = s.sensor_config()
    assert not s.idle() and not cfg.gyro_on and cfg.gyro_wake_on_motion
    assert cfg.batch_s == LOW_POWER_BATCH_S  # the device needs no answer to wake it
    s.compass_ready = True
    assert s.idle()


def test_standing_with_a_gyroscope_the_device_woke_keeps_it_until_the_device_puts_it_down() -> None:
    """The "stand" label lags the data by up to 1.5 s: a gyroscope the device woke for a foot that already walks
    stays with the device (wake-on-motion) instead of being switched off (gdin exp43, returning: 10.9 m)."""
    s = standing(calibrated("walk", "run"))
    assert s.idle()
    s.device_gyro_awake = True
    assert not s.idle() and s.sensor_config().gyro_wake_on_motion
    assert Scheduler.from_state(s.get_state()).device_gyro_awake
    s.device_gyro_awake = False
    assert s.idle()


def test_table1_zupt_mode_keeps_gyro_on_while_moving() -> None:
    s = aligned("auto", CFG, Profile())
    s.on_behaviour("walk", 1.0, 1)
    assert s.working == "zupt" and s.gyro_wanted()
    assert s.sensor_config().acc_rate_hz == CFG.full_rate_hz


def test_table1_gait_dr_gyro_off_until_t0_then_on_for_one_step() -> None:
    s = aligned("auto", CFG, Profile())
    s.on_behaviour("walk", 1.0, 1)
    walk_to(s, CFG.l0_m)
    assert s.ready_for_pdr()
    s.on_calibrated(10.0, 10)
    assert s.working == "pdr" and not s.gyro_wanted()
    assert s.sensor_config().acc_rate_hz == CFG.pdr_rate_hz  # 004 Section 4.3 de-sampling
    assert not s.exam_due(10.0 + CFG.t0_s - 0.1)
    assert s.exam_due(10.0 + CFG.t0_s)
    s.start_exam(40.0, 40)
    assert s.gyro_wanted() and s.sensor_config().acc_rate_hz == CFG.full_rate_hz
    s.on_exam_result(True, 1.40, 1.41, 41.0, 41)
    assert s.working == "pdr" and not s.gyro_wanted()


# ---------------------------------------------------------------- Table 2: mode switching
def test_table2_stays_in_zupt_below_l0() -> None:
    s = aligned("auto", CFG, Profile())
    s.on_behaviour("walk", 1.0, 1)
    walk_to(s, CFG.l0_m - 2.0)
    assert not s.ready_for_pdr()


def test_table2_new_behaviour_sends_gait_dr_back_to_zupt() -> None:
    s = aligned("auto", CFG, Profile())
    s.on_behaviour("walk", 1.0, 1)
    walk_to(s, CFG.l0_m)
    s.on_calibrated(10.0, 10)
    events = s.on_behaviour("run", 12.0, 12)
    assert s.working == "zupt" and s.calibrating == "run" and s.l_zupt_m == 0.0
    assert any(e.kind == "mode_switch" and e.detail["to"] == "zupt" for e in events)


def test_table2_new_behaviour_after_a_stand_sends_gait_dr_back_to_zupt() -> None:
    s = aligned("auto", CFG, Profile())
    s.on_behaviour("walk", 1.0, 1)
    walk_to(s, CFG.l0_m)
    s.on_calibrated(10.0, 10)
    s.profile.behaviours["walk"] = calibrated("walk").behaviours["walk"]  # what the engine stores
    s.on_behaviour("stand", 11.0, 11)
    s.on_behaviour("walk", 14.0, 14)  # calibrated: Gait-DR goes on
    assert s.working == "pdr" and not s.exam_active
    s.on_behaviour("stand", 20.0, 20)
    events = s.on_behaviour("run", 24.0, 24)  # no model for it: the generic prior would place its strides
    assert s.working == "zupt" and s.calibrating == "run" and s.l_zupt_m == 0.0
    assert any(e.kind == "mode_switch" and e.detail["to"] == "zupt" for e in events)


def test_table2_calibrated_behaviour_resumes_gait_dr_with_an_examination() -> None:
    s = aligned("auto", CFG, calibrated("walk"))
    events = s.on_behaviour("walk", 1.0, 1)
    assert s.working == "pdr" and s.exam_active
    assert {e.kind for e in events} >= {"mode_switch", "examination_started"}


def test_pdr_mode_ignores_behaviour_changes_and_zupt_mode_never_switches() -> None:
    s = aligned("pdr", CFG, Profile())
    s.on_behaviour("walk", 1.0, 1)
    walk_to(s, CFG.l0_m)
    s.on_calibrated(5.0, 5)
    s.on_behaviour("run", 6.0, 6)
    assert s.working == "pdr" and not s.gyro_wanted()
    z = aligned("zupt", CFG, Profile())
    z.on_behaviour("walk", 1.0, 1)
    walk_to(z, 10 * CFG.l0_m)
    assert not z.ready_for_pdr() and z.gyro_wanted()
    z.on_behaviour("stand", 2.0, 2)
    assert z.gyro_wanted() and z.sensor_config().acc_rate_hz == CFG.full_rate_hz


# ---------------------------------------------------------------- Table 3: examination
@pytest.mark.parametrize("passed, working", [(True, "pdr"), (False, "zupt")])
def test_table3_examination_outcome(passed: bool, working: str) -> None:
    s = aligned("auto", CFG, Profile())
    s.on_behaviour("walk", 1.0, 1)
    walk_to(s, CFG.l0_m)
    s.on_calibrated(10.0, 10)
    s.start_exam(40.0, 40)
    if not passed:  # a miss is confirmed on the next stride (EXAM_STRIDES_TO_FAIL = 2)
        events = s.on_exam_result(passed, 1.4, 1.2, 40.5, 40)
        assert [e.kind for e in events] == ["examination_repeated"]
        assert s.working == "pdr" and s.exam_active and s.gyro_wanted()
    events = s.on_exam_result(passed, 1.4, 1.2, 41.0, 41)
    assert s.working == working and not s.exam_active and s.last_exam_s == 41.0
    assert events[0].kind == ("examination_passed" if passed else "examination_failed")
    if not passed:
        assert s.calibrating == "walk" and s.l_zupt_m == 0.0


def test_table3_a_single_missed_stride_followed_by_a_good_one_keeps_gait_dr() -> None:
    from energy.scheduler import EXAM_STRIDES_TO_FAIL

    assert EXAM_STRIDES_TO_FAIL == 2
    s = aligned("auto", CFG, calibrated("walk"))
    s.on_behaviour("walk", 1.0, 1)
    assert s.exam_active and s.working == "pdr"
    assert [e.kind for e in s.on_exam_result(False, 1.35, 1.61, 3.0, 3)] == ["examination_repeated"]
    r = Scheduler.from_state(s.get_state())  # the miss survives a restore
    for sched in (s, r):
        assert [e.kind for e in sched.on_exam_result(True, 1.36, 1.38, 4.2, 4)] == ["examination_passed"]
        assert sched.working == "pdr" and not sched.exam_active and sched.exam_misses == 0
    s.start_exam(40.0, 40)  # a new examination starts with no miss
    assert s.exam_misses == 0


def test_state_round_trip() -> None:
    s = aligned("auto", CFG, calibrated("run"))
    s.on_behaviour("walk", 1.0, 1)
    walk_to(s, 7.0)
    r = Scheduler.from_state(s.get_state())
    assert r.get_state() == s.get_state()


def test_gyro_stays_on_until_the_zupt_kf_has_aligned() -> None:
    s = Scheduler("auto", CFG, calibrated("walk", "run"))
    s.on_behaviour("stand", 1.0, 1)
    assert s.gyro_wanted() and s.sensor_config().acc_rate_hz == CFG.full_rate_hz
    s.nav_ready = True
    assert not s.gyro_wanted() and s.idle()


def test_gait_dr_without_a_heading_source_keeps_the_gyro_on() -> None:
    s = aligned("auto", CFG, Profile())
    s.on_behaviour("walk", 1.0, 1)
    walk_to(s, CFG.l0_m)
    s.on_calibrated(10.0, 10)
    s.compass_ready = False
    assert s.working == "pdr" and s.gyro_wanted()
    s.compass_ready = True
    assert not s.gyro_wanted()


def test_tick_starts_a_due_examination_and_gives_up_a_stale_one() -> None:
    s = aligned("auto", CFG, Profile())
    s.on_behaviour("walk", 1.0, 1)
    walk_to(s, CFG.l0_m)
    s.on_calibrated(10.0, 10)
    assert s.tick(10.0 + CFG.t0_s - 1.0, 0) == []
    started = s.tick(10.0 + CFG.t0_s, 0)
    assert [e.kind for e in started] == ["examination_started"] and s.exam_active
    assert s.tick(10.0 + CFG.t0_s + CFG.exam_timeout_s - 0.5, 0) == [] and s.exam_active
    skipped = s.tick(10.0 + CFG.t0_s + CFG.exam_timeout_s + 0.5, 0)
    assert [e.kind for e in skipped] == ["examination_skipped"] and not s.exam_active and not s.gyro_wanted()


def test_heading_assist_turns_the_gyro_on_in_a_disturbance_and_off_after_it() -> None:
    s = aligned("auto", EngineConfig(l0_m=20.0, heading_assist=True), Profile())
    s.on_behaviour("walk", 1.0, 1)
    walk_to(s, 20.0)
    s.on_calibrated(10.0, 10)
    assert not s.gyro_wanted()
    assert [e.kind for e in s.request_heading_assist(0)] == ["gyroscope_requested"]
    assert s.gyro_wanted() and s.request_heading_assist(0) == []
    assert [e.kind for e in s.release_heading_assist(0)] == ["gyroscope_released"]
    assert not s.gyro_wanted()
    off = aligned("auto", EngineConfig(l0_m=20.0), Profile())  # off by default
    off.on_behaviour("walk", 1.0, 1)
    walk_to(off, 20.0)
    off.on_calibrated(10.0, 10)
    assert off.request_heading_assist(0) == [] and not off.gyro_wanted()


def test_an_interrupted_initialisation_continues_where_it_stopped() -> None:
    s = aligned("auto", CFG, Profile())
    s.on_behaviour("walk", 1.0, 1)
    walk_to(s, 0.6 * CFG.l0_m)
    done = s.l_zupt_m
    s.on_behaviour("run", 2.0, 2)  # a brief mislabelled stretch
    assert s.calibrating == "run" and s.l_zupt_m == 0.0
    walk_to(s, 3.0)
    s.on_behaviour("walk", 3.0, 3)
    assert s.calibrating == "walk" and s.l_zupt_m == done
    walk_to(s, 0.4 * CFG.l0_m + 1.0)
    assert s.ready_for_pdr()


# ---------------------------------------------------------------- upload period
def test_long_uploads_only_with_the_gyroscope_off_once_gait_dr_can_navigate() -> None:
    from energy.scheduler import BATCH_S, LOW_POWER_BATCH_S

    assert LOW_POWER_BATCH_S > BATCH_S
    s = Scheduler("auto", CFG, calibrated("walk", "run"))
    assert s.sensor_config().batch_s == BATCH_S  # not aligned yet: the start of the walk must be heard at once
    s.nav_ready = True
    s.on_behaviour("stand", 1.0, 1)
    assert not s.sensor_config().gyro_on and s.sensor_config().batch_s == LOW_POWER_BATCH_S
    s.on_behaviour("walk", 2.0, 2)  # calibrated: Gait-DR with a one-stride examination
    assert s.working == "pdr" and s.exam_active
    assert s.sensor_config().gyro_on and s.sensor_config().batch_s == BATCH_S
    s.on_exam_result(True, 1.3, 1.3, 3.0, 3, FITS)
    assert not s.sensor_config().gyro_on and s.sensor_config().batch_s == LOW_POWER_BATCH_S
    for mode in ("zupt", "pdr"):  # the fixed schemes keep 1-s uploads
        f = aligned(mode, CFG, calibrated("walk"))
        f.working = "pdr"
        assert f.sensor_config().batch_s == BATCH_S


def test_standing_at_session_start_gyro_sleeps_once_aligned_only_for_a_returning_user() -> None:
    for profile, sleeps in ((calibrated("walk", "run"), True), (Profile(), False)):
        s = Scheduler("auto", CFG, profile)
        s.deviation_pending.clear()  # its stored heading deviation confirmed (see the test below)
        assert s.behaviour == "stand" and s.gyro_wanted()  # the ZUPT-KF must level on the still foot first
        s.zupt_aligned = True
        assert s.gyro_wanted() is not sleeps  # a new user: no model could place the first steps
        if sleeps:
            assert s.sensor_config().acc_rate_hz == CFG.stand_rate_hz
            s.on_behaviour("walk", 5.0, 5)  # the profile resumes after a one-stride examination
            assert s.working == "pdr" and s.exam_active and s.gyro_wanted()
        restored = Scheduler.from_state(s.get_state())
        assert restored.zupt_aligned and restored.gyro_wanted() == s.gyro_wanted()
    failed = Scheduler("auto", CFG, calibrated("walk"))
    failed.failed.add("walk")  # an examination failed in this session: not resumable
    failed.zupt_aligned = True
    assert failed.gyro_wanted()


def test_short_uploads_again_when_an_examination_falls_due() -> None:
    from energy.scheduler import BATCH_S, LOW_POWER_BATCH_S

    s = aligned("auto", CFG, calibrated("walk"))
    s.on_behaviour("walk", 0.0, 0)
    s.on_exam_result(True, 1.3, 1.3, 1.0, 1, FITS)  # last examination at 1 s
    s.tick(1.0 + CFG.t0_s - LOW_POWER_BATCH_S - 0.5, 2)
    assert s.sensor_config().batch_s == LOW_POWER_BATCH_S
    s.tick(1.0 + CFG.t0_s - LOW_POWER_BATCH_S + 0.5, 3)  # due within one long upload
    assert not s.sensor_config().gyro_on and s.sensor_config().batch_s == BATCH_S
    assert Scheduler.from_state(s.get_state()).sensor_config() == s.sensor_config()


# ---------------------------------------------------------------- stored heading deviation (sensor re-mounted)
def resumed() -> Scheduler:
    """A returning user walking off in Gait-DR on a stored walk calibration, its examination running."""
    s = aligned("auto", CFG, calibrated("walk", "run"))
    s.on_behaviour("walk", 1.0, 1)
    assert s.working == "pdr" and s.exam_active and s.deviation_pending == {"walk", "run"}
    return s


def test_a_stored_deviation_that_misses_twice_fails_the_examination_and_re_initialises() -> None:
    s = resumed()
    assert [e.kind for e in s.on_exam_result(True, 1.4, 1.41, 2.0, 2, MISSES)] == ["examination_repeated"]
    assert s.exam_active and s.working == "pdr"
    events = s.on_exam_result(True, 1.4, 1.41, 3.0, 3, MISSES)  # step length fits, the deviation does not
    assert [e.kind for e in events] == ["examination_failed", "mode_switch"]
    assert events[0].detail["cause"] == "heading_deviation" and "re-mounted" in events[0].detail["reason"]
    assert events[0].detail["heading"] == MISSES
    assert s.working == "zupt" and s.calibrating == "walk" and s.l_zupt_m == 0.0 and not s.exam_active
    assert "walk" in s.failed and not s._resumable("walk")
    assert s.deviation_pending == set()  # every stored deviation belonged to the old mount


def test_a_fitting_deviation_confirms_the_profile_once() -> None:
    s = resumed()
    events = s.on_exam_result(True, 1.4, 1.41, 2.0, 2, FITS)
    assert [e.kind for e in events] == ["examination_passed"] and events[0].detail["heading"] == FITS
    assert s.working == "pdr" and not s.exam_active and s.deviation_pending == {"run"}
    s.start_exam(40.0, 40)  # later examinations are 004 Table 3's: a stride without a heading observation passes
    assert [e.kind for e in s.on_exam_result(True, 1.4, 1.41, 41.0, 41)] == ["examination_passed"]


def test_a_step_length_miss_fails_whatever_the_heading() -> None:
    s = resumed()
    s.on_exam_result(False, 1.4, 1.8, 2.0, 2, FITS)
    events = s.on_exam_result(False, 1.4, 1.8, 3.0, 3, FITS)
    assert events[0].kind == "examination_failed" and events[0].detail["cause"] == "step_length"
    assert events[1].detail["reason"] == "step-length model no longer fits"
    assert s.deviation_pending == {"run"}  # the deviation itself was confirmed


def test_an_unconfirmed_deviation_keeps_the_examination_over_turning_strides() -> None:
    from energy.scheduler import EXAM_MAX_STRIDES

    s = resumed()
    for k in range(EXAM_MAX_STRIDES - 1):  # turning strides: no gamma - psi observed
        events = s.on_exam_result(True, 1.4, 1.41, 2.0 + k, 2 + k)
        assert [e.kind for e in events] == ["examination_repeated"] and s.exam_active and s.gyro_wanted()
        assert events[0].detail["reason"] == "heading deviation not observed"
    assert [e.kind for e in s.on_exam_result(True, 1.4, 1.41, 9.0, 9)] == ["examination_passed"]
    assert "walk" in s.deviation_pending  # still to be confirmed, at the next ZUPT-KF stride


def test_zupt_kf_strides_outside_an_examination_test_the_stored_deviation() -> None:
    s = resumed()
    s.on_exam_result(False, 1.4, 1.8, 2.0, 2)
    s.on_exam_result(False, 1.4, 1.8, 3.0, 3)  # step-length failure: re-initialising walk in the ZUPT-KF
    assert s.working == "zupt" and "walk" in s.deviation_pending
    walk_to(s, 7.0)
    assert s.on_heading_check(MISSES, 4.0, 4) == []  # one miss is confirmed on the next stride
    r = Scheduler.from_state(s.get_state())
    for sched in (s, r):
        events = sched.on_heading_check(MISSES, 5.0, 5)
        assert [e.kind for e in events] == ["examination_failed"] and events[0].detail["cause"] == "heading_deviation"
        assert sched.calibrating == "walk" and sched.l_zupt_m == 0.0 and sched.deviation_pending == set()
    ok = resumed()
    assert ok.on_heading_check(MISSES, 2.0, 2) == [] and ok.on_heading_check(FITS, 3.0, 3) == []
    assert ok.deviation_pending == {"run"} and ok.heading_misses == 0
    assert ok.on_heading_check(MISSES, 4.0, 4) == []  # confirmed: nothing more to test


def test_a_new_user_or_a_fresh_calibration_has_no_stored_deviation_to_test() -> None:
    assert aligned("auto", CFG, Profile()).deviation_pending == set()
    assert aligned("zupt", CFG, calibrated("walk")).deviation_pending == set()
    s = resumed()
    s.on_exam_result(True, 1.4, 1.41, 2.0, 2, MISSES)
    s.on_exam_result(True, 1.4, 1.41, 3.0, 3, MISSES)
    walk_to(s, CFG.l0_m)
    s.on_calibrated(30.0, 30)
    assert s.working == "pdr" and "walk" not in s.failed and s.deviation_pending == set()


def test_deviation_state_round_trip() -> None:
    s = resumed()
    s.on_exam_result(True, 1.4, 1.41, 2.0, 2, MISSES)
    state = s.get_state()
    assert state["deviation_pending"] == ["run", "walk"] and state["exam_strides"] == 1 and state["exam_misses"] == 1
    r = Scheduler.from_state(state)
    assert r.get_state() == state
    old = {k: v for k, v in state.items() if k not in ("deviation_pending", "exam_strides", "heading_misses")}
    assert Scheduler.from_state(old).deviation_pending == set()  # states stored before the test existed


def test_a_session_start_on_an_unconfirmed_deviation_leaves_the_first_strides_to_the_zupt_kf() -> None:
    """Gait-DR would place the first strides on the stored deviation until the examination's verdict: with the
    gyroscope woken on the first motion they are the ZUPT-KF's, and they examine it."""
    s = Scheduler("auto", CFG, calibrated("walk", "run"))
    s.zupt_aligned = True
    assert s.deviation_pending == {"walk", "run"}
    assert s.gyro_wanted() and s.wake_on_motion() and not s.idle()
    cfg = s.sensor_config()
    assert cfg.gyro_wake_on_motion and not cfg.gyro_on and cfg.acc_rate_hz == CFG.stand_rate_hz
    assert Scheduler.from_state(s.get_state()).sensor_config() == cfg
    s.on_behaviour("walk", 5.0, 5)
    assert s.working == "pdr" and s.exam_active and s.gyro_wanted()
    s.on_exam_result(True, 1.4, 1.41, 6.0, 6, FITS)
    s.on_behaviour("stand", 9.0, 9)
    assert s.idle()  # confirmed: later stands sleep


# ---------------------------------------------------------------- Table 2 (ii): walking pattern
FITTED_HZ = [(0.71, 0.90)]  # cadences the walk model was fitted on


def walking_in_gait_dr(mode: str = "auto") -> Scheduler:
    s = aligned(mode, CFG, Profile())
    s.on_behaviour("walk", 1.0, 1)
    walk_to(s, CFG.l0_m)
    s.on_calibrated(10.0, 10)
    s.profile.behaviours["walk"] = calibrated("walk").behaviours["walk"]  # what the engine stores
    assert s.working == "pdr"
    return s


def test_a_sustained_cadence_change_re_initialises_the_walking_pattern_and_one_odd_stride_does_not() -> None:
    from energy.scheduler import PATTERN_INIT_STRIDES, PATTERN_STRIDES

    s = walking_in_gait_dr()
    # odd strides, single and in pairs, fast and slow (the window's median stays inside)
    odd = [0.87] * 4 + [1.05] + [0.86] * 6 + [0.60] + [0.88] * 3 + [1.05, 1.1] + [0.88] * 3 + [0.6, 0.5] + [0.88] * 5
    assert not [e for f in odd for e in s.on_cadence(f, FITTED_HZ, 1)]
    assert s.working == "pdr"
    fast = [1.0, 0.96, 1.04]
    n_out = PATTERN_STRIDES // 2 + 1  # the median leaves the range with the majority of the window
    for f in fast[:n_out - 1]:
        assert s.on_cadence(f, FITTED_HZ, 2) == []
    events = s.on_cadence(fast[n_out - 1], FITTED_HZ, 3)
    assert [e.kind for e in events] == ["walking_pattern_changed", "mode_switch"]
    assert events[0].detail["f_s_hz"] > FITTED_HZ[0][1] and len(s.cadences) == 0
    assert s.working == "zupt" and s.gyro_wanted() and s.calibrating == "walk" and s.l_zupt_m == 0.0
    assert PATTERN_STRIDES < PATTERN_INIT_STRIDES  # the hysteresis is shorter than the re-initialisation
    for _ in range(PATTERN_INIT_STRIDES - 1):  # far shorter than L0
        s.on_zupt_distance(1.6, 4)
        assert not s.ready_for_pdr()
    s.on_zupt_distance(1.6, 5)
    assert s.ready_for_pdr() and s.l_zupt_m < CFG.l0_m
    s.on_calibrated(20.0, 20)
    assert s.working == "pdr" and s.pattern_left is None and s.last_exam_s == 20.0


def test_a_pace_between_two_sample_counts_is_not_a_new_walking_pattern() -> None:
    """Periods in whole 0.04-s samples: a 1.11-s pace reads as 1.08 and 1.16 s. Three 1.08-s strides in five make
    the median cadence (0.926 Hz) leave a range fitted up to 0.909 Hz; the middle periods' mean (1.107 s) does
    not. One sample shorter throughout (1.04 s) is a new pattern."""
    fitted = [(0.70, 0.909)]
    s = walking_in_gait_dr()
    mixed = [1 / 1.08, 1 / 1.16, 1 / 1.08, 1 / 1.16, 1 / 1.08, 1 / 1.24, 1 / 1.08, 1 / 1.16, 1 / 1.08]
    assert not [e for f in mixed for e in s.on_cadence(f, fitted, 1)] and s.working == "pdr"
    events = [e for f in [1 / 1.04] * 3 for e in s.on_cadence(f, fitted, 2)]
    assert [e.kind for e in events] == ["walking_pattern_changed", "mode_switch"] and s.working == "zupt"


def test_a_pace_between_two_fitted_paces_is_a_new_walking_pattern() -> None:
    """A model fitted on a slow and a fast walk (two cadence ranges) has not seen the walk between them (held-out
    synthetic day, seed 2: interpolated 9 % long, within its examination's 3 sigma); paces within either are
    known."""
    fitted = [(0.72, 0.77), (0.95, 1.0)]
    s = walking_in_gait_dr()
    known = [0.74, 0.75, 0.98, 0.97, 0.74, 0.99, 0.75]
    assert not [e for f in known for e in s.on_cadence(f, fitted, 1)] and s.working == "pdr"
    s.on_behaviour("stand", 30.0, 30)
    s.on_behaviour("walk", 33.0, 33)
    events = [e for f in [0.87] * 5 for e in s.on_cadence(f, fitted, 34)]
    assert [e.kind for e in events] == ["walking_pattern_changed", "mode_switch"] and s.working == "zupt"
    assert events[0].detail["fitted_hz"] == [0.72, 1.0]
    assert events[0].detail["fitted_ranges_hz"] == [[0.72, 0.77], [0.95, 1.0]]


def test_the_walking_pattern_trigger_needs_auto_mode_gait_dr_and_a_fitted_model() -> None:
    fast = [1.0] * 6
    p = walking_in_gait_dr("pdr")  # the fixed scheme has no examinations
    assert not [e for f in fast for e in p.on_cadence(f, FITTED_HZ, 1)] and p.working == "pdr"
    a = walking_in_gait_dr()
    assert not [e for f in fast for e in a.on_cadence(f, None, 1)] and a.working == "pdr"
    a.on_behaviour("run", 30.0, 30)  # a new behaviour is initialised in full, not as a walking pattern
    assert a.working == "zupt" and a.pattern_left is None


def test_a_behaviour_change_or_stand_restarts_the_cadence_window() -> None:
    from energy.scheduler import PATTERN_STRIDES

    s = walking_in_gait_dr()
    for _ in range(PATTERN_STRIDES - 1):
        s.on_cadence(1.0, FITTED_HZ, 1)
    s.on_behaviour("stand", 30.0, 30)
    s.on_behaviour("walk", 33.0, 33)
    assert s.on_cadence(1.0, FITTED_HZ, 34) == [] and s.working == "pdr"


def test_walking_pattern_state_round_trip() -> None:
    from energy.scheduler import PATTERN_INIT_STRIDES, PATTERN_STRIDES

    s = walking_in_gait_dr()
    for _ in range(PATTERN_STRIDES - 1):
        s.on_cadence(1.0, FITTED_HZ, 1)
    r = Scheduler.from_state(s.get_state())  # a window half full
    assert r.get_state() == s.get_state() and r.cadences == s.cadences
    for sched in (s, r):
        assert sched.on_cadence(1.0, FITTED_HZ, 2)[0].kind == "walking_pattern_changed"
        sched.on_zupt_distance(1.6, 3)
    r = Scheduler.from_state(s.get_state())  # during the re-initialisation
    assert r.get_state() == s.get_state() and r.pattern_left == PATTERN_INIT_STRIDES - 1
    for _ in range(PATTERN_INIT_STRIDES - 1):
        r.on_zupt_distance(1.6, 4)
    assert r.ready_for_pdr()
    old = s.get_state()
    del old["cadences"], old["pattern_left"]  # a state stored before the walking-pattern trigger
    o = Scheduler.from_state(old)
    assert o.cadences == [] and o.pattern_left is None


def test_an_examination_failed_at_a_cadence_the_model_never_saw_initialises_a_walking_pattern_not_l0() -> None:
    from energy.scheduler import PATTERN_INIT_STRIDES

    for new_pattern in (True, False):
        s = walking_in_gait_dr()
        s.start_exam(40.0, 40)
        s.on_exam_result(False, 1.62, 1.33, 40.5, 40, None, new_pattern)
        events = s.on_exam_result(False, 1.58, 1.33, 41.5, 41, None, new_pattern)
        assert events[0].kind == "examination_failed" and s.working == "zupt" and s.calibrating == "walk"
        assert not s.exam_active and s.l_zupt_m == 0.0
        if new_pattern:  # a walking pattern of a model still good for its own: a few ZUPT-KF strides
            assert events[0].detail["cause"] == "walking_pattern" and s.pattern_left == PATTERN_INIT_STRIDES
            assert "walk" not in s.failed
        else:  # the model no longer fits where it was fitted: a whole initialisation
            assert events[0].detail["cause"] == "step_length" and s.pattern_left is None and "walk" in s.failed
    s = walking_in_gait_dr()  # a heading miss is a re-mounted sensor whatever the cadence
    s.start_exam(40.0, 40)
    miss = {"passed": False, "gamma_psi_rad": 1.0, "deviation_rad": 0.0, "sigma_rad": 0.05}
    s.on_exam_result(True, 1.4, 1.4, 40.5, 40, miss, True)
    assert s.on_exam_result(True, 1.4, 1.4, 41.5, 41, miss, True)[0].detail["cause"] == "heading_deviation"


# ---------------------------------------------------------------- run wake (device high-g interrupt)
def test_gait_dr_of_a_walk_lets_the_device_wake_the_gyro_on_a_run_it_has_no_model_for() -> None:
    s = walking_in_gait_dr()
    c = s.sensor_config()
    assert not c.gyro_on and not c.gyro_wake_on_motion  # no threshold known yet: plain de-sampled Gait-DR
    s.run_wake_ms2 = 42.0
    c = s.sensor_config()
    assert not c.gyro_on and c.gyro_wake_on_motion and c.wake_mode == "high_g" and c.wake_threshold_ms2 == 42.0
    assert c.acc_rate_hz == CFG.pdr_rate_hz and c.gyr_rate_hz == CFG.full_rate_hz and c.mag_rate_hz == CFG.pdr_rate_hz
    assert not c.mag_follows_gyro  # the compass keeps its field
    r = Scheduler.from_state(s.get_state())
    assert r.get_state() == s.get_state() and r.sensor_config() == c
    s.profile.behaviours["run"] = calibrated("run").behaviours["run"]  # a run has a model: nothing to wake for
    assert not s.sensor_config().gyro_wake_on_motion
    s.profile.behaviours.pop("run")
    s.start_exam(50.0, 50)  # the host wants the gyroscope: it asks for it
    assert s.sensor_config().gyro_on
    p = walking_in_gait_dr("pdr")  # the fixed scheme never asks for the gyroscope
    p.run_wake_ms2 = 42.0
    assert not p.sensor_config().gyro_wake_on_motion and not p.sensor_config().gyro_on


def test_gait_dr_with_a_trusted_compass_lets_the_device_wake_the_gyro_on_a_weak_field() -> None:
    """The engine hands the scheduler the weak-field threshold and the compass's calibration (``weak_wake``): the
    Gait-DR configuration then tells the device to wake the gyroscope itself at a weak stance; a run the person has
    no model for comes first (the high-g wake), the host's own request overrides both, the fixed ``pdr`` scheme
    never, and the setting survives a state round trip."""
    s = walking_in_gait_dr()
    b, w = (1.0, -2.0, 3.0), (1.0, 0.1, 0.0, 0.0, 0.9, 0.0, 0.0, 0.0, 1.1)
    s.weak_wake = (6.5, b, w)
    c = s.sensor_config()
    assert not c.gyro_on and c.gyro_wake_on_motion and c.wake_mode == "weak_field" and c.wake_field_ut == 6.5
    assert c.mag_offset_ut == b and c.mag_matrix == w and c.sleep_after_s == WEAK_SLEEP_AFTER_S
    assert c.acc_rate_hz == CFG.pdr_rate_hz and c.gyr_rate_hz == CFG.full_rate_hz and c.mag_rate_hz == CFG.pdr_rate_hz
    assert not c.mag_follows_gyro and c.batch_s == LOW_POWER_BATCH_S
    r = Scheduler.from_state(s.get_state())
    assert r.get_state() == s.get_state() and r.sensor_config() == c
    s.run_wake_ms2 = 42.0
    assert s.sensor_config().wake_mode == "high_g"
    s.run_wake_ms2 = None
    s.request_heading_assist(20, weak_field=True)
    assert s.sensor_config().gyro_on
    p = walking_in_gait_dr("pdr")
    p.weak_wake = (6.5, b, w)
    assert not p.sensor_config().gyro_wake_on_motion
    old = s.get_state()
    old.pop("weak_wake")  # a state stored before the field existed: no weak-field wake
    assert Scheduler.from_state(old).weak_wake is None


@pytest.mark.parametrize("weak_field_h, wanted", [(0.3, True), (0.0, False)])
def test_a_weak_field_asks_for_the_gyroscope_without_heading_assist(weak_field_h: float, wanted: bool) -> None:
    """``weak_field_h`` > 0 (the default) turns the gyroscope on in Gait-DR where the field is too weak for the
    compass to tell turns, with ``heading_assist`` off; the request survives a state round trip."""
    s = aligned("auto", EngineConfig(l0_m=20.0, weak_field_h=weak_field_h), Profile())
    s.on_behaviour("walk", 1.0, 1)
    walk_to(s, 20.0)
    s.on_calibrated(10.0, 10)
    assert s.request_heading_assist(0) == []  # a disturbance alone: heading_assist is off
    got = s.request_heading_assist(0, weak_field=True)
    assert [(e.kind, e.detail["reason"]) for e in got] == ([("gyroscope_requested", "weak magnetic field")] if wanted else [])
    back = Scheduler.from_state(s.get_state())
    assert back.gyro_wanted() == wanted and back.assist_weak == wanted
    assert [e.kind for e in back.release_heading_assist(0)] == (["gyroscope_released"] if wanted else [])
    assert not back.gyro_wanted()
