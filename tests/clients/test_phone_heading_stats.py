"""``clients.evaluation.phone_heading``: the compass's heading-dependent error statistic on synthetic steps."""

from __future__ import annotations

import math

import numpy as np
import pytest

from clients.evaluation.phone_heading import StepTable, heading_statistics


def _walk(k_turn: float, seed: int = 3) -> StepTable:
    """Straight stretches of 28 steps and 90-deg turns over two steps; the compass errs by white noise (2 deg)
    plus, at each turn, ``k_turn`` times the turn times one standard normal draw per turn (a heading-dependent
    error whose change across a turn scales with the turn)."""
    rng = np.random.default_rng(seed)
    inc, de = [], []
    for _ in range(100):
        inc += list(rng.normal(0.0, math.radians(1.0), 28))
        de += [0.0] * 28
        side, eps = rng.choice([-1.0, 1.0]), rng.normal()
        for _ in range(2):
            inc.append(side * math.radians(45.0))
            de.append(k_turn * math.radians(45.0) * eps)
    direction = np.cumsum(inc)
    compass = direction + np.cumsum(de) + rng.normal(0.0, math.radians(2.0), len(inc))
    n = len(inc)
    return StepTable("synthetic", direction, compass, np.ones(n, bool), np.full(n, math.radians(2.0)),
                     np.zeros(n), np.ones(n, bool), np.arange(n))


@pytest.mark.parametrize("k_turn", [0.0, 0.1, 0.2])
def test_deflection_per_turn_recovers_the_heading_dependent_error(k_turn: float) -> None:
    """The excess of the turning windows' compass change over the straight ones', per radian of turn, is the
    simulated deflection change per radian (to the robust SD's sampling error of 200 turning windows)."""
    st = heading_statistics([_walk(k_turn)])
    assert st["compass_change_straight_sd_deg"] == pytest.approx(2.0 * math.sqrt(2.0), rel=0.1)
    assert st["deflection_per_turn"] == pytest.approx(k_turn, abs=0.03 + 0.2 * k_turn)
