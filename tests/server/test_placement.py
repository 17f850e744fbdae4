"""The placement decides the engine: session field, validation, the step-and-heading engine behind phone and
watch sessions, known-distance calibration into the profile, re-processing, and the migration of older rows."""

from __future__ import annotations

from functools import lru_cache

import pytest
from sqlalchemy import text

from clients.phone_synth import synthesize_phone
from clients.sdk import PednavClient
from clients.simulators import PhoneSimulator, WatchSimulator
from tests.server.conftest import auth


@lru_cache(maxsize=None)
def _rec(name: str):  # type: ignore[no-untyped-def]
    return synthesize_phone(name, seed=3)


def _start(client, tok, **body):  # type: ignore[no-untyped-def]
    return client.post("/v1/sessions", json=body, headers=auth(tok))


@pytest.mark.parametrize("kind, placement, stored", [
    ("foot", None, "foot"), ("foot", "foot", "foot"), ("phone", None, None), ("phone", "phone-pocket", "phone-pocket"),
    ("phone", "foot", "foot"), ("watch", None, "watch"),
])
def test_session_placement_is_stored_and_echoed(client, make_user, kind, placement, stored) -> None:  # type: ignore[no-untyped-def]
    _, tok = make_user()
    body = {"device_kind": kind, **({"placement": placement} if placement else {})}
    r = _start(client, tok, **body)
    assert r.status_code == 201, r.text
    assert r.json()["placement"] == stored
    assert client.get(f"/v1/sessions/{r.json()['id']}", headers=auth(tok)).json()["placement"] == stored


@pytest.mark.parametrize("kind, placement", [("watch", "phone-hand"), ("foot", "watch"), ("phone", "watch"),
                                             ("phone", "belt"), ("foot", "phone-pocket")])
def test_impossible_placements_are_422_naming_it(client, make_user, kind, placement) -> None:  # type: ignore[no-untyped-def]
    _, tok = make_user()
    r = _start(client, tok, device_kind=kind, placement=placement)
    assert r.status_code == 422 and "placement" in r.text
    assert client.get("/v1/sessions", headers=auth(tok)).json() == []  # nothing was created


@pytest.mark.parametrize("sim, name", [(PhoneSimulator, "phone-walk"), (WatchSimulator, "watch-walk")])
def test_phone_and_watch_sessions_run_the_step_and_heading_engine(client, make_user, sim, name) -> None:  # type: ignore[no-untyped-def]
    _, tok = make_user()
    api = PednavClient(token=tok, http=client)
    res = sim(_rec(name)).run(api, start={"latitude_deg": 49.46, "longitude_deg": 11.11})
    assert len(res.positions) > 40 and {p["mode"] for p in res.positions} == {"pdr"}
    ev = api.events(res.session_id)
    ref = [e for e in ev if e["kind"] == "heading_reference"]
    assert ref and ref[0]["detail"]["north"] == "magnetic" and ref[0]["detail"]["wmm_field"]
    traj = api.trajectory(res.session_id)  # geo-referenced when read: magnetic north turned by the declination
    assert traj["north"] == "true" and 3.0 < traj["declination_deg"] < 5.0


def test_a_recognised_pocket_is_an_event(client, make_user) -> None:  # type: ignore[no-untyped-def]
    _, tok = make_user()
    api = PednavClient(token=tok, http=client)
    res = PhoneSimulator(_rec("phone-pocket-walk")).run(api)
    kinds = [(e["kind"], e["detail"].get("placement")) for e in api.events(res.session_id)]
    assert ("placement_changed", "phone-pocket") in kinds


