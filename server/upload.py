"""The batch-upload hot path on plain driver connections (sqlite3 / psycopg), without ORM or Core compilation.

One upload costs, in the server worker: one read (token and session in ONE statement; skipped when this worker
committed the session's previous batch with the same token: the write then checks the token, see
:class:`Uploader`), the engine (in a helper process, which also encodes the answer, the canonical raw batch, its
digest and the state checkpoint when one is due), and one durable write:

- SQLite: the writes of all uploads waiting at that moment are committed in ONE transaction, in the thread of
  the upload that found no commit under way (group commit; each upload in its own savepoint, so a failed version
  check drops only that upload). The database runs ``synchronous=FULL`` in WAL mode: a commit is on disk (fsync
  of the WAL) before any of its uploads is answered, and under load one fsync covers many uploads.
- PostgreSQL: one atomic statement in autocommit mode (versioned session update, raw batch, positions and
  events in a data-modifying CTE whose inserts take the session id from the update's RETURNING, so a failed
  version check writes nothing): two round trips per upload, one when the read is skipped.

Semantics are those of :func:`server.ingest.apply_batch` (same refusals, same stored rows, same answers): a
retried sequence number is answered from the stored batch and never applied twice; a concurrent writer that
applied it first makes this upload answer as a retry.
"""

from __future__ import annotations

import json
import queue
import threading
import time
from collections import OrderedDict
from datetime import datetime, timezone
from typing import Any, NamedTuple

from fastapi import HTTPException, status

from models.batch import BatchError, SensorBatch
from server.auth import RateLimiter, admit, require_token, token_expiry
from server.formats import canonical_bytes, decode_upload, digest
from server.ingest import (EngineHost, Fed, IngestConflict, StorageBusy, batch_busy_message, checkpoint_due,
                           engine_profile_from_stored, feed_engine, is_contention, pool_feed)
from server.security import hash_token
from server.statecodec import pack_checkpoint, pack_state
from server.timing import phase, since
from server.plausibility import STILL_GYRO
from server.watermarks import advanced, check_after

__all__ = ["SqliteGroupWriter", "Uploader"]

_DT_FORMAT = "%Y-%m-%d %H:%M:%S.%f"  # SQLAlchemy's SQLite text form of a datetime (read back by the ORM)


class _Raced(Exception):
    """Another writer changed the session between the read and the write; start over."""


class _Unverified(Exception):
    """An upload without a read found its token or the session changed (the write's checks failed, nothing
    written): it is decided afresh after the read."""


class _Session(NamedTuple):
    version: int
    next_seq: int
    status: str
    gyr_newest_ns: int | None
    mag_newest_ns: int | None

    def newest(self) -> dict[str, int | None]:
        return {"gyr": self.gyr_newest_ns, "mag": self.mag_newest_ns}


class _Known(NamedTuple):
    """A session as this worker's last commit left it, with the token that uploaded it (see :class:`Uploader`)."""

    token_hash: str
    user_id: int
    expires_at: datetime | None  # the token's expiry (aware) or None
    sess: _Session


def _utc_text() -> str:
    from server.models import utcnow

    return utcnow().strftime(_DT_FORMAT)


def _write_params(session_id: int, version: int, seq: int, fed: Fed, newest: dict[str, int | None]) -> dict[str, Any]:
    r = fed.resp
    # fed.state: the checkpoint (server.statecodec) or None (none due: the stored one stays)
    return {"gyr_newest": newest["gyr"], "mag_newest": newest["mag"],
        "sid": session_id, "v0": version, "v1": version + 1, "next_seq": seq + 1, "state": fed.state,
        "behaviour": r["behaviour"], "mode": r["mode"], "sensor_config": json.dumps(r["sensor_config"]),
        "n_new": len(r["positions"]), "seq": seq, "sha": fed.digest, "raw": fed.raw, "n_acc": fed.n_acc,
        "n_gyr": fed.n_gyr, "n_mag": fed.n_mag, "response": fed.resp_json,
    }


_POS_COLS = ("t_ns", "north", "east", "down", "heading_rad", "behaviour", "mode", "step_length_m", "gyro_on")

