"""The engine helper's cache after a write that failed: the next batch continues from what the database holds.

A helper caches the engine it fed under the version the worker is about to commit, before the worker writes.
When that write fails (another worker committed the number first with other content, or the write transaction
was refused, e.g. a Sensor Logger piece whose messages changed meanwhile) and another worker then commits that
version, the next batch must not continue from the helper's engine of the failed write.
"""

from __future__ import annotations

import functools
import json
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient

from clients.synth import synthesize
from energy.engine import Engine
from models.batch import SensorBatch
from server import ingest, upload
from server.formats import MSGPACK_TYPE, decode_batch, encode_msgpack
from server.ingest import IngestConflict, apply_batch, feed_engine
from server.models import TrackSession
from server.statecodec import unpack_checkpoint
from tests.server.conftest import app_with, auth

K = 5  # the number whose first write fails


@pytest.fixture(scope="module")
def worker_a(settings):  # type: ignore[no-untyped-def]
    """Worker A: a second app on the test database, its engines in one helper process (shared by the tests)."""
    with app_with(settings, engine_processes=1) as (a, c):
        assert a.state.host.pool is not None and a.state.uploader is not None
        yield a, c


@functools.lru_cache(maxsize=1)
def _walk() -> list[SensorBatch]:
    return synthesize("walk", seed=4).batch.split_seconds(2.0)[: K + 2]


def _turned(b: SensorBatch) -> SensorBatch:
    """Other content under the same number: a gyroscope z bias of 0.2 rad/s turns the next batch's positions."""
    return SensorBatch(acc_t_ns=b.acc_t_ns, acc=b.acc, gyr_t_ns=b.gyr_t_ns, gyr=b.gyr + np.array([0.0, 0.0, 0.2]),
                       mag_t_ns=b.mag_t_ns, mag=b.mag)


def _put(c: TestClient, tok: str, sid: int, seq: int, b: SensorBatch) -> Any:
    return c.put(f"/v1/sessions/{sid}/batches/{seq}", content=encode_msgpack(b),
                 headers={**auth(tok), "content-type": MSGPACK_TYPE})


def _replay(client: TestClient, tok: str, sid: int, n: int) -> tuple[list[dict[str, Any]], list[bytes]]:
    """Answers of a fresh in-process engine fed the session's stored batches, and its state after each number
    of them (``[k]``: after batches ``0 .. k - 1``)."""
    e = Engine(mode="auto")
    answers = []
    states = [e.to_bytes()]
    for seq in range(n):
        raw = client.get(f"/v1/sessions/{sid}/batches/{seq}/raw", headers=auth(tok))
        assert raw.status_code == 200
        answers.append(json.loads(feed_engine(e, decode_batch(raw.content, MSGPACK_TYPE, 2**62, allow_empty=True), sid, seq).resp_json))
        states.append(e.to_bytes())
    return answers, states


def _assert_stored_state(app: Any, sid: int, states: list[bytes]) -> None:
    """The stored checkpoint is the replay's state after the batches it says it holds (the batches after it are
    replayed from storage on a restore)."""
    with app.state.sessionmaker() as db:
        blob = db.get(TrackSession, sid).engine_state
    state, held = unpack_checkpoint(blob)
    assert held is not None and state == states[held]


