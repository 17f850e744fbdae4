"""Drive one engine per session: idempotent, sequenced batch application with durable storage.

The server holds no navigation math; it restores the session's engine (from an in-process cache when the
cached copy is at the stored version, else from the persisted bytes), feeds it the batch, and commits the raw
batch, the new positions/events and the new engine state in one transaction. The session row carries an
optimistic-concurrency version, so two workers can never both apply the same batch.

Batch uploads take the driver-level path of :mod:`server.upload` (same rules, fewer statements); the ORM path
here serves Sensor Logger pushes (whose watermark moves inside the same transaction) and PostgreSQL with
``PEDNAV_PG_ONE_STATEMENT_WRITES=false``.
"""

from __future__ import annotations

import dataclasses
import json
import math
import threading
import time
from collections import OrderedDict
from collections.abc import Callable, Iterator
from contextlib import contextmanager, nullcontext
from typing import Any, NamedTuple, Protocol

import numpy as np
from sqlalchemy import insert, select, update
from sqlalchemy.exc import IntegrityError, OperationalError
from sqlalchemy.orm import Session, object_session
from sqlalchemy.orm.exc import StaleDataError

from models.batch import STREAMS, BatchError, SensorBatch
from server import crud
from server.engine_pool import EngineHelperDied, EnginePool
from server.formats import MSGPACK_TYPE, canonical_bytes, decode_batch, digest
from server.models import BatchRecord, EventRecord, PositionRecord, TrackSession, User, utcnow
from server.statecodec import held_batches, pack_checkpoint, pack_state, unpack_checkpoint
from server.timing import phase, since
from server.plausibility import STILL_GYRO
from server.watermarks import advanced, check_after

__all__ = [
    "EngineHost",
    "EngineUnavailable",
    "Fed",
    "IngestConflict",
    "StorageBusy",
    "apply_batch",
    "close_session",
    "apply_known_distance",
    "checkpoint_due",
    "engine_profile_in",
    "engine_profile_from_stored",
    "session_spec",
    "feed_engine",
    "is_contention",
    "pool_feed",
    "json_safe",
    "replay_engine",
    "stored_batch",
    "validate_calibration",
]

class EngineLike(Protocol):  # the contract of energy.engine.Engine that the server relies on
    def feed(self, batch: SensorBatch) -> Any: ...
    def flush(self) -> Any: ...
    def to_bytes(self) -> bytes: ...
    def profile_dict(self) -> dict[str, Any]: ...


class IngestConflict(Exception):
    """HTTP 409: wrong sequence number, closed session, or a reused sequence with other content."""

    def __init__(self, message: str, expected_seq: int) -> None:
        super().__init__(message)
        self.message = message
        self.expected_seq = expected_seq


class StorageBusy(Exception):
    """HTTP 503 with ``Retry-After``: the database stayed busy through every attempt (other writers held its
    locks, or kept changing the session) and nothing of the request was committed, so sending it again (a batch:
    under the same sequence number) is safe. Raised with the last attempt's error as its cause."""

    def __init__(self, message: str, retry_after_s: int = 1) -> None:
        super().__init__(message)
        self.message = message
        self.retry_after_s = retry_after_s


class EngineUnavailable(StorageBusy):
    """HTTP 503 with ``Retry-After``: the engine cannot take the batch now (its helper process died twice in a row
    under this request, or the engines are still being compiled after a fresh install); nothing was stored, the
    same batch may be sent again under the same sequence number."""


def batch_busy_message(session_id: int, seq: int, attempts: int) -> str:
    """The 503 answer's detail for a batch whose every attempt met a busy database."""
    return (f"database busy: batch {seq} of session {session_id} was NOT stored (other writes held the database "
            f"through {attempts} attempts); send it again with the same sequence number {seq}")


# PostgreSQL: serialization failure, deadlock, lock not available (lock_timeout), query canceled (statement_timeout)
_PG_CONTENTION = frozenset({"40001", "40P01", "55P03", "57014"})
_SQLITE_CONTENTION = frozenset({5, 6})  # SQLITE_BUSY, SQLITE_LOCKED (primary result codes)


def is_contention(exc: BaseException) -> bool:
    """True when the database refused a statement only because other transactions held what it needed (SQLite:
    busy or locked beyond its timeout; PostgreSQL: the SQLSTATEs above): its transaction is rolled back (or never
    began), nothing of it is committed. False for any other error, a broken or refused connection included (after a
    lost connection a commit's fate can be unknown). Takes the driver's error or SQLAlchemy's wrapper of it."""
    orig = getattr(exc, "orig", None) or exc
    code = getattr(orig, "sqlite_errorcode", None)
    if code is not None:
        return code & 0xFF in _SQLITE_CONTENTION
    state = getattr(orig, "sqlstate", None)
    if state is not None:
        return state in _PG_CONTENTION
    import sqlite3

    # no result code: an error not raised by sqlite3 itself (built by hand); SQLite's messages for these codes
    return isinstance(orig, sqlite3.OperationalError) and str(orig).startswith(
        ("database is locked", "database table is locked"))


