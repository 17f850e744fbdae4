"""Per-user gait summary: step length, cadence and the heading deviation (latest and over time) read from the
engine's calibration events; per-user isolation."""

from __future__ import annotations

import pytest

from server.models import EventRecord, PositionRecord
from tests.server.conftest import auth

T0 = 1_700_000_000_000_000_000


def _session(client, tok: str) -> int:  # type: ignore[no-untyped-def]
    r = client.post("/v1/sessions", json={"device_kind": "foot"}, headers=auth(tok))
    assert r.status_code == 201
    return r.json()["id"]


def _store(app, sid: int, steps: int, events: list[tuple[int, str, dict]]) -> None:  # type: ignore[no-untyped-def,type-arg]
    with app.state.sessionmaker() as db:  # as the engine's answers would have been stored
        for i in range(steps):
            db.add(PositionRecord(session_id=sid, seq=i, t_ns=T0 + i * 500_000_000, north=0.7 * i, east=0.0, down=0.0,
                                  heading_rad=0.0, behaviour="walk", mode="pdr", step_length_m=0.7, gyro_on=False))
        for k, (t_s, kind, detail) in enumerate(events):
            db.add(EventRecord(session_id=sid, seq=k, t_ns=T0 + t_s * 10**9, kind=kind, detail=detail))
        db.commit()


def test_heading_deviation_comes_from_calibration_events(client, app, make_user) -> None:  # type: ignore[no-untyped-def]
    _, a = make_user()
    _, b = make_user()
    s1, s2, s3 = _session(client, a), _session(client, a), _session(client, a)
    _store(app, s1, 5, [
        (1, "mode_switch", {"to": "pdr"}),
        (2, "calibration_done", {"behaviour": "walk", "l_zupt_m": 30.0, "heading_deviation_rad": 0.12,
                                 "heading_deviation_var": 4e-4}),
        (3, "calibration_done", {"behaviour": "run", "heading_deviation_rad": None, "heading_deviation_var": None}),  # NaN
        (4, "calibration_done", {"behaviour": "walk", "heading_deviation_rad": 0.10, "heading_deviation_var": 2e-4}),
    ])
    _store(app, s2, 3, [(1, "calibration_done", {"behaviour": "walk", "l_zupt_m": 30.0})])  # an engine without it
    _store(app, s3, 3, [(1, "calibration_done", {"behaviour": "walk", "heading_deviation_rad": -0.05})])
    _store(app, _session(client, b), 4, [(1, "calibration_done", {"behaviour": "walk", "heading_deviation_rad": 9.9})])
    r = client.get("/v1/users/me/gait-summary", headers=auth(a))
    assert r.status_code == 200
    doc = r.json()
    by = {s["session_id"]: s for s in doc["sessions"]}
    assert set(by) == {s1, s2, s3}  # only the caller's sessions
    one = by[s1]
    assert one["heading_deviation_rad"] == pytest.approx(0.10) and one["heading_deviation_var"] == pytest.approx(2e-4)
    assert [(d["t_ns"], d["heading_deviation_rad"]) for d in one["heading_deviation"]] == [(T0 + 2 * 10**9, 0.12), (T0 + 4 * 10**9, 0.10)]
    assert one["heading_deviation"][0]["behaviour"] == "walk" and one["heading_deviation"][0]["event"] == "calibration_done"
    assert one["steps"] == 5 and one["mean_step_length_m"] == pytest.approx(0.7)
    assert one["cadence_steps_per_min"] == pytest.approx(120.0)
    assert by[s2]["heading_deviation_rad"] is None and by[s2]["heading_deviation"] == []
    assert by[s3]["heading_deviation_rad"] == pytest.approx(-0.05) and by[s3]["heading_deviation_var"] is None
    assert [(d["session_id"], d["heading_deviation_rad"]) for d in doc["heading_deviation_over_time"]] == [
        (s1, 0.12), (s1, 0.10), (s3, -0.05)]
    assert all(d["heading_deviation_rad"] != 9.9 for d in doc["heading_deviation_over_time"])  # not user b's


def test_gait_summary_refusals_and_empty(client, make_user) -> None:  # type: ignore[no-untyped-def]
    assert client.get("/v1/users/me/gait-summary").status_code == 401
    assert client.get("/v1/users/me/gait-summary", headers=auth("pn_wrong")).status_code == 401
    _, a = make_user()
    assert client.get("/v1/users/me/gait-summary", headers=auth(a)).json() == {"sessions": [], "heading_deviation_over_time": []}


def test_gait_summary_of_a_streamed_walk_matches_its_events(client, make_user) -> None:  # type: ignore[no-untyped-def]
    """End to end with the real engine: whatever heading-deviation estimates its calibration events carry are the
    summary's (the latest one is the session's figure)."""
    from clients.sdk import PednavClient
    from clients.simulators import FootSensorSimulator
    from clients.synth import synthesize

    _, tok = make_user()
    api = PednavClient(token=tok, http=client)
    res = FootSensorSimulator(synthesize("walk", seed=3)).run(api)
    events = api.events(res.session_id)
    finite = [e for e in events if isinstance(e["detail"].get("heading_deviation_rad"), float)]
    s = api.gait_summary()["sessions"][0]
    assert s["steps"] > 10 and 0.3 < s["mean_step_length_m"] < 2.0
    assert [d["heading_deviation_rad"] for d in s["heading_deviation"]] == [e["detail"]["heading_deviation_rad"] for e in finite]
    assert s["heading_deviation_rad"] == (finite[-1]["detail"]["heading_deviation_rad"] if finite else None)
