"""A write that loses every retry to a busy database (another worker holds the lock it needs past the wait) is
refused with 503, ``Retry-After`` and a detail saying nothing was stored (it was a 500 with no message); the
same request sent again once the database is free is applied exactly once. A lost connection stays a 500."""

from __future__ import annotations

from typing import Any

import pytest
from fastapi.testclient import TestClient

from server.formats import MSGPACK_TYPE, encode_msgpack
from server.models import TrackSession
from tests.server.conftest import app_with, auth, database_locked, short_lock_waits

_PARTS: list[Any] = []


def _part(seq: int) -> Any:
    """Batch ``seq``: 2 s of a synthetic walk (batch 3 is the first with positions and events)."""
    if not _PARTS:
        from clients.synth import synthesize

        _PARTS.extend(synthesize("walk", seed=7).batch.split_seconds(2.0))
    return _PARTS[seq]


def _put(c: TestClient, tok: str, sid: int, seq: int):  # type: ignore[no-untyped-def]
    return c.put(f"/v1/sessions/{sid}/batches/{seq}", content=encode_msgpack(_part(seq)),
                 headers={**auth(tok), "content-type": MSGPACK_TYPE})


def _stored(c: TestClient, tok: str, sid: int) -> tuple[Any, ...]:
    """Everything a batch upload writes: the session's sequence, version and counts, batches, positions, events."""
    s = c.get(f"/v1/sessions/{sid}", headers=auth(tok)).json()
    return (s["next_seq"], s["n_positions"], s["behaviour"], s["mode"],
            [{k: v for k, v in b.items() if k != "received_at"} for b in c.get(f"/v1/sessions/{sid}/batches", headers=auth(tok)).json()],
            c.get(f"/v1/sessions/{sid}/trajectory", headers=auth(tok)).json()["positions"],
            c.get(f"/v1/sessions/{sid}/events", headers=auth(tok)).json())


def _engine_state(app: Any, sid: int) -> tuple[int, bytes]:
    with app.state.sessionmaker() as db:
        s = db.get(TrackSession, sid)
        return s.version, s.engine_state


def _assert_busy(r: Any, what: str) -> None:
    assert r.status_code == 503, (r.status_code, r.text)
    assert r.headers["retry-after"].isdigit() and 1 <= int(r.headers["retry-after"]) <= 10, r.headers
    assert "database busy" in r.json()["detail"] and what in r.json()["detail"], r.json()


@pytest.mark.parametrize("path", ["driver-write", "orm-write"])
def test_an_upload_losing_every_retry_to_a_busy_database_is_503_and_stores_nothing(settings, backend, client, make_user,  # type: ignore[no-untyped-def]
                                                                                   path) -> None:
    """Another worker holds the lock the upload's write needs through all its attempts: 503 with Retry-After and
    a detail naming the batch as NOT stored (it was a 500), and nothing of it is stored (session, batches,
    positions, events, engine state). Sent again when the lock is gone: applied once, as if never refused (the
    same answer and engine state as a session that never met the lock), and a third time answered as a retry."""
    if backend == "sqlite" and path == "orm-write":
        pytest.skip("SQLite uploads always take the driver path (its ORM path: the Sensor Logger tests below)")
    _, tok = make_user()
    ref = client.post("/v1/sessions", json={"device_kind": "foot"}, headers=auth(tok)).json()["id"]
    ref_answers = [_put(client, tok, ref, seq).json() for seq in range(4)]
    sid = client.post("/v1/sessions", json={"device_kind": "foot"}, headers=auth(tok)).json()["id"]
    assert all(_put(client, tok, sid, seq).status_code == 200 for seq in range(3))
    before = _stored(client, tok, sid)
    with app_with(settings, pg_one_statement_writes=path == "driver-write") as (a, c):
        assert (a.state.uploader is not None) is (path == "driver-write")
        short_lock_waits(a)
        state = _engine_state(a, sid)
        with database_locked(settings, sid):
            r = _put(c, tok, sid, 3)
        _assert_busy(r, f"batch 3 of session {sid} was NOT stored")
        assert "same sequence number 3" in r.json()["detail"]
        assert _stored(client, tok, sid) == before and _engine_state(a, sid) == state
        r = _put(c, tok, sid, 3)  # the lock is gone: the same batch again
        assert r.status_code == 200 and r.headers["x-pednav-replayed"] == "false", r.text
        got = r.json()
        again = _put(c, tok, sid, 3)
        assert again.status_code == 200 and again.headers["x-pednav-replayed"] == "true" and again.json() == got
        assert _engine_state(a, sid)[1] == _engine_state(a, ref)[1]
    assert got["positions"] and got["events"]  # batch 3 writes rows of every kind
    assert {**got, "session_id": ref} == ref_answers[3]
    after = _stored(client, tok, sid)
    assert after[0] == 4 and [b["seq"] for b in after[4]] == [0, 1, 2, 3]
    assert after[1] == len(after[5]) == len(before[5]) + len(got["positions"])  # positions stored once
    assert len(after[6]) == len(before[6]) + len(got["events"])


