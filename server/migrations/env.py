"""Alembic environment: uses the connection handed in by server.db.migrate (or PEDNAV_DATABASE_URL).

Each revision runs in a transaction of its own, which this environment begins and commits: the connection
handed in must not be in a transaction (one begun outside would make every revision part of it, and nothing
could run between two revisions). On SQLite, foreign keys are not enforced while the revisions run: a revision
that rebuilds a table (batch mode's "move and copy") drops the old table, and with enforcement on that DROP
deletes, through ON DELETE CASCADE, every row that refers to the table. SQLite ignores ``PRAGMA foreign_keys``
inside a transaction, so it is switched between transactions, before the first revision and after the last;
instead each revision must leave ``PRAGMA foreign_key_check`` empty before it commits.
"""

from __future__ import annotations

from typing import Any

from alembic import context
from sqlalchemy import Connection

from server.models import Base

target_metadata = Base.metadata


def _sqlite_foreign_keys(connection: Connection, on: bool) -> None:
    """Switch SQLite's foreign-key enforcement on ``connection`` (outside any transaction) and check it took."""
    if connection.in_transaction():
        raise RuntimeError("PRAGMA foreign_keys has no effect inside a transaction")
    level = connection.get_isolation_level()
    connection.execution_options(isolation_level="AUTOCOMMIT")
    try:
        with connection.begin():
            connection.exec_driver_sql(f"PRAGMA foreign_keys={'ON' if on else 'OFF'}")
            now = connection.exec_driver_sql("PRAGMA foreign_keys").scalar()
    finally:
        connection.execution_options(isolation_level=level)
    if now != int(on):
        raise RuntimeError(f"SQLite kept PRAGMA foreign_keys={now}")


def _foreign_key_check(ctx: Any, step: Any, heads: Any, run_args: Any) -> None:
    """After a revision, inside its transaction (SQLite): every foreign key must still hold."""
    bad = ctx.connection.exec_driver_sql("PRAGMA foreign_key_check").fetchall()
    if bad:
        raise RuntimeError(f"revision {step.up_revision_id} left rows violating foreign keys "
                           f"(table, rowid, parent, fk index): {bad[:10]}")


def _run(connection: Connection) -> None:
    sqlite = connection.dialect.name == "sqlite"
    if sqlite:
        _sqlite_foreign_keys(connection, False)
    try:
        context.configure(connection=connection, target_metadata=target_metadata, render_as_batch=True,
                          transaction_per_migration=True, on_version_apply=(_foreign_key_check,) if sqlite else ())
        with context.begin_transaction():
            context.run_migrations()
        if connection.in_transaction():  # what Alembic did outside a revision (e.g. read the version table)
            connection.commit()
    finally:
        if sqlite:
            if connection.in_transaction():  # a revision failed (Alembic rolled it back) or the commit did
                connection.rollback()
            try:
                _sqlite_foreign_keys(connection, True)
            except Exception:
                connection.invalidate()  # never hand out a connection without enforcement
                raise


def run_migrations_online() -> None:
    conn = context.config.attributes.get("connection")
    if conn is not None:
        _run(conn)
        return
    from server.db import make_engine
    from server.settings import Settings

    engine = make_engine(Settings())
    with engine.connect() as c:  # not begun: see the module docstring
        _run(c)


run_migrations_online()
