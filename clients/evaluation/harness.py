"""Evaluation harness: run the engine over public recordings and compute DESIGN.md's metrics.

The engine is replayed like a real device (:func:`energy.device.replay`): it decides the gyroscope state and
the rates, and the replay obeys them. The metrics only use what the engine outputs (the per-sample trace and
the per-stance positions) and the recording's truth; no engine setting is read from the truth.

Frames: the engine outputs NED. The VICON truth's horizontal axes have the same handedness as (north, east)
(checked with a plain ZUPT filter: the authors' ARMSE is reproduced without any mirroring) and its z axis
points up, so for 3-D errors the estimate's "down" is negated. For gdin the stride metric negates y as
DESIGN.md prescribes (the ground-control frame is mirrored).

Definitions of this module (beyond DESIGN.md):

- ``strides_detected`` = number of strides that moved among the stance-to-stance intervals the engine reported
  (:func:`energy.strides.count_moved`: horizontal displacement between consecutive positions of at least
  ``STRIDE_MIN_M``; a re-stance on the spot while standing is no stride; the first stance is the origin of the
  session, not a completed stride); ``stances`` = the positions reported, re-stances included;
- the estimate "at a sample" is the trace position of the last processed accelerometer sample at or before
  that time (sample-and-hold; before the first processed sample: the first one);
- behaviour fractions are time-weighted over the processed samples (each sample stands for the interval to
  the next one); labels other than stand/walk/run count as ``other``.

Returning-user protocol (``pednav eval gdin --profile leave-one-out``): every gdin recording normally starts
as a new user (no profile: the full L0 ZUPT-KF initialisation). With the protocol, the profile a recording
starts with is the one the engine handed out after walking the OTHER recordings of the same sensor/format
group (``RecordingMeta.source_format``), in experiment-number order, each session starting from the profile
the previous one handed out, exactly as one user's successive sessions would (:class:`ProfileChain`,
:func:`leave_one_out_chains`). The sessions run in the evaluated mode (same L0, same conventional flag); the
engine only ever sees sensor samples, so no truth enters a profile, and the evaluated recording is never one
of its own sessions. Recordings whose ground truth is flagged unusable still feed profiles (their samples are
valid walks; they stay out of the summary); recordings that failed to load are not walked. The walkers,
paces and mounts of the recordings differ, so a profile may not fit: the engine's own examination (004
Table 3) decides, and the row says what happened. What a profile holds after a session is the engine's rule
(``Engine.profile_dict``): a session that re-calibrates a behaviour replaces its calibration, one that passes
the examination hands the profile on unchanged.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from clients.evaluation import metrics
from clients.importers._common import is_hidden
from clients.importers.gdin import GdinEntry, find_gdin, load_gdin
from clients.importers.vicon import load_vicon
from clients.recording import Recording
from energy.strides import count_moved
from models.batch import SensorBatch

if TYPE_CHECKING:
    from energy.power import Timeline

__all__ = [
    "BEHAVIOURS",
    "EngineRun",
    "Runner",
    "Evaluated",
    "run_engine",
    "positions_at",
    "behaviour_fractions",
    "mode_fractions",
    "MODES",
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
    "gaitmap_recordings",
    "evaluate_gaitmap_recording",
    "gaitmap_summary",
    "GAITMAP_SUMMARY_KEYS",
    "PROFILE_PROTOCOLS",
    "Session",
    "ProfileChain",
    "leave_one_out_chains",
    "profile_info",
    "event_counts",
]

log = logging.getLogger(__name__)

BEHAVIOURS: tuple[str, ...] = ("stand", "walk", "run", "other")
MODES: tuple[str, ...] = ("zupt", "pdr", "idle")  # navigation modes of the engine's trace
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
GAITMAP_SUMMARY_KEYS: tuple[str, ...] = (
    "stride_length_mean_abs_err_m",
    "stride_length_rmse_m",
    "stride_height_rmse_m",
    "distance_err_pct",
    "gyro_on_fraction",
)
PROFILE_PROTOCOLS: tuple[str, ...] = ("none", "leave-one-out")
_PROFILE_EVENTS: tuple[str, ...] = (
    "calibration_done",
    "examination_passed",
    "examination_repeated",
    "examination_failed",
    "examination_skipped",
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
    profile : dict or None
        The per-user calibration profile the engine handed out at the end (``Engine.profile_dict``); None
        when the runner does not say.
    events : tuple of (str, dict)
        Every engine event (kind, detail) in order; empty when the runner does not say.
    timeline : energy.power.Timeline or None
        What the device did during the replay (:meth:`energy.power.Timeline.from_replay`: sensor states and
        rates over time, samples and batches per cost class, bytes uploaded), the input of the power
        accounting; None when the runner does not say.
    t_start_ns : int
        First sample time of the replayed recording [ns] (the origin of the timelines).
    """

    t_ns: np.ndarray
    pos: np.ndarray
    behaviour: np.ndarray
    stances: np.ndarray
    gyro_on_fraction: float
    mean_rate_hz: float
    mode: np.ndarray | None = None
    profile: dict[str, Any] | None = None
    events: tuple[tuple[str, dict[str, Any]], ...] = ()
    timeline: Timeline | None = None
    t_start_ns: int = 0


