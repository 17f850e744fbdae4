"""MARG attitude filter for a hand-held, pocketed or worn device: error-state Kalman filter of the attitude and
the gyroscope bias, with gravity, compass and quasi-static-field updates (003 Section 3).

State (003 eq. 1, as an error state): the attitude error ``dtheta`` [rad] in the navigation frame (local NED:
``C_true = exp([dtheta x]) C_est``, ``C`` body -> NED), the gyroscope bias error ``db`` [rad/s] (body frame) and,
while a quasi-static field is being tracked, a clone of the heading error at its start (stochastic cloning).

- Prediction (003 eq. 2-4): the quaternion is integrated with the bias-corrected angular rate; the bias is a
  random walk (003 eq. 7 with ``c = 1``). Without gyroscope samples (gyroscope off) the attitude is held and its
  heading uncertainty grows by :attr:`MargConfig.no_gyro_rad_s` per square-root second.
- Gravity update (003 eq. 8-10 in vector form): the measured specific force rotated to NED against
  ``(0, 0, -g)``; its noise grows with ``| |f| - g |`` (a walking hand's accelerations), so tilt is taken from
  the quieter moments.
- Compass update (003 eq. 16-17): the horizontal field's azimuth in NED against the declination. Its noise
  reflects what a building does to a compass: the field's departure from the Earth's (000 eq. 68's magnitude
  test, here with the dip too, as :func:`models.magnetic.field_undisturbed`) as a smallest disturbance vector,
  and a floor ``compass_sigma_rad`` whose errors persist for ``compass_corr_s`` seconds (so ``R`` is inflated by
  that time over the update interval: correlated errors are not averaged as independent ones).
- Quasi-static field update (003 Sections 3.2.3-3.2.4, absolute and differential magnetic field updates): while
  the device stays at one place (the accelerometer still) and the field keeps its magnitude and dip, the field's
  azimuth in NED must not change, whatever the building did to it; the change is the heading error accumulated
  since the start of the period, which makes the vertical gyroscope bias observable even in a disturbed field.

The hot loops are compiled (numba) functions on plain arrays (:class:`MargState`), shared with
:mod:`models.pdr`; :class:`MargFilter` runs them over a merged stream of samples for standalone use and
benchmarks.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields
from typing import Any

import numpy as np
from numba import njit

__all__ = ["MargConfig", "MargState", "MargFilter", "KIND_ACC", "KIND_GYR", "KIND_MAG", "merge_streams", "G"]

KIND_ACC, KIND_GYR, KIND_MAG = 0, 1, 2
G = 9.80665  # [m/s^2]
_N = 7  # error state: dtheta (3), db (3), heading-error clone (1)

# scalar slots of MargState.s
S_T = 0  # time of the attitude [s]
S_INIT = 1  # attitude initialised from the first accelerometer sample
S_TGYR = 2  # time of the latest gyroscope sample [s]
S_CLONE = 3  # quasi-static period active
S_PSIREF = 4  # field azimuth [rad] at its start, in NED (corrected by the clone's estimate)
S_MREF = 5  # field magnitude [uT] at its start
S_DIPREF = 6  # field dip [rad] at its start
S_TMAG = 7  # time of the latest magnetometer update [s]
S_AMEAN = 8  # exponential mean of |f| [m/s^2]
S_AVAR = 9  # exponential variance of |f| [(m/s^2)^2]
S_TACC = 10  # time of the latest accelerometer sample [s]
S_NQSF = 11  # quasi-static field updates so far
S_NCOMP = 12  # compass updates so far
S_STILL = 13  # 1 when the accelerometer says the device is still
S_RATE = 14  # exponential mean of the bias-corrected angular rate's magnitude [rad/s] (time constant still_tau_s)
S_TWAVE = 15  # time of the latest sample of a device waved about (mean rate above wave_rate_rad_s) [s]
S_TSETTLED = 16  # latest time the gyroscope ran with the vertical bias std <= bias_settled_rad_s [s]
S_TMAGS = 17  # time of the latest magnetometer sample, used or not [s]
N_SCALARS = 18

# config slots (MargConfig.as_array)
_C_FIELDS = ("gyro_noise_rad_s", "bias_walk_rad_s2", "bias_prior_rad_s", "no_gyro_rad_s", "gyro_gap_s",
             "acc_noise_ms2", "acc_dynamic_gain", "compass_sigma_rad", "compass_corr_s", "compass_interval_s",
             "compass_disturbance_gain", "compass_max_rate_rad_s", "qsf_sigma_rad", "qsf_magnitude_ut",
             "qsf_dip_rad", "still_std_ms2", "still_tau_s", "max_dt_s", "wave_rate_rad_s", "bias_settled_rad_s")


@dataclass(frozen=True)
class MargConfig:
    """Parameters of the MARG filter (units in the names).

    Attributes
    ----------
    gyro_noise_rad_s : float
        Angle random walk of the gyroscope [rad/s per sqrt(Hz)]: attitude noise per square-root second.
    bias_walk_rad_s2 : float
        Random walk of the gyroscope bias [rad/s per sqrt(s)].
    bias_prior_rad_s : float
        Prior standard deviation of the gyroscope bias [rad/s] (phone gyroscopes: up to about 3 deg/s).
    no_gyro_rad_s : float
        Heading uncertainty growth while no gyroscope sample arrives [rad per sqrt(s)] (the device may turn).
    gyro_gap_s : float
        A gyroscope silent for longer is off [s].
    acc_noise_ms2 : float
        Gravity update noise of a still device [m/s^2].
    acc_dynamic_gain : float
        Added noise per m/s^2 of ``| |f| - g |`` [-].
    compass_sigma_rad : float
        Heading error of a compass inside a building, floor [rad] (13 deg RMS per landmark segment on the IPIN
        2023 dev trials, `docs/phone.md`).
    compass_corr_s : float
        How long such an error persists [s] (a walk passes a disturbance in seconds).
    compass_interval_s : float
        Time between compass updates [s].
    compass_disturbance_gain : float
        Weight of the smallest disturbance vector relative to the horizontal field [-].
    compass_max_rate_rad_s : float
        No compass update while the device turns faster than this [rad/s] (its tilt is least certain then).
    qsf_sigma_rad : float
        Noise of a quasi-static field azimuth difference [rad].
    qsf_magnitude_ut, qsf_dip_rad : float
        A field whose magnitude [uT] or dip [rad] moved more than this since the period's start ends it.
    still_std_ms2 : float
        The device is still while the exponential standard deviation of ``|f|`` is below this [m/s^2].
    still_tau_s : float
        Time constant of that exponential mean and variance [s].
    max_dt_s : float
        Longest interval integrated in one step [s] (a gap in the data is not a rotation).
    wave_rate_rad_s : float
        A device whose angular rate's mean over ``still_tau_s`` exceeds this [rad/s] is waved about, not carried
        (that mean peaks at 1.2-2.3 rad/s in the turns of the 16 IPIN walks, at 7-9 rad/s in their calibration
        waves); the latest such time is ``S_TWAVE``. A wave's scale-factor errors go into the bias estimate
        unseen by its covariance (after the IPIN wave the vertical bias was 0.1-7.9 deg/s wrong while its
        standard deviation said 0.3-1.2 deg/s); the step-and-heading engine then keeps the gyroscope on while
        standing until the quasi-static field has settled it. (Holding the bias covariance at the scale-factor
        error times the rate while waved made the covariance honest but the always-on landmark error worse,
        2.07 -> 2.75 m: the heading estimator took the wave's wilder turns.)
    bias_settled_rad_s : float
        The vertical gyroscope bias has settled while the gyroscope runs with the filter's own standard deviation
        of it (``sqrt((C P_bb C^T)[2, 2])``) at or below this [rad/s]; ``S_TSETTLED`` is the latest such time and
        :func:`bias_settled` says whether it came after the latest wave. Default: the bias's drift over the
        phone heading estimator's consistency window (24 steps of 0.55 s) no larger than the random drift it
        allows the gyroscope over that window (0.5 deg per step): ``0.5 deg / (0.55 s * sqrt(24))`` = 0.19 deg/s.
        Still at one place the quasi-static field update makes the vertical bias observable (it reaches this in
        10-20 s after the IPIN wave); walking, the compass's place errors do not.
    """

    gyro_noise_rad_s: float = 0.01
    bias_walk_rad_s2: float = 0.0005
    bias_prior_rad_s: float = 0.03
    no_gyro_rad_s: float = 0.5
    gyro_gap_s: float = 0.1
    acc_noise_ms2: float = 0.5
    acc_dynamic_gain: float = 2.0
    compass_sigma_rad: float = 0.25
    compass_corr_s: float = 10.0
    compass_interval_s: float = 0.1
    compass_disturbance_gain: float = 0.0
    compass_max_rate_rad_s: float = 1.0
    qsf_sigma_rad: float = 0.03
    qsf_magnitude_ut: float = 2.0
    qsf_dip_rad: float = math.radians(3.0)
    still_std_ms2: float = 0.6
    still_tau_s: float = 0.5
    max_dt_s: float = 0.5
    wave_rate_rad_s: float = 3.0
    bias_settled_rad_s: float = math.radians(0.5) / (0.55 * math.sqrt(24.0))

    def __post_init__(self) -> None:
        for f in fields(self):
            v = float(getattr(self, f.name))
            if not math.isfinite(v) or v < 0:
                raise ValueError(f"MargConfig: {f.name} must be a finite non-negative number, got {v!r}")
        for name in ("gyro_noise_rad_s", "compass_interval_s", "still_tau_s", "max_dt_s", "gyro_gap_s", "qsf_sigma_rad"):
            if getattr(self, name) <= 0:
                raise ValueError(f"MargConfig: {name} must be positive")

    def as_array(self) -> np.ndarray:
        return np.array([float(getattr(self, k)) for k in _C_FIELDS], dtype=np.float64)

    def to_dict(self) -> dict[str, float]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> MargConfig:
        return cls(**{k: float(v) for k, v in d.items()})


def _pad(x: np.ndarray, n: int) -> np.ndarray:
    """``x`` with zeros appended up to length ``n`` (a state saved before a scalar slot was added)."""
    out = np.zeros(n)
    out[: min(n, len(x))] = x[:n]
    return out


@dataclass
class MargState:
    """Everything the filter carries from one sample to the next (plain arrays for the compiled functions).

    Attributes
    ----------
    q : ndarray, shape (4,)
        Attitude quaternion body -> NED (w, x, y, z).
    b : ndarray, shape (3,)
        Gyroscope bias [rad/s], body frame.
    P : ndarray, shape (7, 7)
        Error covariance (dtheta [rad], db [rad/s], heading clone [rad]).
    w : ndarray, shape (3,)
        Latest angular rate sample [rad/s].
    s : ndarray, shape (N_SCALARS,)
        Scalars (times, quasi-static period, stillness); see the ``S_*`` slots.
    ref : ndarray, shape (3,)
        Expected field [uT]: horizontal magnitude, vertical (down) component, declination [rad]; the magnitude 0
        when unknown (no anchor: the compass then weighs only its floor noise and north is magnetic).
    """

    q: np.ndarray
    b: np.ndarray
    P: np.ndarray
    w: np.ndarray
    s: np.ndarray
    ref: np.ndarray

    @classmethod
    def new(cls, config: MargConfig, reference_ned_ut: np.ndarray | None = None, declination_rad: float = 0.0) -> MargState:
        P = np.zeros((_N, _N))
        P[0, 0] = P[1, 1] = 0.5
        P[2, 2] = 10.0  # heading unknown until the compass says
        for i in (3, 4, 5):
            P[i, i] = config.bias_prior_rad_s ** 2
        P[6, 6] = 1.0
        s = np.zeros(N_SCALARS)
        s[S_TGYR] = s[S_TMAG] = s[S_TACC] = s[S_TWAVE] = s[S_TSETTLED] = s[S_TMAGS] = -1e300
        ref = np.zeros(3)
        if reference_ned_ut is not None:
            r = np.asarray(reference_ned_ut, dtype=float).reshape(3)
            ref[0], ref[1] = math.hypot(r[0], r[1]), r[2]
        ref[2] = float(declination_rad)
        return cls(np.array([1.0, 0.0, 0.0, 0.0]), np.zeros(3), P, np.zeros(3), s, ref)

    def get_state(self) -> dict[str, Any]:
        return {"q": self.q.copy(), "b": self.b.copy(), "P": self.P.copy(), "w": self.w.copy(), "s": self.s.copy(),
                "ref": self.ref.copy()}

    @classmethod
    def from_state(cls, d: dict[str, Any]) -> MargState:
        return cls(np.asarray(d["q"], dtype=float).reshape(4).copy(), np.asarray(d["b"], dtype=float).reshape(3).copy(),
                   np.asarray(d["P"], dtype=float).reshape(_N, _N).copy(), np.asarray(d["w"], dtype=float).reshape(3).copy(),
                   _pad(np.asarray(d["s"], dtype=float).reshape(-1), N_SCALARS), np.asarray(d["ref"], dtype=float).reshape(3).copy())

    @property
    def heading_std_rad(self) -> float:
        return float(math.sqrt(max(self.P[2, 2], 0.0)))

    @property
    def vertical_bias_std_rad_s(self) -> float:
        """Standard deviation of the gyroscope bias about the vertical [rad/s] (the part that turns the heading):
        ``sqrt((C P_bb C^T)[2, 2])`` with ``C`` body -> NED."""
        return float(math.sqrt(vertical_bias_var(self.q, self.P)))


# ---------------------------------------------------------------------------------------------- compiled core
# The per-sample functions work on scalars and tuples and on one scratch array per call of the outer loop
# (``work``, :data:`_WORK_ROWS` x 7): a heap array per sample cost more than the arithmetic.
_W_K0, _W_K1, _W_DX, _W_HP0, _W_HP1, _W_PH, _W_H = range(7)
_WORK_ROWS = 7


@njit(cache=True)
def _qmul(p0: float, p1: float, p2: float, p3: float, q0: float, q1: float, q2: float, q3: float
          ) -> tuple[float, float, float, float]:
    """Quaternion product ``p q`` (w, x, y, z)."""
    return (p0 * q0 - p1 * q1 - p2 * q2 - p3 * q3,
            p0 * q1 + p1 * q0 + p2 * q3 - p3 * q2,
            p0 * q2 - p1 * q3 + p2 * q0 + p3 * q1,
            p0 * q3 + p1 * q2 - p2 * q1 + p3 * q0)


@njit(cache=True)
def _rv2q(v0: float, v1: float, v2: float) -> tuple[float, float, float, float]:
    """Quaternion of rotation vector ``v`` [rad]; below 0.1 rad the series to the 4th order (error < 3e-9,
    no trigonometry: the per-sample increments and the error injections are all that small)."""
    a2 = v0 * v0 + v1 * v1 + v2 * v2
    if a2 < 0.01:
        c = 1.0 - a2 / 8.0 + a2 * a2 / 384.0
        s = 0.5 - a2 / 48.0 + a2 * a2 / 3840.0
    else:
        a = math.sqrt(a2)
        c = math.cos(0.5 * a)
        s = math.sin(0.5 * a) / a
    x, y, z = v0 * s, v1 * s, v2 * s
    n = math.sqrt(c * c + x * x + y * y + z * z)
    return c / n, x / n, y / n, z / n


@njit(cache=True)
def dcm(q: np.ndarray) -> tuple[tuple[float, float, float], tuple[float, float, float], tuple[float, float, float]]:
    """Rows of the body -> NED direction cosine matrix of quaternion ``q`` (w, x, y, z), as tuples."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    return ((1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)),
            (2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)),
            (2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)))


