"""gaitmap example CSVs (datasets/gaitmap-mocap, datasets/gaitmap-mag).

gaitmap's own convention: accelerometer [m/s^2], gyroscope [deg/s] (converted here to rad/s), foot frame
with gravity on +z at rest. A column name may state its unit (``gyr_x [rad/s]``, ``acc_x (g)``, ``mag_x [uT]``;
accelerometer m/s^2 or g, gyroscope deg/s or rad/s, magnetometer uT); the gyroscope's unit, stated or not, is
checked against how fast the foot turns while it moves (:func:`clients.importers._common.gyro_unit`): a file
without units whose gyroscope is plainly in rad/s is read as rad/s and says so, one the data cannot place is
refused, one without enough motion to tell keeps gaitmap's deg/s and notes that it was not checked. Two layouts:

- two header rows (``sensor``/first row: ``left_sensor``/``right_sensor``; second row: ``acc_x`` .. ``gyr_z``),
  one foot selected with ``foot=`` (imu_sample.csv, imu_sample_healthy_stair_*.csv);
- one header row ``,acc_x,...,gyr_z[,mag_x,mag_y,mag_z]`` (aligned_data_with_mag_l_walks.csv).

The first column is either a time [s] (then the rate is read from it) or a sample index (then the rate must be
known: ``rate_hz=`` or one of the documented example files in ``KNOWN_RATES_HZ``; otherwise the import fails
rather than guessing). A file without such a column (first column ``acc_x`` ...) is read as consecutive samples
when the rate is known and refused otherwise. A two-sensor file may hold one foot only; :func:`load` then takes that foot. Xsens normalised magnetometer values (1.0 = field at the calibration site) are
converted to uT only when ``mag_scale_ut`` is given; otherwise the magnetometer is NOT imported and the
metadata says so. For imu_sample.csv the synchronised heel-marker trajectory (mocap_sample.csv, 100 Hz, mm)
is attached as truth (converted to m), with the foot's still moments from stride_events_sample.csv
(``Truth.extra["stance_t_ns"]``).
"""

from __future__ import annotations

import csv
import logging
import re
from pathlib import Path

import numpy as np

from clients.importers._common import (
    G0,
    ImporterError,
    clean_stream,
    csv_fields,
    csv_separator,
    drop_untimed_rows,
    gap_notes,
    gyro_unit,
    make_batch,
    read_csv_rows,
)
from clients.recording import Recording, RecordingMeta, Truth

__all__ = ["FORMAT", "KNOWN_RATES_HZ", "MOCAP_RATE_HZ", "sniff", "sensor_feet", "load", "load_gaitmap"]

FORMAT = "gaitmap CSV (columns acc_x, acc_y, acc_z, gyr_x, gyr_y, gyr_z[, mag_x ...])"

log = logging.getLogger(__name__)

# Documented in datasets/gaitmap-*/ABOUT.md; used only for files whose first column is a sample index.
KNOWN_RATES_HZ: dict[str, float] = {
    "imu_sample.csv": 204.8,
    "imu_sample_healthy_stair_up.csv": 204.8,
    "imu_sample_healthy_stair_down.csv": 204.8,
    "aligned_data_with_mag_l_walks.csv": 400.0,
}
MOCAP_RATE_HZ = 100.0
_AXES = ("acc_x", "acc_y", "acc_z", "gyr_x", "gyr_y", "gyr_z")
_MAG = ("mag_x", "mag_y", "mag_z")
_UNIT = re.compile(r"(?P<name>.*?)\s*[\[(](?P<unit>[^\])]*)[\])]")  # "gyr_x [rad/s]", "acc_x (m/s^2)"
_ACC_UNITS = {"m/s^2": 1.0, "m/s2": 1.0, "m/s²": 1.0, "g": G0}  # factor to m/s^2
_GYR_UNITS = {"deg/s": "deg/s", "°/s": "deg/s", "dps": "deg/s", "rad/s": "rad/s"}
_MAG_UNITS = ("ut", "µt", "μt")


def _split_unit(column: str) -> tuple[str, str | None]:
    """``"gyr_x [rad/s]"`` -> ``("gyr_x", "rad/s")``; a name without a unit -> ``(name, None)``."""
    m = _UNIT.fullmatch(column.strip())
    return (m.group("name"), m.group("unit").strip()) if m else (column, None)


