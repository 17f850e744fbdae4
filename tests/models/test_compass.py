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


def test_follow_compass_averages_small_errors_and_takes_clean_turns() -> None:
    from models.compass import follow_compass

    h = 0.0
    assert follow_compass(h, math.radians(10.0), True) == pytest.approx(math.radians(5.0))  # averaged
    assert follow_compass(h, math.radians(90.0), True) == pytest.approx(math.radians(90.0))  # a turn
    assert follow_compass(h, math.radians(90.0), False) == pytest.approx(math.radians(45.0))  # disturbed: no turn
    # across +-pi the innovation is the short way round
    assert follow_compass(math.radians(175.0), math.radians(-175.0), True) == pytest.approx(math.radians(180.0))
    # a straight walk with white compass scatter: the followed heading scatters less than the compass
    rng = np.random.default_rng(4)
    z = rng.normal(scale=math.radians(10.0), size=400)
    out = []
    for zk in z:
        h = follow_compass(h, float(zk), True)
        out.append(h)
    assert np.std(out) < 0.75 * np.std(z)


def _calibrated(rng: np.random.Generator, n: int = 40) -> MagCalibrator:
    cal = MagCalibrator()
    for yaw in rng.uniform(-math.pi, math.pi, n):
        cal.add(*_stance(rng, yaw, np.zeros(3), np.eye(3)), float(yaw))
    assert cal.fit()
    return cal


def test_rotate_frame_turns_the_compass_and_keeps_the_fit() -> None:
    rng = np.random.default_rng(9)
    cal = _calibrated(rng)
    acc, mag = _stance(rng, 1.0, np.zeros(3), np.eye(3))
    h0, shape0 = cal.heading(acc, mag), cal.field_shape(acc, mag)
    cal.rotate_frame(math.radians(70.0))
    assert math.remainder(cal.heading(acc, mag) - h0 - math.radians(70.0), 2 * math.pi) == pytest.approx(0.0, abs=1e-9)
    assert cal.field_shape(acc, mag) == pytest.approx(shape0)
    b = cal.b.copy()
    cal.fit()  # the stored stances turned with the field: refitting gives the same calibration
    assert cal.b == pytest.approx(b, abs=1e-6)
    assert math.remainder(cal.heading(acc, mag) - h0 - math.radians(70.0), 2 * math.pi) == pytest.approx(0.0, abs=1e-6)


def test_relocate_moves_the_gate_to_another_places_field_and_keeps_the_heading() -> None:
    """A calibration fitted where the field is 18/-2/42 uT, used where it is 25 % stronger and 10 deg steeper:
    every stance there fails the gate until the gate is moved to that field; the heading does not change."""
    rng = np.random.default_rng(13)
    cal = _calibrated(rng)
    norm0, dip0 = cal.field_reference()
    c = euler_to_dcm(np.float64(0.05), np.float64(-0.04), np.float64(0.8))
    dip = dip0 + math.radians(10.0)
    here = 1.25 * norm0 * np.array([math.cos(dip) * M_N[0], math.cos(dip) * M_N[1], 0.0]) / np.linalg.norm(M_N[:2])
    here[2] = 1.25 * norm0 * math.sin(dip)
    acc, mag = c.T @ np.array([0.0, 0.0, -G]), c.T @ here
    assert cal.disturbed(acc, mag)
    h0 = cal.heading(acc, mag)
    shape = cal.field_shape(acc, mag)
    assert shape == pytest.approx((1.25 * norm0, dip), rel=0.02)  # this place's field seen through the calibration
    cal.relocate(*shape)
    assert not cal.disturbed(acc, mag)
    assert cal.field_reference() == pytest.approx(shape, abs=1e-9)
    assert cal.heading(acc, mag) == pytest.approx(h0, abs=1e-9)
    assert h0 == pytest.approx(0.8, abs=math.radians(1.0))  # the same azimuth, so still right


def _follow(f, cal: MagCalibrator, h: float, acc: np.ndarray, mag: np.ndarray, trusted: bool = True) -> float:
    return f.step(h, cal.heading(acc, mag), not cal.disturbed(acc, mag), *cal.field_shape(acc, mag), trusted)


