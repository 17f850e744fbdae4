"""``pednav eval ipin``: the step-and-heading engine on GetSensorData logfiles with surveyed landmarks
(datasets/ipin2023-t3-phone, DESIGN.md "Evaluation contracts").

Scoring (datasets/ipin2023-t3-phone/ABOUT.md): the estimate starts at the first landmark: the track is translated
so that its position at the first landmark's time is that landmark (NED at the first landmark); no truth sets the
heading (the engine's own, magnetic north, turned to true north by the WMM declination at the anchor as
geo-referencing does, :func:`models.geo.to_true_north`; the anchor is the first landmark's latitude and longitude,
as a phone app would know its building, on the logfile's date). The estimate at a time is interpolated linearly between
the step positions around it (the origin before the first step). Per trial: the horizontal error at every later
landmark, their mean and 75th percentile (the competition's metric), the error at the last landmark (the trials
return to the first: the loop error), the path ratio (sum of the step lengths between the first and last
landmark over the surveyed path, the sum of landmark-to-landmark distances; the walk between landmarks is not
guaranteed straight, so the surveyed path is a lower bound), the steps between the two, and the energy ratio
(the energy-aware replay over the always-on replay of the whole file, :func:`phone_energy`; ``energy_ratio_landmarks``
the same between the first and the last landmark, the stretch the errors score: the files begin with about a
minute of the competition's calibration manoeuvre, the device waved about, during which ``auto`` keeps the
gyroscope on for its bias), and the samples per
stream the engine received too late to use (``late_samples``, :attr:`energy.phone_engine.PhoneEngine.late_samples`).

Fitted on the data, and so left out per trial (leave-one-route-out: the two repetitions of a route are one
walker's same walk, both are left out): the Weinberg constant of the engine and of the baseline, each as the
surveyed path length over the sum of the model's unscaled step lengths of the other routes' trials.

``calibration="returning-user"`` (the engine only): the user has walked a known distance before, the other
repetition of the route (its surveyed length and the engine's own unscaled steps over it), and the profile's
constant is that walk merged into the population constant above by the engine's own calibration
(:meth:`models.pdr_step_length.PdrStepLength.calibrate`, as ``POST /v1/sessions/{id}/distance`` does): what the
issue's per-user calibration from a known distance buys, on a walk of the same route (so the known distance is
the trial's own surveyed length: an optimistic setting for the path ratio, not for the landmark errors).

The baseline (the issue's "simple baseline"): steps from the accelerometer magnitude (2nd-order Butterworth at
3 Hz applied forward and backward, peaks 0.7 m/s^2 above g at least 0.35 s apart), Weinberg step length with one
constant, and the phone's own rotation vector (the logfile's AHRS quaternion) for the heading of its forward
axis plus the declination. Offline (it sees the whole file), so it is a lower bar than a causal engine.
"""

from __future__ import annotations

import datetime as _dt
import math
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

from clients.recording import Recording

CALIBRATIONS: tuple[str, ...] = ("population", "returning-user")

__all__ = ["CALIBRATIONS", "LandmarkErrors", "TrialResult", "landmark_errors", "route_of", "phone_energy", "run_phone",
           "logfile_recordings",
           "baseline_track", "evaluate_ipin", "ipin_summary", "ipin_logfiles", "logfile_cli", "leave_one_route_out",
           "print_loro", "landmarks", "paired_ratio", "TRIAL_FIELDS"]

TRIAL_FIELDS = ("name", "mean_err_m", "p75_err_m", "final_err_m", "path_ratio", "steps", "energy_ratio")
POWER_PROFILE = "phone-bmi270"


@dataclass(frozen=True)
class LandmarkErrors:
    """Landmark errors of one track (see the module docstring)."""

    errors_m: np.ndarray
    mean_err_m: float
    p75_err_m: float
    final_err_m: float
    path_ratio: float
    steps: int

    def row(self) -> dict[str, Any]:
        return {"mean_err_m": self.mean_err_m, "p75_err_m": self.p75_err_m, "final_err_m": self.final_err_m,
                "path_ratio": self.path_ratio, "steps": self.steps}


