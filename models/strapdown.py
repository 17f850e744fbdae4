"""Strapdown mechanisation (004 eq. 1) in the local NED frame.

:func:`strapdown_step` is the readable numpy reference used by tests and simulators; :func:`integrate` runs
the same equations compiled (:func:`models._zupt_kernel.strapdown_run`, as the navigator's kernel does) unless
asked for the reference (``exact=False`` always uses it).
"""

from __future__ import annotations

import numpy as np

from models._zupt_kernel import strapdown_run
from models.rotations import quat_multiply, quat_to_dcm, rotvec_to_quat

__all__ = ["GRAVITY", "attitude_step", "strapdown_step", "integrate"]

GRAVITY = 9.8  # m/s^2, magnitude used for the NED gravity vector (0, 0, +g)


def attitude_step(q: np.ndarray, gyr: np.ndarray, dt: float, exact: bool = True) -> np.ndarray:
    """Propagate a body-to-NED quaternion by a body rate held constant over ``dt``.

    Parameters
    ----------
    q : ndarray (4,)
        Body-to-NED unit quaternion ``[w, x, y, z]``.
    gyr : ndarray (3,)
        Body angular rate [rad/s] (bias already removed).
    dt : float
        Interval [s].
    exact : bool
        True: exponential map ``q <- q * exp(w dt / 2)`` (exact for a constant rate, stays accurate at low
        rates, 004 Sec. 2). False: first-order ``q <- q * [1, w dt / 2]`` then normalised (diverges below
        ~100 Hz because rotations do not commute).
    """
    phi = np.asarray(gyr, dtype=np.float64) * dt
    dq = rotvec_to_quat(phi) if exact else np.concatenate([[1.0], 0.5 * phi])
    out = quat_multiply(q, dq)
    return out / np.linalg.norm(out)


def strapdown_step(
    q: np.ndarray, v: np.ndarray, p: np.ndarray, acc: np.ndarray, gyr: np.ndarray, dt: float,
    gravity: float = GRAVITY, exact: bool = True,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One mechanisation step (004 eq. 1): attitude, then ``v += (C f + g) dt``, trapezoidal position.

    Parameters
    ----------
    q : (4,) body-to-NED quaternion; v : (3,) NED velocity [m/s]; p : (3,) NED position [m].
    acc : (3,) specific force [m/s^2] body; gyr : (3,) rate [rad/s] body; dt : [s]; gravity : [m/s^2].

    Returns
    -------
    (q, v, p) after the step. The specific force is rotated with the mean of the DCMs before and after.
    """
    c0 = quat_to_dcm(q)
    q1 = attitude_step(q, gyr, dt, exact)
    cm = 0.5 * (c0 + quat_to_dcm(q1))
    a_n = cm @ np.asarray(acc, dtype=np.float64) + np.array([0.0, 0.0, gravity])
    v1 = v + a_n * dt
    p1 = p + 0.5 * (v + v1) * dt
    return q1, v1, p1


def integrate(
    t_s: np.ndarray, acc: np.ndarray, gyr: np.ndarray, q0: np.ndarray, v0: np.ndarray | None = None,
    p0: np.ndarray | None = None, gravity: float = GRAVITY, exact: bool = True, compiled: bool = True,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Free-inertial integration of a whole recording (no aiding).

    Parameters
    ----------
    t_s : (N,) times [s], strictly increasing; acc (N,3) [m/s^2]; gyr (N,3) [rad/s]; q0 (4,) initial attitude;
    v0, p0 : (3,) initial NED velocity [m/s] and position [m] (zero by default).
    compiled : bool
        Run the compiled kernel (default) rather than :func:`strapdown_step` in a Python loop (the reference,
        equal to rounding).

    Returns
    -------
    q (N,4), v (N,3), p (N,3); sample k uses the rate and specific force of sample k over ``t[k]-t[k-1]``.
    """
    t = np.asarray(t_s, dtype=np.float64)
    if t.ndim != 1 or np.any(np.diff(t) <= 0):
        raise ValueError("t_s: must be one-dimensional and strictly increasing")
    n = t.shape[0]
    qs = np.empty((n, 4))
    vs = np.empty((n, 3))
    ps = np.empty((n, 3))
    q = np.asarray(q0, dtype=np.float64)
    v = np.zeros(3) if v0 is None else np.asarray(v0, dtype=np.float64)
    p = np.zeros(3) if p0 is None else np.asarray(p0, dtype=np.float64)
    qs[0], vs[0], ps[0] = q, v, p
    if exact and compiled:
        # the engine integrates a wake-on-motion stride back from its still foot with this (8 times in a
        # synthetic mixed day): the numpy loop took 0.2 ms per sample
        strapdown_run(t, np.ascontiguousarray(acc, dtype=np.float64), np.ascontiguousarray(gyr, dtype=np.float64),
                      q.copy(), v.copy(), p.copy(), float(gravity), qs, vs, ps)
        return qs, vs, ps
    for k in range(1, n):
        q, v, p = strapdown_step(q, v, p, acc[k], gyr[k], t[k] - t[k - 1], gravity, exact)
        qs[k], vs[k], ps[k] = q, v, p
    return qs, vs, ps
