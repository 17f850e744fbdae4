"""Sensor Logger (Android/iOS app) HTTP push ingest.

The app POSTs ``{messageId, sessionId, deviceId, payload: [{name, time, values: {x, y, z}}]}`` with UTC epoch
ns times; messages may arrive out of order and more than once. Each message is stored (deduplicated by
``messageId``); samples are held back ``sensorlogger_hold_s`` behind the newest time seen and then fed to the
session's engine in time order as ordinary sequenced batches (stored raw like any other batch). Samples that
arrive behind what was already fed are counted as late and dropped.

A push is taken whole or not at all: every refusal (4xx) stores nothing, and a message is stored (durably,
committed) before it is answered 2xx. A message is checked on its own as the engine will take it (finite
values, units; its ``accelerometer`` samples need ``gravity`` samples of the same message, since Sensor
Logger's accelerometer excludes gravity) and then together with the held-back samples it is fed with: when
its samples make that window unusable it is refused (422) and the window waits for the next push. Should the
held-back samples of messages already accepted be unusable together without it (values in another unit
in part of a message whose median passed), that window is skipped so that the session goes on: the push is
still taken, and its answer says how many samples were skipped and why (``skipped_samples``, ``skipped``);
they stay stored with their messages.

A push that meets a database busy beyond its retries while it stores its message is refused with 503 and
``Retry-After`` (nothing stored; the app may send it again); one that meets it while it feeds (the message is
stored) is answered 200 with ``deferred`` saying so, and a later push or the flush feeds those samples.

Pushes of one session may arrive at once (the app sends a message per interval and retries; several workers):
each stores its message holding the session's write lock, so it is checked against the watermark and messages
as they are, and then feeds what is held back read afresh, a piece written only if nothing it was read from
changed meanwhile (else read again). So a push is never answered 4xx after its message was stored, and no sample
is fed twice.

Sessions: a push with no sensor samples (the app's connection test, an empty interval) creates nothing and
stores nothing. The first push with samples of a new app ``sessionId`` starts a session; a new ``sessionId`` from
the same ``deviceId`` means the app stopped its previous recording, whose session is then flushed and closed.
A session that received no push for ``PEDNAV_SENSORLOGGER_IDLE_CLOSE_S`` (default 300 s) is flushed and closed by
the server (the app sends nothing when its recording stops): :func:`close_idle_sessions`. Repeated
``messageId`` values are applied once. The app's ``location`` stream anchors the session: the first fix whose
``horizontalAccuracy`` is at most ``PEDNAV_ANCHOR_MAX_ACCURACY_M`` (default 25 m) sets its latitude, longitude,
altitude (WGS-84, the app's ``altitude``), accuracy and date (``models.geo.anchor_from_fixes``), unless the
session already has an anchor.

The app cannot obey the sensor configuration the server answers (gyroscope off, lower rates): it records what
its own settings say. The Python SDK (``clients.sdk``, ``clients.simulators``) uploads batches to
``PUT /v1/sessions/{id}/batches/{seq}`` and applies the ``sensor_config`` of each answer to the next batch.

Point the app at ``http://HOST:PORT/v1/sensorlogger?token=TOKEN`` (or send ``Authorization: Bearer``). This push
is the only route that takes ``?token=`` (the app cannot set headers); every other route, the flush below
included, refuses it with 401 (URLs end up in access logs). Give the app a token of its own (``POST /v1/tokens``
with a label), so it can be revoked alone.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from typing import Annotated, Any

import numpy as np
from fastapi import APIRouter, HTTPException, Path, status
from pydantic import AfterValidator
from sqlalchemy import func, select, update
from sqlalchemy.exc import IntegrityError, OperationalError

from models.batch import BatchError, SensorBatch
from server import crud
from server.deps import CurrentUser, HostDep, SensorLoggerUser, SessionDep, SettingsDep
from server.formats import PayloadTooLarge
from server.ingest import (
    IngestConflict,
    StorageBusy,
    apply_batch,
    close_session,
    engine_profile_in,
    is_contention,
    json_safe,
)
from server.models import SensorLoggerLink, SensorLoggerMessage, TrackSession, User, utcnow
from server.schemas import SensorLoggerPush, check_text
from server.statecodec import pack_state

__all__ = ["router", "samples_to_batch", "location_fixes", "close_idle_sessions", "close_link_session"]

router = APIRouter(prefix="/sensorlogger", tags=["sensorlogger"])

SlSessionPath = Annotated[str, Path(min_length=1, max_length=100, json_schema_extra={"pattern": r"^[^\x00-\x1f\x7f]*$"}),
                          AfterValidator(check_text)]
"""A Sensor Logger ``sessionId`` in the path: as the push's field (a NUL reached PostgreSQL: HTTP 500)."""

