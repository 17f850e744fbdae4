"""Wire formats of a sensor batch: JSON and a compact msgpack body.

JSON (``application/json``)::

    {"acc": {"t_ns": [int, ...], "xyz": [[x, y, z], ...]}, "gyr": {...}, "mag": {...}}

Binary (``application/msgpack``)::

    {"v": 1, "acc": {"n": N, "t0": int, "dt": <N-1 little-endian int32 deltas [ns]>,
                     "dtype": "<f4" | "<f8", "xyz": <N*3 little-endian floats, row-major>}, ...}

``dt`` may be replaced by ``"t": <N little-endian int64>`` when a delta does not fit int32 (gaps > 2.1 s).
Android delivers ``SensorEvent.values`` as float32, so ``<f4`` is lossless for phone data; ``<f8`` is lossless
for anything (used by replays that must match local processing bit for bit). Streams a device did not sample
are omitted. Units are those of :class:`models.batch.SensorBatch` (m/s^2, rad/s, uT, int64 ns).
"""

from __future__ import annotations

import hashlib
import json
from typing import Any

import msgpack
import numpy as np

from models.batch import STREAMS, BatchError, SensorBatch

__all__ = [
    "JSON_TYPE",
    "MSGPACK_TYPE",
    "PayloadTooLarge",
    "decode_batch",
    "encode_json",
    "encode_msgpack",
    "canonical_bytes",
    "decode_upload",
    "digest",
]

JSON_TYPE = "application/json"
MSGPACK_TYPE = "application/msgpack"
_I32 = np.iinfo(np.int32)
_I64 = np.iinfo(np.int64)


class PayloadTooLarge(ValueError):
    """A stream holds more samples than the server accepts in one batch."""


def encode_json(batch: SensorBatch) -> bytes:
    """JSON body of ``batch`` (floats printed with full float64 precision)."""
    doc: dict[str, Any] = {}
    for name in STREAMS:
        t, v = batch.stream(name)
        if t.size:
            doc[name] = {"t_ns": t.tolist(), "xyz": v.tolist()}
    return json.dumps(doc, separators=(",", ":")).encode()


def encode_msgpack(batch: SensorBatch, dtype: str = "<f8") -> bytes:
    """Compact msgpack body of ``batch``; ``dtype`` ``"<f4"`` (phones) or ``"<f8"`` (lossless)."""
    if dtype not in ("<f4", "<f8"):
        raise ValueError("dtype must be '<f4' or '<f8'")
    doc: dict[str, Any] = {"v": 1}
    for name in STREAMS:
        t, v = batch.stream(name)
        if not t.size:
            continue
        s: dict[str, Any] = {"n": int(t.size), "dtype": dtype, "xyz": np.ascontiguousarray(v, dtype=dtype).tobytes()}
        d = np.diff(t)
        if d.size == 0 or (d.min() >= _I32.min and d.max() <= _I32.max):
            s["t0"] = int(t[0])
            s["dt"] = d.astype("<i4").tobytes()
        else:
            s["t"] = t.astype("<i8").tobytes()
        doc[name] = s
    return msgpack.packb(doc, use_bin_type=True)


def _check_n(field: str, n: int, limit: int) -> None:
    if n > limit:
        raise PayloadTooLarge(f"{field}: {n} samples exceed the limit of {limit} per stream and batch")


_NUMBER = (int, float)  # the Python types json.loads gives JSON numbers (bool, a subclass of int, is not one)


def _json_name(v: Any) -> str:
    return {str: "string", bool: "boolean", type(None): "null", list: "array", dict: "object"}.get(type(v), type(v).__name__)


def _check_numbers(name: str, xyz: Any) -> None:
    """``BatchError`` naming ``<name>.xyz``, the row and the value when a sample value is not a JSON number.

    ``np.asarray(..., dtype=float64)`` reads the string "1.5" as 1.5 and ``true`` as 1.0: a client that
    sent its numbers as strings got them taken. Rows that are not three values are left to the shape check.
    """
    try:
        if all(type(a) in _NUMBER and type(b) in _NUMBER and type(c) in _NUMBER for a, b, c in xyz):
            return
    except (TypeError, ValueError):
        pass  # not rows of three values: named by the shape check, unless a row holds a non-number first
    if not isinstance(xyz, list):
        return
    for i, row in enumerate(xyz):
        if not isinstance(row, list):
            continue
        for j, v in enumerate(row):
            if type(v) not in _NUMBER:
                raise BatchError(f"{name}.xyz", f"row {i}, value {j}: must be a number, got {_json_name(v)} {v!r:.40}")


