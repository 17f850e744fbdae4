"""Step-and-heading models: step detection at phone rates, MARG filter (compass, quasi-static-field bias), walking
direction, step length calibration, walking heading, placement."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from energy.phone_engine import PHONE_HEADING
from models.marg import KIND_ACC, KIND_GYR, KIND_MAG, MargConfig, MargFilter, bias_settled, merge_streams
from models.pdr_step_length import HEIGHT_RATIO, WEINBERG_FEATURE_TYP, PdrStepLength, StepLengthConfig
from models.placement import PlacementRecognizer, default_placement
from models.step_detector import StepDetector
from models.heading import HeadingEstimator, wrap
from models.walking_direction import forward_azimuth, forward_sign, principal_direction

G = 9.80665


def _walk_acc(rate: float, seconds: float = 20.0, step_hz: float = 1.8, jitter: float = 0.0, seed: int = 0):
    """|f| of a walk: 3 m/s^2 of bounce at the step frequency, on a phone pitched 50 deg."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, seconds, 1.0 / rate) + rng.uniform(-jitter, jitter, int(np.ceil(seconds * rate)))[: int(np.ceil(seconds * rate))] / rate
    t = np.sort(t)
    a = G + 3.0 * np.cos(2 * np.pi * step_hz * t) + 0.05 * rng.standard_normal(t.size)
    th = math.radians(50)
    acc = np.column_stack([np.zeros(t.size), a * math.sin(th), a * math.cos(th)])
    return t, acc


@pytest.mark.parametrize("rate", [25.0, 50.0, 100.0])
@pytest.mark.parametrize("jitter", [0.0, 0.3])
def test_steps_found_at_every_phone_rate(rate: float, jitter: float) -> None:
    t, acc = _walk_acc(rate, jitter=jitter)
    steps = StepDetector().process(t, acc)
    # 20 s at 1.8 steps/s, the first one needs the filter to settle
    assert 34 <= len(steps) <= 36
    period = np.nanmedian(steps[:, 3])
    assert period == pytest.approx(1 / 1.8, abs=1.5 / rate)
    assert np.all(steps[1:, 1] - steps[1:, 2] > 4.0)  # peak-to-valley of a 3 m/s^2 bounce, filtered (the first
    # peak comes before any valley: the signal starts at its top)


def test_step_times_agree_across_rates() -> None:
    """The filter is exact for the held samples: 25 Hz and 100 Hz sampling of one walk give the same steps to
    within the coarser sampling interval."""
    s25 = StepDetector().process(*_walk_acc(25.0))
    s100 = StepDetector().process(*_walk_acc(100.0))
    n = min(len(s25), len(s100))
    assert abs(len(s25) - len(s100)) <= 1
    np.testing.assert_allclose(s25[-n + 2:, 0], s100[-n + 2:, 0], atol=0.041)


def test_no_steps_standing() -> None:
    rng = np.random.default_rng(1)
    t = np.arange(0, 30, 0.02)
    acc = np.tile([0.0, 7.5, 6.3], (t.size, 1)) + 0.2 * rng.standard_normal((t.size, 3))
    assert len(StepDetector().process(t, acc)) == 0


@settings(max_examples=15, deadline=None)
@given(cuts=st.lists(st.integers(1, 999), min_size=1, max_size=6, unique=True))
def test_step_detector_chunk_invariant(cuts: list[int]) -> None:
    t, acc = _walk_acc(50.0, seconds=20.0, jitter=0.3)
    whole = StepDetector().process(t, acc)
    det = StepDetector()
    parts = []
    edges = [0] + sorted(cuts) + [t.size]
    for a, b in zip(edges[:-1], edges[1:]):
        parts.append(det.process(t[a:b], acc[a:b]))
    np.testing.assert_array_equal(np.concatenate(parts), whole)


# ---------------------------------------------------------------------------------------------- MARG
REF = np.array([20.30, 1.43, 44.60])  # NED field [uT], declination 4.0 deg


