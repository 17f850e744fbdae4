"""Shared checks of the importers: one error type, timestamp policy, finite checks, batch assembly.

Timestamp policy (applies to every importer)
--------------------------------------------
- Timestamps going backwards: rejected (:class:`ImporterError`); a file whose clock jumps back cannot be
  ordered without guessing.
- A duplicated timestamp whose row is an exact copy of the previous row (logger wrote a sample twice):
  the copy is dropped, a warning is logged and a note is added to ``RecordingMeta.notes``.
- A duplicated timestamp with *different* values: rejected; which of the two samples is right (or whether
  the clock stalled) cannot be decided without guessing.
- Jitter (monotonic, uneven spacing) is kept as recorded: the engine works with real timestamps.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from models.batch import BatchError, SensorBatch

__all__ = [
    "ImporterError",
    "G0",
    "seconds_to_ns",
    "check_finite",
    "clean_timestamps",
    "make_batch",
]

log = logging.getLogger(__name__)

G0 = 9.80665  # standard gravity [m/s^2], the unit "g" of accelerometer vendors


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
        All value columns sharing that time axis (any units).

    Returns
    -------
    t_ns, values : ndarray
        With exact duplicate rows removed.
    notes : list of str
        What was repaired (empty when nothing was).
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
    if dup.size:
        same = np.all(v[dup] == v[dup - 1], axis=1)
        if not np.all(same):
            i = int(dup[np.argmin(same)])
            raise ImporterError(
                path, field, f"duplicated timestamp {t[i]} ns at row {i} with different values (cannot tell which is right)"
            )
        keep = np.ones(t.size, dtype=bool)
        keep[dup] = False
        t, v = t[keep], v[keep]
        msg = f"{field}: dropped {dup.size} exact duplicate row(s) (repeated timestamp and values)"
        log.warning("%s: %s", path, msg)
        notes.append(msg)
    return t, v, notes


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
    :class:`ImporterError` that names the file."""
    kw: dict[str, np.ndarray] = {"acc_t_ns": acc_t_ns, "acc": acc}
    if gyr is not None and gyr_t_ns is not None:
        kw.update(gyr_t_ns=gyr_t_ns, gyr=gyr)
    if mag is not None and mag_t_ns is not None:
        kw.update(mag_t_ns=mag_t_ns, mag=mag)
    try:
        return SensorBatch(**kw).validate()
    except BatchError as exc:
        raise ImporterError(path, exc.field, exc.problem) from exc
