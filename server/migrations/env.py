"""Alembic environment: uses the connection handed in by server.db.migrate (or PEDNAV_DATABASE_URL)."""

from __future__ import annotations

from alembic import context
from sqlalchemy import Connection

from server.models import Base

target_metadata = Base.metadata


def _run(connection: Connection) -> None:
    context.configure(connection=connection, target_metadata=target_metadata, render_as_batch=True)
    with context.begin_transaction():
        context.run_migrations()


def run_migrations_online() -> None:
    conn = context.config.attributes.get("connection")
    if conn is not None:
        _run(conn)
        return
    from server.db import make_engine
    from server.settings import Settings

    engine = make_engine(Settings())
    with engine.begin() as c:
        _run(c)


run_migrations_online()
