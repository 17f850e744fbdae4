"""Behaviour recogniser: chunk invariance, state round trip, synthetic transitions, rate robustness, real data."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from clients.synth import synthesize
from models.behaviour import (
    HOP_S,
    LABELS,
    WINDOW_S,
    BehaviourRecognizer,
    WindowFeatures,
    classify_window,
    decide_window,
    label_recording,
    window_features,
)

MAX_DELAY_S = 2.0  # issue 4: synthetic transitions detected within 2 s
MAX_RUN_FRACTION_WALKING = 0.10  # gdin walking recordings: at most brief fast stretches labelled run
FAST_STRIDE_MPS = 1.5  # a stride at least this fast is "fast walking or faster" (normal walking 1.0-1.4 m/s)


@pytest.fixture(scope="module")
def demo():
    r = synthesize("demo", seed=3)
    return r.batch.acc_t_ns / 1e9, r.batch.acc, r


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(cuts=st.lists(st.integers(1, 22999), min_size=1, max_size=12, unique=True))
def test_chunk_invariant(demo, cuts):
    t, a, _ = demo
    whole = label_recording(t, a)
    r = BehaviourRecognizer()
    out = []
    edges = [0] + sorted(cuts) + [len(t)]
    for i0, i1 in zip(edges[:-1], edges[1:]):
        out += r.process(t[i0:i1], a[i0:i1])
    assert out == whole


@pytest.mark.parametrize("cut", [1, 4000, 12345, 22000])
def test_state_round_trip_mid_stream(demo, cut):
    t, a, _ = demo
    whole = label_recording(t, a)
    r = BehaviourRecognizer(rate_hz_hint=200.0)
    first = r.process(t[:cut], a[:cut])
    r2 = BehaviourRecognizer.from_state(r.get_state())
    assert first + r2.process(t[cut:], a[cut:]) == whole


def _transitions(segments: list[tuple[float, float, str]]) -> list[tuple[float, str]]:
    out, prev = [], None
    for t0, t1, lab in segments:
        if t1 - t0 < 3.0:  # a rest shorter than a window is not a behaviour of its own
            continue
        if prev is not None and lab != prev:
            out.append((t0, lab))
        prev = lab
    return out


@pytest.mark.parametrize("scenario,seed", [("demo", 0), ("demo", 1), ("mixed-day", 0), ("run", 2), ("walk", 5)])
def test_synthetic_transitions_detected_within_2s(scenario, seed):
    r = synthesize(scenario, seed=seed)
    dec = label_recording(r.batch.acc_t_ns / 1e9, r.batch.acc)
    td = np.array([d[0] for d in dec])
    labels = np.array([d[1] for d in dec])
    trans = _transitions(r.truth.extra["segments"])
    assert trans, "scenario without transitions"
    for t0, lab in trans:
        hit = np.flatnonzero((td >= t0) & (labels == lab))
        assert hit.size, f"{lab} after {t0:.1f} s never recognised"
        assert td[hit[0]] - t0 <= MAX_DELAY_S, f"{lab} at {t0:.1f} s recognised after {td[hit[0]] - t0:.2f} s"


@pytest.mark.parametrize("factor", [4, 8])  # 200 Hz -> 50 Hz and 25 Hz
def test_same_labels_after_desampling(demo, factor):
    t, a, _ = demo
    full = dict(label_recording(t, a))
    low = dict(label_recording(t[::factor], a[::factor]))
    common = sorted(set(full) & set(low))
    agree = np.mean([full[k] == low[k] for k in common])
    assert agree >= 0.95, f"only {agree:.3f} of decisions agree at 200/{factor} Hz"


def test_synthetic_labels_match_truth(demo):
    t, a, r = demo
    truth = r.truth.extra["behaviour"]
    dec = label_recording(t, a)
    idx = np.clip(np.round(np.array([d[0] for d in dec]) * 200).astype(int) - 1, 0, len(truth) - 1)
    ok = np.mean([truth[i] == lab for i, (_, lab) in zip(idx, dec)])
    assert ok >= 0.9


@pytest.mark.parametrize("scenario", ["demo", "mixed-day"])
@pytest.mark.parametrize("factor", [1, 8])
def test_lazy_decision_equals_the_full_rule_set(scenario, factor):
    """decide_window computes only the features it needs but must give classify_window's label."""
    r = synthesize(scenario, seed=1)
    t, a = r.batch.acc_t_ns[::factor] / 1e9, r.batch.acc[::factor]
    n = np.linalg.norm(a, axis=1)
    labels = set()
    for td in np.arange(t[0] + WINDOW_S, t[-1], HOP_S):
        m = (t >= td - WINDOW_S) & (t < td)
        lab, f = decide_window(t[m], n[m])
        assert lab == classify_window(window_features(t[m], n[m])), f"window ending {td:.2f} s"
        assert f.still_std == pytest.approx(window_features(t[m], n[m]).still_std, rel=1e-12)  # compiled sums
        labels.add(lab)
    assert {"stand", "walk"} <= labels  # the comparison covered more than one branch


