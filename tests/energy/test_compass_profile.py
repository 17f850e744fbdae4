"""The compass a profile hands on, and a returning user's compass, on a realistic magnetometer (hard and soft
iron of the device, clients.synth.LSM9DS1_SHOE) over the synthetic mixed day."""

from __future__ import annotations

import math

import numpy as np
import pytest

from clients.synth import EARTH_FIELD_UT, LSM9DS1_SHOE, synthesize
from energy.device import replay
from energy.engine import Engine
from models.compass import MagCalibrator


@pytest.fixture(scope="module")
def first_day() -> tuple[Engine, dict]:
    eng = Engine(mode="auto")
    replay(eng, synthesize("mixed-day", seed=1003, errors=LSM9DS1_SHOE).batch, batch_seconds=None)
    return eng, eng.profile_dict()


def test_profile_compass_is_the_sensors_hard_iron_fitted_on_the_whole_day(first_day) -> None:
    """44 uT of hard iron (14, -22, 35) recovered to 1.5 uT, the vertical too (level stances alone cannot tell
    it from the field's vertical part: the swings can). Every calibrated behaviour hands on the same compass,
    fitted on all of the day's calibration stances (a walk calibrated 70 s into the day stored one fitted on
    its first 20 stances, all heading 0-90 deg)."""
    eng, prof = first_day
    compasses = [cal["step_model"]["compass"] for cal in prof["behaviours"].values() if cal["calibrated"]]
    assert len(compasses) == 2  # walk and run
    cal = MagCalibrator.from_state(compasses[0])
    assert all(np.array_equal(c["b"], compasses[0]["b"]) for c in compasses)
    assert cal.ready and cal.trusted and cal.n_stances == eng._gait.mag.n_stances and cal.n_swing > 300
    assert cal.b == pytest.approx(LSM9DS1_SHOE.mag_hard_iron_ut, abs=1.5)


def test_returning_users_compass_follows_the_true_heading(first_day) -> None:
    """The next day (another accelerometer turn-on offset, the same sensor): on straight strides outside the
    steel, Gait-DR's heading with the gyroscope off stays within a few degrees of the truth. Turn strides are
    left out (their heading is the chord's, half-way through the turn) and so is the steel (held headings)."""
    _, prof = first_day
    rec = synthesize("mixed-day", seed=3, errors=LSM9DS1_SHOE)
    res = replay(Engine("auto", profile=prof), rec.batch, batch_seconds=None)
    t_ns, yaw = rec.truth.t_ns, rec.truth.extra["heading_rad"]
    steel = rec.truth.extra["steel_intervals"]
    errs, prev = [], None
    for p in res.positions:
        i = min(int(np.searchsorted(t_ns, p.t_ns)), len(t_ns) - 1)
        t = (p.t_ns - t_ns[0]) / 1e9
        straight = prev is not None and yaw[i] == yaw[prev]
        prev = i
        if p.mode == "pdr" and straight and not any(a - 5.0 <= t <= b + 5.0 for a, b in steel):
            errs.append(abs(math.remainder(p.heading_rad - yaw[i], 2 * math.pi)))
    e = np.degrees(errs)
    assert len(e) > 80
    # (the branch point: median 2.41, 95 % 4.63 deg with this sensor; 1.42 / 2.79 with an iron-free one)
    assert np.median(e) < 1.0 and np.percentile(e, 95) < 2.5


@pytest.mark.parametrize("seed", [16, 18])
def test_steel_edges_do_not_pull_the_trusted_compass_fit(seed: int) -> None:
    """Stances at the edge of a steel disturbance pass the magnitude/dip gate; on these two days they were taken
    into the trusted compass fit and pulled its field 7.7 and 8.5 % short of the Earth's and its hard iron to 4.9
    and 6.1 uT (the sensor has none), so that a clean field read 3.5 % off at headings the fit had not seen and
    the compass no longer led after the second steel zone (seed 16: mean error 4.6 m). Only stances whose field
    is settled (the Earth's within its noise) join a trusted fit."""
    eng = Engine(mode="auto")
    replay(eng, synthesize("mixed-day", seed=seed).batch, batch_seconds=None)
    cal = eng._gait.mag
    assert cal.ready and cal.trusted
    assert np.linalg.norm(cal.m_n) == pytest.approx(np.linalg.norm(EARTH_FIELD_UT), rel=0.02)
    assert np.linalg.norm(cal.b) < 1.5
