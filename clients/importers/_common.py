"""Shared checks of the importers: one error type, timestamp policy, finite checks, batch assembly.

Sample policy (applies to every importer; what is dropped is logged and noted in ``RecordingMeta.notes``)
------------------------------------------------------------------------------------------------------
- A row whose time is not finite (empty cell, NaN) cannot be placed: it is dropped. More than
  :data:`MAX_DROPPED_ROW_FRACTION` of such rows: the file is rejected (it is not what it claims to be).
- A sample with a non-finite value (empty cell, NaN, inf) is dropped from its stream only, as a sample the
  sensor did not deliver (loggers leave the cells of a slower stream empty; a logging glitch leaves a row
  empty). A required stream (accelerometer, gyroscope) left with fewer than :data:`MIN_SAMPLES` samples is
  rejected; an optional one (magnetometer) is then left out.
- Timestamps going backwards: rejected (:class:`ImporterError`); a file whose clock jumps back cannot be
  ordered without guessing.
- A duplicated timestamp whose row is an exact copy of the previous row (logger wrote a sample twice):
  the copy is dropped.
- A duplicated timestamp with *different* values: which of the samples is right (or whether the clock
  stalled) cannot be decided, so neither is used: every sample of that timestamp is dropped (a gap of a
  sample or two, which the engine handles). More than :data:`MAX_CONFLICT_FRACTION` of the samples in such
  groups: rejected (the clock is too coarse for the rate; dropping would leave holes everywhere).
- Jitter (monotonic, uneven spacing) is kept as recorded: the engine works with real timestamps.
- The accelerometer's median sample interval must give a rate within :data:`RATE_RANGE_HZ`; otherwise the
  time column is in another unit than the format says (ms, us, ns read as s) and the file is rejected with
  the unit it looks like, never rescaled by guess.
- Gyroscope units: a unit the header states or the format fixes is checked against how fast the sensor turns
  while its accelerometer shows motion; a file that does not say is judged the same way, and a unit the data
  contradicts, or cannot tell, is refused (:func:`gyro_unit`), never divided by 57.3 on a guess.
- Gaps: an interval longer than :data:`GAP_PERIODS` of a stream's median sample periods (a logger that paused,
  a lost radio link, a stretch of rows the policy dropped) is kept as recorded (the engine bridges a short gap
  and restarts its segment after a long one) but noted with where it is (seconds into the recording) and how
  long it lasts (:func:`gap_notes`), so a result over a hole in the data is never taken for a clean run.
"""

from __future__ import annotations

import csv
import logging
import re
import warnings
from pathlib import Path

import numpy as np

from models.batch import STREAMS, BatchError, SensorBatch

__all__ = [
    "ImporterError",
    "G0",
    "MAX_DROPPED_ROW_FRACTION",
    "MAX_CONFLICT_FRACTION",
    "MIN_SAMPLES",
    "first_line",
    "RATE_RANGE_HZ",
    "GAP_PERIODS",
    "GYR_RAD_S_MAX",
    "GYR_DEG_S_MIN",
    "seconds_to_ns",
    "check_finite",
    "clean_timestamps",
    "drop_untimed_rows",
    "clean_stream",
    "check_rate",
    "csv_separator",
    "csv_cell",
    "csv_fields",
    "read_csv_rows",
    "skipped_lines_message",
    "make_batch",
    "gap_notes",
    "gyro_unit",
    "is_hidden",
]

log = logging.getLogger(__name__)

