"""Token expiry and the per-user rate limit: clear 401/429 messages, settings validated at start-up."""

from __future__ import annotations

import uuid
from datetime import datetime, timedelta, timezone

import pytest
from fastapi.testclient import TestClient
from sqlalchemy import update

from server.app import create_app
from server.auth import RateLimiter
from server.formats import MSGPACK_TYPE, encode_msgpack
from server.models import Token
from server.security import hash_token
from server.settings import Settings, SettingsError, load_settings
from tests.server.conftest import app_with, auth, still_batch

T0 = 1_700_000_000_000_000_000


def _expire(app, token: str, when: datetime) -> None:  # type: ignore[no-untyped-def]
    with app.state.sessionmaker() as db:
        db.execute(update(Token).where(Token.token_hash == hash_token(token)).values(expires_at=when))
        db.commit()


def test_minted_tokens_expire_after_their_lifetime(client, app, make_user, settings) -> None:  # type: ignore[no-untyped-def]
    _, tok = make_user()
    r = client.post("/v1/tokens", headers=auth(tok))
    assert r.status_code == 201
    exp = datetime.fromisoformat(r.json()["expires_at"])
    expected = datetime.now(timezone.utc) + timedelta(seconds=settings.token_ttl_s)
    assert abs((exp - expected).total_seconds()) < 60
    short = client.post("/v1/tokens", json={"label": "watch", "ttl_s": 120}, headers=auth(tok)).json()
    assert abs((datetime.fromisoformat(short["expires_at"]) - datetime.now(timezone.utc)).total_seconds() - 120) < 30
    assert client.get("/v1/users/me", headers=auth(short["token"])).status_code == 200
    _expire(app, short["token"], datetime.now(timezone.utc) - timedelta(seconds=1))
    for method, path in (("get", "/v1/users/me"), ("get", "/v1/sessions")):
        r = getattr(client, method)(path, headers=auth(short["token"]))
        assert r.status_code == 401 and "expired at" in r.json()["detail"], r.text
        assert r.headers["www-authenticate"] == "Bearer"
    assert client.get("/v1/users/me", headers=auth(tok)).status_code == 200  # the user's other tokens still work


def test_expired_token_cannot_upload_and_nothing_is_stored(client, app, make_user) -> None:  # type: ignore[no-untyped-def]
    _, tok = make_user()
    dev = client.post("/v1/tokens", json={"ttl_s": 3600}, headers=auth(tok)).json()["token"]
    sid = client.post("/v1/sessions", json={"device_kind": "phone"}, headers=auth(dev)).json()["id"]
    put = lambda seq: client.put(  # noqa: E731
        f"/v1/sessions/{sid}/batches/{seq}", content=encode_msgpack(still_batch(T0 + seq * 10**9)),
        headers={**auth(dev), "content-type": MSGPACK_TYPE})
    assert put(0).status_code == 200
    _expire(app, dev, datetime.now(timezone.utc) - timedelta(seconds=1))
    r = put(1)
    assert r.status_code == 401 and "expired" in r.json()["detail"]
    assert client.get(f"/v1/sessions/{sid}", headers=auth(tok)).json()["next_seq"] == 1


def test_token_refusals_say_which(client, make_user) -> None:  # type: ignore[no-untyped-def]
    _, tok = make_user()
    r = client.get("/v1/users/me")
    assert r.status_code == 401 and "missing bearer token" in r.json()["detail"]
    r = client.get("/v1/users/me", headers=auth("pn_nonsense"))
    assert r.status_code == 401 and r.json()["detail"] == "invalid token"
    second = client.post("/v1/tokens", headers=auth(tok)).json()["token"]
    client.delete("/v1/tokens/current", headers=auth(second))
    r = client.put("/v1/sessions/1/batches/0", content=b"{}", headers=auth(second))
    assert r.status_code == 401 and r.json()["detail"] == "token revoked"
    r = client.post("/v1/tokens", json={"ttl_s": 10}, headers=auth(tok))
    assert r.status_code == 422 and r.json()["field"] == "ttl_s"
    r = client.post("/v1/tokens", json={"ttl_s": 10**10}, headers=auth(tok))
    assert r.status_code == 422 and r.json()["detail"].startswith("ttl_s: at most")
    r = client.post("/v1/tokens", json={"lifetime": 100}, headers=auth(tok))
    assert r.status_code == 422 and r.json()["field"] == "lifetime"


