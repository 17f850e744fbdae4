"""Python SDK of the pednav REST API (httpx2; sync and async).

Uploads are sequenced: batch ``k`` of a session is ``PUT /v1/sessions/{id}/batches/{k}``. A failed request
(connection error, timeout, 429/5xx) is retried with the *same* sequence number and body, which the server
acknowledges again without applying it twice. :class:`BatchStream` adds offline buffering: batches that
cannot be delivered stay queued in order and go out with the next successful send. With ``spool_dir`` the
queue lives on disk (:class:`Spool`, a small SQLite file): every batch is written there, durably, before it
is sent and removed only when the server has acknowledged it, so a crash of the app loses nothing — after a
restart ``api.stream(session_id, spool_dir=...)`` (or :meth:`PednavClient.resume`) sends the queued batches
again with their original sequence numbers, and the server applies each exactly once.

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
import sqlite3
import threading
import time
from collections import deque
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import httpx2
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
    "Spool",
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


def _raise_for(r: httpx2.Response) -> None:
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


def _is_empty(batch: SensorBatch) -> bool:
    """No sample in any stream (the server refuses such an upload)."""
    return not any(len(batch.stream(name)[0]) for name in STREAMS)


def _retry_after(r: httpx2.Response, cap_s: float = 30.0) -> float:
    """Extra wait [s] a 429/503 asks for (``Retry-After`` in seconds; 0 when absent or unreadable)."""
    try:
        return min(max(float(r.headers.get("retry-after", "0")), 0.0), cap_s)
    except ValueError:
        return 0.0


def _decode(r: httpx2.Response) -> Any:
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
    wait_s: float = 300.0


class _RetryPlan:
    """When one request is tried again, and after how long.

    A transport error or a 429/502/503/504 uses up one of ``retries`` extra attempts, the n-th after
    ``backoff_s * 2**(n-1)`` plus the ``Retry-After`` the answer asks for. A 503 or 429 WITH ``Retry-After`` (the
    server says it stored nothing and when to come back: its engines compiling after a fresh install, an engine
    helper that died twice, a busy database, a rate limit) uses up no attempt while such waits add up to at most
    ``wait_s``: a device waits out a server that is starting instead of giving up on it after a few seconds.
    """

    def __init__(self, opts: _Options) -> None:
        self.opts = opts
        self.attempts = 0  # extra attempts used up
        self.waited_s = 0.0  # waited for Retry-After answers that used up no attempt

    def wait_before_next(self, r: httpx2.Response | None) -> float | None:
        """Seconds to wait before trying again after ``r`` (None: a transport error), or None to give up."""
        if r is not None and r.status_code in (429, 503) and "retry-after" in r.headers:
            ra = max(_retry_after(r), 0.1)
            if self.waited_s + ra <= self.opts.wait_s:
                self.waited_s += ra
                return ra
        if self.attempts >= self.opts.retries:
            return None
        self.attempts += 1
        return self.opts.backoff_s * 2 ** (self.attempts - 1) + (_retry_after(r) if r is not None else 0.0)


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
    wait_s : float
        Longest total wait [s] for 503/429 answers that carry ``Retry-After`` (they use up no attempt before it;
        see :class:`_RetryPlan`).
    timeout_s : float
        Per-request timeout [s].
    http : httpx2.Client, optional
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
        wait_s: float = 300.0,
        timeout_s: float = 30.0,
        http: httpx2.Client | None = None,
    ) -> None:
        self._own = http is None
        self.http = http if http is not None else httpx2.Client(base_url=base_url, timeout=timeout_s)
        self.token = token
        self.opts = _Options(encoding, float_dtype, retries, backoff_s, wait_s)

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

    def request(self, method: str, path: str, **kw: Any) -> httpx2.Response:
        """One request with retries on transport errors and 429/5xx; raises :class:`Offline` at the end."""
        headers = self._headers(kw.pop("headers", None))
        plan = _RetryPlan(self.opts)
        while True:
            resp: httpx2.Response | None = None
            try:
                resp = self.http.request(method, path, headers=headers, **kw)
            except httpx2.TransportError as exc:
                last: Exception = exc
            else:
                if resp.status_code not in _RETRY_STATUS:
                    return resp
                last = ApiError(resp.status_code, resp.text)
            wait = plan.wait_before_next(resp)
            if wait is None:
                raise Offline(f"{method} {path}: gave up after {plan.attempts + 1} attempts: {last}")
            time.sleep(wait)

    def _json(self, method: str, path: str, **kw: Any) -> Any:
        return _decode(self.request(method, path, **kw))

    @property
    def server_key(self) -> str:
        """Identifies the server in a shared :class:`Spool` (its base URL)."""
        return str(self.http.base_url).rstrip("/")

    # -------------------------------------------------------------- resources
    def me(self) -> dict[str, Any]:
        return self._json("GET", "/v1/users/me")

    def new_token(self, label: str = "api", ttl_s: int | None = None) -> dict[str, Any]:
        """Mint another token for this user (e.g. one per device), at most as long-lived as the one in use."""
        body: dict[str, Any] = {"label": label}
        if ttl_s is not None:
            body["ttl_s"] = ttl_s
        return self._json("POST", "/v1/tokens", json=body)

    def tokens(self) -> list[dict[str, Any]]:
        """This user's tokens (ids, labels, lifetimes; never the tokens themselves)."""
        return self._json("GET", "/v1/tokens")

    def revoke_token(self, token_id: int) -> None:
        """Revoke one of this user's tokens by id (a lost device's)."""
        self._json("DELETE", f"/v1/tokens/{token_id}")

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
        anchor_date: str | None = None,
        anchor_accuracy_m: float | None = None,
        placement: str | None = None,
    ) -> dict[str, Any]:
        """Start a session, optionally anchored (WGS-84 position of the first stance; ``anchor_date`` ISO
        ``YYYY-MM-DD``, the World Magnetic Model's date); ``placement``: ``foot``, ``phone-hand``,
        ``phone-pocket``, ``watch`` or None to let the server recognise a phone's; returns the session document."""
        body = {"device_kind": device_kind, "device_id": device_id, "latitude_deg": latitude_deg,
                "longitude_deg": longitude_deg, "altitude_m": altitude_m}
        if anchor_date is not None:
            body["anchor_date"] = anchor_date
        if anchor_accuracy_m is not None:
            body["anchor_accuracy_m"] = anchor_accuracy_m
        if placement is not None:
            body["placement"] = placement
        return self._json("POST", "/v1/sessions", json=body)

    def patch_session(self, session_id: int, **changes: Any) -> dict[str, Any]:
        """Change a session's anchor (``latitude_deg``, ``longitude_deg``, ``altitude_m``, ``anchor_date``,
        ``anchor_accuracy_m``; latitude and longitude None remove it); returns the session document."""
        return self._json("PATCH", f"/v1/sessions/{session_id}", json=changes)

    def delete_session(self, session_id: int) -> None:
        """Delete a session with its batches, positions and events (the calibration profiles stay)."""
        _raise_for(self.request("DELETE", f"/v1/sessions/{session_id}"))

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

    def trajectory(self, session_id: int, format: str = "json", fuse_with: int | None = None) -> Any:  # noqa: A002
        """Positions as JSON or GeoJSON (dict), or GPX, KML, CSV (str); ``fuse_with``: the id of the same user's
        watch (or other phone) session whose steps are fused with this one's."""
        params: dict[str, Any] = {"format": format, **({"fuse_with": fuse_with} if fuse_with is not None else {})}
        r = self.request("GET", f"/v1/sessions/{session_id}/trajectory", params=params)
        _raise_for(r)
        return r.json() if format in ("json", "geojson") else r.text

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

    def reprocess(self, session_id: int, engine_mode: str | None = None, dry_run: bool = False) -> dict[str, Any]:
        """Re-process a session with the server's current engine from its stored raw batches."""
        return self._json("POST", f"/v1/sessions/{session_id}/reprocess", json={"engine_mode": engine_mode, "dry_run": dry_run})

    def stream(
        self, session_id: int, next_seq: int = 0, max_buffer: int = 86_400, spool_dir: str | Path | None = None
    ) -> BatchStream:
        """An upload stream with offline buffering for a session (on disk in ``spool_dir`` when given)."""
        return BatchStream(self, session_id, next_seq, max_buffer, spool_dir)

    def resume(self, spool_dir: str | Path) -> dict[int, list[dict[str, Any]]]:
        """After a restart: send every batch still queued in ``spool_dir`` for this server, per session in
        sequence order; returns the answers per session (sessions that are still unreachable stay queued)."""
        with Spool(spool_dir) as sp:
            sids = sp.sessions(self.server_key)
        out: dict[int, list[dict[str, Any]]] = {}
        for sid in sids:
            with self.stream(sid, spool_dir=spool_dir) as st:
                out[sid] = st.drain()
        return out


