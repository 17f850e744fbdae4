"""Online magnetometer calibration against the navigator's attitude, compass heading, disturbance gate."""

from __future__ import annotations

import math

import numpy as np
import pytest

from energy.codec import dumps, loads
from models.compass import MagCalibrator, tilt_from_acc
from models.rotations import euler_to_dcm

G = 9.80665
M_N = np.array([18.0, -2.0, 42.0])  # uT, field in the navigator's NED frame (its north need not be magnetic)


def _stance(rng: np.random.Generator, yaw: float, b: np.ndarray, w: np.ndarray, noise: float = 0.3):
    roll, pitch = rng.normal(scale=0.15, size=2)
    c = euler_to_dcm(np.float64(roll), np.float64(pitch), np.float64(yaw))  # body -> NED
    acc = c.T @ np.array([0.0, 0.0, -G]) + rng.normal(scale=0.02, size=3)
    mag = np.linalg.solve(w, c.T @ M_N) + b + rng.normal(scale=noise, size=3)
    return acc, mag


def test_tilt_from_acc_matches_euler() -> None:
    c = euler_to_dcm(np.float64(0.2), np.float64(-0.3), np.float64(1.0))
    r, p = tilt_from_acc(c.T @ np.array([0.0, 0.0, -G]))
    assert (r, p) == pytest.approx((0.2, -0.3), abs=1e-12)


@pytest.mark.parametrize("soft", [False, True])
def test_calibration_recovers_hard_iron_and_gives_heading(soft: bool) -> None:
    rng = np.random.default_rng(11 + soft)
    b = np.array([12.0, -7.0, 20.0])
    w = np.eye(3) + (np.diag([0.06, -0.04, 0.02]) if soft else 0.0)
    cal = MagCalibrator(soft_iron=soft)
    for yaw in rng.uniform(-math.pi, math.pi, 40):  # a calibration walk with turns
        acc, mag = _stance(rng, yaw, b, w)
        cal.add(acc, mag, float(yaw))
    assert cal.fit()
    errs = []
    for yaw in rng.uniform(-math.pi, math.pi, 50):
        acc, mag = _stance(rng, yaw, b, w)
        assert not cal.disturbed(acc, mag)
        errs.append(abs(math.remainder(cal.heading(acc, mag) - yaw, 2 * math.pi)))
    assert max(errs) < math.radians(3.0)
    if not soft:
        assert cal.b == pytest.approx(b, abs=1.0)


def test_no_calibration_without_turns() -> None:
    rng = np.random.default_rng(3)
    cal = MagCalibrator()
    for _ in range(40):
        acc, mag = _stance(rng, 0.3, np.zeros(3), np.eye(3))
        cal.add(acc, mag, 0.3)
    assert not cal.fit()
    assert math.isnan(cal.heading(acc, mag))


def test_disturbance_gate_trips_on_a_local_field() -> None:
    rng = np.random.default_rng(5)
    cal = MagCalibrator()
    for yaw in rng.uniform(-math.pi, math.pi, 30):
        cal.add(*_stance(rng, yaw, np.zeros(3), np.eye(3)), float(yaw))
    cal.fit()
    acc, mag = _stance(rng, 1.0, np.zeros(3), np.eye(3))
    assert not cal.disturbed(acc, mag)
    assert cal.disturbed(acc, mag + np.array([15.0, 0.0, 0.0]))  # steel door frame, radiator ...


def test_state_round_trip() -> None:
    rng = np.random.default_rng(8)
    cal = MagCalibrator(soft_iron=True)
    for yaw in rng.uniform(-math.pi, math.pi, 25):
        cal.add(*_stance(rng, yaw, np.ones(3), np.eye(3)), float(yaw))
    cal.fit()
    back = MagCalibrator.from_state(loads(dumps(cal.get_state())))
    acc, mag = _stance(rng, 0.5, np.ones(3), np.eye(3))
    assert back.heading(acc, mag) == cal.heading(acc, mag)