def _token_count(app, uid: int) -> int:  # type: ignore[no-untyped-def]
    from sqlalchemy import func, select

    with app.state.sessionmaker() as db:
        return db.execute(select(func.count()).select_from(Token).where(Token.user_id == uid)).scalar_one()


@pytest.mark.parametrize("ttl_s", [365 * 86_400, 3601, 7200])
def test_a_token_cannot_mint_a_token_that_outlives_it(client, app, make_user, ttl_s) -> None:  # type: ignore[no-untyped-def]
    """A one-hour token minted a 365-day one: whoever held a short-lived token could keep the account for a year."""
    uid, tok = make_user()
    short = client.post("/v1/tokens", json={"ttl_s": 3600}, headers=auth(tok)).json()
    n = _token_count(app, uid)
    r = client.post("/v1/tokens", json={"ttl_s": ttl_s}, headers=auth(short["token"]))
    assert r.status_code == 422, r.text
    detail = r.json()["detail"]
    assert detail.startswith("ttl_s: at most 3") and "cannot outlive the token that mints it" in detail, detail
    assert _token_count(app, uid) == n  # nothing minted


def test_a_token_mints_shorter_tokens_and_the_default_ends_with_it(client, make_user, settings) -> None:  # type: ignore[no-untyped-def]
    _, tok = make_user()
    short = client.post("/v1/tokens", json={"ttl_s": 3600}, headers=auth(tok)).json()
    short_exp = datetime.fromisoformat(short["expires_at"])
    r = client.post("/v1/tokens", json={"ttl_s": 600}, headers=auth(short["token"]))
    assert r.status_code == 201
    assert abs((datetime.fromisoformat(r.json()["expires_at"]) - datetime.now(timezone.utc)).total_seconds() - 600) < 30
    # no ttl_s: the server's default lifetime (30 days here) would outlive the minting token: it ends with it
    assert settings.token_ttl_s > 3600
    r = client.post("/v1/tokens", headers=auth(short["token"]))
    assert r.status_code == 201 and datetime.fromisoformat(r.json()["expires_at"]) == short_exp
    assert client.get("/v1/users/me", headers=auth(r.json()["token"])).status_code == 200
    # a token that never expires (the admin bootstrap) still mints up to token_max_ttl_s
    r = client.post("/v1/tokens", json={"ttl_s": settings.token_max_ttl_s}, headers=auth(tok))
    assert r.status_code == 201


def test_a_token_cannot_outlive_its_minter_when_tokens_never_expire(settings, make_user) -> None:  # type: ignore[no-untyped-def]
    """``PEDNAV_TOKEN_TTL_S=0`` (default lifetime: never) from a token that expires: the new one ends with it
    (a minted token and a new user's first token alike)."""
    a = create_app(settings.model_copy(update={"migrate_on_startup": False, "token_ttl_s": 0}))
    try:
        with TestClient(a) as c:
            _, tok = make_user()
            short = c.post("/v1/tokens", json={"ttl_s": 3600}, headers=auth(tok)).json()
            r = c.post("/v1/tokens", headers=auth(short["token"]))
            assert r.status_code == 201 and r.json()["expires_at"] == short["expires_at"]
            assert c.post("/v1/tokens", headers=auth(tok)).json()["expires_at"] is None
            # so does a new user's first token, created by an admin token that expires
            _, adm = make_user(admin=True)
            short = c.post("/v1/tokens", json={"ttl_s": 3600}, headers=auth(adm)).json()
            r = c.post("/v1/users", json={"name": f"n{uuid.uuid4().hex[:10]}"}, headers=auth(short["token"]))
            assert r.status_code == 201 and r.json()["expires_at"] == short["expires_at"]
            r = c.post("/v1/users", json={"name": f"n{uuid.uuid4().hex[:10]}"}, headers=auth(adm))
            assert r.json()["expires_at"] is None
    finally:
        a.state.db_engine.dispose()