def landmark_errors(truth_t_ns: np.ndarray, truth_ne: np.ndarray, pos_t_ns: np.ndarray, pos_ne: np.ndarray,
                    step_m: np.ndarray) -> LandmarkErrors:
    """Errors of a step track at the landmarks.

    Parameters
    ----------
    truth_t_ns : ndarray of int64, shape (K,)
        Landmark times [ns].
    truth_ne : ndarray, shape (K, 2)
        Landmark positions (north, east) [m].
    pos_t_ns : ndarray of int64, shape (N,)
        Step times [ns].
    pos_ne : ndarray, shape (N, 2)
        Positions after each step (north, east) [m].
    step_m : ndarray, shape (N,)
        Each step's length [m].
    """
    T = np.asarray(truth_t_ns, dtype=np.int64)
    L = np.asarray(truth_ne, dtype=float).reshape(-1, 2)
    t = np.asarray(pos_t_ns, dtype=np.int64)
    p = np.asarray(pos_ne, dtype=float).reshape(-1, 2)
    if len(T) < 2:
        raise ValueError("truth: at least two landmarks are needed")
    if len(t) == 0:
        est = np.zeros((len(T), 2))
    else:
        tt = np.concatenate([[t[0] - 1], t]).astype(float)
        pp = np.vstack([np.zeros((1, 2)), p])
        est = np.column_stack([np.interp(T.astype(float), tt, pp[:, 0]), np.interp(T.astype(float), tt, pp[:, 1])])
    est = est - est[0] + L[0]
    err = np.linalg.norm(est[1:] - L[1:], axis=1)
    inside = (t > T[0]) & (t <= T[-1])
    truth_len = float(np.sum(np.linalg.norm(np.diff(L, axis=0), axis=1)))
    ratio = float(np.sum(np.asarray(step_m, dtype=float)[inside]) / truth_len) if truth_len > 0 else math.nan
    return LandmarkErrors(err, float(np.mean(err)), float(np.percentile(err, 75)), float(err[-1]), ratio,
                          int(inside.sum()))


def ipin_logfiles(directory: str | None) -> tuple[Path, list[Path]]:
    """The GetSensorData logfiles (``*.txt``) of ``directory`` or of its ``logfiles`` folder (default
    ``PEDNAV_DATA/ipin2023-t3-phone``): ``(folder looked in, sorted files)``."""
    d = Path(directory) if directory else Path(os.environ.get("PEDNAV_DATA", "../shared/datasets")) / "ipin2023-t3-phone"
    return d, sorted((d / "logfiles" if (d / "logfiles").is_dir() else d).glob("*.txt"))


def logfile_cli(prog: str, description: str, argv: Sequence[str] | None) -> tuple[Any, list[Path]] | None:
    """Command line of the phone diagnosis scripts (``DIR``, ``--json``): ``(arguments, logfiles)``, or None after
    printing one line when the folder holds no logfile."""
    import argparse

    ap = argparse.ArgumentParser(prog=prog, description=description)
    ap.add_argument("dir", nargs="?", help="folder of logfiles (default: PEDNAV_DATA/ipin2023-t3-phone)")
    ap.add_argument("--json", action="store_true", help="print one JSON document")
    a = ap.parse_args(argv)
    d, files = ipin_logfiles(a.dir)
    if not files:
        print(f"error: no GetSensorData logfiles in {d}")
        return None
    return a, files


def logfile_recordings(prog: str, module_doc: str, argv: Sequence[str] | None) -> tuple[Any, list[Recording]] | None:
    """:func:`logfile_cli` with the logfiles loaded, the description the module docstring's first line:
    ``(arguments, recordings)``, or None after one line naming a file that is not a logfile (the caller exits
    with 2)."""
    from clients.importers import ImporterError, load

    parsed = logfile_cli(prog, module_doc.split("\n")[0], argv)
    if parsed is None:
        return None
    try:
        return parsed[0], [load(f) for f in parsed[1]]
    except ImporterError as exc:
        print(f"error: {exc}")
        return None