class Spool:
    """A durable on-disk queue of uploads that the server has not acknowledged yet (one SQLite file,
    ``pednav-spool.sqlite3``, in a directory of the app's choosing).

    A batch is committed to the file (``synchronous=FULL``: on stable storage when the call returns) before
    it is sent, and removed only after the server's answer; the next sequence number of each session is kept
    in the same transaction. Several sessions and servers share one file (keyed by the server's base URL and
    the session id). Usable from several threads.

    Parameters
    ----------
    directory : str or Path
        Created when missing.
    """

    FILENAME = "pednav-spool.sqlite3"

    def __init__(self, directory: str | Path) -> None:
        d = Path(directory)
        d.mkdir(parents=True, exist_ok=True)
        self.path = d / self.FILENAME
        self._lock = threading.Lock()
        self._db = sqlite3.connect(self.path, isolation_level=None, check_same_thread=False, timeout=30.0)
        self._db.execute("PRAGMA journal_mode=WAL")
        self._db.execute("PRAGMA synchronous=FULL")
        self._db.execute(
            "CREATE TABLE IF NOT EXISTS pending (server TEXT NOT NULL, session_id INTEGER NOT NULL, seq INTEGER NOT NULL,"
            " body BLOB NOT NULL, ctype TEXT NOT NULL, PRIMARY KEY (server, session_id, seq))"
        )
        self._db.execute(
            "CREATE TABLE IF NOT EXISTS streams (server TEXT NOT NULL, session_id INTEGER NOT NULL,"
            " next_seq INTEGER NOT NULL, PRIMARY KEY (server, session_id))"
        )

    def __enter__(self) -> Spool:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        with self._lock:
            self._db.close()

    def next_seq(self, server: str, session_id: int) -> int | None:
        """The next sequence number recorded for a session (None when the spool never saw it)."""
        with self._lock:
            row = self._db.execute(
                "SELECT next_seq FROM streams WHERE server=? AND session_id=?", (server, session_id)).fetchone()
        return None if row is None else int(row[0])

    def sessions(self, server: str) -> list[int]:
        """Sessions of ``server`` with queued batches."""
        with self._lock:
            rows = self._db.execute(
                "SELECT DISTINCT session_id FROM pending WHERE server=? ORDER BY session_id", (server,)).fetchall()
        return [int(r[0]) for r in rows]

    def push(self, server: str, session_id: int, seq: int, body: bytes, ctype: str) -> None:
        """Queue batch ``seq`` and record ``seq + 1`` as the session's next number (one durable commit)."""
        with self._lock:
            self._db.execute("BEGIN IMMEDIATE")
            try:
                self._db.execute("INSERT INTO pending VALUES (?, ?, ?, ?, ?)", (server, session_id, seq, body, ctype))
                self._db.execute(
                    "INSERT INTO streams VALUES (?, ?, ?) ON CONFLICT (server, session_id) DO UPDATE SET "
                    "next_seq = max(next_seq, excluded.next_seq)", (server, session_id, seq + 1))
                self._db.execute("COMMIT")
            except BaseException:
                self._db.execute("ROLLBACK")
                raise

    def set_next_seq(self, server: str, session_id: int, next_seq: int) -> None:
        with self._lock:
            self._db.execute(
                "INSERT INTO streams VALUES (?, ?, ?) ON CONFLICT (server, session_id) DO UPDATE SET "
                "next_seq = max(next_seq, excluded.next_seq)", (server, session_id, next_seq))

    def remove(self, server: str, session_id: int, seq: int) -> None:
        """Forget an acknowledged batch."""
        with self._lock:
            self._db.execute("DELETE FROM pending WHERE server=? AND session_id=? AND seq=?", (server, session_id, seq))

    def items(self, server: str, session_id: int) -> list[tuple[int, bytes, str]]:
        """Queued batches of a session, oldest first, as ``(seq, body, content_type)``."""
        with self._lock:
            rows = self._db.execute(
                "SELECT seq, body, ctype FROM pending WHERE server=? AND session_id=? ORDER BY seq",
                (server, session_id)).fetchall()
        return [(int(a), bytes(b), str(c)) for a, b, c in rows]

    def first(self, server: str, session_id: int) -> tuple[int, bytes, str] | None:
        """The oldest queued batch of a session."""
        with self._lock:
            row = self._db.execute(
                "SELECT seq, body, ctype FROM pending WHERE server=? AND session_id=? ORDER BY seq LIMIT 1",
                (server, session_id)).fetchone()
        return None if row is None else (int(row[0]), bytes(row[1]), str(row[2]))

    def count(self, server: str, session_id: int) -> int:
        with self._lock:
            return int(self._db.execute(
                "SELECT count(*) FROM pending WHERE server=? AND session_id=?", (server, session_id)).fetchone()[0])


