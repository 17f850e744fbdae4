"""SDK: wire encoding agrees with the server, payload sizes, retries with the same sequence number, offline
buffering, async client, and identical positions API-streamed vs local."""

from __future__ import annotations

import asyncio
from pathlib import Path

import httpx2
import numpy as np
import pytest
from hypothesis import given, settings as hsettings, strategies as st

from clients.sdk import AsyncPednavClient, Offline, PednavClient, SequenceConflict, encode_batch
from clients.simulators import FootSensorSimulator
from models.batch import SensorBatch
from server.formats import decode_batch, encode_json
from tests.server.conftest import app, backend, client, make_user, settings, still_batch  # noqa: F401 - fixtures

T0 = 1_700_000_000_000_000_000


@st.composite
def batches(draw: st.DrawFn) -> SensorBatch:
    kw = {}
    for name in ("acc", "gyr", "mag"):
        n = draw(st.integers(0, 40))
        t0 = draw(st.integers(0, 2**62))
        steps = draw(st.lists(st.integers(1, 2**33), min_size=max(n - 1, 0), max_size=max(n - 1, 0)))
        t = np.array([t0] + list(t0 + np.cumsum(steps)), dtype=np.int64)[:n] if n else np.zeros(0, np.int64)
        v = np.array(draw(st.lists(st.floats(-1e6, 1e6, width=32), min_size=3 * n, max_size=3 * n))).reshape(n, 3)
        kw[f"{name}_t_ns"], kw[name] = t, v
    return SensorBatch(**kw)


@hsettings(max_examples=60, deadline=None)
@given(batches(), st.sampled_from([("msgpack", "<f8"), ("msgpack", "<f4"), ("json", "<f8")]))
def test_sdk_encoding_round_trips_through_the_server_decoder(batch: SensorBatch, enc: tuple[str, str]) -> None:
    body, ctype = encode_batch(batch, enc[0], enc[1])  # type: ignore[arg-type]
    back = decode_batch(body, ctype, 10**6, allow_empty=True)
    for name in ("acc", "gyr", "mag"):
        assert np.array_equal(back.stream(name)[0], batch.stream(name)[0])
        assert np.array_equal(back.stream(name)[1], batch.stream(name)[1])  # float32 values: lossless in <f4


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_binary_body_is_at_least_3x_smaller_than_json(seed: int) -> None:
    # 1 s of 100 Hz 9-axis phone data; Android reports float32 values, so "<f4" is lossless
    b = still_batch(T0, 1.0, 100.0, seed=seed)
    b = SensorBatch(**{k: (v.astype(np.float32).astype(np.float64) if v.dtype.kind == "f" else v) for k, v in b._kwargs().items()})
    js = encode_json(b)
    f4, _ = encode_batch(b, "msgpack", "<f4")
    assert len(js) / len(f4) >= 3.0
    assert np.array_equal(decode_batch(f4, "application/msgpack", 10**6).acc, b.acc)


class Flaky(httpx2.BaseTransport):
    """Wraps a transport; fails the chosen attempts before sending or after the server answered."""

    def __init__(self, inner: httpx2.BaseTransport) -> None:
        self.inner = inner
        self.fail_before = 0
        self.lose_response = 0
        self.down = False
        self.calls = 0

    def handle_request(self, request: httpx2.Request) -> httpx2.Response:
        self.calls += 1
        if self.down or self.fail_before > 0:
            self.fail_before = max(self.fail_before - 1, 0)
            raise httpx2.ConnectError("simulated: no network", request=request)
        resp = self.inner.handle_request(request)
        if self.lose_response > 0:
            self.lose_response -= 1
            resp.read()
            raise httpx2.ReadTimeout("simulated: answer lost", request=request)
        return resp


@pytest.fixture()
def flaky_api(client, make_user):  # type: ignore[no-untyped-def]  # noqa: F811
    _, tok = make_user()
    flaky = Flaky(client._transport)
    http = httpx2.Client(transport=flaky, base_url=str(client.base_url))
    api = PednavClient(token=tok, http=http, retries=4, backoff_s=0.0)
    yield api, flaky
    http.close()


