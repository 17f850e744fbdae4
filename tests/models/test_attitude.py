from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from models.attitude import align_at_rest, triad
from models.rotations import dcm_heading, rotvec_to_dcm

rotvecs = st.lists(st.floats(-3.1, 3.1), min_size=3, max_size=3).map(np.array)
G = np.array([0.0, 0.0, -9.8])  # specific force at rest in NED (points up)
FIELD = np.array([18.7, -3.4, 49.6])  # uT, NED


@settings(max_examples=60, deadline=None)  # the first example may include numba compilation
@given(rotvecs)
def test_alignment_with_field_recovers_any_mounting(phi):
    c = rotvec_to_dcm(phi)  # true body-to-NED
    est = align_at_rest(c.T @ G, c.T @ FIELD, FIELD)
    np.testing.assert_allclose(est, c, atol=1e-9)


@settings(max_examples=60, deadline=None)  # the first example may include numba compilation
@given(rotvecs)
def test_alignment_without_field_gets_tilt_and_zero_heading(phi):
    c = rotvec_to_dcm(phi)
    est = align_at_rest(c.T @ G)
    np.testing.assert_allclose(est @ (c.T @ G), G, atol=1e-9)  # gravity direction exact for any mounting
    if abs((c.T @ G)[0]) < 0.9 * 9.8:
        assert dcm_heading(est) == pytest.approx(0.0, abs=1e-9)


def test_triad_rejects_parallel_vectors():
    with pytest.raises(ValueError, match="parallel"):
        triad([1, 0, 0], [2, 0, 0], [0, 0, 1], [1, 0, 0])


def test_alignment_rejects_implausible_gravity():
    with pytest.raises(ValueError, match="9.8"):
        align_at_rest(np.array([0.0, 0.0, -1.0]))  # a batch in g, not m/s^2