@pytest.mark.parametrize(("field_error_ut", "trusted"), [(0.0, True), (25.0, False)])
def test_compass_is_trusted_only_where_it_agrees_with_the_zupt_kf(field_error_ut: float, trusted: bool) -> None:
    """A building's local fields (a different disturbance at every stance) make the compass disagree with the
    ZUPT-KF heading on its own calibration stances; such a compass must not replace the gyroscope."""
    rng = np.random.default_rng(21)
    cal = MagCalibrator()
    for yaw in rng.uniform(-math.pi, math.pi, 40):
        acc, mag = _stance(rng, yaw, np.zeros(3), np.eye(3))
        cal.add(acc, mag + rng.normal(scale=field_error_ut, size=3) * np.array([1.0, 1.0, 0.0]), float(yaw))
    assert cal.fit()
    assert cal.trusted is trusted
    assert (cal.heading_rms < math.radians(2.0)) is trusted
    back = MagCalibrator.from_state(loads(dumps(cal.get_state())))
    assert back.trusted is trusted and back.heading_rms == cal.heading_rms


def test_calibration_stored_before_the_agreement_was_measured_counts_as_trusted() -> None:
    rng = np.random.default_rng(4)
    cal = MagCalibrator()
    for yaw in rng.uniform(-math.pi, math.pi, 30):
        cal.add(*_stance(rng, yaw, np.zeros(3), np.eye(3)), float(yaw))
    cal.fit()
    old = cal.get_state()
    old["params"] = old["params"][:8]
    del old["heading_rms"]
    assert MagCalibrator.from_state(old).trusted


def test_vertical_hard_iron_prior_keeps_pitched_stances_right() -> None:
    """Level calibration stances cannot separate b_z from the field's vertical part; the prior fixes the split.

    Calibrated on nearly level stances (0.3 deg tilt scatter), then used on stances tilted by ~7 deg: without
    the prior the fit puts b_z ~9 uT off and the tilt turns that into heading error (median 2.9 vs 1.3 deg).
    """
    b = np.array([12.0, -7.0, 3.0])

    def stance(rng: np.random.Generator, yaw: float, tilt_std: float):
        roll, pitch = rng.normal(scale=tilt_std, size=2)
        c = euler_to_dcm(np.float64(roll), np.float64(pitch), np.float64(yaw))
        return c.T @ np.array([0.0, 0.0, -G]), c.T @ M_N + b + rng.normal(scale=0.5, size=3)

    worst = {}
    for name, vstd in (("prior", 10.0), ("free", math.inf)):
        rng = np.random.default_rng(21)
        cal = MagCalibrator(vertical_hard_iron_std=vstd)
        for yaw in rng.uniform(-math.pi, math.pi, 40):
            cal.add(*stance(rng, yaw, math.radians(0.3)), float(yaw))
        assert cal.fit()
        errs = []
        for yaw in rng.uniform(-math.pi, math.pi, 60):
            acc, mag = stance(rng, yaw, math.radians(7.0))
            errs.append(abs(math.remainder(cal.heading(acc, mag) - yaw, 2 * math.pi)))
        worst[name] = float(np.median(errs))
        if name == "prior":
            assert cal.b[2] == pytest.approx(b[2], abs=1.5)
    assert worst["prior"] < math.radians(4.0)
    assert worst["free"] > 2.0 * worst["prior"]


def _calibrated(rng: np.random.Generator, n: int = 40) -> MagCalibrator:
    cal = MagCalibrator()
    for yaw in rng.uniform(-math.pi, math.pi, n):
        cal.add(*_stance(rng, yaw, np.zeros(3), np.eye(3)), float(yaw))
    assert cal.fit()
    return cal


B_SHOE = np.array([14.0, -22.0, 35.0])  # uT: clients.synth.LSM9DS1_SHOE's hard iron
S_SHOE = np.array([[1.04, 0.02, -0.015], [0.02, 0.97, 0.01], [-0.015, 0.01, 1.00]])  # and its soft iron


