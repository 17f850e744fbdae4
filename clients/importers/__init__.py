"""Importers of recorded sensor formats; each returns a :class:`clients.recording.Recording` in SI units.

Every importer module exposes ``sniff(path) -> bool`` (does this file look like my format, by content) and
``load(path) -> Recording``. :func:`load` asks them in turn; :func:`list_recordings` lists the importable
sensor files of a folder (truth-only files such as gdin ``GCP`` .mat files and ``stride_gcp`` tables are not
recordings and are skipped).

Modules: ``vicon`` (University of Toronto .mat), ``sensorconnect`` (MicroStrain CSV, gdin formats A/B),
``gdin`` (format C .mat, truth pairing), ``gaitmap`` (gaitmap CSV), ``xio`` (x-io NGIMU / Gait-Tracking CSV),
``sensor_logger`` and ``phyphox`` (phone apps), ``getsensordata`` (GetSensorData logfiles, the IPIN smartphone
format); each states what it reads in ``FORMAT``. ``generic_csv`` reads any other CSV with the columns and units its
caller states (never chosen by :func:`load`). A file no importer takes is refused with :func:`describe` (what it
looks like) and :func:`formats` (what is read).
"""

from __future__ import annotations

import importlib
import re
from pathlib import Path
from types import ModuleType

from clients.importers._common import ImporterError, is_hidden
from clients.recording import Recording

__all__ = ["ImporterError", "load", "list_recordings", "importer_for", "describe", "formats"]

# Order matters only where two formats could both claim a file; gdin (format C) before vicon because a
# format C file may also carry stray VICON variables (exp 23).
_MODULES: tuple[str, ...] = (
    "clients.importers.gdin",
    "clients.importers.vicon",
    "clients.importers.sensorconnect",
    "clients.importers.gaitmap",
    "clients.importers.xio",
    "clients.importers.sensor_logger",
    "clients.importers.phyphox",
    "clients.importers.getsensordata",
)


def _modules() -> list[ModuleType]:
    out = []
    for name in _MODULES:
        try:
            m = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name == name:  # optional importer not written / not installed
                continue
            raise
        if hasattr(m, "sniff") and hasattr(m, "load"):
            out.append(m)
    return out


def importer_for(path: str | Path) -> ModuleType | None:
    """The importer module whose ``sniff`` accepts ``path``, or ``None``."""
    p = Path(path)
    for m in _modules():
        try:
            if m.sniff(p):
                return m
        except Exception:  # noqa: BLE001 - a sniffer must never break the search
            continue
    return None


def load(path: str | Path) -> Recording:
    """Import a recording, choosing the importer by the file's content.

    gdin sensor files inside the gdin layout come back with their ground truth attached.

    Raises
    ------
    ImporterError
        File missing, not a recording, or malformed (the message names file, field and problem).
    """
    p = Path(path)
    if not p.exists():
        raise ImporterError(p, "file", "does not exist")
    m = importer_for(p)
    if m is None:
        if p.name.startswith("._"):
            raise ImporterError(p, "file", "is a macOS AppleDouble resource fork (Finder metadata written beside "
                                f"{p.name[2:]} on a non-Mac drive), not a recording; load {p.name[2:]} itself")
        if p.is_dir():
            raise ImporterError(p, "file", "is a folder that no importer recognises (" + describe(p) + "); use "
                                "list_recordings() for folders of recordings. " + formats())
        raise ImporterError(p, "file", "no importer recognises this file: " + describe(p) + ". " + formats())
    if m.__name__ == "clients.importers.sensorconnect":
        m = importlib.import_module("clients.importers.gdin")  # attaches truth when in the gdin layout
    return m.load(p)


_TIME_LIKE = re.compile(r"(time|timestamp|t|ts|stamp|seconds|elapsed|zeit)\b.*", re.IGNORECASE)
_SENSOR_LIKE = {  # column names that look like a sensor's axis
    "accelerometer": re.compile(r"(acc\w*|a|linear\w*|beschleunigung\w*)[ _\-.]?[xyz]?\b.*", re.IGNORECASE),
    "gyroscope": re.compile(r"(gyr\w*|w|omega|rate|rot\w*|drehrate\w*)[ _\-.]?[xyz]?\b.*", re.IGNORECASE),
    "magnetometer": re.compile(r"(mag\w*|m|field)[ _\-.]?[xyz]?\b.*", re.IGNORECASE),
}


