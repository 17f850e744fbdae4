"""Sessions a client can edit and delete, anchored trajectories in every export format, CORS off by default."""

from __future__ import annotations

import datetime as dt
import json
import math
from typing import Any

import numpy as np
import pytest

from models.geo import Anchor, geodetic_to_ned, magnetic_elements
from models.track_export import read_csv, read_geojson, read_gpx, read_kml
from server.models import BatchRecord, EventRecord, PositionRecord, ProfileVersion, TrackSession
from tests.server.conftest import app_with, auth, still_batch

T0 = 1_700_000_000_000_000_000


def _start(client, token: str, **kw: Any) -> int:  # type: ignore[no-untyped-def]
    r = client.post("/v1/sessions", json={"device_kind": "foot", **kw}, headers=auth(token))
    assert r.status_code == 201, r.text
    return r.json()["id"]


def _positions(app, sid: int, pts: list[tuple[float, float]]) -> None:  # type: ignore[no-untyped-def]
    with app.state.sessionmaker() as db:
        for i, (n, e) in enumerate(pts):
            db.add(PositionRecord(session_id=sid, seq=i, t_ns=T0 + i * 10**9, north=n, east=e, down=0.0,
                                  heading_rad=0.0, behaviour="walk", mode="zupt", step_length_m=1.0, gyro_on=True))
        db.commit()


def _magnetic_north_engine() -> type:
    """The engine class declaring a magnetic-north frame (``NORTH_REFERENCE``), as an engine with magnetic
    heading updates will."""
    from energy.engine import Engine

    return type("MagneticNorthEngine", (Engine,), {"NORTH_REFERENCE": "magnetic"})


def test_patch_sets_changes_and_removes_the_anchor(client, make_user) -> None:  # type: ignore[no-untyped-def]
    _, a = make_user()
    sid = _start(client, a)
    s = client.get(f"/v1/sessions/{sid}", headers=auth(a)).json()
    assert s["latitude_deg"] is None and s["declination_deg"] is None
    r = client.patch(f"/v1/sessions/{sid}", json={"latitude_deg": 33.6405, "longitude_deg": -117.8443,
                                                  "anchor_date": "2026-12-03"}, headers=auth(a))
    assert r.status_code == 200, r.text
    s = r.json()
    assert s["latitude_deg"] == 33.6405 and s["anchor_source"] == "user" and s["anchor_date"] == "2026-12-03"
    assert 10.5 < s["declination_deg"] < 12.0
    r = client.patch(f"/v1/sessions/{sid}", json={"altitude_m": 20.0}, headers=auth(a))
    assert r.json()["altitude_m"] == 20.0 and r.json()["latitude_deg"] == 33.6405
    r = client.patch(f"/v1/sessions/{sid}", json={"latitude_deg": None, "longitude_deg": None}, headers=auth(a))
    s = r.json()
    assert s["latitude_deg"] is None and s["altitude_m"] is None and s["anchor_date"] is None and s["declination_deg"] is None


@pytest.mark.parametrize("body, field", [
    ({"latitude_deg": 10.0}, "latitude_deg"),
    ({"latitude_deg": 95.0, "longitude_deg": 0.0}, "latitude_deg"),
    ({"latitude_deg": 10.0, "longitude_deg": None}, "latitude_deg"),
    ({"altitude_m": 10.0}, "latitude_deg"),  # no anchor to change
    ({"latitude_deg": "10", "longitude_deg": 0.0}, "latitude_deg"),
    ({"lat": 10.0}, "lat"),
    ({"anchor_date": "yesterday"}, "anchor_date"),
])
def test_patch_refusals_name_the_field(client, make_user, body, field) -> None:  # type: ignore[no-untyped-def]
    _, a = make_user()
    sid = _start(client, a)
    r = client.patch(f"/v1/sessions/{sid}", json=body, headers=auth(a))
    assert r.status_code == 422 and field in r.text, r.text
    assert client.get(f"/v1/sessions/{sid}", headers=auth(a)).json()["latitude_deg"] is None


