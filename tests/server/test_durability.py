"""Durability: restart in the middle of a session continues it exactly; concurrent workers never apply a
batch twice."""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

import pytest
from fastapi.testclient import TestClient

from energy.engine import Engine
from server.app import create_app
from server.formats import MSGPACK_TYPE, encode_msgpack
from server.ingest import IngestConflict, apply_batch
from server.models import TrackSession
from server.statecodec import held_batches, pack_state
from tests.server.conftest import auth, still_batch

T0 = 1_700_000_000_000_000_000


def _put(c: TestClient, tok: str, sid: int, seq: int, seed: int):  # type: ignore[no-untyped-def]
    b = still_batch(T0 + seq * 10**9, seed=seed * 1000 + seq)
    return c.put(f"/v1/sessions/{sid}/batches/{seq}", content=encode_msgpack(b),
                 headers={**auth(tok), "content-type": MSGPACK_TYPE})


@pytest.mark.parametrize("cut", [1, 3])
def test_restart_in_the_middle_continues_exactly(settings, client, make_user, cut) -> None:  # type: ignore[no-untyped-def]
    _, tok = make_user()
    n = 5
    ref = client.post("/v1/sessions", json={"device_kind": "foot"}, headers=auth(tok)).json()["id"]
    ref_resp = [_put(client, tok, ref, i, seed=1).json() for i in range(n)]
    sid = client.post("/v1/sessions", json={"device_kind": "foot"}, headers=auth(tok)).json()["id"]
    got = [_put(client, tok, sid, i, seed=1).json() for i in range(cut)]
    app2 = create_app(settings)  # a new process: empty engine cache, same database
    try:
        with TestClient(app2) as c2:
            got += [_put(c2, tok, sid, i, seed=1).json() for i in range(cut, n)]
            with app2.state.sessionmaker() as db:
                a, b = db.get(TrackSession, ref), db.get(TrackSession, sid)
                assert a.engine_state == b.engine_state  # bit-identical engine state
    finally:
        app2.state.db_engine.dispose()
    for x, y in zip(ref_resp, got):
        x.pop("session_id"), y.pop("session_id")
    assert got == ref_resp


def test_two_workers_never_apply_the_same_batch_twice(settings, client, make_user) -> None:  # type: ignore[no-untyped-def]
    _, tok = make_user()
    sid = client.post("/v1/sessions", json={"device_kind": "foot"}, headers=auth(tok)).json()["id"]
    apps = [create_app(settings.model_copy(update={"migrate_on_startup": False})) for _ in range(2)]
    clients = [TestClient(a) for a in apps]
    results: list[tuple[int, str, dict]] = []  # type: ignore[type-arg]
    try:
        for seq in range(4):
            barrier = threading.Barrier(4)

            def send(c: TestClient, seq: int = seq) -> None:
                barrier.wait()
                r = _put(c, tok, sid, seq, seed=2)
                results.append((r.status_code, r.headers.get("x-pednav-replayed", ""), r.json()))

            threads = [threading.Thread(target=send, args=(clients[i % 2],)) for i in range(4)]
            for t in threads:
                t.start()
            for t in threads:
                t.join()
    finally:
        for a in apps:
            a.state.db_engine.dispose()
    assert all(code == 200 for code, _, _ in results), results
    assert sum(1 for _, rep, _ in results if rep == "false") == 4  # each sequence applied exactly once
    batches = client.get(f"/v1/sessions/{sid}/batches", headers=auth(tok)).json()
    assert [b["seq"] for b in batches] == [0, 1, 2, 3]
    by_seq: dict[int, list[dict]] = {}  # type: ignore[type-arg]
    for _, _, body in results:
        by_seq.setdefault(body["seq"], []).append(body)
    assert all(all(b == group[0] for b in group) for group in by_seq.values())



