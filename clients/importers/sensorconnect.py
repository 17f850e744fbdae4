"""MicroStrain SensorConnect CSV exports (datasets/gdin formats A and B).

Format A (``scaledAccel*``/``scaledGyro*``/``scaledMag*``): accelerometer in g, gyroscope in rad/s,
magnetometer in gauss (MicroStrain 3DM-GX5 "scaled" channels). Converted: g -> m/s^2 (x 9.80665),
gauss -> uT (x 100). The units are read from the channel names and then checked against the data
(|a| at rest ~1 g, |m| ~0.2-0.7 G): a file whose values contradict its header is rejected, never guessed.

Format B (``estCompensatedAccel*``/``estAngularRate*`` with ``:valid`` flag columns, 250 Hz, no
magnetometer): the sensor's bias-compensated filter outputs, already m/s^2 and rad/s. Rows whose acc/gyro
valid flag is 0 are dropped (logged, noted in the metadata): an invalid estimate must not reach the filter.

Orientation columns (roll/pitch/yaw, est*) are the sensor's own estimates, not truth, and are not imported.
"""

from __future__ import annotations

import logging
import warnings
from pathlib import Path

import numpy as np

from clients.importers._common import (
    G0,
    ImporterError,
    check_finite,
    clean_timestamps,
    make_batch,
    seconds_to_ns,
)
from clients.recording import Recording, RecordingMeta

__all__ = ["sniff", "load", "load_sensorconnect", "read_header"]

log = logging.getLogger(__name__)

GAUSS_TO_UT = 100.0

_A_ACC = ("scaledAccelX", "scaledAccelY", "scaledAccelZ")
_A_GYR = ("scaledGyroX", "scaledGyroY", "scaledGyroZ")
_A_MAG = ("scaledMagX", "scaledMagY", "scaledMagZ")
_B_ACC = ("estCompensatedAccelX", "estCompensatedAccelY", "estCompensatedAccelZ")
_B_GYR = ("estAngularRateX", "estAngularRateY", "estAngularRateZ")


def read_header(path: str | Path) -> list[str]:
    """Channel names of a SensorConnect CSV with the ``inertial-<serial>:`` prefix removed."""
    p = Path(path)
    try:
        with open(p, encoding="utf-8", errors="replace") as fh:
            line = fh.readline()
    except OSError as exc:
        raise ImporterError(p, "file", f"cannot be read ({exc})") from exc
    if not line.strip():
        raise ImporterError(p, "header", "empty file")
    return [c.strip().split(":", 1)[1] if ":" in c else c.strip() for c in line.strip().split(",")]


def sniff(path: str | Path) -> bool:
    """True for a ``.csv`` whose header has SensorConnect format A or B channels."""
    p = Path(path)
    if p.suffix.lower() != ".csv":
        return False
    try:
        cols = read_header(p)
    except ImporterError:
        return False
    return bool(cols) and cols[0] == "Time" and (_A_ACC[0] in cols or _B_ACC[0] in cols)


def load(path: str | Path) -> Recording:
    """Alias of :func:`load_sensorconnect` (uniform importer interface)."""
    return load_sensorconnect(path)


def _index(p: Path, cols: list[str], names: tuple[str, ...]) -> list[int]:
    missing = [n for n in names if n not in cols]
    if missing:
        raise ImporterError(p, missing[0], f"column missing (have: {', '.join(cols)})")
    return [cols.index(n) for n in names]