@pytest.mark.parametrize("how", ["query-with-other-scheme", "extra-blank"])
def test_revoking_the_current_token_revokes_the_one_that_authenticated(client, make_user, how) -> None:  # type: ignore[no-untyped-def]
    """DELETE /v1/tokens/current parsed the Authorization header again: with another scheme and ``?token=`` (or
    two blanks after "Bearer") it looked up a token that does not exist and answered 500, revoking nothing.
    (``?token=`` is now refused outside the Sensor Logger push: 401, and nothing is revoked.)"""
    _, tok = make_user()
    second = client.post("/v1/tokens", headers=auth(tok)).json()["token"]
    if how == "query-with-other-scheme":
        r = client.delete(f"/v1/tokens/current?token={second}", headers={"Authorization": "Basic dXNlcjpwdw=="})
        assert r.status_code == 401 and "query string" in r.json()["detail"], r.text
        assert client.get("/v1/users/me", headers=auth(second)).status_code == 200
        r = client.delete("/v1/tokens/current", headers=auth(second))
    else:
        r = client.delete("/v1/tokens/current", headers={"Authorization": f"Bearer  {second}"})
    assert r.status_code == 204, r.text
    r = client.get("/v1/users/me", headers=auth(second))
    assert r.status_code == 401 and r.json()["detail"] == "token revoked"
    assert client.get("/v1/users/me", headers=auth(tok)).status_code == 200


@pytest.mark.parametrize("with_header", [False, True], ids=["query-only", "query-and-header"])
@pytest.mark.parametrize("method, path", [
    ("get", "/v1/users/me"),
    ("get", "/v1/sessions"),
    ("get", "/v1/sessions/{sid}/trajectory"),
    ("get", "/v1/profiles"),
    ("post", "/v1/tokens"),
    ("get", "/v1/tokens"),
    ("delete", "/v1/tokens/current"),
    ("delete", "/v1/tokens/1"),
    ("put", "/v1/sessions/{sid}/batches/0"),  # the upload fast path
    ("post", "/v1/sensorlogger/phone-q/flush"),
])
def test_a_query_token_is_refused_outside_the_sensor_logger_push(client, make_user, method, path, with_header) -> None:  # type: ignore[no-untyped-def]
    """``?token=`` was taken on every route, so tokens ended up in access logs; only the Sensor Logger push (the
    app cannot set headers) takes it now. Everything else answers 401 naming the query string and does nothing."""
    _, tok = make_user()
    sid = client.post("/v1/sessions", json={"device_kind": "foot"}, headers=auth(tok)).json()["id"]
    kw: dict = {"headers": auth(tok) if with_header else {}}  # type: ignore[type-arg]
    if method == "put":
        kw = {"content": encode_msgpack(still_batch(T0)), "headers": {**kw["headers"], "content-type": MSGPACK_TYPE}}
    r = getattr(client, method)(path.format(sid=sid) + f"?token={tok}", **kw)
    assert r.status_code == 401, r.text
    assert "query string" in r.json()["detail"] and "Authorization: Bearer" in r.json()["detail"]
    assert r.headers["www-authenticate"] == "Bearer"
    assert client.get("/v1/users/me", headers=auth(tok)).status_code == 200  # not revoked
    assert client.get(f"/v1/sessions/{sid}", headers=auth(tok)).json()["next_seq"] == 0  # nothing uploaded


def test_the_sensor_logger_push_takes_a_query_token(client, make_user) -> None:  # type: ignore[no-untyped-def]
    _, tok = make_user()
    msg = {"messageId": 1, "sessionId": "phone-q", "deviceId": "d", "payload": [
        {"name": "totalacceleration", "time": T0, "values": {"x": 0.0, "y": 0.0, "z": 9.81}}]}
    r = client.post(f"/v1/sensorlogger?token={tok}", json=msg)
    assert r.status_code == 200 and r.json()["duplicate"] is False, r.text
    r = client.post("/v1/sensorlogger?token=pn_nonsense", json={**msg, "messageId": 2})
    assert r.status_code == 401 and r.json()["detail"] == "invalid token"
    # the push's header still wins over its query parameter
    r = client.post("/v1/sensorlogger?token=pn_nonsense", json={**msg, "messageId": 3}, headers=auth(tok))
    assert r.status_code == 200


@pytest.fixture()
def limited(settings):  # type: ignore[no-untyped-def]
    # one request back every 20 s: a slow machine (the first session of a run imports the engine) refills nothing
    # between the requests a test counts
    with app_with(settings, rate_limit_per_s=0.05, rate_limit_burst=3) as ac:
        yield ac


