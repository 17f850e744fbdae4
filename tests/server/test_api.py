"""Routes of the REST API: happy paths and refusals, on SQLite and PostgreSQL (see conftest)."""

from __future__ import annotations

import csv
import io
import json

import msgpack
import numpy as np
import pytest

from models.batch import SensorBatch
from server.formats import MSGPACK_TYPE, encode_json, encode_msgpack
from tests.server.conftest import app_with, auth, still_batch

T0 = 1_700_000_000_000_000_000  # UTC epoch ns


def _start(client, token: str, **kw) -> int:  # type: ignore[no-untyped-def]
    r = client.post("/v1/sessions", json={"device_kind": "foot", **kw}, headers=auth(token))
    assert r.status_code == 201, r.text
    return r.json()["id"]


def _put(client, token: str, sid: int, seq: int, batch: SensorBatch, binary: bool = True):  # type: ignore[no-untyped-def]
    if binary:
        return client.put(f"/v1/sessions/{sid}/batches/{seq}", content=encode_msgpack(batch),
                          headers={**auth(token), "content-type": MSGPACK_TYPE})
    return client.put(f"/v1/sessions/{sid}/batches/{seq}", content=encode_json(batch),
                      headers={**auth(token), "content-type": "application/json"})


# ---------------------------------------------------------------- auth and users
@pytest.mark.parametrize("headers", [{}, {"Authorization": "Bearer nope"}, {"Authorization": "Basic abc"}])
def test_unauthenticated_requests_are_refused(client, headers) -> None:  # type: ignore[no-untyped-def]
    for method, path in (("get", "/v1/users/me"), ("get", "/v1/sessions"), ("get", "/v1/profiles"), ("get", "/v1/devices")):
        r = getattr(client, method)(path, headers=headers)
        assert r.status_code == 401, (path, r.text)


def test_admin_creates_users_and_others_cannot(client, make_user) -> None:  # type: ignore[no-untyped-def]
    _, admin = make_user(admin=True)
    _, plain = make_user()
    name = f"bob{np.random.default_rng().integers(1e9)}"
    r = client.post("/v1/users", json={"name": name}, headers=auth(admin))
    assert r.status_code == 201
    new_token = r.json()["token"]
    assert client.get("/v1/users/me", headers=auth(new_token)).json()["name"] == name
    assert client.post("/v1/users", json={"name": name}, headers=auth(admin)).status_code == 409
    assert client.post("/v1/users", json={"name": name + "x"}, headers=auth(plain)).status_code == 403
    r = client.post("/v1/users", json={"name": "bad name!"}, headers=auth(admin))
    assert r.status_code == 422 and r.json()["field"] == "name"


def test_tokens_minted_and_revoked(client, make_user) -> None:  # type: ignore[no-untyped-def]
    _, tok = make_user()
    r = client.post("/v1/tokens", headers=auth(tok))
    second = r.json()["token"]
    assert r.status_code == 201 and second != tok
    assert client.delete("/v1/tokens/current", headers=auth(second)).status_code == 204
    assert client.get("/v1/users/me", headers=auth(second)).status_code == 401
    assert client.get("/v1/users/me", headers=auth(tok)).status_code == 200


def test_tokens_are_stored_hashed(app, make_user) -> None:  # type: ignore[no-untyped-def]
    from sqlalchemy import select

    from server.models import Token

    uid, tok = make_user()
    with app.state.sessionmaker() as db:
        hashes = list(db.execute(select(Token.token_hash).where(Token.user_id == uid)).scalars())
    assert hashes and tok not in hashes and all(len(h) == 64 for h in hashes)


# ---------------------------------------------------------------- devices
@pytest.mark.parametrize(
    "method, path, body, field",
    [
        ("post", "/v1/devices", {"kind": "watch", "colour": "red"}, "colour"),
        ("put", "/v1/profiles/walk", {"data": {"n_steps": 1}, "behaviour": "run"}, "behaviour"),
        ("post", "/v1/users", {"name": "carol", "is_admin": True}, "is_admin"),
    ],
)
def test_unknown_fields_are_422_naming_them(client, make_user, method, path, body, field) -> None:  # type: ignore[no-untyped-def]
    """Unknown fields were ignored with 201/200 (a new user asked to be an admin was created as a plain one)."""
    _, admin = make_user(admin=True)
    r = getattr(client, method)(path, json=body, headers=auth(admin))
    assert r.status_code == 422 and r.json()["field"] == field, r.text
    assert client.get("/v1/devices", headers=auth(admin)).json() == []
    assert client.get("/v1/profiles", headers=auth(admin)).json() == []


@pytest.mark.parametrize(
    "content, ctype, problem",
    [
        (b'{"kind": "watch",', "application/json", "not valid JSON"),
        (b'{"kind": "watch"}', "text/plain", "Content-Type: application/json"),
        (b'{"kind": "watch"}', None, "Content-Type: application/json"),
    ],
    ids=["truncated-json", "text-plain", "no-content-type"],
)
def test_unreadable_bodies_are_422_naming_the_body(client, make_user, content, ctype, problem) -> None:  # type: ignore[no-untyped-def]
    """A JSON syntax error was reported as field "17" (the character offset) and a body sent without the JSON
    content type as field "" ("Input should be a valid dictionary ...")."""
    _, a = make_user()
    headers = {**auth(a), **({"content-type": ctype} if ctype else {})}
    r = client.post("/v1/devices", content=content, headers=headers)
    assert r.status_code == 422 and r.json()["field"] == "body", r.text
    assert r.json()["detail"].startswith("body: ") and problem in r.json()["detail"]