_NAMES = {"accelerometer", "totalacceleration", "gravity", "gyroscope", "magnetometer"}


def _stream(items: list[dict[str, Any]], name: str) -> tuple[np.ndarray, np.ndarray]:
    rows = [(int(it["time"]), float(it["values"]["x"]), float(it["values"]["y"]), float(it["values"]["z"]))
            for it in items if it["name"] == name]
    if not rows:
        return np.zeros(0, dtype=np.int64), np.zeros((0, 3))
    a = np.array(rows, dtype=object)
    t = a[:, 0].astype(np.int64)
    v = a[:, 1:].astype(np.float64)
    t, idx = np.unique(t, return_index=True)  # sorted, duplicates dropped
    return t, v[idx]


def samples_to_batch(items: list[dict[str, Any]]) -> SensorBatch:
    """Sensor Logger samples -> SensorBatch (specific force with gravity, rad/s, uT).

    ``totalacceleration`` is the specific force; ``accelerometer`` in Sensor Logger excludes gravity, so
    without ``totalacceleration`` it is used only together with ``gravity`` (summed, nearest gravity sample).
    """
    t_tot, v_tot = _stream(items, "totalacceleration")
    t_acc, v_acc = _stream(items, "accelerometer")
    t_grav, v_grav = _stream(items, "gravity")
    if t_tot.size:
        acc_t, acc = t_tot, v_tot
    elif t_acc.size and t_grav.size:
        j = np.clip(np.searchsorted(t_grav, t_acc), 0, t_grav.size - 1)
        jm = np.clip(j - 1, 0, t_grav.size - 1)
        j = np.where(np.abs(t_grav[jm] - t_acc) < np.abs(t_grav[j] - t_acc), jm, j)
        acc_t, acc = t_acc, v_acc + v_grav[j]
    elif t_acc.size:
        raise BatchError(
            "payload.accelerometer",
            "Sensor Logger's 'accelerometer' excludes gravity; enable TotalAcceleration (or Gravity) in the app",
        )
    else:
        acc_t, acc = np.zeros(0, dtype=np.int64), np.zeros((0, 3))
    g_t, g = _stream(items, "gyroscope")
    m_t, m = _stream(items, "magnetometer")
    return SensorBatch(acc_t_ns=acc_t, acc=acc, gyr_t_ns=g_t, gyr=g, mag_t_ns=m_t, mag=m)


def location_fixes(payload: list[Any]) -> list[Any]:
    """The ``location`` items of a push as :class:`models.geo.Fix` (time order). Sensor Logger's fields:
    ``latitude``, ``longitude`` [deg], ``altitude`` [m, WGS-84], ``horizontalAccuracy`` [m]. An item without a
    numeric latitude and longitude is no fix and is left out (the push's sensor samples are still taken); a
    missing accuracy makes a fix that never anchors."""
    from models.geo import Fix

    def num(v: dict[str, Any], k: str) -> float | None:
        x = v.get(k, v.get(k.lower()))
        return float(x) if isinstance(x, (int, float)) and not isinstance(x, bool) and abs(x) < 1e300 else None

    fixes = []
    for it in payload:
        if it.name.lower() != "location":
            continue
        lat, lon = num(it.values, "latitude"), num(it.values, "longitude")
        if lat is None or lon is None:
            continue
        fixes.append(Fix(int(it.time), lat, lon, num(it.values, "altitude"), num(it.values, "horizontalAccuracy")))
    return sorted(fixes, key=lambda f: f.t_ns)


