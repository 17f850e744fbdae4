"""A duty-cycled gyroscope (issue 26; docs/phone.md, "A duty-cycled gyroscope"): the contract's fields, the device
emulator's delivery and charge, and the phone engine's gap filling (chunk invariance, state round trip, schedule)."""

from __future__ import annotations

import json
from dataclasses import replace
from functools import lru_cache

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from clients.phone_synth import synthesize_phone
from energy.device import GYRO_TURN_ON_S, DeviceEmulator, replay
from energy.engines import engine_from_bytes
from energy.phone_engine import PhoneEngine, PhoneEngineConfig, _DutyFill
from energy.types import SensorConfig
from models.batch import SensorBatch
from server.schemas import SensorConfigOut

ANCHOR = (49.4612, 11.1113, 300.0)
P, ON = 0.5, 0.15
DUTY = SensorConfig(True, 50.0, 50.0, 10.0, 1.0, gyr_duty_period_s=P, gyr_duty_on_s=ON)
CFG = PhoneEngineConfig(gyro_duty_period_s=P, gyro_duty_on_s=ON, walk_gyro="on-demand")  # duty-cycled where it would go off


@lru_cache(maxsize=None)
def _rec(name: str = "phone-walk", seed: int = 1):  # type: ignore[no-untyped-def]
    return synthesize_phone(name, seed=seed)


def _still(seconds: float = 6.0, rate_hz: float = 100.0) -> SensorBatch:
    t = np.arange(0, int(seconds * 1e9), int(1e9 / rate_hz), dtype=np.int64)
    n = len(t)
    return SensorBatch(acc_t_ns=t, acc=np.tile([0.0, 0.0, 9.81], (n, 1)), gyr_t_ns=t,
                       gyr=np.column_stack([np.zeros(n), np.zeros(n), 0.3 * np.sin(t / 1e9)]),
                       mag_t_ns=t, mag=np.tile([20.0, 0.0, 40.0], (n, 1)))


def test_sensor_config_fields() -> None:
    assert DUTY.gyr_duty and not SensorConfig(True, 50.0, 50.0, 10.0).gyr_duty
    for bad in ({"gyr_duty_on_s": 0.0}, {"gyr_duty_period_s": 0.0}, {"gyr_duty_on_s": 0.5}, {"gyr_duty_on_s": -0.1},
                {"gyr_duty_period_s": float("inf")}, {"gyro_on": False}, {"gyr_rate_hz": 0.0}):
        with pytest.raises(ValueError, match="duty|gyr_duty"):
            SensorConfig(**{**DUTY.to_dict(), **bad})
    assert SensorConfig(**json.loads(json.dumps(DUTY.to_dict()))) == DUTY
    served = SensorConfigOut(**DUTY.to_dict())
    assert served.gyr_duty_period_s == P and served.gyr_duty_on_s == ON
    old = {k: v for k, v in DUTY.to_dict().items() if not k.startswith("gyr_duty")}
    assert SensorConfigOut(**old).gyr_duty_period_s == 0.0  # a row stored before the fields existed
    with pytest.raises(ValueError, match="gyro_duty"):
        PhoneEngineConfig(gyro_duty_period_s=0.5)
    assert PhoneEngineConfig.from_dict(CFG.to_dict()) == CFG


@pytest.mark.parametrize("cuts", [[1.0, 2.0, 3.0, 4.0, 5.0], [0.3, 1.7, 2.05, 4.4]])
def test_device_delivers_inside_the_windows_on_its_own_clock(cuts: list[float]) -> None:
    """Samples only in ``[e + k P + t_on, e + k P + t_on + on)`` (``e``: the first duty batch's start, whatever the
    uploads' cuts), charged from each power-up to the window's end: ``(on + t_on) / P`` of the time."""
    rec = _still()
    d = DeviceEmulator(rec)
    edges = [0] + [int(c * 1e9) for c in cuts] + [int(rec.t_end_ns) + 1]
    got, charged = [], 0
    for a, b in zip(edges[:-1], edges[1:]):
        got.append(d.emit(a, b, DUTY).gyr_t_ns)
        charged += sum(y - x for x, y, _, g, _ in d.last_spans if g > 0)
        assert all(s[2] == 50.0 and s[4] == 10.0 for s in d.last_spans)  # accelerometer, magnetometer: throughout
    t = np.concatenate(got)
    phase = (t % int(P * 1e9)) / 1e9
    assert len(t) and np.all(phase >= GYRO_TURN_ON_S) and np.all(phase < GYRO_TURN_ON_S + ON)
    assert len(t) == 12 * round(ON * 50)  # 12 windows of 0.15 s at 50 Hz
    assert charged / edges[-1] == pytest.approx((ON + GYRO_TURN_ON_S) / P, abs=0.01)
    # the same samples whatever the cuts (the phase is the device's)
    ref = DeviceEmulator(rec).emit(0, edges[-1], DUTY).gyr_t_ns
    np.testing.assert_array_equal(t, ref)