@pytest.mark.parametrize("factor", [1, 8])
def test_streaming_decisions_are_decide_window_of_each_window(factor):
    """The recogniser decides all the windows of a batch in one compiled pass; each decision must be
    decide_window's (label and features) on the window [td - WINDOW_S, td) of the samples seen so far."""
    rec = synthesize("mixed-day", seed=2)
    t, a = rec.batch.acc_t_ns[::factor] / 1e9, rec.batch.acc[::factor]
    n = np.linalg.norm(a, axis=1)
    r = BehaviourRecognizer()
    step = int(200 / factor)  # 1-s chunks
    labels = set()
    for i0 in range(0, len(t), step):
        out = r.process(t[i0:i0 + step], a[i0:i0 + step])
        decided = [td for td, _ in out if td - t[0] >= 1.0 and np.count_nonzero((t >= td - WINDOW_S) & (t < td)) >= 8]
        if not decided:
            continue
        m = (t >= decided[-1] - WINDOW_S) & (t < decided[-1])
        lab, f = decide_window(t[m], n[m])
        assert repr(r.features) == repr(f), f"window ending {decided[-1]:.2f} s"
        labels.add(lab)
    assert {"stand", "walk", "run"} <= labels


@pytest.mark.parametrize("factor", [1, 8])
@pytest.mark.parametrize("at_s", [15.0, 20.0, 25.0, 45.0])
def test_one_odd_stride_does_not_flip_walk(at_s, factor):
    """Hysteresis: one running stride (0.74 s of the synthetic run) spliced into a walk gives no run label."""
    w, r = synthesize("walk", seed=1), synthesize("run", seed=1)
    tw, a = w.batch.acc_t_ns / 1e9, w.batch.acc.copy()
    i0, j0, n = int(np.searchsorted(tw, at_s)), int(np.searchsorted(r.batch.acc_t_ns / 1e9, 20.0)), 148
    a[i0 : i0 + n] = r.batch.acc[j0 : j0 + n]
    labels = {lab for _, lab in label_recording(tw[::factor], a[::factor])}
    assert labels == {"stand", "walk"}


def test_vote_needs_three_of_the_last_four():
    r = BehaviourRecognizer()
    r.label = "walk"
    for d in ["run", "walk", "run", "walk", "run", "walk"]:  # alternating: never 3 of 4
        r._vote(d)
        assert r.label == "walk"
    for d, want in [("run", "walk"), ("run", "run")]:  # run, walk, run, run: 3 of the last 4
        r._vote(d)
        assert r.label == want


def test_run_on_which_the_cues_agree_needs_two_of_the_last_three():
    r = BehaviourRecognizer()
    r.label = "walk"
    r._vote("run", fast=True)  # one decision is not a change
    assert r.label == "walk"
    r._vote("walk")
    r._vote("run", fast=True)  # run, walk, run: 2 of the last 3
    assert r.label == "run"
    r._vote("walk")
    r._vote("run")
    r._vote("walk")  # leaving run: 3 of the last 4 as before
    assert r.label == "run"


