"""Database engine and sessions; migrations run programmatically (works from an installed package)."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from sqlalchemy import Connection, Engine, create_engine, event, text
from sqlalchemy.orm import Session, sessionmaker

from server.settings import Settings

__all__ = ["make_engine", "make_sessionmaker", "migrate", "session_scope"]

_HERE = Path(__file__).resolve().parent
_LOCK_CLASS = 0x7065646E  # "pedn": first key of pednav's PostgreSQL advisory locks (second: the schema's hash)


def make_engine(settings: Settings) -> Engine:
    """SQLAlchemy engine for ``settings.database_url`` (SQLite: WAL, synchronous=FULL, busy timeout; PostgreSQL:
    schema)."""
    url = settings.database_url
    if url.startswith("sqlite"):
        # unbounded overflow: SQLite connections are cheap and a bounded pool can starve the thread pool
        eng = create_engine(url, connect_args={"check_same_thread": False, "timeout": 30}, pool_size=20, max_overflow=-1)

        @event.listens_for(eng, "connect")
        def _sqlite_pragmas(dbapi_conn, _rec) -> None:  # type: ignore[no-untyped-def]
            cur = dbapi_conn.cursor()
            cur.execute("PRAGMA journal_mode=WAL")
            # FULL: in WAL mode every commit fsyncs the WAL, so an acknowledged batch survives a power loss
            # (NORMAL may lose the last commits); uploads group their commits (server.upload), so one fsync
            # covers many batches under load
            cur.execute("PRAGMA synchronous=FULL")
            cur.execute("PRAGMA foreign_keys=ON")
            cur.close()

        return eng
    eng = create_engine(url, pool_size=20, max_overflow=40, pool_timeout=15, pool_recycle=1800)
    if settings.db_schema:
        schema = settings.db_schema

        @event.listens_for(eng, "connect")
        def _pg_schema(dbapi_conn, _rec) -> None:  # type: ignore[no-untyped-def]
            cur = dbapi_conn.cursor()
            # concurrent CREATE SCHEMA IF NOT EXISTS of one name can still collide (unique violation in
            # pg_namespace): new connections of several workers take turns (lock released by the commit)
            cur.execute("SELECT pg_advisory_xact_lock(%s, hashtext(%s))", (_LOCK_CLASS, schema))
            cur.execute(f'CREATE SCHEMA IF NOT EXISTS "{schema}"')
            cur.execute(f'SET search_path TO "{schema}"')
            cur.close()
            dbapi_conn.commit()

    return eng


def make_sessionmaker(engine: Engine) -> sessionmaker[Session]:
    return sessionmaker(engine, expire_on_commit=False)


def migrate(engine: Engine, revision: str = "head") -> None:
    """Upgrade the database behind ``engine`` to ``revision`` with Alembic (each revision committed on its own)."""
    from alembic import command
    from alembic.config import Config

    cfg = Config(str(_HERE / "alembic.ini"))
    cfg.set_main_option("script_location", str(_HERE / "migrations"))
    # a connection NOT in a transaction: the environment (migrations/env.py) runs each revision in a transaction
    # of its own; inside one begun here every revision would share it, and SQLite's foreign keys could not be
    # switched off for revisions that rebuild a referenced table (the PRAGMA is a no-op inside a transaction)
    with engine.connect() as conn, _migration_lock(conn):
        cfg.attributes["connection"] = conn
        command.upgrade(cfg, revision)


@contextmanager
def _migration_lock(conn: Connection) -> Iterator[None]:
    """Make migrations of one database take turns: several API workers start at once and each migrates on
    startup; without it two of them create the version table (or apply a revision) together and one fails
    (PostgreSQL: unique violation; SQLite: table already exists). The later ones then find the database at head
    and do nothing. PostgreSQL: a session advisory lock per schema (kept across the revisions' own
    transactions); SQLite: an exclusive lock on a file beside the database (in-memory databases: none)."""
    if conn.dialect.name == "postgresql":
        conn.exec_driver_sql("SELECT pg_advisory_lock(%s, hashtext(current_schema()))", (_LOCK_CLASS,))
        conn.commit()
        try:
            yield
        finally:
            if conn.in_transaction():
                conn.rollback()
            conn.exec_driver_sql("SELECT pg_advisory_unlock(%s, hashtext(current_schema()))", (_LOCK_CLASS,))
            conn.commit()
        return
    path = conn.engine.url.database if conn.dialect.name == "sqlite" else None
    if not path or path == ":memory:" or path.startswith("file:"):
        yield
        return
    import fcntl

    with open(f"{path}.migrate-lock", "a") as f:
        fcntl.flock(f, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(f, fcntl.LOCK_UN)


def session_scope(factory: sessionmaker[Session]) -> Iterator[Session]:
    """Yield a session and close it (used by the FastAPI dependency)."""
    with factory() as s:
        yield s


def drop_schema(engine: Engine, schema: str) -> None:
    """Drop a PostgreSQL schema and everything in it (tests)."""
    with engine.begin() as conn:
        conn.execute(text(f'DROP SCHEMA IF EXISTS "{schema}" CASCADE'))
