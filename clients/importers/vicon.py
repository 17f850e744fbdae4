"""University of Toronto VICON trials (pyshoe format, datasets/vicon/ABOUT.md).

Each ``.mat`` holds ``imu`` (N x 6: specific force [m/s^2] then angular rate [rad/s], body z axis down),
``ts`` (1 x N, [s]) and ``gt`` (N x 3, Vicon foot position [m], z up) on the same timestamps. The files are
already SI: no unit is converted. The ``zv_*``/``G_*``/``trial_error`` fields are per-trial oracles and are
deliberately NOT imported into the recording (nothing downstream may read them).

A file with ``imu`` and ``ts`` but no ``gt`` (the same IMU log without the Vicon capture) is a recording
without truth: :func:`load` reads it and notes that the truth is missing; :func:`load_vicon`, which
``pednav eval vicon`` uses, refuses it by default, saying that the ground truth the ARMSE needs is missing.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import scipy.io as sio

from clients.importers._common import (
    ImporterError,
    clean_stream,
    drop_untimed_rows,
    gap_notes,
    gyro_unit,
    make_batch,
    seconds_to_ns,
)
from clients.recording import Recording, RecordingMeta, Truth

__all__ = ["FORMAT", "sniff", "load", "load_vicon"]

FORMAT = "University of Toronto VICON .mat (variables imu, ts[, gt])"

_IMU_COLUMNS = ["imu[:,0] acc_x", "imu[:,1] acc_y", "imu[:,2] acc_z", "imu[:,3] gyr_x", "imu[:,4] gyr_y", "imu[:,5] gyr_z"]


def sniff(path: str | Path) -> bool:
    """True when ``path`` is a ``.mat`` file with the VICON variables ``imu`` and ``ts`` (``gt`` optional)."""
    p = Path(path)
    if p.suffix.lower() != ".mat":
        return False
    try:
        names = {n for n, _, _ in sio.whosmat(p)}
    except Exception:  # noqa: BLE001 - not a readable MATLAB file
        return False
    return {"imu", "ts"} <= names and "imu_data" not in names


def load(path: str | Path) -> Recording:
    """:func:`load_vicon` as a recording (uniform importer interface): a file without ``gt`` loads without truth."""
    return load_vicon(path, require_truth=False)


def load_vicon(path: str | Path, require_truth: bool = True) -> Recording:
    """Read one VICON trial.

    Parameters
    ----------
    path : str or Path
        The trial's ``.mat`` file.
    require_truth : bool
        Refuse a file without ``gt`` (default: an evaluation trial needs it); False: load it with
        ``truth=None`` and a note.

    Returns
    -------
    Recording
        ``batch``: acc [m/s^2] and gyr [rad/s] in the sensor's body frame (z down) on the ``ts`` clock
        converted to int64 ns; no magnetometer. ``truth.positions``: Vicon positions [m] per sample in the
        capture frame (x, y horizontal, z UP), ``truth.t_ns`` = the same timestamps (samples whose position
        is not finite, e.g. an occluded marker, are left out of the truth and noted).

    Raises
    ------
    ImporterError
        Missing variables, wrong shapes, empty, non-monotonic times, too few finite samples (the sample
        policy of :mod:`clients.importers._common`).
    """
    p = Path(path)
    try:
        d = sio.loadmat(p)
    except Exception as exc:  # noqa: BLE001 - scipy raises several types for broken files
        raise ImporterError(p, "file", f"not a readable MATLAB file ({exc})") from exc
    for key in ("imu", "ts"):
        if key not in d:
            raise ImporterError(p, key, "variable missing (not a University of Toronto VICON trial)")
    if "gt" not in d and require_truth:
        raise ImporterError(p, "gt", "variable missing: the file has the IMU log (imu, ts) but not the Vicon "
                            "positions the trial is evaluated against; without ground truth it can be replayed "
                            "(pednav replay), not evaluated")
    imu = np.asarray(d["imu"], dtype=np.float64)
    ts = np.asarray(d["ts"], dtype=np.float64).reshape(-1)
    gt = np.asarray(d["gt"], dtype=np.float64) if "gt" in d else None
    if imu.ndim != 2 or imu.shape[1] != 6:
        raise ImporterError(p, "imu", f"expected N x 6 (acc m/s^2, gyro rad/s), got shape {imu.shape}")
    if imu.shape[0] == 0:
        raise ImporterError(p, "imu", "no samples (empty)")
    if ts.size != imu.shape[0]:
        raise ImporterError(p, "ts", f"{ts.size} timestamps for {imu.shape[0]} imu rows")
    if gt is not None and gt.shape != (imu.shape[0], 3):
        raise ImporterError(p, "gt", f"expected {imu.shape[0]} x 3 positions, got shape {gt.shape}")
    keep, notes = drop_untimed_rows(p, "ts", ts)
    imu, ts = imu[keep], ts[keep]
    t_all = seconds_to_ns(p, "ts", ts)
    acc_t, acc, n1 = clean_stream(p, "ts", _IMU_COLUMNS[:3], t_all, imu[:, :3])
    gyr_t, gyr, n2 = clean_stream(p, "ts", _IMU_COLUMNS[3:], t_all, imu[:, 3:])
    notes += n1 + n2
    truth = None
    if gt is not None:
        # truth: Vicon loses the marker now and then (occlusion); such samples are simply not compared
        gt_t, gt_v, n3 = clean_stream(p, "ts", ["gt x", "gt y", "gt z"], t_all, gt[keep])
        notes += n3
        truth = Truth(t_ns=gt_t, positions=gt_v,
                      extra={"frame": "vicon capture frame: x, y horizontal, z up (right-handed)"})
    else:
        notes.append("gt: variable missing: no Vicon ground truth, recording loaded without truth")
    gyro_unit(p, _IMU_COLUMNS[3], acc_t, acc, gyr_t, gyr, "rad/s", "the format (imu: acc m/s^2, gyro rad/s)")
    batch = make_batch(p, acc_t, acc, gyr_t, gyr)
    notes += gap_notes(p, batch)
    meta = RecordingMeta(
        source_format="vicon-mat",
        rate_hz=float(batch.rate_hz("acc")),
        units_converted={},
        mount="foot (University of Toronto VICON set: body z axis down at rest)",
        notes=tuple(notes),
    )
    return Recording(name=p.stem, batch=batch, meta=meta, truth=truth)