G0 = 9.80665  # standard gravity [m/s^2], the unit "g" of accelerometer vendors
MAX_DROPPED_ROW_FRACTION = 0.10  # rows without a usable time (or malformed) above this: the file is rejected
MAX_CONFLICT_FRACTION = 0.05  # samples in conflicting duplicated-timestamp groups above this: rejected
MIN_SAMPLES = 10  # a required stream needs at least this many finite samples
RATE_RANGE_HZ = (2.0, 10000.0)  # plausible accelerometer rates [Hz]; outside: the time unit is not seconds
# a longer interval is a gap worth a note: jitter (< 2 periods in the VICON and gdin files) and the sample or two
# the policy drops for a conflicting timestamp (noted on their own) stay below it; ten missing samples do not
GAP_PERIODS = 10.0
# Gyroscope unit from the data: the 99th percentile of |w| at gyroscope samples within _MOTION_NEAR_S of an
# accelerometer sample in motion (| |a| - 1 g | > _MOTION_MS2), in the file's numbers. Measured on the foot
# recordings (42 VICON trials, 30 gdin walks, 7 gaitmap feet, slow shuffling to running): 1.5-12.2 rad/s, i.e.
# 89-700 deg/s; sprinting feet stay below about 30 rad/s. So <= GYR_RAD_S_MAX reads as rad/s (as deg/s it would
# be a foot turning at < 0.5 rad/s while it walks), >= GYR_DEG_S_MIN as deg/s (as rad/s: > 2500 deg/s);
# in between the data cannot tell. Judged only with motion in at least _MIN_MOTION_FRACTION of the samples.
GYR_RAD_S_MAX = 30.0
GYR_DEG_S_MIN = 45.0
_MOTION_MS2 = 2.0
_MOTION_NEAR_S = 0.2
_MIN_MOTION_FRACTION = 0.05
_GAPS_LISTED = 5  # gaps named in a note (the count and the longest are always given)
_MAX_SECONDS = 9.0e9  # |t| [s] that int64 nanoseconds can hold (2^63 ns = 9.22e9 s)


class ImporterError(ValueError):
    """A recording cannot be imported.

    Attributes
    ----------
    path : str
        File that was read.
    field : str
        Column / variable / stream at fault (e.g. ``"scaledAccelX"``, ``"Time"``, ``"imu"``).
    problem : str
        What is wrong with it.
    """

    def __init__(self, path: str | Path, field: str, problem: str) -> None:
        super().__init__(f"{path}: {field}: {problem}")
        self.path = str(path)
        self.field = field
        self.problem = problem


def is_hidden(path: str | Path) -> bool:
    """True when any part of ``path`` (give it relative to the folder scanned, or a zip member's name) is a
    dotfile/dot-folder, including the macOS AppleDouble resource forks ``._name`` that copying to a FAT/exFAT
    or network drive leaves beside every file, or a zip's ``__MACOSX`` folder of them. Folder scans skip these:
    they are never recordings (an AppleDouble ``._trial.mat`` holds Finder metadata, not MATLAB data)."""
    parts = Path(path).parts
    return any((part.startswith(".") and part not in (".", "..")) or part == "__MACOSX" for part in parts)


def seconds_to_ns(path: str | Path, field: str, t_s: np.ndarray) -> np.ndarray:
    """Convert a time column [s] to int64 nanoseconds, rejecting non-finite times.

    Parameters
    ----------
    path, field : str
        Used in error messages.
    t_s : ndarray, shape (N,)
        Times [s].

    Returns
    -------
    ndarray of int64, shape (N,)
        Times [ns].
    """
    t = np.asarray(t_s, dtype=np.float64).reshape(-1)
    if not np.all(np.isfinite(t)):
        i = int(np.argmax(~np.isfinite(t)))
        raise ImporterError(path, field, f"time of row {i} is not finite ({t[i]})")
    if t.size and float(np.max(np.abs(t))) > _MAX_SECONDS:
        raise ImporterError(path, field, f"time {float(np.max(np.abs(t))):.6g} is beyond int64 nanoseconds as seconds: "
                            "the times look like nanoseconds or microseconds, not seconds; refusing to guess")
    return np.round(t * 1e9).astype(np.int64)


def check_finite(path: str | Path, columns: list[str], values: np.ndarray) -> None:
    """Raise naming the column and row of the first NaN/inf in ``values`` (N, len(columns))."""
    v = np.asarray(values, dtype=np.float64)
    bad = ~np.isfinite(v)
    if bad.any():
        row, col = np.argwhere(bad)[0]
        raise ImporterError(path, columns[int(col)], f"row {int(row)} is not finite ({v[row, col]})")