@pytest.mark.parametrize("one_statement", [True, False], ids=["driver-write", "orm-write"])
def test_two_workers_given_other_batches_under_one_seq_apply_exactly_one(settings, backend, client, make_user,  # type: ignore[no-untyped-def]
                                                                         one_statement) -> None:
    """Uploads of different batches under the same number at once, through two workers (only the database orders
    them): one is applied and answered 200, every other one 409 with the expected number and nothing of it
    stored; the session goes on at the next number."""
    from server.formats import canonical_bytes

    if backend == "sqlite" and not one_statement:
        pytest.skip("SQLite uploads always take the driver path")
    _, tok = make_user()
    sid = client.post("/v1/sessions", json={"device_kind": "foot"}, headers=auth(tok)).json()["id"]
    upd = {"migrate_on_startup": False, "pg_one_statement_writes": one_statement}
    apps = [create_app(settings.model_copy(update=upd)) for _ in range(2)]
    clients = [TestClient(a) for a in apps]
    try:
        for seq in range(3):
            barrier = threading.Barrier(4)
            results: dict[int, tuple[int, dict]] = {}  # type: ignore[type-arg]

            def send(k: int, seq: int = seq) -> None:
                barrier.wait()
                r = _put(clients[k % 2], tok, sid, seq, seed=10 + k)
                results[k] = (r.status_code, r.json())

            threads = [threading.Thread(target=send, args=(k,)) for k in range(4)]
            for t in threads:
                t.start()
            for t in threads:
                t.join()
            won = [k for k, (code, _) in results.items() if code == 200]
            assert len(won) == 1, results
            assert all(body["expected_seq"] == seq + 1 for code, body in results.values() if code != 200), results
            raw = client.get(f"/v1/sessions/{sid}/batches/{seq}/raw", headers=auth(tok)).content
            assert raw == canonical_bytes(still_batch(T0 + seq * 10**9, seed=(10 + won[0]) * 1000 + seq))
    finally:
        for a in apps:
            a.state.db_engine.dispose()
    assert [b["seq"] for b in client.get(f"/v1/sessions/{sid}/batches", headers=auth(tok)).json()] == [0, 1, 2]
    assert client.get(f"/v1/sessions/{sid}", headers=auth(tok)).json()["next_seq"] == 3

def test_engine_helper_process_gives_identical_results(settings, client, make_user) -> None:  # type: ignore[no-untyped-def]
    from clients.sdk import PednavClient
    from clients.simulators import FootSensorSimulator
    from clients.synth import synthesize

    rec = synthesize("walk", seed=5)
    _, tok = make_user()
    _, tok2 = make_user()  # another user: closing the first session stores a calibration profile for its user
    ref = FootSensorSimulator(rec).run(PednavClient(token=tok, http=client))  # engine in this process
    prof = client.get("/v1/profiles/walk", headers=auth(tok))
    assert prof.status_code == 200 and prof.json()["source"] == f"session:{ref.session_id}"  # learned at close
    app2 = create_app(settings.model_copy(update={"engine_processes": 1, "migrate_on_startup": False}))
    try:
        assert app2.state.host.pool is not None
        with TestClient(app2) as c2:
            got = FootSensorSimulator(rec).run(PednavClient(token=tok2, http=c2))  # engine in a helper process
        with app2.state.sessionmaker() as db:
            assert db.get(TrackSession, ref.session_id).engine_state == db.get(TrackSession, got.session_id).engine_state
    finally:
        app2.state.host.pool.shutdown()
        app2.state.db_engine.dispose()
    assert len(got.positions) > 5
    strip = lambda rs: [{k: v for k, v in r.items() if k != "session_id"} for r in rs]  # noqa: E731
    assert strip(got.responses) == strip(ref.responses)
    assert got.positions == ref.positions


