"""Gait-related heading-deviation Kalman filter KF II (004 Section 3, eq. 17-21).

The walking direction gamma differs from the sensor heading psi by a personal, repeatable deviation
delta_gamma (004 eq. 16). KF II estimates it step by step while the ZUPT-KF runs: state
``x = [delta_gamma_dot, delta_gamma]`` (004 eq. 17-18), observation ``z = gamma_i - psi_i`` (eq. 19) with
gamma from the ZUPT-KF position increment (eq. 20) or peak velocity (eq. 21) and psi the heading at heel
strike. Angles in radians, heading clockwise from north (NED).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["wrap_angle", "gamma_from_increment", "gamma_from_velocity", "HeadingDeviationKF"]


def wrap_angle(a: float) -> float:
    """Wrap an angle [rad] to (-pi, pi]."""
    return float(math.atan2(math.sin(a), math.cos(a)))


def gamma_from_increment(d_north: float, d_east: float) -> float:
    """Walking direction from a position increment, 004 eq. (20): ``atan(dp_x / dp_y)``, x east, y north [rad]."""
    return float(math.atan2(d_east, d_north))


def gamma_from_velocity(v_north: float, v_east: float) -> float:
    """Walking direction from the peak swing velocity, 004 eq. (21) [rad]."""
    return float(math.atan2(v_east, v_north))


class HeadingDeviationKF:
    """KF II of 004 eq. (17)-(19).

    Parameters
    ----------
    q_rate : float
        Process noise PSD of the deviation rate, w1 in eq. (17) [rad^2/s^3].
    q_dev : float
        Process noise PSD of the deviation, w2 in eq. (18) [rad^2/s].
    r_obs : float
        Observation noise standard deviation of ``gamma - psi`` [rad] (R^II).
    p0_dev, p0_rate : float
        Initial standard deviations of the deviation [rad] and its rate [rad/s]. The first observation
        initialises the deviation directly (with variance ``r_obs**2``), so any mounting angle works.
    converge_std : float
        Converged when the deviation's standard deviation falls below this [rad] ...
    min_updates : int
        ... after at least this many updates.
    gate_sigma : float
        Observations whose innovation exceeds this many innovation standard deviations are rejected
        (turns, where eq. 20 mixes two directions); 0 disables the gate.
    adapt_r : float
        Forgetting factor (0..1) of a Sage-Husa estimate of R^II from the accepted innovations
        (``R <- (1 - b) R + b (nu^2 - H P H^T)``, floored at ``r_obs**2``): the spread of gamma - psi differs
        between people, mountings and floors (2-15 deg per stride on gdin), and a filter that assumes too
        small an R follows that noise. Measured on gdin (ZUPT-KF stances, heel-strike psi; the measurement is now
        ``tests/energy/test_gait_dr.py::kf2_movement_after_convergence``):
        with ``adapt_r=0.1`` the estimate stays within 1.1 deg after convergence on every recording where it
        converges (7 of 26), against up to 8 deg with R fixed at 4 deg (14 of 26 converge, 3 beyond 2 deg);
        0 (default, for now) keeps R fixed at ``r_obs**2``.
    """

    def __init__(self, q_rate: float = 1e-10, q_dev: float = 1e-6, r_obs: float = math.radians(4.0),
                 p0_dev: float = math.radians(30.0), p0_rate: float = math.radians(0.05),
                 converge_std: float = math.radians(1.0), min_updates: int = 10, gate_sigma: float = 4.0,
                 adapt_r: float = 0.0) -> None:
        self.q_rate = float(q_rate)
        self.q_dev = float(q_dev)
        self.r_obs = float(r_obs)
        self.p0_dev = float(p0_dev)
        self.p0_rate = float(p0_rate)
        self.converge_std = float(converge_std)
        self.min_updates = int(min_updates)
        self.gate_sigma = float(gate_sigma)
        self.adapt_r = float(adapt_r)
        self.r_var = self.r_obs**2  # observation noise variance in use [rad^2] (adapted when adapt_r > 0)
        self.x = np.zeros(2)  # [delta_gamma_dot rad/s, delta_gamma rad]
        self.p = np.diag([self.p0_rate**2, self.p0_dev**2])
        self.n_updates = 0
        self.n_rejected = 0

    @property
    def deviation(self) -> float:
        """Estimated heading deviation delta_gamma [rad]."""
        return float(self.x[1])

    @property
    def variance(self) -> float:
        """Variance of the deviation estimate [rad^2]."""
        return float(self.p[1, 1])

    @property
    def converged(self) -> bool:
        """True once the deviation is known to ``converge_std`` after ``min_updates`` steps."""
        return self.n_updates >= self.min_updates and math.sqrt(self.p[1, 1]) < self.converge_std

    def predict(self, dt: float) -> None:
        """Propagate over one step of ``dt`` seconds, 004 eq. (18)."""
        phi = np.array([[1.0, 0.0], [dt, 1.0]])
        q = np.array([[self.q_rate * dt, 0.0], [0.0, self.q_dev * dt]])  # Q^II = diag(Q_w1, Q_w2)
        self.x = phi @ self.x
        self.p = phi @ self.p @ phi.T + q

    def update(self, z: float, dt: float = 1.0) -> bool:
        """One step: predict over ``dt`` [s], then observe ``z = gamma_i - psi_i`` [rad] (004 eq. 19).

        Returns
        -------
        bool
            True if the observation was used (False when gated out).
        """
        if self.n_updates == 0:
            # first observation initialises the deviation (it can be anywhere in (-pi, pi]: sensor mounting)
            self.x = np.array([0.0, wrap_angle(float(z))])
            self.p = np.diag([self.p0_rate**2, self.r_var])
            self.n_updates = 1
            return True
        self.predict(dt)
        # H = [0 1]: H x, P H^T and the gain's products below are written out element by element (the same
        # IEEE operations as the array forms they replace, without a dozen small temporaries); the two
        # matrix products of the Joseph form stay NumPy's
        x0, x1 = self.x.tolist()
        nu = wrap_angle(float(z) - x1)
        hph = float(self.p[1, 1])
        s = hph + self.r_var
        if self.gate_sigma > 0 and self.n_updates >= 3 and abs(nu) > self.gate_sigma * math.sqrt(s):
            self.n_rejected += 1
            return False
        if self.adapt_r > 0.0 and self.n_updates >= 2:
            b = self.adapt_r
            self.r_var = max(self.r_obs**2, (1.0 - b) * self.r_var + b * (nu * nu - hph))  # Sage-Husa R^II
            s = hph + self.r_var
        k0, k1 = self.p[0, 1] / s, self.p[1, 1] / s  # K = P H^T / S, 004 eq. (19), H = [0 1]
        k0, k1 = float(k0), float(k1)
        self.x = np.array([x0 + k0 * nu, wrap_angle(x1 + k1 * nu)])
        ikh = np.array([[1.0, 0.0 - k0], [0.0, 1.0 - k1]])  # I - K H
        r = self.r_var
        kkr = np.array([[k0 * k0 * r, k0 * k1 * r], [k1 * k0 * r, k1 * k1 * r]])  # K K^T R
        self.p = ikh @ self.p @ ikh.T + kkr  # Joseph form
        self.n_updates += 1
        return True

    def get_state(self) -> dict:
        """Plain-data state for ``energy.codec``."""
        return {"params": [self.q_rate, self.q_dev, self.r_obs, self.p0_dev, self.p0_rate, self.converge_std,
                           self.min_updates, self.gate_sigma, self.adapt_r],
                "x": self.x.copy(), "p": self.p.copy(), "n_updates": self.n_updates, "n_rejected": self.n_rejected,
                "r_var": self.r_var}

    @classmethod
    def from_state(cls, d: dict) -> HeadingDeviationKF:
        """Rebuild from :meth:`get_state` output."""
        p = d["params"]
        obj = cls(float(p[0]), float(p[1]), float(p[2]), float(p[3]), float(p[4]), float(p[5]), int(p[6]), float(p[7]),
                  float(p[8]) if len(p) > 8 else 0.0)
        obj.r_var = float(d.get("r_var", obj.r_obs**2))
        obj.x = np.asarray(d["x"], dtype=np.float64).copy()
        obj.p = np.asarray(d["p"], dtype=np.float64).reshape(2, 2).copy()
        obj.n_updates = int(d["n_updates"])
        obj.n_rejected = int(d["n_rejected"])
        return obj