def clean_timestamps(
    path: str | Path, field: str, t_ns: np.ndarray, values: np.ndarray
) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Apply the module's timestamp policy to one time axis and its rows.

    Parameters
    ----------
    path, field : str
        Used in error messages (``field`` = the time column).
    t_ns : ndarray of int64, shape (N,)
        Sample times [ns].
    values : ndarray, shape (N, M)
        All value columns sharing that time axis (any units; NaN equals NaN when rows are compared).

    Returns
    -------
    t_ns, values : ndarray
        With exact duplicate rows reduced to one and conflicting duplicated timestamps removed.
    notes : list of str
        What was repaired (empty when nothing was).

    Raises
    ------
    ImporterError
        Empty, timestamps going backwards, or conflicting duplicates above :data:`MAX_CONFLICT_FRACTION`.
    """
    t = np.asarray(t_ns, dtype=np.int64)
    v = np.asarray(values, dtype=np.float64).reshape(t.size, -1)
    if t.size == 0:
        raise ImporterError(path, field, "no samples (empty file)")
    d = np.diff(t)
    if np.any(d < 0):
        i = int(np.argmax(d < 0)) + 1
        raise ImporterError(path, field, f"timestamps go backwards at row {i} ({t[i - 1]} -> {t[i]} ns)")
    notes: list[str] = []
    dup = np.flatnonzero(d == 0) + 1
    if not dup.size:
        return t, v, notes
    a, b = v[dup], v[dup - 1]
    same = np.all((a == b) | (np.isnan(a) & np.isnan(b)), axis=1)
    keep = np.ones(t.size, dtype=bool)
    keep[dup[same]] = False  # exact copies: the first one stays
    n_copies = int(same.sum())
    if n_copies:
        msg = f"{field}: dropped {n_copies} exact duplicate row(s) (repeated timestamp and values)"
        log.warning("%s: %s", path, msg)
        notes.append(msg)
    conflict_t = np.unique(t[dup[~same]])
    if conflict_t.size:
        bad = np.isin(t, conflict_t)
        n_bad = int(bad.sum())
        if n_bad > MAX_CONFLICT_FRACTION * t.size:
            i = int(dup[~same][0])
            raise ImporterError(
                path, field, f"{n_bad} of {t.size} samples share a timestamp with different values (first at row {i}, "
                f"{t[i]} ns): the clock is too coarse for the sample rate; cannot tell the samples' times")
        keep &= ~bad
        msg = (f"{field}: {conflict_t.size} timestamp(s) carried different values (first {int(conflict_t[0])} ns); "
               f"all {n_bad} sample(s) at them dropped (cannot tell which is right)")
        log.warning("%s: %s", path, msg)
        notes.append(msg)
    return t[keep], v[keep], notes


def drop_untimed_rows(
    path: str | Path, field: str, t_s: np.ndarray, n_total: int | None = None
) -> tuple[np.ndarray, list[str]]:
    """Which rows have a finite time; rejects a file where too many do not.

    Parameters
    ----------
    path, field : str
        Used in error messages and notes (``field`` = the time column).
    t_s : ndarray, shape (N,)
        Times [any unit]; NaN/inf where the cell was empty or unreadable.
    n_total : int, optional
        Rows the file had before other rows were discarded (e.g. malformed lines) that count against
        :data:`MAX_DROPPED_ROW_FRACTION` too (default N).

    Returns
    -------
    keep : ndarray of bool, shape (N,)
        Rows with a finite time.
    notes : list of str
    """
    t = np.asarray(t_s, dtype=np.float64).reshape(-1)
    keep = np.isfinite(t)
    total = max(int(n_total if n_total is not None else t.size), 1)
    lost = total - int(keep.sum())
    if not keep.any():
        raise ImporterError(path, field, "no row has a finite time")
    if lost > MAX_DROPPED_ROW_FRACTION * total:
        i = int(np.argmax(~keep)) if (~keep).any() else -1
        raise ImporterError(path, field, f"{lost} of {total} rows have no usable time (first unusable row {i}): "
                            "not a recording this importer can trust")
    notes: list[str] = []
    if (~keep).any():
        i = int(np.argmax(~keep))
        msg = f"{field}: dropped {int((~keep).sum())} row(s) whose time is not finite (first row {i})"
        log.warning("%s: %s", path, msg)
        notes.append(msg)
    return keep, notes


def clean_stream(
    path: str | Path, time_field: str, columns: list[str], t_ns: np.ndarray, values: np.ndarray, required: bool = True
) -> tuple[np.ndarray | None, np.ndarray | None, list[str]]:
    """One sensor stream after the sample policy: non-finite samples dropped, then :func:`clean_timestamps`.

    Parameters
    ----------
    path, time_field : str
        Used in error messages and notes.
    columns : list of str
        Names of the value columns (errors and notes name the first one).
    t_ns : ndarray of int64, shape (N,)
        Sample times [ns] (finite).
    values : ndarray, shape (N, M)
        The stream's values (any units); NaN/inf where the sensor did not deliver.
    required : bool
        An accelerometer/gyroscope (True: fewer than :data:`MIN_SAMPLES` finite samples is an error) or an
        optional stream (False: then ``None`` is returned with a note).

    Returns
    -------
    t_ns, values : ndarray or None
        The usable samples (``None`` for an optional stream without any).
    notes : list of str
    """
    t = np.asarray(t_ns, dtype=np.int64).reshape(-1)
    v = np.asarray(values, dtype=np.float64).reshape(t.size, -1)
    ok = np.all(np.isfinite(v), axis=1)
    notes: list[str] = []
    name = columns[0] if columns else "values"
    if int(ok.sum()) < (MIN_SAMPLES if required else 1):
        if required:
            raise ImporterError(path, name, f"only {int(ok.sum())} of {t.size} samples are finite: no usable stream")
        msg = f"{name}: no finite sample; stream left out"
        log.warning("%s: %s", path, msg)
        return None, None, [msg]
    if not ok.all():
        i = int(np.argmax(~ok))
        msg = f"{name}: dropped {int((~ok).sum())} sample(s) with a non-finite value (first row {i})"
        log.warning("%s: %s", path, msg)
        notes.append(msg)
        t, v = t[ok], v[ok]
    t, v, n = clean_timestamps(path, time_field, t, v)
    return t, v, notes + n


def check_rate(path: str | Path, field: str, t_ns: np.ndarray) -> None:
    """Reject a time axis whose median sample interval is not a plausible IMU rate (:data:`RATE_RANGE_HZ`).

    A time column in milliseconds read as seconds gives intervals of ~5 "s" (0.2 Hz); one in nanoseconds gives
    ~5e6 "s". The message says which unit it looks like; the importer never rescales by guess.
    """
    t = np.asarray(t_ns, dtype=np.int64)
    if t.size < MIN_SAMPLES:
        return
    dt_s = float(np.median(np.diff(t))) * 1e-9
    lo, hi = RATE_RANGE_HZ
    if dt_s <= 0 or not (1.0 / hi <= dt_s <= 1.0 / lo):
        rate = 1.0 / dt_s if dt_s > 0 else float("inf")
        if dt_s > 1.0 / lo:
            hint = next((u for u, k in (("milliseconds", 1e3), ("microseconds", 1e6), ("nanoseconds", 1e9))
                         if 1.0 / hi <= dt_s / k <= 1.0 / lo), "another unit")
        else:
            hint = "another unit (or far too many samples per second)"
        raise ImporterError(
            path, field, f"median sample interval {dt_s:.6g} s ({rate:.4g} Hz) is not a plausible IMU rate "
            f"({lo:g}-{hi:g} Hz): the times look like {hint}, not seconds; refusing to guess")


def skipped_lines_message(bad_lines: list[int], n_fields: int) -> str:
    """What a note says of data lines skipped for not having the header's ``n_fields`` fields (the first five
    line numbers, 1-based)."""
    shown = ", ".join(str(k) for k in bad_lines[:5]) + (" ..." if len(bad_lines) > 5 else "")
    return f"skipped {len(bad_lines)} line(s) without {n_fields} fields (line {shown})"


def first_line(path: str | Path, empty: tuple[str, str] = ("file", "is empty")) -> str:
    """The first line of a text file (a byte-order mark dropped); ``ImporterError`` naming the file when it
    cannot be read, and ``empty`` (field, problem) when that line is blank."""
    p = Path(path)
    try:
        with open(p, encoding="utf-8-sig", errors="replace") as fh:
            line = fh.readline()
    except OSError as exc:
        raise ImporterError(p, "file", f"cannot be read ({exc})") from None
    if not line.strip():
        raise ImporterError(p, *empty)
    return line


def csv_separator(first_line: str) -> str:
    """The field separator of a CSV file from its first line: tab, semicolon (the European spreadsheet
    export, whose decimal separator is the comma) or comma."""
    if "\t" in first_line:
        return "\t"
    return ";" if first_line.count(";") > first_line.count(",") else ","


def csv_cell(cell: str, sep: str) -> float:
    """A number cell as float: surrounding blanks and quotes ignored, a decimal comma accepted unless the comma
    separates the fields; empty or unreadable -> NaN (the sample policy drops that sample)."""
    c = cell.strip().strip('"').strip()
    try:
        return float(c.replace(",", ".") if sep != "," else c)
    except ValueError:
        return float("nan")


def csv_fields(line: str, sep: str | None = None) -> list[str]:
    """The fields of one CSV line (a header), quotes removed and blanks stripped; ``sep`` default: the line's
    own (:func:`csv_separator`)."""
    row = next(csv.reader([line.rstrip("\r\n")], delimiter=sep or csv_separator(line)), [])
    return [c.strip().strip('"').strip() for c in row]


_COMMA_NUMBER = re.compile(r"[+-]?\d[\d,]*(\.\d*)?([eE][+-]?\d+)?")  # "0,005", "1,234.5": a number with a comma


def _refuse_quoted_commas(path: Path, rows: list[list[str]], line_numbers: list[int], header: list[str]) -> None:
    """A quoted number with a comma in a comma-separated file (``"0,005"``) is a decimal comma or a thousands
    separator (``"1,234"``): which one cannot be told, so such a file is refused, naming the first cell."""
    for k, row in zip(line_numbers, rows):
        for j, c in enumerate(row):
            if "," in c and _COMMA_NUMBER.fullmatch(c.strip()):
                col = header[j] if j < len(header) and header[j] else f"column {j + 1}"
                raise ImporterError(path, col, f"line {k} holds the quoted number {c!r} in a comma-separated file: a "
                                    "decimal comma or a thousands separator, which cannot be told apart; export "
                                    "with a decimal point, or with ';' between the fields")


def read_csv_rows(path: str | Path, n_cols: int, skip_header: int = 1) -> tuple[np.ndarray, list[str], int]:
    """The data rows of a CSV file with ``n_cols`` fields per line, as floats.

    The separator is the first line's (:func:`csv_separator`): comma, semicolon or tab; with a semicolon or tab
    a decimal comma is read as a decimal point (the European spreadsheet export). Quoted cells (``"0.005"``,
    as pandas' ``QUOTE_ALL`` and many spreadsheets write them) are read as their numbers. Empty or unreadable
    cells become NaN (the sample policy then drops them per stream). Lines with another number of fields (e.g.
    the last line of a logger stopped mid-write) are skipped and named in a note; blank lines are ignored;
    CR/LF line ends are both accepted.

    Parameters
    ----------
    path : str or Path
        The file.
    n_cols : int
        Fields per line (the header's).
    skip_header : int
        Header lines before the data.

    Returns
    -------
    rows : ndarray, shape (R, n_cols)
    notes : list of str
    n_lines : int
        Non-blank data lines in the file (read or not), for :func:`drop_untimed_rows`.
    """
    p = Path(path)
    try:
        with open(p, encoding="utf-8-sig", errors="replace", newline=None) as fh:
            text = fh.read()
    except OSError as exc:
        raise ImporterError(p, "file", f"cannot be read ({exc})") from exc
    lines = text.splitlines()
    sep = csv_separator(lines[0]) if lines else ","
    numbered = [(i + skip_header + 1, ln) for i, ln in enumerate(lines[skip_header:]) if ln.strip()]
    plain = sep == "," and '"' not in text  # the common flavour: counted and parsed without the csv module
    if plain:
        n_fields = [ln.count(",") + 1 for _, ln in numbered]
    else:  # quotes may hold a separator; the csv module splits such lines right
        fields = list(csv.reader((ln for _, ln in numbered), delimiter=sep))
        n_fields = [len(f) for f in fields]
    good = [i for i, n in enumerate(n_fields) if n == n_cols]
    bad = [numbered[i][0] for i, n in enumerate(n_fields) if n != n_cols]
    notes: list[str] = []
    if bad:
        msg = skipped_lines_message(bad, n_cols)
        log.warning("%s: %s", p, msg)
        notes.append(msg)
    if len(bad) > MAX_DROPPED_ROW_FRACTION * max(len(numbered), 1):
        raise ImporterError(p, "rows", f"{len(bad)} of {len(numbered)} lines do not have the header's {n_cols} fields "
                            f"(first: line {bad[0]}): not the format the header announces")
    if not good:
        return np.zeros((0, n_cols)), notes, len(numbered)
    if not plain:
        if sep == ",":
            _refuse_quoted_commas(p, [fields[i] for i in good], [numbered[i][0] for i in good],
                                  csv_fields(lines[skip_header - 1], sep) if skip_header else [])
        data = np.array([[csv_cell(c, sep) for c in fields[i]] for i in good], dtype=np.float64)
        return data.reshape(len(good), n_cols), notes, len(numbered)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # unreadable cells become NaN, handled by the sample policy
        data = np.genfromtxt([numbered[i][1] for i in good], delimiter=",", dtype=np.float64, invalid_raise=True)
    return np.atleast_2d(data).reshape(len(good), n_cols), notes, len(numbered)


def make_batch(
    path: str | Path,
    acc_t_ns: np.ndarray,
    acc: np.ndarray,
    gyr_t_ns: np.ndarray | None = None,
    gyr: np.ndarray | None = None,
    mag_t_ns: np.ndarray | None = None,
    mag: np.ndarray | None = None,
) -> SensorBatch:
    """Assemble and validate a :class:`SensorBatch` (SI units), turning a ``BatchError`` into an
    :class:`ImporterError` that names the file; the accelerometer's rate must be plausible
    (:func:`check_rate`)."""
    check_rate(path, "acc time", acc_t_ns)
    kw: dict[str, np.ndarray] = {"acc_t_ns": acc_t_ns, "acc": acc}
    if gyr is not None and gyr_t_ns is not None:
        kw.update(gyr_t_ns=gyr_t_ns, gyr=gyr)
    if mag is not None and mag_t_ns is not None:
        kw.update(mag_t_ns=mag_t_ns, mag=mag)
    try:
        return SensorBatch(**kw).validate()
    except BatchError as exc:
        raise ImporterError(path, exc.field, exc.problem) from exc


def gap_notes(path: str | Path, batch: SensorBatch) -> list[str]:
    """Notes on the gaps of each stream of ``batch``: intervals longer than :data:`GAP_PERIODS` times the
    stream's median sample interval, each given by where it starts (seconds after the recording's first sample)
    and how long it lasts. Streams with the same gaps (accelerometer and gyroscope of one row-per-sample file)
    share one note. Logged as warnings; empty when there is no gap."""
    t_start = batch.t_start_ns
    groups: dict[tuple[tuple[int, int], ...], list[str]] = {}
    period: dict[str, float] = {}
    for name in STREAMS:
        t = batch.stream(name)[0]
        if t.size < MIN_SAMPLES:
            continue
        d = np.diff(t)
        dt = float(np.median(d))
        at = np.flatnonzero(d > GAP_PERIODS * dt)
        if dt <= 0 or not at.size:
            continue
        groups.setdefault(tuple((int(t[i]), int(t[i + 1])) for i in at), []).append(name)
        period[name] = dt
    notes: list[str] = []
    for gaps, names in groups.items():
        dt = period[names[0]]
        length = [(b - a) * 1e-9 for a, b in gaps]
        shown = ", ".join(f"{g:.4g} s from t = {(a - t_start) * 1e-9:.3f} s"
                          for g, (a, _) in zip(length[:_GAPS_LISTED], gaps))
        more = f" and {len(gaps) - _GAPS_LISTED} more" if len(gaps) > _GAPS_LISTED else ""
        msg = (f"{'/'.join(names)}: {len(gaps)} time gap(s) longer than {GAP_PERIODS:g} sample periods "
               f"({GAP_PERIODS * dt * 1e-9:.3g} s), no samples there: {shown}{more}; longest {max(length):.4g} s "
               "(t from the recording's first sample)")
        log.warning("%s: %s", path, msg)
        notes.append(msg)
    return notes


def _turn_rate_in_motion(acc_t_ns: np.ndarray, acc: np.ndarray, gyr_t_ns: np.ndarray, gyr: np.ndarray) -> float | None:
    """99th percentile of |w| [the file's unit] near the accelerometer's moments of motion; ``None`` when the
    accelerometer (m/s^2) shows too little motion to judge (a still or nearly still recording)."""
    a = np.linalg.norm(np.asarray(acc, dtype=np.float64), axis=1)
    moving = np.abs(a - G0) > _MOTION_MS2
    if int(moving.sum()) < max(MIN_SAMPLES, _MIN_MOTION_FRACTION * a.size) or len(gyr_t_ns) < MIN_SAMPLES:
        return None
    tm = np.asarray(acc_t_ns, dtype=np.int64)[moving]
    tg = np.asarray(gyr_t_ns, dtype=np.int64)
    j = np.clip(np.searchsorted(tm, tg), 1, tm.size - 1)
    dist = np.minimum(np.abs(tg - tm[j - 1]), np.abs(tm[j] - tg))
    w = np.linalg.norm(np.asarray(gyr, dtype=np.float64)[dist <= _MOTION_NEAR_S * 1e9], axis=1)
    return float(np.percentile(w, 99)) if w.size >= MIN_SAMPLES else None


def gyro_unit(
    path: str | Path, column: str, acc_t_ns: np.ndarray, acc: np.ndarray, gyr_t_ns: np.ndarray, gyr: np.ndarray,
    unit: str, stated_by: str | None,
) -> tuple[str, str, bool]:
    """The unit of a gyroscope stream, ``"rad/s"`` or ``"deg/s"``, judged by how fast it turns while the
    accelerometer shows motion (thresholds :data:`GYR_RAD_S_MAX`, :data:`GYR_DEG_S_MIN`). Importers of a
    rad/s format call it for its check alone; one whose unit is a convention (gaitmap) also for the answer.

    Parameters
    ----------
    path, column : str
        Used in errors (``column``: the gyroscope's first column).
    acc_t_ns, acc : ndarray
        The accelerometer, already in m/s^2.
    gyr_t_ns, gyr : ndarray
        The gyroscope in the file's numbers.
    unit : {"rad/s", "deg/s"}
        The unit stated by ``stated_by``, or else the format's convention.
    stated_by : str or None
        Who states ``unit`` (``"the header"``, ``"the format"``): data that contradict it are refused. None:
        nothing states it; the data decide, and the convention stands only for a recording with too little
        motion to tell (which the returned text says).

    Returns
    -------
    unit : str
        The unit the values are in.
    how : str
        What decided it, for ``units_converted``/notes.
    checked : bool
        False when the recording had too little motion to check the unit (``unit`` is then as given).

    Raises
    ------
    ImporterError
        A stated unit the data contradict; an unstated one whose magnitudes fit neither unit.
    """
    level = _turn_rate_in_motion(acc_t_ns, acc, gyr_t_ns, gyr)
    source = f"stated by {stated_by}" if stated_by else "not stated: the format's convention"
    if level is None:
        return unit, f"{unit} ({source}; not checked: too little motion in the recording to tell rad/s from deg/s)", False
    seen = "rad/s" if level <= GYR_RAD_S_MAX else "deg/s" if level >= GYR_DEG_S_MIN else None
    what = f"99th percentile of |w| while the sensor moves = {level:.3g}"
    ranges = (f"a moving foot turns at about 1.5-30 rad/s = 90-1700 deg/s: <= {GYR_RAD_S_MAX:g} reads as rad/s, "
              f">= {GYR_DEG_S_MIN:g} as deg/s")
    if seen == unit:
        return unit, f"{unit} ({source}; the motion agrees: {what})", True
    if stated_by and seen is not None:
        raise ImporterError(path, column, f"{stated_by} says {unit} but the values are {seen}: {what} ({ranges}); "
                            "refusing to guess which is wrong")
    if stated_by:
        return unit, f"{unit} ({source}; the motion neither confirms nor contradicts it: {what})", True
    if seen is None:
        raise ImporterError(path, column, f"no unit stated and the values fit neither rad/s nor deg/s: {what} "
                            f"({ranges}); state the unit in the header, e.g. '{column} [deg/s]'")
    return seen, f"{seen} (not stated, and not the format's {unit}: {what}; {ranges})", True
