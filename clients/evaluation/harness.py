"""Evaluation harness: run the engine over public recordings and compute DESIGN.md's metrics.

The engine is replayed like a real device (:func:`energy.device.replay`): it decides the gyroscope state and
the rates, and the replay obeys them. The metrics only use what the engine outputs (the per-sample trace and
the per-stance positions) and the recording's truth; no engine setting is read from the truth.

Frames: the engine outputs NED. The VICON truth's horizontal axes have the same handedness as (north, east)
(checked with a plain ZUPT filter: the authors' ARMSE is reproduced without any mirroring) and its z axis
points up, so for 3-D errors the estimate's "down" is negated. For gdin the stride metric negates y as
DESIGN.md prescribes (the ground-control frame is mirrored).

Definitions of this module (beyond DESIGN.md):

- ``strides_detected`` = number of stance-to-stance intervals the engine reported =
  ``len(positions) - 1`` (the first stance is the origin of the session, not a completed stride);
- the estimate "at a sample" is the trace position of the last processed accelerometer sample at or before
  that time (sample-and-hold; before the first processed sample: the first one);
- behaviour fractions are time-weighted over the processed samples (each sample stands for the interval to
  the next one); labels other than stand/walk/run count as ``other``.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from clients.evaluation import metrics
from clients.importers.gdin import GdinEntry, find_gdin, load_gdin
from clients.importers.vicon import load_vicon
from clients.recording import Recording
from models.batch import SensorBatch

__all__ = [
    "BEHAVIOURS",
    "EngineRun",
    "Runner",
    "Evaluated",
    "run_engine",
    "positions_at",
    "behaviour_fractions",
    "evaluate_vicon_recording",
    "evaluate_gdin_recording",
    "vicon_summary",
    "gdin_summary",
    "GDIN_SUMMARY_KEYS",
    "select",
    "vicon_files",
    "gdin_entries",
    "load_vicon_trial",
    "load_gdin_entry",
]

log = logging.getLogger(__name__)

BEHAVIOURS: tuple[str, ...] = ("stand", "walk", "run", "other")
GDIN_SUMMARY_KEYS: tuple[str, ...] = (
    "loop_closure_pct",
    "stride_mean_err_m",
    "stride_rmse_m",
    "distance_err_pct",
    "strides_detected",
    "strides_truth",
    "gyro_on_fraction",
    "mean_rate_hz",
    "pdr_distance_err_pct",
)
_NED_TO_VICON = np.array([1.0, 1.0, -1.0])  # (north, east, down) -> truth (x, y, z up); see module docstring


@dataclass(frozen=True)
class EngineRun:
    """What the metrics need from one replay (a view of :class:`energy.device.ReplayResult`).

    Attributes
    ----------
    t_ns : ndarray of int64, shape (n,)
        Processed accelerometer sample times [ns].
    pos : ndarray, shape (n, 3)
        NED positions at those samples [m].
    behaviour : ndarray of str, shape (n,)
        Behaviour label per sample.
    stances : ndarray, shape (m, 4)
        Per reported position: time [ns] (as float), north, east, down [m].
    gyro_on_fraction, mean_rate_hz : float
        As reported by the replay.
    mode : ndarray of str, shape (n,) or None
        Navigation mode per sample (``zupt``, ``pdr``, ``idle``); None when the runner does not say.
    """

    t_ns: np.ndarray
    pos: np.ndarray
    behaviour: np.ndarray
    stances: np.ndarray
    gyro_on_fraction: float
    mean_rate_hz: float
    mode: np.ndarray | None = None


class Runner(Protocol):
    def __call__(self, batch: SensorBatch, mode: str, l0_m: float | None) -> EngineRun: ...


def run_engine(batch: SensorBatch, mode: str = "zupt", l0_m: float | None = None, batch_seconds: float = 1.0,
               conventional: bool = False) -> EngineRun:
    """Replay ``batch`` through a fresh engine (``trace=True``) in ``mode``; ``l0_m`` sets ``EngineConfig.l0_m``,
    ``conventional`` the conventional-PDR baseline (``EngineConfig.pdr_conventional``)."""
    from energy.device import replay  # lazy: keeps `pednav --help` fast
    from energy.engine import Engine, EngineConfig

    kw: dict[str, Any] = {"pdr_conventional": bool(conventional)}
    if l0_m is not None:
        kw["l0_m"] = float(l0_m)
    config = EngineConfig(**kw)
    engine = Engine(mode=mode, config=config, profile=None, trace=True)
    res = replay(engine, batch, batch_seconds=batch_seconds)
    tr = res.trace
    stances = np.array([[p.t_ns, p.north, p.east, p.down] for p in res.positions], dtype=np.float64).reshape(-1, 4)
    return EngineRun(
        t_ns=np.asarray(tr.t_ns, dtype=np.int64),
        pos=np.asarray(tr.pos, dtype=np.float64).reshape(-1, 3),
        behaviour=np.asarray(tr.behaviour).astype(str),
        stances=stances,
        gyro_on_fraction=float(res.gyro_on_fraction),
        mean_rate_hz=float(res.mean_rate_hz),
        mode=np.asarray(tr.mode).astype(str),
    )


def positions_at(t_ns: np.ndarray, pos: np.ndarray, query_ns: np.ndarray) -> np.ndarray:
    """Trace position at each query time: the last sample at or before it (the first sample before the trace).

    Parameters
    ----------
    t_ns : ndarray of int64, shape (n,), increasing
        Trace times [ns].
    pos : ndarray, shape (n, 3)
        Trace positions [m].
    query_ns : ndarray of int64, shape (k,)
        Times wanted [ns].
    """
    t = np.asarray(t_ns, dtype=np.int64)
    if t.size == 0:
        raise ValueError("the engine produced no trace samples: nothing to evaluate")
    i = np.searchsorted(t, np.asarray(query_ns, dtype=np.int64), side="right") - 1
    return np.asarray(pos, dtype=np.float64)[np.clip(i, 0, t.size - 1)]


def behaviour_fractions(t_ns: np.ndarray, labels: np.ndarray) -> dict[str, float]:
    """Fraction of the processed time labelled each of :data:`BEHAVIOURS` (sums to 1; zeros when empty)."""
    t = np.asarray(t_ns, dtype=np.int64)
    lab = np.asarray(labels).astype(str)
    out = {b: 0.0 for b in BEHAVIOURS}
    if t.size == 0:
        return out
    dt = np.diff(t).astype(np.float64)
    last = float(np.median(dt)) if dt.size else 1.0
    w = np.append(dt, last)
    lab = np.where(np.isin(lab, BEHAVIOURS[:3]), lab, "other")
    total = float(w.sum())
    for b in BEHAVIOURS:
        out[b] = float(w[lab == b].sum() / total) if total > 0 else 0.0
    return out


@dataclass
class Evaluated:
    """One recording's result row (JSON-ready) and what a plot needs."""

    row: dict[str, Any]
    plot: dict[str, Any] = field(default_factory=dict)
    usable: bool = True