def _default_factory() -> Any:
    from energy.engine import Engine  # imported lazily: the API process starts fast

    return Engine


class EngineHost:
    """Creates, restores and caches engines (LRU, keyed by session id and row version).

    Parameters
    ----------
    cache_size : int
        Engines kept in memory; 0 disables the cache (every batch restores from bytes).
    engine_cls : type, optional
        The engine class (default :class:`energy.engine.Engine`).
    serialize_writes : bool
        Serialise this process's write transactions (SQLite).
    engine_processes : int
        Helper processes that run the engines of batch uploads (0 = in this process).
    channels : int
        Requests in flight to one helper process (one per ingest thread).
    warm : bool
        Compile or load the engine's kernels at :meth:`start` and report :meth:`ready` only then
        (:mod:`server.warmup`); False: ready at once.
    state_every : int
        Batch uploads store the engine state as a checkpoint every this many batches (``Settings.state_every``,
        :mod:`server.statecodec`); a restore replays the stored batches after the last one.
    """

    def __init__(
        self,
        cache_size: int = 512,
        engine_cls: Any | None = None,
        serialize_writes: bool = False,
        engine_processes: int = 0,
        channels: int = 16,
        warm: bool = False,
        state_every: int = 4,
    ) -> None:
        self.cache_size = cache_size
        self.state_every = max(1, int(state_every))
        self.warm = warm
        # engines in helper processes (only for the default engine class: helpers import it themselves)
        self.pool: EnginePool | None = EnginePool(engine_processes, cache_size, channels, warm) if (
            engine_processes > 0 and engine_cls is None) else None
        self._warmed = threading.Event()
        if not warm:
            self._warmed.set()
        # SQLite has one writer at a time; letting this process's threads queue on a lock is far cheaper than
        # SQLite's busy-wait sleeps (other worker processes are still arbitrated by SQLite itself)
        self.serialize_writes = serialize_writes
        self.write_lock: Any = threading.Lock() if serialize_writes else nullcontext()
        self._engine_cls = engine_cls
        # session id -> (version, engine, stored as a complete state: the next batch stores a checkpoint)
        self._cache: OrderedDict[int, tuple[int, EngineLike, bool]] = OrderedDict()
        self._locks: dict[int, threading.Lock] = {}
        self._guard = threading.Lock()

    def start(self) -> None:
        """At server start: spawn the engine helpers (they warm up themselves), or warm up this process's engine
        in a background thread (``warm``); the worker's own compiled code on the upload path too
        (:func:`server.warmup.warm_worker`)."""
        if self.pool is not None:
            self.pool.start()
        if not self._warmed.is_set():
            pool = self.pool

            def warm() -> None:
                from server.warmup import warm_up, warm_worker

                try:
                    warm_worker()
                    if pool is None:
                        warm_up(self.engine_cls)
                finally:
                    self._warmed.set()

            threading.Thread(target=warm, daemon=True, name="engine-warmup").start()

    def ready(self) -> bool:
        """The engine's kernels are compiled and loaded: an upload is answered within the normal latency."""
        if self.pool is not None:
            return self._warmed.is_set() and (not self.warm or self.pool.ready())
        return self._warmed.is_set()

    @property
    def engine_cls(self) -> Any:
        if self._engine_cls is None:
            self._engine_cls = _default_factory()
        return self._engine_cls

    def engine_class_of(self, placement: str | None, device_kind: str) -> Any:
        """The engine class a session of that placement and device kind runs (a custom ``engine_cls`` for all)."""
        if self._engine_cls is not None:
            return self._engine_cls
        from energy.engines import EngineSpec, engine_class

        return engine_class(EngineSpec(device_kind, placement))

    def new(self, mode: str, profile: dict[str, Any] | None, spec: Any = None) -> EngineLike:
        """A fresh engine; ``spec`` (:class:`energy.engines.EngineSpec`, default: a foot sensor) picks the
        pipeline of the default engines; a custom ``engine_cls`` is always used as it is."""
        if self._engine_cls is None:
            from energy.engines import new_engine

            return new_engine(mode, profile, spec)  # type: ignore[no-any-return]
        return self.engine_cls(mode=mode, profile=profile)

    def restore(self, sess: TrackSession) -> EngineLike:
        """The session's engine at its stored version (the checkpoint and the stored batches after it, read in the
        ORM session ``sess`` belongs to)."""
        db = object_session(sess)
        return self.restore_at(sess.id, sess.version, lambda: sess.engine_state, sess.engine_mode, sess.profile_in,
                               lambda n: orm_batches_after(db, sess.id, n, sess.next_seq))

    def restore_at(
        self, session_id: int, version: int, load_state: Any, mode: str, profile: dict[str, Any] | None,
        load_raws: Callable[[int], list[bytes]] | None = None,
    ) -> EngineLike:
        """The engine of ``session_id`` at ``version``: the cached one when it is at that version, else
        restored from ``load_state()`` (bytes or None for a session that never got a batch) and, for a checkpoint,
        the stored raw batches after it (``load_raws(n)``: batches ``n ..`` in order)."""
        return self.restore_held(session_id, version, load_state, mode, profile, load_raws)[0]

    def restore_held(
        self, session_id: int, version: int, load_state: Any, mode: str, profile: dict[str, Any] | None,
        load_raws: Callable[[int], list[bytes]] | None,
    ) -> tuple[EngineLike, int | None, bool]:
        """:meth:`restore_at`, returning ``(engine, held, restored)``: ``held`` the batches the stored blob holds
        (None: a complete state), ``restored`` False for the cached engine (:func:`checkpoint_due`), True for
        one remembered as stored in a complete state (:meth:`remember`): its next batch stores the checkpoint a
        restore from that state would."""
        hit = self._cache.get(session_id)
        if hit is not None and hit[0] == version:
            self._cache.move_to_end(session_id)
            return hit[1], None, hit[2]
        blob = load_state()
        if blob is None:  # only sessions from before engine states were stored: all ran the foot engine
            return self.new(mode, engine_profile_from_stored(profile)), None, True
        state, held = unpack_checkpoint(blob)
        if self._engine_cls is None:
            from energy.engines import engine_from_bytes

            from_bytes: Callable[[bytes], Any] = engine_from_bytes
        else:
            from_bytes = self.engine_cls.from_bytes
        if held is not None and load_raws is None:
            raise ValueError("a checkpoint needs the stored batches after it (load_raws)")
        raws = load_raws(held) if held is not None and load_raws is not None else []
        return replay_engine(from_bytes(state), raws), held, True

    def remember(self, session_id: int, version: int, engine: EngineLike | None, complete: bool = False) -> None:
        """After the commit of ``version``: keep ``engine`` for the next batch (None: the engine helper's, which
        fed it; see :mod:`server.engine_pool`). ``complete``: the commit stored ``engine`` as a complete state
        (a session start), so its next batch is treated as one after a restore from that state
        (:func:`checkpoint_due`), with the engine kept instead of decoded from the bytes just stored."""
        if engine is None:
            if self.pool is not None:
                self.pool.committed(session_id, version)
            return
        if self.cache_size <= 0:
            return
        self._cache[session_id] = (version, engine, complete)
        self._cache.move_to_end(session_id)
        while len(self._cache) > self.cache_size:
            self._cache.popitem(last=False)

    def forget(self, session_id: int) -> None:
        self._cache.pop(session_id, None)
        if self.pool is not None:
            self.pool.forget(session_id)

    @contextmanager
    def lock(self, session_id: int) -> Iterator[None]:
        """Serialise requests of one session inside this process (threads share cached engines)."""
        with self._guard:
            lk = self._locks.setdefault(session_id, threading.Lock())
        with lk:
            yield