def test_state_of_the_consecutive_count_hysteresis_restores():
    r = BehaviourRecognizer()
    st = r.get_state()
    del st["recent"]
    st.update(label="walk", candidate="run", count=2)
    r2 = BehaviourRecognizer.from_state(st)
    r2._vote("run")
    assert r2.label == "run"  # the candidate's two wins carried over


@pytest.mark.parametrize("factor", [2, 8])
def test_duty_factor_is_a_fraction_of_time_in_mixed_rate_windows(demo, factor):
    """A window whose newer part comes at a lower rate (the engine lowered it) measures the same stance
    fraction and stride period as the same window at one rate."""
    t, a, _ = demo
    n = np.linalg.norm(a, axis=1)
    checked = 0
    for td in np.arange(20.0, 100.0, 1.37):
        m = (t >= td - WINDOW_S) & (t < td)
        tt, nn = t[m], n[m]
        mid = tt.size // 2
        keep = np.r_[np.arange(mid), np.arange(mid, tt.size)[::factor]]
        full, mixed = window_features(tt, nn), window_features(tt[keep], nn[keep])
        if full.stance_fraction >= 1.0 or mixed.stance_fraction >= 1.0:
            continue
        assert mixed.stance_fraction == pytest.approx(full.stance_fraction, abs=0.05), f"window ending {td:.2f} s"
        if full.periodicity > 0.5:
            assert mixed.stride_period_s == pytest.approx(full.stride_period_s, rel=0.05), f"window ending {td:.2f} s"
        checked += 1
    assert checked >= 30


def _run_stop_walk(stop_s: float, seed: int):
    """A run, a stop of ``stop_s`` (plus the rest after the last running stride), then fast walking."""
    from clients.synth import Scenario, Segment

    scn = Scenario("run-stop-walk", (Segment("stand", 5.0), Segment("run", 20.0), Segment("stand", stop_s),
                                     Segment("walk_fast", 20.0), Segment("stand", 5.0)))
    return synthesize(scn, seed=seed)


def test_a_stop_ends_the_gait_in_the_duty_factor():
    """The strides before a stop (rest > MAX_STANCE_S) do not count in the duty factor of the gait after it."""
    from models.behaviour import MAX_STANCE_S, STANCE_TOL

    r = _run_stop_walk(1.2, seed=0)
    t, n = r.batch.acc_t_ns / 1e9, np.linalg.norm(r.batch.acc, axis=1)
    t_walk = next(a for a, _, lab in r.truth.extra["segments"] if lab == "walk")
    checked = 0
    for td in t_walk + np.arange(0.3, 1.3, 0.05):
        m = (t >= td - WINDOW_S) & (t < td)
        tt, nn = t[m], n[m]
        moving = np.flatnonzero(np.abs(nn - 9.80665) >= STANCE_TOL)
        gaps = np.flatnonzero(np.diff(moving) > 1)
        stops = [g for g in gaps if tt[moving[g + 1] - 1] - tt[moving[g] + 1] > MAX_STANCE_S]
        if not stops:  # the window starts inside the stop: no gait before it
            continue
        k = moving[stops[-1] + 1]  # first sample after the stop
        whole, after = window_features(tt, nn), window_features(tt[k:], nn[k:])
        assert whole.stance_fraction == after.stance_fraction
        assert whole.gait_s == pytest.approx(after.gait_s, abs=1e-12)
        assert decide_window(tt, nn)[1].stance_fraction == pytest.approx(after.stance_fraction, abs=1e-12)
        checked += 1
    assert checked >= 10


