"""Behaviour recognition against labelled real recordings (``pednav eval behaviour``).

Labels (``behaviour_labels.csv`` beside this module, one row per time range: ``dataset, recording, t0_s, t1_s,
label``; ``t`` in seconds from the recording's first accelerometer sample) are derived from each recording's
truth by :func:`derive_labels`, never from its IMU signals:

- ``stand``: the instrumented foot still for at least ``STAND_MIN_S`` (more than ``STANCE_MAX_S`` at the start
  and end of a recording; 1-2 s inside a gait are ``ignore``: a slow stance or a short stop) by the motion capture (VICON foot marker,
  gaitmap heel marker; speed of the median-filtered position, Savitzky-Golay differentiated, below 0.12 m/s and
  until it exceeds 0.25 m/s, swings shorter than 0.1 s merged into the stance), or, gdin, before the first stride
  (the ``stride_gcp`` timestamp of stride 0: the end of the initial still interval);
- the foot's moving time carries the recording's gait: VICON trials the motion the dataset's table gives
  (datasets/vicon/ABOUT.md: ``walk``, ``run``, ``other`` for in-place foot lifts and crawling; a stride whose
  foot contradicts it, still for at least 30 % of a "run" stride or at most 20 % of a "walk" stride, is ``ignore``:
  trial 2017-11-22-11-44-47, a run by the dataset's authors, strides at 1.3 m/s with its foot still for 34 % of
  each, as walks do), gaitmap ``walk``;
  gdin per stride by its speed between the measured footprints (``stride_gcp``, from toe-off to toe-off): ``walk``
  up to 1.9 m/s, ``run`` from 2.4 m/s (the human walk-run transition lies at 1.9-2.2 m/s; in between
  ``ignore``): exp 34, 35 and 43 change their pace and reach 2.2-3.3 m/s;
- ``ignore``: where the truth cannot place a boundary (gdin's end: the last stride's landing is not given, so
  from the toe-off of the last stride to 1.5 s after it), and the first ``SETTLE_S`` of every gait after a stand
  (its first stride cannot tell walking from running; the stand boundaries are judged by their latency instead).

Metrics per recording (:func:`score`): ``walk_run_share`` = fraction of the labelled walk/run time (``ignore``
left out) the recogniser labels with the gait of the label; ``other_share`` likewise for ``other``; ``stand_share``;
``stand_left_s`` / ``stand_entered_s``: per labelled stand boundary inside the recording (not its start or end),
the time from the boundary to the recogniser's change of label out of / into ``stand`` (negative: before it),
``None`` when it never changed within ``BOUNDARY_WINDOW_S``. Where the wrong time lies (:func:`missed_by_context`:
the first seconds of a gait after a stand, the last before a stop, after a change of pace, after an unscored stretch,
or steady gait) is each row's ``missed_s``; :func:`confusion_table` prints it per recording (``pednav eval behaviour
--confusion``).
"""

from __future__ import annotations

import csv
import math
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

__all__ = [
    "LABEL_TABLE",
    "STAND_MIN_S",
    "SETTLE_S",
    "BOUNDARY_WINDOW_S",
    "LabelRange",
    "foot_still",
    "vicon_motions",
    "derive_labels",
    "read_labels",
    "write_labels",
    "score",
    "CONTEXTS",
    "missed_by_context",
    "confusion_table",
    "summarise",
    "labelled_recordings",
    "evaluate",
]

