"""POST /v1/sensorlogger refusals: a push the engine would refuse is refused before it is stored (it poisoned
every later push of its session), out-of-range numbers and over-long names are 422, not 500."""

from __future__ import annotations

from typing import Any

import pytest

from tests.server.conftest import app_with, auth

T0 = 1_700_000_000_000_000_000


def _items(t0: int, n: int = 200, dt: int = 10_000_000, gyr: float = 0.001) -> list[dict[str, Any]]:
    """``n`` samples of a phone lying still: total acceleration [m/s^2], gyroscope [rad/s], magnetometer [uT]."""
    out = []
    for k in range(n):
        t = t0 + k * dt
        out += [{"name": "totalacceleration", "time": t, "values": {"x": 0.01, "y": 0.0, "z": 9.81}},
                {"name": "gyroscope", "time": t, "values": {"x": gyr, "y": 0.0, "z": 0.0}},
                {"name": "magnetometer", "time": t, "values": {"x": 20.0, "y": 0.0, "z": 40.0}}]
    return out


def _push(client, tok: str, mid: int, payload: list[dict[str, Any]], sl_id: str = "phone-1"):  # type: ignore[no-untyped-def]
    return client.post("/v1/sensorlogger", json={"messageId": mid, "sessionId": sl_id, "deviceId": "d",
                                                 "payload": payload}, headers=auth(tok))


def test_a_push_in_wrong_units_is_refused_and_does_not_block_the_session(client, make_user) -> None:  # type: ignore[no-untyped-def]
    _, a = make_user()
    for k in range(3):
        assert _push(client, a, k, _items(T0 + 2 * k * 10**9)).status_code == 200
    r = _push(client, a, 3, _items(T0 + 6 * 10**9, gyr=100.0))  # deg/s
    assert r.status_code == 422 and r.json()["field"] == "payload.gyroscope" and "deg/s" in r.json()["detail"]
    # before: message 3 was stored with 200, and every later push and the flush answered this 422 for good
    for k in (4, 5):
        r = _push(client, a, k, _items(T0 + 2 * k * 10**9))
        assert r.status_code == 200, r.text
    assert r.json()["positions"]
    sid = r.json()["session_id"]
    assert client.post("/v1/sensorlogger/phone-1/flush", headers=auth(a)).status_code == 200
    assert client.get(f"/v1/sessions/{sid}", headers=auth(a)).json()["next_seq"] >= 2


@pytest.mark.parametrize(
    "mutate, field",
    [
        (lambda m: {**m, "messageId": 2**63}, "messageId"),
        (lambda m: {**m, "sessionId": "s" * 101}, "sessionId"),
        (lambda m: {**m, "deviceId": "d" * 101}, "deviceId"),
        (lambda m: {**m, "payload": [{**m["payload"][0], "time": 2**63}] + m["payload"][1:]}, "payload.0.time"),
        (lambda m: {**m, "payload": [{**m["payload"][0], "values": {"x": 10**400, "y": 0, "z": 9.8}}] + m["payload"][1:]},
         "payload.totalacceleration.values.x"),
        (lambda m: {**m, "payload": [{**m["payload"][0], "values": {"x": True, "y": 0, "z": 9.8}}] + m["payload"][1:]},
         "payload.totalacceleration.values.x"),
        (lambda m: {**m, "payload": [{**m["payload"][0], "values": {"x": "0.01", "y": 0, "z": 9.8}}] + m["payload"][1:]},
         "payload.totalacceleration.values.x"),
        # lax integers: a time as a string, a float or a boolean was taken as nanoseconds
        (lambda m: {**m, "payload": [{**m["payload"][0], "time": str(T0)}] + m["payload"][1:]}, "payload.0.time"),
        (lambda m: {**m, "payload": [{**m["payload"][0], "time": float(T0)}] + m["payload"][1:]}, "payload.0.time"),
        (lambda m: {**m, "payload": [{**m["payload"][0], "time": True}] + m["payload"][1:]}, "payload.0.time"),
    ],
    ids=["message-id-beyond-int64", "long-session-id", "long-device-id", "time-beyond-int64", "value-beyond-float64",
         "boolean-value", "string-value", "string-time", "float-time", "boolean-time"],
)
def test_out_of_range_pushes_are_422_naming_the_field_and_store_nothing(client, make_user, mutate, field) -> None:  # type: ignore[no-untyped-def]
    _, a = make_user()
    msg = {"messageId": 1, "sessionId": "phone-2", "deviceId": "d", "payload": _items(T0, n=20)}
    r = client.post("/v1/sensorlogger", json=mutate(msg), headers=auth(a))
    assert r.status_code == 422 and r.json()["field"] == field, r.text
    assert client.get("/v1/sessions", headers=auth(a)).json() == []


