"""Gyro-off step segmentation: counts on synthetic and real recordings, chunk invariance, state."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from hypothesis import example, given, settings
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


# -- long quiet stretches (standing): bounded memory, the same events --------------------------------------------
def _event_key(events: list) -> list[str]:
    """Events as text, bit for bit (repr of every field; NaN compares equal to NaN)."""
    return [repr(dataclasses.astuple(e)) for e in events]


def _reference(rate: float, t: np.ndarray, acc: np.ndarray) -> list:
    """Events of the segmenter that keeps every sample of a quiet stretch (one piece, then flushed)."""
    ref = StepSegmenter(rate)
    ref._compact = False
    return ref.feed(t, acc) + ref.flush()


def _collapsed(seg: StepSegmenter, n_in: int) -> int:
    """Samples a segmenter fed ``n_in`` samples (and flushed) has collapsed: its sample index is behind by them."""
    return n_in + seg._delay + seg._w + seg._n_ctx + 1 - int(seg._ist[0])


def _pieces(rate: float, kinds: list[tuple[str, float, float]], seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Specific force [m/s^2] from segments ``(kind, duration [s], size)``: ``stride`` (a swing, size = period),
    ``still`` (the foot at rest, tilted; size = spike height [m/s^2] of one sample in its middle, 0: none) and
    ``wobble`` (a shuffle that breaks a quiet stretch without a swing; size = amplitude [m/s^2])."""
    rng = np.random.default_rng(seed)
    parts: list[np.ndarray] = []
    tilt = 0.1
    for kind, dur, size in kinds:
        n = max(1, int(round(dur * rate)))
        ph = np.arange(n) / n
        a = np.tile([G0 * np.sin(tilt), 0.0, -G0 * np.cos(tilt)], (n, 1))
        if kind == "stride":
            ang = 0.8 * np.sin(np.pi * ph)
            a[:, 0] = -G0 * np.sin(ang) + 12.0 * np.sin(2 * np.pi * ph)
            a[:, 2] = -G0 * np.cos(ang) - 8.0 * np.sin(np.pi * ph) ** 2
            tilt = float(rng.uniform(-0.3, 0.3))
        elif kind == "wobble":
            a[:, 1] += size * np.sin(np.pi * ph)
        elif size:
            a[n // 2, 2] -= size
        parts.append(a)
    acc = np.concatenate(parts)
    acc += rng.normal(scale=0.05, size=acc.shape)
    return np.arange(acc.shape[0]) / rate, acc


_SEGMENTS = st.one_of(
    st.tuples(st.just("stride"), st.floats(0.6, 1.5), st.just(0.0)).map(lambda s: (s[0], s[1], s[1])),
    st.tuples(st.just("still"), st.floats(0.05, 25.0), st.sampled_from([0.0, 0.0, 2.0, 6.0, 12.0])),
    st.tuples(st.just("wobble"), st.floats(0.04, 0.6), st.floats(0.5, 4.0)),
)


@settings(max_examples=30, deadline=None)
@given(rate=st.sampled_from([25.0, 200.0]), kinds=st.lists(_SEGMENTS, min_size=2, max_size=14),
       cuts=st.lists(st.floats(0.0, 1.0), max_size=12), restore=st.booleans(), seed=st.integers(0, 3))
@example(rate=25.0, kinds=[("stride", 1.0, 1.0)] * 3 + [("stride", 1.5, 1.5)] * 2 + [("still", 25.0, 12.0),
                                                                                  ("still", 6.0, 6.0)],
         cuts=[], restore=False, seed=0)  # found by hypothesis: the buffer dropped the swing test's spike
@example(rate=25.0, kinds=[("still", 18.5, 0.0), ("stride", 0.625, 0.625), ("still", 1.0, 12.0), ("stride", 0.75, 0.75)],
         cuts=[], restore=False, seed=0)  # found by hypothesis: a candidate the latency bound decided read its
# look-ahead from the rest of the chunk (the cut at 21.84 s, 0.2 s after its end, chose the other half of the stance)
def test_collapsed_quiet_stretches_give_the_same_events(rate: float, kinds: list, cuts: list[float], restore: bool,
                                                        seed: int) -> None:
    """Stands of up to 25 s (collapsed after ~7 s) between strides, shuffles and one-sample spikes (the maximum
    the collapsed samples keep), a stand right after a stance (its stretch loses the competition, so the next
    stance's swing test spans the collapsed samples), cut anywhere (inside stands too), with state round trips:
    every event identical, field by field, to the segmenter that keeps every sample, fed in one piece."""
    kinds = [("stride", 1.1, 1.1), ("still", 0.5, 0.0)] + kinds + [("still", 9.0, 0.0)]
    t, acc = _pieces(rate, kinds, seed)
    ref = _reference(rate, t, acc)
    seg = StepSegmenter(rate)
    got = []
    bounds = [0, *sorted({int(c * t.size) for c in cuts} | set(range(0, t.size, int(7.3 * rate)))), t.size]
    for i, j in zip(bounds[:-1], bounds[1:]):
        if restore:
            seg = StepSegmenter.from_state(loads(dumps(seg.get_state())))
        got += seg.feed(t[i:j], acc[i:j])
    got += seg.flush()
    assert _collapsed(seg, t.size) > 0  # the last stand (9 s) at least
    assert _event_key(got) == _event_key(ref)


@settings(max_examples=30, deadline=None)
@given(rate=st.sampled_from([25.0, 200.0]), kinds=st.lists(_SEGMENTS, min_size=2, max_size=14),
       cuts=st.lists(st.floats(0.0, 1.0), max_size=12), seed=st.integers(0, 3), restore=st.booleans())
def test_no_step_comes_out_before_the_final_before_bound(rate: float, kinds: list, cuts: list[float], seed: int,
                                                         restore: bool) -> None:
    """``final_before_s`` (what the engine waits for before it works through a ZUPT-KF stance): no step emitted
    later has an earlier onset, the bound never moves back, it is at most ``latency_s`` behind the newest input
    (the fixed bound it replaces), and infinite once flushed."""
    kinds = [("stride", 1.1, 1.1)] + kinds + [("still", 3.0, 0.0)]
    t, acc = _pieces(rate, kinds, seed)
    seg = StepSegmenter(rate)
    assert seg.final_before_s == -np.inf
    bounds = [0, *sorted({int(c * t.size) for c in cuts} | set(range(0, t.size, int(0.37 * rate)))), t.size]
    bound, fresher = -np.inf, 0
    for i, j in zip(bounds[:-1], bounds[1:]):
        if restore:
            seg = StepSegmenter.from_state(loads(dumps(seg.get_state())))
        events = seg.feed(t[i:j], acc[i:j])
        assert all(e.t_s >= bound for e in events), (bound, [e.t_s for e in events])
        new = seg.final_before_s
        assert new >= bound
        if j > i:
            assert new >= t[j - 1] - seg.latency_s - 1e-9
            fresher += new > t[j - 1] - seg.latency_s + 0.2
        bound = new
    assert all(e.t_s >= bound for e in seg.flush())
    assert seg.final_before_s == np.inf
    assert fresher > 0


def test_a_stand_right_after_a_stance_gives_the_same_events() -> None:
    """The stand's quiet stretch starts within the swing rule of the stance before it (a shuffle between
    them), so it is not selected; the next step's swing test spans the collapsed samples (a spike among them)."""
    rate = 200.0
    kinds = [("stride", 1.1, 1.1), ("still", 0.3, 0.0)] * 4 + [("wobble", 0.1, 6.0), ("still", 30.0, 12.0)] + \
        [("stride", 1.1, 1.1), ("still", 0.3, 0.0)] * 4 + [("still", 3.0, 0.0)]
    t, acc = _pieces(rate, kinds, 1)
    ref = _reference(rate, t, acc)
    seg = StepSegmenter(rate)
    got: list = []
    unselected_collapsed = False
    for i in range(0, t.size, 200):
        got += seg.feed(t[i:i + 200], acc[i:i + 200])
        run, last = seg._run, seg._last
        if run[0] > 0 and run[8] > 0 and last[3] < run[1] and run[4] > seg._bt.size:
            unselected_collapsed = True  # the stretch lost the competition and its samples were collapsed
    got += seg.flush()
    assert unselected_collapsed
    assert len(ref) >= 8 and _event_key(got) == _event_key(ref)


@pytest.mark.parametrize("rate", [25.0, 200.0])
def test_state_is_bounded_while_standing(rate: float) -> None:
    """Walk, stand 60 min (25 Hz; 12 min at 200 Hz), walk, in 1-s pieces: the state after 10 min of standing
    and 1 min before the stand ends are the same size (7.5 kB at 25 Hz, 29 kB at 200 Hz), and the events are
    those of the segmenter that keeps every sample, also across a state round trip inside the stand."""
    stand_min = 60.0 if rate == 25.0 else 12.0
    walk = [("stride", 1.1, 1.1)] * 10
    t, acc = _pieces(rate, walk + [("still", 60.0 * stand_min, 0.0)] + walk + [("still", 3.0, 0.0)], 2)
    ref = _reference(rate, t, acc)
    n1 = int(rate)
    start = int(round(11.0 * rate))  # the stand starts after the 10 strides [samples]
    marks = {start + int(600 * rate): 0, start + int((stand_min - 1.0) * 60 * rate): 0}
    seg = StepSegmenter(rate)
    got: list = []
    for i in range(0, t.size, n1):
        got += seg.feed(t[i:i + n1], acc[i:i + n1])
        if i + n1 in marks:
            marks[i + n1] = len(dumps(seg.get_state()))
        if i + n1 == start + int(1800 * rate):
            seg = StepSegmenter.from_state(loads(dumps(seg.get_state())))
    got += seg.flush()
    assert _event_key(got) == _event_key(ref) and len(got) == 20
    small, large = marks.values()
    assert abs(large - small) < 100, marks
    assert 0 < large < (10_000 if rate == 25.0 else 40_000), marks


def test_a_state_stored_uncollapsed_mid_stand_restores_and_collapses() -> None:
    """A state written mid-stand by the segmenter that kept every sample (what sessions stored before) restores,
    is collapsed at the next feed, and gives the same events."""
    rate = 25.0
    walk = [("stride", 1.1, 1.1)] * 6
    t, acc = _pieces(rate, walk + [("still", 600.0, 0.0)] + walk + [("still", 3.0, 0.0)], 3)
    ref = _reference(rate, t, acc)
    old = StepSegmenter(rate)
    old._compact = False
    k = int(300 * rate)
    got = old.feed(t[:k], acc[:k])
    assert old._bt.size > 290 * rate
    seg = StepSegmenter.from_state(loads(dumps(old.get_state())))
    got += seg.feed(t[k:k + 25], acc[k:k + 25])
    assert seg._bt.size < 200
    got += seg.feed(t[k + 25:], acc[k + 25:]) + seg.flush()
    assert _event_key(got) == _event_key(ref) and len(got) == 12


# -- a change of pace: walk -> run at the Gait-DR rate ----------------------------------------------------------
def _walk_then_run(walk: str, seed: int, rate: float = 25.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A synthetic walk then a run (no stop), decimated to ``rate`` as the device does: times [s], specific force
    [m/s^2], truth heel strikes [s]."""
    from clients.synth import Scenario, Segment, synthesize

    scn = Scenario("walk-run", (Segment("stand", 3.0), Segment(walk, 12.0), Segment("run", 10.0),
                                Segment("stand", 3.0)))
    rec = synthesize(scn, seed=seed)
    dec = Decimator(rec.batch.rate_hz("acc"), rate)
    t1, a1 = dec.process(rec.batch.acc_t_ns, rec.batch.acc)
    t2, a2 = dec.flush()
    return np.r_[t1, t2] * 1e-9, np.r_[a1, a2], np.asarray(rec.truth.extra["step_t_s"])


@pytest.mark.parametrize(("walk", "seed"), [("walk_slow", 0), ("walk_slow", 3), ("walk", 1)])
def test_no_stride_lost_when_a_walk_turns_into_a_run(walk: str, seed: int) -> None:
    """Run strides (0.74 s) after a walk (1.15-1.35 s) fall inside the refractory period of the walking period
    estimate; the still run stances after a swing are strides nonetheless. Before that rule one stance of each
    pair was suppressed (walk_slow: 12-14 of 21 strides, the estimate locked on the doubled period; walk, seed 1:
    the second run stride lost). Every heel strike found, none added, at 25 Hz without the gyroscope."""
    t, acc, truth = _walk_then_run(walk, seed)
    seg = StepSegmenter(25.0)
    ev = seg.feed(t, acc) + seg.flush()
    on = np.array([e.t_s for e in ev])
    assert on.size == truth.size
    assert np.max(np.abs(on - truth)) < 0.1  # stance onset vs heel strike [s]
    run = np.array([e.period_s for e in ev[-12:]])  # the run's strides after its first (13 in all)
    assert np.allclose(run, 0.74, rtol=0.1)


@settings(max_examples=15, deadline=None)
@given(cuts=st.lists(st.integers(min_value=0, max_value=700), max_size=8), small=st.integers(min_value=1, max_value=30))
def test_walk_to_run_chunk_invariance_and_state_round_trip(cuts: list[int], small: int) -> None:
    t, acc, _ = _walk_then_run("walk_slow", 0)
    ref = StepSegmenter(25.0).feed(t, acc)
    bounds = [0, *sorted({c for c in cuts + list(range(380, 480, small)) if c < t.size}), t.size]
    seg = StepSegmenter(25.0)
    got = []
    for i, j in zip(bounds[:-1], bounds[1:]):
        seg = StepSegmenter.from_state(loads(dumps(seg.get_state())))
        got += seg.feed(t[i:j], acc[i:j])
    assert _event_key(got) == _event_key(ref)


def test_a_state_stored_before_the_stance_statistic_was_kept_restores() -> None:
    """``last`` without the stance's statistic (7 values): restored as not still (the refractory rule applies
    to the next candidate), and the strides after it are found."""
    t, acc = synthetic_foot(25.0, strides=12)
    seg = StepSegmenter(25.0)
    k = int(6.3 * 25)
    first = seg.feed(t[:k], acc[:k])
    d = seg.get_state()
    d["last"] = d["last"][:7]
    seg = StepSegmenter.from_state(loads(dumps(d)))
    assert seg._last.size == 9 and seg._last[7] == np.inf and seg._last[8] == 0.0
    assert len(first) + len(seg.feed(t[k:], acc[k:])) == 12


@pytest.mark.parametrize("rate", [25.0, 200.0])
@pytest.mark.parametrize("stop_s", [1.2, 0.5])
def test_a_stride_after_a_short_pause_has_the_pace_not_the_pause(rate: float, stop_s: float) -> None:
    """A stop of 1.2 s (shorter than ``max_period_s``) inside a walk of 1.1-s strides: the stride after it was
    given 2.3 s (the time since the previous onset), a cadence of 0.44 Hz that the step-length model and the
    fitted cadence range took in. A stop of 0.5 s (a stance of 0.95 s, shorter than the stride) was still given
    1.6 s. It has the pace of the strides before it."""
    stride = [("stride", 0.65, 0.65), ("still", 0.45, 0.0)]
    t, acc = _pieces(rate, [("still", 2.0, 0.0)] + stride * 6 + [("still", stop_s, 0.0)] + stride * 4
                     + [("still", 3.0, 0.0)], 0)
    seg = StepSegmenter(rate)
    ev = seg.feed(t, acc) + seg.flush()
    assert len(ev) == 10 and not any(e.after_rest for e in ev[1:])
    assert np.allclose([e.period_s for e in ev[1:]], 1.1, rtol=0.05)
    # the stride after the stop is marked: its period is the estimate, not its own (the step model of another
    # behaviour's pace must not take it, energy.gait_dr.GaitPipeline.features); the others were measured
    assert [e.paused for e in ev] == [False] * 6 + [True] + [False] * 3


def test_a_sudden_slow_down_reaches_the_period_estimate() -> None:
    """From 1.1-s strides to 1.6-s ones whose stance (0.95 s) is most of the old stride, at Gait-DR's 25 Hz: the
    first slow stride is taken for one after a pause (the pace before it), but never two in a row, so the
    estimate follows the slower pace from the 6th slow stride on (3 of the first 5 at the old pace: the price
    of the pause rule); a stance taken for a pause every time would have kept the estimate at 1.1 s for good."""
    rate = 25.0
    fast = [("stride", 0.65, 0.65), ("still", 0.45, 0.0)]
    slow = [("stride", 0.65, 0.65), ("still", 0.95, 0.0)]
    t, acc = _pieces(rate, [("still", 2.0, 0.0)] + fast * 6 + slow * 10 + [("still", 3.0, 0.0)], 0)
    seg = StepSegmenter(rate)
    ev = seg.feed(t, acc) + seg.flush()
    assert len(ev) == 16
    periods = np.array([e.period_s for e in ev])
    assert np.allclose(periods[1:6], 1.1, rtol=0.05)
    assert np.sum(periods[7:] < 1.3) == 3  # the first slow strides, every other one
    assert np.allclose(periods[-4:], 1.6, rtol=0.05)
    assert seg._last[8] == 0.0


def test_buffer_appends_times_and_norms() -> None:
    """The segmenter's buffer append (``_k_append``): the old rows, then the new times and each new row's |a|."""
    from models.steps import _k_append

    rng = np.random.default_rng(5)
    a = rng.normal(size=(2000, 3)) * rng.lognormal(size=(2000, 1)) * 5.0
    t = np.arange(2000.0)
    for lo, hi in ((0, 1), (0, 25), (3, 60), (7, 2000)):
        bt, bm = np.empty(5 + hi - lo), np.empty(5 + hi - lo)
        _k_append(np.arange(5.0), np.ones(5), t[lo:hi], np.ascontiguousarray(a[lo:hi]), bt, bm)
        np.testing.assert_allclose(bm[5:], np.linalg.norm(a[lo:hi], axis=1), rtol=1e-15, atol=0)
        assert np.array_equal(bt, np.concatenate([np.arange(5.0), t[lo:hi]]))
        assert np.array_equal(bm[:5], np.ones(5))
