"""Trajectories of a session as JSON, GeoJSON, GPX, KML or CSV, plus its events.

Positions are stored as the engine gave them (NED about the first stance, the engine's north) and
geo-referenced when read by :func:`models.geo.georeference`, the function ``pednav replay --anchor`` uses too:
an anchored session whose engine navigates by magnetic north is turned to true north by the World Magnetic
Model's declination at the anchor and date, so an anchor set or changed later (PATCH) needs no rewrite of the
stored positions. Each answer says what its north is (``north``: ``true``, ``magnetic`` or ``initial-heading``).
The answers to batch uploads stay in the engine's frame (a retried batch gets its stored answer unchanged).
"""

from __future__ import annotations

import json
from typing import Any, Literal

from fastapi import APIRouter, HTTPException, Response, status
from sqlalchemy.orm import Session

from models.geo import GeoTrack, engine_north, georeference, magnetic_north_of
from models.track_export import MEDIA_TYPES, TrackLabels, to_csv, to_geojson, to_gpx, to_kml
from server import crud
from server.deps import CurrentUser, HostDep, PathId, SessionDep
from server.ingest import EngineHost
from server.models import TrackSession
from server.schemas import session_anchor

__all__ = ["router", "track_of"]

router = APIRouter(prefix="/sessions/{session_id}", tags=["trajectories"])

_FIELDS = ("t_ns", "north", "east", "down", "heading_rad", "behaviour", "mode", "step_length_m", "gyro_on")


def track_of(db: Session, sess: TrackSession, host: EngineHost) -> tuple[GeoTrack, TrackLabels, list[dict[str, Any]]]:
    """The session's stored positions geo-referenced (``georeference`` with the session's anchor and the north of
    its engine's frame), their labels, and the stored rows."""
    import numpy as np

    rows = [{f: getattr(p, f) for f in _FIELDS} for p in crud.positions_of(db, sess.id)]
    col = {f: np.array([r[f] for r in rows], dtype=float) for f in ("north", "east", "down", "heading_rad")}
    cls = host.engine_class_of(sess.placement, sess.device_kind)
    north_in = engine_north(getattr(cls, "NORTH_REFERENCE", None), crud.has_magnetometer(db, sess.id))
    az = magnetic_north_of((e.kind, e.detail) for e in crud.events_of(db, sess.id))
    track = georeference(col["north"], col["east"], col["down"], col["heading_rad"], session_anchor(sess), north_in, az)
    labels = TrackLabels([r["t_ns"] for r in rows], [r["behaviour"] for r in rows], [r["mode"] for r in rows],
                         [r["step_length_m"] for r in rows], [r["gyro_on"] for r in rows])
    return track, labels, rows


@router.get("/trajectory")
def trajectory(
    session_id: PathId, db: SessionDep, user: CurrentUser, host: HostDep,
    format: Literal["json", "geojson", "gpx", "kml", "csv"] = "json",  # noqa: A002
) -> Any:
    """The session's positions, one per step or stance.

    ``json``: ``{"session_id", "frame": "NED", "units": "m", "north", "declination_deg", "dip_deg",
    "magnetic_model", "anchor", "positions": [...]}``; positions in NED [m] about the first stance with north as
    ``north`` says, each with ``latitude_deg``, ``longitude_deg``, ``altitude_m`` when the session is anchored.
    ``geojson`` (RFC 7946), ``gpx`` (1.1) and ``kml`` (2.2) need an anchor (409 without one); ``csv`` keeps the
    NED columns and adds latitude/longitude/altitude when anchored.
    """
    sess = crud.get_session(db, user, session_id)
    if sess is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"session {session_id} not found")
    track, labels, rows = track_of(db, sess, host)
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
    return {"session_id": sess.id, "frame": "NED", "units": "m", **track.frame_dict(), "positions": out}


@router.get("/events")
def events(session_id: PathId, db: SessionDep, user: CurrentUser) -> list[dict[str, Any]]:
    sess = crud.get_session(db, user, session_id)
    if sess is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"session {session_id} not found")
    return [{"seq": e.seq, "t_ns": e.t_ns, "kind": e.kind, "detail": e.detail} for e in crud.events_of(db, sess.id)]