class _MemoryQueue:
    """The in-memory pending queue (no spool)."""

    def __init__(self) -> None:
        self._q: deque[tuple[int, bytes, str]] = deque()

    def __len__(self) -> int:
        return len(self._q)

    def __iter__(self) -> Iterator[tuple[int, bytes, str]]:
        return iter(list(self._q))

    def first(self) -> tuple[int, bytes, str] | None:
        return self._q[0] if self._q else None

    def push(self, seq: int, body: bytes, ctype: str) -> None:
        self._q.append((seq, body, ctype))

    def remove(self, seq: int) -> None:
        if self._q and self._q[0][0] == seq:
            self._q.popleft()

    def close(self) -> None:
        pass


class _SpoolQueue:
    """The pending queue of one session in a :class:`Spool`."""

    def __init__(self, spool: Spool, server: str, session_id: int, own: bool) -> None:
        self.spool, self.server, self.session_id, self._own = spool, server, session_id, own

    def __len__(self) -> int:
        return self.spool.count(self.server, self.session_id)

    def __iter__(self) -> Iterator[tuple[int, bytes, str]]:
        return iter(self.spool.items(self.server, self.session_id))

    def first(self) -> tuple[int, bytes, str] | None:
        return self.spool.first(self.server, self.session_id)

    def push(self, seq: int, body: bytes, ctype: str) -> None:
        self.spool.push(self.server, self.session_id, seq, body, ctype)

    def remove(self, seq: int) -> None:
        self.spool.remove(self.server, self.session_id, seq)

    def close(self) -> None:
        if self._own:
            self.spool.close()


