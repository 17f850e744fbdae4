"""Compass-swing wake (``SensorConfig.wake_mode == "compass_swing"``): a phone's device wakes its gyroscope itself
when its tilt-compensated compass azimuth swings (a turn), not on a straight walk with a noisy compass; the
gyroscope is charged from the swing on, delivers after its turn-on time and sleeps ``sleep_after_s`` after the last
swing, or at once when the host says so; the configuration is validated and served; the phone engine asks for it
when it switches the gyroscope off walking and navigates with the samples the device sends unasked."""

from __future__ import annotations

from dataclasses import replace

import json
import math

import numpy as np
import pytest

from clients.phone_synth import Leg, PhoneScenario, synthesize_phone
from energy.compass_swing import SWING_RAD, SWING_WINDOW_S, CompassSwing
from energy.device import GYRO_TURN_ON_S, DeviceEmulator, replay
from energy.phone_engine import PhoneEngine, PhoneEngineConfig
from energy.types import SensorConfig

SWING = SensorConfig(gyro_on=False, acc_rate_hz=50.0, gyr_rate_hz=50.0, mag_rate_hz=10.0, gyro_wake_on_motion=True,
                     sleep_after_s=1.5, wake_mode="compass_swing", wake_swing_rad=SWING_RAD, wake_window_s=SWING_WINDOW_S)
STEP_HZ = 1.8  # PhoneScenario's default step frequency
START_S = 4.0  # ... and its still start


def _run(rec, cfgs) -> tuple[np.ndarray, float, list]:  # type: ignore[no-untyped-def]
    """1-s batches under ``cfgs(k)`` (batch k): the gyroscope's sample times [s from the start], the seconds it was
    charged, and the spans."""
    dev = DeviceEmulator(rec.batch)
    t0 = int(rec.batch.t_start_ns)
    n = int(math.ceil((int(rec.batch.t_end_ns) - t0) / 1e9))
    times, spans = [], []
    for k in range(n):
        out = dev.emit(t0 + k * 10**9, t0 + (k + 1) * 10**9, cfgs(k))
        times.append(out.gyr_t_ns)
        spans += dev.last_spans
    on_s = sum(b - a for a, b, _, gyr, _ in spans if gyr > 0) / 1e9
    return (np.concatenate(times) - t0) / 1e9, on_s, spans


def test_a_straight_walk_with_a_noisy_compass_does_not_wake_the_gyroscope() -> None:
    """40 steps straight, the hand wobbling 3 deg, a magnetometer three times noisier than the synthesiser's (1.3 deg
    per 10-Hz output) and a disturbed place on the way (its field turns the compass by about 10 deg over a few
    metres)."""
    scn = PhoneScenario((Leg("walk", 40),), wobble_deg=3.0, mag_noise_ut=1.0,
                        disturbances=((8.0 * math.cos(math.radians(30)), 8.0 * math.sin(math.radians(30)), 3.0,
                                       0.0, 4.0, 0.0),))
    t, on_s, _ = _run(synthesize_phone(scn, seed=3), lambda k: SWING)
    assert len(t) == 0 and on_s == 0.0


def test_a_turn_wakes_the_gyroscope_which_is_charged_and_sleeps_again() -> None:
    legs = (Leg("walk", 20, turn_deg=90.0), Leg("walk", 20))
    rec = synthesize_phone(PhoneScenario(legs), seed=1)
    turn0 = START_S + (20 - 2) / STEP_HZ  # the turn takes the last 2 steps of the first leg
    turn1 = START_S + 20 / STEP_HZ
    t, on_s, spans = _run(rec, lambda k: SWING)
    assert len(t) > 0
    # woken by the turn itself: not before it, and within the window plus the turn-on time of the swing
    assert turn0 < t[0] < turn0 + SWING_WINDOW_S + GYRO_TURN_ON_S + 0.3, t[0]
    # asleep again sleep_after_s after the turn's last swing (it cannot outlast the turn by more than that and a window)
    assert t[-1] < turn1 + SWING.sleep_after_s + SWING_WINDOW_S + 0.1, t[-1]
    assert t[-1] > turn1 - 0.2
    # the rates of a configuration, and the energy: charged from the swing (turn-on time included) to power-down
    assert np.all(np.diff(t) > 0) and np.median(np.diff(t)) == pytest.approx(1 / 50.0, rel=0.05)
    delivered = t[-1] - t[0] + 1 / 50.0
    assert delivered + GYRO_TURN_ON_S - 0.05 <= on_s <= delivered + GYRO_TURN_ON_S + 0.25
    assert all((gyr == 0.0 or abs(gyr - 50.0) < 0.5) and abs(acc - 50.0) < 0.5 for _, _, acc, gyr, _ in spans)
    # the detector's azimuth turns with the device: 90 deg from a second before the turn to 3 s after it (the
    # mean over a step, the hand's wobble and the bounce's tilt averaged out)
    b = rec.batch
    t_mag, psi, _ = CompassSwing().process(b.acc_t_ns, b.acc, b.mag_t_ns, b.mag)
    ts = (t_mag - int(b.t_start_ns)) / 1e9

    def around(x: float) -> float:
        return float(np.mean(psi[(ts > x - 0.28) & (ts < x + 0.28)]))

    assert math.degrees(abs(around(turn1 + 3.0) - around(turn0 - 1.0))) == pytest.approx(90.0, abs=5.0)


