"""Re-process a session with the server's current engine from its stored raw batches.

Every accepted batch is stored losslessly (canonical msgpack, float64) together with its sequence number, so
a session can be run again through whatever engine the server runs now (a newer release, another engine
mode). The batches are fed one by one in sequence order, exactly as they were cut when they arrived (the
engine is chunk-invariant, but feeding the same pieces makes "engine unchanged" reproduce the original run
bit for bit); a closed session is flushed at the end as its close did.

The new trajectory (positions and events), the engine state and the session's current behaviour, mode and
sensor configuration replace the old ones in ONE write transaction guarded by the session's version: a batch
that arrives while the session is being re-processed makes the re-processing fail with a conflict (retry it)
instead of being overwritten. The stored answers of the original uploads are left as they were sent (a
retried upload keeps getting its original answer), and calibration profiles are not touched.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from sqlalchemy import delete, insert, select, update
from sqlalchemy.orm import Session

from models.batch import BatchError
from server.formats import MSGPACK_TYPE, decode_batch
from server.ingest import EngineHost, _update_dict, engine_profile_from_stored, session_spec
from server.models import BatchRecord, EventRecord, PositionRecord, TrackSession, User, utcnow
from server.statecodec import pack_state

__all__ = ["ReprocessConflict", "ReprocessResult", "reprocess_session"]

_TS = TrackSession.__table__
_BATCHES = BatchRecord.__table__
_POSITIONS = PositionRecord.__table__
_EVENTS = EventRecord.__table__
_POS_FIELDS = ("t_ns", "north", "east", "down", "heading_rad", "behaviour", "mode", "step_length_m", "gyro_on")


class ReprocessConflict(Exception):
    """HTTP 409: the stored batches cannot be re-processed now (session changed meanwhile, a stored batch is
    refused by the current engine, or batches are missing). Nothing was changed."""

    def __init__(self, message: str) -> None:
        super().__init__(message)
        self.message = message


@dataclass
class ReprocessResult:
    """What a re-processing did (or would do, for a dry run)."""

    session_id: int
    engine: str
    engine_mode: str
    batches: int
    positions_before: int
    positions_after: int
    events_after: int
    identical: bool
    max_shift_m: float | None
    stored: bool
    reprocess_count: int


def _run(host: EngineHost, session_id: int, mode: str, profile: dict[str, Any] | None, raws: list[Any],
         closed: bool, next_seq: int, spec: Any = None
         ) -> tuple[list[dict[str, Any]], list[dict[str, Any]], dict[str, Any] | None, bytes, str]:
    """Feed the stored batches to a fresh engine (built for the session's ``spec``); returns (position rows,
    event rows, last answer, state, the engine class's name).

    ``profile`` is the session's stored ``profile_in`` (nulls where the engine had NaN), given to the engine in
    its own form as the session's first upload did (the stored form failed with TypeError: HTTP 500).
    """
    engine = host.new(mode, engine_profile_from_stored(profile), spec)
    positions: list[dict[str, Any]] = []
    events: list[dict[str, Any]] = []
    last: dict[str, Any] | None = None

    def take(seq: int, upd: Any) -> None:
        nonlocal last
        d = _update_dict(session_id, seq, seq + 1, upd)
        positions.extend({"session_id": session_id, "seq": seq, **p} for p in d["positions"])
        events.extend({"session_id": session_id, "seq": seq, **e} for e in d["events"])
        last = d

    for row in raws:
        batch = decode_batch(row.raw, MSGPACK_TYPE, 2**62, allow_empty=True)
        try:
            upd = engine.feed(batch)
        except BatchError as exc:
            raise ReprocessConflict(
                f"stored batch {row.seq} is refused by the current engine ({exc.field}: {exc.problem}); nothing was changed"
            ) from None
        take(row.seq, upd)
    if closed:
        take(next_seq, engine.flush())
    cls = type(engine)
    return positions, events, last, pack_state(engine.to_bytes()), f"{cls.__module__}.{cls.__qualname__}"


def _compare(old: list[Any], new: list[dict[str, Any]]) -> tuple[bool, float | None]:
    """(identical, largest 3-D displacement [m] when both have the same positions at the same times)."""
    same_times = len(old) == len(new) and all(int(o.t_ns) == n["t_ns"] for o, n in zip(old, new))
    if not same_times:
        return False, None
    shift = 0.0
    identical = True
    for o, n in zip(old, new):
        d = math.dist((o.north, o.east, o.down), (n["north"], n["east"], n["down"]))
        shift = max(shift, d) if math.isfinite(d) else math.inf
        if any(getattr(o, f) != n[f] for f in _POS_FIELDS):
            identical = False
    return identical, shift


def store_rows(db: Session, positions: list[dict[str, Any]], events: list[dict[str, Any]]) -> None:
    """Insert the new trajectory (inside the caller's transaction)."""
    if positions:
        db.execute(insert(_POSITIONS), positions)
    if events:
        db.execute(insert(_EVENTS), events)


def reprocess_session(
    db: Session, host: EngineHost, user: User, session_id: int, engine_mode: str | None = None, dry_run: bool = False
) -> ReprocessResult | None:
    """Re-run the session of ``user`` through the current engine; None when the user has no such session.

    Parameters
    ----------
    engine_mode : {"auto", "zupt", "pdr"}, optional
        Engine mode of the re-run (default: the session's own); stored as the session's mode.
    dry_run : bool
        Compute and compare only; store nothing.

    Raises
    ------
    ReprocessConflict
        The session changed while it was re-processed, a stored batch is refused by the current engine, or
        stored batches are missing. Nothing is changed then.
    """
    with host.lock(session_id):  # uploads of this session in this process wait; other processes: version check
        sess = db.execute(
            select(_TS.c.version, _TS.c.status, _TS.c.next_seq, _TS.c.engine_mode, _TS.c.profile_in, _TS.c.reprocess_count,
                   _TS.c.device_kind, _TS.c.placement, _TS.c.latitude_deg, _TS.c.longitude_deg, _TS.c.altitude_m,
                   _TS.c.created_at)
            .where(_TS.c.id == session_id, _TS.c.user_id == user.id)
        ).first()
        if sess is None:
            db.rollback()
            return None
        raws = db.execute(
            select(_BATCHES.c.seq, _BATCHES.c.raw).where(_BATCHES.c.session_id == session_id).order_by(_BATCHES.c.seq)
        ).all()
        old = db.execute(
            select(*(getattr(_POSITIONS.c, f) for f in _POS_FIELDS)).where(_POSITIONS.c.session_id == session_id)
            .order_by(_POSITIONS.c.id)
        ).all()
        db.rollback()  # no transaction stays open while the engine runs
        seqs = [r.seq for r in raws]
        if seqs != list(range(sess.next_seq)):
            raise ReprocessConflict(
                f"session {session_id} has {len(seqs)} stored batches but {sess.next_seq} were accepted; cannot re-process"
            )
        mode = engine_mode or sess.engine_mode
        closed = sess.status != "open"
        spec = session_spec(sess.device_kind, sess.placement, sess.latitude_deg, sess.longitude_deg, sess.altitude_m,
                            sess.created_at)
        positions, events, last, state, engine_name = _run(host, session_id, mode, sess.profile_in, raws, closed,
                                                           sess.next_seq, spec)
        identical, shift = _compare(old, positions)
        result = ReprocessResult(
            session_id=session_id, engine=engine_name,
            engine_mode=mode, batches=len(raws), positions_before=len(old), positions_after=len(positions),
            events_after=len(events), identical=identical, max_shift_m=shift, stored=False,
            reprocess_count=sess.reprocess_count,
        )
        if dry_run:
            return result
        values: dict[str, Any] = {
            "version": sess.version + 1, "engine_state": state, "engine_mode": mode, "n_positions": len(positions),
            "reprocessed_at": utcnow(), "reprocess_count": sess.reprocess_count + 1,
        }
        if last is not None:
            values.update(behaviour=last["behaviour"], mode=last["mode"], sensor_config=last["sensor_config"])
        try:
            with host.write_lock:
                res = db.execute(update(_TS).where(_TS.c.id == session_id, _TS.c.version == sess.version).values(**values))
                if res.rowcount != 1:
                    raise ReprocessConflict(
                        f"session {session_id} received a batch or was closed while it was re-processed; nothing was "
                        "changed, retry"
                    )
                db.execute(delete(_POSITIONS).where(_POSITIONS.c.session_id == session_id))
                db.execute(delete(_EVENTS).where(_EVENTS.c.session_id == session_id))
                store_rows(db, positions, events)
                db.commit()
        except BaseException:
            db.rollback()
            raise
        finally:
            host.forget(session_id)  # a cached engine is at the old version (helpers: no longer continued either)
        result.stored = True
        result.reprocess_count = sess.reprocess_count + 1
        return result
