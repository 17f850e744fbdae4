"""Trajectories of a session as JSON, GeoJSON, GPX, KML or CSV, plus its events.

Positions are stored as the engine gave them (NED about the first stance, the engine's north) and
geo-referenced when read by :func:`models.geo.georeference`, the function ``pednav replay --anchor`` uses too:
an anchored session whose engine navigates by magnetic north is turned to true north by the World Magnetic
Model's declination at the anchor and date, so an anchor set or changed later (PATCH) needs no rewrite of the
stored positions. Each answer says what its north is (``north``: ``true``, ``magnetic`` or ``initial-heading``).
The answers to batch uploads stay in the engine's frame (a retried batch gets its stored answer unchanged).

A phone session's trajectory may be read fused with a watch's (or another phone's) session of the same user
(``fuse_with``): 000's complementary fusion of two devices' steps (:func:`models.step_fusion.fuse_track`). Each
device uploads its own session (its own sequence numbers, durability and sensor configuration); the fusion is a
reading of the two stored tracks, so it needs no state and any later batch of either is in the next reading.
"""

from __future__ import annotations

import json
from typing import Annotated, Any, Literal

from fastapi import APIRouter, HTTPException, Query, Response, status
from sqlalchemy.orm import Session

from energy.engines import EngineSpec
from models.geo import GeoTrack, engine_north, georeference, magnetic_north_of
from models.step_fusion import fuse_track
from models.track_export import MEDIA_TYPES, TrackLabels, to_csv, to_geojson, to_gpx, to_kml
from server import crud
from server.deps import ID_MAX, ID_MIN, CurrentUser, HostDep, PathId, SessionDep
from server.ingest import EngineHost
from server.models import TrackSession
from server.schemas import session_anchor

__all__ = ["router", "track_of"]

router = APIRouter(prefix="/sessions/{session_id}", tags=["trajectories"])

_FIELDS = ("t_ns", "north", "east", "down", "heading_rad", "behaviour", "mode", "step_length_m", "gyro_on")


def _frame_of(db: Session, sess: TrackSession, host: EngineHost) -> tuple[str, float | None]:
    """The north of the session's stored positions and the azimuth of magnetic north in it (None: none told)."""
    cls = host.engine_class_of(sess.placement, sess.device_kind)
    north_in = engine_north(getattr(cls, "NORTH_REFERENCE", None), crud.has_magnetometer(db, sess.id))
    return north_in, magnetic_north_of((e.kind, e.detail) for e in crud.events_of(db, sess.id))


def _fusable(sess: TrackSession, frame: tuple[str, float | None], has_steps: bool) -> None:
    """409 naming ``fuse_with`` unless the session's steps can be fused with another device's: a step-and-heading
    session whose headings refer to magnetic north (a session without steps yet has nothing to compare)."""
    if EngineSpec(sess.device_kind, sess.placement).pipeline != "step-and-heading":
        raise HTTPException(status.HTTP_409_CONFLICT, f"fuse_with: session {sess.id} is a {sess.device_kind} session "
                            "navigated by the foot engine; only step-and-heading (phone, watch) sessions are fused")
    if has_steps and (frame[0] != "magnetic" or frame[1] is not None):
        raise HTTPException(status.HTTP_409_CONFLICT, f"fuse_with: session {sess.id} has no magnetometer heading, so "
                            "its steps' directions cannot be compared with the other device's")


def track_of(db: Session, sess: TrackSession, host: EngineHost, companion: TrackSession | None = None
             ) -> tuple[GeoTrack, TrackLabels, list[dict[str, Any]]]:
    """The session's stored positions geo-referenced (``georeference`` with the session's anchor and the north of
    its engine's frame), their labels, and the stored rows; with ``companion`` (a step-and-heading session of the
    same walker, on the same clock) the steps fused with the companion's (``step_length_m`` and ``heading_rad``
    of the rows are then the fused ones, and each row says whether it was ``blended``)."""
    import numpy as np

    rows = [{f: getattr(p, f) for f in _FIELDS} for p in crud.positions_of(db, sess.id)]
    col = {f: np.array([r[f] for r in rows], dtype=float) for f in ("north", "east", "down", "heading_rad")}
    north_in, az = _frame_of(db, sess, host)
    if companion is not None:
        other = crud.positions_of(db, companion.id)
        _fusable(sess, (north_in, az), bool(rows) and bool(other))
        _fusable(companion, _frame_of(db, companion, host), bool(rows) and bool(other))
        n, e, length, heading, blended = fuse_track(
            col["north"], col["east"], np.array([r["t_ns"] for r in rows], dtype=float) * 1e-9,
            np.array([r["step_length_m"] or 0.0 for r in rows], dtype=float), col["heading_rad"],
            np.array([p.t_ns for p in other], dtype=float) * 1e-9,
            np.array([p.step_length_m or 0.0 for p in other], dtype=float), np.array([p.heading_rad for p in other], dtype=float))
        col.update(north=n, east=e, heading_rad=heading)
        for r, li, bi in zip(rows, length, blended):
            r.update(step_length_m=float(li), blended=bool(bi))
    track = georeference(col["north"], col["east"], col["down"], col["heading_rad"], session_anchor(sess), north_in, az)
    labels = TrackLabels([r["t_ns"] for r in rows], [r["behaviour"] for r in rows], [r["mode"] for r in rows],
                         [r["step_length_m"] for r in rows], [r["gyro_on"] for r in rows])
    return track, labels, rows