class Runner(Protocol):
    """Replays a batch; ``profile`` (the per-user profile the engine starts with) is passed only when not None."""

    def __call__(self, batch: SensorBatch, mode: str, l0_m: float | None) -> EngineRun: ...


def run_engine(batch: SensorBatch, mode: str = "zupt", l0_m: float | None = None, batch_seconds: float | None = 1.0,
               conventional: bool = False, profile: dict[str, Any] | None = None,
               settings: dict[str, Any] | None = None) -> EngineRun:
    """Replay ``batch`` through a fresh engine (``trace=True``) in ``mode``; ``l0_m`` sets ``EngineConfig.l0_m``,
    ``conventional`` the conventional-PDR baseline (``EngineConfig.pdr_conventional``), ``profile`` the per-user
    calibration profile it starts with (None: a new user), ``settings`` further engine settings by dotted path
    (:meth:`energy.config.EngineConfig.override`); ``batch_seconds`` None uploads as the engine asks."""
    from energy.device import replay  # lazy: keeps `pednav --help` fast
    from energy.engine import Engine, EngineConfig
    from energy.power import Timeline

    kw: dict[str, Any] = {"pdr_conventional": bool(conventional), **(settings or {})}
    if l0_m is not None:
        kw["scheduler.l0_m"] = float(l0_m)
    config = EngineConfig().override(kw)
    engine = Engine(mode=mode, config=config, profile=profile, trace=True)
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
        profile=engine.profile_dict(),
        events=tuple((e.kind, dict(e.detail)) for u in res.updates for e in u.events),
        timeline=Timeline.from_replay(res, int(batch.t_end_ns or 0)),
        t_start_ns=int(batch.t_start_ns or 0),
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


def _time_fractions(t_ns: np.ndarray, labels: np.ndarray, names: Sequence[str], other: str | None) -> dict[str, float]:
    """Fraction of the processed time carrying each label of ``names``: each sample stands for the interval to
    the next one (the last one for the median interval). Labels outside ``names`` count as ``other`` (one of
    ``names``) or, with None, towards no fraction. Zeros when empty."""
    t = np.asarray(t_ns, dtype=np.int64)
    lab = np.asarray(labels).astype(str)
    out = {b: 0.0 for b in names}
    if t.size == 0:
        return out
    dt = np.diff(t).astype(np.float64)
    last = float(np.median(dt)) if dt.size else 1.0
    w = np.append(dt, last)
    if other is not None:
        lab = np.where(np.isin(lab, [n for n in names if n != other]), lab, other)
    total = float(w.sum())
    for b in names:
        out[b] = float(w[lab == b].sum() / total) if total > 0 else 0.0
    return out


def behaviour_fractions(t_ns: np.ndarray, labels: np.ndarray) -> dict[str, float]:
    """Fraction of the processed time labelled each of :data:`BEHAVIOURS` (sums to 1; zeros when empty)."""
    return _time_fractions(t_ns, labels, BEHAVIOURS, "other")


