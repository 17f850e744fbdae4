from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from models.rotations import euler_to_dcm
from models.zupt_kf import heading_row, predict_covariance, transition_matrix, update_heading, update_zupt


def random_spd(rng, n=15):
    a = rng.normal(size=(n, n))
    return a @ a.T + n * np.eye(n)


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 10_000))
def test_sparse_prediction_equals_dense(seed):
    rng = np.random.default_rng(seed)
    P = random_spd(rng) * 1e-3
    c = euler_to_dcm(*rng.uniform(-1, 1, 3))
    fn = rng.normal(0, 5, 3)
    dt = 0.005
    q = (1e-3, 2e-6, 1e-6, 1e-9)
    F = transition_matrix(c, fn, dt)
    Q = np.diag(np.repeat([0.0, q[0], q[1], q[2], q[3]], 3)) * dt
    expected = F @ P @ F.T + Q
    predict_covariance(P, c, fn, dt, *q)
    np.testing.assert_allclose(P, expected, rtol=1e-10, atol=1e-14)


def test_zupt_update_shrinks_velocity_uncertainty_and_keeps_symmetry():
    rng = np.random.default_rng(3)
    P = random_spd(rng) * 1e-2
    dx = np.zeros(15)
    before = np.trace(P[3:6, 3:6])
    update_zupt(P, dx, np.array([0.1, -0.2, 0.05]), 0.01)
    assert np.trace(P[3:6, 3:6]) < 0.1 * before
    np.testing.assert_allclose(P, P.T, atol=1e-12)
    assert np.all(np.linalg.eigvalsh(P) > 0)
    # velocity error estimate pulls towards -v_est
    assert dx[3] < 0 and dx[4] > 0


def test_heading_row_matches_numerical_derivative():
    c = euler_to_dcm(0.3, -0.2, 1.1)
    h = heading_row(c)
    eps = 1e-7
    for k in range(3):
        phi = np.zeros(3)
        phi[k] = eps
        skew = np.array([[0, -phi[2], phi[1]], [phi[2], 0, -phi[0]], [-phi[1], phi[0], 0]])
        c2 = (np.eye(3) + skew) @ c
        d = (np.arctan2(c2[1, 0], c2[0, 0]) - np.arctan2(c[1, 0], c[0, 0])) / eps
        assert h[6 + k] == pytest.approx(d, rel=1e-4, abs=1e-6)


def test_heading_gate_rejects_outlier():
    P = np.eye(15) * 1e-4
    dx = np.zeros(15)
    assert not update_heading(P, dx, np.eye(3), 1.0, 0.05, gate_sigma=3.0)
    assert np.all(dx == 0)
    assert update_heading(P, dx, np.eye(3), 0.01, 0.05, gate_sigma=3.0)
    assert dx[8] > 0
