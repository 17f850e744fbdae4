"""Behaviour recognition, leave-one-group-out, and the limits of the labelled real recordings.

The recogniser (:mod:`models.behaviour`) is one fixed rule set; the one constant that was read off the labelled
real recordings themselves is ``STAND_ENTER_S``, the quiet time after which it enters ``stand`` at once: it must
lie above every quiet stretch (``| |a| - g | < QUIET_TOL``) inside labelled walking, running and ``other`` time.
:func:`leave_one_group_out` re-derives it for every group from the other groups only (:func:`fit_stand_enter`:
the next 0.1 s above their longest quiet stretch, never below ``MAX_STANCE_S`` - the value the module holds) and
scores the recogniser with it on the held-out group alone, at the recorded rate and de-sampled. A group is one
recording (a VICON trial, a gdin walk) or, gaitmap, both feet of its one walk: 42 + 10 + 1 = 53 groups.

:func:`oracle_decisions` is the bound that lag alone sets: a recogniser that knows each gdin stride's label (its
speed between the measured footprints) as soon as the stride is over, and holds the last one until the next is
over. On the recordings that change pace every few strides it loses the first stride of every pace; no
recogniser that needs to see a stride before it decides can beat it there.

:func:`labelled_features` gives the recogniser's features inside labelled ranges (duty factor from ``|a|``, |a|
spread, stride period), the evidence of the label conflict between gdin exp34's walking and VICON
trial 2017-11-22-11-44-47, a run by the dataset's table (docs/behaviour.md). ``python -m
clients.evaluation.behaviour_fit [ROOT]`` prints all of it as one JSON document.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from clients.evaluation import behaviour as bh

__all__ = [
    "group_of",
    "quiet_in_gait",
    "fit_stand_enter",
    "leave_one_group_out",
    "gdin_strides",
    "oracle_decisions",
    "oracle_shares",
    "labelled_features",
    "acc_p99_g",
    "quiet_stretches",
    "recent_stance",
    "stop_signal_evidence",
    "main",
]

_GAIT = ("walk", "run", "other")


def group_of(dataset: str, recording: str) -> str:
    """The group a recording is held out with: itself, except gaitmap's two feet (one walk, one person)."""
    return f"{dataset}/{recording.rsplit('-', 1)[0]}" if dataset == "gaitmap" else f"{dataset}/{recording}"


def quiet_in_gait(t_s: np.ndarray, acc: np.ndarray, ranges: Sequence[bh.LabelRange]) -> np.ndarray:
    """Durations [s] of the quiet stretches inside labelled walk/run/other time: per stretch of samples with
    ``| |a| - g | < QUIET_TOL``, the time between the non-quiet samples on either side (what the recogniser's
    quiet timer reads at its largest), kept when both lie in one gait range."""
    from models.behaviour import G, QUIET_TOL

    t = np.asarray(t_s, dtype=float)
    loud = np.flatnonzero(np.abs(np.linalg.norm(acc, axis=1) - G) >= QUIET_TOL)
    if loud.size < 2:
        return np.zeros(0)
    t0, t1 = t[loud[:-1]], t[loud[1:]]
    out = []
    for r in ranges:
        if r.label in _GAIT:
            m = (t0 >= r.t0_s) & (t1 < r.t1_s)
            out.append((t1 - t0)[m])
    return np.concatenate(out) if out else np.zeros(0)


def fit_stand_enter(quiet: Sequence[np.ndarray]) -> float:
    """``STAND_ENTER_S`` [s] from the training groups' quiet stretches in gait: the next 0.1 s above the longest,
    at least ``MAX_STANCE_S``."""
    from models.behaviour import MAX_STANCE_S

    longest = max((float(q.max()) for q in quiet if q.size), default=0.0)
    return round(max(MAX_STANCE_S, math.floor(longest * 10.0 + 1e-9) / 10.0 + 0.1), 1)


