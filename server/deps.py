"""FastAPI dependencies as ``Annotated`` aliases: the database session and the authenticated user."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Annotated

from fastapi import Depends, HTTPException, Path, Query, Request, status
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from sqlalchemy.orm import Session

from server.auth import authenticate
from server.ingest import EngineHost
from server.models import User
from server.settings import Settings

__all__ = ["INT64_MAX", "OffsetQuery", "PathId", "SessionDep", "CurrentUser", "SettingsDep", "HostDep", "get_db", "current_user"]

INT64_MAX = 2**63 - 1
"""Largest id, sequence number or offset the database can bind (SQLite INTEGER, PostgreSQL bigint); a larger
one made the driver raise OverflowError (HTTP 500) before the query could answer "not found"."""

# an id or sequence number in the path: 422 naming the parameter beyond int64, never a driver error
PathId = Annotated[int, Path(ge=-INT64_MAX - 1, le=INT64_MAX)]
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


def current_user(
    db: SessionDep,
    request: Request,
    cred: Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)],
) -> User:
    """The user owning the bearer token (``Authorization: Bearer ...``; ``?token=`` for Sensor Logger).

    401 for a missing, invalid, revoked or expired token; 429 when the token exceeds its rate limit.
    """
    token = cred.credentials if cred is not None else request.query_params.get("token")
    request.state.token = token  # the token this request was authenticated with (DELETE /v1/tokens/current)
    try:
        user_id = authenticate(db, token, request.app.state.limiter)
        user = db.get(User, user_id)
        if user is None:
            raise HTTPException(status.HTTP_401_UNAUTHORIZED, "invalid token", headers={"WWW-Authenticate": "Bearer"})
        db.expunge(user)  # keep the loaded row usable after the transaction ends
    finally:
        # end the read transaction now: the connection goes back to the pool before the next thread hop, so
        # requests waiting for a worker thread never sit on pooled connections (that deadlocks under load)
        db.rollback()
    return user


CurrentUser = Annotated[User, Depends(current_user)]