def _still_device(heading_deg: float, seconds: float, bias=(0.0, 0.0, 0.0), rng=None):
    """A flat device (x forward) at rest pointing ``heading_deg``: its streams at 50/100/50 Hz."""
    rng = rng or np.random.default_rng(0)
    psi = math.radians(heading_deg)
    C = np.array([[math.cos(psi), -math.sin(psi), 0], [math.sin(psi), math.cos(psi), 0], [0, 0, 1.0]])  # body -> NED
    ta, tg, tm = np.arange(0, seconds, 0.02), np.arange(0, seconds, 0.01), np.arange(0.005, seconds, 0.02)
    acc = np.tile(C.T @ np.array([0, 0, -G]), (ta.size, 1)) + 0.03 * rng.standard_normal((ta.size, 3))
    gyr = np.tile(bias, (tg.size, 1)) + 0.003 * rng.standard_normal((tg.size, 3))
    mag = np.tile(C.T @ REF, (tm.size, 1)) + 0.2 * rng.standard_normal((tm.size, 3))
    return merge_streams((ta, acc), (tg, gyr), (tm, mag))


def _yaw(q: np.ndarray) -> float:
    w, x, y, z = q
    return math.atan2(2 * (x * y + w * z), 1 - 2 * (y * y + z * z))


@pytest.mark.parametrize("heading", [0.0, 75.0, -130.0])
def test_compass_heading_with_declination(heading: float) -> None:
    f = MargFilter(MargConfig(), REF, math.atan2(REF[1], REF[0]))
    q = f.process(*_still_device(heading, 120.0))
    assert math.degrees(wrap(_yaw(q[-1]) - math.radians(heading))) == pytest.approx(0.0, abs=2.0)


def test_quasi_static_field_finds_the_vertical_gyro_bias_in_a_disturbed_field() -> None:
    """Standing in a field far from the Earth's (no compass to speak of), the field's unchanging azimuth shows
    the vertical gyroscope bias (0.3 deg/s here)."""
    cfg = MargConfig(compass_sigma_rad=0.0)  # no absolute compass at all
    bias = (0.0, 0.0, math.radians(0.3))
    f = MargFilter(cfg)
    f.process(*_still_device(20.0, 90.0, bias))
    assert f.state.b[2] == pytest.approx(bias[2], abs=math.radians(0.03))
    # without the quasi-static update the bias stays unknown
    f2 = MargFilter(MargConfig(compass_sigma_rad=0.0, qsf_sigma_rad=1e3))
    f2.process(*_still_device(20.0, 90.0, bias))
    assert abs(f2.state.b[2] - bias[2]) > math.radians(0.2)


def test_vertical_bias_settles_standing_and_a_wave_unsettles_it() -> None:
    """At rest the quasi-static field settles the vertical bias to the filter's own bound, its estimate within
    three of its standard deviations of the truth; a wave (the device turned at 6 rad/s) unsettles it."""
    cfg = MargConfig()
    bias = (0.0, 0.0, math.radians(0.8))
    f = MargFilter(cfg, REF, math.atan2(REF[1], REF[0]))
    f.process(*_still_device(40.0, 1.0, bias))
    assert not bias_settled(f.state.s)  # the prior (1.7 deg/s) is not settled
    f2 = MargFilter(cfg, REF, math.atan2(REF[1], REF[0]))
    f2.process(*_still_device(40.0, 60.0, bias))
    std = f2.state.vertical_bias_std_rad_s
    assert bias_settled(f2.state.s) and std <= cfg.bias_settled_rad_s
    assert abs(f2.state.b[2] - bias[2]) <= 3.0 * std
    t, k, v = _still_device(40.0, 2.0, bias)
    v = v.copy()
    v[k == KIND_GYR] = (6.0, 0.0, 0.0)
    f2.process(t + 60.0, k, v)
    assert not bias_settled(f2.state.s)


