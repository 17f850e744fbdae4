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


def test_unit_checks_use_the_median_norm_and_the_peak() -> None:
    # 10 samples (the unit checks start at 10): |a| = 1, ..., 10 -> median (5 + 6) / 2 = 5.5 m/s^2 passes
    kw = _walk(10)
    kw["acc"] = np.c_[np.zeros(10), np.zeros(10), np.arange(1.0, 11.0)]
    SensorBatch(**kw).validate()
    kw["acc"][:, 2] = np.r_[np.full(6, 2.0), np.full(4, 9.8)]  # median 2.0: looks like g
    assert _error(kw) == ("acc", "median |a| = 2; looks like g, expected m/s^2 (about 9.81 at rest)")
    kw["acc"][:, 2] = 3.0 * np.r_[np.full(5, 2.0), np.full(5, 3.0)] / np.sqrt(9.0)  # norms 2, 3 -> median 2.5
    SensorBatch(**kw).validate()  # exactly at the limit: not below it
    assert _error(_walk(acc=60.0)) == ("acc", "median |a| = 60 m/s^2 is implausible (expected about 9.81 at rest)")
    kw = _walk()
    kw["gyr"][4] = [0.0, -61.0, 0.0]  # one sample is enough for the peak
    assert _error(kw) == ("gyr", "peak |w| = 61; looks like deg/s, expected rad/s")
    assert _error(_walk(mag=0.4)) == ("mag", "median |m| = 0.4 uT is outside (5.0, 200.0); looks like gauss (x100)")
    assert _error(_walk(mag=40000.0)) == ("mag", "median |m| = 4e+04 uT is outside (5.0, 200.0); looks like nT (/1000)")


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
