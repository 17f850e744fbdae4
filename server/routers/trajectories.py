"""Trajectories of a session as JSON, GeoJSON (geolocated sessions) or CSV, plus its events."""

from __future__ import annotations

import csv
import json
import io
from typing import Any, Literal

from fastapi import APIRouter, HTTPException, Response, status

from server import crud
from server.deps import CurrentUser, PathId, SessionDep

__all__ = ["router", "to_geojson", "to_csv"]

router = APIRouter(prefix="/sessions/{session_id}", tags=["trajectories"])

_FIELDS = ("t_ns", "north", "east", "down", "heading_rad", "behaviour", "mode", "step_length_m", "gyro_on")


def _rows(db: SessionDep, session_id: int) -> list[dict[str, Any]]:
    return [{f: getattr(p, f) for f in _FIELDS} for p in crud.positions_of(db, session_id)]


def to_geojson(rows: list[dict[str, Any]], lat0: float, lon0: float, h0: float, props: dict[str, Any]) -> dict[str, Any]:
    """A LineString (lon, lat, height) of the NED positions about the geodetic start (WGS-84, pymap3d)."""
    import numpy as np
    import pymap3d

    n = np.array([r["north"] for r in rows], dtype=float)
    e = np.array([r["east"] for r in rows], dtype=float)
    d = np.array([r["down"] for r in rows], dtype=float)
    lat, lon, h = pymap3d.ned2geodetic(n, e, d, lat0, lon0, h0)
    coords = [[float(a), float(b), float(c)] for a, b, c in zip(np.atleast_1d(lon), np.atleast_1d(lat), np.atleast_1d(h))]
    return {
        "type": "FeatureCollection",
        "features": [
            {"type": "Feature", "geometry": {"type": "LineString", "coordinates": coords}, "properties": {
                **props, "t_ns": [r["t_ns"] for r in rows], "mode": [r["mode"] for r in rows],
                "behaviour": [r["behaviour"] for r in rows]}},
        ],
    }


def to_csv(rows: list[dict[str, Any]]) -> str:
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=list(_FIELDS), lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({k: (repr(v) if isinstance(v, float) else v) for k, v in r.items()})
    return buf.getvalue()


@router.get("/trajectory")
def trajectory(
    session_id: PathId, db: SessionDep, user: CurrentUser, format: Literal["json", "geojson", "csv"] = "json"  # noqa: A002
) -> Any:
    """Positions in the session's NED frame [m] (origin at the first stance); GeoJSON needs a geodetic start."""
    sess = crud.get_session(db, user, session_id)
    if sess is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"session {session_id} not found")
    rows = _rows(db, sess.id)
    if format == "csv":
        return Response(content=to_csv(rows), media_type="text/csv")
    if format == "geojson":
        if sess.latitude_deg is None or sess.longitude_deg is None:
            raise HTTPException(
                status.HTTP_409_CONFLICT, "format: geojson needs a session started with latitude_deg/longitude_deg"
            )
        doc = to_geojson(rows, sess.latitude_deg, sess.longitude_deg, sess.altitude_m or 0.0, {"session_id": sess.id})
        return Response(content=json.dumps(doc), media_type="application/geo+json")
    return {"session_id": sess.id, "frame": "NED", "units": "m", "positions": rows}


@router.get("/events")
def events(session_id: PathId, db: SessionDep, user: CurrentUser) -> list[dict[str, Any]]:
    sess = crud.get_session(db, user, session_id)
    if sess is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"session {session_id} not found")
    return [{"seq": e.seq, "t_ns": e.t_ns, "kind": e.kind, "detail": e.detail} for e in crud.events_of(db, sess.id)]
