"""Sessions: start (with an optional anchor), list, read, change the anchor, close, delete, re-process."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from fastapi import APIRouter, HTTPException, Query, Response, status

from server import crud
from server.deps import CurrentUser, HostDep, OffsetQuery, PathId, SessionDep, SettingsDep
from server.ingest import IngestConflict, apply_known_distance, close_session, engine_profile_in, json_safe, session_spec
from server.models import utcnow
from server.reprocess import ReprocessConflict, reprocess_session
from server.schemas import DistanceIn, EventOut, ReprocessIn, ReprocessOut, SessionCreate, SessionOut, SessionPatch
from server.statecodec import pack_state

__all__ = ["router"]

router = APIRouter(prefix="/sessions", tags=["sessions"])


@router.post("", response_model=SessionOut, status_code=status.HTTP_201_CREATED)
def start_session(body: SessionCreate, db: SessionDep, user: CurrentUser, settings: SettingsDep, host: HostDep) -> Any:
    """Start a session; its placement picks the engine, the user's current calibration profiles for that engine
    are handed to it."""
    if body.device_id is not None:
        dev = crud.get_device(db, user, body.device_id)
        if dev is None:
            raise HTTPException(status.HTTP_404_NOT_FOUND, f"device_id: device {body.device_id} not found")
    if (body.latitude_deg is None) != (body.longitude_deg is None):
        raise HTTPException(422, "latitude_deg: latitude and longitude must be given together")
    from energy.engines import check_spec

    try:
        check_spec(body.device_kind, body.placement)
    except ValueError as exc:
        raise HTTPException(422, str(exc)) from None
    placement = body.placement if body.placement is not None or body.device_kind == "phone" else body.device_kind
    created = utcnow()
    spec = session_spec(body.device_kind, placement, body.latitude_deg, body.longitude_deg, body.altitude_m,
                        body.anchor_date or created)
    profile = engine_profile_in(db, user, spec.pipeline)
    engine = host.new(settings.engine_mode, profile, spec)
    sess = crud.create_session(
        db, user, device_kind=body.device_kind, placement=placement, device_id=body.device_id,
        latitude_deg=body.latitude_deg, longitude_deg=body.longitude_deg, altitude_m=body.altitude_m,
        anchor_date=body.anchor_date, anchor_accuracy_m=body.anchor_accuracy_m,
        anchor_source="user" if body.latitude_deg is not None else None, engine_mode=settings.engine_mode,
        profile_in=json_safe(profile), engine_state=pack_state(engine.to_bytes()), sensor_config=engine.sensor_config.to_dict(),
        created_at=created,
    )
    db.commit()
    if host.pool is None:  # engines in this process: the session's first batch here takes this engine as it is
        host.remember(sess.id, sess.version, engine, complete=True)  # (~0.5 ms of decoding its state spared)
    return sess


@router.get("", response_model=list[SessionOut])
def list_sessions(
    db: SessionDep, user: CurrentUser, status_: Annotated[Literal["open", "closed"] | None, Query(alias="status")] = None, limit: int = 100, offset: OffsetQuery = 0
) -> Any:
    return crud.list_sessions(db, user, status_, min(max(limit, 1), 1000), max(offset, 0))


@router.get("/{session_id}", response_model=SessionOut)
def get_session(session_id: PathId, db: SessionDep, user: CurrentUser) -> Any:
    sess = crud.get_session(db, user, session_id)
    if sess is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"session {session_id} not found")
    return sess


@router.patch("/{session_id}", response_model=SessionOut)
def patch_session(session_id: PathId, body: SessionPatch, db: SessionDep, user: CurrentUser) -> Any:
    """Set, change or remove the session's anchor (open or closed). Only the fields sent change;
    ``latitude_deg`` and ``longitude_deg`` null together remove it (with its date, accuracy and source). The
    trajectory is geo-referenced when read, so every export follows at once; the stored positions are unchanged."""
    sess = crud.get_session(db, user, session_id, for_update=True)
    if sess is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"session {session_id} not found")
    sent = body.model_fields_set
    if ("latitude_deg" in sent) != ("longitude_deg" in sent):
        raise HTTPException(422, "latitude_deg: latitude and longitude must be given together")
    if "latitude_deg" in sent and (body.latitude_deg is None) != (body.longitude_deg is None):
        raise HTTPException(422, "latitude_deg: latitude and longitude must both be numbers or both null")
    if "latitude_deg" in sent and body.latitude_deg is None:
        for f in ("latitude_deg", "longitude_deg", "altitude_m", "anchor_date", "anchor_accuracy_m", "anchor_source"):
            setattr(sess, f, None)
    else:
        if "latitude_deg" not in sent and sess.latitude_deg is None and sent:
            raise HTTPException(422, "latitude_deg: the session has no anchor; send latitude_deg and longitude_deg")
        for f in ("latitude_deg", "longitude_deg", "altitude_m", "anchor_date", "anchor_accuracy_m"):
            if f in sent:
                setattr(sess, f, getattr(body, f))
        if "latitude_deg" in sent:
            sess.anchor_source = "user"
            if "anchor_accuracy_m" not in sent:
                sess.anchor_accuracy_m = None  # a hand-given position has no fix accuracy
    db.commit()
    return sess


@router.delete("/{session_id}", status_code=status.HTTP_204_NO_CONTENT, response_class=Response)
def delete_session(session_id: PathId, db: SessionDep, user: CurrentUser, host: HostDep) -> Response:
    """Delete the session with its raw batches, positions, events and Sensor Logger messages (open or closed).
    The user's calibration profiles stay (a closed session has already handed its calibration over)."""
    with host.lock(session_id):
        sess = crud.get_session(db, user, session_id, for_update=True)
        if sess is None:
            raise HTTPException(status.HTTP_404_NOT_FOUND, f"session {session_id} not found")
        crud.delete_session(db, sess)
        with host.write_lock:
            db.commit()
        host.forget(session_id)
    return Response(status_code=status.HTTP_204_NO_CONTENT)


