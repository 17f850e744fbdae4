"""The calling user and their gait summary."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter

from server import crud
from server.deps import CurrentUser, SessionDep
from server.schemas import GaitSummaryOut, UserOut

__all__ = ["router"]

router = APIRouter(prefix="/users", tags=["users"])


@router.get("/me", response_model=UserOut)
def me(user: CurrentUser) -> Any:
    return user


def _session_gait(db: SessionDep, sess: Any) -> dict[str, Any]:
    pos = crud.positions_of(db, sess.id)
    moving = [p for p in pos if p.behaviour in ("walk", "run") and p.step_length_m > 0]
    out: dict[str, Any] = {
        "session_id": sess.id,
        "started": sess.created_at.isoformat(),
        "device_kind": sess.device_kind,
        "steps": len(moving),
        "distance_m": float(sum(p.step_length_m for p in moving)),
        "mean_step_length_m": None,
        "cadence_steps_per_min": None,
        "heading_deviation_rad": None,
    }
    if moving:
        out["mean_step_length_m"] = out["distance_m"] / len(moving)
    if len(moving) >= 2:
        span_s = (moving[-1].t_ns - moving[0].t_ns) / 1e9
        if span_s > 0:
            out["cadence_steps_per_min"] = 60.0 * (len(moving) - 1) / span_s
    # the engine's heading-deviation filter (004 Section 4.2, KF II) reports its estimate in events
    for e in reversed(crud.events_of(db, sess.id)):
        if "heading_deviation_rad" in e.detail:
            out["heading_deviation_rad"] = float(e.detail["heading_deviation_rad"])
            break
    return out


@router.get("/me/gait-summary", response_model=GaitSummaryOut)
def gait_summary(db: SessionDep, user: CurrentUser) -> GaitSummaryOut:
    """Per session: steps, distance, mean step length, cadence and heading deviation, oldest first."""
    return GaitSummaryOut(sessions=[_session_gait(db, s) for s in crud.list_sessions(db, user, limit=10_000)])
