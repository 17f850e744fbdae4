"""The scheduler as a specification: 004 Tables 1-3 and the gyroscope on demand from the heading budget."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from energy.codec import dumps, loads
from energy.config import EngineConfig
from energy.profile import BehaviourCalibration, Profile
from energy.scheduler import Scheduler

CFG = EngineConfig().override({"scheduler.l0_m": 20.0, "scheduler.t0_s": 30.0})
BUDGET = CFG.scheduler.cross_track_pct
# a stride's direction examination (energy.engine._heading_test) that fits / misses the stored deviation
FITS = {"passed": True, "gamma_psi_rad": 3.10, "deviation_rad": 3.12, "sigma_rad": 0.07}
MISSES = {"passed": False, "gamma_psi_rad": -0.27, "deviation_rad": 3.12, "sigma_rad": 0.07}


def calibrated(*behaviours: str) -> Profile:
    return Profile({b: BehaviourCalibration(sigma_d_m=0.05, calibrated=True, n_steps=30) for b in behaviours})


def kinds(events) -> list[str]:
    return [e.kind for e in events]


def in_gait_dr(heading_ok: bool = True) -> Scheduler:
    """An auto scheduler of a calibrated walker in Gait-DR whose stored deviation is confirmed."""
    s = Scheduler("auto", CFG, calibrated("walk", "run"))
    s.nav_ready = s.zupt_aligned = True
    s.deviation_pending.clear()
    s.on_behaviour("walk", 1.0, 1)
    s.on_exam_result(True, 1.4, 1.4, 2.0, 2)
    if heading_ok:
        for _ in range(CFG.scheduler.release_strides):
            s.on_heading(0.5 * BUDGET, True, 3)
    assert s.working == "pdr" and not s.exam_active
    return s


# ---------------------------------------------------------------- 004 Table 2: initialisation over L0
def test_a_new_user_initialises_over_l0_then_hands_over_when_the_heading_holds() -> None:
    s = Scheduler("auto", CFG, Profile())
    s.nav_ready = True
    s.on_behaviour("walk", 1.0, 1)
    assert s.working == "zupt" and s.calibrating == "walk" and s.gyro_wanted()
    for _ in range(14):
        s.on_zupt_distance(1.5, 0)
        s.on_heading(0.5 * BUDGET, True, 0)
    assert s.ready_for_pdr()
    ev = s.on_calibrated(25.0, 25)
    assert kinds(ev) == ["calibration_done", "gyroscope_released"]
    assert ev[1].detail["reason"] == "initialisation complete" and not s.sensor_config().gyro_on


def test_an_initialisation_that_ends_where_the_heading_cannot_be_held_keeps_the_gyroscope() -> None:
    s = Scheduler("auto", CFG, Profile())
    s.nav_ready = True
    s.on_behaviour("walk", 1.0, 1)
    for _ in range(14):
        s.on_zupt_distance(1.5, 0)
        s.on_heading(4 * BUDGET, True, 0)  # an indoor compass: 20 % drift forecast
    assert kinds(s.on_calibrated(25.0, 25)) == ["calibration_done"]
    assert s.working == "pdr" and s.gyro_wanted() and s.sensor_config().gyro_on


# ---------------------------------------------------------------- the gyroscope on demand
def test_a_gait_dr_stride_beyond_the_budget_requests_the_gyroscope_and_says_why() -> None:
    s = in_gait_dr()
    assert not s.gyro_wanted()
    assert s.on_heading(0.9 * BUDGET, False, 10) == []
    ev = s.on_heading(1.5 * BUDGET, False, 11)
    assert kinds(ev) == ["gyroscope_requested"] and "heading uncertain" in ev[0].detail["reason"]
    assert s.gyro_wanted() and s.sensor_config().gyro_on


def test_the_gyroscope_is_released_only_after_release_strides_within_the_budget_running() -> None:
    s = in_gait_dr()
    s.on_heading(1.5 * BUDGET, False, 10)
    n = CFG.scheduler.release_strides
    for k in range(n - 1):
        assert s.on_heading(0.5 * BUDGET, True, 20 + k) == []
    assert s.on_heading(1.5 * BUDGET, True, 30) == []  # one stride beyond: the count starts again
    for k in range(n - 1):
        assert s.on_heading(0.5 * BUDGET, True, 40 + k) == []
    ev = s.on_heading(0.5 * BUDGET, True, 50)
    assert kinds(ev) == ["gyroscope_released"] and "compass holds the heading" in ev[0].detail["reason"]


def test_gyroscope_strides_never_request_and_gait_dr_strides_never_release() -> None:
    s = in_gait_dr()
    assert s.on_heading(9 * BUDGET, True, 1) == [] and not s.heading_gyro
    s.on_heading(9 * BUDGET, False, 2)
    for k in range(5):
        assert s.on_heading(0.1 * BUDGET, False, 3 + k) == []
    assert s.heading_gyro


@pytest.mark.parametrize("budget, wanted", [(1.0, True), (50.0, False)])
def test_the_budget_is_one_configuration_value(budget: float, wanted: bool) -> None:
    s = Scheduler("auto", CFG.override({"scheduler.cross_track_pct": budget}), calibrated("walk"))
    s.nav_ready = True
    s.deviation_pending.clear()
    s.on_behaviour("walk", 1.0, 1)
    s.on_exam_result(True, 1.4, 1.4, 2.0, 2)
    for k in range(5):
        s.on_heading(10.0, True, k)
    assert s.gyro_wanted() == wanted


# ---------------------------------------------------------------- 004 Tables 1 and 3: examinations
def test_t0_starts_an_examination_and_a_pass_gives_the_gyroscope_back() -> None:
    s = in_gait_dr()
    assert s.tick(10.0, 10) == []
    ev = s.tick(40.0, 40)
    assert kinds(ev) == ["examination_started", "gyroscope_requested"] and s.gyro_wanted()
    ev = s.on_exam_result(True, 1.40, 1.42, 41.0, 41)
    assert kinds(ev) == ["examination_passed", "gyroscope_released"]


def test_two_missed_strides_fail_the_examination_and_re_initialise() -> None:
    s = in_gait_dr()
    s.tick(40.0, 40)
    assert kinds(s.on_exam_result(False, 1.4, 1.9, 41.0, 41)) == ["examination_repeated"]
    ev = s.on_exam_result(False, 1.4, 1.9, 42.0, 42)
    assert ev[0].kind == "examination_failed" and ev[0].detail["cause"] == "step_length"
    assert s.working == "zupt" and s.calibrating == "walk" and "walk" in s.failed


def test_a_walking_direction_that_changed_fails_the_direction_examination() -> None:
    """Backward or sideways walking, a re-mounted sensor: KF II's innovation beyond 3 sigma on two strides."""
    s = in_gait_dr()
    s.tick(40.0, 40)
    s.on_exam_result(True, 1.4, 1.4, 41.0, 41, heading=MISSES)
    ev = s.on_exam_result(True, 1.4, 1.4, 42.0, 42, heading=MISSES)
    assert ev[0].kind == "examination_failed" and ev[0].detail["cause"] == "heading_deviation"
    assert s.working == "zupt"


