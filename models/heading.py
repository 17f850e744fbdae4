"""Walking-heading estimator: the heading of the foot and its uncertainty, stride by stride.

One filter takes whatever the device provides at each stride and says how well the heading is known:

- the gyroscope (through the ZUPT-KF) gives the heading change over a stride with a small error;
- with the gyroscope off nothing measures the change: the person walks on straight or turns. That is a
  jump process, not a Gaussian one, so two motion models run side by side as an interacting multiple-model
  (IMM) filter (Blom & Bar-Shalom 1988; Bar-Shalom, Li & Kirubarajan, *Estimation with Applications to
  Tracking and Navigation*, 2001, Sec. 11.6): *straight* (the path's small stride-to-stride wander) and
  *turn* (a change of tens of degrees), switching as a Markov chain. A compass change that only a turn
  explains is taken whole; small disagreements are averaged;
- the tilt-compensated compass observes the heading plus two offsets: the compass's frame offset (a
  profile's compass was fitted in another session's frame) and the local field's deflection (a building's,
  a steel door's). Its noise is estimated, not assumed (:class:`CompassNoise`): a floor from the
  calibration's own agreement with the ZUPT-KF and a place term from the innovations of strides whose
  heading the gyroscope knew. The deflection is what the field's shape tells: it random-walks by as much as
  the stance field's magnitude and dip changed since the last stance (a rotation of the foot changes neither),
  and is observed to be zero where the field has the Earth's shape.

State per model: ``x = [theta, c0, d]`` (:class:`HeadingEstimator`). The walking direction adds the gait
deviation of KF II (004 eq. 16); the scheduler asks :meth:`HeadingEstimator.forecast` how well the heading
would be known one stride ahead with the gyroscope off, and turns the gyroscope on when the cross-track drift
that uncertainty would cause exceeds its budget.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any

import numpy as np
from numba import njit

from models.stats import median

__all__ = ["HeadingConfig", "CompassNoise", "HeadingEstimator", "wrap"]

_STRAIGHT, _TURN = 0, 1
_H = np.array([1.0, 1.0])  # compass: z = theta + c
_CHI2_1_MEDIAN = 0.4549  # median of a chi-square variable with one degree of freedom


def wrap(a: float) -> float:
    """Angle [rad] wrapped to [-pi, pi)."""
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def _wrap_all(a: np.ndarray) -> np.ndarray:
    """:func:`wrap` element-wise (the same arithmetic on an array)."""
    return np.remainder(a + math.pi, 2.0 * math.pi) - math.pi


@njit(cache=True)
def _moments_kernel(w, x, p, ref, mean, cov):  # pragma: no cover - compiled
    """Mean ``mean`` (3,) and covariance ``cov`` (3, 3) of the mixture of the Gaussians ``(x[i], p[i])`` with
    weights ``w`` (Bar-Shalom, Li & Kirubarajan 2001, eq. 11.6.6-5/6: moment matching), angles relative to
    ``ref`` and wrapped as :func:`wrap`. The arithmetic of the numpy form it replaced, element by element and
    in the same order (``d = wrap(x - ref)``, ``m = w d``, ``cov = sum_i w_i (p_i + (d_i - m)(d_i - m)^T)``,
    ``mean = wrap(ref + m)``), so the results are the same to the bit; a stride asks for it about three times,
    and the numpy form spent ~13 us a call on the call overhead of 3-element arrays."""
    n = w.shape[0]
    tp = 2.0 * math.pi
    d = np.empty((n, 3))
    for i in range(n):
        for k in range(3):
            d[i, k] = np.remainder(x[i, k] - ref[k] + math.pi, tp) - math.pi
    m = np.zeros(3)
    for k in range(3):
        s = 0.0
        for i in range(n):
            s += w[i] * d[i, k]
        m[k] = s
    for a in range(3):
        for b in range(3):
            cov[a, b] = 0.0
    for i in range(n):
        for a in range(3):
            ea = d[i, a] - m[a]
            for b in range(3):
                cov[a, b] += w[i] * (p[i, a, b] + ea * (d[i, b] - m[b]))
    for k in range(3):
        mean[k] = np.remainder(ref[k] + m[k] + math.pi, tp) - math.pi


@njit(cache=True)
def _mix_kernel(mu, pi, x, p, x0, p0, cbar):  # pragma: no cover - compiled
    """IMM interaction (Bar-Shalom, Li & Kirubarajan 2001, Sec. 11.6.6): predicted model probabilities
    ``cbar = mu pi``, mixing weights ``w[i, j] = pi[i, j] mu[i] / max(cbar[j], 1e-300)`` and each model's mixed
    start ``(x0[j], p0[j])`` (:func:`_moments_kernel` about ``x[j]``), in the numpy form's arithmetic, ``cbar``
    summed in index order (numpy's ``mu @ pi`` goes through BLAS, which fuses the multiply-add on some hosts)."""
    n = mu.shape[0]
    for j in range(n):
        s = 0.0
        for i in range(n):
            s += mu[i] * pi[i, j]
        cbar[j] = s
    w = np.empty(n)
    mean = np.empty(3)
    cov = np.empty((3, 3))
    for j in range(n):
        c = cbar[j]
        den = c if (c >= 1e-300 or c != c) else 1e-300  # np.maximum (NaN propagates)
        for i in range(n):
            w[i] = (pi[i, j] * mu[i]) / den
        _moments_kernel(w, x, p, x[j], mean, cov)
        for k in range(3):
            x0[j, k] = mean[k]
            for l in range(3):
                p0[j, k, l] = cov[k, l]


@dataclass(frozen=True)
class HeadingConfig:
    """Parameters of the heading estimator (units in the names; angles in radians).

    The motion-model values are statistics of the ZUPT-KF's own strides on the real walks of gdin (1557
    strides of 26 recordings, `docs/engine.md`): the stride-to-stride heading change of strides turning
    less than 10 deg has a robust standard deviation of 2.9 deg (``straight_sigma_rad``); 33 % of strides
    turn more than 10 deg, with an RMS change of 45 deg (``turn_sigma_rad``); turns last two strides at the
    median (``p_turn_stay``).

    Attributes
    ----------
    straight_sigma_rad : float
        Heading change per stride walking straight [rad].
    turn_sigma_rad : float
        Heading change per stride turning [rad].
    p_turn_start : float
        Probability that a straight stride is followed by a turning one.
    p_turn_stay : float
        Probability that a turning stride is followed by another turning one.
    gyro_sigma_rad : float
        Error of a gyroscope heading increment over one stride [rad] (bias residual and noise after the
        ZUPT-KF's calibration).
    gyro_scale : float
        Relative error of a gyroscope heading increment (scale factor) [-].
    deflection_walk_rad : float
        Random walk of the field's deflection per stride beyond what the field's change of shape shows [rad].
    deflection_floor_rad : float
        Smallest noise of the pseudo-observation "no deflection" of a field of the Earth's shape [rad] (a
        perpendicular disturbance leaves the shape as it is).
    offset_prior_rad : float
        Prior standard deviation of the offset of this session's own compass fit [rad] (its field is fitted
        in the session frame: the offset is the fit's error).
    compass_floor_rad : float
        Smallest compass noise [rad], whatever the calibration claims.
    consistency_window : int
        Strides whose innovations estimate the compass's unexplained noise (:class:`CompassNoise`).
    consistency_max_var : float
        Largest strides' heading variance [rad^2] for an innovation to count as a consistency sample
        (the heading must be known from the gyroscope, not from the compass itself).
    outlier_sigmas : float
        A compass reading whose innovation exceeds this many standard deviations of a model weighs as one
        at that bound (Huber): single stances err by up to 150 deg indoors (gdin).
    dominant_on : bool
        Gyroscope-off strides along one of the building's dominant directions (learned by the ZUPT-KF,
        ``ZuptConfig.dom_on``) are pulled onto it with the straight-walking noise (iHDE, 003 drift reduction).
    """

    straight_sigma_rad: float = math.radians(3.0)
    turn_sigma_rad: float = math.radians(45.0)
    p_turn_start: float = 0.15
    p_turn_stay: float = 0.5
    gyro_sigma_rad: float = math.radians(0.2)
    gyro_scale: float = 0.01
    deflection_walk_rad: float = math.radians(0.5)
    deflection_floor_rad: float = math.radians(1.0)
    offset_prior_rad: float = math.radians(2.0)
    compass_floor_rad: float = math.radians(1.0)
    consistency_window: int = 12
    consistency_max_var: float = math.radians(3.0) ** 2
    outlier_sigmas: float = 3.0
    dominant_on: bool = True

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise ValueError(f"HeadingConfig.{f.name}: must be a finite number >= 0, got {v!r}")
        for name in ("p_turn_start", "p_turn_stay"):
            if not 0.0 < getattr(self, name) < 1.0:
                raise ValueError(f"HeadingConfig.{name}: must lie strictly between 0 and 1")
        if self.consistency_window < 1:
            raise ValueError("HeadingConfig.consistency_window: must be at least 1")


class CompassNoise:
    """Variance of one stance compass reading, estimated from the data.

    ``R = max(floor, s_cal)^2 + s_place^2`` [rad^2], with ``s_cal`` the calibration's robust disagreement with
    the ZUPT-KF heading on its own stances; and :meth:`field_sigma`, the heading a change of the field's
    shape can cause (a disturbance ``dB`` turns the compass by up to ``atan(|dB_perp| / B_h)``; the stance
    shows the change of the vertical component and of the horizontal magnitude, not the perpendicular part;
    taken as isotropic, ``|dB_perp| ~ rms(dB_v, dB_h)``, divided by the stance's own horizontal field: a weak
    horizontal field is turned far more by the same disturbance):

    - ``s_place``: what the recent innovations of strides whose heading the gyroscope knew say beyond the
      two (covariance matching, Mehra 1972), robustly: the median of ``nu^2`` over ``consistency_window``
      strides, divided by 0.455 (the median of a chi-square with one degree of freedom), less the median
      expected ``S``, floored at 0. Indoors (gdin) this is where most of the noise is: fields whose magnitude
      and dip look clean still err by 17 deg RMS there, and single stances by up to 150 deg.
    """

    def __init__(self, config: HeadingConfig) -> None:
        self.config = config
        self.samples: list[list[float]] = []  # [nu^2, S] of recent strides with a gyroscope-known heading [rad^2]

    @staticmethod
    def field_sigma(b_v: float, b_h: float, ref_v: float, ref_h: float) -> float:
        """Heading [rad] a disturbance can cause that shows as a stance field of vertical ``b_v`` and horizontal
        ``b_h`` [uT] against a field of ``ref_v``, ``ref_h`` [uT] (the Earth's: the anomaly; the previous
        stance's: the change)."""
        db = math.sqrt(0.5 * ((b_v - ref_v) ** 2 + (b_h - ref_h) ** 2))
        return math.atan2(db, max(b_h, 1e-9))

    @property
    def place_var(self) -> float:
        """Unexplained compass variance in this place [rad^2] (0 without samples)."""
        if not self.samples:
            return 0.0
        a = np.asarray(self.samples)
        return max(0.0, median(a[:, 0]) / _CHI2_1_MEDIAN - median(a[:, 1]))

    def reading_variance(self, s_cal: float) -> float:
        """Variance [rad^2] of a reading for calibration scale ``s_cal`` [rad], without the place term (the
        estimator adds it)."""
        return max(self.config.compass_floor_rad, s_cal) ** 2

    def learn(self, nu: float, s_model: float) -> None:
        """One innovation ``nu`` [rad] of a stride whose heading the gyroscope knew, with the innovation
        variance ``s_model`` [rad^2] the filter expected *without* the place term."""
        self.samples.append([float(nu * nu), float(s_model)])
        del self.samples[: -self.config.consistency_window]

    def get_state(self) -> dict[str, Any]:
        return {"samples": list(self.samples)}

    def set_state(self, d: dict[str, Any]) -> None:
        self.samples = [[float(x) for x in r] for r in d["samples"]]


class HeadingEstimator:
    """IMM filter of the heading and the compass offsets (module docstring).

    State per model: ``x = [theta, c0, d]`` [rad]: theta the heading of the sensor's x axis in the session
    frame; c0 the compass's frame offset (0 for this session's own fit, whose field is fitted in the session
    frame; a profile's compass reads in its own session's frame); d the deflection of the local field
    (a building's, a steel door's). A reading is ``z = theta + c0 + d + v``. The deflection random-walks
    by as much as the stance field's shape changed since the last stance (the foot rotating does not change
    it, a disturbance does), and a field whose shape is the Earth's observes ``d = 0`` with the noise of
    its own anomaly: the compass's change is taken as the foot's turn where the field holds its shape, its
    absolute reading where the field is the Earth's.

    Call :meth:`start` once (the first ZUPT-KF stance defines the session frame: theta known exactly), then
    per stride one prediction (:meth:`predict_gyro` with the gyroscope's heading increment, or
    :meth:`predict_free` without one) followed by at most one :meth:`update_compass`.

    Parameters
    ----------
    config : HeadingConfig
    """

    N = 3  # state size

    def __init__(self, config: HeadingConfig) -> None:
        self.config = config
        self.noise = CompassNoise(config)
        self.x = np.zeros((2, self.N))  # per model: [theta, c0, d] [rad]
        self.p = np.zeros((2, self.N, self.N))  # per model: covariance [rad^2]
        self.mu = np.array([1.0, 0.0])  # model probabilities (straight, turn)
        self._comb_key = b""  # the state _comb was computed for
        self._comb: tuple[np.ndarray, np.ndarray] = (np.zeros(self.N), np.zeros((self.N, self.N)))
        self.started = False
        self.offset_known = False  # c0 has been initialised (prior or first compass reading)
        self.turn_prob = 0.0  # probability that the last stride turned (gyroscope off) [-]
        c = config
        self._pi = np.array([[1.0 - c.p_turn_start, c.p_turn_start], [1.0 - c.p_turn_stay, c.p_turn_stay]])

    # ------------------------------------------------------------------ state
    @property
    def heading(self) -> float:
        """Combined heading estimate theta [rad] (mean of the models by probability)."""
        return float(self._combine()[0][0])

    @property
    def offset(self) -> float:
        """Compass offset c0 + d [rad]."""
        x = self._combine()[0]
        return wrap(x[1] + x[2])

    @property
    def variance(self) -> float:
        """Variance of theta [rad^2] (mixture of the models, spread of their means included)."""
        return float(self._combine()[1][0, 0])

    @property
    def std(self) -> float:
        """Standard deviation of theta [rad]."""
        return math.sqrt(max(self.variance, 0.0))

    @staticmethod
    def _moments(w: np.ndarray, x: np.ndarray, p: np.ndarray, ref: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Mean and covariance of the mixture of Gaussians ``(x[i], p[i])`` with weights ``w`` (angles: the
        differences to ``ref`` are wrapped)."""
        mean = np.empty(3)
        cov = np.empty((3, 3))
        _moments_kernel(np.ascontiguousarray(w, dtype=np.float64), x, p, ref, mean, cov)
        return mean, cov

    def combined(self) -> tuple[np.ndarray, np.ndarray]:
        """Mean ``[theta, c0, d]`` [rad] and covariance [rad^2] of the estimate (the models' mixture)."""
        return self._combine()

    def _combine(self) -> tuple[np.ndarray, np.ndarray]:
        """Moment-matched mean and covariance of the mixture of the models (computed once per state: every
        stride asks for it several times)."""
        key = self.x.tobytes() + self.p.tobytes() + self.mu.tobytes()
        if key != self._comb_key:
            self._comb = self._moments(self.mu, self.x, self.p, self.x[_STRAIGHT])
            self._comb_key = key
        return self._comb

    def start(self, theta: float, theta_var: float = 0.0) -> None:
        """Define the session frame: heading ``theta`` [rad] with variance ``theta_var`` [rad^2]; the compass
        offset is unknown until :meth:`set_offset_prior` or the first compass reading."""
        for j in range(2):
            self.x[j] = [wrap(theta), 0.0, 0.0]
            self.p[j] = np.diag([theta_var, 0.0, self.config.deflection_floor_rad ** 2])
        self.mu = np.array([1.0, 0.0])
        self.started = True
        self.offset_known = False

    def set_offset_prior(self, c: float, std: float) -> None:
        """Compass frame offset ``c`` [rad] known to ``std`` [rad] (own compass fit: 0 and ``offset_prior_rad``)."""
        for j in range(2):
            self.x[j, 1] = wrap(c)
            self.p[j, 1, :] = self.p[j, :, 1] = 0.0
            self.p[j, 1, 1] = std * std
        self.offset_known = True

    def forget_offset(self) -> None:
        """The compass changed (a profile's compass in use): its frame offset is unknown again."""
        self.offset_known = False

    # ------------------------------------------------------------------ predict
    def _mix(self) -> None:
        """IMM interaction step: each model starts from the mixture the Markov chain hands it."""
        x0 = np.empty_like(self.x)
        p0 = np.empty_like(self.p)
        cbar = np.empty(2)
        _mix_kernel(self.mu, self._pi, self.x, self.p, x0, p0, cbar)
        self.x, self.p, self.mu = x0, p0, cbar

    def _q(self, theta_var: float, field_change: float) -> np.ndarray:
        c = self.config
        # diag(theta_var, 0, ...) built directly (np.diag's Python wrapper is most of this call)
        return np.array([[theta_var, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, c.deflection_walk_rad**2 + field_change**2]])

    def predict_gyro(self, delta: float, field_change: float = 0.0, extra_var: float = 0.0) -> None:
        """A stride whose heading change ``delta`` [rad] the gyroscope measured (ZUPT-KF); ``field_change`` [rad]
        the heading noise the change of the stance field's shape since the last stance could cause
        (:meth:`CompassNoise.field_sigma` of one stance against the other); ``extra_var`` [rad^2] added to the
        gyroscope's own (a duty-cycled gyroscope's unseen part of the stride)."""
        c = self.config
        q = self._q(c.gyro_sigma_rad**2 + (c.gyro_scale * delta) ** 2 + extra_var, field_change)
        self._mix()
        for j in range(2):
            self.x[j, 0] = wrap(self.x[j, 0] + delta)
            self.p[j] += q
        self.turn_prob = 0.0

    def predict_free(self, delta: float = 0.0, unseen: float = 1.0, field_change: float = 0.0) -> None:
        """A stride without the gyroscope (or with it for part of the stride: ``delta`` [rad] seen over the
        rest, ``unseen`` the fraction of the stride it missed, 0..1); ``field_change`` as :meth:`predict_gyro`."""
        c = self.config
        u = min(max(unseen, 0.0), 1.0)
        g = c.gyro_sigma_rad**2 + (c.gyro_scale * delta) ** 2
        self._mix()
        for j, s in ((_STRAIGHT, c.straight_sigma_rad), (_TURN, c.turn_sigma_rad)):
            self.x[j, 0] = wrap(self.x[j, 0] + delta)
            self.p[j] += self._q(u * s * s + (1.0 - u) * g, field_change)

    # ------------------------------------------------------------------ update
    def update_compass(self, z: float, r: float, field_anomaly: float, learn: bool = False) -> float:
        """Compass reading ``z`` [rad] with noise variance ``r`` [rad^2] (without the place term, which the
        estimator adds from :attr:`noise`) at a stance whose field differs from the Earth's by as much as
        could turn it by ``field_anomaly`` [rad] (the deflection's pseudo-observation ``d = 0``). ``learn``:
        the stride's heading came from the gyroscope, so its innovation measures the compass
        (:meth:`CompassNoise.learn`). Returns the normalised innovation ``nu^2 / S`` of the combined
        estimate."""
        self._observe_clean(field_anomaly)
        h = np.ones(self.N)
        if not self.offset_known:
            # the frame offset is whatever the first reading says, known as well as that reading
            for j in range(2):
                x, p = self.x[j], self.p[j]
                x[1] = wrap(z - x[0] - x[2])
                p[1, :] = p[:, 1] = 0.0
                p[1, 1] = r + self.noise.place_var + p[0, 0] + p[2, 2]
                p[0, 1] = p[1, 0] = -p[0, 0]
                p[1, 2] = p[2, 1] = -p[2, 2]
            self.offset_known = True
            return 0.0
        xc, pc = self._combine()
        nu = wrap(z - float(h @ xc))
        s_model = float(h @ pc @ h) + r
        if learn and pc[0, 0] <= self.config.consistency_max_var:
            self.noise.learn(nu, s_model)
        r_all = r + self.noise.place_var
        lik = np.zeros(2)
        k_out = self.config.outlier_sigmas
        for j in range(2):
            nu_j = wrap(z - float(h @ self.x[j]))
            s = float(h @ self.p[j] @ h) + r_all
            lik[j] = math.exp(-0.5 * nu_j * nu_j / s) / math.sqrt(2.0 * math.pi * s)
            if nu_j * nu_j > k_out * k_out * s:
                s = nu_j * nu_j / (k_out * k_out)  # Huber: a reading beyond k sigma weighs as one at k sigma
            self._kalman(j, h, nu_j, s)
        post = self.mu * lik
        total = float(post.sum())
        if total > 0.0 and math.isfinite(total):
            self.mu = post / total
        self.turn_prob = float(self.mu[_TURN])
        return nu * nu / (s_model + self.noise.place_var)

    def _kalman(self, j: int, h: np.ndarray, nu: float, s: float) -> None:
        """Kalman update of model ``j`` with observation row ``h``, innovation ``nu`` and its variance ``s``."""
        k = self.p[j] @ h / s
        self.x[j] = _wrap_all(self.x[j] + k * nu)
        self.p[j] = self.p[j] - np.outer(k, h @ self.p[j])

    def _observe_clean(self, field_anomaly: float) -> None:
        """Pseudo-observation ``d = 0`` with noise ``field_anomaly`` [rad] (floored)."""
        h = np.array([0.0, 0.0, 1.0])
        r = max(field_anomaly, self.config.deflection_floor_rad) ** 2
        for j in range(2):
            self._kalman(j, h, -float(self.x[j, 2]), float(self.p[j, 2, 2]) + r)

    def update_heading(self, z: float, var: float) -> float:
        """An absolute observation ``z`` [rad] of theta itself with variance ``var`` [rad^2] (another filter's
        heading, e.g. a phone's MARG attitude filter, whose compass updates it already carries: the compass's
        offsets are not observed). Each model is updated (``h = [1, 0, 0]``) and weighted by its likelihood.
        Returns the normalised innovation ``nu^2 / S`` of the combined estimate."""
        h = np.array([1.0, 0.0, 0.0])
        xc, pc = self._combine()
        nu = wrap(z - float(xc[0]))
        lik = np.zeros(2)
        for j in range(2):
            nu_j = wrap(z - float(self.x[j, 0]))
            s = float(self.p[j, 0, 0]) + var
            lik[j] = math.exp(-0.5 * nu_j * nu_j / s) / math.sqrt(2.0 * math.pi * s)
            self._kalman(j, h, nu_j, s)
        post = self.mu * lik
        total = float(post.sum())
        if total > 0.0 and math.isfinite(total):
            self.mu = post / total
        return nu * nu / (float(pc[0, 0]) + var)

    def update_dominant(self, ref: float, sigma: float, gate: float) -> None:
        """A building's dominant directions ``ref + k * 90 deg`` [rad] (the ZUPT-KF's; heuristic drift
        elimination, 003 drift reduction) as a pseudo-observation of theta with noise ``sigma`` [rad], for each
        model whose heading lies within ``gate`` [rad] of one of them (a stride along a corridor; a path
        across them is left alone)."""
        h = np.array([1.0, 0.0, 0.0])
        for j in range(2):
            grid = ref + round(wrap(self.x[j, 0] - ref) / (0.5 * math.pi)) * 0.5 * math.pi
            nu = wrap(grid - self.x[j, 0])
            if abs(nu) < gate:
                self._kalman(j, h, nu, float(self.p[j, 0, 0]) + sigma * sigma)

    # ------------------------------------------------------------------ forecast
    def forecast(self, r: float | None, field_anomaly: float = 0.0, field_change: float = 0.0) -> tuple[float, float]:
        """Standard deviations [rad] of theta one gyroscope-off stride ahead: in all, and its persistent part.

        The forecast takes a compass reading of variance ``r`` [rad^2] (without the place term; ``None``: no
        compass) in a field as anomalous and as changing as given [rad] (the IMM's mixture moment-matched to
        one Gaussian). What a reading leaves is the error of the offsets ``c0 + d`` it is read through, which
        persists from stride to stride, plus its own noise, which does not; without a compass all of it
        persists."""
        c = self.config
        _, p = self._combine()
        cbar = self.mu @ self._pi
        q = float(cbar @ np.array([c.straight_sigma_rad**2, c.turn_sigma_rad**2]))
        p = p + self._q(q, field_change)
        if r is None:
            s = math.sqrt(max(float(p[0, 0]), 0.0))
            return s, s
        for h, rr in ((np.array([0.0, 0.0, 1.0]), max(field_anomaly, c.deflection_floor_rad) ** 2),
                      (np.ones(self.N), r + self.noise.place_var)):
            k = p @ h / (float(h @ p @ h) + rr)
            p = p - np.outer(k, h @ p)
        off = np.array([0.0, 1.0, 1.0])
        total = math.sqrt(max(float(p[0, 0]), 0.0))
        return total, min(total, math.sqrt(max(float(off @ p @ off), 0.0)))

    # ------------------------------------------------------------------ state
    def get_state(self) -> dict[str, Any]:
        return {"x": self.x.copy(), "p": self.p.copy(), "mu": self.mu.copy(), "started": self.started,
                "offset_known": self.offset_known, "turn_prob": self.turn_prob, "noise": self.noise.get_state()}

    @classmethod
    def from_state(cls, config: HeadingConfig, d: dict[str, Any]) -> HeadingEstimator:
        obj = cls(config)
        obj.x = np.asarray(d["x"], dtype=float).reshape(2, cls.N)
        obj.p = np.asarray(d["p"], dtype=float).reshape(2, cls.N, cls.N)
        obj.mu = np.asarray(d["mu"], dtype=float).reshape(2)
        obj.started = bool(d["started"])
        obj.offset_known = bool(d["offset_known"])
        obj.turn_prob = float(d["turn_prob"])
        obj.noise.set_state(d["noise"])
        return obj
