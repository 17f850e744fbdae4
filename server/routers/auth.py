"""Accounts and tokens: admins create users; every user can mint, list and revoke their own tokens."""

from __future__ import annotations

from datetime import datetime, timedelta, timezone

from fastapi import APIRouter, HTTPException, Request, status
from sqlalchemy import select
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session

from server import crud
from server.deps import CurrentUser, PathId, SessionDep, SettingsDep
from server.models import Token, User
from server.schemas import TokenCreate, TokenInfoOut, TokenOut, UserCreate
from server.security import hash_token
from server.settings import Settings

__all__ = ["router"]

router = APIRouter(tags=["auth"])


def _expiry(db: Session, request: Request, user: User, settings: Settings, ttl_s: int | None) -> datetime | None:
    """Expiry of a token minted by this request (None: never), by the rule that a token never outlives the token
    of the request that mints it; 422 naming ``ttl_s`` for a lifetime beyond ``token_max_ttl_s`` or beyond the
    remaining lifetime of the request's token."""
    if ttl_s is not None and ttl_s > settings.token_max_ttl_s:
        raise HTTPException(422, f"ttl_s: at most {settings.token_max_ttl_s} s on this server, got {ttl_s}")
    now = datetime.now(timezone.utc)
    minting_exp = db.execute(
        select(Token.expires_at).where(Token.token_hash == hash_token(request.state.token), Token.user_id == user.id)
    ).scalar_one_or_none()
    ttl = ttl_s if ttl_s is not None else (settings.token_ttl_s or None)
    exp = None if ttl is None else now + timedelta(seconds=ttl)
    if minting_exp is not None:
        left_s = max(0, int((minting_exp - now).total_seconds()))
        if ttl_s is not None and ttl_s > left_s:
            raise HTTPException(422, (
                f"ttl_s: at most {left_s} s: a token cannot outlive the token that mints it (this one expires at "
                f"{minting_exp.isoformat(timespec='seconds')}), got {ttl_s}; longer-lived tokens come from an "
                "admin ('pednav admin token NAME --ttl-s S')"))
        if exp is None or exp > minting_exp:
            exp = minting_exp  # the default lifetime ends with the minting token
    return exp


@router.post("/users", response_model=TokenOut, status_code=status.HTTP_201_CREATED)
def create_user(request: Request, body: UserCreate, db: SessionDep, user: CurrentUser,
                settings: SettingsDep) -> TokenOut:
    """Create a user (admins only); returns the new user's first token, shown only once.

    The first token follows the rule of ``POST /v1/tokens``: it never outlives the admin's token of this request,
    so an admin token that expires in an hour cannot leave behind an account whose token lasts the default 30
    days. ``ttl_s`` given: at most ``token_max_ttl_s`` and the remaining lifetime of the admin's token (422
    naming ``ttl_s`` beyond); omitted: the server's ``token_ttl_s``, ending no later than the admin's token
    (``expires_at`` of the answer says when). A longer-lived first token comes from
    ``pednav admin create-user NAME --ttl-s S``. 409 naming ``name`` when the user exists.
    """
    if not user.is_admin:
        raise HTTPException(status.HTTP_403_FORBIDDEN, "only admins can create users")
    exp = _expiry(db, request, user, settings, body.ttl_s)
    try:
        new, token = crud.create_user(db, body.name, expires_at=exp)
        row = db.query(Token).filter(Token.token_hash == hash_token(token)).one()
        db.commit()
    except IntegrityError:
        db.rollback()
        raise HTTPException(status.HTTP_409_CONFLICT, f"name: user {body.name!r} already exists") from None
    return TokenOut(user_id=new.id, token=token, expires_at=row.expires_at, id=row.id, label=row.label)