def _stated_unit(p: Path, columns: list[str], units: list[str | None], known: tuple[str, ...]) -> str | None:
    """The unit the header states for one sensor's three columns (lower case), ``None`` when it states none;
    refused when the axes disagree or the unit is not one of ``known``."""
    given = {u.lower() for u in units if u}
    if not given:
        return None
    if len(given) > 1 or None in units:
        raise ImporterError(p, columns[0], f"the axes {', '.join(columns)} state different units "
                            f"({', '.join(u or 'none' for u in units)})")
    unit = given.pop()
    if unit not in known:
        raise ImporterError(p, columns[0], f"unit {unit!r} not understood (expected one of: {', '.join(known)})")
    return unit


def _headers(p: Path) -> tuple[list[str], list[str] | None, list[str | None]]:
    """Column names without their units, the sensor row of a two-sensor file (else ``None``), and each
    column's stated unit (``None`` where it states none)."""
    axes, sensors = _header_rows(p)
    split = [_split_unit(a) for a in axes]
    return [n for n, _ in split], sensors, [u for _, u in split]


def _header_rows(p: Path) -> tuple[list[str], list[str] | None]:
    try:
        with open(p, encoding="utf-8-sig", newline="") as fh:
            first, second = fh.readline(), fh.readline()
    except OSError as exc:
        raise ImporterError(p, "file", f"cannot be read ({exc})") from exc
    sep = csv_separator(first)
    h1 = csv_fields(first, sep) if first.strip() else []
    h2 = csv_fields(second, sep) if second.strip() else []
    if not h1:
        raise ImporterError(p, "header", "empty file")
    if any(c in ("left_sensor", "right_sensor") for c in h1):
        return h2, h1
    return h1, None


def sniff(path: str | Path) -> bool:
    """True for a ``.csv`` with gaitmap acc_x..gyr_z columns."""
    p = Path(path)
    if p.suffix.lower() != ".csv":
        return False
    try:
        axes, _, _ = _headers(p)
    except ImporterError:
        return False
    return all(a in axes for a in _AXES)


def sensor_feet(path: str | Path) -> tuple[str, ...]:
    """The ``foot=`` values :func:`load_gaitmap` accepts for this file: the feet whose sensor the two-sensor
    layout holds (both, or only one), ``("left",)`` (ignored) for a single sensor."""
    _, sensors, _ = _headers(Path(path))
    if sensors is None:
        return ("left",)
    return tuple(f for f in ("left", "right") if f"{f}_sensor" in sensors)


def load(path: str | Path) -> Recording:
    """:func:`load_gaitmap` with defaults: the left foot, or the only foot a two-sensor file holds."""
    feet = sensor_feet(path)
    return load_gaitmap(path, foot=feet[0] if feet else "left")


