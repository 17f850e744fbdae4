"""phyphox (RWTH Aachen) CSV exports: one CSV per sensor, a zip of them, or a single CSV.

Each CSV has a header like ``"Time (s)","Acceleration x (m/s^2)","Acceleration y (m/s^2)",...``; the sensor and
its unit are read from the column names: ``Acceleration`` (with g, m/s^2; the "Acceleration with g"
experiment), ``Linear Acceleration`` (gravity removed: refused, it is not specific force), ``Gyroscope``
(rad/s) and ``Magnetic field`` (uT). Time is seconds from the start of the experiment; phyphox's
``meta/time.csv`` gives the system time of that start, used (when present) to place the samples on the UTC
epoch. All of phyphox's CSV flavours are read: comma (decimal point), tab (decimal point or comma) and
semicolon (decimal comma). Damaged files follow the sample policy of :mod:`clients.importers._common`: a line
cut mid-write is skipped, an empty cell drops that sample, a header-only gyroscope/magnetometer table is left
out; all noted.
"""

from __future__ import annotations

import csv
import io
import logging
import zipfile
from pathlib import Path

import numpy as np

from clients.importers._common import (
    MAX_DROPPED_ROW_FRACTION,
    ImporterError,
    clean_stream,
    csv_cell,
    csv_fields,
    csv_separator,
    drop_untimed_rows,
    gap_notes,
    gyro_unit,
    is_hidden,
    make_batch,
    skipped_lines_message,
)
from clients.recording import Recording, RecordingMeta

__all__ = ["FORMAT", "sniff", "load", "load_phyphox"]

FORMAT = "phyphox export (CSV header \"Time (s)\",\"Acceleration x (m/s^2)\",...; folder or zip)"

log = logging.getLogger(__name__)


def _parse(text: str, where: str) -> tuple[list[str], np.ndarray, list[str]]:
    """Header and data rows of one phyphox CSV.

    Sample policy of :mod:`clients.importers._common`: a line with another number of fields than the header
    (an export cut mid-write) is skipped and noted; an empty or unreadable cell becomes NaN (dropped per
    stream later); too many skipped lines: :class:`ImporterError`.

    Returns
    -------
    head : list of str
        Column names.
    data : ndarray, shape (R, len(head))
        Values in the file's units (phyphox: s, m/s^2, rad/s, uT); R may be 0 (header only).
    notes : list of str
    """
    first = text.splitlines()[0] if text else ""
    sep = csv_separator(first)
    rows = list(csv.reader(io.StringIO(text), delimiter=sep))
    if not rows:
        raise ImporterError(where, "header", "empty file")
    head = [h.strip() for h in rows[0]]
    body = [(k + 2, r) for k, r in enumerate(rows[1:]) if any(c.strip() for c in r)]
    bad = [k for k, r in body if len(r) != len(head)]
    notes: list[str] = []
    if bad:
        notes.append(f"{where}: {skipped_lines_message(bad, len(head))}")
        log.warning("%s", notes[-1])
        if len(bad) > MAX_DROPPED_ROW_FRACTION * len(body):
            raise ImporterError(where, "rows", f"{len(bad)} of {len(body)} lines do not have the header's {len(head)} "
                                f"fields (first: line {bad[0]}): not a phyphox export this importer can trust")
    data = np.array([[csv_cell(c, sep) for c in r] for _, r in body if len(r) == len(head)], dtype=np.float64)
    return head, data.reshape(-1, len(head)), notes


def _kind(head: list[str]) -> str | None:
    joined = " ".join(head).lower()
    if "linear acceleration" in joined:
        return "linear"
    if "acceleration x" in joined:
        return "acc"
    if "gyroscope x" in joined:
        return "gyr"
    if "magnetic field x" in joined:
        return "mag"
    return None


def _xyz_columns(head: list[str], where: str) -> list[int]:
    idx = []
    for axis in ("x", "y", "z"):
        hits = [i for i, h in enumerate(head) if f" {axis} (" in h.lower()]
        if not hits:
            raise ImporterError(where, f"{axis} column", f"missing in header {head}")
        idx.append(hits[0])
    return idx


def _files(path: Path) -> tuple[list[tuple[str, str]], str | None]:
    """``[(name, text)]`` of the sensor CSVs and the meta/time.csv text."""
    out: list[tuple[str, str]] = []
    time_csv = None
    if path.suffix.lower() == ".zip":
        with zipfile.ZipFile(path) as zf:
            for n in zf.namelist():
                if n.lower().endswith("meta/time.csv"):
                    time_csv = zf.read(n).decode("utf-8-sig")
                elif n.lower().endswith(".csv") and "/meta/" not in "/" + n.lower() and not is_hidden(n):
                    out.append((f"{path}:{n}", zf.read(n).decode("utf-8-sig")))
        return out, time_csv
    folder = path if path.is_dir() else None
    if folder is None:
        out.append((str(path), path.read_text(encoding="utf-8-sig")))
        meta = path.parent / "meta" / "time.csv"
    else:
        out += [(str(f), f.read_text(encoding="utf-8-sig")) for f in sorted(folder.glob("*.csv"))
                if not is_hidden(f.name)]
        meta = folder / "meta" / "time.csv"
    if meta.exists():
        time_csv = meta.read_text(encoding="utf-8-sig")
    return out, time_csv


