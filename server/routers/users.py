"""The calling user and their gait summary."""

from __future__ import annotations

import math
from typing import Any

from fastapi import APIRouter

from energy.strides import STRIDE_MIN_M
from server import crud
from server.deps import CurrentUser, SessionDep
from server.schemas import GaitSummaryOut, UserOut

__all__ = ["router"]

router = APIRouter(prefix="/users", tags=["users"])


@router.get("/me", response_model=UserOut)
def me(user: CurrentUser) -> Any:
    return user


def _finite(v: Any) -> float | None:
    if isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v):
        return float(v)
    return None


def _deviation_series(db: SessionDep, sess: Any) -> list[dict[str, Any]]:
    """Heading-deviation estimates of a session, oldest first: the engine's heading-deviation filter
    (004 Section 4.2, KF II) reports one in the detail of its calibration events (``heading_deviation_rad``,
    ``heading_deviation_var``); events without a finite value are skipped (NaN is stored as null)."""
    out = []
    for e in crud.events_of(db, sess.id):
        detail = e.detail or {}
        rad = _finite(detail.get("heading_deviation_rad"))
        if rad is None:
            continue
        out.append({"session_id": sess.id, "t_ns": int(e.t_ns), "event": e.kind, "behaviour": detail.get("behaviour"),
                    "heading_deviation_rad": rad, "heading_deviation_var": _finite(detail.get("heading_deviation_var"))})
    return out


def _session_gait(db: SessionDep, sess: Any) -> dict[str, Any]:
    pos = crud.positions_of(db, sess.id)
    # strides that moved: a re-stance on the spot while standing (a step length of a few cm) is no step
    moving = [p for p in pos if p.behaviour in ("walk", "run") and p.step_length_m >= STRIDE_MIN_M]
    series = _deviation_series(db, sess)
    out: dict[str, Any] = {
        "session_id": sess.id,
        "started": sess.created_at.isoformat(),
        "device_kind": sess.device_kind,
        "steps": len(moving),
        "distance_m": float(sum(p.step_length_m for p in moving)),
        "mean_step_length_m": None,
        "cadence_steps_per_min": None,
        # the session's latest estimate (None when the engine reported none)
        "heading_deviation_rad": series[-1]["heading_deviation_rad"] if series else None,
        "heading_deviation_var": series[-1]["heading_deviation_var"] if series else None,
        "heading_deviation": [{k: v for k, v in d.items() if k != "session_id"} for d in series],
    }
    if moving:
        out["mean_step_length_m"] = out["distance_m"] / len(moving)
    if len(moving) >= 2:
        span_s = (moving[-1].t_ns - moving[0].t_ns) / 1e9
        if span_s > 0:
            out["cadence_steps_per_min"] = 60.0 * (len(moving) - 1) / span_s
    return out


@router.get("/me/gait-summary", response_model=GaitSummaryOut)
def gait_summary(db: SessionDep, user: CurrentUser) -> GaitSummaryOut:
    """Per session, oldest first: steps, distance, mean step length, cadence and the heading deviation (latest
    estimate and its history); plus every heading-deviation estimate of the user over time (rehabilitation
    monitoring, 004 Section 4.2)."""
    sessions = [_session_gait(db, s) for s in crud.list_sessions(db, user, limit=10_000)]
    over_time = [{"session_id": s["session_id"], **d} for s in sessions for d in s["heading_deviation"]]
    return GaitSummaryOut(sessions=sessions, heading_deviation_over_time=over_time)