def test_retry_after_lost_answer_is_applied_once(flaky_api) -> None:  # type: ignore[no-untyped-def]
    api, flaky = flaky_api
    sid = api.start_session("foot")["id"]
    first = api.upload(sid, 0, still_batch(T0))
    flaky.lose_response = 2  # the server applies batch 1, the answer is lost twice, the SDK retries seq 1
    second = api.upload(sid, 1, still_batch(T0 + 10**9, seed=1))
    assert second["seq"] == 1 and second["next_seq"] == 2 and first["next_seq"] == 1
    assert [b["seq"] for b in api._json("GET", f"/v1/sessions/{sid}/batches")] == [0, 1]
    flaky.fail_before = 3
    assert api.upload(sid, 2, still_batch(T0 + 2 * 10**9, seed=2))["next_seq"] == 3
    with pytest.raises(SequenceConflict) as exc:
        api.upload(sid, 7, still_batch(T0 + 3 * 10**9))
    assert exc.value.expected_seq == 3


def test_offline_buffering_delivers_in_order(flaky_api) -> None:  # type: ignore[no-untyped-def]
    api, flaky = flaky_api
    sid = api.start_session("phone")["id"]
    stream = api.stream(sid)
    assert len(stream.send(still_batch(T0))) == 1
    flaky.down = True
    for k in range(1, 4):
        assert stream.send(still_batch(T0 + k * 10**9, seed=k)) == []
    assert [seq for seq, _, _ in stream.pending] == [1, 2, 3]
    with pytest.raises(Offline):
        api.upload(sid, 1, still_batch(T0 + 10**9, seed=1))
    flaky.down = False
    got = stream.send(still_batch(T0 + 4 * 10**9, seed=4))
    assert [r["seq"] for r in got] == [1, 2, 3, 4] and not stream.pending
    assert stream.sensor_config == got[-1]["sensor_config"]
    assert api.session(sid)["next_seq"] == 5


class _Time:
    """``clients.sdk``'s time module with its sleeps recorded and handed to ``sleep`` instead of slept."""

    def __init__(self, sleep) -> None:  # type: ignore[no-untyped-def]
        self.slept: list[float] = []
        self._sleep = sleep

    def sleep(self, s: float) -> None:
        self.slept.append(s)
        self._sleep(s)

    def __getattr__(self, name: str):  # type: ignore[no-untyped-def]
        import time

        return getattr(time, name)


def test_a_busy_database_is_waited_out_as_retry_after_says_and_the_batch_applied_once(settings, make_user,  # type: ignore[no-untyped-def]  # noqa: F811
                                                                                       monkeypatch) -> None:
    """The server answers 503 with ``Retry-After: 1`` when another worker holds the database through all its
    retries (nothing stored; it was a 500, which the SDK does not retry): the SDK waits Retry-After and sends the
    same sequence number again, applied once. Such waits use up no attempt until they add up to ``wait_s``; busy
    for longer than that and its retries, the batch stays queued in the stream and goes out later under its number."""
    import clients.sdk as sdk
    from tests.server.conftest import app_with, database_locked, short_lock_waits

    _, tok = make_user()
    with app_with(settings) as (a, c):
        short_lock_waits(a)
        api = PednavClient(token=tok, http=c, retries=3, backoff_s=0.0, wait_s=2.0)
        sid = api.start_session("foot")["id"]
        stream = api.stream(sid)
        assert [r["seq"] for r in stream.send(still_batch(T0))] == [0]
        with database_locked(settings, sid) as lock:
            clock = _Time(lambda s: lock.release() if s >= 1 else None)  # free once Retry-After is over
            monkeypatch.setattr(sdk, "time", clock)
            got = stream.send(still_batch(T0 + 10**9, seed=1))
        assert [r["seq"] for r in got] == [1] and not stream.pending
        assert clock.slept == [1.0]  # Retry-After (no attempt used up)
        with database_locked(settings, sid):
            clock = _Time(lambda s: None)
            monkeypatch.setattr(sdk, "time", clock)
            assert stream.send(still_batch(T0 + 2 * 10**9, seed=2)) == []  # wait_s, then 3 retries, all 503: queued
        # two Retry-After waits within wait_s = 2 s, then each retry waits backoff (0) plus Retry-After
        assert clock.slept == [1.0] * 5
        assert [seq for seq, _, _ in stream.pending] == [2]
        assert [b["seq"] for b in api._json("GET", f"/v1/sessions/{sid}/batches")] == [0, 1]
        got = stream.send(still_batch(T0 + 3 * 10**9, seed=3))
        assert [r["seq"] for r in got] == [2, 3] and not stream.pending
        assert [b["seq"] for b in api._json("GET", f"/v1/sessions/{sid}/batches")] == [0, 1, 2, 3]
        assert api.upload(sid, 2, still_batch(T0 + 2 * 10**9, seed=2)) == got[0]  # applied once: a retry now