@pytest.mark.parametrize("factor", [1, 8])
@pytest.mark.parametrize("stop_s", [1.2, 1.6])
def test_walking_after_a_run_and_a_stop_within_2s(stop_s, factor):
    """Run, stop (shorter than a behaviour of its own), fast walking: walk recognised within 2 s. Before a stop
    ended the gait, the running strides before the stop kept the duty factor of the first walking strides low:
    worst 2.35 s (stop 1.2 s, 25 Hz) and 2.43 / 2.45 s (stop 1.6 s, 200 / 25 Hz)."""
    worst = 0.0
    for seed in range(4):
        r = _run_stop_walk(stop_s, seed)
        t_walk = next(a for a, _, lab in r.truth.extra["segments"] if lab == "walk")
        dec = label_recording(r.batch.acc_t_ns[::factor] / 1e9, r.batch.acc[::factor])
        worst = max(worst, next(td for td, lab in dec if td >= t_walk and lab == "walk") - t_walk)
    assert worst <= MAX_DELAY_S


def test_run_needs_vigour():
    """A low duty factor alone is not running: gentle first steps (less than a stride visible) read one too."""
    from models.behaviour import RUN_MIN_GAIT_STD

    def f(gait_std: float) -> WindowFeatures:
        return WindowFeatures(dc=10.0, variance=gait_std**2, energy=gait_std**2, still_std=gait_std,
                              stance_fraction=0.2, stride_period_s=0.75, periodicity=0.8, gait_s=3.0, gait_std=gait_std)

    assert classify_window(f(RUN_MIN_GAIT_STD + 1.0)) == "run"
    assert classify_window(f(RUN_MIN_GAIT_STD - 1.0)) == "walk"


def test_running_cadence_and_energy_confirm_run():
    """A duty factor below the walking median is run when the cadence and the energy are running's (the 3-s
    window still holds the walking strides of before a walk-to-run change); either cue alone is not."""
    from models.behaviour import CADENCE_RUN_PERIOD_S, CADENCE_RUN_STANCE, CADENCE_RUN_STD, JOG_STANCE

    def f(period_s: float, still_std: float) -> WindowFeatures:
        return WindowFeatures(dc=11.0, variance=144.0, energy=145.0, still_std=still_std,
                              stance_fraction=(JOG_STANCE + CADENCE_RUN_STANCE) / 2, stride_period_s=period_s,
                              periodicity=0.6, gait_s=3.0, gait_std=12.0)

    assert classify_window(f(CADENCE_RUN_PERIOD_S - 0.1, CADENCE_RUN_STD + 1.0)) == "run"
    assert classify_window(f(CADENCE_RUN_PERIOD_S + 0.1, CADENCE_RUN_STD + 1.0)) == "walk"
    assert classify_window(f(CADENCE_RUN_PERIOD_S - 0.1, CADENCE_RUN_STD - 1.0)) == "walk"


def test_labels_are_known():
    t = np.arange(2000) / 200.0
    a = np.tile([0.0, 0.0, -9.81], (2000, 1))
    labs = {lab for _, lab in label_recording(t, a)}
    assert labs <= set(LABELS) and labs == {"stand"}


# ------------------------------------------------------------------ real data
def _vicon_labels(vicon_dir: Path) -> dict[str, str]:
    rows = {}
    for line in (vicon_dir / "ABOUT.md").read_text().splitlines():
        m = re.match(r"\| (20\d\d-[\d-]+) \| [\d.]+ \| [\d.]+ \| ([^|]+) \|", line)
        if m:
            rows[m.group(1)] = m.group(2).strip()
    return rows


@pytest.mark.slow
@pytest.mark.parametrize("factor", [1, 8])
def test_vicon_walk_vs_run(vicon_dir, factor):
    """>= 97 % of the walk/run decisions on trials labelled walk or run carry the trial's label (issue 4)."""
    from clients.importers import load

    labels = _vicon_labels(vicon_dir)
    ok = n = 0
    confusion: dict[str, dict[str, int]] = {}
    for name, lab in labels.items():
        truth = "walk" if lab.startswith("walk") else "run" if lab.startswith("run") else None
        if truth is None:
            continue
        r = load(vicon_dir / f"{name}.mat")
        t = r.batch.acc_t_ns / 1e9
        dec = [d for _, d in label_recording(t[::factor], r.batch.acc[::factor])]
        row = confusion.setdefault(truth, dict.fromkeys(LABELS, 0))
        for d in dec:
            row[d] += 1
        gait = [d for d in dec if d in ("walk", "run")]
        ok += sum(d == truth for d in gait)
        n += len(gait)
    print(f"vicon 200/{factor} Hz confusion (trial label -> decisions): {confusion}")
    assert ok / n >= 0.97, f"walk vs run correct {ok}/{n} = {ok / n:.3f}"