def route_of(name: str) -> str:
    """The route a trial walks: its name without the repetition (``IPIN2023_T3_TrainingTrial03_repetition01`` ->
    ``IPIN2023_T3_TrainingTrial03``)."""
    return name.rsplit("_repetition", 1)[0]


def leave_one_route_out(tables: Sequence[Any], statistics: Callable[[Sequence[Any]], dict[str, float]]) -> dict[str, Any]:
    """``statistics`` of per-trial tables (each with a ``name``) on all trials, per fold leaving out one route
    (:func:`route_of`), and each statistic's range over the folds: ``{"all", "folds", "range"}``."""
    routes = sorted({route_of(t.name) for t in tables})
    folds = {r: statistics([t for t in tables if route_of(t.name) != r]) for r in routes}
    every = statistics(tables)
    return {"all": every, "folds": folds,
            "range": {k: [min(f[k] for f in folds.values()), max(f[k] for f in folds.values())] for k in every}}


def print_loro(stats: dict[str, Any], indent: str = "", width: int = 26) -> None:
    """Print :func:`leave_one_route_out`'s result, a statistic a line: its value on all trials and its range."""
    for k, v in stats["all"].items():
        lo, hi = stats["range"][k]
        print(f"{indent}{k:{width}s} {v:9.3f}   leave-one-route-out {lo:9.3f} .. {hi:9.3f}")


def _anchor_and_date(rec: Recording) -> tuple[tuple[float, float, float], _dt.date | None]:
    assert rec.truth is not None
    lat, lon = rec.truth.extra["origin_deg"]
    day = (rec.aux.get("device") or {}).get("date")
    return (float(lat), float(lon), 0.0), (_dt.date.fromisoformat(day) if day else None)


@lru_cache(maxsize=1)
def _phone_profile() -> Any:
    """The phone power profile with the step-and-heading engine's compute costs (read once: every replay is
    accounted twice, the whole file and the landmarks' stretch)."""
    from energy.power import load_compute_costs, load_profile

    return load_profile(POWER_PROFILE, compute=load_compute_costs().for_engine("phone"))


def phone_energy(res: Any, t_end_ns: int, window_ns: tuple[int, int] | None = None) -> Any:
    """Energy of a replay (:func:`energy.device.replay`) on the phone power profile ``phone-bmi270``, with the
    step-and-heading engine's measured compute costs (``compute_costs.json``, engine ``phone``); of the stretch
    ``window_ns`` ``(t0, t1)`` [ns] only if given (:meth:`energy.power.Timeline.from_replay`)."""
    from energy.power import Timeline, account

    return account(Timeline.from_replay(res, t_end_ns, window_ns), _phone_profile())


@dataclass
class TrialResult:
    """One replay of a trial: its positions, step lengths and energy."""

    t_ns: np.ndarray
    ne: np.ndarray
    step_m: np.ndarray
    energy_mj: float
    gyro_on_fraction: float
    events: dict[str, int] = field(default_factory=dict)
    late_samples: dict[str, int] = field(default_factory=dict)
    energy_landmarks_mj: float = math.nan  # between the first and the last landmark


