"""Compiled Gauss-Newton iterations of the joint stance-and-swing compass fit.

:meth:`models.compass.MagCalibrator._fit_joint` drives :func:`joint_gauss_newton`, which runs the fit's
iterations (residuals, Huber weights and robust scales, Jacobian, normal equations, step-halving line search)
with all state in plain arrays, in and out. The numpy version (``MagCalibrator._fit_joint_reference``, kept as
the reference the tests compare with) spent 4-11 ms per fit, mostly on the call overhead of small arrays.

Unknowns (13): ``[m_n (3), c = W b (3), alignment update (3), e (4)]``: field [uT] (navigation frame), hard
iron c [uT], the rotation A from the magnetometer's axes to the accelerometer's (held as a matrix, stepped by
a rotation vector [rad] on the left), soft iron ``W = I + E`` with ``E = [[e0 e1 e2] [e1 -e0 e3] [e2 e3 0]]``
(dimensionless; :func:`models.compass._soft_matrix`). Divisions follow numpy's error model (inf/NaN, no
exception), as the reference's arrays did: a non-finite fit keeps the linear one.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from models._zupt_kernel import quat_dcm_s, quat_exp_s

__all__ = ["N_JOINT", "PAUSED", "joint_gauss_newton"]

N_JOINT = 13  # unknowns
PAUSED = 1  # joint_gauss_newton's status: stopped at iteration pause_at after the normal equations, before its step
_SQRT3 = math.sqrt(3.0)


@njit(cache=True)
def _wm_minus_c(e, m0, m1, m2, c):
    """``W m - c`` [uT] for the soft iron ``e`` (module docstring) and hard iron ``c``."""
    return ((1.0 + e[0]) * m0 + e[1] * m1 + e[2] * m2 - c[0],
            e[1] * m0 + (1.0 - e[0]) * m1 + e[3] * m2 - c[1],
            e[2] * m0 + e[3] * m1 + m2 - c[2])


@njit(cache=True, error_model="numpy")
def _residuals(c_i, m_i, swing, mn, c, rot, e, r_st, rv, r_sw, sh):
    """Stance residuals ``C_i A (W m_i - c) - m_n`` -> r_st (n, 3) [uT] with ``A (W m_i - c)`` -> rv (n, 3);
    swing residuals ``|W m_k - c| - |m_n|`` -> r_sw (k,) [uT] with the unit vectors of ``W m_k - c`` -> sh (k, 3)."""
    for i in range(m_i.shape[0]):
        u0, u1, u2 = _wm_minus_c(e, m_i[i, 0], m_i[i, 1], m_i[i, 2], c)
        for r in range(3):
            rv[i, r] = rot[r, 0] * u0 + rot[r, 1] * u1 + rot[r, 2] * u2
        for r in range(3):
            r_st[i, r] = c_i[i, r, 0] * rv[i, 0] + c_i[i, r, 1] * rv[i, 1] + c_i[i, r, 2] * rv[i, 2] - mn[r]
    nm = math.sqrt(mn[0] * mn[0] + mn[1] * mn[1] + mn[2] * mn[2])
    for j in range(swing.shape[0]):
        u0, u1, u2 = _wm_minus_c(e, swing[j, 0], swing[j, 1], swing[j, 2], c)
        ns = math.sqrt(u0 * u0 + u1 * u1 + u2 * u2)
        r_sw[j] = ns - nm
        sh[j, 0] = u0 / ns
        sh[j, 1] = u1 / ns
        sh[j, 2] = u2 / ns


@njit(cache=True)
def _rot_vec_s(r):
    """Rotation vector [rad] of a rotation matrix (small to moderate angles; ``models.compass._rot_vec``)."""
    ang = math.acos(max(-1.0, min(1.0, (r[0, 0] + r[1, 1] + r[2, 2] - 1.0) / 2.0)))
    v0, v1, v2 = (r[2, 1] - r[1, 2]) / 2.0, (r[0, 2] - r[2, 0]) / 2.0, (r[1, 0] - r[0, 1]) / 2.0
    sn = math.sin(ang)
    if sn > 1e-12:
        f = ang / sn
        return v0 * f, v1 * f, v2 * f
    return v0, v1, v2


@njit(cache=True)
def _params(c, rot, e, theta):
    """The prior's parameter vector ``[0 (3), c, rotation vector of A, e]`` -> theta (13,)."""
    theta[0:3] = 0.0
    theta[3:6] = c
    theta[6], theta[7], theta[8] = _rot_vec_s(rot)
    theta[9:13] = e