def test_device_duty_cycle_restarts_with_the_configuration() -> None:
    rec = _still()
    d = DeviceEmulator(rec)
    d.emit(0, 1_000_000_000, DUTY)
    off = d.emit(1_000_000_000, 2_000_000_000, SensorConfig(False, 50.0, 0.0, 10.0))
    assert len(off.gyr_t_ns) == 0
    t = d.emit(2_300_000_000, 3_000_000_000, DUTY).gyr_t_ns
    assert t[0] >= 2_300_000_000 + int(GYRO_TURN_ON_S * 1e9)  # a new cycle from the batch it starts in


def _duty_cycled(batch: SensorBatch, offset_s: float = 0.0) -> SensorBatch:
    """The recording with the gyroscope's samples only inside the windows (as the device sends them)."""
    ph = ((batch.gyr_t_ns - int(batch.t_start_ns)) / 1e9 - offset_s) % P
    keep = (ph >= GYRO_TURN_ON_S) & (ph < GYRO_TURN_ON_S + ON)
    return replace(batch, gyr_t_ns=batch.gyr_t_ns[keep], gyr=batch.gyr[keep])


def test_fill_is_the_line_between_the_windows_means() -> None:
    rec = _duty_cycled(_still())
    f = _DutyFill(P, ON, 100.0)
    t, v = f.push(rec.gyr_t_ns, rec.gyr)
    t2, v2 = f.close(None)
    t, v = np.concatenate([t, t2]), np.concatenate([v, v2])
    assert np.all(np.diff(t) > 0) and np.max(np.diff(t)) <= 10_000_000  # continuous at the gyroscope's rate
    kept = np.isin(t, rec.gyr_t_ns)
    np.testing.assert_array_equal(v[kept], rec.gyr)  # the measured samples unchanged
    # a gap's samples lie on the line between the neighbouring windows' means
    starts = np.flatnonzero(np.diff(rec.gyr_t_ns) > 25_000_000)
    i = starts[1]
    a, b = rec.gyr_t_ns[i], rec.gyr_t_ns[i + 1]
    wa = (rec.gyr_t_ns > a - int(ON * 1e9)) & (rec.gyr_t_ns <= a)
    wb = (rec.gyr_t_ns >= b) & (rec.gyr_t_ns < b + int(ON * 1e9))
    ma, mb = rec.gyr[wa, 2].mean(), rec.gyr[wb, 2].mean()
    gap = (t > a) & (t < b)
    assert gap.sum() > 10
    np.testing.assert_allclose(v[gap, 2], ma + (mb - ma) * (t[gap] - a) / (b - a), atol=1e-12)


@settings(max_examples=8, deadline=None)
@given(fractions=st.lists(st.floats(0.02, 0.999), min_size=1, max_size=30))
def test_chunk_invariance_duty(fractions: list[float]) -> None:
    """``auto`` with the duty cycle, fed the same duty-cycled samples in any cut, gives the same track."""
    rec = _duty_cycled(_rec().batch, 0.21)
    dur = (int(rec.t_end_ns) - int(rec.t_start_ns)) / 1e9
    t0 = int(rec.t_start_ns)
    edges = sorted({t0 + int((2.0 + f * (dur - 2.0)) * 1e9) for f in [0.0, *fractions]})
    parts = [rec.time_slice(a, b) for a, b in zip([t0, *edges], [*edges, int(rec.t_end_ns) + 1]) if b > a]

    def run(batches: list[SensorBatch]) -> np.ndarray:
        e = PhoneEngine("auto", config=CFG, placement="phone-hand", anchor=ANCHOR)
        rows = [[p.t_ns, p.north, p.east, p.heading_rad, p.gyro_on] for b in batches for p in e.feed(b).positions]
        rows += [[p.t_ns, p.north, p.east, p.heading_rad, p.gyro_on] for p in e.flush().positions]
        assert e.late_samples["gyr"] == 0
        return np.array(rows, dtype=float)

    whole, cut = run([rec]), run(parts)
    assert whole.shape == cut.shape and len(whole) > 50
    assert whole[:, 4].mean() > 0.9  # the filled steps are gyroscope steps
    np.testing.assert_allclose(cut, whole, atol=1e-9, rtol=0)