def stored_batch(raw: bytes) -> SensorBatch:
    """A stored raw batch (:func:`server.formats.canonical_bytes`) as the batch it was."""
    return decode_batch(raw, MSGPACK_TYPE, 2**62, allow_empty=True)


def replay_engine(engine: EngineLike, raws: list[bytes]) -> EngineLike:
    """Feed ``engine`` (restored from a checkpoint) the stored raw batches after it, in order: the state after the
    last of them, exactly (the engine is chunk invariant; the outputs were stored when they were first fed)."""
    for raw in raws:
        engine.feed(stored_batch(raw))
    return engine


def checkpoint_due(seq: int, every: int, held: int | None, restored: bool) -> bool:
    """Whether batch ``seq``'s upload stores the engine state: every ``every`` batches (after batches ``every - 1``,
    ``2 every - 1`` ...), and after a restore from a complete state (``held`` None: an older server's, or the
    session start's, migrated now) or from a checkpoint ``every`` or more batches back (``every`` was larger)."""
    if (seq + 1) % every == 0:
        return True
    return restored and (held is None or seq + 1 - held >= every)


def orm_batches_after(db: Session, session_id: int, n: int, next_seq: int) -> list[bytes]:
    """Raw batches ``n .. next_seq - 1`` of the session, in order (raises :class:`_Raced` when one is missing:
    another writer changed the session meanwhile)."""
    rows = db.execute(select(_BATCHES.c.raw).where(_BATCHES.c.session_id == session_id, _BATCHES.c.seq >= n,
                                                   _BATCHES.c.seq < next_seq).order_by(_BATCHES.c.seq)).all()
    if len(rows) != next_seq - n:
        raise _Raced()
    return [bytes(r.raw) for r in rows]


