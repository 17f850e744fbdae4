"""FastAPI dependencies as ``Annotated`` aliases: the database session and the authenticated user."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Annotated

from fastapi import Depends, HTTPException, Path, Query, Request, status
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from sqlalchemy.orm import Session

from server.auth import authenticate, query_token_refused
from server.ingest import EngineHost
from server.models import User
from server.settings import Settings

__all__ = ["ID_MAX", "ID_MIN", "INT64_MAX", "OffsetQuery", "PathId", "SessionDep", "CurrentUser", "SensorLoggerUser", "SettingsDep", "HostDep", "get_db", "current_user", "sensorlogger_user"]

INT64_MAX = 2**63 - 1
"""Largest offset the database can bind (SQLite INTEGER, PostgreSQL bigint); a larger one made the driver raise
OverflowError (HTTP 500) before the query could answer "not found"."""

ID_MIN, ID_MAX = -(2**31), 2**31 - 1
"""Range of the id and sequence-number columns (``Integer``: 32-bit on PostgreSQL). A path id between 2^31 and
2^63 - 1 reached PostgreSQL and failed there ("integer out of range": HTTP 500); SQLite took it."""

# an id or sequence number in the path: 422 naming the parameter beyond the column's range, never a driver error
PathId = Annotated[int, Path(ge=ID_MIN, le=ID_MAX)]
OffsetQuery = Annotated[int, Query(le=INT64_MAX)]

_bearer = HTTPBearer(auto_error=False)


def get_db(request: Request) -> Iterator[Session]:
    with request.app.state.sessionmaker() as db:
        yield db


SessionDep = Annotated[Session, Depends(get_db)]


def get_settings(request: Request) -> Settings:
    return request.app.state.settings


def get_host(request: Request) -> EngineHost:
    return request.app.state.host


SettingsDep = Annotated[Settings, Depends(get_settings)]
HostDep = Annotated[EngineHost, Depends(get_host)]


def client_address(request: Request) -> str | None:
    """The peer address the failed-authentication guard counts by (:class:`server.auth.FailedAuthGuard`)."""
    return request.client.host if request.client is not None else None


def _user_of(db: Session, request: Request, token: str | None) -> User:
    request.state.token = token  # the token this request was authenticated with (DELETE /v1/tokens/current)
    guard = request.app.state.auth_guard
    client = client_address(request)
    guard.check(client)  # 429 before the lookup for a client that keeps failing
    try:
        try:
            user_id = authenticate(db, token, request.app.state.limiter)
        except HTTPException as exc:
            if exc.status_code == status.HTTP_401_UNAUTHORIZED:
                guard.failed(client)
            raise
        user = db.get(User, user_id)
        if user is None:
            raise HTTPException(status.HTTP_401_UNAUTHORIZED, "invalid token", headers={"WWW-Authenticate": "Bearer"})
        db.expunge(user)  # keep the loaded row usable after the transaction ends
    finally:
        # end the read transaction now: the connection goes back to the pool before the next thread hop, so
        # requests waiting for a worker thread never sit on pooled connections (that deadlocks under load)
        db.rollback()
    return user


def current_user(
    db: SessionDep,
    request: Request,
    cred: Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)],
) -> User:
    """The user owning the bearer token (``Authorization: Bearer ...``).

    401 for a missing, invalid, revoked or expired token, and for a request with a ``token`` query parameter
    (only the Sensor Logger push takes one, :func:`sensorlogger_user`); 429 when the token exceeds its rate limit.
    """
    if "token" in request.query_params:
        request.app.state.auth_guard.failed(client_address(request))  # the token may be guessed through logs
        raise query_token_refused()
    return _user_of(db, request, cred.credentials if cred is not None else None)


def sensorlogger_user(
    db: SessionDep,
    request: Request,
    cred: Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)],
) -> User:
    """:func:`current_user` for ``POST /v1/sensorlogger``: the token may also come as ``?token=`` (the Sensor
    Logger app cannot set headers); a bearer header wins."""
    return _user_of(db, request, cred.credentials if cred is not None else request.query_params.get("token"))


CurrentUser = Annotated[User, Depends(current_user)]
SensorLoggerUser = Annotated[User, Depends(sensorlogger_user)]