def test_a_stored_deviation_is_confirmed_by_one_fitting_stride() -> None:
    s = Scheduler("auto", CFG, calibrated("walk"))
    s.nav_ready = True
    assert s.deviation_pending == {"walk"}
    s.on_behaviour("walk", 1.0, 1)  # resumes in Gait-DR with an examination
    assert s.exam_active and s.working == "pdr"
    assert kinds(s.on_exam_result(True, 1.4, 1.4, 2.0, 2))[0] == "examination_repeated"  # no observation yet
    ev = s.on_exam_result(True, 1.4, 1.4, 3.0, 3, heading=FITS)
    assert ev[0].kind == "examination_passed" and s.deviation_pending == set()


def test_a_walking_pattern_outside_the_fitted_cadences_re_initialises_it() -> None:
    s = in_gait_dr()
    for k in range(CFG.scheduler.pattern_strides - 1):
        assert s.on_cadence(1.2, [(0.8, 0.95)], k) == []
    ev = s.on_cadence(1.2, [(0.8, 0.95)], 9)
    assert kinds(ev)[:2] == ["walking_pattern_changed", "gyroscope_requested"]
    assert s.working == "zupt" and s.pattern_left == CFG.scheduler.pattern_init_strides


def test_other_gaits_never_run_in_gait_dr() -> None:
    """Backward or sideways walking, shuffling, foot lifts: no step model and no known walking direction."""
    s = in_gait_dr()
    ev = s.on_behaviour("other", 50.0, 50)
    assert "gyroscope_requested" in kinds(ev) and s.sensor_config().gyro_on
    ev = s.on_behaviour("walk", 60.0, 60)  # the ZUPT-KF carried the heading meanwhile: Gait-DR resumes
    assert kinds(ev)[-1] == "gyroscope_released" and not s.sensor_config().gyro_on


