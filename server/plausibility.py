"""A gyroscope in deg/s recognised while the foot stands still, from physics rather than from motion.

``SensorBatch.validate`` takes a gyroscope for deg/s when its peak rate is beyond anything a foot does in rad/s,
which needs motion: a standing batch in deg/s (a few deg/s of zero-rate offset read as as many rad/s) was
accepted and integrated as rad/s. Standing, the accelerometer measures gravity, and any rotation about a
horizontal axis turns gravity in the sensor frame by the same angle (strapdown kinematics, 004 eq. (1): the
body-frame gravity direction obeys dg/dt = -w x g). So over a stretch in which the accelerometer is still, the
gyroscope's mean rate about the horizontal axes, integrated over the stretch, must agree with the turn of the
measured gravity direction. A rad/s gyroscope cannot report a sustained horizontal rotation of more than
``min_tilt_rad`` that the accelerometer does not see: its zero-rate offset is far below that (consumer MEMS parts
specify a few deg/s at most, i.e. < 0.06 rad/s, against the 0.35 rad/s this takes over 1 s). In deg/s the same
offsets read as 1-3 "rad/s". Rotations about the vertical (turning on the spot) are left out of the test.

The check runs on the upload path before the engine (422 naming ``gyr``, nothing stored); it refuses nothing of
the real recordings in ``PEDNAV_DATA`` (tests/server/test_plausibility.py runs it over every 1-s batch of them).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from models.batch import BatchError, SensorBatch

__all__ = ["STILL_GYRO", "StillGyroCheck"]

_G = 9.80665


@njit(cache=True)
def _spans_beyond(t, a, lo, hi, limit):  # pragma: no cover - compiled
    """Whether some axis of the rows of ``a`` with ``lo <= t <= hi`` spans more than ``limit`` (max - min); False
    when a value there is not finite (left to the full test)."""
    mn = np.full(3, np.inf)
    mx = np.full(3, -np.inf)
    for i in range(t.shape[0]):
        if t[i] < lo or t[i] > hi:
            continue
        for k in range(3):
            v = a[i, k]
            if not np.isfinite(v):
                return False
            if v < mn[k]:
                mn[k] = v
            if v > mx[k]:
                mx[k] = v
    for k in range(3):
        if mx[k] - mn[k] > limit:
            return True
    return False


@dataclass(frozen=True)
class StillGyroCheck:
    """Refuses a gyroscope in deg/s seen while the sensor stands still.

    Parameters
    ----------
    min_still_s : float
        Shortest still stretch examined [s].
    still_tol_ms2 : float
        Still: every accelerometer sample within this of the stretch's mean specific force [m/s^2], and the mean's
        norm within ``g_tol_ms2`` of g.
    g_tol_ms2 : float
        See ``still_tol_ms2`` [m/s^2].
    min_tilt_rad : float
        Horizontal rotation the gyroscope must claim over the stretch [rad] ...
    max_seen_ratio : float
        ... while the gravity direction turned by less than this fraction of it.
    """

    min_still_s: float = 0.5
    still_tol_ms2: float = 0.6
    g_tol_ms2: float = 1.5
    min_tilt_rad: float = 0.35
    max_seen_ratio: float = 0.1

    def __post_init__(self) -> None:
        for name in ("min_still_s", "still_tol_ms2", "g_tol_ms2", "min_tilt_rad", "max_seen_ratio"):
            if not getattr(self, name) > 0:
                raise ValueError(f"StillGyroCheck.{name} must be > 0")

    def check(self, batch: SensorBatch) -> None:
        """Raise :class:`BatchError` naming ``gyr`` when ``batch`` is still and its gyroscope is not in rad/s."""
        found = self.examine(batch)
        if found is None:
            return
        claimed, seen, rate, span_s = found
        if claimed >= self.min_tilt_rad and seen < self.max_seen_ratio * claimed:
            raise BatchError(
                "gyr",
                f"the sensor stands still (accelerometer steady) but the gyroscope claims a {np.degrees(claimed):.0f} deg "
                f"rotation about the horizontal axes in {span_s:.2f} s that gravity did not follow "
                f"({np.degrees(seen):.1f} deg seen); its mean rate {rate:.3g} is no rad/s zero-rate "
                "offset: the values look like deg/s, expected rad/s")

    def examine(self, batch: SensorBatch) -> tuple[float, float, float, float] | None:
        """For a still ``batch``: (horizontal rotation the gyroscope claims [rad if rad/s], turn of gravity seen
        [rad], the gyroscope's mean horizontal rate, the stretch [s]); None when the batch is not still (or too
        short)."""
        t_a, acc = batch.stream("acc")
        t_g, gyr = batch.stream("gyr")
        if len(t_a) < 10 or len(t_g) < 10:
            return None
        lo, hi = max(int(t_a[0]), int(t_g[0])), min(int(t_a[-1]), int(t_g[-1]))
        span_s = (hi - lo) / 1e9
        if span_s < self.min_still_s:
            return None
        if _spans_beyond(np.ascontiguousarray(t_a), np.ascontiguousarray(acc), lo, hi, 2.0 * self.still_tol_ms2 + 1e-6):
            # an axis spans more than twice the tolerance, so a sample departs from any mean by more than it on
            # that axis alone: not still, as the test below would find (one pass instead of its ~20 us of array
            # operations on every walking batch)
            return None
        ka = (t_a >= lo) & (t_a <= hi)
        kg = (t_g >= lo) & (t_g <= hi)
        a, w = acc[ka], gyr[kg]
        if len(a) < 10 or len(w) < 10 or not (np.all(np.isfinite(a)) and np.all(np.isfinite(w))):
            return None
        m = a.mean(axis=0)
        if abs(np.linalg.norm(m) - _G) > self.g_tol_ms2 or np.max(np.linalg.norm(a - m, axis=1)) > self.still_tol_ms2:
            return None  # not still: the engine's own (motion-based) unit check applies
        up = m / np.linalg.norm(m)
        w_mean = w.mean(axis=0)
        w_h = w_mean - np.dot(w_mean, up) * up  # rotation about the horizontal axes [rad/s if rad/s]
        claimed = float(np.linalg.norm(w_h)) * span_s
        q = max(len(a) // 4, 1)
        d0, d1 = a[:q].mean(axis=0), a[-q:].mean(axis=0)
        seen = float(np.arccos(np.clip(np.dot(d0, d1) / (np.linalg.norm(d0) * np.linalg.norm(d1)), -1.0, 1.0)))
        return claimed, seen, float(np.linalg.norm(w_h)), span_s


STILL_GYRO = StillGyroCheck()
"""The check the upload path applies (its defaults)."""