def load_gaitmap(
    path: str | Path,
    foot: str = "left",
    rate_hz: float | None = None,
    mag_scale_ut: float | None = None,
) -> Recording:
    """Read a gaitmap example CSV into SI units.

    Parameters
    ----------
    path : str or Path
        The CSV file.
    foot : {"left", "right"}
        Sensor to read from two-sensor files (ignored for single-sensor files).
    rate_hz : float, optional
        Sample rate [Hz] for files indexed by sample number (default: ``KNOWN_RATES_HZ`` by file name).
    mag_scale_ut : float, optional
        Field magnitude [uT] that the normalised magnetometer unit 1.0 stands for (the calibration site's
        field); without it the magnetometer is not imported.

    Returns
    -------
    Recording
        acc [m/s^2], gyr [rad/s] (from deg/s, or as read: ``meta.units_converted["gyr"]`` says which and why),
        optionally mag [uT]; time from the first sample (t = 0).
    """
    p = Path(path)
    axes, sensors, stated = _headers(p)
    if foot not in ("left", "right"):
        raise ValueError(f"foot must be 'left' or 'right', got {foot!r}")
    data, notes, n_lines = read_csv_rows(p, len(axes), skip_header=2 if sensors else 1)
    if n_lines == 0:
        raise ImporterError(p, "rows", "no samples (empty file)")

    def col(name: str) -> int:
        for i, a in enumerate(axes):
            if a == name and (sensors is None or sensors[i] == f"{foot}_sensor"):
                return i
        raise ImporterError(p, name, f"column missing{'' if sensors is None else f' for {foot}_sensor'}")

    idx = [col(a) for a in _AXES]
    has_mag = sensors is None and all(m in axes for m in _MAG)
    midx = [col(m) for m in _MAG] if has_mag else []
    if axes[0] in _AXES + _MAG:
        # no index/time column (a DataFrame saved without its index): the rows are consecutive samples, which
        # needs the rate; reading acc_x as a clock would only say "timestamps go backwards"
        rate0 = rate_hz if rate_hz is not None else KNOWN_RATES_HZ.get(p.name)
        if rate0 is None:
            raise ImporterError(p, axes[0], "the first column is a sensor column: the file has no sample index or "
                                "time [s] column, so the sample times are unknown; add one or pass rate_hz")
        data = np.column_stack([np.arange(data.shape[0], dtype=np.float64), data])
        idx, midx = [i + 1 for i in idx], [i + 1 for i in midx]
        notes.append(f"no index/time column: rows taken as consecutive samples at {rate0:g} Hz")
        axes = ["row"] + axes
        stated = [None] + stated
        if sensors is not None:
            sensors = [""] + sensors
        rate_hz = rate0
    tname = axes[0] or "index/time"
    keep, tn = drop_untimed_rows(p, tname, data[:, 0], n_total=n_lines)
    notes += tn
    data = data[keep]
    first = data[:, 0]
    # a sample index: whole numbers counting up by one (a dropped sample leaves a step of 2, not a new unit)
    steps = np.diff(first)
    is_index = bool(first.size > 1 and np.allclose(first, np.round(first)) and np.all(steps >= 0)
                    and float(np.median(steps)) == 1.0)
    if is_index:
        rate = rate_hz if rate_hz is not None else KNOWN_RATES_HZ.get(p.name)
        if rate is None:
            raise ImporterError(p, axes[0] or "column 0", "first column is a sample index and the rate is unknown: pass rate_hz")
        t_s = (first - first[0]) / float(rate)
    else:
        t_s = first - first[0]
    t_ns = np.round(t_s * 1e9).astype(np.int64)
    acc_t, acc_v, n1 = clean_stream(p, tname, [axes[i] for i in idx[:3]], t_ns, data[:, idx[:3]])
    gyr_t, gyr_v, n2 = clean_stream(p, tname, [axes[i] for i in idx[3:]], t_ns, data[:, idx[3:]])
    mag_t = mag_v = None
    n3: list[str] = []
    if midx:
        mag_t, mag_v, n3 = clean_stream(p, tname, [axes[i] for i in midx], t_ns, data[:, midx], required=False)
    notes += n1 + n2 + n3
    assert acc_v is not None and gyr_v is not None  # required streams: clean_stream raises instead
    units: dict[str, str] = {}
    acc_unit = _stated_unit(p, [axes[i] for i in idx[:3]], [stated[i] for i in idx[:3]], tuple(_ACC_UNITS))
    acc = acc_v * _ACC_UNITS[acc_unit or "m/s^2"]
    if acc_unit == "g":
        units["acc"] = f"g (stated) -> m/s^2 (x {G0})"
    gyr_stated = _stated_unit(p, [axes[i] for i in idx[3:]], [stated[i] for i in idx[3:]], tuple(_GYR_UNITS))
    gyr_unit, how, checked = gyro_unit(p, axes[idx[3]], acc_t, acc, gyr_t, gyr_v,
                                       _GYR_UNITS[gyr_stated] if gyr_stated else "deg/s",
                                       "the header" if gyr_stated else None)
    if gyr_unit == "deg/s":
        gyr = np.deg2rad(gyr_v)
        units["gyr"] = f"deg/s -> rad/s (x pi/180); unit: {how}"
    else:
        gyr = gyr_v
        units["gyr"] = f"rad/s, used as is; unit: {how}"
    if gyr_stated is None and (gyr_unit != "deg/s" or not checked):  # not gaitmap's deg/s, or not verifiable
        notes.append(f"gyroscope ({axes[idx[3]]}..{axes[idx[5]]}): {how}")
        log.warning("%s: %s", p, notes[-1])
    mag = None
    mag_unit = _stated_unit(p, [axes[i] for i in midx], [stated[i] for i in midx], _MAG_UNITS) if midx else None
    if mag_unit is not None and mag_v is not None:
        mag = mag_v
        units["mag"] = "uT (stated), used as is" + ("; mag_scale_ut not needed, ignored" if mag_scale_ut else "")
    elif has_mag and mag_v is not None:
        if mag_scale_ut is None:
            units["mag"] = "Xsens normalised (scale unknown) -> NOT imported; pass mag_scale_ut to convert"
            notes.append("magnetometer in Xsens normalised units with unknown scale: left out of the batch")
        else:
            mag = mag_v * float(mag_scale_ut)
            units["mag"] = f"Xsens normalised -> uT (x {mag_scale_ut:g}, user-supplied scale)"
    batch = make_batch(p, acc_t, acc, gyr_t, gyr, mag_t if mag is not None else None, mag)
    notes += gap_notes(p, batch)
    truth = _mocap_truth(p, foot) if sensors is not None else None
    meta = RecordingMeta(
        source_format="gaitmap-csv",
        rate_hz=float(batch.rate_hz("acc")),
        units_converted=units,
        mount=f"foot ({foot if sensors is not None else 'single'} sensor, gaitmap foot frame: gravity on +z at rest)",
        notes=tuple(notes),
    )
    name = f"{p.stem}-{foot}" if sensors is not None else p.stem
    return Recording(name=name, batch=batch, meta=meta, truth=truth)


