"""KF II (004 eq. 17-21): convergence to a known deviation, wrap-around, gating, state."""

from __future__ import annotations

import math

import numpy as np
import pytest

from energy.codec import dumps, loads
from models.heading_deviation import HeadingDeviationKF, gamma_from_increment, wrap_angle


@pytest.mark.parametrize("dev_deg", [-170.0, -30.0, 0.0, 12.0, 179.0])
def test_converges_to_a_known_deviation(dev_deg: float) -> None:
    rng = np.random.default_rng(int(dev_deg) + 500)
    kf = HeadingDeviationKF()
    dev = math.radians(dev_deg)
    for i in range(60):
        psi = rng.uniform(-math.pi, math.pi)  # any walking direction
        gamma = psi + dev + rng.normal(scale=math.radians(4.0))
        kf.update(wrap_angle(gamma - psi), 1.0)
    assert kf.converged
    assert abs(wrap_angle(kf.deviation - dev)) < math.radians(2.0)
    assert math.sqrt(kf.variance) < math.radians(1.0)


def test_not_converged_after_few_steps() -> None:
    kf = HeadingDeviationKF()
    for _ in range(3):
        kf.update(0.2, 1.0)
    assert not kf.converged


def test_turn_outliers_are_gated() -> None:
    kf = HeadingDeviationKF()
    for _ in range(20):
        kf.update(math.radians(10.0), 1.0)
    assert not kf.update(math.radians(80.0), 1.0)  # a turn step mixes two directions
    assert kf.deviation == pytest.approx(math.radians(10.0), abs=math.radians(0.5))


def test_gamma_from_increment_is_clockwise_from_north() -> None:
    assert gamma_from_increment(1.0, 0.0) == pytest.approx(0.0)
    assert gamma_from_increment(0.0, 1.0) == pytest.approx(math.pi / 2)
    assert gamma_from_increment(-1.0, -1e-12) == pytest.approx(-math.pi, abs=1e-9)


def test_state_round_trip() -> None:
    kf = HeadingDeviationKF()
    for z in (0.1, 0.12, 0.09):
        kf.update(z, 1.1)
    back = HeadingDeviationKF.from_state(loads(dumps(kf.get_state())))
    kf.update(0.11, 1.0)
    back.update(0.11, 1.0)
    assert back.get_state()["x"].tolist() == kf.get_state()["x"].tolist()
    assert back.converged == kf.converged


def test_adaptive_r_learns_the_spread_and_keeps_the_estimate_stable() -> None:
    rng = np.random.default_rng(11)
    dev = math.radians(-20.0)
    kf = HeadingDeviationKF(adapt_r=0.1)
    fixed = HeadingDeviationKF(adapt_r=0.0)
    hist, hist_fixed = [], []
    for _ in range(300):
        z = wrap_angle(dev + rng.normal(scale=math.radians(10.0)))  # a noisy walker: 10 deg per stride
        kf.update(z, 1.0)
        fixed.update(z, 1.0)
        hist.append(kf.deviation)
        hist_fixed.append(fixed.deviation)
    assert math.degrees(math.sqrt(kf.r_var)) == pytest.approx(10.0, rel=0.35)
    late, late_fixed = np.array(hist[100:]), np.array(hist_fixed[100:])
    assert np.max(np.abs(late - dev)) < math.radians(2.0)
    assert np.ptp(late) < np.ptp(late_fixed)  # the fixed-R filter follows the noise more
    assert fixed.n_rejected > kf.n_rejected  # and gates good strides out as "turns"
    back = HeadingDeviationKF.from_state(loads(dumps(kf.get_state())))
    assert back.r_var == kf.r_var and back.adapt_r == kf.adapt_r
