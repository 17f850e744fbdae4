"""SQLite group commit without a writer thread (:class:`server.upload.SqliteGroupWriter`): a lone upload commits
in its own thread; uploads arriving during a commit are committed together by one of them; each gets its own
result (stored, refused by its version check, or the error that failed its transaction), and what it reports is
what is stored."""

from __future__ import annotations

import threading
import time
from typing import Any

import pytest
import sqlalchemy as sa

from server import upload
from server.upload import SqliteGroupWriter


@pytest.fixture()
def writer(tmp_path, monkeypatch):  # type: ignore[no-untyped-def]
    eng = sa.create_engine(f"sqlite:///{tmp_path}/g.db", connect_args={"check_same_thread": False})
    with eng.begin() as c:
        c.exec_driver_sql("CREATE TABLE t (k INTEGER PRIMARY KEY)")
    committed_by: dict[int, int] = {}

    def fake_write(cur: Any, job: Any) -> bool:
        k, ok, delay = job
        if k < 0:
            raise RuntimeError("broken write")
        time.sleep(delay)  # a slow write: uploads arriving meanwhile queue for the next group
        committed_by[k] = threading.get_ident()
        if ok:
            cur.execute("INSERT INTO t (k) VALUES (?)", (k,))
        return ok

    monkeypatch.setattr(upload, "_sqlite_write", fake_write)
    w = SqliteGroupWriter(eng, threading.Lock())
    yield w, eng, committed_by
    w.stop()
    eng.dispose()


def _stored(eng: Any) -> set[int]:
    with eng.connect() as c:
        return {r[0] for r in c.exec_driver_sql("SELECT k FROM t")}


def test_a_lone_write_commits_in_its_own_thread(writer) -> None:  # type: ignore[no-untyped-def]
    w, eng, by = writer
    assert w.write((1, True, 0.0)) is True
    assert w.write((2, False, 0.0)) is False  # its version check failed: nothing of it stored
    assert by[1] == threading.get_ident() and _stored(eng) == {1}


def test_concurrent_writes_are_grouped_and_each_gets_its_own_result(writer) -> None:  # type: ignore[no-untyped-def]
    w, eng, by = writer
    results: dict[int, Any] = {}
    threads: dict[int, int] = {}

    def put(k: int) -> None:
        threads[k] = threading.get_ident()
        results[k] = w.write((k, k % 3 != 0, 0.02))

    ts = [threading.Thread(target=put, args=(k,)) for k in range(1, 25)]
    for t in ts:
        t.start()
        time.sleep(0.002)
    for t in ts:
        t.join(timeout=30)
    assert results == {k: k % 3 != 0 for k in range(1, 25)}
    assert _stored(eng) == {k for k in range(1, 25) if k % 3 != 0}
    # some uploads were committed by another upload's thread (grouped), none left waiting
    assert any(by[k] != threads[k] for k in results)


def test_an_error_fails_its_group_only_and_the_next_write_succeeds(writer) -> None:  # type: ignore[no-untyped-def]
    w, eng, _ = writer
    with pytest.raises(RuntimeError, match="broken write"):
        w.write((-1, True, 0.0))
    assert w.write((7, True, 0.0)) is True
    assert _stored(eng) == {7}
