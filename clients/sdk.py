"""Python SDK of the pednav REST API (httpx; sync and async).

Uploads are sequenced: batch ``k`` of a session is ``PUT /v1/sessions/{id}/batches/{k}``. A failed request
(connection error, timeout, 429/5xx) is retried with the *same* sequence number and body, which the server
acknowledges again without applying it twice. :class:`BatchStream` adds offline buffering: batches that
cannot be delivered stay queued in order and go out with the next successful send.

Wire formats (see ``server/formats.py`` for the server side): JSON or msgpack with packed little-endian
arrays; ``float_dtype="<f4"`` is lossless for Android sensor values (float32) and ~5x smaller than JSON,
``"<f8"`` is lossless for anything.

Example
-------
>>> with PednavClient("http://127.0.0.1:8000", token) as api:          # doctest: +SKIP
...     s = api.start_session("foot")
...     stream = api.stream(s["id"])
...     for batch in batches:
...         for resp in stream.send(batch):
...             print(resp["positions"], resp["sensor_config"])
...     api.close_session(s["id"])
"""

from __future__ import annotations

import asyncio
import json
import time
from collections import deque
from dataclasses import dataclass
from typing import Any, Literal

import httpx
import msgpack
import numpy as np

from models.batch import STREAMS, SensorBatch

__all__ = [
    "ApiError",
    "SequenceConflict",
    "Offline",
    "encode_batch",
    "PednavClient",
    "AsyncPednavClient",
    "BatchStream",
    "AsyncBatchStream",
]

Encoding = Literal["msgpack", "json"]
_RETRY_STATUS = {429, 502, 503, 504}
_I32 = np.iinfo(np.int32)


class ApiError(Exception):
    """The server refused a request (4xx/5xx after retries)."""

    def __init__(self, status: int, detail: str, body: Any = None) -> None:
        super().__init__(f"HTTP {status}: {detail}")
        self.status = status
        self.detail = detail
        self.body = body


class SequenceConflict(ApiError):
    """HTTP 409 on an upload; ``expected_seq`` is the number the server expects next."""

    def __init__(self, status: int, detail: str, body: Any, expected_seq: int | None) -> None:
        super().__init__(status, detail, body)
        self.expected_seq = expected_seq


class Offline(Exception):
    """The server could not be reached after all retries (the batch stays buffered in a stream)."""


def encode_batch(batch: SensorBatch, encoding: Encoding = "msgpack", float_dtype: str = "<f8") -> tuple[bytes, str]:
    """Encode a batch for upload; returns ``(body, content_type)``.

    Parameters
    ----------
    batch : SensorBatch
        Samples in SI units (m/s^2, rad/s, uT) with int64 ns timestamps per stream.
    encoding : {"msgpack", "json"}
    float_dtype : {"<f8", "<f4"}
        Value precision of the msgpack body.
    """
    if encoding == "json":
        doc: dict[str, Any] = {}
        for name in STREAMS:
            t, v = batch.stream(name)
            if t.size:
                doc[name] = {"t_ns": t.tolist(), "xyz": v.tolist()}
        return json.dumps(doc, separators=(",", ":")).encode(), "application/json"
    if float_dtype not in ("<f4", "<f8"):
        raise ValueError("float_dtype must be '<f4' or '<f8'")
    out: dict[str, Any] = {"v": 1}
    for name in STREAMS:
        t, v = batch.stream(name)
        if not t.size:
            continue
        s: dict[str, Any] = {"n": int(t.size), "dtype": float_dtype, "xyz": np.ascontiguousarray(v, dtype=float_dtype).tobytes()}
        d = np.diff(t)
        if d.size == 0 or (d.min() >= _I32.min and d.max() <= _I32.max):
            s["t0"], s["dt"] = int(t[0]), d.astype("<i4").tobytes()
        else:
            s["t"] = t.astype("<i8").tobytes()
        out[name] = s
    return msgpack.packb(out, use_bin_type=True), "application/msgpack"


def _raise_for(r: httpx.Response) -> None:
    if r.status_code < 400:
        return
    try:
        body = r.json()
        detail = str(body.get("detail", body)) if isinstance(body, dict) else str(body)
    except ValueError:
        body, detail = r.text, r.text
    if r.status_code == 409:
        exp = body.get("expected_seq") if isinstance(body, dict) else None
        raise SequenceConflict(r.status_code, detail, body, exp)
    raise ApiError(r.status_code, detail, body)


