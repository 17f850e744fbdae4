"""A ZUPT-KF segment turned to a trusted compass that disagrees with it consistently on the Earth's field."""

from __future__ import annotations

import math

import numpy as np
import pytest

from energy.engine import _REANCHOR_STANCES, Engine
from models.compass import CompassFollower
from models.zupt_nav import Stance


class _Gait:
    """The parts of GaitPipeline the re-anchoring reads: the compass at a stance, its noise and the follower."""

    def __init__(self, readings: list[float | None], sigma: float = math.radians(2.0)) -> None:
        self.readings = list(readings)
        self.sigma = sigma
        self.follower = CompassFollower()
        self.follower.gyro_ref = (0.1, 0.2)

    def earth_compass(self, e: object) -> float | None:
        return self.readings.pop(0)

    def _compass_sigma(self) -> float:
        return self.sigma


def _stance(k: int, heading: float) -> Stance:
    """The k-th stance of a straight walk along ``heading`` [rad], 1.4-m strides, in the segment's frame."""
    p = np.array([1.4 * k * math.cos(heading), 1.4 * k * math.sin(heading), 0.0])
    d = np.array([1.4 * math.cos(heading), 1.4 * math.sin(heading), 0.0])
    return Stance(float(k), k + 0.3, p, heading, d, 1.5, 60, False)


def _walk(readings_deg: list[float | None], heading: float = 0.3) -> tuple[Engine, list[Stance], _Gait]:
    """Stances of a walk through :meth:`Engine._compass_reanchor` with the compass reading ``heading`` + these
    offsets [deg] (None: no Earth-field compass there); the engine keeps its own Gait-DR pipeline afterwards."""
    eng = Engine(mode="auto")
    own, stub = eng._gait, _Gait([None if r is None else heading + math.radians(r) for r in readings_deg])
    eng._gait = stub  # type: ignore[assignment]
    eng._offset = np.array([5.0, -2.0, 0.0])
    out = []
    for k in range(len(readings_deg)):
        st = eng._session_stance(_stance(k, heading))
        out.append(eng._compass_reanchor(st, object()))
    eng._gait = own
    return eng, out, stub


def test_a_consistent_compass_offset_turns_the_segment_about_the_stance_it_is_found_at() -> None:
    """Three stances whose compass reads 40 deg from the ZUPT-KF heading (beyond the 10-deg tolerance, within half
    of it of each other): the third is turned by their mean, its position stays, and the segment's later stances
    continue from it in the turned direction; the follower's gyroscope test starts again."""
    offs = [40.0, 41.0, 39.5]
    eng, out, gait = _walk(offs + [None])
    mean = math.radians(np.mean(offs))
    assert _REANCHOR_STANCES == 3
    assert [s.heading for s in out[:2]] == pytest.approx([0.3, 0.3])
    assert out[2].heading == pytest.approx(0.3 + mean)
    assert out[2].position == pytest.approx(np.array([5.0 + 2.8 * math.cos(0.3), -2.0 + 2.8 * math.sin(0.3), 0.0]))
    assert math.atan2(out[2].delta[1], out[2].delta[0]) == pytest.approx(0.3 + mean)
    assert eng._yaw == pytest.approx(mean) and eng._head == pytest.approx(0.3 + mean)
    step = out[3].position - out[2].position
    assert np.hypot(step[0], step[1]) == pytest.approx(1.4)
    assert math.atan2(step[1], step[0]) == pytest.approx(0.3 + mean)
    assert out[3].heading == pytest.approx(0.3 + mean)
    assert gait.follower.gyro_ref is None
    assert eng._compass_offsets == []  # a later turn needs three stances of its own
    back = Engine.from_state(eng.get_state())
    assert back._compass_offsets == eng._compass_offsets and back._yaw == pytest.approx(eng._yaw)


@pytest.mark.parametrize("offs", [
    [5.0, 6.0, 5.5],  # within the tolerance: the compass's own noise
    [30.0, 45.0, 60.0],  # not one offset: a field that steel turns
    [40.0, None, 41.0, 39.0],  # a stance without an Earth-field compass breaks the run
    [40.0, 41.0],  # too few
])
def test_the_segment_keeps_its_heading_without_a_consistent_offset_beyond_the_tolerance(offs) -> None:
    eng, out, _ = _walk(offs)
    assert [s.heading for s in out] == pytest.approx([0.3] * len(offs))
    assert eng._yaw == 0.0


def test_offsets_pending_survive_a_state_round_trip() -> None:
    eng, _, _ = _walk([40.0, 41.0])
    back = Engine.from_state(eng.get_state())
    assert back._compass_offsets == pytest.approx([math.radians(40.0), math.radians(41.0)])


def test_no_earth_compass_without_a_trusted_calibration() -> None:
    from energy.gait_dr import GaitPipeline

    assert GaitPipeline(25.0).earth_compass(object()) is None  # type: ignore[arg-type]
