"""The statistics behind the phone's heading-estimator parameters (:data:`energy.phone_engine.PHONE_HEADING`).

``python -m clients.evaluation.phone_heading [DIR] [--json]`` over the IPIN 2023 T3 dev trials (GetSensorData
logfiles with landmarks; default ``PEDNAV_DATA/ipin2023-t3-phone``). Each trial's samples run once through the
step-and-heading front end (:func:`models.pdr.run_pdr`: MARG filter, step detector, walking direction; the phone
in the hand, every sensor on, the WMM field at the first landmark as the engine gets it). Only steps between the
first and the last landmark count (no calibration manoeuvre); the compass's statistics take those of a steady gait
(the engine's cadence rule, under which it learns the compass). No landmark position is used: these are
statistics of the sensors, not of the errors.

- Motion models (per step, from the MARG filter's change of the forward axis's azimuth between two steps with
  the gyroscope): the robust standard deviation (1.4826 MAD) of steps turning less than 10 deg
  (``straight_sigma``), the RMS of the others (``turn_sigma``), and the Markov chain's transition frequencies
  (``p_turn_start``, ``p_turn_stay``).
- The compass's walking direction minus the MARG filter's (whose gyroscope carries the heading over a step),
  ``e``: its robust standard deviation ``s``, the robust standard deviation of its change over one step
  (``lag1``) and over five (``lag5``). As an AR(1) process with the correlation per step
  ``rho = (1 - lag5^2 / (2 s^2))^(1/5)``, it is the estimator's deflection ``d``: a random walk of
  ``q = s^2 (1 - rho^2)`` per step (less the median field-change term the estimator adds itself) held at
  ``s^2`` by the pseudo-observation ``d = 0`` of variance ``s^2 (s^2 + q) / q`` (the Kalman steady state).
  Its white part (``compass_floor``) is at most ``lag1 / sqrt(2)``.
- The compass's heading-dependent error: over 3-step windows with the gyroscope throughout, the robust standard
  deviation of that difference's change where the MARG filter turned by more than 60 deg
  (``compass_change_turning_sd``) and by less than 10 deg (``compass_change_straight_sd``); the excess variance
  over the turning windows' mean square turn is the deflection's change per radian of turn
  (``deflection_per_turn``, docs/phone.md "Tried in the estimator and dropped").
- The MARG filter's heading standard deviation on these steps (its settled range).

Everything is computed on all trials and leaving out each route in turn (both repetitions of a route are one
walker's walk): the configuration takes values within the folds' range.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from clients.recording import Recording

__all__ = ["StepTable", "front_end", "step_table", "heading_statistics", "loro_statistics", "main"]


@dataclass(frozen=True)
class StepTable:
    """Per step of one trial (steady gait between the first and last landmark, shape (n,) each).

    Attributes
    ----------
    direction : ndarray
        The MARG filter's forward-axis azimuth [rad] (magnetic north).
    compass : ndarray
        The compass's walking direction [rad] (NaN without a magnetometer reading).
    gyro : ndarray of bool
        The step had the gyroscope.
    yaw_std : ndarray
        The MARG filter's heading standard deviation [rad].
    field_change : ndarray
        The heading the change of the field's shape since the previous step could cause [rad]
        (:meth:`models.heading.CompassNoise.field_sigma`).
    walking : ndarray of bool
        The step and the one before it were of a steady gait (the engine's cadence rule).
    index : ndarray of int
        The step's number among all the trial's steps (consecutive steps differ by one).
    """

    name: str
    direction: np.ndarray
    compass: np.ndarray
    gyro: np.ndarray
    yaw_std: np.ndarray
    field_change: np.ndarray
    walking: np.ndarray
    index: np.ndarray


_WIN = 3  # steps of the windows over which the compass's change is compared with the turn


def _wrap(a: np.ndarray) -> np.ndarray:
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


def front_end(rec: Recording) -> np.ndarray:
    """The step-and-heading front end's step records (:data:`models.pdr.STEP_RECORD`) of one recording: every
    sensor on, the WMM field at the first landmark (see the module docstring); times [s] from the batch's start."""
    from clients.evaluation.ipin import _anchor_and_date
    from energy.phone_engine import PhoneEngineConfig
    from models.geo import Anchor, magnetic_elements
    from models.marg import MargState, merge_streams
    from models.pdr import PdrState, run_pdr

    cfg = PhoneEngineConfig()
    (lat, lon, alt), day = _anchor_and_date(rec)
    el = magnetic_elements(Anchor(lat, lon, alt, **({"date": day} if day else {})))
    state = PdrState.new(MargState.new(cfg.marg, np.asarray(el.field_magnetic_ned_ut, dtype=float), 0.0))
    b = rec.batch
    t, kind, v = merge_streams((b.acc_t_ns, b.acc), (b.gyr_t_ns, b.gyr), (b.mag_t_ns, b.mag))
    return run_pdr(state, cfg.marg.as_array(), cfg.steps.as_array(),
                   (t - int(b.t_start_ns)).astype(np.float64) * 1e-9, kind, v)


def step_table(rec: Recording) -> StepTable:
    """The front end's steps of one recording (see the module docstring)."""
    from clients.evaluation.ipin import landmarks
    from energy.phone_engine import steady_step
    from models.heading import CompassNoise
    from models.pdr import STEP_RECORD

    f = {k: i for i, k in enumerate(STEP_RECORD)}
    r = front_end(rec)
    t0 = int(rec.batch.t_start_ns)
    T, _ = landmarks(rec)
    t_ns = t0 + np.round(r[:, f["t_s"]] * 1e9)
    steady = np.array([steady_step(p, w) for p, w in zip(r[:, f["period_s"]], r[:, f["rate_rad_s"]])], dtype=bool)
    walking = steady & np.concatenate([[False], steady[:-1]])  # the engine's cadence of two steady steps
    keep = (t_ns > T[0]) & (t_ns <= T[-1])
    direction = r[:, f["fwd_az"]]
    compass = np.where(r[:, f["n_mag"]] > 0, _wrap(direction - r[:, f["field_az"]]), np.nan)
    bv, bh = r[:, f["field_ut"]] * np.sin(r[:, f["dip_rad"]]), r[:, f["field_ut"]] * np.cos(r[:, f["dip_rad"]])
    change = np.array([math.nan] + [CompassNoise.field_sigma(bv[k], bh[k], bv[k - 1], bh[k - 1])
                                    for k in range(1, len(r))])
    return StepTable(rec.name, direction[keep], compass[keep], (r[:, f["gyro_frac"]] >= 0.9)[keep],
                     r[keep, f["yaw_std"]], change[keep], walking[keep], np.flatnonzero(keep))


def _robust_sd(x: np.ndarray) -> float:
    x = np.asarray(x, dtype=float)
    x = x[np.isfinite(x)]
    return float(1.4826 * np.median(np.abs(x - np.median(x)))) if len(x) else math.nan


def heading_statistics(tables: Sequence[StepTable]) -> dict[str, float]:
    """The statistics of the module docstring over the given trials (angles in degrees)."""
    incs, turns_seq, e_all, lag1, lag5, changes, yaw = [], [], [], [], [], [], []
    win_de, win_turn = [], []  # 3-step windows: the compass-minus-MARG change and the MARG turn [deg]
    for s in tables:
        both = s.gyro[1:] & s.gyro[:-1] & (np.diff(s.index) == 1)
        inc = np.degrees(_wrap(np.diff(s.direction)))[both]
        incs.append(inc)
        turns_seq.append(np.abs(inc) >= 10.0)
        e = np.degrees(_wrap(s.compass - s.direction))
        ok = s.gyro & s.walking & np.isfinite(e)
        e_all.append(e[ok])
        at = {int(i): k for k, i in enumerate(s.index)}  # step number -> row
        for lag, out in ((1, lag1), (5, lag5)):
            pairs = [(k, at[int(i) + lag]) for k, i in enumerate(s.index) if int(i) + lag in at]
            j, jl = (np.array(x, dtype=np.int64) for x in zip(*pairs)) if pairs else (np.zeros(0, np.int64),) * 2
            m = ok[j] & ok[jl]
            out.append(np.degrees(_wrap(np.radians(e[jl][m] - e[j][m]))))
        changes.append(np.degrees(s.field_change[ok]))
        pairs3 = [(k, at[int(i) + _WIN]) for k, i in enumerate(s.index) if int(i) + _WIN in at]
        for j, jl in pairs3:
            if jl - j == _WIN and ok[j] and ok[jl] and bool(np.all(s.gyro[j:jl + 1])):
                win_de.append(math.degrees(float(_wrap(np.radians(e[jl] - e[j])))))
                win_turn.append(math.degrees(float(_wrap(s.direction[jl] - s.direction[j]))))
        yaw.append(np.degrees(s.yaw_std[s.gyro & s.walking]))
    inc = np.concatenate(incs)
    small = inc[np.abs(inc) < 10.0]
    big = inc[np.abs(inc) >= 10.0]
    a = np.concatenate([t[:-1] for t in turns_seq])
    b_ = np.concatenate([t[1:] for t in turns_seq])
    sd = _robust_sd(np.concatenate(e_all))
    l1, l5 = _robust_sd(np.concatenate(lag1)), _robust_sd(np.concatenate(lag5))
    rho = max(1.0 - l5 * l5 / (2.0 * sd * sd), 1e-6) ** 0.2
    q = sd * sd * (1.0 - rho * rho)
    de, tw = np.asarray(win_de), np.abs(np.asarray(win_turn))
    sd_turn, sd_straight = _robust_sd(de[tw > 60.0]), _robust_sd(de[tw < 10.0])
    k_turn = math.sqrt(max(sd_turn**2 - sd_straight**2, 0.0) / float(np.mean(tw[tw > 60.0] ** 2)))
    ch = np.concatenate(changes)
    ch2 = float(np.median(ch[np.isfinite(ch)] ** 2))
    return {
        "steps": float(len(inc)),
        "straight_sigma_deg": _robust_sd(small),
        "turn_sigma_deg": float(np.sqrt(np.mean(big * big))),
        "p_turn_start": float(np.sum(~a & b_) / max(np.sum(~a), 1)),
        "p_turn_stay": float(np.sum(a & b_) / max(np.sum(a), 1)),
        "compass_sd_deg": sd,
        "compass_lag1_sd_deg": l1,
        "compass_lag5_sd_deg": l5,
        "compass_rho_per_step": rho,
        "deflection_walk_deg": math.sqrt(max(q - ch2, 0.0)),
        "deflection_floor_deg": math.sqrt(sd * sd * (sd * sd + q) / q),
        "compass_white_max_deg": l1 / math.sqrt(2.0),
        "compass_change_turning_sd_deg": sd_turn,
        "compass_change_straight_sd_deg": sd_straight,
        "deflection_per_turn": k_turn,
        "marg_yaw_std_p95_deg": float(np.percentile(np.concatenate(yaw), 95)),
    }


def loro_statistics(tables: Sequence[StepTable]) -> dict[str, Any]:
    """:func:`heading_statistics` on all trials, and the range over the folds that leave out one route each."""
    from clients.evaluation.ipin import leave_one_route_out

    return leave_one_route_out(tables, heading_statistics)


def main(argv: Sequence[str] | None = None) -> int:
    from clients.evaluation.ipin import logfile_recordings, print_loro

    parsed = logfile_recordings("python -m clients.evaluation.phone_heading", __doc__, argv)
    if parsed is None:
        return 2
    a, recs = parsed
    out = loro_statistics([step_table(r) for r in recs])
    if a.json:
        print(json.dumps(out, indent=1))
    else:
        print_loro(out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