_SQLITE_UPDATE = (
    "UPDATE sessions SET version = :v1, next_seq = :next_seq, engine_state = COALESCE(:state, engine_state), "
    "behaviour = :behaviour, "
    "mode = :mode, sensor_config = :sensor_config, n_positions = n_positions + :n_new, gyr_newest_ns = :gyr_newest, "
    "mag_newest_ns = :mag_newest WHERE id = :sid AND version = :v0"
)
# the same, for an upload whose token and session were not read: the session's owner must still hold this token
# (not revoked, not expired) when the update runs (see Uploader: uploads after this worker's own commit)
_SQLITE_UPDATE_TOKEN = _SQLITE_UPDATE + (
    " AND EXISTS (SELECT 1 FROM tokens t WHERE t.token_hash = :tok AND t.user_id = sessions.user_id "
    "AND NOT t.revoked AND (t.expires_at IS NULL OR t.expires_at > :now))"
)
_SQLITE_BATCH = (
    "INSERT INTO batches (session_id, seq, body_sha256, raw, n_acc, n_gyr, n_mag, response, received_at) "
    "VALUES (:sid, :seq, :sha, :raw, :n_acc, :n_gyr, :n_mag, :response, :now)"
)
_SQLITE_POS = (
    "INSERT INTO positions (session_id, seq, " + ", ".join(_POS_COLS) + ") VALUES (?, ?, " + ", ".join("?" * len(_POS_COLS)) + ")"
)
_SQLITE_EVENT = "INSERT INTO events (session_id, seq, t_ns, kind, detail) VALUES (?, ?, ?, ?, ?)"


class _LazyCursor:
    """The cursor of an upload's pool connection, checked out at its first statement.

    An upload after this worker's own commit of the session (no read, see :class:`Uploader`) whose engine is
    cached runs no statement of its own on SQLite (the write goes through the group writer's connection), and the
    pool's check-out and return (with its reset) cost ~25 us of its CPU.
    """

    def __init__(self, connect: Any) -> None:
        self._connect = connect
        self.conn: Any = None  # the pool connection, once checked out
        self._cur: Any = None

    def execute(self, sql: str, params: Any = ()) -> Any:
        if self._cur is None:
            self.conn = self._connect()
            self._cur = self.conn.cursor()
        return self._cur.execute(sql, params)

    def fetchone(self) -> Any:
        return self._cur.fetchone()

    def fetchall(self) -> Any:
        return self._cur.fetchall()


_HOLD_S = 60.0  # PostgreSQL: an upload connection goes back to the pool after this long checked out [s]

_Job = tuple[int, int, int, Fed, dict[str, int | None], str | None]  # session, version, seq, fed, watermarks, token


def _sqlite_write(cur: Any, job: _Job, now: str) -> bool:
    """One upload's rows inside the open transaction (``now``: its time, :func:`_utc_text`, the batch's
    ``received_at`` and the instant its token must not have expired by); False when the version check (and with a
    token hash, the token check) failed: nothing written."""
    session_id, version, seq, fed, newest, tok = job
    p = _write_params(session_id, version, seq, fed, newest)
    p["tok"] = tok
    p["now"] = now  # (a statement takes only the named parameters it has from the mapping)
    cur.execute(_SQLITE_UPDATE if tok is None else _SQLITE_UPDATE_TOKEN, p)
    if cur.rowcount != 1:
        return False
    cur.execute(_SQLITE_BATCH, p)
    ps, es = fed.resp["positions"], fed.resp["events"]
    if ps:
        cur.executemany(_SQLITE_POS, [(session_id, seq, *(x[k] for k in _POS_COLS)) for x in ps])
    if es:
        cur.executemany(_SQLITE_EVENT, [(session_id, seq, e["t_ns"], e["kind"], json.dumps(e["detail"])) for e in es])
    return True