def test_follower_holds_through_steel_takes_its_turns_and_reanchors() -> None:
    """A straight walk north into a disturbance that grows over 8 strides (deflecting the compass by up to
    ~40 deg) with a 90 deg turn in two strides inside it, then out onto a clean field again.

    The heading must neither follow the deflection nor lose the turn (holding alone would), and must be pulled
    back to the compass once the field has been clean for a few stances."""
    from models.compass import CompassFollower

    rng = np.random.default_rng(12)
    cal = _calibrated(rng)
    f = CompassFollower()
    yaws = [0.0] * 6 + [0.0, 0.0, 0.0, math.radians(45.0)] + [math.radians(90.0)] * 12
    d_peak = np.array([10.0, 22.0, 8.0])  # steel field in NED [uT]
    amp = [0.0] * 5 + [0.15, 0.35, 0.6, 0.8, 0.9, 1.0, 1.0, 0.9, 0.7, 0.45, 0.2] + [0.0] * 6
    h, errs, comp = 0.0, [], []
    for yaw, a in zip(yaws, amp):
        roll, pitch = rng.normal(scale=0.02, size=2)
        c = euler_to_dcm(np.float64(roll), np.float64(pitch), np.float64(yaw))
        acc = c.T @ np.array([0.0, 0.0, -G])
        mag = c.T @ (M_N + a * d_peak) + rng.normal(scale=0.3, size=3)
        h = _follow(f, cal, h, acc, mag)
        errs.append(abs(math.remainder(h - yaw, 2 * math.pi)))
        comp.append(abs(math.remainder(cal.heading(acc, mag) - yaw, 2 * math.pi)))
    assert max(comp) > math.radians(25.0)  # the compass alone is fooled
    # the edge of the disturbance passes the 12 % / 8 deg gate and pulls the heading (here by 14 deg); once the
    # gate trips the heading is held (no further pull) and the turn is taken from the compass change
    assert abs(errs[9] - errs[6]) < math.radians(5.0) and abs(errs[15] - errs[6]) < math.radians(5.0)
    assert max(errs[-3:]) < math.radians(3.0)  # re-anchored on the clean field
    from models.compass import follow_compass

    h_old = 0.0
    old = []
    for yaw, a in zip(yaws, amp):  # the previous rule: pulled half-way to the disturbed compass every stance
        c = euler_to_dcm(np.float64(0.0), np.float64(0.0), np.float64(yaw))
        acc, mag = c.T @ np.array([0.0, 0.0, -G]), c.T @ (M_N + a * d_peak)
        h_old = follow_compass(h_old, cal.heading(acc, mag), not cal.disturbed(acc, mag))
        old.append(abs(math.remainder(h_old - yaw, 2 * math.pi)))
    assert max(old) > 3.0 * max(errs)  # 72 vs 17 deg


def test_untrusted_compass_is_averaged_as_before() -> None:
    from models.compass import CompassFollower, follow_compass

    rng = np.random.default_rng(2)
    cal = _calibrated(rng)
    f = CompassFollower()
    acc, mag = _stance(rng, 0.3, np.zeros(3), np.eye(3))
    mag_dist = mag + np.array([20.0, 0.0, 0.0])
    for m in (mag, mag_dist, mag, mag_dist):
        want = follow_compass(0.1, cal.heading(acc, m), not cal.disturbed(acc, m))
        assert _follow(f, cal, 0.1, acc, m, trusted=False) == pytest.approx(want)


def test_follower_state_round_trip() -> None:
    from models.compass import CompassFollower

    f = CompassFollower(reanchor_stances=2, lead_mag_tol=0.03)
    f.observe(0.3, True, 47.0, 1.1)
    f.observe(0.4, False, 52.0, 1.0)
    back = CompassFollower.from_state(loads(dumps(f.get_state())))
    assert (back.clean_run, back.prev, back.reanchor_stances, back.lead_mag_tol) == (f.clean_run, f.prev, 2, 0.03)
    old = f.get_state()
    old["params"] = old["params"][:8]  # a state stored before the lead tolerance existed: the default
    assert CompassFollower.from_state(old).lead_mag_tol == CompassFollower().lead_mag_tol
    for g in (f, back):
        g.forget()
    assert back.step(0.0, 1.0, False, 52.0, 1.0) == f.step(0.0, 1.0, False, 52.0, 1.0)


