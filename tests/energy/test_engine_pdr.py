"""Gait-DR through the engine: hand-over at L0, calibration into the profile, gyro-off positions."""

from __future__ import annotations

import numpy as np
import pytest

from clients.synth import synthesize
from energy.config import EngineConfig
from energy.device import replay
from energy.engine import Engine
from models.batch import SensorBatch

CFG = EngineConfig().override({"scheduler.l0_m": 15.0})


@pytest.fixture(scope="module")
def walk() -> SensorBatch:
    return synthesize("walk", seed=5).batch


@pytest.fixture(scope="module")
def replayed(walk: SensorBatch):
    eng = Engine(mode="pdr", config=CFG, trace=True)
    return eng, replay(eng, walk, batch_seconds=1.0)


def test_hand_over_after_l0_then_gyro_off_at_low_rate(replayed) -> None:
    eng, res = replayed
    kinds = [e.kind for u in res.updates for e in u.events]
    assert "calibration_done" in kinds and "mode_switch" in kinds
    modes = [p.mode for p in res.positions]
    first_pdr = modes.index("pdr")
    assert set(modes[first_pdr:]) == {"pdr"}
    zupt_dist = sum(p.step_length_m for p in res.positions[:first_pdr])
    assert zupt_dist >= CFG.scheduler.l0_m
    assert not any(p.gyro_on for p in res.positions[first_pdr:])
    assert res.updates[-1].sensor_config.gyro_on is False
    assert res.updates[-1].sensor_config.acc_rate_hz == CFG.rates.pdr_rate_hz
    assert res.gyro_on_fraction < 0.6 and res.mean_rate_hz < 150.0


def test_calibration_lands_in_the_profile_and_a_returning_user_starts_in_gait_dr(replayed) -> None:
    eng, _ = replayed
    prof = eng.profile_dict()
    walk_cal = prof["behaviours"]["walk"]
    assert walk_cal["calibrated"] and walk_cal["n_steps"] >= 8 and walk_cal["sigma_d_m"] > 0
    back = Engine(mode="auto", config=CFG, profile=prof)
    back._sched.on_behaviour("walk", 1.0, 1)
    assert back._sched.working == "pdr" and back._sched.exam_active


def test_gait_dr_tracks_the_synthetic_truth(walk: SensorBatch, replayed) -> None:
    _, res = replayed
    rec = synthesize("walk", seed=5)
    truth = rec.truth.positions
    end = np.array([res.positions[-1].north, res.positions[-1].east])
    t_idx = np.searchsorted(rec.batch.acc_t_ns, res.positions[-1].t_ns)
    true_end = truth[min(t_idx, len(truth) - 1), :2] - truth[0, :2]
    path = np.sum(np.linalg.norm(np.diff(truth[:, :2], axis=0), axis=1))
    assert np.linalg.norm(end - true_end) < 0.05 * path


def test_pdr_mode_is_chunk_invariant(walk: SensorBatch) -> None:
    def run(seconds: float | None) -> np.ndarray:
        eng = Engine(mode="pdr", config=CFG)
        pieces = [walk] if seconds is None else walk.split_seconds(seconds)
        ups = [eng.feed(p) for p in pieces] + [eng.flush()]
        return np.array([[p.t_ns, p.north, p.east] for u in ups for p in u.positions])

    whole, chunked = run(None), run(2.7)
    assert whole.shape == chunked.shape
    assert np.abs(whole - chunked).max() <= 1e-9


def test_pdr_without_a_magnetometer_refuses_the_gyroscope_off_and_says_why(walk: SensorBatch) -> None:
    """With the gyroscope off and no magnetometer nothing would tell a turn (gaitmap-mag without its field: 200 s
    of back-and-forth legs came out as one straight line; gdin's 6-axis walks ran 14-32 m off): the 004 scheme
    keeps the ZUPT-KF after L0 and says so in an event; with a magnetometer it turns the gyroscope off."""
    cfg = EngineConfig().override({"scheduler.l0_m": 20.0})
    res = replay(Engine(mode="pdr", config=cfg), walk.without("mag"), batch_seconds=1.0)
    events = [e for u in res.updates for e in u.events]
    refused = [e for e in events if e.kind == "gyroscope_off_refused"]
    assert len(refused) == 1 and "no magnetometer" in refused[0].detail["reason"]
    assert {p.mode for p in res.positions} == {"zupt"}
    assert res.updates[-1].sensor_config.gyro_on
    with_mag = replay(Engine(mode="pdr", config=cfg), walk, batch_seconds=1.0)
    assert "pdr" in {p.mode for p in with_mag.positions}