def test_async_client(app, make_user) -> None:  # type: ignore[no-untyped-def]  # noqa: F811
    _, tok = make_user()

    async def go() -> list[dict]:  # type: ignore[type-arg]
        http = httpx2.AsyncClient(transport=httpx2.ASGITransport(app=app), base_url="http://test")
        async with AsyncPednavClient(token=tok, http=http) as api:
            sid = (await api.start_session("watch"))["id"]
            stream = api.stream(sid)
            out = []
            for k in range(3):
                out += await stream.send(still_batch(T0 + k * 10**9, seed=k))
            again = await api.upload(sid, 1, still_batch(T0 + 10**9, seed=1))
            assert again == out[1]
            await api.close_session(sid)
            assert (await api.session(sid))["status"] == "closed"
        await http.aclose()
        return out

    out = asyncio.run(go())
    assert [r["seq"] for r in out] == [0, 1, 2]


# ---------------------------------------------------------------- identical positions both ways
def _api_vs_local(client, tok: str, recording, encoding: str, check_one_piece: bool = False) -> None:  # type: ignore[no-untyped-def]  # noqa: F811
    from energy.device import replay
    from energy.engine import Engine
    from server.formats import decode_batch as dec

    api = PednavClient(token=tok, http=client, encoding=encoding)  # type: ignore[arg-type]
    res = FootSensorSimulator(recording, batch_seconds=1.0).run(api)
    got = np.array([[p["t_ns"], p["north"], p["east"], p["down"]] for p in res.positions])
    # 1) the local device replay (same 1-s batches, same sensor commands)
    loc = replay(Engine(mode="auto"), recording.batch, 1.0)
    ref = np.array([[p.t_ns, p.north, p.east, p.down] for p in loc.positions])
    # 2) what the server stored, fed locally in ONE piece
    raws = [dec(api.request("GET", f"/v1/sessions/{res.session_id}/batches/{b['seq']}/raw").content, "application/msgpack", 10**7)
            for b in api._json("GET", f"/v1/sessions/{res.session_id}/batches")]
    eng = Engine(mode="auto")
    one = eng.feed(SensorBatch.concat(raws)).positions + eng.flush().positions
    whole = np.array([[p.t_ns, p.north, p.east, p.down] for p in one])
    assert len(got) > 5
    for other in (ref, whole) if check_one_piece else (ref,):
        assert other.shape == got.shape
        assert np.array_equal(other[:, 0], got[:, 0])
        assert np.max(np.abs(other[:, 1:] - got[:, 1:])) <= 1e-9
    assert res.gyro_on_fraction == pytest.approx(loc.gyro_on_fraction)


@pytest.mark.parametrize("encoding", ["msgpack", "json"])
def test_api_streamed_equals_local_synthetic(client, make_user, encoding) -> None:  # type: ignore[no-untyped-def]  # noqa: F811
    from clients.synth import synthesize

    _, tok = make_user()
    _api_vs_local(client, tok, synthesize("walk", seed=3), encoding)


def test_stored_batches_refed_in_one_piece_equal_the_stream(client, make_user) -> None:  # type: ignore[no-untyped-def]  # noqa: F811
    from clients.synth import synthesize

    _, tok = make_user()
    _api_vs_local(client, tok, synthesize("walk", seed=3), "msgpack", check_one_piece=True)


