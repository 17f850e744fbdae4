"""Sensor batches: the one data type that flows from importers and the API into the engine.

Each sensor stream has its own int64 nanosecond timestamps (Android ``SensorEvent`` clock) and SI values:
specific force in m/s^2 (body frame, reads +9.81 m/s^2 away from the Earth at rest), angular rate in
rad/s (body frame), magnetic field in uT (body frame). A stream that the device did not send (gyroscope
off, no magnetometer) is simply empty.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = ["BatchError", "SensorBatch", "STREAMS"]

STREAMS: tuple[str, ...] = ("acc", "gyr", "mag")

# Unit checks of validate(). Values are refused only where a unit error is certain, never because the motion is
# vigorous: a sprinting foot reads 10-16 g and its batch median |a| passes 5 g (VN-200 sprints at 800 Hz), which the
# former batch-median check (> 50 m/s^2) refused. The accelerometer is judged on its STEADY stretches only:
# consecutive blocks of _STEADY_S whose samples all lie within _STEADY_TOL of the block's mean vector (relative to
# its length), i.e. a constant specific force, which for a person is standing (or a steady vehicle, elevator).
# Measured on every development recording (42 VICON trials, 26 gdin walks, gaitmap: 1478 such blocks): |a| =
# 9.72-9.98 m/s^2. A steady 1 g in g units reads 1.0, in milli-g or cm/s^2 about 1000; no person holds a steady
# specific force of 0.8-1.25 m/s^2 (a free fall reads about 0) or beyond 10 g (aerobatic pilots black out at 6-9 g).
_STEADY_S = 0.25  # s, block length
_STEADY_MIN_N = 5  # samples a block needs
_STEADY_TOL = 0.05  # max |a_i - mean| / |mean| within a steady block
_STEADY_G_LIKE = (0.8, 1.25)  # steady |a| here: the accelerometer is in g
_STEADY_MAX = 100.0  # m/s^2; a steady |a| beyond this is no specific force a person can hold (1 g in mg reads ~1000)
# rad/s; beyond the full scale of every wearable MEMS gyroscope (+-4000 deg/s = 69.8 rad/s; a sprinting foot turns
# at 25-45 rad/s): such a reading is deg/s (a walking foot's 300-600 deg/s)
_GYR_MAX = 75.0
# uT, median |m|: Earth 20-70 uT; gauss reads 0.2-0.7. Above: beyond the full scale of IMU magnetometers (AK8963
# +-4900 uT); a magnet near the sensor reads hundreds of uT and is physically possible; nT reads >= 20 000.
_MAG_RANGE = (5.0, 5000.0)


_MEDIAN_NORM, _MAX_ABS = 0, 1  # statistic _scan returns for the unit check of each stream
_STAT = {"acc": _MAX_ABS, "gyr": _MAX_ABS, "mag": _MEDIAN_NORM}  # acc: judged by _steady
# |value| no sensor of the kind can report (about 1000 g, 570 000 deg/s, 0.1 T), whatever the unit check says:
# a single such sample in an otherwise plausible batch (1e30 m/s^2) made the ZUPT-KF raise LinAlgError
_ABS_MAX = {"acc": 1e4, "gyr": 1e4, "mag": 1e5}
_SENSOR = {"acc": ("accelerometer", "m/s^2"), "gyr": ("gyroscope", "rad/s"), "mag": ("magnetometer", "uT")}


def _scan_py(t: np.ndarray, v: np.ndarray, stat: int, lim: float) -> tuple[int, int, int, float]:
    """Checks of one stream in one pass: ``(first row that is non-finite or has a value beyond +-lim, first
    duplicated timestamp, first backwards timestamp, statistic)``, indices -1 when there is none.

    The statistic is the median of the row norms ``|v|`` (``stat == _MEDIAN_NORM``) or the largest absolute
    value (``_MAX_ABS``), over all rows (meaningful only without non-finite rows). Timestamp steps are
    ``t[i] - t[i - 1]`` in int64 (wrapping as ``np.diff`` does); a duplicate anywhere is reported before a
    step backwards (as :meth:`SensorBatch.validate` always did).
    """
    n = v.shape[0]
    bad = -1
    for i in range(n):
        if not (abs(v[i, 0]) <= lim and abs(v[i, 1]) <= lim and abs(v[i, 2]) <= lim):  # False for NaN too
            bad = i
            break
    dup = -1
    back = -1
    for i in range(1, t.shape[0]):
        d = t[i] - t[i - 1]
        if d == 0:
            dup = i
            break
        if d < 0 and back < 0:
            back = i
    out = 0.0
    if n and bad < 0:
        if stat == _MEDIAN_NORM:
            r = np.empty(n)
            for i in range(n):
                r[i] = np.sqrt(v[i, 0] * v[i, 0] + v[i, 1] * v[i, 1] + v[i, 2] * v[i, 2])
            out = np.median(r)
        else:
            for i in range(n):
                for j in range(3):
                    out = max(out, abs(v[i, j]))
    return bad, dup, back, out


_SCAN: Any = None


def _scan(t: np.ndarray, v: np.ndarray, stat: int, lim: float) -> tuple[int, int, int, float]:
    """:func:`_scan_py` compiled (numba, on first use: importing this module does not load numba, so the
    API process that only decodes batches stays small; the engine's processes load it anyway)."""
    global _SCAN
    if _SCAN is None:
        from numba import njit

        _SCAN = njit(cache=True)(_scan_py)
    return _SCAN(t, v, stat, lim)  # type: ignore[no-any-return]


_STATS = (_STAT["acc"], _STAT["gyr"], _STAT["mag"])  # per stream in STREAMS order (compiled in as constants)
_LIMS = (_ABS_MAX["acc"], _ABS_MAX["gyr"], _ABS_MAX["mag"])


def _scan_streams_py(ta: np.ndarray, va: np.ndarray, tg: np.ndarray, vg: np.ndarray, tm: np.ndarray, vm: np.ndarray,
                     out: np.ndarray) -> None:
    """:func:`_scan_py` of the three streams (``STREAMS`` order, each with its ``_STAT`` and ``_ABS_MAX``) in
    one call: row ``k`` of ``out`` (3, 4) is stream ``k``'s ``(bad, dup, back, statistic)``."""
    r = _SCAN(ta, va, _STATS[0], _LIMS[0])
    out[0, 0], out[0, 1], out[0, 2], out[0, 3] = r[0], r[1], r[2], r[3]
    r = _SCAN(tg, vg, _STATS[1], _LIMS[1])
    out[1, 0], out[1, 1], out[1, 2], out[1, 3] = r[0], r[1], r[2], r[3]
    r = _SCAN(tm, vm, _STATS[2], _LIMS[2])
    out[2, 0], out[2, 1], out[2, 2], out[2, 3] = r[0], r[1], r[2], r[3]


_SCAN_STREAMS: Any = None


def _scan_streams(ta: np.ndarray, va: np.ndarray, tg: np.ndarray, vg: np.ndarray, tm: np.ndarray,
                  vm: np.ndarray) -> list[list[float]]:
    """:func:`_scan_streams_py` compiled (on first use, as :func:`_scan`); the rows as lists."""
    global _SCAN, _SCAN_STREAMS
    if _SCAN_STREAMS is None:
        from numba import njit

        if _SCAN is None:
            _SCAN = njit(cache=True)(_scan_py)
        _SCAN_STREAMS = njit(cache=True)(_scan_streams_py)
    out = np.empty((3, 4))
    _SCAN_STREAMS(ta, va, tg, vg, tm, vm, out)
    return out.tolist()  # type: ignore[no-any-return]


def _steady_py(t: np.ndarray, v: np.ndarray, span_ns: int, min_n: int, tol: float, out: np.ndarray) -> int:
    """Steady blocks of a stream: consecutive blocks of at least ``span_ns`` and ``min_n`` samples (block ``k``
    starts at the first sample after block ``k - 1``) whose samples all lie within ``tol`` of the block's mean
    vector, relative to the mean's length. Writes ``(first row, last row + 1, |mean|)`` of each into ``out``
    (preallocated, at least ``len(t) // min_n`` rows) and returns how many there are. The last, incomplete
    block is not judged."""
    n = t.shape[0]
    k = 0
    i = 0
    while i < n:
        j = i
        while j < n and t[j] - t[i] < span_ns:
            j += 1
        if j >= n:
            break  # incomplete block at the end
        j += 1  # the block holds t[i] .. t[j - 1], spanning at least span_ns
        if j - i >= min_n:
            m0 = 0.0
            m1 = 0.0
            m2 = 0.0
            for r in range(i, j):
                m0 += v[r, 0]
                m1 += v[r, 1]
                m2 += v[r, 2]
            m0 /= j - i
            m1 /= j - i
            m2 /= j - i
            nm = np.sqrt(m0 * m0 + m1 * m1 + m2 * m2)
            ok = nm > 0.0
            lim = (tol * nm) ** 2
            r = i
            while ok and r < j:
                d0 = v[r, 0] - m0
                d1 = v[r, 1] - m1
                d2 = v[r, 2] - m2
                ok = d0 * d0 + d1 * d1 + d2 * d2 <= lim
                r += 1
            if ok:
                out[k, 0] = i
                out[k, 1] = j
                out[k, 2] = nm
                k += 1
        i = j
    return k


_STEADY: Any = None


def _steady(t: np.ndarray, v: np.ndarray) -> np.ndarray:
    """:func:`_steady_py` compiled (numba, on first use); returns the steady blocks as rows ``(first, end, |mean|)``."""
    global _STEADY
    if _STEADY is None:
        from numba import njit

        _STEADY = njit(cache=True)(_steady_py)
    out = np.empty((t.shape[0] // _STEADY_MIN_N + 1, 3))
    k = _STEADY(t, v, int(_STEADY_S * 1e9), _STEADY_MIN_N, _STEADY_TOL, out)
    return out[:k]


class BatchError(ValueError):
    """A batch is malformed or its units are implausible.

    Attributes
    ----------
    field : str
        Name of the offending field, e.g. ``"acc_t_ns"`` or ``"gyr"``.
    problem : str
        Human-readable description of what is wrong.
    """

    def __init__(self, field: str, problem: str) -> None:
        super().__init__(f"{field}: {problem}")
        self.field = field
        self.problem = problem

    def __reduce__(self) -> tuple[type[BatchError], tuple[str, str]]:
        # the default reduction calls cls(message) with ONE argument; rebuild from both (pickle, processes)
        return (type(self), (self.field, self.problem))


def _empty_t() -> np.ndarray:
    return np.zeros(0, dtype=np.int64)


def _empty_v() -> np.ndarray:
    return np.zeros((0, 3), dtype=np.float64)


@dataclass(frozen=True)
class SensorBatch:
    """Samples of up to three sensor streams, each with its own timestamps.

    Parameters
    ----------
    acc_t_ns, gyr_t_ns, mag_t_ns : ndarray of int64, shape (N,), (M,), (K,)
        Sample times [ns], strictly increasing within a stream.
    acc : ndarray, shape (N, 3)
        Specific force [m/s^2], body frame.
    gyr : ndarray, shape (M, 3)
        Angular rate [rad/s], body frame.
    mag : ndarray, shape (K, 3)
        Magnetic flux density [uT], body frame.
    """

    acc_t_ns: np.ndarray = field(default_factory=_empty_t)
    acc: np.ndarray = field(default_factory=_empty_v)
    gyr_t_ns: np.ndarray = field(default_factory=_empty_t)
    gyr: np.ndarray = field(default_factory=_empty_v)
    mag_t_ns: np.ndarray = field(default_factory=_empty_t)
    mag: np.ndarray = field(default_factory=_empty_v)

    def __post_init__(self) -> None:
        for name in STREAMS:
            tk, vk = f"{name}_t_ns", name
            t, v = getattr(self, tk), getattr(self, vk)
            # fast path: the arrays already have the stored form (decoded uploads, slices of batches)
            if not (type(t) is np.ndarray and t.dtype == np.int64 and t.ndim == 1):
                t = np.asarray(t)
                if t.size and not np.issubdtype(t.dtype, np.integer):
                    raise BatchError(tk, f"timestamps must be integer nanoseconds, got {t.dtype}")
                t = t.astype(np.int64, copy=False).reshape(-1)
            if not (type(v) is np.ndarray and v.dtype == np.float64 and v.ndim == 2 and v.shape[1] == 3 and v.size):
                v = np.asarray(v, dtype=np.float64)
                v = v.reshape(-1, 3) if v.size else _empty_v()
            if len(t) != len(v):
                raise BatchError(name, f"{len(v)} samples but {len(t)} timestamps")
            object.__setattr__(self, tk, t)
            object.__setattr__(self, vk, v)

    # ------------------------------------------------------------------ basic properties
    def __len__(self) -> int:
        return int(self.acc_t_ns.size)

    @property
    def is_empty(self) -> bool:
        return self.acc_t_ns.size == 0 and self.gyr_t_ns.size == 0 and self.mag_t_ns.size == 0

    def stream(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """Return ``(t_ns, values)`` of stream ``name`` (one of ``acc``, ``gyr``, ``mag``)."""
        return getattr(self, f"{name}_t_ns"), getattr(self, name)

    @property
    def t_start_ns(self) -> int | None:
        starts = [t[0] for t in (self.acc_t_ns, self.gyr_t_ns, self.mag_t_ns) if t.size]
        return int(min(starts)) if starts else None

    @property
    def t_end_ns(self) -> int | None:
        ends = [t[-1] for t in (self.acc_t_ns, self.gyr_t_ns, self.mag_t_ns) if t.size]
        return int(max(ends)) if ends else None

    def rate_hz(self, name: str = "acc") -> float:
        """Median sample rate of a stream [Hz]; ``nan`` with fewer than two samples."""
        t = self.stream(name)[0]
        if t.size < 2:
            return float("nan")
        return 1e9 / float(np.median(np.diff(t)))

    # ------------------------------------------------------------------ construction helpers
    @classmethod
    def from_arrays(
        cls,
        t_s: np.ndarray,
        acc: np.ndarray,
        gyr: np.ndarray | None = None,
        mag: np.ndarray | None = None,
    ) -> SensorBatch:
        """Build a batch whose streams share one time axis given in seconds."""
        t_ns = np.round(np.asarray(t_s, dtype=np.float64) * 1e9).astype(np.int64)
        kw: dict[str, np.ndarray] = {"acc_t_ns": t_ns, "acc": acc}
        if gyr is not None:
            kw.update(gyr_t_ns=t_ns.copy(), gyr=gyr)
        if mag is not None:
            kw.update(mag_t_ns=t_ns.copy(), mag=mag)
        return cls(**kw)

    @classmethod
    def concat(cls, batches: list[SensorBatch]) -> SensorBatch:
        """Concatenate batches stream by stream (no sorting, no validation)."""
        kw: dict[str, np.ndarray] = {}
        for name in STREAMS:
            kw[f"{name}_t_ns"] = np.concatenate([_empty_t()] + [b.stream(name)[0] for b in batches])
            kw[name] = np.concatenate([_empty_v()] + [b.stream(name)[1] for b in batches])
        return cls(**kw)

    def _sorted(self, name: str) -> bool:
        """Stream ``name``'s timestamps never decrease (checked once per batch and stream, then remembered)."""
        cache = self.__dict__.setdefault("_sorted_cache", {})
        if name not in cache:
            t = self.stream(name)[0]
            cache[name] = bool(t.size < 2 or np.all(t[1:] >= t[:-1]))
        return cache[name]

    def time_slice(self, t0_ns: int | None, t1_ns: int | None) -> SensorBatch:
        """Samples with ``t0_ns <= t < t1_ns`` in every stream (``None`` = unbounded), copied.

        Sorted streams are cut by binary search, so slicing a long recording piece by piece (a device replaying
        it batch by batch) costs the pieces, not the recording each time (replaying 62 min of mostly standing in
        pdr mode: 14.4 -> 1.2 s CPU).
        """
        kw: dict[str, np.ndarray] = {}
        for name in STREAMS:
            t, v = self.stream(name)
            if self._sorted(name):
                i0 = 0 if t0_ns is None else int(np.searchsorted(t, t0_ns, side="left"))
                i1 = t.size if t1_ns is None else int(np.searchsorted(t, t1_ns, side="left"))
                i1 = max(i0, i1)
                kw[f"{name}_t_ns"], kw[name] = t[i0:i1].copy(), v[i0:i1].copy()
                continue
            m = np.ones(t.size, dtype=bool)
            if t0_ns is not None:
                m &= t >= t0_ns
            if t1_ns is not None:
                m &= t < t1_ns
            kw[f"{name}_t_ns"], kw[name] = t[m], v[m]
        return SensorBatch(**kw)

    def split_seconds(self, seconds: float) -> list[SensorBatch]:
        """Split into consecutive pieces of ``seconds`` duration (all streams cut at the same instants)."""
        t0, t1 = self.t_start_ns, self.t_end_ns
        if t0 is None or t1 is None:
            return []
        step = int(round(seconds * 1e9))
        if step <= 0:
            raise ValueError("seconds must be positive")
        edges = list(range(t0, t1 + 1, step)) + [t1 + 1]
        return [self.time_slice(a, b) for a, b in zip(edges[:-1], edges[1:]) if b > a]

    def without(self, name: str) -> SensorBatch:
        """A copy with stream ``name`` emptied (e.g. the gyroscope switched off)."""
        return SensorBatch(**{**self._kwargs(), f"{name}_t_ns": _empty_t(), name: _empty_v()})

    def _kwargs(self) -> dict[str, np.ndarray]:
        kw: dict[str, np.ndarray] = {}
        for name in STREAMS:
            kw[f"{name}_t_ns"], kw[name] = self.stream(name)
        return kw

    # ------------------------------------------------------------------ validation
    def validate(self, *, check_units: bool = True) -> SensorBatch:
        """Raise :class:`BatchError` naming the field and the problem; return ``self`` when valid.

        Checks: finite values within the range of any sensor of the kind, strictly increasing timestamps per
        stream (duplicates and reversals are errors), and with ``check_units`` units where a unit error is
        certain: the accelerometer on its steady stretches (reading 1 g as about 1 or 1000: g, milli-g), a
        gyroscope beyond any wearable's full scale (deg/s), a magnetometer median beyond 5-5000 uT (gauss, nT).
        Values a sensor on a sprinting or jumping foot can report (16 g, 2000 deg/s) are never refused; a
        stream with fewer than 10 samples, or an accelerometer without a steady stretch, is not unit-checked.
        """
        scans = []
        # one compiled pass over the three streams, no temporaries
        rows = _scan_streams(self.acc_t_ns, self.acc, self.gyr_t_ns, self.gyr, self.mag_t_ns, self.mag)
        for name, (bad_f, dup_f, back_f, stat) in zip(STREAMS, rows):
            bad, dup, back = int(bad_f), int(dup_f), int(back_f)
            if bad >= 0:
                v = self.stream(name)[1]
                if not np.all(np.isfinite(v[bad])):
                    raise BatchError(name, f"sample {bad} is not finite (NaN or inf)")
                sensor, unit = _SENSOR[name]
                raise BatchError(name, f"sample {bad} ({float(np.max(np.abs(v[bad]))):.3g} {unit}) is beyond the range "
                                       f"of any {sensor} (|value| <= {_ABS_MAX[name]:g} {unit})")
            if dup >= 0:
                raise BatchError(f"{name}_t_ns", f"duplicated timestamp {int(self.stream(name)[0][dup])} at sample {dup}")
            if back >= 0:
                raise BatchError(f"{name}_t_ns", f"timestamps go backwards at sample {back}")
            scans.append(stat)
        if not check_units:
            return self
        _, peak_gyr, med_mag = scans
        if self.acc.shape[0] >= 10:
            self._check_steady_acc()
        if self.gyr.shape[0] >= 10 and peak_gyr > _GYR_MAX:
            i = int(np.argmax(np.max(np.abs(self.gyr), axis=1)))
            raise BatchError("gyr", f"sample {i}: |w| = {peak_gyr:.3g} is beyond the full scale of any wearable gyroscope "
                                    f"in rad/s (+-4000 deg/s = 69.8 rad/s); looks like deg/s, expected rad/s")
        if self.mag.shape[0] >= 10 and not (_MAG_RANGE[0] <= med_mag <= _MAG_RANGE[1]):
            hint = "gauss (x100)" if med_mag < _MAG_RANGE[0] else "nT (/1000)"
            raise BatchError("mag", f"median |m| = {med_mag:.3g} uT is outside {_MAG_RANGE}; looks like {hint}")
        return self

    def _check_steady_acc(self) -> None:
        """The accelerometer's unit, judged where it means something: its steady stretches (see ``_STEADY_S``).
        A batch without one (a foot in motion all the time: a sprint, a jump) is not judged; any value a sensor
        can report is physically possible there."""
        blocks = _steady(self.acc_t_ns, self.acc)
        if not len(blocks):
            return
        # np.median of the few block levels, without its generic machinery (the middle one, or the mean of the
        # two middle ones: the same value)
        lv = sorted(blocks[:, 2].tolist())
        k = len(lv) // 2
        level = lv[k] if len(lv) % 2 else (lv[k - 1] + lv[k]) / 2.0
        if not (_STEADY_G_LIKE[0] <= level <= _STEADY_G_LIKE[1] or level > _STEADY_MAX):
            return
        i0, i1 = int(blocks[0, 0]), int(blocks[0, 1]) - 1
        where = (f"{len(blocks)} steady stretch(es) of {_STEADY_S:g} s, the first samples {i0}-{i1} (all within "
                 f"{_STEADY_TOL:.0%} of their mean), hold |a| = {level:.3g}")
        if _STEADY_G_LIKE[0] <= level <= _STEADY_G_LIKE[1]:
            raise BatchError("acc", f"{where}: looks like g, expected m/s^2 (9.81 at rest)")
        if level > _STEADY_MAX:
            hint = "; looks like milli-g or cm/s^2 (1 g reads about 1000)" if 700.0 <= level <= 1300.0 else ""
            raise BatchError("acc", f"{where} m/s^2: no person holds a steady specific force beyond "
                                    f"{_STEADY_MAX:g} m/s^2 (about 10 g){hint}, expected m/s^2 (9.81 at rest)")