def test_known_distance_calibrates_the_users_profile(client, make_user) -> None:  # type: ignore[no-untyped-def]
    _, tok = make_user()
    api = PednavClient(token=tok, http=client)
    res = PhoneSimulator(_rec("phone-walk"), placement="phone-hand").run(api, close=False)
    sid = res.session_id
    walked = sum(p["step_length_m"] for p in res.positions)
    t0, t1 = res.positions[0]["t_ns"] - 1, res.positions[-1]["t_ns"]
    bad = client.post(f"/v1/sessions/{sid}/distance", json={"t0_ns": t1, "t1_ns": t0, "distance_m": 10.0}, headers=auth(tok))
    assert bad.status_code == 422 and "t1_ns" in bad.text
    none = client.post(f"/v1/sessions/{sid}/distance", json={"t0_ns": t1 + 1, "t1_ns": t1 + 2, "distance_m": 10.0},
                       headers=auth(tok))
    assert none.status_code == 422 and "steps" in none.text
    r = client.post(f"/v1/sessions/{sid}/distance", json={"t0_ns": t0, "t1_ns": t1, "distance_m": 1.2 * walked},
                    headers=auth(tok))
    assert r.status_code == 200, r.text
    assert r.json()["kind"] == "calibration" and r.json()["detail"]["placement"] == "phone-hand"
    api.close_session(sid)
    prof = client.get("/v1/profiles/pdr", headers=auth(tok)).json()
    k = prof["data"]["step_model"]["placements"]["phone-hand"]["k"]
    assert k > 0.45
    # the next phone session starts from it; a foot session does not get it
    again = PhoneSimulator(_rec("phone-walk"), placement="phone-hand").run(api)
    assert sum(p["step_length_m"] for p in again.positions) > 1.1 * walked
    foot = _start(client, tok, device_kind="foot").json()["id"]
    closed = client.post(f"/v1/sessions/{sid}/distance", json={"t0_ns": t0, "t1_ns": t1, "distance_m": 5.0}, headers=auth(tok))
    assert closed.status_code == 409
    r = client.post(f"/v1/sessions/{foot}/distance", json={"t0_ns": 0, "t1_ns": 10, "distance_m": 5.0}, headers=auth(tok))
    assert r.status_code == 422 and "foot" in r.text


def test_other_users_cannot_calibrate(client, make_user) -> None:  # type: ignore[no-untyped-def]
    _, tok = make_user()
    _, other = make_user()
    sid = _start(client, tok, device_kind="phone").json()["id"]
    r = client.post(f"/v1/sessions/{sid}/distance", json={"t0_ns": 0, "t1_ns": 10, "distance_m": 5.0}, headers=auth(other))
    assert r.status_code == 404


def test_reprocessing_a_phone_session_reproduces_it(client, make_user) -> None:  # type: ignore[no-untyped-def]
    _, tok = make_user()
    api = PednavClient(token=tok, http=client)
    res = PhoneSimulator(_rec("phone-pocket-walk")).run(api)
    out = api.reprocess(res.session_id)
    assert out["identical"] and out["engine"] == "energy.phone_engine.PhoneEngine"


def test_pdr_profile_is_validated_by_the_phone_engine(client, make_user) -> None:  # type: ignore[no-untyped-def]
    _, tok = make_user()
    good = {"step_model": {"placements": {"phone-hand": {"k": 0.5, "k_var": 0.001, "n_steps": 30, "distance_m": 20.0}}},
            "n_steps": 30, "calibrated": True}
    assert client.put("/v1/profiles/pdr", json={"data": good}, headers=auth(tok)).status_code == 200
    bad = {**good, "step_model": {"placements": {"phone-hand": {"k": -1.0, "k_var": 0.001}}}}
    r = client.put("/v1/profiles/pdr", json={"data": bad}, headers=auth(tok))
    assert r.status_code == 422 and "k" in r.text