def test_the_host_switches_the_woken_gyroscope_off_at_once() -> None:
    """The host's word wins: a configuration without the wake stops a woken gyroscope at the batch; one that had
    the gyroscope on and now asks for the swing wake powers it down at once (no swing on the straight leg)."""
    legs = (Leg("walk", 20, turn_deg=90.0), Leg("walk", 20))
    rec = synthesize_phone(PhoneScenario(legs), seed=1)
    turn0 = START_S + (20 - 2) / STEP_HZ
    k_stop = int(turn0) + 1  # the batch after the turn's start
    off = SensorConfig(False, 50.0, 0.0, 10.0)
    t, _, _ = _run(rec, lambda k: SWING if k < k_stop else off)
    assert len(t) > 0 and t[-1] < k_stop
    on = SensorConfig(True, 50.0, 50.0, 10.0)
    t, _, _ = _run(rec, lambda k: on if k < 8 else SWING)  # straight until the turn at ~14 s
    before = t[t < turn0]
    assert len(before) and before[-1] < 8.0


def test_compass_swing_configs_are_validated_and_served() -> None:
    from server.schemas import SensorConfigOut

    for bad, match in (({"wake_swing_rad": 0.0}, "positive finite wake_swing_rad"),
                       ({"wake_window_s": float("inf")}, "positive finite wake_window_s"),
                       ({"sleep_after_s": 0.0}, "positive finite sleep_after_s")):
        with pytest.raises(ValueError, match=match):
            SensorConfig(**{**SWING.to_dict(), **bad})
    with pytest.raises(ValueError, match="wake_mode"):
        SensorConfig(**{**SWING.to_dict(), "wake_mode": "swing"})
    assert SensorConfig(**json.loads(json.dumps(SWING.to_dict()))) == SWING
    served = SensorConfigOut(**SWING.to_dict())
    assert served.wake_mode == "compass_swing" and served.wake_swing_rad == SWING.wake_swing_rad
    old = {k: v for k, v in SWING.to_dict().items() if k not in ("wake_swing_rad", "wake_window_s", "wake_mode")}
    row = SensorConfigOut(**old)  # a row stored before the fields existed
    assert row.wake_swing_rad == 0.0 and row.wake_window_s == 0.0 and row.wake_mode == "motion"


def test_the_phone_engine_asks_for_the_swing_wake_and_uses_the_samples_it_did_not_ask_for() -> None:
    rec = synthesize_phone("phone-walk", seed=1)
    demand = PhoneEngineConfig(walk_gyro="on-demand")  # the swing wakes a gyroscope switched off walking
    res = replay(PhoneEngine("auto", placement="phone-hand", config=replace(demand, swing_wake=True)), rec.batch, 1.0)
    t0 = int(rec.batch.t_start_ns)
    asked = {t: c for t, c in res.configs}
    swing = [c for c in asked.values() if c.wake_mode == "compass_swing"]
    assert swing and all(not c.gyro_on and c.gyro_wake_on_motion and c.acc_rate_hz == demand.auto_acc_rate_hz
                         for c in swing)

    def config_at(t_ns: int) -> SensorConfig:
        return asked[max(t for t in asked if t <= t_ns)]

    unasked = [p for p in res.positions if p.gyro_on and not config_at(p.t_ns).gyro_on]
    assert unasked, "no step navigated with a gyroscope the device woke itself"
    # ... and they are at the square's turns: the truth's walking heading changes within a few steps of them
    heading = np.unwrap(np.asarray(rec.truth.extra["walking_heading_rad"], dtype=float))
    step_t = np.asarray(rec.truth.t_ns, dtype=np.int64)
    turning = step_t[np.flatnonzero(np.abs(np.diff(heading)) > math.radians(10.0)) + 1]
    assert len(turning) and all(np.min(np.abs(turning - p.t_ns)) < 3e9 for p in unasked)
    off = replay(PhoneEngine("auto", placement="phone-hand", config=demand), rec.batch, 1.0)  # the default: no swing wake
    assert not any(c.gyro_wake_on_motion for _, c in off.configs)
    assert not any(p.gyro_on and not c.gyro_on for p in off.positions
                   for c in [max(((t, c) for t, c in off.configs if t <= p.t_ns), key=lambda x: x[0])[1]])


def test_the_swing_constants_are_the_dev_trials_statistics(ipin_dir) -> None:  # type: ignore[no-untyped-def]
    """The threshold lies within the leave-one-route-out range of the straight stretches' 99th percentile, and at
    the constants the detector misses none of the trials' turns, firing within 0.3 s of the gyroscope's 20 deg."""
    from clients.evaluation.phone_swing import loro_statistics, swing_table
    from clients.importers import load
    from energy.compass_swing import SWING_TAU_S

    files = sorted(ipin_dir.glob("*.txt"))
    st = loro_statistics([swing_table(load(f), SWING_WINDOW_S, SWING_TAU_S) for f in files])
    lo, hi = st["range"]["straight_p99_deg"]
    assert lo <= math.degrees(SWING_RAD) <= hi, (math.degrees(SWING_RAD), lo, hi)
    assert st["all"]["turns"] > 50 and st["all"]["turns_missed"] == 0
    assert st["all"]["delay_p90_s"] <= 0.3