def json_safe(obj: Any) -> Any:
    """JSON-storable copy: non-finite floats -> None (JSON and PostgreSQL's json type have no NaN), numpy
    arrays -> (nested) lists, numpy scalars -> Python numbers."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_safe(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return json_safe(obj.tolist())
    if isinstance(obj, np.generic):
        return json_safe(obj.item())
    return obj


def _null_to_nan(v: Any) -> Any:
    if v is None:
        return float("nan")
    if isinstance(v, dict):
        return {k: _null_to_nan(x) for k, x in v.items()}
    if isinstance(v, list):
        return [_null_to_nan(x) for x in v]
    return v


def _calibration_in(data: dict[str, Any]) -> dict[str, Any]:
    """Stored calibration -> engine form: a null float becomes NaN again, inside ``step_model`` at any depth.

    The stored form is :func:`json_safe`'s: each non-finite float became null (JSON has none), also inside
    ``step_model`` (a compass that never got its fit keeps its field ``m_n``, ``residual_std`` and
    ``heading_rms`` NaN). The engine's profile form holds no None of its own, so a null is always such a
    float. Restoring only the top-level fields left ``float(None)`` in the compass's ``from_state``: every
    session start of a user whose stored profile came from a session without a magnetometer fit failed with
    HTTP 500. (An infinite float, stored as null too, comes back as NaN.) At the top level only the float
    fields are restored (a null ``calibrated`` or ``n_steps`` stays invalid input, as before).
    """
    from energy.profile import BehaviourCalibration

    floats = {f.name for f in dataclasses.fields(BehaviourCalibration) if f.type in ("float", float)}
    out = {k: (float("nan") if k in floats and v is None else v) for k, v in data.items()}
    if isinstance(out.get("step_model"), dict):
        out["step_model"] = _null_to_nan(out["step_model"])
    return out


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def validate_calibration(behaviour: str, data: dict[str, Any], host: EngineHost | None = None) -> None:
    """Raise ``ValueError`` naming the problem when ``data`` is not a valid calibration of ``behaviour``.

    Checks the field types (numbers or null for the floats, an integer ``n_steps``, a boolean ``calibrated``),
    then with ``host`` that an engine takes the calibration in its stored form as a session start would hand
    it over: a profile accepted with a string ``heading_deviation_rad`` or a malformed ``step_model`` made every
    later session start of its user fail with HTTP 500.
    """
    from energy.profile import BehaviourCalibration, Profile

    for f in dataclasses.fields(BehaviourCalibration):
        if f.name not in data:
            continue
        v = data[f.name]
        if f.type in ("float", float) and v is not None:
            if not _is_number(v):
                raise ValueError(f"{f.name}: must be a number or null, got {type(v).__name__}")
            try:
                float(v)
            except OverflowError:
                raise ValueError(f"{f.name}: beyond the float64 range") from None
        elif f.name == "n_steps" and not (isinstance(v, int) and not isinstance(v, bool)):
            raise ValueError(f"n_steps: must be an integer, got {type(v).__name__}")
        elif f.name == "calibrated" and not isinstance(v, bool):
            raise ValueError(f"calibrated: must be true or false, got {type(v).__name__}")
    try:
        Profile.from_dict({"version": 1, "behaviours": {behaviour: _calibration_in(data)}})
        if host is not None:
            from energy.engines import EngineSpec
            from energy.phone_engine import PROFILE_KEY

            stored = json_safe(data)  # what is stored; a session start reads it back through _calibration_in
            # the engine that takes this calibration ("auto" loads it): a phone's for the step-and-heading entry
            spec = EngineSpec("phone", "phone-hand") if behaviour == PROFILE_KEY else None
            host.new("auto", {"version": 1, "behaviours": {behaviour: _calibration_in(stored)}}, spec)
    except ValueError:
        raise
    except RecursionError:
        raise ValueError("nested too deeply") from None
    except Exception as exc:  # noqa: BLE001 - whatever the engine cannot load is a client error here
        raise ValueError(f"the engine cannot load this calibration ({type(exc).__name__}: {exc})") from None


def engine_profile_from_stored(profile: dict[str, Any] | None) -> dict[str, Any] | None:
    """A session's stored ``profile_in`` (:func:`json_safe` form, what :func:`engine_profile_in` handed its
    engine) in the engine's form again."""
    if not profile:
        return None
    behaviours = profile.get("behaviours") or {}
    return {**profile, "behaviours": {b: _calibration_in(c) for b, c in behaviours.items() if isinstance(c, dict)}}


def engine_profile_in(db: Session, user: User, pipeline: str | None = None) -> dict[str, Any] | None:
    """The user's current calibration profiles in the engine's form, or None when there are none; with
    ``pipeline`` (``foot`` / ``step-and-heading``) only what an engine of that pipeline takes."""
    cur = {b: _calibration_in(p.data) for b, p in crud.current_profiles(db, user).items() if p.data is not None}
    prof = {"version": 1, "behaviours": cur} if cur else None
    if pipeline is None:
        return prof
    from energy.engines import profile_for

    return profile_for(prof, pipeline)