def test_a_non_finite_sample_is_refused_before_it_is_stored(client, make_user) -> None:  # type: ignore[no-untyped-def]
    _, a = make_user()
    body = (b'{"messageId": 1, "sessionId": "phone-3", "payload": [{"name": "totalacceleration", '
            b'"time": 1700000000000000000, "values": {"x": NaN, "y": 0, "z": 9.8}}]}')
    r = client.post("/v1/sensorlogger", content=body, headers={**auth(a), "content-type": "application/json"})
    assert r.status_code == 422 and r.json()["field"] == "payload.totalacceleration" and "finite" in r.json()["detail"]
    assert client.get("/v1/sessions", headers=auth(a)).json() == []
    assert _push(client, a, 2, _items(T0), sl_id="phone-3").status_code == 200


def test_a_push_to_a_closed_session_is_409_and_not_stored(client, make_user, app) -> None:  # type: ignore[no-untyped-def]
    from sqlalchemy import func, select

    from server.models import SensorLoggerMessage

    _, a = make_user()
    sid = _push(client, a, 1, _items(T0), sl_id="phone-4").json()["session_id"]
    assert client.post(f"/v1/sessions/{sid}/close", headers=auth(a)).status_code == 200
    r = _push(client, a, 2, _items(T0 + 2 * 10**9), sl_id="phone-4")
    assert r.status_code == 409 and "closed" in r.json()["detail"]
    assert _push(client, a, 1, _items(T0), sl_id="phone-4").json()["duplicate"] is True  # a retry is still answered
    with app.state.sessionmaker() as db:
        n = db.execute(select(func.count()).select_from(SensorLoggerMessage).where(SensorLoggerMessage.session_id == sid))
        assert n.scalar_one() == 1


# ---------------------------------------------------------------- taken whole or not at all
def _stream_items(t0: int, n: int, dt: int = 10_000_000, mag=lambda k: 40.0, gyr=lambda k: 0.001,  # type: ignore[no-untyped-def]
                  acc: str = "totalacceleration", gyr_every: int = 1) -> list[dict[str, Any]]:
    """``n`` samples of a phone lying still, with the magnetometer's z (x: half of it) [uT] and the gyroscope's x
    [rad/s] per sample ``k``; ``acc="accelerometer"``: Sensor Logger's accelerometer without gravity (and no gravity samples)."""
    out = []
    for k in range(n):
        t = t0 + k * dt
        a = {"x": 0.01, "y": 0.0, "z": 9.81 if acc == "totalacceleration" else 0.0}
        out += [{"name": acc, "time": t, "values": a},
                {"name": "magnetometer", "time": t, "values": {"x": mag(k) / 2, "y": 0.0, "z": mag(k)}}]
        if k % gyr_every == 0:
            out.append({"name": "gyroscope", "time": t, "values": {"x": gyr(k), "y": 0.0, "z": 0.0}})
    return out


def _stored(app, uid: int) -> int:  # type: ignore[no-untyped-def]
    """Sensor Logger messages stored for the user's sessions."""
    from sqlalchemy import func, select

    from server.models import SensorLoggerMessage, TrackSession

    with app.state.sessionmaker() as db:
        q = select(func.count()).select_from(SensorLoggerMessage).join(
            TrackSession, TrackSession.id == SensorLoggerMessage.session_id).where(TrackSession.user_id == uid)
        return db.execute(q).scalar_one()


