"""A session's timeline: what the device sent batch by batch (sensors, rates) and what the engine said (mode,
behaviour), with the energy this cost on the device's power profile (``energy.power``)."""

from __future__ import annotations

import dataclasses
from typing import Any

from fastapi import APIRouter, HTTPException, status
from sqlalchemy.orm import Session

from server import crud
from server.deps import CurrentUser, PathId, SessionDep
from server.formats import MSGPACK_TYPE, decode_batch

__all__ = ["router", "session_timeline"]

router = APIRouter(prefix="/sessions/{session_id}", tags=["trajectories"])

POWER_PROFILES = {"foot": "foot-lsm9ds1", "phone": "phone-bmi270", "watch": "phone-bmi270"}
"""Power profile charged per device kind (energy/profiles/*.json; a watch is charged the phone's IMU)."""


def _rate(n: int, t0: int, t1: int) -> float:
    return (n - 1) / ((t1 - t0) / 1e9) if n > 1 and t1 > t0 else 0.0


def session_timeline(db: Session, sess: Any) -> dict[str, Any]:
    """Per stored batch: time span [ns], samples and observed rate [Hz] of each stream, the gyroscope on (it sent
    samples), the engine's mode and behaviour after it; and the energy (:func:`energy.power.account`) of what
    the device did, or None for a session without batches."""
    from energy.power import (
        REQUEST_OVERHEAD_BYTES,
        SAMPLE_BYTES,
        TIMESTAMP_BYTES,
        Interval,
        Timeline,
        account,
        cost_class,
        load_profile,
    )

    rows = []
    behaviour = "stand"  # what the engine said before each batch (the first: nothing yet)
    for b in crud.batches_of(db, sess.id):
        batch = decode_batch(b.raw, MSGPACK_TYPE, max(b.n_acc, b.n_gyr, b.n_mag, 1))
        spans = {name: batch.stream(name)[0] for name in ("acc", "gyr", "mag")}
        ts = [t for t in spans.values() if t.size]
        if not ts:
            continue
        t0, t1 = min(int(t[0]) for t in ts), max(int(t[-1]) for t in ts)
        resp = b.response or {}
        rows.append({
            "seq": b.seq, "t_start_ns": t0, "t_end_ns": t1, "n_acc": b.n_acc, "n_gyr": b.n_gyr, "n_mag": b.n_mag,
            **{f"{k}_hz": _rate(len(t), int(t[0]), int(t[-1])) if t.size else 0.0 for k, t in spans.items()},
            "gyro_on": b.n_gyr > 0, "mode": resp.get("mode"), "behaviour": resp.get("behaviour"),
            "behaviour_before": behaviour,
        })
        behaviour = resp.get("behaviour") or behaviour
    if not rows:
        return {"session_id": sess.id, "batches": [], "energy": None}
    intervals, samples, batches = [], {}, {}
    for i, r in enumerate(rows):
        end = rows[i + 1]["t_start_ns"] if i + 1 < len(rows) else r["t_end_ns"]
        intervals.append(Interval(r["t_start_ns"] / 1e9, max(end, r["t_start_ns"]) / 1e9, r["acc_hz"], r["gyr_hz"], r["mag_hz"]))
        k = cost_class(r["gyro_on"], r["behaviour_before"])
        samples[k] = samples.get(k, 0) + r["n_acc"]
        batches[k] = batches.get(k, 0) + 1
    steps: dict[str, int] = {}
    for p in crud.positions_of(db, sess.id):
        steps[p.mode] = steps.get(p.mode, 0) + 1
    n = sum(r["n_acc"] + r["n_gyr"] + r["n_mag"] for r in rows)
    timeline = Timeline(intervals, samples, steps, n * (SAMPLE_BYTES + TIMESTAMP_BYTES) + len(rows) * REQUEST_OVERHEAD_BYTES,
                        len(rows), batches)
    prof = load_profile(POWER_PROFILES.get(sess.device_kind, "foot-lsm9ds1"))
    prof = dataclasses.replace(prof, compute=prof.compute.for_engine(sess.engine_mode))
    rep = account(timeline, prof)
    return {"session_id": sess.id, "batches": rows, "energy": {"profile": prof.name, **rep.to_dict()}}


@router.get("/timeline")
def timeline(session_id: PathId, db: SessionDep, user: CurrentUser) -> dict[str, Any]:
    """What the device sent and what the engine said, batch by batch: ``batches`` (``seq``, ``t_start_ns``,
    ``t_end_ns``, ``n_acc``/``n_gyr``/``n_mag``, observed ``acc_hz``/``gyr_hz``/``mag_hz``, ``gyro_on``, the
    engine's ``mode`` and ``behaviour`` after the batch) and ``energy``: the device's energy on its power profile
    (sensors at the rates they ran, computation per navigation mode, radio) [mJ]; null without batches."""
    sess = crud.get_session(db, user, session_id)
    if sess is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"session {session_id} not found")
    return session_timeline(db, sess)
