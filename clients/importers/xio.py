"""x-io Technologies CSV: NGIMU ``sensors.csv`` (from the NGIMU GUI's session export, one folder per device) and
the Gait-Tracking example files (github.com/xioTechnologies/Gait-Tracking, ``short_walk.csv``).

Header, one unit per column in parentheses::

    Time (s),Gyroscope X (deg/s),Gyroscope Y (deg/s),Gyroscope Z (deg/s),Accelerometer X (g),Accelerometer Y (g),
    Accelerometer Z (g)[,Magnetometer X (uT),Magnetometer Y (uT),Magnetometer Z (uT)][,Barometer (hPa)]

The units are read from the header, not assumed: time s (ms accepted), gyroscope deg/s or rad/s, accelerometer g or
m/s^2, magnetometer uT (or gauss); anything else is refused naming the column. The gyroscope's unit is checked
against how fast the sensor turns while it moves (:func:`clients.importers._common.gyro_unit`). The accelerometer
reads +1 g up at rest (x-io's convention is specific force, as ours). Other columns (barometer) are noted and left
out. The NGIMU repeats the previous magnetometer sample between its (slower) updates: such repeats are kept as
recorded (they are the device's output). A device folder (``NGIMU - 0029CEC0``) holding ``sensors.csv`` loads as
that file. Damaged rows follow the sample policy of :mod:`clients.importers._common` (the Gait-Tracking files
repeat some rows exactly: dropped and noted).
"""

from __future__ import annotations

import logging
import re
from pathlib import Path

import numpy as np

from clients.importers._common import (
    G0,
    ImporterError,
    clean_stream,
    csv_fields,
    drop_untimed_rows,
    gap_notes,
    gyro_unit,
    make_batch,
    read_csv_rows,
    seconds_to_ns,
)
from clients.recording import Recording, RecordingMeta

__all__ = ["FORMAT", "sniff", "load", "load_xio"]

FORMAT = ("x-io NGIMU / Gait-Tracking CSV (header 'Time (s),Gyroscope X (deg/s),...,Accelerometer X (g),...', "
          "optional Magnetometer X (uT); an NGIMU device folder holding sensors.csv)")

log = logging.getLogger(__name__)

_COL = re.compile(r"(?P<name>[A-Za-z ]+?)\s*(?P<axis>[XYZ])?\s*\((?P<unit>[^)]*)\)")
_TIME_UNITS = {"s": 1.0, "ms": 1e-3}
_GYR_UNITS = {"deg/s": "deg/s", "°/s": "deg/s", "dps": "deg/s", "rad/s": "rad/s"}
_ACC_UNITS = {"g": G0, "m/s^2": 1.0, "m/s²": 1.0, "m/s2": 1.0}
_MAG_UNITS = {"ut": 1.0, "µt": 1.0, "μt": 1.0, "g": 100.0, "gauss": 100.0}
_SENSORS = {"Gyroscope": "gyr", "Accelerometer": "acc", "Magnetometer": "mag"}


def _file(path: Path) -> Path:
    """The CSV of ``path``: the file itself, or a device folder's ``sensors.csv``."""
    return path / "sensors.csv" if path.is_dir() else path


def _columns(header: list[str]) -> dict[str, tuple[int, str]]:
    """``{"time": (index, unit), "gyr_x": ..., "acc_x": ..., "mag_x": ..., "other:<name>": ...}`` from the header."""
    out: dict[str, tuple[int, str]] = {}
    for i, cell in enumerate(header):
        m = _COL.fullmatch(cell.strip())
        if not m:
            out[f"other:{cell}"] = (i, "")
            continue
        name, axis, unit = m.group("name").strip(), m.group("axis"), m.group("unit").strip()
        if name == "Time" and axis is None:
            out["time"] = (i, unit)
        elif name in _SENSORS and axis is not None:
            out[f"{_SENSORS[name]}_{axis.lower()}"] = (i, unit)
        else:
            out[f"other:{cell}"] = (i, unit)
    return out


def sniff(path: str | Path) -> bool:
    """An x-io CSV: its header holds ``Time (s)``, ``Gyroscope X (...)`` and ``Accelerometer X (...)`` columns."""
    p = _file(Path(path))
    if p.suffix.lower() != ".csv" or not p.is_file():
        return False
    try:
        with open(p, encoding="utf-8-sig", errors="replace") as fh:
            cols = _columns(csv_fields(fh.readline()))
    except OSError:
        return False
    return {"time", "gyr_x", "acc_x"} <= set(cols)