@pytest.mark.parametrize(
    ("d_norm", "d_dip_deg", "same"),
    [(0.0, 0.0, True), (0.04, 2.5, True), (0.06, 0.0, False), (0.0, 3.5, False), (-0.06, -3.5, False)],
)
def test_turn_since_is_the_compass_change_only_where_the_field_kept_its_shape(d_norm, d_dip_deg, same) -> None:
    """A rotation of the foot leaves the field's magnitude and dip unchanged; a field that changed shape
    (a disturbance moved into) gives no turn, whatever the compass says."""
    from models.compass import CompassFollower

    f = CompassFollower()
    assert f.turn_since(1.0, 47.0, 1.1) is None  # no previous stance
    f.observe(3.0, True, 47.0, 1.1)
    got = f.turn_since(-3.0, 47.0 * (1.0 + d_norm), 1.1 + math.radians(d_dip_deg))
    if same:
        assert got == pytest.approx(math.remainder(-6.0, 2 * math.pi))  # wrapped across +-pi
    else:
        assert got is None


def test_the_absolute_compass_leads_only_on_an_established_clean_field() -> None:
    from models.compass import CompassFollower

    f = CompassFollower(reanchor_stances=3)
    for clean in (True, True, False, True, True):
        f.observe(0.0, clean, 47.0, 1.1)
        assert not f.established
    f.observe(0.0, True, 47.0, 1.1)
    assert f.established



@pytest.mark.parametrize("turn_deg, taken_deg", [(22.0, 22.0), (-35.0, -35.0), (6.0, 3.0)])
def test_an_established_trusted_compass_takes_a_turn_of_the_foot_whole(turn_deg: float, taken_deg: float) -> None:
    """On an established clean field a trusted compass (noise 0.5 deg) that turns by more than its tolerance
    (10 deg) between two stances of an unchanged field saw the foot turn: the turn is taken whole, as the gyroscope
    would, then the remaining disagreement is averaged. Before, a 22-deg turning stride moved the heading by 11 deg
    and the heading trailed the compass for the next strides (synthetic mixed days: Gait-DR step direction error
    1.52 -> 1.19 deg new user, 1.40 -> 0.99 deg returning). A change within the tolerance is averaged as before."""
    from models.compass import CompassFollower

    sigma = math.radians(0.5)
    f = CompassFollower(reanchor_stances=3)
    heading = 0.3
    for _ in range(4):
        heading = f.step(heading, 0.3, True, 47.0, 1.1, True, sigma, True)
    assert f.established and heading == pytest.approx(0.3)
    out = f.step(heading, 0.3 + math.radians(turn_deg), True, 47.0, 1.1, True, sigma, True)
    assert math.degrees(out - 0.3) == pytest.approx(taken_deg, abs=1e-9)


def test_a_turn_during_the_hand_over_stride_is_taken_from_the_last_zupt_kf_stance() -> None:
    """Gait-DR restarting from the ZUPT-KF in the middle of a turn: the compass change since the last ZUPT-KF
    stance is the rest of the turn (synthetic mixed day seed 6, a run handed over mid-turn: the heading trailed
    the truth by 11, 6, 4 deg over the next strides)."""
    from models.compass import CompassFollower

    sigma = math.radians(0.5)
    f = CompassFollower(reanchor_stances=3)
    for k in range(4):  # ZUPT-KF stances turning with the gyroscope
        f.observe(0.1 * k, True, 47.0, 1.1, psi=0.1 * k, sigma=sigma)
    assert f.established
    f.restart()  # Gait-DR starts from the last ZUPT-KF stance's heading (0.3 rad)
    out = f.step(0.3, 0.3 + math.radians(20.0), True, 47.0, 1.1, True, sigma, True)
    assert math.degrees(out - 0.3) == pytest.approx(20.0, abs=1e-9)


# ---------------------------------------------------------------------------------------------- swings, alignment
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