def _from_json(doc: Any, limit: int) -> SensorBatch:
    if not isinstance(doc, dict):
        raise BatchError("body", "must be a JSON object with streams acc/gyr/mag")
    unknown = set(doc) - set(STREAMS)
    if unknown:
        raise BatchError(sorted(unknown)[0], f"unknown stream (expected one of {', '.join(STREAMS)})")
    kw: dict[str, np.ndarray] = {}
    for name in STREAMS:
        s = doc.get(name)
        if s is None:
            continue
        if not isinstance(s, dict) or "t_ns" not in s or "xyz" not in s:
            raise BatchError(name, "must be an object with 't_ns' and 'xyz'")
        ts, xyz = s["t_ns"], s["xyz"]
        if not isinstance(ts, list) or not all(isinstance(x, int) and not isinstance(x, bool) for x in ts):
            raise BatchError(f"{name}.t_ns", "must be a list of integer nanoseconds")
        _check_n(name, len(ts), limit)
        if not ts and xyz == []:
            continue  # an empty stream is a stream the device did not sample (as msgpack's n = 0)
        _check_numbers(name, xyz)
        try:
            v = np.asarray(xyz, dtype=np.float64)
        except (TypeError, ValueError):
            raise BatchError(f"{name}.xyz", "must be a list of [x, y, z] numbers") from None
        except OverflowError:
            raise BatchError(f"{name}.xyz", "a value is beyond the float64 range") from None
        if v.ndim != 2 or v.shape[1] != 3 or v.shape[0] != len(ts):
            raise BatchError(f"{name}.xyz", f"must be {len(ts)} rows of [x, y, z], got shape {list(v.shape)}")
        try:
            t = np.asarray(ts, dtype=np.int64)
        except OverflowError:
            raise BatchError(f"{name}.t_ns", "timestamp outside int64") from None
        kw[f"{name}_t_ns"], kw[name] = t, v
    return SensorBatch(**kw)


def _from_msgpack(doc: Any, limit: int) -> tuple[SensorBatch, bytes | None]:
    """The batch of a msgpack document, and its :func:`canonical_bytes` when they follow from the document alone
    (every stream in ``<f8`` with ``t0``/``dt`` timestamps, the form :func:`encode_msgpack` writes for the
    server): the canonical document holds the same byte strings, so re-encoding the arrays is not needed."""
    if not isinstance(doc, dict):
        raise BatchError("body", "must be a msgpack map with streams acc/gyr/mag")
    if doc.get("v") != 1:
        raise BatchError("v", "unsupported binary format version (expected 1)")
    unknown = set(doc) - set(STREAMS) - {"v"}
    if unknown:
        raise BatchError(str(sorted(map(str, unknown))[0]), "unknown stream")
    kw: dict[str, np.ndarray] = {}
    canon: dict[str, Any] | None = {"v": 1}  # encode_msgpack's document of the batch, while it can be built here
    for name in STREAMS:
        s = doc.get(name)
        if s is None:
            continue
        if not isinstance(s, dict):
            raise BatchError(name, "must be a map")
        n = s.get("n")
        if not isinstance(n, int) or isinstance(n, bool) or n < 0:
            raise BatchError(f"{name}.n", "must be a non-negative integer")
        _check_n(name, n, limit)
        dtype = s.get("dtype")
        if dtype not in ("<f4", "<f8"):
            raise BatchError(f"{name}.dtype", "must be '<f4' or '<f8'")
        xyz = s.get("xyz")
        if not isinstance(xyz, bytes) or len(xyz) != n * 3 * np.dtype(dtype).itemsize:
            raise BatchError(f"{name}.xyz", f"must be {n * 3} packed {dtype} values")
        v = np.frombuffer(xyz, dtype=dtype).reshape(n, 3).astype(np.float64)
        if "t" in s:
            tb = s["t"]
            if not isinstance(tb, bytes) or len(tb) != 8 * n:
                raise BatchError(f"{name}.t", f"must be {n} packed <i8 values")
            t = np.frombuffer(tb, dtype="<i8").astype(np.int64)
        else:
            t0, dt = s.get("t0"), s.get("dt")
            if n and (not isinstance(t0, int) or isinstance(t0, bool) or not isinstance(dt, bytes) or len(dt) != 4 * (n - 1)):
                raise BatchError(f"{name}.dt", f"needs integer t0 and {max(n - 1, 0)} packed <i4 deltas")
            if n and not _I64.min <= t0 <= _I64.max:
                raise BatchError(f"{name}.t0", "timestamp outside int64")
            if n == 0:
                t = np.zeros(0, dtype=np.int64)
            else:
                deltas = np.frombuffer(dt, dtype="<i4").astype(np.int64)
                t = int(t0) + np.concatenate([np.zeros(1, dtype=np.int64), np.cumsum(deltas)])
                if canon is not None and dtype == "<f8":
                    # what encode_msgpack(batch, "<f8") writes for this stream: the same values' bytes, t[0] = t0
                    # and the same int32 differences
                    canon[name] = {"n": n, "dtype": dtype, "xyz": xyz, "t0": int(t0), "dt": dt}
                else:
                    canon = None
        if "t" in s and n:
            canon = None  # int64 timestamps: their canonical form (t0/dt or t) needs the differences
        kw[f"{name}_t_ns"], kw[name] = t, v
    raw = None if canon is None else msgpack.packb(canon, use_bin_type=True)
    return SensorBatch(**kw), raw


