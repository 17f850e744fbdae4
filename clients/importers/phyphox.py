"""phyphox (RWTH Aachen) CSV exports: one CSV per sensor, a zip of them, or a single CSV.

Each CSV has a header like ``"Time (s)","Acceleration x (m/s^2)","Acceleration y (m/s^2)",...``; the sensor and
its unit are read from the column names: ``Acceleration`` (with g, m/s^2; the "Acceleration with g"
experiment), ``Linear Acceleration`` (gravity removed: refused, it is not specific force), ``Gyroscope``
(rad/s) and ``Magnetic field`` (uT). Time is seconds from the start of the experiment; phyphox's
``meta/time.csv`` gives the system time of that start, used (when present) to place the samples on the UTC
epoch. Exports with ``;`` separators (decimal comma) are read too.
"""

from __future__ import annotations

import csv
import io
import zipfile
from pathlib import Path

import numpy as np

from clients.importers._common import ImporterError, clean_stream, drop_untimed_rows, make_batch
from clients.recording import Recording, RecordingMeta

__all__ = ["sniff", "load", "load_phyphox"]


def _parse(text: str, where: str) -> tuple[list[str], np.ndarray]:
    first = text.splitlines()[0] if text else ""
    sep = ";" if first.count(";") > first.count(",") else ","
    rows = list(csv.reader(io.StringIO(text), delimiter=sep))
    if not rows:
        raise ImporterError(where, "header", "empty file")
    head = [h.strip() for h in rows[0]]
    try:
        data = np.array([[float(c.replace(",", ".")) if sep == ";" else float(c) for c in r] for r in rows[1:] if r])
    except ValueError as exc:
        raise ImporterError(where, "row", f"not a number ({exc})") from None
    if data.size == 0:
        raise ImporterError(where, head[0] if head else "Time (s)", "no samples (empty file)")
    return head, data.reshape(len(data), -1)


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
                elif n.lower().endswith(".csv") and "/meta/" not in "/" + n.lower():
                    out.append((f"{path}:{n}", zf.read(n).decode("utf-8-sig")))
        return out, time_csv
    folder = path if path.is_dir() else None
    if folder is None:
        out.append((str(path), path.read_text(encoding="utf-8-sig")))
        meta = path.parent / "meta" / "time.csv"
    else:
        out += [(str(f), f.read_text(encoding="utf-8-sig")) for f in sorted(folder.glob("*.csv"))]
        meta = folder / "meta" / "time.csv"
    if meta.exists():
        time_csv = meta.read_text(encoding="utf-8-sig")
    return out, time_csv


def _epoch_ns(time_csv: str | None) -> int:
    """UTC epoch [ns] of experiment time 0 from meta/time.csv ("START" row, "system time" column)."""
    if not time_csv:
        return 0
    rows = list(csv.DictReader(io.StringIO(time_csv)))
    for r in rows:
        if str(r.get("event", "")).upper() == "START":
            try:
                return int(round((float(r["system time"]) - float(r["experiment time"])) * 1e9))
            except (KeyError, ValueError):
                return 0
    return 0


def load_phyphox(path: str | Path) -> Recording:
    """Import a phyphox CSV export (single CSV, folder or zip) as SI streams."""
    p = Path(path)
    files, time_csv = _files(p)
    t_epoch = _epoch_ns(time_csv)
    streams: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    notes: list[str] = []
    for where, text in files:
        head, data = _parse(text, where)
        kind = _kind(head)
        if kind is None:
            continue
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
    if not t_epoch:
        notes.append("time: seconds from the experiment start (no meta/time.csv)")
    batch = make_batch(p, *streams["acc"], *streams.get("gyr", (None, None)), *streams.get("mag", (None, None)))
    return Recording(
        name=p.stem,
        batch=batch,
        meta=RecordingMeta(source_format="phyphox", rate_hz=batch.rate_hz("acc"), mount="phone", notes=tuple(notes)),
    )


def sniff(path: str | Path) -> bool:
    """A CSV whose first column is phyphox's ``Time (s)`` and names a supported sensor, or a zip of them."""
    p = Path(path)
    try:
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