def test_a_compass_that_turns_while_the_gyroscope_does_not_is_not_followed() -> None:
    """Walking straight north (the ZUPT-KF heading stays 0) through a field that turns by 15 deg per stride, its
    magnitude up by at most 7 % and its dip unchanged (within the 12 % / 8 deg gate): the examination's stances
    show the compass turning where the gyroscope does not, so Gait-DR after it holds the handed-over heading
    instead of following the compass 45 deg away, and lets the compass lead again once it is steady on a field
    of the Earth's shape."""
    from models.compass import CompassFollower

    rng = np.random.default_rng(21)
    cal = _calibrated(rng)
    assert cal.trusted
    turns = np.radians([0.0, 15.0, 30.0])  # the field's turn at the examination's stances
    gait = np.radians([40.0, 45.0, 40.0, 30.0, 15.0, 0.0, 0.0, 0.0, 0.0, 0.0])  # ... and at Gait-DR's after it
    runs = {}
    for gyro, settled_test in ((True, True), (False, True), (False, False)):
        f = CompassFollower()
        for _ in range(4):  # an established clean field before
            f.observe(cal.heading(*_turned_field(0.0, 0.0, rng)), True, *cal.field_shape(*_turned_field(0.0, 0.0, rng)))
        for t in turns:
            acc, mag = _turned_field(0.0, float(t), rng)
            assert not cal.disturbed(acc, mag)
            f.observe(cal.heading(acc, mag), True, *cal.field_shape(acc, mag), psi=0.0 if gyro else None,
                      sigma=cal.heading_scale)
        assert f.suspect == gyro
        f.restart()
        h, errs = 0.0, []
        for t in gait:
            acc, mag = _turned_field(0.0, float(t), rng, 1.0 + 0.07 * float(t) / gait.max())
            assert not cal.disturbed(acc, mag)
            h = _gait_step(f, cal, h, acc, mag, settled_test)
            errs.append(abs(math.remainder(h, 2 * math.pi)))
        runs[gyro, settled_test] = errs
        assert not f.suspect and f.established  # the compass leads again on the Earth's field
    assert max(runs[True, True]) < math.radians(2.0)  # held through, nothing followed
    # without the gyroscope's test the field's shape (magnitude 7 % off: not the Earth's) still holds the heading;
    # with neither, the follower follows the field
    assert max(runs[False, True]) < math.radians(2.0)
    assert max(runs[False, False]) > math.radians(30.0)


def test_a_compass_that_turns_with_the_gyroscope_stays_trusted() -> None:
    """A real turn of the foot (the compass and the ZUPT-KF heading turn together) raises no suspicion."""
    from models.compass import CompassFollower

    rng = np.random.default_rng(22)
    cal = _calibrated(rng)
    f = CompassFollower()
    for yaw in np.radians([0.0, 0.0, 30.0, 60.0, 90.0, 90.0]):
        acc, mag = _turned_field(float(yaw), 0.0, rng)
        f.observe(cal.heading(acc, mag), True, *cal.field_shape(acc, mag), psi=float(yaw), sigma=cal.heading_scale)
    assert not f.suspect and f.established


def test_a_suspect_compass_leads_again_when_steady_even_against_the_held_heading() -> None:
    """The held heading may be the wrong one (the ZUPT-KF restarted from a heading already taken from the
    disturbed compass): a compass steady on a field of the Earth's shape leads again after ``reanchor_stances``
    stances, and pulls the heading back to itself; a settled compass that keeps moving does not."""
    from models.compass import CompassFollower

    rng = np.random.default_rng(23)
    cal = _calibrated(rng)
    f = CompassFollower()
    f.suspect = True
    f.clean_run = 10
    h = math.radians(25.0)  # held, 25 deg off the truth (0)
    for k in range(4):  # the first stance has no previous one to be steady against; 3 steady ones after it
        h = _gait_step(f, cal, h, *_turned_field(0.0, 0.0, rng))
        assert f.suspect == (k < 3)
    for _ in range(6):
        h = _gait_step(f, cal, h, *_turned_field(0.0, 0.0, rng))
    assert abs(h) < math.radians(1.0)
    g = CompassFollower()
    g.suspect, g.clean_run = True, 10
    for t in np.radians([0.0, 12.0, 24.0, 36.0, 48.0]):  # the field keeps turning: never consistent
        _gait_step(g, cal, math.radians(60.0), *_turned_field(0.0, float(t), rng))
        assert g.suspect


def test_a_suspect_compass_takes_no_turns_on_a_field_that_is_not_the_earths() -> None:
    """Walking straight through a disturbance that fails the gate (15 % weak) and turns the compass by 30 deg per
    stride while its magnitude and dip stay put: each change looks like a turn of the foot. A compass the
    gyroscope has already caught turning with the field (suspect) is not believed: the heading is held (synthetic
    mixed day, seed 27, 146-149 s: three such changes taken, 58 deg off, mean error 6.4 -> 2.1 m). One not caught
    takes them, as it takes a real turn inside a disturbance."""
    from models.compass import CompassFollower

    rng = np.random.default_rng(24)
    cal = _calibrated(rng)
    field_turns = np.radians([0.0, 30.0, 60.0, 90.0])
    held = {}
    for suspect in (True, False):
        f = CompassFollower()
        f.suspect = suspect
        h = 0.0
        for t in field_turns:
            acc, mag = _turned_field(0.0, float(t), rng, 0.85)
            assert cal.disturbed(acc, mag)
            h = _gait_step(f, cal, h, acc, mag)
        held[suspect] = abs(math.remainder(h, 2 * math.pi))
    assert held[True] < math.radians(1.0)
    assert held[False] > math.radians(60.0)