def _batches(root: Path, groups: dict[tuple[str, str], list[bh.LabelRange]],
             rates_hz: Sequence[float | None]) -> dict[tuple[str, str, str], Any]:
    """(dataset, recording, rate key) -> the accelerometer batch at that rate (recordings missing here skipped)."""
    from energy.device import desample

    out = {}
    for key in groups:
        try:
            b0 = bh._recording(root, *key).batch
        except (FileNotFoundError, KeyError):
            continue
        for rate in rates_hz:
            b = desample(b0, rate) if rate is not None and rate < 0.9 * b0.rate_hz("acc") else b0
            out[(*key, "recorded" if rate is None else f"{rate:g}")] = b
    return out


def leave_one_group_out(root: Path, rates_hz: Sequence[float | None] = (None, 25.0),
                        ranges: Sequence[bh.LabelRange] | None = None,
                        progress: Callable[[str], None] | None = None) -> dict[str, Any]:
    """Per rate: every group scored by the recogniser whose ``STAND_ENTER_S`` was fitted on the other groups
    (:func:`fit_stand_enter`), the per-recording rows (``name``, ``group``, ``stand_enter_s`` and
    :func:`clients.evaluation.behaviour.score`'s metrics) and their :func:`clients.evaluation.behaviour.summarise`."""
    import models.behaviour as mb

    groups = bh.labelled_recordings(bh.read_labels() if ranges is None else ranges)
    batches = _batches(root, groups, rates_hz)
    out: dict[str, Any] = {"groups": 0, "rates": {}}
    held = mb.STAND_ENTER_S
    try:
        for rate in rates_hz:
            rk = "recorded" if rate is None else f"{rate:g}"
            keys = [k for k in groups if (*k, rk) in batches]
            quiet: dict[str, list[np.ndarray]] = {}
            for k in keys:
                b = batches[(*k, rk)]
                t = (b.acc_t_ns - b.acc_t_ns[0]) / 1e9
                quiet.setdefault(group_of(*k), []).append(quiet_in_gait(t, b.acc, groups[k]))
            rows = []
            for k in keys:
                g = group_of(*k)
                fitted = fit_stand_enter([q for h, qs in quiet.items() if h != g for q in qs])
                mb.STAND_ENTER_S = fitted
                b = batches[(*k, rk)]
                t = (b.acc_t_ns - b.acc_t_ns[0]) / 1e9
                dec = mb.BehaviourRecognizer().process(t, b.acc)
                rows.append({"name": f"{k[0]}/{k[1]}", "group": g, "rate_hz": round(float(b.rate_hz("acc")), 1),
                             "stand_enter_s": fitted, **bh.score(dec, groups[k]),
                             "missed_s": bh.missed_by_context(dec, groups[k])})
                if progress is not None:
                    progress(f"{rk} {k[1]}")
            longest = {h: max((float(q.max()) for q in qs if q.size), default=0.0) for h, qs in quiet.items()}
            out["groups"] = len(quiet)
            out["rates"][rk] = {"summary": bh.summarise(rows), "longest_quiet_in_gait_s": longest, "recordings": rows}
    finally:
        mb.STAND_ENTER_S = held
    return out


def gdin_strides(root: Path) -> dict[str, dict[str, np.ndarray]]:
    """gdin recording -> ``toe_off_s`` (the stride_gcp times, s from the first accelerometer sample) and per stride
    k (toe-off k-1 to toe-off k, k >= 1) its ``speed_ms`` between the measured footprints."""
    from clients.importers.gdin import find_gdin, load_gdin

    out = {}
    for e in find_gdin(root / "gdin"):
        rec = load_gdin(e)
        x = rec.truth.extra if rec.truth is not None else {}
        if x.get("stride_t_ns") is None or len(x["stride_t_ns"]) < 3:
            continue
        s = (np.asarray(x["stride_t_ns"], dtype=np.int64) - int(rec.batch.acc_t_ns[0])) / 1e9
        g = np.asarray(x["gcp_m"], dtype=float)
        n = min(len(s), len(g))
        speed = np.linalg.norm(np.diff(g[:n], axis=0), axis=1) / np.diff(s[:n])
        out[rec.name] = {"toe_off_s": s[:n], "speed_ms": speed}
    return out