def decode_batch(body: bytes, content_type: str | None, max_samples: int, *, allow_empty: bool = False) -> SensorBatch:
    """Parse a request body into a :class:`SensorBatch` (not yet validated for plausibility); see
    :func:`decode_upload`."""
    return decode_upload(body, content_type, max_samples, allow_empty=allow_empty)[0]


def decode_upload(body: bytes, content_type: str | None, max_samples: int, *,
                  allow_empty: bool = False) -> tuple[SensorBatch, bytes | None]:
    """Parse a request body into a :class:`SensorBatch` (not yet validated for plausibility), with its
    :func:`canonical_bytes` when the body's form gives them without re-encoding (msgpack, ``<f8``, ``t0``/``dt``
    timestamps: what the SDK sends for foot sensors), else None (call :func:`canonical_bytes`).

    ``allow_empty``: take a batch without any sample (stored batches, re-processed as they were stored). An
    upload without samples is refused: ``{}`` was accepted and consumed a sequence number for nothing (a device
    with nothing to send sends nothing; the SDK skips empty batches).

    Raises
    ------
    BatchError
        Malformed body or, unless ``allow_empty``, no samples in any stream; ``field`` names the offending part.
    PayloadTooLarge
        More than ``max_samples`` samples in one stream.
    """
    ctype = (content_type or JSON_TYPE).split(";")[0].strip().lower()
    if ctype in (MSGPACK_TYPE, "application/x-msgpack"):
        try:
            doc = msgpack.unpackb(body, raw=False, strict_map_key=True, max_bin_len=len(body), max_array_len=16, max_map_len=16)
        except Exception as exc:  # noqa: BLE001 - any unpack failure is a client error
            raise BatchError("body", f"not valid msgpack: {exc}") from None
        batch, raw = _from_msgpack(doc, max_samples)
    elif ctype == JSON_TYPE:
        try:
            doc = json.loads(body)
        except (ValueError, UnicodeDecodeError) as exc:
            raise BatchError("body", f"not valid JSON: {exc}") from None
        except RecursionError:
            raise BatchError("body", "JSON nested too deeply") from None
        batch, raw = _from_json(doc, max_samples), None
    else:
        raise BatchError("content-type", f"unsupported {ctype!r}; use {JSON_TYPE} or {MSGPACK_TYPE}")
    if not allow_empty and not any(batch.stream(name)[0].size for name in STREAMS):
        raise BatchError("body", "a batch without samples (every stream missing or empty); send batches that hold "
                                 "samples (the sequence number stays free)")
    return batch, raw


def canonical_bytes(batch: SensorBatch) -> bytes:
    """Lossless canonical encoding used to store raw batches and to compare retries."""
    return encode_msgpack(batch, dtype="<f8")


def digest(raw: bytes) -> str:
    return hashlib.sha256(raw).hexdigest()