def test_follower_state_keeps_the_suspicion() -> None:
    from models.compass import CompassFollower

    f = CompassFollower()
    f.observe(0.0, True, 47.0, 1.1, psi=0.0, sigma=0.01)
    f.observe(0.5, True, 47.0, 1.1, psi=0.0, sigma=0.01)
    assert f.suspect
    back = CompassFollower.from_state(loads(dumps(f.get_state())))
    assert (back.suspect, back.consistent_run, back.gyro_ref, back.sigmas, back.min_dev) == (
        f.suspect, f.consistent_run, f.gyro_ref, f.sigmas, f.min_dev)
    old = f.get_state()
    old["params"] = old["params"][:6]
    for k in ("suspect", "consistent_run", "gyro_ref"):
        del old[k]
    legacy = CompassFollower.from_state(old)  # a state stored before the test
    assert not legacy.suspect and legacy.gyro_ref is None and legacy.min_dev == CompassFollower().min_dev


@pytest.mark.parametrize("seed", [12, 3, 7])
def test_a_trusted_compass_leads_only_on_a_settled_field(seed: int) -> None:
    """The steel walk above, with the follower told whether each stance's field is the Earth's within its noise
    (:meth:`MagCalibrator.settled`). The edge of the disturbance passes the gate but not that test: the heading is
    held there instead of being pulled towards the deflected compass (synthetic mixed day, seed 8: the compass
    turned by 9, 20 and 33 deg over three gate-passing stances, Gait-DR followed it and the examination's ZUPT-KF
    restarted 26 deg off; mean error 7.5 -> 2.0 m). The steadiness test (``steady_tol``), which holds this edge
    by itself too, is switched off for the comparison and then tested alone."""
    from models.compass import CompassFollower

    yaws = [0.0] * 6 + [0.0, 0.0, 0.0, math.radians(45.0)] + [math.radians(90.0)] * 12
    d_peak = np.array([10.0, 22.0, 8.0])  # steel field in NED [uT]
    amp = [0.0] * 5 + [0.15, 0.35, 0.6, 0.8, 0.9, 1.0, 1.0, 0.9, 0.7, 0.45, 0.2] + [0.0] * 6
    worst = {}
    for use_settled, steady_tol in ((True, math.inf), (False, math.inf), ("steady only", 0.01)):
        rng = np.random.default_rng(seed)
        cal = _calibrated(rng)
        f = CompassFollower(steady_tol=steady_tol)
        h, errs = 0.0, []
        for yaw, a in zip(yaws, amp):
            roll, pitch = rng.normal(scale=0.02, size=2)
            c = euler_to_dcm(np.float64(roll), np.float64(pitch), np.float64(yaw))
            acc = c.T @ np.array([0.0, 0.0, -G])
            mag = c.T @ (M_N + a * d_peak) + rng.normal(scale=0.3, size=3)
            shape = cal.field_shape(acc, mag)
            settled = cal.settled(*shape, f.lead_mag_tol, f.rot_dip_tol) if use_settled is True else True
            h = f.step(h, cal.heading(acc, mag), not cal.disturbed(acc, mag), *shape, True, math.nan, settled)
            errs.append(abs(math.remainder(h - yaw, 2 * math.pi)))
        assert max(errs[-3:]) < math.radians(4.0)  # re-anchored on the clean field either way
        worst[use_settled] = max(errs[:9])  # before the turn
    # measured 2026-12-02: 0.2-0.6 deg held against 12.9-13.7 deg followed
    assert worst[True] < 0.5 * worst[False], np.degrees([worst[True], worst[False]])
    # the steadiness test alone: 0.2-0.6 deg
    assert worst["steady only"] < 0.5 * worst[False], np.degrees([worst["steady only"], worst[False]])