def test_patch_and_delete_of_another_users_session_are_404(client, make_user) -> None:  # type: ignore[no-untyped-def]
    _, a = make_user()
    _, b = make_user()
    sid = _start(client, a)
    assert client.patch(f"/v1/sessions/{sid}", json={"latitude_deg": 1.0, "longitude_deg": 2.0}, headers=auth(b)).status_code == 404
    assert client.delete(f"/v1/sessions/{sid}", headers=auth(b)).status_code == 404
    assert client.get(f"/v1/sessions/{sid}", headers=auth(a)).status_code == 200
    assert client.delete(f"/v1/sessions/{sid}").status_code == 401


def test_delete_removes_batches_positions_events_and_keeps_the_profile(client, make_user, app) -> None:  # type: ignore[no-untyped-def]
    from sqlalchemy import func, select

    from server.formats import encode_msgpack

    uid, a = make_user()
    sid = _start(client, a)
    for k in range(3):
        r = client.put(f"/v1/sessions/{sid}/batches/{k}", content=encode_msgpack(still_batch(T0 + k * 10**9, seed=k)),
                       headers={**auth(a), "Content-Type": "application/msgpack"})
        assert r.status_code == 200, r.text
    _positions(app, sid, [(0.0, 0.0), (1.0, 0.0)])
    with app.state.sessionmaker() as db:
        db.add(EventRecord(session_id=sid, seq=0, t_ns=T0, kind="test", detail={}))
        db.add(ProfileVersion(user_id=uid, behaviour="walk", version=1, data={"n_steps": 3}, source="test"))
        db.commit()
    assert client.delete(f"/v1/sessions/{sid}", headers=auth(a)).status_code == 204
    assert client.get(f"/v1/sessions/{sid}", headers=auth(a)).status_code == 404
    assert client.delete(f"/v1/sessions/{sid}", headers=auth(a)).status_code == 404
    with app.state.sessionmaker() as db:
        for table in (BatchRecord, PositionRecord, EventRecord):
            n = db.execute(select(func.count()).select_from(table).where(table.session_id == sid)).scalar_one()
            assert n == 0, table.__tablename__
        assert db.get(TrackSession, sid) is None
        assert db.execute(select(func.count()).select_from(ProfileVersion).where(ProfileVersion.user_id == uid)).scalar_one() == 1
    # a new session never takes the deleted one's id
    assert _start(client, a) > sid


def test_every_format_of_an_anchored_session_reads_back_to_its_positions(client, make_user, app) -> None:  # type: ignore[no-untyped-def]
    import xmlschema
    from pathlib import Path

    from tests.models.test_track_export import check_rfc7946

    _, a = make_user()
    anchor = Anchor(43.66, -79.39, 80.0, dt.date(2026, 12, 3))
    sid = _start(client, a, latitude_deg=anchor.latitude_deg, longitude_deg=anchor.longitude_deg,
                 altitude_m=anchor.altitude_m, anchor_date="2026-12-03")
    pts = [(0.0, 0.0), (100.0, 0.0), (100.0, 50.0), (30.0, -20.0)]
    _positions(app, sid, pts)
    js = client.get(f"/v1/sessions/{sid}/trajectory", headers=auth(a)).json()
    # the default engine's north is its initial heading: placed on the map, not turned
    assert js["north"] == "initial-heading" and js["declination_deg"] == 0.0
    assert [(p["north"], p["east"]) for p in js["positions"]] == pts
    ned = np.array([[n, e, 0.0] for n, e in pts])
    xsd = Path(__file__).parents[1] / "models" / "data" / "gpx11_subset.xsd"
    for fmt, reader, ctype in (("geojson", read_geojson, "application/geo+json"), ("gpx", read_gpx, "application/gpx+xml"),
                               ("kml", read_kml, "application/vnd.google-earth.kml+xml")):
        r = client.get(f"/v1/sessions/{sid}/trajectory?format={fmt}", headers=auth(a))
        assert r.status_code == 200 and r.headers["content-type"].startswith(ctype)
        if fmt == "geojson":
            check_rfc7946(r.json())
        if fmt == "gpx":
            xmlschema.XMLSchema(str(xsd)).validate(r.text)
        lla = reader(r.text)
        n, e, d = geodetic_to_ned(lla[:, 0], lla[:, 1], lla[:, 2], anchor)
        assert np.max(np.abs(np.column_stack([n, e, d]) - ned)) < 1e-3, fmt
    rows = read_csv(client.get(f"/v1/sessions/{sid}/trajectory?format=csv", headers=auth(a)).text)
    assert [(float(r["north"]), float(r["east"])) for r in rows] == pts and "latitude_deg" in rows[0]


