"""Any CSV of IMU samples, read with columns and units the user states (``pednav replay FILE --columns C --units U``).

Never chosen by content (nothing is guessed): the caller names the columns and their units.

``columns``: ``time=COL,acc=COL:COL:COL,gyr=COL:COL:COL[,mag=COL:COL:COL]`` where ``COL`` is a header name or a
1-based column number (``#2``; a file without a header row must use numbers). ``time`` and ``acc`` are required.

``units``: ``time=U,acc=U[,gyr=U][,mag=U]`` for every stream in ``columns``:

- time: ``s``, ``ms``, ``us``, ``ns`` (from any origin: the first row becomes t = 0);
- acc: ``m/s^2``, ``g`` (x 9.80665), ``mg`` (specific force: about 9.81 m/s^2 up at rest);
- gyr: ``rad/s``, ``deg/s``;
- mag: ``uT``, ``nT``, ``mT``, ``G``/``gauss``, ``mG``.

A missing or unknown column, an unknown stream or unit, or a stream without a unit is an :class:`ImporterError`
naming the option (``--columns acc``, ``--units gyr``) and what the file or the spec holds. The values then go
through the sample policy of :mod:`clients.importers._common` and the batch's own unit checks (a stated ``m/s^2``
that stands still at 1.0 is refused as g); the stated gyroscope unit is checked against the motion
(:func:`clients.importers._common.gyro_unit`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from clients.importers._common import (
    G0,
    ImporterError,
    clean_stream,
    csv_cell,
    csv_fields,
    csv_separator,
    first_line,
    drop_untimed_rows,
    gap_notes,
    gyro_unit,
    make_batch,
    read_csv_rows,
    seconds_to_ns,
)
from clients.recording import Recording, RecordingMeta

__all__ = ["FORMAT", "UNITS", "load_generic_csv", "parse_columns", "parse_units"]

FORMAT = ("any other CSV, with its columns and units stated: pednav replay FILE --columns "
          "'time=t,acc=ax:ay:az,gyr=gx:gy:gz' --units 'time=s,acc=m/s^2,gyr=rad/s'")

#: units per stream and their factors to SI (s, m/s^2, rad/s, uT)
UNITS: dict[str, dict[str, float]] = {
    "time": {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9},
    "acc": {"m/s^2": 1.0, "m/s2": 1.0, "g": G0, "mg": G0 * 1e-3},
    "gyr": {"rad/s": 1.0, "deg/s": np.pi / 180.0},
    "mag": {"ut": 1.0, "nt": 1e-3, "mt": 1e3, "g": 100.0, "gauss": 100.0, "mg": 0.1},
}
_AXES = {"time": 1, "acc": 3, "gyr": 3, "mag": 3}


def _pairs(spec: str, option: str) -> dict[str, str]:
    out: dict[str, str] = {}
    for part in [s.strip() for s in spec.split(",") if s.strip()]:
        if "=" not in part:
            raise ImporterError(option, part, f"expected STREAM=VALUE (streams: {', '.join(_AXES)}), got {part!r}")
        k, v = (x.strip() for x in part.split("=", 1))
        if k not in _AXES:
            raise ImporterError(option, k, f"unknown stream (streams: {', '.join(_AXES)})")
        if k in out:
            raise ImporterError(option, k, "given twice")
        out[k] = v
    return out


def parse_columns(spec: str) -> dict[str, list[str]]:
    """``--columns`` -> ``{stream: [column, ...]}`` (names or ``#N``), checked for streams and axis counts."""
    cols = {k: [c.strip() for c in v.split(":")] for k, v in _pairs(spec, "--columns").items()}
    for k in ("time", "acc"):
        if k not in cols:
            raise ImporterError("--columns", k, "missing: time and acc are required, e.g. 'time=t,acc=ax:ay:az'")
    for k, v in cols.items():
        if len(v) != _AXES[k] or not all(v):
            raise ImporterError("--columns", k, f"needs {_AXES[k]} column(s) separated by ':', got {':'.join(v)!r}")
    return cols


def parse_units(spec: str, streams: list[str]) -> dict[str, float]:
    """``--units`` -> ``{stream: factor to SI}`` for exactly the ``streams`` of ``--columns``."""
    given = _pairs(spec, "--units")
    out: dict[str, float] = {}
    for k in streams:
        if k not in given:
            raise ImporterError("--units", k, f"missing: every stream of --columns needs its unit ({', '.join(UNITS[k])})")
        u = given[k]
        table = {key.lower(): f for key, f in UNITS[k].items()}
        if u.lower() not in table:
            raise ImporterError("--units", k, f"unknown unit {u!r} (known: {', '.join(UNITS[k])})")
        out[k] = table[u.lower()]
    extra = sorted(set(given) - set(streams))
    if extra:
        raise ImporterError("--units", extra[0], "a unit for a stream --columns does not name")
    return out


def _header(p: Path) -> tuple[list[str] | None, int, str]:
    """``(header or None, the number of fields, separator)``: a first line whose cells all read as numbers is data."""
    first = first_line(p)
    sep = csv_separator(first)
    cells = csv_fields(first, sep)
    numeric = all(np.isfinite(csv_cell(c, sep)) for c in cells)
    return (None if numeric else cells), len(cells), sep


def _index(p: Path, header: list[str] | None, n: int, col: str, stream: str) -> int:
    if col.startswith("#"):
        try:
            k = int(col[1:])
        except ValueError:
            raise ImporterError("--columns", stream, f"{col!r} is not a column number (#1 .. #{n})") from None
        if not 1 <= k <= n:
            raise ImporterError("--columns", stream, f"column {col} does not exist: the file has {n} columns")
        return k - 1
    if header is None:
        raise ImporterError("--columns", stream, f"column {col!r}: {p.name} has no header row; name columns by "
                            f"number (#1 .. #{n})")
    if col not in header:
        raise ImporterError("--columns", stream, f"column {col!r} is not in the header of {p.name} (columns: "
                            f"{', '.join(header)})")
    return header.index(col)


def load_generic_csv(path: str | Path, columns: str, units: str) -> Recording:
    """Read ``path`` with the stated ``columns`` and ``units`` (module docstring) into SI units."""
    p = Path(path)
    if not p.is_file():
        raise ImporterError(p, "file", "does not exist or is not a file")
    cols = parse_columns(columns)
    factors = parse_units(units, list(cols))
    header, n, _ = _header(p)
    idx = {k: [_index(p, header, n, c, k) for c in v] for k, v in cols.items()}
    data, notes, n_lines = read_csv_rows(p, n, skip_header=0 if header is None else 1)
    if not len(data):
        raise ImporterError(p, "rows", "no samples")
    tname = header[idx["time"][0]] if header else f"column {idx['time'][0] + 1}"
    keep, n0 = drop_untimed_rows(p, tname, data[:, idx["time"][0]], n_total=n_lines)
    data = data[keep]
    notes += n0
    t_ns = seconds_to_ns(p, tname, (data[:, idx["time"][0]] - data[0, idx["time"][0]]) * factors["time"])
    names = {k: [header[i] if header else f"column {i + 1}" for i in v] for k, v in idx.items()}
    out: dict[str, tuple[np.ndarray | None, np.ndarray | None]] = {}
    for k in ("acc", "gyr", "mag"):
        if k in idx:
            t, v, n1 = clean_stream(p, tname, names[k], t_ns, data[:, idx[k]], required=k != "mag")
            notes += n1
            out[k] = (t, None if v is None else v * factors[k])
    acc_t, acc = out["acc"]
    assert acc_t is not None and acc is not None
    conv = {k: f"{dict(_pairs(units, '--units'))[k]} (stated) -> SI (x {factors[k]:.6g})" for k in out}
    gyr_t, gyr = out.get("gyr", (None, None))
    if gyr_t is not None and gyr is not None:  # the stated unit, checked against the motion (values now rad/s)
        gyro_unit(p, names["gyr"][0], acc_t, acc, gyr_t, gyr, "rad/s", "--units")
    mag_t, mag = out.get("mag", (None, None))
    batch = make_batch(p, acc_t, acc, gyr_t, gyr, mag_t, mag)
    notes += gap_notes(p, batch)
    return Recording(
        name=p.stem,
        batch=batch,
        meta=RecordingMeta(source_format="generic-csv", rate_hz=float(batch.rate_hz("acc")), units_converted=conv,
                           mount="unknown (stated columns)", notes=tuple(notes)),
    )