LABEL_TABLE = Path(__file__).with_name("behaviour_labels.csv")
STAND_MIN_S = 2.0  # s: a foot still this long is a stand ...
STANCE_MAX_S = 1.0  # s: ... this long or shorter a stance of the gait; in between either (not scored)
SETTLE_S = 1.0  # s after a stand left out of the gait shares
BOUNDARY_WINDOW_S = 5.0  # s either side of a stand boundary in which the recogniser's change is looked for
_STILL_ENTER, _STILL_LEAVE = 0.12, 0.25  # m/s: hysteresis of the foot-still test on the truth
_MIN_SWING_S = 0.1  # s: a shorter "swing" is marker noise inside a stance
_GDIN_LAST_LANDING_S = 1.5  # s after the last stride's toe-off that the final landing may take
# gdin strides by their speed between measured footprints: people walk below about 2.0 m/s and run above it (the
# preferred walk-run transition: 1.9-2.2 m/s); a stride within the margin is not scored
_WALK_MAX_MS, _RUN_MIN_MS = 1.9, 2.4
# a stride of a trial labelled "run" whose foot is still for at least this fraction of it walked (running strides of
# the VICON run trials: 0.06-0.24; walks 0.22-0.59), one of a "walk" trial with at most this much ran: not scored
_RUN_DUTY_MAX, _WALK_DUTY_MIN = 0.30, 0.20


@dataclass(frozen=True)
class LabelRange:
    """One labelled time range of a recording: ``t0_s <= t < t1_s`` [s from its first accelerometer sample]."""

    dataset: str
    recording: str
    t0_s: float
    t1_s: float
    label: str


def foot_still(t_s: np.ndarray, pos_m: np.ndarray) -> np.ndarray:
    """Per truth sample: the foot is still (speed below 0.12 m/s, until it exceeds 0.25 m/s; swings shorter than
    0.1 s are marker noise). ``pos_m`` (N, 3) [m], ``t_s`` (N,) [s], uniformly sampled."""
    from scipy.signal import medfilt, savgol_filter

    t = np.asarray(t_s, dtype=float)
    p = np.asarray(pos_m, dtype=float)
    dt = float(np.median(np.diff(t)))
    p = np.stack([medfilt(p[:, k], 9) for k in range(3)], axis=1)  # single-sample marker glitches
    w = max(int(round(0.05 / dt)) | 1, 5)
    v = np.linalg.norm(savgol_filter(p, w, 2, deriv=1, delta=dt, axis=0), axis=1)
    still = np.zeros(v.size, dtype=bool)
    s = True
    for i, x in enumerate(v):
        s = bool(x < _STILL_LEAVE) if s else bool(x < _STILL_ENTER)
        still[i] = s
    a, b = _runs(still)
    for k in range(1, len(a)):
        if t[a[k]] - t[b[k - 1] - 1] < _MIN_SWING_S:
            still[b[k - 1] : a[k]] = True
    return still