@pytest.mark.slow
@pytest.mark.parametrize(
    "factor",
    [
        1,
        pytest.param(8, marks=pytest.mark.xfail(
            strict=True,
            reason="measured 2026-11-22 at 25 Hz: exp21 10.6 % run (24.0-29.25 s; its windows all overlap its "
            "fastest ZUPT-KF strides, see test_gdin_run_labels_fall_in_fast_stretches), every other walk 0 %")),
    ],
)
def test_gdin_walks_not_run(gdin_dir, factor):
    """No run labels on the gdin walking recordings apart from the fastest (truth mean speed >= 1.5 m/s)."""
    from clients.importers import list_recordings, load

    failing = []
    for p in list_recordings(gdin_dir):
        r = load(p)
        extra = r.truth.extra if r.truth else {}
        path_m = extra.get("truth_path_length_m")
        dur = (r.batch.acc_t_ns[-1] - r.batch.acc_t_ns[0]) / 1e9
        if path_m is None or path_m / dur >= 1.5:
            continue
        dec = [d for _, d in label_recording(r.batch.acc_t_ns[::factor] / 1e9, r.batch.acc[::factor])]
        frac = dec.count("run") / len(dec)
        print(f"{r.name}: {path_m / dur:.2f} m/s, run fraction {frac:.3f}")
        if frac > MAX_RUN_FRACTION_WALKING:
            failing.append(r.name)
    # Measured 2026-11-22 after the recency-weighted duty factor, 200 Hz: exp21 8.7 % (run decisions 24.0-28.25 s,
    # on and just after its fastest ZUPT-KF strides, see the next test), every other walk 0 %.
    assert failing == []


def _fast_strides(r) -> tuple[np.ndarray, np.ndarray, str]:
    """Stride start/end times [s from the first sample] and speeds [m/s] of a gdin recording, and their source.

    Per-stride footprints where the recording has them (exp 31-43); otherwise the ZUPT-KF's stances (engine in
    ``zupt`` mode, gyroscope on: an estimate independent of the accelerometer-only recogniser, gdin loop
    closure ~0.4-3 %)."""
    from clients.evaluation.harness import run_engine

    t0 = r.batch.acc_t_ns[0]
    extra = r.truth.extra if r.truth else {}
    if "stride_t_ns" in extra:
        ts = (np.asarray(extra["stride_t_ns"]) - t0) / 1e9
        xy = np.asarray(extra["stride_gcp_xy"], dtype=float)
        src = "footprints"
    else:
        st = run_engine(r.batch, "zupt").stances
        ts, xy, src = (st[:, 0] - t0) / 1e9, st[:, 1:3], "zupt-kf"
    v = np.linalg.norm(np.diff(xy, axis=0), axis=1) / np.maximum(np.diff(ts), 1e-3)
    return ts, v, src


