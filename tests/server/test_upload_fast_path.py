"""The upload fast path (pure ASGI middleware, driver connections) answers exactly as the documented FastAPI
route does: same status codes, bodies and headers for accepted, replayed and refused uploads."""

from __future__ import annotations

import json
import uuid
from typing import Any

from fastapi.testclient import TestClient

from server import crud
from server.app import create_app
from server.formats import MSGPACK_TYPE, encode_json, encode_msgpack
from server.routers.batches import UploadFastPath
from tests.server.conftest import auth, still_batch

T0 = 1_700_000_000_000_000_000


def _script(c: TestClient, tok: str, other: str) -> list[tuple[int, Any, str | None, str | None]]:
    """The same requests against a fresh session; (status, body, x-pednav-replayed, www-authenticate) each."""
    sid = c.post("/v1/sessions", json={"device_kind": "foot"}, headers=auth(tok)).json()["id"]
    mp = {**auth(tok), "content-type": MSGPACK_TYPE}
    b0, b1 = encode_msgpack(still_batch(T0, seed=1)), encode_msgpack(still_batch(T0 + 10**9, seed=2))
    reqs = [
        (f"/v1/sessions/{sid}/batches/0", b0, mp),  # accepted
        (f"/v1/sessions/{sid}/batches/0", b0, mp),  # retry: replayed
        (f"/v1/sessions/{sid}/batches/0", b1, mp),  # old number, other content: 409
        (f"/v1/sessions/{sid}/batches/5", b1, mp),  # gap: 409
        (f"/v1/sessions/{sid}/batches/1", encode_json(still_batch(T0 + 10**9, seed=2)),
         {**auth(tok), "content-type": "application/json"}),  # JSON body accepted
        (f"/v1/sessions/{sid}/batches/2", b"\x81\xa1v\x02", mp),  # bad body: 422 names the field
        (f"/v1/sessions/{sid}/batches/-1", b0, mp),  # 422 seq
        (f"/v1/sessions/{sid}/batches/2", b0, {"content-type": MSGPACK_TYPE}),  # 401 missing token
        (f"/v1/sessions/{sid}/batches/2", b0, {**auth("nope"), "content-type": MSGPACK_TYPE}),  # 401 invalid
        (f"/v1/sessions/{sid}/batches/2", b0, {**auth(other), "content-type": MSGPACK_TYPE}),  # other user: 404
        (f"/v1/sessions/{sid + 10**6}/batches/0", b0, mp),  # no such session: 404
        (f"/v1/sessions/{sid}/batches/2?token={tok}", encode_msgpack(still_batch(T0 + 2 * 10**9, seed=3)),
         {"content-type": MSGPACK_TYPE}),  # token as a query parameter: 401 (only the Sensor Logger push takes it)
        (f"/v1/sessions/{sid}/batches/3", b"x" * 3_000_000, mp),  # over the body limit: 413
    ]
    out = []
    for path, body, headers in reqs:
        r = c.put(path, content=body, headers=headers)
        data = r.json()
        if isinstance(data, dict):
            data.pop("session_id", None)
            if "detail" in data and isinstance(data["detail"], str):
                data["detail"] = data["detail"].replace(f"session {sid + 10**6}", "session SID+1e6").replace(
                    f"session {sid}", "session SID")
        out.append((r.status_code, data, r.headers.get("x-pednav-replayed"), r.headers.get("www-authenticate")))
    return out


def test_fast_path_answers_as_the_route(settings) -> None:  # type: ignore[no-untyped-def]
    got = []
    for fast in (True, False):
        app = create_app(settings)
        if not fast:
            app.user_middleware = [m for m in app.user_middleware if m.cls is not UploadFastPath]
        try:
            with app.state.sessionmaker() as db:
                toks = []
                for _ in range(2):
                    _, t = crud.create_user(db, f"u{uuid.uuid4().hex[:10]}")
                    toks.append(t)
                db.commit()
            with TestClient(app) as c:
                got.append(_script(c, *toks))
        finally:
            app.state.db_engine.dispose()
    fast, route = got
    assert [s for s, *_ in fast] == [200, 200, 409, 409, 200, 422, 422, 401, 401, 404, 404, 401, 413]
    assert [x[2] for x in fast[:2]] == ["false", "true"] and fast[0][1] == fast[1][1]
    for a, b in zip(fast, route):
        assert json.dumps(a, sort_keys=True) == json.dumps(b, sort_keys=True)


def test_decoded_canonical_bytes_equal_the_encoded_ones() -> None:
    """``decode_upload`` gives the canonical bytes without re-encoding only where they are those
    ``canonical_bytes`` encodes (f8 with t0/dt, streams in any order, one sample, an empty stream), and None for
    bodies whose canonical form differs from theirs (f4 values, int64 timestamps)."""
    import msgpack
    import numpy as np

    from models.batch import SensorBatch
    from server.formats import canonical_bytes, decode_upload

    b = still_batch(T0, seed=3)
    one = SensorBatch(acc_t_ns=b.acc_t_ns[:1], acc=b.acc[:1], gyr_t_ns=b.gyr_t_ns[:1], gyr=b.gyr[:1])
    doc = msgpack.unpackb(encode_msgpack(b), raw=False)
    reordered = msgpack.packb({k: doc[k] for k in reversed(list(doc))}, use_bin_type=True)
    empty_mag = msgpack.packb({**doc, "mag": {"n": 0, "dtype": "<f8", "xyz": b"", "t0": 0, "dt": b""}}, use_bin_type=True)
    t_form = msgpack.packb({**doc, "acc": {"n": len(b.acc_t_ns), "dtype": "<f8", "xyz": b.acc.tobytes(),
                                           "t": b.acc_t_ns.astype("<i8").tobytes()}}, use_bin_type=True)
    for body, given in ((encode_msgpack(b), True), (encode_msgpack(one), True), (reordered, True),
                        (empty_mag, True), (encode_msgpack(b, "<f4"), False), (t_form, False)):
        batch, raw = decode_upload(body, MSGPACK_TYPE, 10**6)
        assert (raw is not None) == given
        if raw is not None:
            assert raw == canonical_bytes(batch)
    assert decode_upload(encode_json(b), "application/json", 10**6)[1] is None
    assert np.array_equal(decode_upload(reordered, MSGPACK_TYPE, 10**6)[0].acc, b.acc)
