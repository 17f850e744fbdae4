"""Thin data-access layer: every query is scoped by the owning user."""

from __future__ import annotations

from datetime import datetime, timedelta, timezone
from typing import Any

from sqlalchemy import delete, func, select, update
from sqlalchemy.orm import Session

from server.models import (
    BatchRecord,
    Device,
    EventRecord,
    PositionRecord,
    ProfileVersion,
    Token,
    TrackSession,
    User,
)
from server.security import hash_token, new_token

__all__ = [
    "create_user",
    "issue_token",
    "list_tokens",
    "get_token",
    "lock_user",
    "lock_user_for_write",
    "count_live_tokens",
    "prune_dead_tokens",
    "user_by_token",
    "create_device",
    "list_devices",
    "get_device",
    "create_session",
    "get_session",
    "list_sessions",
    "delete_session",
    "has_magnetometer",
    "get_batch",
    "positions_of",
    "events_of",
    "current_profiles",
    "profile_history",
    "add_profile_version",
]


def create_user(db: Session, name: str, is_admin: bool = False, ttl_s: float | None = None, *,
                expires_at: datetime | None = None) -> tuple[User, str]:
    """Create a user and its first token; returns ``(user, token)`` (the token is shown only once).

    ``ttl_s``: lifetime of the token [s]; None = never expires. ``expires_at``, when given, is the token's expiry
    instead.
    """
    user = User(name=name, is_admin=is_admin)
    db.add(user)
    db.flush()
    token, _ = issue_token_row(db, user, "initial", ttl_s, expires_at=expires_at)
    return user, token


def issue_token(db: Session, user: User, label: str = "", ttl_s: float | None = None) -> str:
    """Mint a token of ``user`` valid for ``ttl_s`` seconds (None = never expires); returns the secret."""
    token, _ = issue_token_row(db, user, label, ttl_s)
    return token


def issue_token_row(db: Session, user: User, label: str = "", ttl_s: float | None = None, *,
                    expires_at: datetime | None = None) -> tuple[str, Token]:
    """:func:`issue_token` returning ``(secret, row)``; ``expires_at``, when given, wins over ``ttl_s``."""
    token = new_token()
    expires = expires_at if expires_at is not None else (
        None if not ttl_s else datetime.now(timezone.utc) + timedelta(seconds=ttl_s))
    row = Token(user_id=user.id, token_hash=hash_token(token), label=label, expires_at=expires)
    db.add(row)
    db.flush()
    return token, row


def list_tokens(db: Session, user: User) -> list[Token]:
    """All tokens of ``user`` (live, expired and revoked), oldest first."""
    return list(db.execute(select(Token).where(Token.user_id == user.id).order_by(Token.id)).scalars())


def get_token(db: Session, user: User, token_id: int) -> Token | None:
    """``user``'s token ``token_id``; None when there is none or it belongs to someone else."""
    return db.execute(select(Token).where(Token.id == token_id, Token.user_id == user.id)).scalar_one_or_none()


def lock_user(db: Session, user: User) -> None:
    """Lock ``user``'s row until the transaction ends (PostgreSQL ``SELECT ... FOR UPDATE``), so that two
    requests of one user that count and then add rows (tokens) take turns. SQLite has no row locks: there the
    first write of a transaction takes the database's write lock, which serializes the same way."""
    db.execute(select(User.id).where(User.id == user.id).with_for_update())


def lock_user_for_write(db: Session, user: User) -> None:
    """Take ``user``'s write lock as the transaction's FIRST statement, held until it ends: a no-op update of the
    user's row locks that row on PostgreSQL and, as the first write of the transaction, takes SQLite's write lock
    before anything is read (a read first would pin a snapshot whose later write fails at once with "database is
    locked" when another writer committed meanwhile). Writers that read and then add a user's rows (profile
    versions) so take turns instead of computing the same next version (HTTP 500 on the unique constraint)."""
    users = User.__table__
    db.execute(update(users).where(users.c.id == user.id).values(id=users.c.id))


def _live(now: datetime) -> Any:
    return Token.revoked.is_(False) & (Token.expires_at.is_(None) | (Token.expires_at > now))


def count_live_tokens(db: Session, user: User) -> int:
    """Tokens of ``user`` that are neither revoked nor expired."""
    q = select(func.count()).select_from(Token).where(Token.user_id == user.id, _live(utcnow()))
    return int(db.execute(q).scalar_one())


def prune_dead_tokens(db: Session, user: User, keep: int) -> int:
    """Delete ``user``'s revoked and expired tokens but the newest ``keep`` of them; returns how many went.

    A deleted token is still refused (401 "invalid token" instead of "token revoked" / "expired").
    """
    dead = select(Token.id).where(Token.user_id == user.id, ~_live(utcnow()))
    ids = list(db.execute(dead.order_by(Token.id.desc()).offset(keep)).scalars())
    if ids:
        db.execute(delete(Token).where(Token.id.in_(ids)))
    return len(ids)


def user_by_token(db: Session, token: str) -> User | None:
    """The owner of a valid (not revoked, not expired) token."""
    row = db.execute(
        select(User).join(Token, Token.user_id == User.id).where(
            Token.token_hash == hash_token(token), Token.revoked.is_(False),
            (Token.expires_at.is_(None)) | (Token.expires_at > datetime.now(timezone.utc)),
        )
    ).scalar_one_or_none()
    return row


