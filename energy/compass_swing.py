"""A phone's own compass-swing detector: the device wakes its gyroscope when its azimuth swings.

A phone's sensor hub has the accelerometer and the magnetometer running while the host keeps the gyroscope off;
from them it can compute a tilt-compensated compass azimuth at the magnetometer's rate (a few multiplications per
sample), and power the gyroscope up itself when that azimuth changes by more than ``swing_rad`` within
``window_s``: a turn (or a compass whose place error is changing fast, which the gyroscope also has to bridge).
The host learns of a turn only from its next upload (a batch plus the stream wait); the device sees it at once
(``SensorConfig.wake_mode == "compass_swing"``, :class:`energy.device.DeviceEmulator`).

The azimuth is accumulated from its increments: the horizontal field's turn about the vertical between two
magnetometer outputs, in the device's frame,

    dpsi_k = atan2(u . (h_{k-1} x h_k), h_{k-1} . h_k),   h = m - (m . u) u,   u = g_lp / |g_lp|,

with ``g_lp`` the accelerometer low-passed with time constant ``tau_s`` (the vertical, as an e-compass's tilt
compensation takes it: Android ``SensorManager.getRotationMatrix`` from gravity and the geomagnetic field). It
needs no forward axis (any holding), and its sign is the device's turn's opposite (the field turns the other way in
the device's frame); only its size over the window matters here. The constants and the statistics they come from:
``python -m clients.evaluation.phone_swing`` (docs/phone.md, "The device wakes its gyroscope on a compass swing").
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

__all__ = ["SWING_RAD", "SWING_TAU_S", "SWING_WINDOW_S", "CompassSwing"]

# The detector's constants, statistics of the IPIN 2023 T3 dev trials' sensors (no landmark used):
# `python -m clients.evaluation.phone_swing` (docs/phone.md); values within the leave-one-route-out folds' range.
SWING_WINDOW_S = 0.5  # [s] the window: 0.5 s fires 0.1 s (median; 90th percentile 0.2 s) after a turn's gyroscope
#   passed 20 deg and misses none of the 94 turns; 1.0 s: 0.2 / 0.4 s; 1.5 s: 0.4 / 0.6 s and misses 5
SWING_RAD = math.radians(17.0)  # the 99th percentile of the change within 0.5 s on straight windows (gyroscope < 10 deg
#   over 1 s): 17.3 deg, 15.9-18.1 leaving out each route; a turn's window (> 45 deg over 1 s) changes by 34 deg (median)
SWING_TAU_S = 1.0  # [s] gravity low-pass (two steps): straight 99th percentile 17.3 deg, at 0.5 s 17.7, at 0.25 s 19.3


class CompassSwing:
    """Stateful compass-swing detector over the device's accelerometer and magnetometer outputs (chunk-invariant).

    Parameters
    ----------
    swing_rad : float
        Azimuth change [rad] within ``window_s`` that is a swing.
    window_s : float
        Window [s] over which the change is taken (the largest change between any earlier output in the window and
        the newest).
    tau_s : float
        Time constant [s] of the accelerometer's low-pass that gives the vertical.
    """

    def __init__(self, swing_rad: float = SWING_RAD, window_s: float = SWING_WINDOW_S, tau_s: float = SWING_TAU_S) -> None:
        self.swing_rad = float(swing_rad)
        self.window_ns = int(round(float(window_s) * 1e9))
        self.tau_s = float(tau_s)
        self._g: np.ndarray | None = None  # low-passed specific force [m/s^2]
        self._g_t = 0  # its time [ns]
        self._h: np.ndarray | None = None  # previous horizontal field direction (device frame, unit)
        self._psi = 0.0  # accumulated azimuth [rad]
        self._hist: deque[tuple[int, float]] = deque()  # (t_ns, psi) within the window

    @property
    def up(self) -> np.ndarray | None:
        """The low-passed specific force's direction (up, device frame), None before the first output."""
        return None if self._g is None else self._g / float(np.linalg.norm(self._g))

    def feed_acc(self, t: int, a: np.ndarray) -> None:
        """Fold one accelerometer output [m/s^2] at ``t`` [ns] into the low-passed vertical."""
        if self._g is None:
            self._g, self._g_t = a.astype(np.float64).copy(), t
            return
        alpha = 1.0 - math.exp(-max(t - self._g_t, 0) * 1e-9 / self.tau_s)
        self._g = self._g + alpha * (a - self._g)
        self._g_t = t

    def _mag(self, t: int, m: np.ndarray) -> tuple[float, bool]:
        """Fold in one magnetometer output; returns (the azimuth [rad], a swing)."""
        if self._g is None:
            return self._psi, False
        n = float(np.linalg.norm(self._g))
        if not n > 0:
            return self._psi, False
        u = self._g / n
        h = m - float(m @ u) * u
        hn = float(np.linalg.norm(h))
        if not hn > 0:
            return self._psi, False
        h = h / hn
        if self._h is not None:
            self._psi += math.atan2(float(u @ np.cross(self._h, h)), float(self._h @ h))
        self._h = h
        hist = self._hist
        while hist and hist[0][0] < t - self.window_ns:
            hist.popleft()
        swing = any(abs(self._psi - p) > self.swing_rad for _, p in hist)
        hist.append((t, self._psi))
        return self._psi, swing

    def process(self, acc_t: np.ndarray, acc_v: np.ndarray, mag_t: np.ndarray, mag_v: np.ndarray,
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Run over the outputs of one chunk, in time order (an accelerometer output at a magnetometer output's time
        goes first).

        Parameters
        ----------
        acc_t, mag_t : ndarray of int64
            Output times [ns].
        acc_v : ndarray, shape (n, 3)
            Specific force [m/s^2], device frame.
        mag_v : ndarray, shape (m, 3)
            Magnetic field [uT], device frame.

        Returns
        -------
        t_ns : ndarray of int64
            The magnetometer outputs' times.
        psi : ndarray
            The accumulated azimuth at each [rad] (NaN before the vertical is known).
        swing : ndarray of bool
            The output ended a swing (an azimuth change above ``swing_rad`` within ``window_s``).
        """
        acc_v = np.asarray(acc_v, dtype=np.float64).reshape(-1, 3)
        mag_v = np.asarray(mag_v, dtype=np.float64).reshape(-1, 3)
        psi = np.full(len(mag_t), math.nan)
        swing = np.zeros(len(mag_t), dtype=bool)
        i = 0
        for k in range(len(mag_t)):
            tk = int(mag_t[k])
            while i < len(acc_t) and int(acc_t[i]) <= tk:
                self.feed_acc(int(acc_t[i]), acc_v[i])
                i += 1
            if self._g is not None:
                psi[k], swing[k] = self._mag(tk, mag_v[k])
        while i < len(acc_t):
            self.feed_acc(int(acc_t[i]), acc_v[i])
            i += 1
        return np.asarray(mag_t, dtype=np.int64), psi, swing