def _tilted_acc(c: np.ndarray, offset: np.ndarray) -> np.ndarray:
    """Specific force at rest for body-to-NED ``c``, seen by an accelerometer whose tilt is off by the rotation
    vector ``offset`` [rad] (zero-g offset, axis misalignment against the magnetometer)."""
    from models.rotations import rotvec_to_dcm

    return rotvec_to_dcm(offset) @ (c.T @ np.array([0.0, 0.0, -G]))


def _walk(rng: np.random.Generator, cal: MagCalibrator, n: int, offset: np.ndarray, tilt_std: float = 0.0,
          swings: bool = True, b: np.ndarray = B_SHOE, s: np.ndarray = S_SHOE) -> None:
    """``n`` calibration stances at random headings (tilt scatter ``tilt_std`` [rad]) with the swings before them:
    the foot pitching -25..+30 deg on the way (field samples only)."""
    for yaw in rng.uniform(-math.pi, math.pi, n):
        roll, pitch = rng.normal(scale=tilt_std, size=2) if tilt_std else (0.0, 0.0)
        c = euler_to_dcm(np.float64(roll), np.float64(pitch), np.float64(yaw))
        mag = s @ (c.T @ M_N) + b + rng.normal(scale=0.1, size=3)
        sw = None
        if swings:
            sw = np.array([s @ (euler_to_dcm(np.float64(roll), np.float64(pitch + math.radians(p)), np.float64(yaw)).T
                                @ M_N) + b + rng.normal(scale=0.1, size=3) for p in np.linspace(-25.0, 30.0, 8)])
        cal.add(_tilted_acc(c, offset), mag, float(yaw), sw)


def _heading_errors(rng: np.random.Generator, cal: MagCalibrator, offset: np.ndarray, tilt_deg: float,
                    n: int = 60) -> np.ndarray:
    """Compass errors [rad] on stances tilted by ``tilt_deg`` in pitch or roll (slopes, stairs, another mount)."""
    out = []
    for yaw in rng.uniform(-math.pi, math.pi, n):
        roll, pitch = np.radians(tilt_deg) * rng.choice([-1.0, 1.0], size=2) * rng.integers(0, 2, size=2)
        c = euler_to_dcm(np.float64(roll), np.float64(pitch), np.float64(yaw))
        mag = S_SHOE @ (c.T @ M_N) + B_SHOE + rng.normal(scale=0.1, size=3)
        out.append(math.remainder(cal.heading(_tilted_acc(c, offset), mag) - yaw, 2 * math.pi))
    return np.abs(np.asarray(out))


def test_swings_recover_the_hard_iron_that_level_stances_cannot() -> None:
    """A shoe sensor with 44 uT of hard iron and a few per cent of soft iron, calibrated on level stances (the
    synthetic gait's are exactly level) whose accelerometer tilt is 0.6 deg off. Stances alone put the vertical
    field into the hard iron (b_z ~ 35 + 42 - prior); their compass is then right on level ground and wrong on a
    slope. The swings' field magnitudes give b in all three axes, the soft iron and the tilt offset."""
    offset = np.radians([0.4, -0.45, 0.0])
    rng = np.random.default_rng(31)
    stance_only = MagCalibrator()
    _walk(rng, stance_only, 60, offset, tilt_std=math.radians(0.1), swings=False)
    assert stance_only.fit() and stance_only.n_swing == 0
    assert abs(stance_only.b[2] - B_SHOE[2]) > 10.0  # the split is the prior's, not the sensor's
    rng = np.random.default_rng(31)
    joint = MagCalibrator()
    _walk(rng, joint, 60, offset, tilt_std=math.radians(0.1))
    assert joint.fit() and joint.trusted and joint.n_swing == 480
    assert joint.b == pytest.approx(B_SHOE, abs=1.0)
    assert np.linalg.norm(joint.m_n) == pytest.approx(np.linalg.norm(M_N), rel=0.03)
    level = _heading_errors(np.random.default_rng(5), joint, offset, 0.0)
    slope = _heading_errors(np.random.default_rng(5), joint, offset, 6.0)
    assert np.max(level) < math.radians(1.0) and np.max(slope) < math.radians(1.5)
    assert np.median(_heading_errors(np.random.default_rng(5), stance_only, offset, 6.0)) > 3.0 * np.median(slope)