@njit(cache=True)
def _wrap(a: float) -> float:
    return (a + math.pi) % (2.0 * math.pi) - math.pi


@njit(cache=True)
def _inject(q: np.ndarray, b: np.ndarray, s: np.ndarray, dx: np.ndarray) -> None:
    """Move the estimated error into the nominal state (the error state is zero again)."""
    d0, d1, d2, d3 = _rv2q(dx[0], dx[1], dx[2])
    qn = _qmul(d0, d1, d2, d3, q[0], q[1], q[2], q[3])
    nrm = math.sqrt(qn[0] ** 2 + qn[1] ** 2 + qn[2] ** 2 + qn[3] ** 2)
    for i in range(4):
        q[i] = qn[i] / nrm
    for i in range(3):
        b[i] += dx[3 + i]
    if s[S_CLONE] > 0.5:
        s[S_PSIREF] += dx[6]


@njit(cache=True)
def _scalar_update(q: np.ndarray, b: np.ndarray, P: np.ndarray, s: np.ndarray, h: np.ndarray, z: float, r: float,
                   work: np.ndarray) -> None:
    """Kalman update with one scalar measurement ``z = h . x + noise(r)``: ``P <- P - k (P h)^T``, symmetrised."""
    n = P.shape[0]
    ph = work[_W_PH]
    for i in range(n):
        acc = 0.0
        for j in range(n):
            acc += P[i, j] * h[j]
        ph[i] = acc
    sv = r
    for i in range(n):
        sv += h[i] * ph[i]
    dx = work[_W_DX]
    for i in range(n):
        dx[i] = ph[i] / sv * z
    for i in range(n):
        ki = ph[i] / sv
        for j in range(n):
            P[i, j] -= ki * ph[j]
    for i in range(n):
        for j in range(i + 1, n):
            a = 0.5 * (P[i, j] + P[j, i])
            P[i, j] = a
            P[j, i] = a
    _inject(q, b, s, dx)


