"""Accounts and tokens: admins create users; every user can mint and revoke their own tokens."""

from __future__ import annotations

from fastapi import APIRouter, HTTPException, Request, status
from sqlalchemy.exc import IntegrityError

from server import crud
from server.deps import CurrentUser, SessionDep, SettingsDep
from server.models import Token
from server.schemas import TokenCreate, TokenOut, UserCreate
from server.security import hash_token

__all__ = ["router"]

router = APIRouter(tags=["auth"])


@router.post("/users", response_model=TokenOut, status_code=status.HTTP_201_CREATED)
def create_user(body: UserCreate, db: SessionDep, user: CurrentUser, settings: SettingsDep) -> TokenOut:
    """Create a user (admins only); returns the new user's first token (valid ``token_ttl_s``), shown only once."""
    if not user.is_admin:
        raise HTTPException(status.HTTP_403_FORBIDDEN, "only admins can create users")
    try:
        new, token = crud.create_user(db, body.name, ttl_s=settings.token_ttl_s or None)
        row = db.query(Token).filter(Token.token_hash == hash_token(token)).one()
        db.commit()
    except IntegrityError:
        db.rollback()
        raise HTTPException(status.HTTP_409_CONFLICT, f"name: user {body.name!r} already exists") from None
    return TokenOut(user_id=new.id, token=token, expires_at=row.expires_at)


@router.post("/tokens", response_model=TokenOut, status_code=status.HTTP_201_CREATED)
def new_token(db: SessionDep, user: CurrentUser, settings: SettingsDep, body: TokenCreate | None = None) -> TokenOut:
    """Mint another token for the calling user (e.g. one per device); ``ttl_s`` up to the server's
    ``token_max_ttl_s`` (default ``token_ttl_s``)."""
    opts = body or TokenCreate()
    if opts.ttl_s is not None and opts.ttl_s > settings.token_max_ttl_s:
        raise HTTPException(422, f"ttl_s: at most {settings.token_max_ttl_s} s on this server, got {opts.ttl_s}")
    ttl = opts.ttl_s if opts.ttl_s is not None else (settings.token_ttl_s or None)
    token, row = crud.issue_token_row(db, user, opts.label, ttl)
    db.commit()
    return TokenOut(user_id=user.id, token=token, expires_at=row.expires_at)


@router.delete("/tokens/current", status_code=status.HTTP_204_NO_CONTENT)
def revoke_current(request: Request, db: SessionDep, user: CurrentUser) -> None:
    """Revoke the token used for this request."""
    # the token current_user authenticated, not the header parsed again (another scheme with ``?token=``, or
    # extra blanks after "Bearer", named a token that does not exist: HTTP 500)
    row = db.query(Token).filter(Token.token_hash == hash_token(request.state.token), Token.user_id == user.id).one()
    row.revoked = True
    db.commit()
