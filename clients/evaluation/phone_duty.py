"""A duty-cycled gyroscope while walking: its turns per step and per turn against the full gyroscope's.

``python -m clients.evaluation.phone_duty [DIR] [--json]`` over the IPIN 2023 T3 dev trials (GetSensorData
logfiles; default ``PEDNAV_DATA/ipin2023-t3-phone``), docs/phone.md "A duty-cycled gyroscope (measured; not built)".

The idea (issue #26): instead of switching the gyroscope off for whole batches (``auto``), run it for a fraction
``d`` of every period ``P`` while walking, so that every turn is partly measured. The gyroscope delivers over
``[o + k P, o + k P + d P)`` (offset ``o``: where the on-windows fall against the walk, the batch phase's
counterpart) and is charged from its power-up ``t_on`` earlier, so its energy against always-on is
``min(1, (d P + t_on) / P)``. Its turn about the vertical over an interval is estimated from the on-parts by

- ``scaled``: the on-parts' integral over the interval divided by ``d`` (unbiased over the offsets);
- ``interp``: the rate measured in the on-windows, and in each gap the straight line between the means of the
  on-windows on either side (a rate known ``(1 - d) P`` late: the next window's mean), integrated.

The rate about the vertical is the recorded 100-Hz gyroscope (raw, no bias removed) projected on the
accelerometer's direction low-passed with ``TAU_S`` (no gyroscope in the vertical, as the device would have it
between on-windows; :mod:`clients.evaluation.phone_swing`'s vertical), + clockwise as ``gyro_dyaw``. ``d = 1``
(always on, the same vertical and integration) is the control, reported against ``gyro_dyaw``: what the vertical,
the missing bias correction and the step's boundaries cost, not the duty cycle.

References, between the first and the last landmark (no landmark position used):

- per step and per turn of 45 deg or more (:mod:`clients.evaluation.phone_centripetal`'s steps and its 50 turns:
  a run of steps turning 10 deg or more adding to 45 deg, with the step before and two after; the reference is
  ``gyro_dyaw`` of the always-on front end, which classifies the steps and turns, the compass's error across the
  same turn alongside): the duty-cycled step turn minus the full gyroscope's over the same step (same vertical);
  straight steps (``|gyro_dyaw| < 10 deg``): robust SD (1.4826 MAD), RMS, 95th
  percentile of the absolute error; turns: RMS, robust SD, 95th percentile of the absolute error;
- per turn of :mod:`clients.evaluation.phone_swing` (its 94 turns: the gyroscope's largest turn within 1 s,
  at 10 Hz, rising through 20 deg into a stretch that reaches 45 deg), measured from 1 s before the crossing to the
  stretch's end (the full gyroscope's turn over that interval, same vertical, is the reference);
- over consecutive ``WINDOW_S`` windows from the first landmark on (walking, standing and turning alike): the
  accumulated error of the duty-cycled turn against the full gyroscope's (same vertical), the drift a heading
  carried by it alone would gather (slow errors the per-step figures do not show, such as the hand's wobble at the
  step frequency aliased by on-windows whose period is near the step's).

The whole device's energy (``system_<t_on>``, :func:`energy_estimate`): ``auto``'s replay (batch phase 0) accounted
as ``pednav eval ipin`` accounts it (``energy/power.py``, profile ``phone-bmi270``), with its gyroscope's energy
while walking replaced by the duty cycle's fraction of the gyroscope always on while walking; over always-on's.

Every figure is averaged over ``N_OFFSETS`` offsets ``o = k P / N_OFFSETS`` (and its worst offset given), as the
on-windows fall anywhere against the steps. Nothing is fitted (the scaling is ``1/d`` by construction), so no
leave-one-route-out is needed; the routes' spread is in ``range`` of :func:`clients.evaluation.ipin.leave_one_route_out`.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from clients.recording import Recording

__all__ = ["DutyTrial", "duty_rate", "duty_yaw", "duty_trial", "duty_statistics", "gyro_energy_fraction",
           "energy_components", "energy_estimate", "main"]

TAU_S = 1.0  # [s] the vertical's low-pass (energy.compass_swing.SWING_TAU_S: two steps)
PERIODS_S = (0.25, 0.5, 1.0)  # [s] duty-cycle periods P
DUTIES = (0.2, 0.3, 0.4, 0.5, 0.6, 1.0)  # on-fractions d (1.0: the control, always on)
N_OFFSETS = 8  # on-window offsets per period, k P / N_OFFSETS
ESTIMATORS = ("scaled", "interp")
# [s] the gyroscope's power-up overhead charged per on-window: the device emulator's GYRO_TURN_ON_S (80 ms, an
# LSM6DS3 figure: an assumption for the BMI270), and the BMI270's 2 ms "in fast start mode" (datasheet
# BST-BMI270-DS000-05 Rev 1.3, p. 2, "Key features"; the fast start mode's own standing current was not found)
TURN_ON_S = (0.080, 0.002)
STRAIGHT_DEG = 10.0
WINDOW_S = 10.0  # [s] consecutive windows from the first landmark on: the duty cycle's accumulated error (drift)


def gyro_energy_fraction(period_s: float, duty: float, turn_on_s: float) -> float:
    """The duty-cycled gyroscope's energy over always-on's [-]: ``min(1, (d P + t_on) / P)`` (current flat in the
    output rate, as ``energy/profiles/phone-bmi270.json`` has it, charged from each power-up)."""
    if duty >= 1.0:
        return 1.0
    return min(1.0, (duty * period_s + turn_on_s) / period_s)


def _on_mask(t_s: np.ndarray, period_s: float, duty: float, offset_s: float) -> np.ndarray:
    return np.mod(t_s - offset_s, period_s) < duty * period_s


def duty_rate(t_s: np.ndarray, rate: np.ndarray, period_s: float, duty: float, offset_s: float,
              estimator: str = "scaled") -> np.ndarray:
    """The rate [rad/s] a duty-cycled gyroscope's estimator integrates, at each sample time ``t_s`` [s].

    Parameters
    ----------
    t_s, rate : ndarray, shape (n,)
        Sample times [s] and the full gyroscope's rate about the vertical [rad/s].
    period_s, duty, offset_s : float
        ``P`` [s], ``d`` [-] and the on-windows' offset ``o`` [s] (module docstring).
    estimator : {"scaled", "interp"}
        ``scaled``: ``rate / d`` on the on-samples, 0 elsewhere; ``interp``: ``rate`` on the on-samples, in the
        gaps the line between the adjacent on-windows' mean rates (held beyond the first and last).
    """
    if duty >= 1.0:
        return rate.astype(float).copy()
    on = _on_mask(t_s, period_s, duty, offset_s)
    if estimator == "scaled":
        return np.where(on, rate / duty, 0.0)
    if estimator != "interp":
        raise ValueError(f"unknown estimator {estimator!r}")
    win = np.floor((t_s - offset_s) / period_s).astype(np.int64)
    ids, first = np.unique(win[on], return_index=True)
    if len(ids) == 0:
        return np.zeros_like(rate, dtype=float)
    t_on, r_on = t_s[on], rate[on]
    counts = np.diff(np.append(first, len(t_on)))
    means = np.add.reduceat(r_on, first) / counts
    last = first + counts - 1
    knots_t = np.ravel(np.column_stack([t_on[first], t_on[last]]))
    knots_r = np.repeat(means, 2)
    return np.where(on, rate, np.interp(t_s, knots_t, knots_r))


def duty_yaw(t_s: np.ndarray, rate: np.ndarray, period_s: float, duty: float, offset_s: float,
             estimator: str = "scaled") -> np.ndarray:
    """The estimated turn [rad] from the first sample to each sample: :func:`duty_rate` integrated, each sample's
    rate held to the next sample (so an on-sample's interval is the one it opens)."""
    return _integrate(t_s, duty_rate(t_s, rate, period_s, duty, offset_s, estimator))


def _integrate(t_s: np.ndarray, w: np.ndarray) -> np.ndarray:
    return np.concatenate([[0.0], np.cumsum(w[:-1] * np.diff(t_s))])


@dataclass(frozen=True)
class DutyTrial:
    """One trial's references and the full gyroscope's rate (see the module docstring).

    Attributes
    ----------
    name : str
    t_s, rate : ndarray
        The gyroscope's sample times [s, from the batch's start] and its rate about the vertical [rad/s], + clockwise.
    step_t0, step_t1 : ndarray
        Each kept step's start and end [s] (the previous step's time and its own).
    steps : Any
        :class:`clients.evaluation.phone_centripetal.CentripetalTable` of the kept steps (``gyro``: ``gyro_dyaw``).
    turn_t0, turn_t1 : ndarray
        The swing statistics' turns: from 1 s before the crossing to the stretch's end [s].
    span : tuple of float
        The first and the last landmark's times [s].
    """

    name: str
    t_s: np.ndarray
    rate: np.ndarray
    step_t0: np.ndarray
    step_t1: np.ndarray
    steps: Any
    turn_t0: np.ndarray
    turn_t1: np.ndarray
    span: tuple[float, float]


def duty_trial(rec: Recording, front: np.ndarray | None = None) -> DutyTrial:
    """:class:`DutyTrial` of one recording; ``front`` is
    :func:`clients.evaluation.phone_heading.front_end`'s step records (computed when not given)."""
    from clients.evaluation.ipin import landmarks
    from clients.evaluation.phone_centripetal import _lowpass, centripetal_table
    from clients.evaluation.phone_heading import front_end
    from clients.evaluation.phone_swing import ACC_HZ, MAG_HZ, REF_WINDOW_S, _odr, _window_max, turn_spans
    from models.pdr import STEP_RECORD

    b = rec.batch
    t0 = int(b.t_start_ns)
    r = front_end(rec) if front is None else front
    steps = centripetal_table(rec, TAU_S, r)
    ts = r[:, STEP_RECORD.index("t_s")]
    acc_t, acc = _odr(b.acc_t_ns, b.acc, b.rate_hz("acc"), ACC_HZ)
    up = _lowpass(acc_t, acc, TAU_S)
    up /= np.linalg.norm(up, axis=1)[:, None]
    up_g = np.stack([np.interp(b.gyr_t_ns, acc_t, up[:, i]) for i in range(3)], axis=1)
    rate = -np.einsum("ij,ij->i", b.gyr, up_g)  # + clockwise (gyro_dyaw's sign)
    t_s = (b.gyr_t_ns - t0) * 1e-9
    yaw = np.concatenate([[0.0], np.cumsum(0.5 * (rate[1:] + rate[:-1]) * np.diff(t_s))])
    # the swing statistics' turns, on the walking magnetometer's 10-Hz output times
    mag_t, _ = _odr(b.mag_t_ns, b.mag, b.rate_hz("mag"), MAG_HZ)
    tm = (mag_t - t0) * 1e-9
    G = np.degrees(_window_max(mag_t, np.interp(tm, t_s, yaw), int(REF_WINDOW_S * 1e9)))
    T, _ = landmarks(rec)
    keep = (mag_t > T[0]) & (mag_t <= T[-1])
    tm, G = tm[keep], G[keep]
    spans = turn_spans(G)
    turn_t0 = np.array([tm[k] - REF_WINDOW_S for k, _, _ in spans])
    turn_t1 = np.array([tm[end - 1] for _, end, _ in spans])
    idx = steps.index
    return DutyTrial(rec.name, t_s, rate, ts[idx - 1], ts[idx], steps, turn_t0, turn_t1,
                     ((T[0] - t0) * 1e-9, (T[-1] - t0) * 1e-9))


def _offset_figures(trials: Sequence[DutyTrial], period_s: float, duty: float, offset_s: float,
                    estimator: str, reference: str = "full") -> dict[str, float]:
    from clients.evaluation.phone_centripetal import CentripetalTable, _pct, _rms, _turns
    from clients.evaluation.phone_heading import _robust_sd

    est_tables, swing_err, win_err = [], [], []
    for tr in trials:
        y = duty_yaw(tr.t_s, tr.rate, period_s, duty, offset_s, estimator)
        full = _integrate(tr.t_s, tr.rate)
        step = np.interp(tr.step_t1, tr.t_s, y) - np.interp(tr.step_t0, tr.t_s, y)
        s = tr.steps
        if reference == "full":  # the error against the full gyroscope's step turn, classified by gyro_dyaw
            step = step - (np.interp(tr.step_t1, tr.t_s, full) - np.interp(tr.step_t0, tr.t_s, full)) + s.gyro
        elif reference != "gyro_dyaw":
            raise ValueError(f"unknown reference {reference!r}")
        est_tables.append(CentripetalTable(s.name, step, s.gyro, s.direction, s.compass, s.index, s.a_lat, s.rate,
                                           s.speed))
        edges = np.arange(tr.span[0], tr.span[1] + 1e-9, WINDOW_S)
        if len(edges) > 1:
            win_err.append(np.diff(np.interp(edges, tr.t_s, y)) - np.diff(np.interp(edges, tr.t_s, full)))
        if len(tr.turn_t0):
            d_est = np.interp(tr.turn_t1, tr.t_s, y) - np.interp(tr.turn_t0, tr.t_s, y)
            d_ref = np.interp(tr.turn_t1, tr.t_s, full) - np.interp(tr.turn_t0, tr.t_s, full)
            swing_err.append(d_est - d_ref)
    x = np.concatenate([t.feature for t in est_tables])
    g = np.concatenate([t.gyro for t in est_tables])
    straight = np.abs(g) < math.radians(STRAIGHT_DEG)
    e_step = np.degrees(x - g)
    turns = np.array([t for s in est_tables for t in _turns(s, 1.0, math.inf)]).reshape(-1, 5)
    e_turn = np.degrees(turns[:, 1] - turns[:, 0])
    e_comp = np.degrees(turns[:, 2])
    e_sw = np.degrees(np.concatenate(swing_err)) if swing_err else np.zeros(0)
    e_win = np.degrees(np.concatenate(win_err)) if win_err else np.zeros(0)
    return {
        "straight_steps": float(np.sum(straight)),
        "straight_sd_deg": _robust_sd(e_step[straight]),
        "straight_rms_deg": _rms(e_step[straight]),
        "straight_p95_deg": _pct(np.abs(e_step[straight]), 95),
        "turn_step_sd_deg": _robust_sd(e_step[~straight]),
        "turns": float(len(e_turn)),
        "turn_rms_deg": _rms(e_turn),
        "turn_sd_deg": _robust_sd(e_turn),
        "turn_p95_deg": _pct(np.abs(e_turn), 95),
        "compass_turn_rms_deg": _rms(e_comp),
        "compass_turn_sd_deg": _robust_sd(e_comp),
        "compass_turn_p95_deg": _pct(np.abs(e_comp), 95),
        "swing_turns": float(len(e_sw)),
        "swing_turn_rms_deg": _rms(e_sw),
        "swing_turn_sd_deg": _robust_sd(e_sw),
        "swing_turn_p95_deg": _pct(np.abs(e_sw), 95),
        "windows": float(len(e_win)),
        "window_rms_deg": _rms(e_win),
        "window_p95_deg": _pct(np.abs(e_win), 95),
    }


def duty_statistics(trials: Sequence[DutyTrial], period_s: float, duty: float,
                    estimator: str = "scaled", n_offsets: int = N_OFFSETS, reference: str = "full") -> dict[str, float]:
    """The module docstring's figures for one ``(P, d, estimator)`` over the given trials: each the mean over
    ``n_offsets`` on-window offsets, the error figures' worst offset as ``..._worst``, and the gyroscope's
    energy fraction for each power-up overhead of ``TURN_ON_S`` (``energy_<ms>ms``). ``reference``: the per-step
    and per-turn (50 turns) errors against the full gyroscope's turn over the same steps (``"full"``: the duty
    cycle's own error) or against ``gyro_dyaw`` (``"gyro_dyaw"``: with the vertical's and the bias's cost, the
    control's use)."""
    per = [_offset_figures(trials, period_s, duty, k * period_s / n_offsets, estimator, reference)
           for k in range(n_offsets)]
    out = {k: float(np.mean([p[k] for p in per])) for k in per[0]}
    for k in ("straight_sd_deg", "straight_rms_deg", "turn_rms_deg", "turn_p95_deg", "swing_turn_rms_deg",
              "window_rms_deg"):
        out[k + "_worst"] = float(np.max([p[k] for p in per]))
    for t_on in TURN_ON_S:
        out[f"energy_{round(t_on * 1000)}ms"] = gyro_energy_fraction(period_s, duty, t_on)
    return out


def energy_components(rec: Recording, mode: str) -> tuple[dict[str, float], float, float, float]:
    """One replay of ``rec`` through the phone engine in ``mode`` (1-s batches, batch phase 0, the default
    Weinberg constant: the energy does not depend on it) accounted as ``pednav eval ipin`` accounts it
    (:func:`clients.evaluation.ipin.phone_energy`): ``(components [mJ], walking time [s], the gyroscope's
    energy while walking [mJ], its energy on the gyroscope always on while walking [mJ])``; walking is the engine's
    walking configuration (the accelerometer at ``PhoneEngineConfig.acc_rate_hz``; ``auto`` stands at
    ``stand_acc_rate_hz``)."""
    from clients.evaluation.ipin import POWER_PROFILE, _anchor_and_date, phone_energy
    from energy.device import replay
    from energy.phone_engine import PhoneEngine, PhoneEngineConfig
    from energy.power import Timeline, load_profile

    cfg = PhoneEngineConfig()
    anchor, day = _anchor_and_date(rec)
    eng = PhoneEngine(mode=mode, config=cfg, device_kind="phone", placement="phone-hand", anchor=anchor, date=day)
    res = replay(eng, rec.batch, cfg.batch_s)
    t_end = int(rec.batch.t_end_ns or 0) + 1
    report = phone_energy(res, t_end)
    profile = load_profile(POWER_PROFILE)
    gyr, v = profile.sensors["gyr"], profile.supply_v
    walk = [iv for iv in Timeline.from_replay(res, t_end).intervals if iv.acc_rate_hz >= cfg.acc_rate_hz]
    t_walk = float(sum(iv.t1_s - iv.t0_s for iv in walk))
    e_walk = sum((iv.t1_s - iv.t0_s) * gyr.current(iv.gyr_rate_hz) * v for iv in walk) / 1000.0
    e_walk_on = t_walk * gyr.current(cfg.auto_gyr_rate_hz) * v / 1000.0
    return dict(report.components_mj), t_walk, float(e_walk), float(e_walk_on)


def energy_estimate(recs: Sequence[Recording], fractions: Sequence[float]) -> dict[str, Any]:
    """The energy ratio over always-on (median over trials) of ``auto`` with its gyroscope, while walking, run at
    each gyroscope energy fraction of ``fractions`` instead of on or off per batch: ``auto``'s replay accounted
    by component, its walking gyroscope energy replaced by the fraction times the gyroscope's energy always on
    while walking (standing, the gyroscope as ``auto`` runs it: bias settling). The other components (accelerometer,
    magnetometer, compute, radio) are ``auto``'s: the gyroscope samples uploaded and processed differ by the
    difference in on-time, a small share of compute and radio. Also ``auto``'s own ratio, its gyroscope's on-time
    while walking and the always-on components."""
    rows = []
    for rec in recs:
        on, _, _, _ = energy_components(rec, "always-on")
        au, t_walk, e_walk, e_walk_on = energy_components(rec, "auto")
        e_on, e_au = sum(on.values()), sum(au.values())
        rows.append({"auto": e_au / e_on, "auto_walk_gyro_fraction": e_walk / e_walk_on if e_walk_on else math.nan,
                     **{f"duty {f:.4f}": (e_au - e_walk + f * e_walk_on) / e_on for f in fractions},
                     **{f"always_on_{k}_share": v / e_on for k, v in on.items()}})
    return {k: float(np.median([r[k] for r in rows])) for k in rows[0]}


def _grid() -> list[tuple[float, float, str]]:
    return [(p, d, e) for e in ESTIMATORS for p in PERIODS_S for d in DUTIES if d < 1.0] + [(1.0, 1.0, "scaled")]


COLUMNS = ("energy_80ms", "energy_2ms", "system_80ms", "system_2ms", "straight_sd_deg", "straight_rms_deg", "straight_p95_deg", "turn_rms_deg",
           "turn_sd_deg", "turn_p95_deg", "turn_rms_deg_worst", "swing_turn_rms_deg", "swing_turn_p95_deg",
           "window_rms_deg", "window_p95_deg", "compass_turn_rms_deg")


def main(argv: Sequence[str] | None = None) -> int:
    from clients.evaluation.ipin import leave_one_route_out, logfile_recordings

    parsed = logfile_recordings("python -m clients.evaluation.phone_duty", __doc__, argv)
    if parsed is None:
        return 2
    a, recs = parsed
    trials = [duty_trial(r) for r in recs]
    out: dict[str, Any] = {}
    for p, d, e in _grid():
        name = "always on (control)" if d >= 1.0 else f"{e} P {p} s d {d}"
        ref = "gyro_dyaw" if d >= 1.0 else "full"
        out[name] = leave_one_route_out(trials, lambda ts, p=p, d=d, e=e, ref=ref: duty_statistics(ts, p, d, e,
                                                                                              reference=ref))
    fractions = sorted({gyro_energy_fraction(p, d, t) for p, d, _ in _grid() for t in TURN_ON_S})
    energy = energy_estimate(recs, fractions)
    for p, d, e in _grid():
        name = "always on (control)" if d >= 1.0 else f"{e} P {p} s d {d}"
        for t in TURN_ON_S:
            out[name]["all"][f"system_{round(t * 1000)}ms"] = energy[f"duty {gyro_energy_fraction(p, d, t):.4f}"]
    out["energy"] = energy
    if a.json:
        print(json.dumps(out, indent=1))
        return 0
    first = out["always on (control)"]["all"]
    print(f"{int(first['straight_steps'])} straight steps, {int(first['turns'])} turns (steps), "
          f"{int(first['swing_turns'])} turns (swing), {int(first['windows'])} windows of {WINDOW_S} s; "
          f"errors [deg], means over {N_OFFSETS} offsets")
    print(f"{'':24s}" + "".join(f"{c[:18]:>19s}" for c in COLUMNS))
    for name, st in out.items():
        if name != "energy":
            print(f"{name:24s}" + "".join(f"{st['all'][c]:19.3f}" for c in COLUMNS))
    print("leave-one-route-out range of turn_rms_deg / straight_sd_deg / window_rms_deg:")
    for name, st in out.items():
        if name != "energy":
            r = st["range"]
            print(f"  {name:24s} {r['turn_rms_deg'][0]:7.2f} .. {r['turn_rms_deg'][1]:7.2f}   "
                  f"{r['straight_sd_deg'][0]:6.2f} .. {r['straight_sd_deg'][1]:6.2f}   "
                  f"{r['window_rms_deg'][0]:6.2f} .. {r['window_rms_deg'][1]:6.2f}")
    print("energy over always-on (median over trials; auto's replay with its walking gyroscope at the fraction):")
    for k, v in energy.items():
        print(f"  {k:36s} {v:7.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
