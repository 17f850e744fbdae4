"""Gyro-free heading at each stance: tilt-compensated compass with online magnetometer calibration.

While the gyroscope is off the accelerometer at stance gives roll and pitch (the foot is still, so the
specific force is gravity alone) and the calibrated magnetometer gives the heading. The magnetometer is
calibrated online while the ZUPT-KF knows the attitude: at each stance the navigator's heading and the
accelerometer tilt give the body-to-NED rotation C_i, and the model ``C_i W (m_i - b) = m_n`` (hard iron
b [uT], optional soft iron W = I + E with E symmetric and trace-free, constant field m_n [uT] in the
navigator's own NED frame) is linear in (m_n, W b, E) and fitted by Huber-weighted least squares. Because
m_n is expressed in the navigator's frame, the compass heading comes out in that frame directly (no
declination, no offset between the two).

Stances are nearly level, so the stance data cannot tell the hard iron along the body's vertical axis from
the field's vertical component (on gdin the unconstrained fit split the same ~35 uT between them anywhere
from -52/+83 uT); the wrong split then turns every stance-to-stance pitch change into a heading error
(``sin(pitch) * error`` enters the horizontal field). Worse, the accelerometer's tilt is noisier than the
stances' real tilt differences (synthetic stances are exactly level), and a fit that puts the whole vertical
field into the hard iron makes the compass blind to tilt errors, so least squares drifts there: 35-40 uT of
"hard iron" on a sensor with none, which real stances (slopes, stairs, a re-mounted sensor) would turn into
heading errors of ``tan(dip)`` times their tilt change. Only a zero-mean prior on the vertical hard iron
(``vertical_hard_iron_std``) fixes that direction in the linear fit. What observes it is the swing: the foot
pitches by tens of degrees between stances, and the field's magnitude does not depend on the attitude, so
``|W (m_k - b)| = |m_n|`` at the swing's samples (the attitude-free constraint of ellipsoid calibration) holds
the hard iron in all three axes. A trusted calibration with swing samples is refined by a joint robust fit of
stances and swings (:meth:`MagCalibrator._fit_joint`) that also fits the soft iron the swings make observable
and the rotation between the magnetometer's axes and the accelerometer's tilt (the accelerometer's offset tilts
every stance). That offset changes from one power-on to the next; a calibration loaded from an earlier session
re-estimates it from this session's stances through the dip, which must not depend on the heading
(:meth:`MagCalibrator.observe_dip`). The linear fit's soft-iron scale is fixed (trace E = 0): a common scale of
W and m_n is unobservable and does not affect the heading (without it the fit could shrink W and m_n towards
zero).

A stance is magnetically disturbed when the calibrated field's magnitude or dip differs from m_n by more
than a tolerance (the magnitude/inclination test of 002 eq. 4-5 applied to the calibrated field).
Angles [rad], heading clockwise from north (NED); field [uT]; specific force [m/s^2], body frame.
"""

from __future__ import annotations

import itertools
import math

import numpy as np

from models._compass_kernel import N_JOINT, PAUSED, joint_gauss_newton
from models.rotations import euler_to_dcm, rotvec_to_dcm, skew
from models.stats import median

__all__ = ["tilt_from_acc", "level_heading", "MagCalibrator"]

# Latest stances and swing field samples kept: every ZUPT-KF stance adds one stance and up to 8 swing samples, and
# the calibration lives in the engine state (stored after every upload) and in each calibrated behaviour of the
# profile a user carries from day to day, so neither may grow with the time the sensor is used. 300 stances are
# 20x the 15 a fit needs; 600 swing samples (75 strides) fix the vertical hard iron to well under 1 uT.
_ROWS_KEEP = 300
_SWING_KEEP = 600
# A compass is trusted when the robust scale of its disagreement with the ZUPT-KF is within max_heading_rms and
# the plain RMS within this many times it: a few stances of steel that passed the disturbance gate (synthetic
# mixed day, returning user, seed 1: 2 of 18 stances) took a 15-stance fit's RMS from 3.9 to 6.0 deg (its
# robust scale stayed under 2 deg) and, untrusted, it took every stance from then on (RMS 12 deg at the end,
# gyroscope on for the rest of the day); indoors the disagreement is everywhere, not in a few stances (gdin:
# robust 5.2-23.6 deg, RMS 8.3-35.7 deg).
_RMS_OVER_SCALE = 2.0
# ... and the calibration stances' field is one field: robust scales of its magnitude and dip about m_n within
# these (clean synthetic fits: <= 0.5 % and 0.15 deg; a fit on stances inside steel agreed with the ZUPT-KF to
# 1.7 deg on a straight run while its field's magnitude scattered by 5.6 % and its dip by 8.7 deg, and every
# later stance of the Earth's field then failed its disturbance gate)
_MAX_SHAPE_MAG = 0.03
_MAX_SHAPE_DIP = math.radians(2.0)
# An untrusted fit is tried again on the newest half, then quarter, of its stances (at least this many): a walk
# that began in steel has its Earth-field stances after it, and a fit on all of them stays untrusted
_RECENT_MIN = 20
_DIP_STANCES = 300  # latest stances whose dip estimates a session's tilt offset (MagCalibrator.observe_dip)
_SESSION_TILT_STD = math.radians(0.8)  # prior of a session's tilt offset against the fitting session's [rad]:
# the change of the accelerometer's turn-on offset between two power-ons (10 mg each, the synthesiser's
# assumption for the LSM9DS1 after a static calibration: sqrt(2) x 0.57 deg)
_FREEZE_WEIGHTS = 8  # MagCalibrator._fit_joint re-weights (Huber, robust scales) in its first iterations only
_DIP_NOISE = math.sin(math.radians(0.1))  # floor of that fit's robust scale: the stillest stance window's tilt
# noise (gait_dr.GaitPipeline._queue_event); a synthesiser figure (0.08 deg walking), not yet measured on a real walk


def _table(rows: list[list[float]], width: int) -> np.ndarray:
    """``np.asarray(rows, dtype=np.float64).reshape(-1, width)`` for a list of ``width``-long rows of numbers:
    the same array, filled from one flat iterator (about half the time of the nested-list conversion for the
    hundreds of rows the calibrator keeps; it is made at every refit and every stored state)."""
    return np.fromiter(itertools.chain.from_iterable(rows), dtype=np.float64, count=width * len(rows)).reshape(-1, width)


def tilt_from_acc(acc: np.ndarray) -> tuple[float, float]:
    """Roll and pitch [rad] from the specific force at rest (body frame, m/s^2; reads +g upwards)."""
    f = np.asarray(acc, dtype=np.float64).reshape(3)
    roll = math.atan2(-f[1], -f[2])
    pitch = math.atan2(f[0], math.hypot(f[1], f[2]))
    return roll, pitch