# ---------------------------------------------------------------- standing, pdr mode
def test_standing_leaves_the_gyroscope_to_the_device_while_the_walk_may_need_it() -> None:
    s = in_gait_dr(heading_ok=False)  # the heading needs the gyroscope
    s.on_behaviour("stand", 50.0, 50)
    cfg = s.sensor_config()
    assert not cfg.gyro_on and cfg.gyro_wake_on_motion and cfg.acc_rate_hz == CFG.rates.stand_rate_hz
    t = in_gait_dr()
    t.on_behaviour("stand", 50.0, 50)
    assert t.idle() and not t.sensor_config().gyro_wake_on_motion


def test_pdr_refuses_the_gyroscope_off_until_a_compass_reads() -> None:
    s = Scheduler("pdr", CFG, Profile())
    s.nav_ready = True
    s.has_mag = False
    s.on_behaviour("walk", 1.0, 1)
    for _ in range(14):
        s.on_zupt_distance(1.5, 0)
    ev = s.on_calibrated(25.0, 25)
    assert kinds(ev) == ["calibration_done", "gyroscope_off_refused"] and "no magnetometer" in ev[1].detail["reason"]
    assert s.gyro_wanted()
    s.has_mag = True
    assert kinds(s.on_compass(True, 30)) == ["gyroscope_released"] and not s.gyro_wanted()


# ---------------------------------------------------------------- invariants
_INPUTS = st.lists(st.one_of(
    st.tuples(st.just("behaviour"), st.sampled_from(["stand", "walk", "run", "other"])),
    st.tuples(st.just("heading"), st.floats(0.0, 30.0), st.booleans()),
    st.tuples(st.just("distance"), st.floats(0.0, 2.0)),
    st.tuples(st.just("tick"), st.floats(0.0, 40.0)),
    st.tuples(st.just("exam"), st.booleans()),
    st.tuples(st.just("calibrated"),),
), max_size=40)


def _apply(s: Scheduler, op: tuple, t: float) -> list:
    kind = op[0]
    if kind == "behaviour":
        return s.on_behaviour(op[1], t, int(t * 1e9))
    if kind == "heading":
        return s.on_heading(op[1], op[2], int(t * 1e9))
    if kind == "distance":
        return s.on_zupt_distance(op[1], int(t * 1e9))
    if kind == "tick":
        return s.tick(t + op[1], int(t * 1e9))
    if kind == "exam":
        return s.on_exam_result(op[1], 1.4, 1.4, t, int(t * 1e9)) if s.exam_active else []
    return s.on_calibrated(t, int(t * 1e9)) if s.ready_for_pdr() else []


@settings(max_examples=60, deadline=None)
@given(ops=_INPUTS, returning=st.booleans(), cut=st.integers(0, 40))
def test_announcements_track_the_wanted_gyroscope_and_the_state_round_trips(ops, returning, cut) -> None:
    """Every change of whether the gyroscope is wanted is announced once, requests and releases alternate, and
    a scheduler restored from its state mid-way answers the rest identically."""
    s = Scheduler("auto", CFG, calibrated("walk") if returning else Profile())
    s.nav_ready = True
    twin = None
    last = None
    for k, op in enumerate(ops):
        if k == cut:
            twin = Scheduler.from_state(CFG, loads(dumps(s.get_state())))
        ev = _apply(s, op, float(k))
        if twin is not None:
            assert [e.to_dict() for e in _apply(twin, op, float(k))] == [e.to_dict() for e in ev]
        for e in ev:
            if e.kind in ("gyroscope_requested", "gyroscope_released"):
                assert e.kind != last
                last = e.kind
        assert s.gyro == s.gyro_wanted(device=False)
