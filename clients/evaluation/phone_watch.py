"""``pednav eval phone-watch``: what fusing a watch's steps with a phone's buys (000 eq. 70), on synthetic walks.

No public recording carries a phone and a watch of one walker, so the walks are synthetic
(:mod:`clients.phone_synth`): one planned walk (a square loop with stands and turns, through two patches of
magnetic disturbance) carried at once by a phone held in front and a watch on the left wrist, each with its own
noise and gyroscope bias drawn from the seed. Both run the step-and-heading engine always on; the phone's steps
are then fused with the watch's (:func:`models.step_fusion.fuse_steps`). Errors against the planned walk's
centre of mass, at every 10th true step (the landmarks of this evaluation; the track starts at the first):
the mean horizontal error and the path length ratio, for the phone alone, the watch alone and the fusion.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

__all__ = ["evaluate_phone_watch", "phone_and_watch"]


def _track(rec: Any, device_kind: str, placement: str, declination_rad: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    from energy.device import replay
    from energy.phone_engine import PhoneEngine

    res = replay(PhoneEngine("always-on", device_kind=device_kind, placement=placement), rec.batch, 1.0)
    p = res.positions
    # the engine's north is magnetic; the synthetic field's declination turns it to the truth's north
    return (np.array([q.t_ns for q in p], dtype=np.int64), np.array([q.step_length_m for q in p]),
            np.array([q.heading_rad for q in p]) + declination_rad)


def _errors(truth: Any, t: np.ndarray, length: np.ndarray, head: np.ndarray) -> dict[str, float]:
    from clients.evaluation.ipin import landmark_errors

    ne = np.cumsum(np.column_stack([length * np.cos(head), length * np.sin(head)]), axis=0)
    k = np.arange(0, len(truth.t_ns), 10)
    e = landmark_errors(truth.t_ns[k], truth.positions[k, :2], t, ne, length)
    return {"mean_err_m": e.mean_err_m, "final_err_m": e.final_err_m, "path_ratio": e.path_ratio}


def phone_and_watch(seed: int) -> tuple[Any, Any, float]:
    """One planned walk carried at once by a phone held in front and a watch on the wrist, on one clock: the two
    synthetic recordings and the synthetic field's declination [rad] (the seed draws the disturbances, the
    initial heading and each device's gyroscope bias)."""
    from clients.phone_synth import PHONE_SCENARIOS, synthesize_phone

    base = PHONE_SCENARIOS["phone-walk"]
    rng = np.random.default_rng(1000 + seed)
    dist = ((4.0, 6.0, 3.0, *rng.normal(0, 12, 3)), (10.0, -3.0, 3.0, *rng.normal(0, 12, 3)))
    common = {"disturbances": dist, "heading0_deg": float(rng.uniform(-180, 180))}
    phone = replace(base, placement="phone-hand", gyr_bias_rad_s=tuple(rng.normal(0, 0.006, 3)), **common)
    watch = replace(base, placement="watch", swing_deg=30.0, gyr_bias_rad_s=tuple(rng.normal(0, 0.006, 3)), **common)
    decl = float(np.arctan2(base.field_ned_ut[1], base.field_ned_ut[0]))
    return synthesize_phone(phone, seed=seed), synthesize_phone(watch, seed=seed + 100), decl


def evaluate_phone_watch(seeds: range = range(6)) -> dict[str, Any]:
    """Per seed, the errors of phone, watch and fused tracks; medians in the summary."""
    from models.step_fusion import fuse_steps

    rows = []
    for seed in seeds:
        rp, rw, decl = phone_and_watch(seed)
        tp, lp, hp = _track(rp, "phone", "phone-hand", decl)
        tw, lw, hw = _track(rw, "watch", "watch", decl)
        lf, hf, blended = fuse_steps(tp * 1e-9, lp, hp, tw * 1e-9, lw, hw)
        rows.append({"seed": seed, "phone": _errors(rp.truth, tp, lp, hp), "watch": _errors(rw.truth, tw, lw, hw),
                     "fused": _errors(rp.truth, tp, lf, hf), "blended_fraction": float(blended.mean()),
                     "phone_steps": int(len(tp)), "watch_steps": int(len(tw)), "true_steps": int(len(rp.truth.t_ns))})
    summary = {k: {m: float(np.median([r[k][m] for r in rows])) for m in ("mean_err_m", "final_err_m", "path_ratio")}
               for k in ("phone", "watch", "fused")}
    return {"dataset": "synthetic phone + watch (no public recording has both)", "recordings": rows, "summary": summary}
