"""Metrics of DESIGN.md on synthetic trajectories with known answers."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from clients.evaluation import metrics


def _rot(theta: float) -> np.ndarray:
    c, s = np.cos(theta), np.sin(theta)
    return np.array([[c, -s], [s, c]])


def _walk(n: int = 400, seed: int = 0) -> np.ndarray:
    """A wiggly 3-D foot trajectory [m] that travels several metres horizontally."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 1.0, n)
    x = 4.0 * t + 0.3 * np.sin(9 * t)
    y = 2.0 * t**2 + 0.2 * np.cos(7 * t) + 0.01 * rng.standard_normal(n)
    z = 0.05 * np.abs(np.sin(40 * t))
    return np.column_stack([x, y, z])


# ---------------------------------------------------------------------------------------------- ARMSE
@settings(max_examples=40, deadline=None)
@given(
    theta=st.floats(-np.pi, np.pi),
    shift=st.tuples(st.floats(-50, 50), st.floats(-50, 50), st.floats(-5, 5)),
    seed=st.integers(0, 1000),
)
def test_armse_invariant_to_vertical_rotation_and_translation(theta: float, shift: tuple, seed: int) -> None:
    truth = _walk(seed=seed)
    est = truth.copy()
    est[:, :2] = truth[:, :2] @ _rot(theta).T
    est += np.array(shift)
    assert metrics.armse(est, truth, dims=2, round_mm=False) == pytest.approx(0.0, abs=1e-9)
    assert metrics.armse(est, truth, dims=3, round_mm=False) == pytest.approx(0.0, abs=1e-9)


def test_armse_not_invariant_to_mirroring() -> None:
    truth = _walk()
    est = truth * np.array([1.0, -1.0, 1.0])
    assert metrics.armse(est, truth, round_mm=False) > 0.1


@pytest.mark.parametrize("k_reach", [5, 37, 120])
def test_alignment_index_keeps_the_authors_off_by_one(k_reach: int) -> None:
    n = 200
    est = np.zeros((n, 3))
    est[:, 0] = np.where(np.arange(n) >= k_reach, 1.0, 0.1)  # |est[k] - est[0]| >= 0.8 first at k = k_reach
    truth = est.copy()
    _, _, i = metrics.align_like_authors(est, truth)
    # d[k] = |est[k+1] - est[0]| reaches 0.8 first at k = k_reach - 1, and that sample is used
    assert i == k_reach - 1


def test_alignment_uses_the_off_by_one_sample_for_the_rotation() -> None:
    # the estimate is a straight line along +x; the truth turns 90 deg exactly at the sample after index i,
    # so aligning on sample i (the authors' off-by-one) keeps the angle 0 whereas sample i+1 would not
    n = 100
    est = np.zeros((n, 3))
    est[:, 0] = np.linspace(0.0, 2.0, n)
    reach = int(np.argmax(est[:, 0] >= 0.8))
    i = reach - 1
    truth = est.copy()
    truth[i + 1 :, 0] = est[i, 0]
    truth[i + 1 :, 1] = est[i + 1 :, 0] - est[i, 0]
    aligned, _, idx = metrics.align_like_authors(est, truth)
    assert idx == i
    np.testing.assert_allclose(aligned, est - est[0], atol=1e-12)


def test_alignment_falls_back_to_sample_300() -> None:
    n = 500
    truth = np.zeros((n, 3))
    truth[:, 1] = np.linspace(0, 0.5, n)
    est = np.zeros((n, 3))
    est[:, 0] = np.linspace(0, 0.5, n)  # never travels 0.8 m
    aligned, _, i = metrics.align_like_authors(est, truth)
    assert i == 300
    np.testing.assert_allclose(aligned[:, :2], truth[:, :2], atol=1e-12)


def test_armse_known_value_2d_and_3d() -> None:
    n = 1000
    truth = np.zeros((n, 3))
    truth[:, 0] = np.linspace(0.0, 5.0, n)
    est = truth.copy()
    late = np.arange(n) >= 500  # after the alignment sample (which is near sample 160)
    est[late, 1] += 0.3
    est[late, 2] += 0.6
    frac = late.mean()
    assert metrics.armse(est, truth, dims=2, round_mm=False) == pytest.approx(frac * 0.3 / np.sqrt(2))
    assert metrics.armse(est, truth, dims=3, round_mm=False) == pytest.approx(frac * np.sqrt((0.3**2 + 0.6**2) / 3))