def test_older_sessions_become_foot_sessions(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """Every session before revision 0008 ran the foot engine: that is the placement the migration gives them."""
    from server.db import make_engine, migrate
    from server.settings import Settings

    eng = make_engine(Settings(database_url=f"sqlite:///{tmp_path / 'old.db'}"))
    migrate(eng, "0006")
    with eng.begin() as conn:
        conn.execute(text("INSERT INTO users (id, name, is_admin, created_at) VALUES (1, 'u', 0, '2026-01-01')"))
        conn.execute(text("INSERT INTO sessions (user_id, device_kind, status, engine_mode, created_at, next_seq, behaviour, "
                          "mode, n_positions, version) VALUES (1, 'phone', 'open', 'auto', '2026-01-01', 0, 'stand', 'idle', 0, 0)"))
    migrate(eng)
    with eng.connect() as conn:
        assert conn.execute(text("SELECT placement FROM sessions")).scalar_one() == "foot"
    eng.dispose()


@lru_cache(maxsize=None)
def _pair(seed: int):  # type: ignore[no-untyped-def]
    from clients.evaluation.phone_watch import phone_and_watch

    return phone_and_watch(seed)


def test_a_phone_trajectory_fused_with_the_watch_of_the_same_walk(client, make_user) -> None:  # type: ignore[no-untyped-def]
    """``GET .../trajectory?fuse_with=`` (issue 26, 000 eq. 70): the phone's stored steps fused with the watch's
    session of the same user and clock, as :func:`models.step_fusion.fuse_track` fuses the two stored tracks; a
    companion without steps changes nothing; the refusals name ``fuse_with``."""
    import numpy as np

    from models.step_fusion import fuse_track

    phone_rec, watch_rec, _ = _pair(0)
    _, tok = make_user()
    api = PednavClient(token=tok, http=client)
    phone = PhoneSimulator(phone_rec, placement="phone-hand").run(api).session_id
    watch = WatchSimulator(watch_rec).run(api).session_id
    own, other = api.trajectory(phone), api.trajectory(watch)
    fused = api.trajectory(phone, fuse_with=watch)
    assert fused["fused_with"] == watch and len(fused["positions"]) == len(own["positions"])
    assert 0 < fused["blended_steps"] <= len(own["positions"])
    col = {k: np.array([p[k] for p in own["positions"]], dtype=float) for k in ("t_ns", "north", "east", "step_length_m", "heading_rad")}
    oc = {k: np.array([p[k] for p in other["positions"]], dtype=float) for k in ("t_ns", "step_length_m", "heading_rad")}
    n, e, length, heading, blended = fuse_track(col["north"], col["east"], col["t_ns"] * 1e-9, col["step_length_m"],
                                                col["heading_rad"], oc["t_ns"] * 1e-9, oc["step_length_m"], oc["heading_rad"])
    got = {k: np.array([p[k] for p in fused["positions"]], dtype=float) for k in ("north", "east", "step_length_m", "heading_rad")}
    assert np.allclose(got["north"], n, atol=1e-6) and np.allclose(got["east"], e, atol=1e-6)
    assert np.allclose(got["step_length_m"], length) and np.allclose(got["heading_rad"], heading)
    assert [p["blended"] for p in fused["positions"]] == blended.tolist() and int(blended.sum()) == fused["blended_steps"]
    assert "fuse_with" not in own and "blended" not in own["positions"][0]
    # a companion that has no steps yet: the phone's own track
    empty = _start(client, tok, device_kind="watch").json()["id"]
    alone = api.trajectory(phone, fuse_with=empty)
    assert alone["blended_steps"] == 0 and [p["north"] for p in alone["positions"]] == [p["north"] for p in own["positions"]]
    assert client.get(f"/v1/sessions/{phone}/trajectory", params={"fuse_with": watch, "format": "csv"},
                      headers=auth(tok)).status_code == 200
    # refusals: another user's session, the session itself, a foot session, an id beyond the column
    _, stranger = make_user()
    theirs = _start(client, stranger, device_kind="watch").json()["id"]
    r = client.get(f"/v1/sessions/{phone}/trajectory", params={"fuse_with": theirs}, headers=auth(tok))
    assert r.status_code == 404 and "fuse_with" in r.text
    r = client.get(f"/v1/sessions/{phone}/trajectory", params={"fuse_with": phone}, headers=auth(tok))
    assert r.status_code == 422 and "fuse_with" in r.text
    foot = _start(client, tok, device_kind="foot").json()["id"]
    r = client.get(f"/v1/sessions/{phone}/trajectory", params={"fuse_with": foot}, headers=auth(tok))
    assert r.status_code == 409 and "fuse_with" in r.text and "foot" in r.text
    r = client.get(f"/v1/sessions/{phone}/trajectory", params={"fuse_with": 2**40}, headers=auth(tok))
    assert r.status_code == 422 and "fuse_with" in r.text