def _queue(server: str, session_id: int, next_seq: int, spool_dir: str | Path | Spool | None) -> tuple[Any, int]:
    if spool_dir is None:
        return _MemoryQueue(), next_seq
    spool = spool_dir if isinstance(spool_dir, Spool) else Spool(spool_dir)
    stored = spool.next_seq(server, session_id)
    nxt = max(next_seq, stored if stored is not None else 0)
    spool.set_next_seq(server, session_id, nxt)
    return _SpoolQueue(spool, server, session_id, own=not isinstance(spool_dir, Spool)), nxt


class BatchStream:
    """Sequenced uploads with an in-order offline buffer (in memory, or durable on disk with ``spool_dir``).

    Parameters
    ----------
    client : PednavClient
    session_id : int
    next_seq : int
        Sequence number of the next batch (0 for a new session; ``session["next_seq"]`` to resume). With a
        spool the larger of this and the spool's own record is used, so batches queued before a crash keep
        their numbers and new ones follow them.
    max_buffer : int
        Most batches kept while offline; beyond that :meth:`send` raises ``BufferError``.
    spool_dir : str, Path or Spool, optional
        Keep the queue in this directory's :class:`Spool`; batches queued there by an earlier run (crash)
        are delivered first.
    """

    def __init__(
        self, client: PednavClient, session_id: int, next_seq: int = 0, max_buffer: int = 86_400,
        spool_dir: str | Path | Spool | None = None,
    ) -> None:
        self.client = client
        self.session_id = session_id
        self.max_buffer = max_buffer
        self.pending, self.next_seq = _queue(client.server_key, session_id, next_seq, spool_dir)
        self.last_response: dict[str, Any] | None = None
        self.bytes_sent = 0  # request body bytes queued so far

    def __enter__(self) -> BatchStream:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Close the spool file (queued batches stay in it)."""
        self.pending.close()

    @property
    def sensor_config(self) -> dict[str, Any] | None:
        """The sensor configuration of the latest answer (what the device must use next).

        Keys as :class:`energy.types.SensorConfig`; with ``gyro_wake_on_motion`` the gyroscope is off but the
        device turns it on by itself (``sleep_after_s``; ``wake_mode`` says on what: ``"motion"``, a departure from
        the still reference, and ``"high_g"``, the absolute acceleration, beyond ``wake_threshold_ms2``;
        ``"weak_field"``, a still stance whose field calibrated by ``mag_offset_ut`` and ``mag_matrix`` has a
        horizontal part below ``wake_field_ut``; ``"compass_swing"``, a phone's compass azimuth changing by more than
        ``wake_swing_rad`` within ``wake_window_s``); with ``gyro_on`` and ``gyr_duty_period_s`` > 0 the device
        duty-cycles the gyroscope itself (powered up every ``gyr_duty_period_s`` of its own clock, delivering for
        ``gyr_duty_on_s`` after its turn-on time; keys absent in older servers' answers mean 0, not duty-cycled),
        see :class:`energy.device.DeviceEmulator`.
        """
        return None if self.last_response is None else self.last_response["sensor_config"]

    def send(self, batch: SensorBatch) -> list[dict[str, Any]]:
        """Queue ``batch`` as the next sequence number and deliver what can be delivered.

        Returns the answers received now (oldest first, including those of batches queued earlier); an
        empty list means the server is unreachable and the batch is buffered. A batch without samples is not
        sent (the server refuses it; the sequence number stays free) and only delivers what is buffered.
        """
        if _is_empty(batch):
            return self.drain()
        if len(self.pending) >= self.max_buffer:
            raise BufferError(f"offline buffer full ({self.max_buffer} batches)")
        body, ctype = encode_batch(batch, self.client.opts.encoding, self.client.opts.float_dtype)
        self.bytes_sent += len(body)
        self.pending.push(self.next_seq, body, ctype)  # durable before it is sent
        self.next_seq += 1
        return self.drain()

    def drain(self) -> list[dict[str, Any]]:
        """Deliver buffered batches in order until one fails in transit."""
        out: list[dict[str, Any]] = []
        while (head := self.pending.first()) is not None:
            seq, body, ctype = head
            try:
                resp = self.client.upload_encoded(self.session_id, seq, body, ctype)
            except Offline:
                break
            self.pending.remove(seq)  # only after the server's answer
            self.last_response = resp
            out.append(resp)
        return out


class AsyncPednavClient:
    """Asynchronous twin of :class:`PednavClient` (same parameters; ``http`` is an ``httpx2.AsyncClient``)."""

    def __init__(
        self,
        base_url: str = "http://127.0.0.1:8000",
        token: str | None = None,
        *,
        encoding: Encoding = "msgpack",
        float_dtype: str = "<f8",
        retries: int = 5,
        backoff_s: float = 0.1,
        wait_s: float = 300.0,
        timeout_s: float = 30.0,
        http: httpx2.AsyncClient | None = None,
    ) -> None:
        self._own = http is None
        self.http = http if http is not None else httpx2.AsyncClient(base_url=base_url, timeout=timeout_s)
        self.token = token
        self.opts = _Options(encoding, float_dtype, retries, backoff_s, wait_s)

    async def __aenter__(self) -> AsyncPednavClient:
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.aclose()

    async def aclose(self) -> None:
        if self._own:
            await self.http.aclose()

    async def request(self, method: str, path: str, **kw: Any) -> httpx2.Response:
        headers = {**({"Authorization": f"Bearer {self.token}"} if self.token else {}), **(kw.pop("headers", None) or {})}
        plan = _RetryPlan(self.opts)
        while True:
            resp: httpx2.Response | None = None
            try:
                resp = await self.http.request(method, path, headers=headers, **kw)
            except httpx2.TransportError as exc:
                last: Exception = exc
            else:
                if resp.status_code not in _RETRY_STATUS:
                    return resp
                last = ApiError(resp.status_code, resp.text)
            wait = plan.wait_before_next(resp)
            if wait is None:
                raise Offline(f"{method} {path}: gave up after {plan.attempts + 1} attempts: {last}")
            await asyncio.sleep(wait)

    @property
    def server_key(self) -> str:
        return str(self.http.base_url).rstrip("/")

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
        placement: str | None = None,
    ) -> dict[str, Any]:
        body = {"device_kind": device_kind, "device_id": device_id, "latitude_deg": latitude_deg,
                "longitude_deg": longitude_deg, "altitude_m": altitude_m}
        if placement is not None:
            body["placement"] = placement
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

    async def trajectory(self, session_id: int, format: str = "json", fuse_with: int | None = None) -> Any:  # noqa: A002
        params: dict[str, Any] = {"format": format, **({"fuse_with": fuse_with} if fuse_with is not None else {})}
        r = await self.request("GET", f"/v1/sessions/{session_id}/trajectory", params=params)
        _raise_for(r)
        return r.text if format == "csv" else r.json()

    async def reprocess(self, session_id: int, engine_mode: str | None = None, dry_run: bool = False) -> dict[str, Any]:
        return await self._json("POST", f"/v1/sessions/{session_id}/reprocess", json={"engine_mode": engine_mode, "dry_run": dry_run})

    def stream(
        self, session_id: int, next_seq: int = 0, max_buffer: int = 86_400, spool_dir: str | Path | None = None
    ) -> AsyncBatchStream:
        return AsyncBatchStream(self, session_id, next_seq, max_buffer, spool_dir)


class AsyncBatchStream:
    """Asynchronous twin of :class:`BatchStream` (the spool's file operations are short and synchronous)."""

    def __init__(
        self, client: AsyncPednavClient, session_id: int, next_seq: int = 0, max_buffer: int = 86_400,
        spool_dir: str | Path | Spool | None = None,
    ) -> None:
        self.client = client
        self.session_id = session_id
        self.max_buffer = max_buffer
        self.pending, self.next_seq = _queue(client.server_key, session_id, next_seq, spool_dir)
        self.last_response: dict[str, Any] | None = None
        self.bytes_sent = 0  # request body bytes queued so far

    def close(self) -> None:
        self.pending.close()

    @property
    def sensor_config(self) -> dict[str, Any] | None:
        return None if self.last_response is None else self.last_response["sensor_config"]

    async def send(self, batch: SensorBatch) -> list[dict[str, Any]]:
        if _is_empty(batch):
            return await self.drain()
        if len(self.pending) >= self.max_buffer:
            raise BufferError(f"offline buffer full ({self.max_buffer} batches)")
        body, ctype = encode_batch(batch, self.client.opts.encoding, self.client.opts.float_dtype)
        self.bytes_sent += len(body)
        self.pending.push(self.next_seq, body, ctype)
        self.next_seq += 1
        return await self.drain()

    async def drain(self) -> list[dict[str, Any]]:
        out: list[dict[str, Any]] = []
        while (head := self.pending.first()) is not None:
            seq, body, ctype = head
            try:
                resp = await self.client.upload_encoded(self.session_id, seq, body, ctype)
            except Offline:
                break
            self.pending.remove(seq)
            self.last_response = resp
            out.append(resp)
        return out
