"""Gait dead reckoning (004 eq. 14, 16): geometry, compensation, state."""

from __future__ import annotations

import math

import numpy as np
import pytest

from energy.codec import dumps, loads
from models.gait_pdr import GaitDeadReckoner


def test_square_walk_closes() -> None:
    dr = GaitDeadReckoner()
    for k in range(40):
        dr.step(float(k), 1.25, heading=(k // 10) * math.pi / 2)
    assert dr.position[:2] == pytest.approx([0.0, 0.0], abs=1e-9)
    assert dr.distance == pytest.approx(50.0)


@pytest.mark.parametrize("dev_deg", [-25.0, 8.0, 170.0])
def test_deviation_rotates_the_walking_direction(dev_deg: float) -> None:
    dev = math.radians(dev_deg)
    comp, conv = GaitDeadReckoner(compensate=True), GaitDeadReckoner(compensate=False)
    for k in range(10):
        s = comp.step(float(k), 1.0, heading=0.0, deviation=dev)
        conv.step(float(k), 1.0, heading=0.0, deviation=dev)
    assert comp.position[:2] == pytest.approx([10 * math.cos(dev), 10 * math.sin(dev)])
    assert conv.position[:2] == pytest.approx([10.0, 0.0])  # conventional PDR ignores KF II
    assert s.direction == pytest.approx(math.remainder(dev, 2 * math.pi))


def test_state_round_trip_mid_walk() -> None:
    a = GaitDeadReckoner(np.array([1.0, 2.0, -0.5]))
    a.step(0.0, 1.3, 0.4, 0.1, "walk")
    b = GaitDeadReckoner.from_state(loads(dumps(a.get_state())))
    assert a.step(1.0, 1.2, 0.5, 0.1) == b.step(1.0, 1.2, 0.5, 0.1)
    assert b.position[2] == -0.5