def _decode(r: httpx.Response) -> Any:
    _raise_for(r)
    if r.status_code == 204:
        return None
    ctype = r.headers.get("content-type", "")
    if "json" in ctype:
        return r.json()
    return r.text


@dataclass(frozen=True)
class _Options:
    encoding: Encoding
    float_dtype: str
    retries: int
    backoff_s: float


class PednavClient:
    """Synchronous client.

    Parameters
    ----------
    base_url : str
        Server root, e.g. ``http://127.0.0.1:8000``.
    token : str, optional
        Bearer token (``pednav admin create-user NAME --json``).
    encoding : {"msgpack", "json"}
        Body format of uploads.
    float_dtype : {"<f8", "<f4"}
        Value precision of msgpack uploads.
    retries : int
        Extra attempts of a request that failed in transit or got 429/502/503/504.
    backoff_s : float
        First retry delay [s]; doubles per attempt.
    timeout_s : float
        Per-request timeout [s].
    http : httpx.Client, optional
        A ready client (tests pass FastAPI's ``TestClient``); ``base_url`` is then ignored.
    """

    def __init__(
        self,
        base_url: str = "http://127.0.0.1:8000",
        token: str | None = None,
        *,
        encoding: Encoding = "msgpack",
        float_dtype: str = "<f8",
        retries: int = 5,
        backoff_s: float = 0.1,
        timeout_s: float = 30.0,
        http: httpx.Client | None = None,
    ) -> None:
        self._own = http is None
        self.http = http if http is not None else httpx.Client(base_url=base_url, timeout=timeout_s)
        self.token = token
        self.opts = _Options(encoding, float_dtype, retries, backoff_s)

    # -------------------------------------------------------------- plumbing
    def __enter__(self) -> PednavClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        if self._own:
            self.http.close()

    def _headers(self, extra: dict[str, str] | None = None) -> dict[str, str]:
        h = {"Authorization": f"Bearer {self.token}"} if self.token else {}
        return {**h, **(extra or {})}

    def request(self, method: str, path: str, **kw: Any) -> httpx.Response:
        """One request with retries on transport errors and 429/5xx; raises :class:`Offline` at the end."""
        headers = self._headers(kw.pop("headers", None))
        last: Exception | None = None
        for attempt in range(self.opts.retries + 1):
            if attempt:
                time.sleep(self.opts.backoff_s * 2 ** (attempt - 1))
            try:
                r = self.http.request(method, path, headers=headers, **kw)
            except httpx.TransportError as exc:
                last = exc
                continue
            if r.status_code in _RETRY_STATUS:
                last = ApiError(r.status_code, r.text)
                continue
            return r
        raise Offline(f"{method} {path}: gave up after {self.opts.retries + 1} attempts: {last}")

    def _json(self, method: str, path: str, **kw: Any) -> Any:
        return _decode(self.request(method, path, **kw))

    # -------------------------------------------------------------- resources
    def me(self) -> dict[str, Any]:
        return self._json("GET", "/v1/users/me")

    def create_device(self, kind: str, name: str = "") -> dict[str, Any]:
        return self._json("POST", "/v1/devices", json={"kind": kind, "name": name})

    def devices(self) -> list[dict[str, Any]]:
        return self._json("GET", "/v1/devices")

    def start_session(
        self,
        device_kind: str,
        device_id: int | None = None,
        latitude_deg: float | None = None,
        longitude_deg: float | None = None,
        altitude_m: float | None = None,
    ) -> dict[str, Any]:
        """Start a session (optional WGS-84 start for GeoJSON export); returns the session document."""
        body = {"device_kind": device_kind, "device_id": device_id, "latitude_deg": latitude_deg,
                "longitude_deg": longitude_deg, "altitude_m": altitude_m}
        return self._json("POST", "/v1/sessions", json=body)

    def session(self, session_id: int) -> dict[str, Any]:
        return self._json("GET", f"/v1/sessions/{session_id}")

    def sessions(self, status: str | None = None) -> list[dict[str, Any]]:
        return self._json("GET", "/v1/sessions", params={"status": status} if status else None)

    def close_session(self, session_id: int) -> dict[str, Any]:
        return self._json("POST", f"/v1/sessions/{session_id}/close")

    def upload(self, session_id: int, seq: int, batch: SensorBatch) -> dict[str, Any]:
        """Upload batch ``seq``; retried with the same number on failures; returns the server's answer."""
        body, ctype = encode_batch(batch, self.opts.encoding, self.opts.float_dtype)
        return self.upload_encoded(session_id, seq, body, ctype)

    def upload_encoded(self, session_id: int, seq: int, body: bytes, ctype: str) -> dict[str, Any]:
        return self._json("PUT", f"/v1/sessions/{session_id}/batches/{seq}", content=body, headers={"content-type": ctype})

    def trajectory(self, session_id: int, format: str = "json") -> Any:  # noqa: A002
        """Positions as JSON (dict), GeoJSON (dict) or CSV (str)."""
        r = self.request("GET", f"/v1/sessions/{session_id}/trajectory", params={"format": format})
        _raise_for(r)
        return r.text if format == "csv" else r.json()

    def events(self, session_id: int) -> list[dict[str, Any]]:
        return self._json("GET", f"/v1/sessions/{session_id}/events")

    def gait_summary(self) -> dict[str, Any]:
        return self._json("GET", "/v1/users/me/gait-summary")

    def profiles(self) -> list[dict[str, Any]]:
        return self._json("GET", "/v1/profiles")

    def profile(self, behaviour: str) -> dict[str, Any]:
        return self._json("GET", f"/v1/profiles/{behaviour}")

    def put_profile(self, behaviour: str, data: dict[str, Any]) -> dict[str, Any]:
        return self._json("PUT", f"/v1/profiles/{behaviour}", json={"data": data})

    def reset_profile(self, behaviour: str) -> dict[str, Any]:
        return self._json("DELETE", f"/v1/profiles/{behaviour}")

    def profile_history(self, behaviour: str) -> list[dict[str, Any]]:
        return self._json("GET", f"/v1/profiles/{behaviour}/history")

    def stream(self, session_id: int, next_seq: int = 0, max_buffer: int = 86_400) -> BatchStream:
        """An upload stream with offline buffering for a session."""
        return BatchStream(self, session_id, next_seq, max_buffer)


