"""A gyroscope in deg/s while the foot stands still is refused (422 naming ``gyr``); physically possible data
never is: rad/s standing with a zero-rate offset, turning on the spot, every 1-s batch of the real recordings."""

from __future__ import annotations

import numpy as np
import pytest

from models.batch import BatchError, SensorBatch
from server.formats import MSGPACK_TYPE, encode_msgpack
from server.plausibility import STILL_GYRO, StillGyroCheck
from tests.server.conftest import auth, still_batch

T0 = 1_700_000_000_000_000_000


def _with_gyro(b: SensorBatch, gyr: np.ndarray) -> SensorBatch:
    kw = b._kwargs()
    kw["gyr"] = gyr
    return SensorBatch(**kw)


@pytest.mark.parametrize("offset_dps", [(1.0, 0.5, 0.2), (0.0, -2.0, 0.0), (3.0, 3.0, -3.0)])
def test_standing_in_deg_per_s_is_refused_and_in_rad_per_s_taken(offset_dps) -> None:  # type: ignore[no-untyped-def]
    b = still_batch(T0, seed=3)
    rad = b.gyr + np.radians(offset_dps)  # a rad/s gyroscope with this zero-rate offset: physically possible
    STILL_GYRO.check(_with_gyro(b, rad))
    with pytest.raises(BatchError) as e:
        STILL_GYRO.check(_with_gyro(b, np.degrees(rad)))  # the same gyroscope reporting deg/s
    assert e.value.field == "gyr" and "deg/s" in e.value.problem


def test_turning_on_the_spot_is_taken() -> None:
    """A rotation about the vertical leaves gravity where it is: not a unit error, whatever its rate."""
    b = still_batch(T0, seed=4)
    STILL_GYRO.check(_with_gyro(b, b.gyr + np.array([0.0, 0.0, 3.0])))  # 3 rad/s about the vertical (z)


def test_motion_is_left_to_the_engines_check() -> None:
    b = still_batch(T0, seed=5)
    kw = b._kwargs()
    kw["acc"] = kw["acc"] + np.column_stack([3 * np.sin(np.linspace(0, 6, len(kw["acc"])))] + [np.zeros(len(kw["acc"]))] * 2)
    assert STILL_GYRO.examine(SensorBatch(**kw)) is None


def test_parameters_are_validated() -> None:
    with pytest.raises(ValueError, match="min_tilt_rad"):
        StillGyroCheck(min_tilt_rad=0.0)


def test_upload_of_a_standing_batch_in_deg_per_s_is_422_and_stores_nothing(client, make_user) -> None:  # type: ignore[no-untyped-def]
    _, a = make_user()
    sid = client.post("/v1/sessions", json={"device_kind": "foot"}, headers=auth(a)).json()["id"]
    b = still_batch(T0, seed=6)
    bad = _with_gyro(b, np.degrees(b.gyr + np.radians([1.5, -1.0, 0.5])))
    r = client.put(f"/v1/sessions/{sid}/batches/0", content=encode_msgpack(bad), headers={**auth(a), "content-type": MSGPACK_TYPE})
    assert r.status_code == 422 and r.json()["field"] == "gyr" and "deg/s" in r.json()["detail"], r.text
    assert client.get(f"/v1/sessions/{sid}", headers=auth(a)).json()["next_seq"] == 0


@pytest.mark.slow
def test_no_real_recording_is_refused() -> None:
    """Every 1-s batch of every importable recording in PEDNAV_DATA (rad/s after import) passes; the still ones
    converted to deg/s are refused in part (calibrated parts have small zero-rate offsets)."""
    from clients.datasets import dataset_dir
    from clients.importers import list_recordings, load

    files = [f for name in ("vicon", "gdin", "gaitmap-mocap", "gaitmap-mag", "ipin2023-t3-phone")
             if (d := dataset_dir(name)) is not None for f in list_recordings(d)]
    if not files:
        pytest.skip("no dataset found: set PEDNAV_DATA or place ../shared/datasets beside the project")
    batches = still = refused_dps = 0
    for f in files:
        try:
            b = load(f).batch
        except Exception:  # noqa: BLE001 - files the importers do not take are not this test's subject
            continue
        if not len(b.gyr_t_ns):
            continue
        for p in b.split_seconds(1.0):
            batches += 1
            STILL_GYRO.check(p)  # raises on a refusal: none allowed
            if STILL_GYRO.examine(p) is not None:
                still += 1
                try:
                    STILL_GYRO.check(_with_gyro(p, np.degrees(p.gyr)))
                except BatchError:
                    refused_dps += 1
    assert batches > 1000 and still > 50
    assert refused_dps > 0
