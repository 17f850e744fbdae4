"""Gyro-off step segmentation: counts on synthetic and real recordings, chunk invariance, state."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from energy.codec import dumps, loads
from models.fir import Decimator
from models.steps import G0, StepSegmenter


def synthetic_foot(rate: float, strides: int, period: float = 1.1, stance: float = 0.45, rest: float = 2.0,
                   seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Foot-like specific force: still stances (gravity, fixed tilt) and swings that rotate and accelerate."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, rest * 2 + strides * period, 1.0 / rate)
    acc = np.tile([0.0, 0.0, -G0], (t.size, 1))
    for k in range(strides):
        t0 = rest + k * period + stance
        sw = (t >= t0) & (t < rest + (k + 1) * period)
        ph = (t[sw] - t0) / (period - stance)
        ang = 0.8 * np.sin(np.pi * ph)  # pitch of the foot during the swing [rad]
        acc[sw, 0] = -G0 * np.sin(ang) + 12.0 * np.sin(2 * np.pi * ph)
        acc[sw, 2] = -G0 * np.cos(ang) - 8.0 * np.sin(np.pi * ph) ** 2
    acc += rng.normal(scale=0.05, size=acc.shape)
    return t, acc


@pytest.mark.parametrize("rate", [20.0, 25.0, 50.0, 100.0, 200.0])
@pytest.mark.parametrize("period", [0.8, 1.1, 1.5])
def test_counts_synthetic_strides_at_any_rate(rate: float, period: float) -> None:
    t, acc = synthetic_foot(rate, strides=20, period=period, stance=0.35 * period)
    ev = StepSegmenter(rate).feed(t, acc)
    assert len(ev) == 20
    f = np.array([e.f_s for e in ev[1:]])
    assert np.allclose(f, 1.0 / period, rtol=0.05)


@settings(max_examples=20, deadline=None)
@given(rate=st.sampled_from([25.0, 200.0]), cuts=st.lists(st.integers(min_value=0, max_value=6000), max_size=8),
       small=st.integers(min_value=1, max_value=30))
def test_chunk_invariance_and_state_round_trip(rate: float, cuts: list[int], small: int) -> None:
    t, acc = synthetic_foot(rate, strides=25)
    ref = StepSegmenter(rate).feed(t, acc)
    cuts = cuts + list(range(100, 400, small))  # also many chunks shorter than the filter and the window
    seg = StepSegmenter(rate)
    got = []
    bounds = [0, *sorted({c for c in cuts if c < t.size}), t.size]
    for i, j in zip(bounds[:-1], bounds[1:]):
        seg = StepSegmenter.from_state(loads(dumps(seg.get_state())))
        got += seg.feed(t[i:j], acc[i:j])
    assert got == ref


def test_gyroscope_does_not_change_events() -> None:
    t, acc = synthetic_foot(50.0, strides=10)
    gyr = np.random.default_rng(2).normal(size=acc.shape)
    assert StepSegmenter(50.0).feed(t, acc) == StepSegmenter(50.0).feed(t, acc, gyr)


@pytest.mark.parametrize("rate", [25.0, 200.0])
@pytest.mark.parametrize("period", [0.8, 1.5])
def test_latency_bound_and_last_stance_reported_while_standing(rate: float, period: float) -> None:
    t, acc = synthetic_foot(rate, strides=12, period=period, stance=0.35 * period, rest=2.0)
    seg = StepSegmenter(rate)
    got = []
    for k in range(t.size):  # one sample at a time: the input time at which each step comes out
        for e in seg.feed(t[k:k + 1], acc[k:k + 1]):
            got.append((e, t[k]))
    assert len(got) == 12  # the last one too, without flush (the foot stands still afterwards)
    lat = [tk - e.t_s for e, tk in got]
    assert max(lat) <= seg.latency_s + 1e-9


# Real recordings (exp 31-43 have a footprint per stride), fast walks (34, 35, 43) included: one configuration
# for every recording and rate, nothing read from the truth. The stream is flushed at the end (the last stance
# of a recording is its last stride).
_PER_STRIDE = [f"exp{n}" for n in (31, 32, 33, 34, 35, 36, 37, 41, 42, 43)]


@pytest.mark.slow
@pytest.mark.parametrize("rate_out", [20.0, 25.0, 50.0, None], ids=["20Hz", "25Hz", "50Hz", "native"])
@pytest.mark.parametrize("name", _PER_STRIDE)
def test_gyro_off_step_count_within_2pct_of_truth(gdin_dir: Path, name: str, rate_out: float | None) -> None:
    from clients.importers.gdin import find_gdin, load_gdin

    entries = {e.name: e for e in find_gdin(gdin_dir) if e.stride_path is not None}
    if name not in entries:
        pytest.skip(f"{name} not in this copy of gdin")
    rec = load_gdin(entries[name])
    b = rec.batch
    truth = int(rec.truth.extra["stride_t_ns"].size - 1)
    rate = rec.meta.rate_hz
    t_ns, acc = b.acc_t_ns, b.acc
    if rate_out is not None:
        dec = Decimator(rate, rate_out)
        t1, a1 = dec.process(t_ns, acc)
        t2, a2 = dec.flush()
        t_ns, acc = np.r_[t1, t2], np.r_[a1, a2]
        rate = dec.rate_out_actual_hz
    seg = StepSegmenter(rate)
    n = len(seg.feed(t_ns * 1e-9, acc)) + len(seg.flush())  # gyroscope never passed
    assert abs(n - truth) <= 0.02 * truth, f"{n} steps vs {truth} strides"


def test_state_of_the_earlier_segmenter_restores_as_a_fresh_detector() -> None:
    old = {"params": [25.0, 0.12, 1.5, 5.0, 0.6, 0.4, 2.5, 8.0, 0.16], "fir": StepSegmenter(25.0)._fir.get_state(),
           "t_hist": np.zeros(2), "win": np.zeros((2, 3)), "stance": False, "peak": 0.0, "last_onset": 1.0,
           "last_event": 1.0, "last_stance_end": 1.2, "periods": [1.1], "buf": np.zeros(0), "count": 10,
           "n_events": 1}
    seg = StepSegmenter.from_state(loads(dumps(old)))
    t, acc = synthetic_foot(25.0, strides=6)
    assert len(seg.feed(t, acc)) == 6 and seg.min_period_s == 0.4