@pytest.mark.parametrize("cut", [0.13, 0.5, 0.87])
def test_state_round_trip_duty(cut: float) -> None:
    rec = _duty_cycled(_rec().batch, 0.07)
    t0, t1 = int(rec.t_start_ns), int(rec.t_end_ns) + 1
    m = t0 + int(cut * (t1 - t0))
    first, second = rec.time_slice(t0, m), rec.time_slice(m, t1)
    ref = PhoneEngine("auto", config=CFG, anchor=ANCHOR)
    want = [p.t_ns for b in (first, second) for p in ref.feed(b).positions] + [p.t_ns for p in ref.flush().positions]
    e = PhoneEngine("auto", config=CFG, anchor=ANCHOR)
    got = [p.t_ns for p in e.feed(first).positions]
    blob = e.to_bytes()
    e2 = engine_from_bytes(blob)
    assert isinstance(e2, PhoneEngine) and e2.to_bytes() == blob
    got += [p.t_ns for p in e2.feed(second).positions] + [p.t_ns for p in e2.flush().positions]
    assert got == want
    # a state from before the duty cycle existed (no "duty" entry) loads as one without it
    plain = PhoneEngine("auto", anchor=ANCHOR)
    plain.feed(first)
    st_ = plain.get_state()
    st_.pop("duty")
    assert PhoneEngine.from_state(st_)._duty is None


def test_auto_asks_for_the_duty_cycle_walking() -> None:
    rec = _rec()
    res = replay(PhoneEngine("auto", config=CFG, anchor=ANCHOR), rec.batch, 1.0)
    duty = [c for _, c in res.configs if c.gyr_duty]
    assert duty and all(c.gyro_on and c.gyr_duty_period_s == P and c.gyr_duty_on_s == ON for c in duty)
    plain = replay(PhoneEngine("auto", config=replace(CFG, gyro_duty_period_s=0.0, gyro_duty_on_s=0.0), anchor=ANCHOR),
                   rec.batch, 1.0)
    assert not any(c.gyr_duty for _, c in plain.configs)
    assert not any(c.gyr_duty for _, c in replay(PhoneEngine("auto", anchor=ANCHOR), rec.batch, 1.0).configs)  # off by default
    # where on demand switches the gyroscope off walking, the duty cycle's steps are gyroscope steps
    assert np.mean([p.gyro_on for p in res.positions]) > np.mean([p.gyro_on for p in plain.positions])


def test_filled_steps_noise_and_duty_only_schedule() -> None:
    """``gyro_duty_sigma_rad``: the filled steps widen the heading's uncertainty (they are not the full gyroscope's);
    ``gyro_duty_only``: walking, the duty cycle replaces the full gyroscope the heading's forecast asked for."""
    with pytest.raises(ValueError, match="gyro_duty_sigma_rad"):
        PhoneEngineConfig(gyro_duty_period_s=P, gyro_duty_on_s=ON, gyro_duty_sigma_rad=-0.1)
    rec = _duty_cycled(_rec().batch, 0.13)
    stds = []
    for sigma in (0.0, np.radians(2.5)):
        e = PhoneEngine("auto", config=replace(CFG, gyro_duty_sigma_rad=float(sigma)), placement="phone-hand",
                        anchor=ANCHOR)
        e.feed(rec)
        e.flush()
        stds.append(e._heading.std)
    assert stds[1] > stds[0]
    full = replay(PhoneEngine("auto", config=CFG, anchor=ANCHOR), _rec().batch, 1.0)
    only = replay(PhoneEngine("auto", config=replace(CFG, gyro_duty_only=True), anchor=ANCHOR), _rec().batch, 1.0)
    n_full = sum(c.gyro_on and not c.gyr_duty for _, c in full.configs)
    n_only = sum(c.gyro_on and not c.gyr_duty for _, c in only.configs)
    assert n_only < n_full