@njit(cache=True)
def _cost(r_st, r_sw, w_st, w_sw, s_st, s_sw, lam, theta):
    """Robust cost: Huber-weighted squares over the robust scales plus the zero-mean priors ``lam theta^2``."""
    a = 0.0
    for i in range(r_st.shape[0]):
        a += w_st[i] * (r_st[i, 0] * r_st[i, 0] + r_st[i, 1] * r_st[i, 1] + r_st[i, 2] * r_st[i, 2])
    b = 0.0
    for j in range(r_sw.shape[0]):
        b += w_sw[j] * r_sw[j] * r_sw[j]
    q = 0.0
    for t in range(theta.shape[0]):
        q += lam[t] * theta[t] * theta[t]
    return a / s_st**2 + b / s_sw**2 + q


@njit(cache=True)
def _huber(u, out):
    """Huber weights (threshold 1.5) of scaled residuals ``u`` -> out."""
    for j in range(u.shape[0]):
        out[j] = 1.0 if u[j] <= 1.5 else 1.5 / max(u[j], 1e-12)


@njit(cache=True)
def _rotvec_dcm_s(p0, p1, p2):
    """``exp([phi x])`` via the unit quaternion, as ``models.rotations.rotvec_to_dcm``."""
    q = quat_exp_s(p0, p1, p2)
    return quat_dcm_s(q / math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]))


@njit(cache=True)
def _mat3(a, b, out):
    """3x3 matrix product ``a @ b`` -> out."""
    for r in range(3):
        for q in range(3):
            out[r, q] = a[r, 0] * b[0, q] + a[r, 1] * b[1, q] + a[r, 2] * b[2, q]


