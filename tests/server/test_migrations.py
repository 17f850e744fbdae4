"""Schema migrations: each revision runs in a transaction of its own (on SQLite with foreign keys off while the
revisions run, and checked after each)."""

from __future__ import annotations

import uuid
from collections.abc import Iterator
from typing import Any

import pytest
from sqlalchemy import Engine, inspect, text

from server.db import drop_schema, make_engine, migrate
from server.settings import Settings
from tests.server.conftest import PG_URL


@pytest.fixture
def empty_db(backend: str, tmp_path) -> Iterator[Engine]:  # type: ignore[no-untyped-def]
    """An engine on a new, empty database (SQLite file; PostgreSQL: a schema of its own, dropped afterwards)."""
    if backend == "sqlite":
        eng = make_engine(Settings(database_url=f"sqlite:///{tmp_path / 'old.db'}"))
        yield eng
        eng.dispose()
        return
    schema = f"m_{uuid.uuid4().hex[:12]}"
    eng = make_engine(Settings(database_url=PG_URL, db_schema=schema))
    yield eng
    eng.dispose()
    admin = make_engine(Settings(database_url=PG_URL))
    drop_schema(admin, schema)
    admin.dispose()


def test_each_revision_commits_on_its_own(backend, empty_db, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """A revision that fails leaves the revisions before it committed and the version table saying so, and
    nothing of its own: the next run goes on from there. (With all revisions in one outer transaction a failure
    rolled back the version table, while on SQLite the ALTERs run before its first write had already been
    committed: the next run re-applied 0003 and failed on its existing column.)"""
    from alembic import op

    eng = empty_db
    migrate(eng, "0002")
    real = op.batch_alter_table

    def failing(table: str, *a: Any, **kw: Any) -> Any:
        if table == "tokens":  # revision 0004
            raise RuntimeError("revision 0004 fails")
        return real(table, *a, **kw)

    monkeypatch.setattr(op, "batch_alter_table", failing)
    with pytest.raises(RuntimeError, match="0004 fails"):
        migrate(eng)
    with eng.connect() as conn:
        assert conn.execute(text("SELECT version_num FROM alembic_version")).scalar_one() == "0003"
        if backend == "sqlite":  # enforcement is back on the connection the failed run used
            assert conn.execute(text("PRAGMA foreign_keys")).scalar_one() == 1
    insp = inspect(eng)
    assert "reprocess_count" in {c["name"] for c in insp.get_columns("sessions")}
    assert "expires_at" not in {c["name"] for c in insp.get_columns("tokens")}
    monkeypatch.undo()
    migrate(eng)
    with eng.connect() as conn:
        assert conn.execute(text("SELECT version_num FROM alembic_version")).scalar_one() == _head()


def _head() -> str:
    from alembic.config import Config
    from alembic.script import ScriptDirectory

    from server.db import _HERE

    cfg = Config(str(_HERE / "alembic.ini"))
    cfg.set_main_option("script_location", str(_HERE / "migrations"))
    return ScriptDirectory.from_config(cfg).get_current_head()
