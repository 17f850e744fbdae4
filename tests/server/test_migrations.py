"""Schema migrations: one ``migrate()`` call brings a database of any older revision, rows and all, to head
(each revision in its own transaction; on SQLite with foreign keys off while tables are rebuilt), and session
ids are never reused once a session row is deleted (engine caches are keyed by session id and version)."""

from __future__ import annotations

import uuid
from collections.abc import Iterator
from datetime import datetime, timezone
from typing import Any

import pytest
from alembic.autogenerate import compare_metadata
from alembic.migration import MigrationContext
from sqlalchemy import Engine, MetaData, delete, insert, inspect, select, text

from server.db import drop_schema, make_engine, migrate
from server.models import Base, TrackSession
from server.settings import Settings
from tests.server.conftest import PG_URL, auth

# every table whose rows must survive; children of ``sessions`` last
_TABLES = ("users", "devices", "tokens", "profiles", "sessions", "batches", "positions", "events",
           "sensorlogger_links", "sensorlogger_messages")
_SESSION_CHILDREN = ("batches", "positions", "events", "sensorlogger_links", "sensorlogger_messages")


@pytest.fixture
def empty_settings(backend: str, tmp_path) -> Iterator[Settings]:  # type: ignore[no-untyped-def]
    """Settings of a new, empty database (SQLite file; PostgreSQL: a schema of its own, dropped afterwards)."""
    if backend == "sqlite":
        yield Settings(database_url=f"sqlite:///{tmp_path / 'old.db'}")
        return
    schema = f"m_{uuid.uuid4().hex[:12]}"
    yield Settings(database_url=PG_URL, db_schema=schema)
    admin = make_engine(Settings(database_url=PG_URL))
    drop_schema(admin, schema)
    admin.dispose()


@pytest.fixture
def empty_db(empty_settings: Settings) -> Iterator[Engine]:
    """An engine on a new, empty database."""
    eng = make_engine(empty_settings)
    yield eng
    eng.dispose()


def _head() -> str:
    from alembic.config import Config
    from alembic.script import ScriptDirectory

    from server.db import _HERE

    cfg = Config(str(_HERE / "alembic.ini"))
    cfg.set_main_option("script_location", str(_HERE / "migrations"))
    return ScriptDirectory.from_config(cfg).get_current_head()


def _seed(eng: Engine) -> dict[str, int]:
    """Rows in every table (columns of revision 0001, which every later revision keeps); returns their ids."""
    now = datetime(2026, 1, 2, 3, 4, 5, tzinfo=timezone.utc)
    md = MetaData()
    md.reflect(eng)
    t = md.tables
    ids: dict[str, int] = {}

    def add(conn: Any, table: str, key: str, **row: Any) -> int:
        ids[key] = conn.execute(insert(t[table]).returning(t[table].c.id), row).scalar_one()
        return ids[key]

    with eng.begin() as conn:
        for u in ("alice", "bob"):
            uid = add(conn, "users", u, name=u, is_admin=u == "alice", created_at=now)
            add(conn, "devices", f"dev_{u}", user_id=uid, kind="foot", name=f"{u}'s shoe", created_at=now)
            add(conn, "tokens", f"tok_{u}", user_id=uid, token_hash=u * 8, label="cli", created_at=now, revoked=False)
            add(conn, "profiles", f"prof_{u}", user_id=uid, behaviour="walk", version=1, data={"n_steps": 40},
                source="api", created_at=now)
        for k, (user, dev, status) in enumerate((("alice", True, "closed"), ("alice", False, "open"), ("bob", True, "open"))):
            sid = add(conn, "sessions", f"s{k}", user_id=ids[user], device_id=ids[f"dev_{user}"] if dev else None,
                      device_kind="foot", latitude_deg=48.1 + k, longitude_deg=11.5, altitude_m=None, status=status,
                      engine_mode="auto", created_at=now, closed_at=now if status == "closed" else None, next_seq=2,
                      engine_state=bytes(range(k, 200)), behaviour="walk", mode="active",
                      sensor_config={"rate_hz": 100.0 + k}, profile_in=None, n_positions=2, version=3)
            for seq in range(2):
                add(conn, "batches", f"b{k}_{seq}", session_id=sid, seq=seq, body_sha256=f"{k}{seq}" * 32,
                    raw=bytes([k, seq]) * 50, n_acc=100, n_gyr=100, n_mag=100, response={"seq": seq}, received_at=now)
                add(conn, "positions", f"p{k}_{seq}", session_id=sid, seq=seq, t_ns=10**18 + seq, north=1.5 * seq,
                    east=-0.25, down=0.0, heading_rad=0.1, behaviour="walk", mode="active", step_length_m=0.7,
                    gyro_on=seq == 0)
                add(conn, "events", f"e{k}_{seq}", session_id=sid, seq=seq, t_ns=10**18 + seq, kind="step",
                    detail={"n": seq})
            add(conn, "sensorlogger_links", f"l{k}", user_id=ids[user], sl_session_id=f"sl{k}", device_id="phone",
                session_id=sid, watermark_ns=10**18, late_samples=k)
            add(conn, "sensorlogger_messages", f"m{k}", session_id=sid, message_id=k, t_max_ns=10**18,
                payload=[{"name": "accelerometer"}], received_at=now)
    return ids