def test_an_upload_whose_session_changes_under_every_attempt_is_503(settings, client, make_user, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """The fast path's other way to lose every retry: the session changed between its read and its write each
    time (another worker's close or re-processing, five times over): 503 as well, nothing stored."""
    from server import upload

    _, tok = make_user()
    sid = client.post("/v1/sessions", json={"device_kind": "foot"}, headers=auth(tok)).json()["id"]
    assert _put(client, tok, sid, 0).status_code == 200
    before = _stored(client, tok, sid)
    calls: list[int] = []

    def raced(self, cur, session_id, seq, batch, sess, *rest):  # type: ignore[no-untyped-def]
        calls.append(seq)
        raise upload._Raced()

    with monkeypatch.context() as m:
        m.setattr(upload.Uploader, "_apply", raced)
        r = _put(client, tok, sid, 1)
    assert len(calls) == 5
    _assert_busy(r, f"batch 1 of session {sid} was NOT stored")
    assert _stored(client, tok, sid) == before
    assert _put(client, tok, sid, 1).headers["x-pednav-replayed"] == "false"


@pytest.mark.parametrize("path", ["driver-write", "orm-write"])
def test_a_lost_database_connection_is_not_reported_as_busy(settings, backend, make_user, monkeypatch, path) -> None:  # type: ignore[no-untyped-def]
    """An error that is not contention (here: the connection to the database lost at the write) keeps its 500:
    whether a commit went through is not known then, so "NOT stored, send it again" would be a guess. (The same
    answer as before; this guards the line between the two.)"""
    import sqlite3

    import psycopg
    from sqlalchemy.exc import OperationalError

    from server import ingest, upload

    if backend == "sqlite" and path == "orm-write":
        pytest.skip("SQLite uploads always take the driver path")
    lost = (sqlite3.OperationalError("disk I/O error") if backend == "sqlite"
            else psycopg.OperationalError("consuming input failed: server closed the connection unexpectedly"))

    def fail(*_a: Any, **_kw: Any) -> Any:
        if path == "orm-write":
            raise OperationalError("UPDATE sessions ...", {}, lost)
        raise lost

    _, tok = make_user()
    with app_with(settings, pg_one_statement_writes=path == "driver-write") as (a, _):
        with TestClient(a, raise_server_exceptions=False) as c:
            sid = c.post("/v1/sessions", json={"device_kind": "foot"}, headers=auth(tok)).json()["id"]
            with monkeypatch.context() as m:
                if path == "orm-write":
                    m.setattr(ingest, "_apply_once", fail)
                elif backend == "sqlite":
                    m.setattr(upload.SqliteGroupWriter, "write", fail)
                else:
                    m.setattr(upload, "_pg_write", fail)
                r = _put(c, tok, sid, 0)
            assert r.status_code == 500 and "retry-after" not in r.headers, (r.status_code, r.text)
            assert _put(c, tok, sid, 0).status_code == 200  # and the next attempt goes through


# ---------------------------------------------------------------- Sensor Logger: the ORM path on both backends
T0 = 1_700_000_000_000_000_000
S = 10**9


def _items(t0: int, n: int = 200, dt: int = 10_000_000) -> list[dict[str, Any]]:
    out = []
    for k in range(n):
        t = t0 + k * dt
        out += [{"name": "totalacceleration", "time": t, "values": {"x": 0.01, "y": 0.0, "z": 9.81}},
                {"name": "gyroscope", "time": t, "values": {"x": 0.001, "y": 0.0, "z": 0.0}},
                {"name": "magnetometer", "time": t, "values": {"x": 20.0, "y": 0.0, "z": 40.0}}]
    return out


def _push(c: TestClient, tok: str, mid: int, t0: int, sl_id: str):  # type: ignore[no-untyped-def]
    return c.post("/v1/sensorlogger", json={"messageId": mid, "sessionId": sl_id, "deviceId": "d",
                                            "payload": _items(t0)}, headers=auth(tok))


def _messages(app: Any, sid: int) -> int:
    from sqlalchemy import func, select

    from server.models import SensorLoggerMessage

    with app.state.sessionmaker() as db:
        return db.execute(select(func.count()).select_from(SensorLoggerMessage)
                          .where(SensorLoggerMessage.session_id == sid)).scalar_one()


def _fed(c: TestClient, tok: str, sid: int) -> list[int]:
    """The accelerometer times of every batch fed to the session, in sequence order."""
    from server.formats import decode_batch

    out: list[int] = []
    for b in c.get(f"/v1/sessions/{sid}/batches", headers=auth(tok)).json():
        raw = c.get(f"/v1/sessions/{sid}/batches/{b['seq']}/raw", headers=auth(tok))
        out += decode_batch(raw.content, raw.headers["content-type"], 10**6, allow_empty=True).acc_t_ns.tolist()
    return out


def test_a_sensor_logger_push_meeting_a_busy_database_while_it_stores_is_503_and_stores_nothing(settings, make_user) -> None:  # type: ignore[no-untyped-def]
    """The push's message cannot be stored (another worker holds the lock past the wait): 503 with Retry-After
    and a detail naming the message as NOT stored (it was a 500); sent again later it is stored (not a
    duplicate) and fed once."""
    _, tok = make_user()
    with app_with(settings) as (a, c):
        short_lock_waits(a)
        sid = _push(c, tok, 0, T0, "busy-store").json()["session_id"]
        with database_locked(settings, sid):
            r = _push(c, tok, 1, T0 + 2 * S, "busy-store")
        _assert_busy(r, "message 1 was NOT stored")
        assert _messages(a, sid) == 1
        r = _push(c, tok, 1, T0 + 2 * S, "busy-store")
        assert r.status_code == 200 and r.json()["duplicate"] is False and r.json()["deferred"] is None, r.text
        assert _messages(a, sid) == 2
        assert c.post("/v1/sensorlogger/busy-store/flush", headers=auth(tok)).status_code == 200
        fed = _fed(c, tok, sid)
        assert fed == sorted(set(fed)) and len(fed) == 2 * 200


def test_a_sensor_logger_feed_losing_every_retry_is_deferred_and_the_flush_is_503(settings, make_user, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """The database turns busy after the push stored its message, while it feeds the held-back samples (through
    ``apply_batch``, the ORM path, which loses every retry): the message is stored, so the push is answered 200
    with ``deferred`` saying so, nothing fed (it was a 500 for a stored message). A flush meanwhile: 503 with
    Retry-After (nothing fed). Once the database is free the flush feeds every sample once."""
    from server.routers import sensorlogger

    _, tok = make_user()
    with app_with(settings) as (a, c):
        short_lock_waits(a)
        sid = _push(c, tok, 0, T0, "busy-feed").json()["session_id"]  # held back: nothing fed yet
        locks: list[Any] = []
        real = sensorlogger._feed

        def locked_first(db, user, *args, **kw):  # type: ignore[no-untyped-def]
            from tests.server.conftest import DatabaseLock

            locks.append(DatabaseLock(settings, sid))  # another worker takes the lock after the message's commit
            return real(db, user, *args, **kw)

        try:
            with monkeypatch.context() as m:
                m.setattr(sensorlogger, "_feed", locked_first)
                r = _push(c, tok, 1, T0 + 2 * S, "busy-feed")
            assert r.status_code == 200 and r.json()["duplicate"] is False, r.text
            assert r.json()["positions"] == [] and "database busy" in r.json()["deferred"], r.json()
            assert _messages(a, sid) == 2
            s = c.get(f"/v1/sessions/{sid}", headers=auth(tok)).json()
            assert (s["next_seq"], s["n_positions"]) == (0, 0)
            assert c.get(f"/v1/sessions/{sid}/batches", headers=auth(tok)).json() == []
            r = c.post("/v1/sensorlogger/busy-feed/flush", headers=auth(tok))
            _assert_busy(r, "not all fed")
            assert c.get(f"/v1/sessions/{sid}", headers=auth(tok)).json()["next_seq"] == 0
        finally:
            for lk in locks:
                lk.release()
        r = c.post("/v1/sensorlogger/busy-feed/flush", headers=auth(tok))
        assert r.status_code == 200 and r.json()["skipped"] is None, r.text
        fed = _fed(c, tok, sid)
        assert fed == sorted(set(fed)) and len(fed) == 2 * 200  # every sample of both messages, once