def test_upload_after_a_lost_write_continues_from_the_other_workers_batch(app, client, worker_a, make_user,  # type: ignore[no-untyped-def]
                                                                          monkeypatch) -> None:
    """Batch uploads (driver writes): worker A's helper fed number K, then worker B committed K with other
    content first, so A's write failed its version check (409). A's next upload (K + 1) answers exactly what a
    replay of the stored batches gives, and stores that replay's state; before, A's helper engine is continued
    (the stored state is read for the first batch only)."""
    _, tok = make_user()
    sid = client.post("/v1/sessions", json={"device_kind": "foot"}, headers=auth(tok)).json()["id"]
    bs = _walk()
    real = upload.pool_feed
    loads: list[int] = []  # numbers whose feed read the stored state

    def racing(pool: Any, session_id: int, version: int, seq: int, batch: SensorBatch, load_blob: Any, *rest: Any) -> Any:
        def counted() -> Any:
            loads.append(seq)
            return load_blob()

        fed = real(pool, session_id, version, seq, batch, counted, *rest)  # the helper caches its engine at version + 1
        if seq == K:  # worker B (the module's app, engine in process) commits number K first, other content
            assert _put(client, tok, sid, K, _turned(bs[K])).status_code == 200
        return fed

    monkeypatch.setattr(upload, "pool_feed", racing)
    _, ca = worker_a
    for seq in range(K):
        assert _put(ca, tok, sid, seq, bs[seq]).status_code == 200
    assert loads == [0]
    lost = _put(ca, tok, sid, K, bs[K])
    assert lost.status_code == 409 and lost.json()["expected_seq"] == K + 1, lost.json()
    nxt = _put(ca, tok, sid, K + 1, bs[K + 1])
    assert nxt.status_code == 200, nxt.json()
    ref, state = _replay(client, tok, sid, K + 2)
    assert ref[K + 1]["positions"]  # the batch has positions to compare
    assert nxt.json() == ref[K + 1]
    _assert_stored_state(app, sid, state)
    assert loads == [0, K + 1]  # K + 1 restored the stored state (B's batch K), not A's helper engine


@pytest.mark.parametrize("failure", ["version", "refused"])
def test_apply_batch_after_a_failed_write_continues_from_the_other_workers_batch(app, client, worker_a, make_user,  # type: ignore[no-untyped-def]
                                                                                 monkeypatch, failure) -> None:
    """The ORM write of :func:`server.ingest.apply_batch` (Sensor Logger pushes; PostgreSQL without driver
    writes): worker A's helper fed number K, A's write failed, worker B committed K with other content.

    ``version``: B committed between A's engine step and A's write (A answers 409). ``refused``: A's write
    transaction was refused by ``also`` (as a Sensor Logger piece whose messages changed meanwhile), then B
    committed. A's next batch (K + 1) answers exactly what a replay of the stored batches gives."""
    uid, tok = make_user()
    sid = client.post("/v1/sessions", json={"device_kind": "foot"}, headers=auth(tok)).json()["id"]
    bs = _walk()
    a, _ = worker_a
    host = a.state.host
    real = ingest.pool_feed

    def racing(pool: Any, session_id: int, version: int, seq: int, batch: SensorBatch, load_blob: Any, *rest: Any) -> Any:
        fed = real(pool, session_id, version, seq, batch, load_blob, *rest)
        if seq == K:
            assert _put(client, tok, sid, K, _turned(bs[K])).status_code == 200
        return fed

    class Refused(Exception):
        pass

    def refuse(_db: Any) -> None:
        raise Refused()

    with a.state.sessionmaker() as db:
        for seq in range(K):
            out = apply_batch(db, host, uid, sid, seq, bs[seq])
            assert out is not None and out[1] is False
        if failure == "version":
            monkeypatch.setattr(ingest, "pool_feed", racing)
            with pytest.raises(IngestConflict):
                apply_batch(db, host, uid, sid, K, bs[K])
            monkeypatch.setattr(ingest, "pool_feed", real)
        else:
            with pytest.raises(Refused):
                apply_batch(db, host, uid, sid, K, bs[K], also=refuse)
            db.rollback()
            assert _put(client, tok, sid, K, _turned(bs[K])).status_code == 200
        out = apply_batch(db, host, uid, sid, K + 1, bs[K + 1])
        assert out is not None and out[1] is False
    ref, state = _replay(client, tok, sid, K + 2)
    assert ref[K + 1]["positions"]
    assert json.loads(json.dumps(out[0])) == ref[K + 1]
    _assert_stored_state(app, sid, state)
