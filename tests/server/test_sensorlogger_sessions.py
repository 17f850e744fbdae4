"""Sensor Logger live push end to end: empty pushes create nothing, idle sessions close, a new recording of the
device closes the earlier one, repeated messages are applied once, the location stream anchors the session."""

from __future__ import annotations

import time
from datetime import timedelta
from typing import Any

import pytest
from sqlalchemy import func, select

from server.models import SensorLoggerMessage, TrackSession, utcnow
from server.routers.sensorlogger import close_idle_sessions
from tests.server.conftest import app_with, auth
from tests.server.test_sensorlogger import T0, _items


def _push(client, tok: str, mid: int, payload: list[dict[str, Any]], sl_id: str, device: str = "d"):  # type: ignore[no-untyped-def]
    return client.post("/v1/sensorlogger", json={"messageId": mid, "sessionId": sl_id, "deviceId": device,
                                                 "payload": payload}, params={"token": tok})


def _fix(t: int, lat: float, lon: float, acc: float | None, alt: float = 20.0) -> dict[str, Any]:
    v: dict[str, Any] = {"latitude": lat, "longitude": lon, "altitude": alt, "speed": 0.0, "bearing": 0.0}
    if acc is not None:
        v["horizontalAccuracy"] = acc
    return {"name": "location", "time": t, "values": v}


def _sessions(client, tok: str) -> list[dict[str, Any]]:  # type: ignore[no-untyped-def]
    return client.get("/v1/sessions", headers=auth(tok)).json()


def test_empty_pushes_create_nothing(client, make_user, app) -> None:  # type: ignore[no-untyped-def]
    _, a = make_user()
    for mid, payload in enumerate([[], [_fix(T0, 33.6, -117.8, 5.0)], [{"name": "battery", "time": T0, "values": {"x": 1}}]]):
        r = _push(client, a, mid, payload, "empty-1")
        assert r.status_code == 200 and r.json()["session_id"] is None and r.json()["empty"] is True
    assert _sessions(client, a) == []  # (a message is stored with its session: none without one)
    # the first push with samples starts the session; a later empty one changes nothing
    sid = _push(client, a, 10, _items(T0), "empty-1").json()["session_id"]
    assert _push(client, a, 11, [], "empty-1").json()["session_id"] == sid
    assert [s["id"] for s in _sessions(client, a)] == [sid]


def test_repeated_message_ids_are_applied_once(client, make_user, app) -> None:  # type: ignore[no-untyped-def]
    _, a = make_user()
    answers = [_push(client, a, k % 3, _items(T0 + 2 * (k % 3) * 10**9), "dup-1").json() for k in range(6)]
    assert [x["duplicate"] for x in answers] == [False, False, False, True, True, True]
    sid = answers[0]["session_id"]
    with app.state.sessionmaker() as db:
        n = db.execute(select(func.count()).select_from(SensorLoggerMessage).where(SensorLoggerMessage.session_id == sid))
        assert n.scalar_one() == 3


def test_the_location_stream_anchors_the_session_at_the_first_good_fix(client, make_user) -> None:  # type: ignore[no-untyped-def]
    _, a = make_user()
    t = T0
    payload = _items(t) + [_fix(t, 33.0, -117.0, 120.0), _fix(t + 10**8, 33.6405, -117.8443, 8.5, alt=15.0),
                           _fix(t + 2 * 10**8, 34.0, -118.0, 3.0)]
    sid = _push(client, a, 1, payload, "loc-1").json()["session_id"]
    s = client.get(f"/v1/sessions/{sid}", headers=auth(a)).json()
    assert (s["latitude_deg"], s["longitude_deg"], s["altitude_m"]) == (33.6405, -117.8443, 15.0)
    assert s["anchor_accuracy_m"] == 8.5 and s["anchor_source"] == "location" and s["anchor_date"] == "2023-11-14"
    assert 10.0 < s["declination_deg"] < 13.0
    _push(client, a, 2, _items(t + 2 * 10**9) + [_fix(t + 2 * 10**9, 40.0, -100.0, 1.0)], "loc-1")
    assert client.get(f"/v1/sessions/{sid}", headers=auth(a)).json()["latitude_deg"] == 33.6405  # kept