S = 10**9
BAD_PUSHES = {
    # Sensor Logger's accelerometer excludes gravity: stored with 200, then the next push that fed it was 422
    "accelerometer-without-gravity": ([_stream_items(T0 + 2 * k * S, 200, acc="accelerometer") for k in range(3)],
                                      "payload.accelerometer"),
    # 5 gyroscope samples a message (fewer than the 10 the unit check needs) in deg/s: each message was taken,
    # then the window of two messages held 10 and every push from then on answered 422 after storing its message
    "few-samples-in-deg-s": ([_stream_items(T0 + k * S, 100, gyr=lambda k: 100.0, gyr_every=20) for k in range(4)],
                             "payload.gyroscope"),
}


@pytest.mark.parametrize("case", sorted(BAD_PUSHES))
def test_a_push_is_taken_whole_or_not_at_all(client, app, make_user, case) -> None:  # type: ignore[no-untyped-def]
    """Every 4xx stores nothing and every 2xx answers a stored message; after bad pushes good ones go on."""
    uid, a = make_user()
    pushes, field = BAD_PUSHES[case]
    for mid, payload in enumerate(pushes):
        before = _stored(app, uid)
        r = _push(client, a, mid, payload, sl_id=case)
        assert r.status_code == 422 and r.json()["field"] == field, r.text
        assert _stored(app, uid) == before, f"push {mid}: answered {r.status_code} but stored"
    t0 = T0 + 20 * S
    for k in range(3):
        r = _push(client, a, 100 + k, _items(t0 + 2 * k * S), sl_id=case)
        assert r.status_code == 200, r.text
        assert _stored(app, uid) == k + 1
    assert r.json()["skipped_samples"] == 0 and r.json()["skipped"] is None
    r = client.post(f"/v1/sensorlogger/{case}/flush", headers=auth(a))
    assert r.status_code == 200 and r.json()["skipped"] is None
    assert client.get(f"/v1/sessions/{r.json()['session_id']}", headers=auth(a)).json()["next_seq"] == 3  # all fed


def test_a_message_that_spoils_the_window_it_is_fed_in_is_refused(client, app, make_user) -> None:  # type: ignore[no-untyped-def]
    """A 10-s message whose magnetometer reads gauss for its first 4.9 s passes on its own (median in uT), but
    the first 8 s it feeds do not: refused whole (422), no session, no message."""
    uid, a = make_user()
    r = _push(client, a, 1, _stream_items(T0, 1000, mag=lambda k: 0.4 if k < 490 else 40.0), sl_id="spoiler")
    assert r.status_code == 422 and r.json()["field"] == "payload.magnetometer", r.text
    assert "held-back samples this push would feed" in r.json()["detail"]
    assert _stored(app, uid) == 0 and client.get("/v1/sessions", headers=auth(a)).json() == []
    assert _push(client, a, 2, _items(T0), sl_id="spoiler").status_code == 200


def test_held_back_samples_unusable_together_are_skipped_not_blocking(client, app, make_user) -> None:  # type: ignore[no-untyped-def]
    """A 6-s message whose last 2 s of magnetometer read gauss passes on its own and its first 4 s are fed; the
    held-back 2 s cannot be fed with anything. The next push was answered 422 after its message was stored, and
    so was every later one. Now it is taken and its answer says what was skipped; the session goes on."""
    uid, a = make_user()
    r = _push(client, a, 1, _stream_items(T0, 600, mag=lambda k: 0.4 if k >= 400 else 40.0), sl_id="tail")
    assert r.status_code == 200 and r.json().get("skipped") is None, r.text
    r = _push(client, a, 2, _items(T0 + 6 * S), sl_id="tail")
    assert r.status_code == 200, r.text
    assert r.json()["skipped"]["field"] == "payload.magnetometer" and "uT" in r.json()["skipped"]["problem"]
    assert r.json()["skipped_samples"] == 3 * 200
    assert _stored(app, uid) == 2
    for k in range(2):
        r = _push(client, a, 3 + k, _items(T0 + (8 + 2 * k) * S), sl_id="tail")
        assert r.status_code == 200 and r.json()["skipped"] is None, r.text
    r = client.post("/v1/sensorlogger/tail/flush", headers=auth(a))
    assert r.status_code == 200 and r.json()["skipped"] is None
    sid = r.json()["session_id"]
    assert client.get(f"/v1/sessions/{sid}", headers=auth(a)).json()["next_seq"] == 4  # A's first 4 s, then 3 windows