@njit(cache=True)
def marg_init(q: np.ndarray, s: np.ndarray, f: np.ndarray, t: float) -> None:
    """Roll and pitch from one specific-force sample, heading 0 (uncertain: P says so)."""
    n = math.sqrt(f[0] ** 2 + f[1] ** 2 + f[2] ** 2)
    if n < 1e-6:
        return
    ax, ay, az = f[0] / n, f[1] / n, f[2] / n
    roll = math.atan2(-ay, -az)
    pitch = math.atan2(ax, math.sqrt(ay * ay + az * az))
    cr, sr, cp, sp = math.cos(0.5 * roll), math.sin(0.5 * roll), math.cos(0.5 * pitch), math.sin(0.5 * pitch)
    q[0], q[1], q[2], q[3] = cr * cp, sr * cp, cr * sp, -sr * sp
    s[S_INIT] = 1.0
    s[S_T] = t


@njit(cache=True)
def marg_predict(q: np.ndarray, b: np.ndarray, P: np.ndarray, w: np.ndarray, s: np.ndarray, t: float, c: np.ndarray) -> None:
    """Propagate attitude and covariance to time ``t`` [s] with the latest angular rate (003 eq. 2-4)."""
    dt = t - s[S_T]
    if dt <= 0.0:
        return
    s[S_T] = t
    if dt > c[17]:
        dt = c[17]
    gyro = (t - s[S_TGYR]) <= c[4]
    C = dcm(q)
    if gyro:
        r0, r1, r2, r3 = _rv2q((w[0] - b[0]) * dt, (w[1] - b[1]) * dt, (w[2] - b[2]) * dt)
        qn = _qmul(q[0], q[1], q[2], q[3], r0, r1, r2, r3)
        nrm = math.sqrt(qn[0] ** 2 + qn[1] ** 2 + qn[2] ** 2 + qn[3] ** 2)
        for i in range(4):
            q[i] = qn[i] / nrm
        # P <- F P F^T + Q with F = [[I, -C dt, 0], [0, I, 0], [0, 0, 1]]: rows 0-2, then columns 0-2 (in place:
        # the rows update reads rows 3-5 only, the columns update columns 3-5 only)
        n = P.shape[0]
        for i in range(3):
            Ci = C[i]
            for j in range(n):
                P[i, j] = P[i, j] - dt * (Ci[0] * P[3, j] + Ci[1] * P[4, j] + Ci[2] * P[5, j])
        for i in range(n):
            for j in range(3):
                Cj = C[j]
                P[i, j] = P[i, j] - dt * (P[i, 3] * Cj[0] + P[i, 4] * Cj[1] + P[i, 5] * Cj[2])
        for i in range(3):
            P[i, i] += c[0] * c[0] * dt
            P[3 + i, 3 + i] += c[1] * c[1] * dt
        r2 = (w[0] - b[0]) ** 2 + (w[1] - b[1]) ** 2 + (w[2] - b[2]) ** 2
        s[S_RATE] += dt / (c[16] + dt) * (math.sqrt(r2) - s[S_RATE])  # 1 - exp(-dt/tau) to first order
        if s[S_RATE] > c[18]:
            s[S_TWAVE] = t
    else:
        s[S_RATE] = 0.0  # no rate without the gyroscope
        for i in range(3):
            P[i, i] += c[0] * c[0] * dt
            P[3 + i, 3 + i] += c[1] * c[1] * dt
        P[0, 0] += c[3] * c[3] * dt * 0.25  # tilt: a turning hand tilts too, the gravity update holds it
        P[1, 1] += c[3] * c[3] * dt * 0.25
        P[2, 2] += c[3] * c[3] * dt


