"""Uploads after the worker's own commit of the session skip the read (server.upload.Uploader, notes): the token
is then checked in the write statement, and every refusal is the read path's (same status, same detail)."""

from __future__ import annotations

from typing import Any

import pytest

from server import upload
from server.formats import MSGPACK_TYPE, encode_msgpack
from tests.server.conftest import auth, still_batch

T0 = 1_700_000_000_000_000_000


def _put(client: Any, tok: str, sid: int, seq: int) -> Any:
    body = encode_msgpack(still_batch(T0 + seq * 10**9, seed=seq))
    headers = {**auth(tok), "content-type": MSGPACK_TYPE}
    return client.put(f"/v1/sessions/{sid}/batches/{seq}", content=body, headers=headers)


@pytest.fixture
def reads(app, monkeypatch) -> list[int]:  # type: ignore[no-untyped-def]
    """Counts the uploads' token-and-session reads (one entry per read)."""
    up = app.state.uploader
    seen: list[int] = []
    connect = up._connect

    class Cur:
        def __init__(self, cur: Any) -> None:
            self._cur = cur

        def __getattr__(self, name: str) -> Any:
            return getattr(self._cur, name)

        def execute(self, sql: str, *a: Any) -> Any:
            if sql == up._read_sql:
                seen.append(1)
            return self._cur.execute(sql, *a)

    class Conn:
        def __init__(self, conn: Any) -> None:
            self._conn = conn

        def __getattr__(self, name: str) -> Any:
            return getattr(self._conn, name)

        def cursor(self) -> Cur:
            return Cur(self._conn.cursor())

    monkeypatch.setattr(up, "_connect", lambda: Conn(connect()))
    monkeypatch.setattr(up, "_release", lambda conn: type(up)._release(up, conn._conn))
    return seen


def test_the_next_batch_skips_the_read_and_answers_the_same(  # type: ignore[no-untyped-def]
        client, make_user, reads) -> None:
    _, tok = make_user()
    sid = client.post("/v1/sessions", json={"device_kind": "foot"}, headers=auth(tok)).json()["id"]
    answers = [_put(client, tok, sid, k) for k in range(4)]
    assert [r.status_code for r in answers] == [200] * 4
    assert len(reads) == 1  # only the first batch read the token and the session
    assert [r.json()["next_seq"] for r in answers] == [1, 2, 3, 4]
    r = _put(client, tok, sid, 3)  # a retry: read, answered from the stored batch
    assert r.status_code == 200 and r.headers["x-pednav-replayed"] == "true" and r.json() == answers[3].json()
    assert _put(client, tok, sid, 6).status_code == 409  # a gap: read, refused as before
    assert _put(client, tok, sid, 4).status_code == 200
    assert client.get(f"/v1/sessions/{sid}", headers=auth(tok)).json()["next_seq"] == 5


def test_a_revoked_token_is_refused_after_its_own_commit(  # type: ignore[no-untyped-def]
        client, make_user, reads) -> None:
    _, tok = make_user()
    dev = client.post("/v1/tokens", headers=auth(tok)).json()["token"]
    sid = client.post("/v1/sessions", json={"device_kind": "foot"}, headers=auth(dev)).json()["id"]
    assert _put(client, dev, sid, 0).status_code == 200
    assert _put(client, dev, sid, 1).status_code == 200
    assert client.delete("/v1/tokens/current", headers=auth(dev)).status_code in (200, 204)
    r = _put(client, dev, sid, 2)  # no read: the write's token check fails, nothing stored, then the read's 401
    assert r.status_code == 401 and r.json()["detail"] == "token revoked"
    assert client.get(f"/v1/sessions/{sid}", headers=auth(tok)).json()["next_seq"] == 2
    assert _put(client, tok, sid, 2).status_code == 200  # the user's other token goes on from the stored state
    assert _put(client, tok, sid, 3).status_code == 200


def test_a_session_closed_meanwhile_is_refused_as_closed(client, make_user) -> None:  # type: ignore[no-untyped-def]
    _, tok = make_user()
    sid = client.post("/v1/sessions", json={"device_kind": "foot"}, headers=auth(tok)).json()["id"]
    assert _put(client, tok, sid, 0).status_code == 200
    assert client.post(f"/v1/sessions/{sid}/close", headers=auth(tok)).status_code == 200
    r = _put(client, tok, sid, 1)
    assert r.status_code == 409 and "closed" in r.json()["detail"]


def test_a_deleted_session_is_not_found(client, make_user) -> None:  # type: ignore[no-untyped-def]
    _, tok = make_user()
    sid = client.post("/v1/sessions", json={"device_kind": "foot"}, headers=auth(tok)).json()["id"]
    assert _put(client, tok, sid, 0).status_code == 200
    assert client.delete(f"/v1/sessions/{sid}", headers=auth(tok)).status_code in (200, 204)
    assert _put(client, tok, sid, 1).status_code == 404


def test_the_known_sessions_are_bounded(app) -> None:  # type: ignore[no-untyped-def]
    up = app.state.uploader
    old = up.known_max
    try:
        up.known_max = 3
        for sid in range(10):
            up._keep(10**9 + sid, upload._Known("h", 1, None, upload._Session(1, 1, "open", None, None)))
        assert len(up._known) <= 3 and 10**9 + 9 in up._known
    finally:
        up.known_max = old
        with up._known_lock:
            for sid in range(10):
                up._known.pop(10**9 + sid, None)