class BatchStream:
    """Sequenced uploads with an in-order offline buffer.

    Parameters
    ----------
    client : PednavClient
    session_id : int
    next_seq : int
        Sequence number of the next batch (0 for a new session; ``session["next_seq"]`` to resume).
    max_buffer : int
        Most batches kept while offline; beyond that :meth:`send` raises ``BufferError``.
    """

    def __init__(self, client: PednavClient, session_id: int, next_seq: int = 0, max_buffer: int = 86_400) -> None:
        self.client = client
        self.session_id = session_id
        self.next_seq = next_seq
        self.max_buffer = max_buffer
        self.pending: deque[tuple[int, bytes, str]] = deque()
        self.last_response: dict[str, Any] | None = None
        self.bytes_sent = 0  # request body bytes queued so far

    @property
    def sensor_config(self) -> dict[str, Any] | None:
        """The sensor configuration of the latest answer (what the device must use next)."""
        return None if self.last_response is None else self.last_response["sensor_config"]

    def send(self, batch: SensorBatch) -> list[dict[str, Any]]:
        """Queue ``batch`` as the next sequence number and deliver what can be delivered.

        Returns the answers received now (oldest first); an empty list means the server is unreachable and
        the batch is buffered.
        """
        if len(self.pending) >= self.max_buffer:
            raise BufferError(f"offline buffer full ({self.max_buffer} batches)")
        body, ctype = encode_batch(batch, self.client.opts.encoding, self.client.opts.float_dtype)
        self.bytes_sent += len(body)
        self.pending.append((self.next_seq, body, ctype))
        self.next_seq += 1
        return self.drain()

    def drain(self) -> list[dict[str, Any]]:
        """Deliver buffered batches in order until one fails in transit."""
        out: list[dict[str, Any]] = []
        while self.pending:
            seq, body, ctype = self.pending[0]
            try:
                resp = self.client.upload_encoded(self.session_id, seq, body, ctype)
            except Offline:
                break
            self.pending.popleft()
            self.last_response = resp
            out.append(resp)
        return out


