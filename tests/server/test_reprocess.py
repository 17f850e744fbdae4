"""POST /v1/sessions/{id}/reprocess: the same engine reproduces the stored trajectory exactly, a newer engine
replaces it atomically, the session continues correctly afterwards, and refusals change nothing."""

from __future__ import annotations

import math

import dataclasses
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import pytest
from fastapi.testclient import TestClient
from sqlalchemy import update

from energy.engine import Engine
from models.batch import BatchError
from server.app import create_app
from server.formats import MSGPACK_TYPE, encode_msgpack
from server.models import TrackSession
from tests.server.conftest import auth, still_batch

T0 = 1_700_000_000_000_000_000


def _put(c: TestClient, tok: str, sid: int, seq: int, seed: int = 7):  # type: ignore[no-untyped-def]
    b = still_batch(T0 + seq * 10**9, seed=seed * 1000 + seq)
    return c.put(f"/v1/sessions/{sid}/batches/{seq}", content=encode_msgpack(b),
                 headers={**auth(tok), "content-type": MSGPACK_TYPE})


def _snapshot(c: TestClient, app: Any, tok: str, sid: int) -> tuple[Any, ...]:
    traj = c.get(f"/v1/sessions/{sid}/trajectory", headers=auth(tok)).json()["positions"]
    ev = c.get(f"/v1/sessions/{sid}/events", headers=auth(tok)).json()
    with app.state.sessionmaker() as db:
        s = db.get(TrackSession, sid)
        return traj, ev, s.engine_state, s.version, s.n_positions


def _still_session(c: TestClient, tok: str, n: int = 4) -> int:
    sid = c.post("/v1/sessions", json={"device_kind": "foot"}, headers=auth(tok)).json()["id"]
    for k in range(n):
        assert _put(c, tok, sid, k).status_code == 200
    return sid


@pytest.fixture(scope="module")
def walked(client, make_user):  # type: ignore[no-untyped-def]
    """A closed session of a synthetic walk (stand, walk, turns; ZUPT-KF and Gait-DR) streamed through the API."""
    from clients.sdk import PednavClient
    from clients.simulators import FootSensorSimulator
    from clients.synth import synthesize

    _, tok = make_user()
    res = FootSensorSimulator(synthesize("walk", seed=3)).run(PednavClient(token=tok, http=client))
    assert len(res.positions) > 5
    return tok, res.session_id


def test_unchanged_engine_reproduces_the_closed_session_exactly(client, app, walked) -> None:  # type: ignore[no-untyped-def]
    tok, sid = walked
    before = _snapshot(client, app, tok, sid)
    profiles = client.get("/v1/profiles/walk/history", headers=auth(tok)).json()
    r = client.post(f"/v1/sessions/{sid}/reprocess", headers=auth(tok))
    assert r.status_code == 200, r.text
    out = r.json()
    assert out["identical"] is True and out["max_shift_m"] == 0.0 and out["stored"] is True
    assert out["positions_before"] == out["positions_after"] == len(before[0]) > 5
    assert out["batches"] == client.get(f"/v1/sessions/{sid}", headers=auth(tok)).json()["next_seq"]
    assert out["engine"] == "energy.engine.Engine" and out["engine_mode"] == "auto"
    after = _snapshot(client, app, tok, sid)
    assert after[0] == before[0]  # every position field, bit for bit
    assert after[1] == before[1]  # events
    assert after[2] == before[2]  # engine state bytes
    assert after[3] == before[3] + 1 and after[4] == before[4]
    s = client.get(f"/v1/sessions/{sid}", headers=auth(tok)).json()
    assert s["reprocess_count"] >= 1 and s["reprocessed_at"] is not None and s["status"] == "closed"
    assert client.get("/v1/profiles/walk/history", headers=auth(tok)).json() == profiles  # profiles untouched


def test_open_session_continues_exactly_after_reprocessing(client, app, make_user) -> None:  # type: ignore[no-untyped-def]
    _, tok = make_user()
    ref = _still_session(client, tok, 3)
    sid = _still_session(client, tok, 3)
    r = client.post(f"/v1/sessions/{sid}/reprocess", headers=auth(tok))
    assert r.status_code == 200 and r.json()["identical"] is True
    for k in (3, 4):
        a, b = _put(client, tok, ref, k).json(), _put(client, tok, sid, k).json()
        a.pop("session_id"), b.pop("session_id")
        assert a == b
    assert _snapshot(client, app, tok, sid)[0] == _snapshot(client, app, tok, ref)[0]
    with app.state.sessionmaker() as db:
        assert db.get(TrackSession, sid).engine_state == db.get(TrackSession, ref).engine_state
    # a retried old upload still gets its original answer and changes nothing
    again = _put(client, tok, sid, 1)
    assert again.status_code == 200 and again.headers["x-pednav-replayed"] == "true"