def test_devices_crud_and_isolation(client, make_user) -> None:  # type: ignore[no-untyped-def]
    _, a = make_user()
    _, b = make_user()
    r = client.post("/v1/devices", json={"kind": "watch", "name": "left wrist"}, headers=auth(a))
    assert r.status_code == 201
    did = r.json()["id"]
    assert [d["id"] for d in client.get("/v1/devices", headers=auth(a)).json()] == [did]
    assert client.get(f"/v1/devices/{did}", headers=auth(a)).status_code == 200
    assert client.get(f"/v1/devices/{did}", headers=auth(b)).status_code == 404
    assert client.get("/v1/devices", headers=auth(b)).json() == []
    r = client.post("/v1/devices", json={"kind": "toaster"}, headers=auth(a))
    assert r.status_code == 422 and r.json()["field"] == "kind"
    # b cannot start a session on a's device
    r = client.post("/v1/sessions", json={"device_kind": "watch", "device_id": did}, headers=auth(b))
    assert r.status_code == 404 and "device_id" in r.json()["detail"]


# ---------------------------------------------------------------- sessions
def test_a_weak_field_wake_configuration_is_served_whole(client, make_user) -> None:  # type: ignore[no-untyped-def]
    """The engine's Gait-DR configuration with the device's weak-field wake (threshold and the compass's
    calibration) goes out through the session's schema unchanged, as the device must apply it."""
    from energy.types import SensorConfig
    from server.models import TrackSession

    _, a = make_user()
    sid = _start(client, a)
    cfg = SensorConfig(gyro_on=False, acc_rate_hz=25.0, gyr_rate_hz=200.0, mag_rate_hz=25.0, batch_s=4.0,
                       gyro_wake_on_motion=True, sleep_after_s=2.0, wake_mode="weak_field", wake_field_ut=6.6,
                       mag_offset_ut=(1.0, -2.0, 3.0), mag_matrix=(1.0, 0.1, 0.0, 0.0, 0.9, 0.0, 0.0, 0.0, 1.1))
    with client.app.state.sessionmaker() as db:
        db.get(TrackSession, sid).sensor_config = cfg.to_dict()
        db.commit()
    r = client.get(f"/v1/sessions/{sid}", headers=auth(a))
    assert r.status_code == 200 and SensorConfig(**r.json()["sensor_config"]) == cfg


def test_session_lifecycle(client, make_user) -> None:  # type: ignore[no-untyped-def]
    _, a = make_user()
    sid = _start(client, a, latitude_deg=43.66, longitude_deg=-79.39, altitude_m=80.0)
    s = client.get(f"/v1/sessions/{sid}", headers=auth(a)).json()
    assert s["status"] == "open" and s["next_seq"] == 0 and s["sensor_config"] is not None
    assert [x["id"] for x in client.get("/v1/sessions?status=open", headers=auth(a)).json()] == [sid]
    r = client.post(f"/v1/sessions/{sid}/close", headers=auth(a))
    assert r.status_code == 200 and r.json()["status"] == "closed"
    assert client.post(f"/v1/sessions/{sid}/close", headers=auth(a)).json()["closed_at"] == r.json()["closed_at"]
    assert client.get("/v1/sessions?status=open", headers=auth(a)).json() == []


@pytest.mark.parametrize(
    "body, field",
    [
        ({"device_kind": "fridge"}, "device_kind"),
        ({"device_kind": "phone", "latitude_deg": 91.0, "longitude_deg": 0.0}, "latitude_deg"),
        ({"device_kind": "phone", "latitude_deg": 10.0}, "latitude_deg"),
        ({}, "device_kind"),
        # a misspelt field was ignored: 201 and a session without its geodetic start (GeoJSON export: 409)
        ({"device_kind": "phone", "latitude": 43.66, "longitude": -79.39}, "latitude"),
    ],
)
def test_session_start_validation_names_the_field(client, make_user, body, field) -> None:  # type: ignore[no-untyped-def]
    _, a = make_user()
    r = client.post("/v1/sessions", json=body, headers=auth(a))
    assert r.status_code == 422
    assert field in r.json()["detail"]


_GEO = {"device_kind": "phone", "latitude_deg": 43.66, "longitude_deg": -79.39, "altitude_m": 80.0}


@pytest.mark.parametrize("field", ["latitude_deg", "longitude_deg", "altitude_m"])
@pytest.mark.parametrize("value", ["12.5", "0", True, None], ids=["number-string", "zero-string", "bool", "NaN"])
def test_session_coordinates_are_strict_numbers(client, make_user, field, value) -> None:  # type: ignore[no-untyped-def]
    """A number string ("12.5") was converted and stored as the geodetic start: coordinates are JSON numbers now
    (422 naming the field); NaN (which Python's JSON parser reads) is refused as well."""
    _, a = make_user()
    if value is None:  # NaN: not valid JSON, but accepted by the parser
        r = client.post("/v1/sessions", content=json.dumps({**_GEO, field: float("nan")}),
                        headers={**auth(a), "content-type": "application/json"})
    else:
        r = client.post("/v1/sessions", json={**_GEO, field: value}, headers=auth(a))
    assert r.status_code == 422, r.text
    assert r.json()["field"] == field and r.json()["detail"].startswith(f"{field}: "), r.text
    assert client.get("/v1/sessions", headers=auth(a)).json() == []  # no session started