class SqliteGroupWriter:
    """Commits the uploads' writes, all waiting ones in one transaction (group commit), in the thread of an upload.

    The upload that finds no commit under way commits the writes waiting at that moment, its own among them (it
    leads the group); the uploads that arrive meanwhile queue their writes and wait for the commit under way to
    end, and the first of them then commits all those still waiting. So a lone upload commits in its own thread,
    without the hand-over to a writer thread and back (two thread wake-ups, ~40 us of CPU per upload), and under
    load the groups are the same as a writer thread's: everything that queued during the previous commit.

    Parameters
    ----------
    db_engine : sqlalchemy.Engine
        The SQLite engine (its connections carry the WAL/synchronous pragmas).
    write_lock : lock
        Held during each transaction (the process's other writers queue on it instead of SQLite's busy wait).
    """

    def __init__(self, db_engine: Any, write_lock: Any) -> None:
        self.db_engine = db_engine
        self.write_lock = write_lock
        self._q: queue.SimpleQueue[list[Any]] = queue.SimpleQueue()
        self._lead = threading.Lock()  # held by the upload that commits a group (and by stop)
        self._conn: Any = None  # the writers' connection (used by one group's leader at a time)

    def write(self, job: _Job) -> bool:
        """Commit ``job`` (session id, read version, seq, fed, new stream watermarks, token hash or None) durably;
        False when its version check (or token check) failed."""
        box: list[Any] = [job, False, None]  # job, done, result (True/False or the error)
        self._q.put(box)
        with self._lead:
            if not box[1]:  # not in the group committed while this upload waited: it leads the next one
                self._commit_waiting()
        if isinstance(box[2], BaseException):
            raise box[2]
        return bool(box[2])

    def stop(self) -> None:
        with self._lead:
            if self._conn is not None:
                self._conn.close()
                self._conn = None

    def _commit_waiting(self) -> None:
        """Commit every queued write in one transaction (the caller holds ``_lead``)."""
        boxes: list[list[Any]] = []
        while True:
            try:
                boxes.append(self._q.get_nowait())
            except queue.Empty:
                break
        try:
            self._commit(boxes)
        except Exception as exc:  # noqa: BLE001 - every upload of the group gets the error (nothing committed)
            for b in boxes:
                b[2] = exc
            if self._conn is not None:
                try:
                    self._conn.rollback()
                except Exception:  # noqa: BLE001 - a broken connection is replaced
                    try:
                        self._conn.invalidate()
                    except Exception:  # noqa: BLE001
                        pass
                    self._conn = None
        finally:
            for b in boxes:
                b[1] = True

    def _commit(self, boxes: list[list[Any]]) -> None:
        """The group's transaction: each write's result into its box; raises when the transaction failed."""
        import sqlite3

        if self._conn is None:
            self._conn = self.db_engine.raw_connection()
        conn = self._conn
        with self.write_lock:
            cur = conn.cursor()
            cur.execute("BEGIN IMMEDIATE")
            # each upload in its own savepoint, but a group of one needs none: its failure rolls back the
            # whole transaction, which holds nothing else (two statements less per upload when idle)
            single = len(boxes) == 1
            now = _utc_text()  # one clock reading and text for the group (received_at, the token's expiry)
            for b in boxes:
                if not single:
                    cur.execute("SAVEPOINT upload")
                try:
                    b[2] = _sqlite_write(cur, b[0], now)
                except sqlite3.IntegrityError:
                    b[2] = False  # (session, seq) already stored: answered as a retry
                if not single:
                    if not b[2]:
                        cur.execute("ROLLBACK TO upload")
                    cur.execute("RELEASE upload")
            if single and not boxes[0][2]:
                conn.rollback()
            else:
                conn.commit()
            cur.close()


