"""The 15-state error-state Kalman filter of the ZUPT-aided navigator (004 eq. 6-13).

Error state ``dx = [dp, dv, phi, dba, dbg]`` (NED, m, m/s, rad, m/s^2, rad/s), attitude error defined by
``C_true = (I + [phi x]) C_est``. These functions operate in place on a covariance ``P`` (15x15) and an
error state ``dx`` (15,); they are the compiled routines the navigator's kernel uses, exposed for tests and
for callers that build their own loops.
"""

from __future__ import annotations

import numpy as np

from models import _zupt_kernel as _k
from models.rotations import skew

__all__ = [
    "N_STATES",
    "transition_matrix",
    "predict_covariance",
    "update_zupt",
    "update_zaru",
    "update_heading",
    "heading_row",
]

N_STATES = 15


def transition_matrix(c_bn: np.ndarray, f_n: np.ndarray, dt: float) -> np.ndarray:
    """Dense ``F = I + A dt`` (004 eq. 7-8): dp/dv = I, dv/dphi = -[f_n x], dv/dba = -C, dphi/dbg = -C.

    Parameters
    ----------
    c_bn : (3,3) body-to-NED DCM; f_n : (3,) specific force in NED [m/s^2]; dt : [s].
    """
    F = np.eye(N_STATES)
    c = np.asarray(c_bn, dtype=np.float64)
    F[0:3, 3:6] += np.eye(3) * dt
    F[3:6, 6:9] = -skew(f_n) * dt
    F[3:6, 9:12] = -c * dt
    F[6:9, 12:15] = -c * dt
    return F


def predict_covariance(
    P: np.ndarray, c_bn: np.ndarray, f_n: np.ndarray, dt: float,
    acc_psd: float, gyr_psd: float, ba_psd: float, bg_psd: float,
) -> None:
    """In place ``P <- F P F^T + Q dt`` using the sparsity of F (004 eq. 8). PSDs in SI units per second."""
    c = np.ascontiguousarray(c_bn, dtype=np.float64)
    f = np.ascontiguousarray(f_n, dtype=np.float64)
    _k.cov_predict(P, c, f, float(dt), float(acc_psd), float(gyr_psd), float(ba_psd), float(bg_psd))


def update_zupt(P: np.ndarray, dx: np.ndarray, v_est: np.ndarray, sigma: float) -> None:
    """Zero-velocity update (004 eq. 9, 11-13, Joseph form): measurement ``0 - v_est`` with noise sigma [m/s]."""
    _k._update_block3(P, dx, 3, -np.asarray(v_est, dtype=np.float64), float(sigma))


def update_zaru(P: np.ndarray, dx: np.ndarray, gyr_minus_bias: np.ndarray, sigma: float) -> None:
    """Zero-angular-rate update (001 eq. 34-35): at rest the measured rate minus the bias estimate is the
    bias error; noise sigma [rad/s]."""
    _k._update_block3(P, dx, 12, np.asarray(gyr_minus_bias, dtype=np.float64), float(sigma))


def heading_row(c_bn: np.ndarray) -> np.ndarray:
    """Measurement row of the heading error (004 Appendix A eq. 30, the D row) at attitude ``c_bn``."""
    return _k._heading_row(np.ascontiguousarray(c_bn, dtype=np.float64))


def update_heading(
    P: np.ndarray, dx: np.ndarray, c_bn: np.ndarray, innovation_rad: float, sigma_rad: float, gate_sigma: float = 0.0
) -> bool:
    """Heading observation (004 eq. 10): ``innovation = psi_measured - psi_est`` [rad]; returns False when
    the innovation gate (``gate_sigma`` > 0) rejects it."""
    h = heading_row(c_bn)
    return bool(_k._update_scalar(P, dx, h, float(innovation_rad), float(sigma_rad) ** 2, float(gate_sigma)))
