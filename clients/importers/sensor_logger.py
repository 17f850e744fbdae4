"""Sensor Logger (Android/iOS app by Kelvin Choi) exports: CSV folder, zip of it, or the JSON export.

CSV files are named by sensor (``Accelerometer.csv``, ``TotalAcceleration.csv``, ``Gravity.csv``,
``Gyroscope.csv``, ``Magnetometer.csv``, ...), each with the header ``time,seconds_elapsed,z,y,x``: note
the z, y, x column order. ``time`` is UTC epoch [ns]. The JSON export is one list of records
``{"sensor": "Accelerometer", "time": ..., "seconds_elapsed": ..., "z": ..., "y": ..., "x": ...}`` (values
often as strings).

Accelerometer choice, decided from the data and reported in ``RecordingMeta.notes`` (never guessed):
``TotalAcceleration`` (specific force, with gravity) is used when present. Otherwise ``Accelerometer`` is used
as it is when it carries gravity (its mean vector is nearly as long as its typical sample: Android's raw
accelerometer), or summed with ``Gravity`` when it averages to about zero (gravity removed, as Sensor
Logger's ``Accelerometer`` is on iOS and often on Android). A gravity-carrying stream whose median magnitude
reads about 1.0 is in units of g and is converted (x 9.80665) and said so.
Gyroscope [rad/s] and magnetometer [uT] are used as recorded.

Platform conventions (github.com/tszheichoi/awesome-sensor-logger, UNITS.md, COORDINATES.md, CROSSPLATFORM.md),
read from the export's ``Metadata.csv`` (columns ``platform``: ``android``/``ios``, ``standardisation``:
``true``/``false``; the JSON export's ``Metadata`` record):

- Android, or "Standardise Units & Frames" on: acceleration and gravity are Android's (specific force: lying
  flat on its back the phone reads +9.81 m/s^2 on z); ``TotalAcceleration`` (Android only) is used as is.
- iOS with standardisation off (the app's default): ``Accelerometer`` (user acceleration, m/s^2) and ``Gravity``
  are the NEGATIVE of Android's on all three axes (CoreMotion reports the inertial force: flat on its back the
  gravity vector reads -z): their sum is negated to the specific force. The gyroscope's axes and sign agree on
  both platforms and are used as recorded, as is the magnetometer (uT).
- No Metadata.csv (a bare CSV, or an export with it deleted): the platform is unknown; Android's convention is
  used and a note says so (an iOS export read that way stands upside down: keep its Metadata.csv).

Damaged files follow the sample policy of :mod:`clients.importers._common`: a line cut mid-write is skipped,
an empty cell drops that sample, a header-only file (a sensor that delivered nothing) leaves its stream out;
all noted. Only the accelerometer is required.
"""

from __future__ import annotations

import csv
import io
import json
import logging
import zipfile
from pathlib import Path

import numpy as np

from clients.importers._common import (
    G0,
    MAX_DROPPED_ROW_FRACTION,
    ImporterError,
    clean_stream,
    gap_notes,
    gyro_unit,
    make_batch,
    skipped_lines_message,
)
from clients.recording import Recording, RecordingMeta

__all__ = ["FORMAT", "sniff", "load", "load_sensor_logger", "SENSOR_FILES"]

FORMAT = ("Sensor Logger export, Android or iOS (folder, zip or JSON; CSVs named Accelerometer, TotalAcceleration, Gravity, Gyroscope, ... with header time,seconds_elapsed,z,y,x; Metadata.csv)")

SENSOR_FILES = ("TotalAcceleration", "Accelerometer", "Gravity", "Gyroscope", "Magnetometer")
_HEADER = ["time", "seconds_elapsed", "z", "y", "x"]

log = logging.getLogger(__name__)


def _is_header(row: list[str]) -> bool:
    cols = [c.strip().lower() for c in row]
    return cols[:2] == ["time", "seconds_elapsed"] and {"x", "y", "z"} <= set(cols)


def _cell_float(cell: str) -> float:
    """A value cell as float; an empty or unreadable cell is NaN (the sample policy then drops that sample)."""
    try:
        return float(cell)
    except ValueError:
        return float("nan")


def _cell_time_ns(cell: str) -> int | None:
    """A ``time`` cell [ns] as int (exact for digit strings), ``None`` when empty or unreadable."""
    c = cell.strip()
    if c.lstrip("-").isdigit():
        return int(c)
    try:
        f = float(c)
    except ValueError:
        return None
    return int(round(f)) if np.isfinite(f) else None


