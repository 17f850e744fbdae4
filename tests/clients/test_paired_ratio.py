"""``clients.evaluation.ipin.paired_ratio``: the per-trial error ratio of a configuration over always-on, its
geometric mean and bootstrap interval (what `pednav eval ipin` reports next to the ratio of the medians)."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from clients.evaluation.ipin import paired_ratio

errors = st.lists(st.floats(0.1, 20.0), min_size=1, max_size=20)


@settings(max_examples=60, deadline=None)
@given(errors, st.floats(0.5, 2.0))
def test_a_constant_factor_is_found_exactly_with_no_spread(ref: list[float], factor: float) -> None:
    r = paired_ratio([factor * x for x in ref], ref)
    assert r["n"] == len(ref)
    assert r["geomean"] == pytest.approx(factor, rel=1e-9)
    assert r["ci90"] == pytest.approx([factor, factor], rel=1e-9)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.floats(0.1, 20.0), st.floats(0.1, 20.0)), min_size=2, max_size=20))
def test_interval_brackets_the_estimate_and_swapping_inverts_it(pairs: list[tuple[float, float]]) -> None:
    a, b = [p[0] for p in pairs], [p[1] for p in pairs]
    r, s = paired_ratio(a, b), paired_ratio(b, a)
    lo, hi = r["ci90"]
    assert lo <= hi
    assert min(x / y for x, y in pairs) * (1 - 1e-9) <= lo and hi <= max(x / y for x, y in pairs) * (1 + 1e-9)
    assert r["geomean"] * s["geomean"] == pytest.approx(1.0, rel=1e-9)
    assert paired_ratio(a, b) == r  # seeded: the same interval every time


def test_trial_difficulty_cancels_where_the_ratio_of_medians_does_not() -> None:
    """Easy and hard trials with a 10 % penalty, two trials' luck swapped: the paired ratio stays 1.10 (the
    swap's ratios multiply to 1.1^2), with a spread from the swapped pair."""
    ref = [1.0, 1.2, 4.0, 4.5, 1.1, 5.0]
    cfg = [1.1 * x for x in ref]
    cfg[2], cfg[3] = 1.1 * ref[3], 1.1 * ref[2]  # the two middle trials' luck swapped
    r = paired_ratio(cfg, ref)
    assert r["geomean"] == pytest.approx(1.1, rel=1e-12)
    assert r["ci90"][0] < 1.1 < r["ci90"][1]
    assert r["ci90"][1] - r["ci90"][0] > 0.0


def test_missing_and_bad_pairs_are_left_out() -> None:
    r = paired_ratio([2.0, None, math.nan, 0.0, 3.0], [1.0, 1.0, 1.0, 1.0, math.inf])  # type: ignore[list-item]
    assert r["n"] == 1 and r["geomean"] == pytest.approx(2.0)
    assert paired_ratio([], []) == {"geomean": None, "ci90": None, "n": 0}
    with pytest.raises(ValueError):
        paired_ratio([1.0, 2.0], [1.0])