def _anchor_from(db: SessionDep, session_id: int, fixes: list[Any], max_accuracy_m: float) -> None:
    """Anchor the session at the first good fix unless it has an anchor (in the caller's transaction)."""
    from models.geo import anchor_from_fixes

    if not fixes:
        return
    sess = db.get(TrackSession, session_id)
    if sess is None or sess.latitude_deg is not None:
        return
    a = anchor_from_fixes(fixes, max_accuracy_m, source="location")
    if a is None:
        return
    sess.latitude_deg, sess.longitude_deg, sess.altitude_m = a.latitude_deg, a.longitude_deg, a.altitude_m
    sess.anchor_date, sess.anchor_accuracy_m, sess.anchor_source = a.date, a.accuracy_m, a.source


_FLOAT_MAX = int(np.finfo(np.float64).max)
_I64_MAX = int(np.iinfo(np.int64).max)
_SL_NAME = {"gyr": "gyroscope", "mag": "magnetometer"}
_UNIT_CHECK_MIN = 10  # SensorBatch.validate checks units on streams of at least this many samples


def _acc_name(items: Any) -> str:
    """The sensor whose samples make the acceleration stream of ``items`` (samples of one or more messages)."""
    return "totalacceleration" if any(it["name"] == "totalacceleration" for it in items) else "accelerometer"


def _refusal(exc: BatchError, acc_name: str, suffix: str = "") -> BatchError:
    """A batch's refusal named by the Sensor Logger sensor (``payload.gyroscope`` for ``gyr``)."""
    stream = exc.field.removesuffix("_t_ns")
    return BatchError(f"payload.{_SL_NAME.get(stream, acc_name)}", exc.problem + suffix)


def _check_size(items: list[dict[str, Any]], limit: int) -> None:
    """413 (nothing stored) for a message with more than ``limit`` samples of one sensor (``max_samples_per_stream``,
    the limit of an uploaded batch, which pushes escaped: their windows reached the engine as batches of any size)."""
    counts: dict[str, int] = {}
    for it in items:
        counts[it["name"]] = counts.get(it["name"], 0) + 1
    for name, n in sorted(counts.items()):
        if n > limit:
            raise PayloadTooLarge(f"payload.{name}: {n} samples exceed the limit of {limit} per stream and message")


