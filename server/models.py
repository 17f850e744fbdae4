"""ORM tables (SQLAlchemy 2.0 typed mappings). Storage only: no navigation math."""

from __future__ import annotations

from datetime import date, datetime, timezone
from typing import Any

from sqlalchemy import (
    JSON,
    BigInteger,
    Boolean,
    Date,
    DateTime,
    Float,
    ForeignKey,
    Integer,
    LargeBinary,
    String,
    UniqueConstraint,
)
from sqlalchemy.orm import DeclarativeBase, Mapped, mapped_column
from sqlalchemy.types import TypeDecorator

__all__ = [
    "Base",
    "User",
    "Token",
    "Device",
    "TrackSession",
    "BatchRecord",
    "PositionRecord",
    "EventRecord",
    "ProfileVersion",
    "SensorLoggerMessage",
    "SensorLoggerLink",
]


def utcnow() -> datetime:
    return datetime.now(timezone.utc)


class UTCDateTime(TypeDecorator[datetime]):
    """Timezone-aware UTC datetimes on every backend (SQLite drops the zone on the way back)."""

    impl = DateTime(timezone=True)
    cache_ok = True

    def process_bind_param(self, value: datetime | None, dialect: Any) -> datetime | None:
        if value is not None and value.tzinfo is None:
            value = value.replace(tzinfo=timezone.utc)
        return value

    def process_result_value(self, value: datetime | None, dialect: Any) -> datetime | None:
        if value is not None and value.tzinfo is None:
            value = value.replace(tzinfo=timezone.utc)
        return value


class Base(DeclarativeBase):
    pass


class User(Base):
    __tablename__ = "users"
    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    name: Mapped[str] = mapped_column(String(100), unique=True)
    is_admin: Mapped[bool] = mapped_column(Boolean, default=False)
    created_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow)


class Token(Base):
    """A bearer token; only its SHA-256 is stored. ``expires_at`` None = never expires."""

    __tablename__ = "tokens"
    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    user_id: Mapped[int] = mapped_column(ForeignKey("users.id", ondelete="CASCADE"), index=True)
    token_hash: Mapped[str] = mapped_column(String(64), unique=True)
    label: Mapped[str] = mapped_column(String(100), default="")
    created_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow)
    revoked: Mapped[bool] = mapped_column(Boolean, default=False)
    expires_at: Mapped[datetime | None] = mapped_column(UTCDateTime, nullable=True)  # None = never


class Device(Base):
    __tablename__ = "devices"
    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    user_id: Mapped[int] = mapped_column(ForeignKey("users.id", ondelete="CASCADE"), index=True)
    kind: Mapped[str] = mapped_column(String(20))
    name: Mapped[str] = mapped_column(String(100), default="")
    created_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow)


class TrackSession(Base):
    """One recording session of one device; holds the engine state between batches.

    ``version`` is an optimistic-concurrency counter: an update that does not find the version it read
    fails, so two workers can never both apply the same batch. Ids are never reused (SQLite: AUTOINCREMENT,
    migration 0005; PostgreSQL's sequences never hand one out twice): engine caches are keyed by session id and
    version, and a deleted session's cached engine must never be continued for a new session.
    """

    __tablename__ = "sessions"
    __table_args__ = {"sqlite_autoincrement": True}
    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    user_id: Mapped[int] = mapped_column(ForeignKey("users.id", ondelete="CASCADE"), index=True)
    device_id: Mapped[int | None] = mapped_column(ForeignKey("devices.id", ondelete="SET NULL"), nullable=True)
    device_kind: Mapped[str] = mapped_column(String(20))
    # where the device is carried (models.placement.PLACEMENTS); NULL: recognised by the engine (migration 0008
    # set 'foot' on older sessions: they all ran the foot engine)
    placement: Mapped[str | None] = mapped_column(String(12), nullable=True)
    latitude_deg: Mapped[float | None] = mapped_column(Float, nullable=True)
    longitude_deg: Mapped[float | None] = mapped_column(Float, nullable=True)
    altitude_m: Mapped[float | None] = mapped_column(Float, nullable=True)
    # the anchor (latitude/longitude/altitude above): the World Magnetic Model's date (None: the creation date),
    # its horizontal accuracy [m] (None: given by hand) and source (models.geo.ANCHOR_SOURCES); revision 0006
    anchor_date: Mapped[date | None] = mapped_column(Date, nullable=True)
    anchor_accuracy_m: Mapped[float | None] = mapped_column(Float, nullable=True)
    anchor_source: Mapped[str | None] = mapped_column(String(20), nullable=True)
    status: Mapped[str] = mapped_column(String(10), default="open")
    engine_mode: Mapped[str] = mapped_column(String(10), default="auto")
    created_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow)
    closed_at: Mapped[datetime | None] = mapped_column(UTCDateTime, nullable=True)
    next_seq: Mapped[int] = mapped_column(Integer, default=0)
    engine_state: Mapped[bytes | None] = mapped_column(LargeBinary, nullable=True, deferred=True)  # loaded on a cache miss
    behaviour: Mapped[str] = mapped_column(String(10), default="stand")
    mode: Mapped[str] = mapped_column(String(10), default="idle")
    sensor_config: Mapped[dict[str, Any] | None] = mapped_column(JSON, nullable=True)
    profile_in: Mapped[dict[str, Any] | None] = mapped_column(JSON, nullable=True)
    n_positions: Mapped[int] = mapped_column(Integer, default=0)
    reprocessed_at: Mapped[datetime | None] = mapped_column(UTCDateTime, nullable=True)
    reprocess_count: Mapped[int] = mapped_column(Integer, default=0, server_default="0")
    version: Mapped[int] = mapped_column(Integer, nullable=False, default=0)
    # newest gyroscope / magnetometer sample time received [ns] (None: none yet): later uploads must start after
    # them (server.watermarks)
    gyr_newest_ns: Mapped[int | None] = mapped_column(BigInteger, nullable=True)
    mag_newest_ns: Mapped[int | None] = mapped_column(BigInteger, nullable=True)

    __mapper_args__ = {"version_id_col": version}


