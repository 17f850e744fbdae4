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
(``sin(pitch) * error`` enters the horizontal field). A zero-mean prior on the vertical hard iron
(``vertical_hard_iron_std``) fixes that direction; the horizontal hard iron stays free (weak prior).
The soft-iron scale is fixed (trace E = 0): a common scale of W and m_n is unobservable and does not affect
the heading (without it the fit could shrink W and m_n towards zero).

A stance is magnetically disturbed when the calibrated field's magnitude or dip differs from m_n by more
than a tolerance (the magnitude/inclination test of 002 eq. 4-5 applied to the calibrated field).
Angles [rad], heading clockwise from north (NED); field [uT]; specific force [m/s^2], body frame.
"""

from __future__ import annotations

import math

import numpy as np

from models.heading_deviation import wrap_angle
from models.rotations import euler_to_dcm

__all__ = ["tilt_from_acc", "level_heading", "follow_compass", "CompassFollower", "MagCalibrator"]


def tilt_from_acc(acc: np.ndarray) -> tuple[float, float]:
    """Roll and pitch [rad] from the specific force at rest (body frame, m/s^2; reads +g upwards)."""
    f = np.asarray(acc, dtype=np.float64).reshape(3)
    roll = math.atan2(-f[1], -f[2])
    pitch = math.atan2(f[0], math.hypot(f[1], f[2]))
    return roll, pitch


def _tilt(f: list[float]) -> tuple[float, float]:
    """:func:`tilt_from_acc` on plain floats (the same operations)."""
    return math.atan2(-f[1], -f[2]), math.atan2(f[0], math.hypot(f[1], f[2]))


def _median(x: np.ndarray) -> float:
    """``np.median`` of a 1-D float array, bit for bit (the middle value, or the mean of the two middle values
    as ``(a + b) / 2``), without its generic machinery (~20 us per call); NaN-containing input goes to
    ``np.median`` itself."""
    k = x.size // 2
    if x.size == 0 or np.isnan(x).any():
        return float(np.median(x))
    if x.size % 2:
        return float(np.partition(x, k)[k])
    p = np.partition(x, (k - 1, k))
    return float((p[k - 1] + p[k]) / 2.0)


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


def follow_compass(heading: float, compass: float, clean: bool, gain: float = 0.5,
                   turn: float = math.radians(30.0)) -> float:
    """Per-step heading with the gyroscope off: the held heading pulled towards the stance compass [rad].

    Indoors the calibrated compass at a stance scatters by ~10 deg (median) about the walking heading even with
    the calibration fitted on the whole walk, and that scatter is nearly white from stance to stance (lag-1
    correlation 0.16 on gdin), whereas a person walks straight between turns. So a small disagreement is
    averaged (``heading + gain * innovation``), and a large one on a clean field is a turn and taken at once.
    A stance whose field failed the disturbance test may pull the heading by ``gain`` but never makes a turn
    (holding the heading there, the earlier design, lost every turn inside a disturbance).

    Parameters
    ----------
    heading : float
        Heading held from the previous step [rad].
    compass : float
        Compass heading at this stance [rad] (:meth:`MagCalibrator.heading`).
    clean : bool
        The stance field passed the disturbance test (:meth:`MagCalibrator.disturbed` is False).
    gain : float
        Fraction of a small innovation taken per step.
    turn : float
        Innovations larger than this [rad] on a clean field are turns (taken whole).
    """
    nu = wrap_angle(compass - heading)
    step = nu if (clean and abs(nu) > turn) else gain * nu
    return wrap_angle(heading + step)


class CompassFollower:
    """Per-step heading with the gyroscope off through magnetic disturbances (state between stances).

    A steel disturbance changes gradually along the walk and turns the compass by 10-30 deg at its edges while
    its field still passes the magnitude/dip gate (mixed-day synthetic days: the compass error grows by up to
    18 deg per stride inside steel, 1 deg on a clean field); a turn of the foot is quick and, being a rotation
    about the vertical, leaves the magnitude and dip of the field it sees unchanged (a moved-into disturbance
    generally changes them). So:

    - on an established clean field (the last ``reanchor_stances`` stances all passed the gate) the absolute
      compass leads, :func:`follow_compass` (small disagreements averaged, turns taken whole);
    - otherwise the heading is held, and a turn is taken from the change of the compass since the previous
      stance when that change exceeds ``min_turn`` and the field's magnitude and dip stayed within
      ``rot_mag_tol`` (relative) and ``rot_dip_tol`` of the previous stance's (a rotation of the foot, not of
      the field). The absolute compass pulls the heading again once the field has been clean for
      ``reanchor_stances`` stances (re-anchoring after the disturbance).

    ZUPT-KF stances of the same session are passed to :meth:`observe` (they count towards the clean run), so a
    hand-over to Gait-DR on a clean field uses the compass at once.

    Parameters
    ----------
    gain, turn : float
        Of :func:`follow_compass` on an established clean field (fraction, rad).
    min_turn : float
        Smallest stance-to-stance compass change [rad] taken as a turn where the absolute compass is not
        trusted (a walking turn of 90 deg takes 2-4 strides: 22-45 deg per stride).
    reanchor_stances : int
        Consecutive clean stances before the absolute compass leads again.
    rot_mag_tol : float
        Largest relative change of the field magnitude between two stances for a compass change to count as
        a rotation of the foot.
    rot_dip_tol : float
        Largest change of the dip [rad] between two stances for the same.
    """

    def __init__(self, gain: float = 0.5, turn: float = math.radians(30.0), min_turn: float = math.radians(20.0),
                 reanchor_stances: int = 3, rot_mag_tol: float = 0.05, rot_dip_tol: float = math.radians(3.0)) -> None:
        self.gain = float(gain)
        self.turn = float(turn)
        self.min_turn = float(min_turn)
        self.reanchor_stances = int(reanchor_stances)
        self.rot_mag_tol = float(rot_mag_tol)
        self.rot_dip_tol = float(rot_dip_tol)
        self.clean_run = 0  # consecutive stances whose field passed the gate
        self.prev: tuple[float, float, float] | None = None  # (compass rad, |m| uT, dip rad) of the last stance

    def observe(self, compass: float, clean: bool, norm: float, dip: float) -> None:
        """A stance whose heading comes from elsewhere (ZUPT-KF): field bookkeeping only."""
        self.clean_run = self.clean_run + 1 if clean else 0
        self.prev = (float(compass), float(norm), float(dip))

    def forget(self) -> None:
        """A step without a usable field reading, or a restart from another heading: no previous compass."""
        self.prev = None

    def turn_since(self, compass: float, norm: float, dip: float) -> float | None:
        """Compass change [rad] since the previous stance when the field's magnitude [uT] and dip [rad] stayed
        within ``rot_mag_tol``/``rot_dip_tol`` of it (a rotation of the foot, not of the field); else None."""
        if self.prev is None:
            return None
        c0, n0, d0 = self.prev
        same_field = abs(norm - n0) <= self.rot_mag_tol * max(n0, 1e-9) and abs(dip - d0) <= self.rot_dip_tol
        return wrap_angle(compass - c0) if same_field else None

    @property
    def established(self) -> bool:
        """The last ``reanchor_stances`` stances all passed the disturbance gate (the absolute compass leads)."""
        return self.clean_run >= self.reanchor_stances

    def rotation(self, compass: float, norm: float, dip: float) -> float:
        """Compass change since the previous stance [rad] if it is a turn of the foot, else 0."""
        dc = self.turn_since(compass, norm, dip)
        return dc if (dc is not None and abs(dc) > self.min_turn) else 0.0

    def step(self, heading: float, compass: float, clean: bool, norm: float, dip: float, trusted: bool = True) -> float:
        """Heading [rad] after a Gait-DR stance.

        Parameters
        ----------
        heading : float
            Heading held from the previous step [rad].
        compass : float
            Compass heading at this stance [rad] (:meth:`MagCalibrator.heading`).
        clean : bool
            The stance field passed the disturbance test.
        norm, dip : float
            Magnitude [uT] and dip [rad] of the stance field (:meth:`MagCalibrator.field_shape`).
        trusted : bool
            The compass agrees with the ZUPT-KF on its calibration stances (:attr:`MagCalibrator.trusted`).
            An untrusted compass (every gdin indoor recording: 10-33 deg RMS, single readings off by 100 deg)
            scatters as much as a disturbance deflects it; its readings are averaged whatever the gate says
            (:func:`follow_compass`, the disturbed ones pull but never turn), as holding through its many
            "disturbed" stances lost its turns (gdin ``--mode pdr`` stride median 1.03 -> 4.2 m).
        """
        turned = self.rotation(compass, norm, dip)
        self.observe(compass, clean, norm, dip)
        if not trusted:
            return follow_compass(heading, compass, clean, self.gain, self.turn)
        if clean and self.established:
            return follow_compass(heading, compass, True, self.gain, self.turn)
        return wrap_angle(heading + turned)

    def get_state(self) -> dict:
        """Plain-data state for ``energy.codec``."""
        return {"params": [self.gain, self.turn, self.min_turn, self.reanchor_stances, self.rot_mag_tol,
                           self.rot_dip_tol],
                "clean_run": self.clean_run, "prev": None if self.prev is None else list(self.prev)}

    @classmethod
    def from_state(cls, d: dict) -> CompassFollower:
        """Rebuild from :meth:`get_state` output."""
        p = d["params"]
        obj = cls(float(p[0]), float(p[1]), float(p[2]), int(p[3]), float(p[4]), float(p[5]))
        obj.clean_run = int(d["clean_run"])
        obj.prev = None if d["prev"] is None else (float(d["prev"][0]), float(d["prev"][1]), float(d["prev"][2]))
        return obj


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
        [uT] (z: the direction level stances cannot observe; see the module docstring).
    max_heading_rms : float
        Largest RMS disagreement [rad] between the compass and the ZUPT-KF heading on the calibration stances
        for which the compass counts as :attr:`trusted`. Measured (whole walks): 1.8 deg on the synthetic clean
        field, 10-33 deg on every gdin indoor recording, where Gait-DR on the compass drifted 3-22 % of the
        distance in loop closure against 0.1-0.8 % with the gyroscope.
    """

    def __init__(self, soft_iron: bool = False, min_stances: int = 15, min_heading_spread: float = math.radians(60.0),
                 mag_tol: float = 0.12, dip_tol: float = math.radians(8.0), soft_iron_std: float = 0.1,
                 hard_iron_std: float = 1000.0, vertical_hard_iron_std: float = 10.0,
                 max_heading_rms: float = math.radians(5.0)) -> None:
        self.soft_iron = bool(soft_iron)
        self.min_stances = int(min_stances)
        self.min_heading_spread = float(min_heading_spread)
        self.mag_tol = float(mag_tol)
        self.dip_tol = float(dip_tol)
        self.soft_iron_std = float(soft_iron_std)
        self.hard_iron_std = float(hard_iron_std)
        self.vertical_hard_iron_std = float(vertical_hard_iron_std)
        self._rows: list[list[float]] = []  # [ax, ay, az, mx, my, mz, heading]
        self.m_n = np.full(3, np.nan)
        self.b = np.zeros(3)
        self.w = np.eye(3)
        self.residual_std = float("nan")
        self.heading_rms = float("nan")  # RMS of compass - ZUPT-KF heading over the calibration stances [rad]
        self.max_heading_rms = float(max_heading_rms)
        self.ready = False

    def add(self, acc_stance: np.ndarray, mag_stance: np.ndarray, heading_kf: float) -> None:
        """Record one stance: mean specific force [m/s^2], mean field [uT] (body), ZUPT-KF heading [rad]."""
        a = np.asarray(acc_stance, dtype=np.float64).reshape(3)
        m = np.asarray(mag_stance, dtype=np.float64).reshape(3)
        if np.all(np.isfinite(a)) and np.all(np.isfinite(m)) and math.isfinite(heading_kf):
            self._rows.append([*a.tolist(), *m.tolist(), float(heading_kf)])

    @property
    def n_stances(self) -> int:
        """Stances recorded so far."""
        return len(self._rows)

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

    def fit(self) -> bool:
        """Fit the calibration from the recorded stances; returns :attr:`ready`."""
        rows = np.asarray(self._rows, dtype=np.float64).reshape(-1, 7)
        if rows.shape[0] < self.min_stances:
            return self.ready
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
        wts = np.ones(rows.shape[0])
        s = 5.0  # uT
        x = np.zeros(p)
        for _ in range(10):
            wr = np.repeat(wts, 3) / s**2
            aw = a * wr[:, None]  # the same product both normal-equation terms used to compute on their own
            x = np.linalg.solve(aw.T @ a + np.diag(lam), aw.T @ y)
            r = (y - a @ x).reshape(-1, 3)
            rn = np.sqrt(np.add.reduce(r * r, axis=1))  # = np.linalg.norm(r, axis=1), bit for bit
            s = max(1.4826 * _median(rn) / math.sqrt(3.0) * 1.2, 0.5)
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
        self.ready = bool(np.all(np.isfinite(self.m_n)) and np.linalg.norm(self.m_n[:2]) > 1.0)
        if self.ready:
            d = [h - r[6] for h, r in zip(self._headings(rows), rows.tolist())]
            self.heading_rms = math.sqrt(float(np.mean(np.square(np.angle(np.exp(1j * np.asarray(d)))))))
        return self.ready

    @property
    def trusted(self) -> bool:
        """Calibrated, and its headings on the calibration stances agree with the ZUPT-KF's within
        ``max_heading_rms`` (RMS): the compass can stand in for the gyroscope. Unknown agreement (a
        calibration stored before it was measured) counts as agreement."""
        return self.ready and not self.heading_rms > self.max_heading_rms

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

    def relocate(self, norm: float, dip: float) -> None:
        """Take another place's field as m_n: its magnitude [uT] and dip [rad] replace m_n's, the azimuth (the
        heading reference) and the sensor's hard/soft iron are kept. A calibration fitted elsewhere (a profile
        from another building) would otherwise find every stance here disturbed (the gate tests against the
        field of the place it was fitted in)."""
        az = math.atan2(float(self.m_n[1]), float(self.m_n[0]))
        h = norm * math.cos(dip)
        self.m_n = np.array([h * math.cos(az), h * math.sin(az), norm * math.sin(dip)])

    def rotate_frame(self, delta: float) -> None:
        """Express the calibration in a navigation frame turned by ``delta`` [rad] about the vertical
        (headings in the new frame = old + delta): the field m_n and the stored stances' headings turn with it,
        the sensor's hard/soft iron does not. Used when a calibration from an earlier session (whose navigation
        frame began at that session's first stance) is re-anchored to this session's frame."""
        c, s_ = math.cos(delta), math.sin(delta)
        n, e = float(self.m_n[0]), float(self.m_n[1])
        self.m_n = np.array([c * n - s_ * e, s_ * n + c * e, float(self.m_n[2])])
        for r in self._rows:
            r[6] = wrap_angle(r[6] + delta)

    def heading(self, acc_stance: np.ndarray, mag_stance: np.ndarray) -> float:
        """Compass heading [rad] of the body in the navigator's NED frame (NaN before calibration)."""
        if not self.ready:
            return float("nan")
        alpha = _level_heading(np.asarray(acc_stance, dtype=np.float64).reshape(3).tolist(), self._cal3(mag_stance))
        psi = math.atan2(float(self.m_n[1]), float(self.m_n[0])) - alpha
        return math.atan2(math.sin(psi), math.cos(psi))

    def _headings(self, rows: np.ndarray) -> list[float]:
        """:meth:`heading` of every stance row ``[acc(3), mag(3), ...]`` (same operations, bit for bit, with the
        calibration read once instead of once per stance)."""
        az = math.atan2(float(self.m_n[1]), float(self.m_n[0]))
        b = self.b.tolist()
        w0, w1, w2 = self.w.tolist()
        out = []
        for r in rows.tolist():
            d = [r[3] - b[0], r[4] - b[1], r[5] - b[2]]
            m = [w0[0] * d[0] + w0[1] * d[1] + w0[2] * d[2],
                 w1[0] * d[0] + w1[1] * d[1] + w1[2] * d[2],
                 w2[0] * d[0] + w2[1] * d[1] + w2[2] * d[2]]
            psi = az - _level_heading(r, m)
            out.append(math.atan2(math.sin(psi), math.cos(psi)))
        return out

    def get_state(self) -> dict:
        """Plain-data state for ``energy.codec``."""
        return {"params": [self.soft_iron, self.min_stances, self.min_heading_spread, self.mag_tol, self.dip_tol,
                           self.soft_iron_std, self.hard_iron_std, self.vertical_hard_iron_std, self.max_heading_rms],
                "rows": np.asarray(self._rows, dtype=np.float64).reshape(-1, 7), "m_n": self.m_n.copy(),
                "b": self.b.copy(), "w": self.w.copy(), "residual_std": self.residual_std, "ready": self.ready,
                "heading_rms": self.heading_rms}

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
        obj.heading_rms = float(d.get("heading_rms", math.nan))  # unknown in states stored before it existed
        obj._rows = np.asarray(d["rows"], dtype=np.float64).reshape(-1, 7).tolist()
        obj.m_n = np.asarray(d["m_n"], dtype=np.float64).copy()
        obj.b = np.asarray(d["b"], dtype=np.float64).copy()
        obj.w = np.asarray(d["w"], dtype=np.float64).reshape(3, 3).copy()
        obj.residual_std = float(d["residual_std"])
        obj.ready = bool(d["ready"])
        return obj