def load_sensorconnect(path: str | Path, name: str | None = None) -> Recording:
    """Read a SensorConnect CSV (format A or B) into SI units.

    Parameters
    ----------
    path : str or Path
        The CSV file.
    name : str, optional
        Recording name (default: the file stem).

    Returns
    -------
    Recording
        ``batch``: acc [m/s^2], gyr [rad/s] and (format A) mag [uT] in the sensor's body frame, all on the
        file's ``Time`` column [s] converted to int64 ns. ``truth`` is ``None`` (see
        :func:`clients.importers.gdin.load_gdin` for the paired ground truth).

    Raises
    ------
    ImporterError
        Unknown or missing columns, empty file, NaN/inf, non-monotonic/conflicting times, values that
        contradict the header's units.
    """
    p = Path(path)
    cols = read_header(p)
    if not cols or cols[0] != "Time":
        raise ImporterError(p, "Time", f"first column must be 'Time' [s], got {cols[:1]}")
    if _A_ACC[0] in cols:
        fmt = "A"
    elif _B_ACC[0] in cols:
        fmt = "B"
    else:
        raise ImporterError(p, "header", "neither scaledAccel* (format A) nor estCompensatedAccel* (format B) columns")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # "empty input file": reported below as an ImporterError
            data = np.genfromtxt(p, delimiter=",", skip_header=1, dtype=np.float64, invalid_raise=True)
    except ValueError as exc:
        raise ImporterError(p, "rows", f"malformed CSV ({exc})") from exc
    if data.size == 0:
        raise ImporterError(p, "rows", "no samples (empty file)")
    data = np.atleast_2d(data)
    if data.shape[1] != len(cols):
        raise ImporterError(p, "rows", f"{data.shape[1]} values per row but {len(cols)} header columns")
    notes: list[str] = []
    units: dict[str, str] = {}
    if fmt == "A":
        ia, ig, im = _index(p, cols, _A_ACC), _index(p, cols, _A_GYR), _index(p, cols, _A_MAG)
        used = [0] + ia + ig + im
    else:
        ia, ig = _index(p, cols, _B_ACC), _index(p, cols, _B_GYR)
        im = []
        used = [0] + ia + ig
        flags = [cols.index(f"{c}:valid") for c in _B_ACC + _B_GYR if f"{c}:valid" in cols]
        if flags:
            fv = data[:, flags]
            check_finite(p, [cols[i] for i in flags], fv)
            ok = np.all(fv != 0, axis=1)
            if not ok.all():
                msg = f"dropped {int((~ok).sum())} row(s) whose acc/gyro valid flag is 0"
                log.warning("%s: %s", p, msg)
                notes.append(msg)
                data = data[ok]
                if data.shape[0] == 0:
                    raise ImporterError(p, "valid", "no row has valid acc/gyro flags")
    check_finite(p, [cols[i] for i in used], data[:, used])
    t_ns = seconds_to_ns(p, "Time", data[:, 0])
    t_ns, vals, tnotes = clean_timestamps(p, "Time", t_ns, data[:, used[1:]])
    notes += tnotes
    acc, gyr = vals[:, 0:3], vals[:, 3:6]
    mag = vals[:, 6:9] if fmt == "A" else None
    if fmt == "A":
        med_a = float(np.median(np.linalg.norm(acc, axis=1)))
        if not 0.5 <= med_a <= 2.5:
            raise ImporterError(
                p, _A_ACC[0], f"header says g (scaledAccel) but median |a| = {med_a:.3g}; units unclear, refusing to guess"
            )
        acc = acc * G0
        units["acc"] = f"g -> m/s^2 (x {G0})"
        med_m = float(np.median(np.linalg.norm(mag, axis=1)))
        if not 0.05 <= med_m <= 2.0:
            raise ImporterError(
                p, _A_MAG[0], f"header says gauss (scaledMag) but median |m| = {med_m:.3g}; units unclear, refusing to guess"
            )
        mag = mag * GAUSS_TO_UT
        units["mag"] = f"gauss -> uT (x {GAUSS_TO_UT:g})"
    batch = make_batch(p, t_ns, acc, t_ns.copy(), gyr, t_ns.copy() if mag is not None else None, mag)
    meta = RecordingMeta(
        source_format=f"sensorconnect-{fmt.lower()}",
        rate_hz=float(batch.rate_hz("acc")),
        units_converted=units,
        mount="foot (MicroStrain 3DM-GX5-25 on one shoe; body axes of the sensor)",
        notes=tuple(notes),
    )
    return Recording(name=name or p.stem, batch=batch, meta=meta, truth=None)
