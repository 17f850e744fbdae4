"""The job engine: Dramatiq over Redis with two local worker processes re-processes stored sessions (SQLite and
PostgreSQL); skipped with the reason when Redis does not answer or Dramatiq is not installed."""

from __future__ import annotations

import os
import subprocess
import sys
import time
import uuid

import pytest

from server.formats import MSGPACK_TYPE, encode_msgpack
from tests.server.conftest import auth, still_batch

REDIS_URL = os.environ.get("PEDNAV_TEST_REDIS_URL", "redis://127.0.0.1:6379/15")
T0 = 1_700_000_000_000_000_000


def _redis_reason() -> str | None:
    try:
        import dramatiq  # noqa: F401
        import redis
    except ImportError as exc:
        return f"the job engine is not installed ({exc.name}): pip install 'pednav[jobs]'"
    try:
        redis.Redis.from_url(REDIS_URL, socket_connect_timeout=2).ping()
    except Exception as exc:  # noqa: BLE001 - any failure: skip with the reason
        return f"Redis at {REDIS_URL} unreachable: {type(exc).__name__}: {exc}"
    return None


def test_two_local_workers_reprocess_stored_sessions(settings, client, make_user) -> None:  # type: ignore[no-untyped-def]
    reason = _redis_reason()
    if reason:
        pytest.skip(reason)
    from server.jobs import declare, enqueue_reprocess, make_broker, outcomes

    _, tok = make_user()
    sids = []
    for i in range(8):
        sid = client.post("/v1/sessions", json={"device_kind": "foot"}, headers=auth(tok)).json()["id"]
        for seq in range(4):
            r = client.put(f"/v1/sessions/{sid}/batches/{seq}", content=encode_msgpack(still_batch(T0 + seq * 10**9, seed=i)),
                           headers={**auth(tok), "content-type": MSGPACK_TYPE})
            assert r.status_code == 200, r.text
        sids.append(sid)
    broker = make_broker(REDIS_URL)
    broker.flush_all()
    actor = declare(broker)
    env = {**os.environ, "PEDNAV_REDIS_URL": REDIS_URL, "PEDNAV_DATABASE_URL": settings.database_url}
    if settings.db_schema:
        env["PEDNAV_DB_SCHEMA"] = settings.db_schema
    proc = subprocess.Popen([sys.executable, "-m", "dramatiq", "server.jobs_worker", "--processes", "2", "--threads", "1",
                             "--queues", "pednav"], env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    run = uuid.uuid4().hex
    try:
        enqueue_reprocess(actor, sids, run, redis_url=REDIS_URL)
        deadline = time.monotonic() + 300
        while (res := outcomes(run, REDIS_URL)).done < len(sids):
            assert proc.poll() is None, proc.stderr.read().decode() if proc.stderr else ""
            assert time.monotonic() < deadline, f"jobs not done in 300 s: {res}"
            time.sleep(0.05)
    finally:
        proc.terminate()
        proc.wait(timeout=60)
        broker.close()
    assert res.identical == len(sids) and res.changed == res.missing == res.conflicts == 0, res
    assert 1 <= len(res.worker_pids) <= 2 and os.getpid() not in res.worker_pids
    for sid in sids:  # stored by the workers: every session re-processed once, trajectory unchanged
        s = client.get(f"/v1/sessions/{sid}", headers=auth(tok)).json()
        assert s["reprocess_count"] == 1 and s["reprocessed_at"] is not None