def test_a_10_hz_magnetometer_is_read_whole() -> None:
    """The compass is due every 0.1 s: a magnetometer at 10 Hz with jitter (the energy-aware rate) gives an update
    at (nearly) every sample, not at every other one; one at 50 Hz still every fifth."""
    from models import marg as M

    rng = np.random.default_rng(3)
    t, k, v = _still_device(30.0, 20.0, (0.0, 0.0, math.radians(0.3)))
    for keep, expect in ((5, 0.9), (1, 0.9 / 5)):
        mag = np.flatnonzero(k == KIND_MAG)
        drop = mag[np.arange(mag.size) % keep != 0]
        sel = np.setdiff1d(np.arange(t.size), drop)
        tt = t[sel].copy()
        m = k[sel] == KIND_MAG
        tt[m] += rng.uniform(-0.004, 0.004, int(m.sum()))
        o = np.argsort(tt, kind="stable")
        f = MargFilter(MargConfig())
        f.process(tt[o], k[sel][o], v[sel][o])
        updates = f.state.s[M.S_NQSF] + f.state.s[M.S_NCOMP]
        assert updates >= expect * m.sum() and updates <= 1.1 * m.sum() / (5 // keep)


def test_gyro_dyaw_is_the_turn_about_the_vertical() -> None:
    """A pitched phone walking while turning at 0.2 rad/s about the vertical: the steps' ``gyro_dyaw`` add up to
    the turn between the first and the last step, whatever the pitch puts on the body's axes."""
    from energy.phone_engine import PhoneEngineConfig
    from models.marg import MargState
    from models.pdr import STEP_RECORD, PdrState, run_pdr

    rate = 0.2
    ta, acc = _walk_acc(50.0, seconds=30.0)
    th = math.radians(50)
    tg = np.arange(0.0, 30.0, 0.01)
    gyr = np.tile(rate * np.array([0.0, -math.sin(th), -math.cos(th)]), (tg.size, 1))
    cfg = PhoneEngineConfig()
    state = PdrState.new(MargState.new(cfg.marg))
    t, k, v = merge_streams((ta, acc), (tg, gyr), (np.zeros(0), np.zeros((0, 3))))
    r = run_pdr(state, cfg.marg.as_array(), cfg.steps.as_array(), t, k, v)
    F = {n: i for i, n in enumerate(STEP_RECORD)}
    assert len(r) > 20
    turn = float(np.sum(r[1:, F["gyro_dyaw"]]))
    assert turn == pytest.approx(rate * (r[-1, F["t_s"]] - r[0, F["t_s"]]), rel=0.02)


def test_merge_order_and_kinds() -> None:
    t, k, _ = merge_streams((np.array([1, 3]), np.zeros((2, 3))), (np.array([1, 2]), np.ones((2, 3))),
                            (np.array([3]), np.ones((1, 3))))
    assert list(t) == [1, 1, 2, 3, 3] and list(k) == [KIND_ACC, KIND_GYR, KIND_GYR, KIND_ACC, KIND_MAG]


# ---------------------------------------------------------------------------------------------- direction
@pytest.mark.parametrize("heading", [0.0, 45.0, 170.0, -100.0])
@pytest.mark.parametrize("pitch", [0.0, 50.0, 85.0])
def test_forward_azimuth_of_a_held_phone(heading: float, pitch: float) -> None:
    th, psi = math.radians(pitch), math.radians(heading)
    c0 = np.array([[0.0, math.cos(th), -math.sin(th)], [1.0, 0.0, 0.0], [0.0, -math.sin(th), -math.cos(th)]])
    rz = np.array([[math.cos(psi), -math.sin(psi), 0], [math.sin(psi), math.cos(psi), 0], [0, 0, 1.0]])
    assert math.degrees(wrap(forward_azimuth(rz @ c0) - psi)) == pytest.approx(0.0, abs=1e-9)


@pytest.mark.parametrize("walk_deg", [10.0, 100.0, -150.0])
def test_principal_direction_and_its_sign(walk_deg: float) -> None:
    """Forward acceleration a quarter step after the upward one (gait): the sign statistic picks the walking
    direction out of the principal axis."""
    f = 1.8
    t = np.arange(0, 2.0, 0.02)
    a_up = -3.0 * np.cos(2 * np.pi * f * t)  # highest point (largest downward acceleration) at t = 0
    a_fwd = 1.0 * np.sin(2 * np.pi * f * t)  # forward speed lowest at the top
    psi = math.radians(walk_deg)
    w = np.column_stack([t, a_fwd * math.cos(psi), a_fwd * math.sin(psi), -(a_up + G)])
    th, ratio = principal_direction(w)
    assert ratio > 100
    assert abs(wrap(2 * (th - psi))) < 1e-6  # modulo pi
    s_right = forward_sign(w, psi, 1 / f)
    s_wrong = forward_sign(w, psi + math.pi, 1 / f)
    assert s_right > 0 > s_wrong


# ---------------------------------------------------------------------------------------------- step length
def test_new_user_constant_from_height() -> None:
    sl = PdrStepLength(StepLengthConfig(height_m=1.80))
    assert sl.k == pytest.approx(HEIGHT_RATIO * 1.80 / WEINBERG_FEATURE_TYP)
    assert sl.length(9.81 + 3.0, 9.81 - 2.0, 1.8) == pytest.approx(sl.k * 5.0 ** 0.25)


def test_known_distance_calibrates_and_bad_input_is_refused() -> None:
    sl = PdrStepLength(StepLengthConfig(weinberg_k=0.45))
    u = np.full(40, 1.3)
    out = sl.calibrate(40 * 0.60, u)  # the user's true K: 0.60 / 1.3 = 0.4615
    assert out["k_observed"] == pytest.approx(0.60 / 1.3)
    assert 0.45 < sl.k < 0.4615 + 1e-9 and sl.calibrated
    for _ in range(5):
        sl.calibrate(40 * 0.60, u)
    assert sl.k == pytest.approx(0.60 / 1.3, rel=0.005)  # repeated evidence wins over the population prior
    with pytest.raises(ValueError, match="distance_m"):
        sl.calibrate(-1.0, u)
    with pytest.raises(ValueError, match="steps"):
        sl.calibrate(5.0, u[:3])
    restored = PdrStepLength(StepLengthConfig(), sl.calibration())
    assert restored.k == sl.k and restored.calibrated


def test_height_frequency_model_is_a_typical_step() -> None:
    sl = PdrStepLength(StepLengthConfig(model="height_freq", height_m=1.75))
    assert sl.length(0.0, 0.0, 1.79) == pytest.approx(0.70, abs=1e-9)
    assert sl.length(0.0, 0.0, 2.1) > sl.length(0.0, 0.0, 1.6)
    with pytest.raises(ValueError, match="height_m"):
        StepLengthConfig(model="height_freq")


# ---------------------------------------------------------------------------------------------- walk heading
# the phone's use of the shared heading estimator (models.heading) with its hand-held parameters, per step
DEG = math.pi / 180.0


def _phone_heading(theta: float) -> HeadingEstimator:
    h = HeadingEstimator(PHONE_HEADING)
    h.start(theta, (1 * DEG) ** 2)
    h.set_offset_prior(0.0, PHONE_HEADING.offset_prior_rad)  # the phone's compass reads in the heading's frame
    return h


def test_gyroscope_steps_learn_the_place_and_gyroscope_off_steps_hold_through_it() -> None:
    """A compass 20 deg off at this place while the gyroscope carries the heading: the deflection is learnt, not
    the heading; with the gyroscope off the heading holds instead of following the compass."""
    h = _phone_heading(0.3)
    rng = np.random.default_rng(2)
    for _ in range(20):
        h.predict_gyro(0.0)
        h.update_compass(0.3 + 20 * DEG + 2 * DEG * rng.standard_normal(), (2 * DEG) ** 2, 0.5, learn=True)
    assert abs(wrap(h.heading - 0.3)) < 3 * DEG and len(h.noise.samples) == 20
    for _ in range(5):
        h.predict_free()
        h.update_compass(0.3 + 20 * DEG + 2 * DEG * rng.standard_normal(), (2 * DEG) ** 2, 0.5)
    assert abs(wrap(h.heading - 0.3)) < 4 * DEG and h.turn_prob < 0.5


@pytest.mark.parametrize("turn_deg", [90.0, -90.0, 180.0])
def test_gyroscope_off_a_compass_jump_is_a_turn(turn_deg: float) -> None:
    h = _phone_heading(0.0)
    rng = np.random.default_rng(3)
    for _ in range(10):
        h.predict_free()
        h.update_compass(2 * DEG * rng.standard_normal(), (2 * DEG) ** 2, 0.5)
    assert h.turn_prob < 0.5
    turned = []
    for _ in range(2):
        h.predict_free()
        h.update_compass(turn_deg * DEG + 2 * DEG * rng.standard_normal(), (2 * DEG) ** 2, 0.5)
        turned.append(h.turn_prob > 0.5)
    assert turned[0] and abs(wrap(h.heading - turn_deg * DEG)) < 10 * DEG


def test_forecast_grows_without_a_compass() -> None:
    h = _phone_heading(0.0)
    stds = []
    for _ in range(10):
        stds.append(h.forecast(None)[0])
        h.predict_free()
    assert all(b > a for a, b in zip(stds, stds[1:]))


# ---------------------------------------------------------------------------------------------- placement
def test_placement_recognition_needs_consecutive_steps() -> None:
    r = PlacementRecognizer("phone")
    assert r.placement == default_placement("phone") == "phone-hand"
    changes = [r.step(0.96, 1.8) for _ in range(8)]
    assert changes[:-1] == [None] * 7 and changes[-1] == "phone-pocket"
    assert r.step(0.999, 0.3) is None and r.placement == "phone-pocket"  # one steady step is not a change
    assert PlacementRecognizer("phone", "phone-hand").step(0.9, 3.0) is None  # given by the client: kept
    assert PlacementRecognizer("watch").placement == "watch"
    with pytest.raises(ValueError, match="placement"):
        PlacementRecognizer("phone", "foot")


# ---------------------------------------------------------------------------------------------- fusion
def test_step_fusion_blends_agreeing_steps_and_keeps_the_primary_otherwise() -> None:
    from models.step_fusion import StepFusionConfig, fuse_steps

    t = np.arange(10) * 0.55
    la, ha = np.full(10, 0.70), np.full(10, 0.5)
    lb, hb = np.full(10, 0.66), np.full(10, 0.5 + math.radians(10.0))
    lb[3] = 0.2  # a false short step of the secondary: the 000 Table 7 ratio gate keeps it out
    hb[4] = 0.5 + math.radians(90.0)  # a heading the primary disagrees with by far
    length, head, blended = fuse_steps(t, la, ha, t + 0.05, lb, hb)
    assert length[0] == pytest.approx(0.68) and head[0] == pytest.approx(0.5 + math.radians(5.0))  # 000 eq. (70)
    assert length[3] == 0.70 and head[4] == 0.5 and blended.all()
    # nothing to pair with: the primary as it is
    length, head, blended = fuse_steps(t, la, ha, t + 50.0, lb, hb)
    assert not blended.any() and np.array_equal(length, la)
    with pytest.raises(ValueError):
        StepFusionConfig(ratio_low=1.1)


@settings(max_examples=40, deadline=None)
@given(st.integers(3, 40), st.floats(-0.3, 0.3), st.integers(0, 2**31 - 1))
def test_fused_track_is_the_sum_of_the_fused_steps(n: int, offset_rad: float, seed: int) -> None:
    """``fuse_track``: without a partner the track comes back bit for bit; a secondary whose every step agrees in
    length and turns the heading by ``offset_rad`` (inside the gate) turns the track about its start by half of
    it (000 eq. 70, weight 0.5)."""
    from models.step_fusion import fuse_track

    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(0.45, 0.7, n))
    length, head = rng.uniform(0.5, 0.8, n), np.cumsum(rng.normal(0.0, 0.3, n))
    start = rng.normal(0.0, 5.0, 2)
    north = start[0] + np.cumsum(length * np.cos(head))
    east = start[1] + np.cumsum(length * np.sin(head))
    fn, fe, fl, fh, blended = fuse_track(north, east, t, length, head, t + 60.0, length, head)
    assert not blended.any() and np.array_equal(fn, north) and np.array_equal(fe, east) and np.array_equal(fh, head)
    fn, fe, fl, fh, blended = fuse_track(north, east, t, length, head, t + 0.02, length, head + offset_rad)
    assert blended.all() and np.allclose(fl, length) and np.allclose(fh, head + offset_rad / 2)
    c, s = math.cos(offset_rad / 2), math.sin(offset_rad / 2)
    dn, de = north - start[0], east - start[1]
    assert np.allclose(fn, start[0] + c * dn - s * de, atol=1e-9)
    assert np.allclose(fe, start[1] + s * dn + c * de, atol=1e-9)