def test_returning_user_with_a_null_in_the_profile_is_reprocessed(client, app, make_user) -> None:  # type: ignore[no-untyped-def]
    """A stored profile holds null for each NaN float (JSON has none). Uploads hand the engine the profile through
    engine_profile_from_stored (null -> NaN); re-processing handed it the stored form, and float(None) in
    GaitPipeline.load_calibration answered 500 for every session started on such a profile."""
    _, tok = make_user()
    cal = {"step_model": {"kind": "test", "a": 0.7}, "sigma_d_m": None, "heading_deviation_rad": 0.1,
           "heading_deviation_var": None, "n_steps": 40, "calibrated": True}
    assert client.put("/v1/profiles/walk", json={"data": cal}, headers=auth(tok)).status_code == 200
    sid = _still_session(client, tok, 3)
    for dry in (True, False):
        r = client.post(f"/v1/sessions/{sid}/reprocess", json={"dry_run": dry}, headers=auth(tok))
        assert r.status_code == 200, r.text
        assert r.json()["identical"] is True and r.json()["stored"] is not dry


class ShiftedEngine(Engine):
    """A "newer engine": every position 1 m further north."""

    def _shift(self, upd: Any) -> Any:
        return dataclasses.replace(upd, positions=[dataclasses.replace(p, north=p.north + 1.0) for p in upd.positions])

    def feed(self, batch: Any) -> Any:
        return self._shift(super().feed(batch))

    def flush(self) -> Any:
        return self._shift(super().flush())


@contextmanager
def _other_app(settings: Any, engine_cls: type) -> Iterator[TestClient]:
    """A client of a second app instance on the same database whose sessions run ``engine_cls``."""
    app2 = create_app(settings.model_copy(update={"migrate_on_startup": False}), engine_cls=engine_cls)
    try:
        with TestClient(app2) as c2:
            yield c2
    finally:
        app2.state.db_engine.dispose()


def test_newer_engine_replaces_the_trajectory_and_dry_run_stores_nothing(settings, client, app, make_user) -> None:  # type: ignore[no-untyped-def]
    from clients.sdk import PednavClient
    from clients.simulators import FootSensorSimulator
    from clients.synth import synthesize

    _, tok = make_user()
    sid = FootSensorSimulator(synthesize("walk", seed=4)).run(PednavClient(token=tok, http=client)).session_id
    before = _snapshot(client, app, tok, sid)
    with _other_app(settings, ShiftedEngine) as c2:
        dry = c2.post(f"/v1/sessions/{sid}/reprocess", json={"dry_run": True}, headers=auth(tok)).json()
        assert dry["stored"] is False and dry["identical"] is False and dry["max_shift_m"] == pytest.approx(1.0)
        assert _snapshot(client, app, tok, sid) == before  # nothing stored
        r = c2.post(f"/v1/sessions/{sid}/reprocess", json={}, headers=auth(tok))
        assert r.status_code == 200, r.text
        assert r.json()["engine"].endswith("ShiftedEngine") and r.json()["stored"] is True
    shifted = _snapshot(client, app, tok, sid)[0]
    assert len(shifted) == len(before[0])
    for a, b in zip(before[0], shifted):  # 1 m north in the engine's frame, served turned onto magnetic north
        assert math.hypot(b["north"] - a["north"], b["east"] - a["east"]) == pytest.approx(1.0, abs=1e-9)
        moved = ("north", "east")
        assert {k: v for k, v in a.items() if k not in moved} == {k: v for k, v in b.items() if k not in moved}
    # and back with the server's own engine: the original trajectory again
    assert client.post(f"/v1/sessions/{sid}/reprocess", headers=auth(tok)).json()["identical"] is False
    back = _snapshot(client, app, tok, sid)
    assert back[0] == before[0] and back[2] == before[2]