@pytest.mark.parametrize("value", ["5", True, 5.5], ids=["number-string", "bool", "fraction"])
def test_session_device_id_is_a_strict_integer(client, make_user, value) -> None:  # type: ignore[no-untyped-def]
    """A device id sent as "5" (or true) was converted and taken: it is a JSON integer now (422 naming it)."""
    _, a = make_user()
    r = client.post("/v1/sessions", json={"device_kind": "phone", "device_id": value}, headers=auth(a))
    assert r.status_code == 422 and r.json()["field"] == "device_id", r.text
    assert client.get("/v1/sessions", headers=auth(a)).json() == []


@pytest.mark.parametrize("field, value", [
    ("latitude_deg", 90.0001), ("latitude_deg", -91), ("longitude_deg", 180.5), ("longitude_deg", -181),
    ("altitude_m", -501), ("altitude_m", 1e6),
])
def test_session_coordinates_out_of_range_name_the_field(client, make_user, field, value) -> None:  # type: ignore[no-untyped-def]
    _, a = make_user()
    r = client.post("/v1/sessions", json={**_GEO, field: value}, headers=auth(a))
    assert r.status_code == 422 and r.json()["field"] == field, r.text
    assert "less than or equal" in r.json()["detail"] or "greater than or equal" in r.json()["detail"]


def test_session_coordinates_take_integers_and_the_bounds(client, make_user) -> None:  # type: ignore[no-untyped-def]
    _, a = make_user()
    r = client.post("/v1/sessions", json={"device_kind": "phone", "latitude_deg": -90, "longitude_deg": 180,
                                          "altitude_m": 0}, headers=auth(a))
    assert r.status_code == 201, r.text
    assert (r.json()["latitude_deg"], r.json()["longitude_deg"], r.json()["altitude_m"]) == (-90.0, 180.0, 0.0)


def test_sessions_isolated_between_users(client, make_user) -> None:  # type: ignore[no-untyped-def]
    _, a = make_user()
    _, b = make_user()
    sid = _start(client, a)
    assert _put(client, a, sid, 0, still_batch(T0)).status_code == 200
    for method, path in (
        ("get", f"/v1/sessions/{sid}"),
        ("post", f"/v1/sessions/{sid}/close"),
        ("get", f"/v1/sessions/{sid}/trajectory"),
        ("get", f"/v1/sessions/{sid}/events"),
        ("get", f"/v1/sessions/{sid}/batches"),
        ("get", f"/v1/sessions/{sid}/batches/0/raw"),
    ):
        assert getattr(client, method)(path, headers=auth(b)).status_code == 404, path
    assert _put(client, b, sid, 1, still_batch(T0 + 10**9)).status_code == 404
    assert client.get("/v1/sessions", headers=auth(b)).json() == []
    # nothing b did changed a's session
    assert client.get(f"/v1/sessions/{sid}", headers=auth(a)).json()["next_seq"] == 1


# ---------------------------------------------------------------- batches
@pytest.mark.parametrize("binary", [True, False], ids=["msgpack", "json"])
def test_batch_retry_is_idempotent(client, make_user, binary) -> None:  # type: ignore[no-untyped-def]
    _, a = make_user()
    sid = _start(client, a)
    r0 = _put(client, a, sid, 0, still_batch(T0), binary)
    assert r0.status_code == 200 and r0.headers["x-pednav-replayed"] == "false"
    assert r0.json()["next_seq"] == 1
    again = _put(client, a, sid, 0, still_batch(T0), not binary)  # same content, other encoding
    assert again.status_code == 200 and again.headers["x-pednav-replayed"] == "true"
    assert again.json() == r0.json()
    batches = client.get(f"/v1/sessions/{sid}/batches", headers=auth(a)).json()
    assert [b["seq"] for b in batches] == [0]
    assert client.get(f"/v1/sessions/{sid}", headers=auth(a)).json()["next_seq"] == 1


def test_batch_sequence_conflicts_say_what_is_expected(client, make_user) -> None:  # type: ignore[no-untyped-def]
    _, a = make_user()
    sid = _start(client, a)
    r = _put(client, a, sid, 3, still_batch(T0))
    assert r.status_code == 409 and r.json()["expected_seq"] == 0 and "expected sequence 0" in r.json()["detail"]
    assert _put(client, a, sid, 0, still_batch(T0)).status_code == 200
    r = _put(client, a, sid, 0, still_batch(T0, seed=5))  # reused number, other content
    assert r.status_code == 409 and r.json()["expected_seq"] == 1
    client.post(f"/v1/sessions/{sid}/close", headers=auth(a))
    r = _put(client, a, sid, 1, still_batch(T0 + 10**9))
    assert r.status_code == 409 and "closed" in r.json()["detail"]
    assert _put(client, a, sid, 0, still_batch(T0)).status_code == 200  # a late retry still gets its answer


