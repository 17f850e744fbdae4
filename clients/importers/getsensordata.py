"""GetSensorData logfiles (Android app of LOPSI, CAR-CSIC; the IPIN competition's smartphone format).

A text file (latin-1), one line per sensor event, fields separated by ``;``, header lines starting with ``%``:

- ``ACCE;AppTimestamp;SensorTimestamp;x;y;z;accuracy`` specific force with gravity [m/s^2], Android axes;
- ``GYRO;AppTimestamp;SensorTimestamp;x;y;z;accuracy`` angular rate [rad/s];
- ``MAGN;AppTimestamp;SensorTimestamp;x;y;z;accuracy`` calibrated field [uT] (the header documents an empty
  column between x and y: ``Mag_X(uT);;Mag_Y(uT)``; both layouts are read);
- ``AHRS;AppTimestamp;SensorTimestamp;pitch;roll;yaw [deg];qx;qy;qz;accuracy`` the phone's own rotation vector;
- ``GNSS;AppTimestamp;SensorTimestamp;lat;lon;alt [m];bearing [deg];accuracy [m];speed [m/s];in view;in use``;
- ``POSI;AppTimestamp;counter;lat;lon;floor;building`` ground truth: logged when the walker stood on a surveyed
  landmark (WGS-84).

Other lines (pressure, light, sound, Wi-Fi, BLE ...) are not read.

Time: ``AppTimestamp`` [s] is the app's common clock (POSI and GNSS have only it); ``SensorTimestamp`` [s] is
the sensor's own clock, whose differences are the accurate sample intervals. The inertial streams share one
sensor clock (Android's ``SensorEvent`` time base), so every sample keeps its sensor time, shifted onto the app
clock by one offset: the median over the accelerometer lines of ``SensorTimestamp - AppTimestamp`` (the app
reads each event some milliseconds after the sensor stamped it; the median of that latency is in the offset,
its spread is not in the samples). Stored times are that app-clock time in int64 ns, so the landmarks' and
fixes' AppTimestamps are on the samples' axis as they stand. The offset is noted in ``RecordingMeta.notes``.

What the recording holds besides the engine's streams: :attr:`clients.recording.Recording.truth` the landmarks
(``t_ns``; ``positions`` in a local NED frame [m] at the first landmark, height 0; ``extra``: ``latitude_deg``,
``longitude_deg``, ``floor``, ``building``, ``counter``, ``origin_deg``), and
:attr:`clients.recording.Recording.aux` the location fixes ``gnss`` (``t_ns``, ``latitude_deg``,
``longitude_deg``, ``altitude_m``, ``bearing_deg``, ``accuracy_m``, ``speed_m_s``, ``sats_in_view``,
``sats_in_use``, ``utc_ns`` the fix's own UTC time; the first good one is ``RecordingMeta.anchor``), the phone's orientation ``ahrs`` (``t_ns``, ``pitch_roll_yaw_deg``, ``quat_xyz``) and
``device`` (manufacturer, model, Android version and the creation ``date`` from the header). Damaged lines follow the sample policy of
:mod:`clients.importers._common`: a line with too few fields or an unreadable number is skipped and noted.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import numpy as np

from clients.importers._common import (
    MAX_DROPPED_ROW_FRACTION,
    ImporterError,
    clean_stream,
    gap_notes,
    gyro_unit,
    make_batch,
)
from clients.recording import Recording, RecordingMeta, Truth

__all__ = ["sniff", "load", "load_getsensordata", "SOURCE_FORMAT"]

log = logging.getLogger(__name__)

SOURCE_FORMAT = "getsensordata"
_SIGNATURE = "GetSensorData"
_INERTIAL = {"ACCE": "acc", "GYRO": "gyr", "MAGN": "mag"}
_READ = ("ACCE", "GYRO", "MAGN", "AHRS", "GNSS", "POSI")
_SNIFF_BYTES = 8192


def _numbers(fields: list[str]) -> list[float] | None:
    """The fields as floats (an empty field, as MAGN's documented empty column, is skipped); None if any other
    field is not a number."""
    out = []
    for f in fields:
        f = f.strip()
        if not f:
            continue
        try:
            out.append(float(f))
        except ValueError:
            return None
    return out


def _creation_date(text: str) -> str | None:
    """ISO date of the header's ``Date of creation: Wed Jun 14 10:46:42 GMT+02:00 2023`` (None if unreadable)."""
    parts = text.split()
    months = ("Jan", "Feb", "Mar", "Apr", "May", "Jun", "Jul", "Aug", "Sep", "Oct", "Nov", "Dec")
    try:
        return f"{int(parts[-1]):04d}-{months.index(parts[1][:3]) + 1:02d}-{int(parts[2]):02d}"
    except (IndexError, ValueError):
        return None


def _parse_group(tag: str, lines: list[tuple[int, str]], need: int) -> tuple[list[list[float]], list[int]]:
    """Rows of one line kind and the numbers of its unreadable lines. The lines with the kind's usual field count
    are parsed in one go (numpy's C parser); the rest, and a group the fast parser refuses, line by line."""
    if not lines:
        return [], []
    texts = [t.rstrip(";").replace(";;", ";") for _, t in lines]
    counts = np.array([t.count(";") for t in texts])
    usual = int(np.bincount(counts).argmax())
    rows: list[list[float]] = []
    bad: list[int] = []
    slow = list(range(len(texts)))
    if usual + 1 >= need:
        fast = np.flatnonzero(counts == usual)
        try:
            a = np.loadtxt([texts[i] for i in fast], delimiter=";", dtype=np.float64, ndmin=2)
            rows = a.tolist()
            slow = [i for i in range(len(texts)) if counts[i] != usual]
        except ValueError:
            rows = []
    for i in slow:
        vals = _numbers(texts[i].split(";"))
        if vals is None or len(vals) < need:
            bad.append(lines[i][0])
        else:
            rows.append(vals)
    if slow and rows:
        order = np.argsort([r[0] for r in rows], kind="stable")  # back into AppTimestamp order
        rows = [rows[i] for i in order]
    return rows, bad


def _read_lines(p: Path) -> tuple[dict[str, list[list[float]]], dict[str, str], list[str]]:
    """Rows of the line kinds read here, header facts and notes."""
    header: dict[str, str] = {}
    # fields each kind needs after its tag (MAGN's empty column is dropped before counting)
    need = {"ACCE": 5, "GYRO": 5, "MAGN": 5, "AHRS": 8, "GNSS": 10, "POSI": 4}
    groups: dict[str, list[tuple[int, str]]] = {k: [] for k in _READ}
    try:
        with open(p, encoding="latin-1", newline=None) as fh:
            text = fh.read()
    except OSError as exc:
        raise ImporterError(p, "file", f"cannot be read ({exc})") from exc
    for k, line in enumerate(text.splitlines(), start=1):
        if line.startswith("%"):
            h = line[1:].strip()
            for key in ("Manufacturer", "Model", "Android version Release"):
                if h.startswith(key + ":"):
                    header[key] = h.split(":", 1)[1].strip()
            if h.startswith("Date of creation:"):
                day = _creation_date(h.split(":", 1)[1])
                if day is not None:
                    header["date"] = day
            continue
        tag, _, rest = line.partition(";")
        if tag in groups:
            groups[tag].append((k, rest))
    rows: dict[str, list[list[float]]] = {}
    notes = []
    for tag in _READ:
        rows[tag], lines = _parse_group(tag, groups[tag], need[tag])
        if not lines:
            continue
        shown = ", ".join(str(x) for x in lines[:5]) + (" ..." if len(lines) > 5 else "")
        msg = f"{tag}: skipped {len(lines)} line(s) with missing or unreadable fields (line {shown})"
        log.warning("%s: %s", p, msg)
        notes.append(msg)
        total = len(rows[tag]) + len(lines)
        if len(lines) > MAX_DROPPED_ROW_FRACTION * total:
            raise ImporterError(p, tag, f"{len(lines)} of {total} lines are malformed (first: line {lines[0]}): not a "
                                "GetSensorData logfile this importer can trust")
    return rows, header, notes


def _clock_offset_s(p: Path, acc: np.ndarray) -> float:
    """Median of SensorTimestamp - AppTimestamp over the accelerometer lines [s]."""
    off = acc[:, 1] - acc[:, 0]
    if not np.all(np.isfinite(off)):
        raise ImporterError(p, "ACCE", "a timestamp is not finite")
    return float(np.median(off))


def _to_ns(t_s: np.ndarray) -> np.ndarray:
    return np.round(np.asarray(t_s, dtype=np.float64) * 1e9).astype(np.int64)


def _landmarks(p: Path, posi: list[list[float]]) -> Truth | None:
    if not posi:
        return None
    import pymap3d

    a = np.asarray(posi, dtype=np.float64)
    t, counter, lat, lon = a[:, 0], a[:, 1], a[:, 2], a[:, 3]
    if np.any(np.abs(lat) > 90.0) or np.any(np.abs(lon) > 180.0):
        raise ImporterError(p, "POSI", "a landmark's latitude/longitude is out of range")
    n, e, d = pymap3d.geodetic2ned(lat, lon, np.zeros_like(lat), lat[0], lon[0], 0.0)
    extra: dict[str, Any] = {
        "latitude_deg": lat, "longitude_deg": lon, "counter": counter.astype(np.int64),
        "floor": a[:, 4] if a.shape[1] > 4 else np.full(len(a), np.nan),
        "building": a[:, 5] if a.shape[1] > 5 else np.full(len(a), np.nan),
        "origin_deg": (float(lat[0]), float(lon[0])),
        "kind": "landmarks",
    }
    return Truth(t_ns=_to_ns(t), positions=np.column_stack([n, e, d]), extra=extra)


def _gnss(gnss: list[list[float]]) -> dict[str, np.ndarray] | None:
    if not gnss:
        return None
    a = np.asarray(gnss, dtype=np.float64)
    utc = a[:, 1]  # the fix's own time: UTC epoch seconds
    names = ("latitude_deg", "longitude_deg", "altitude_m", "bearing_deg", "accuracy_m", "speed_m_s", "sats_in_view",
             "sats_in_use")
    out = {"t_ns": _to_ns(a[:, 0])}  # AppTimestamp; the SensorTimeStamp column is the fix's UTC time
    for i, name in enumerate(names):
        out[name] = a[:, 2 + i] if a.shape[1] > 2 + i else np.full(len(a), np.nan)
    out["utc_ns"] = np.round(utc * 1e9).astype(np.int64)
    return out


def _anchor(fixes: dict[str, np.ndarray] | None) -> Any:
    """The recording's anchor: its first good GNSS fix (:func:`models.geo.anchor_from_fixes`), dated by the fix's
    UTC time; None without one."""
    if fixes is None:
        return None
    from models.geo import Fix, anchor_from_fixes

    return anchor_from_fixes((Fix(int(t), float(la), float(lo), float(h), float(acc)) for t, la, lo, h, acc in zip(
        fixes["utc_ns"], fixes["latitude_deg"], fixes["longitude_deg"], fixes["altitude_m"], fixes["accuracy_m"])),
        source="gnss")


def load_getsensordata(path: str | Path) -> Recording:
    """Import a GetSensorData logfile (see the module docstring)."""
    p = Path(path)
    rows, header, notes = _read_lines(p)
    if not rows["ACCE"]:
        raise ImporterError(p, "ACCE", "no accelerometer lines")
    acc_rows = np.asarray(rows["ACCE"], dtype=np.float64)
    offset = _clock_offset_s(p, acc_rows)
    notes.append(f"time: each sample's SensorTimestamp moved onto the AppTimestamp clock by {offset:.4f} s (median "
                 "SensorTimestamp - AppTimestamp of the accelerometer lines)")
    streams: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for tag, name in _INERTIAL.items():
        if not rows[tag]:
            if name == "acc":
                raise ImporterError(p, tag, "no samples")
            notes.append(f"{tag}: no lines; stream left out")
            continue
        a = np.asarray(rows[tag], dtype=np.float64)
        t_ns = _to_ns(a[:, 1] - offset)
        t, v, n = clean_stream(p, f"{tag} SensorTimestamp", [f"{tag} x"], t_ns, a[:, 2:5], required=name != "mag")
        notes += n
        if t is not None and v is not None:
            streams[name] = (t, v)
    if "gyr" in streams:
        gyro_unit(p, "GYRO x", *streams["acc"], *streams["gyr"], "rad/s", "the header (Gyr_X(rad/s))")
    batch = make_batch(p, *streams["acc"], *streams.get("gyr", (None, None)), *streams.get("mag", (None, None)))
    notes += gap_notes(p, batch)
    aux: dict[str, Any] = {"device": dict(header)}
    fixes = _gnss(rows["GNSS"])
    if fixes is not None:
        aux["gnss"] = fixes
    if rows["AHRS"]:
        a = np.asarray(rows["AHRS"], dtype=np.float64)
        aux["ahrs"] = {"t_ns": _to_ns(a[:, 1] - offset), "pitch_roll_yaw_deg": a[:, 2:5], "quat_xyz": a[:, 5:8]}
    if header.get("Model"):
        notes.append(f"device: {header.get('Manufacturer', '?')} {header['Model']} (Android {header.get('Android version Release', '?')})")
    return Recording(
        name=p.stem,
        batch=batch,
        meta=RecordingMeta(source_format=SOURCE_FORMAT, rate_hz=batch.rate_hz("acc"), mount="phone", notes=tuple(notes),
                           anchor=_anchor(fixes)),
        truth=_landmarks(p, rows["POSI"]),
        aux=aux,
    )


def sniff(path: str | Path) -> bool:
    """A text file whose header names the GetSensorData app, or whose first data lines are its sensor lines."""
    p = Path(path)
    if not p.is_file():
        return False
    try:
        with open(p, "rb") as fh:
            head = fh.read(_SNIFF_BYTES).decode("latin-1")
    except OSError:
        return False
    if _SIGNATURE in head:
        return True
    data = [ln for ln in head.splitlines()[:50] if ln and not ln.startswith("%")]
    return bool(data) and all(ln.split(";", 1)[0] in ("ACCE", "GYRO", "MAGN", "AHRS", "PRES", "LIGH", "GNSS", "POSI",
                                                      "SOUN", "WIFI", "BLE4", "PROX")
                              for ln in data[:-1] or data)


def load(path: str | Path) -> Recording:
    return load_getsensordata(path)