def test_engine_mode_can_be_chosen(client, app, make_user) -> None:  # type: ignore[no-untyped-def]
    _, tok = make_user()
    sid = _still_session(client, tok, 3)
    from clients.sdk import PednavClient

    assert PednavClient(token=tok, http=client).reprocess(sid, engine_mode="zupt")["engine_mode"] == "zupt"
    assert _put(client, tok, sid, 3).status_code == 200  # the session goes on with its new engine
    with app.state.sessionmaker() as db:
        assert db.get(TrackSession, sid).engine_mode == "zupt"


def test_reprocess_refusals_name_the_problem(client, app, make_user) -> None:  # type: ignore[no-untyped-def]
    _, owner = make_user()
    _, other = make_user()
    sid = _still_session(client, owner, 3)
    before = _snapshot(client, app, owner, sid)
    assert client.post(f"/v1/sessions/{sid}/reprocess").status_code == 401
    r = client.post(f"/v1/sessions/{sid}/reprocess", headers=auth(other))  # another user's session: not found
    assert r.status_code == 404 and "not found" in r.json()["detail"]
    assert client.post("/v1/sessions/999999999/reprocess", headers=auth(owner)).status_code == 404
    r = client.post(f"/v1/sessions/{sid}/reprocess", json={"engine_mode": "fast"}, headers=auth(owner))
    assert r.status_code == 422 and r.json()["field"] == "engine_mode"
    r = client.post(f"/v1/sessions/{sid}/reprocess", json={"dryrun": True}, headers=auth(owner))
    assert r.status_code == 422 and r.json()["field"] == "dryrun"
    assert _snapshot(client, app, owner, sid) == before


class RefusingEngine(Engine):
    """A newer engine that refuses the second stored batch."""

    fed = 0

    def feed(self, batch: Any) -> Any:
        RefusingEngine.fed += 1
        if RefusingEngine.fed == 2:
            raise BatchError("acc", "rejected by the newer engine")
        return super().feed(batch)


def test_refused_stored_batch_is_409_and_changes_nothing(settings, client, app, make_user) -> None:  # type: ignore[no-untyped-def]
    _, tok = make_user()
    sid = _still_session(client, tok, 3)
    before = _snapshot(client, app, tok, sid)
    RefusingEngine.fed = 0
    with _other_app(settings, RefusingEngine) as c2:
        r = c2.post(f"/v1/sessions/{sid}/reprocess", headers=auth(tok))
    assert r.status_code == 409 and "stored batch 1" in r.json()["detail"] and "acc" in r.json()["detail"]
    assert _snapshot(client, app, tok, sid) == before


def test_upload_during_reprocessing_is_409_and_changes_nothing(settings, client, app, make_user) -> None:  # type: ignore[no-untyped-def]
    _, tok = make_user()
    sid = _still_session(client, tok, 3)
    db_engine = app.state.db_engine

    class Interrupted(Engine):
        """Another worker commits to the session while this re-processing is running."""

        def feed(self, batch: Any) -> Any:
            with db_engine.begin() as conn:
                conn.execute(update(TrackSession.__table__).where(TrackSession.__table__.c.id == sid)
                             .values(version=TrackSession.__table__.c.version + 1))
            return super().feed(batch)

    before = _snapshot(client, app, tok, sid)
    with _other_app(settings, Interrupted) as c2:
        r = c2.post(f"/v1/sessions/{sid}/reprocess", headers=auth(tok))
    assert r.status_code == 409 and "retry" in r.json()["detail"]
    after = _snapshot(client, app, tok, sid)
    assert after[:3] == before[:3] and after[4] == before[4]  # only the (simulated) other worker's version bump


def test_failure_while_writing_keeps_the_old_trajectory(client, app, make_user, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    import server.reprocess as rp

    _, tok = make_user()
    sid = _still_session(client, tok, 3)
    before = _snapshot(client, app, tok, sid)

    def broken(db: Any, positions: Any, events: Any) -> None:
        raise RuntimeError("disk full (simulated) after the old trajectory was deleted")

    monkeypatch.setattr(rp, "store_rows", broken)
    with pytest.raises(RuntimeError):
        client.post(f"/v1/sessions/{sid}/reprocess", headers=auth(tok))
    monkeypatch.undo()
    assert _snapshot(client, app, tok, sid) == before  # the delete was rolled back with the rest
    assert client.post(f"/v1/sessions/{sid}/reprocess", headers=auth(tok)).json()["identical"] is True