def evaluate_vicon_recording(rec: Recording, runner: Runner) -> Evaluated:
    """ARMSE (2-D and 3-D, authors' definition) and behaviour fractions of one VICON trial, engine in ``zupt``."""
    if rec.truth is None or rec.truth.positions is None or rec.truth.t_ns is None:
        raise ValueError(f"{rec.name}: no per-sample truth")
    run = runner(rec.batch, "zupt", None)
    est = positions_at(run.t_ns, run.pos, rec.truth.t_ns) * _NED_TO_VICON
    gt = rec.truth.positions
    a2 = metrics.armse(est, gt, dims=2)
    a3 = metrics.armse(est, gt, dims=3)
    aligned, gt0, _ = metrics.align_like_authors(est, gt)
    row = {
        "name": rec.name,
        "armse_2d_m": a2,
        "armse_3d_m": a3,
        "samples": int(rec.truth.t_ns.size),
        "behaviour": behaviour_fractions(run.t_ns, run.behaviour),
        "stances": int(run.stances.shape[0]),
    }
    return Evaluated(row, {"est_xy": aligned[:, :2], "truth_xy": gt0[:, :2]})


def evaluate_gdin_recording(rec: Recording, runner: Runner, mode: str, l0_m: float | None = None) -> Evaluated:
    """gdin metrics of DESIGN.md for one recording (keys present only where that truth exists)."""
    x = rec.truth.extra if rec.truth is not None else {}
    if "gcp_m" not in x:
        raise ValueError(f"{rec.name}: no ground-control points (truth .mat missing)")
    run = runner(rec.batch, mode, l0_m)
    st = run.stances
    truth_len = float(x["truth_path_length_m"])
    n_truth = x.get("number_of_strides")
    row: dict[str, Any] = {"name": rec.name}
    plot: dict[str, Any] = {
        "stances_xy": st[:, 1:3].copy(),
        "gcp_xy": np.asarray(x["gcp_m"], dtype=np.float64),
        "gcp_stride_numbers": x.get("gcp_stride_numbers"),
    }
    if x.get("closed_loop") and st.shape[0] >= 2:
        row["loop_closure_pct"] = metrics.loop_closure_pct(st[0, 1:3], st[-1, 1:3], truth_len)
    if "stride_t_ns" in x:
        gcp = np.asarray(x["gcp_m"], dtype=np.float64)
        n = min(len(x["stride_t_ns"]), gcp.shape[0]) - 1
        if n_truth is not None:
            n = min(n, int(n_truth))
        est = positions_at(run.t_ns, run.pos, np.asarray(x["stride_t_ns"])[: n + 1])
        se = metrics.stride_errors(est[:, :2], gcp[: n + 1])
        row["stride_mean_err_m"] = se.mean_m
        row["stride_rmse_m"] = se.rmse_m
        if run.mode is not None:
            # the strides Gait-DR placed: every trace sample from stride k-1 to stride k is in "pdr"
            not_pdr = np.concatenate([[0], np.cumsum(run.mode != "pdr")])
            idx = np.searchsorted(run.t_ns, np.asarray(x["stride_t_ns"])[: n + 1], side="right")
            inside = (not_pdr[idx[1:]] - not_pdr[idx[:-1]] == 0) & (idx[1:] > idx[:-1])
            row["pdr_distance_err_pct"], row["pdr_strides"] = metrics.segment_distance_error_pct(
                est[:, :2], gcp[: n + 1], inside)
        plot.update(aligned_strides_xy=se.aligned_xy, angle_rad=se.angle_rad, gcp_xy=gcp[: n + 1])
    est_len = metrics.path_length_xy(st[:, 1:3]) if st.shape[0] >= 2 else 0.0
    row["distance_err_pct"] = metrics.distance_error_pct(est_len, truth_len)
    row["strides_detected"] = max(int(st.shape[0]) - 1, 0)
    row["strides_truth"] = int(n_truth) if n_truth is not None else int(len(x["gcp_m"]) - 1)
    row["gyro_on_fraction"] = run.gyro_on_fraction
    row["mean_rate_hz"] = run.mean_rate_hz
    row["gt_usable"] = bool(x.get("gcp_exist_and_correct", True))
    row["format"] = rec.meta.source_format
    row["est_path_m"] = est_len
    row["truth_path_m"] = truth_len
    return Evaluated(row, plot, usable=row["gt_usable"])