# ---------------------------------------------------------------- sample limits
@pytest.fixture()
def small_limit(settings):  # type: ignore[no-untyped-def]
    with app_with(settings, max_samples_per_stream=150, sensorlogger_hold_s=10.0) as ac:
        yield ac


def test_a_push_beyond_the_sample_limit_is_413_and_stores_nothing(small_limit, make_user) -> None:  # type: ignore[no-untyped-def]
    """max_samples_per_stream bounded uploaded batches only: a push of any number of samples (up to the body
    limit) was stored and reached the engine whole."""
    app, c = small_limit
    uid, a = make_user()
    r = _push(c, a, 1, _items(T0, n=151), sl_id="big")
    assert r.status_code == 413, r.text
    assert r.json()["detail"] == "payload.gyroscope: 151 samples exceed the limit of 150 per stream and message"
    assert _stored(app, uid) == 0 and c.get("/v1/sessions", headers=auth(a)).json() == []
    assert _push(c, a, 2, _items(T0, n=150), sl_id="big").status_code == 200


def test_held_back_samples_are_fed_in_batches_within_the_sample_limit(small_limit, make_user) -> None:  # type: ignore[no-untyped-def]
    """Messages held back (hold 10 s here) were fed as ONE batch however many samples they held (1000 per stream
    once a push moved the horizon 20 s on); now in pieces of at most max_samples_per_stream, none lost."""
    _, c = small_limit
    _, a = make_user()
    for k in range(11):
        assert _push(c, a, k, _items(T0 + k * S, n=100), sl_id="held").status_code == 200
    r = _push(c, a, 11, _items(T0 + 30 * S, n=100), sl_id="held")  # the horizon moves to T0 + 21 s
    assert r.status_code == 200 and r.json()["skipped"] is None, r.text
    sid = r.json()["session_id"]
    batches = c.get(f"/v1/sessions/{sid}/batches", headers=auth(a)).json()
    assert max(b["n_acc"] for b in batches) <= 150 and max(b["n_gyr"] for b in batches) <= 150
    assert sum(b["n_acc"] for b in batches) == 1100  # the 11 first messages, every sample once
    r = c.post("/v1/sensorlogger/held/flush", headers=auth(a))
    assert r.status_code == 200 and r.json()["skipped"] is None
    batches = c.get(f"/v1/sessions/{sid}/batches", headers=auth(a)).json()
    assert sum(b["n_acc"] for b in batches) == 1200 and max(b["n_mag"] for b in batches) <= 150


# ---------------------------------------------------------------- concurrent pushes to one session
def _fed(c, tok: str, sid: int) -> list[int]:  # type: ignore[no-untyped-def]
    """The accelerometer times of every batch fed to the session, in sequence order."""
    from server.formats import decode_batch

    out: list[int] = []
    for b in c.get(f"/v1/sessions/{sid}/batches", headers=auth(tok)).json():
        raw = c.get(f"/v1/sessions/{sid}/batches/{b['seq']}/raw", headers=auth(tok))
        out += decode_batch(raw.content, raw.headers["content-type"], 10**6, allow_empty=True).acc_t_ns.tolist()
    return out