def test_api_streamed_equals_local_real_recording(client, make_user, vicon_dir: Path) -> None:  # type: ignore[no-untyped-def]  # noqa: F811
    from clients.importers import list_recordings, load

    files = list_recordings(vicon_dir)
    if not files:
        pytest.skip(f"no recordings in {vicon_dir}")
    _, tok = make_user()
    _api_vs_local(client, tok, load(files[0]), "msgpack")


# ---------------------------------------------------------------- durable offline buffer (spool)
_CRASHING_DEVICE = r"""
import os, signal, sys
import httpx2
from clients.sdk import PednavClient
from tests.server.conftest import still_batch

class Down(httpx2.BaseTransport):
    def handle_request(self, request):
        raise httpx2.ConnectError("simulated: no network", request=request)

sid, spool, t0 = int(sys.argv[1]), sys.argv[2], int(sys.argv[3])
api = PednavClient(token="irrelevant", http=httpx2.Client(transport=Down(), base_url="http://testserver"), retries=0)
stream = api.stream(sid, next_seq=1, spool_dir=spool)
for k in range(1, 4):
    assert stream.send(still_batch(t0 + k * 10**9, seed=k)) == []
print("queued", [seq for seq, _, _ in stream.pending], flush=True)
os.kill(os.getpid(), signal.SIGKILL)  # crash: no close, no cleanup
"""


def test_spooled_batches_survive_a_crash_and_go_out_with_the_same_numbers(client, make_user, tmp_path) -> None:  # type: ignore[no-untyped-def]  # noqa: F811
    import signal
    import subprocess
    import sys

    _, tok = make_user()
    api = PednavClient(token=tok, http=client)
    sid = api.start_session("phone")["id"]
    assert api.upload(sid, 0, still_batch(T0))["next_seq"] == 1
    spool = tmp_path / "spool"
    proc = subprocess.run([sys.executable, "-c", _CRASHING_DEVICE, str(sid), str(spool), str(T0)],
                          capture_output=True, text=True, timeout=120, cwd=Path(__file__).resolve().parents[2])
    assert proc.returncode == -signal.SIGKILL, proc.stderr
    assert "queued [1, 2, 3]" in proc.stdout
    assert api.session(sid)["next_seq"] == 1  # nothing reached the server
    # the app starts again: the spool is found and delivered in order with the original sequence numbers
    got = api.resume(spool)
    assert [r["seq"] for r in got[sid]] == [1, 2, 3]
    with api.stream(sid, next_seq=api.session(sid)["next_seq"], spool_dir=spool) as stream:
        assert not stream.pending and stream.next_seq == 4
        assert [r["seq"] for r in stream.send(still_batch(T0 + 4 * 10**9, seed=4))] == [4]
    # exactly the batches the crashed app produced, each stored once
    ref = PednavClient(token=tok, http=client)
    rid = ref.start_session("phone")["id"]
    for k in range(5):
        last = ref.upload(rid, k, still_batch(T0 + k * 10**9, seed=k))
    batches = api._json("GET", f"/v1/sessions/{sid}/batches")
    assert [b["seq"] for b in batches] == [0, 1, 2, 3, 4]
    assert [b["sha256"] for b in batches] == [b["sha256"] for b in ref._json("GET", f"/v1/sessions/{rid}/batches")]
    assert api.session(sid)["sensor_config"] == last["sensor_config"]


def test_spool_resends_a_batch_whose_answer_was_lost_before_the_crash(flaky_api, tmp_path) -> None:  # type: ignore[no-untyped-def]
    api, flaky = flaky_api
    sid = api.start_session("watch")["id"]
    stream = api.stream(sid, spool_dir=tmp_path)
    assert [r["seq"] for r in stream.send(still_batch(T0))] == [0]
    flaky.lose_response = api.opts.retries + 1  # the server applies batch 1, every answer is lost
    assert stream.send(still_batch(T0 + 10**9, seed=1)) == []
    assert [seq for seq, _, _ in stream.pending] == [1]
    del stream  # crash: the queue object is gone, the file stays
    again = api.stream(sid, spool_dir=tmp_path)
    assert again.next_seq == 2 and len(again.pending) == 1
    r = api.request("PUT", f"/v1/sessions/{sid}/batches/1", content=again.pending.first()[1],
                    headers={"content-type": "application/msgpack"})
    assert r.headers["x-pednav-replayed"] == "true"  # what resume sends is acknowledged, not applied again
    assert [x["seq"] for x in again.drain()] == [1] and not again.pending
    assert [b["seq"] for b in api._json("GET", f"/v1/sessions/{sid}/batches")] == [0, 1]
    again.close()


