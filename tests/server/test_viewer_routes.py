"""The viewer's files and the timeline route it draws from (without a browser)."""

from __future__ import annotations

import pytest

from server.formats import encode_msgpack
from tests.server.conftest import auth, still_batch

T0 = 1_700_000_000_000_000_000


def test_viewer_is_served_without_a_build_step(client) -> None:  # type: ignore[no-untyped-def]
    r = client.get("/app", follow_redirects=False)
    assert r.status_code in (302, 307) and r.headers["location"] == "/app/"
    r = client.get("/app/")
    assert r.status_code == 200 and "text/html" in r.headers["content-type"] and 'id="map"' in r.text
    assert "script-src 'self'" in r.headers["content-security-policy"]
    for path in ("/app/static/app.js", "/app/static/app.css", "/app/static/leaflet/leaflet.js",
                 "/app/static/leaflet/leaflet.css", "/app/static/leaflet/LICENSE.txt"):
        assert client.get(path).status_code == 200, path
    cfg = client.get("/app/config.json").json()
    assert cfg["tile_url"].startswith("https://") and "OpenStreetMap" in cfg["tile_attribution"]
    assert client.get("/app/static/../settings.py").status_code == 404


def test_timeline_says_what_the_device_sent_and_what_it_cost(client, make_user) -> None:  # type: ignore[no-untyped-def]
    _, a = make_user()
    _, b = make_user()
    sid = client.post("/v1/sessions", json={"device_kind": "foot"}, headers=auth(a)).json()["id"]
    assert client.get(f"/v1/sessions/{sid}/timeline", headers=auth(a)).json() == {"session_id": sid, "batches": [], "energy": None}
    for k in range(3):
        r = client.put(f"/v1/sessions/{sid}/batches/{k}", content=encode_msgpack(still_batch(T0 + k * 10**9, seed=k)),
                       headers={**auth(a), "Content-Type": "application/msgpack"})
        assert r.status_code == 200
    tl = client.get(f"/v1/sessions/{sid}/timeline", headers=auth(a)).json()
    assert [x["seq"] for x in tl["batches"]] == [0, 1, 2]
    first = tl["batches"][0]
    assert first["t_start_ns"] == T0 and first["n_acc"] == 100 and first["acc_hz"] == pytest.approx(100.0)
    assert first["gyro_on"] is True and first["mode"] in ("idle", "zupt", "pdr")
    e = tl["energy"]
    assert e["profile"] == "foot-lsm9ds1" and e["total_mj"] == pytest.approx(sum(e["components_mj"].values()))
    assert e["components_mj"]["gyr"] > 0 and e["duration_s"] == pytest.approx(2.99, abs=0.02)
    assert client.get(f"/v1/sessions/{sid}/timeline", headers=auth(b)).status_code == 404
    assert client.get(f"/v1/sessions/{sid}/timeline").status_code == 401
