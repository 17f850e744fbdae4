"""Device emulation: what is sent obeys the sensor configuration, independent of how time was cut."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from energy.device import Desampler, DeviceEmulator
from energy.types import SensorConfig
from models.batch import SensorBatch


def recording(seconds: float = 6.0, rate: float = 200.0) -> SensorBatch:
    t = np.arange(int(seconds * rate)) / rate
    rng = np.random.default_rng(1)
    acc = np.c_[np.sin(2 * np.pi * 1.0 * t), np.zeros_like(t), 9.81 + 0 * t] + 0.01 * rng.standard_normal((len(t), 3))
    gyr = 0.1 * rng.standard_normal((len(t), 3))
    mag = np.tile([20.0, 0.0, 40.0], (len(t), 1))
    return SensorBatch.from_arrays(t, acc, gyr, mag)


FULL = SensorConfig(True, 200.0, 200.0, 50.0)
LOW = SensorConfig(False, 25.0, 0.0, 25.0)


def test_gyro_off_sends_no_gyro_and_low_rate_is_decimated() -> None:
    dev = DeviceEmulator(recording())
    out = dev.emit(0, int(3e9), LOW)
    assert out.gyr_t_ns.size == 0
    assert out.rate_hz("acc") == pytest.approx(25.0)
    full = DeviceEmulator(recording()).emit(0, int(3e9), FULL)
    assert full.gyr_t_ns.size == full.acc_t_ns.size == 600


def test_decimation_keeps_a_slow_signal_and_removes_aliasing() -> None:
    rate = 200.0
    t = np.arange(4000) / rate
    slow = np.sin(2 * np.pi * 1.0 * t)
    fast = 0.5 * np.sin(2 * np.pi * 24.0 * t)  # would alias to 1 Hz at 25 Hz without a filter
    d = Desampler(rate)
    d.set_rate(25.0)
    tn = np.round(t * 1e9).astype(np.int64)
    out_t, out_v = d.process(tn, np.c_[slow + fast, slow, 0 * t])
    ref = np.sin(2 * np.pi * 1.0 * out_t / 1e9)
    err_mixed = np.abs(out_v[20:, 0] - ref[20:]).max()
    assert err_mixed < 0.05  # the 24 Hz tone is suppressed instead of folding onto the slow signal
    assert np.abs(out_v[20:, 1] - ref[20:]).max() < 0.01


@settings(max_examples=20, deadline=None)
@given(cuts=st.lists(st.integers(1, 1199), max_size=8, unique=True))
def test_emission_is_chunk_invariant(cuts: list[int]) -> None:
    rec = recording()
    whole = DeviceEmulator(rec).emit(0, int(6e9), LOW)
    dev = DeviceEmulator(rec)
    edges = [0] + sorted(c * 5_000_000 for c in cuts) + [int(6e9)]
    parts = [dev.emit(a, b, LOW) for a, b in zip(edges[:-1], edges[1:])]
    joined = SensorBatch.concat(parts)
    np.testing.assert_array_equal(joined.acc_t_ns, whole.acc_t_ns)
    np.testing.assert_allclose(joined.acc, whole.acc, atol=1e-12)


def test_rate_change_never_sends_time_backwards() -> None:
    dev = DeviceEmulator(recording())
    a = dev.emit(0, int(2e9), FULL)
    b = dev.emit(int(2e9), int(4e9), LOW)
    c = dev.emit(int(4e9), int(6e9), FULL)
    t = np.concatenate([a.acc_t_ns, b.acc_t_ns, c.acc_t_ns])
    assert np.all(np.diff(t) > 0)