def test_spool_refusals_and_isolation(flaky_api, tmp_path) -> None:  # type: ignore[no-untyped-def]
    from clients.sdk import Spool

    api, flaky = flaky_api
    a = api.start_session("foot")["id"]
    b = api.start_session("foot")["id"]
    flaky.down = True
    sa = api.stream(a, spool_dir=tmp_path, max_buffer=2)
    sb = api.stream(b, spool_dir=tmp_path)
    sa.send(still_batch(T0))
    sa.send(still_batch(T0 + 10**9, seed=1))
    with pytest.raises(BufferError, match="buffer full"):
        sa.send(still_batch(T0 + 2 * 10**9, seed=2))
    sb.send(still_batch(T0))
    assert sa.next_seq == 2 and len(sa.pending) == 2 and len(sb.pending) == 1  # the refused batch took no number
    with Spool(tmp_path) as sp:
        assert sp.sessions(api.server_key) == [a, b]
        assert sp.sessions("http://another-server") == []  # queues are per server
    flaky.down = False
    got = api.resume(tmp_path)
    assert {k: [r["seq"] for r in v] for k, v in got.items()} == {a: [0, 1], b: [0]}
    sa.close(), sb.close()
    with Spool(tmp_path) as sp:
        assert sp.sessions(api.server_key) == []
    with pytest.raises(SequenceConflict) as exc:  # a spool that disagrees with the server is not silently dropped
        stale = api.stream(a, next_seq=5, spool_dir=tmp_path / "other")
        stale.send(still_batch(T0 + 9 * 10**9))
    assert exc.value.expected_seq == 2 and len(stale.pending) == 1
    stale.close()


def test_async_stream_with_spool(app, make_user, tmp_path) -> None:  # type: ignore[no-untyped-def]  # noqa: F811
    _, tok = make_user()

    async def go() -> tuple[list[int], list[int]]:
        http = httpx2.AsyncClient(transport=httpx2.ASGITransport(app=app), base_url="http://test")
        async with AsyncPednavClient(token=tok, http=http) as api:
            sid = (await api.start_session("watch"))["id"]
            stream = api.stream(sid, spool_dir=tmp_path)
            seqs = [r["seq"] for k in range(3) for r in await stream.send(still_batch(T0 + k * 10**9, seed=k))]
            left = [s for s, _, _ in stream.pending]
            stream.close()
        await http.aclose()
        return seqs, left

    seqs, left = asyncio.run(go())
    assert seqs == [0, 1, 2] and left == []


def test_a_device_token_is_minted_listed_and_revoked_through_the_sdk(client, make_user) -> None:  # type: ignore[no-untyped-def]  # noqa: F811
    """A phone mints a token for a watch, lists the user's tokens (no secrets in the list) and revokes the watch's
    when it is lost: the watch is then refused, the phone is not; another user cannot revoke it (404)."""
    from clients.sdk import ApiError

    _, tok = make_user()
    phone = PednavClient(token=tok, http=client)
    minted = phone.new_token("watch", ttl_s=3600)
    watch = PednavClient(token=minted["token"], http=client)
    assert watch.me()["id"] == phone.me()["id"]
    listed = {t["id"]: t for t in phone.tokens()}
    assert listed[minted["id"]]["label"] == "watch" and all("token" not in t for t in listed.values())
    _, other_tok = make_user()
    with pytest.raises(ApiError) as err:
        PednavClient(token=other_tok, http=client).revoke_token(minted["id"])
    assert err.value.status == 404
    assert watch.me()["id"]  # still valid
    phone.revoke_token(minted["id"])
    with pytest.raises(ApiError) as err:
        watch.me()
    assert err.value.status == 401
    assert phone.me()["id"]
