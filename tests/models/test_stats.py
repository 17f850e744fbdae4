from __future__ import annotations

import numpy as np
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from models.stats import median


@given(arrays(np.float64, st.integers(0, 40), elements=st.floats(-1e6, 1e6) | st.just(float("nan"))))
def test_median_is_numpy_median_bit_for_bit(x: np.ndarray) -> None:
    with np.errstate(all="ignore"):
        want = np.median(x) if x.size else np.nan
        got = median(x) if x.size else np.nan
    assert (np.isnan(want) and np.isnan(got)) or got == want