def _pace(speed: float) -> str:
    """walk/run by a stride's speed (the label table's limits; between them the nearer one)."""
    return "walk" if speed < 0.5 * (bh._WALK_MAX_MS + bh._RUN_MIN_MS) else "run"


def oracle_decisions(toe_off_s: np.ndarray, speed_ms: np.ndarray, t_end_s: float,
                     hop_s: float = 0.25) -> list[tuple[float, str]]:
    """Decisions ``(t_s, label)`` every ``hop_s`` of a recogniser that knows each stride's pace once the stride is
    over (at its closing toe-off) and holds it until the next is over: ``stand`` before the first toe-off, the
    first stride's pace from then on (a free guess over the settling time), ``stand`` 1.5 s after the last
    toe-off (the label table's landing allowance)."""
    s = np.asarray(toe_off_s, dtype=float)
    pace = [_pace(v) for v in speed_ms]
    out = []
    for td in np.arange(hop_s, t_end_s, hop_s):
        if td < s[0] or td >= s[-1] + bh._GDIN_LAST_LANDING_S:
            out.append((float(td), "stand"))
            continue
        k = int(np.searchsorted(s, td, side="right")) - 1  # strides 1..k are over (stride j ends at s[j])
        out.append((float(td), pace[max(k, 1) - 1]))
    return out


def oracle_shares(root: Path, ranges: Sequence[bh.LabelRange] | None = None) -> dict[str, float]:
    """gdin recording -> walk/run share of :func:`oracle_decisions` against the label table."""
    groups = bh.labelled_recordings(bh.read_labels() if ranges is None else ranges)
    out = {}
    for name, st in gdin_strides(root).items():
        rr = groups.get(("gdin", name))
        if rr is None:
            continue
        share = bh.score(oracle_decisions(st["toe_off_s"], st["speed_ms"], rr[-1].t1_s), rr)["walk_run_share"]
        out[name] = float(share)
    return out


def labelled_features(root: Path, dataset: str, recording: str, labels: Sequence[str],
                      ranges: Sequence[bh.LabelRange] | None = None) -> np.ndarray:
    """The recogniser's features every ``HOP_S`` inside the recording's ranges labelled one of ``labels`` (window
    ``[t - WINDOW_S, t)``, :func:`models.behaviour.window_features`, at the recorded rate): rows of (stance
    fraction, gait |a| spread [m/s^2], |a| spread over the last second [m/s^2], stride period [s])."""
    from models.behaviour import HOP_S, WINDOW_S, window_features

    groups = bh.labelled_recordings(bh.read_labels() if ranges is None else ranges)
    b = bh._recording(root, dataset, recording).batch
    t = (b.acc_t_ns - b.acc_t_ns[0]) / 1e9
    a = np.linalg.norm(b.acc, axis=1)
    rows = []
    for r in groups[(dataset, recording)]:
        if r.label not in labels:
            continue
        for td in np.arange(r.t0_s + HOP_S / 2, r.t1_s, HOP_S):
            m = (t >= td - WINDOW_S) & (t < td)
            if td < WINDOW_S or np.count_nonzero(m) < 8:
                continue
            f = window_features(t[m], a[m])
            rows.append((f.stance_fraction, f.gait_std, f.still_std, f.stride_period_s))
    return np.array(rows, dtype=float).reshape(-1, 4)


