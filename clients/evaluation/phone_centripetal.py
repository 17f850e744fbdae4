"""The accelerometer's turn: the centripetal acceleration of a turning walker, against the gyroscope and the compass.

``python -m clients.evaluation.phone_centripetal [DIR] [--json]`` over the IPIN 2023 T3 dev trials (GetSensorData
logfiles; default ``PEDNAV_DATA/ipin2023-t3-phone``), docs/phone.md "The accelerometer's turn (measured; not used)".

Walking at speed ``v`` while turning at the rate ``w`` the body accelerates by ``v w`` towards the turn's centre;
a phone held in front yaws with the walker and keeps its tilt, so the horizontal specific force along the device's
lateral axis (its x axis, the axis :func:`models.walking_direction.forward_azimuth` takes the forward direction
from, made horizontal), averaged over a stride (two steps: the gait's lateral sway cancels), is ``v w``. Over a
step of period ``T`` and length ``L = K f`` (Weinberg, 000 eq. 35, ``f = (a_max - a_min)^(1/4)``) the turn is
``w T = a_lat T / v = a_lat T^2 / (K f)``; the raw feature is ``x = a_lat T^2 / f`` [rad m], the turn ``s x`` with
``s = 1 / K`` fitted by least squares against the gyroscope (on all trials, and leaving out each route). No
gyroscope is needed: the vertical is the accelerometer low-passed (time constant ``tau``) up to the start of the
stride (the phone's tilt of the preceding seconds, free of the turn's own acceleration), each axis taken at the
engine's walking accelerometer rate (50 Hz, the mean of each output period's native samples).

Per step (the always-on front end :func:`models.pdr.run_pdr`, as in :mod:`clients.evaluation.phone_heading`;
between the first and the last landmark, steps of a steady gait; no landmark position is used):

- the reference is the gyroscope's turn about the vertical over the step (``gyro_dyaw``, + clockwise), and over the
  same stride (the mean of the step's and the previous one's, ``gyro_stride``: the accelerometer's window);
- straight steps turn by less than 10 deg (the gyroscope), turn steps by 10 deg or more;
- ``corr``: the correlation of ``s x`` with the gyroscope's step turn; ``err_straight_sd``, ``err_turn_sd``: the
  robust standard deviation (1.4826 MAD) of ``s x`` minus the gyroscope's step turn on straight and on turn steps;
  ``straight_p99``: the 99th percentile of ``|s x|`` on straight steps (a detector's threshold).

Per turn (a run of turn steps whose gyroscope turns add to at least 45 deg, with the step before it and two after
it: the causal stride lags by half a step): the turn error of the accelerometer (the sum of ``s x`` minus the sum
of ``gyro_dyaw``) and of the compass (its walking direction's change from the step before to the last step,
minus the MARG filter's change of the forward azimuth over the same steps: the change of the compass's error
across the turn, what a gyroscope-off estimator takes into its heading); their robust standard deviations, RMS and
95th percentiles of the absolute value. ``detect``: per turn, the first step from the one before the turn on whose
``|s x|`` exceeds ``straight_p99``, and the gyroscope's turn accumulated up to that step's end [deg] (and as a
share of the turn): what a woken gyroscope would not see (the compass-swing wake: 34 deg, docs/phone.md).
``acc_turn_corr``: the correlation of the accelerometer's and the gyroscope's turns per turn;
``acc_turn_err_rms_turnfit_deg``: the accelerometer's turn error with the scale fitted on the turns themselves (in
sample: an optimistic bound).

As a wake detector sampled continuously (``detector``: the device's view, not per step), the running mean of the
lateral specific force over the last stride (``STRIDE_S``; the vertical low-passed up to before that window) at
10 Hz goes through :func:`clients.evaluation.phone_swing.swing_statistics` in place of the compass swing, with the
same reference (the gyroscope's largest turn within 1 s: straight below 10 deg, turns through 20 deg reaching 45):
the threshold is the straight stretches' 99th percentile [m/s^2], ``turned_at_wake`` how far the device had turned
when it fired (the swing wake: 34 deg, median, none of 94 turns missed).

``leave_one_route_out`` gives each statistic's range over the folds (each fold fits its own ``s``); the
``out_of_route`` block applies to each route the ``s`` fitted on the other routes and pools the errors.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from clients.evaluation.phone_heading import _robust_sd, _wrap, front_end
from clients.recording import Recording

__all__ = ["CentripetalTable", "centripetal_table", "detector_table", "detector_statistics", "fit_scale",
           "centripetal_statistics", "out_of_route", "loro_statistics", "main"]

ACC_HZ = 50.0  # the phone engine's walking accelerometer rate (PhoneEngineConfig.acc_rate_hz)
STRAIGHT_DEG = 10.0  # a step turning less is straight (clients.evaluation.phone_heading's straight_sigma)
TURN_DEG = 45.0  # a run of turn steps adding to at least this is a turn
TAUS_S = (1.0, 2.0, 4.0, 8.0)  # [s] time constants of the low-pass that gives the vertical
STRIDE_S = 1.2  # [s] the continuous detector's running mean: a stride (two steps of about 0.6 s)
DETECT_HZ = 10.0  # [Hz] the continuous detector's output rate (the swing detector's: the walking magnetometer's)


@dataclass(frozen=True)
class CentripetalTable:
    """Per step of one trial between the first and the last landmark at a walking cadence, with the gyroscope
    (shape (n,) each).

    Attributes
    ----------
    feature : ndarray
        ``x = a_lat T^2 / f`` [rad m]: the accelerometer's turn over the step times the Weinberg constant.
    gyro : ndarray
        The gyroscope's turn about the vertical over the step [rad], + clockwise (``gyro_dyaw``).
    direction : ndarray
        The MARG filter's forward-axis azimuth [rad] (always-on: the gyroscope carries it).
    compass : ndarray
        The compass's walking direction [rad] (NaN without a magnetometer reading).
    index : ndarray of int
        The step's number among all the trial's steps (consecutive steps differ by one).
    a_lat : ndarray
        The stride's mean specific force along the horizontal lateral axis [m/s^2] (+ to the device's right).
    rate : ndarray
        The gyroscope's mean turn rate over the same stride [rad/s], + clockwise.
    speed : ndarray
        The walking speed ``K f / T`` [m/s] with the default Weinberg constant (``StepLengthConfig.weinberg_k``).
    """

    name: str
    feature: np.ndarray
    gyro: np.ndarray
    direction: np.ndarray
    compass: np.ndarray
    index: np.ndarray
    a_lat: np.ndarray
    rate: np.ndarray
    speed: np.ndarray


def _lowpass(t_ns: np.ndarray, v: np.ndarray, tau_s: float) -> np.ndarray:
    """First-order low-pass of ``v`` (n, 3) with time constant ``tau_s``, started at the first sample."""
    out = np.empty_like(v)
    out[0] = v[0]
    alpha = 1.0 - np.exp(-np.diff(t_ns) * 1e-9 / tau_s)
    for i in range(1, len(v)):
        out[i] = out[i - 1] + alpha[i - 1] * (v[i] - out[i - 1])
    return out


def centripetal_table(rec: Recording, tau_s: float = 2.0, front: np.ndarray | None = None) -> CentripetalTable:
    """The accelerometer's turn feature, the gyroscope's and the compass per step of one recording (module
    docstring). ``front`` is :func:`clients.evaluation.phone_heading.front_end`'s step records of ``rec``
    (computed when not given)."""
    from clients.evaluation.ipin import landmarks
    from clients.evaluation.phone_swing import _odr
    from energy.phone_engine import steady_step
    from models.pdr import STEP_RECORD
    from models.pdr_step_length import StepLengthConfig

    f = {k: i for i, k in enumerate(STEP_RECORD)}
    b = rec.batch
    r = front_end(rec) if front is None else front
    t0 = int(b.t_start_ns)
    t_ns = t0 + np.round(r[:, f["t_s"]] * 1e9).astype(np.int64)
    acc_t, acc = _odr(b.acc_t_ns, b.acc, b.rate_hz("acc"), ACC_HZ)
    up = _lowpass(acc_t, acc, tau_s)
    x = np.full(len(r), math.nan)
    alat = np.full(len(r), math.nan)
    rate = np.full(len(r), math.nan)
    speed = np.full(len(r), math.nan)
    k_w = StepLengthConfig().weinberg_k
    for k in range(2, len(r)):
        lo, hi = np.searchsorted(acc_t, [t_ns[k - 2], t_ns[k]], side="right")
        if hi - lo < 4 or lo == 0:
            continue
        u = up[lo - 1] / np.linalg.norm(up[lo - 1])  # the vertical (up) before the stride, device frame
        lat = np.array([1.0, 0.0, 0.0]) - u[0] * u  # the device's x axis made horizontal
        n = np.linalg.norm(lat)
        if n < 0.3:
            continue
        a_lat = float(np.mean(acc[lo:hi] @ (lat / n)))  # [m/s^2]
        period, feat = r[k, f["period_s"]], (r[k, f["a_max"]] - r[k, f["a_min"]]) ** 0.25
        if math.isfinite(period) and feat > 0:
            x[k] = a_lat * period * period / feat
            alat[k] = a_lat
            rate[k] = (r[k, f["gyro_dyaw"]] + r[k - 1, f["gyro_dyaw"]]) / ((t_ns[k] - t_ns[k - 2]) * 1e-9)
            speed[k] = k_w * feat / period
    T, _ = landmarks(rec)
    # a walking cadence on this step and the one before (the engine's cadence rule without its waving test,
    # which needs the gyroscope: the landmarks' span has no calibration manoeuvre)
    steady = np.array([steady_step(p, math.nan) for p in r[:, f["period_s"]]], dtype=bool)
    walking = steady & np.concatenate([[False], steady[:-1]])
    direction = r[:, f["fwd_az"]]
    compass = np.where(r[:, f["n_mag"]] > 0, _wrap(direction - r[:, f["field_az"]]), np.nan)
    keep = (t_ns > T[0]) & (t_ns <= T[-1]) & walking & np.isfinite(x) & (r[:, f["gyro_frac"]] >= 0.9)
    return CentripetalTable(rec.name, x[keep], r[keep, f["gyro_dyaw"]], direction[keep], compass[keep],
                            np.flatnonzero(keep), alat[keep], rate[keep], speed[keep])


def detector_table(rec: Recording, tau_s: float) -> Any:
    """The continuous detector (module docstring) as a :class:`clients.evaluation.phone_swing.SwingTable`: at
    ``DETECT_HZ`` between the first and the last landmark, ``detector`` the stride's mean lateral specific force's
    magnitude [m/s^2], ``gyro`` the gyroscope's largest turn about the vertical within 1 s [deg]."""
    from clients.evaluation.ipin import landmarks
    from clients.evaluation.phone_swing import REF_WINDOW_S, SwingTable, _odr, _window_max

    b = rec.batch
    acc_t, acc = _odr(b.acc_t_ns, b.acc, b.rate_hz("acc"), ACC_HZ)
    up = _lowpass(acc_t, acc, tau_s)
    up /= np.linalg.norm(up, axis=1)[:, None]
    n_w = int(round(STRIDE_S * ACC_HZ))
    before = np.vstack([np.repeat(up[:1], n_w, axis=0), up[:-n_w]])  # the vertical a stride earlier
    lat = np.array([1.0, 0.0, 0.0])[None, :] - before[:, [0]] * before
    lat /= np.maximum(np.linalg.norm(lat, axis=1), 1e-9)[:, None]
    a_lat = np.einsum("ij,ij->i", acc, lat)
    c = np.concatenate([[0.0], np.cumsum(a_lat)])
    mean = np.full(len(a_lat), math.nan)
    mean[n_w - 1 :] = (c[n_w:] - c[:-n_w]) / n_w
    up_g = np.stack([np.interp(b.gyr_t_ns, acc_t, up[:, i]) for i in range(3)], axis=1)
    rate = np.einsum("ij,ij->i", b.gyr, up_g)
    yaw = np.concatenate([[0.0], np.cumsum(0.5 * (rate[1:] + rate[:-1]) * np.diff(b.gyr_t_ns) * 1e-9)])
    step = max(1, int(round(ACC_HZ / DETECT_HZ)))
    t = acc_t[::step]
    G = _window_max(t, np.interp(t, b.gyr_t_ns, yaw), int(REF_WINDOW_S * 1e9))
    T, _ = landmarks(rec)
    keep = (t > T[0]) & (t <= T[-1]) & np.isfinite(mean[::step])
    return SwingTable(rec.name, (t[keep] - t[keep][0]) * 1e-9, np.abs(mean[::step][keep]), np.degrees(G[keep]))