@pytest.mark.slow
@pytest.mark.parametrize("factor", [1, 8])
def test_gdin_run_labels_fall_in_fast_stretches(gdin_dir, factor):
    """Run decisions on gdin must fall in fast stretches: a stride of >= FAST_STRIDE_MPS overlapping the
    decision's window. Stride speeds from the footprints (exp 31-43) or, where gdin has only corner GCPs, from
    the ZUPT-KF (see _fast_strides). Measured 2026-12-01, 200 Hz / 25 Hz: exp34 63/63 / 63/63, exp35 76/76 /
    79/80, exp43 108/108 / 104/104 (footprints), exp21 18/18 / 22/22 (ZUPT-KF: its fastest strides are
    22.0-24.7 s at 1.68-1.76 m/s, then 25.7-26.7 s at 1.56 m/s); no run decision on any other recording
    (2026-11-22, before run needed vigour: exp34 63/66 / 63/63, exp35 78/78 / 83/84, exp43 109/113 / 105/110)."""
    from clients.importers import list_recordings, load
    from models.behaviour import WINDOW_S

    n_run = n_fast = 0
    rows = []
    for p in list_recordings(gdin_dir):
        r = load(p)
        t0 = r.batch.acc_t_ns[0]
        dec = label_recording((r.batch.acc_t_ns[::factor] - t0) / 1e9, r.batch.acc[::factor])
        runs_t = [td for td, lab in dec if lab == "run"]
        if not runs_t:
            continue
        ts, v, src = _fast_strides(r)
        fast = 0
        for td in runs_t:
            m = (ts[1:] >= td - WINDOW_S) & (ts[:-1] <= td)
            fast += bool(m.any() and v[m].max() >= FAST_STRIDE_MPS)
        rows.append(f"{r.name} {fast}/{len(runs_t)} ({src})")
        n_run, n_fast = n_run + len(runs_t), n_fast + fast
    print(f"200/{factor} Hz gdin run decisions in fast stretches:", "; ".join(rows))
    assert n_run and n_fast / n_run >= 0.9


# ------------------------------------------------------------------ transition latency, measured more widely
def _latencies(scenarios, factor):
    """Delay [s] from each synthetic behaviour change to the first decision carrying the new label."""
    out = {}
    for sc, seed in scenarios:
        r = synthesize(sc, seed=seed)
        dec = label_recording(r.batch.acc_t_ns[::factor] / 1e9, r.batch.acc[::factor])
        td = np.array([d[0] for d in dec])
        labels = np.array([d[1] for d in dec])
        prev = None
        for t0, t1, lab in r.truth.extra["segments"]:
            if t1 - t0 < 3.0:
                continue
            if prev is not None and lab != prev:
                hit = np.flatnonzero((td >= t0) & (labels == lab))
                out.setdefault(f"{prev}->{lab}", []).append(float(td[hit[0]] - t0) if hit.size else float("inf"))
            prev = lab
    return out


@pytest.mark.slow
@pytest.mark.parametrize(
    "factor,seeds",
    [
        (1, range(6)),
        (8, range(6)),
        # seeds 6-13 were not looked at while the recogniser was first designed; the 2026-12 changes (a stop ends
        # the gait, run needs vigour, running cadence and energy) were measured on them
        (1, range(6, 14)),
        (8, range(6, 14)),
    ],
)
def test_every_synthetic_transition_within_2s_over_seeds(factor, seeds):
    """Every behaviour change of synthetic days at 200 Hz and 25 Hz recognised within 2 s (issue 4).
    Measured 2026-12-01: seeds 0-5 worst 2.00 s (run->walk mixed-day/4, as before) at 200 Hz, 1.75 s at 25 Hz;
    seeds 6-13 worst 1.75 s at 200 and 25 Hz (was 1.82 s and, at 25 Hz, 3 of 104 over 2 s: walk->run 2.06 s
    demo/6 and 2.31 s demo/9, run->walk_fast 2.54 s demo/10)."""
    scen = [(sc, seed) for sc in ("demo", "mixed-day") for seed in seeds]
    lat = _latencies(scen, factor)
    summary = {k: (len(v), round(max(v), 2), round(float(np.median(v)), 2)) for k, v in sorted(lat.items())}
    print(f"200/{factor} Hz transition latency (n, max s, median s): {summary}")
    assert max(max(v) for v in lat.values()) <= MAX_DELAY_S