def _mocap_truth(p: Path, foot: str) -> Truth | None:
    """Heel marker (``L_FCC``/``R_FCC``) of mocap_sample.csv beside imu_sample.csv, [mm] -> [m], 100 Hz."""
    if p.name != "imu_sample.csv":
        return None
    mp = p.with_name("mocap_sample.csv")
    if not mp.exists():
        return None
    with open(mp, encoding="utf-8", newline="") as fh:
        r = csv.reader(fh)
        markers, coords = next(r), next(r)
    marker = ("L" if foot == "left" else "R") + "_FCC"
    try:
        cols = [i for i, (m, c) in enumerate(zip(markers, coords)) if m == marker and c in ("x", "y", "z")]
    except ValueError:
        cols = []
    if len(cols) != 3:
        log.warning("%s: heel marker %s not found, no truth attached", mp, marker)
        return None
    a = np.atleast_2d(np.genfromtxt(mp, delimiter=",", skip_header=2, dtype=np.float64))
    pos = a[:, cols] / 1000.0
    ok = np.all(np.isfinite(pos), axis=1)
    k = np.arange(a.shape[0])[ok]
    extra: dict[str, object] = {"marker": marker, "frame": "mocap lab frame [m] (from mm)", "rate_hz": MOCAP_RATE_HZ}
    stance = _mid_stances(p.with_name("stride_events_sample.csv"), foot, KNOWN_RATES_HZ[p.name])
    if stance is not None:
        extra["stance_t_ns"] = stance
    return Truth(t_ns=np.round(k / MOCAP_RATE_HZ * 1e9).astype(np.int64), positions=pos[ok], extra=extra)


def _mid_stances(path: Path, foot: str, rate_hz: float) -> np.ndarray | None:
    """Times [ns] of the foot's still moments from gaitmap's mocap-derived stride events (``min_vel``: each
    stride runs from one to the next; the last stride's ``end`` is the next), sorted; None without the file."""
    if not path.exists():
        return None
    with open(path, encoding="utf-8", newline="") as fh:
        rows = [r for r in csv.DictReader(fh) if r.get("foot") == foot]
    try:
        idx = {float(r["min_vel"]) for r in rows} | {float(r["end"]) for r in rows}
    except (KeyError, ValueError) as exc:
        raise ImporterError(path, "min_vel/end", f"stride events unreadable ({exc})") from exc
    return np.round(np.array(sorted(idx)) / rate_hz * 1e9).astype(np.int64) if idx else None