@pytest.mark.parametrize(
    "mutate, field",
    [
        (lambda b: SensorBatch(acc_t_ns=b.acc_t_ns, acc=b.acc / 9.81), "acc"),  # g instead of m/s^2
        (lambda b: SensorBatch(acc_t_ns=b.acc_t_ns, acc=b.acc, gyr_t_ns=b.gyr_t_ns, gyr=b.gyr * 0 + 90.0), "gyr"),
        (lambda b: SensorBatch(acc_t_ns=b.acc_t_ns[::-1].copy(), acc=b.acc), "acc_t_ns"),
        (lambda b: SensorBatch(acc_t_ns=b.acc_t_ns, acc=np.where(np.arange(len(b.acc))[:, None] == 3, np.nan, b.acc)), "acc"),
        (lambda b: SensorBatch(acc_t_ns=b.acc_t_ns, acc=b.acc, mag_t_ns=b.mag_t_ns, mag=b.mag / 100.0), "mag"),
        # one sample no sensor can report in an otherwise plausible batch: the engine raised LinAlgError (500)
        (lambda b: SensorBatch(acc_t_ns=b.acc_t_ns, acc=np.where(np.arange(len(b.acc))[:, None] == 50, 1e300, b.acc)), "acc"),
        (lambda b: SensorBatch(acc_t_ns=b.acc_t_ns, acc=b.acc, mag_t_ns=b.mag_t_ns,
                               mag=np.where(np.arange(len(b.mag))[:, None] == 50, 1e30, b.mag)), "mag"),
    ],
    ids=["acc-in-g", "gyr-in-deg", "time-reversed", "nan", "mag-in-gauss", "acc-beyond-any-sensor", "mag-beyond-any-sensor"],
)
def test_invalid_batches_are_422_naming_the_field_and_store_nothing(client, make_user, mutate, field) -> None:  # type: ignore[no-untyped-def]
    _, a = make_user()
    sid = _start(client, a)
    bad = mutate(still_batch(T0))
    r = _put(client, a, sid, 0, bad, binary=False)
    assert r.status_code == 422, r.text
    assert r.json()["field"] == field and field in r.json()["detail"]
    assert client.get(f"/v1/sessions/{sid}/batches", headers=auth(a)).json() == []
    assert client.get(f"/v1/sessions/{sid}", headers=auth(a)).json()["next_seq"] == 0
    assert _put(client, a, sid, 0, still_batch(T0)).status_code == 200


@pytest.mark.parametrize(
    "body, ctype, field",
    [
        (b"{not json", "application/json", "body"),
        (b'{"acc": {"t_ns": [1, 2], "xyz": [[1, 2, 3]]}}', "application/json", "acc.xyz"),
        (b'{"acc": {"t_ns": [1.5], "xyz": [[1, 2, 3]]}}', "application/json", "acc.t_ns"),
        (b'{"baro": {}}', "application/json", "baro"),
        (b"\xc1", MSGPACK_TYPE, "body"),
        (b"abc", "text/plain", "content-type"),
        # these four answered 500 (OverflowError, RecursionError, TypeError escaped the decoder)
        (b'{"acc": {"t_ns": [1], "xyz": [[1%s, 0, 0]]}}' % (b"0" * 400), "application/json", "acc.xyz"),
        (b"[" * 100_000 + b"]" * 100_000, "application/json", "body"),
        (msgpack.packb({"v": 1, "acc": {"n": 1, "t0": 2**64 - 1, "dt": b"", "dtype": "<f8",
                                        "xyz": np.zeros(3).tobytes()}}), MSGPACK_TYPE, "acc.t0"),
        (msgpack.packb({"v": 1, "acc": {"n": True, "t0": 0, "dt": b"", "dtype": "<f8",
                                        "xyz": np.zeros(3).tobytes()}}), MSGPACK_TYPE, "acc.n"),
        (msgpack.packb({"v": 1, "acc": {"n": 1, "t0": True, "dt": b"", "dtype": "<f8",
                                        "xyz": np.zeros(3).tobytes()}}), MSGPACK_TYPE, "acc.dt"),
    ],
    ids=["not-json", "rows-mismatch", "float-time", "unknown-stream", "not-msgpack", "text-plain", "int-beyond-float64",
         "nested-too-deep", "msgpack-t0-beyond-int64", "msgpack-n-bool", "msgpack-t0-bool"],
)
def test_malformed_bodies_are_422(client, make_user, body, ctype, field) -> None:  # type: ignore[no-untyped-def]
    _, a = make_user()
    sid = _start(client, a)
    r = client.put(f"/v1/sessions/{sid}/batches/0", content=body, headers={**auth(a), "content-type": ctype})
    assert r.status_code == 422 and r.json()["field"] == field, r.text


@pytest.mark.parametrize("value, got", [('"1.5"', "string '1.5'"), ("true", "boolean True"), ("null", "null None"),
                                        ('[1.5]', "array [1.5]")],
                         ids=["string", "boolean", "null", "array"])
@pytest.mark.parametrize("stream", ["acc", "gyr", "mag"])
def test_sample_values_must_be_json_numbers(client, make_user, stream, value, got) -> None:  # type: ignore[no-untyped-def]
    """The JSON upload read sample values through numpy: the string "1.5" was taken as 1.5 and true as 1.0."""
    _, a = make_user()
    sid = _start(client, a)
    b = still_batch(T0)
    doc = {name: {"t_ns": b.stream(name)[0].tolist(), "xyz": b.stream(name)[1].tolist()} for name in ("acc", "gyr", "mag")}
    doc[stream]["xyz"][4][0] = json.loads(value)
    text = json.dumps(doc)
    r = client.put(f"/v1/sessions/{sid}/batches/0", content=text, headers={**auth(a), "content-type": "application/json"})
    assert r.status_code == 422, r.text
    assert r.json()["field"] == f"{stream}.xyz"
    assert r.json()["detail"] == f"{stream}.xyz: row 4, value 0: must be a number, got {got}"
    assert client.get(f"/v1/sessions/{sid}", headers=auth(a)).json()["next_seq"] == 0