def test_calibration_recovers_hard_iron_with_pitched_stances() -> None:
    """With real tilt variety at the stances (3 deg) the stance model sees the vertical hard iron too; with the
    swings the joint fit gets the whole of it, and the stances' accelerometer offset is not taken for hard iron."""
    offset = np.radians([-0.5, 0.7, 0.0])
    rng = np.random.default_rng(32)
    cal = MagCalibrator()
    _walk(rng, cal, 50, offset, tilt_std=math.radians(3.0))
    assert cal.fit() and cal.trusted
    assert cal.b == pytest.approx(B_SHOE, abs=1.0)
    assert np.max(_heading_errors(np.random.default_rng(6), cal, offset, 8.0)) < math.radians(1.5)


def test_joint_fit_is_only_for_a_trusted_compass() -> None:
    """Indoors the field's magnitude changes along a stride (gdin: 6-7 uT) and the stances disagree with the
    ZUPT-KF by 10-33 deg: the extra unknowns would chase the disturbances, so such a calibration stays linear."""
    rng = np.random.default_rng(33)
    cal = MagCalibrator()
    for yaw in rng.uniform(-math.pi, math.pi, 40):
        c = euler_to_dcm(np.float64(0.0), np.float64(0.0), np.float64(yaw))
        local = rng.normal(scale=25.0, size=3) * np.array([1.0, 1.0, 0.0])
        sw = c.T @ M_N + rng.normal(scale=7.0, size=(8, 3))
        cal.add(c.T @ np.array([0.0, 0.0, -G]), c.T @ (M_N + local), float(yaw), sw)
    assert cal.fit() and not cal.trusted
    assert np.array_equal(cal.w, np.eye(3))  # no soft iron, no axis rotation: the linear hard-iron fit


def test_a_loaded_calibration_re_estimates_this_sessions_tilt_offset() -> None:
    """The accelerometer's offset changes between power-ons; a calibration fitted on another day's stances then
    turns the compass by up to tan(dip) x the change (here 1.2 deg -> up to 2.2 deg). The dip of this session's
    clean stances must not depend on the heading; after turns it tells the change and the compass is right."""
    day1, day2 = np.radians([0.3, -0.4, 0.0]), np.radians([-0.5, 0.5, 0.0])
    rng = np.random.default_rng(34)
    fitted = MagCalibrator()
    _walk(rng, fitted, 60, day1, tilt_std=math.radians(0.1))
    assert fitted.fit() and fitted.trusted
    loaded = MagCalibrator.from_state(loads(dumps(fitted.get_state())))
    loaded.start_session()
    before = _heading_errors(np.random.default_rng(7), loaded, day2, 0.0)
    for yaw in rng.uniform(-math.pi, math.pi, 30):  # this session's stances, any mode: no heading needed
        c = euler_to_dcm(np.float64(0.0), np.float64(0.0), np.float64(yaw))
        loaded.observe_dip(_tilted_acc(c, day2), S_SHOE @ (c.T @ M_N) + B_SHOE + rng.normal(scale=0.1, size=3))
    after = _heading_errors(np.random.default_rng(7), loaded, day2, 0.0)
    assert np.max(before) > math.radians(1.5) and np.max(after) < 0.5 * np.max(before)
    back = MagCalibrator.from_state(loads(dumps(loaded.get_state())))
    assert np.array_equal(back.w, loaded.w) and back.session_on
    fitted.observe_dip(*_stance(rng, 0.3, B_SHOE, np.linalg.inv(S_SHOE)))  # its own session: nothing to estimate
    assert np.array_equal(fitted.session_tilt, np.eye(3))