@njit(cache=True)
def marg_gravity(q: np.ndarray, b: np.ndarray, P: np.ndarray, s: np.ndarray, f: np.ndarray, c: np.ndarray,
                 work: np.ndarray) -> None:
    """Gravity update with specific force ``f`` [m/s^2] (body): NED ``C f`` against ``(0, 0, -g)``.

    ``C f - (0, 0, -g) = (g dtheta_y, -g dtheta_x, 0)`` to first order: one update with the north and east
    components (``H`` picks ``g P[1]`` and ``-g P[0]``)."""
    n = math.sqrt(f[0] ** 2 + f[1] ** 2 + f[2] ** 2)
    sig = c[5] + c[6] * abs(n - G)
    r = sig * sig
    C0, C1, _ = dcm(q)
    z0 = C0[0] * f[0] + C0[1] * f[1] + C0[2] * f[2]
    z1 = C1[0] * f[0] + C1[1] * f[1] + C1[2] * f[2]
    m = P.shape[0]
    # P H^T: columns g P[:, 1] and -g P[:, 0]; S = H P H^T + R
    s00 = G * G * P[1, 1] + r
    s01 = -G * G * P[1, 0]
    s11 = G * G * P[0, 0] + r
    det = s00 * s11 - s01 * s01
    i00, i01, i11 = s11 / det, -s01 / det, s00 / det
    K0, K1, dx, HP0, HP1 = work[_W_K0], work[_W_K1], work[_W_DX], work[_W_HP0], work[_W_HP1]
    for i in range(m):
        a0, a1 = G * P[i, 1], -G * P[i, 0]
        K0[i] = a0 * i00 + a1 * i01
        K1[i] = a0 * i01 + a1 * i11
    for i in range(m):
        dx[i] = K0[i] * z0 + K1[i] * z1
    for j in range(m):
        HP0[j] = G * P[1, j]
        HP1[j] = -G * P[0, j]
    for i in range(m):
        for j in range(m):
            P[i, j] -= K0[i] * HP0[j] + K1[i] * HP1[j]
    for i in range(m):
        for j in range(i + 1, m):
            a = 0.5 * (P[i, j] + P[j, i])
            P[i, j] = a
            P[j, i] = a
    _inject(q, b, s, dx)