# PostgreSQL: the versioned update and every insert of an upload in ONE atomic statement (see module docstring).
# The positions are taken from the answer's JSON text, which the statement sends anyway (the batch's stored
# response): per position column a list parameter cost the worker ~12 array adaptations per upload in psycopg's
# Python. float8 read from JSON text is the same double (Python writes the shortest text that round-trips, and
# PostgreSQL reads it correctly rounded); NaN is null in both (server.ingest._answer).
_PG_WRITE = """
WITH u AS (
    UPDATE sessions SET version = %(v1)s, next_seq = %(next_seq)s,
        engine_state = COALESCE(CAST(%(state)s AS bytea), engine_state), behaviour = %(behaviour)s,
        mode = %(mode)s, sensor_config = CAST(%(sensor_config)s AS json), n_positions = n_positions + %(n_new)s,
        gyr_newest_ns = %(gyr_newest)s, mag_newest_ns = %(mag_newest)s
    WHERE id = %(sid)s AND version = %(v0)s{token}
    RETURNING id
), b AS (
    INSERT INTO batches (session_id, seq, body_sha256, raw, n_acc, n_gyr, n_mag, response, received_at)
    SELECT u.id, %(seq)s, %(sha)s, %(raw)s, %(n_acc)s, %(n_gyr)s, %(n_mag)s, CAST(%(response)s AS json), now() FROM u
), p AS (
    INSERT INTO positions (session_id, seq, t_ns, north, east, down, heading_rad, behaviour, mode, step_length_m, gyro_on)
    SELECT u.id, %(seq)s, x.* FROM u, json_to_recordset(CAST(%(response)s AS json) -> 'positions') AS x(
        t_ns bigint, north float8, east float8, down float8, heading_rad float8, behaviour text, mode text,
        step_length_m float8, gyro_on boolean)
){events}
SELECT count(*) FROM u
"""
# the events (one upload in ~10 has any) as arrays, their detail as before (json.dumps text, stored as sent)
_PG_EVENTS = """, e AS (
    INSERT INTO events (session_id, seq, t_ns, kind, detail)
    SELECT u.id, %(seq)s, x.* FROM u, unnest(CAST(%(e_t)s AS bigint[]), CAST(%(e_k)s AS text[]), CAST(%(e_d)s AS json[])) AS x
)"""
# an upload after this worker's own commit (no read): the token is checked in the same statement as the version
_PG_TOKEN = (
    "\n        AND EXISTS (SELECT 1 FROM tokens t WHERE t.token_hash = %(tok)s AND t.user_id = sessions.user_id"
    "\n            AND NOT t.revoked AND (t.expires_at IS NULL OR t.expires_at > now()))")
# (token checked, events present) -> statement; without the token check after this upload's read
_PG_WRITES = {(tok, ev): _PG_WRITE.format(token=_PG_TOKEN if tok else "", events=_PG_EVENTS if ev else "")
              for tok in (False, True) for ev in (False, True)}


def _pg_write(cur: Any, session_id: int, version: int, seq: int, fed: Fed, newest: dict[str, int | None],
              tok: str | None = None) -> bool:
    p = _write_params(session_id, version, seq, fed, newest)
    p["tok"] = tok
    es = fed.resp["events"]
    if es:
        p["e_t"] = [e["t_ns"] for e in es]
        p["e_k"] = [e["kind"] for e in es]
        p["e_d"] = [json.dumps(e["detail"]) for e in es]
    cur.execute(_PG_WRITES[tok is not None, bool(es)], p)
    return bool(cur.fetchone()[0] == 1)


