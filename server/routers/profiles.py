"""Calibration profiles per user and behaviour: read, replace, reset, history (versioned).

Every replace, reset and session close adds a version; the newest ``max_profile_versions`` per behaviour are
kept (older ones are deleted). A profile put by a client is at most ``max_profile_bytes`` as compact JSON.
"""

from __future__ import annotations

import json
from typing import Annotated, Any, Literal

from fastapi import APIRouter, HTTPException, Path, status

from server import crud
from server.deps import CurrentUser, HostDep, SessionDep, SettingsDep
from server.ingest import json_safe, validate_calibration
from server.schemas import ProfileIn, ProfileOut

__all__ = ["Calibrated", "router"]

router = APIRouter(prefix="/profiles", tags=["profiles"])

Calibrated = Literal["walk", "run", "pdr"]
"""The profile entries that hold a calibration (``energy.profile.PROFILE_BEHAVIOURS``; a test keeps them in step):
the foot engine's behaviours and ``pdr``, the step-and-heading engines' (per placement); an enum in the published
schema."""
BehaviourPath = Annotated[Calibrated, Path(description="a behaviour with a calibration")]


def _out(p: Any) -> ProfileOut:
    return ProfileOut(behaviour=p.behaviour, version=p.version, data=p.data, source=p.source, created_at=p.created_at)


@router.get("", response_model=list[ProfileOut])
def list_profiles(db: SessionDep, user: CurrentUser) -> Any:
    """Current profile of every behaviour that has one (resets show ``data: null``)."""
    return [_out(p) for _, p in sorted(crud.current_profiles(db, user).items())]


@router.get("/{behaviour}", response_model=ProfileOut)
def get_profile(behaviour: BehaviourPath, db: SessionDep, user: CurrentUser) -> Any:
    cur = crud.current_profiles(db, user).get(behaviour)
    if cur is None or cur.data is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"no calibration profile for behaviour {behaviour!r}")
    return _out(cur)


def _check_size(data: dict[str, Any], limit: int) -> None:
    """413 naming ``data`` when its compact JSON exceeds ``limit`` bytes (before anything heavier looks at it)."""
    try:
        n = len(json.dumps(json_safe(data), separators=(",", ":")).encode())
    except RecursionError:
        raise HTTPException(422, "data: nested too deeply") from None
    if n > limit:
        raise HTTPException(413, f"data: calibration of {n} bytes (compact JSON) exceeds the limit of {limit} bytes per profile")


@router.put("/{behaviour}", response_model=ProfileOut)
def replace_profile(behaviour: BehaviourPath, body: ProfileIn, db: SessionDep, user: CurrentUser, host: HostDep,
                    settings: SettingsDep) -> Any:
    """Replace the profile (a new version; the newest ``max_profile_versions`` stay in the history). Used by new
    sessions. 413 when ``data`` as compact JSON exceeds ``max_profile_bytes``."""
    _check_size(body.data, settings.max_profile_bytes)
    try:
        validate_calibration(behaviour, body.data, host)
    except ValueError as exc:
        raise HTTPException(422, f"data: {exc}") from None
    row = crud.add_profile_version(db, user, behaviour, json_safe(body.data), source="api",
                                   keep=settings.max_profile_versions)
    db.commit()
    return _out(row)


@router.delete("/{behaviour}", response_model=ProfileOut)
def reset_profile(behaviour: BehaviourPath, db: SessionDep, user: CurrentUser, settings: SettingsDep) -> Any:
    """Reset: new sessions start uncalibrated for this behaviour (recorded as a version with ``data: null``)."""
    row = crud.add_profile_version(db, user, behaviour, None, source="reset", keep=settings.max_profile_versions)
    db.commit()
    return _out(row)


@router.get("/{behaviour}/history", response_model=list[ProfileOut])
def history(behaviour: BehaviourPath, db: SessionDep, user: CurrentUser) -> Any:
    """The kept versions of the profile, oldest first (the newest ``max_profile_versions``)."""
    return [_out(p) for p in crud.profile_history(db, user, behaviour)]