def detector_statistics(tables: Sequence[Any]) -> dict[str, float]:
    """:func:`clients.evaluation.phone_swing.swing_statistics` of :func:`detector_table`'s tables, the
    detector's own figures renamed to its unit (m/s^2)."""
    from clients.evaluation.phone_swing import swing_statistics

    st = swing_statistics(tables)
    return {(k.replace("_deg", "_m_s2") if k in ("straight_p95_deg", "straight_p99_deg", "turn_median_deg") else k): v
            for k, v in st.items()}


def fit_scale(tables: Sequence[CentripetalTable]) -> float:
    """``s`` [1/m] with ``E[s x | g] = g`` (the regression of ``x`` on the gyroscope's step turn ``g``, inverted:
    ``s = <g, g> / <x, g>``; regressing ``g`` on the noisy ``x`` would shrink ``s`` by the noise), over all steps."""
    x = np.concatenate([s.feature for s in tables])
    g = np.concatenate([s.gyro for s in tables])
    return float(np.dot(g, g) / np.dot(x, g))


def _rms(x: np.ndarray) -> float:
    x = np.asarray(x, dtype=float)
    x = x[np.isfinite(x)]
    return float(np.sqrt(np.mean(x * x))) if len(x) else math.nan


def _pct(x: np.ndarray, q: float) -> float:
    x = np.asarray(x, dtype=float)
    x = x[np.isfinite(x)]
    return float(np.percentile(x, q)) if len(x) else math.nan


