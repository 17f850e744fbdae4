"""The walking-heading estimator (models.heading) as a specification: what it does with each source."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from energy.codec import dumps, loads
from models.heading import CompassNoise, HeadingConfig, HeadingEstimator, wrap

CFG = HeadingConfig()
DEG = math.pi / 180.0


def _gyro_walk(est: HeadingEstimator, rng: np.random.Generator, n: int, offset: float, noise: float,
               heading: float = 0.0) -> None:
    for _ in range(n):
        est.predict_gyro(0.0)
        est.update_compass(heading + offset + rng.normal(scale=noise), noise**2, 0.0, learn=True)


def test_gyroscope_strides_teach_the_compass_offset_and_keep_the_heading() -> None:
    """While the gyroscope knows the heading, compass readings 40 deg off teach the offset, not the heading."""
    rng = np.random.default_rng(1)
    est = HeadingEstimator(CFG)
    est.start(0.3)
    _gyro_walk(est, rng, 30, 40 * DEG, 2 * DEG, heading=0.3)
    assert est.heading == pytest.approx(0.3, abs=1 * DEG)
    assert wrap(est.offset - 40 * DEG) == pytest.approx(0.0, abs=2 * DEG)
    assert est.std < 2 * DEG


def test_gyroscope_off_straight_walk_averages_compass_noise() -> None:
    rng = np.random.default_rng(2)
    est = HeadingEstimator(CFG)
    est.start(0.0)
    est.set_offset_prior(0.0, 1 * DEG)
    noise = 10 * DEG
    errs = []
    for _ in range(80):
        est.predict_free()
        est.update_compass(rng.normal(scale=noise), noise**2, 0.0)
        errs.append(est.heading)
    assert float(np.std(errs)) < 0.6 * noise


@pytest.mark.parametrize("turn_deg", [45.0, 90.0, -90.0, 180.0])
def test_a_turn_seen_by_a_clean_compass_is_taken_within_two_strides(turn_deg: float) -> None:
    rng = np.random.default_rng(3)
    est = HeadingEstimator(CFG)
    est.start(0.0)
    est.set_offset_prior(0.0, 1 * DEG)
    for _ in range(5):
        est.predict_free()
        est.update_compass(rng.normal(scale=2 * DEG), (2 * DEG) ** 2, 0.0)
    for _ in range(2):
        est.predict_free()
        est.update_compass(turn_deg * DEG + rng.normal(scale=2 * DEG), (2 * DEG) ** 2, 0.0)
    assert abs(wrap(est.heading - turn_deg * DEG)) < 5 * DEG


def test_without_a_compass_the_uncertainty_grows_and_all_of_it_persists() -> None:
    est = HeadingEstimator(CFG)
    est.start(0.0)
    stds = []
    for _ in range(5):
        est.predict_free()
        stds.append(est.std)
    assert np.all(np.diff(stds) > 0) and est.heading == 0.0
    total, persistent = est.forecast(None)
    assert total == persistent > stds[-1]


def test_one_wild_reading_is_undone_by_the_next_consistent_ones() -> None:
    """Indoors single stances read up to 150 deg off (gdin); one stride cannot tell such a reading from a U-turn,
    the next ones can: back within a few degrees after two readings that agree with the earlier ones."""
    est = HeadingEstimator(CFG)
    est.start(0.0)
    est.set_offset_prior(0.0, 1 * DEG)
    for _ in range(10):
        est.predict_free()
        est.update_compass(0.0, (5 * DEG) ** 2, 0.0)
    est.predict_free()
    est.update_compass(150 * DEG, (5 * DEG) ** 2, 0.0)
    for _ in range(2):
        est.predict_free()
        est.update_compass(0.0, (5 * DEG) ** 2, 0.0)
    assert abs(est.heading) < 5 * DEG


def test_the_place_noise_is_learned_from_gyroscope_known_strides() -> None:
    """Readings declared 1 deg but scattering by 15 deg (an indoor field of the Earth's shape): the unexplained
    variance is estimated from the innovations of strides whose heading the gyroscope knew."""
    rng = np.random.default_rng(4)
    est = HeadingEstimator(CFG)
    est.start(0.0)
    est.set_offset_prior(0.0, 1 * DEG)
    for _ in range(CFG.consistency_window * 3):
        est.predict_gyro(0.0)
        est.update_compass(rng.normal(scale=15 * DEG), (1 * DEG) ** 2, 0.0, learn=True)
    assert math.sqrt(est.noise.place_var) == pytest.approx(15 * DEG, rel=0.5)


def test_a_field_that_changed_shape_is_a_deflection_not_a_turn() -> None:
    """The same 30-deg compass swing: with the field's shape unchanged it is the foot turning, with a change of
    shape that could turn the compass by 30 deg it is mostly the field."""
    out = {}
    for change in (0.0, 30 * DEG):
        est = HeadingEstimator(CFG)
        est.start(0.0)
        est.set_offset_prior(0.0, 1 * DEG)
        est.predict_free(field_change=change)
        est.update_compass(30 * DEG, (2 * DEG) ** 2, change)
        out[change] = est.heading
    assert out[0.0] == pytest.approx(30 * DEG, abs=4 * DEG)
    assert abs(out[30 * DEG]) < 15 * DEG


@pytest.mark.parametrize("off_deg, snapped", [(8.0, True), (30.0, False)])
def test_dominant_directions_pull_a_nearby_heading_only(off_deg: float, snapped: bool) -> None:
    est = HeadingEstimator(CFG)
    est.start(off_deg * DEG, (10 * DEG) ** 2)
    est.update_dominant(90 * DEG, 3 * DEG, 15 * DEG)
    assert (abs(est.heading) < 3 * DEG) == snapped


def test_field_sigma_grows_as_the_horizontal_field_weakens() -> None:
    strong = CompassNoise.field_sigma(40.0, 22.0, 37.0, 22.0)
    weak = CompassNoise.field_sigma(40.0, 4.0, 37.0, 4.0)
    assert weak > 4 * strong > 0


@pytest.mark.parametrize("name, value", [("p_turn_start", 1.0), ("straight_sigma_rad", -1.0),
                                         ("consistency_window", 0), ("outlier_sigmas", float("nan"))])
def test_bad_configuration_is_refused_by_name(name: str, value: float) -> None:
    with pytest.raises(ValueError, match=name):
        HeadingConfig(**{name: value})


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(1, 20), cut=st.integers(0, 20))
def test_state_round_trip_continues_identically(seed: int, n: int, cut: int) -> None:
    rng = np.random.default_rng(seed)
    steps = [(rng.uniform(-0.5, 0.5), bool(rng.integers(2)), rng.normal(scale=0.3), rng.uniform(0, 0.1))
             for _ in range(n)]
    a = HeadingEstimator(CFG)
    a.start(0.1)
    b = None
    for k, (delta, gyro, z, ch) in enumerate(steps):
        if k == min(cut, n - 1):
            b = HeadingEstimator.from_state(CFG, loads(dumps(a.get_state())))
        for est in (a, b) if b is not None else (a,):
            if gyro:
                est.predict_gyro(delta, ch)
            else:
                est.predict_free(field_change=ch)
            est.update_compass(z, (3 * DEG) ** 2, ch, learn=gyro)
    assert b is not None
    assert np.array_equal(a.x, b.x) and np.array_equal(a.p, b.p) and np.array_equal(a.mu, b.mu)
    assert a.forecast((3 * DEG) ** 2) == b.forecast((3 * DEG) ** 2)


@settings(max_examples=40, deadline=None)
@given(theta=st.floats(-3.0, 3.0), z=st.floats(-3.0, 3.0), prior_deg=st.floats(1.0, 60.0), obs_deg=st.floats(0.5, 60.0))
def test_an_absolute_heading_moves_theta_towards_it_by_the_variances_and_leaves_the_offsets(
        theta: float, z: float, prior_deg: float, obs_deg: float) -> None:
    """update_heading: another filter's heading (a phone's MARG filter) is a Kalman observation of theta alone."""
    est = HeadingEstimator(CFG)
    est.start(theta, (prior_deg * DEG) ** 2)
    est.set_offset_prior(0.2, 1 * DEG)
    est.update_heading(z, (obs_deg * DEG) ** 2)
    k = prior_deg**2 / (prior_deg**2 + obs_deg**2)
    assert wrap(est.heading - theta) == pytest.approx(k * wrap(z - theta), abs=1e-9)
    assert est.variance == pytest.approx((1 - k) * (prior_deg * DEG) ** 2, rel=1e-9)
    assert est.offset == pytest.approx(0.2, abs=1e-12)


def test_an_absolute_heading_weighs_the_motion_models() -> None:
    """After a gyroscope-off stride, a heading far from the straight model's is evidence of a turn."""
    est = HeadingEstimator(CFG)
    est.start(0.0, (1 * DEG) ** 2)
    est.predict_free()
    est.update_heading(0.0, (2 * DEG) ** 2)
    assert est.mu[1] < 0.5
    est.predict_free()
    est.update_heading(60 * DEG, (2 * DEG) ** 2)
    assert est.mu[1] > 0.9 and abs(wrap(est.heading - 60 * DEG)) < 3 * DEG