def test_orientation_std_shrinks_with_independent_votes_and_grows_with_their_spread() -> None:
    """DominantDirections.orientation_std_rad: the votes' circular spread (of 4 theta) / 4 over the square root of
    n (1 - rho) / (1 + rho) independent votes."""
    import cmath

    from models.dominant_directions import DominantDirections, DominantDirectionsConfig

    d = DominantDirections(DominantDirectionsConfig())
    assert d.orientation_std_rad(0.9) == math.inf
    rng = np.random.default_rng(3)
    sd = math.radians(10.0)
    errs = rng.normal(0.0, sd, 400)
    for k, e in enumerate(errs):
        d.vote += cmath.exp(4j * (0.3 + e + (k % 4) * math.pi / 2))
        d.votes += 1
    assert d.orientation_rad == pytest.approx(0.3, abs=3 * sd / math.sqrt(400))
    assert d.orientation_std_rad(0.0) == pytest.approx(sd / math.sqrt(400), rel=0.15)
    assert d.orientation_std_rad(0.9) == pytest.approx(sd / math.sqrt(400 * 0.1 / 1.9), rel=0.15)
    few = DominantDirections(DominantDirectionsConfig())
    few.vote, few.votes = d.vote * 0.01, 4
    assert few.orientation_std_rad(0.9) > d.orientation_std_rad(0.9)