def session_spec(device_kind: str, placement: str | None, latitude_deg: float | None, longitude_deg: float | None,
                 altitude_m: float | None, created_at: Any) -> Any:
    """The :class:`energy.engines.EngineSpec` of a session's stored fields (anchor from its geodetic start, WMM
    date from its creation)."""
    from energy.engines import EngineSpec

    anchor = None
    if latitude_deg is not None and longitude_deg is not None:
        anchor = (float(latitude_deg), float(longitude_deg), float(altitude_m or 0.0))
    day = created_at.date() if hasattr(created_at, "date") and callable(created_at.date) else created_at
    return EngineSpec(device_kind, placement, anchor, day)


def _update_dict(session_id: int, seq: int, next_seq: int, upd: Any) -> dict[str, Any]:
    """The answer to a batch (flat copies of the engine's frozen dataclasses; NaN -> None)."""
    return _answer(session_id, seq, next_seq, upd)[0]


def _answer(session_id: int, seq: int, next_seq: int, upd: Any) -> tuple[dict[str, Any], str]:
    """The answer to a batch and its compact JSON text (NaN/inf -> null: they are invalid JSON and invalid in
    PostgreSQL's json)."""
    d = {
        "session_id": session_id,
        "seq": seq,
        "next_seq": next_seq,
        "positions": [dict(vars(p)) for p in upd.positions],
        "events": [{"t_ns": int(e.t_ns), "kind": e.kind, "detail": dict(e.detail)} for e in upd.events],
        "behaviour": upd.behaviour,
        "mode": upd.mode,
        "sensor_config": dict(vars(upd.sensor_config)),
    }
    try:
        text = json.dumps(d, allow_nan=False, separators=(",", ":"))
    except ValueError:
        d = json_safe(d)
        text = json.dumps(d, allow_nan=False, separators=(",", ":"))
    return d, text


class Fed(NamedTuple):
    """What the worker stores and answers after the engine took a batch (built where the engine runs)."""

    resp: dict[str, Any]  # the answer
    resp_json: str  # the answer as compact JSON (stored as the batch's response and sent)
    raw: bytes  # canonical raw batch (lossless msgpack)
    digest: str  # SHA-256 of raw (retries must match it)
    state: bytes | None  # the engine's new state (Engine.to_bytes; None: no checkpoint at this batch, server.statecodec)
    n_acc: int
    n_gyr: int
    n_mag: int


def feed_engine(engine: EngineLike, batch: SensorBatch, session_id: int, seq: int, want_state: bool = True,
                raw: bytes | None = None) -> Fed:
    """Feed ``batch`` as number ``seq`` and encode everything that is stored for it, the engine's state only with
    ``want_state`` (``BatchError`` from the engine's validation passes through; the engine is then unchanged).
    ``raw``: the batch's :func:`~server.formats.canonical_bytes` when the decoder had them
    (:func:`~server.formats.decode_upload`), else they are encoded here."""
    upd = engine.feed(batch)
    resp, text = _answer(session_id, seq, seq + 1, upd)
    if raw is None:
        raw = canonical_bytes(batch)
    return Fed(resp, text, raw, digest(raw), engine.to_bytes() if want_state else None, len(batch.acc_t_ns),
               len(batch.gyr_t_ns), len(batch.mag_t_ns))


def pool_feed(pool: EnginePool, session_id: int, version: int, seq: int, batch: SensorBatch,
              load_blob: Callable[[], bytes], load_raws: Callable[[int], list[bytes]], every: int,
              raw: bytes | None = None) -> Fed:
    """Feed ``batch`` through the engine helper process: its cached engine when this worker committed
    ``version`` from it (:meth:`EnginePool.take`) and the helper still holds it, else the stored state
    ``load_blob()`` and, for a checkpoint, the stored batches after it (``load_raws(n)``); ``BatchError`` from the
    engine's validation is raised here. The answer carries the engine state when :func:`checkpoint_due` (``every``
    batches). ``raw``: the batch's canonical bytes when the decoder had them (the helper then neither encodes nor
    sends them back). Call ``host.remember(session_id, version + 1, None)`` after the commit."""
    streams: dict[str, Any] = {}
    for name in STREAMS:
        streams[f"{name}_t_ns"], streams[name] = batch.stream(name)
    out: tuple[Any, ...] = ("miss",)
    if pool.take(session_id, version):
        try:
            with phase("engine"):
                out = pool.feed(session_id, version, None, seq, streams, checkpoint_due(seq, every, None, False),
                                raw is None)
        except EngineHelperDied:  # its cached engine died with it: a fresh helper restores the stored state
            out = ("miss",)
    if out[0] == "miss":
        with phase("load_state"):
            blob = load_blob()
            held = held_batches(blob)
            stored = (blob, load_raws(held) if held is not None else [])
        want = checkpoint_due(seq, every, held, True)
        for attempt in (1, 2):  # a helper that dies under the request costs one retry on a fresh one
            try:
                with phase("engine"):
                    out = pool.feed(session_id, version, stored, seq, streams, want, raw is None)
                break
            except EngineHelperDied as exc:
                if attempt == 2:
                    raise EngineUnavailable(
                        f"the navigation engine's helper process died twice under batch {seq} of session "
                        f"{session_id}; the batch was NOT stored: send it again with the same sequence number",
                        retry_after_s=2) from exc
    if out[0] == "batch_error":
        raise BatchError(out[1], out[2])
    if raw is not None:
        return out[1]._replace(raw=raw, digest=digest(raw))
    return out[1]