def test_postgresql_one_statement_write_stores_what_the_transactional_write_stores(settings, backend, make_user) -> None:  # type: ignore[no-untyped-def]
    """PostgreSQL uploads write session, raw batch, positions and events in one statement (autocommit); the
    stored rows equal those of the multi-statement transaction."""
    if backend != "postgresql":
        pytest.skip("PostgreSQL only")
    from clients.sdk import PednavClient
    from clients.simulators import FootSensorSimulator
    from clients.synth import synthesize

    rec = synthesize("walk", seed=6)
    out = []
    for flag in (True, False):
        a = create_app(settings.model_copy(update={"migrate_on_startup": False, "pg_one_statement_writes": flag}))
        try:
            assert (a.state.uploader is not None) is flag
            _, tok = make_user()
            with TestClient(a) as c:
                api = PednavClient(token=tok, http=c)
                sid = FootSensorSimulator(rec).run(api, close=False).session_id
                traj = api.trajectory(sid)["positions"]
                ev = [{k: v for k, v in e.items()} for e in api.events(sid)]
                batches = [{k: v for k, v in b.items() if k != "received_at"} for b in api._json("GET", f"/v1/sessions/{sid}/batches")]
                again = c.put(f"/v1/sessions/{sid}/batches/3", content=api.request(
                    "GET", f"/v1/sessions/{sid}/batches/3/raw").content, headers={**auth(tok), "content-type": MSGPACK_TYPE})
                assert again.status_code == 200 and again.headers["x-pednav-replayed"] == "true"
            with a.state.sessionmaker() as db:
                s = db.get(TrackSession, sid)
                out.append((traj, ev, batches, s.engine_state, s.n_positions, s.next_seq, s.sensor_config, s.mode))
        finally:
            a.state.db_engine.dispose()
    assert len(out[0][0]) > 5 and any(out[0][1])
    assert out[0] == out[1]


class _OvertakenEngine(Engine):
    """The engine of a worker whose upload another worker overtakes: while it takes the batch (after the worker
    read the session, before it writes), the next action of :attr:`meanwhile` runs once."""

    meanwhile: list[Callable[[], Any]] = []

    def feed(self, batch: Any) -> Any:
        upd = super().feed(batch)
        if type(self).meanwhile:
            type(self).meanwhile.pop()()
        return upd


def _overtaken_upload(settings, client, tok: str, uid: int, sid: int, seq: int, path: str,  # type: ignore[no-untyped-def]
                      meanwhile: Callable[[], Any]) -> tuple[int, dict[str, Any]]:
    """Upload ``seq`` through a second worker (``path``: its driver write, its ORM write, or ``apply_batch``
    itself) while ``meanwhile`` runs between its read of the session and its write; (status, answer)."""
    upd = {"migrate_on_startup": False, "pg_one_statement_writes": path != "orm-write"}
    a = create_app(settings.model_copy(update=upd), engine_cls=_OvertakenEngine)
    _OvertakenEngine.meanwhile[:] = [meanwhile]
    try:
        if path == "apply_batch":
            with a.state.sessionmaker() as db:
                try:
                    resp, _ = apply_batch(db, a.state.host, uid, sid, seq, still_batch(T0 + seq * 10**9, seed=3000 + seq))
                except IngestConflict as exc:
                    return 409, {"detail": exc.message, "expected_seq": exc.expected_seq}
                return 200, resp
        with TestClient(a) as c2:
            r = _put(c2, tok, sid, seq, seed=3)
            return r.status_code, r.json()
    finally:
        assert _OvertakenEngine.meanwhile == []  # it did run in between
        a.state.db_engine.dispose()


_PATHS = pytest.mark.parametrize("path", ["driver-write", "orm-write", "apply_batch"])