def describe(path: str | Path) -> str:
    """What a file looks like, for the message of a file no importer takes: a folder's files, a MATLAB file's
    variables, a text table's separator and header with the columns that look like time or a sensor, or binary."""
    p = Path(path)
    if p.is_dir():
        names = sorted(f.name for f in p.iterdir() if not is_hidden(f.name))
        return f"a folder of {len(names)} file(s): {', '.join(names[:8])}{' ...' if len(names) > 8 else ''}"
    if p.suffix.lower() == ".mat":
        try:
            import scipy.io as sio

            names = [n for n, _, _ in sio.whosmat(p)]
            return f"a MATLAB file with the variables {', '.join(names[:12]) or '(none)'}"
        except Exception:  # noqa: BLE001 - any reason it cannot be read says the same
            return "a .mat file that is not readable MATLAB data"
    try:
        with open(p, "rb") as fh:
            head = fh.read(4096)
    except OSError as exc:
        return f"not readable ({exc})"
    if not head.strip():
        return "an empty file"
    try:
        text = head.decode("utf-8-sig")
    except UnicodeDecodeError:
        text = head.decode("latin-1")
    printable = sum(ch.isprintable() or ch in "\r\n\t" for ch in text) / max(len(text), 1)
    if b"\x00" in head or printable < 0.95:
        return f"binary content ({p.suffix or 'no extension'}), not a text table"
    from clients.importers._common import csv_fields, csv_separator

    first = text.splitlines()[0]
    sep = csv_separator(first)
    cells = csv_fields(first, sep)
    sep_name = {",": "comma", ";": "semicolon", "\t": "tab"}[sep]
    shown = ", ".join(repr(c) for c in cells[:10]) + (" ..." if len(cells) > 10 else "")
    seen = []
    time_cols = [c for c in cells if _TIME_LIKE.fullmatch(c.strip())]
    if time_cols:
        seen.append(f"time-like {time_cols[0]!r}")
    for sensor, pattern in _SENSOR_LIKE.items():
        hits = [c for c in cells if pattern.fullmatch(c.strip())]
        if hits:
            seen.append(f"{sensor}-like {', '.join(repr(h) for h in hits[:3])}")
    what = f"a {sep_name}-separated table whose first line has {len(cells)} field(s): {shown}"
    return what + ("; recognised: " + "; ".join(seen) if seen else "; no time or sensor column recognised")


def formats() -> str:
    """The formats the importers read, for messages."""
    out = []
    for name in _MODULES + ("clients.importers.generic_csv",):
        try:
            m = importlib.import_module(name)
        except ModuleNotFoundError:
            continue
        if hasattr(m, "FORMAT"):
            out.append(str(m.FORMAT))
        elif m.__doc__:  # an importer that does not state it: its docstring's first line
            out.append(m.__doc__.strip().splitlines()[0].rstrip("."))
    return "Formats read: " + "; ".join(out)


_SUFFIXES = (".mat", ".csv", ".json", ".zip", ".txt")


def list_recordings(directory: str | Path, recursive: bool = True) -> list[Path]:
    """Sorted importable recordings under ``directory``: files, and sub-folders that an importer reads as one
    recording (e.g. a Sensor Logger export folder, not descended into). Truth-only files are excluded, and so
    are hidden files and folders (dotfiles, macOS ``._*`` resource forks: :func:`_common.is_hidden`)."""
    d = Path(directory)
    if not d.is_dir():
        raise ImporterError(d, "directory", "does not exist or is not a folder")
    out: list[Path] = []
    for f in sorted(d.iterdir()):
        if is_hidden(f.name):
            continue
        if f.is_dir():
            if importer_for(f) is not None:
                out.append(f)
            elif recursive:
                out += list_recordings(f, recursive=True)
        elif f.suffix.lower() in _SUFFIXES and importer_for(f) is not None:
            out.append(f)
    return sorted(out)