def test_an_established_compass_does_not_lead_while_the_field_magnitude_drifts() -> None:
    """The edge of a disturbance: the field still of the Earth's shape within the settled floors, but its
    magnitude falling by 1.3 % per stride while the compass drifts by 5 deg per stride. The heading is held; the
    same drift on a steady field is followed (averaged), and a turn of the foot is taken either way."""
    from models.compass import CompassFollower

    rng = np.random.default_rng(25)
    cal = _calibrated(rng)
    drift = np.radians([0.0, 5.0, 10.0])
    out = {}
    for scales in ((1.012, 0.999, 0.986), (1.012, 1.012, 1.012)):
        f = CompassFollower()
        for _ in range(4):  # an established clean field
            acc, mag = _turned_field(0.0, 0.0, rng, scales[0])
            f.observe(cal.heading(acc, mag), True, *cal.field_shape(acc, mag))
        h = 0.0
        for d, k in zip(drift, scales):
            acc, mag = _turned_field(0.0, float(d), rng, k)
            assert not cal.disturbed(acc, mag) and cal.settled(*cal.field_shape(acc, mag), f.lead_mag_tol, f.rot_dip_tol)
            h = _gait_step(f, cal, h, acc, mag)
        out[scales[1] < scales[0]] = math.degrees(abs(math.remainder(h, 2 * math.pi)))
        acc, mag = _turned_field(math.radians(60.0), float(drift[-1]), rng, scales[-1])  # a 60-deg turn
        h1 = _gait_step(f, cal, h, acc, mag)
        assert math.degrees(math.remainder(h1 - h, 2 * math.pi)) > 45.0  # taken
    assert out[True] < 1.5  # held
    assert out[False] > 3.0  # followed


@pytest.mark.parametrize("dip_deg, taken", [(42.0, True), (85.0, False)])
def test_a_suspect_compass_takes_a_turn_of_the_foot_in_a_strong_disturbed_field(dip_deg: float, taken: bool) -> None:
    """A suspect compass (it turned once where the gyroscope did not) on a disturbed field: a stride whose
    compass turns by 23 deg while the field's magnitude and dip stay put is the foot turning where the field's
    horizontal part is at least as strong as the Earth's (a disturbance changing by a few uT per stride turns
    such a field by a few degrees: synthetic steel, 38.5 uT at dip 42 deg, four such strides were a 90-deg
    turn the follower held through, 92 deg off for 20 strides). Where it is weak (dip 85 deg: 4 uT) the same
    change may be the field's own turning, and the heading is held (synthetic mixed day seed 27)."""
    from models.compass import CompassFollower

    earth_norm, earth_dip = 47.4, math.radians(62.3)
    h_ref = earth_norm * math.cos(earth_dip)
    f = CompassFollower()
    f.suspect = True
    dip = math.radians(dip_deg)
    heading = f.step(0.0, 0.5, False, 38.5, dip, True, math.radians(0.5), False, h_ref)
    assert heading == 0.0  # a first disturbed stance: nothing to compare with, held
    out = f.step(heading, 0.5 + math.radians(-23.0), False, 38.6, dip + 0.002, True, math.radians(0.5), False, h_ref)
    assert math.degrees(out) == pytest.approx(-23.0 if taken else 0.0, abs=1e-9)
    no_ref = f.step(out, 0.5 + math.radians(-46.0), False, 38.6, dip, True, math.radians(0.5), False)
    assert no_ref == out  # without h_ref: held


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


def test_a_field_turning_for_longer_than_a_walking_turn_is_given_back() -> None:
    """Steel can turn the field by 6-9 deg a stride, its shape steady, for more strides than a walking turn takes
    (held-out synthetic day, seed 12, 386-418 s: 8 strides one way, then back). What such a run took once past
    ``min_turn`` is given back at its fifth stride, and it takes no more until the compass stops turning that way
    (before: it was taken again four strides at a time, 64 deg here); a run that starts after a still stride is a
    turn again. The run survives a state round trip, also one stored before the run kept its start."""
    from models.compass import CompassFollower

    f = CompassFollower()
    h0 = 0.3
    h, c = f.step(h0, -0.4, False, 38.0, 1.0), -0.4
    out = []
    for k in range(8):
        c += math.radians(8.0)
        h = f.step(h, c, False, 38.0, 1.0)
        out.append(math.degrees(h - h0))
        if k == 1:
            f = CompassFollower.from_state(f.get_state())
    assert out == pytest.approx([0.0, 0.0, 24.0, 32.0, 0.0, 0.0, 0.0, 0.0], abs=1e-9)
    c += math.radians(1.0)
    h = f.step(h, c, False, 38.0, 1.0)  # the field stops turning
    assert f.run is None and math.degrees(h - h0) == pytest.approx(0.0, abs=1e-9)
    for k in range(3):  # a walking turn of 3 x 8 deg after it
        c += math.radians(8.0)
        h = f.step(h, c, False, 38.0, 1.0)
        if k == 0:  # a state stored before the run kept its start: [accumulated, taken, |m|, dip, strides]
            old = f.get_state()
            old["run"] = old["run"][:5]
            f = CompassFollower.from_state(old)
            assert f.run == pytest.approx([math.radians(8.0), 0.0, 38.0, 1.0, 1, 38.0, 1.0])
    assert math.degrees(h - h0) == pytest.approx(24.0, abs=1e-9)


