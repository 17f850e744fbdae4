"""Walking direction of a device that is not on the foot (003 Section 5; hand-held and pocket placements).

- Held in front (texting, reading): the device's forward axis. For a phone in portrait at any pitch between
  flat and upright the forward axis is the horizontal direction perpendicular to its x (right) axis:
  ``up x x_nav`` (in NED, ``(x_E, -x_N, 0)`` with ``x_nav`` the body x axis in NED), defined as long as the
  x axis is not vertical.
- In a pocket or a swinging hand the device's axes say nothing about the walking direction; the horizontal
  specific force does: over a stride the body accelerates and decelerates along the walking direction, so its
  principal direction (largest eigenvector of the horizontal covariance) is the walking direction up to 180
  degrees. The ambiguity is resolved from the body's gait cycle: the centre of mass is highest at mid-stance,
  where the forward velocity is lowest, so the forward acceleration follows the vertical (upward) acceleration
  by a quarter of a step, ``E[a_fwd(t) a_up(t + T/4)] > 0`` for the right sign.

The compiled functions work on a ring buffer of NED specific force kept by :mod:`models.pdr`.
"""

from __future__ import annotations

import math

from typing import Any

import numpy as np
from numba import njit

from models.marg import G

__all__ = ["forward_azimuth", "window", "principal_direction", "forward_sign", "RING"]

RING = 512  # samples of NED specific force kept (5 s at 100 Hz)


@njit(cache=True)
def forward_azimuth(C: Any) -> float:
    """Azimuth [rad] (clockwise from north) of a hand-held device's forward axis, from its body -> NED DCM (an
    array, or its rows as tuples: :func:`models.marg.dcm`)."""
    return math.atan2(-C[0][0], C[1][0])


@njit(cache=True)
def window(ring: np.ndarray, n: int, t0: float, t1: float) -> np.ndarray:
    """The ring's samples with ``t0 < t <= t1`` in time order (``n`` samples were ever written; the ring holds
    the last ``ring.shape[0]``)."""
    size = ring.shape[0]
    m = min(n, size)
    first = n - m
    k = 0
    for j in range(first, n):
        t = ring[j % size, 0]
        if t0 < t <= t1:
            k += 1
    out = np.empty((k, 4))
    k = 0
    for j in range(first, n):
        r = ring[j % size]
        if t0 < r[0] <= t1:
            out[k] = r
            k += 1
    return out


@njit(cache=True)
def principal_direction(w: np.ndarray) -> tuple[float, float]:
    """Principal horizontal direction [rad, modulo pi] of specific-force samples ``w`` (rows ``t, f_N, f_E,
    f_D``) and the ratio of the two eigenvalues (>= 1: how clearly there is one direction); NaN for fewer than 4."""
    k = w.shape[0]
    if k < 4:
        return math.nan, math.nan
    mn = 0.0
    me = 0.0
    for i in range(k):
        mn += w[i, 1]
        me += w[i, 2]
    mn /= k
    me /= k
    cnn = 0.0
    cee = 0.0
    cne = 0.0
    for i in range(k):
        a, b = w[i, 1] - mn, w[i, 2] - me
        cnn += a * a
        cee += b * b
        cne += a * b
    th = 0.5 * math.atan2(2.0 * cne, cnn - cee)  # eigenvector of [[cnn, cne], [cne, cee]]
    tr = cnn + cee
    d = math.sqrt(max((cnn - cee) ** 2 + 4.0 * cne * cne, 0.0))
    return th, (0.5 * (tr + d)) / max(0.5 * (tr - d), 1e-12)


@njit(cache=True)
def forward_sign(w: np.ndarray, azimuth: float, period_s: float) -> float:
    """``E[a_fwd(t) a_up(t + T/4)]`` over specific-force samples ``w`` (rows ``t, f_N, f_E, f_D``, time order)
    along ``azimuth`` [rad], with ``a_up = -(f_D + g)``: positive when ``azimuth`` is the walking direction,
    negative for the opposite one; 0 when it cannot be told."""
    k = w.shape[0]
    if k < 4 or not period_s > 0.0:
        return 0.0
    lag = 0.25 * period_s
    cn, ce = math.cos(azimuth), math.sin(azimuth)
    mf = 0.0
    mu = 0.0
    for i in range(k):
        mf += w[i, 1] * cn + w[i, 2] * ce
        mu += -(w[i, 3] + G)
    mf /= k
    mu /= k
    acc = 0.0
    j = 0
    for i in range(k):
        target = w[i, 0] + lag
        if target > w[k - 1, 0]:
            break
        while j + 1 < k and w[j + 1, 0] <= target:
            j += 1
        u = -(w[j, 3] + G)
        if j + 1 < k and w[j + 1, 0] > w[j, 0]:  # linear between the neighbours
            x = (target - w[j, 0]) / (w[j + 1, 0] - w[j, 0])
            u += x * (-(w[j + 1, 3] + G) - u)
        acc += (w[i, 1] * cn + w[i, 2] * ce - mf) * (u - mu)
    return acc