def acc_p99_g(root: Path, ranges: Sequence[bh.LabelRange] | None = None) -> dict[str, float]:
    """``"dataset/recording label"`` -> 99th percentile of |a| [g] over the recording's time labelled ``walk`` or
    ``run`` (at least 1 s of it), at the recorded rate: the statistic by which 37 of the 42 VICON motion labels
    were guessed (run = at least 4 g, ``datasets/vicon/ABOUT.md``), applied to every labelled gait."""
    from models.behaviour import G

    groups = bh.labelled_recordings(bh.read_labels() if ranges is None else ranges)
    out = {}
    for (ds, name), rr in groups.items():
        try:
            b = bh._recording(root, ds, name).batch
        except (FileNotFoundError, KeyError):
            continue
        t = (b.acc_t_ns - b.acc_t_ns[0]) / 1e9
        a = np.linalg.norm(b.acc, axis=1) / G
        for lab in ("walk", "run"):
            m = np.zeros(t.size, dtype=bool)
            for r in rr:
                if r.label == lab:
                    m |= (t >= r.t0_s) & (t < r.t1_s)
            if np.count_nonzero(m) >= b.rate_hz("acc"):
                out[f"{ds}/{name} {lab}"] = round(float(np.percentile(a[m], 99)), 2)
    return out