def test_a_magnetic_north_engine_is_turned_by_the_declination(settings, make_user) -> None:  # type: ignore[no-untyped-def]
    with app_with(settings, engine_processes=0) as (app2, c):
        app2.state.host._engine_cls = _magnetic_north_engine()
        with app2.state.sessionmaker() as db:
            from server import crud

            user, tok = crud.create_user(db, f"mag-{id(c)}")
            db.commit()
        sid = _start(c, tok, latitude_deg=33.6405, longitude_deg=-117.8443, anchor_date="2026-12-03")
        _positions(app2, sid, [(0.0, 0.0), (100.0, 0.0)])
        js = c.get(f"/v1/sessions/{sid}/trajectory", headers=auth(tok)).json()
        assert js["north"] == "initial-heading"  # no batch with a magnetometer: nothing magnetic to correct
        with app2.state.sessionmaker() as db:
            db.add(BatchRecord(session_id=sid, seq=0, body_sha256="0" * 64, raw=b"", n_acc=1, n_gyr=1, n_mag=1, response={}))
            db.commit()
        js = c.get(f"/v1/sessions/{sid}/trajectory", headers=auth(tok)).json()
        dec = magnetic_elements(Anchor(33.6405, -117.8443, 0.0, dt.date(2026, 12, 3))).declination_rad
        assert js["north"] == "true" and js["declination_deg"] == pytest.approx(math.degrees(dec), abs=1e-12)
        p = js["positions"][1]
        assert (p["north"], p["east"]) == pytest.approx((100 * math.cos(dec), 100 * math.sin(dec)), abs=1e-9)
        assert p["heading_rad"] == pytest.approx(dec, abs=1e-12)
        # removing the anchor gives the stored magnetic frame back
        c.patch(f"/v1/sessions/{sid}", json={"latitude_deg": None, "longitude_deg": None}, headers=auth(tok))
        js = c.get(f"/v1/sessions/{sid}/trajectory", headers=auth(tok)).json()
        assert js["north"] == "magnetic" and js["positions"][1]["north"] == 100.0


def test_geo_formats_without_anchor_are_409(client, make_user, app) -> None:  # type: ignore[no-untyped-def]
    _, a = make_user()
    sid = _start(client, a)
    _positions(app, sid, [(0.0, 0.0), (1.0, 0.0)])
    for fmt in ("geojson", "gpx", "kml"):
        r = client.get(f"/v1/sessions/{sid}/trajectory?format={fmt}", headers=auth(a))
        assert r.status_code == 409 and "anchor" in r.json()["detail"]
    assert client.get(f"/v1/sessions/{sid}/trajectory", headers=auth(a)).json()["north"] == "initial-heading"


def test_cors_is_off_by_default_and_configurable(client, settings) -> None:  # type: ignore[no-untyped-def]
    pre = {"Origin": "https://viewer.example.org", "Access-Control-Request-Method": "GET",
           "Access-Control-Request-Headers": "authorization"}
    r = client.options("/v1/sessions", headers=pre)
    assert "access-control-allow-origin" not in r.headers
    with app_with(settings, cors_origins="https://viewer.example.org") as (_, c):
        r = c.options("/v1/sessions", headers=pre)
        assert r.status_code == 200 and r.headers["access-control-allow-origin"] == "https://viewer.example.org"
        r = c.options("/v1/sessions", headers={**pre, "Origin": "https://evil.example.com"})
        assert r.headers.get("access-control-allow-origin") != "https://evil.example.com"


@pytest.mark.parametrize("value", ["viewer.example.org", "https://a.org/path", "ftp://x"])
def test_cors_origins_are_checked(value: str) -> None:
    from server.settings import SettingsError, load_settings

    with pytest.raises(SettingsError, match="PEDNAV_CORS_ORIGINS"):
        load_settings(cors_origins=value)


def test_openapi_lists_patch_and_delete(client) -> None:  # type: ignore[no-untyped-def]
    spec = client.get("/openapi.json").json()
    ops = spec["paths"]["/v1/sessions/{session_id}"]
    assert {"get", "patch", "delete"} <= set(ops)
    assert ops["patch"]["responses"]["200"]["content"]["application/json"]["schema"]["$ref"].endswith("/SessionOut")
    assert "204" in ops["delete"]["responses"]
    json.dumps(spec)
