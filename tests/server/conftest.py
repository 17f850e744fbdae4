"""Fixtures of the service tests: settings and app per database backend, client, user tokens.

Engines run in the test process (``engine_processes=0``, no warm-up at start: test_coldstart.py checks it) to keep
the run fast; the helper-process path that
the server uses by default is checked against it in test_durability.py.

The PostgreSQL leg uses a unique schema per test run (dropped afterwards) on
``PEDNAV_TEST_PG_URL`` (default ``postgresql+psycopg://postgres@127.0.0.1:5432/test``) and is skipped with
the reason when that server cannot be reached.
"""

from __future__ import annotations

import os
import uuid
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient

from models.batch import SensorBatch
from server import crud
from server.app import create_app
from server.db import drop_schema, make_engine
from server.settings import Settings

PG_URL = os.environ.get("PEDNAV_TEST_PG_URL", "postgresql+psycopg://postgres@127.0.0.1:5432/test")


def _pg_reachable() -> str | None:
    try:
        import psycopg

        with psycopg.connect(PG_URL.replace("+psycopg", ""), connect_timeout=3):
            return None
    except Exception as exc:  # noqa: BLE001 - any failure means: skip with the reason
        return f"PostgreSQL at {PG_URL} unreachable: {type(exc).__name__}: {exc}"


@pytest.fixture(params=["sqlite", "postgresql"], scope="module")
def backend(request: pytest.FixtureRequest) -> str:
    if request.param == "postgresql":
        reason = _pg_reachable()
        if reason:
            pytest.skip(reason)
    return request.param


@pytest.fixture(scope="module")
def settings(backend: str, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Settings]:
    if backend == "sqlite":
        path: Path = tmp_path_factory.mktemp("db") / "pednav.db"
        yield Settings(database_url=f"sqlite:///{path}", max_body_bytes=2_000_000, max_samples_per_stream=20_000,
                       engine_processes=0, engine_warmup=False)
        return
    schema = f"t_{uuid.uuid4().hex[:12]}"
    s = Settings(database_url=PG_URL, db_schema=schema, max_body_bytes=2_000_000, max_samples_per_stream=20_000,
                 engine_processes=0, engine_warmup=False)
    yield s
    eng = make_engine(Settings(database_url=PG_URL))
    drop_schema(eng, schema)
    eng.dispose()


@pytest.fixture(scope="module")
def app(settings: Settings):  # type: ignore[no-untyped-def]
    a = create_app(settings)
    yield a
    a.state.db_engine.dispose()


@pytest.fixture(scope="module")
def client(app) -> Iterator[TestClient]:  # type: ignore[no-untyped-def]
    with TestClient(app) as c:
        yield c


@pytest.fixture(scope="module")
def make_user(app) -> Callable[[str], tuple[int, str]]:  # type: ignore[no-untyped-def]
    """Create a user directly in the database (the CLI bootstrap path); returns ``(user_id, token)``."""

    def _make(name: str | None = None, admin: bool = False) -> tuple[int, str]:
        with app.state.sessionmaker() as db:
            user, token = crud.create_user(db, name or f"u{uuid.uuid4().hex[:10]}", is_admin=admin)
            db.commit()
            return user.id, token

    return _make


@contextmanager
def app_with(settings: Settings, **overrides: Any) -> Iterator[tuple[Any, TestClient]]:
    """A second app on the test database with these settings changed (no migration: the schema is there), and a
    client of it; the app's database engine is disposed afterwards."""
    a = create_app(settings.model_copy(update={"migrate_on_startup": False, **overrides}))
    try:
        with TestClient(a) as c:
            yield a, c
    finally:
        a.state.db_engine.dispose()


def auth(token: str) -> dict[str, str]:
    return {"Authorization": f"Bearer {token}"}


def still_batch(t0_ns: int, seconds: float = 1.0, rate_hz: float = 100.0, seed: int = 0) -> SensorBatch:
    """A device lying still: specific force ~9.81 m/s^2 up, small gyro noise [rad/s], Earth field [uT]."""
    rng = np.random.default_rng(seed)
    n = int(round(seconds * rate_hz))
    t = t0_ns + np.arange(n, dtype=np.int64) * int(round(1e9 / rate_hz))
    acc = np.array([0.0, 0.0, -9.81]) + rng.normal(0, 0.02, (n, 3))
    gyr = rng.normal(0, 0.002, (n, 3))
    mag = np.array([20.0, 0.0, 40.0]) + rng.normal(0, 0.2, (n, 3))
    return SensorBatch(acc_t_ns=t, acc=acc, gyr_t_ns=t.copy(), gyr=gyr, mag_t_ns=t.copy(), mag=mag)


def short_lock_waits(app: Any) -> None:
    """The app's database connections give up waiting for a lock after 50 ms (SQLite's busy timeout is 30 s,
    PostgreSQL waits for a row lock for ever): a held lock fails a write at once, as one held past the timeout
    does. Call before the app's first request (connections opened later only)."""
    from sqlalchemy import event

    eng = app.state.db_engine
    eng.dispose()

    @event.listens_for(eng, "do_connect")
    def _short(_dialect: Any, _rec: Any, _cargs: Any, cparams: dict[str, Any]) -> None:
        if eng.dialect.name == "sqlite":
            cparams["timeout"] = 0.05
        else:
            cparams["options"] = "-c lock_timeout=50"


class DatabaseLock:
    """Another worker's transaction holding what a batch's write needs: SQLite's write lock (``BEGIN IMMEDIATE``),
    on PostgreSQL the session's row (``SELECT ... FOR UPDATE``); held from creation until :meth:`release`."""

    def __init__(self, settings: Settings, session_id: int) -> None:
        url = settings.database_url
        if url.startswith("sqlite"):
            import sqlite3

            self.conn: Any = sqlite3.connect(url.removeprefix("sqlite:///"), isolation_level=None, check_same_thread=False)
            self.conn.execute("BEGIN IMMEDIATE")
        else:
            import psycopg

            self.conn = psycopg.connect(url.replace("+psycopg", ""))
            self.conn.execute(f'SELECT 1 FROM "{settings.db_schema}".sessions WHERE id = %s FOR UPDATE', (session_id,))

    def release(self) -> None:
        if self.conn is not None:
            self.conn.rollback()
            self.conn.close()
            self.conn = None


@contextmanager
def database_locked(settings: Settings, session_id: int) -> Iterator[DatabaseLock]:
    lock = DatabaseLock(settings, session_id)
    try:
        yield lock
    finally:
        lock.release()
