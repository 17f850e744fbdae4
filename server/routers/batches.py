"""Batch upload: ``PUT /v1/sessions/{id}/batches/{seq}`` with a JSON or msgpack body."""

from __future__ import annotations

import asyncio
import json
import re
import time
from typing import Annotated, Any

from fastapi import APIRouter, Depends, HTTPException, Request, Response, status

from models.batch import BatchError
from server import crud
from server.auth import authenticate, query_token_refused
from server.deps import ID_MAX, ID_MIN, CurrentUser, PathId, SessionDep
from server.formats import MSGPACK_TYPE, decode_batch
from server.ingest import EngineUnavailable, apply_batch
from server.timing import Phases, phase
from server.schemas import BatchResponse

__all__ = ["UploadFastPath", "router"]

router = APIRouter(prefix="/sessions/{session_id}/batches", tags=["batches"])


async def _body(request: Request) -> bytes:
    """The request body (its size is bounded by :class:`server.app.BodyLimit`, declared or streamed)."""
    return await request.body()


def _upload_sync(app: Any, token: str | None, ctype: str | None, session_id: int, seq: int, body: bytes,
                 queued_at: float, client: str | None = None) -> tuple[bytes, list[tuple[bytes, bytes]]]:
    """The whole upload in ONE worker thread: auth, decode, validate, apply, encode (no connection is held
    while a request waits for a thread). Returns the JSON answer and the extra response headers. ``client``: the
    peer address counted by the failed-authentication guard."""
    if not app.state.host.ready():  # a fresh server compiling its engines: answered now, nothing stored
        raise EngineUnavailable("the navigation engines are still being compiled or loaded after the server "
                                "started; this batch was NOT stored: send it again with the same sequence number",
                                retry_after_s=2)
    guard = app.state.auth_guard
    guard.check(client)  # 429 before the token lookup for a client that keeps failing
    try:
        return _upload_guarded(app, token, ctype, session_id, seq, body, queued_at)
    except HTTPException as exc:
        if exc.status_code == status.HTTP_401_UNAUTHORIZED:
            guard.failed(client)
        raise


def _upload_guarded(app: Any, token: str | None, ctype: str | None, session_id: int, seq: int, body: bytes,
                    queued_at: float) -> tuple[bytes, list[tuple[bytes, bytes]]]:
    with Phases() as ph:
        ph.add("queue", time.perf_counter() - queued_at)  # waiting for an ingest thread
        settings = app.state.settings
        if app.state.uploader is not None:  # driver connections, group commit / one statement
            content, replayed = app.state.uploader.upload(token, session_id, seq, body, ctype,
                                                          settings.max_samples_per_stream)
        else:  # PostgreSQL with PEDNAV_PG_ONE_STATEMENT_WRITES=false: the ORM transaction
            with app.state.sessionmaker() as db:
                with phase("auth"):
                    user_id = authenticate(db, token, app.state.limiter)  # 401 / 429
                if seq < 0:
                    raise BatchError("seq", "must be >= 0")
                with phase("decode"):
                    batch = decode_batch(body, ctype, settings.max_samples_per_stream)
                try:
                    out = apply_batch(db, app.state.host, user_id, session_id, seq, batch)
                except BatchError:
                    db.rollback()
                    raise
            if out is None:
                raise HTTPException(status.HTTP_404_NOT_FOUND, f"session {session_id} not found")
            resp, replayed = out
            with phase("encode"):
                content = json.dumps(resp, separators=(",", ":"))
        return content.encode(), [(b"x-pednav-replayed", b"true" if replayed else b"false"),
                                  (b"server-timing", ph.header().encode())]


def _token_of(authorization: str, query_string: bytes) -> str | None:
    """Bearer token of the ``Authorization`` header; a ``token`` query parameter is refused with 401 (only the
    Sensor Logger push takes one, :data:`server.auth.QUERY_TOKEN_ROUTE`)."""
    if query_string:
        from urllib.parse import parse_qs

        if "token" in parse_qs(query_string.decode("latin-1"), keep_blank_values=True):
            raise query_token_refused()
    scheme, _, cred = authorization.partition(" ")
    if scheme.lower() == "bearer" and cred.strip():
        return cred.strip()
    return None


_UPLOAD_PATH = re.compile(r"^/v1/sessions/(\d+)/batches/(-?\d+)$")


