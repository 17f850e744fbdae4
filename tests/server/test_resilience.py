"""No 5xx and no silent loss: concurrent writers of one user, ids beyond the id columns, control characters,
empty uploads (SQLite and PostgreSQL)."""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient

from energy.profile import PROFILE_BEHAVIOURS
from server.formats import MSGPACK_TYPE, encode_msgpack
from tests.server.conftest import app_with, auth, still_batch

T0 = 1_700_000_000_000_000_000


def _at_once(n: int, fn: Callable[[int], Any]) -> list[Any]:
    """Run ``fn(0..n-1)`` in ``n`` threads released together; their results in order."""
    barrier = threading.Barrier(n)
    out: list[Any] = [None] * n

    def go(i: int) -> None:
        barrier.wait()
        out[i] = fn(i)

    threads = [threading.Thread(target=go, args=(i,)) for i in range(n)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return out


def _calibration(k: int) -> dict[str, Any]:
    return {"calibrated": True, "n_steps": 10 + k, "heading_deviation_rad": 0.01 * k}


def test_profile_behaviours_are_the_published_enum() -> None:
    from typing import get_args

    from server.routers.profiles import Calibrated

    assert set(get_args(Calibrated)) == set(PROFILE_BEHAVIOURS)


def test_eight_concurrent_profile_writes_all_succeed_with_consecutive_versions(settings, client, make_user) -> None:  # type: ignore[no-untyped-def]
    _, tok = make_user()
    with app_with(settings) as (_, c2):  # two workers (apps) on one database
        clients = [client, c2]
        codes = _at_once(8, lambda i: clients[i % 2].put("/v1/profiles/walk", json={"data": _calibration(i)},
                                                         headers=auth(tok)))
    assert [r.status_code for r in codes] == [200] * 8, [r.text for r in codes if r.status_code != 200]
    versions = [p["version"] for p in client.get("/v1/profiles/walk/history", headers=auth(tok)).json()]
    assert versions == list(range(1, 9))
    assert sorted(r.json()["version"] for r in codes) == versions


@pytest.mark.parametrize("same_session", [True, False], ids=["same-session", "one-user-many-sessions"])
def test_concurrent_closes_answer_200_and_close_every_session(settings, client, make_user, same_session) -> None:  # type: ignore[no-untyped-def]
    _, tok = make_user()
    sids = []
    for i in range(1 if same_session else 6):
        sid = client.post("/v1/sessions", json={"device_kind": "foot"}, headers=auth(tok)).json()["id"]
        for seq in range(3):
            r = client.put(f"/v1/sessions/{sid}/batches/{seq}", content=encode_msgpack(still_batch(T0 + seq * 10**9, seed=i)),
                           headers={**auth(tok), "content-type": MSGPACK_TYPE})
            assert r.status_code == 200, r.text
        sids.append(sid)
    with app_with(settings) as (_, c2):
        clients = [client, c2]
        answers = _at_once(6, lambda i: clients[i % 2].post(f"/v1/sessions/{sids[i % len(sids)]}/close", headers=auth(tok)))
    assert [r.status_code for r in answers] == [200] * 6, [r.text for r in answers if r.status_code != 200]
    for sid in sids:
        s = client.get(f"/v1/sessions/{sid}", headers=auth(tok)).json()
        assert s["status"] == "closed"
        # closed once: the flush's positions are stored once (a second close stores nothing)
        traj = client.get(f"/v1/sessions/{sid}/trajectory", headers=auth(tok)).json()["positions"]
        assert len(traj) == s["n_positions"]
        assert len({p["t_ns"] for p in traj}) == len(traj)


@pytest.mark.parametrize("big", [2**31, 2**32 + 5, 2**63 - 1])
@pytest.mark.parametrize(
    "method, path, field",
    [
        ("get", "/v1/sessions/{big}", "path.session_id"),
        ("post", "/v1/sessions/{big}/close", "path.session_id"),
        ("get", "/v1/sessions/{big}/trajectory", "path.session_id"),
        ("get", "/v1/sessions/1/batches/{big}/raw", "path.seq"),
        ("put", "/v1/sessions/{big}/batches/0", "path.session_id"),
        ("put", "/v1/sessions/1/batches/{big}", "path.seq"),
        ("get", "/v1/devices/{big}", "path.device_id"),
        ("delete", "/v1/tokens/{big}", "path.token_id"),
    ],
)
def test_ids_beyond_the_id_columns_are_422_naming_the_field(client, make_user, big, method, path, field) -> None:  # type: ignore[no-untyped-def]
    _, a = make_user()
    kw: dict[str, Any] = {"headers": auth(a)}
    if method == "put":
        kw = {"content": encode_msgpack(still_batch(T0)), "headers": {**auth(a), "content-type": MSGPACK_TYPE}}
    r = getattr(client, method)(path.format(big=big), **kw)
    assert r.status_code == 422, r.text
    assert r.json()["field"] == field


def test_device_id_beyond_the_id_column_is_422(client, make_user) -> None:  # type: ignore[no-untyped-def]
    _, a = make_user()
    r = client.post("/v1/sessions", json={"device_kind": "foot", "device_id": 2**31}, headers=auth(a))
    assert r.status_code == 422 and r.json()["field"] == "device_id", r.text
    assert client.get("/v1/sessions", headers=auth(a)).json() == []


@pytest.mark.parametrize("bad", ["a\x00b", "\x07", "tab\there", "\x7f"], ids=["nul", "bell", "tab", "del"])
def test_control_characters_in_text_are_422_and_store_nothing(client, make_user, bad) -> None:  # type: ignore[no-untyped-def]
    _, a = make_user()
    r = client.post("/v1/devices", json={"kind": "foot", "name": bad}, headers=auth(a))
    assert r.status_code == 422 and r.json()["field"] == "name" and "control character" in r.json()["detail"], r.text
    assert client.get("/v1/devices", headers=auth(a)).json() == []
    r = client.post("/v1/tokens", json={"label": bad}, headers=auth(a))
    assert r.status_code == 422 and r.json()["field"] == "label", r.text
    assert len(client.get("/v1/tokens", headers=auth(a)).json()) == 1
    push = {"messageId": 1, "sessionId": "s1", "deviceId": "d", "payload": []}
    for key in ("sessionId", "deviceId"):
        r = client.post("/v1/sensorlogger", json={**push, key: bad}, headers=auth(a))
        assert r.status_code == 422 and r.json()["field"] == key, r.text
    assert client.get("/v1/sessions", headers=auth(a)).json() == []
    from urllib.parse import quote

    r = client.post(f"/v1/sensorlogger/{quote(bad)}/flush", headers=auth(a))
    assert r.status_code == 422 and r.json()["field"] == "path.sl_session_id", r.text


@pytest.mark.parametrize("body, ctype", [
    (b"{}", "application/json"),
    (b'{"acc": {"t_ns": [], "xyz": []}}', "application/json"),
    (encode_msgpack(still_batch(T0, seconds=0.0)), MSGPACK_TYPE),
], ids=["empty-object", "empty-stream", "msgpack-no-streams"])
def test_an_empty_batch_is_refused_and_consumes_no_sequence_number(client, make_user, body, ctype) -> None:  # type: ignore[no-untyped-def]
    _, a = make_user()
    sid = client.post("/v1/sessions", json={"device_kind": "foot"}, headers=auth(a)).json()["id"]
    r = client.put(f"/v1/sessions/{sid}/batches/0", content=body, headers={**auth(a), "content-type": ctype})
    assert r.status_code == 422 and r.json()["field"] == "body" and "without samples" in r.json()["detail"], r.text
    assert client.get(f"/v1/sessions/{sid}", headers=auth(a)).json()["next_seq"] == 0
    r = client.put(f"/v1/sessions/{sid}/batches/0", content=encode_msgpack(still_batch(T0)),
                   headers={**auth(a), "content-type": MSGPACK_TYPE})
    assert r.status_code == 200 and r.json()["next_seq"] == 1, r.text


def test_sdk_stream_skips_an_empty_batch(client, make_user) -> None:  # type: ignore[no-untyped-def]
    from clients.sdk import PednavClient

    _, a = make_user()
    api = PednavClient(token=a, http=client)
    sid = api.start_session("foot")["id"]
    st = api.stream(sid)
    assert st.send(still_batch(T0)) and st.next_seq == 1
    assert st.send(still_batch(T0 + 10**9, seconds=0.0)) == [] and st.next_seq == 1 and not st.pending
    assert st.send(still_batch(T0 + 10**9))[0]["seq"] == 1


def test_admin_create_user_refuses_an_empty_name(tmp_path) -> None:  # type: ignore[no-untyped-def]
    import subprocess
    import sys

    for name in ("", "a b", "x" * 101):
        p = subprocess.run([sys.executable, "-m", "clients.cli", "admin", "create-user", name, "--json",
                            "--database-url", f"sqlite:///{tmp_path}/a.db"], capture_output=True, text=True, timeout=120)
        assert p.returncode == 2 and "Traceback" not in p.stderr, p.stderr
        assert p.stderr.strip().count("\n") == 0 and "user name" in p.stderr
    assert not (tmp_path / "a.db").exists()  # refused before the database is touched


def test_client_tokens_for_sessions_are_unaffected(client: TestClient, make_user) -> None:  # type: ignore[no-untyped-def]
    """Ordinary text (letters, blanks, accents, emoji) is taken as before."""
    _, a = make_user()
    r = client.post("/v1/devices", json={"kind": "phone", "name": "Zoë's phone 📱"}, headers=auth(a))
    assert r.status_code == 201 and r.json()["name"] == "Zoë's phone 📱"


@pytest.mark.parametrize("stream", ["gyr", "mag"])
@pytest.mark.parametrize("orm_path", [False, True], ids=["fast-path", "orm-path"])
def test_late_gyroscope_or_magnetometer_samples_are_422_not_dropped(settings, client, make_user, stream, orm_path) -> None:  # type: ignore[no-untyped-def]
    """A batch repeating the previous batch's gyroscope (magnetometer) samples was answered 200 and the engine
    dropped them without a word; now 422 names the stream, nothing is stored, and the batch without them is taken."""
    from models.batch import SensorBatch

    if orm_path and settings.database_url.startswith("sqlite"):
        pytest.skip("the ORM upload path serves PostgreSQL with pg_one_statement_writes=false only")
    _, a = make_user()
    with app_with(settings, pg_one_statement_writes=not orm_path) as (_, c):
        sid = c.post("/v1/sessions", json={"device_kind": "foot"}, headers=auth(a)).json()["id"]
        b0, b1 = still_batch(T0, seed=1), still_batch(T0 + 10**9, seed=2)
        h = {**auth(a), "content-type": MSGPACK_TYPE}
        assert c.put(f"/v1/sessions/{sid}/batches/0", content=encode_msgpack(b0), headers=h).status_code == 200
        kw = b1._kwargs()
        t_old, v_old = b0.stream(stream)
        kw[f"{stream}_t_ns"] = np.concatenate([t_old[-5:], kw[f"{stream}_t_ns"]])
        kw[stream] = np.concatenate([v_old[-5:], kw[stream]])
        r = c.put(f"/v1/sessions/{sid}/batches/1", content=encode_msgpack(SensorBatch(**kw)), headers=h)
        assert r.status_code == 422 and r.json()["field"] == f"{stream}_t_ns", r.text
        assert "5 " in r.json()["detail"] and "newest this session already received" in r.json()["detail"]
        assert c.get(f"/v1/sessions/{sid}", headers=auth(a)).json()["next_seq"] == 1
        r = c.put(f"/v1/sessions/{sid}/batches/1", content=encode_msgpack(b1), headers=h)
        assert r.status_code == 200, r.text
        # a retry of an applied batch is still answered from the store (no watermark check for it)
        r = c.put(f"/v1/sessions/{sid}/batches/1", content=encode_msgpack(b1), headers=h)
        assert r.status_code == 200 and r.headers["x-pednav-replayed"] == "true"


def test_watermarks_advance_by_the_last_sample_of_each_stream() -> None:
    from server.watermarks import advanced, check_after

    b = still_batch(T0)
    w = advanced(b, {"gyr": None, "mag": None})
    assert w == {"gyr": int(b.gyr_t_ns[-1]), "mag": int(b.mag_t_ns[-1])}
    assert advanced(b.without("gyr"), w) == w  # a stream not sent keeps its watermark
    check_after(still_batch(T0 + 10**9), w)  # the next second is after them


def test_engine_helper_killed_mid_stream_costs_a_retry_not_a_500(settings, make_user) -> None:  # type: ignore[no-untyped-def]
    """SIGKILL of the engine helper twice during a stream (its pipes break under the next upload): every upload is answered 200
    (retried on a fresh helper from the stored state) and the trajectory equals the uninterrupted run's."""
    import os
    import signal

    _, a = make_user()
    h = {**auth(a), "content-type": MSGPACK_TYPE}
    bodies = [encode_msgpack(still_batch(T0 + k * 10**9, seed=k)) for k in range(8)]
    answers = {}
    for killed in (False, True):
        with app_with(settings, engine_processes=1) as (app, c):
            sid = c.post("/v1/sessions", json={"device_kind": "foot"}, headers=auth(a)).json()["id"]
            out = []
            for k, body in enumerate(bodies):
                if killed and k in (2, 5):
                    for pid in app.state.host.pool.pids():
                        os.kill(pid, signal.SIGKILL)
                r = c.put(f"/v1/sessions/{sid}/batches/{k}", content=body, headers=h)
                assert r.status_code == 200, r.text
                out.append({key: v for key, v in r.json().items() if key != "session_id"})
            if killed:
                assert app.state.host.pool.pids()  # a fresh helper took over
            answers[killed] = out
    assert answers[True] == answers[False]


def test_engine_helper_dying_on_every_attempt_is_503_retry_after_nothing_stored(settings, make_user, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    from server.engine_pool import EngineHelperDied, EnginePool

    _, a = make_user()
    with app_with(settings, engine_processes=1) as (_, c):
        sid = c.post("/v1/sessions", json={"device_kind": "foot"}, headers=auth(a)).json()["id"]

        def dies(*_a: Any, **_k: Any) -> Any:
            raise EngineHelperDied("engine helper process died (EOFError)")

        monkeypatch.setattr(EnginePool, "feed", dies)
        r = c.put(f"/v1/sessions/{sid}/batches/0", content=encode_msgpack(still_batch(T0)),
                  headers={**auth(a), "content-type": MSGPACK_TYPE})
        assert r.status_code == 503 and int(r.headers["retry-after"]) >= 1, r.text
        assert "NOT stored" in r.json()["detail"]
        monkeypatch.undo()
        assert c.get(f"/v1/sessions/{sid}", headers=auth(a)).json()["next_seq"] == 0
        r = c.put(f"/v1/sessions/{sid}/batches/0", content=encode_msgpack(still_batch(T0)),
                  headers={**auth(a), "content-type": MSGPACK_TYPE})
        assert r.status_code == 200, r.text


def test_failed_authentications_are_rate_limited_per_client_before_the_lookup(settings, make_user, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """Invalid tokens were never limited (1,000 x 401 at ~300 requests/s, each a database lookup): past the burst a
    client gets 429 with Retry-After and its token is not looked up; a valid token of another client still works,
    and the upload route is guarded the same way."""
    import server.deps as deps

    _, good = make_user()
    with app_with(settings, auth_failures_per_s=0.5, auth_failures_burst=5) as (app, c):
        lookups = []
        real = deps.authenticate
        monkeypatch.setattr(deps, "authenticate", lambda *a, **k: lookups.append(1) or real(*a, **k))
        codes = [c.get("/v1/users/me", headers=auth(f"pn_guess{i}")).status_code for i in range(20)]
        assert codes[:5] == [401] * 5 and set(codes[5:]) == {429}, codes
        assert len(lookups) == 5  # the refused ones never reached the database
        r = c.get("/v1/users/me", headers=auth(good))
        assert r.status_code == 429 and int(r.headers["retry-after"]) >= 1  # the same client: held off too
        r = c.put("/v1/sessions/1/batches/0", content=encode_msgpack(still_batch(T0)),
                  headers={**auth("pn_guess"), "content-type": MSGPACK_TYPE})
        assert r.status_code == 429, r.text
        other = TestClient(app, client=("203.0.113.9", 50000))
        assert other.get("/v1/users/me", headers=auth(good)).status_code == 200  # another client is not held


def test_tokens_never_reach_the_access_log(caplog) -> None:  # type: ignore[no-untyped-def]
    import logging

    from server.redact import REDACTED, install

    install()
    tok = "pn_" + "A" * 43
    with caplog.at_level(logging.INFO, logger="uvicorn.access"):
        logging.getLogger("uvicorn.access").info('%s - "%s %s HTTP/%s" %d', "127.0.0.1:5", "POST",
                                                   f"/v1/sensorlogger?token={tok}&x=1", "1.1", 200)
        logging.getLogger("uvicorn.access").info('%s - "%s %s HTTP/%s" %d', "127.0.0.1:5", "GET",
                                                   "/v1/users/me?token=wrong-guess", "1.1", 401)
    text = "\n".join(r.getMessage() for r in caplog.records)
    assert tok not in text and "wrong-guess" not in text and text.count(REDACTED) == 2
    assert "&x=1" in text  # the rest of the URL stays readable
