"""Step-length models and online calibration: coefficient recovery, sigma_d, examination, state."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from energy.codec import dumps, loads
from models.step_length import MODELS, StepFeatures, StepLengthCalibrator, regressors, robust_fit, sigma_d


def _features(rng: np.random.Generator, n: int, f_lo: float = 0.7, f_hi: float = 1.3) -> list[StepFeatures]:
    f = rng.uniform(f_lo, f_hi, n)
    amax = rng.uniform(25.0, 60.0, n)
    amean = rng.uniform(11.0, 16.0, n)
    return [StepFeatures(float(a), float(b), float(c), float(c) - float(d))
            for a, b, c, d in zip(f, amean, amax, rng.uniform(15.0, 40.0, n))]


@settings(max_examples=30, deadline=None)
@given(k=st.tuples(st.floats(-0.5, 0.5), st.floats(-0.5, 0.5), st.floats(0.5, 1.8), st.floats(-0.01, 0.01)),
       seed=st.integers(0, 10_000))
def test_calibration_recovers_eq15_coefficients(k: tuple[float, float, float, float], seed: int) -> None:
    rng = np.random.default_rng(seed)
    xs = _features(rng, 200, 0.6, 1.6)  # a calibration walk spanning paces
    coef = np.array(k)
    d = np.array([regressors("eq15", x) @ coef for x in xs]) + rng.normal(scale=0.01, size=len(xs))
    cal = StepLengthCalibrator("eq15", band_hz=10.0)  # one band: check the pooled fit
    for x, y in zip(xs, d):
        cal.add("walk", x, float(y))
    cal.fit("walk")
    test = _features(rng, 50, 0.6, 1.6)
    pred = np.array([cal.predict("walk", x)[0] for x in test])
    true = np.array([regressors("eq15", x) @ coef for x in test])
    assert np.max(np.abs(pred - true)) < 0.03  # metres: the model, not the noise, is recovered
    assert cal.predict("walk", test[0])[1] == pytest.approx(0.03, abs=0.02)  # sigma_d ~ noise, floored


@pytest.mark.parametrize("model", ["eq15_run", "weinberg"])
def test_single_coefficient_models_are_recovered_despite_outliers(model: str) -> None:
    rng = np.random.default_rng(3)
    xs = _features(rng, 100)
    x = np.array([regressors(model, q) for q in xs])
    d = x @ np.array([0.55]) + rng.normal(scale=0.01, size=100)
    d[::10] += 1.5  # ten grossly wrong ZUPT distances (a missed stance doubles a step)
    c = robust_fit(x, d, np.array([0.0]), np.array([10.0]))
    assert c[0] == pytest.approx(0.55, abs=0.01)


def test_sigma_d_is_table3_formula() -> None:
    d_kf = np.array([1.0, 1.2, 1.4, 1.1])
    d_sl = np.array([1.1, 1.2, 1.3, 1.1])
    assert sigma_d(d_kf, d_sl) == pytest.approx(np.sqrt(0.02 / 3))


def test_examination_trips_when_the_gait_changes() -> None:
    rng = np.random.default_rng(5)
    cal = StepLengthCalibrator("eq15")
    coef = np.array([0.1, 0.0, 1.2, 0.002])
    xs = _features(rng, 60, 0.85, 0.95)
    for x in xs:
        cal.add("walk", x, float(regressors("eq15", x) @ coef + rng.normal(scale=0.03)))
    cal.fit("walk")
    same = _features(rng, 40, 0.85, 0.95)
    ok_same = [cal.examine(float(regressors("eq15", x) @ coef), cal.predict("walk", x)[0], "walk", x.f_s)
               for x in same]
    assert np.mean(ok_same) > 0.95
    # new gait at the same cadence: 35 % longer strides (e.g. a shuffle to a lunge); the model is stale
    ok_new = [cal.examine(1.35 * float(regressors("eq15", x) @ coef), cal.predict("walk", x)[0], "walk", x.f_s)
              for x in same]
    assert not any(ok_new)


def test_bands_give_separate_models_per_walking_pattern() -> None:
    rng = np.random.default_rng(7)
    cal = StepLengthCalibrator("eq15", band_hz=0.2, min_pairs=8)
    slow = _features(rng, 30, 0.62, 0.78)
    fast = _features(rng, 30, 1.22, 1.38)
    for x in slow:
        cal.add("walk", x, 0.9)
    for x in fast:
        cal.add("walk", x, 1.7)
    fits = cal.fit("walk")
    assert len([k for k in fits if k.startswith("walk/")]) == 2
    # each band's level (within a band the slope over f stays near the population prior's, which does not
    # know that these synthetic strides ignore the cadence)
    assert np.mean([cal.predict("walk", x)[0] for x in slow]) == pytest.approx(0.9, abs=0.02)
    assert np.mean([cal.predict("walk", x)[0] for x in fast]) == pytest.approx(1.7, abs=0.02)


def test_uncalibrated_examination_fails_safe_and_models_are_checked() -> None:
    cal = StepLengthCalibrator()
    assert not cal.examine(1.0, 1.0, "walk", 0.9)
    with pytest.raises(ValueError):
        StepLengthCalibrator("nope")
    for m in MODELS:
        assert np.all(np.isfinite(regressors(m, StepFeatures(0.9, 12.0, 40.0, 5.0))))


def test_state_round_trip() -> None:
    rng = np.random.default_rng(9)
    cal = StepLengthCalibrator("height_freq", height_m=1.8)
    for x in _features(rng, 20):
        cal.add("walk", x, 1.4)
    cal.fit("walk")
    back = StepLengthCalibrator.from_state(loads(dumps(cal.get_state())))
    x = StepFeatures(0.9, 12.0, 40.0, 5.0)
    assert back.predict("walk", x) == cal.predict("walk", x)
    assert back.get_state() == cal.get_state()


def test_examination_reports_z_and_sigma_and_agrees_with_examine() -> None:
    rng = np.random.default_rng(9)
    cal = StepLengthCalibrator("eq15")
    assert cal.examination(1.0, 1.0)[0] is False  # no model yet
    coef = np.array([0.1, 0.0, 1.2, 0.002])
    for x in _features(rng, 40, 0.85, 0.95):
        cal.add("walk", x, float(regressors("eq15", x) @ coef + rng.normal(scale=0.03)))
    cal.fit("walk")
    x = _features(rng, 1, 0.85, 0.95)[0]
    d_sl = cal.predict("walk", x)[0]
    for d_kf in (d_sl, d_sl + 0.05, d_sl + 0.5):
        ok, z, sig = cal.examination(d_kf, d_sl, "walk", x.f_s)
        assert ok == cal.examine(d_kf, d_sl, "walk", x.f_s)
        assert z == pytest.approx((d_kf - d_sl) / sig) and sig >= cal.sigma_floor


def test_band_models_shrink_towards_the_pooled_model() -> None:
    rng = np.random.default_rng(4)
    coef = np.array([0.1, 0.0, 1.2, 0.002])
    xs = _features(rng, 60, 0.70, 1.30)
    d = [float(regressors("eq15", x) @ coef + rng.normal(scale=0.03)) for x in xs]
    out = {}
    for scale in (0.1, np.inf):
        cal = StepLengthCalibrator("eq15", band_prior_scale=scale)
        for x, y in zip(xs, d):
            cal.add("walk", x, y)
        fits = cal.fit("walk")
        pooled = np.array(fits["walk"]["coef"])
        out[scale] = max(np.abs(np.array(v["coef"]) - pooled).max() for k, v in fits.items() if "/" in k)
        back = StepLengthCalibrator.from_state(loads(dumps(cal.get_state())))
        assert back.band_prior_scale == cal.band_prior_scale
    assert out[0.1] < out[np.inf]


def test_narrow_pace_calibration_extrapolates_with_the_cadence() -> None:
    """A calibration walk at one pace cannot tell the slope over f; the prior's shape decides: a slower
    cadence gives a shorter stride (the constant-speed shape ``d ~ 1/f`` predicted a longer one)."""
    rng = np.random.default_rng(12)
    cal = StepLengthCalibrator("eq15")
    for x in _features(rng, 40, 0.84, 0.86):
        cal.add("walk", x, 1.25 * x.f_s / 0.85 + float(rng.normal(scale=0.04)))  # stride ~ cadence
    cal.fit("walk")
    slow = StepFeatures(0.72, 13.0, 40.0, 10.0)
    base = StepFeatures(0.85, 13.0, 40.0, 10.0)
    d_slow, d_base = cal.predict("walk", slow)[0], cal.predict("walk", base)[0]
    assert d_slow < d_base
    assert d_slow == pytest.approx(1.25 * 0.72 / 0.85, abs=0.08)


def test_walking_model_follows_the_mean_acceleration_at_one_cadence() -> None:
    """004 eq. (15)'s K3 acts on the mean filtered acceleration: at one cadence, strides that grow with it
    (as the gdin strides do) are followed; the peak acceleration does not enter the walking model."""
    rng = np.random.default_rng(21)
    cal = StepLengthCalibrator("eq15")
    for x in _features(rng, 40, 0.84, 0.86):
        cal.add("walk", x, 1.3 + 0.15 * (x.acc_mean - 13.5) + float(rng.normal(scale=0.02)))
    cal.fit("walk")
    lo, hi = StepFeatures(0.85, 12.5, 30.0, 5.0), StepFeatures(0.85, 14.5, 30.0, 5.0)
    assert cal.predict("walk", hi)[0] - cal.predict("walk", lo)[0] == pytest.approx(0.30, abs=0.06)
    peak = StepFeatures(0.85, 12.5, 55.0, 5.0)
    assert cal.predict("walk", peak)[0] == cal.predict("walk", lo)[0]


def test_state_from_an_older_regressor_form_is_refitted() -> None:
    """Profiles stored before K3 moved to the mean acceleration: their fits are redone from the stored pairs
    (those the pooled fit used), not applied to the new regressor."""
    rng = np.random.default_rng(22)
    cal = StepLengthCalibrator("eq15")
    xs = _features(rng, 30, 0.8, 0.9)
    for x in xs[:24]:
        cal.add("walk", x, 1.3 + float(rng.normal(scale=0.03)))
    cal.fit("walk")
    for x in xs[24:]:
        cal.add("walk", x, 1.3)  # pairs gathered after the fit
    old = cal.get_state()
    del old["form"]
    for v in old["fits"].values():
        v["coef"][3] = -0.014  # a peak-acceleration K3 (m per m/s^2 of a ~30 m/s^2 peak)
    back = StepLengthCalibrator.from_state(old)
    assert back.n_pairs("walk") == 30
    x = StepFeatures(0.85, 13.5, 30.0, 5.0)
    assert back.predict("walk", x) == cal.predict("walk", x)
    assert back.get_state()["fits"] == cal.get_state()["fits"]


def test_running_model_follows_the_cadence_and_older_states_keep_the_cube_root() -> None:
    """Running strides over 1.0-1.3 Hz (1.5-2.6 m, as gdin's): the eq. (15) walking form fitted on them
    predicts the slower ones; 004's K4 cbrt(a_bar) (elasticity 1/3, no cadence) cannot."""
    rng = np.random.default_rng(23)
    f = rng.uniform(1.0, 1.3, 30)
    d = 1.5 + 3.5 * (f - 1.0)
    amean = 16.0 + 30.0 * (f - 1.0)
    out = {}
    for run_model in ("eq15", "eq15_run"):
        cal = StepLengthCalibrator("eq15", run_model=run_model)
        for fi, ai, di in zip(f, amean, d):
            cal.add("run", StepFeatures(float(fi), float(ai), 40.0, 5.0), float(di + rng.normal(scale=0.03)))
        cal.fit("run")
        out[run_model] = cal.predict("run", StepFeatures(1.02, 16.6, 40.0, 5.0))[0]
        back = StepLengthCalibrator.from_state(loads(dumps(cal.get_state())))
        assert back.run_model == run_model and back.get_state() == cal.get_state()
    assert out["eq15"] == pytest.approx(1.57, abs=0.06)
    assert out["eq15_run"] > 1.57 + 0.1
    old = StepLengthCalibrator().get_state()
    del old["run_model"]
    assert StepLengthCalibrator.from_state(old).model_for("run") == "eq15_run"


def test_cadence_range_is_that_of_the_fitted_pairs_widened_by_half_a_resolution_step() -> None:
    rng = np.random.default_rng(3)
    cal = StepLengthCalibrator()
    assert cal.cadence_range("walk") is None
    xs = _features(rng, 12, 0.8, 0.9)
    for x in xs:
        cal.add("walk", x, 1.35)
    assert cal.cadence_range("walk") is None  # pairs without a fitted model
    cal.fit("walk")
    lo, hi = min(x.f_s for x in xs), max(x.f_s for x in xs)
    assert cal.cadence_range("walk") == pytest.approx((lo, hi))
    res = 0.04  # a step period measured to one sample at 25 Hz
    assert cal.cadence_range("walk", res) == pytest.approx((lo - lo * lo * res / 2, hi + hi * hi * res / 2))
    cal.add("walk", StepFeatures(1.0, 13.0, 40.0, 10.0), 1.6)  # an examination stride, not yet fitted
    assert cal.cadence_range("walk") == pytest.approx((lo, hi))
    cal.fit("walk")
    assert cal.cadence_range("walk")[1] == pytest.approx(1.0)
    r = StepLengthCalibrator.from_state(loads(dumps(cal.get_state())))
    assert r.cadence_range("walk") == cal.cadence_range("walk")


def test_cadence_ranges_leave_out_the_paces_between_a_slow_and_a_fast_walk() -> None:
    """A model fitted on a slow and a fast walk has not seen the pace between them: the fitted cadences split where
    two neighbours lie more than CADENCE_GAP_HZ apart (or three resolution steps), each part widened by half a
    resolution step; one continuous spread stays one range."""
    from models.step_length import CADENCE_GAP_HZ

    rng = np.random.default_rng(5)
    cal = StepLengthCalibrator()
    slow, fast = _features(rng, 15, 0.72, 0.76), _features(rng, 15, 0.96, 1.0)
    for x in slow:
        cal.add("walk", x, 1.05)
    for x in fast:
        cal.add("walk", x, 1.6)
    cal.fit("walk")
    res = 0.04
    ranges = cal.cadence_ranges("walk", res)
    assert len(ranges) == 2
    (lo0, hi0), (lo1, hi1) = ranges
    f_slow, f_fast = [x.f_s for x in slow], [x.f_s for x in fast]
    assert lo0 == pytest.approx(min(f_slow) - min(f_slow) ** 2 * res / 2)
    assert hi0 == pytest.approx(max(f_slow) + max(f_slow) ** 2 * res / 2)
    assert lo1 == pytest.approx(min(f_fast) - min(f_fast) ** 2 * res / 2)
    assert hi1 == pytest.approx(max(f_fast) + max(f_fast) ** 2 * res / 2)
    assert not any(lo <= 0.87 <= hi for lo, hi in ranges)  # the walk between them
    assert cal.cadence_range("walk", res) == pytest.approx((lo0, hi1))  # the outer ends
    assert len(cal.cadence_ranges("walk", res, gap_hz=0.3)) == 1  # a gap the model may interpolate across
    assert CADENCE_GAP_HZ < min(f_fast) - max(f_slow)
    for x in _features(rng, 30, 0.76, 0.96):  # the paces between, seen and fitted
        cal.add("walk", x, 1.35)
    cal.fit("walk")
    assert len(cal.cadence_ranges("walk", res)) == 1
    r = StepLengthCalibrator.from_state(loads(dumps(cal.get_state())))
    assert r.cadence_ranges("walk", res) == cal.cadence_ranges("walk", res)


def test_pairs_are_bounded_to_the_newest_and_the_fit_keeps_counting_its_own() -> None:
    """Every ZUPT-KF stride adds a pair; the newest ``max_pairs`` are kept (the state and the profile stayed
    bounded), and the pooled fit's ``n`` still counts the kept pairs it used (cadence_range, refits)."""
    rng = np.random.default_rng(7)
    cal = StepLengthCalibrator(max_pairs=20)
    slow = _features(rng, 15, 0.7, 0.8)
    for x in slow:
        cal.add("walk", x, 1.2)
    cal.fit("walk")
    fast = _features(rng, 10, 1.1, 1.2)
    for x in fast:
        cal.add("walk", x, 1.5)
    assert cal.n_pairs("walk") == 20  # 25 added
    kept = [x.f_s for x in slow[5:]]  # the 5 oldest slow pairs are gone
    assert cal.cadence_range("walk") == pytest.approx((min(kept), max(kept)))
    for x in _features(rng, 10, 1.1, 1.2):
        cal.add("walk", x, 1.5)
    assert cal.cadence_range("walk") is None  # no pair the fit used is left
    cal.fit("walk")
    assert cal.cadence_range("walk")[0] >= 1.1 and cal.n_pairs("walk") == 20
    stored = cal.get_state()
    stored["pairs"]["walk"] = [[0.75, 13.0, 40.0, 10.0, 1.2]] * 30 + stored["pairs"]["walk"]  # an older profile
    del stored["max_pairs"]
    back = StepLengthCalibrator.from_state(loads(dumps(stored)))
    assert back.max_pairs == 300 and back.n_pairs("walk") == 50
    with pytest.raises(ValueError, match="max_pairs"):
        StepLengthCalibrator(max_pairs=4)


@pytest.mark.parametrize("k3", [-0.05, 0.15])
def test_a_negative_acceleration_slope_is_not_extrapolated_beyond_the_calibration(k3: float) -> None:
    """Fitted over a_bar 13-14 m/s^2, a negative K3 would place a stride of a_bar 24 (a first running stride still
    labelled walk) far shorter than the walk's; beyond the fitted range a_bar is held at its edge. Within the
    range, and for a positive K3 beyond it, the fitted slope applies."""
    rng = np.random.default_rng(5)
    cal = StepLengthCalibrator("eq15")
    for _ in range(40):
        a = float(rng.uniform(13.0, 14.0))
        cal.add("walk", StepFeatures(0.85, a, 30.0, 5.0), 1.35 + k3 * (a - 13.5) + float(rng.normal(scale=0.005)))
    cal.fit("walk")
    assert cal._fits["walk"]["coef"][3] == pytest.approx(k3, abs=0.03)
    edge = cal.predict("walk", StepFeatures(0.85, 14.0, 30.0, 5.0))[0]
    inside = cal.predict("walk", StepFeatures(0.85, 13.2, 30.0, 5.0))[0]
    vigorous = cal.predict("walk", StepFeatures(0.85, 24.0, 30.0, 5.0))[0]
    assert (edge - inside) * k3 > 0.0  # the fitted slope within the range
    if k3 < 0.0:
        assert vigorous == pytest.approx(edge)
    else:
        assert vigorous > edge + 1.0