@njit(cache=True)
def still_update(s: np.ndarray, f: np.ndarray, t: float, c: np.ndarray) -> None:
    """Exponential mean and variance of ``|f|`` (time constant ``still_tau_s``) and the still flag."""
    n = math.sqrt(f[0] ** 2 + f[1] ** 2 + f[2] ** 2)
    if s[S_TACC] < -1e299:
        s[S_AMEAN] = n
        s[S_AVAR] = 1.0  # not still until it has been seen so
    else:
        dt = t - s[S_TACC]
        if dt < 0.0:
            dt = 0.0
        a = 1.0 - math.exp(-dt / c[16])
        d = n - s[S_AMEAN]
        s[S_AMEAN] += a * d
        s[S_AVAR] = (1.0 - a) * (s[S_AVAR] + a * d * d)
    s[S_TACC] = t
    s[S_STILL] = 1.0 if s[S_AVAR] < c[15] * c[15] else 0.0


@njit(cache=True)
def marg_magnetic(q: np.ndarray, b: np.ndarray, P: np.ndarray, s: np.ndarray, w: np.ndarray, ref: np.ndarray,
                  m: np.ndarray, t: float, c: np.ndarray, work: np.ndarray) -> None:
    """Compass and quasi-static field updates with field ``m`` [uT] (body), every ``compass_interval_s``."""
    spacing = t - s[S_TMAGS]
    s[S_TMAGS] = t
    # due every compass_interval_s; a stream sampled at most twice as fast is taken whole (its samples come about
    # one interval apart, with jitter: a 10 Hz stream would otherwise lose every other one)
    if t - s[S_TMAG] < c[9] and spacing < 0.5 * c[9]:
        return
    s[S_TMAG] = t
    C = dcm(q)
    mn = (C[0][0] * m[0] + C[0][1] * m[1] + C[0][2] * m[2], C[1][0] * m[0] + C[1][1] * m[1] + C[1][2] * m[2],
          C[2][0] * m[0] + C[2][1] * m[1] + C[2][2] * m[2])
    mh = math.sqrt(mn[0] ** 2 + mn[1] ** 2)
    if mh < 1.0:
        return
    mag = math.sqrt(mh * mh + mn[2] ** 2)
    dip = math.atan2(mn[2], mh)
    psi = math.atan2(mn[1], mn[0])
    gyro = (t - s[S_TGYR]) <= c[4]
    rate = math.sqrt((w[0] - b[0]) ** 2 + (w[1] - b[1]) ** 2 + (w[2] - b[2]) ** 2) if gyro else 0.0
    still = s[S_STILL] > 0.5
    # quasi-static field: the device at one place, its field unchanged -> its azimuth must not change
    if still and gyro and s[S_CLONE] > 0.5 and abs(mag - s[S_MREF]) < c[13] and abs(dip - s[S_DIPREF]) < c[14]:
        h = work[_W_H]
        h[:] = 0.0
        h[2] = 1.0
        h[6] = -1.0
        _scalar_update(q, b, P, s, h, _wrap(s[S_PSIREF] - psi), c[12] * c[12], work)
        s[S_NQSF] += 1.0
    elif still and gyro and rate < c[11]:
        s[S_CLONE] = 1.0  # a new period: clone the heading error
        s[S_PSIREF] = psi
        s[S_MREF] = mag
        s[S_DIPREF] = dip
        for i in range(_N):
            P[6, i] = P[2, i]
            P[i, 6] = P[i, 2]
        P[6, 6] = P[2, 2]
    else:
        s[S_CLONE] = 0.0
    if s[S_CLONE] < 0.5:
        for i in range(_N):
            P[6, i] = 0.0
            P[i, 6] = 0.0
        P[6, 6] = 1.0
    # compass: the horizontal field points to magnetic north, the declination east of true north. Its error is the
    # building's, fixed in space: a device that stays at one place reads the same error again and again, so a
    # still device updates only a heading the compass has not yet set as well as one place can tell: the floor,
    # and, where the Earth's field is known, the angle the smallest disturbance vector can turn the field by
    # (a clean field: the floor; the IPIN hall's 27-40 uT against the Earth's 49: a radian)
    dmin = math.sqrt((mh - ref[0]) ** 2 + (mn[2] - ref[1]) ** 2) if ref[0] > 0.0 else 0.0  # [uT]
    place = c[7] * c[7] + (dmin / mh) ** 2 if ref[0] > 0.0 else 4.0 * c[7] * c[7]
    if rate < c[11] and c[7] > 0.0 and not (still and P[2, 2] < place):
        r = c[7] * c[7] * max(c[8] / c[9], 1.0)
        if ref[0] > 0.0:
            r += (c[10] * dmin / mh) ** 2 * max(c[8] / c[9], 1.0)
        h = work[_W_H]
        h[:] = 0.0
        h[2] = 1.0
        _scalar_update(q, b, P, s, h, _wrap(ref[2] - psi), r, work)
        s[S_NCOMP] += 1.0