class UploadFastPath:
    """Pure ASGI middleware that serves ``PUT /v1/sessions/{id}/batches/{seq}`` without the framework's
    routing, dependency and response layers (about a fifth of the worker's CPU per upload). Same behaviour as
    the route below (which documents the endpoint and serves it when this middleware is not installed): body
    limit, refusals through the app's own exception handlers, answer and headers."""

    def __init__(self, app: Any, fastapi_app: Any) -> None:
        self.app = app
        self.fastapi_app = fastapi_app

    async def __call__(self, scope: Any, receive: Any, send: Any) -> None:
        m = _UPLOAD_PATH.match(scope["path"]) if scope["type"] == "http" and scope["method"] == "PUT" else None
        if m is None or not all(ID_MIN <= int(g) <= ID_MAX for g in m.groups()):
            # not an upload, or an id beyond the id columns' range: the route answers (its validation names it)
            await self.app(scope, receive, send)
            return
        app = self.fastapi_app
        try:
            chunks: list[bytes] = []  # bounded by BodyLimit, which wraps this middleware (413 past the limit)
            more = True
            while more:
                msg = await receive()
                if msg["type"] == "http.disconnect":
                    return
                chunks.append(msg.get("body", b""))
                more = msg.get("more_body", False)
            auth, ctype = "", None
            for k, v in scope["headers"]:
                if k == b"authorization":
                    auth = v.decode("latin-1")
                elif k == b"content-type":
                    ctype = v.decode("latin-1")
            loop = asyncio.get_running_loop()
            content, extra = await loop.run_in_executor(
                app.state.ingest_pool, _upload_sync, app, _token_of(auth, scope.get("query_string", b"")), ctype,
                int(m.group(1)), int(m.group(2)), b"".join(chunks), time.perf_counter(),
                (scope.get("client") or (None,))[0])
        except Exception as exc:
            handler = next((app.exception_handlers[t] for t in type(exc).__mro__ if t in app.exception_handlers), None)
            if handler is None:
                raise
            resp = await handler(Request(scope), exc)
            await resp(scope, receive, send)
            return
        await send({"type": "http.response.start", "status": 200, "headers": [
            (b"content-type", b"application/json"), (b"content-length", str(len(content)).encode()), *extra]})
        await send({"type": "http.response.body", "body": content})


@router.put(
    "/{seq}",
    response_model=BatchResponse,
    openapi_extra={"requestBody": {"required": True, "content": {"application/json": {}, MSGPACK_TYPE: {}}}},
)
async def put_batch(session_id: PathId, seq: PathId, body: Annotated[bytes, Depends(_body)], request: Request) -> Response:
    """Upload batch number ``seq`` (0, 1, 2, ...) of a session (``Authorization: Bearer``).

    Idempotent: a retry with the same number and content gets the same answer (header
    ``X-Pednav-Replayed: true``) and is never applied twice. A gap or an old number with other content
    gets 409 with ``expected_seq``. Samples are validated (units, order, finiteness): 422 names the field.
    The body is JSON or msgpack (``Content-Type``), see ``server/formats.py``.
    """
    loop = asyncio.get_running_loop()
    token = _token_of(request.headers.get("authorization", ""), request.scope.get("query_string", b""))
    content, extra = await loop.run_in_executor(
        request.app.state.ingest_pool, _upload_sync, request.app, token, request.headers.get("content-type"),
        session_id, seq, body, time.perf_counter(), request.client.host if request.client is not None else None)
    return Response(content=content, media_type="application/json", headers={k.decode(): v.decode() for k, v in extra})


@router.get("")
def list_batches(session_id: PathId, db: SessionDep, user: CurrentUser) -> list[dict[str, Any]]:
    """Stored raw batches of a session (metadata)."""
    sess = crud.get_session(db, user, session_id)
    if sess is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"session {session_id} not found")
    return [
        {"seq": b.seq, "n_acc": b.n_acc, "n_gyr": b.n_gyr, "n_mag": b.n_mag, "sha256": b.body_sha256,
         "received_at": b.received_at.isoformat()}
        for b in crud.batches_of(db, sess.id)
    ]


@router.get("/{seq}/raw", response_class=Response)
def raw_batch(session_id: PathId, seq: PathId, db: SessionDep, user: CurrentUser) -> Response:
    """The stored batch in the lossless msgpack format (for re-processing with a newer engine)."""
    sess = crud.get_session(db, user, session_id)
    rec = crud.get_batch(db, sess.id, seq) if sess is not None else None
    if rec is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"batch {seq} of session {session_id} not found")
    return Response(content=rec.raw, media_type=MSGPACK_TYPE)