def test_mixture_moments_kernel_equals_the_numpy_form() -> None:
    """The compiled moment matching of the IMM gives what the numpy form gave, to the bit (angles near the wrap,
    equal means, degenerate weights)."""
    from models.heading import HeadingEstimator, _wrap_all

    def reference(w, x, p, ref):  # type: ignore[no-untyped-def]
        d = _wrap_all(x - ref[None, :])
        m = w @ d
        cov = np.zeros_like(p[0])
        for i in range(len(w)):
            e = d[i] - m
            cov += w[i] * (p[i] + np.outer(e, e))
        return _wrap_all(ref + m), cov

    rng = np.random.default_rng(3)
    for k in range(3000):
        w = rng.random(2) if k % 7 else np.array([1.0, 0.0])
        w = w / w.sum()
        x = rng.uniform(-np.pi, np.pi, (2, 3)) if k % 3 else np.array([[3.1, 0.2, 0.0], [-3.1, 0.1, 0.0]])
        if k % 5 == 0:
            x[1] = x[0]
        a = rng.normal(size=(2, 3, 3))
        p = a @ a.transpose(0, 2, 1)
        ref = x[k % 2]
        mean, cov = HeadingEstimator._moments(w, x, p, ref)
        m0, c0 = reference(w, x, p, ref)
        assert mean.tobytes() == m0.tobytes() and cov.tobytes() == c0.tobytes()


