from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from models.rotations import euler_to_dcm, quat_to_dcm, rotvec_to_dcm
from models.strapdown import GRAVITY, integrate


@pytest.mark.parametrize("rate_hz", [25.0, 100.0, 400.0])
@pytest.mark.parametrize("w", [[0.0, 0.0, 2.0], [1.5, -2.0, 0.7]])
def test_constant_rotation_exact_attitude(rate_hz, w):
    w = np.array(w)
    t = np.arange(0, 5.0, 1.0 / rate_hz)
    n = t.size
    gyr = np.tile(w, (n, 1))
    acc = np.zeros((n, 3))
    q, _, _ = integrate(t, acc, gyr, np.array([1.0, 0, 0, 0]))
    np.testing.assert_allclose(quat_to_dcm(q[-1]), rotvec_to_dcm(w * t[-1]), atol=1e-9)


def test_first_order_update_diverges_at_low_rate():
    # coning-free but fast rotation about a fixed tilted axis at 50 Hz: the first-order update loses accuracy
    w = np.array([3.0, -4.0, 5.0])
    t = np.arange(0, 4.0, 1 / 50)
    gyr = np.tile(w, (t.size, 1))
    truth = rotvec_to_dcm(w * t[-1])
    q_ex, _, _ = integrate(t, np.zeros_like(gyr), gyr, np.array([1.0, 0, 0, 0]), exact=True)
    q_fo, _, _ = integrate(t, np.zeros_like(gyr), gyr, np.array([1.0, 0, 0, 0]), exact=False)
    err_ex = np.linalg.norm(quat_to_dcm(q_ex[-1]) - truth)
    err_fo = np.linalg.norm(quat_to_dcm(q_fo[-1]) - truth)
    assert err_ex < 1e-9
    assert err_fo > 1e-2


def test_rest_does_not_drift_beyond_noise():
    rng = np.random.default_rng(1)
    c = euler_to_dcm(0.2, -0.4, 1.0)
    t = np.arange(0, 10.0, 1 / 200)
    acc = np.tile(c.T @ [0, 0, -GRAVITY], (t.size, 1)) + rng.normal(0, 0.01, (t.size, 3))
    gyr = rng.normal(0, 1e-4, (t.size, 3))
    from models.rotations import dcm_to_quat

    _, v, p = integrate(t, acc, gyr, dcm_to_quat(c))
    # white noise 0.01 m/s^2 at 200 Hz over 10 s: velocity random walk ~ 0.01*sqrt(10/200) ~ 2 mm/s
    assert np.linalg.norm(v[-1]) < 0.02
    assert np.linalg.norm(p[-1]) < 0.1


def test_non_monotonic_time_rejected():
    with pytest.raises(ValueError, match="increasing"):
        integrate(np.array([0.0, 0.1, 0.05]), np.zeros((3, 3)), np.zeros((3, 3)), np.array([1.0, 0, 0, 0]))


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(2, 300), rate=st.sampled_from([25.0, 100.0, 200.0]))
def test_compiled_integration_equals_the_numpy_reference(seed: int, n: int, rate: float) -> None:
    """The compiled kernel integrate() runs is the reference strapdown_step sample by sample, to rounding."""
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(0.5, 1.5, n)) / rate
    acc = rng.normal(0.0, 5.0, (n, 3)) + np.array([0.0, 0.0, -GRAVITY])
    gyr = rng.normal(0.0, 3.0, (n, 3))
    q0 = rng.normal(size=4)
    q0 /= np.linalg.norm(q0)
    v0, p0 = rng.normal(size=3), rng.normal(size=3)
    fast = integrate(t, acc, gyr, q0, v0, p0)
    ref = integrate(t, acc, gyr, q0, v0, p0, compiled=False)
    for a, b in zip(fast, ref):
        np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-9)