def mode_fractions(t_ns: np.ndarray, modes: np.ndarray) -> dict[str, float]:
    """Fraction of the processed time the engine navigated in each of :data:`MODES` (time-weighted as
    :func:`behaviour_fractions`; sums to 1 when every sample has one of them)."""
    return _time_fractions(t_ns, modes, MODES, None)


@dataclass
class Evaluated:
    """One recording's result row (JSON-ready) and what a plot needs."""

    row: dict[str, Any]
    plot: dict[str, Any] = field(default_factory=dict)
    usable: bool = True


def evaluate_vicon_recording(rec: Recording, runner: Runner, mode: str = "zupt") -> Evaluated:
    """ARMSE (2-D and 3-D, authors' definition) and behaviour fractions of one VICON trial, engine in ``mode``
    (default ``zupt``, DESIGN.md's form); the plot dict keeps the :class:`EngineRun` under ``"run"``."""
    if rec.truth is None or rec.truth.positions is None or rec.truth.t_ns is None:
        raise ValueError(f"{rec.name}: no per-sample truth")
    run = runner(rec.batch, mode, None)
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
    if rec.meta.notes:  # what the importer dropped (e.g. truth samples of an occluded marker)
        row["notes"] = list(rec.meta.notes)
    return Evaluated(row, {"est_xy": aligned[:, :2], "truth_xy": gt0[:, :2], "run": run})


def evaluate_gdin_recording(rec: Recording, runner: Runner, mode: str, l0_m: float | None = None,
                            profile: dict[str, Any] | None = None) -> Evaluated:
    """gdin metrics of DESIGN.md for one recording (keys present only where that truth exists).

    ``profile``: the per-user profile the engine starts with (passed to ``runner`` as ``profile=`` only when
    not None); the plot dict keeps the :class:`EngineRun` under ``"run"``. A recording without ground-control
    points still runs: its row has the figures that need no truth, ``distance_err_pct``/``strides_truth``
    ``None``, ``gt_usable`` False (never in the summary) and a note; stride errors need strides 0 and 1 in
    both the stride table and ``GCP_meters``. ``notes`` (only when there are any): what the importer dropped
    or found missing (``RecordingMeta.notes``, ``truth_notes``) and why a metric is absent.
    """
    x = rec.truth.extra if rec.truth is not None else {}
    run = runner(rec.batch, mode, l0_m) if profile is None else runner(rec.batch, mode, l0_m, profile=profile)  # type: ignore[call-arg]
    st = run.stances
    notes = list(rec.meta.notes) + list(x.get("truth_notes", ()))
    if "gcp_m" not in x:
        # nothing to compare with: the engine's own figures, listed but never in the summary
        notes.append("no ground truth (no SensorConnectData_NN.mat with GCP_meters for this experiment): "
                     "figures without truth only, left out of the summary")
        est_len = metrics.path_length_xy(st[:, 1:3]) if st.shape[0] >= 2 else 0.0
        refused = [d.get("reason") for kind, d in run.events if kind == "gyroscope_off_refused"]
        row0: dict[str, Any] = {
            "name": rec.name, "distance_err_pct": None, "gyro_off_refused": refused[0] if refused else None, "strides_detected": count_moved(st[:, 1:3]),
            "stances": int(st.shape[0]),
            "strides_truth": None, "gyro_on_fraction": run.gyro_on_fraction, "mean_rate_hz": run.mean_rate_hz,
            "gt_usable": False, "format": rec.meta.source_format, "est_path_m": est_len, "truth_path_m": None,
            "notes": notes,
        }
        return Evaluated(row0, {"stances_xy": st[:, 1:3].copy(), "run": run}, usable=False)
    truth_len = float(x["truth_path_length_m"])
    n_truth = x.get("number_of_strides")
    row: dict[str, Any] = {"name": rec.name}
    plot: dict[str, Any] = {
        "stances_xy": st[:, 1:3].copy(),
        "gcp_xy": np.asarray(x["gcp_m"], dtype=np.float64),
        "gcp_stride_numbers": x.get("gcp_stride_numbers"),
        "run": run,
    }
    if x.get("closed_loop") and st.shape[0] >= 2:
        row["loop_closure_pct"] = metrics.loop_closure_pct(st[0, 1:3], st[-1, 1:3], truth_len)
    n = -1
    if "stride_t_ns" in x:
        gcp = np.asarray(x["gcp_m"], dtype=np.float64)
        n = min(len(x["stride_t_ns"]), gcp.shape[0]) - 1
        if n_truth is not None:
            n = min(n, int(n_truth))
        if n < 1:
            notes.append(f"stride table and GCP_meters share {n + 1} stride(s): no stride errors "
                         "(need strides 0 and 1)")
    if n >= 1:
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
    row["strides_detected"] = count_moved(st[:, 1:3])
    row["stances"] = int(st.shape[0])
    row["strides_truth"] = int(n_truth) if n_truth is not None else int(len(x["gcp_m"]) - 1)
    row["gyro_on_fraction"] = run.gyro_on_fraction
    row["mean_rate_hz"] = run.mean_rate_hz
    if mode != "zupt":
        # --mode pdr kept the gyroscope because nothing would hold the heading (the engine's event says why)
        refused = [d.get("reason") for kind, d in run.events if kind == "gyroscope_off_refused"]
        row["gyro_off_refused"] = refused[0] if refused else None
    # a sensor file cut short against its truth (clients.importers.gdin.load_gdin) is not comparable either
    row["gt_usable"] = bool(x.get("gcp_exist_and_correct", True)) and bool(x.get("truth_covers_recording", True))
    row["format"] = rec.meta.source_format
    row["est_path_m"] = est_len
    row["truth_path_m"] = truth_len
    if notes:
        row["notes"] = notes
    return Evaluated(row, plot, usable=row["gt_usable"])