@_PATHS
def test_upload_overtaken_by_a_close_is_refused_as_closed(settings, backend, client, make_user, path) -> None:  # type: ignore[no-untyped-def]
    """Another worker closes the session between an upload's read of the session and its write: the upload is
    refused with 409 naming the closed session (it was "sequence N is in the past; expected N"), nothing of it
    is stored, and everything accepted before it stays."""
    if backend == "sqlite" and path == "orm-write":
        pytest.skip("SQLite uploads always take the driver path")
    uid, tok = make_user()
    sid = client.post("/v1/sessions", json={"device_kind": "foot"}, headers=auth(tok)).json()["id"]
    assert all(_put(client, tok, sid, seq, seed=3).status_code == 200 for seq in range(2))
    batches = client.get(f"/v1/sessions/{sid}/batches", headers=auth(tok)).json()
    closed: list[Any] = []
    code, body = _overtaken_upload(settings, client, tok, uid, sid, 2, path, lambda: closed.append(
        client.post(f"/v1/sessions/{sid}/close", headers=auth(tok))))
    assert closed[0].status_code == 200, (path, closed[0].text)
    assert (code, body) == (409, {"detail": f"session {sid} is closed; no more batches accepted",
                                  "expected_seq": 2}), path
    assert client.get(f"/v1/sessions/{sid}/batches", headers=auth(tok)).json() == batches  # seq 2 not stored
    s = client.get(f"/v1/sessions/{sid}", headers=auth(tok)).json()
    assert (s["status"], s["next_seq"], s["n_positions"]) == ("closed", 2, closed[0].json()["n_positions"])
    # a stale sequence number on an open session keeps its own refusal
    other = client.post("/v1/sessions", json={"device_kind": "foot"}, headers=auth(tok)).json()["id"]
    assert _put(client, tok, other, 0, seed=3).status_code == 200
    r = _put(client, tok, other, 0, seed=4)
    assert (r.status_code, r.json()["detail"]) == (409, "sequence 0 was already used by a different batch; expected sequence 1")


@_PATHS
def test_upload_overtaken_by_a_reprocessing_is_applied(settings, backend, client, make_user, path) -> None:  # type: ignore[no-untyped-def]
    """Another worker re-processes the (open) session between an upload's read and its write: the session's
    version moved but its sequence did not, so the upload reads the session again and is applied on the
    re-processed state (it was refused: "sequence N is in the past; expected N")."""
    if backend == "sqlite" and path == "orm-write":
        pytest.skip("SQLite uploads always take the driver path")
    uid, tok = make_user()
    sid = client.post("/v1/sessions", json={"device_kind": "foot"}, headers=auth(tok)).json()["id"]
    assert all(_put(client, tok, sid, seq, seed=3).status_code == 200 for seq in range(2))
    done: list[Any] = []
    code, body = _overtaken_upload(settings, client, tok, uid, sid, 2, path, lambda: done.append(
        client.post(f"/v1/sessions/{sid}/reprocess", headers=auth(tok))))
    assert done[0].status_code == 200 and done[0].json()["stored"] is True, (path, done[0].text)
    assert code == 200 and body["seq"] == 2 and body["next_seq"] == 3, (path, body)
    assert [b["seq"] for b in client.get(f"/v1/sessions/{sid}/batches", headers=auth(tok)).json()] == [0, 1, 2]
    assert _put(client, tok, sid, 2, seed=3).headers["x-pednav-replayed"] == "true"  # applied once


def _walk_batches(n: int) -> list[Any]:
    from clients.synth import synthesize

    return synthesize("walk", seed=7).batch.split_seconds(1.0)[:n]


def _put_batch(c: TestClient, tok: str, sid: int, seq: int, b: Any):  # type: ignore[no-untyped-def]
    return c.put(f"/v1/sessions/{sid}/batches/{seq}", content=encode_msgpack(b),
                 headers={**auth(tok), "content-type": MSGPACK_TYPE})


def _session_run(c: TestClient, tok: str, sid: int, bs: list[Any], seqs: range) -> list[dict[str, Any]]:
    out = []
    for seq in seqs:
        r = _put_batch(c, tok, sid, seq, bs[seq])
        assert r.status_code == 200, r.text
        d = r.json()
        d.pop("session_id")
        out.append(d)
    return out


