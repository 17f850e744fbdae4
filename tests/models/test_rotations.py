from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from models import rotations as r

angles = st.tuples(
    st.floats(-np.pi + 1e-3, np.pi - 1e-3), st.floats(-np.pi / 2 + 1e-3, np.pi / 2 - 1e-3), st.floats(-np.pi + 1e-3, np.pi - 1e-3)
)
rotvecs = st.lists(st.floats(-3.0, 3.0), min_size=3, max_size=3).map(np.array)


@given(angles)
def test_euler_dcm_round_trip(a):
    c = r.euler_to_dcm(*a)
    np.testing.assert_allclose(c @ c.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(c) == pytest.approx(1.0)
    np.testing.assert_allclose(r.dcm_to_euler(c), a, atol=1e-9)


@given(angles)
def test_quat_dcm_round_trip(a):
    c = r.euler_to_dcm(*a)
    q = r.dcm_to_quat(c)
    assert q[0] >= 0 and np.linalg.norm(q) == pytest.approx(1.0)
    np.testing.assert_allclose(r.quat_to_dcm(q), c, atol=1e-12)


@given(rotvecs)
def test_rotvec_exp_log_round_trip(phi):
    if np.linalg.norm(phi) >= np.pi:
        phi = phi / np.linalg.norm(phi) * (np.pi - 1e-3)
    np.testing.assert_allclose(r.quat_to_rotvec(r.rotvec_to_quat(phi)), phi, atol=1e-9)
    # Rodrigues agrees with the matrix exponential series
    k = r.skew(phi)
    expm = np.eye(3)
    term = np.eye(3)
    for n in range(1, 40):
        term = term @ k / n
        expm = expm + term
    np.testing.assert_allclose(r.rotvec_to_dcm(phi), expm, atol=1e-9)


@given(rotvecs, rotvecs)
def test_quat_product_is_dcm_product(a, b):
    qa, qb = r.rotvec_to_quat(a), r.rotvec_to_quat(b)
    np.testing.assert_allclose(r.quat_to_dcm(r.quat_multiply(qa, qb)), r.quat_to_dcm(qa) @ r.quat_to_dcm(qb), atol=1e-12)
    np.testing.assert_allclose(r.quat_to_dcm(r.quat_conjugate(qa)), r.quat_to_dcm(qa).T, atol=1e-12)


@pytest.mark.parametrize("yaw", [-3.0, -1.0, 0.0, 0.5, 2.9])
def test_heading_is_clockwise_from_north(yaw):
    c = r.euler_to_dcm(0.0, 0.0, yaw)
    assert r.dcm_heading(c) == pytest.approx(yaw)
    # body x axis at yaw 90 deg points east in NED
    if yaw == 0.5:
        np.testing.assert_allclose(r.euler_to_dcm(0, 0, np.pi / 2) @ [1, 0, 0], [0, 1, 0], atol=1e-12)


def test_zero_quaternion_rejected():
    with pytest.raises(ValueError, match="norm"):
        r.quat_normalize(np.zeros(4))