def test_rate_limit_is_per_user_with_429_and_retry_after(limited, make_user) -> None:  # type: ignore[no-untyped-def]
    app, c = limited
    _, tok = make_user()
    _, other = make_user()
    codes = [c.get("/v1/users/me", headers=auth(tok)).status_code for _ in range(3)]
    assert codes == [200, 200, 200]  # the burst
    r = c.get("/v1/users/me", headers=auth(tok))
    assert r.status_code == 429 and "at most 0.05 requests/s per user" in r.json()["detail"]
    assert int(r.headers["retry-after"]) >= 1
    assert c.get("/v1/users/me", headers=auth(other)).status_code == 200  # another user is not affected
    sid = c.post("/v1/sessions", json={"device_kind": "foot"}, headers=auth(other)).json()["id"]
    c.get("/v1/users/me", headers=auth(other))
    r = c.put(f"/v1/sessions/{sid}/batches/0", content=encode_msgpack(still_batch(T0)),
              headers={**auth(other), "content-type": MSGPACK_TYPE})
    assert r.status_code == 429  # uploads share the user's bucket; the refused batch is not stored
    with app.state.sessionmaker() as db:
        from server.models import TrackSession

        assert db.get(TrackSession, sid).next_seq == 0


def test_a_users_tokens_share_one_rate_limit(limited, make_user) -> None:  # type: ignore[no-untyped-def]
    """A bucket per token let a user multiply the rate limit by minting tokens (each new token came with a full
    burst); all tokens of a user now draw from the user's one bucket, on the normal and the upload route."""
    app, c = limited
    _, tok = make_user()
    fresh = [c.post("/v1/tokens", headers=auth(tok)).json()["token"] for _ in range(2)]  # 2 of the burst of 3
    assert c.get("/v1/users/me", headers=auth(fresh[0])).status_code == 200  # the 3rd
    r = c.get("/v1/users/me", headers=auth(fresh[1]))  # a token that has not made a request yet
    assert r.status_code == 429 and "shared by all of the user's tokens" in r.json()["detail"], r.text
    r = c.put("/v1/sessions/1/batches/0", content=encode_msgpack(still_batch(T0)),
              headers={**auth(fresh[1]), "content-type": MSGPACK_TYPE})
    assert r.status_code == 429, r.text  # the upload fast path draws from the same bucket


def test_sdk_waits_out_a_429_and_the_batch_is_applied_once(limited, make_user) -> None:  # type: ignore[no-untyped-def]
    from clients.sdk import PednavClient

    _, tok = make_user()
    _, c = limited
    api = PednavClient(token=tok, http=c, retries=3, backoff_s=0.0)
    sid = api.start_session("watch")["id"]
    answers = [api.upload(sid, k, still_batch(T0 + k * 10**9, seed=k)) for k in range(4)]  # burst 3: one waits
    assert [a["seq"] for a in answers] == [0, 1, 2, 3]
    assert api.session(sid)["next_seq"] == 4


def test_rate_limiter_refills_at_the_rate() -> None:
    rl = RateLimiter(rate_per_s=10.0, burst=2)
    assert rl.hit("a", now=0.0) == 0 and rl.hit("a", now=0.0) == 0
    assert rl.hit("a", now=0.0) == pytest.approx(0.1)
    assert rl.hit("a", now=0.05) == pytest.approx(0.05)
    assert rl.hit("a", now=0.1) == 0.0
    assert RateLimiter(0.0, 1).hit("a") == 0.0  # disabled