def test_a_few_disturbed_stances_do_not_untrust_a_compass_a_spread_everywhere_does() -> None:
    """Trust is the robust scale of the disagreement with the ZUPT-KF (and the RMS within twice the limit):
    two steel stances among 18 that passed the gate took the RMS of a 15-stance fit over 5 deg; indoors every
    stance disagrees (gdin: robust 5.2-23.6 deg)."""
    rng = np.random.default_rng(31)
    cal = MagCalibrator()
    for yaw in rng.uniform(-math.pi, math.pi, 18):
        cal.add(*_stance(rng, yaw, np.zeros(3), np.eye(3)), float(yaw))
    for yaw in (0.4, 2.0):  # steel: a local field the disturbance gate may not see
        acc, mag = _stance(rng, yaw, np.zeros(3), np.eye(3))
        cal.add(acc, mag + np.array([9.0, -7.0, 0.0]), yaw)
    assert cal.fit()
    assert cal.heading_rms > cal.max_heading_rms  # the plain RMS alone would untrust it
    assert cal.heading_scale < cal.max_heading_rms and cal.trusted
    back = MagCalibrator.from_state(loads(dumps(cal.get_state())))
    assert back.trusted and back.heading_scale == cal.heading_scale


def test_a_trusted_calibration_is_not_replaced_by_an_untrusted_refit() -> None:
    rng = np.random.default_rng(32)
    cal = _calibrated(rng, n=16)
    assert cal.trusted
    b0 = cal.b.copy()
    for yaw in rng.uniform(-math.pi, math.pi, 12):  # a building's local fields at every new stance
        acc, mag = _stance(rng, yaw, np.zeros(3), np.eye(3))
        cal.add(acc, mag + rng.normal(scale=25.0, size=3) * np.array([1.0, 1.0, 0.0]), float(yaw))
    trial = MagCalibrator.from_state(cal.get_state())
    trial.fit()
    assert not trial.trusted  # fit() would have taken it
    assert cal.refit() and cal.trusted and np.array_equal(cal.b, b0)  # refit() keeps the one in use
    assert cal.n_stances == 28  # the stances stay recorded


def test_stances_are_bounded_to_the_newest_and_refits_count_all() -> None:
    from models.compass import _ROWS_KEEP

    rng = np.random.default_rng(33)
    cal = MagCalibrator()
    for yaw in rng.uniform(-math.pi, math.pi, _ROWS_KEEP + 25):
        cal.add(*_stance(rng, yaw, np.zeros(3), np.eye(3)), float(yaw))
    assert cal.n_stances == _ROWS_KEEP and cal.n_added == _ROWS_KEEP + 25
    state = cal.get_state()
    back = MagCalibrator.from_state(loads(dumps(state)))
    assert back.n_added == _ROWS_KEEP + 25
    del state["added"]
    state["rows"] = np.vstack([state["rows"], state["rows"][:40]])  # a state stored before the bound
    old = MagCalibrator.from_state(state)
    assert old.n_stances == _ROWS_KEEP and old.n_added == _ROWS_KEEP + 40