def _read_csv_text(text: str, where: str) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """``(t_ns, xyz, notes)`` of one Sensor Logger CSV (columns found by name, so z,y,x order is handled).

    Follows the sample policy of :mod:`clients.importers._common`: a line with another number of fields
    (the last line of an app stopped mid-write) is skipped, an empty or unreadable value cell becomes NaN
    (dropped later by :func:`clean_stream`), a row without a readable time is dropped; all noted. Too many
    such lines or rows: :class:`ImporterError`. A header-only file gives empty arrays (the caller decides
    whether the stream was required).

    Returns
    -------
    t_ns : ndarray of int64, shape (N,)
        UTC epoch [ns] (``time`` column).
    xyz : ndarray, shape (N, 3)
        The x, y, z columns in the file's units.
    notes : list of str
    """
    rows = list(csv.reader(io.StringIO(text)))
    if not rows or not _is_header(rows[0]):
        raise ImporterError(where, "header", f"expected {','.join(_HEADER)}, got {rows[0] if rows else 'nothing'}")
    cols = [c.strip().lower() for c in rows[0]]
    it, ix, iy, iz = cols.index("time"), cols.index("x"), cols.index("y"), cols.index("z")
    numbered = [(k + 2, r) for k, r in enumerate(rows[1:]) if any(c.strip() for c in r)]  # line numbers (1-based)
    notes: list[str] = []
    bad_lines = [k for k, r in numbered if len(r) != len(cols)]
    if bad_lines:
        notes.append(f"{where}: {skipped_lines_message(bad_lines, len(cols))}")
    body = [(k, r) for k, r in numbered if len(r) == len(cols)]
    times = [_cell_time_ns(r[it]) for _, r in body]
    untimed = [k for (k, _), ti in zip(body, times) if ti is None]
    if untimed:
        notes.append(f"{where}: dropped {len(untimed)} row(s) without a readable time (first line {untimed[0]})")
    lost = len(bad_lines) + len(untimed)
    if numbered and lost > MAX_DROPPED_ROW_FRACTION * len(numbered):
        first = min(bad_lines[:1] + untimed[:1])
        raise ImporterError(where, "time", f"{lost} of {len(numbered)} lines are malformed or have no readable time "
                            f"(first: line {first}): not a Sensor Logger CSV this importer can trust")
    for n in notes:
        log.warning("%s", n)
    good = [(ti, r) for ti, (_, r) in zip(times, body) if ti is not None]
    t = np.array([ti for ti, _ in good], dtype=np.int64)
    v = np.array([[_cell_float(r[ix]), _cell_float(r[iy]), _cell_float(r[iz])] for _, r in good],
                 dtype=np.float64).reshape(-1, 3)
    return t, v, notes


def _read_json(obj: object, where: str) -> tuple[dict[str, tuple[np.ndarray, np.ndarray]], str]:
    """Streams by sensor name and the platform (its ``Metadata`` record, ``unknown`` without one)."""
    if not isinstance(obj, list):
        raise ImporterError(where, "file", "Sensor Logger JSON export must be a list of records")
    per: dict[str, list[tuple[int, float, float, float]]] = {}
    platform = "unknown"
    for i, rec in enumerate(obj):
        if not isinstance(rec, dict) or "sensor" not in rec:
            continue
        name = str(rec["sensor"])
        if name.lower() == "metadata":
            platform = _platform_of(rec)
            continue
        if name not in SENSOR_FILES:
            continue
        try:
            per.setdefault(name, []).append((int(float(rec["time"])) if not str(rec["time"]).isdigit() else int(rec["time"]),
                                             float(rec["x"]), float(rec["y"]), float(rec["z"])))
        except (KeyError, ValueError, TypeError) as exc:
            raise ImporterError(where, f"record {i} ({name})", f"missing or non-numeric time/x/y/z ({exc})") from None
    out = {}
    for name, rows in per.items():
        a = np.array(rows, dtype=object)
        out[name] = (a[:, 0].astype(np.int64), a[:, 1:].astype(np.float64))
    return out, platform


def _collect(path: Path) -> tuple[dict[str, tuple[np.ndarray, np.ndarray]], list[str], str, Path]:
    """Streams by sensor name, what reading them noted, the platform (from Metadata.csv when present) and the
    source path."""
    streams: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    notes: list[str] = []
    platform = "unknown"

    def add(name: str, text: str, where: str) -> None:
        t, v, n = _read_csv_text(text, where)
        streams[name] = (t, v)
        notes.extend(n)
    if path.suffix.lower() == ".zip":
        with zipfile.ZipFile(path) as zf:
            for info in zf.infolist():
                stem = Path(info.filename).stem
                if Path(info.filename).suffix.lower() != ".csv":
                    continue
                text = zf.read(info).decode("utf-8-sig")
                if stem in SENSOR_FILES:
                    add(stem, text, f"{path}:{info.filename}")
                elif stem.lower() == "metadata":
                    platform = _platform(text)
        return streams, notes, platform, path
    if path.suffix.lower() == ".json":
        try:
            obj = json.loads(path.read_text(encoding="utf-8-sig"))
        except (OSError, ValueError) as exc:
            raise ImporterError(path, "file", f"not readable JSON ({exc})") from None
        streams, platform = _read_json(obj, str(path))
        return streams, notes, platform, path
    folder = path if path.is_dir() else path.parent
    for name in SENSOR_FILES:
        f = folder / f"{name}.csv"
        if f.exists():
            add(name, f.read_text(encoding="utf-8-sig"), str(f))
    meta = folder / "Metadata.csv"
    if meta.exists():
        platform = _platform(meta.read_text(encoding="utf-8-sig"))
    return streams, notes, platform, folder