@pytest.mark.parametrize("drift, taken", [(0.0, True), (0.07, False)])
def test_a_gradual_turn_through_a_disturbance_is_taken_from_its_run_of_changes(drift: float, taken: bool) -> None:
    """Inside a disturbance (the heading held, turns only from compass changes) a 45-deg walking turn shows as
    four changes of about 11 deg, none beyond ``min_turn`` (20 deg): their run is a turn once it passes 20 deg
    with the field's shape unchanged along it (held-out synthetic days: every 45-deg turn inside steel was
    missed; one random day's mean error 6.3 -> 1.5 m). A field turning by the same amounts while its magnitude
    drifts by 7 % (steel turning it) is not taken. The run and its bookkeeping survive a state round trip."""
    from models.compass import CompassFollower

    f = CompassFollower()
    h, c = 0.3, -0.4
    h = f.step(h, c, False, 38.0, 1.0)  # a disturbed field: no absolute compass
    out = []
    for k in range(4):
        c += math.radians(11.25)
        h = f.step(h, c, False, 38.0 * (1.0 + drift * (k + 1) / 4), 1.0)
        out.append(math.degrees(h - 0.3))
        if k == 1:
            f = CompassFollower.from_state(f.get_state())
    if taken:
        assert out == pytest.approx([0.0, 22.5, 33.75, 45.0], abs=1e-9)  # from the second change on
    else:
        assert out == pytest.approx([0.0, 0.0, 0.0, 0.0], abs=1e-12)
    h = f.step(h, c + math.radians(3.0), False, 38.0 * (1.0 + drift), 1.0)  # below a run's step: the run ends
    assert f.run is None


@pytest.mark.parametrize("changes, dips, total", [
    ((-8.9, -14.0, -11.7, -7.8), (49.2, 48.7, 48.1, 50.0), 42.4),  # the dip jitters after the run took a turn
    # before it took one, a dip moved by 1.6 deg still restarts the reference (that stride not counted)
    ((-11.25, -11.25, -11.25, -11.25), (49.8, 48.2, 48.2, 48.2), 22.5),
])
def test_a_run_that_took_a_turn_keeps_taking_it_while_the_dip_jitters(
        changes: tuple[float, ...], dips: tuple[float, ...], total: float) -> None:
    """Held-out random day, seed 9, 252-256 s: a 45-deg turn while running in steel reads -8.9, -14.0, -11.7,
    -7.8 deg with the dip at 49.2, 48.7, 48.1, 50.0 deg (a running foot's stances scatter it by 1-2 deg). The
    run took 22.8 deg at its second stride; the third moved the dip 1.7 deg from the run's reference, which used
    to start the reference again and not count the change, the fourth again: 19.5 deg of the turn lost, the
    stretch 20 deg off. Once a run has taken a turn only its start's shape bounds it (``rot_dip_tol``)."""
    from models.compass import CompassFollower

    f = CompassFollower()
    h, c = 0.0, -1.0
    h = f.step(h, c, False, 59.6, math.radians(49.8))  # a disturbed field: no absolute compass
    for k, (dc, dip) in enumerate(zip(changes, dips)):
        c += math.radians(dc)
        h = f.step(h, c, False, 60.3, math.radians(dip))
        if k == 1:
            f = CompassFollower.from_state(f.get_state())
    assert -math.degrees(h) == pytest.approx(total, abs=1e-9)


@pytest.mark.parametrize("second, total", [(-19.9, -89.3), (-12.0, -81.4), (19.9, -69.4)])
def test_a_turning_stride_takes_the_smaller_strides_of_the_same_turn_before_it(second: float, total: float) -> None:
    """Inside a disturbance a 90-deg turn reads -22.3, -19.9, -23.7, -23.4 deg (held-out random day, seed 15,
    returning user, 31-33 s). The second is under ``min_turn`` and began a run that the third, a turning stride
    of its own, used to discard: the heading then held the turn 20 deg short. A turning stride the same way as
    the run before it takes the run's untaken part along; one the other way does not (a stride back by 19.9 deg
    and on by 23.7 deg is no turn of 43.6)."""
    from models.compass import CompassFollower

    f = CompassFollower()
    h, c = 0.0, 1.0
    h = f.step(h, c, False, 51.4, 0.6)  # a disturbed field: no absolute compass
    for k, dc in enumerate((-22.3, second, -23.7, -23.4)):
        c += math.radians(dc)
        h = f.step(h, c, False, 51.4, 0.6)
        if k == 1:
            f = CompassFollower.from_state(f.get_state())  # the run survives a state round trip
    assert math.degrees(h) == pytest.approx(total, abs=1e-9)
    assert f.run is None