@pytest.mark.parametrize("where", ["_feed", "apply_batch"], ids=["before-its-feed", "between-seq-read-and-write"])
def test_a_push_overtaken_while_it_feeds_is_taken_and_feeds_nothing_twice(client, app, make_user, monkeypatch,  # type: ignore[no-untyped-def]
                                                                           where) -> None:
    """Push B (message 2) stores and feeds while push A (message 1) has stored its message but not fed yet (before
    A's feed, or between its read of the next sequence number and its write). A then fed the window it had read
    before B under the number B had used: answered 409 (``sequence 0 was already used``) after its message was
    stored. Now A reads again and feeds what is left: both 200, every sample once."""
    import threading

    from server.routers import sensorlogger

    uid, a = make_user()
    assert _push(client, a, 0, _items(T0), sl_id=where).status_code == 200  # held back: nothing fed yet
    real, answers = getattr(sensorlogger, where), {}

    def overtaken(*args, **kw):  # type: ignore[no-untyped-def]
        if not answers:  # A's first feed: B pushes and feeds in between (in another thread: its own connection)
            answers["B"] = None
            t = threading.Thread(target=lambda: answers.update(B=_push(client, a, 2, _items(T0 + 4 * S), sl_id=where)))
            t.start()
            t.join()
        return real(*args, **kw)

    monkeypatch.setattr(sensorlogger, where, overtaken)
    r = _push(client, a, 1, _items(T0 + 2 * S), sl_id=where)
    monkeypatch.setattr(sensorlogger, where, real)
    assert answers["B"].status_code == 200, answers["B"].text
    assert r.status_code == 200, r.text
    assert _stored(app, uid) == 3
    sid = r.json()["session_id"]
    assert client.post(f"/v1/sensorlogger/{where}/flush", headers=auth(a)).status_code == 200
    fed = _fed(client, a, sid)
    assert fed == sorted(set(fed)) and len(fed) == 3 * 200  # each sample fed once, in time order


# FastAPI silences this pydantic warning with warnings.catch_warnings(), which is not thread-safe: with requests
# in several threads of a new app at once it leaks now and then (harmless)
@pytest.mark.filterwarnings("ignore::pydantic.warnings.UnsupportedFieldAttributeWarning")
def test_concurrent_pushes_from_two_workers_are_all_taken_and_fed_once(settings, make_user) -> None:  # type: ignore[no-untyped-def]
    """Rounds of 6 pushes at once (messages of 0.5 s, in any order within the 5-s hold) to one session through
    two workers (own engines and locks: only the database orders them). Pushes were answered after their messages
    were stored 409 (a sequence number another push had used) or 422 (``not after the last one processed``: samples
    another push had fed, fed again), and first pushes 500 (both created the session's link). Now: all 200, every
    sample fed once."""
    import threading

    uid, a = make_user()
    rounds, per_round, n = 5, 6, 50
    with app_with(settings, sensorlogger_hold_s=5.0) as (app1, c1), app_with(settings, sensorlogger_hold_s=5.0) as (_, c2):
        answers: list[Any] = []
        for r in range(rounds):
            barrier = threading.Barrier(per_round)

            def send(c: Any, mid: int) -> None:
                barrier.wait()
                try:
                    answers.append(_push(c, a, mid, _items(T0 + mid * S // 2, n=n), sl_id="crowd"))
                except Exception as exc:  # noqa: BLE001 - a 500, raised by the test client
                    answers.append(exc)

            threads = [threading.Thread(target=send, args=((c1, c2)[k % 2], r * per_round + k)) for k in range(per_round)]
            for t in threads:
                t.start()
            for t in threads:
                t.join()
        codes = [getattr(x, "status_code", 500) for x in answers]
        assert codes == [200] * rounds * per_round, [getattr(x, "text", repr(x)) for x, c in zip(answers, codes) if c != 200]
        assert _stored(app1, uid) == rounds * per_round
        r = c1.post("/v1/sensorlogger/crowd/flush", headers=auth(a))
        assert r.status_code == 200 and r.json()["skipped"] is None, r.text
        fed = _fed(c1, a, r.json()["session_id"])
    assert max(x.json()["late_samples"] for x in answers) == 0
    assert fed == sorted(set(fed)) and len(fed) == rounds * per_round * n  # each sample fed once, in time order