@pytest.mark.parametrize("env, problem", [
    ({"PEDNAV_TOKEN_TTL_S": "30"}, "PEDNAV_TOKEN_TTL_S"),  # 0 or >= 60
    ({"PEDNAV_TOKEN_TTL_S": "-1"}, "PEDNAV_TOKEN_TTL_S"),
    ({"PEDNAV_TOKEN_TTL_S": "7200", "PEDNAV_TOKEN_MAX_TTL_S": "3600"}, "exceeds PEDNAV_TOKEN_MAX_TTL_S"),
    ({"PEDNAV_RATE_LIMIT_PER_S": "-5"}, "PEDNAV_RATE_LIMIT_PER_S"),
    ({"PEDNAV_RATE_LIMIT_PER_S": "nan"}, "PEDNAV_RATE_LIMIT_PER_S"),
    ({"PEDNAV_RATE_LIMIT_BURST": "0"}, "PEDNAV_RATE_LIMIT_BURST"),
    ({"PEDNAV_RATE_LIMIT_BURST": "many"}, "PEDNAV_RATE_LIMIT_BURST"),
    ({"PEDNAV_MAX_PROFILE_BYTES": "1000"}, "PEDNAV_MAX_PROFILE_BYTES"),  # below what the engine hands out
    ({"PEDNAV_MAX_PROFILE_VERSIONS": "0"}, "PEDNAV_MAX_PROFILE_VERSIONS"),  # the current version must stay
    ({"PEDNAV_MAX_TOKENS_PER_USER": "0"}, "PEDNAV_MAX_TOKENS_PER_USER"),  # no user could mint a token
    ({"PEDNAV_MAX_TOKENS_PER_USER": "many"}, "PEDNAV_MAX_TOKENS_PER_USER"),
])
def test_bad_settings_fail_fast_naming_the_variable(monkeypatch, env, problem) -> None:  # type: ignore[no-untyped-def]
    for k, v in env.items():
        monkeypatch.setenv(k, v)
    with pytest.raises(SettingsError, match=problem):
        load_settings()


def test_default_settings_are_valid() -> None:
    s = Settings()
    assert s.token_ttl_s == 30 * 86_400 and s.rate_limit_per_s > 0 and s.rate_limit_burst >= 1
    assert s.max_tokens_per_user >= 1
    assert Settings(token_ttl_s=0).token_ttl_s == 0  # never expires