def _platform(text: str) -> str:
    """``android``, ``ios`` or ``ios-standardised`` from Metadata.csv (``unknown`` when it says nothing)."""
    rows = list(csv.DictReader(io.StringIO(text)))
    return _platform_of(rows[0]) if rows else "unknown"


def _platform_of(row: dict[str, object]) -> str:
    plat = str(row.get("platform") or "unknown").strip().lower()
    std = str(row.get("standardisation") or "false").strip().lower() == "true"
    return "ios-standardised" if plat == "ios" and std else plat


def _median_norm(v: np.ndarray) -> float:
    return float(np.median(np.linalg.norm(v, axis=1))) if len(v) else float("nan")


def _has_gravity(v: np.ndarray) -> bool:
    """Gravity dominates a stream that carries it: its mean vector is nearly as long as its typical sample,
    while a gravity-removed stream averages to about zero."""
    return bool(np.linalg.norm(v.mean(axis=0)) > 0.5 * _median_norm(v))


def _to_ms2(name: str, v: np.ndarray, conv: dict[str, str]) -> np.ndarray:
    """A gravity-carrying stream whose median magnitude is about 1 is in g: convert to m/s^2 and say so."""
    med = _median_norm(v)
    if 0.5 < med < 1.5:
        conv[name] = "g -> m/s^2 (x 9.80665)"
        return v * G0
    return v


def _location_fixes(path: Path) -> list:  # type: ignore[type-arg]
    """The fixes of the export's ``Location.csv`` (folder or zip; columns by name: ``time`` [ns], ``latitude``,
    ``longitude``, ``altitude``, ``horizontalAccuracy``), as :class:`models.geo.Fix`; rows that cannot be read
    are left out (a location file never refuses the recording)."""
    from models.geo import Fix

    text = None
    if path.suffix.lower() == ".zip":
        with zipfile.ZipFile(path) as zf:
            for info in zf.infolist():
                if Path(info.filename).name.lower() == "location.csv":
                    text = zf.read(info).decode("utf-8-sig")
    elif path.suffix.lower() != ".json":
        f = (path if path.is_dir() else path.parent) / "Location.csv"
        if f.exists():
            text = f.read_text(encoding="utf-8-sig")
    fixes = []
    for row in csv.DictReader(io.StringIO(text or "")):
        def num(k: str) -> float | None:
            try:
                v = float(row.get(k) or "nan")
            except ValueError:
                return None
            return v if np.isfinite(v) else None

        t, lat, lon = _cell_time_ns(row.get("time") or ""), num("latitude"), num("longitude")
        if t is not None and lat is not None and lon is not None:
            fixes.append(Fix(t, lat, lon, num("altitude"), num("horizontalAccuracy")))
    return fixes


