"""SensorBatch construction and validation: each check names its field and problem (hand-made batches)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from models.batch import BatchError, SensorBatch


def _walk(n: int = 20, acc: float = 9.81, gyr: float = 0.5, mag: float = 40.0) -> dict[str, np.ndarray]:
    t = np.arange(n, dtype=np.int64) * 10_000_000
    return {
        "acc_t_ns": t, "acc": np.tile([0.0, 0.0, acc], (n, 1)),
        "gyr_t_ns": t.copy(), "gyr": np.tile([gyr, 0.0, 0.0], (n, 1)),
        "mag_t_ns": t.copy(), "mag": np.tile([0.0, mag, 0.0], (n, 1)),
    }


def _error(kw: dict[str, np.ndarray], check_units: bool = True) -> tuple[str, str]:
    with pytest.raises(BatchError) as err:
        SensorBatch(**kw).validate(check_units=check_units)
    return err.value.field, err.value.problem


def test_valid_batch_passes_and_returns_itself() -> None:
    b = SensorBatch(**_walk())
    assert b.validate() is b


def test_construction_converts_lists_and_float32_and_checks_lengths() -> None:
    b = SensorBatch(acc_t_ns=[1, 2], acc=np.ones((2, 3), dtype=np.float32), gyr_t_ns=np.array([5], dtype=np.int32),
                    gyr=[0.1, 0.2, 0.3])
    assert b.acc_t_ns.dtype == np.int64 and b.acc.dtype == np.float64 and b.gyr.shape == (1, 3)
    assert b.mag.shape == (0, 3) and b.mag_t_ns.dtype == np.int64
    with pytest.raises(BatchError, match="acc_t_ns: timestamps must be integer nanoseconds"):
        SensorBatch(acc_t_ns=np.array([1.0]), acc=[[1.0, 2.0, 3.0]])
    with pytest.raises(BatchError, match="acc: 3 samples but 2 timestamps"):
        SensorBatch(acc_t_ns=np.array([1, 2]), acc=np.ones((3, 3)))


def test_first_non_finite_row_is_named_per_stream_in_order() -> None:
    kw = _walk()
    kw["gyr"][7, 2] = np.inf
    kw["gyr"][9, 0] = np.nan
    kw["mag"][1, 1] = np.nan
    assert _error(kw) == ("gyr", "sample 7 is not finite (NaN or inf)")


def test_duplicate_reported_before_an_earlier_step_backwards() -> None:
    kw = _walk()
    t = kw["acc_t_ns"]
    t[3], t[4] = t[4], t[3]  # backwards at sample 4
    t[12] = t[11]  # duplicate at sample 12
    assert _error(kw) == ("acc_t_ns", f"duplicated timestamp {int(t[12])} at sample 12")
    kw = _walk()
    kw["mag_t_ns"][5] = kw["mag_t_ns"][4] - 1
    assert _error(kw) == ("mag_t_ns", "timestamps go backwards at sample 5")


def test_timestamp_checks_come_before_unit_checks() -> None:
    kw = _walk(acc=1.0)  # in g
    kw["gyr_t_ns"][2] = kw["gyr_t_ns"][1]
    assert _error(kw)[0] == "gyr_t_ns"
    assert _error(kw, check_units=False)[0] == "gyr_t_ns"
    SensorBatch(**_walk(acc=1.0)).validate(check_units=False)  # units unchecked: passes


def _steady(level: float, n: int = 100, rate_hz: float = 100.0) -> dict[str, np.ndarray]:
    """An accelerometer holding a constant specific force of ``level`` (any unit) with 0.5 % noise."""
    t = np.arange(n, dtype=np.int64) * int(1e9 / rate_hz)
    rng = np.random.default_rng(1)
    return {"acc_t_ns": t, "acc": np.array([0.3, -0.2, 0.93]) / np.linalg.norm([0.3, -0.2, 0.93]) * level
            * (1.0 + 0.005 * rng.standard_normal((n, 1)))}


@pytest.mark.parametrize("level, unit", [(1.0, "looks like g"), (0.81, "looks like g"), (1.24, "looks like g"), (1000.0, "milli-g"), (981.0, "milli-g"),
                                         (150.0, "100 m/s^2")])
def test_a_steady_accelerometer_in_another_unit_is_refused_naming_the_samples(level: float, unit: str) -> None:
    field, problem = _error(_steady(level))
    assert field == "acc"
    assert "the first samples 0-25" in problem and f"|a| = {level:.3g}" in problem and unit in problem


@pytest.mark.parametrize("level", [9.81, 9.72, 9.98, 0.05, 0.5, 2.0, 14.0, 60.0, 100.0])
def test_a_steady_specific_force_a_person_can_hold_is_taken(level: float) -> None:
    """Standing (9.72-9.98 on every development recording), free fall, a braking car, an aerobatic pull-up."""
    SensorBatch(**_steady(level)).validate()


def _sprint(seconds: float = 1.0, rate_hz: float = 800.0, peak_g: float = 16.0, seed: int = 0) -> dict[str, np.ndarray]:
    """A sprinting foot: |a| between 2 and ``peak_g`` g with a batch median near 56 m/s^2, rates up to 2000 deg/s,
    clipped at the sensor's full scale, never steady."""
    rng = np.random.default_rng(seed)
    n = int(seconds * rate_hz)
    t = np.arange(n, dtype=np.int64) * int(1e9 / rate_hz)
    ph = 2 * np.pi * np.arange(n) / rate_hz / 0.55  # stride 0.55 s
    mag = 9.81 * (2.0 + (peak_g - 2.0) * np.abs(np.sin(ph)) ** 0.4)
    d = rng.standard_normal((n, 3))
    acc = np.clip(d / np.linalg.norm(d, axis=1, keepdims=True) * mag[:, None], -peak_g * 9.81, peak_g * 9.81)
    gyr = np.clip(40.0 * np.c_[np.sin(ph), 0.3 * np.cos(ph), 0.1 * np.sin(2 * ph)], -np.radians(2000), np.radians(2000))
    return {"acc_t_ns": t, "acc": acc, "gyr_t_ns": t.copy(), "gyr": gyr}