def test_admin_cli_token_lifetime(tmp_path, capsys) -> None:  # type: ignore[no-untyped-def]
    import json

    from clients.cli import main

    url = f"sqlite:///{tmp_path}/cli.db"
    assert main(["admin", "create-user", "ann", "--json", "--database-url", url, "--ttl-s", "3600"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert abs((datetime.fromisoformat(out["expires_at"]) - datetime.now(timezone.utc)).total_seconds() - 3600) < 60
    assert main(["admin", "token", "ann", "--json", "--database-url", url, "--ttl-s", "0"]) == 0
    assert json.loads(capsys.readouterr().out)["expires_at"] is None
    with pytest.raises(SystemExit):
        main(["admin", "token", "ann", "--json", "--database-url", url, "--ttl-s", "5"])
    assert "at least 60" in capsys.readouterr().err


def test_a_user_lists_their_tokens_without_secrets(client, make_user) -> None:  # type: ignore[no-untyped-def]
    """There was no way to see one's tokens: a user could only revoke the token in hand."""
    _, tok = make_user()
    _, other = make_user()
    client.post("/v1/tokens", headers=auth(other))  # someone else's token is not listed
    minted = client.post("/v1/tokens", json={"label": "watch", "ttl_s": 3600}, headers=auth(tok)).json()
    assert isinstance(minted["id"], int) and minted["label"] == "watch"  # added to the answer; nothing renamed
    assert {"user_id", "token", "expires_at"} <= minted.keys()
    gone = client.post("/v1/tokens", json={"label": "old phone"}, headers=auth(tok)).json()
    assert client.delete("/v1/tokens/current", headers=auth(gone["token"])).status_code == 204
    r = client.get("/v1/tokens", headers=auth(minted["token"]))
    assert r.status_code == 200, r.text
    rows = r.json()
    assert [t["label"] for t in rows] == ["initial", "watch", "old phone"]  # oldest first, only the caller's
    for t in rows:
        assert set(t) == {"id", "label", "created_at", "expires_at", "revoked", "live", "current"}
    assert "pn_" not in r.text and tok not in r.text and hash_token(tok) not in r.text
    by_label = {t["label"]: t for t in rows}
    assert by_label["watch"]["id"] == minted["id"] and by_label["watch"]["current"] is True
    assert by_label["watch"]["expires_at"] is not None and by_label["watch"]["live"] is True
    assert by_label["initial"]["current"] is False and by_label["initial"]["expires_at"] is None
    assert by_label["old phone"]["revoked"] is True and by_label["old phone"]["live"] is False


def test_a_user_revokes_a_token_by_id_and_another_users_id_is_404(client, make_user) -> None:  # type: ignore[no-untyped-def]
    _, tok = make_user()
    _, other = make_user()
    lost = client.post("/v1/tokens", json={"label": "lost phone"}, headers=auth(tok)).json()
    theirs = client.post("/v1/tokens", headers=auth(other)).json()
    r = client.delete(f"/v1/tokens/{lost['id']}", headers=auth(tok))
    assert r.status_code == 204, r.text
    r = client.get("/v1/users/me", headers=auth(lost["token"]))
    assert r.status_code == 401 and r.json()["detail"] == "token revoked"
    assert client.delete(f"/v1/tokens/{lost['id']}", headers=auth(tok)).status_code == 204  # again: no-op
    # someone else's token: 404 like an id that does not exist (not 403: ids are not probed), and it still works
    for tid in (theirs["id"], 10**9):
        r = client.delete(f"/v1/tokens/{tid}", headers=auth(tok))
        assert r.status_code == 404 and r.json()["detail"] == f"token {tid} not found", r.text
    assert client.get("/v1/users/me", headers=auth(theirs["token"])).status_code == 200
    r = client.delete("/v1/tokens/abc", headers=auth(tok))
    assert r.status_code == 422 and r.json()["field"] == "path.token_id"
    r = client.delete(f"/v1/tokens/{2**63}", headers=auth(tok))
    assert r.status_code == 422 and r.json()["field"] == "path.token_id"
    assert client.get("/v1/users/me", headers=auth(tok)).status_code == 200
    # DELETE /v1/tokens/current still revokes the token of the request, not a token with some id
    assert client.delete("/v1/tokens/current", headers=auth(tok)).status_code == 204
    assert client.get("/v1/users/me", headers=auth(tok)).json()["detail"] == "token revoked"


@pytest.fixture()
def capped(settings):  # type: ignore[no-untyped-def]
    """The app with at most 3 live tokens per user (and no rate limit, which is not under test here)."""
    with app_with(settings, max_tokens_per_user=3, rate_limit_per_s=0.0) as ac:
        yield ac


def test_a_user_holds_at_most_max_tokens_per_user_live_tokens(capped, make_user) -> None:  # type: ignore[no-untyped-def]
    """Any token could mint tokens without limit: the tokens table grew at the client's will (and, before the
    rate limit was per user, every token added a rate limit). Beyond the cap: 409 naming it, nothing minted."""
    app, c = capped
    uid, tok = make_user()
    minted = [c.post("/v1/tokens", headers=auth(tok)).json() for _ in range(2)]  # with the initial one: 3
    assert all("token" in m for m in minted)
    r = c.post("/v1/tokens", json={"label": "one too many"}, headers=auth(tok))
    assert r.status_code == 409, r.text
    detail = r.json()["detail"]
    assert detail.startswith("tokens: at most 3 live") and "holds 3" in detail and "DELETE /v1/tokens/{id}" in detail
    assert _token_count(app, uid) == 3  # nothing minted
    # a slot comes back when a token is revoked ...
    assert c.delete(f"/v1/tokens/{minted[0]['id']}", headers=auth(tok)).status_code == 204
    third = c.post("/v1/tokens", headers=auth(tok))
    assert third.status_code == 201, third.text
    assert c.post("/v1/tokens", headers=auth(tok)).status_code == 409
    # ... or expires
    _expire(app, third.json()["token"], datetime.now(timezone.utc) - timedelta(seconds=1))
    assert c.post("/v1/tokens", headers=auth(tok)).status_code == 201
    live = [t for t in c.get("/v1/tokens", headers=auth(tok)).json() if t["live"]]
    assert len(live) == 3
    # other users are not affected
    _, other = make_user()
    assert c.post("/v1/tokens", headers=auth(other)).status_code == 201


def test_revoked_and_expired_tokens_are_pruned_when_minting(capped, make_user) -> None:  # type: ignore[no-untyped-def]
    """With a cap on live tokens only, mint-and-revoke in a loop still grew the table without bound: minting now
    keeps the newest max_tokens_per_user dead tokens of the user and deletes the older ones."""
    app, c = capped
    uid, tok = make_user()
    dead = []
    for k in range(6):
        m = c.post("/v1/tokens", json={"label": f"t{k}"}, headers=auth(tok)).json()
        assert c.delete(f"/v1/tokens/{m['id']}", headers=auth(tok)).status_code == 204
        dead.append(m)
    # minting t5 kept the newest 3 dead (t2..t4) and deleted t0, t1; t5 was revoked after it
    assert _token_count(app, uid) == 1 + 3 + 1
    rows = c.get("/v1/tokens", headers=auth(tok)).json()
    assert [t["label"] for t in rows] == ["initial", "t2", "t3", "t4", "t5"]
    r = c.get("/v1/users/me", headers=auth(dead[0]["token"]))
    assert r.status_code == 401 and r.json()["detail"] == "invalid token"  # pruned: still refused
    assert c.get("/v1/users/me", headers=auth(tok)).status_code == 200  # live tokens are never pruned


def test_concurrent_mints_do_not_pass_the_cap_together(capped, make_user) -> None:  # type: ignore[no-untyped-def]
    """Each mint counts the user's live tokens; concurrent mints of one user take turns (PostgreSQL: a row lock
    on the user; SQLite: the write lock), so they cannot all see room for one more."""
    from concurrent.futures import ThreadPoolExecutor

    app, c = capped
    uid, tok = make_user()
    with ThreadPoolExecutor(8) as pool:
        codes = list(pool.map(lambda _: c.post("/v1/tokens", headers=auth(tok)).status_code, range(8)))
    assert sorted(codes) == [201, 201] + [409] * 6, codes
    assert _token_count(app, uid) == 3


def _user_exists(app, name: str) -> bool:  # type: ignore[no-untyped-def]
    from server import crud

    with app.state.sessionmaker() as db:
        return crud.user_by_name(db, name) is not None


def test_a_new_users_first_token_does_not_outlive_the_admins_token(client, app, make_user, settings) -> None:  # type: ignore[no-untyped-def]
    """POST /v1/users gave the new user's first token the full token_ttl_s (30 days) whatever the admin's token:
    an admin token that expired in an hour could leave behind an account usable for a month."""
    _, admin = make_user(admin=True)
    short = client.post("/v1/tokens", json={"ttl_s": 3600}, headers=auth(admin)).json()
    name = f"n{uuid.uuid4().hex[:10]}"
    r = client.post("/v1/users", json={"name": name}, headers=auth(short["token"]))
    assert r.status_code == 201, r.text
    assert settings.token_ttl_s > 3600
    assert datetime.fromisoformat(r.json()["expires_at"]) == datetime.fromisoformat(short["expires_at"])
    assert isinstance(r.json()["id"], int) and r.json()["label"] == "initial"
    assert client.get("/v1/users/me", headers=auth(r.json()["token"])).json()["name"] == name
    # an explicit lifetime beyond the admin's token: 422 naming ttl_s, and no user is created
    name2 = f"n{uuid.uuid4().hex[:10]}"
    r = client.post("/v1/users", json={"name": name2, "ttl_s": 7200}, headers=auth(short["token"]))
    assert r.status_code == 422, r.text
    assert r.json()["detail"].startswith("ttl_s: at most 3") and "cannot outlive" in r.json()["detail"]
    assert not _user_exists(app, name2)
    r = client.post("/v1/users", json={"name": name2, "ttl_s": 600}, headers=auth(short["token"]))
    assert r.status_code == 201
    assert abs((datetime.fromisoformat(r.json()["expires_at"]) - datetime.now(timezone.utc)).total_seconds() - 600) < 30
    # an admin token that never expires: the server's default lifetime, or ttl_s up to token_max_ttl_s
    r = client.post("/v1/users", json={"name": f"n{uuid.uuid4().hex[:10]}"}, headers=auth(admin))
    expected = datetime.now(timezone.utc) + timedelta(seconds=settings.token_ttl_s)
    assert abs((datetime.fromisoformat(r.json()["expires_at"]) - expected).total_seconds()) < 60
    r = client.post("/v1/users", json={"name": f"n{uuid.uuid4().hex[:10]}", "ttl_s": settings.token_max_ttl_s + 1},
                    headers=auth(admin))
    assert r.status_code == 422 and r.json()["detail"].startswith(f"ttl_s: at most {settings.token_max_ttl_s} s")
    r = client.post("/v1/users", json={"name": f"n{uuid.uuid4().hex[:10]}", "ttl_s": 5}, headers=auth(admin))
    assert r.status_code == 422 and r.json()["field"] == "ttl_s"
    # still admins only
    _, plain = make_user()
    r = client.post("/v1/users", json={"name": f"n{uuid.uuid4().hex[:10]}"}, headers=auth(plain))
    assert r.status_code == 403