def _turns(s: CentripetalTable, scale: float, thr_rad: float) -> list[tuple[float, float, float, float, float]]:
    """Per turn: (gyroscope's turn, the accelerometer's turn feature summed over the turn [rad m], compass's error,
    the gyroscope's turn when the accelerometer first exceeded ``thr_rad``, the step of that relative to the turn's
    first step) [rad, -]."""
    out = []
    turning = np.abs(s.gyro) >= math.radians(STRAIGHT_DEG)
    consecutive = np.concatenate([[False], np.diff(s.index) == 1])
    k = 0
    n = len(s.gyro)
    while k < n:
        if not turning[k]:
            k += 1
            continue
        a = k
        while k + 1 < n and turning[k + 1] and consecutive[k + 1]:
            k += 1
        z = k
        k += 1
        i, j = a - 1, z + 2
        if i < 0 or j >= n or not bool(np.all(consecutive[i + 1 : j + 1])):
            continue
        g_turn = float(np.sum(s.gyro[a : z + 1]))
        if abs(g_turn) < math.radians(TURN_DEG):
            continue
        g = float(np.sum(s.gyro[i + 1 : j + 1]))
        acc_sum = float(np.sum(s.feature[i + 1 : j + 1]))
        comp_err = float(_wrap((s.compass[j] - s.compass[i]) - (s.direction[j] - s.direction[i])))
        sign = math.copysign(1.0, g_turn)
        hit = np.flatnonzero(sign * scale * s.feature[i : j + 1] > thr_rad)
        if len(hit):
            m = i + int(hit[0])
            turned = float(sign * np.sum(s.gyro[i : m + 1]))
            out.append((g, acc_sum, comp_err, turned, float(m - a)))
        else:
            out.append((g, acc_sum, comp_err, math.nan, math.nan))
    return out