def quiet_stretches(t_s: np.ndarray, acc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Start and end [s] of every quiet stretch (``| |a| - g | < QUIET_TOL``), measured as :func:`quiet_in_gait`
    does, from the non-quiet sample before it to the one after it (what the recogniser's quiet timer reads at its
    largest); the stretch after the last non-quiet sample ends at ``inf`` (the recording ends quiet)."""
    from models.behaviour import G, QUIET_TOL

    t = np.asarray(t_s, dtype=float)
    loud = t[np.abs(np.linalg.norm(acc, axis=1) - G) >= QUIET_TOL]
    ends = np.append(loud, np.inf)
    return ends[:-1], ends[1:]


def recent_stance(t0: np.ndarray, t1: np.ndarray, history_s: float = 3.0, min_stance_s: float = 0.15,
                  min_n: int = 2) -> np.ndarray:
    """Per quiet stretch: the longest of the completed earlier stretches that look like stances (``min_stance_s``
    to ``MAX_STANCE_S`` long, ended within ``history_s`` before it starts; the recogniser's window), ``nan``
    with fewer than ``min_n`` of them. A stance-adaptive stop bound would be that plus a margin [s]."""
    from models.behaviour import MAX_STANCE_S

    d = t1 - t0
    out = np.full(t0.size, np.nan)
    ok = (d >= min_stance_s) & (d <= MAX_STANCE_S)
    for i in range(t0.size):
        m = ok & (t1 <= t0[i]) & (t1 > t0[i] - history_s)
        if np.count_nonzero(m) >= min_n:
            out[i] = float(d[m].max())
    return out


def _stop_quiet(t0: np.ndarray, t1: np.ndarray, stand: bh.LabelRange) -> int | None:
    """Index of the first quiet stretch longer than ``MAX_STANCE_S`` that starts from 1 s before to 1.5 s after
    a labelled stop (``None`` when there is none)."""
    from models.behaviour import MAX_STANCE_S

    i = np.flatnonzero((t1 - t0 > MAX_STANCE_S) & (t0 > stand.t0_s - 1.0) & (t0 < stand.t0_s + 1.5))
    return int(i[0]) if i.size else None


def stop_signal_evidence(root: Path, rates_hz: Sequence[float | None] = (None, 25.0),
                         ranges: Sequence[bh.LabelRange] | None = None, still_s: tuple[float, float] = (0.05, 0.65),
                         margin_step_s: float = 0.1) -> dict[str, Any]:
    """Whether the foot's |a| can signal a stop faster than the 1.0-s quiet timer (docs/behaviour.md, tried and
    rejected), per rate:

    - ``excess``: how far a quiet stretch inside labelled walk/run/other outlasts the longest recent stance
      (:func:`recent_stance`): its largest value and recording, and the margin fitted without each group (the next
      ``margin_step_s`` above the other groups' largest, as :func:`fit_stand_enter`);
    - ``stop_recent_stance_s``: the longest recent stance before each labelled stop's quiet (percentiles, and how
      many stops have fewer than two);
    - ``replay_entered_median_abs_s``: stand-entry latency (median of the absolute values over the labelled stops)
      of the quiet timer replayed on the quiet stretches, with the bound ``MAX_STANCE_S`` or
      ``min(MAX_STANCE_S, recent stance + held-out margin)``, decided on the ``HOP_S`` grid or at the crossing;
    - ``stillness_std_ms2``: the std of |a| [m/s^2] over ``still_s`` after the quiet starts, stops against the quiet
      stretches inside gait longer than ``still_s[1]`` (the ones a faster stop signal must tell from a stop);
    - ``last_swing_std_ms2``: the std of |a| [m/s^2] over the ``still_s[1]`` before the quiet starts (the last swing: a
      closing half-step before a stop?), the same two sets.
    """
    from models.behaviour import HOP_S, MAX_STANCE_S

    groups = bh.labelled_recordings(bh.read_labels() if ranges is None else ranges)
    batches = _batches(root, groups, rates_hz)
    out: dict[str, Any] = {}
    for rate in rates_hz:
        rk = "recorded" if rate is None else f"{rate:g}"
        per: dict[tuple[str, str], dict[str, Any]] = {}
        for k in (k for k in groups if (*k, rk) in batches):
            b = batches[(*k, rk)]
            t = (b.acc_t_ns - b.acc_t_ns[0]) / 1e9
            a = np.linalg.norm(b.acc, axis=1)
            t0, t1 = quiet_stretches(t, b.acc)
            rec = recent_stance(t0, t1)
            in_gait = np.zeros(t0.size, dtype=bool)
            for r in groups[k]:
                if r.label in _GAIT:
                    in_gait |= (t0 >= r.t0_s) & (t1 < r.t1_s)
            found = [(_stop_quiet(t0, t1, r), r.t0_s) for r in groups[k] if r.label == "stand" and r.t0_s > 0.5]
            stops = [i for i, _ in found if i is not None]  # the stop's quiet stretch ...
            labelled = [s for i, s in found if i is not None]  # ... and its labelled time [s]

            def std_after(i: int) -> float:
                m = (t > t0[i] + still_s[0]) & (t < t0[i] + still_s[1])
                return float(a[m].std()) if np.count_nonzero(m) >= 5 else float("nan")

            def std_before(i: int) -> float:
                m = (t >= t0[i] - still_s[1]) & (t <= t0[i])
                return float(a[m].std()) if np.count_nonzero(m) >= 5 else float("nan")

            long_ = np.flatnonzero(in_gait & (t1 - t0 > still_s[1]))
            per[k] = {"excess": (t1 - t0 - rec)[in_gait & np.isfinite(rec)], "stops": stops, "labelled": labelled,
                      "t0": t0, "recent": rec, "still_stop": [std_after(i) for i in stops],
                      "still_gait": [std_after(i) for i in long_], "swing_stop": [std_before(i) for i in stops],
                      "swing_gait": [std_before(i) for i in long_]}
        exc = {group_of(*k): [] for k in per}
        for k, v in per.items():
            exc[group_of(*k)].append(v["excess"])
        worst = max(per, key=lambda k: float(np.max(per[k]["excess"], initial=-np.inf)))

        def fit(without: str) -> float:
            m = max((float(e.max()) for g, es in exc.items() if g != without for e in es if e.size), default=0.0)
            return round(math.floor(m / margin_step_s + 1e-9) * margin_step_s + margin_step_s, 3)

        lat: dict[str, list[float]] = {"timer 1.0 s, HOP_S grid": [], "timer 1.0 s, at the crossing": [],
                                       "stance-adaptive, HOP_S grid": [], "stance-adaptive, at the crossing": []}
        margins = set()
        for k, v in per.items():
            margin = fit(group_of(*k))
            margins.add(margin)
            for i, lab in zip(v["stops"], v["labelled"]):
                adaptive = MAX_STANCE_S if np.isnan(v["recent"][i]) else min(MAX_STANCE_S, v["recent"][i] + margin)
                for name, bound in (("timer 1.0 s", MAX_STANCE_S), ("stance-adaptive", adaptive)):
                    cross = v["t0"][i] + bound
                    lat[f"{name}, HOP_S grid"].append(math.ceil(cross / HOP_S - 1e-9) * HOP_S - lab)
                    lat[f"{name}, at the crossing"].append(cross - lab)
        recent = np.array([v["recent"][i] for v in per.values() for i in v["stops"]])
        still_stop = np.array([x for v in per.values() for x in v["still_stop"]])
        still_gait = np.array([x for v in per.values() for x in v["still_gait"]])
        swing_stop = np.array([x for v in per.values() for x in v["swing_stop"]])
        swing_gait = np.array([x for v in per.values() for x in v["swing_gait"]])
        out[rk] = {
            "excess": {"max_s": round(float(np.max(per[worst]["excess"])), 3), "recording": "/".join(worst),
                       "held_out_margin_s": sorted(margins)},
            "stop_recent_stance_s": {"stops": int(recent.size), "fewer_than_two": int(np.isnan(recent).sum()),
                                     "p10_p50_p90": [round(float(q), 2) for q in
                                                     np.nanpercentile(recent, [10, 50, 90])]},
            "replay_entered_median_abs_s": {n: round(float(np.median(np.abs(v))), 3) for n, v in lat.items()},
            "stillness_std_ms2": {
                "stops_p50_p90_max": [round(float(q), 3) for q in np.nanpercentile(still_stop, [50, 90, 100])],
                "gait_quiet_min_p10_p50": [round(float(q), 3) for q in np.nanpercentile(still_gait, [0, 10, 50])],
                "gait_quiet_stretches": int(np.isfinite(still_gait).sum())},
            "last_swing_std_ms2": {
                "stops_p10_p50_p90": [round(float(q), 2) for q in np.nanpercentile(swing_stop, [10, 50, 90])],
                "gait_quiet_p10_p50_p90": [round(float(q), 2) for q in np.nanpercentile(swing_gait, [10, 50, 90])]},
        }
    return out


def _spread(x: np.ndarray) -> list[list[float]]:
    """Per column: median, 10th and 90th percentile (rounded)."""
    return [[round(float(np.nanpercentile(x[:, c], q)), 2) for q in (50, 10, 90)] for c in range(x.shape[1])]


def main() -> None:
    """``python -m clients.evaluation.behaviour_fit [ROOT]``: one JSON document with the leave-one-group-out
    summaries (recorded rate and 25 Hz), the oracle's shares and the label-conflict features (docs/behaviour.md);
    ``python -m clients.evaluation.behaviour_fit --stop-signal [ROOT]``: :func:`stop_signal_evidence` instead."""
    import json
    import os
    import sys

    args = [a for a in sys.argv[1:] if a != "--stop-signal"]
    root = Path(args[0] if args else os.environ.get("PEDNAV_DATA", "../shared/datasets"))
    if "--stop-signal" in sys.argv[1:]:
        print(json.dumps(stop_signal_evidence(root), indent=1))
        return
    logo = leave_one_group_out(root, (None, 25.0))
    conflict = {
        "gdin/exp34 walk": labelled_features(root, "gdin", "exp34", ("walk",)),
        "vicon/2017-11-22-11-44-47 run and ignore": labelled_features(root, "vicon", "2017-11-22-11-44-47",
                                                                      ("run", "ignore")),
    }
    doc = {
        "groups": logo["groups"],
        "rates": {k: {"summary": v["summary"], "stand_enter_s": sorted({r["stand_enter_s"] for r in v["recordings"]}),
                      "longest_quiet_in_gait_s": max(v["longest_quiet_in_gait_s"].values())}
                  for k, v in logo["rates"].items()},
        "oracle_walk_run_share": oracle_shares(root),
        "acc_p99_g": acc_p99_g(root),
        "features_median_p10_p90": {k: dict(zip(("stance_fraction", "gait_std", "still_std", "stride_period_s"),
                                                _spread(v))) for k, v in conflict.items()},
    }
    print(json.dumps(doc, indent=1))


if __name__ == "__main__":
    main()