# ------------------------------------------------------------------------------ compass against the gyroscope
def _turned_field(yaw: float, field_turn: float, rng: np.random.Generator,
                  scale: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """A level stance at ``yaw`` [rad] in the Earth's field turned by ``field_turn`` [rad] about the vertical and
    scaled by ``scale`` (the dip unchanged); the compass reads ``yaw - field_turn``."""
    c = euler_to_dcm(np.float64(0.0), np.float64(0.0), np.float64(yaw))
    rz = euler_to_dcm(np.float64(0.0), np.float64(0.0), np.float64(field_turn))
    return c.T @ np.array([0.0, 0.0, -G]), c.T @ (scale * rz @ M_N) + rng.normal(scale=0.05, size=3)


def _gait_step(f, cal: MagCalibrator, h: float, acc: np.ndarray, mag: np.ndarray, settled_test: bool = True) -> float:
    """One Gait-DR stance; ``settled_test`` False: the follower is told every field is settled (the rule before
    a trusted compass had to be settled to lead)."""
    shape = cal.field_shape(acc, mag)
    settled = cal.settled(*shape, f.lead_mag_tol, f.rot_dip_tol) if settled_test else True
    return f.step(h, cal.heading(acc, mag), not cal.disturbed(acc, mag), *shape, cal.trusted, cal.heading_scale, settled)


def _steel_stance(rng: np.random.Generator, yaw: float, k: int, n: int) -> tuple[np.ndarray, np.ndarray]:
    """A level stance at ``yaw`` [rad], the ``k``-th of ``n`` along a steel structure: the Earth's field plus a
    disturbance of up to 25 uT that grows and fades along the way (clients.synth's steel)."""
    c = euler_to_dcm(np.float64(0.0), np.float64(0.0), np.float64(yaw))
    d = 25.0 * math.sin(math.pi * (k + 0.5) / n) ** 2 * np.array([0.3, -0.8, 0.52])
    return c.T @ np.array([0.0, 0.0, -G]), c.T @ (M_N + d) + rng.normal(scale=0.3, size=3)


def test_a_fit_whose_stances_hold_different_fields_is_not_trusted() -> None:
    """Stances whose field is the Earth's scaled by up to 15 % and tilted towards the vertical by up to 8 deg
    (its horizontal direction kept): the compass agrees with the ZUPT-KF heading on every one of them, but the
    field's magnitude and dip scatter, so the stances hold different fields and the fit is not trusted (a run
    inside steel agreed to 1.7 deg with the ZUPT-KF while its field scattered by 5.6 % and 8.7 deg; every later
    stance of the Earth's field then failed its gate). The Earth's field alone: trusted."""
    rng = np.random.default_rng(3)
    cal = MagCalibrator()
    for yaw in rng.uniform(-math.pi, math.pi, 40):
        c = euler_to_dcm(np.float64(0.0), np.float64(0.0), np.float64(yaw))
        h, v = math.hypot(M_N[0], M_N[1]), M_N[2]
        scale, tilt = rng.uniform(0.85, 1.15), math.radians(rng.uniform(-8.0, 8.0))
        dip = math.atan2(v, h) + tilt
        field = scale * np.linalg.norm(M_N) * np.array([M_N[0] / h * math.cos(dip), M_N[1] / h * math.cos(dip),
                                                         math.sin(dip)])
        cal.add(c.T @ np.array([0.0, 0.0, -G]), c.T @ field + rng.normal(scale=0.3, size=3), float(yaw))
    assert cal.fit(recent=False)
    assert cal.heading_scale < math.radians(3.0) and cal.heading_rms < math.radians(5.0)  # the headings would trust it
    assert not cal.trusted
    assert _calibrated(np.random.default_rng(3)).trusted


def test_a_walk_that_began_in_steel_gets_a_trusted_compass_from_its_later_stances() -> None:
    """40 stances along steel, then 60 of the Earth's field at all headings: the fit on all of them is not
    trusted, the one on the newest half is; it is kept and the steel stances are dropped (before, the compass
    stayed untrusted all day and the scheduler kept the gyroscope on)."""
    rng = np.random.default_rng(4)
    cal = MagCalibrator()
    for k, yaw in enumerate(np.linspace(0.0, 1.4, 40)):
        cal.add(*_steel_stance(rng, float(yaw), k, 40), float(yaw))
    for yaw in rng.uniform(-math.pi, math.pi, 60):
        cal.add(*_stance(rng, float(yaw), np.zeros(3), np.eye(3)), float(yaw))
    all_rows = MagCalibrator.from_state(cal.get_state())
    assert all_rows._fit_all() and not all_rows.trusted
    assert cal.fit() and cal.trusted
    assert cal.n_stances == 50 and cal.n_added == 100  # the newest half held; the count of all is kept
    assert np.linalg.norm(cal.m_n) == pytest.approx(np.linalg.norm(M_N), rel=0.02)
    acc, mag = _stance(rng, 2.0, np.zeros(3), np.eye(3))
    assert abs(math.remainder(cal.heading(acc, mag) - 2.0, 2 * math.pi)) < math.radians(3.0)
    back = MagCalibrator.from_state(cal.get_state())  # the swing bookkeeping survives a round trip
    assert back._row_swings == cal._row_swings and len(back._row_swings) == back.n_stances