@pytest.mark.slow
def test_transition_latency_through_the_engine():
    """The engine's behaviour events while the device follows its sensor commands (25 Hz in Gait-DR and
    standing): every transition recognised within 2 s (issue 4). Measured 2026-11-22: worst 1.75 s (was
    2.28 s before the duty factor became a time fraction in windows that mix the rates)."""
    from energy.device import replay
    from energy.engine import Engine

    worst = 0.0
    rows = []
    for sc, seed in [("demo", 0), ("demo", 1), ("mixed-day", 0)]:
        r = synthesize(sc, seed=seed)
        res = replay(Engine(mode="auto"), r.batch)
        ev = [(e.t_ns / 1e9, e.detail["to"]) for u in res.updates for e in u.events if e.kind == "behaviour"]
        te = np.array([t for t, _ in ev])
        le = np.array([lab for _, lab in ev])
        for t0, lab in _transitions(r.truth.extra["segments"]):
            hit = np.flatnonzero((te >= t0) & (le == lab))
            d = float(te[hit[0]] - t0) if hit.size else float("inf")
            rows.append(f"{sc}/{seed} {lab}@{t0:.1f}s {d:.2f}s")
            worst = max(worst, d)
    print("engine-loop transition latency:", "; ".join(rows), f"; worst {worst:.2f} s")
    assert worst <= MAX_DELAY_S


def _stance_walk_then_stop(stance_s: float, rate_hz: float, walk_s: float = 12.0, stop_s: float = 4.0,
                           swing_s: float = 0.6, seed: int = 0) -> tuple[np.ndarray, np.ndarray, float]:
    """|a| of a foot that rests ``stance_s`` per stride (within 0.05 m/s^2 of g) and swings ``swing_s`` (|a| up to
    6 m/s^2 off g), for ``walk_s``, then stands still for ``stop_s``; returns times [s], specific force (N, 3)
    [m/s^2] and the time the foot goes quiet for good [s]: its last sample off g by ``QUIET_TOL`` or more (the
    swing's edges are already quiet)."""
    from models.behaviour import G, QUIET_TOL

    rng = np.random.default_rng(seed)
    t = np.arange(0.0, walk_s + stop_s, 1.0 / rate_hz)
    stride = stance_s + swing_s
    n_strides = int(walk_s // stride)
    t_quiet = n_strides * stride
    phase = t % stride
    swing = (phase >= stance_s) & (t < t_quiet)
    n = G + rng.normal(0.0, 0.05, t.size)
    n[swing] = G + 6.0 * np.sin(np.pi * (phase[swing] - stance_s) / swing_s) * np.sign(np.sin(
        4 * np.pi * (phase[swing] - stance_s) / swing_s) + 1e-9)
    acc = np.zeros((t.size, 3))
    acc[:, 2] = n
    return t, acc, float(t[np.abs(n - G) >= QUIET_TOL][-1])


@settings(max_examples=12, deadline=None)
@given(stance_s=st.floats(0.2, 0.9), rate_hz=st.sampled_from([25.0, 200.0]), seed=st.integers(0, 3))
def test_quiet_timer_enters_stand_after_a_stop_and_never_cuts_a_stance(stance_s, rate_hz, seed):
    """The stop signal of the recogniser is the quiet timer: whatever the walker's stance duration D (up to 0.9 s,
    below the longest quiet stretch of real walking, 0.94 s), stand is entered within ``STAND_ENTER_S`` plus one
    decision interval (and a sample) of the foot going quiet for good, and never while the foot still walks (the
    stances of a slow walk are not cut into stands). docs/behaviour.md: no faster stop signal from |a| was found
    that keeps the second half of this."""
    from models.behaviour import STAND_ENTER_S

    t, acc, t_quiet = _stance_walk_then_stop(stance_s, rate_hz, seed=seed)
    dec = label_recording(t, acc)
    left = next(td for td, lab in dec if lab != "stand")  # the recogniser starts as stand
    assert left < 4.0
    walking = [lab for td, lab in dec if left <= td < t_quiet]
    assert "stand" not in walking
    entered = next(td for td, lab in dec if td >= t_quiet and lab == "stand")
    assert entered - t_quiet <= STAND_ENTER_S + HOP_S + 1e-9
    assert entered - t_quiet >= STAND_ENTER_S - 1e-9  # no earlier than the timer: it is the only stop signal