def evaluate_gaitmap_recording(rec: Recording, runner: Runner, mode: str = "zupt") -> Evaluated:
    """Stride lengths against optical motion capture, and the height climbed, for one gaitmap foot recording.

    At the foot's still moments of the mocap-derived stride events (``Truth.extra["stance_t_ns"]``) the
    engine's trace position is compared with the heel marker's (:func:`clients.evaluation.metrics.
    stride_length_errors`: strides of at least 0.3 m, distance over all of them); the engine's own stance times
    are not used (it reports a stance at its end, when the heel has already lifted by centimetres).
    The plot dict keeps the :class:`EngineRun` under ``"run"``.
    ``climb_m``: height of the last reported stance above the first [m] (stairs: what the flight rose or,
    negative, fell; there is no truth for it). ``strides_detected``: strides that moved among the
    stance-to-stance intervals reported (module docstring); ``stances``: positions reported.
    """
    run = runner(rec.batch, mode, None)
    st = run.stances
    has_truth = rec.truth is not None and "stance_t_ns" in rec.truth.extra
    row: dict[str, Any] = {"name": rec.name, "mode": mode, "strides_detected": count_moved(st[:, 1:3]),
                           "stances": int(st.shape[0]),
                           "climb_m": float(st[0, 3] - st[-1, 3]) if st.shape[0] >= 2 else 0.0,
                           "gyro_on_fraction": run.gyro_on_fraction, "mean_rate_hz": run.mean_rate_hz,
                           "truth": has_truth}
    plot: dict[str, Any] = {"stances_ned": st[:, 1:4].copy(), "run": run}
    if has_truth:
        assert rec.truth is not None
        q = np.asarray(rec.truth.extra["stance_t_ns"], dtype=np.int64)
        q = q[(q >= rec.truth.t_ns[0]) & (q <= rec.truth.t_ns[-1])]
        est = positions_at(run.t_ns, run.pos, q)
        truth = positions_at(rec.truth.t_ns, rec.truth.positions, q)
        se = metrics.stride_length_errors(est, truth)
        row.update(stride_length_mean_abs_err_m=se.mean_abs_m, stride_length_rmse_m=se.rmse_m,
                   stride_height_rmse_m=se.height_rmse_m, strides_compared=se.n, distance_err_pct=se.distance_err_pct)
        plot["truth_xyz"] = truth
    if rec.meta.notes:
        row["notes"] = list(rec.meta.notes)
    return Evaluated(row, plot, usable=has_truth)