def centripetal_statistics(tables: Sequence[CentripetalTable], scale: float | None = None) -> dict[str, float]:
    """The statistics of the module docstring over the given trials (angles in degrees), with ``scale`` (fitted
    on these trials when None)."""
    s_ = fit_scale(tables) if scale is None else scale
    x = np.concatenate([s.feature for s in tables]) * s_
    g = np.concatenate([s.gyro for s in tables])
    g2 = np.concatenate([0.5 * (s.gyro[1:] + s.gyro[:-1]) for s in tables])
    x2 = np.concatenate([s.feature[1:] for s in tables]) * s_
    straight = np.abs(g) < math.radians(STRAIGHT_DEG)
    a = np.concatenate([s.a_lat for s in tables])
    w = np.concatenate([s.rate for s in tables])
    v = np.concatenate([s.speed for s in tables])
    thr = float(np.percentile(np.abs(x[straight]), 99))
    turns = np.array([t for s in tables for t in _turns(s, s_, thr)]).reshape(-1, 5)
    G, ec, turned, step = np.degrees(turns[:, 0]), np.degrees(turns[:, 2]), np.degrees(turns[:, 3]), turns[:, 4]
    ea = np.degrees(s_ * turns[:, 1] - turns[:, 0])
    # the optimistic bound: the scale fitted on these turns' own sums (least squares of the turn on the sum)
    s_turn = float(np.dot(turns[:, 1], turns[:, 0]) / np.dot(turns[:, 1], turns[:, 1])) if len(G) else math.nan
    ea_best = np.degrees(s_turn * turns[:, 1] - turns[:, 0])
    found = np.isfinite(turned)
    return {
        "scale_per_m": s_,
        "steps": float(len(g)),
        "turn_steps": float(np.sum(~straight)),
        "speed_median_m_s": float(np.median(v)),
        "gain_turn_m_s": float(np.dot(a[~straight], w[~straight]) / np.dot(w[~straight], w[~straight])),
        "corr_a_lat_rate_turn": float(np.corrcoef(a[~straight], w[~straight])[0, 1]),
        "a_lat_straight_sd_m_s2": _robust_sd(a[straight]),
        "corr": float(np.corrcoef(x, g)[0, 1]),
        "corr_stride": float(np.corrcoef(x2, g2)[0, 1]),
        "bias_straight_deg": float(np.degrees(np.median(x[straight] - g[straight]))),
        "err_straight_sd_deg": float(np.degrees(_robust_sd(x[straight] - g[straight]))),
        "err_turn_sd_deg": float(np.degrees(_robust_sd(x[~straight] - g[~straight]))),
        "err_turn_stride_sd_deg": float(np.degrees(_robust_sd(x2 - g2))),
        "straight_p99_deg": math.degrees(thr),
        "turns": float(len(G)),
        "turn_rms_deg": _rms(G),
        "acc_turn_err_sd_deg": _robust_sd(ea),
        "acc_turn_err_rms_deg": _rms(ea),
        "acc_turn_err_p95_deg": _pct(np.abs(ea), 95),
        "acc_turn_err_median_deg": _pct(ea * np.sign(G), 50),
        "acc_turn_corr": float(np.corrcoef(turns[:, 1], turns[:, 0])[0, 1]) if len(G) > 2 else math.nan,
        "acc_turn_err_rms_turnfit_deg": _rms(ea_best),
        "compass_turn_err_sd_deg": _robust_sd(ec),
        "compass_turn_err_rms_deg": _rms(ec),
        "compass_turn_err_p95_deg": _pct(np.abs(ec), 95),
        "turns_missed": float(np.sum(~found)),
        "turned_at_detect_median_deg": _pct(turned, 50),
        "turned_at_detect_p90_deg": _pct(turned, 90),
        "turned_at_detect_share_median": _pct(turned / np.abs(G), 50),
        "detect_step_median": _pct(step, 50),
    }