def _runs(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Starts and ends (exclusive) of the runs of True."""
    d = np.diff(np.r_[0, mask.astype(np.int8), 0])
    return np.flatnonzero(d == 1), np.flatnonzero(d == -1)


def _ranges_from_still(dataset: str, name: str, t: np.ndarray, still: np.ndarray, gait: str,
                       t_end: float) -> list[LabelRange]:
    """Stand where the foot is still >= STAND_MIN_S, the gait elsewhere, its first SETTLE_S after a stand ignored."""
    a, b = _runs(still)
    stands = [(float(t[i]), float(t[j - 1])) for i, j in zip(a, b) if t[j - 1] - t[i] >= STAND_MIN_S
              or (i == 0 and t[j - 1] - t[i] > STANCE_MAX_S) or (j == len(t) and t[j - 1] - t[i] > STANCE_MAX_S)]
    unsure = [(float(t[i]), float(t[j - 1])) for i, j in zip(a, b) if STANCE_MAX_S < t[j - 1] - t[i] < STAND_MIN_S]
    # strides whose foot contradicts the gait of the recording's label (duty: the still fraction of the stride,
    # toe-off to toe-off): a "run" stride with the foot still for >= 30 % of it, a "walk" stride <= 20 %
    for k in range(1, len(a)):
        stance, stride = t[b[k] - 1] - t[a[k]], t[b[k] - 1] - t[b[k - 1] - 1]
        if stance > STANCE_MAX_S or stride > STANCE_MAX_S + 2.0:
            continue
        duty = stance / stride
        if (gait == "run" and duty >= _RUN_DUTY_MAX) or (gait == "walk" and duty <= _WALK_DUTY_MIN):
            unsure.append((float(t[b[k - 1] - 1]), float(t[b[k] - 1])))
    unsure.sort()
    if stands and stands[0][0] <= t[0] + 0.05:
        stands[0] = (0.0, stands[0][1])
    if stands and stands[-1][1] >= t[-1] - 0.05:
        stands[-1] = (stands[-1][0], t_end)
    out: list[LabelRange] = []
    cur = 0.0
    for s0, s1 in stands:
        if s0 > cur:
            out += _gait(dataset, name, cur, s0, gait, settle=bool(out))
        out.append(LabelRange(dataset, name, s0, s1, "stand"))
        cur = s1
    if cur < t_end:
        out += _gait(dataset, name, cur, t_end, gait, settle=bool(out))
    # a foot still for 1-2 s inside the gait: a slow stance or a short stop, either label is right
    return [piece for r in out for piece in _cut(r, unsure)]


def _cut(r: LabelRange, holes: list[tuple[float, float]]) -> list[LabelRange]:
    """``r`` with the ``holes`` (not scored) cut out of its gait (stands are kept whole)."""
    if r.label in ("stand", "ignore"):
        return [r]
    out, cur = [], r.t0_s
    for h0, h1 in holes:
        if h1 <= cur or h0 >= r.t1_s:
            continue
        if h0 > cur:
            out.append(LabelRange(r.dataset, r.recording, cur, h0, r.label))
        out.append(LabelRange(r.dataset, r.recording, max(h0, cur), min(h1, r.t1_s), "ignore"))
        cur = min(h1, r.t1_s)
    if cur < r.t1_s:
        out.append(LabelRange(r.dataset, r.recording, cur, r.t1_s, r.label))
    return out


def _gait(dataset: str, name: str, t0: float, t1: float, gait: str, settle: bool) -> list[LabelRange]:
    if not settle:
        return [LabelRange(dataset, name, t0, t1, gait)]
    mid = min(t0 + SETTLE_S, t1)
    out = [LabelRange(dataset, name, t0, mid, "ignore")]
    if t1 > mid:
        out.append(LabelRange(dataset, name, mid, t1, gait))
    return out


def vicon_motions(about: str) -> dict[str, str]:
    """Trial -> ``walk``/``run``/``other`` from the trials table of datasets/vicon/ABOUT.md (its motion column)."""
    out = {}
    for name, motion in re.findall(r"\| (\d{4}-\d\d-\d\d-\d\d-\d\d-\d\d) \| [\d.]+ \| [\d.]+ \| ([^|]+) \|", about):
        m = motion.strip()
        out[name] = "other" if m.startswith("other") else "run" if m.startswith("run") else "walk"
    return out


def derive_labels(root: Path) -> list[LabelRange]:
    """The label table from the truth of the development recordings under ``root`` (``PEDNAV_DATA``)."""
    from clients.importers import load
    from clients.importers.gaitmap import load_gaitmap
    from clients.importers.gdin import find_gdin, load_gdin

    out: list[LabelRange] = []
    vdir = root / "vicon"
    if vdir.is_dir():
        motions = vicon_motions((vdir / "ABOUT.md").read_text())
        for f in sorted(vdir.glob("*.mat")):
            rec = load(f)
            assert rec.truth is not None and rec.truth.t_ns is not None and rec.truth.positions is not None
            t0 = int(rec.batch.acc_t_ns[0])
            t = (rec.truth.t_ns - t0) / 1e9
            end = (int(rec.batch.acc_t_ns[-1]) - t0) / 1e9
            out += _ranges_from_still("vicon", rec.name, t, foot_still(t, rec.truth.positions), motions[rec.name], end)
    gdir = root / "gdin"
    if gdir.is_dir():
        for e in find_gdin(gdir):
            rec = load_gdin(e)
            x = rec.truth.extra if rec.truth is not None else {}
            if x.get("stride_t_ns") is None or len(x["stride_t_ns"]) < 3:
                continue
            t0 = int(rec.batch.acc_t_ns[0])
            s = (np.asarray(x["stride_t_ns"], dtype=np.int64) - t0) / 1e9
            end = (int(rec.batch.acc_t_ns[-1]) - t0) / 1e9
            last_off = float(s[-2])  # toe-off of the last stride (end of the still interval before it)
            g = np.asarray(x["gcp_m"], dtype=float)
            n = min(len(s), len(g))
            out += [LabelRange("gdin", rec.name, 0.0, float(s[0]), "stand"),
                    LabelRange("gdin", rec.name, float(s[0]), min(float(s[0]) + SETTLE_S, last_off), "ignore")]
            cur = min(float(s[0]) + SETTLE_S, last_off)
            for k in range(1, n - 1):  # stride k: from the toe-off s[k-1] to the toe-off s[k]; the last one ignored
                speed = float(np.linalg.norm(g[k] - g[k - 1])) / float(s[k] - s[k - 1])
                lab = "walk" if speed <= _WALK_MAX_MS else "run" if speed >= _RUN_MIN_MS else "ignore"
                if float(s[k]) > cur:
                    out.append(LabelRange("gdin", rec.name, max(cur, float(s[k - 1])), float(s[k]), lab))
                    cur = float(s[k])
            out.append(LabelRange("gdin", rec.name, last_off, min(last_off + _GDIN_LAST_LANDING_S, end), "ignore"))
            if end > last_off + _GDIN_LAST_LANDING_S + STAND_MIN_S:
                out.append(LabelRange("gdin", rec.name, last_off + _GDIN_LAST_LANDING_S, end, "stand"))
    mdir = root / "gaitmap-mocap"
    if (mdir / "imu_sample.csv").is_file():
        for foot in ("left", "right"):
            rec = load_gaitmap(mdir / "imu_sample.csv", foot=foot)
            assert rec.truth is not None and rec.truth.t_ns is not None and rec.truth.positions is not None
            t0 = int(rec.batch.acc_t_ns[0])
            t = (rec.truth.t_ns - t0) / 1e9
            end = (int(rec.batch.acc_t_ns[-1]) - t0) / 1e9
            out += _ranges_from_still("gaitmap", rec.name, t, foot_still(t, rec.truth.positions), "walk", end)
    return _merged([r for r in out if r.t1_s > r.t0_s])


def _merged(ranges: list[LabelRange]) -> list[LabelRange]:
    """Adjacent ranges of one recording with the same label joined."""
    out: list[LabelRange] = []
    for r in ranges:
        p = out[-1] if out else None
        if (p is not None and (p.dataset, p.recording, p.label) == (r.dataset, r.recording, r.label)
                and abs(p.t1_s - r.t0_s) < 1e-6):
            out[-1] = LabelRange(p.dataset, p.recording, p.t0_s, r.t1_s, p.label)
        else:
            out.append(r)
    return out


def write_labels(ranges: Iterable[LabelRange], path: Path = LABEL_TABLE) -> None:
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(["dataset", "recording", "t0_s", "t1_s", "label"])
        for r in ranges:
            w.writerow([r.dataset, r.recording, f"{r.t0_s:.2f}", f"{r.t1_s:.2f}", r.label])


def read_labels(path: Path = LABEL_TABLE) -> list[LabelRange]:
    with open(path, newline="") as fh:
        return [LabelRange(row["dataset"], row["recording"], float(row["t0_s"]), float(row["t1_s"]), row["label"])
                for row in csv.DictReader(fh)]


def labelled_recordings(ranges: Sequence[LabelRange]) -> dict[tuple[str, str], list[LabelRange]]:
    """Ranges grouped by ``(dataset, recording)`` in table order."""
    out: dict[tuple[str, str], list[LabelRange]] = {}
    for r in ranges:
        out.setdefault((r.dataset, r.recording), []).append(r)
    return out


def _label_at(td: np.ndarray, lab: np.ndarray, t: np.ndarray) -> np.ndarray:
    """The recogniser's label at times ``t``: that of its latest decision at or before (``stand`` before any)."""
    if not len(lab):
        return np.full(t.shape, "stand", dtype=object)
    i = np.searchsorted(td, t, side="right") - 1
    return np.where(i >= 0, lab[np.clip(i, 0, len(lab) - 1)], "stand")


def _change(td: np.ndarray, lab: np.ndarray, lo: float, hi: float, into_stand: bool) -> float | None:
    """Time of the last change of label into (``into_stand``) or out of ``stand`` within ``[lo, hi]``: the one that
    stuck (the first would be an early flicker)."""
    prev = np.concatenate([np.array(["stand"], dtype=object), lab[:-1]])  # the recogniser starts as stand
    if into_stand:
        ch = (lab == "stand") & (prev != "stand")
    else:
        ch = (lab != "stand") & (prev == "stand")
    k = np.flatnonzero(ch & (td >= lo) & (td <= hi))
    return float(td[k[0]]) if k.size else None


def score(decisions: Sequence[tuple[float, str]], ranges: Sequence[LabelRange], step_s: float = 0.05) -> dict[str, Any]:
    """Metrics of one recording's decisions ``(t_s, label)`` against its labelled ranges (module docstring)."""
    td = np.array([d[0] for d in decisions], dtype=float)
    lab = np.array([d[1] for d in decisions], dtype=object)
    hit: dict[str, list[float]] = {"walk_run": [0.0, 0.0], "other": [0.0, 0.0], "stand": [0.0, 0.0]}
    confusion: dict[str, dict[str, float]] = {}
    for r in ranges:
        if r.label == "ignore":
            continue
        t = np.arange(r.t0_s + step_s / 2, r.t1_s, step_s)
        got = _label_at(td, lab, t)
        key = "walk_run" if r.label in ("walk", "run") else r.label
        hit[key][0] += float(np.sum(got == r.label)) * step_s
        hit[key][1] += t.size * step_s
        row = confusion.setdefault(r.label, {})
        for g in ("stand", "walk", "run", "other"):
            row[g] = row.get(g, 0.0) + float(np.sum(got == g)) * step_s
    left: list[float | None] = []
    entered: list[float | None] = []
    first, last = ranges[0], ranges[-1]
    for r in ranges:
        if r.label != "stand":
            continue
        mid = 0.5 * (r.t0_s + r.t1_s)
        if r is not first:
            c = _change(td, lab, max(r.t0_s - BOUNDARY_WINDOW_S, 0.0), r.t1_s, into_stand=True)
            entered.append(None if c is None else c - r.t0_s)
        if r is not last:
            c = _change(td, lab, mid, r.t1_s + BOUNDARY_WINDOW_S, into_stand=False)
            left.append(None if c is None else c - r.t1_s)
    share = {k: (v[0] / v[1] if v[1] > 0 else None) for k, v in hit.items()}
    return {"walk_run_share": share["walk_run"], "other_share": share["other"], "stand_share": share["stand"],
            "walk_run_s": hit["walk_run"][1], "stand_left_s": left, "stand_entered_s": entered,
            "confusion_s": {k: {g: round(x, 2) for g, x in v.items()} for k, v in confusion.items()}}


CONTEXTS: tuple[str, ...] = ("start", "stop", "pace", "hole", "steady")
_CONTEXT_S = 2.0  # s: the reach of each context below


def _context(t: float, stands: Sequence[LabelRange], holes: Sequence[LabelRange],
             changes: Sequence[float]) -> str:
    """Where a moment of labelled gait lies (first match of :data:`CONTEXTS`): ``start`` within ``_CONTEXT_S``
    after the end of the settling time that follows a stand (1-3 s into a gait); ``stop`` within ``_CONTEXT_S``
    before a stand begins; ``pace`` within ``_CONTEXT_S`` after the labelled gait changed (walk <-> run, gdin);
    ``hole`` within ``_CONTEXT_S`` after an unscored stretch inside the gait (a 1-2 s stop, a stride whose foot
    contradicts the trial's label, an in-between pace); ``steady`` otherwise."""
    if any(0.0 <= t - s.t1_s - SETTLE_S < _CONTEXT_S for s in stands):
        return "start"
    if any(0.0 <= s.t0_s - t < _CONTEXT_S for s in stands):
        return "stop"
    if any(0.0 <= t - c < _CONTEXT_S for c in changes):
        return "pace"
    if any(0.0 <= t - h.t1_s < _CONTEXT_S for h in holes):
        return "hole"
    return "steady"


def missed_by_context(decisions: Sequence[tuple[float, str]], ranges: Sequence[LabelRange],
                      step_s: float = 0.05) -> dict[str, dict[str, dict[str, float]]]:
    """Where the labelled walk/run/other time the recogniser gets wrong goes: ``{context: {labelled: {recognised:
    seconds}}}`` over the contexts of :data:`CONTEXTS` (see :func:`_context`), sampled every ``step_s`` [s] as
    :func:`score` does (only wrong time is counted; ``ignore`` left out)."""
    td = np.array([d[0] for d in decisions], dtype=float)
    lab = np.array([d[1] for d in decisions], dtype=object)
    stands = [r for r in ranges if r.label == "stand"]
    settles = {s.t1_s for s in stands}
    holes = [r for r in ranges if r.label == "ignore" and r.t0_s not in settles]
    gaits = [r for r in ranges if r.label in ("walk", "run")]
    changes = [b.t0_s for a, b in zip(gaits, gaits[1:]) if a.label != b.label and b.t0_s - a.t1_s < _CONTEXT_S]
    out: dict[str, dict[str, dict[str, float]]] = {}
    for r in ranges:
        if r.label not in ("walk", "run", "other"):
            continue
        t = np.arange(r.t0_s + step_s / 2, r.t1_s, step_s)
        got = _label_at(td, lab, t)
        for x, g in zip(t[got != r.label], got[got != r.label]):
            row = out.setdefault(_context(float(x), stands, holes, changes), {}).setdefault(r.label, {})
            row[str(g)] = row.get(str(g), 0.0) + step_s
    return {c: {k: {g: round(x, 2) for g, x in v.items()} for k, v in out[c].items()} for c in CONTEXTS if c in out}


def confusion_table(rows: Sequence[dict[str, Any]]) -> list[str]:
    """Text lines, one per recording and one for all: labelled x recognised seconds of walk/run/other time (the
    ``confusion_s`` of :func:`score`) and the wrong seconds by context and recognised label (``missed_s`` of
    :func:`missed_by_context`), e.g. ``start walk>other 1.2`` = 1.2 s of labelled walking 1-3 s after a stand
    recognised as ``other``."""
    def cells(conf: dict[str, dict[str, float]]) -> str:
        got = ("stand", "walk", "run", "other")
        return " ".join(f"{k}[" + " ".join(f"{g[0]}{conf[k].get(g, 0.0):.1f}" for g in got) + "]"
                        for k in ("walk", "run", "other") if k in conf)

    def missed(m: dict[str, dict[str, dict[str, float]]]) -> str:
        items = [(x, f"{c} {k}>{g}") for c, v in m.items() for k, w in v.items() for g, x in w.items() if x > 0]
        return ", ".join(f"{name} {x:.1f}" for x, name in sorted(items, key=lambda i: -i[0]))

    out, conf_all, miss_all = [], {}, {}
    for r in rows:
        out.append(f"{r['name']:<30} {cells(r['confusion_s'])} | missed: {missed(r['missed_s'])}")
        for k, v in r["confusion_s"].items():
            for g, x in v.items():
                conf_all.setdefault(k, {})[g] = conf_all.setdefault(k, {}).get(g, 0.0) + x
        for c, v in r["missed_s"].items():
            for k, w in v.items():
                for g, x in w.items():
                    d = miss_all.setdefault(c, {}).setdefault(k, {})
                    d[g] = d.get(g, 0.0) + x
    out.append(f"{'all':<30} {cells(conf_all)} | missed: {missed(miss_all)}")
    return out


def _finite(values: Iterable[float | None]) -> list[float]:
    return [float(v) for v in values if v is not None and math.isfinite(v)]


def summarise(rows: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """Mean and worst walk/run share over the recordings that have walk/run time; median absolute latency of the
    stand boundaries (and how many were never crossed within the window)."""
    shares = _finite(r["walk_run_share"] for r in rows)
    other = _finite(r["other_share"] for r in rows)
    left = [v for r in rows for v in r["stand_left_s"]]
    entered = [v for r in rows for v in r["stand_entered_s"]]
    worst = min(rows, key=lambda r: r["walk_run_share"] if r["walk_run_share"] is not None else 2.0) if shares else None
    return {
        "recordings": len(rows),
        "walk_run_share_mean": float(np.mean(shares)) if shares else None,
        "walk_run_share_worst": min(shares) if shares else None,
        "worst_recording": worst["name"] if worst else None,
        "other_share_mean": float(np.mean(other)) if other else None,
        "stand_left_median_abs_s": float(np.median(np.abs(_finite(left)))) if _finite(left) else None,
        "stand_entered_median_abs_s": float(np.median(np.abs(_finite(entered)))) if _finite(entered) else None,
        "stand_boundaries": len(left) + len(entered),
        "stand_boundaries_missed": sum(v is None for v in left + entered),
    }


def _recording(root: Path, dataset: str, name: str) -> Any:
    from clients.importers import load
    from clients.importers.gaitmap import load_gaitmap
    from clients.importers.gdin import find_gdin, load_gdin

    if dataset == "vicon":
        return load(root / "vicon" / f"{name}.mat")
    if dataset == "gdin":
        entries = {e.name: e for e in find_gdin(root / "gdin")}
        return load_gdin(entries[name])
    if dataset == "gaitmap":
        return load_gaitmap(root / "gaitmap-mocap" / "imu_sample.csv", foot=name.rsplit("-", 1)[-1])
    raise ValueError(f"unknown dataset {dataset!r} in the label table")


def evaluate(root: Path, rates_hz: Sequence[float | None] = (None,), ranges: Sequence[LabelRange] | None = None,
             progress: Any = None) -> dict[str, Any]:
    """Run a fresh :class:`models.behaviour.BehaviourRecognizer` over every labelled recording under ``root`` (the
    accelerometer only), at its recorded rate (``None``) and de-sampled to each rate [Hz]
    (:func:`energy.device.desample`), and score it (:func:`score`, :func:`summarise`)."""
    from energy.device import desample
    from models.behaviour import BehaviourRecognizer

    groups = labelled_recordings(read_labels() if ranges is None else ranges)
    out: dict[str, Any] = {"rates": {}}
    recs = {}
    for key in groups:
        try:
            recs[key] = _recording(root, *key).batch
        except (FileNotFoundError, KeyError):
            continue  # this copy of the datasets lacks it
        if progress is not None:
            progress(key)
    for rate in rates_hz:
        rows = []
        for key, rr in groups.items():
            if key not in recs:
                continue
            b = recs[key]
            if rate is not None and rate < 0.9 * b.rate_hz("acc"):
                b = desample(b, rate)
            t = (b.acc_t_ns - b.acc_t_ns[0]) / 1e9
            dec = BehaviourRecognizer().process(t, b.acc)
            rows.append({"name": f"{key[0]}/{key[1]}", "rate_hz": round(float(b.rate_hz("acc")), 1),
                         **score(dec, rr), "missed_s": missed_by_context(dec, rr)})
        out["rates"]["recorded" if rate is None else f"{rate:g}"] = {"summary": summarise(rows), "recordings": rows}
    return out