def test_armse_is_rounded_to_the_millimetre() -> None:
    n = 300
    truth = np.zeros((n, 3))
    truth[:, 0] = np.linspace(0.0, 3.0, n)
    est = truth.copy()
    est[200:, 1] += 0.0123 * np.sqrt(2) * 3  # raw ARMSE = 100/300 * 0.0369 = 0.0123
    raw = metrics.armse(est, truth, round_mm=False)
    assert raw == pytest.approx(0.0123)
    assert metrics.armse(est, truth) == 0.012


@pytest.mark.parametrize(
    "bad",
    [np.zeros((10, 3)), np.full((5, 3), np.nan)],
)
def test_armse_rejects_mismatched_or_non_finite(bad: np.ndarray) -> None:
    with pytest.raises(ValueError):
        metrics.armse(bad, np.zeros((5, 3)))


# ---------------------------------------------------------------------------------------------- gdin
def _gcp_path(n: int = 40, seed: int = 1) -> np.ndarray:
    """Footprints of an L-shaped walk [m] in the ground-control frame, first at the origin."""
    rng = np.random.default_rng(seed)
    steps = np.vstack([np.tile([1.3, 0.0], (n // 2, 1)), np.tile([0.0, 1.2], (n - n // 2, 1))])
    steps += 0.05 * rng.standard_normal(steps.shape)
    return np.vstack([[0.0, 0.0], np.cumsum(steps, axis=0)])


def _as_engine_output(gcp: np.ndarray, theta: float, shift: np.ndarray) -> np.ndarray:
    """What a perfect right-handed NED solution reports: the mirrored GCP path, rotated and shifted."""
    mirrored = gcp * np.array([1.0, -1.0])
    return mirrored @ _rot(theta).T + shift


@settings(max_examples=40, deadline=None)
@given(theta=st.floats(-np.pi, np.pi), sx=st.floats(-100, 100), sy=st.floats(-100, 100))
def test_stride_errors_zero_for_a_perfect_mirrored_solution(theta: float, sx: float, sy: float) -> None:
    gcp = _gcp_path()
    est = _as_engine_output(gcp, theta, np.array([sx, sy]))
    r = metrics.stride_errors(est, gcp)
    assert r.mean_m == pytest.approx(0.0, abs=1e-9)
    assert r.rmse_m == pytest.approx(0.0, abs=1e-9)
    assert r.errors_m.shape == (gcp.shape[0] - 1,)


def test_stride_errors_need_the_y_negation() -> None:
    gcp = _gcp_path()
    est = gcp @ _rot(0.4).T  # NOT mirrored: the metric's y negation must make this wrong
    assert metrics.stride_errors(est, gcp).mean_m > 1.0


def test_stride_errors_known_value_after_the_fit_window() -> None:
    gcp = _gcp_path()
    est = _as_engine_output(gcp, 0.7, np.array([3.0, -2.0]))
    bad = np.arange(gcp.shape[0]) >= 10  # strides >= 10 off by 0.5 m, outside the 1-5 fit window
    off = _as_engine_output(np.array([[0.0, 0.5]]), 0.7, np.zeros(2))[0]
    est[bad] += off
    r = metrics.stride_errors(est, gcp)
    n = gcp.shape[0] - 1
    k = int(bad.sum())
    assert r.mean_m == pytest.approx(0.5 * k / n)
    assert r.rmse_m == pytest.approx(np.sqrt(0.25 * k / n))


def test_stride_rotation_is_fitted_on_strides_1_to_5_only() -> None:
    gcp = _gcp_path()
    est = _as_engine_output(gcp, -1.1, np.zeros(2))
    est[6:] = _as_engine_output(gcp[6:], -0.9, np.zeros(2))  # heading error after stride 5 must stay visible
    r = metrics.stride_errors(est, gcp)
    assert r.errors_m[:5] == pytest.approx(np.zeros(5), abs=1e-9)
    assert r.mean_m > 0.5


@settings(max_examples=30, deadline=None)
@given(theta=st.floats(-3.0, 3.0), seed=st.integers(0, 10_000))
def test_fit_rotation_is_the_least_squares_optimum(theta: float, seed: int) -> None:
    rng = np.random.default_rng(seed)
    dst = rng.normal(size=(5, 2)) * 3
    src = (dst + 0.3 * rng.normal(size=dst.shape)) @ _rot(-theta).T
    best = metrics.fit_rotation_2d(src, dst)

    def cost(a: float) -> float:
        return float(np.sum((src @ _rot(a).T - dst) ** 2))

    grid = np.linspace(-np.pi, np.pi, 7201)
    assert cost(best) <= min(cost(a) for a in grid) + 1e-9


def test_loop_closure_and_distance_error_known_values() -> None:
    square = np.array([[0, 0], [10, 0], [10, 10], [0, 10], [0, 0]], dtype=float)
    assert metrics.path_length_xy(square) == pytest.approx(40.0)
    assert metrics.loop_closure_pct([0, 0], [0.3, 0.4], 40.0) == pytest.approx(1.25)
    assert metrics.distance_error_pct(39.0, 40.0) == pytest.approx(2.5)
    assert metrics.distance_error_pct(41.0, 40.0) == pytest.approx(2.5)
    with pytest.raises(ValueError):
        metrics.loop_closure_pct([0, 0], [1, 1], 0.0)


def test_path_length_ignores_vertical() -> None:
    p = np.array([[0, 0, 0], [3, 4, 10], [3, 4, -10]], dtype=float)
    assert metrics.path_length_xy(p) == pytest.approx(5.0)


def test_summarise_skips_missing_values() -> None:
    s = metrics.summarise([1.0, None, 3.0, 8.0])
    assert s == {"mean": 4.0, "median": 3.0, "n": 3}
    assert metrics.summarise([None]) == {"mean": None, "median": None, "n": 0}


def test_segment_distance_error_counts_only_the_chosen_strides() -> None:
    truth = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [3.0, 0.0], [4.0, 0.0]])
    est = truth.copy()
    est[3:] += [0.5, 0.0]  # stride 2 -> 3 is 50 % long
    assert metrics.segment_distance_error_pct(est, truth, np.array([True, True, False, True])) == (0.0, 3)
    pct, n = metrics.segment_distance_error_pct(est, truth, np.array([False, False, True, True]))
    assert n == 2 and pct == pytest.approx(25.0)
    assert metrics.segment_distance_error_pct(est, truth, np.zeros(4, dtype=bool)) == (None, 0)
    with pytest.raises(ValueError, match="inside"):
        metrics.segment_distance_error_pct(est, truth, np.ones(3, dtype=bool))


@settings(max_examples=25, deadline=None)
@given(st.floats(-np.pi, np.pi), st.floats(-50.0, 50.0), st.floats(-50.0, 50.0))
def test_stride_length_errors_ignore_where_the_frames_start_and_point(theta: float, dx: float, dy: float) -> None:
    """A perfect estimate in another horizontal frame (NED, turned and shifted) has no stride errors; the truth's
    z is up, the estimate's d down."""
    truth = _walk(40)
    truth[:, 2] = np.linspace(0.0, 3.0, truth.shape[0])  # climbing
    est = np.column_stack([(truth[:, :2] @ _rot(theta).T) + [dx, dy], -truth[:, 2]])
    e = metrics.stride_length_errors(est, truth, min_length_m=0.05)
    assert e.n > 30
    assert e.mean_abs_m == pytest.approx(0.0, abs=1e-9) and e.height_rmse_m == pytest.approx(0.0, abs=1e-9)
    assert e.distance_err_pct == pytest.approx(0.0, abs=1e-9)


def test_stride_length_errors_of_a_long_and_flat_estimate() -> None:
    """Strides 10 % long and never climbing: every counted stride errs by a tenth of its length and by its
    climb; strides under ``min_length_m`` count only towards the distance."""
    truth = np.array([[0.0, 0, 0], [1.0, 0, 0.2], [2.0, 0, 0.4], [2.1, 0, 0.4], [3.1, 0, 0.6]])
    est = np.column_stack([truth[:, 0] * 1.1, truth[:, 1], np.zeros(5)])
    e = metrics.stride_length_errors(est, truth, min_length_m=0.3)
    assert e.n == 3
    assert e.mean_abs_m == pytest.approx(0.1) and e.rmse_m == pytest.approx(0.1)
    assert e.height_rmse_m == pytest.approx(0.2)
    assert e.distance_err_pct == pytest.approx(10.0)
    with pytest.raises(ValueError, match="same stances"):
        metrics.stride_length_errors(est[:4], truth)
