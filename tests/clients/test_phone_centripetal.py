"""``clients.evaluation.phone_centripetal``: the accelerometer's turn statistics on synthetic steps, and the dev
trials' finding that decided against it (docs/phone.md "The accelerometer's turn")."""

from __future__ import annotations

import math

import numpy as np
import pytest

from clients.evaluation.phone_centripetal import CentripetalTable, centripetal_statistics, fit_scale


def _walk(noise_deg: float, scale: float = 2.5, seed: int = 5) -> CentripetalTable:
    """Straight stretches of 20 steps and 90-deg turns over two steps between them; the accelerometer's feature is the step's
    turn over ``scale`` plus white noise of ``noise_deg`` (after scaling); the compass is exact."""
    rng = np.random.default_rng(seed)
    g: list[float] = []
    for _ in range(60):
        g += list(rng.normal(0.0, math.radians(1.0), 20))
        side = rng.choice([-1.0, 1.0])
        g += [side * math.radians(45.0)] * 2
    g += list(rng.normal(0.0, math.radians(1.0), 20))
    gyro = np.asarray(g)
    n = len(gyro)
    feature = (gyro + rng.normal(0.0, math.radians(noise_deg), n)) / scale
    direction = np.cumsum(gyro)
    nan = np.full(n, math.nan)
    return CentripetalTable("synthetic", feature, gyro, direction, direction.copy(), np.arange(n), nan, nan, nan)


@pytest.mark.parametrize("noise_deg", [0.5, 3.0])
def test_scale_and_turn_errors_follow_the_simulated_noise(noise_deg: float) -> None:
    """The fitted scale is the simulated one; the per-step error is the noise; a turn's error (5 steps summed) is
    about sqrt(5) times it; the exact compass errs by nothing; every turn is detected by its first step."""
    t = _walk(noise_deg)
    assert fit_scale([t]) == pytest.approx(2.5, rel=0.05)
    st = centripetal_statistics([t])
    assert st["turns"] == 60
    assert st["err_straight_sd_deg"] == pytest.approx(noise_deg, rel=0.15)
    assert st["acc_turn_err_rms_deg"] == pytest.approx(noise_deg * math.sqrt(5.0), rel=0.3)
    assert st["compass_turn_err_rms_deg"] == pytest.approx(0.0, abs=1e-6)
    assert st["turns_missed"] == 0 and st["detect_step_median"] == 0


def test_the_accelerometer_turn_is_worse_than_the_compass_on_the_dev_trials(ipin_dir) -> None:  # type: ignore[no-untyped-def]
    """The finding behind not using it: per turn the accelerometer errs by several times the compass (the
    compass's error across a turn is what a gyroscope-off estimator takes), with the scale of the other routes."""
    from clients.evaluation.phone_centripetal import centripetal_table, out_of_route
    from clients.importers import load

    files = sorted(ipin_dir.glob("*.txt"))
    st = out_of_route([centripetal_table(load(f), 4.0) for f in files])
    assert st["turns"] >= 40
    assert st["acc_turn_err_rms_deg"] > 3.0 * st["compass_turn_err_rms_deg"]