class BatchRecord(Base):
    """A raw accepted batch (canonical msgpack), kept so a session can be re-processed by a newer engine."""

    __tablename__ = "batches"
    __table_args__ = (UniqueConstraint("session_id", "seq", name="uq_batches_session_seq"),)
    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    session_id: Mapped[int] = mapped_column(ForeignKey("sessions.id", ondelete="CASCADE"), index=True)
    seq: Mapped[int] = mapped_column(Integer)
    body_sha256: Mapped[str] = mapped_column(String(64))
    raw: Mapped[bytes] = mapped_column(LargeBinary)
    n_acc: Mapped[int] = mapped_column(Integer, default=0)
    n_gyr: Mapped[int] = mapped_column(Integer, default=0)
    n_mag: Mapped[int] = mapped_column(Integer, default=0)
    response: Mapped[dict[str, Any]] = mapped_column(JSON)
    received_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow)


class PositionRecord(Base):
    __tablename__ = "positions"
    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    session_id: Mapped[int] = mapped_column(ForeignKey("sessions.id", ondelete="CASCADE"), index=True)
    seq: Mapped[int] = mapped_column(Integer)
    t_ns: Mapped[int] = mapped_column(BigInteger)
    north: Mapped[float] = mapped_column(Float)
    east: Mapped[float] = mapped_column(Float)
    down: Mapped[float] = mapped_column(Float)
    heading_rad: Mapped[float] = mapped_column(Float)
    behaviour: Mapped[str] = mapped_column(String(10))
    mode: Mapped[str] = mapped_column(String(10))
    step_length_m: Mapped[float] = mapped_column(Float)
    gyro_on: Mapped[bool] = mapped_column(Boolean)


class EventRecord(Base):
    __tablename__ = "events"
    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    session_id: Mapped[int] = mapped_column(ForeignKey("sessions.id", ondelete="CASCADE"), index=True)
    seq: Mapped[int] = mapped_column(Integer)
    t_ns: Mapped[int] = mapped_column(BigInteger)
    kind: Mapped[str] = mapped_column(String(50))
    detail: Mapped[dict[str, Any]] = mapped_column(JSON)


class ProfileVersion(Base):
    """One version of a user's calibration profile for one behaviour; ``data`` None = reset."""

    __tablename__ = "profiles"
    __table_args__ = (UniqueConstraint("user_id", "behaviour", "version", name="uq_profiles_version"),)
    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    user_id: Mapped[int] = mapped_column(ForeignKey("users.id", ondelete="CASCADE"), index=True)
    behaviour: Mapped[str] = mapped_column(String(10))
    version: Mapped[int] = mapped_column(Integer)
    data: Mapped[dict[str, Any] | None] = mapped_column(JSON, nullable=True)
    source: Mapped[str] = mapped_column(String(50), default="api")
    created_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow)


class SensorLoggerMessage(Base):
    """A Sensor Logger HTTP push message (dedup by messageId; samples held for time-ordering)."""

    __tablename__ = "sensorlogger_messages"
    __table_args__ = (UniqueConstraint("session_id", "message_id", name="uq_sl_message"),)
    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    session_id: Mapped[int] = mapped_column(ForeignKey("sessions.id", ondelete="CASCADE"), index=True)
    message_id: Mapped[int] = mapped_column(BigInteger)
    t_max_ns: Mapped[int] = mapped_column(BigInteger)
    payload: Mapped[list[Any]] = mapped_column(JSON)
    received_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow)


class SensorLoggerLink(Base):
    """Maps a Sensor Logger (user, app sessionId) to a pednav session and its time watermark."""

    __tablename__ = "sensorlogger_links"
    __table_args__ = (UniqueConstraint("user_id", "sl_session_id", name="uq_sl_link"),)
    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    user_id: Mapped[int] = mapped_column(ForeignKey("users.id", ondelete="CASCADE"), index=True)
    sl_session_id: Mapped[str] = mapped_column(String(100))
    device_id: Mapped[str] = mapped_column(String(100), default="")
    session_id: Mapped[int] = mapped_column(ForeignKey("sessions.id", ondelete="CASCADE"))
    watermark_ns: Mapped[int] = mapped_column(BigInteger, default=0)
    late_samples: Mapped[int] = mapped_column(Integer, default=0)
    last_push_at: Mapped[datetime | None] = mapped_column(UTCDateTime, nullable=True)  # idle close (revision 0006)