def _snapshot(eng: Engine, columns: dict[str, list[str]] | None = None) -> dict[str, list[tuple[Any, ...]]]:
    """Every row of :data:`_TABLES` (only ``columns`` of each when given), ordered by id."""
    md = MetaData()
    md.reflect(eng)
    out = {}
    with eng.connect() as conn:
        for name in _TABLES:
            tbl = md.tables[name]
            cols = [tbl.c[c] for c in (columns[name] if columns else tbl.c.keys())]
            out[name] = [tuple(r) for r in conn.execute(select(*cols).order_by(tbl.c.id))]
    return out


def _fks(eng: Engine) -> dict[str, list[tuple[Any, ...]]]:
    """The foreign keys of every table: (columns, referred table, referred columns, ON DELETE)."""
    insp = inspect(eng)
    return {
        name: sorted((tuple(fk["constrained_columns"]), fk["referred_table"], tuple(fk["referred_columns"]),
                      (fk.get("options") or {}).get("ondelete")) for fk in insp.get_foreign_keys(name))
        for name in _TABLES
    }


# columns added after revision 0005 (left out where a structure is compared with revision 0004's)
_LATER_COLUMNS = {"anchor_date", "anchor_accuracy_m", "anchor_source", "last_push_at", "gyr_newest_ns", "mag_newest_ns",
                  "placement"}


def _structure(eng: Engine, skip: frozenset[str] | set[str] = frozenset()) -> dict[str, Any]:
    """Columns (but ``skip``), keys, indexes and unique constraints of every table, as reflected."""
    insp = inspect(eng)
    return {name: (
        [(c["name"], str(c["type"]), c["nullable"], c["default"]) for c in insp.get_columns(name) if c["name"] not in skip],
        insp.get_pk_constraint(name)["constrained_columns"],
        sorted((ix["name"], tuple(ix["column_names"]), bool(ix["unique"])) for ix in insp.get_indexes(name)),
        sorted(tuple(u["column_names"]) for u in insp.get_unique_constraints(name)),
    ) for name in _TABLES} | {"fks": _fks(eng)}


def _count(eng: Engine, table: str, session_id: int) -> int:
    with eng.connect() as conn:
        return conn.execute(text(f"SELECT count(*) FROM {table} WHERE session_id = :s"), {"s": session_id}).scalar_one()


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