def _epoch_ns(time_csv: str | None) -> tuple[int, str | None]:
    """UTC epoch [ns] of experiment time 0 from meta/time.csv ("START" row, "system time" column, any of
    phyphox's separators), and a note when it cannot be used (0 then: times stay from the experiment start)."""
    if not time_csv:
        return 0, "time: seconds from the experiment start (no meta/time.csv)"
    sep = csv_separator(time_csv.splitlines()[0] if time_csv.strip() else "")
    rows = list(csv.DictReader(io.StringIO(time_csv), delimiter=sep))
    for r in rows:
        r = {str(k).strip().lower(): v for k, v in r.items()}
        if str(r.get("event", "")).strip().upper() == "START":
            system, experiment = csv_cell(str(r.get("system time", "")), sep), csv_cell(str(r.get("experiment time", "")), sep)
            if np.isfinite(system) and np.isfinite(experiment):
                return int(round((system - experiment) * 1e9)), None
    return 0, "time: seconds from the experiment start (meta/time.csv has no readable START row)"


def _is_export_folder(folder: Path) -> bool:
    """An unpacked phyphox export: ``meta/time.csv`` beside the sensor tables."""
    return (folder / "meta" / "time.csv").is_file()


def load_phyphox(path: str | Path) -> Recording:
    """Import a phyphox CSV export (single CSV, folder or zip) as SI streams.

    One CSV of an unpacked export (``meta/time.csv`` beside it) loads the whole export folder, so that the
    gyroscope and magnetometer tables beside ``Accelerometer.csv`` are not silently left out (noted).
    """
    p = Path(path)
    notes: list[str] = []
    if p.is_file() and p.suffix.lower() == ".csv" and _is_export_folder(p.parent):
        notes.append(f"{p.name} is part of the phyphox export {p.parent}: the whole export was loaded")
        p = p.parent
    files, time_csv = _files(p)
    t_epoch, time_note = _epoch_ns(time_csv)
    streams: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for where, text in files:
        first = text.splitlines()[0] if text.strip() else ""
        kind = _kind(csv_fields(first))
        if kind is None:
            continue  # not a sensor table of this importer (e.g. a location export): never parsed
        head, data, n_parse = _parse(text, where)
        notes += n_parse
        if data.shape[0] == 0 and kind != "acc":
            notes.append(f"{where}: no samples (header only); left out")
            log.warning("%s", notes[-1])
            continue
        if data.shape[0] == 0:
            raise ImporterError(where, head[0] if head else "Time (s)", "no samples (empty file)")
        if kind == "linear":
            if "acc" not in streams:
                notes.append(f"{where}: linear acceleration (gravity removed) ignored; not specific force")
            continue
        cols = _xyz_columns(head, where)
        keep, n0 = drop_untimed_rows(where, head[0], data[:, 0])
        data = data[keep]
        t = np.round(data[:, 0] * 1e9).astype(np.int64) + t_epoch
        t, v, n = clean_stream(where, head[0], [head[i] for i in cols], t, data[:, cols], required=kind == "acc")
        notes += n0 + n
        if t is not None and v is not None:
            streams[kind] = (t, v)
    if "acc" not in streams:
        raise ImporterError(p, "Acceleration x (m/s^2)", "no accelerometer with g found (use the 'Acceleration with g' sensor)")
    if time_note:
        notes.append(time_note)
    if "gyr" in streams:
        gyro_unit(p, "Gyroscope x (rad/s)", *streams["acc"], *streams["gyr"], "rad/s", "the format (phyphox: rad/s)")
    batch = make_batch(p, *streams["acc"], *streams.get("gyr", (None, None)), *streams.get("mag", (None, None)))
    notes += gap_notes(p, batch)
    return Recording(
        name=p.stem,
        batch=batch,
        meta=RecordingMeta(source_format="phyphox", rate_hz=batch.rate_hz("acc"), mount="phone", notes=tuple(notes)),
    )


def sniff(path: str | Path) -> bool:
    """A CSV whose first column is phyphox's ``Time (s)`` and names a supported sensor, a zip of them, or an
    unpacked export folder (``meta/time.csv`` and such CSVs)."""
    p = Path(path)
    try:
        if p.is_dir():
            return _is_export_folder(p) and any(sniff(f) for f in sorted(p.glob("*.csv")) if not is_hidden(f.name))
        if p.suffix.lower() == ".csv":
            with open(p, encoding="utf-8-sig") as fh:
                first = fh.readline()
            return first.strip().strip('"').startswith("Time (s)") and _kind([first]) is not None
        if p.suffix.lower() == ".zip":
            with zipfile.ZipFile(p) as zf:
                names = zf.namelist()
                return any(n.lower().endswith("meta/time.csv") for n in names) or any(
                    n.endswith(".csv") and zf.read(n)[:20].lstrip(b"\xef\xbb\xbf\"").startswith(b"Time (s)") for n in names
                )
    except (OSError, zipfile.BadZipFile, UnicodeDecodeError):
        return False
    return False


def load(path: str | Path) -> Recording:
    return load_phyphox(path)