def _store_outputs(db: Session, sess: TrackSession, seq: int, upd: Any) -> None:
    for p in upd.positions:
        db.add(PositionRecord(session_id=sess.id, seq=seq, **p.to_dict()))
    for e in upd.events:
        db.add(EventRecord(session_id=sess.id, seq=seq, t_ns=int(e.t_ns), kind=e.kind, detail=dict(e.detail)))
    sess.n_positions += len(upd.positions)
    sess.behaviour = upd.behaviour
    sess.mode = upd.mode
    sess.sensor_config = upd.sensor_config.to_dict()


def _replayed(db: Session, sess: TrackSession, seq: int, h: str) -> dict[str, Any]:
    old = crud.get_batch(db, sess.id, seq)
    if old is None:  # cannot happen unless batches were deleted
        raise IngestConflict(f"sequence {seq} is in the past; expected {sess.next_seq}", sess.next_seq)
    if old.body_sha256 != h:
        raise IngestConflict(
            f"sequence {seq} was already used by a different batch; expected sequence {sess.next_seq}", sess.next_seq
        )
    return dict(old.response)


def apply_batch(
    db: Session,
    host: EngineHost,
    user_id: int,
    session_id: int,
    seq: int,
    batch: SensorBatch,
    attempts: int = 5,
    also: Callable[[Session], None] | None = None,
) -> tuple[dict[str, Any], bool] | None:
    """Apply ``batch`` as number ``seq`` of the session; returns ``(response, replayed)`` or None (no session
    of this user).

    A retry of an applied sequence number with the same content returns the stored response
    (``replayed=True``) and changes nothing. Raises :class:`IngestConflict` for gaps, old numbers with other
    content and closed sessions, and ``BatchError`` (from the engine's validation) for a bad batch; nothing is
    stored then. Retries when the database is busy (SQLite: another worker wrote since this transaction
    began); the retry then sees that worker's result and answers as for a retried batch. When every attempt met
    a busy database, raises :class:`StorageBusy` (nothing stored: the same batch may be sent again).
    ``also(db)`` runs inside the same write transaction (e.g. to advance the Sensor Logger watermark atomically).
    """
    raw = canonical_bytes(batch)
    h = digest(raw)
    contended = True  # every failed attempt failed through contention (nothing committed)
    for i in range(attempts):
        try:
            return _apply_once(db, host, user_id, session_id, seq, batch, raw, h, also)
        except (OperationalError, _Raced) as exc:
            db.rollback()
            host.forget(session_id)
            contended = contended and (isinstance(exc, _Raced) or is_contention(exc))
            if i == attempts - 1:
                if contended:  # a retryable 503, not a 500: the batch was not stored
                    raise StorageBusy(batch_busy_message(session_id, seq, attempts)) from exc
                raise  # e.g. a lost connection: whether a commit went through is not known here
            time.sleep(0.01 * (i + 1))
    return None


class _Raced(Exception):
    """Another worker committed this session between two reads; start over."""


_TS = TrackSession.__table__
_BATCHES = BatchRecord.__table__
_POSITIONS = PositionRecord.__table__
_EVENTS = EventRecord.__table__


def _answer_as_retry(db: Session, session_id: int, seq: int, h: str) -> dict[str, Any]:
    """The version check failed: roll back; a concurrent writer that applied ``seq`` first makes this an upload
    answered as a retry. One that changed the session otherwise (a close, a re-processing) raises
    :class:`_Raced`: the session is read again and the upload decided afresh (a closed session is then refused
    as closed, not as a sequence in the past)."""
    db.rollback()
    cur = db.execute(select(_TS.c.next_seq).where(_TS.c.id == session_id)).scalar_one()
    if seq >= cur:
        db.rollback()
        raise _Raced()
    return _replayed_core(db, session_id, seq, h, cur)


def _replayed_core(db: Session, session_id: int, seq: int, h: str, expected: int) -> dict[str, Any]:
    row = db.execute(
        select(_BATCHES.c.body_sha256, _BATCHES.c.response).where(_BATCHES.c.session_id == session_id, _BATCHES.c.seq == seq)
    ).first()
    db.rollback()
    if row is None:
        raise IngestConflict(f"sequence {seq} is in the past; expected {expected}", expected)
    if row.body_sha256 != h:
        raise IngestConflict(f"sequence {seq} was already used by a different batch; expected sequence {expected}", expected)
    return dict(row.response)


