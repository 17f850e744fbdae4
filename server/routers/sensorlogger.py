"""Sensor Logger (Android/iOS app) HTTP push ingest.

The app POSTs ``{messageId, sessionId, deviceId, payload: [{name, time, values: {x, y, z}}]}`` with UTC epoch
ns times; messages may arrive out of order and more than once. Each message is stored (deduplicated by
``messageId``); samples are held back ``sensorlogger_hold_s`` behind the newest time seen and then fed to the
session's engine in time order as ordinary sequenced batches (stored raw like any other batch). Samples that
arrive behind what was already fed are counted as late and dropped.

Point the app at ``http://HOST:PORT/v1/sensorlogger?token=TOKEN`` (or send ``Authorization: Bearer``). This push
is the only route that takes ``?token=`` (the app cannot set headers); every other route, the flush below
included, refuses it with 401 (URLs end up in access logs). Give the app a token of its own (``POST /v1/tokens``
with a label), so it can be revoked alone.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from fastapi import APIRouter, HTTPException, status
from sqlalchemy import select, update
from sqlalchemy.exc import IntegrityError

from models.batch import BatchError, SensorBatch
from server import crud
from server.deps import CurrentUser, HostDep, SensorLoggerUser, SessionDep, SettingsDep
from server.ingest import IngestConflict, apply_batch, engine_profile_in, json_safe
from server.models import SensorLoggerLink, SensorLoggerMessage, User
from server.schemas import SensorLoggerPush
from server.statecodec import pack_state

__all__ = ["router", "samples_to_batch"]

router = APIRouter(prefix="/sensorlogger", tags=["sensorlogger"])

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


_FLOAT_MAX = int(np.finfo(np.float64).max)
_SL_NAME = {"gyr": "gyroscope", "mag": "magnetometer"}


def _check_samples(items: list[dict[str, Any]]) -> None:
    """Refuse (422, nothing stored) a push whose own samples the engine would refuse: non-finite values or
    implausible units (a gyroscope in deg/s, a magnetometer in gauss).

    A message is stored before its samples are fed, and every later push feeds the held-back samples of all
    stored messages together: one such message, acknowledged with 200, made every later push of the session
    and its flush fail with 422 for good. (A message with only ``accelerometer`` samples is still taken: its
    samples are used when ``gravity`` or ``totalacceleration`` samples of other messages come with them.)
    """
    try:
        batch = samples_to_batch(items)
        acc_name = "totalacceleration" if any(it["name"] == "totalacceleration" for it in items) else "accelerometer"
    except BatchError as exc:
        if exc.field != "payload.accelerometer":
            raise
        batch = samples_to_batch([it for it in items if it["name"] != "accelerometer"])
        acc_name = "totalacceleration"
    try:
        batch.validate()
    except BatchError as exc:
        stream = exc.field.removesuffix("_t_ns")
        raise BatchError(f"payload.{_SL_NAME.get(stream, acc_name)}", exc.problem) from None


def _link(db: SessionDep, user: User, push: SensorLoggerPush, settings: Any, host: Any) -> SensorLoggerLink:
    link = db.execute(
        select(SensorLoggerLink).where(SensorLoggerLink.user_id == user.id, SensorLoggerLink.sl_session_id == push.sessionId)
    ).scalar_one_or_none()
    if link is not None:
        return link
    profile = engine_profile_in(db, user)
    engine = host.new(settings.engine_mode, profile)
    sess = crud.create_session(
        db, user, device_kind="phone", engine_mode=settings.engine_mode, profile_in=json_safe(profile),
        engine_state=pack_state(engine.to_bytes()), sensor_config=engine.sensor_config.to_dict(),
    )
    link = SensorLoggerLink(user_id=user.id, sl_session_id=push.sessionId, device_id=push.deviceId, session_id=sess.id)
    db.add(link)
    db.commit()
    return link


def _feed_ready(db: SessionDep, user: User, link: SensorLoggerLink, host: Any, horizon_ns: int) -> dict[str, Any] | None:
    msgs = db.execute(
        select(SensorLoggerMessage).where(
            SensorLoggerMessage.session_id == link.session_id, SensorLoggerMessage.t_max_ns > link.watermark_ns
        )
    ).scalars()
    items = [it for msg in msgs for it in msg.payload if link.watermark_ns < int(it["time"]) <= horizon_ns]
    if not items:
        return None
    batch = samples_to_batch(items)
    if batch.is_empty:
        return None
    batch.validate()
    sess = crud.get_session(db, user, link.session_id)
    assert sess is not None
    link_id, next_seq = link.id, sess.next_seq
    db.rollback()

    def advance(tx: Any) -> None:  # in the batch's own write transaction: fed samples are never fed again
        tx.execute(update(SensorLoggerLink).where(SensorLoggerLink.id == link_id).values(watermark_ns=horizon_ns))

    out = apply_batch(db, host, user.id, link.session_id, next_seq, batch, also=advance)
    return out[0] if out else None


@router.post("")
def push(body: SensorLoggerPush, db: SessionDep, user: SensorLoggerUser, settings: SettingsDep, host: HostDep) -> dict[str, Any]:
    """Receive one Sensor Logger push message; returns the session and any new positions."""
    items = [it.model_dump() for it in body.payload if it.name.lower() in _NAMES]
    for it in items:
        it["name"] = it["name"].lower()
        for k in ("x", "y", "z"):
            v = it["values"].get(k)
            if not isinstance(v, (int, float)) or isinstance(v, bool):
                raise BatchError(f"payload.{it['name']}.values.{k}", "missing or not a number")
            if isinstance(v, int) and not -_FLOAT_MAX <= v <= _FLOAT_MAX:
                raise BatchError(f"payload.{it['name']}.values.{k}", "beyond the float64 range")
    _check_samples(items)
    link = _link(db, user, body, settings, host)
    t_max = max((int(it["time"]) for it in items), default=0)
    late = sum(1 for it in items if int(it["time"]) <= link.watermark_ns)
    db.add(SensorLoggerMessage(session_id=link.session_id, message_id=body.messageId, t_max_ns=t_max, payload=items))
    try:
        db.flush()
    except IntegrityError:
        db.rollback()
        return {"session_id": link.session_id, "duplicate": True, "late_samples": link.late_samples, "positions": [],
                "behaviour": None}
    sess = crud.get_session(db, user, link.session_id)
    if sess is not None and sess.status != "open":  # refused: not stored (it would never be fed)
        db.rollback()
        raise IngestConflict(f"session {link.session_id} is closed; no more batches accepted", sess.next_seq)
    db.commit()
    if late:
        link.late_samples += late
        db.commit()
    newest = db.execute(
        select(SensorLoggerMessage.t_max_ns).where(SensorLoggerMessage.session_id == link.session_id)
        .order_by(SensorLoggerMessage.t_max_ns.desc()).limit(1)
    ).scalar_one()
    horizon = int(newest - settings.sensorlogger_hold_s * 1e9)
    resp = _feed_ready(db, user, link, host, horizon) if horizon > link.watermark_ns else None
    return {"session_id": link.session_id, "duplicate": False, "late_samples": link.late_samples,
            "positions": resp["positions"] if resp else [], "behaviour": resp["behaviour"] if resp else None}


@router.post("/{sl_session_id}/flush")
def flush(sl_session_id: str, db: SessionDep, user: CurrentUser, host: HostDep) -> dict[str, Any]:
    """Feed every held-back sample of a Sensor Logger session now (call before closing the session)."""
    link = db.execute(
        select(SensorLoggerLink).where(SensorLoggerLink.user_id == user.id, SensorLoggerLink.sl_session_id == sl_session_id)
    ).scalar_one_or_none()
    if link is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"Sensor Logger session {sl_session_id!r} not found")
    resp = _feed_ready(db, user, link, host, np.iinfo(np.int64).max)
    return {"session_id": link.session_id, "positions": resp["positions"] if resp else []}