def _unit(p: Path, cols: dict[str, tuple[int, str]], keys: list[str], table: dict[str, object]) -> object:
    units = {cols[k][1].lower() for k in keys}
    if len(units) != 1:
        raise ImporterError(p, keys[0], f"the axes state different units ({', '.join(sorted(units))})")
    u = units.pop()
    if u not in table:
        raise ImporterError(p, keys[0], f"unit {u!r} is not one this importer knows ({', '.join(table)})")
    return table[u]


def load_xio(path: str | Path) -> Recording:
    """Read an x-io CSV (or an NGIMU device folder) into SI units (see the module docstring)."""
    src = Path(path)
    p = _file(src)
    with open(p, encoding="utf-8-sig", errors="replace") as fh:
        header = csv_fields(fh.readline())
    cols = _columns(header)
    for k in ("time", "gyr_x", "gyr_y", "gyr_z", "acc_x", "acc_y", "acc_z"):
        if k not in cols:
            raise ImporterError(p, k, f"column missing (header: {', '.join(header)})")
    data, notes, n_lines = read_csv_rows(p, len(header))
    if n_lines == 0 or not len(data):
        raise ImporterError(p, "rows", "no samples (empty file)")
    ti, tu = cols["time"]
    if tu.lower() not in _TIME_UNITS:
        raise ImporterError(p, header[ti], f"time unit {tu!r} is not one this importer knows ({', '.join(_TIME_UNITS)})")
    keep, n0 = drop_untimed_rows(p, header[ti], data[:, ti], n_total=n_lines)
    data = data[keep]
    notes += n0
    t_ns = seconds_to_ns(p, header[ti], data[:, ti] * _TIME_UNITS[tu.lower()])
    t_ns = t_ns - t_ns[0]
    units: dict[str, str] = {}

    def stream(name: str, required: bool = True) -> tuple[np.ndarray | None, np.ndarray | None]:
        keys = [f"{name}_{a}" for a in "xyz"]
        idx = [cols[k][0] for k in keys]
        t, v, n = clean_stream(p, header[ti], [header[i] for i in idx], t_ns, data[:, idx], required=required)
        notes.extend(n)
        return t, v

    acc_t, acc_v = stream("acc")
    gyr_t, gyr_v = stream("gyr")
    assert acc_t is not None and acc_v is not None and gyr_t is not None and gyr_v is not None
    k_acc = float(_unit(p, cols, ["acc_x", "acc_y", "acc_z"], _ACC_UNITS))  # type: ignore[arg-type]
    acc = acc_v * k_acc
    units["acc"] = f"{cols['acc_x'][1]} (header)" + (f" -> m/s^2 (x {k_acc:g})" if k_acc != 1.0 else ", used as is")
    stated = str(_unit(p, cols, ["gyr_x", "gyr_y", "gyr_z"], _GYR_UNITS))
    gu, how, _ = gyro_unit(p, header[cols["gyr_x"][0]], acc_t, acc, gyr_t, gyr_v, stated, "the header")
    gyr = np.deg2rad(gyr_v) if gu == "deg/s" else gyr_v
    units["gyr"] = ("deg/s -> rad/s (x pi/180)" if gu == "deg/s" else "rad/s, used as is") + f"; unit: {how}"
    mag_t = mag = None
    if all(f"mag_{a}" in cols for a in "xyz"):
        mag_t, mag_v = stream("mag", required=False)
        if mag_v is not None:
            k_mag = float(_unit(p, cols, ["mag_x", "mag_y", "mag_z"], _MAG_UNITS))  # type: ignore[arg-type]
            mag = mag_v * k_mag
            units["mag"] = f"{cols['mag_x'][1]} (header)" + (f" -> uT (x {k_mag:g})" if k_mag != 1.0 else ", used as is")
    others = [k.split(":", 1)[1] for k in cols if k.startswith("other:")]
    if others:
        notes.append(f"columns left out: {', '.join(others)}")
    batch = make_batch(p, acc_t, acc, gyr_t, gyr, mag_t if mag is not None else None, mag)
    notes += gap_notes(p, batch)
    for n in notes:
        log.info("%s: %s", p, n)
    name = src.name if src.is_dir() else p.stem
    return Recording(
        name=name,
        batch=batch,
        meta=RecordingMeta(source_format="xio-csv", rate_hz=float(batch.rate_hz("acc")), units_converted=units,
                           mount="unknown (x-io sensor axes as recorded)", notes=tuple(notes)),
    )


def load(path: str | Path) -> Recording:
    """Importer entry point (see :mod:`clients.importers`)."""
    return load_xio(path)
