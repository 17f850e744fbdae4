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


@njit(cache=True)
def _scan(t, v, flags, start, stop, final, peaks, par):
    """Flag rows ``start .. stop - 1`` of ``v`` (N, 6: acc, gyr) whose next row exists (or ``final``); returns the
    first row not scanned. Row ``start - 1`` must be the previous row; ``peaks`` (12), the largest |value| per
    channel and sign so far, is updated in row order."""
    n = t.shape[0]
    i = start
    while i < stop:
        if i + 1 >= n and not final:
            break
        f = 0
        for ch in range(6):
            s = 0 if ch < 3 else 1
            val = v[i, ch]
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
                    hit = ((i > 0 and v[i - 1, ch] * val > 0.0 and abs(v[i - 1, ch] - val) <= par[_FLAT] * mag)
                           or (i + 1 < n and v[i + 1, ch] * val > 0.0 and abs(v[i + 1, ch] - val) <= par[_FLAT] * mag))
            if hit:
                f |= 1 << ch
        flags[i] = f
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
def _repair(t, v, r, flags, sig, lo, scanned, final, par):
    """Repair, in ``r`` (a copy of ``v``), the runs of each channel that have rows in ``lo .. scanned - 1`` and are
    decided: closed (their end and ``fit_n`` rows after it scanned, or ``final``) or longer than ``max_s`` (never
    repaired). Fits read the original values ``v``. ``sig`` (N, 6) receives the 1-sigma error of each flagged
    value. Returns the first row of the earliest undecided run (or ``scanned``): the rows before it are decided."""
    fit_n = int(par[_FITN])
    release = scanned
    tt = np.empty(2 * fit_n)
    yy = np.empty(2 * fit_n)
    for ch in range(6):
        s = 0 if ch < 3 else 1
        floor = par[_SIG + s]
        i = lo
        while i < scanned:
            if not (flags[i] >> ch) & 1:
                i += 1
                continue
            if i > 0 and (flags[i - 1] >> ch) & 1:
                # the rest of a run decided before (repaired, or too long to be): too long, its rows are flagged only
                if sig[i, ch] == 0.0:
                    sig[i, ch] = floor
                i += 1
                continue
            j = i
            while j < scanned and (flags[j] >> ch) & 1:
                j += 1
            too_long = t[j - 1] - t[i] > par[_MAXS]
            closed = final or (j < scanned and j + fit_n <= scanned)
            if not (closed or too_long):
                if i < release:
                    release = i
                break
            m = 0
            n_left = 0
            if not too_long:
                k = i - 1
                while k >= 0 and m < fit_n and i - k <= 2 * fit_n and t[i] - t[k] <= par[_MAXS]:
                    if not (flags[k] >> ch) & 1:
                        tt[m] = t[k] - t[i]
                        yy[m] = v[k, ch]
                        m += 1
                    k -= 1
                n_left = m
                k = j
                while k < scanned and k - j < fit_n and t[k] - t[j - 1] <= par[_MAXS]:
                    if not (flags[k] >> ch) & 1:
                        tt[m] = t[k] - t[i]
                        yy[m] = v[k, ch]
                        m += 1
                    k += 1
            repairable = not too_long and n_left >= 1 and m - n_left >= 1 and m >= 3
            for q in range(i, j):
                orig = v[q, ch]
                added = 0.0
                if repairable:
                    est = _quad_at(tt, yy, m, t[q] - t[i])
                    if est * orig > 0.0 and abs(est) > abs(orig):
                        added = abs(est) - abs(orig)
                        r[q, ch] = est
                sig[q, ch] = max(floor, par[_REL] * added)
            i = j
    return release


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
        self._t = np.zeros(0)
        self._v = np.zeros((0, 6))  # acc, gyr as recorded (detection and fits read these)
        self._r = np.zeros((0, 6))  # ... repaired (the output)
        self._m = np.zeros((0, 3))  # mag (passed through)
        self._f = np.zeros(0, dtype=np.uint8)
        self._sig = np.zeros((0, 6))
        self._n_tail = 0  # leading rows already released (context for the next runs)
        self._scanned = 0  # rows flagged so far

    def push(self, t: np.ndarray, acc: np.ndarray, gyr: np.ndarray, mag: np.ndarray,
             final: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Take rows (``t`` [s] increasing, ``acc`` [m/s^2], ``gyr`` [rad/s], ``mag`` [uT] (N, 3) each); return
        the rows that are decided: ``(t, acc, gyr, mag, flags, sigma)`` with the clipped values repaired,
        ``flags`` (uint8, :data:`SAT_ACC` | :data:`SAT_GYR` bits) and ``sigma`` (M, 6) the 1-sigma error of each
        flagged value (0 elsewhere). ``final``: the recording ends here, release everything."""
        if len(t):
            self._t = np.concatenate([self._t, t])
            v = np.concatenate([acc, gyr], axis=1)
            self._v = np.concatenate([self._v, v])
            self._r = np.concatenate([self._r, v])
            self._m = np.concatenate([self._m, mag])
            self._f = np.concatenate([self._f, np.zeros(len(t), dtype=np.uint8)])
            self._sig = np.concatenate([self._sig, np.zeros((len(t), 6))])
        n = self._t.shape[0]
        self._scanned = _scan(self._t, self._v, self._f, self._scanned, n, final, self._peaks, self._par)
        lo = self._n_tail
        release = _repair(self._t, self._v, self._r, self._f, self._sig, lo, self._scanned, final, self._par)
        out = (self._t[lo:release].copy(), self._r[lo:release, :3].copy(), self._r[lo:release, 3:].copy(),
               self._m[lo:release].copy(), self._f[lo:release].copy(), self._sig[lo:release].copy())
        if final:
            self._forget(n)
        else:
            self._drop(release)
        return out

    def _drop(self, release: int) -> None:
        """Keep the released rows the next runs may fit to (``2 fit_n``) and everything not released."""
        keep_from = max(release - 2 * int(self.config.fit_n), 0)
        self._t = self._t[keep_from:]
        self._v = self._v[keep_from:]
        self._r = self._r[keep_from:]
        self._m = self._m[keep_from:]
        self._f = self._f[keep_from:]
        self._sig = self._sig[keep_from:]
        self._n_tail = release - keep_from
        self._scanned -= keep_from

    def _forget(self, n: int = 0) -> None:
        """After the end of a recording (or a restart): no row is context for what follows; the peaks stay (they
        are the sensor's range)."""
        self._t = np.zeros(0)
        self._v = np.zeros((0, 6))
        self._r = np.zeros((0, 6))
        self._m = np.zeros((0, 3))
        self._f = np.zeros(0, dtype=np.uint8)
        self._sig = np.zeros((0, 6))
        self._n_tail = 0
        self._scanned = 0

    def reset(self) -> None:
        """Forget the held rows (a new segment of data starts after a gap); the learnt ranges stay."""
        self._forget(0)

    @property
    def held(self) -> int:
        """Rows taken but not released yet."""
        return int(self._t.shape[0] - self._n_tail)

    def get_state(self) -> dict[str, Any]:
        return {"peaks": self._peaks.copy(), "t": self._t.copy(), "v": self._v.copy(), "r": self._r.copy(), "m": self._m.copy(),
                "f": self._f.copy(), "sig": self._sig.copy(), "n_tail": self._n_tail, "scanned": self._scanned}

    @classmethod
    def from_state(cls, config: SaturationConfig, d: dict[str, Any]) -> ClipRepair:
        obj = cls(config)
        obj._peaks = np.asarray(d["peaks"], dtype=np.float64).reshape(12)
        obj._t = np.asarray(d["t"], dtype=np.float64).reshape(-1)
        obj._v = np.asarray(d["v"], dtype=np.float64).reshape(-1, 6)
        obj._r = np.asarray(d["r"], dtype=np.float64).reshape(-1, 6)
        obj._m = np.asarray(d["m"], dtype=np.float64).reshape(-1, 3)
        obj._f = np.asarray(d["f"], dtype=np.uint8).reshape(-1)
        obj._sig = np.asarray(d["sig"], dtype=np.float64).reshape(-1, 6)
        obj._n_tail = int(d["n_tail"])
        obj._scanned = int(d["scanned"])
        return obj