def run_phone(rec: Recording, mode: str, weinberg_k: float, placement: str | None = "phone-hand",
              batch_seconds: float = 1.0, max_heading_std_rad: float | None = None,
              start_offset_s: float = 0.0, gyro_duty: tuple[float, ...] | None = None,
              walk_gyro: str | None = None) -> TrialResult:
    """Replay a recording through the step-and-heading engine as a phone obeying its sensor configuration
    (``max_heading_std_rad``: the energy-aware mode's bound, default the engine's; ``start_offset_s`` [s]: the
    replay starts this long after the recording, which moves the upload batches' boundaries against the walk;
    ``gyro_duty``: ``(P, on)`` [s], ``auto`` duty-cycles the gyroscope where it would switch it off walking,
    ``PhoneEngineConfig.gyro_duty_period_s`` / ``gyro_duty_on_s``; ``(P, on, 1)``: also ``gyro_duty_only``; ``(P, on, only,
    sigma_deg)``: also ``gyro_duty_sigma_rad``; None: the engine's default; ``walk_gyro``:
    :attr:`energy.phone_engine.PhoneEngineConfig.walk_gyro`, None: the engine's default)."""
    from dataclasses import replace

    from energy.device import replay
    from energy.phone_engine import PhoneEngine, PhoneEngineConfig

    anchor, day = _anchor_and_date(rec)
    base = PhoneEngineConfig()
    cfg = replace(base, step_length=replace(base.step_length, weinberg_k=float(weinberg_k)))
    if max_heading_std_rad is not None:
        cfg = replace(cfg, max_heading_std_rad=float(max_heading_std_rad))
    if walk_gyro is not None:
        cfg = replace(cfg, walk_gyro=walk_gyro)
    if gyro_duty is not None:
        cfg = replace(cfg, gyro_duty_period_s=float(gyro_duty[0]), gyro_duty_on_s=float(gyro_duty[1]),
                      gyro_duty_only=len(gyro_duty) > 2 and bool(gyro_duty[2]),
                      gyro_duty_sigma_rad=math.radians(float(gyro_duty[3])) if len(gyro_duty) > 3 else 0.0)
    eng = PhoneEngine(mode=mode, config=cfg, device_kind="phone", placement=placement, anchor=anchor, date=day)
    batch = rec.batch
    if start_offset_s > 0:
        batch = batch.time_slice(int(batch.t_start_ns or 0) + int(round(start_offset_s * 1e9)), int(batch.t_end_ns or 0) + 1)
    res = replay(eng, batch, batch_seconds)
    t_end = int(rec.batch.t_end_ns or 0) + 1
    report = phone_energy(res, t_end)
    T, _ = landmarks(rec)
    walked = phone_energy(res, t_end, (int(T[0]), int(T[-1])))
    ev: dict[str, int] = {}
    for u in res.updates:
        for e in u.events:
            ev[e.kind] = ev.get(e.kind, 0) + 1
    pos = res.positions
    from models.geo import to_true_north

    _, decl = _declination(rec)  # the engine's north is magnetic: turned as geo-referencing turns it
    n, e, _h = to_true_north(np.array([p.north for p in pos]), np.array([p.east for p in pos]),
                             np.array([p.heading_rad for p in pos]), decl)
    return TrialResult(np.array([p.t_ns for p in pos], dtype=np.int64), np.column_stack([n, e]).reshape(-1, 2),
                       np.array([p.step_length_m for p in pos]), float(report.total_mj), float(res.gyro_on_fraction), ev,
                       eng.late_samples, float(walked.total_mj))