@njit(cache=True, error_model="numpy")
def _normal_equations(c_i, m_i, swing, mn, rot, r_st, rv, r_sw, sh, w_st, w_sw, s_st, s_sw, lam, theta, h, g):
    """Gauss-Newton normal matrix -> h (13, 13) and right-hand side -> g (13,) at the residuals r_st, r_sw.

    Stance rows ``[-I, -C_i A, -C_i [rv x], C_i A dE m_i/de]``, swing rows ``[-m_n/|m_n|, -sh, 0, sh dE m_k/de]``
    (the rotation perturbed on the left; ``E m = [[m0 m1 m2 0] [-m1 m0 0 m2] [0 0 m0 m1]] e``), weighted by the
    Huber weights over the squared robust scales; priors ``lam`` (zero mean) at the parameters ``theta``.
    """
    p = h.shape[0]
    h[:, :] = 0.0
    g[:] = 0.0
    # stances: the m_n block of a stance's rows is -I, so only the other 10 columns (jr[:, 3:13] -> q[:, 0:10])
    # need products; sums over the stances of wa (-> m_n, m_n), wa q (-> m_n, rest) and wa r (-> g of m_n)
    q = np.empty((3, 10))
    sw_a, sq, sr = 0.0, np.zeros((3, 10)), np.zeros(3)
    for i in range(m_i.shape[0]):
        wa = w_st[i] / s_st**2
        m0, m1, m2 = m_i[i, 0], m_i[i, 1], m_i[i, 2]
        v0, v1, v2 = rv[i, 0], rv[i, 1], rv[i, 2]
        for r in range(3):
            ci0, ci1, ci2 = c_i[i, r, 0], c_i[i, r, 1], c_i[i, r, 2]
            a0 = ci0 * rot[0, 0] + ci1 * rot[1, 0] + ci2 * rot[2, 0]  # (C_i A)[r, :]
            a1 = ci0 * rot[0, 1] + ci1 * rot[1, 1] + ci2 * rot[2, 1]
            a2 = ci0 * rot[0, 2] + ci1 * rot[1, 2] + ci2 * rot[2, 2]
            q[r, 0], q[r, 1], q[r, 2] = -a0, -a1, -a2
            q[r, 3] = -(ci1 * v2 - ci2 * v1)  # -(C_i [rv x])[r, :]
            q[r, 4] = -(ci2 * v0 - ci0 * v2)
            q[r, 5] = -(ci0 * v1 - ci1 * v0)
            q[r, 6] = a0 * m0 - a1 * m1
            q[r, 7] = a0 * m1 + a1 * m0
            q[r, 8] = a0 * m2 + a2 * m0
            q[r, 9] = a1 * m2 + a2 * m1
        r0, r1, r2 = r_st[i, 0], r_st[i, 1], r_st[i, 2]
        sw_a += wa
        for r in range(3):
            sr[r] += wa * r_st[i, r]
            for a in range(10):
                sq[r, a] += wa * q[r, a]
        for a in range(10):
            g[3 + a] -= wa * (q[0, a] * r0 + q[1, a] * r1 + q[2, a] * r2)
            for b in range(a, 10):
                h[3 + a, 3 + b] += wa * (q[0, a] * q[0, b] + q[1, a] * q[1, b] + q[2, a] * q[2, b])
    for r in range(3):
        h[r, r] += sw_a
        g[r] += sr[r]
        for a in range(10):
            h[r, 3 + a] -= sq[r, a]
    # swings: rows [-u, -sh, 0, z_e] with u = m_n/|m_n| the same for all; sums of wb, wb z, wb z z^T, wb r, wb z r
    # over z = [sh, z_e] (7)
    nm = math.sqrt(mn[0] * mn[0] + mn[1] * mn[1] + mn[2] * mn[2])
    u0, u1, u2 = mn[0] / nm, mn[1] / nm, mn[2] / nm
    z = np.empty(7)
    sb, sbr, sz, szr, szz = 0.0, 0.0, np.zeros(7), np.zeros(7), np.zeros((7, 7))
    for j in range(swing.shape[0]):
        wb = w_sw[j] / s_sw**2
        s0, s1, s2 = sh[j, 0], sh[j, 1], sh[j, 2]
        m0, m1, m2 = swing[j, 0], swing[j, 1], swing[j, 2]
        z[0], z[1], z[2] = s0, s1, s2
        z[3], z[4], z[5], z[6] = s0 * m0 - s1 * m1, s0 * m1 + s1 * m0, s0 * m2 + s2 * m0, s1 * m2 + s2 * m1
        rj = r_sw[j]
        sb += wb
        sbr += wb * rj
        for a in range(7):
            wz = wb * z[a]
            sz[a] += wz
            szr[a] += wz * rj
            for b in range(a, 7):
                szz[a, b] += wz * z[b]
    uu = (u0, u1, u2)
    sg = (-1.0, -1.0, -1.0, 1.0, 1.0, 1.0, 1.0)  # signs of z's columns in the rows
    col = (3, 4, 5, 9, 10, 11, 12)
    for r in range(3):
        g[r] += uu[r] * sbr
        for q2 in range(r, 3):
            h[r, q2] += sb * uu[r] * uu[q2]
        for a in range(7):
            h[r, col[a]] -= uu[r] * sg[a] * sz[a]
    for a in range(7):
        g[col[a]] -= sg[a] * szr[a]
        for b in range(a, 7):
            h[col[a], col[b]] += sg[a] * sg[b] * szz[a, b]
    for a in range(p):
        h[a, a] += lam[a]
        g[a] -= lam[a] * theta[a]
        for b in range(a):
            h[a, b] = h[b, a]