def vicon_summary(rows: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """``{"mean_armse_2d_m", "median_armse_2d_m", "trials"}`` (plus 3-D mean/median) over successful trials."""
    v = [r["armse_2d_m"] for r in rows if r.get("armse_2d_m") is not None]
    v3 = [r["armse_3d_m"] for r in rows if r.get("armse_3d_m") is not None]
    return {
        "mean_armse_2d_m": float(np.mean(v)) if v else None,
        "median_armse_2d_m": float(np.median(v)) if v else None,
        "trials": len(v),
        "mean_armse_3d_m": float(np.mean(v3)) if v3 else None,
        "median_armse_3d_m": float(np.median(v3)) if v3 else None,
    }


def gdin_summary(rows: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """Per metric ``{"mean", "median", "n"}`` over the rows with usable ground truth (gt_usable)."""
    ok = [r for r in rows if r.get("gt_usable", False) and "error" not in r]
    return {k: metrics.summarise([r.get(k) for r in ok]) for k in GDIN_SUMMARY_KEYS}


def select(items: Iterable[Any], names: Callable[[Any], str], match: Sequence[str] | None, limit: int | None) -> list[Any]:
    """Items whose name contains any of ``match`` (all when empty), at most ``limit`` of them."""
    out = [it for it in items if not match or any(m in names(it) for m in match)]
    return out[:limit] if limit is not None and limit >= 0 else out


def vicon_files(directory: str | Path) -> list[Path]:
    """Every ``*.mat`` in ``directory`` (sorted), as DESIGN.md's ``pednav eval vicon DIR`` specifies."""
    return sorted(Path(directory).glob("*.mat"))


def gdin_entries(directory: str | Path) -> list[GdinEntry]:
    """Every gdin recording under ``directory``, paired with its truth."""
    return find_gdin(directory)


def load_vicon_trial(path: Path) -> Recording:
    return load_vicon(path)


def load_gdin_entry(entry: GdinEntry) -> Recording:
    return load_gdin(entry)