@pytest.mark.parametrize("start", ["0001", "0003"])
def test_one_migrate_call_upgrades_an_old_database_with_rows_to_head(backend, empty_db, start, tmp_path) -> None:  # type: ignore[no-untyped-def]
    """A database of revision ``start`` holding rows in every table goes to head in ONE ``migrate()`` call: all
    rows and foreign keys intact (cascades still act), foreign keys enforced again afterwards, and a deleted
    session's id is not given to the next session."""
    eng = empty_db
    migrate(eng, start)
    ids = _seed(eng)
    before = _snapshot(eng)
    md = MetaData()
    md.reflect(eng)
    old_columns = {name: list(md.tables[name].c.keys()) for name in _TABLES}

    migrate(eng)  # start -> head in one call

    with eng.connect() as conn:
        assert conn.execute(text("SELECT version_num FROM alembic_version")).scalar_one() == _head()
    assert _snapshot(eng, old_columns) == before
    with eng.connect() as conn:  # the schema is the models' (Alembic finds nothing to autogenerate)
        assert compare_metadata(MigrationContext.configure(conn), Base.metadata) == []
    if backend == "sqlite":  # the rebuild of sessions changed nothing that reflection shows (only AUTOINCREMENT)
        at_0004 = make_engine(Settings(database_url=f"sqlite:///{tmp_path / 'at_0004.db'}"))
        migrate(at_0004, "0004")
        assert _structure(eng, _LATER_COLUMNS) == _structure(at_0004)
        at_0004.dispose()
    fks = _fks(eng)
    for child in _SESSION_CHILDREN:
        assert (("session_id",), "sessions", ("id",), "CASCADE") in fks[child], fks[child]
    assert (("device_id",), "devices", ("id",), "SET NULL") in fks["sessions"]
    assert (("user_id",), "users", ("id",), "CASCADE") in fks["sessions"]
    assert "ix_sessions_user_id" in {ix["name"] for ix in inspect(eng).get_indexes("sessions")}

    if backend == "sqlite":
        assert eng.pool.checkedin() == 1  # the migration's connection, back in the pool ...
        with eng.connect() as conn:  # ... is the next one handed out: foreign keys enforced on it again
            assert conn.execute(text("PRAGMA foreign_keys")).scalar_one() == 1
            assert conn.execute(text("PRAGMA foreign_key_check")).fetchall() == []
            ddl = conn.execute(text("SELECT sql FROM sqlite_master WHERE type = 'table' AND name = 'sessions'")).scalar_one()
        assert "AUTOINCREMENT" in ddl

    # cascades act on the migrated tables
    newest = ids["s2"]
    with eng.begin() as conn:
        conn.execute(text("DELETE FROM devices WHERE id = :d"), {"d": ids["dev_alice"]})
        assert conn.execute(text("SELECT device_id FROM sessions WHERE id = :s"), {"s": ids["s0"]}).scalar_one() is None
        conn.execute(text("DELETE FROM sessions WHERE id = :s"), {"s": newest})
    for child in _SESSION_CHILDREN:
        assert _count(eng, child, newest) == 0
        assert _count(eng, child, ids["s1"]) == (2 if child in ("batches", "positions", "events") else 1)

    # a new session after the newest was deleted gets a new id
    with eng.begin() as conn:
        sid = conn.execute(insert(TrackSession.__table__).returning(TrackSession.__table__.c.id), {
            "user_id": ids["bob"], "device_kind": "foot", "status": "open", "engine_mode": "auto",
            "created_at": datetime.now(timezone.utc), "next_seq": 0, "behaviour": "stand", "mode": "idle",
            "n_positions": 0, "reprocess_count": 0, "version": 1}).scalar_one()
    assert sid > newest


def test_deleting_the_newest_session_never_hands_its_id_to_the_next(client, app, make_user) -> None:  # type: ignore[no-untyped-def]
    """Engine caches (in the worker and in the helper process) are keyed by session id and version: a reused id
    could continue the deleted session's engine for the new session."""
    _, tok = make_user()
    first = client.post("/v1/sessions", json={"device_kind": "foot"}, headers=auth(tok)).json()["id"]
    newest = client.post("/v1/sessions", json={"device_kind": "foot"}, headers=auth(tok)).json()["id"]
    assert newest > first
    with app.state.sessionmaker() as db:  # there is no DELETE route; by hand
        db.execute(delete(TrackSession).where(TrackSession.id == newest))
        db.commit()
    again = client.post("/v1/sessions", json={"device_kind": "foot"}, headers=auth(tok)).json()["id"]
    assert again != newest and again > first


def _migrate_in_process(settings: Settings) -> None:
    eng = make_engine(settings)
    try:
        migrate(eng)
    finally:
        eng.dispose()


def test_workers_starting_together_migrate_one_after_the_other(empty_settings, empty_db) -> None:  # type: ignore[no-untyped-def]
    """Every API worker process migrates on startup; several starting at once on an empty database must all
    succeed (without the migration lock two of them created the version table together: PostgreSQL unique
    violation, SQLite "table alembic_version already exists"; found by ``pednav bench load --workers 2``)."""
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor

    n = 4
    with ProcessPoolExecutor(n, mp_context=mp.get_context("spawn")) as pool:
        list(pool.map(int, range(n)))  # every process started (imports done) before the migrations race
        results = [pool.submit(_migrate_in_process, empty_settings) for _ in range(n)]
        errors = [r.exception(timeout=120) for r in results]
    assert errors == [None] * n, errors
    with empty_db.connect() as conn:
        assert MigrationContext.configure(conn).get_current_revision() == _head()