def test_an_empty_json_stream_is_a_stream_the_device_did_not_sample(client, make_user) -> None:  # type: ignore[no-untyped-def]
    """``{"t_ns": [], "xyz": []}`` is what a device whose gyroscope is off sends for it; the msgpack form (``n: 0``)
    was accepted while the JSON form got 422 "must be 0 rows of [x, y, z], got shape [0]"."""
    _, a = make_user()
    sid = _start(client, a)
    b = still_batch(T0)
    doc = {"acc": {"t_ns": b.acc_t_ns.tolist(), "xyz": b.acc.tolist()}, "gyr": {"t_ns": [], "xyz": []}}
    r = client.put(f"/v1/sessions/{sid}/batches/0", json=doc, headers=auth(a))
    assert r.status_code == 200, r.text
    assert client.get(f"/v1/sessions/{sid}/batches", headers=auth(a)).json()[0]["n_gyr"] == 0


def test_a_streamed_batch_upload_over_the_limit_is_413_and_not_stored(client, make_user, settings) -> None:  # type: ignore[no-untyped-def]
    """The upload's own size count went when BodyLimit came to count streamed bodies on every route: a chunked
    upload past the limit is still refused before it is decoded, and nothing is stored."""
    _, a = make_user()
    sid = _start(client, a)

    def chunks():  # type: ignore[no-untyped-def]
        for _ in range(settings.max_body_bytes // 65536 + 2):
            yield b"x" * 65536

    r = client.put(f"/v1/sessions/{sid}/batches/0", content=chunks(), headers={**auth(a), "content-type": "application/json"})
    assert r.status_code == 413 and "limit" in r.json()["detail"], r.text[:200]
    assert client.get(f"/v1/sessions/{sid}/batches", headers=auth(a)).json() == []


@pytest.mark.parametrize("path", ["/v1/profiles/walk", "/v1/sensorlogger"])
def test_streamed_bodies_over_the_limit_are_413_on_every_route(client, make_user, settings, path) -> None:  # type: ignore[no-untyped-def]
    """A chunked body (no Content-Length) was counted only by the batch upload: a 3 MB profile or Sensor Logger
    push against a 2 MB limit was parsed and stored whole."""
    _, a = make_user()

    def chunks():  # type: ignore[no-untyped-def]
        if path == "/v1/sensorlogger":
            yield b'{"messageId": 1, "sessionId": "big", "payload": [{"name": "pad", "time": 1, "values": {"x": "'
        else:
            yield b'{"data": {"n_steps": 1, "step_model": {"pad": "'
        for _ in range(settings.max_body_bytes // 65536 + 2):
            yield b"x" * 65536
        yield b'"}}]}' if path == "/v1/sensorlogger" else b'"}}}'

    method = client.post if path == "/v1/sensorlogger" else client.put
    r = method(path, content=chunks(), headers={**auth(a), "content-type": "application/json"})
    assert r.status_code == 413 and "limit" in r.json()["detail"], r.text[:200]
    assert client.get("/v1/profiles", headers=auth(a)).json() == []
    assert client.get("/v1/sessions", headers=auth(a)).json() == []


def test_payload_limits_are_413(client, make_user, settings) -> None:  # type: ignore[no-untyped-def]
    _, a = make_user()
    sid = _start(client, a)
    r = client.put(f"/v1/sessions/{sid}/batches/0", content=b"x" * (settings.max_body_bytes + 1),
                   headers={**auth(a), "content-type": "application/json"})
    assert r.status_code == 413 and "limit" in r.json()["detail"]
    many = still_batch(T0, seconds=(settings.max_samples_per_stream + 100) / 100.0)
    r = _put(client, a, sid, 0, many)
    assert r.status_code == 413 and "acc" in r.json()["detail"]
    assert client.get(f"/v1/sessions/{sid}/batches", headers=auth(a)).json() == []


def test_raw_batch_is_kept_losslessly(client, make_user) -> None:  # type: ignore[no-untyped-def]
    from server.formats import decode_batch

    _, a = make_user()
    sid = _start(client, a)
    b = still_batch(T0, seed=3)
    _put(client, a, sid, 0, b, binary=False)
    raw = client.get(f"/v1/sessions/{sid}/batches/0/raw", headers=auth(a))
    back = decode_batch(raw.content, raw.headers["content-type"], 10**6)
    for name in ("acc", "gyr", "mag"):
        assert np.array_equal(back.stream(name)[0], b.stream(name)[0])
        assert np.array_equal(back.stream(name)[1], b.stream(name)[1])


# ---------------------------------------------------------------- profiles
def _calibration(step: float = 0.7) -> dict:  # type: ignore[type-arg]
    return {"step_model": {"kind": "test", "a": step}, "sigma_d_m": 0.05, "heading_deviation_rad": 0.1,
            "heading_deviation_var": 0.01, "n_steps": 40, "calibrated": True}


def _nested(depth: int) -> dict:  # type: ignore[type-arg]
    d: dict = {"a": 1}  # type: ignore[type-arg]
    for _ in range(depth):
        d = {"a": d}
    return d


def test_profiles_replace_read_reset_history_and_isolation(client, make_user) -> None:  # type: ignore[no-untyped-def]
    _, a = make_user()
    _, b = make_user()
    assert client.get("/v1/profiles/walk", headers=auth(a)).status_code == 404
    r1 = client.put("/v1/profiles/walk", json={"data": _calibration(0.7)}, headers=auth(a))
    r2 = client.put("/v1/profiles/walk", json={"data": _calibration(0.8)}, headers=auth(a))
    assert (r1.status_code, r2.status_code) == (200, 200) and r2.json()["version"] == r1.json()["version"] + 1
    assert client.get("/v1/profiles/walk", headers=auth(a)).json()["data"]["step_model"]["a"] == 0.8
    sid = _start(client, a)  # new sessions get the current profile
    from server.models import TrackSession

    with client.app.state.sessionmaker() as db:
        prof = db.get(TrackSession, sid).profile_in
    assert prof["behaviours"]["walk"]["step_model"]["a"] == 0.8
    # user b sees none of it and cannot change it
    assert client.get("/v1/profiles/walk", headers=auth(b)).status_code == 404
    assert client.get("/v1/profiles", headers=auth(b)).json() == []
    assert client.get("/v1/profiles/walk/history", headers=auth(b)).json() == []
    client.delete("/v1/profiles/walk", headers=auth(b))
    assert client.get("/v1/profiles/walk", headers=auth(a)).status_code == 200
    # reset
    assert client.delete("/v1/profiles/walk", headers=auth(a)).json()["data"] is None
    assert client.get("/v1/profiles/walk", headers=auth(a)).status_code == 404
    hist = client.get("/v1/profiles/walk/history", headers=auth(a)).json()
    assert [h["version"] for h in hist] == [1, 2, 3] and hist[-1]["source"] == "reset"
    sid2 = _start(client, a)
    with client.app.state.sessionmaker() as db:
        assert db.get(TrackSession, sid2).profile_in is None


@pytest.mark.parametrize(
    "behaviour, data, field",
    [
        ("walk", {"n_steps": -1}, "data"),
        ("walk", {"bogus": 1}, "data"),
        ("swim", {}, "path.behaviour"),
        # accepted before, and then every session start of the user answered 500 (the engine could not load them)
        ("walk", {**_calibration(), "heading_deviation_rad": "0.1"}, "data: heading_deviation_rad"),
        ("walk", {**_calibration(), "heading_deviation_var": [0.01]}, "data: heading_deviation_var"),
        ("walk", {**_calibration(), "step_model": {"calibrator": {"pairs": "x"}}}, "data: the engine cannot load"),
        # accepted and stored as given: a string "no" read as calibrated, 3.5 steps, a float beyond float64
        ("walk", {**_calibration(), "calibrated": "no"}, "data: calibrated"),
        ("walk", {**_calibration(), "n_steps": 3.5}, "data: n_steps"),
        ("walk", {**_calibration(), "sigma_d_m": 10**400}, "data: sigma_d_m"),
        # 500 (RecursionError) before
        ("walk", {**_calibration(), "step_model": _nested(900)}, "data: nested too deeply"),
    ],
    ids=["negative-steps", "unknown-field", "unknown-behaviour", "string-deviation", "list-variance",
         "malformed-calibrator", "string-calibrated", "fractional-steps", "beyond-float64", "nested-too-deep"],
)
def test_profile_validation(client, make_user, behaviour, data, field) -> None:  # type: ignore[no-untyped-def]
    _, a = make_user()
    r = client.put(f"/v1/profiles/{behaviour}", json={"data": data}, headers=auth(a))
    assert r.status_code == 422 and r.json()["detail"].startswith(field), r.text
    assert client.get("/v1/profiles", headers=auth(a)).json() == []
    assert client.post("/v1/sessions", json={"device_kind": "foot"}, headers=auth(a)).status_code == 201



def test_a_profile_beyond_the_size_limit_is_413_and_not_stored(client, make_user, settings) -> None:  # type: ignore[no-untyped-def]
    """A step_model was limited only by the 2 MB body: every session start then copied it into the session row."""
    _, a = make_user()
    pad = "x" * (settings.max_profile_bytes + 1)
    r = client.put("/v1/profiles/walk", json={"data": {**_calibration(), "step_model": {"kind": "test", "a": 0.7, "pad": pad}}},
                   headers=auth(a))
    assert r.status_code == 413, r.text[:300]
    assert r.json()["detail"].startswith("data: calibration of ") and f"limit of {settings.max_profile_bytes} bytes" in r.json()["detail"]
    assert client.get("/v1/profiles", headers=auth(a)).json() == []
    # just under the limit (engine-sized profiles are far below it) is stored
    small = {**_calibration(), "step_model": {"kind": "test", "a": 0.7, "pad": "x" * (settings.max_profile_bytes - 1000)}}
    assert client.put("/v1/profiles/walk", json={"data": small}, headers=auth(a)).status_code == 200


@pytest.fixture()
def few_versions(settings):  # type: ignore[no-untyped-def]
    with app_with(settings, max_profile_versions=3) as (_, c):
        yield c


def test_profile_history_keeps_the_newest_versions(few_versions, make_user) -> None:  # type: ignore[no-untyped-def]
    """Every replace, reset and session close added a version and none was ever deleted: the history grew
    without bound. The newest max_profile_versions (3 here) of each behaviour are kept; numbering goes on."""
    c = few_versions
    _, a = make_user()
    _, b = make_user()
    assert c.put("/v1/profiles/walk", json={"data": _calibration(0.5)}, headers=auth(b)).status_code == 200
    assert c.put("/v1/profiles/run", json={"data": _calibration(1.2)}, headers=auth(a)).status_code == 200
    for k in range(5):
        assert c.put("/v1/profiles/walk", json={"data": _calibration(0.6 + 0.01 * k)}, headers=auth(a)).status_code == 200
    hist = c.get("/v1/profiles/walk/history", headers=auth(a)).json()
    assert [h["version"] for h in hist] == [3, 4, 5]
    assert c.get("/v1/profiles/walk", headers=auth(a)).json()["data"]["step_model"]["a"] == pytest.approx(0.64)
    assert c.delete("/v1/profiles/walk", headers=auth(a)).json()["version"] == 6  # a reset is a version too
    assert [h["version"] for h in c.get("/v1/profiles/walk/history", headers=auth(a)).json()] == [4, 5, 6]
    # other behaviours and other users keep theirs
    assert [h["version"] for h in c.get("/v1/profiles/run/history", headers=auth(a)).json()] == [1]
    assert [h["version"] for h in c.get("/v1/profiles/walk/history", headers=auth(b)).json()] == [1]


def test_a_session_close_keeps_the_newest_profile_versions(app, make_user) -> None:  # type: ignore[no-untyped-def]
    """The session close stores its profile through the same bound (here with a stand-in engine profile)."""
    from types import SimpleNamespace

    from server import crud
    from server.ingest import close_session
    from server.models import User

    uid, a = make_user()
    with app.state.sessionmaker() as db:
        user = db.get(User, uid)
        for k in range(4):
            crud.add_profile_version(db, user, "walk", _calibration(0.5 + 0.01 * k), source="api", keep=2)
        db.commit()
        assert [p.version for p in crud.profile_history(db, user, "walk")] == [3, 4]

        upd = SimpleNamespace(positions=[], events=[], behaviour="stand", mode="idle",
                              sensor_config=SimpleNamespace(to_dict=dict))
        engine = SimpleNamespace(flush=lambda: upd, to_bytes=lambda: b"state",  # hands out a new walk calibration
                                 profile_dict=lambda: {"behaviours": {"walk": _calibration(0.9)}})
        sid = crud.create_session(db, user, device_kind="foot").id
        db.commit()
        host = SimpleNamespace(lock=app.state.host.lock, write_lock=app.state.host.write_lock,
                               forget=lambda _sid: None, restore=lambda _sess: engine)
        close_session(db, host, user, sid, keep_versions=2)
        assert [(p.version, p.source) for p in crud.profile_history(db, user, "walk")] == [(4, "api"), (5, f"session:{sid}")]


# ---------------------------------------------------------------- trajectories
def test_trajectory_formats(client, make_user, app) -> None:  # type: ignore[no-untyped-def]
    from server.models import PositionRecord

    _, a = make_user()
    geo = _start(client, a, latitude_deg=43.66, longitude_deg=-79.39, altitude_m=80.0)
    flat = _start(client, a)
    with app.state.sessionmaker() as db:  # positions as the engine would have stored them
        for sid in (geo, flat):
            for i, (n, e) in enumerate([(0.0, 0.0), (100.0, 0.0), (100.0, 50.0)]):
                db.add(PositionRecord(session_id=sid, seq=i, t_ns=T0 + i * 10**9, north=n, east=e, down=0.0,
                                      heading_rad=0.0, behaviour="walk", mode="zupt", step_length_m=1.0, gyro_on=True))
        db.commit()
    js = client.get(f"/v1/sessions/{geo}/trajectory", headers=auth(a)).json()
    assert [p["north"] for p in js["positions"]] == [0.0, 100.0, 100.0]
    rows = list(csv.DictReader(io.StringIO(client.get(f"/v1/sessions/{geo}/trajectory?format=csv", headers=auth(a)).text)))
    assert [float(r["east"]) for r in rows] == [0.0, 0.0, 50.0] and rows[0]["mode"] == "zupt"
    gj = client.get(f"/v1/sessions/{geo}/trajectory?format=geojson", headers=auth(a)).json()
    coords = np.array(gj["features"][0]["geometry"]["coordinates"])
    assert coords.shape == (3, 3)
    # 100 m north is ~0.0009 deg of latitude; 50 m east at 43.66 deg is ~0.00062 deg of longitude
    assert coords[1, 1] - coords[0, 1] == pytest.approx(100.0 / 111_090, rel=2e-3)
    assert coords[2, 0] - coords[1, 0] == pytest.approx(50.0 / (111_320 * np.cos(np.radians(43.66))), rel=3e-3)
    assert coords[0, 2] == pytest.approx(80.0, abs=1e-6)
    r = client.get(f"/v1/sessions/{flat}/trajectory?format=geojson", headers=auth(a))
    assert r.status_code == 409 and "latitude" in r.json()["detail"]
    assert client.get(f"/v1/sessions/{geo}/trajectory?format=shp", headers=auth(a)).status_code == 422
    summary = client.get("/v1/users/me/gait-summary", headers=auth(a)).json()["sessions"]
    assert summary[0]["steps"] == 3 and summary[0]["distance_m"] == pytest.approx(3.0)
    assert summary[0]["cadence_steps_per_min"] == pytest.approx(60.0)


def test_openapi_page(client) -> None:  # type: ignore[no-untyped-def]
    assert client.get("/docs").status_code == 200
    paths = client.get("/openapi.json").json()["paths"]
    assert "/v1/sessions/{session_id}/batches/{seq}" in paths and "/v1/sensorlogger" in paths


def test_json_safe_stores_what_an_engine_profile_may_hold() -> None:
    import json

    from server.ingest import json_safe

    doc = {"a": np.array([[1.0, np.nan], [2.0, 3.0]]), "b": np.float32(0.5), "c": (np.int64(3), float("inf")), "d": "x"}
    out = json_safe(doc)
    assert out == {"a": [[1.0, None], [2.0, 3.0]], "b": 0.5, "c": [3, None], "d": "x"}
    json.dumps(out, allow_nan=False)


# ---------------------------------------------------------------- ids beyond the database's integers
BIG = 2**63  # one past int64: no row can have this id, and the database driver cannot even bind it


@pytest.mark.parametrize(
    "method, path, field",
    [
        ("get", f"/v1/sessions/{BIG}", "session_id"),
        ("post", f"/v1/sessions/{BIG}/close", "session_id"),
        ("post", f"/v1/sessions/{BIG}/reprocess", "session_id"),
        ("get", f"/v1/sessions/{BIG}/trajectory", "session_id"),
        ("get", f"/v1/sessions/{BIG}/events", "session_id"),
        ("get", f"/v1/sessions/{BIG}/batches", "session_id"),
        ("get", f"/v1/sessions/{BIG}/batches/0/raw", "session_id"),
        ("get", f"/v1/sessions/1/batches/{BIG}/raw", "seq"),
        ("put", f"/v1/sessions/{BIG}/batches/0", "session_id"),
        ("get", f"/v1/devices/{BIG}", "device_id"),
        ("get", f"/v1/sessions?offset={BIG}", "offset"),
    ],
)
def test_ids_beyond_int64_are_422_naming_the_field(client, make_user, method, path, field) -> None:  # type: ignore[no-untyped-def]
    _, a = make_user()
    kw = {"content": encode_msgpack(still_batch(T0)), "headers": {**auth(a), "content-type": MSGPACK_TYPE}} if method == "put" \
        else {"headers": auth(a)}
    r = getattr(client, method)(path, **kw)
    assert r.status_code == 422, r.text
    assert r.json()["field"].endswith(field) and "less than or equal" in r.json()["detail"]


def test_device_id_beyond_int64_is_422_and_starts_nothing(client, make_user) -> None:  # type: ignore[no-untyped-def]
    _, a = make_user()
    r = client.post("/v1/sessions", json={"device_kind": "foot", "device_id": BIG}, headers=auth(a))
    assert r.status_code == 422 and r.json()["field"] == "device_id", r.text
    assert client.get("/v1/sessions", headers=auth(a)).json() == []


@pytest.mark.parametrize("rate_hz", [200.0, 800.0])
def test_a_clipping_sprint_is_taken_batch_by_batch_and_a_steady_g_batch_refused(client, make_user, rate_hz) -> None:  # type: ignore[no-untyped-def]
    """Sprint batches whose median |a| passes 5 g (16 g peaks, 2000 deg/s at the part's range) were refused as
    'median |a| = 56 m/s^2 is implausible' and lost. They are physically possible: all are stored. A batch in g
    whose foot stands still is still refused, naming the field, the samples and why, and nothing of it is stored."""
    from clients.synth import LSM9DS1_CLIPPING, synthesize

    rec = synthesize("sprint", rate_hz=rate_hz, errors=LSM9DS1_CLIPPING)
    b = rec.batch
    t0 = int(b.acc_t_ns[0])
    seconds = [b.time_slice(t0 + k * 10**9, t0 + (k + 1) * 10**9) for k in (0, 1, 2, 16, 17, 18)]  # stand, then sprint
    seconds = [SensorBatch(acc_t_ns=s.acc_t_ns + T0, acc=s.acc, gyr_t_ns=s.gyr_t_ns + T0, gyr=s.gyr) for s in seconds]
    assert max(float(np.median(np.linalg.norm(s.acc, axis=1))) for s in seconds) > 50.0
    _, a = make_user()
    sid = _start(client, a)
    for seq, s in enumerate(seconds):
        r = _put(client, a, sid, seq, s)
        assert r.status_code == 200, r.text
    still_in_g = still_batch(T0 + 30 * 10**9, rate_hz=rate_hz)
    still_in_g = SensorBatch(acc_t_ns=still_in_g.acc_t_ns, acc=still_in_g.acc / 9.81)
    r = _put(client, a, sid, len(seconds), still_in_g)
    assert r.status_code == 422 and r.json()["field"] == "acc", r.text
    assert "samples 0-" in r.json()["detail"] and "looks like g" in r.json()["detail"]
    assert client.get(f"/v1/sessions/{sid}", headers=auth(a)).json()["next_seq"] == len(seconds)
    assert len(client.get(f"/v1/sessions/{sid}/batches", headers=auth(a)).json()) == len(seconds)
