"""sessions: AUTOINCREMENT on SQLite, so a deleted session's id is never given to a later session

Engine caches (server.ingest.EngineHost, server.engine_pool and the helper processes) are keyed by session id
and version; without AUTOINCREMENT SQLite hands the largest rowid out again once that row is deleted, so a
worker could continue the deleted session's cached engine for the new session. SQLite adds AUTOINCREMENT only
by rebuilding the table: batch mode copies every row into a new table (sqlite_sequence then starts at the
largest id), drops the old table and renames the new one; the tables that refer to sessions refer to it by
name and so refer to the new one. Foreign keys must be off for this (migrations/env.py switches them off for
every run and checks them after each revision): with them on, the DROP deletes every batch, position, event
and Sensor Logger row through ON DELETE CASCADE.

PostgreSQL: nothing to do (serial/identity sequences never hand out an id twice).

Revision ID: 0005
Revises: 0004
"""

from __future__ import annotations

from alembic import op

revision = "0005"
down_revision = "0004"
branch_labels = None
depends_on = None


def _rebuild_sessions(autoincrement: bool) -> None:
    bind = op.get_bind()
    if bind.dialect.name != "sqlite":
        return
    if bind.exec_driver_sql("PRAGMA foreign_keys").scalar():
        raise RuntimeError("revision 0005 rebuilds the sessions table and must run with foreign keys off "
                           "(server.db.migrate does): dropping the old table would delete every row referring to it")
    op.execute("DROP TABLE IF EXISTS _alembic_tmp_sessions")  # left by an interrupted earlier run, if any
    with op.batch_alter_table("sessions", recreate="always", table_kwargs={"sqlite_autoincrement": autoincrement}):
        pass


def upgrade() -> None:
    _rebuild_sessions(True)


def downgrade() -> None:
    _rebuild_sessions(False)
