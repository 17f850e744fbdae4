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


@pytest.mark.parametrize("first, second", [(FULL, LOW), (LOW, FULL)])
def test_rate_change_leaves_no_hole(first: SensorConfig, second: SensorConfig) -> None:
    """A rate change loses nothing the sensor measured: no gap longer than the slower of the two periods."""
    dev = DeviceEmulator(recording())
    a = dev.emit(0, int(3e9), first)
    b = dev.emit(int(3e9), int(6e9), second)
    t = np.concatenate([a.acc_t_ns, b.acc_t_ns])
    slower_period_ns = 1e9 / min(first.acc_rate_hz, second.acc_rate_hz)
    assert np.diff(t).max() <= slower_period_ns * 1.01


class _ScriptedEngine:
    """Stands in for an engine: asks for the configurations of ``script`` in turn, records what it was fed."""

    def __init__(self, script: list[SensorConfig]) -> None:
        self.script = script
        self.fed: list[SensorBatch] = []
        self.trace = None

    @property
    def sensor_config(self) -> SensorConfig:
        return self.script[min(len(self.fed), len(self.script) - 1)]

    def feed(self, batch: SensorBatch):  # noqa: ANN201
        from energy.types import Update

        self.fed.append(batch)
        return Update([], [], self.sensor_config, "walk", "pdr")

    def flush(self):  # noqa: ANN201
        from energy.types import Update

        return Update([], [], self.sensor_config, "walk", "pdr")


def test_replay_batches_as_long_as_the_configuration_says() -> None:
    from dataclasses import replace

    from energy.device import replay

    script = [FULL, replace(LOW, batch_s=2.5), replace(LOW, batch_s=2.5), FULL]
    eng = _ScriptedEngine(script)
    res = replay(eng, recording(seconds=6.0), batch_seconds=None)  # type: ignore[arg-type]
    starts = [t for t, _ in res.configs]
    assert starts == [0, 1_000_000_000, 3_500_000_000, 6_000_000_000][: len(starts)]
    assert len(starts) == 3 and res.batches == 3  # 1 s + 2.5 s + 2.5 s covers the 6 s recording
    assert len(eng.fed[0]) == 200 and eng.fed[0].gyr_t_ns.size == 200  # 1 s at 200 Hz, gyroscope on
    for b in eng.fed[1:]:  # then 25 Hz with the gyroscope off ...
        assert b.gyr_t_ns.size == 0 and np.diff(b.acc_t_ns) == pytest.approx(40_000_000)
    # ... for 2.5 s each (the decimator's output lags its input by its group delay)
    assert eng.fed[2].acc_t_ns[-1] - eng.fed[1].acc_t_ns[-1] == pytest.approx(2.5e9, abs=40e6)
    fixed = replay(_ScriptedEngine(script), recording(seconds=6.0), batch_seconds=1.0)  # type: ignore[arg-type]
    assert fixed.batches == 6  # a fixed duration overrides the configuration's


def test_desample_is_the_streaming_decimator_over_the_whole_recording() -> None:
    """pednav replay --rate-hz: the recording as a sensor set to a lower rate delivers it, tail included."""
    from energy.device import desample
    from models.fir import Decimator

    rec = recording()  # 200 Hz acc/gyr/mag
    t = np.arange(1200) * 5_000_000
    rec = SensorBatch(acc_t_ns=rec.acc_t_ns, acc=rec.acc, gyr_t_ns=rec.gyr_t_ns, gyr=rec.gyr,
                      mag_t_ns=t[::4], mag=rec.mag[::4])  # the magnetometer at 50 Hz
    low = desample(rec, 50.0)
    dec = Decimator(200.0, 50.0)
    (t1, v1), (t2, v2) = dec.process(rec.acc_t_ns, rec.acc), dec.flush()
    np.testing.assert_array_equal(low.acc_t_ns, np.concatenate([t1, t2]))
    np.testing.assert_array_equal(low.acc, np.concatenate([v1, v2]))
    assert low.rate_hz("acc") == pytest.approx(50.0) and low.rate_hz("gyr") == pytest.approx(50.0)
    assert low.acc_t_ns[0] == rec.acc_t_ns[0] and low.acc_t_ns[-1] == rec.acc_t_ns[-4]  # no lost tail
    np.testing.assert_array_equal(low.mag_t_ns, rec.mag_t_ns)  # already at 50 Hz: kept, not filtered
    np.testing.assert_array_equal(low.mag, rec.mag)
    assert desample(rec, 400.0).acc.shape == rec.acc.shape  # never up-sampled
    with pytest.raises(ValueError, match="positive"):
        desample(rec, 0.0)


def test_desample_removes_what_would_alias() -> None:
    from energy.device import desample

    t = np.arange(4000) / 200.0
    slow = np.sin(2 * np.pi * 1.0 * t)
    tone = 0.5 * np.sin(2 * np.pi * 24.0 * t)  # folds onto 1 Hz at 25 Hz without a filter
    low = desample(SensorBatch.from_arrays(t, np.c_[slow + tone, slow, 9.81 + 0 * t], np.zeros((t.size, 3))), 25.0)
    ref = np.sin(2 * np.pi * 1.0 * low.acc_t_ns / 1e9)
    assert np.abs(low.acc[20:-20, 0] - ref[20:-20]).max() < 0.05
    assert np.abs(low.acc[20:-20, 0] - (slow + tone)[::8][20:-20]).max() > 0.3  # plain every-8th sample aliases