def load_sensor_logger(path: str | Path) -> Recording:
    """Import a Sensor Logger export (folder, one of its CSVs, zip, or JSON) as SI streams."""
    p = Path(path)
    streams, read_notes, platform, src = _collect(p)
    notes: list[str] = [f"platform: {platform}"] + read_notes
    for name in [n for n, (t, _) in streams.items() if len(t) == 0]:  # header only: the sensor delivered nothing
        del streams[name]
        notes.append(f"{name}: no samples (header only); left out")
        log.warning("%s: %s", src, notes[-1])
    conv: dict[str, str] = {}

    def clean(name: str) -> tuple[np.ndarray, np.ndarray]:
        t, v = streams[name]
        order = np.argsort(t, kind="stable")
        if np.any(order != np.arange(len(t))):
            notes.append(f"{name}: rows were not in time order; sorted")
            t, v = t[order], v[order]
        t2, v2, n = clean_stream(src, f"{name}.time", [f"{name}.x", f"{name}.y", f"{name}.z"], t, v)
        assert t2 is not None and v2 is not None  # required: clean_stream raises instead
        notes.extend(n)
        return t2, v2

    if "TotalAcceleration" in streams:
        acc_t, acc = clean("TotalAcceleration")
        acc = _to_ms2("TotalAcceleration", acc, conv)
        notes.append("accelerometer: TotalAcceleration (specific force including gravity)")
    elif "Accelerometer" in streams:
        acc_t, acc = clean("Accelerometer")
        if _has_gravity(acc):  # Android's raw accelerometer
            acc = _to_ms2("Accelerometer", acc, conv)
            notes.append("accelerometer: Accelerometer carries gravity (mean vector ~ 1 g); used as is")
        elif "Gravity" in streams:
            g_t, g = clean("Gravity")
            g = _to_ms2("Gravity", g, conv)
            if "Gravity" in conv:
                acc = acc * G0
                conv["Accelerometer"] = "g -> m/s^2 (x 9.80665), like Gravity"
            j = np.clip(np.searchsorted(g_t, acc_t), 0, len(g_t) - 1)
            jm = np.clip(j - 1, 0, len(g_t) - 1)
            j = np.where(np.abs(g_t[jm] - acc_t) < np.abs(g_t[j] - acc_t), jm, j)
            acc = acc + g[j]
            notes.append("accelerometer: Accelerometer (gravity removed) + Gravity, nearest sample")
        else:
            raise ImporterError(src, "Accelerometer", "gravity removed (mean vector ~ 0) and no TotalAcceleration "
                                "or Gravity file to restore it; export with TotalAcceleration on")
    else:
        raise ImporterError(src, "TotalAcceleration", "no accelerometer file with samples (TotalAcceleration.csv or Accelerometer.csv)")
    if platform == "ios":
        acc = -acc
        conv["acc axes"] = ("iOS, standardisation off: CoreMotion's sign (inertial force) -> specific force "
                            "(x -1 on every axis; Metadata.csv)")
        notes.append("iOS export without 'Standardise Units & Frames': acceleration and gravity negated to the "
                     "specific force (gyroscope and magnetometer agree on both platforms, used as recorded)")
    elif platform in ("android", "ios-standardised"):
        notes.append(f"{platform}: Android's axis and sign convention (specific force), used as recorded")
    else:
        notes.append("platform unknown (no Metadata.csv): Android's convention (specific force) assumed; an iOS "
                     "export read this way stands upside down, keep its Metadata.csv")
        log.warning("%s: %s", src, notes[-1])
    gyr_t = gyr = mag_t = mag = None
    if "Gyroscope" in streams:
        gyr_t, gyr = clean("Gyroscope")
    if "Magnetometer" in streams:
        mag_t, mag = clean("Magnetometer")
    if gyr_t is not None and gyr is not None:
        gyro_unit(src, "Gyroscope.x", acc_t, acc, gyr_t, gyr, "rad/s", "the format (Sensor Logger's Gyroscope: rad/s)")
    batch = make_batch(src, acc_t, acc, gyr_t, gyr, mag_t, mag)
    notes += gap_notes(src, batch)
    rate = batch.rate_hz("acc")
    from models.geo import anchor_from_fixes

    fixes = _location_fixes(p)
    anchor = anchor_from_fixes(fixes)
    if fixes:
        notes.append(f"location: {len(fixes)} fixes; " + (
            f"anchored at the first with an accuracy of {anchor.accuracy_m:g} m ({anchor.latitude_deg:.6f}, "
            f"{anchor.longitude_deg:.6f})" if anchor is not None else "none accurate enough to anchor (25 m)"))
    return Recording(
        name=src.stem if src.is_file() else src.name,
        batch=batch,
        meta=RecordingMeta(source_format="sensor-logger", rate_hz=rate, units_converted=conv, mount="phone",
                           notes=tuple(notes), anchor=anchor),
    )


def sniff(path: str | Path) -> bool:
    """A Sensor Logger CSV (``time,seconds_elapsed,z,y,x``), a zip holding them, or its JSON export."""
    p = Path(path)
    if p.is_dir():  # by the header too: a phyphox export folder has an Accelerometer.csv as well
        return any(sniff(p / f"{n}.csv") for n in ("TotalAcceleration", "Accelerometer") if (p / f"{n}.csv").is_file())
    suf = p.suffix.lower()
    try:
        if suf == ".csv":
            with open(p, encoding="utf-8-sig", newline="") as fh:
                return p.stem in SENSOR_FILES and _is_header(next(csv.reader(fh), []))
        if suf == ".zip":
            with zipfile.ZipFile(p) as zf:
                stems = {Path(n).stem for n in zf.namelist()}
            return bool(stems & {"TotalAcceleration", "Accelerometer"}) and "time" not in stems
        if suf == ".json":
            with open(p, encoding="utf-8-sig") as fh:
                head = fh.read(4096)
            return head.lstrip().startswith("[") and '"seconds_elapsed"' in head and '"sensor"' in head
    except (OSError, zipfile.BadZipFile, UnicodeDecodeError):
        return False
    return False


def load(path: str | Path) -> Recording:
    """Importer entry point (see :mod:`clients.importers`): a CSV loads its whole export folder."""
    return load_sensor_logger(path)