def _check_samples(items: list[dict[str, Any]]) -> None:
    """Refuse (422, nothing stored) a push whose own samples the engine would refuse: non-finite values,
    implausible units (a gyroscope in deg/s, a magnetometer in gauss), or ``accelerometer`` samples without
    ``gravity`` (or ``totalacceleration``) samples in the same message.

    Units are checked on every stream of the message, also on one of fewer than ten samples (on its samples
    repeated to ten: same median, same peak), which ``SensorBatch.validate`` leaves alone: a few such samples
    per message were taken, and once the held-back samples of several messages were fed together they made
    that window, and every later one that still held them, fail with 422. For the same reason accelerometer
    samples are paired only with the gravity samples of their own message (those of a message without any
    were taken, and the next push that fed them answered 422 after its own message was stored).
    """
    batch = samples_to_batch(items)  # BatchError payload.accelerometer: no gravity in this message
    acc_name = _acc_name(items)
    try:
        batch.validate()
        small = {}
        for name in ("acc", "gyr", "mag"):
            t, v = batch.stream(name)
            if 0 < t.size < _UNIT_CHECK_MIN:
                reps = -(-_UNIT_CHECK_MIN // t.size)
                small[f"{name}_t_ns"] = np.arange(t.size * reps, dtype=np.int64)
                small[name] = np.tile(v, (reps, 1))
        if small:
            SensorBatch(**small).validate()
    except BatchError as exc:
        raise _refusal(exc, acc_name) from None


def _message_batch(payload: list[dict[str, Any]]) -> SensorBatch:
    """A stored message's samples as the engine takes them (accelerometer paired with its own message's gravity;
    messages stored before that was checked lose only their unpaired accelerometer samples)."""
    try:
        return samples_to_batch(payload)
    except BatchError:
        return samples_to_batch([it for it in payload if it["name"] != "accelerometer"])


def _window(msgs: list[SensorLoggerMessage], lo_ns: int, hi_ns: int) -> SensorBatch:
    """The held-back samples of ``msgs`` with ``lo_ns < time <= hi_ns``, in time order (a time present in several
    messages: the oldest message's sample)."""
    kw: dict[str, np.ndarray] = {}
    parts = [_message_batch(m.payload) for m in sorted(msgs, key=lambda m: m.id)]
    for name in ("acc", "gyr", "mag"):
        ts, vs = [], []
        for b in parts:
            t, v = b.stream(name)
            k = (t > lo_ns) & (t <= hi_ns)
            ts.append(t[k])
            vs.append(v[k])
        t = np.concatenate(ts) if ts else np.zeros(0, dtype=np.int64)
        v = np.concatenate(vs) if vs else np.zeros((0, 3))
        t, idx = np.unique(t, return_index=True)  # sorted, duplicates dropped
        kw[f"{name}_t_ns"], kw[name] = t, v[idx].reshape(-1, 3)
    return SensorBatch(**kw)


def _pieces(batch: SensorBatch, lo_ns: int, hi_ns: int, limit: int) -> list[tuple[SensorBatch, int]]:
    """The window ``batch`` (samples with ``lo_ns < time <= hi_ns``) cut in time order into pieces of at most
    ``limit`` samples per stream (``max_samples_per_stream``, as any uploaded batch); ``(piece, its end)`` each,
    a piece holding the samples after the previous end up to and including its own."""
    out: list[tuple[SensorBatch, int]] = []
    start = lo_ns
    while True:
        ends = []
        for name in ("acc", "gyr", "mag"):
            t, _ = batch.stream(name)
            i = int(np.searchsorted(t, start, side="right"))
            if t.size - i > limit:
                ends.append(int(t[i + limit - 1]))
        if not ends:
            out.append((batch.time_slice(start + 1, None) if start > lo_ns else batch, hi_ns))
            return out
        end = min(ends)
        out.append((batch.time_slice(start + 1, end + 1 if end < _I64_MAX else None), end))
        start = end


def _window_problem(pieces: list[tuple[SensorBatch, int]]) -> BatchError | None:
    """The first refusal of a piece of a window, or None."""
    for piece, _ in pieces:
        try:
            piece.validate()
        except BatchError as exc:
            return exc
    return None


def _link(db: SessionDep, user: User, push: SensorLoggerPush, settings: Any, host: Any) -> tuple[SensorLoggerLink, bool]:
    """The link of the push's Sensor Logger session and whether this call made it; a new one (and its session) is
    flushed, not committed: it is stored with the push's message or not at all."""
    link = db.execute(
        select(SensorLoggerLink).where(SensorLoggerLink.user_id == user.id, SensorLoggerLink.sl_session_id == push.sessionId)
    ).scalar_one_or_none()
    if link is not None:
        return link, False
    profile = engine_profile_in(db, user)
    engine = host.new(settings.engine_mode, profile)
    sess = crud.create_session(  # the foot engine: a Sensor Logger phone is strapped to a shoe (placement "foot")
        db, user, device_kind="phone", placement="foot", engine_mode=settings.engine_mode, profile_in=json_safe(profile),
        engine_state=pack_state(engine.to_bytes()), sensor_config=engine.sensor_config.to_dict(),
    )
    link = SensorLoggerLink(user_id=user.id, sl_session_id=push.sessionId, device_id=push.deviceId, session_id=sess.id,
                            watermark_ns=0, late_samples=0, last_push_at=utcnow())
    db.add(link)
    try:
        db.flush()
    except IntegrityError:  # a concurrent first push of this session created it (was HTTP 500): take that one
        db.rollback()
        return db.execute(select(SensorLoggerLink).where(
            SensorLoggerLink.user_id == user.id, SensorLoggerLink.sl_session_id == push.sessionId)).scalar_one(), False
    return link, True


def _unfed(db: SessionDep, link: SensorLoggerLink) -> list[SensorLoggerMessage]:
    return list(db.execute(
        select(SensorLoggerMessage).where(
            SensorLoggerMessage.session_id == link.session_id, SensorLoggerMessage.t_max_ns > link.watermark_ns
        )
    ).scalars())


_FEED_ATTEMPTS = 10  # pieces read again in a row after other pushes or flushes of the session changed them


class _Moved(Exception):
    """The held-back samples of a piece changed between its read and its write: read again."""


def _lock_session(db: SessionDep, session_id: int) -> None:
    """Take the session's write lock before this transaction reads anything (held until it ends).

    A no-op update holds the session row on PostgreSQL (as ``SELECT ... FOR UPDATE``) and, as the transaction's
    first write, the database's write lock on SQLite (``BEGIN IMMEDIATE``): pushes of one session store their
    messages one at a time, each checked against the watermark and messages as they are.
    """
    ts = TrackSession.__table__
    db.execute(update(ts).where(ts.c.id == session_id).values(status=ts.c.status))


def _feed(db: SessionDep, user: User, link_id: int, host: Any, limit: int,
          hold_ns: int | None) -> tuple[list[dict[str, Any]], str | None, dict[str, Any], Exception | None]:
    """Feed the held-back samples up to the horizon (``hold_ns`` behind the newest sample stored; None: all) as
    sequenced batches of at most ``limit`` samples per stream, each moving the watermark to its end in its own
    write transaction (fed samples are never fed again); a piece the engine would refuse is skipped instead
    (watermark moved, nothing fed). Returns (new positions, the last behaviour or None, ``{"skipped_samples",
    "skipped"}``, None or the error of a busy database that stopped the feed: the pieces before are fed, that
    piece and those after it are not, the watermark is at its start).

    Pushes and flushes of one session may feed at once (also in other workers). Each piece is read afresh
    (watermark, next sequence number, unfed messages) and written only if, in its write transaction, the
    watermark and the unfed messages are still those it was read from and its sequence number is still free;
    else it is read again (another push fed it, or stored samples into it). Raises :class:`IngestConflict`
    when there is something to feed and the session is closed.
    """
    positions: list[dict[str, Any]] = []
    behaviour = None
    skipped: dict[str, Any] = {"skipped_samples": 0, "skipped": None}
    uid = user.id
    moved = 0
    busy: Exception | None = None
    while moved < _FEED_ATTEMPTS:
        # the sequence number before the watermark: a piece read after another push's write then carries a used
        # number (refused by apply_batch before the engine sees it), never a free one with samples already fed
        sess = db.execute(
            select(TrackSession.next_seq, TrackSession.status)
            .join(SensorLoggerLink, SensorLoggerLink.session_id == TrackSession.id).where(SensorLoggerLink.id == link_id)
        ).first()
        link = db.get(SensorLoggerLink, link_id, populate_existing=True)
        if link is None or sess is None:  # the session was deleted
            db.rollback()
            break
        sid, lo_ns = link.session_id, link.watermark_ns
        if hold_ns is None:
            horizon = _I64_MAX
        else:
            newest = db.execute(select(func.max(SensorLoggerMessage.t_max_ns))
                                .where(SensorLoggerMessage.session_id == sid)).scalar_one()
            horizon = int(newest - hold_ns)
        unfed = _unfed(db, link) if horizon > lo_ns else []
        pieces = _pieces(_window(unfed, lo_ns, horizon), lo_ns, horizon, limit) if unfed else []
        piece, end_ns = next(((p, e) for p, e in pieces if not p.is_empty), (None, horizon))
        if piece is None:
            db.rollback()
            break
        if sess.status != "open":
            db.rollback()
            raise IngestConflict(f"session {sid} is closed; no more batches accepted", sess.next_seq)
        acc_name = _acc_name(it for m in unfed for it in m.payload)
        db.rollback()  # the write transaction starts afresh

        def advance(tx: Any, lo_ns: int = lo_ns, end_ns: int = end_ns, n_unfed: int = len(unfed), sid: int = sid) -> None:
            # in the piece's write transaction: the watermark and the unfed messages still those it was read from
            res = tx.execute(update(SensorLoggerLink).where(
                SensorLoggerLink.id == link_id, SensorLoggerLink.watermark_ns == lo_ns).values(watermark_ns=end_ns))
            n_now = tx.execute(select(func.count()).select_from(SensorLoggerMessage).where(
                SensorLoggerMessage.session_id == sid, SensorLoggerMessage.t_max_ns > lo_ns)).scalar_one()
            if res.rowcount != 1 or n_now != n_unfed:
                raise _Moved()

        try:
            try:
                piece.validate()
            except BatchError as problem:
                with host.write_lock:
                    advance(db)
                    db.commit()
                exc = _refusal(problem, acc_name)
                skipped["skipped_samples"] += int(len(piece.acc_t_ns) + len(piece.gyr_t_ns) + len(piece.mag_t_ns))
                skipped["skipped"] = skipped["skipped"] or {"field": exc.field, "problem": exc.problem}
            else:
                out = apply_batch(db, host, uid, sid, sess.next_seq, piece, also=advance)
                if out is None:  # the session was deleted
                    break
                if not out[1]:  # (a replayed piece was fed by another push, whose answer has its positions)
                    positions += out[0]["positions"]
                    behaviour = out[0]["behaviour"]
            moved = 0
        except (_Moved, IngestConflict):  # another push fed or stored meanwhile (a closed session: raised above)
            db.rollback()
            moved += 1
        except (StorageBusy, OperationalError) as exc:  # apply_batch's attempts, or the skip's one write
            db.rollback()
            if isinstance(exc, OperationalError) and not is_contention(exc):
                raise
            busy = exc  # nothing of this piece committed: it is fed later
            break
    return positions, behaviour, skipped, busy


@contextmanager
def _not_stored_when_busy(db: SessionDep, message_id: int) -> Iterator[None]:
    """A busy database while the push stores its message (its only transaction up to the commit) is a 503: nothing
    is stored, and the same message may be sent again (a message stored already is answered as a duplicate)."""
    try:
        yield
    except OperationalError as exc:
        if not is_contention(exc):
            raise
        db.rollback()
        raise StorageBusy(f"database busy: message {message_id} was NOT stored; send it again") from exc


@router.post("")
def push(body: SensorLoggerPush, db: SessionDep, user: SensorLoggerUser, settings: SettingsDep, host: HostDep) -> dict[str, Any]:
    """Receive one Sensor Logger push message; returns the session and any new positions.

    Taken whole or not at all (see the module docstring): a 4xx stores nothing; a 2xx answers a stored message.
    ``skipped_samples`` / ``skipped`` (``{"field", "problem"}`` or null): held-back samples of messages taken
    earlier that could not be fed together and were left out of the trajectory by this push (they stay stored).
    A database busy beyond its retries: 503 with ``Retry-After`` while the message is stored (nothing stored,
    send it again); once it is stored, the feed is only put off: 200 with ``deferred`` saying so (else null).
    """
    fixes = location_fixes(body.payload)
    items = [it.model_dump() for it in body.payload if it.name.lower() in _NAMES]
    if not items:  # nothing to navigate on (a connection test, an empty interval): nothing is created or stored
        return _sampleless(db, user, body, fixes, settings)
    for it in items:
        it["name"] = it["name"].lower()
        for k in ("x", "y", "z"):
            v = it["values"].get(k)
            if not isinstance(v, (int, float)) or isinstance(v, bool):
                raise BatchError(f"payload.{it['name']}.values.{k}", "missing or not a number")
            if isinstance(v, int) and not -_FLOAT_MAX <= v <= _FLOAT_MAX:
                raise BatchError(f"payload.{it['name']}.values.{k}", "beyond the float64 range")
    _check_size(items, settings.max_samples_per_stream)
    _check_samples(items)
    with _not_stored_when_busy(db, body.messageId):
        link, new_link = _link(db, user, body, settings, host)
        _lock_session(db, link.session_id)  # until the message is committed: concurrent pushes of the session wait
        db.refresh(link)  # the watermark as it is now
        t_max = max((int(it["time"]) for it in items), default=0)
        late = sum(1 for it in items if int(it["time"]) <= link.watermark_ns)
        msg = SensorLoggerMessage(session_id=link.session_id, message_id=body.messageId, t_max_ns=t_max, payload=items)
        db.add(msg)
        try:
            db.flush()
        except IntegrityError:
            db.rollback()
            return {"session_id": link.session_id, "duplicate": True, "late_samples": link.late_samples,
                    "positions": [], "behaviour": None, "skipped_samples": 0, "skipped": None, "deferred": None}
        sess = crud.get_session(db, user, link.session_id)
        if sess is not None and sess.status != "open":  # refused: not stored (it would never be fed)
            db.rollback()
            raise IngestConflict(f"session {link.session_id} is closed; no more batches accepted", sess.next_seq)
        newest = db.execute(
            select(SensorLoggerMessage.t_max_ns).where(SensorLoggerMessage.session_id == link.session_id)
            .order_by(SensorLoggerMessage.t_max_ns.desc()).limit(1)
        ).scalar_one()
        horizon = int(newest - settings.sensorlogger_hold_s * 1e9)
        pieces = None
        if horizon > link.watermark_ns:
            # the window this push feeds, checked before the message is stored: refused when its samples spoil it
            unfed = _unfed(db, link)
            acc_name = _acc_name(it for m in unfed for it in m.payload)
            limit = settings.max_samples_per_stream
            pieces = _pieces(_window(unfed, link.watermark_ns, horizon), link.watermark_ns, horizon, limit)
            problem = _window_problem(pieces)
            if problem is not None and _window_problem(_pieces(
                    _window([m for m in unfed if m.id != msg.id], link.watermark_ns, horizon), link.watermark_ns,
                    horizon, limit)) is None:
                db.rollback()
                raise _refusal(problem, acc_name, " (in the held-back samples this push would feed)")
        if late:
            link.late_samples += late
        link.last_push_at = utcnow()
        _anchor_from(db, link.session_id, fixes, settings.anchor_max_accuracy_m)
        session_id, late_samples = link.session_id, link.late_samples
        db.commit()  # the message is stored before it is answered
    if new_link and body.deviceId:  # a new recording of this device: the app stopped its earlier ones
        _close_earlier_recordings(db, host, user, body, settings)
    positions, behaviour, skipped, busy = [], None, {"skipped_samples": 0, "skipped": None}, None
    if pieces is not None:  # this push moved the horizon: feed up to it (read again: other pushes may feed too)
        try:
            positions, behaviour, skipped, busy = _feed(db, user, link.id, host, settings.max_samples_per_stream,
                                                        int(settings.sensorlogger_hold_s * 1e9))
        except IngestConflict:  # closed after the message was stored: it is kept, and answered as stored
            pass
    # the message is stored: a busy database only defers the feed (a 503 would say it was not stored)
    deferred = None if busy is None else (
        "database busy: held-back samples not fed yet; this message is stored, a later push or the flush feeds them")
    return {"session_id": session_id, "duplicate": False, "late_samples": late_samples,
            "positions": positions, "behaviour": behaviour, **skipped, "deferred": deferred}


def _sampleless(db: SessionDep, user: User, body: SensorLoggerPush, fixes: list[Any], settings: Any) -> dict[str, Any]:
    """A push without sensor samples: creates no session and stores no message; its location fixes may anchor the
    session of its app session when that exists."""
    link = db.execute(select(SensorLoggerLink).where(
        SensorLoggerLink.user_id == user.id, SensorLoggerLink.sl_session_id == body.sessionId)).scalar_one_or_none()
    if link is not None and fixes:
        _anchor_from(db, link.session_id, fixes, settings.anchor_max_accuracy_m)
        db.commit()
    return {"session_id": None if link is None else link.session_id, "duplicate": False,
            "late_samples": 0 if link is None else link.late_samples, "positions": [], "behaviour": None,
            "skipped_samples": 0, "skipped": None, "deferred": None, "empty": True}


def close_link_session(db: SessionDep, host: Any, link_id: int, settings: Any) -> int | None:
    """Feed every held-back sample of a Sensor Logger link's session and close it; returns the session id when
    this call closed it (None: gone, or already closed)."""
    link = db.get(SensorLoggerLink, link_id)
    if link is None:
        return None
    user = db.get(User, link.user_id)
    sess = db.get(TrackSession, link.session_id)
    if user is None or sess is None or sess.status != "open":
        db.rollback()
        return None
    db.expunge(user)
    sid = sess.id
    db.rollback()
    try:
        _feed(db, user, link_id, host, settings.max_samples_per_stream, None)
    except IngestConflict:  # closed meanwhile
        return None
    closed = close_session(db, host, user, sid, keep_versions=settings.max_profile_versions)
    return sid if closed is not None and closed.status == "closed" else None


def _close_earlier_recordings(db: SessionDep, host: Any, user: User, body: SensorLoggerPush, settings: Any) -> None:
    rows = db.execute(
        select(SensorLoggerLink.id).join(TrackSession, TrackSession.id == SensorLoggerLink.session_id).where(
            SensorLoggerLink.user_id == user.id, SensorLoggerLink.device_id == body.deviceId,
            SensorLoggerLink.sl_session_id != body.sessionId, TrackSession.status == "open")).scalars().all()
    db.rollback()
    for link_id in rows:
        close_link_session(db, host, link_id, settings)


def close_idle_sessions(sessionmaker: Any, host: Any, settings: Any, now: Any = None) -> list[int]:
    """Flush and close every open Sensor Logger session whose last push is older than
    ``settings.sensorlogger_idle_close_s``; returns the ids closed. Run periodically by the app (``create_app``)."""
    from datetime import timedelta

    if settings.sensorlogger_idle_close_s <= 0:
        return []
    cutoff = (now or utcnow()) - timedelta(seconds=settings.sensorlogger_idle_close_s)
    closed = []
    with sessionmaker() as db:
        ids = db.execute(
            select(SensorLoggerLink.id).join(TrackSession, TrackSession.id == SensorLoggerLink.session_id).where(
                TrackSession.status == "open", SensorLoggerLink.last_push_at.is_not(None),
                SensorLoggerLink.last_push_at < cutoff)).scalars().all()
        db.rollback()
        for link_id in ids:
            sid = close_link_session(db, host, link_id, settings)
            if sid is not None:
                closed.append(sid)
    return closed


@router.post("/{sl_session_id}/flush")
def flush(sl_session_id: SlSessionPath, db: SessionDep, user: CurrentUser, host: HostDep, settings: SettingsDep) -> dict[str, Any]:
    """Feed every held-back sample of a Sensor Logger session now (call before closing the session).
    ``skipped_samples`` / ``skipped`` as for the push. A database busy beyond its retries: 503 with
    ``Retry-After`` (the pieces fed before stay fed; call the flush again)."""
    link = db.execute(
        select(SensorLoggerLink).where(SensorLoggerLink.user_id == user.id, SensorLoggerLink.sl_session_id == sl_session_id)
    ).scalar_one_or_none()
    if link is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"Sensor Logger session {sl_session_id!r} not found")
    positions, _, skipped, busy = _feed(db, user, link.id, host, settings.max_samples_per_stream, None)
    if busy is not None:  # a flush is called to feed everything (before a close): refused, to be called again
        raise StorageBusy(f"database busy: the held-back samples of Sensor Logger session {sl_session_id!r} were "
                          "not all fed (those fed are kept); call the flush again") from busy
    return {"session_id": link.session_id, "positions": positions, **skipped}