def out_of_route(tables: Sequence[CentripetalTable]) -> dict[str, float]:
    """:func:`centripetal_statistics` of each route's steps and turns with the scale fitted on the other routes,
    pooled (the figures a deployed constant would give; per-step and per-turn errors only)."""
    from clients.evaluation.ipin import route_of

    routes = sorted({route_of(t.name) for t in tables})
    rows = []
    for r in routes:
        held = [t for t in tables if route_of(t.name) == r]
        s_ = fit_scale([t for t in tables if route_of(t.name) != r])
        rows.append((held, s_))
    # pool by rescaling each held-out route's features to the common scale 1 (scale applied in the features)
    scaled = [CentripetalTable(t.name, t.feature * s_, t.gyro, t.direction, t.compass, t.index, t.a_lat, t.rate,
                               t.speed)
              for held, s_ in rows for t in held]
    st = centripetal_statistics(scaled, scale=1.0)
    st["scale_per_m"] = math.nan
    return st


def loro_statistics(tables: Sequence[CentripetalTable]) -> dict[str, Any]:
    """:func:`centripetal_statistics` on all trials, the range over the folds leaving out one route each, and
    :func:`out_of_route`."""
    from clients.evaluation.ipin import leave_one_route_out

    out = leave_one_route_out(tables, centripetal_statistics)
    out["out_of_route"] = out_of_route(tables)
    return out


def main(argv: Sequence[str] | None = None) -> int:
    from clients.evaluation.ipin import logfile_recordings, print_loro

    parsed = logfile_recordings("python -m clients.evaluation.phone_centripetal", __doc__, argv)
    if parsed is None:
        return 2
    a, recs = parsed
    fronts = [front_end(r) for r in recs]
    from clients.evaluation.ipin import leave_one_route_out

    out = {f"tau {tau} s": loro_statistics([centripetal_table(r, tau, fr) for r, fr in zip(recs, fronts)])
           for tau in TAUS_S}
    for tau in TAUS_S:
        out[f"tau {tau} s"]["detector"] = leave_one_route_out([detector_table(r, tau) for r in recs],
                                                              detector_statistics)
    if a.json:
        print(json.dumps(out, indent=1))
    else:
        for name, st in out.items():
            print(name)
            print_loro(st, indent="  ", width=30)
            print("  out of route (each route with the scale of the others):")
            for k, v in st["out_of_route"].items():
                print(f"    {k:30s} {v:9.3f}")
            print("  continuous detector (a stride's lateral specific force, 10 Hz):")
            print_loro(st["detector"], indent="    ", width=28)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
