"""Importers of recorded sensor formats; each returns a :class:`clients.recording.Recording` in SI units.

Every importer module exposes ``sniff(path) -> bool`` (does this file look like my format, by content) and
``load(path) -> Recording``. :func:`load` asks them in turn; :func:`list_recordings` lists the importable
sensor files of a folder (truth-only files such as gdin ``GCP`` .mat files and ``stride_gcp`` tables are not
recordings and are skipped).

Modules: ``vicon`` (University of Toronto .mat), ``sensorconnect`` (MicroStrain CSV, gdin formats A/B),
``gdin`` (format C .mat, truth pairing), ``gaitmap`` (gaitmap CSV), and, when present, ``sensor_logger`` and
``phyphox`` (phone apps), ``getsensordata`` (GetSensorData logfiles, the IPIN smartphone format).
"""

from __future__ import annotations

import importlib
from pathlib import Path
from types import ModuleType

from clients.importers._common import ImporterError, is_hidden
from clients.recording import Recording

__all__ = ["ImporterError", "load", "list_recordings", "importer_for"]

# Order matters only where two formats could both claim a file; gdin (format C) before vicon because a
# format C file may also carry stray VICON variables (exp 23).
_MODULES: tuple[str, ...] = (
    "clients.importers.gdin",
    "clients.importers.vicon",
    "clients.importers.sensorconnect",
    "clients.importers.gaitmap",
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
            raise ImporterError(p, "file", "is a folder that no importer recognises; use list_recordings() for folders")
        raise ImporterError(p, "file", "no importer recognises this file" + _header_hint(p) + " (supported: "
                            + ", ".join(_MODULES) + ")")
    if m.__name__ == "clients.importers.sensorconnect":
        m = importlib.import_module("clients.importers.gdin")  # attaches truth when in the gdin layout
    return m.load(p)


def _header_hint(p: Path) -> str:
    """``; its first line: '...'`` for a text table (what the importers judged it by), else empty."""
    if p.suffix.lower() not in (".csv", ".txt", ".tsv"):
        return ""
    try:
        with open(p, encoding="utf-8-sig", errors="replace") as fh:
            line = fh.readline().rstrip("\r\n")
    except OSError:
        return ""
    return f"; its first line: {line[:120]!r}{' ...' if len(line) > 120 else ''}" if line.strip() else "; it is empty"


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
