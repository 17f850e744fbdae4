"""Rotation helpers: quaternions, direction-cosine matrices, Euler angles, rotation vectors.

Conventions (used everywhere in pednav)
---------------------------------------
- Quaternions are Hamilton, scalar first ``q = [w, x, y, z]``, unit norm.
- ``C = quat_to_dcm(q)`` is the body-to-navigation DCM: ``v_nav = C @ v_body``. The navigation frame is local
  NED (north, east, down).
- Euler angles are ``(roll, pitch, yaw)`` [rad], aerospace ZYX sequence: ``C = Rz(yaw) Ry(pitch) Rx(roll)``;
  yaw (heading) is clockwise from north seen from above (NED).
- Rotation vectors ``phi`` [rad] map to rotations through the exponential map ``C = exp([phi x])``.

All functions accept a single item or a stack (leading axes) and return float64 arrays.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "skew",
    "quat_normalize",
    "quat_multiply",
    "quat_conjugate",
    "quat_to_dcm",
    "dcm_to_quat",
    "euler_to_dcm",
    "dcm_to_euler",
    "rotvec_to_quat",
    "quat_to_rotvec",
    "rotvec_to_dcm",
    "dcm_heading",
]


def skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrix ``[v x]`` so that ``skew(v) @ u == cross(v, u)``.

    Parameters
    ----------
    v : array_like, shape (..., 3)
        Any 3-vector (units preserved).
    """
    v = np.asarray(v, dtype=np.float64)
    z = np.zeros(v.shape[:-1])
    return np.stack(
        [
            np.stack([z, -v[..., 2], v[..., 1]], -1),
            np.stack([v[..., 2], z, -v[..., 0]], -1),
            np.stack([-v[..., 1], v[..., 0], z], -1),
        ],
        -2,
    )


def quat_normalize(q: np.ndarray) -> np.ndarray:
    """Unit quaternion with non-negative scalar part (``q`` and ``-q`` are the same rotation)."""
    q = np.asarray(q, dtype=np.float64)
    n = np.linalg.norm(q, axis=-1, keepdims=True)
    if np.any(n == 0) or not np.all(np.isfinite(n)):
        raise ValueError("quaternion: zero or non-finite norm")
    q = q / n
    return np.where(q[..., :1] < 0, -q, q)


def quat_multiply(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Hamilton product ``p * q`` (apply ``q`` first, then ``p`` when both map body->nav)."""
    p = np.asarray(p, dtype=np.float64)
    q = np.asarray(q, dtype=np.float64)
    pw, px, py, pz = np.moveaxis(p, -1, 0)
    qw, qx, qy, qz = np.moveaxis(q, -1, 0)
    return np.stack(
        [
            pw * qw - px * qx - py * qy - pz * qz,
            pw * qx + px * qw + py * qz - pz * qy,
            pw * qy - px * qz + py * qw + pz * qx,
            pw * qz + px * qy - py * qx + pz * qw,
        ],
        -1,
    )


def quat_conjugate(q: np.ndarray) -> np.ndarray:
    """Inverse of a unit quaternion."""
    q = np.array(q, dtype=np.float64)
    q[..., 1:] *= -1.0
    return q


def quat_to_dcm(q: np.ndarray) -> np.ndarray:
    """Body-to-navigation DCM of a unit quaternion ``[w, x, y, z]``."""
    q = np.asarray(q, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def dcm_to_quat(c: np.ndarray) -> np.ndarray:
    """Unit quaternion (scalar >= 0) of a rotation matrix; numerically stable (Shepperd's method)."""
    c = np.asarray(c, dtype=np.float64)
    shape = c.shape[:-2]
    c = c.reshape(-1, 3, 3)
    out = np.empty((c.shape[0], 4))
    for k, m in enumerate(c):
        tr = m[0, 0] + m[1, 1] + m[2, 2]
        cand = np.array([tr, m[0, 0], m[1, 1], m[2, 2]])
        i = int(np.argmax(cand))
        if i == 0:
            s = 2.0 * np.sqrt(1.0 + tr)
            q = [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
        elif i == 1:
            s = 2.0 * np.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
            q = [(m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s]
        elif i == 2:
            s = 2.0 * np.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
            q = [(m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s]
        else:
            s = 2.0 * np.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
            q = [(m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s]
        out[k] = q
    return quat_normalize(out).reshape(*shape, 4)


def euler_to_dcm(roll: np.ndarray, pitch: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """Body-to-NED DCM ``Rz(yaw) Ry(pitch) Rx(roll)`` from Euler angles [rad]."""
    r, p, y = (np.asarray(a, dtype=np.float64) for a in (roll, pitch, yaw))
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    return np.stack(
        [
            np.stack([cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr], -1),
            np.stack([sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr], -1),
            np.stack([-sp, cp * sr, cp * cr], -1),
        ],
        -2,
    )


def dcm_to_euler(c: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(roll, pitch, yaw)`` [rad] of a body-to-NED DCM; yaw in (-pi, pi], pitch in [-pi/2, pi/2]."""
    c = np.asarray(c, dtype=np.float64)
    roll = np.arctan2(c[..., 2, 1], c[..., 2, 2])
    pitch = -np.arcsin(np.clip(c[..., 2, 0], -1.0, 1.0))
    yaw = np.arctan2(c[..., 1, 0], c[..., 0, 0])
    return roll, pitch, yaw


def dcm_heading(c: np.ndarray) -> np.ndarray:
    """Heading [rad] (clockwise from north) of the body x axis projected on the horizontal plane."""
    c = np.asarray(c, dtype=np.float64)
    return np.arctan2(c[..., 1, 0], c[..., 0, 0])


def rotvec_to_quat(phi: np.ndarray) -> np.ndarray:
    """Exponential map: rotation vector [rad] -> unit quaternion (exact for any angle)."""
    phi = np.asarray(phi, dtype=np.float64)
    ang = np.linalg.norm(phi, axis=-1, keepdims=True)
    half = 0.5 * ang
    # sin(|phi|/2)/|phi| with its Taylor series near 0
    k = np.where(ang > 1e-8, np.sin(half) / np.where(ang > 1e-8, ang, 1.0), 0.5 - ang**2 / 48.0)
    return np.concatenate([np.cos(half), k * phi], axis=-1)


def quat_to_rotvec(q: np.ndarray) -> np.ndarray:
    """Logarithm map: unit quaternion -> rotation vector [rad] with angle in [0, pi]."""
    q = quat_normalize(q)
    v = q[..., 1:]
    s = np.linalg.norm(v, axis=-1, keepdims=True)
    ang = 2.0 * np.arctan2(s, q[..., :1])
    k = np.where(s > 1e-12, ang / np.where(s > 1e-12, s, 1.0), 2.0)
    return k * v


def rotvec_to_dcm(phi: np.ndarray) -> np.ndarray:
    """Exponential map ``exp([phi x])`` (Rodrigues' formula)."""
    return quat_to_dcm(rotvec_to_quat(phi))