class AsyncPednavClient:
    """Asynchronous twin of :class:`PednavClient` (same parameters; ``http`` is an ``httpx.AsyncClient``)."""

    def __init__(
        self,
        base_url: str = "http://127.0.0.1:8000",
        token: str | None = None,
        *,
        encoding: Encoding = "msgpack",
        float_dtype: str = "<f8",
        retries: int = 5,
        backoff_s: float = 0.1,
        timeout_s: float = 30.0,
        http: httpx.AsyncClient | None = None,
    ) -> None:
        self._own = http is None
        self.http = http if http is not None else httpx.AsyncClient(base_url=base_url, timeout=timeout_s)
        self.token = token
        self.opts = _Options(encoding, float_dtype, retries, backoff_s)

    async def __aenter__(self) -> AsyncPednavClient:
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.aclose()

    async def aclose(self) -> None:
        if self._own:
            await self.http.aclose()

    async def request(self, method: str, path: str, **kw: Any) -> httpx.Response:
        headers = {**({"Authorization": f"Bearer {self.token}"} if self.token else {}), **(kw.pop("headers", None) or {})}
        last: Exception | None = None
        for attempt in range(self.opts.retries + 1):
            if attempt:
                await asyncio.sleep(self.opts.backoff_s * 2 ** (attempt - 1))
            try:
                r = await self.http.request(method, path, headers=headers, **kw)
            except httpx.TransportError as exc:
                last = exc
                continue
            if r.status_code in _RETRY_STATUS:
                last = ApiError(r.status_code, r.text)
                continue
            return r
        raise Offline(f"{method} {path}: gave up after {self.opts.retries + 1} attempts: {last}")

    async def _json(self, method: str, path: str, **kw: Any) -> Any:
        return _decode(await self.request(method, path, **kw))

    async def me(self) -> dict[str, Any]:
        return await self._json("GET", "/v1/users/me")

    async def start_session(
        self,
        device_kind: str,
        device_id: int | None = None,
        latitude_deg: float | None = None,
        longitude_deg: float | None = None,
        altitude_m: float | None = None,
    ) -> dict[str, Any]:
        body = {"device_kind": device_kind, "device_id": device_id, "latitude_deg": latitude_deg,
                "longitude_deg": longitude_deg, "altitude_m": altitude_m}
        return await self._json("POST", "/v1/sessions", json=body)

    async def session(self, session_id: int) -> dict[str, Any]:
        return await self._json("GET", f"/v1/sessions/{session_id}")

    async def close_session(self, session_id: int) -> dict[str, Any]:
        return await self._json("POST", f"/v1/sessions/{session_id}/close")

    async def upload(self, session_id: int, seq: int, batch: SensorBatch) -> dict[str, Any]:
        body, ctype = encode_batch(batch, self.opts.encoding, self.opts.float_dtype)
        return await self.upload_encoded(session_id, seq, body, ctype)

    async def upload_encoded(self, session_id: int, seq: int, body: bytes, ctype: str) -> dict[str, Any]:
        return await self._json("PUT", f"/v1/sessions/{session_id}/batches/{seq}", content=body, headers={"content-type": ctype})

    async def trajectory(self, session_id: int, format: str = "json") -> Any:  # noqa: A002
        r = await self.request("GET", f"/v1/sessions/{session_id}/trajectory", params={"format": format})
        _raise_for(r)
        return r.text if format == "csv" else r.json()

    def stream(self, session_id: int, next_seq: int = 0, max_buffer: int = 86_400) -> AsyncBatchStream:
        return AsyncBatchStream(self, session_id, next_seq, max_buffer)


class AsyncBatchStream:
    """Asynchronous twin of :class:`BatchStream`."""

    def __init__(self, client: AsyncPednavClient, session_id: int, next_seq: int = 0, max_buffer: int = 86_400) -> None:
        self.client = client
        self.session_id = session_id
        self.next_seq = next_seq
        self.max_buffer = max_buffer
        self.pending: deque[tuple[int, bytes, str]] = deque()
        self.last_response: dict[str, Any] | None = None
        self.bytes_sent = 0  # request body bytes queued so far

    @property
    def sensor_config(self) -> dict[str, Any] | None:
        return None if self.last_response is None else self.last_response["sensor_config"]

    async def send(self, batch: SensorBatch) -> list[dict[str, Any]]:
        if len(self.pending) >= self.max_buffer:
            raise BufferError(f"offline buffer full ({self.max_buffer} batches)")
        body, ctype = encode_batch(batch, self.client.opts.encoding, self.client.opts.float_dtype)
        self.bytes_sent += len(body)
        self.pending.append((self.next_seq, body, ctype))
        self.next_seq += 1
        return await self.drain()

    async def drain(self) -> list[dict[str, Any]]:
        out: list[dict[str, Any]] = []
        while self.pending:
            seq, body, ctype = self.pending[0]
            try:
                resp = await self.client.upload_encoded(self.session_id, seq, body, ctype)
            except Offline:
                break
            self.pending.popleft()
            self.last_response = resp
            out.append(resp)
        return out