@pytest.mark.parametrize("rate_hz", [100.0, 200.0, 800.0])
def test_a_sprint_batch_whose_median_passes_5_g_is_taken(rate_hz: float) -> None:
    """A VN-200 sprint batch (median |a| 56 m/s^2) was refused as 'median |a| = 56 m/s^2 is implausible'."""
    kw = _sprint(rate_hz=rate_hz)
    assert np.median(np.linalg.norm(kw["acc"], axis=1)) > 50.0
    assert np.max(np.abs(kw["gyr"])) == pytest.approx(np.radians(2000))
    SensorBatch(**kw).validate()


@given(st.floats(2.0, 100.0), st.floats(0.0, 16.0), st.integers(0, 2**16))
def test_physically_possible_values_are_never_refused(level: float, spread_g: float, seed: int) -> None:
    """Any steady specific force a person can hold followed by any motion up to 16 g and 2000 deg/s."""
    still = _steady(level, n=50)
    move = _sprint(0.5, 200.0, max(spread_g, 2.0), seed)
    t = np.r_[still["acc_t_ns"], move["acc_t_ns"] + 500_000_000]
    SensorBatch(acc_t_ns=t, acc=np.r_[still["acc"], move["acc"]], gyr_t_ns=t.copy(),
                gyr=np.r_[np.zeros((50, 3)), move["gyr"]]).validate()


def test_an_accelerometer_without_a_steady_stretch_is_not_unit_checked() -> None:
    """Nothing says which unit a batch in constant motion is in (a g-unit sprint would read 1.5-16); it is taken,
    and the first steady stretch of the session judges the unit."""
    kw = _sprint()
    kw["acc"] = kw["acc"] / 9.81
    SensorBatch(**kw).validate()


def test_the_gyroscope_beyond_any_wearable_full_scale_is_deg_per_s_naming_the_sample() -> None:
    kw = _walk()
    kw["gyr"][:, 0] = np.radians(4000.0)  # a +-4000 deg/s part at full scale, in rad/s: taken
    SensorBatch(**kw).validate()
    kw["gyr"][4] = [0.0, -76.0, 0.0]  # one sample is enough
    field, problem = _error(kw)
    assert field == "gyr" and problem.startswith("sample 4: |w| = 76") and "deg/s" in problem


def test_magnetometer_units_by_the_median() -> None:
    SensorBatch(**_walk(mag=300.0)).validate()  # a magnet beside the sensor
    assert _error(_walk(mag=0.4)) == ("mag", "median |m| = 0.4 uT is outside (5.0, 5000.0); looks like gauss (x100)")
    assert _error(_walk(mag=40000.0)) == ("mag", "median |m| = 4e+04 uT is outside (5.0, 5000.0); looks like nT (/1000)")


def test_unit_checks_skip_streams_with_fewer_than_ten_samples() -> None:
    SensorBatch(**_walk(9, acc=1.0, gyr=100.0, mag=0.4)).validate()
    SensorBatch().validate()


@given(st.lists(st.integers(0, 50), min_size=0, max_size=40), st.one_of(st.none(), st.integers(-5, 55)),
       st.one_of(st.none(), st.integers(-5, 55)), st.booleans())
def test_time_slice_keeps_exactly_the_samples_in_the_interval(ts, t0, t1, shuffle) -> None:
    """Sorted streams are cut by binary search, others by a mask: both give ``t0 <= t < t1``, in order, copied."""
    t = np.array(sorted(ts) if not shuffle else ts, dtype=np.int64)
    v = np.column_stack([t, t, t]).astype(np.float64)
    b = SensorBatch(acc_t_ns=t, acc=v, mag_t_ns=t[::2].copy(), mag=v[::2].copy())
    out = b.time_slice(t0, t1)
    for name in ("acc", "mag"):
        tt, vv = b.stream(name)
        m = np.ones(tt.size, dtype=bool)
        if t0 is not None:
            m &= tt >= t0
        if t1 is not None:
            m &= tt < t1
        ot, ov = out.stream(name)
        np.testing.assert_array_equal(ot, tt[m])
        np.testing.assert_array_equal(ov, vv[m])
        assert not np.shares_memory(ot, tt) or ot.size == 0
