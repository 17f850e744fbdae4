"""Sensor range clipping (saturation): which samples sit at the accelerometer's or gyroscope's full scale, and
what they most likely missed.

A MEMS output register saturates at the part's range (+-2..16 g, +-250..4000 deg/s): a sprinting foot turns faster
than 2000 deg/s and lands harder than 16 g, and a foot-mounted gyroscope of 500 deg/s clips in every running
stride (the VICON trials' gyroscope sits at 9.1-9.7 rad/s on all three axes). Integrating the clipped value as if it
were the rate loses rotation each stride: tilt that the next ZUPT re-levels, but also velocity and position it
cannot give back, and heading where the clipped axis is not horizontal.

:class:`ClipRepair` streams over the samples and, per axis of both sensors,

- flags a sample whose axis is at the range: within ``flat`` of the range the device profile gives, or (range
  not known) at least ``acc_min`` / ``gyr_min``, within ``frac`` of the largest |value| of that axis and sign so
  far, with a neighbour within ``flat`` of it: a plateau at the extreme (a register at full scale repeats its value;
  the calibration matrix mixes a little of the other axes in, so VICON's plateaus vary by 0.2-1.2 %);
- repairs a run of flagged samples by the quadratic through the ``fit_n`` unclipped samples on either side within
  ``max_s`` of it (the peak of a rate or specific-force bump is smooth; not across a gap in the data), kept only
  where it lies beyond the clipped value;
- gives each flagged sample a 1-sigma error of its (repaired) value: ``rel_sigma`` times what the repair added,
  at least ``gyr_sigma`` / ``acc_sigma`` (what the repair cannot know). The ZUPT-KF turns it into covariance.

A run is repaired once its end and ``fit_n`` samples after it have arrived, so rows are held back while a run is
open (a clipped stretch lasts 10-60 ms); a run longer than ``max_s`` is passed on unrepaired, flagged (a quadratic
extrapolated further is no better than the clipped value: a walk clipped at 6 of 9.4 rad/s for 0.1 s a swing
measured its distance 1.0 % wrong repaired, 0.15 % not). Every
decision depends on the data alone, so feeding a recording in any pieces gives the same rows (``final`` only at
its end).

A smooth natural maximum can be as flat as a plateau; where it is also the largest so far it is flagged, its repair
changes little (the quadratic through its flanks is about the value) and it pays with a little variance. Measured
with the ZUPT-KF (:class:`models.zupt_nav.ZuptNavigator`, which turns the errors into covariance) against the same
filter without it: synthetic sprints (``clients.synth`` "sprint", +-16 g / +-2000 deg/s) mean / sd of the strides'
height change -0.217 / 0.372 m -> -0.029 / 0.031 m at 200 Hz (final height error -10.6 -> -1.5 m), -0.566 / 0.648 m
-> -0.053 / 0.024 m at 800 Hz (-27.6 -> -3.0 m); VICON (42 trials, a gyroscope clipping at 9.1-9.7 rad/s) mean
2-D ARMSE 0.077 -> 0.075 m, 3-D 0.129 -> 0.119 m; gdin stride-truth walks (10) mean stride error 0.66 -> 0.62 m.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numba import njit

from models.rows import RowBuffer

__all__ = ["SaturationConfig", "ClipRepair", "SAT_ACC", "SAT_GYR"]

#: bits of the per-sample flags: accelerometer x, y, z at the range, then gyroscope x, y, z
SAT_ACC = 0b000111
SAT_GYR = 0b111000


@dataclass(frozen=True)
class SaturationConfig:
    """Parameters of :class:`ClipRepair` (defaults: :class:`models.zupt_nav.ZuptConfig`'s).

    Parameters
    ----------
    acc_range, gyr_range : float
        Full scale [m/s^2], [rad/s] from the device profile; 0 = not known (detected).
    acc_min, gyr_min : float
        No part's range is smaller [m/s^2], [rad/s] (+-2 g; a few hundred deg/s).
    frac : float
        A detected clip is within this fraction of the largest |value| of its axis and sign so far (0..1].
    flat : float
        Relative tolerance of a plateau (a neighbour within it) and of a known range [0..1).
    fit_n : int
        Unclipped samples on each side the repair's quadratic is fitted to (>= 2).
    max_s : float
        Longest run repaired [s]; longer ones are flagged only.
    rel_sigma : float
        1-sigma error of a repaired value as a fraction of what the repair added.
    acc_sigma, gyr_sigma : float
        Least 1-sigma error of a clipped sample's value [m/s^2], [rad/s].
    """

    acc_range: float = 0.0
    gyr_range: float = 0.0
    acc_min: float = 19.0
    gyr_min: float = 4.0
    frac: float = 0.985
    flat: float = 0.02
    fit_n: int = 3
    max_s: float = 0.06
    rel_sigma: float = 0.5
    acc_sigma: float = 1.0
    gyr_sigma: float = 1.0

    def __post_init__(self) -> None:
        for name in ("acc_range", "gyr_range", "acc_min", "gyr_min", "max_s", "rel_sigma", "acc_sigma", "gyr_sigma"):
            v = float(getattr(self, name))
            if not (math.isfinite(v) and v >= 0.0):
                raise ValueError(f"SaturationConfig.{name}: must be finite and >= 0, got {v!r}")
        if not 0.0 < self.frac <= 1.0:
            raise ValueError(f"SaturationConfig.frac: must be in (0, 1], got {self.frac!r}")
        if not 0.0 <= self.flat < 1.0:
            raise ValueError(f"SaturationConfig.flat: must be in [0, 1), got {self.flat!r}")
        if int(self.fit_n) != self.fit_n or self.fit_n < 2:
            raise ValueError(f"SaturationConfig.fit_n: must be an integer >= 2, got {self.fit_n!r}")

    def to_array(self) -> np.ndarray:
        return np.array([self.acc_range, self.gyr_range, self.acc_min, self.gyr_min, self.frac, self.flat,
                         float(self.fit_n), self.max_s, self.rel_sigma, self.acc_sigma, self.gyr_sigma])


_RANGE, _MIN, _FRAC, _FLAT, _FITN, _MAXS, _REL, _SIG = 0, 2, 4, 5, 6, 7, 8, 9


# columns of ClipRepair's row buffer
_T, _V, _R, _M, _S, _F, _NCOL = 0, 1, 7, 13, 16, 22, 23


@njit(cache=True)
def _fill(new, t, acc, gyr, mag):
    """New rows of the buffer: time, recorded acc and gyr (twice: as recorded and to be repaired), mag, no
    sigma and no flags (the column assignments of :meth:`ClipRepair.push` in one compiled call)."""
    for i in range(new.shape[0]):
        new[i, _T] = t[i]
        for c in range(3):
            new[i, _V + c] = acc[i, c]
            new[i, _V + 3 + c] = gyr[i, c]
            new[i, _R + c] = acc[i, c]
            new[i, _R + 3 + c] = gyr[i, c]
            new[i, _M + c] = mag[i, c]
        for c in range(_S, _NCOL):
            new[i, c] = 0.0


@njit(cache=True)
def _scan(buf, start, final, peaks, par):
    """Flag rows ``start ..`` of the buffer (column ``_F``) whose next row exists (or ``final``) from their recorded
    values (columns ``_V .. _V + 5``: acc, gyr); returns the first row not scanned. Row ``start - 1`` must be the
    previous row; ``peaks`` (12), the largest |value| per channel and sign so far, is updated in row order."""
    n = buf.shape[0]
    i = start
    while i < n:
        if i + 1 >= n and not final:
            break
        f = 0
        for ch in range(6):
            s = 0 if ch < 3 else 1
            col = _V + ch
            val = buf[i, col]
            mag = abs(val)
            slot = 2 * ch + (1 if val < 0.0 else 0)
            if mag > peaks[slot]:
                peaks[slot] = mag
            known = par[_RANGE + s]
            if known > 0.0:
                hit = mag >= (1.0 - par[_FLAT]) * known
            else:
                hit = mag >= par[_MIN + s] and mag >= par[_FRAC] * peaks[slot]
                if hit:  # a plateau: a neighbour of the same sign holds the value
                    hit = ((i > 0 and buf[i - 1, col] * val > 0.0 and abs(buf[i - 1, col] - val) <= par[_FLAT] * mag)
                           or (i + 1 < n and buf[i + 1, col] * val > 0.0
                               and abs(buf[i + 1, col] - val) <= par[_FLAT] * mag))
            if hit:
                f |= 1 << ch
        buf[i, _F] = f
        i += 1
    return i


@njit(cache=True)
def _quad_at(tt, yy, m, tq):
    """Least-squares quadratic through ``m`` points ``(tt, yy)`` evaluated at ``tq`` (times relative, [s])."""
    # normal equations of y = c0 + c1 t + c2 t^2 (3x3), t centred for conditioning
    tc = 0.0
    for j in range(m):
        tc += tt[j]
    tc /= m
    s = np.zeros(5)
    b = np.zeros(3)
    for j in range(m):
        x = tt[j] - tc
        p = 1.0
        for k in range(5):
            s[k] += p
            if k < 3:
                b[k] += p * yy[j]
            p *= x
    a = np.empty((3, 3))
    for r in range(3):
        for c in range(3):
            a[r, c] = s[r + c]
    c = np.linalg.solve(a, b)
    x = tq - tc
    return c[0] + c[1] * x + c[2] * x * x


@njit(cache=True)
def _repair(buf, lo, scanned, final, par):
    """Repair, in the buffer's columns ``_R`` (a copy of the recorded ``_V``), the runs of each channel that have
    rows in ``lo .. scanned - 1`` and are decided: closed (their end and ``fit_n`` rows after it scanned, or
    ``final``) or longer than ``max_s`` (never repaired). Fits read the recorded values. Columns ``_S`` receive the
    1-sigma error of each flagged value. Returns the first row of the earliest undecided run (or ``scanned``): the rows before it are decided."""
    fit_n = int(par[_FITN])
    release = scanned
    any_flag = False
    for i in range(lo, scanned):  # (most batches flag nothing: then nothing below changes a row)
        if buf[i, _F] != 0.0:
            any_flag = True
            break
    if not any_flag:
        return release
    tt = np.empty(2 * fit_n)
    yy = np.empty(2 * fit_n)
    for ch in range(6):
        s = 0 if ch < 3 else 1
        floor = par[_SIG + s]
        i = lo
        while i < scanned:
            if not (int(buf[i, _F]) >> ch) & 1:
                i += 1
                continue
            if i > 0 and (int(buf[i - 1, _F]) >> ch) & 1:
                # the rest of a run decided before (repaired, or too long to be): too long, its rows are flagged only
                if buf[i, _S + ch] == 0.0:
                    buf[i, _S + ch] = floor
                i += 1
                continue
            j = i
            while j < scanned and (int(buf[j, _F]) >> ch) & 1:
                j += 1
            too_long = buf[j - 1, _T] - buf[i, _T] > par[_MAXS]
            closed = final or (j < scanned and j + fit_n <= scanned)
            if not (closed or too_long):
                if i < release:
                    release = i
                break
            m = 0
            n_left = 0
            if not too_long:
                k = i - 1
                while k >= 0 and m < fit_n and i - k <= 2 * fit_n and buf[i, _T] - buf[k, _T] <= par[_MAXS]:
                    if not (int(buf[k, _F]) >> ch) & 1:
                        tt[m] = buf[k, _T] - buf[i, _T]
                        yy[m] = buf[k, _V + ch]
                        m += 1
                    k -= 1
                n_left = m
                k = j
                while k < scanned and k - j < fit_n and buf[k, _T] - buf[j - 1, _T] <= par[_MAXS]:
                    if not (int(buf[k, _F]) >> ch) & 1:
                        tt[m] = buf[k, _T] - buf[i, _T]
                        yy[m] = buf[k, _V + ch]
                        m += 1
                    k += 1
            repairable = not too_long and n_left >= 1 and m - n_left >= 1 and m >= 3
            for q in range(i, j):
                orig = buf[q, _V + ch]
                added = 0.0
                if repairable:
                    est = _quad_at(tt, yy, m, buf[q, _T] - buf[i, _T])
                    if est * orig > 0.0 and abs(est) > abs(orig):
                        added = abs(est) - abs(orig)
                        buf[q, _R + ch] = est
                buf[q, _S + ch] = max(floor, par[_REL] * added)
            i = j
    return release


@njit(cache=True)
def _push(buf, k, t, acc, gyr, mag, scanned, lo, final, peaks, par, o_t, o_acc, o_gyr, o_mag, o_flags, o_sigma, hi):
    """:meth:`ClipRepair.push_into` in one compiled call: the buffer's last ``k`` rows filled from the new
    samples (:func:`_fill`), flagged (:func:`_scan`, from row ``scanned``) and repaired (:func:`_repair`, rows
    ``lo ..``), and the decided rows written to the output arrays from their row ``hi`` on (time, repaired acc
    and gyr, mag, flags, 1-sigma errors). Returns ``(scanned, release)``: the first row not scanned and the first
    row not decided."""
    n = buf.shape[0]
    _fill(buf[n - k:], t, acc, gyr, mag)
    scanned = _scan(buf, scanned, final, peaks, par)
    release = _repair(buf, lo, scanned, final, par)
    for r in range(lo, release):
        j = hi + r - lo
        o_t[j] = buf[r, _T]
        for c in range(3):
            o_acc[j, c] = buf[r, _R + c]
            o_gyr[j, c] = buf[r, _R + 3 + c]
            o_mag[j, c] = buf[r, _M + c]
        o_flags[j] = np.uint8(buf[r, _F])
        for c in range(6):
            o_sigma[j, c] = buf[r, _S + c]
    return scanned, release


class ClipRepair:
    """Streaming detection and repair of range clipping for a ZUPT-KF's input (see the module docstring).

    Parameters
    ----------
    config : SaturationConfig
    """

    def __init__(self, config: SaturationConfig) -> None:
        self.config = config
        self._par = config.to_array()
        self._peaks = np.zeros(12)
        # one row per sample: t, acc+gyr as recorded, as repaired, mag, 1-sigma errors, flags (columns _T .. _F)
        # the held rows (in place, :class:`RowBuffer`), seen through the view _buf
        self._rows = RowBuffer(np.zeros((0, _NCOL)))
        self._buf = self._rows.views()[0]
        self._n_tail = 0  # leading rows already released (context for the next runs)
        self._scanned = 0  # rows flagged so far

    def push(self, t: np.ndarray, acc: np.ndarray, gyr: np.ndarray, mag: np.ndarray,
             final: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Take rows (``t`` [s] increasing, ``acc`` [m/s^2], ``gyr`` [rad/s], ``mag`` [uT] (N, 3) each); return
        the rows that are decided: ``(t, acc, gyr, mag, flags, sigma)`` with the clipped values repaired,
        ``flags`` (uint8, :data:`SAT_ACC` | :data:`SAT_GYR` bits) and ``sigma`` (M, 6) the 1-sigma error of each
        flagged value (0 elsewhere). ``final``: the recording ends here, release everything."""
        out = RowBuffer(np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0, dtype=np.uint8),
                        np.zeros((0, 6)))
        self.push_into(t, acc, gyr, mag, out, final)
        return out.views()  # type: ignore[return-value]

    def push_into(self, t: np.ndarray, acc: np.ndarray, gyr: np.ndarray, mag: np.ndarray, out: RowBuffer,
                  final: bool = False) -> int:
        """:meth:`push`, the decided rows appended to ``out`` (a :class:`~models.rows.RowBuffer` of the arrays
        ``t (n,)``, ``acc``, ``gyr``, ``mag (n, 3)``, ``flags (n,)`` uint8, ``sigma (n, 6)``; C-contiguous
        float64 but the flags) in one compiled call instead of returned as new arrays. ``t``, ``acc``, ``gyr``,
        ``mag`` as :meth:`push` takes them (C-contiguous float64). Returns the number of rows appended."""
        k = len(t)
        if k:
            self._rows.add(k)  # (the new rows are filled by _push)
            self._buf = self._rows.view()
        buf = self._buf
        lo = self._n_tail
        out.reserve(buf.shape[0] - lo)  # at most every row held is decided now
        self._scanned, release = _push(buf, k, t, acc, gyr, mag, self._scanned, lo, final, self._peaks, self._par,
                                       *out.storage, out.hi)
        out.hi += release - lo
        if final:
            self.reset()
        else:
            keep_from = max(release - 2 * int(self.config.fit_n), 0)  # the context the next runs may fit to
            self._rows.drop(keep_from)
            self._buf = buf[keep_from:]
            self._n_tail = release - keep_from
            self._scanned -= keep_from
        return release - lo

    def reset(self) -> None:
        """Forget the held rows (the recording ended, or a new segment of data starts after a gap: no row is context
        for what follows); the peaks stay (they are the sensor's range)."""
        self._rows.clear()
        self._buf = self._rows.views()[0]
        self._n_tail = 0
        self._scanned = 0

    @property
    def held(self) -> int:
        """Rows taken but not released yet."""
        return int(self._buf.shape[0] - self._n_tail)

    def get_state(self) -> dict[str, Any]:
        """Complete state as plain values and arrays (for ``energy.codec``)."""
        return {"peaks": self._peaks.copy(), "buf": self._buf.copy(), "n_tail": self._n_tail, "scanned": self._scanned}

    @classmethod
    def from_state(cls, config: SaturationConfig, d: dict[str, Any]) -> ClipRepair:
        """Restore from :meth:`get_state` output."""
        obj = cls(config)
        obj._peaks = np.asarray(d["peaks"], dtype=np.float64).reshape(12)
        obj._rows = RowBuffer(np.asarray(d["buf"], dtype=np.float64).reshape(-1, _NCOL).copy())
        obj._buf = obj._rows.views()[0]
        obj._n_tail = int(d["n_tail"])
        obj._scanned = int(d["scanned"])
        return obj