def test_imm_mixing_kernel_equals_the_numpy_form() -> None:
    """The compiled IMM interaction step gives the numpy form's mixed starts and probabilities to the bit."""
    from models.heading import _mix_kernel

    rng = np.random.default_rng(5)
    for k in range(2000):
        mu = rng.random(2) if k % 11 else np.array([1.0, 0.0])
        mu = mu / mu.sum()
        a, b = rng.random(2) * 0.3
        pi = np.array([[1 - a, a], [1 - b, b]])
        x = rng.uniform(-np.pi, np.pi, (2, 3))
        q = rng.normal(size=(2, 3, 3))
        p = q @ q.transpose(0, 2, 1)
        # mu pi summed in index order, as the kernel does (a BLAS matmul fuses the multiply-add on some hosts)
        cbar = mu[0] * pi[0] + mu[1] * pi[1]
        w = (pi * mu[:, None]) / np.maximum(cbar, 1e-300)[None, :]
        ref = [HeadingEstimator._moments(w[:, j], x, p, x[j]) for j in range(2)]
        x0, p0, cb = np.empty_like(x), np.empty_like(p), np.empty(2)
        _mix_kernel(mu, pi, x, p, x0, p0, cb)
        assert cb.tobytes() == cbar.tobytes()
        assert x0.tobytes() == np.array([r[0] for r in ref]).tobytes()
        assert p0.tobytes() == np.array([r[1] for r in ref]).tobytes()