def baseline_track(rec: Recording, weinberg_k: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The simple baseline's track: ``(t_ns, positions NE, step lengths, unscaled Weinberg features)``."""
    from scipy.signal import butter, filtfilt, find_peaks

    b = rec.batch
    ahrs = rec.aux.get("ahrs")
    if ahrs is None:
        raise ValueError(f"{rec.name}: the baseline needs the phone's rotation vector (AHRS lines)")
    t = b.acc_t_ns
    a = np.linalg.norm(b.acc, axis=1)
    fs = b.rate_hz("acc")
    bb, aa = butter(2, 3.0 / (fs / 2.0))
    af = filtfilt(bb, aa, a)
    pk, _ = find_peaks(af, height=9.80665 + 0.7, distance=max(1, int(round(0.35 * fs))))
    feat = np.empty(len(pk))
    for i, k in enumerate(pk):
        k0 = pk[i - 1] if i > 0 else max(0, k - int(round(0.5 * fs)))
        seg = af[k0:k + 1]
        feat[i] = (seg.max() - seg.min()) ** 0.25  # 000 eq. (35)
    sl = weinberg_k * feat
    # forward axis of the rotation vector (Android: body -> ENU), up x x_body, azimuth from north, + declination
    q = np.asarray(ahrs["quat_xyz"], dtype=float)
    w = np.sqrt(np.clip(1.0 - np.sum(q * q, axis=1), 0.0, 1.0))
    x, y, z = q[:, 0], q[:, 1], q[:, 2]
    x_e, x_n = 1 - 2 * (y * y + z * z), 2 * (x * y + w * z)  # body x axis in ENU (east, north)
    az = np.arctan2(-x_n, x_e)  # up x x_body = (-x_n, x_e) in (east, north): azimuth atan2(east, north)
    _, decl = _declination(rec)
    i = np.clip(np.searchsorted(ahrs["t_ns"], t[pk]), 0, len(az) - 1)
    head = np.unwrap(az[i]) + decl
    ne = np.cumsum(np.column_stack([sl * np.cos(head), sl * np.sin(head)]), axis=0)
    return t[pk], ne.reshape(-1, 2), sl, feat


def _declination(rec: Recording) -> tuple[Any, float]:
    """The WMM's elements and declination [rad] at the first landmark on the logfile's date."""
    from models.geo import Anchor, magnetic_elements

    (lat, lon, alt), day = _anchor_and_date(rec)
    el = magnetic_elements(Anchor(lat, lon, alt, **({"date": day} if day else {})))
    return el, el.declination_rad


def _loo_k(name: str, totals: dict[str, tuple[float, float]]) -> float:
    """Surveyed length over unscaled step lengths of the trials of the other routes."""
    num = sum(d for n, (d, _) in totals.items() if route_of(n) != route_of(name))
    den = sum(s for n, (_, s) in totals.items() if route_of(n) != route_of(name))
    if not den > 0:
        raise ValueError(f"{name}: no steps on the other routes' trials to fit the Weinberg step constant on "
                         "(a logfile with neither gyroscope nor magnetometer has no heading, so no steps are placed)")
    return num / den


def _returning_user_k(name: str, k_population: float, walked: dict[str, tuple[float, np.ndarray]]) -> float:
    """The constant of a user who walked the other repetitions of ``name``'s route as known distances, each
    merged into the population constant ``k_population`` by the engine's calibration (``k_population`` when
    there is none)."""
    from dataclasses import replace

    from energy.phone_engine import PhoneEngineConfig
    from models.pdr_step_length import PdrStepLength

    base = PhoneEngineConfig().step_length
    sl = PdrStepLength(replace(base, weinberg_k=float(k_population)))
    for other, (distance_m, unscaled) in walked.items():
        if other != name and route_of(other) == route_of(name):
            sl.calibrate(distance_m, unscaled)
    return float(sl.k)


def landmarks(rec: Recording) -> tuple[np.ndarray, np.ndarray]:
    """The trial's surveyed landmarks (POSI lines): times [ns] and positions (N, 2) [m, local frame]."""
    if rec.truth is None or rec.truth.positions is None or rec.truth.t_ns is None:
        raise ValueError(f"{rec.name}: no landmarks (POSI lines)")
    return rec.truth.t_ns, rec.truth.positions[:, :2]


def _window_sum(rec: Recording, t_ns: np.ndarray, values: np.ndarray) -> float:
    T, _ = landmarks(rec)
    inside = (t_ns > T[0]) & (t_ns <= T[-1])
    return float(np.sum(values[inside]))


def _surveyed(rec: Recording) -> float:
    _, L = landmarks(rec)
    return float(np.sum(np.linalg.norm(np.diff(L, axis=0), axis=1)))


def evaluate_ipin(recs: Sequence[Recording], mode: str = "auto", placement: str | None = "phone-hand",
                  batch_seconds: float = 1.0, progress: Callable[[str], None] | None = None,
                  max_heading_std_rad: float | None = None, phases: int = 1,
                  calibration: str = "population", gyro_duty: tuple[float, ...] | None = None,
                  walk_gyro: str | None = None) -> dict[str, Any]:
    """The ``pednav eval ipin`` document for loaded recordings (see the module docstring; ``calibration``:
    ``"population"`` or ``"returning-user"``).

    Every trial is replayed always-on (the energy baseline; its steps also fit the Weinberg constant of the
    others) and, with ``mode="auto"``, energy-aware; the trial's row reports ``mode``'s track; ``always_on``
    and ``baseline`` hold the same metrics of the always-on replay and of the simple baseline.

    ``phases`` > 1: both replays are repeated with the upload batches' boundaries moved by ``k / phases`` of a
    batch (``k = 1 .. phases - 1``; the replay starts that much later, inside the calibration manoeuvre before
    the first landmark). An energy-aware engine switches its sensors at batch boundaries, so whether the
    gyroscope is back in time for a turn depends on where they fall: ``doc["phases"]`` holds the medians of each
    phase and their mean, the figure that does not depend on that luck (the rows are phase 0's).
    ``gyro_duty``: ``(P, on)`` [s] of the energy-aware mode's duty-cycled gyroscope, ``walk_gyro`` its gyroscope
    while walking (:func:`run_phone`).
    """
    from energy.phone_engine import PhoneEngineConfig

    if calibration not in CALIBRATIONS:
        raise ValueError(f"calibration: one of {', '.join(CALIBRATIONS)}, got {calibration!r}")
    k0 = PhoneEngineConfig().step_length.weinberg_k
    always: dict[str, TrialResult] = {}
    totals: dict[str, tuple[float, float]] = {}
    walked: dict[str, tuple[float, np.ndarray]] = {}  # surveyed length, unscaled steps over it (returning user)
    base_totals: dict[str, tuple[float, float]] = {}
    for rec in recs:  # pass 1: features for the leave-one-route-out constants (independent of the constant)
        if progress:
            progress(rec.name)
        r = run_phone(rec, "always-on", k0, placement, batch_seconds)
        always[rec.name] = r
        totals[rec.name] = (_surveyed(rec), _window_sum(rec, r.t_ns, r.step_m / k0))
        T, _ = landmarks(rec)
        walked[rec.name] = (_surveyed(rec), (r.step_m / k0)[(r.t_ns > T[0]) & (r.t_ns <= T[-1])])
        bt, _, _, feat = baseline_track(rec, 1.0)
        base_totals[rec.name] = (_surveyed(rec), _window_sum(rec, bt, feat))
    trials = []
    for rec in recs:
        if progress:
            progress(rec.name)
        T, L = landmarks(rec)
        k = _loo_k(rec.name, totals)
        if calibration == "returning-user":
            k = _returning_user_k(rec.name, k, walked)
        on = run_phone(rec, "always-on", k, placement, batch_seconds)
        run = on if mode == "always-on" else run_phone(rec, mode, k, placement, batch_seconds, max_heading_std_rad,
                                                       gyro_duty=gyro_duty, walk_gyro=walk_gyro)
        e = landmark_errors(T, L, run.t_ns, run.ne, run.step_m)
        e_on = landmark_errors(T, L, on.t_ns, on.ne, on.step_m)
        kb = _loo_k(rec.name, base_totals)
        bt, bne, bsl, _ = baseline_track(rec, kb)
        e_b = landmark_errors(T, L, bt, bne, bsl)
        row = {"name": rec.name, **e.row(), "energy_ratio": run.energy_mj / on.energy_mj,
               "energy_ratio_landmarks": run.energy_landmarks_mj / on.energy_landmarks_mj,
               "accuracy_ratio": e.mean_err_m / e_on.mean_err_m if e_on.mean_err_m > 0 else None,
               "gyro_on_fraction": run.gyro_on_fraction, "weinberg_k": k, "landmarks": int(len(T)),
               "phone": (rec.aux.get("device") or {}).get("Model"), "events": run.events,
               "late_samples": run.late_samples,
               "always_on": {**e_on.row(), "energy_mj": on.energy_mj, "late_samples": on.late_samples},
               "baseline": {**e_b.row(), "weinberg_k": kb}}
        trials.append(row)
    doc = {"dataset": "ipin", "mode": mode, "placement": placement, "calibration": calibration, "trials": trials,
           "summary": ipin_summary(trials)}
    if phases > 1:
        doc["phases"] = _phases(recs, trials, mode, placement, batch_seconds, max_heading_std_rad, int(phases), progress,
                                gyro_duty, walk_gyro)
    if max_heading_std_rad is not None:
        doc["max_heading_std_rad"] = max_heading_std_rad
    if gyro_duty is not None:
        doc["gyro_duty"] = [float(x) for x in gyro_duty]
    if walk_gyro is not None:
        doc["walk_gyro"] = walk_gyro
    return doc


def _phases(recs: Sequence[Recording], trials: list[dict[str, Any]], mode: str, placement: str | None,
            batch_seconds: float, max_heading_std_rad: float | None, phases: int,
            progress: Callable[[str], None] | None, gyro_duty: tuple[float, ...] | None = None,
            walk_gyro: str | None = None) -> dict[str, Any]:
    """Median and worst mean landmark error, median 75th percentile and median energy ratio of ``mode`` and of
    always-on for each batch phase (phase 0: ``trials``), their means over the phases, and each trial's mean
    error averaged over the phases."""
    rows: list[list[dict[str, float]]] = [[{"mean": t["mean_err_m"], "p75": t["p75_err_m"], "on": t["always_on"]["mean_err_m"],
                                             "on_p75": t["always_on"]["p75_err_m"], "energy": t["energy_ratio"],
                                             "energy_lm": t["energy_ratio_landmarks"]}
                                            for t in trials]]
    ks = {t["name"]: t["weinberg_k"] for t in trials}
    for k in range(1, phases):
        off = k * batch_seconds / phases
        per = []
        for rec in recs:
            if progress:
                progress(f"{rec.name} phase {k}")
            T, L = landmarks(rec)
            on = run_phone(rec, "always-on", ks[rec.name], placement, batch_seconds, start_offset_s=off)
            run = on if mode == "always-on" else run_phone(rec, mode, ks[rec.name], placement, batch_seconds,
                                                           max_heading_std_rad, start_offset_s=off, gyro_duty=gyro_duty,
                                                           walk_gyro=walk_gyro)
            e, e_on = landmark_errors(T, L, run.t_ns, run.ne, run.step_m), landmark_errors(T, L, on.t_ns, on.ne, on.step_m)
            per.append({"mean": e.mean_err_m, "p75": e.p75_err_m, "on": e_on.mean_err_m, "on_p75": e_on.p75_err_m,
                        "energy": run.energy_mj / on.energy_mj,
                        "energy_lm": run.energy_landmarks_mj / on.energy_landmarks_mj})
        rows.append(per)
    out: list[dict[str, Any]] = []
    for k, per in enumerate(rows):
        med = {f: float(np.median([r[f] for r in per])) for f in ("mean", "p75", "on", "on_p75", "energy", "energy_lm")}
        out.append({"offset_s": k * batch_seconds / phases, "mean_err_m": med["mean"], "p75_err_m": med["p75"],
                    "worst_mean_err_m": float(max(r["mean"] for r in per)), "energy_ratio": med["energy"],
                    "energy_ratio_landmarks": med["energy_lm"],
                    "always_on": {"mean_err_m": med["on"], "p75_err_m": med["on_p75"],
                                  "worst_mean_err_m": float(max(r["on"] for r in per))},
                    "ratio_of_medians": med["mean"] / med["on"] if med["on"] > 0 else None})

    def avg(key: str, part: str | None = None) -> float:
        return float(np.mean([(p[part] if part else p)[key] for p in out]))

    per_trial = [(float(np.mean([rows[k][i]["mean"] for k in range(phases)])),
                  float(np.mean([rows[k][i]["on"] for k in range(phases)]))) for i in range(len(trials))]
    return {"phases": phases, "per_phase": out,
            "mean": {"mean_err_m": avg("mean_err_m"), "p75_err_m": avg("p75_err_m"),
                     "worst_mean_err_m": avg("worst_mean_err_m"), "energy_ratio": avg("energy_ratio"),
                     "energy_ratio_landmarks": avg("energy_ratio_landmarks"),
                     "ratio_of_medians": float(np.mean([p["ratio_of_medians"] for p in out])),
                     "paired_ratio": paired_ratio([a for a, _ in per_trial], [b for _, b in per_trial]),
                     "always_on": {"mean_err_m": avg("mean_err_m", "always_on"), "p75_err_m": avg("p75_err_m", "always_on"),
                                   "worst_mean_err_m": avg("worst_mean_err_m", "always_on")}},
            "trials": [{"name": t["name"], "mean_err_m": a, "always_on_mean_err_m": b}
                       for t, (a, b) in zip(trials, per_trial, strict=True)]}


def paired_ratio(errors: Sequence[float], reference: Sequence[float], resamples: int = 4000,
                 seed: int = 0) -> dict[str, Any]:
    """Geometric mean of the per-trial error ratios ``errors / reference`` with a bootstrap 90 % interval over
    the trials.

    The ratio of the two medians mixes each configuration's luck on different trials (a trial's compass offset
    moves its error by a metre from one configuration to the next); the per-trial ratio pairs them, so the
    trials' difficulty cancels and the interval says how far the 16 dev trials pin the ratio down.

    Parameters
    ----------
    errors, reference : sequence of float
        Per trial, the configuration's and the reference's error [m] (the same trials in the same order).
        Pairs with a missing, non-finite or non-positive value are left out.
    resamples : int
        Bootstrap resamples of the trials (with replacement).
    seed : int
        Seed of the resampling (the interval is reproducible).

    Returns
    -------
    dict
        ``geomean`` [-], ``ci90`` ([5th, 95th] percentile of the resampled geometric means), ``n`` (pairs used);
        ``None`` values without a pair.
    """
    pairs = [(float(a), float(b)) for a, b in zip(errors, reference, strict=True)
             if a is not None and b is not None and math.isfinite(a) and math.isfinite(b) and a > 0 and b > 0]
    if not pairs:
        return {"geomean": None, "ci90": None, "n": 0}
    lr = np.log([a / b for a, b in pairs])
    idx = np.random.default_rng(seed).integers(0, len(lr), size=(int(resamples), len(lr)))
    boot = np.exp(lr[idx].mean(axis=1))
    lo, hi = np.percentile(boot, [5.0, 95.0])
    return {"geomean": float(np.exp(lr.mean())), "ci90": [float(lo), float(hi)], "n": len(pairs)}


def _stats(values: list[float], worst: str) -> dict[str, Any]:
    v = [x for x in values if x is not None and math.isfinite(x)]
    if not v:
        return {"median": None, "worst": None, "n": 0}
    w = max(v) if worst == "max" else min(v) if worst == "min" else max(v, key=lambda x: abs(x - 1.0))
    return {"median": float(np.median(v)), "worst": float(w), "n": len(v)}


def ipin_summary(trials: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """Median and worst of every metric (worst: the largest error / ratio, the path ratio farthest from 1), for
    the evaluated mode, the always-on replay and the baseline; path ratios per phone model too."""
    ok = [t for t in trials if "error" not in t]
    out: dict[str, Any] = {"trials": len(ok)}
    for k in ("mean_err_m", "p75_err_m", "final_err_m", "energy_ratio", "energy_ratio_landmarks", "accuracy_ratio",
              "gyro_on_fraction"):
        out[k] = _stats([t.get(k) for t in ok], "max")
    out["accuracy_ratio"]["paired"] = paired_ratio([t["mean_err_m"] for t in ok],
                                                   [t["always_on"]["mean_err_m"] for t in ok])
    out["path_ratio"] = _stats([t["path_ratio"] for t in ok], "far")
    out["steps"] = _stats([t["steps"] for t in ok], "max")
    for part in ("always_on", "baseline"):
        out[part] = {k: _stats([t[part][k] for t in ok], "max") for k in ("mean_err_m", "p75_err_m", "final_err_m")}
        out[part]["path_ratio"] = _stats([t[part]["path_ratio"] for t in ok], "far")
    phones = sorted({str(t.get("phone")) for t in ok})
    out["path_ratio_by_phone"] = {p: _stats([t["path_ratio"] for t in ok if str(t.get("phone")) == p], "far") for p in phones}
    return out