def _apply_once(
    db: Session,
    host: EngineHost,
    user_id: int,
    session_id: int,
    seq: int,
    batch: SensorBatch,
    raw: bytes,
    h: str,
    also: Callable[[Session], None] | None,
) -> tuple[dict[str, Any], bool] | None:
    # Core statements on the hot path: one read transaction, the engine outside any transaction, one short
    # write transaction whose version check makes concurrent workers unable to apply a batch twice.
    t_lock = time.perf_counter()
    with host.lock(session_id):
        since("lock", t_lock)
        with phase("read"):
            row = db.execute(
                select(_TS.c.version, _TS.c.next_seq, _TS.c.status, _TS.c.engine_mode, _TS.c.profile_in,
                       _TS.c.gyr_newest_ns, _TS.c.mag_newest_ns).where(
                    _TS.c.id == session_id, _TS.c.user_id == user_id
                )
            ).first()
        if row is None:
            db.rollback()
            return None
        if seq < row.next_seq:
            return _replayed_core(db, session_id, seq, h, row.next_seq), True
        if row.status != "open":
            db.rollback()
            raise IngestConflict(f"session {session_id} is closed; no more batches accepted", row.next_seq)
        if seq > row.next_seq:
            db.rollback()
            raise IngestConflict(f"sequence {seq} leaves a gap; expected sequence {row.next_seq}", row.next_seq)
        newest0 = {"gyr": row.gyr_newest_ns, "mag": row.mag_newest_ns}
        try:
            check_after(batch, newest0)  # 422: late gyroscope/magnetometer samples (nothing stored)
            STILL_GYRO.check(batch)  # 422: a gyroscope in deg/s while standing
        except BatchError:
            db.rollback()
            raise
        newest = advanced(batch, newest0)

        def load_state() -> bytes | None:
            # version and state in ONE statement: separate SELECTs need not see the same commit (SQLite's
            # driver runs SELECTs outside a transaction; PostgreSQL reads committed per statement)
            cur = db.execute(select(_TS.c.version, _TS.c.engine_state).where(_TS.c.id == session_id)).one()
            if cur.version != row.version:
                raise _Raced()
            return cur.engine_state

        def end_read() -> None:
            # SQLite: a read transaction that later writes fails if another writer committed meanwhile, so
            # end it before the engine runs; PostgreSQL: keep it (saves round trips; the version check guards)
            if host.serialize_writes:
                db.rollback()

        engine: EngineLike | None = None
        if host.pool is not None:  # the engine runs in a helper process
            end_read()

            def stored_blob() -> bytes:
                blob = load_state()
                if blob is None:  # as for the in-process engine below: a new engine of the stored mode and profile
                    blob = pack_state(host.new(row.engine_mode, engine_profile_from_stored(row.profile_in)).to_bytes())
                return blob

            fed = pool_feed(host.pool, session_id, row.version, seq, batch, stored_blob,
                            lambda n: orm_batches_after(db, session_id, n, row.next_seq), host.state_every)
            resp, behaviour, mode = fed.resp, fed.resp["behaviour"], fed.resp["mode"]
            state = None if fed.state is None else pack_checkpoint(fed.state, seq + 1)
        else:
            with phase("load_state"):
                engine, held, restored = host.restore_held(session_id, row.version, load_state, row.engine_mode,
                                                         row.profile_in,
                                                         lambda n: orm_batches_after(db, session_id, n, row.next_seq))
                end_read()
            host.forget(session_id)  # the cached object is mutated now; re-cached only after the commit
            with phase("engine"):
                upd = engine.feed(batch)  # validates the batch (BatchError -> 422, nothing stored)
                resp = _update_dict(session_id, seq, seq + 1, upd)
                due = checkpoint_due(seq, host.state_every, held, restored)
                state = pack_checkpoint(engine.to_bytes(), seq + 1) if due else None
            behaviour, mode = upd.behaviour, upd.mode
        next_seq = seq + 1
        try:
            t_wl = time.perf_counter()
            with host.write_lock, phase("write"):
                since("write_lock", t_wl)
                values: dict[str, Any] = {"engine_state": state} if state is not None else {}  # a checkpoint
                res = db.execute(
                    update(_TS).where(_TS.c.id == session_id, _TS.c.version == row.version).values(
                        version=row.version + 1, next_seq=next_seq, behaviour=behaviour,
                        mode=mode, sensor_config=resp["sensor_config"],
                        n_positions=_TS.c.n_positions + len(resp["positions"]), gyr_newest_ns=newest["gyr"],
                        mag_newest_ns=newest["mag"], **values,
                    )
                )
                if res.rowcount != 1:
                    raise StaleDataError("session changed since it was read")
                db.execute(insert(_BATCHES), [{
                    "session_id": session_id, "seq": seq, "body_sha256": h, "raw": raw, "n_acc": len(batch.acc_t_ns),
                    "n_gyr": len(batch.gyr_t_ns), "n_mag": len(batch.mag_t_ns), "response": resp, "received_at": utcnow(),
                }])
                if resp["positions"]:
                    db.execute(insert(_POSITIONS), [{"session_id": session_id, "seq": seq, **p} for p in resp["positions"]])
                if resp["events"]:
                    db.execute(insert(_EVENTS), [{"session_id": session_id, "seq": seq, **e} for e in resp["events"]])
                if also is not None:
                    also(db)
                with phase("commit"):
                    db.commit()
        except (StaleDataError, IntegrityError):
            # another worker changed the session first: a retry's answer if it applied this sequence number
            return _answer_as_retry(db, session_id, seq, h), True
        host.remember(session_id, row.version + 1, engine)  # engine None: the helper's (vouched for now)
        return resp, False