def _tilt(f: list[float]) -> tuple[float, float]:
    """:func:`tilt_from_acc` on plain floats (the same operations)."""
    return math.atan2(-f[1], -f[2]), math.atan2(f[0], math.hypot(f[1], f[2]))


def _level_heading(f: tuple[float, float, float] | list[float], m: tuple[float, float, float] | list[float]) -> float:
    """:func:`level_heading` on plain floats (no array overhead: called once per Gait-DR step)."""
    roll = math.atan2(-f[1], -f[2])
    pitch = math.atan2(f[0], math.hypot(f[1], f[2]))
    cr, sr, cp, sp = math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch)
    # first two rows of Rz(0) Ry(pitch) Rx(roll) (models.rotations.euler_to_dcm) applied to m
    h_n = cp * m[0] + sp * sr * m[1] + sp * cr * m[2]
    h_e = cr * m[1] - sr * m[2]
    return math.atan2(h_e, h_n)


def level_heading(acc: np.ndarray, mag: np.ndarray) -> float:
    """Angle [rad] of the levelled field's horizontal part seen from the body with zero yaw: atan2(E, N)."""
    return _level_heading(np.asarray(acc, dtype=np.float64).reshape(3).tolist(),
                          np.asarray(mag, dtype=np.float64).reshape(3).tolist())


def _soft_matrix(e: np.ndarray) -> np.ndarray:
    """W = I + E from (e_h, e01, e02, e12): E symmetric with diagonal (e_h, -e_h, 0)
    (:meth:`MagCalibrator._fit_joint`)."""
    return np.eye(3) + np.array([[e[0], e[1], e[2]], [e[1], -e[0], e[3]], [e[2], e[3], 0.0]])


def _soft_map(m: np.ndarray) -> np.ndarray:
    """``E m`` as a linear map of (e_h, e01, e02, e12) for :func:`_soft_matrix`: shape (N, 3, 4)."""
    m = np.asarray(m, dtype=np.float64).reshape(-1, 3)
    z = np.zeros(m.shape[0])
    return np.stack([np.stack([m[:, 0], m[:, 1], m[:, 2], z], -1),
                     np.stack([-m[:, 1], m[:, 0], z, m[:, 2]], -1),
                     np.stack([z, z, m[:, 0], m[:, 1]], -1)], -2)


def _rot_vec(r: np.ndarray) -> np.ndarray:
    """Rotation vector [rad] of a rotation matrix (small to moderate angles)."""
    ang = math.acos(max(-1.0, min(1.0, (float(np.trace(r)) - 1.0) / 2.0)))
    v = np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]]) / 2.0
    sn = math.sin(ang)
    return v * (ang / sn) if sn > 1e-12 else v


