"""SQLite group commit led by the uploads' own threads (server.upload.SqliteGroupWriter): uploads that arrive
while a commit is under way are committed together by the first of them, each stored exactly once, with the
answers the same uploads get one at a time."""

from __future__ import annotations

import threading
import time
from typing import Any

import pytest

from server import upload
from server.formats import MSGPACK_TYPE, encode_msgpack
from tests.server.conftest import auth, still_batch

T0 = 1_700_000_000_000_000_000


def _put(c: Any, tok: str, sid: int, seq: int, seed: int) -> Any:
    b = still_batch(T0 + seq * 10**9, seed=seed * 1000 + seq)
    return c.put(f"/v1/sessions/{sid}/batches/{seq}", content=encode_msgpack(b),
                 headers={**auth(tok), "content-type": MSGPACK_TYPE})


def test_concurrent_uploads_commit_in_groups_each_once(backend, client, make_user,  # type: ignore[no-untyped-def]
                                                        monkeypatch: pytest.MonkeyPatch) -> None:
    if backend != "sqlite":
        pytest.skip("PostgreSQL uploads write in one statement each (no group writer)")
    _, tok = make_user()
    n_sess, n_seq = 6, 3
    new = lambda: client.post("/v1/sessions", json={"device_kind": "foot"}, headers=auth(tok)).json()["id"]  # noqa: E731
    ref = [new() for _ in range(n_sess)]
    want = {(i, k): _put(client, tok, ref[i], k, seed=i).json() for k in range(n_seq) for i in range(n_sess)}

    groups: list[int] = []
    commit = upload.SqliteGroupWriter._commit

    def slow_commit(self: Any, boxes: list[list[Any]]) -> None:
        groups.append(len(boxes))
        time.sleep(0.02)  # a slow disk: the other uploads queue meanwhile
        commit(self, boxes)

    monkeypatch.setattr(upload.SqliteGroupWriter, "_commit", slow_commit)
    sids = [new() for _ in range(n_sess)]
    got: dict[tuple[int, int], Any] = {}

    def device(i: int) -> None:
        for k in range(n_seq):
            r = _put(client, tok, sids[i], k, seed=i)
            got[(i, k)] = (r.status_code, r.headers.get("x-pednav-replayed", ""), r.json())

    threads = [threading.Thread(target=device, args=(i,)) for i in range(n_sess)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert all(code == 200 and rep == "false" for code, rep, _ in got.values()), got
    assert sum(groups) == n_sess * n_seq  # every write committed once
    assert max(groups) > 1  # uploads that queued during a commit were committed together
    for (i, k), (_, _, body) in got.items():
        assert body["session_id"] == sids[i]
        assert {**body, "session_id": 0} == {**want[(i, k)], "session_id": 0}
    for sid in sids:
        batches = client.get(f"/v1/sessions/{sid}/batches", headers=auth(tok)).json()
        assert [b["seq"] for b in batches] == list(range(n_seq))
