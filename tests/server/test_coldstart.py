"""Cold start: the engines warm up when the server starts; until then /healthz says 503 and an upload is answered
at once with 503 Retry-After (nothing stored), never left waiting for a compilation; afterwards uploads answer."""

from __future__ import annotations

import time

from server.formats import MSGPACK_TYPE, encode_msgpack
from tests.server.conftest import app_with, auth, still_batch

T0 = 1_700_000_000_000_000_000


def test_not_ready_refuses_uploads_at_once_and_ready_takes_them(settings, make_user) -> None:  # type: ignore[no-untyped-def]
    _, tok = make_user()
    h = {**auth(tok), "content-type": MSGPACK_TYPE}
    with app_with(settings, engine_processes=1, engine_warmup=True) as (app, c):
        sid = c.post("/v1/sessions", json={"device_kind": "foot"}, headers=auth(tok)).json()["id"]
        seen_starting = False
        deadline = time.monotonic() + 600
        while True:
            health = c.get("/healthz")
            if health.status_code == 200:
                assert health.json()["ready"] is True
                break
            seen_starting = True
            assert health.status_code == 503 and health.json()["ready"] is False and health.headers["retry-after"]
            t = time.perf_counter()
            r = c.put(f"/v1/sessions/{sid}/batches/0", content=encode_msgpack(still_batch(T0)), headers=h)
            if r.status_code == 503:  # still warming: answered at once, nothing stored
                assert time.perf_counter() - t < 2.0 and int(r.headers["retry-after"]) >= 1
                assert "NOT stored" in r.json()["detail"]
                assert c.get(f"/v1/sessions/{sid}", headers=auth(tok)).json()["next_seq"] == 0
            else:  # the warm-up ended between the two requests
                assert r.status_code == 200, r.text
                break
            assert time.monotonic() < deadline, "the engines did not warm up in 10 min"
            time.sleep(0.2)
        assert app.state.host.ready()
        for seq in range(c.get(f"/v1/sessions/{sid}", headers=auth(tok)).json()["next_seq"], 3):
            r = c.put(f"/v1/sessions/{sid}/batches/{seq}", content=encode_msgpack(still_batch(T0 + seq * 10**9)), headers=h)
            assert r.status_code == 200, r.text
    # with helpers, the warm-up is a spawn plus a few seconds of feeding: the 503 phase is normally seen
    assert seen_starting or app.state.host.ready()


def test_sdk_waits_out_a_warming_server(settings, make_user) -> None:  # type: ignore[no-untyped-def]
    from clients.sdk import PednavClient

    _, tok = make_user()
    with app_with(settings, engine_processes=1, engine_warmup=True) as (app, c):
        api = PednavClient(token=tok, http=c, retries=2, backoff_s=0.0)
        sid = api.start_session("foot")["id"]
        st = api.stream(sid)
        answers = st.send(still_batch(T0))  # 503 Retry-After while warming: waited out, then applied once
        assert [a["seq"] for a in answers] == [0] and not st.pending
        assert app.state.host.ready()


def test_warm_signal_walks() -> None:
    """The warm-up signal is walked by the engine (steps found), so the walking kernels are compiled too."""
    from energy.engine import Engine
    from server.warmup import warm_signal

    e = Engine(mode="auto")
    n = sum(len(e.feed(p).positions) for p in warm_signal().split_seconds(1.0))
    assert n >= 20