def test_only_poor_fixes_do_not_anchor_and_a_users_anchor_is_kept(client, make_user) -> None:  # type: ignore[no-untyped-def]
    _, a = make_user()
    sid = _push(client, a, 1, _items(T0) + [_fix(T0, 33.0, -117.0, 80.0), _fix(T0 + 1, 33.0, -117.0, None),
                                             {"name": "location", "time": T0 + 2, "values": {"latitude": 1.0}}],
                "loc-2").json()["session_id"]
    assert client.get(f"/v1/sessions/{sid}", headers=auth(a)).json()["latitude_deg"] is None
    client.patch(f"/v1/sessions/{sid}", json={"latitude_deg": 51.5, "longitude_deg": -0.12}, headers=auth(a))
    _push(client, a, 2, _items(T0 + 2 * 10**9) + [_fix(T0 + 2 * 10**9, 33.0, -117.0, 2.0)], "loc-2")
    s = client.get(f"/v1/sessions/{sid}", headers=auth(a)).json()
    assert s["latitude_deg"] == 51.5 and s["anchor_source"] == "user"
    # a location-only push (no samples) anchors an existing unanchored session too
    sid2 = _push(client, a, 1, _items(T0), "loc-3").json()["session_id"]
    assert _push(client, a, 2, [_fix(T0 + 10**9, 48.85, 2.35, 4.0)], "loc-3").json()["session_id"] == sid2
    assert client.get(f"/v1/sessions/{sid2}", headers=auth(a)).json()["latitude_deg"] == 48.85


def test_an_idle_session_is_flushed_and_closed(client, make_user, app, settings) -> None:  # type: ignore[no-untyped-def]
    _, a = make_user()
    for k in range(4):
        assert _push(client, a, k, _items(T0 + 2 * k * 10**9), "idle-1").status_code == 200
    sid = _push(client, a, 4, _items(T0 + 8 * 10**9), "idle-1").json()["session_id"]
    host = app.state.host
    assert close_idle_sessions(app.state.sessionmaker, host, settings) == []  # just pushed: not idle
    later = utcnow() + timedelta(seconds=settings.sensorlogger_idle_close_s + 1)
    assert sid in close_idle_sessions(app.state.sessionmaker, host, settings, now=later)
    s = client.get(f"/v1/sessions/{sid}", headers=auth(a)).json()
    assert s["status"] == "closed"
    # every held-back sample was fed before the close: the watermark reached the last sample
    from server.models import SensorLoggerLink

    with app.state.sessionmaker() as db:
        link = db.execute(select(SensorLoggerLink).where(SensorLoggerLink.session_id == sid)).scalar_one()
        newest = db.execute(select(func.max(SensorLoggerMessage.t_max_ns)).where(SensorLoggerMessage.session_id == sid)).scalar_one()
        assert link.watermark_ns >= newest
    assert close_idle_sessions(app.state.sessionmaker, host, settings, now=later) == []  # once
    assert _push(client, a, 5, _items(T0 + 10 * 10**9), "idle-1").status_code == 409


def test_a_new_recording_of_the_device_closes_the_earlier_one(client, make_user) -> None:  # type: ignore[no-untyped-def]
    _, a = make_user()
    first = _push(client, a, 1, _items(T0), "rec-A", device="phone-7").json()["session_id"]
    other = _push(client, a, 1, _items(T0), "rec-X", device="phone-8").json()["session_id"]
    second = _push(client, a, 1, _items(T0 + 60 * 10**9), "rec-B", device="phone-7").json()["session_id"]
    st = {s["id"]: s["status"] for s in _sessions(client, a)}
    assert st == {first: "closed", other: "open", second: "open"}


def test_the_server_closes_idle_sessions_by_itself(settings, make_user) -> None:  # type: ignore[no-untyped-def]
    with app_with(settings, sensorlogger_idle_close_s=0.5) as (app2, c):
        _, tok = make_user()
        sid = _push(c, tok, 1, _items(T0), "self-1").json()["session_id"]
        deadline = time.monotonic() + 15
        while time.monotonic() < deadline:
            with app2.state.sessionmaker() as db:
                if db.get(TrackSession, sid).status == "closed":
                    break
            time.sleep(0.2)
        with app2.state.sessionmaker() as db:
            assert db.get(TrackSession, sid).status == "closed"


@pytest.mark.parametrize("value", [-1.0, float("nan")])
def test_idle_setting_is_checked(value: float) -> None:
    from server.settings import SettingsError, load_settings

    with pytest.raises(SettingsError, match="SENSORLOGGER_IDLE_CLOSE_S"):
        load_settings(sensorlogger_idle_close_s=value)