@router.post("/tokens", response_model=TokenOut, status_code=status.HTTP_201_CREATED)
def new_token(request: Request, db: SessionDep, user: CurrentUser, settings: SettingsDep,
              body: TokenCreate | None = None) -> TokenOut:
    """Mint another token for the calling user (e.g. one per device).

    A token never outlives the token that mints it, so a short-lived token cannot be turned into a long-lived
    one:

    - ``ttl_s`` given: at most the server's ``token_max_ttl_s`` and at most the remaining lifetime of the
      token of this request; more is refused with 422 naming ``ttl_s`` and the most that can be had (the
      client asked for a lifetime it would not get, so it is told instead of being handed a shorter one).
    - ``ttl_s`` omitted: the server's ``token_ttl_s``, ending no later than the token of this request
      (``expires_at`` of the answer says when).

    Longer-lived tokens come from an admin: ``pednav admin token NAME --ttl-s S``.

    A user holds at most the server's ``max_tokens_per_user`` live (unexpired, unrevoked) tokens: one more is
    refused with 409 naming ``tokens`` and the limit; ``GET /v1/tokens`` lists them and ``DELETE
    /v1/tokens/{id}`` revokes one. Minting also deletes the user's oldest revoked and expired tokens beyond that
    many. (All of a user's tokens share one rate limit.)
    """
    opts = body or TokenCreate()
    exp = _expiry(db, request, user, settings, opts.ttl_s)
    # the new token is added first and counted with the others: on SQLite its insert takes the write lock, on
    # PostgreSQL the user's row lock makes concurrent mints of one user wait, so they cannot all pass the count
    crud.lock_user(db, user)
    token, row = crud.issue_token_row(db, user, opts.label, expires_at=exp)
    live = crud.count_live_tokens(db, user)
    if live > settings.max_tokens_per_user:
        db.rollback()
        raise HTTPException(status.HTTP_409_CONFLICT, (
            f"tokens: at most {settings.max_tokens_per_user} live (unexpired, unrevoked) tokens per user on this "
            f"server, and this user holds {live - 1}; revoke one (GET /v1/tokens lists them, DELETE "
            "/v1/tokens/{id} revokes one) or wait until one expires"))
    crud.prune_dead_tokens(db, user, keep=settings.max_tokens_per_user)
    db.commit()
    return TokenOut(user_id=user.id, token=token, expires_at=row.expires_at, id=row.id, label=row.label)


@router.get("/tokens", response_model=list[TokenInfoOut])
def list_tokens(request: Request, db: SessionDep, user: CurrentUser) -> list[TokenInfoOut]:
    """The calling user's tokens, oldest first: live, expired and revoked ones, each with its ``id`` (for
    ``DELETE /v1/tokens/{id}``), ``label``, ``created_at``, ``expires_at``, ``revoked``, ``live`` and whether it
    is the token of this request (``current``). Never a token itself (shown once, when minted) nor its hash.
    When a token was last used is not recorded.
    """
    now = datetime.now(timezone.utc)
    mine = hash_token(request.state.token)
    return [
        TokenInfoOut(id=t.id, label=t.label, created_at=t.created_at, expires_at=t.expires_at, revoked=t.revoked,
                     live=not t.revoked and (t.expires_at is None or t.expires_at > now), current=t.token_hash == mine)
        for t in crud.list_tokens(db, user)
    ]


@router.delete("/tokens/current", status_code=status.HTTP_204_NO_CONTENT)
def revoke_current(request: Request, db: SessionDep, user: CurrentUser) -> None:
    """Revoke the token used for this request (``DELETE /v1/tokens/{id}`` revokes any other of the caller's)."""
    # the token current_user authenticated, not the header parsed again (another scheme with ``?token=``, or
    # extra blanks after "Bearer", named a token that does not exist: HTTP 500)
    row = db.query(Token).filter(Token.token_hash == hash_token(request.state.token), Token.user_id == user.id).one()
    row.revoked = True
    db.commit()


# declared after /tokens/current: a route matches in declaration order, and "current" is no id
@router.delete("/tokens/{token_id}", status_code=status.HTTP_204_NO_CONTENT)
def revoke_token(token_id: PathId, db: SessionDep, user: CurrentUser) -> None:
    """Revoke one of the calling user's tokens by its ``id`` (``GET /v1/tokens``; the token of this request too).

    Revoking a revoked token again is a no-op (204). Another user's token id is 404, like an id that does not
    exist, so ids cannot be probed.
    """
    row = crud.get_token(db, user, token_id)
    if row is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"token {token_id} not found")
    row.revoked = True
    db.commit()
