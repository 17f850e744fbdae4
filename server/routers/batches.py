"""Batch upload: ``PUT /v1/sessions/{id}/batches/{seq}`` with a JSON or msgpack body."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Depends, HTTPException, Request, Response, status

from models.batch import BatchError
from server import crud
from server.deps import CurrentUser, HostDep, SessionDep, SettingsDep
from server.formats import MSGPACK_TYPE, decode_batch
from server.ingest import apply_batch
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


@router.put(
    "/{seq}",
    response_model=BatchResponse,
    openapi_extra={"requestBody": {"required": True, "content": {"application/json": {}, MSGPACK_TYPE: {}}}},
)
def put_batch(
    session_id: int,
    seq: int,
    body: Annotated[bytes, Depends(_body)],
    request: Request,
    response: Response,
    db: SessionDep,
    user: CurrentUser,
    settings: SettingsDep,
    host: HostDep,
) -> Any:
    """Upload batch number ``seq`` (0, 1, 2, ...) of a session.

    Idempotent: a retry with the same number and content gets the same answer (header
    ``X-Pednav-Replayed: true``) and is never applied twice. A gap or an old number with other content
    gets 409 with ``expected_seq``. Samples are validated (units, order, finiteness): 422 names the field.
    """
    if seq < 0:
        raise BatchError("seq", "must be >= 0")
    batch = decode_batch(body, request.headers.get("content-type"), settings.max_samples_per_stream)
    batch.validate()
    try:
        out = apply_batch(db, host, user, session_id, seq, batch)
    except BatchError:
        db.rollback()
        raise
    if out is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"session {session_id} not found")
    resp, replayed = out
    response.headers["X-Pednav-Replayed"] = "true" if replayed else "false"
    return resp


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