@njit(cache=True)
def marg_event(q: np.ndarray, b: np.ndarray, P: np.ndarray, w: np.ndarray, s: np.ndarray, ref: np.ndarray, t: float,
               kind: int, v: np.ndarray, c: np.ndarray, work: np.ndarray) -> None:
    """One sample of any stream, in time order (``work``: scratch, :func:`new_work`)."""
    if s[S_INIT] < 0.5:
        if kind == KIND_ACC:
            marg_init(q, s, v, t)
            still_update(s, v, t, c)
        elif kind == KIND_GYR:
            w[:] = v
            s[S_TGYR] = t
        return
    marg_predict(q, b, P, w, s, t, c)
    if kind == KIND_GYR:
        w[:] = v
        s[S_TGYR] = t
    elif kind == KIND_ACC:
        still_update(s, v, t, c)
        marg_gravity(q, b, P, s, v, c, work)
    else:
        marg_magnetic(q, b, P, s, w, ref, v, t, c, work)
        if t - s[S_TGYR] <= c[4] and vertical_bias_var(q, P) <= c[19] * c[19]:
            s[S_TSETTLED] = t


@njit(cache=True)
def new_work() -> np.ndarray:
    """Scratch for :func:`marg_event` (one per loop over samples, not per sample)."""
    return np.zeros((_WORK_ROWS, _N))