def gaitmap_summary(rows: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """Per metric ``{"mean", "median", "n"}`` over the rows with motion-capture truth."""
    ok = [r for r in rows if r.get("truth") and "error" not in r]
    return {k: metrics.summarise([r.get(k) for r in ok]) for k in GAITMAP_SUMMARY_KEYS}


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
    """Every ``*.mat`` in ``directory`` (sorted), as DESIGN.md's ``pednav eval vicon DIR`` specifies (the
    extension in any case: ``.MAT`` from a Windows export too); hidden files (dotfiles, the macOS ``._*.mat``
    resource forks beside each trial on a copied drive) are not trials and are skipped."""
    return sorted(f for f in Path(directory).iterdir()
                  if f.suffix.lower() == ".mat" and f.is_file() and not is_hidden(f.name))


def gdin_entries(directory: str | Path) -> list[GdinEntry]:
    """Every gdin recording under ``directory``, paired with its truth."""
    return find_gdin(directory)


def gaitmap_recordings(directory: str | Path) -> list[tuple[Path, str]]:
    """``(file, foot)`` for every two-sensor gaitmap CSV in ``directory`` (``imu_sample*.csv``: both feet),
    sorted by file name."""
    from clients.importers.gaitmap import sensor_feet, sniff

    files = sorted(f for f in Path(directory).glob("*.csv") if f.is_file() and not is_hidden(f.name) and sniff(f))
    return [(f, foot) for f in files for foot in sensor_feet(f)]


def load_vicon_trial(path: Path) -> Recording:
    return load_vicon(path)


def load_gdin_entry(entry: GdinEntry) -> Recording:
    return load_gdin(entry)


# ---------------------------------------------------------------------------------------------- returning users
def event_counts(events: Iterable[tuple[str, dict[str, Any]]]) -> dict[str, int]:
    """How often each calibration/examination event kind occurred (kinds of ``_PROFILE_EVENTS``, zeros kept)."""
    out = {k: 0 for k in _PROFILE_EVENTS}
    for kind, _ in events:
        if kind in out:
            out[kind] += 1
    return out


@dataclass(frozen=True)
class Session:
    """One session of a profile chain: the recording walked and what its engine did with the profile.

    Attributes
    ----------
    name : str
        Recording walked.
    events : dict of str to int
        :func:`event_counts` of the session.
    calibrated : tuple of str
        Behaviours the session (re)calibrated (``calibration_done``): the profile's calibration of those
        behaviours comes from this session from here on.
    error : str or None
        The session failed (the profile passes through unchanged).
    """

    name: str
    events: dict[str, int]
    calibrated: tuple[str, ...] = ()
    error: str | None = None

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {"name": self.name, "events": dict(self.events), "calibrated": list(self.calibrated)}
        if self.error is not None:
            d["error"] = self.error
        return d


# session(name, profile_in) -> (profile_out, events): walk one recording as a session of the engine
SessionFn = Callable[[str, dict[str, Any] | None], tuple[dict[str, Any] | None, Sequence[tuple[str, dict[str, Any]]]]]


class ProfileChain:
    """Profiles handed out after walking sequences of recordings, each session starting from the previous one's.

    ``session(name, profile_in) -> (profile_out, events)`` walks one recording as a session of the engine.
    Results are memoised per prefix, so the leave-one-out chains of a group (which share their prefixes) cost
    about N^2/2 sessions instead of N(N-1). :meth:`seed` records a new-user session run elsewhere (the
    evaluation's own new-user pass: the engine is deterministic, so it is the same session).
    """

    def __init__(self, session: SessionFn) -> None:
        self._session = session
        self._memo: dict[tuple[str, ...], tuple[dict[str, Any] | None, tuple[Session, ...]]] = {(): (None, ())}
        self.sessions_run = 0

    def seed(self, name: str, profile: dict[str, Any] | None, events: Sequence[tuple[str, dict[str, Any]]]) -> None:
        """A new user's session on ``name`` handed out ``profile`` with ``events``."""
        self._memo[(name,)] = (profile, (_session(name, events),))

    def after(self, chain: Sequence[str]) -> tuple[dict[str, Any] | None, tuple[Session, ...]]:
        """Profile handed out after the sessions ``chain`` (in order, the first one a new user) and the sessions."""
        key = tuple(chain)
        k = len(key)
        while key[:k] not in self._memo:
            k -= 1
        profile, sessions = self._memo[key[:k]]
        for i in range(k, len(key)):
            name = key[i]
            try:
                out, events = self._session(name, profile)
                self.sessions_run += 1
                profile, sessions = out, sessions + (_session(name, events),)
            except Exception as exc:  # noqa: BLE001 - a broken session leaves the profile as it was
                log.exception("profile session %s failed", name)
                sessions = sessions + (Session(name, {k2: 0 for k2 in _PROFILE_EVENTS}, (), f"{type(exc).__name__}: {exc}"),)
            self._memo[key[: i + 1]] = (profile, sessions)
        return profile, sessions


def _session(name: str, events: Sequence[tuple[str, dict[str, Any]]]) -> Session:
    cal = tuple(dict.fromkeys(str(d.get("behaviour")) for kind, d in events if kind == "calibration_done"))
    return Session(name, event_counts(events), cal)


def leave_one_out_chains(groups: dict[str, Sequence[str]]) -> dict[str, tuple[str, ...]]:
    """Per recording, the sessions its profile is built from: the other members of its group, in group order.

    Parameters
    ----------
    groups : dict of str to sequence of str
        Group key (sensor/format) -> recording names in the order a user would have walked them.
    """
    out: dict[str, tuple[str, ...]] = {}
    for members in groups.values():
        for name in members:
            out[name] = tuple(m for m in members if m != name)
    return out


def profile_info(profile: dict[str, Any] | None, sessions: Sequence[Session],
                 events: Sequence[tuple[str, dict[str, Any]]]) -> dict[str, Any]:
    """The ``profile`` entry of a returning-user row: what fed the profile, what it held, what the engine did.

    ``fed_by``: the recordings walked to build it, in order; ``calibrated_in``: per behaviour, the session
    whose calibration the profile held at the end (the last one that calibrated it); ``behaviours``: per
    calibrated behaviour its steps, sigma_d [m], heading deviation [deg] and whether a fitted compass came with
    it; ``events``: :func:`event_counts` of the evaluated session (``examination_failed`` > 0: the engine
    rejected the profile and re-initialised); ``resumed``: the evaluated session passed an examination of the
    profile's calibration before any re-calibration.
    """
    last: dict[str, str] = {}
    for s in sessions:
        for b in s.calibrated:
            last[b] = s.name
    behaviours: dict[str, Any] = {}
    for b, cal in ((profile or {}).get("behaviours") or {}).items():
        if not cal.get("calibrated"):
            continue
        compass = (cal.get("step_model") or {}).get("compass") or {}
        rms = compass.get("heading_rms")
        behaviours[b] = {
            "n_steps": int(cal.get("n_steps", 0)),
            "sigma_d_m": _finite(cal.get("sigma_d_m")),
            "heading_deviation_deg": _finite(np.degrees(float(cal.get("heading_deviation_rad", np.nan)))),
            "compass_ready": bool(compass.get("ready", False)),
            "compass_heading_rms_deg": _finite(np.degrees(float(rms))) if rms is not None else None,
        }
    kinds = [k for k, _ in events]
    first_cal = kinds.index("calibration_done") if "calibration_done" in kinds else len(kinds)
    return {
        "fed_by": [s.name for s in sessions],
        "sessions": [s.to_dict() for s in sessions],
        "calibrated_in": last,
        "behaviours": behaviours,
        "events": event_counts(events),
        "resumed": "examination_passed" in kinds[:first_cal],
    }


def _finite(v: Any) -> float | None:
    try:
        f = float(v)
    except (TypeError, ValueError):
        return None
    return f if np.isfinite(f) else None