def close_session(db: Session, host: EngineHost, user: User, session_id: int,
                  keep_versions: int | None = None) -> TrackSession | None:
    """Flush the engine, store the last positions and the updated calibration profiles, mark closed.

    Closing an already closed session changes nothing. ``keep_versions``: profile versions kept per behaviour
    (the newest; ``Settings.max_profile_versions``).

    The session's write lock is the transaction's first statement (a no-op update of its row: PostgreSQL's row
    lock, SQLite's write lock), so concurrent closes of one session (other threads, other workers) take turns
    and each later one finds it closed; its profile versions then take the user's lock
    (:func:`server.crud.add_profile_version`). Reading first let six simultaneous closes on PostgreSQL all add
    the same next profile version: five answered HTTP 500 and left their sessions open.
    """
    with host.lock(session_id), host.write_lock:  # SQLite: this process's writers queue here, not in busy waits
        locked = db.execute(update(_TS).where(_TS.c.id == session_id, _TS.c.user_id == user.id)
                            .values(status=_TS.c.status))
        if locked.rowcount != 1:
            db.rollback()
            return None
        sess = crud.get_session(db, user, session_id)
        if sess is None or sess.status != "open":
            db.rollback()
            return sess
        engine = host.restore(sess)
        host.forget(session_id)
        upd = engine.flush()
        _store_outputs(db, sess, sess.next_seq, upd)
        for behaviour, data in _profiles_out(engine).items():
            cur = crud.current_profiles(db, user).get(behaviour)
            if cur is None or cur.data != data:
                crud.add_profile_version(db, user, behaviour, data, source=f"session:{sess.id}", keep=keep_versions)
        sess.engine_state = pack_state(engine.to_bytes())
        sess.status = "closed"
        sess.closed_at = utcnow()
        db.commit()
        return sess


def apply_known_distance(db: Session, host: EngineHost, user: User, session_id: int, t0_ns: int, t1_ns: int,
                         distance_m: float) -> dict[str, Any] | None:
    """A distance the user walked between two times of an open session (a user-entered distance, a stretch a foot
    sensor or GNSS measured): the session's step-and-heading engine calibrates its step length from the steps
    between them; the ``calibration`` event is stored and returned, the engine state with it (the profile takes it
    at the close). None when the user has no such session.

    Raises
    ------
    IngestConflict
        The session is closed.
    ValueError
        Not a step-and-heading session, or the engine refuses the distance (no steps between the times ...).
    """
    with host.lock(session_id):
        sess = crud.get_session(db, user, session_id, for_update=True)
        if sess is None:
            return None
        if sess.status != "open":
            db.rollback()
            raise IngestConflict(f"session {session_id} is closed; a distance calibrates an open session", sess.next_seq)
        engine = host.restore(sess)
        host.forget(session_id)
        calibrate = getattr(engine, "calibrate_distance", None)
        if calibrate is None:
            db.rollback()
            raise ValueError("session: a foot sensor's step length is calibrated by its own ZUPT-KF; known distances "
                             "calibrate phone and watch sessions")
        try:
            ev = calibrate(int(t0_ns), int(t1_ns), float(distance_m))
        except ValueError:
            db.rollback()
            raise
        detail = json_safe(dict(ev.detail))
        db.add(EventRecord(session_id=sess.id, seq=max(sess.next_seq - 1, 0), t_ns=int(ev.t_ns), kind=ev.kind, detail=detail))
        sess.engine_state = pack_state(engine.to_bytes())
        with host.write_lock:
            db.commit()
        return {"t_ns": int(ev.t_ns), "kind": ev.kind, "detail": detail}


def _profiles_out(engine: EngineLike) -> dict[str, dict[str, Any]]:
    prof = (engine.profile_dict() or {}).get("behaviours", {})
    return {b: json_safe(v) for b, v in prof.items() if isinstance(v, dict) and v}