class Uploader:
    """Applies batch uploads on driver connections (see the module docstring).

    Parameters
    ----------
    db_engine : sqlalchemy.Engine
        SQLite or PostgreSQL engine (connections from its pool).
    host : EngineHost
        Engines (helper processes or in-process) and the per-session locks.
    limiter : RateLimiter
        Per-user rate limit.
    known_max : int
        Sessions whose state after this worker's last commit is kept (see below).

    Notes
    -----
    An upload normally reads the token and the session first (one statement). When this worker committed the
    session's previous batch itself, with the same token, and the upload carries the next sequence number, the read
    is skipped: the session as that commit left it (version, next sequence number, stream watermarks) is known, and
    the write statement checks the token (same owner, not revoked, not expired) together with the version. A
    failed check writes nothing; the engine's cached copy is dropped and the upload is decided afresh after the
    read, so the answers (401 before 404/409/422, a retry answered from the stored batch) and their order are those
    of the read path. PostgreSQL: one round trip per upload instead of two.
    """

    def __init__(self, db_engine: Any, host: EngineHost, limiter: RateLimiter | None, known_max: int = 8192) -> None:
        self.db_engine = db_engine
        self.host = host
        self.limiter = limiter
        self.sqlite = db_engine.dialect.name == "sqlite"
        self.writer = SqliteGroupWriter(db_engine, host.write_lock) if self.sqlite else None
        ph = "?" if self.sqlite else "%s"
        self._read_sql = (
            "SELECT t.user_id, t.revoked, t.expires_at, s.version, s.next_seq, s.status, s.gyr_newest_ns, "
            "s.mag_newest_ns FROM tokens t "
            f"LEFT JOIN sessions s ON s.id = {ph} AND s.user_id = t.user_id WHERE t.token_hash = {ph}"
        )
        self._session_sql = (f"SELECT version, next_seq, status, gyr_newest_ns, mag_newest_ns FROM sessions "
                             f"WHERE id = {ph}")
        self._state_sql = f"SELECT version, engine_state, engine_mode, profile_in FROM sessions WHERE id = {ph}"
        self._replay_sql = f"SELECT body_sha256, response FROM batches WHERE session_id = {ph} AND seq = {ph}"
        self._raws_sql = (f"SELECT raw FROM batches WHERE session_id = {ph} AND seq >= {ph} AND seq < {ph} "
                          "ORDER BY seq")
        # session id -> _Known: the sessions this worker committed last, so that the next upload of the same
        # session with the same token skips the read (see upload); bounded (least recently written dropped)
        self._known: OrderedDict[int, _Known] = OrderedDict()
        self._known_lock = threading.Lock()
        self.known_max = max(1, int(known_max))
        # PostgreSQL: the uploads' pool connections, kept checked out in autocommit mode between uploads (at most
        # one per concurrent upload) instead of going back to the pool after each one (see _release)
        self._idle: list[Any] = []
        self._idle_lock = threading.Lock()

    def close(self) -> None:
        if self.writer is not None:
            self.writer.stop()
        with self._idle_lock:
            idle, self._idle = self._idle, []
        for conn in idle:
            self._to_pool(conn)

    def _connect(self) -> Any:
        if not self.sqlite:
            with self._idle_lock:
                if self._idle:
                    return self._idle.pop()
        conn = self.db_engine.raw_connection()
        if not self.sqlite:
            conn.driver_connection.autocommit = True  # every statement is its own transaction (no BEGIN trips)
            conn.info["pednav_checked_out"] = time.monotonic()
        return conn

    def _release(self, conn: Any) -> None:
        if conn.dbapi_connection is None:  # invalidated
            conn.close()
            return
        if not self.sqlite:
            from psycopg.pq import TransactionStatus

            # kept for the next upload (the pool's check-out, reset and return and the two autocommit switches
            # cost ~35 us of the worker's CPU per upload); back to the pool now and then, so that its recycling
            # (pool_recycle) still replaces the connection
            if time.monotonic() - conn.info.get("pednav_checked_out", 0.0) < _HOLD_S and (
                    conn.driver_connection.info.transaction_status == TransactionStatus.IDLE):
                with self._idle_lock:
                    self._idle.append(conn)
                return
            self._to_pool(conn)
            return
        conn.close()

    @staticmethod
    def _to_pool(conn: Any) -> None:
        try:
            conn.driver_connection.autocommit = False  # back to the pool as the ORM expects it
        except Exception:  # noqa: BLE001 - a broken connection is dropped by the pool
            conn.invalidate()
        conn.close()

    def upload(self, token: str | None, session_id: int, seq: int, body: bytes, content_type: str | None,
               max_samples: int) -> tuple[str, bool]:
        """Apply one upload; returns (answer JSON text, replayed). Raises HTTPException (401/404/429),
        BatchError (422), PayloadTooLarge (413), IngestConflict (409), StorageBusy (503: every attempt met a busy
        database, nothing stored)."""
        h_tok = hash_token(require_token(token))  # 401 when missing
        t_lock = time.perf_counter()
        with self.host.lock(session_id):
            since("lock", t_lock)
            cur = _LazyCursor(self._connect)
            try:
                limited = False  # the rate limit took this request already (the known path)
                with self._known_lock:
                    known = self._known.pop(session_id, None)
                if known is not None and known.token_hash == h_tok and seq == known.sess.next_seq and (
                        known.sess.status == "open") and (
                        known.expires_at is None or known.expires_at > datetime.now(timezone.utc)):
                    if self.limiter is None or self.limiter.hit(known.user_id) == 0.0:
                        limited = self.limiter is not None
                        try:
                            return self._upload_known(cur, known, session_id, seq, body, content_type, max_samples)
                        except (self.db_engine.dialect.dbapi.OperationalError,
                                self.db_engine.dialect.dbapi.InterfaceError) as exc:
                            if not is_contention(exc):
                                raise  # possibly broken: as on the read path (below)
                        except Exception:  # noqa: BLE001 - decided afresh after the read (same answers, same order)
                            pass
                        self.host.forget(session_id)  # the engine may have taken the batch: not committed
                with phase("read"):
                    cur.execute(self._read_sql, (session_id, h_tok))
                    row = cur.fetchone()
                user_id = admit(h_tok, row, None if limited else self.limiter)  # 401 / 429
                if seq < 0:
                    raise BatchError("seq", "must be >= 0")
                with phase("decode"):
                    batch, raw = decode_upload(body, content_type, max_samples)
                if row[3] is None:
                    raise HTTPException(status.HTTP_404_NOT_FOUND, f"session {session_id} not found")
                sess = _Session(*row[3:8])
                busy = self.db_engine.dialect.dbapi.OperationalError  # e.g. SQLite busy beyond its timeout
                contended = True  # every failed attempt failed through contention (nothing committed)
                for attempt in range(5):
                    try:
                        answer, replayed, after = self._apply(cur, session_id, seq, batch, sess, raw)
                        if after is not None:
                            self._keep(session_id, _Known(h_tok, user_id, token_expiry(row[2]), after))
                        return answer, replayed
                    except (_Raced, busy) as exc:  # nothing was committed: read again and start over
                        self.host.forget(session_id)
                        contended = contended and (isinstance(exc, _Raced) or is_contention(exc))
                        if attempt == 4:
                            if contended:  # a retryable 503, not a 500: the batch was not stored
                                raise StorageBusy(batch_busy_message(session_id, seq, 5)) from exc
                            raise  # e.g. a lost connection: whether a commit went through is not known here
                        time.sleep(0.01 * (attempt + 1))
                        cur.execute(self._session_sql, (session_id,))
                        sess = _Session(*cur.fetchone())
                raise AssertionError("unreachable")
            except StorageBusy as exc:
                if not isinstance(exc.__cause__, _Raced) and cur.conn is not None:
                    cur.conn.invalidate()  # as for the driver's error it stands for (below)
                raise
            except (self.db_engine.dialect.dbapi.OperationalError, self.db_engine.dialect.dbapi.InterfaceError):
                if cur.conn is not None:
                    cur.conn.invalidate()  # possibly broken: the pool opens a new connection instead
                raise
            finally:
                if cur.conn is not None:
                    self._release(cur.conn)

    def _upload_known(self, cur: Any, known: _Known, session_id: int, seq: int, body: bytes,
                      content_type: str | None, max_samples: int) -> tuple[str, bool]:
        """The upload after this worker's own commit of the session (class notes): no read; raises on anything
        but a stored batch (the caller then decides it after the read)."""
        with phase("decode"):
            batch, raw = decode_upload(body, content_type, max_samples)
        answer, replayed, after = self._apply(cur, session_id, seq, batch, known.sess, raw, token_hash=known.token_hash)
        if after is None:
            raise _Unverified()
        self._keep(session_id, known._replace(sess=after))
        return answer, replayed

    def _keep(self, session_id: int, known: _Known) -> None:
        with self._known_lock:
            self._known[session_id] = known
            self._known.move_to_end(session_id)
            while len(self._known) > self.known_max:
                self._known.popitem(last=False)

    def _apply(self, cur: Any, session_id: int, seq: int, batch: SensorBatch, sess: _Session,
               raw: bytes | None = None, token_hash: str | None = None) -> tuple[str, bool, _Session | None]:
        """Apply ``batch`` to the session read as ``sess``; returns (answer JSON, replayed, the session as this
        commit left it or None when nothing was committed). With ``token_hash`` (the known path, no read) the
        write also checks the token, and a failed check raises :class:`_Unverified` (nothing written)."""
        # raw: the batch's canonical bytes when the decoder had them (server.formats.decode_upload)
        if seq < sess.next_seq:
            return self._replay(cur, session_id, seq, digest(canonical_bytes(batch) if raw is None else raw),
                                sess.next_seq), True, None
        if sess.status != "open":
            raise IngestConflict(f"session {session_id} is closed; no more batches accepted", sess.next_seq)
        if seq > sess.next_seq:
            raise IngestConflict(f"sequence {seq} leaves a gap; expected sequence {sess.next_seq}", sess.next_seq)
        check_after(batch, sess.newest())  # 422: late gyroscope/magnetometer samples (nothing stored)
        STILL_GYRO.check(batch)  # 422: a gyroscope in deg/s while standing (the engine's check needs motion)
        newest = advanced(batch, sess.newest())

        def load_state() -> tuple[bytes | None, str, Any]:
            # version and state in ONE statement (separate reads need not see the same commit)
            cur.execute(self._state_sql, (session_id,))
            v, blob, mode, profile = cur.fetchone()
            if v != sess.version:
                raise _Raced()
            if isinstance(profile, str):
                profile = json.loads(profile)
            return (None if blob is None else bytes(blob)), mode, profile

        def stored_state() -> bytes:
            blob, mode, profile = load_state()  # a session that never stored a state gets a new engine
            if blob is not None:
                return blob
            return pack_state(self.host.new(mode, engine_profile_from_stored(profile)).to_bytes())  # null -> NaN

        def raws_after(n: int) -> list[bytes]:
            # the stored batches after the checkpoint (this session's batches below next_seq never change)
            cur.execute(self._raws_sql, (session_id, n, sess.next_seq))
            raws = [bytes(r[0]) for r in cur.fetchall()]
            if len(raws) != sess.next_seq - n:
                raise _Raced()
            return raws

        host = self.host
        engine = None
        if host.pool is not None:
            fed: Fed = pool_feed(host.pool, session_id, sess.version, seq, batch, stored_state, raws_after,
                                 host.state_every, raw)
        else:
            with phase("load_state"):
                engine, held, restored = host.restore_held(session_id, sess.version, stored_state, "auto", None,
                                                         raws_after)
            host.forget(session_id)  # the cached object is mutated now; re-cached only after the commit
            with phase("engine"):
                fed = feed_engine(engine, batch, session_id, seq,
                                  checkpoint_due(seq, host.state_every, held, restored), raw)
        if fed.state is not None:  # a checkpoint every host.state_every batches (server.statecodec)
            fed = fed._replace(state=pack_checkpoint(fed.state, seq + 1))
        with phase("write"):
            if self.writer is not None:
                ok = self.writer.write((session_id, sess.version, seq, fed, newest, token_hash))
            else:
                try:
                    ok = _pg_write(cur, session_id, sess.version, seq, fed, newest, token_hash)
                except Exception as exc:
                    import psycopg

                    if not isinstance(exc, psycopg.IntegrityError):
                        raise
                    ok = False
        if not ok and token_hash is not None:
            raise _Unverified()  # the token or the session changed: decided afresh after the read
        if not ok:  # the version check failed: another writer changed the session since it was read
            cur.execute(self._session_sql, (session_id,))
            next_seq = cur.fetchone()[1]
            if seq >= next_seq:
                # not by applying this sequence number (a close, a re-processing): read the session again and
                # decide afresh (a closed session is refused as closed, not as a sequence in the past)
                raise _Raced()
            return self._replay(cur, session_id, seq, fed.digest, next_seq), True, None  # applied by the other: a retry
        host.remember(session_id, sess.version + 1, engine)  # engine None: the helper's (vouched for now)
        return fed.resp_json, False, _Session(sess.version + 1, seq + 1, "open", newest["gyr"], newest["mag"])

    def _replay(self, cur: Any, session_id: int, seq: int, h: str, expected: int) -> str:
        cur.execute(self._replay_sql, (session_id, seq))
        row = cur.fetchone()
        if row is None:
            raise IngestConflict(f"sequence {seq} is in the past; expected {expected}", expected)
        if row[0] != h:
            raise IngestConflict(f"sequence {seq} was already used by a different batch; expected sequence {expected}", expected)
        resp = row[1]
        return resp if isinstance(resp, str) else json.dumps(resp, separators=(",", ":"))