@njit(cache=True)
def vertical_bias_var(q: np.ndarray, P: np.ndarray) -> float:
    """Variance of the gyroscope bias about the vertical [(rad/s)^2]: ``(C P_bb C^T)[2, 2]``, ``C`` body -> NED."""
    C2 = dcm(q)[2]
    acc = 0.0
    for i in range(3):
        for j in range(3):
            acc += C2[i] * P[3 + i, 3 + j] * C2[j]
    return max(acc, 0.0)


def bias_settled(s: np.ndarray) -> bool:
    """Has the vertical gyroscope bias settled (``bias_settled_rad_s``) since the start and the latest wave?"""
    return bool(s[S_TSETTLED] > -1e299 and s[S_TSETTLED] >= s[S_TWAVE])


@njit(cache=True)
def _run(t: np.ndarray, kind: np.ndarray, v: np.ndarray, q: np.ndarray, b: np.ndarray, P: np.ndarray, w: np.ndarray,
         s: np.ndarray, ref: np.ndarray, c: np.ndarray, out_q: np.ndarray) -> None:
    work = new_work()
    for i in range(t.shape[0]):
        marg_event(q, b, P, w, s, ref, t[i], kind[i], v[i], c, work)
        out_q[i] = q


def merge_streams(acc: tuple[np.ndarray, np.ndarray], gyr: tuple[np.ndarray, np.ndarray],
                  mag: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Samples of the three streams in one time order ``(t [s or ns], kind, values)``; at equal times the
    accelerometer first, then the gyroscope, then the magnetometer."""
    ts = [np.asarray(x[0]) for x in (acc, gyr, mag)]
    vs = [np.asarray(x[1], dtype=np.float64).reshape(-1, 3) for x in (acc, gyr, mag)]
    t = np.concatenate(ts)
    k = np.concatenate([np.full(len(x), i, dtype=np.int64) for i, x in enumerate(ts)])
    v = np.concatenate(vs)
    o = np.lexsort((k, t))
    return t[o], k[o], v[o]


class MargFilter:
    """The MARG filter over recorded streams (standalone use and benchmarks; :mod:`models.pdr` runs the same
    compiled functions inside the step-and-heading pipeline).

    Parameters
    ----------
    config : MargConfig
    reference_ned_ut : ndarray, shape (3,), optional
        Expected Earth field in NED [uT] (:func:`models.magnetic.wmm_reference`); None: unknown.
    declination_rad : float
        Magnetic declination [rad] (east positive); 0 without an anchor (north is then magnetic).
    """

    def __init__(self, config: MargConfig | None = None, reference_ned_ut: np.ndarray | None = None,
                 declination_rad: float = 0.0) -> None:
        self.config = config or MargConfig()
        self._c = self.config.as_array()
        self.state = MargState.new(self.config, reference_ned_ut, declination_rad)

    def process(self, t_s: np.ndarray, kind: np.ndarray, values: np.ndarray) -> np.ndarray:
        """Run over samples in time order (:func:`merge_streams`); returns the attitude after each, shape (n, 4)."""
        t = np.ascontiguousarray(t_s, dtype=np.float64)
        out = np.zeros((t.size, 4))
        st = self.state
        _run(t, np.ascontiguousarray(kind, dtype=np.int64), np.ascontiguousarray(values, dtype=np.float64).reshape(-1, 3),
             st.q, st.b, st.P, st.w, st.s, st.ref, self._c, out)
        return out
