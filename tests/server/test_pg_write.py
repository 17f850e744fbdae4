"""PostgreSQL uploads: the write statement (server.upload._pg_write) stores the answer's positions and events
exactly (the positions are read by PostgreSQL from the answer's JSON text, so every float must come back as the
same double: signed zero, subnormals and the extremes included), and the uploads keep their pool connection from
one upload to the next."""

from __future__ import annotations

import json
import math
import struct
from typing import Any

import pytest
from sqlalchemy import text

from server import upload
from server.ingest import Fed
from tests.server.conftest import auth

AWKWARD = [0.1 + 0.2, -0.0, 5e-324, 2.2250738585072014e-308, 1.7976931348623157e308, -1e-300, 1 / 3, 123456.789e10]


def _bits(x: float) -> bytes:
    return struct.pack("<d", x)


def _fed(session_id: int, seq: int, positions: list[dict[str, Any]], events: list[dict[str, Any]]) -> Fed:
    resp = {"session_id": session_id, "seq": seq, "next_seq": seq + 1, "positions": positions, "events": events,
            "behaviour": "walking", "mode": "auto", "sensor_config": {"gyr_on": True}}
    raw = b"\x81\xa1v\x01"
    return Fed(resp, json.dumps(resp, allow_nan=False, separators=(",", ":")), raw, "0" * 64, None, 1, 1, 0)


def _position(k: int, x: float, step: float) -> dict[str, Any]:
    return {"t_ns": 1_700_000_000_000_000_000 + k, "north": x, "east": -x, "down": x / 7, "heading_rad": math.pi,
            "behaviour": "walking", "mode": "zupt", "step_length_m": step, "gyro_on": k % 2 == 0, "extra": 1}


def test_positions_and_events_stored_to_the_bit(backend, app, client, make_user) -> None:  # type: ignore[no-untyped-def]
    if backend != "postgresql":
        pytest.skip("PostgreSQL's write statement")
    _, tok = make_user()
    sid = client.post("/v1/sessions", json={"device_kind": "foot"}, headers=auth(tok)).json()["id"]
    batches = [
        [_position(k, x, 0.7 + k) for k, x in enumerate(AWKWARD)],
        [],  # no positions, no events
        [_position(99, 1.0, 0.5)],
    ]
    events = [[{"t_ns": 5, "kind": "stance", "detail": {"a": 1.5, "b": [1, "x"]}}], [], []]
    conn = app.state.db_engine.raw_connection()
    try:
        conn.driver_connection.autocommit = True
        cur = conn.cursor()
        cur.execute("SELECT version FROM sessions WHERE id = %s", (sid,))
        v0 = cur.fetchone()[0]
        for seq, (ps, es) in enumerate(zip(batches, events)):
            assert upload._pg_write(cur, sid, v0 + seq, seq, _fed(sid, seq, ps, es), {"gyr": None, "mag": None})
        assert not upload._pg_write(cur, sid, v0, 3, _fed(sid, 3, batches[2], []), {"gyr": None, "mag": None})
    finally:
        conn.driver_connection.autocommit = False
        conn.close()
    with app.state.db_engine.connect() as c:
        rows = c.execute(text("SELECT seq, t_ns, north, east, down, heading_rad, behaviour, mode, step_length_m, "
                              "gyro_on FROM positions WHERE session_id = :s ORDER BY id"), {"s": sid}).fetchall()
        ev = c.execute(text("SELECT seq, t_ns, kind, detail FROM events WHERE session_id = :s"), {"s": sid}).fetchall()
        n = c.execute(text("SELECT n_positions, next_seq FROM sessions WHERE id = :s"), {"s": sid}).one()
    want = [(seq, p["t_ns"], *map(_bits, (p["north"], p["east"], p["down"], p["heading_rad"])), p["behaviour"],
             p["mode"], _bits(p["step_length_m"]), p["gyro_on"]) for seq, ps in enumerate(batches) for p in ps]
    got = [(r[0], r[1], *map(_bits, r[2:6]), r[6], r[7], _bits(r[8]), r[9]) for r in rows]
    assert got == want
    assert [tuple(r) for r in ev] == [(0, 5, "stance", {"a": 1.5, "b": [1, "x"]})]
    assert tuple(n) == (len(want), 3)  # the failed version check (an old version) wrote nothing


def test_upload_connections_kept_between_uploads_and_returned(backend, app, client, make_user, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """Uploads on PostgreSQL keep their pool connection (autocommit) for the next upload instead of returning it
    each time; past ``_HOLD_S`` and at close it goes back to the pool, out of autocommit."""
    if backend != "postgresql":
        pytest.skip("PostgreSQL's upload connections")
    from server.formats import MSGPACK_TYPE, encode_msgpack
    from tests.server.conftest import still_batch

    up, pool = app.state.uploader, app.state.db_engine.pool
    up.close()
    _, tok = make_user()
    sid = client.post("/v1/sessions", json={"device_kind": "foot"}, headers=auth(tok)).json()["id"]

    def put(seq: int) -> None:
        body = encode_msgpack(still_batch(1_700_000_000_000_000_000 + seq * 10**9, seed=seq))
        r = client.put(f"/v1/sessions/{sid}/batches/{seq}", content=body,
                       headers={**auth(tok), "content-type": MSGPACK_TYPE})
        assert r.status_code == 200, r.text

    before = pool.checkedout()
    put(0)
    kept = list(up._idle)
    assert len(kept) == 1 and kept[0].driver_connection.autocommit
    for seq in (1, 2, 3):
        put(seq)
    assert up._idle == kept  # the same connection each time, no check-out from the pool
    assert pool.checkedout() == before + 1
    up.close()
    assert up._idle == [] and pool.checkedout() == before
    monkeypatch.setattr(upload, "_HOLD_S", 0.0)
    put(4)
    assert up._idle == [] and pool.checkedout() == before  # held too long: back to the pool after the upload
