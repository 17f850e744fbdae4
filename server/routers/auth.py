"""Accounts and tokens: admins create users; every user can mint and revoke their own tokens."""

from __future__ import annotations

from fastapi import APIRouter, HTTPException, Request, status
from sqlalchemy.exc import IntegrityError

from server import crud
from server.deps import CurrentUser, SessionDep
from server.models import Token
from server.schemas import TokenOut, UserCreate
from server.security import hash_token

__all__ = ["router"]

router = APIRouter(tags=["auth"])


@router.post("/users", response_model=TokenOut, status_code=status.HTTP_201_CREATED)
def create_user(body: UserCreate, db: SessionDep, user: CurrentUser) -> TokenOut:
    """Create a user (admins only); returns the new user's first token, shown only once."""
    if not user.is_admin:
        raise HTTPException(status.HTTP_403_FORBIDDEN, "only admins can create users")
    try:
        new, token = crud.create_user(db, body.name)
        db.commit()
    except IntegrityError:
        db.rollback()
        raise HTTPException(status.HTTP_409_CONFLICT, f"name: user {body.name!r} already exists") from None
    return TokenOut(user_id=new.id, token=token)


@router.post("/tokens", response_model=TokenOut, status_code=status.HTTP_201_CREATED)
def new_token(db: SessionDep, user: CurrentUser) -> TokenOut:
    """Mint another token for the calling user (e.g. one per device)."""
    token = crud.issue_token(db, user, "api")
    db.commit()
    return TokenOut(user_id=user.id, token=token)


@router.delete("/tokens/current", status_code=status.HTTP_204_NO_CONTENT)
def revoke_current(request: Request, db: SessionDep, user: CurrentUser) -> None:
    """Revoke the token used for this request."""
    auth = request.headers.get("authorization", "")
    token = auth.split(" ", 1)[1] if " " in auth else request.query_params.get("token", "")
    row = db.query(Token).filter(Token.token_hash == hash_token(token), Token.user_id == user.id).one()
    row.revoked = True
    db.commit()