@router.post("/{session_id}/close", response_model=SessionOut)
def close(session_id: PathId, db: SessionDep, user: CurrentUser, host: HostDep, settings: SettingsDep) -> Any:
    """Close: drain the engine's held-back positions, store the updated calibration profiles."""
    sess = close_session(db, host, user, session_id, keep_versions=settings.max_profile_versions)
    if sess is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"session {session_id} not found")
    return sess


@router.post("/{session_id}/distance", response_model=EventOut)
def known_distance(session_id: PathId, body: DistanceIn, db: SessionDep, user: CurrentUser, host: HostDep) -> Any:
    """A distance walked between two times (user-entered, a foot sensor's or GNSS's): a phone or watch session's
    step length is calibrated on the steps between them (stored in the profile at the close). 422 when the times
    hold too few steps or the session is a foot sensor's; 409 when the session is closed."""
    if body.t1_ns <= body.t0_ns:
        raise HTTPException(422, "t1_ns: must be after t0_ns")
    try:
        ev = apply_known_distance(db, host, user, session_id, body.t0_ns, body.t1_ns, body.distance_m)
    except IngestConflict as exc:
        raise HTTPException(status.HTTP_409_CONFLICT, exc.message) from None
    except ValueError as exc:
        raise HTTPException(422, str(exc)) from None
    if ev is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"session {session_id} not found")
    return ev


@router.post("/{session_id}/reprocess", response_model=ReprocessOut)
def reprocess(
    session_id: PathId, db: SessionDep, user: CurrentUser, host: HostDep, body: ReprocessIn | None = None
) -> Any:
    """Re-process the session with the server's current engine from its stored raw batches (owner only).

    The batches are fed in sequence order as they arrived (a closed session is flushed again); the new
    positions, events and engine state replace the old ones atomically. With the engine unchanged the
    trajectory is reproduced exactly (``identical: true``). 409 when the session received a batch meanwhile
    or a stored batch is refused by the current engine; nothing is changed then. ``dry_run`` only compares.
    """
    opts = body or ReprocessIn()
    try:
        res = reprocess_session(db, host, user, session_id, opts.engine_mode, opts.dry_run)
    except ReprocessConflict as exc:
        raise HTTPException(status.HTTP_409_CONFLICT, exc.message) from None
    if res is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"session {session_id} not found")
    return ReprocessOut(**vars(res))