@router.get("/trajectory")
def trajectory(
    session_id: PathId, db: SessionDep, user: CurrentUser, host: HostDep,
    format: Literal["json", "geojson", "gpx", "kml", "csv"] = "json",  # noqa: A002
    fuse_with: Annotated[int | None, Query(ge=ID_MIN, le=ID_MAX, description=(
        "id of another step-and-heading session of the same user (a watch beside this phone, on the same clock): "
        "this session's steps fused with that one's (000 eq. 70)"))] = None,
) -> Any:
    """The session's positions, one per step or stance.

    ``json``: ``{"session_id", "frame": "NED", "units": "m", "north", "declination_deg", "dip_deg",
    "magnetic_model", "anchor", "positions": [...]}``; positions in NED [m] about the first stance with north as
    ``north`` says, each with ``latitude_deg``, ``longitude_deg``, ``altitude_m`` when the session is anchored.
    ``geojson`` (RFC 7946), ``gpx`` (1.1) and ``kml`` (2.2) need an anchor (409 without one); ``csv`` keeps the
    NED columns and adds latitude/longitude/altitude when anchored. ``fuse_with``: the steps fused with that
    session's (each position's ``step_length_m`` and ``heading_rad`` the fused ones, ``blended`` whether the other
    device's step was taken in; ``fused_with`` and ``blended_steps`` in the document); 409 when either session is not
    a step-and-heading session with a magnetometer heading.
    """
    sess = crud.get_session(db, user, session_id)
    if sess is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"session {session_id} not found")
    companion = None
    if fuse_with is not None:
        if fuse_with == session_id:
            raise HTTPException(422, "fuse_with: another session than this one")
        companion = crud.get_session(db, user, fuse_with)
        if companion is None:
            raise HTTPException(status.HTTP_404_NOT_FOUND, f"fuse_with: session {fuse_with} not found")
    track, labels, rows = track_of(db, sess, host, companion)
    if format == "csv":
        return Response(content=to_csv(track, labels), media_type=MEDIA_TYPES["csv"])
    if format in ("geojson", "gpx", "kml"):
        if track.anchor is None:
            raise HTTPException(status.HTTP_409_CONFLICT, f"format: {format} needs an anchored session (set "
                                "latitude_deg/longitude_deg at the start or with PATCH /v1/sessions/{id})")
        name = f"pednav session {sess.id}"
        if format == "geojson":
            text = json.dumps(to_geojson(track, labels, {"session_id": sess.id}), allow_nan=False)
        else:
            text = (to_gpx if format == "gpx" else to_kml)(track, labels, name)
        return Response(content=text, media_type=MEDIA_TYPES[format], headers={
            "Content-Disposition": f'attachment; filename="pednav-session-{sess.id}.{format}"'})
    out = []
    for i, r in enumerate(rows):
        p = {**r, "north": float(track.north[i]), "east": float(track.east[i]), "heading_rad": float(track.heading_rad[i])}
        if track.latitude_deg is not None:
            assert track.longitude_deg is not None and track.altitude_m is not None
            p.update(latitude_deg=float(track.latitude_deg[i]), longitude_deg=float(track.longitude_deg[i]),
                     altitude_m=float(track.altitude_m[i]))
        out.append(p)
    doc = {"session_id": sess.id, "frame": "NED", "units": "m", **track.frame_dict(), "positions": out}
    if companion is not None:
        doc.update(fused_with=companion.id, blended_steps=sum(1 for r in rows if r["blended"]))
    return doc


@router.get("/events")
def events(session_id: PathId, db: SessionDep, user: CurrentUser) -> list[dict[str, Any]]:
    sess = crud.get_session(db, user, session_id)
    if sess is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"session {session_id} not found")
    return [{"seq": e.seq, "t_ns": e.t_ns, "kind": e.kind, "detail": e.detail} for e in crud.events_of(db, sess.id)]
