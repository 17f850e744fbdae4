"""Gait-DR pipeline: KF II turn gate, compass following in dead reckoning, state round trip."""

from __future__ import annotations

import math

import numpy as np
import pytest

from energy.codec import dumps, loads
from energy.gait_dr import GaitPipeline
from models.steps import StepEvent
from models.zupt_nav import Stance


def _pair(k: int, heading: float, walk_dir: float, d: float = 1.3, period: float = 1.2) -> tuple[Stance, StepEvent]:
    t = 1.0 + k * period
    delta = np.array([d * math.cos(walk_dir), d * math.sin(walk_dir), 0.0])
    st = Stance(t, t + 0.3, np.zeros(3), heading, delta, 1.5, 60, False)
    e = StepEvent(t, period, 1.0 / period, 12.0, 25.0, 5.0, (0.0, 0.0, -9.81), False, k)
    return st, e


def test_kf2_skips_turning_strides() -> None:
    gp = GaitPipeline(25.0)
    dev = math.radians(5.0)
    k = 0
    for _ in range(12):  # straight north: walking direction = heading + 5 deg
        gp.learn(*_pair(k, 0.0, dev), "walk")
        k += 1
    n = gp.kf2["walk"].n_updates
    # a 20 deg turn over one stride: the chord points half-way, gamma - psi = -5 deg (inside the innovation
    # gate, 10 deg from the deviation) but it is not an observation of the deviation
    gp.learn(*_pair(k, math.radians(20.0), math.radians(15.0)), "walk")
    k += 1
    assert gp.kf2["walk"].n_updates == n
    for _ in range(5):  # straight again in the new direction: observed again
        gp.learn(*_pair(k, math.radians(20.0), math.radians(20.0) + dev), "walk")
        k += 1
    assert gp.kf2["walk"].n_updates == n + 5
    assert gp.kf2["walk"].deviation == pytest.approx(dev, abs=math.radians(0.5))
    back = GaitPipeline.from_state(loads(dumps(gp.get_state())))
    assert back._prev_stance == gp._prev_stance


def test_conventional_pipeline_uses_the_generic_model_and_no_deviation() -> None:
    from models.step_length import StepFeatures, StepLengthCalibrator

    gps = {c: GaitPipeline(25.0, conventional=c) for c in (False, True)}
    for gp in gps.values():
        for k in range(12):  # a person with 1.6 m strides walking 20 deg off the sensor's x axis
            gp.learn(*_pair(k, 0.0, math.radians(20.0), d=1.6), "walk")
        gp.fit("walk")
        gp.start(np.zeros(3), 0.0)
    e = _pair(20, 0.0, 0.0)[1]
    generic = StepLengthCalibrator().predict("walk", StepFeatures(e.f_s, e.acc_mean, e.acc_max, e.acc_min))[0]
    assert gps[True].step_length(e, "walk")[0] == pytest.approx(generic)
    assert gps[False].step_length(e, "walk")[0] == pytest.approx(1.6, abs=0.05)
    assert gps[False].kf2["walk"].deviation == pytest.approx(math.radians(20.0), abs=math.radians(0.5))
    assert gps[True].dr is not None and not gps[True].dr.compensate
    assert GaitPipeline.from_state(loads(dumps(gps[True].get_state()))).conventional


def test_profile_fitted_with_the_older_step_model_form_is_refitted_on_load() -> None:
    """A profile whose walking fit predates K3 on the mean acceleration is refitted from its pairs."""
    src = GaitPipeline(25.0)
    for k in range(20):
        src.learn(*_pair(k, 0.0, 0.0, d=1.25 + 0.01 * (k % 3)), "walk")
    src.fit("walk")
    fresh = src.calibration_state()
    old = loads(dumps(fresh))
    del old["calibrator"]["form"]
    for v in old["calibrator"]["fits"].values():
        v["coef"][3] = -0.014  # a K3 fitted on the ~30 m/s^2 peak
    gp = GaitPipeline(25.0)
    gp.load_calibration("walk", old, 0.0, 1e-4)
    e = _pair(30, 0.0, 0.0)[1]
    assert gp.step_length(e, "walk") == src.step_length(e, "walk")
