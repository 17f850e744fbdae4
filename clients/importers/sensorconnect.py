"""MicroStrain SensorConnect CSV exports (datasets/gdin formats A and B).

Format A (``scaledAccel*``/``scaledGyro*``/``scaledMag*``): accelerometer in g, gyroscope in rad/s,
magnetometer in gauss (MicroStrain 3DM-GX5 "scaled" channels). Converted: g -> m/s^2 (x 9.80665),
gauss -> uT (x 100). The units are read from the channel names and then checked against the data
(|a| at rest ~1 g, |m| ~0.2-0.7 G): a file whose values contradict its header is rejected, never guessed.
The magnetometer is optional (a 6-axis export has no ``scaledMag*`` columns; the recording then has no
magnetometer stream and the metadata says so).

Columns are found by name (any order, extra channels ignored; the ``inertial-<node>:`` prefix may carry any
node id or be absent; an export of several nodes in one file is refused, never mixed); the time
column is ``Time`` [s]. Besides SensorConnect's own comma-separated form, a copy saved by a spreadsheet is read:
semicolon (or tab) separated with decimal commas, as European locales write it, and quoted cells. Rows that
cannot be read (a line with another number of fields, e.g. the last line of a logger that was stopped
mid-write) and empty cells follow the sample policy of :mod:`clients.importers._common`: dropped, logged and
noted.

Format B (``estCompensatedAccel*``/``estAngularRate*`` with ``:valid`` flag columns, 250 Hz, no
magnetometer): the sensor's bias-compensated filter outputs, already m/s^2 and rad/s. Rows whose acc/gyro
valid flag is 0 are dropped (logged, noted in the metadata): an invalid estimate must not reach the filter.

Orientation columns (roll/pitch/yaw, est*) are the sensor's own estimates, not truth, and are not imported.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from clients.importers._common import (
    G0,
    ImporterError,
    clean_stream,
    csv_fields,
    drop_untimed_rows,
    first_line,
    gap_notes,
    gyro_unit,
    make_batch,
    read_csv_rows,
    seconds_to_ns,
)
from clients.recording import Recording, RecordingMeta

__all__ = ["FORMAT", "sniff", "load", "load_sensorconnect", "read_header"]

FORMAT = ("MicroStrain SensorConnect CSV (header Time,...:scaledAccelX,... or estCompensatedAccelX,...; gdin formats A/B)")

log = logging.getLogger(__name__)

GAUSS_TO_UT = 100.0

_A_ACC = ("scaledAccelX", "scaledAccelY", "scaledAccelZ")
_A_GYR = ("scaledGyroX", "scaledGyroY", "scaledGyroZ")
_A_MAG = ("scaledMagX", "scaledMagY", "scaledMagZ")
_B_ACC = ("estCompensatedAccelX", "estCompensatedAccelY", "estCompensatedAccelZ")
_B_GYR = ("estAngularRateX", "estAngularRateY", "estAngularRateZ")


def read_header(path: str | Path) -> list[str]:
    """Channel names of a SensorConnect CSV with the ``inertial-<serial>:`` prefix (any node id) removed
    (a byte-order mark and quotes around the names are ignored; comma, semicolon or tab separated)."""
    names = csv_fields(first_line(path, empty=("header", "empty file")))
    return [c.split(":", 1)[1] if ":" in c else c for c in names]


def sniff(path: str | Path) -> bool:
    """True for a ``.csv`` whose header has a ``Time`` column and SensorConnect format A or B channels."""
    p = Path(path)
    if p.suffix.lower() != ".csv":
        return False
    try:
        cols = read_header(p)
    except ImporterError:
        return False
    return "Time" in cols and (_A_ACC[0] in cols or _B_ACC[0] in cols)


def load(path: str | Path) -> Recording:
    """Alias of :func:`load_sensorconnect` (uniform importer interface)."""
    return load_sensorconnect(path)


def _index(p: Path, cols: list[str], names: tuple[str, ...]) -> list[int]:
    missing = [n for n in names if n not in cols]
    if missing:
        raise ImporterError(p, missing[0], f"column missing (have: {', '.join(cols)})")
    return [cols.index(n) for n in names]


def _scaled(p: Path, column: str, x: np.ndarray, plausible: tuple[float, float], unit: str, name: str,
            factor: float) -> np.ndarray:
    """``x`` in the header's ``unit`` converted by ``factor``, after checking that the median norm lies in the
    ``plausible`` range for that unit (a file whose values do not fit its header is refused, not guessed)."""
    med = float(np.median(np.linalg.norm(x, axis=1)))
    if not plausible[0] <= med <= plausible[1]:
        raise ImporterError(p, column,
                            f"header says {unit} but median {name} = {med:.3g}; units unclear, refusing to guess")
    return x * factor


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
        ``batch``: acc [m/s^2], gyr [rad/s] and (format A with magnetometer columns) mag [uT] in the sensor's
        body frame, on the file's ``Time`` column [s] converted to int64 ns (each stream keeps the rows where
        its values are finite). ``truth`` is ``None`` (see :func:`clients.importers.gdin.load_gdin` for the
        paired ground truth).

    Raises
    ------
    ImporterError
        Unknown or missing acc/gyro columns, empty file, too many unreadable rows, non-monotonic times,
        implausible rate, values that contradict the header's units.
    """
    p = Path(path)
    cols = read_header(p)
    if "Time" not in cols:
        raise ImporterError(p, "Time", f"no 'Time' [s] column (have: {', '.join(cols)})")
    if _A_ACC[0] in cols:
        fmt = "A"
    elif _B_ACC[0] in cols:
        fmt = "B"
    else:
        raise ImporterError(p, "header", "neither scaledAccel* (format A) nor estCompensatedAccel* (format B) columns")
    it = cols.index("Time")
    acc_names, gyr_names = (_A_ACC, _A_GYR) if fmt == "A" else (_B_ACC, _B_GYR)
    twice = [c for c in acc_names + gyr_names + _A_MAG if cols.count(c) > 1]
    if twice:
        # several nodes exported into one file (e.g. a sensor on each shoe): taking the first column of each name
        # would silently mix or drop sensors
        raise ImporterError(p, twice[0], f"appears {cols.count(twice[0])} times (channels of several sensor nodes in "
                            "one export); export one node per file")
    ia, ig = _index(p, cols, acc_names), _index(p, cols, gyr_names)
    mag_present = [c for c in _A_MAG if c in cols] if fmt == "A" else []
    im = [cols.index(c) for c in _A_MAG] if len(mag_present) == len(_A_MAG) else []
    data, notes, n_lines = read_csv_rows(p, len(cols))
    if n_lines == 0:
        raise ImporterError(p, "rows", "no samples (empty file)")
    units: dict[str, str] = {}
    if fmt == "A" and not im:
        missing = ", ".join(c for c in _A_MAG if c not in mag_present)
        notes.append("no scaledMag* columns: recording without magnetometer" if not mag_present else
                     f"magnetometer incomplete ({missing} missing): left out")
        log.warning("%s: %s", p, notes[-1])
    if fmt == "B":
        flags = [cols.index(f"{c}:valid") for c in _B_ACC + _B_GYR if f"{c}:valid" in cols]
        if flags:
            ok = np.all(data[:, flags] != 0, axis=1) & np.all(np.isfinite(data[:, flags]), axis=1)
            if not ok.all():
                msg = f"dropped {int((~ok).sum())} row(s) whose acc/gyro valid flag is 0 or missing"
                log.warning("%s: %s", p, msg)
                notes.append(msg)
                data = data[ok]
                if data.shape[0] == 0:
                    raise ImporterError(p, "valid", "no row has valid acc/gyro flags")
    keep, tn = drop_untimed_rows(p, "Time", data[:, it], n_total=n_lines)
    notes += tn
    data = data[keep]
    t_all = seconds_to_ns(p, "Time", data[:, it])
    acc_t, acc, n1 = clean_stream(p, "Time", [cols[i] for i in ia], t_all, data[:, ia])
    gyr_t, gyr, n2 = clean_stream(p, "Time", [cols[i] for i in ig], t_all, data[:, ig])
    mag_t = mag = None
    n3: list[str] = []
    if im:
        mag_t, mag, n3 = clean_stream(p, "Time", [cols[i] for i in im], t_all, data[:, im], required=False)
    notes += n1 + n2 + n3
    assert acc is not None and gyr is not None
    if fmt == "A":
        acc = _scaled(p, _A_ACC[0], acc, (0.5, 2.5), "g (scaledAccel)", "|a|", G0)
        units["acc"] = f"g -> m/s^2 (x {G0})"
        if mag is not None:
            mag = _scaled(p, _A_MAG[0], mag, (0.05, 2.0), "gauss (scaledMag)", "|m|", GAUSS_TO_UT)
            units["mag"] = f"gauss -> uT (x {GAUSS_TO_UT:g})"
    gyro_unit(p, cols[ig[0]], acc_t, acc, gyr_t, gyr, "rad/s", f"the header ({gyr_names[0]}: rad/s)")
    batch = make_batch(p, acc_t, acc, gyr_t, gyr, mag_t, mag)
    notes += gap_notes(p, batch)
    meta = RecordingMeta(
        source_format=f"sensorconnect-{fmt.lower()}",
        rate_hz=float(batch.rate_hz("acc")),
        units_converted=units,
        mount="foot (MicroStrain 3DM-GX5-25 on one shoe; body axes of the sensor)",
        notes=tuple(notes),
    )
    return Recording(name=name or p.stem, batch=batch, meta=meta, truth=None)