@njit(cache=True, error_model="numpy")
def joint_gauss_newton(c_i, m_i, swing, lam, s_lin, mn, c, rot, e, w_st, w_sw, scales, h, it0, iterations, freeze,
                       pause_at):
    """Iterations ``it0 .. iterations - 1`` of the joint fit (``MagCalibrator._fit_joint``), state in place.

    Parameters
    ----------
    c_i : ndarray, shape (n, 3, 3)
        Stance body-to-NED rotations from the accelerometer tilt and the ZUPT-KF heading.
    m_i : ndarray, shape (n, 3)
        Stance fields [uT], body.
    swing : ndarray, shape (k, 3)
        Swing field samples [uT], body.
    lam : ndarray, shape (13,)
        Prior precisions of the unknowns (zero mean; 0 for m_n).
    s_lin : float
        The linear stance fit's robust scale [uT]: the stances' scale may not grow past it.
    mn, c, rot, e : ndarray, shapes (3,), (3,), (3, 3), (4,)
        Field [uT], hard iron c = W b [uT], alignment A, soft iron e: the start, updated in place.
    w_st, w_sw : ndarray, shapes (n,), (k,)
        Huber weights, re-estimated (in place) in the iterations before ``freeze``, then kept.
    scales : ndarray, shape (2,)
        Robust scales [uT] of the stance and swing residuals, likewise.
    h : ndarray, shape (13, 13)
        Out: the normal matrix of the last iteration that solved for a step.
    it0, iterations, freeze, pause_at : int
        First iteration, iteration count, iterations that re-weight, iteration after whose normal equations
        to stop (-1: none).

    Returns
    -------
    int
        :data:`PAUSED` when stopped at ``pause_at``, else 0 (converged, or the iterations are used up).
    """
    n, k, p = m_i.shape[0], swing.shape[0], lam.shape[0]
    r_st, rv, r_sw, sh = np.empty((n, 3)), np.empty((n, 3)), np.empty(k), np.empty((k, 3))
    t_st, t_rv, t_sw, t_sh = np.empty((n, 3)), np.empty((n, 3)), np.empty(k), np.empty((k, 3))
    rn, ua = np.empty(n), np.empty(k)
    theta, t_theta, g = np.empty(p), np.empty(p), np.empty(p)
    t_mn, t_c, t_rot, t_e = np.empty(3), np.empty(3), np.empty((3, 3)), np.empty(4)
    s_st, s_sw = scales[0], scales[1]
    for it in range(it0, iterations):
        _residuals(c_i, m_i, swing, mn, c, rot, e, r_st, rv, r_sw, sh)
        if it < freeze:
            # robust scales and Huber weights from the current residuals, then kept (MagCalibrator._fit_joint)
            for i in range(n):
                rn[i] = math.sqrt(r_st[i, 0] * r_st[i, 0] + r_st[i, 1] * r_st[i, 1] + r_st[i, 2] * r_st[i, 2])
            s_st = min(max(1.4826 * np.median(rn) / _SQRT3 * 1.2, 0.5), s_lin)
            _huber(rn / (s_st * _SQRT3), w_st)
            ua[:] = np.abs(r_sw)
            s_sw = max(1.4826 * np.median(ua), 0.1)
            _huber(ua / s_sw, w_sw)
            scales[0], scales[1] = s_st, s_sw
        if it == iterations - 1:
            break
        _params(c, rot, e, theta)
        _normal_equations(c_i, m_i, swing, mn, rot, r_st, rv, r_sw, sh, w_st, w_sw, s_st, s_sw, lam, theta, h, g)
        d = np.linalg.solve(h, g)
        if it == pause_at:
            return PAUSED
        if it >= freeze and np.max(np.abs(d)) < 1e-9:
            break  # converged
        c0 = _cost(r_st, r_sw, w_st, w_sw, s_st, s_sw, lam, theta)
        for _ in range(7):  # steps that raise the robust cost are halved
            t_mn[:] = mn + d[0:3]
            t_c[:] = c + d[3:6]
            _mat3(_rotvec_dcm_s(d[6], d[7], d[8]), rot, t_rot)
            t_e[:] = e + d[9:13]
            _residuals(c_i, m_i, swing, t_mn, t_c, t_rot, t_e, t_st, t_rv, t_sw, t_sh)
            _params(t_c, t_rot, t_e, t_theta)
            if _cost(t_st, t_sw, w_st, w_sw, s_st, s_sw, lam, t_theta) <= c0 * (1.0 + 1e-9):
                mn[:] = t_mn
                c[:] = t_c
                rot[:, :] = t_rot
                e[:] = t_e
                break
            d = d / 2.0
    return 0