class MagCalibrator:
    """Online hard/soft-iron calibration against the ZUPT-KF attitude, and the compass it enables.

    Parameters
    ----------
    soft_iron : bool
        Also fit the soft-iron matrix W = I + E (9 more unknowns, ridge prior ``soft_iron_std``).
    min_stances : int
        Stances needed before the calibration is used.
    min_heading_spread : float
        The stances must span headings with at least this circular spread [rad] (hard iron and field are
        only separable when the foot has pointed in different directions).
    mag_tol : float
        Disturbance gate: relative magnitude tolerance of the calibrated field against |m_n|.
    dip_tol : float
        Disturbance gate: dip-angle tolerance [rad].
    soft_iron_std : float
        Ridge prior standard deviation of the soft-iron elements E (dimensionless).
    hard_iron_std, vertical_hard_iron_std : float
        Zero-mean prior standard deviations of the hard iron along the body x/y axes and the body z axis
        [uT] (z: the direction level stances cannot observe; see the module docstring). ``hard_iron_std``:
        real parts carry tens of uT per axis (two LSM9DS1: up to 69 uT; ``clients.synth.LSM9DS1_SHOE``), and
        the part's most sensitive range ends at 400 uT; 100 uT is weak against the data, strong against a
        far-off ellipsoid.
    max_heading_rms : float
        Largest RMS disagreement [rad] between the compass and the ZUPT-KF heading on the calibration stances
        for which the compass counts as :attr:`trusted`. Measured (whole walks): 1.8 deg on the synthetic clean
        field, 10-33 deg on every gdin indoor recording, where Gait-DR on the compass drifted 3-22 % of the
        distance in loop closure against 0.1-0.8 % with the gyroscope.
    min_swing : int
        Swing field samples (:meth:`add_swing`) needed before they join the fit (:meth:`_fit_joint`): a few
        times its 9-14 unknowns.
    alignment_std : float
        Zero-mean prior standard deviation [rad] of the rotation between the magnetometer's axes and the
        accelerometer's stance tilt (:meth:`_fit_joint`).
    """

    def __init__(self, soft_iron: bool = False, min_stances: int = 15, min_heading_spread: float = math.radians(60.0),
                 mag_tol: float = 0.12, dip_tol: float = math.radians(8.0), soft_iron_std: float = 0.1,
                 hard_iron_std: float = 100.0, vertical_hard_iron_std: float = 10.0,
                 max_heading_rms: float = math.radians(5.0), min_swing: int = 40,
                 alignment_std: float = math.radians(5.0)) -> None:
        self.soft_iron = bool(soft_iron)
        self.min_stances = int(min_stances)
        self.min_heading_spread = float(min_heading_spread)
        self.mag_tol = float(mag_tol)
        self.dip_tol = float(dip_tol)
        self.soft_iron_std = float(soft_iron_std)
        self.hard_iron_std = float(hard_iron_std)
        self.vertical_hard_iron_std = float(vertical_hard_iron_std)
        self._rows: list[list[float]] = []  # [ax, ay, az, mx, my, mz, heading]
        self._added = 0  # stances recorded in all (n_added)
        self._swing: list[list[float]] = []  # [mx, my, mz] field samples of the swings between stances [uT]
        self._row_swings: list[int] = []  # swing samples recorded with each row of _rows
        self.m_n = np.full(3, np.nan)
        self.b = np.zeros(3)
        self.w = np.eye(3)  # in use: session_tilt @ w_fit
        self.w_fit = np.eye(3)  # as fitted (soft iron and axis alignment)
        self.session_tilt = np.eye(3)  # this session's tilt offset (loaded calibrations, observe_dip)
        self.session_on = False  # observe_dip estimates session_tilt (a calibration from an earlier session)
        self._dips: list[list[float]] = []  # [k (3), sin(dip), down (3)] of this session's clean stances
        self._dip_seen = 0  # stances observe_dip has taken in this session
        self._dip_fit_at = 0  # ... at its last fit
        self.residual_std = float("nan")
        self.heading_rms = float("nan")  # RMS of compass - ZUPT-KF heading over the calibration stances [rad]
        self.heading_scale = float("nan")  # ... and its robust version, sqrt(median of squares) / 0.6745 [rad]
        self.max_heading_rms = float(max_heading_rms)
        self.min_swing = int(min_swing)
        self.alignment_std = float(alignment_std)
        self.swing_std = float("nan")  # robust scale of the swings' field-magnitude residuals [uT]
        # robust scales of the calibration stances' field magnitude [uT] and dip [rad] about m_n's (settled)
        self.shape_scale = (float("nan"), float("nan"))
        self.ready = False

    def add(self, acc_stance: np.ndarray, mag_stance: np.ndarray, heading_kf: float,
            swing: np.ndarray | None = None) -> None:
        """Record one stance: mean specific force [m/s^2], mean field [uT] (body), ZUPT-KF heading [rad], and
        optionally field samples [uT] (body, shape (k, 3)) of the swing that led to it (:meth:`add_swing`)."""
        row = [*np.asarray(acc_stance, dtype=np.float64).reshape(3).tolist(),
               *np.asarray(mag_stance, dtype=np.float64).reshape(3).tolist(), float(heading_kf)]
        if all(map(math.isfinite, row)):
            self._rows.append(row)
            del self._rows[:-_ROWS_KEEP]
            self._added += 1
            self._row_swings.append(self.add_swing(swing) if swing is not None else 0)
            del self._row_swings[:-_ROWS_KEEP]

    def add_swing(self, mag: np.ndarray) -> int:
        """Record field samples [uT] (body, shape (k, 3)) taken while the foot swung between two stances.

        The foot pitches by tens of degrees in a swing, and the field's magnitude does not depend on the
        attitude: ``|W (m - b)| = |m_n|`` at every sample (the attitude-free ellipsoid constraint of
        magnetometer calibration) is what tells the hard iron along the stance's vertical from the Earth's
        vertical field, which level stances cannot (module docstring). No attitude is needed, so the samples
        come from the low-rate stream whether or not the gyroscope is on. Returns the samples recorded.
        """
        m = np.asarray(mag, dtype=np.float64).reshape(-1, 3)
        fin = np.isfinite(m)
        if not fin.all():  # (the rare case: the rows with a non-finite value dropped)
            m = m[fin.all(axis=1)]
        self._swing.extend(m.tolist())
        del self._swing[:-_SWING_KEEP]
        return int(m.shape[0])

    def swing_samples(self) -> np.ndarray:
        """The recorded swing field samples [uT], body frame, shape (k, 3)."""
        return _table(self._swing, 3)

    @property
    def n_swing(self) -> int:
        """Swing field samples recorded so far."""
        return len(self._swing)

    @property
    def n_stances(self) -> int:
        """Stances held (the latest ``_ROWS_KEEP``)."""
        return len(self._rows)

    @property
    def n_added(self) -> int:
        """Stances recorded in all (also those no longer held): what refits are scheduled by."""
        return self._added

    def heading_scale_on(self, first_added: int, last_added: int) -> float:
        """Robust scale [rad] of this calibration's disagreement with the ZUPT-KF heading (as
        :attr:`heading_scale`) on the stances held that were recorded ``first_added``-th to ``last_added``-th
        (counts of :attr:`n_added`, end excluded); NaN where none of them is held."""
        lo = max(first_added - (self._added - len(self._rows)), 0)
        hi = max(last_added - (self._added - len(self._rows)), 0)
        rows = _table(self._rows[lo:hi], 7)
        return self._heading_rms(rows)[1] if rows.shape[0] else math.nan

    def _design(self, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Linear model rows: unknowns (m_n, c = W b) hard iron, plus (e00, e11, e01, e02, e12) soft iron.

        The stances' attitudes come from one vectorised :func:`euler_to_dcm` (the same element-wise
        operations as one call per stance, bit for bit: that call cost ~20 us per stance at every refit).
        """
        n = rows.shape[0]
        p = 11 if self.soft_iron else 6
        a = np.zeros((3 * n, p))
        y = np.zeros(3 * n)
        tilts = [_tilt(r) for r in rows[:, :3].tolist()]
        cs = euler_to_dcm(np.array([t[0] for t in tilts], dtype=np.float64),
                          np.array([t[1] for t in tilts], dtype=np.float64), np.ascontiguousarray(rows[:, 6]))
        a[:, 0:3] = np.tile(np.eye(3), (n, 1))
        a[:, 3:6] = cs.reshape(3 * n, 3)
        for i, r in enumerate(rows):
            c = cs[i]
            m = r[3:6]
            s = slice(3 * i, 3 * i + 3)
            # C (m + E m - c) = m_n  ->  m_n - C E m + C c = C m   (E = 0 for hard iron only)
            y[s] = c @ m
            if self.soft_iron:
                em = np.array([[m[0], 0.0, m[1], m[2], 0.0],  # E m, E = [[e00 e01 e02] [e01 e11 e12] [e02 e12 -e00-e11]]
                               [0.0, m[1], m[0], 0.0, m[2]],
                               [-m[2], -m[2], 0.0, m[0], m[1]]])
                a[s, 6:11] = -c @ em
        return a, y

    def refit(self) -> bool:
        """:meth:`fit`, except that a trusted calibration is not replaced by an untrusted refit: the new stances
        stay recorded, the fit in use is kept. Stances of steel that passed the disturbance gate turned a
        15-stance fit untrusted (synthetic mixed day, returning user, seed 7: robust scale 1.1 -> 8.7 deg with one
        such stance), and untrusted it then took every stance, disturbed ones included (scale 31 deg 30 s later,
        gyroscope on for the rest of the day). Returns :attr:`ready`."""
        if not (self.ready and self.trusted):
            return self.fit()
        trial = MagCalibrator.from_state(self.get_state())
        trial.fit()
        if trial.ready and trial.trusted:
            self.__dict__.update(trial.__dict__)
        return self.ready

    def fit(self, recent: bool = True) -> bool:
        """Fit the calibration from the recorded stances (and swings); returns :attr:`ready`.

        First the linear stance model (module docstring) by Huber-weighted least squares; then, with
        ``min_swing`` swing samples or more, :meth:`_fit_joint` refines it with the swings' field magnitudes.
        With ``recent``, a fit that is not :attr:`trusted` is tried again on the newest half and then quarter of
        the stances (at least ``_RECENT_MIN``) with the swings recorded with them; the first trusted one is
        kept and the older stances and swings are dropped (they were a disturbed place: a walk that began in
        steel).
        """
        ok = self._fit_all()
        if recent and ok and not self.trusted:
            self._fit_recent()
        return self.ready

    def _fit_recent(self) -> None:
        """:meth:`fit` on the newest stances only (see there); ``self`` becomes the first trusted such fit."""
        n = len(self._rows)
        for k in (n // 2, n // 4):
            if k < max(self.min_stances, _RECENT_MIN):
                return
            trial = MagCalibrator.from_state(self.get_state())
            nsw = sum(self._row_swings[-k:]) if len(self._row_swings) == n else 0
            trial._rows = [list(r) for r in self._rows[-k:]]
            trial._row_swings = list(self._row_swings[-k:]) if nsw else [0] * k
            trial._swing = [list(r) for r in self._swing[-nsw:]] if 0 < nsw <= len(self._swing) else []
            trial.ready = False
            # trusted, and without the few disturbed stances a trusted fit may hold (RMS within the limit too)
            if trial._fit_all() and trial.trusted and not trial.heading_rms > trial.max_heading_rms:
                self.__dict__.update(trial.__dict__)
                return

    def _fit_all(self) -> bool:
        """The fit of :meth:`fit` on every recorded stance."""
        if len(self._rows) < self.min_stances:
            return self.ready
        rows = _table(self._rows, 7)
        h = rows[:, 6]
        spread = 1.0 - math.hypot(float(np.mean(np.cos(h))), float(np.mean(np.sin(h))))  # circular variance
        if spread < 1.0 - math.cos(self.min_heading_spread / 2.0):
            return self.ready
        a, y = self._design(rows)
        p = a.shape[1]
        lam = np.zeros(p)
        lam[3:5] = 1.0 / self.hard_iron_std**2  # zero-mean priors on c = W b (= b for hard iron only)
        lam[5] = 1.0 / self.vertical_hard_iron_std**2
        if self.soft_iron:
            lam[6:11] = 1.0 / self.soft_iron_std**2
        prior = np.diag(lam)
        wts = np.ones(rows.shape[0])
        s = 5.0  # uT
        x = np.zeros(p)
        for _ in range(10):
            wr = np.repeat(wts, 3) / s**2
            aw = a * wr[:, None]  # the same product both normal-equation terms used to compute on their own
            x = np.linalg.solve(aw.T @ a + prior, aw.T @ y)
            r = (y - a @ x).reshape(-1, 3)
            rn = np.sqrt(np.add.reduce(r * r, axis=1))  # = np.linalg.norm(r, axis=1), bit for bit
            s = max(1.4826 * median(rn) / math.sqrt(3.0) * 1.2, 0.5)
            u = rn / (s * math.sqrt(3.0))
            wts = np.where(u <= 1.5, 1.0, 1.5 / np.maximum(u, 1e-12))
        if self.soft_iron:
            e = x[6:11]
            self.w = np.eye(3) + np.array([[e[0], e[2], e[3]], [e[2], e[1], e[4]], [e[3], e[4], -e[0] - e[1]]])
            self.b = np.linalg.solve(self.w, x[3:6])
            self.m_n = x[0:3]
        else:
            self.m_n = x[0:3]
            self.b = x[3:6]
            self.w = np.eye(3)
        self.residual_std = s
        self.w_fit = self.w.copy()
        self.session_tilt = np.eye(3)  # fitted on this session's stances: their tilt is the fit's
        self.session_on = False
        self._dips = []
        self._dip_seen = self._dip_fit_at = 0
        self.ready = bool(np.all(np.isfinite(self.m_n)) and np.linalg.norm(self.m_n[:2]) > 1.0)
        if not self.ready:
            return False
        self.heading_rms, self.heading_scale = self._heading_rms(rows)
        self.shape_scale = self._shape_scale(rows)
        if self.trusted and len(self._swing) >= self.min_swing:
            # only where the Earth-field model holds at the stances (a trusted compass): indoors (every gdin
            # walk, 10-33 deg RMS) the field's magnitude changed by 6-7 uT along a stride and the extra unknowns
            # chased the disturbances (axis alignment turned by up to 24 deg)
            self._fit_joint(rows, _table(self._swing, 3))
            self.w_fit = self.w.copy()
            self.heading_rms, self.heading_scale = self._heading_rms(rows)
            self.shape_scale = self._shape_scale(rows)
        return self.ready

    def _heading_rms(self, rows: np.ndarray) -> tuple[float, float]:
        """RMS [rad] of compass minus ZUPT-KF heading over stance rows ``[acc, mag, heading]``, and its robust
        version (the square root of the median square over 0.6745, the RMS of a normal spread)."""
        d2 = np.square(np.angle(np.exp(1j * np.asarray([self.heading(r[:3], r[3:6]) - r[6] for r in rows]))))
        return math.sqrt(float(np.mean(d2))), math.sqrt(median(d2)) / 0.6745

    def _shape_scale(self, rows: np.ndarray) -> tuple[float, float]:
        """Robust scales of the calibrated field's magnitude [uT] and dip [rad] over stance rows
        ``[acc, mag, heading]`` about m_n's (as :meth:`_heading_rms`'s robust version: the square root of the
        median square over 0.6745; a bias of the stances against m_n is included)."""
        ref, dip_ref = self.field_reference()
        sh = np.asarray([self.field_shape(r[:3], r[3:6]) for r in rows], dtype=np.float64).reshape(-1, 2)
        if sh.shape[0] == 0:
            return math.nan, math.nan
        return (math.sqrt(median(np.square(sh[:, 0] - ref))) / 0.6745,
                math.sqrt(median(np.square(sh[:, 1] - dip_ref))) / 0.6745)

    def settled(self, norm: float, dip: float, rel_floor: float, dip_floor: float, sigmas: float = 3.0) -> bool:
        """The calibrated field's magnitude [uT] and dip [rad] (:meth:`field_shape`) are m_n's within ``sigmas``
        times their scatter on the calibration stances (:attr:`shape_scale`), and at least within ``rel_floor``
        (relative) and ``dip_floor`` [rad]: the Earth's field as far as its shape can tell, a tighter test than
        the disturbance gate (whose tolerances are set for indoor fields). The calibration stances (ZUPT-KF,
        fitted on) scatter less than the Gait-DR stances it tests (synthetic mixed day, seed 8: 0.08 deg dip
        scale on the fit; 61.6-63.2 deg on Gait-DR stances of a clean field, m_n's 62.1), hence the floors, the
        largest changes of the field between two settled stances. The floors alone where the scatter is unknown
        (states stored before it was measured)."""
        s_n, s_d = self.shape_scale
        ref, dip_ref = self.field_reference()
        tol_n = max(sigmas * s_n, rel_floor * ref) if math.isfinite(s_n) else rel_floor * ref
        tol_d = max(sigmas * s_d, dip_floor) if math.isfinite(s_d) else dip_floor
        return abs(norm - ref) <= tol_n and abs(dip - dip_ref) <= tol_d

    def _fit_joint(self, rows: np.ndarray, swing: np.ndarray, iterations: int = 30) -> None:
        """Stances and swings together: robust Gauss-Newton from the linear stance fit.

        Unknowns: the field m_n [uT] (navigation frame), c = W b [uT], the soft iron W = I + E (E symmetric,
        diagonal (e_h, -e_h, 0): the two horizontal axes' scales differ, their mean is the vertical's; fitted
        whatever ``soft_iron`` says, which is about the linear stance model: the swings make it observable) and the rotation A [rad] from the magnetometer's axes to the axes in which the
        accelerometer measures the stance tilt. Residuals, each group Huber-weighted with its own robust scale:

        - stance i: ``C_i A (W m_i - c) - m_n`` (3 components), C_i from the accelerometer tilt and the ZUPT-KF
          heading (as in the linear model);
        - swing sample k: ``|W m_k - c| - |m_n|`` (the field magnitude does not depend on the attitude).

        Priors (zero mean): c ``hard_iron_std`` on every axis (the swings observe all three; the tighter
        ``vertical_hard_iron_std`` only stands in for them in the stance-only fit), E ``soft_iron_std``, A
        ``alignment_std``. What the motion cannot tell apart is not fitted: a common scale of W and m_n (it does
        not change the heading), and the horizontal axes' mean scale against the vertical one. Stances turn
        the foot about the vertical and swings pitch it by +-25 deg, hardly roll it; a short pitch arc fits
        an ellipse with other axis ratios about another centre nearly as well as the circle, so that scale
        traded against the vertical hard iron: with a trace-free E the fit shrank W along the vertical
        towards 0 (hard iron 10^4-10^5 uT), with W's (z, z) element fixed and e00, e11 free it settled at
        horizontal scales 0.80/0.76 and 13 uT of vertical hard iron on a sensor with neither (synthetic mixed
        day, seeds 6 and 1007: compass errors of 5-7 deg). Sensitivity differences between axes of a few per
        cent (the synthetic device's 1.04/0.97/1.00) are the horizontal ratio e_h, which the yaw turns observe.

        A holds what turns the compass when the hard iron is right but the tilt is not: the accelerometer's
        zero-g offset tilts the stance's gravity direction (LSM9DS1 typical +-90 mg, up to 5 deg, datasheet
        DocID025715 Table 3) and the two sensors' axes are not exactly parallel (the alignment step of the
        MAG.I.C.AL. calibration that 002 Section I applies before MAGINAV). Without it a right hard iron left
        the accelerometer's tilt offset in the compass, as a heading error of up to ``tan(dip) * offset``
        (synthetic mixed day, 0.7 deg offset: up to 1.5 deg); the stance-only fit had absorbed it in a wrong
        horizontal hard iron. The result is stored as ``w = A W`` and ``b = W^-1 c``, so :meth:`calibrate`
        gives the field in the accelerometer's axes. Steps that raise the robust cost are halved (up to 6 times);
        the robust weights are re-estimated in the first ``_FREEZE_WEIGHTS`` iterations, and the iterations stop
        once a step is below 1e-9 (uT, rad).

        The iterations run compiled (:func:`models._compass_kernel.joint_gauss_newton`, state in plain arrays);
        this method prepares them, checks the hard iron's posterior after the weights are settled and at the
        end, and stores the result. :meth:`_fit_joint_reference` is the numpy version it equals to rounding
        (4-11 ms per fit, mostly the call overhead of small arrays).
        """
        n, k = rows.shape[0], swing.shape[0]
        tilts = [_tilt(r) for r in rows[:, :3].tolist()]  # tilt_from_acc's operations on plain floats
        c_i = euler_to_dcm(np.array([t[0] for t in tilts], dtype=np.float64),
                           np.array([t[1] for t in tilts], dtype=np.float64), np.ascontiguousarray(rows[:, 6]))
        lam = np.zeros(N_JOINT)  # zero-mean priors: c, alignment A, soft iron e
        lam[3:6] = 1.0 / self.hard_iron_std**2
        lam[6:9] = 1.0 / self.alignment_std**2
        lam[9:13] = 1.0 / self.soft_iron_std**2
        mn, c, rot, e = self.m_n.astype(np.float64).copy(), self.w @ self.b, np.eye(3), np.zeros(4)
        w_st, w_sw, scales, h = np.ones(n), np.ones(k), np.zeros(2), np.zeros((N_JOINT, N_JOINT))
        state = (c_i, np.ascontiguousarray(rows[:, 3:6]), np.ascontiguousarray(swing, dtype=np.float64), lam,
                 float(self.residual_std), mn, c, rot, e, w_st, w_sw, scales, h)
        if joint_gauss_newton(*state, 0, iterations, _FREEZE_WEIGHTS, _FREEZE_WEIGHTS) == PAUSED:
            # the robust weights are settled (iteration _FREEZE_WEIGHTS): a horizontal hard iron far from
            # determined keeps the linear stance fit without the remaining iterations (_fit_joint_reference)
            if self._hard_iron_sigma(h, mn) > 1.5 * self._hard_iron_sigma_max(mn):
                return
            # from the same state: iteration _FREEZE_WEIGHTS's normal equations again, then its step
            joint_gauss_newton(*state, _FREEZE_WEIGHTS, iterations, _FREEZE_WEIGHTS, -1)
        w_mat = _soft_matrix(e)
        if not (np.all(np.isfinite(mn)) and np.all(np.isfinite(c)) and np.all(np.isfinite(w_mat))) or iterations < 2:
            return  # keep the linear stance fit (iterations < 2: no step solved for, no normal matrix)
        if self._hard_iron_sigma(h, mn) > self._hard_iron_sigma_max(mn):
            return  # keep the linear stance fit (posterior of the horizontal hard iron: _fit_joint_reference)
        self.m_n = mn
        self.b = np.linalg.solve(w_mat, c)
        self.w = rot @ w_mat
        self.residual_std = float(scales[0])
        self.swing_std = float(scales[1])

    def _fit_joint_reference(self, rows: np.ndarray, swing: np.ndarray, iterations: int = 30) -> None:
        """:meth:`_fit_joint` in numpy, the reference the compiled iterations are tested against (same arguments,
        same effect, to rounding)."""
        n, k = rows.shape[0], swing.shape[0]
        soft = True
        p = 9 + (4 if soft else 0)
        i_c, i_a, i_e = slice(3, 6), slice(6, 9), slice(9, 13)
        c_i = euler_to_dcm(*(np.array([tilt_from_acc(r[:3]) for r in rows]).T), rows[:, 6])  # (n, 3, 3)
        m_i = rows[:, 3:6]
        em_i, em_k = _soft_map(m_i), _soft_map(swing)  # (n, 3, 4), (k, 3, 4): E m as a linear map of e
        lam = np.zeros(p)
        lam[i_c] = 1.0 / self.hard_iron_std**2
        lam[i_a] = 1.0 / self.alignment_std**2
        if soft:
            lam[i_e] = 1.0 / self.soft_iron_std**2

        def residuals(mn: np.ndarray, c: np.ndarray, rot: np.ndarray, e: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
            w_mat = _soft_matrix(e)
            rv = (m_i @ w_mat.T - c) @ rot.T  # stance field in the accelerometer's axes
            sv = swing @ w_mat.T - c
            ns = np.linalg.norm(sv, axis=1)
            return np.einsum("nij,nj->ni", c_i, rv) - mn, ns - float(np.linalg.norm(mn)), rv, sv / ns[:, None]

        def cost(r_st: np.ndarray, r_sw: np.ndarray, theta: np.ndarray) -> float:
            return (float(np.sum(np.repeat(w_st, 3) * r_st.reshape(-1) ** 2)) / s_st**2
                    + float(np.sum(w_sw * r_sw**2)) / s_sw**2 + float(np.sum(lam * theta**2)))

        def params(c: np.ndarray, rot: np.ndarray, e: np.ndarray) -> np.ndarray:
            theta = np.zeros(p)
            theta[i_c] = c
            theta[i_a] = _rot_vec(rot)
            if soft:
                theta[i_e] = e
            return theta

        mn, c, rot, e = self.m_n.astype(np.float64).copy(), self.w @ self.b, np.eye(3), np.zeros(4)
        s_lin = self.residual_std
        h = None
        for it in range(iterations):
            r_st, r_sw, rv, sh = residuals(mn, c, rot, e)
            if it < _FREEZE_WEIGHTS:
                # robust scales and Huber weights from the current residuals, then kept: re-weighting converges
                # only linearly (0.7 per iteration: 58 iterations, 0.3 s CPU in a mixed day of 1 s), Gauss-Newton
                # on fixed weights in a few
                rn = np.linalg.norm(r_st, axis=1)
                # the stances' scale may not grow past the linear fit's: with more unknowns the stances fit at
                # least as well, and a scale re-estimated freely let the fit give the stances up for swings fitted
                # by a far-off flat ellipsoid (gdin indoor walks: hard iron 10^5-10^6 uT, residuals 50-200 uT)
                s_st = min(max(1.4826 * median(rn) / math.sqrt(3.0) * 1.2, 0.5), s_lin)
                u = rn / (s_st * math.sqrt(3.0))
                w_st = np.where(u <= 1.5, 1.0, 1.5 / np.maximum(u, 1e-12))
                s_sw = max(1.4826 * float(np.median(np.abs(r_sw))), 0.1)
                u = np.abs(r_sw) / s_sw
                w_sw = np.where(u <= 1.5, 1.0, 1.5 / np.maximum(u, 1e-12))
            if it == iterations - 1:
                break
            car = c_i @ rot
            j_st = np.zeros((n, 3, p))
            j_st[:, :, 0:3] = -np.eye(3)
            j_st[:, :, i_c] = -car
            j_st[:, :, i_a] = -np.einsum("nij,njk->nik", c_i, skew(rv))  # left perturbation of the rotation
            j_sw = np.zeros((k, p))
            j_sw[:, 0:3] = -mn / float(np.linalg.norm(mn))
            j_sw[:, i_c] = -sh
            if soft:
                j_st[:, :, i_e] = np.einsum("nij,njk->nik", car, em_i)
                j_sw[:, i_e] = np.einsum("kj,kjl->kl", sh, em_k)
            ja = j_st.reshape(3 * n, p)
            wa = np.repeat(w_st, 3) / s_st**2
            wb = w_sw / s_sw**2
            theta = params(c, rot, e)
            h = (ja * wa[:, None]).T @ ja + (j_sw * wb[:, None]).T @ j_sw + np.diag(lam)
            g = -(ja * wa[:, None]).T @ r_st.reshape(-1) - (j_sw * wb[:, None]).T @ r_sw - lam * theta
            d = np.linalg.solve(h, g)
            if it == _FREEZE_WEIGHTS and self._hard_iron_sigma(h, mn) > 1.5 * self._hard_iron_sigma_max(mn):
                # far from determined once the robust weights are settled: keep the linear stance fit without the
                # remaining iterations (the mixed day's rejected fits ran 25-28 iterations, 6-9 ms each, half the
                # compass's computation of a day). Not at the linear fit already: with a sensor's real hard iron
                # the linear fit is far off and its sigma says little (a 44-uT shoe sensor: rejected there)
                return
            if it >= _FREEZE_WEIGHTS and float(np.max(np.abs(d))) < 1e-9:
                # converged: stopping here, not after a fixed count, makes the result depend smoothly on the data
                # (the ZUPT-KF headings differ in the last bit between batch cuts; the engine must not)
                break
            c0 = cost(r_st, r_sw, theta)
            for _ in range(7):
                trial = (mn + d[0:3], c + d[i_c], rotvec_to_dcm(d[i_a]) @ rot, e + d[i_e] if soft else e)
                tr_st, tr_sw, _, _ = residuals(*trial)
                if cost(tr_st, tr_sw, params(*trial[1:])) <= c0 * (1.0 + 1e-9):
                    mn, c, rot, e = trial
                    break
                d = d / 2.0
        w_mat = _soft_matrix(e)
        if not (np.all(np.isfinite(mn)) and np.all(np.isfinite(c)) and np.all(np.isfinite(w_mat))) or h is None:
            return  # keep the linear stance fit
        # the extra unknowns only where the motion determines them: the posterior standard deviation of the
        # horizontal hard iron must turn the compass by less than max_heading_rms. Walking only two directions
        # (the mixed day's first minute: 0 and 90 deg) the swings' short pitch arcs left it at 5-9 uT and the
        # fit settled on 10-150 uT of hard iron on a sensor with none, trusted (0.3 deg RMS on its own stances,
        # 17 deg off on a new heading); the first stances towards 160-180 deg brought it under 1 uT
        if self._hard_iron_sigma(h, mn) > self._hard_iron_sigma_max(mn):
            return  # keep the linear stance fit
        self.m_n = mn
        self.b = np.linalg.solve(w_mat, c)
        self.w = rot @ w_mat
        self.residual_std = s_st
        self.swing_std = s_sw

    @staticmethod
    def _hard_iron_sigma(h: np.ndarray, mn: np.ndarray) -> float:
        """Largest posterior standard deviation [uT] of the horizontal hard iron (``c`` x, y) from the joint fit's
        normal matrix ``h`` (its inverse is the parameters' covariance)."""
        return math.sqrt(float(np.linalg.eigvalsh(np.linalg.inv(h)[3:5, 3:5]).max()))

    def _hard_iron_sigma_max(self, mn: np.ndarray) -> float:
        """The horizontal hard iron's standard deviation [uT] that turns the compass by ``max_heading_rms``."""
        return math.hypot(float(mn[0]), float(mn[1])) * math.tan(self.max_heading_rms)

    @property
    def trusted(self) -> bool:
        """Calibrated, and its headings on the calibration stances agree with the ZUPT-KF's: robust scale
        within ``max_heading_rms`` and RMS within ``_RMS_OVER_SCALE`` times it (a few disturbed stances do not
        condemn it, a spread everywhere does): the compass can stand in for the gyroscope. A calibration stored
        before the robust scale existed is held to the RMS alone; unknown agreement (stored before either was
        measured) counts as agreement."""
        if not self.ready:
            return False
        if not math.isfinite(self.heading_scale):
            return not self.heading_rms > self.max_heading_rms
        s_n, s_d = self.shape_scale  # NaN (stored before it was measured): not held against it
        if s_n > _MAX_SHAPE_MAG * float(np.linalg.norm(self.m_n)) or s_d > _MAX_SHAPE_DIP:
            return False
        return self.heading_scale <= self.max_heading_rms and not self.heading_rms > _RMS_OVER_SCALE * self.max_heading_rms

    def start_session(self) -> None:
        """This calibration was fitted in an earlier session (a profile's): from now on :meth:`observe_dip`
        estimates this session's tilt offset (:attr:`session_tilt`) from this session's stances."""
        self.session_on = True
        self.session_tilt = np.eye(3)
        self.w = self.w_fit.copy()
        self._dips = []
        self._dip_seen = self._dip_fit_at = 0

    def observe_dip(self, acc_stance: np.ndarray, mag_stance: np.ndarray) -> bool:
        """A stance whose field passed the disturbance test, in any mode (no heading needed): the dip invariant.

        The angle between the field and gravity does not depend on the attitude: with the calibration right,
        ``sin(dip) = m . g_down / |m|`` is the same at every stance. The accelerometer's tilt, however, is
        offset by its zero-g offset, which changes from one power-on to the next (the synthesiser draws a 10-mg
        turn-on bias per recording: 0.6 deg), so a calibration whose axis alignment was fitted on another day's
        stances turns the compass by up to ``tan(dip)`` times the change (mixed day, returning user: 2.3 deg,
        compass errors of +3 / -5 deg by heading). A tilt offset delta [rad] (body axes) changes the measured
        ``sin(dip)`` by ``delta . (g_down x m) / |m|``, a direction that turns with the foot's heading, so
        after turns the stances tell delta (least squares on ``sin(dip) = s0 + delta . k``, robust, with a
        zero-mean prior of the change of the offset between two power-ons, ``_SESSION_TILT_STD``); :attr:`session_tilt` then rotates the calibrated field back onto
        the accelerometer's axes. Only for calibrations from an earlier session (:meth:`start_session`).

        Returns True when this stance refitted the tilt offset (the compass's headings changed).
        """
        if not (self.session_on and self.trusted):
            return False  # an untrusted compass (indoors) is only averaged; its dips are the disturbances'

        m = self.w_fit @ (np.asarray(mag_stance, dtype=np.float64).reshape(3) - self.b)
        f = np.asarray(acc_stance, dtype=np.float64).reshape(3)
        nm, nf = float(np.linalg.norm(m)), float(np.linalg.norm(f))
        if not (nm > 0.0 and nf > 0.0 and math.isfinite(nm + nf)):
            return False
        g = -f / nf  # down, body frame
        self._dips.append([*(np.cross(g, m) / nm).tolist(), float(m @ g) / nm, *g.tolist()])
        del self._dips[:-_DIP_STANCES]
        self._dip_seen += 1
        if self._dip_seen - self._dip_fit_at >= max(1, len(self._dips) // 10):
            # refitted when a tenth of the stances is new (a fit of 300 stances costs ~0.4 ms: at every Gait-DR
            # stance that was as much again as all the rest of Gait-DR's computation)
            self._dip_fit_at = self._dip_seen
            self._fit_session_tilt()
            return True
        return False

    def _fit_session_tilt(self) -> None:
        """Robust least squares of :meth:`observe_dip`'s model; sets :attr:`session_tilt` and :attr:`w`.

        Only the two tilt components (about the axes perpendicular to the stances' mean vertical) are fitted:
        the third, about the vertical, would turn the heading and does not change the dip (left free, it took
        noise for a 4.9-deg heading offset; synthetic mixed day, seed 7).
        """
        d = _table(self._dips, 7)
        g = d[:, 4:7].mean(axis=0)
        g /= np.linalg.norm(g)
        u1 = np.cross(g, [1.0, 0.0, 0.0] if abs(g[0]) < 0.9 else [0.0, 1.0, 0.0])
        u1 /= np.linalg.norm(u1)
        u2 = np.cross(g, u1)
        a = np.c_[np.ones(d.shape[0]), d[:, :3] @ u1, d[:, :3] @ u2]
        y = d[:, 3]
        lam = np.array([1e-6, 1.0 / _SESSION_TILT_STD**2, 1.0 / _SESSION_TILT_STD**2])
        wts = np.ones(d.shape[0])
        s = math.sin(math.radians(1.0))
        x = np.zeros(3)
        for _ in range(5):
            wr = wts / s**2
            x = np.linalg.solve((a * wr[:, None]).T @ a + np.diag(lam), (a * wr[:, None]).T @ y)
            r = np.abs(y - a @ x)
            s = max(1.4826 * float(np.median(r)), _DIP_NOISE)
            u = r / s
            wts = np.where(u <= 1.5, 1.0, 1.5 / np.maximum(u, 1e-12))
        self.session_tilt = rotvec_to_dcm(x[1] * u1 + x[2] * u2)
        self.w = self.session_tilt @ self.w_fit

    def calibrate(self, mag: np.ndarray) -> np.ndarray:
        """Calibrated field W (m - b) [uT], body frame."""
        return self.w @ (np.asarray(mag, dtype=np.float64).reshape(3) - self.b)

    def _cal3(self, mag: np.ndarray | tuple[float, ...]) -> list[float]:
        """:meth:`calibrate` on plain floats (per-step path)."""
        m = np.asarray(mag, dtype=np.float64).reshape(3).tolist()
        b = self.b.tolist()
        d = [m[0] - b[0], m[1] - b[1], m[2] - b[2]]
        w = self.w.tolist()
        return [w[0][0] * d[0] + w[0][1] * d[1] + w[0][2] * d[2],
                w[1][0] * d[0] + w[1][1] * d[1] + w[1][2] * d[2],
                w[2][0] * d[0] + w[2][1] * d[1] + w[2][2] * d[2]]

    def field_shape(self, acc_stance: np.ndarray, mag_stance: np.ndarray) -> tuple[float, float]:
        """Magnitude [uT] and dip [rad] (positive down) of the calibrated stance field; the accelerometer
        gives the vertical. Both are invariant under a rotation of the foot about the vertical."""
        m = self._cal3(mag_stance)
        nm = math.sqrt(m[0] ** 2 + m[1] ** 2 + m[2] ** 2)
        f = np.asarray(acc_stance, dtype=np.float64).reshape(3).tolist()
        nf = max(math.sqrt(f[0] ** 2 + f[1] ** 2 + f[2] ** 2), 1e-9)
        down_dot = -(m[0] * f[0] + m[1] * f[1] + m[2] * f[2]) / nf
        return nm, math.asin(max(-1.0, min(1.0, down_dot / max(nm, 1e-9))))

    def field_reference(self) -> tuple[float, float]:
        """Magnitude [uT] and dip [rad] (positive down) of m_n: the field the disturbance gate tests against."""
        mn = self.m_n.tolist()
        return math.sqrt(mn[0] ** 2 + mn[1] ** 2 + mn[2] ** 2), math.atan2(mn[2], math.hypot(mn[0], mn[1]))

    def shape_disturbed(self, norm: float, dip: float) -> bool:
        """Magnitude/dip gate of a calibrated field's shape (:meth:`field_shape`: uT, rad) against m_n."""
        ref, dip_ref = self.field_reference()
        if abs(norm - ref) > self.mag_tol * ref:  # 002 eq. (4), magnitude
            return True
        return abs(dip - dip_ref) > self.dip_tol  # 002 eq. (5), inclination

    def disturbed(self, acc_stance: np.ndarray, mag_stance: np.ndarray) -> bool:
        """Magnitude/dip gate of the calibrated field against m_n (True = do not trust the compass)."""
        if not self.ready:
            return True
        return self.shape_disturbed(*self.field_shape(acc_stance, mag_stance))

    def heading(self, acc_stance: np.ndarray, mag_stance: np.ndarray) -> float:
        """Compass heading [rad] of the body in the navigator's NED frame (NaN before calibration)."""
        if not self.ready:
            return float("nan")
        alpha = _level_heading(np.asarray(acc_stance, dtype=np.float64).reshape(3).tolist(), self._cal3(mag_stance))
        psi = math.atan2(float(self.m_n[1]), float(self.m_n[0])) - alpha
        return math.atan2(math.sin(psi), math.cos(psi))

    def get_state(self) -> dict:
        """Plain-data state for ``energy.codec``."""
        return {"params": [self.soft_iron, self.min_stances, self.min_heading_spread, self.mag_tol, self.dip_tol,
                           self.soft_iron_std, self.hard_iron_std, self.vertical_hard_iron_std, self.max_heading_rms,
                           self.min_swing, self.alignment_std],
                "rows": _table(self._rows, 7), "added": self._added,
                "m_n": self.m_n.copy(),
                "swing": _table(self._swing, 3),
                "row_swings": list(self._row_swings),
                "b": self.b.copy(), "w": self.w.copy(), "residual_std": self.residual_std, "ready": self.ready,
                "heading_rms": self.heading_rms, "heading_scale": self.heading_scale, "swing_std": self.swing_std, "w_fit": self.w_fit.copy(),
                "session_tilt": self.session_tilt.copy(), "session_on": self.session_on,
                "shape_scale": list(self.shape_scale),
                "dips": _table(self._dips, 7),
                "dip_counts": [self._dip_seen, self._dip_fit_at]}

    @classmethod
    def from_state(cls, d: dict) -> MagCalibrator:
        """Rebuild from :meth:`get_state` output."""
        p = d["params"]
        obj = cls(bool(p[0]), int(p[1]), float(p[2]), float(p[3]), float(p[4]), float(p[5]))
        if len(p) > 6:  # states stored before the hard-iron priors existed keep the unconstrained fit
            obj.hard_iron_std, obj.vertical_hard_iron_std = float(p[6]), float(p[7])
        else:
            obj.hard_iron_std = obj.vertical_hard_iron_std = math.inf
        if len(p) > 8:
            obj.max_heading_rms = float(p[8])
        if len(p) > 10:
            obj.min_swing, obj.alignment_std = int(p[9]), float(p[10])
        obj._swing = np.asarray(d.get("swing", np.zeros((0, 3))), dtype=np.float64).reshape(-1, 3).tolist()[-_SWING_KEEP:]
        obj._row_swings = [int(v) for v in d.get("row_swings", [])]  # older states: unknown (recent fits drop swings)
        obj.swing_std = float(d.get("swing_std", math.nan))
        obj.session_tilt = np.asarray(d.get("session_tilt", np.eye(3)), dtype=np.float64).reshape(3, 3).copy()
        obj.session_on = bool(d.get("session_on", False))
        ss = d.get("shape_scale", [math.nan, math.nan])  # unknown in states stored before it existed
        obj.shape_scale = (float(ss[0]), float(ss[1]))
        obj._dips = np.asarray(d.get("dips", np.zeros((0, 7))), dtype=np.float64).reshape(-1, 7).tolist()
        obj._dip_seen, obj._dip_fit_at = (int(x) for x in d.get("dip_counts", [len(obj._dips), len(obj._dips)]))
        obj.heading_rms = float(d.get("heading_rms", math.nan))  # unknown in states stored before it existed
        obj.heading_scale = float(d.get("heading_scale", math.nan))  # ... and states before the robust scale
        obj._rows = np.asarray(d["rows"], dtype=np.float64).reshape(-1, 7).tolist()
        obj._added = int(d.get("added", len(obj._rows)))  # absent in states stored before the bound
        del obj._rows[:-_ROWS_KEEP]
        obj.m_n = np.asarray(d["m_n"], dtype=np.float64).copy()
        obj.b = np.asarray(d["b"], dtype=np.float64).copy()
        obj.w = np.asarray(d["w"], dtype=np.float64).reshape(3, 3).copy()
        obj.w_fit = np.asarray(d.get("w_fit", obj.w), dtype=np.float64).reshape(3, 3).copy()
        obj.residual_std = float(d["residual_std"])
        obj.ready = bool(d["ready"])
        return obj