def user_by_name(db: Session, name: str) -> User | None:
    return db.execute(select(User).where(User.name == name)).scalar_one_or_none()


def create_device(db: Session, user: User, kind: str, name: str) -> Device:
    dev = Device(user_id=user.id, kind=kind, name=name)
    db.add(dev)
    db.flush()
    return dev


def list_devices(db: Session, user: User) -> list[Device]:
    return list(db.execute(select(Device).where(Device.user_id == user.id).order_by(Device.id)).scalars())


def get_device(db: Session, user: User, device_id: int) -> Device | None:
    return db.execute(select(Device).where(Device.id == device_id, Device.user_id == user.id)).scalar_one_or_none()


def create_session(db: Session, user: User, **fields: Any) -> TrackSession:
    sess = TrackSession(user_id=user.id, **fields)
    db.add(sess)
    db.flush()
    return sess


def get_session(db: Session, user: User, session_id: int, for_update: bool = False) -> TrackSession | None:
    q = select(TrackSession).where(TrackSession.id == session_id, TrackSession.user_id == user.id)
    if for_update:
        q = q.with_for_update()
    return db.execute(q).scalar_one_or_none()


def list_sessions(db: Session, user: User, status: str | None = None, limit: int = 100, offset: int = 0) -> list[TrackSession]:
    q = select(TrackSession).where(TrackSession.user_id == user.id)
    if status:
        q = q.where(TrackSession.status == status)
    return list(db.execute(q.order_by(TrackSession.id).limit(limit).offset(offset)).scalars())


def delete_session(db: Session, sess: TrackSession) -> None:
    """Delete a session with its batches, positions, events and Sensor Logger messages and link (the database's
    ON DELETE CASCADE); the user's calibration profiles stay."""
    db.execute(delete(TrackSession).where(TrackSession.id == sess.id, TrackSession.user_id == sess.user_id))


def has_magnetometer(db: Session, session_id: int) -> bool:
    """Whether any stored batch of the session carried magnetometer samples."""
    q = select(BatchRecord.id).where(BatchRecord.session_id == session_id, BatchRecord.n_mag > 0).limit(1)
    return db.execute(q).first() is not None


def get_batch(db: Session, session_id: int, seq: int) -> BatchRecord | None:
    return db.execute(select(BatchRecord).where(BatchRecord.session_id == session_id, BatchRecord.seq == seq)).scalar_one_or_none()


def batches_of(db: Session, session_id: int) -> list[BatchRecord]:
    return list(db.execute(select(BatchRecord).where(BatchRecord.session_id == session_id).order_by(BatchRecord.seq)).scalars())


def positions_of(db: Session, session_id: int) -> list[PositionRecord]:
    return list(db.execute(select(PositionRecord).where(PositionRecord.session_id == session_id).order_by(PositionRecord.id)).scalars())


def events_of(db: Session, session_id: int) -> list[EventRecord]:
    return list(db.execute(select(EventRecord).where(EventRecord.session_id == session_id).order_by(EventRecord.id)).scalars())


def _latest_versions(db: Session, user_id: int) -> list[ProfileVersion]:
    sub = (
        select(ProfileVersion.behaviour, func.max(ProfileVersion.version).label("v"))
        .where(ProfileVersion.user_id == user_id)
        .group_by(ProfileVersion.behaviour)
        .subquery()
    )
    q = select(ProfileVersion).join(sub, (ProfileVersion.behaviour == sub.c.behaviour) & (ProfileVersion.version == sub.c.v))
    return list(db.execute(q.where(ProfileVersion.user_id == user_id)).scalars())


def current_profiles(db: Session, user: User) -> dict[str, ProfileVersion]:
    """Latest version per behaviour (including resets, whose ``data`` is None)."""
    return {p.behaviour: p for p in _latest_versions(db, user.id)}


def profile_history(db: Session, user: User, behaviour: str) -> list[ProfileVersion]:
    q = select(ProfileVersion).where(ProfileVersion.user_id == user.id, ProfileVersion.behaviour == behaviour)
    return list(db.execute(q.order_by(ProfileVersion.version)).scalars())


def add_profile_version(db: Session, user: User, behaviour: str, data: dict[str, Any] | None, source: str,
                        keep: int | None = None) -> ProfileVersion:
    """Add the next version of ``user``'s profile of ``behaviour``; with ``keep``, delete all but the newest
    ``keep`` versions of it (versions are consecutive numbers, so these are the ones below ``version - keep + 1``).

    Takes the user's write lock first (:func:`lock_user_for_write`): concurrent writers of one user's profiles
    (PUT, reset, session closes) take turns. Call it before reading anything else in the transaction on SQLite
    (or take that lock first yourself).
    """
    lock_user_for_write(db, user)
    last = db.execute(
        select(func.max(ProfileVersion.version)).where(ProfileVersion.user_id == user.id, ProfileVersion.behaviour == behaviour)
    ).scalar_one()
    row = ProfileVersion(user_id=user.id, behaviour=behaviour, version=(last or 0) + 1, data=data, source=source)
    db.add(row)
    db.flush()
    if keep is not None:
        db.execute(delete(ProfileVersion).where(
            ProfileVersion.user_id == user.id, ProfileVersion.behaviour == behaviour,
            ProfileVersion.version <= row.version - keep))
    return row


def utcnow() -> datetime:
    return datetime.now(timezone.utc)
