"""Batch upload: ``PUT /v1/sessions/{id}/batches/{seq}`` with a JSON or msgpack body."""

from __future__ import annotations

import asyncio
import json
import time
from typing import Annotated, Any

from fastapi import APIRouter, Depends, HTTPException, Request, Response, status
from fastapi.security import HTTPAuthorizationCredentials

from models.batch import BatchError
from server import crud
from server.auth import authenticate
from server.deps import CurrentUser, SessionDep
from server.formats import MSGPACK_TYPE, decode_batch
from server.ingest import apply_batch
from server.timing import Phases, phase
from server.schemas import BatchResponse

__all__ = ["router"]

router = APIRouter(prefix="/sessions/{session_id}/batches", tags=["batches"])


async def _body(request: Request) -> bytes:
    limit = request.app.state.settings.max_body_bytes
    chunks: list[bytes] = []
    size = 0
    async for chunk in request.stream():
        size += len(chunk)
        if size > limit:
            raise HTTPException(status.HTTP_413_REQUEST_ENTITY_TOO_LARGE, f"body exceeds the limit of {limit} bytes")
        chunks.append(chunk)
    return b"".join(chunks)


def _put_batch_sync(request: Request, session_id: int, seq: int, body: bytes, queued_at: float) -> Response:
    """The whole upload in ONE worker thread: auth, decode, validate, apply, encode (no connection is held
    while a request waits for a thread)."""
    with Phases() as ph:
        ph.add("queue", time.perf_counter() - queued_at)  # waiting for an ingest thread
        app = request.app
        settings = app.state.settings
        cred = _bearer_of(request)
        token = cred.credentials if cred is not None else request.query_params.get("token")
        ctype = request.headers.get("content-type")
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
        return Response(
            content=content, media_type="application/json",
            headers={"X-Pednav-Replayed": "true" if replayed else "false", "Server-Timing": ph.header()},
        )


def _bearer_of(request: Request) -> HTTPAuthorizationCredentials | None:
    auth = request.headers.get("authorization", "")
    scheme, _, cred = auth.partition(" ")
    if scheme.lower() == "bearer" and cred:
        return HTTPAuthorizationCredentials(scheme=scheme, credentials=cred.strip())
    return None


@router.put(
    "/{seq}",
    response_model=BatchResponse,
    openapi_extra={"requestBody": {"required": True, "content": {"application/json": {}, MSGPACK_TYPE: {}}}},
)
async def put_batch(session_id: int, seq: int, body: Annotated[bytes, Depends(_body)], request: Request) -> Response:
    """Upload batch number ``seq`` (0, 1, 2, ...) of a session (``Authorization: Bearer``).

    Idempotent: a retry with the same number and content gets the same answer (header
    ``X-Pednav-Replayed: true``) and is never applied twice. A gap or an old number with other content
    gets 409 with ``expected_seq``. Samples are validated (units, order, finiteness): 422 names the field.
    The body is JSON or msgpack (``Content-Type``), see ``server/formats.py``.
    """
    loop = asyncio.get_running_loop()
    return await loop.run_in_executor(
        request.app.state.ingest_pool, _put_batch_sync, request, session_id, seq, body, time.perf_counter())


@router.get("")
def list_batches(session_id: int, db: SessionDep, user: CurrentUser) -> list[dict[str, Any]]:
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
def raw_batch(session_id: int, seq: int, db: SessionDep, user: CurrentUser) -> Response:
    """The stored batch in the lossless msgpack format (for re-processing with a newer engine)."""
    sess = crud.get_session(db, user, session_id)
    rec = crud.get_batch(db, sess.id, seq) if sess is not None else None
    if rec is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"batch {seq} of session {session_id} not found")
    return Response(content=rec.raw, media_type=MSGPACK_TYPE)