def _trajectory(c: TestClient, tok: str, sid: int) -> list[dict[str, Any]]:
    assert c.post(f"/v1/sessions/{sid}/close", headers=auth(tok)).status_code == 200
    return c.get(f"/v1/sessions/{sid}/trajectory", headers=auth(tok)).json()["positions"]


@pytest.mark.parametrize("cut", [5, 7, 9])
def test_restart_between_checkpoints_gives_the_uninterrupted_trajectory(settings, client, make_user, cut) -> None:  # type: ignore[no-untyped-def]
    """A walk in 1-s batches with a checkpoint every 4 batches (the default ``state_every``); the server restarts
    (a new app: no cached engine) after ``cut`` batches, between two checkpoints, so the next upload restores the
    last checkpoint and replays the stored batches after it. Every answer, the stored checkpoint and the closed
    session's trajectory equal an uninterrupted run's."""
    assert settings.state_every == 4
    bs = _walk_batches(11)
    _, tok = make_user()
    ref = client.post("/v1/sessions", json={"device_kind": "foot"}, headers=auth(tok)).json()["id"]
    ref_resp = _session_run(client, tok, ref, bs, range(len(bs)))
    assert sum(len(r["positions"]) for r in ref_resp) >= 3  # a walk: stride positions to compare
    sid = client.post("/v1/sessions", json={"device_kind": "foot"}, headers=auth(tok)).json()["id"]
    got = _session_run(client, tok, sid, bs, range(cut))
    app2 = create_app(settings.model_copy(update={"migrate_on_startup": False}))
    try:
        with TestClient(app2) as c2:
            got += _session_run(c2, tok, sid, bs, range(cut, len(bs)))
            with app2.state.sessionmaker() as db:
                a, b = db.get(TrackSession, ref), db.get(TrackSession, sid)
                assert held_batches(b.engine_state) == 8  # the last checkpoint: batches 0 .. 7 (of 0 .. 10)
                assert a.engine_state == b.engine_state
            traj = _trajectory(c2, tok, sid)
    finally:
        app2.state.db_engine.dispose()
    assert got == ref_resp
    assert traj == _trajectory(client, tok, ref)


def test_state_of_an_older_server_is_migrated_on_the_next_batch(settings, client, make_user) -> None:  # type: ignore[no-untyped-def]
    """A session whose stored state is the complete form an older server wrote after every batch: the next upload
    (a restarted server) continues from it exactly and stores a checkpoint, though no checkpoint is due at that
    number."""
    bs = _walk_batches(8)
    _, tok = make_user()
    ref = client.post("/v1/sessions", json={"device_kind": "foot"}, headers=auth(tok)).json()["id"]
    ref_resp = _session_run(client, tok, ref, bs, range(len(bs)))
    sid = client.post("/v1/sessions", json={"device_kind": "foot"}, headers=auth(tok)).json()["id"]
    got = _session_run(client, tok, sid, bs, range(5))
    e = Engine(mode="auto")
    for b in bs[:5]:
        e.feed(b)
    with client.app.state.sessionmaker() as db:  # what an older server stored after batch 4
        db.get(TrackSession, sid).engine_state = pack_state(e.to_bytes())
        db.commit()
    app2 = create_app(settings.model_copy(update={"migrate_on_startup": False}))
    try:
        with TestClient(app2) as c2:
            got += _session_run(c2, tok, sid, bs, range(5, 6))
            with app2.state.sessionmaker() as db:
                assert held_batches(db.get(TrackSession, sid).engine_state) == 6  # migrated: batches 0 .. 5
            got += _session_run(c2, tok, sid, bs, range(6, len(bs)))
            traj = _trajectory(c2, tok, sid)
    finally:
        app2.state.db_engine.dispose()
    assert got == ref_resp
    assert traj == _trajectory(client, tok, ref)