@pytest.mark.parametrize("weak", [False, True])
def test_a_disturbed_field_too_weak_horizontally_turns_nothing(weak: bool) -> None:
    """Steel that leaves 1.5 uT of a 22-uT horizontal field (dip 88 deg): a compass change of 32 deg with the
    field's magnitude and dip unchanged is a turn by the usual rule, but such a field turns by tens of degrees
    with a few uT of disturbance (synthetic mixed day seed 13: +32 and +52 deg taken while the foot walked
    straight). With ``weak`` the heading is held; a clean and settled stance is still followed."""
    from models.compass import CompassFollower

    h_ref = 47.4 * math.cos(math.radians(62.3))
    dip = math.radians(87.7)
    f = CompassFollower()
    assert f.step(0.0, 0.4, False, 36.3, dip, True, math.radians(0.5), False, h_ref, weak) == 0.0
    out = f.step(0.0, 0.4 + math.radians(32.0), False, 36.2, dip + 0.003, True, math.radians(0.5), False, h_ref, weak)
    assert math.degrees(out) == pytest.approx(0.0 if weak else 32.0, abs=1e-9)
    assert f.run is None


@pytest.mark.parametrize(
    ("norm0", "dip0_deg", "norm1", "dip1_deg", "turn_deg", "taken"),
    [
        (63.5, 68.6, 67.1, 69.2, 46.8, True),  # steel 5.7 % stronger: 2.6 uT about the vertical at most ~6 deg
        (63.5, 68.6, 67.1, 69.2, 15.0, False),  # under min_turn
        (36.8, 83.0, 36.3, 87.0, 40.0, False),  # 1.9-4.5 uT left horizontally: the field itself turns by ~55 deg
        (47.0, 62.0, 47.1, 68.0, 30.0, False),  # dip moved 6 deg: 30 deg is within 3 sigma (34 deg)
    ],
)
def test_a_large_compass_change_beyond_what_the_fields_change_can_turn_is_the_foot(
        norm0, dip0_deg, norm1, dip1_deg, turn_deg, taken) -> None:
    """A field that changed its shape between two stances also turned about the vertical, by an amount the
    visible part of its change (vertical component, horizontal magnitude) scales: taken as isotropic, that
    part over the horizontal field is the turn's standard deviation. A compass change beyond ``min_turn`` and
    three of those is the foot (held-out synthetic day, seed 3, 195 s: a 47-deg stride of a 180-deg turn in
    steel 5.7 % stronger than at the stance before was not taken, and the ZUPT-KF then ran 50 deg off)."""
    from models.compass import CompassFollower

    f = CompassFollower()
    f.observe(0.3, False, norm0, math.radians(dip0_deg))
    got = f.turn_since(0.3 + math.radians(turn_deg), norm1, math.radians(dip1_deg))
    if taken:
        assert got == pytest.approx(math.radians(turn_deg))
    else:
        assert got is None


@pytest.mark.parametrize(("dip_deg", "kept"), [(41.4, True), (80.0, False), (85.0, False)])
def test_a_restart_keeps_the_last_zupt_kf_reading_on_a_strong_disturbed_field(dip_deg: float, kept: bool) -> None:
    """Gait-DR restarts from the ZUPT-KF's last stance; a turn during the hand-over stride is the compass's change
    from that stance's reading. Kept on a disturbed field whose horizontal part is at least ``strong_h`` of the
    Earth's (61 uT at dip 41 deg: 46 uT against 22), forgotten where it is not (no change to take)."""
    from models.compass import CompassFollower

    h_ref = 47.4 * math.cos(math.radians(62.3))
    f = CompassFollower()
    f.observe(0.5, False, 61.3, math.radians(dip_deg))
    f.restart(h_ref)
    assert (f.prev is not None) == kept
    g = CompassFollower()
    g.observe(0.5, False, 61.3, math.radians(dip_deg))
    g.restart()  # without the Earth's field to compare with: forgotten
    assert g.prev is None
