"""FIR design and streaming decimator: linear phase, gains, anti-aliasing, chunk invariance, state."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from energy.codec import dumps, loads
from models.fir import Decimator, FirFilter, hamming_lowpass


@pytest.mark.parametrize("numtaps,cutoff,rate", [(9, 5.0, 25.0), (33, 8.0, 200.0), (129, 10.0, 200.0)])
def test_taps_are_symmetric_with_unit_dc_gain(numtaps: int, cutoff: float, rate: float) -> None:
    h = hamming_lowpass(numtaps, cutoff, rate)
    assert np.allclose(h, h[::-1])  # type-I linear phase
    assert h.sum() == pytest.approx(1.0, abs=1e-12)


def test_group_delay_is_half_the_length() -> None:
    rate, f0, n = 200.0, 2.0, 65
    t = np.arange(4000) / rate
    x = np.sin(2 * np.pi * f0 * t)
    y = FirFilter(hamming_lowpass(n, 10.0, rate)).process(x)
    d = (n - 1) // 2
    assert np.max(np.abs(y[1000:] - x[1000 - d : 4000 - d])) < 0.01


@pytest.mark.parametrize("bad", [0, 4, -3])
def test_even_or_empty_length_is_refused(bad: int) -> None:
    with pytest.raises(ValueError):
        hamming_lowpass(bad, 5.0, 100.0)


@pytest.mark.parametrize("rate_in", [100.0, 200.0, 250.0])
def test_decimator_passes_gait_band_and_rejects_aliases(rate_in: float) -> None:
    t = np.arange(int(20 * rate_in)) / rate_in
    t_ns = np.round(t * 1e9).astype(np.int64)
    dec = Decimator(rate_in, 25.0, channels=1)
    assert dec.rate_out_actual_hz == pytest.approx(25.0)
    low = np.sin(2 * np.pi * 2.0 * t)
    _, y = dec.process(t_ns, low[:, None])
    assert np.max(np.abs(y[100:, 0])) == pytest.approx(1.0, abs=0.02)
    for f_alias in (20.0, 30.0, 45.0):  # would fold onto 5, 5, 5 Hz at 25 Hz without the filter
        d = Decimator(rate_in, 25.0, channels=1)
        _, y = d.process(t_ns, np.sin(2 * np.pi * f_alias * t)[:, None])
        assert np.max(np.abs(y[100:, 0])) < 0.01


def test_decimator_output_times_sit_on_input_samples() -> None:
    t_ns = (np.arange(800) * 5_000_000).astype(np.int64)
    t_out, _ = Decimator(200.0, 25.0).process(t_ns, np.zeros((800, 3)))
    assert np.array_equal(t_out, t_ns[: t_out.size * 8 : 8])
    assert np.all(np.diff(t_out) == 40_000_000)


@settings(max_examples=25, deadline=None)
@given(cuts=st.lists(st.integers(min_value=0, max_value=1500), max_size=6))
def test_decimator_is_chunk_invariant_and_survives_state_round_trip(cuts: list[int]) -> None:
    rng = np.random.default_rng(1)
    n = 1500
    t_ns = (np.arange(n) * 5_000_000).astype(np.int64)
    x = rng.normal(size=(n, 3))
    t_ref, y_ref = Decimator(200.0, 25.0).process(t_ns, x)
    d = Decimator(200.0, 25.0)
    ts, ys = [], []
    bounds = [0, *sorted(cuts), n]
    for i, j in zip(bounds[:-1], bounds[1:]):
        d = Decimator.from_state(loads(dumps(d.get_state())))
        a, b = d.process(t_ns[i:j], x[i:j])
        ts.append(a)
        ys.append(b)
    assert np.array_equal(np.concatenate(ts), t_ref)
    assert np.allclose(np.concatenate(ys), y_ref, rtol=0, atol=1e-12)


def test_decimator_flush_reaches_the_last_input_on_the_same_grid() -> None:
    t = (np.arange(1003) * 5_000_000).astype(np.int64)
    x = np.c_[np.sin(np.arange(1003) / 30.0), np.cos(np.arange(1003) / 17.0), np.ones(1003)]
    d = Decimator(200.0, 25.0)
    t1, y1 = d.process(t, x)
    t2, y2 = d.flush()
    tt = np.r_[t1, t2]
    assert np.all(np.diff(tt) == 40_000_000) and tt[0] == 0
    assert t[-1] - tt[-1] < 40_000_000  # nothing held back any more
    assert np.allclose(np.r_[y1, y2][:, 2], 1.0)


@pytest.mark.parametrize("channels", [1, 3, 4, 7, 9])
def test_fir_rows_sum_each_channel_in_tap_order(channels: int) -> None:
    """``_fir_rows`` (channels four at a time) gives each channel's sum from 0.0 over the taps in order, to the
    bit, whatever the channel count (issue #28, eng12: the form the engine's fingerprint was taken with)."""
    from models.fir import _fir_rows

    rng = np.random.default_rng(channels)
    taps = hamming_lowpass(33, 10.0, 200.0)
    ext = rng.normal(size=(32 + 40, channels)) * 10.0
    rows = np.arange(0, 40, 3)
    y = _fir_rows(ext, taps, rows)
    for j, r in enumerate(rows.tolist()):
        for c in range(channels):
            a = 0.0
            for k in range(taps.size):
                a += float(taps[k]) * float(ext[r + taps.size - 1 - k, c])
            assert y[j, c] == a
