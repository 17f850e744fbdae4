from __future__ import annotations

import numpy as np
import pytest

from models.magnetic import field_undisturbed, inclination, reference_from_rest, wmm_reference
from models.rotations import euler_to_dcm


def test_wmm_toronto_in_microtesla():
    f = wmm_reference(43.66, -79.40)
    assert 50 < np.linalg.norm(f) < 60  # Toronto ~ 54 uT
    assert np.degrees(inclination(f)) == pytest.approx(69.5, abs=2.0)


def test_reference_from_rest_round_trip():
    c = euler_to_dcm(0.4, 0.1, -2.0)
    ref = np.array([20.0, 1.0, 45.0])
    np.testing.assert_allclose(reference_from_rest(c.T @ ref, c), ref, atol=1e-12)
    with pytest.raises(ValueError, match="5-200 uT"):
        reference_from_rest(np.array([0.2, 0.1, 0.3]), c)  # gauss, not uT


@pytest.mark.parametrize(
    "field,expected",
    [([20.0, 0.0, 45.0], True), ([20.0, 15.0, 45.0], True), ([30.0, 0.0, 45.0], False), ([20.0, 0.0, 40.0], False)],
)
def test_disturbance_test(field, expected):
    ref = np.array([20.0, 0.0, 45.0])
    # horizontal rotation keeps magnitude and dip but not heading: still "undisturbed"
    if expected and field[1] != 0:
        field = np.array([np.hypot(20.0, 0.0) * np.cos(0.6), 20.0 * np.sin(0.6), 45.0])
    assert bool(field_undisturbed(np.array(field), ref)) is expected
