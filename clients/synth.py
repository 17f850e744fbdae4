"""Gait/IMU synthesiser: foot-mounted specific force, angular rate and magnetic field with ground truth.

The foot trajectory is built first and the sensor signals are derived from it analytically, so a strapdown
integration of the noise-free signals reproduces the truth:

- stance phases: the foot rests (zero velocity, constant attitude);
- swing phases: horizontal travel along the stride direction with a minimum-jerk profile
  ``s(tau) = L (10 tau^3 - 15 tau^4 + 6 tau^5)``, a vertical lift ``-h 64 tau^3 (1 - tau)^3`` (NED, up is
  negative), a foot pitch profile ``A sin(2 pi tau) sin^2(pi tau)`` (toe-off up, heel strike down) and, in
  turns, a minimum-jerk heading change; all have zero rate at both ends of the swing.
- specific force in the body frame ``f_b = C_n^b (a_n - g_n)`` with ``g_n = (0, 0, g)`` NED, so at rest the
  body z axis (pointing down out of the sole) reads ``-g``; body angular rate from the ZYX Euler rates;
  magnetic field ``m_b = C_n^b (m_n + d_n(t))`` with an Earth field ``m_n`` and disturbances ``d_n`` near steel.
- sensor errors from 002 Table 3 (LSM9DS1, Allan variance): white noise densities, bias instability as a
  first-order Gauss-Markov process, plus a constant turn-on bias; deterministic from the seed. The magnetometer
  can also carry the device's hard and soft iron (``m = S m_b + b``, fixed per device, not drawn from the seed:
  :data:`LSM9DS1_SHOE`), and the accelerometer and gyroscope their scale-factor and cross-axis errors
  (``f = T_a f_b``, ``w = T_g w_b``, also fixed per device: :data:`LSM9DS1_TYPICAL`); the default
  :data:`LSM9DS1` has neither.

Body frame of the foot sensor: x forward along the foot, y right, z down (through the sole), like the
University of Toronto recordings. Attitude ``C_b^n = Rz(yaw) Ry(pitch) Rx(roll)``.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np
from scipy.signal import lfilter

from clients.recording import Recording, RecordingMeta, Truth
from models.batch import SensorBatch

__all__ = [
    "GaitParams",
    "GAITS",
    "Segment",
    "Scenario",
    "SensorErrors",
    "LSM9DS1",
    "LSM9DS1_SHOE",
    "LSM9DS1_TYPICAL",
    "LSM9DS1_CLIPPING",
    "IMU_ERRORS",
    "scenario_names",
    "get_scenario",
    "random_day",
    "RANDOM_DAY",
    "synthesize",
]

G = 9.80665  # m/s^2
DEG = np.pi / 180.0


@dataclass(frozen=True)
class GaitParams:
    """One gait of the instrumented foot.

    Parameters
    ----------
    stride_period_s : float
        Duration of one stride of the instrumented foot [s].
    duty_factor : float
        Fraction of the stride the foot rests flat on the ground (zero velocity). Heel-off and toe-off belong
        to the gait's stance but the foot already moves then, so this is below the gait duty factor
        (walking about 0.45-0.6, running 0.2-0.3, matching the |a| ~ g fraction of the real recordings).
    stride_length_m : float
        Horizontal foot travel per stride [m].
    lift_m : float
        Peak foot lift during swing [m].
    peak_pitch_rate : float
        Peak foot pitch rate during swing [rad/s].
    """

    stride_period_s: float
    duty_factor: float
    stride_length_m: float
    lift_m: float
    peak_pitch_rate: float


# Typical adult values (foot-mounted IMU literature and the development recordings: walking strides 1.0-1.6 s,
# running 0.7-0.8 s; peak foot pitch rates walking 4-9 rad/s, running 9-12 rad/s).
GAITS: dict[str, GaitParams] = {
    "walk_slow": GaitParams(1.35, 0.58, 1.05, 0.08, 4.5),
    "walk": GaitParams(1.15, 0.50, 1.35, 0.10, 6.5),
    "walk_fast": GaitParams(1.02, 0.46, 1.60, 0.12, 8.0),
    "run": GaitParams(0.74, 0.25, 2.30, 0.18, 10.5),
    # An elite sprint: 4.4 m strides in 0.5 s with the foot flat for a fifth of it; the minimum-jerk swing then peaks
    # at 1.875 L / T = 21 m/s foot speed and 5.77 L / T^2 = 16.2 g, the foot pitches at up to 40 rad/s = 2290 deg/s
    # (sprinters' feet: 20-40 rad/s): beyond a +-16 g / +-2000 deg/s sensor's range (SensorErrors.acc_range_ms2).
    "sprint": GaitParams(0.50, 0.20, 4.40, 0.30, 40.0),
}

BEHAVIOUR_OF: dict[str, str] = {"walk_slow": "walk", "walk": "walk", "walk_fast": "walk", "run": "run", "sprint": "run",
                                "stand": "stand"}


@dataclass(frozen=True)
class Segment:
    """A stretch of one behaviour.

    Parameters
    ----------
    kind : str
        ``"stand"`` or a key of :data:`GAITS`.
    duration_s : float
        Duration [s] (a gait segment holds as many whole strides as fit, then rests).
    turn_deg : float
        Heading change over the segment [deg], clockwise positive, spread over up to 4 strides mid-segment.
    steel : bool
        Whether the segment passes near steel (a magnetic disturbance of ``steel_ut`` uT in the field).
    """

    kind: str
    duration_s: float
    turn_deg: float = 0.0
    steel: bool = False


@dataclass(frozen=True)
class Scenario:
    """A named sequence of segments starting at ``heading_deg`` [deg, clockwise from north]."""

    name: str
    segments: tuple[Segment, ...]
    heading_deg: float = 0.0


_IDENTITY = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)


@dataclass(frozen=True)
class SensorErrors:
    """Sensor error model (per axis, 1 sigma).

    Parameters
    ----------
    acc_noise_density : float
        Accelerometer white noise [m/s^2/sqrt(Hz)].
    gyr_noise_density : float
        Gyroscope white noise [rad/s/sqrt(Hz)].
    mag_noise_rms : float
        Magnetometer white noise per sample [uT].
    acc_bias_instability, gyr_bias_instability : float
        Bias instability [m/s^2], [rad/s], modelled as a Gauss-Markov process with ``bias_tau_s``.
    acc_turn_on_bias, gyr_turn_on_bias : float
        Constant bias drawn once per recording [m/s^2], [rad/s].
    bias_tau_s : float
        Correlation time of the bias process [s].
    mag_hard_iron_ut : tuple of 3 float
        Magnetometer hard iron b [uT], body frame: a constant field added to every reading (the sensor's own
        offset plus magnetised parts of the device and the shoe). A property of the device, the same every
        day, so it is given here rather than drawn from the seed.
    mag_soft_iron : tuple of 9 float
        Soft-iron matrix S (row-major, dimensionless) applied to the field before the hard iron:
        ``m = S m_b + b``. Identity = none.
    acc_scale_misalignment, gyr_scale_misalignment : tuple of 9 float
        ``T = I + M`` (row-major, dimensionless) applied to the true specific force and angular rate before the
        biases and noise are added: ``f = T_a f_b``, ``w = T_g w_b``. The diagonal of ``M`` holds the
        scale-factor errors, the off-diagonal terms the cross-axis sensitivities. A property of the device, like
        the iron. Identity = none.
    acc_range_ms2, gyr_range_rads : float
        Full scale of the accelerometer [m/s^2] and gyroscope [rad/s] per axis: a reading beyond it is clipped to
        it, as the part's output register saturates (e.g. +-16 g, +-2000 deg/s). ``inf`` = never clips.
    """

    acc_noise_density: float
    gyr_noise_density: float
    mag_noise_rms: float
    acc_bias_instability: float
    gyr_bias_instability: float
    acc_turn_on_bias: float
    gyr_turn_on_bias: float
    bias_tau_s: float = 100.0
    mag_hard_iron_ut: tuple[float, float, float] = (0.0, 0.0, 0.0)
    mag_soft_iron: tuple[float, ...] = _IDENTITY
    acc_scale_misalignment: tuple[float, ...] = _IDENTITY
    gyr_scale_misalignment: tuple[float, ...] = _IDENTITY
    acc_range_ms2: float = float("inf")
    gyr_range_rads: float = float("inf")

    @property
    def has_iron(self) -> bool:
        """The magnetometer has hard or soft iron (False: readings are the body field plus noise)."""
        return any(v != 0.0 for v in self.mag_hard_iron_ut) or tuple(self.mag_soft_iron) != _IDENTITY

    @property
    def has_scale_errors(self) -> bool:
        """The accelerometer or gyroscope has scale-factor or cross-axis errors."""
        return tuple(self.acc_scale_misalignment) != _IDENTITY or tuple(self.gyr_scale_misalignment) != _IDENTITY


# 002 Table 3 (LSM9DS1, Allan variance): acc noise 226 ug/sqrt(Hz), gyro 0.017 deg/s/sqrt(Hz), bias instability
# acc 182 ug, gyro 8.63 deg/h. 002's magnetometer figure (7.9 uT/sqrt(Hz)) is implausibly large for the part
# (it would bury the Earth field at 80 Hz); we use 0.3 uT rms per sample (LSM9DS1 resolution 0.014 uT at
# +-4 gauss; typical RMS noise of such magnetometers is a few tenths of a uT). Turn-on biases: small residuals
# after a factory/static calibration (assumption, 10 mg and 0.5 deg/s).
LSM9DS1 = SensorErrors(
    acc_noise_density=226e-6 * G,
    gyr_noise_density=0.017 * DEG,
    mag_noise_rms=0.3,
    acc_bias_instability=182e-6 * G,
    gyr_bias_instability=8.63 * DEG / 3600.0,
    acc_turn_on_bias=0.01 * G,
    gyr_turn_on_bias=0.5 * DEG,
)

# The same part on a shoe, with the magnetometer errors a field calibration has to remove (one device: fixed, the
# same every day). Hard iron: the LSM9DS1 leaves it to the user (offset registers OFFSET_X/Y/Z_REG_M, default 0,
# "to compensate environmental effects": datasheet DocID025715 section 8.1-8.3); two parts turned through all
# attitudes on the ST community forum ("Min (always zero) value from LSM9DS1 magnetometer looks suspicious", 2020;
# min/max per axis in mG) were centred at (13, 9, -14) uT and (9, 25, -69) uT: tens of uT per axis, as large as
# the Earth's field. We take b = (14, -22, 35) uT (|b| 44 uT, within that range; an assumption for one device).
# Soft iron: a few per cent of scale difference and cross-coupling (assumption, typical of consumer parts beside
# a battery and PCB traces): S symmetric, diagonal 1.04/0.97/1.00, off-diagonals 0.02/-0.015/0.01.
LSM9DS1_SHOE = dataclasses.replace(
    LSM9DS1,
    mag_hard_iron_ut=(14.0, -22.0, 35.0),
    mag_soft_iron=(1.04, 0.02, -0.015, 0.02, 0.97, 0.01, -0.015, 0.01, 1.00),
)

# A typical part of the same kind with the scale-factor and cross-axis errors every MEMS datasheet lists; without
# them (LSM9DS1 above: white noise and biases only) the always-on ZUPT-KF measures the synthetic mixed day's
# distance 0.03 % wrong, where the real walks give 0.07-1.14 % (gdin `--mode zupt`, exp 17-22; the typical part:
# 0.73 %, tests/clients/test_synth.py). The LSM9DS1 datasheet gives no sensitivity or cross-axis tolerance; the MPU-9250's (InvenSense
# PS-MPU-9250A-01, Tables 1 and 2) are +-3 % scale factor and +-2 % cross axis for both sensors. We take a part
# at about a third of those bounds (one device, fixed, not drawn from the seed): accelerometer scale errors
# +0.8/-0.6/+0.4 % and cross-axis 0.3-0.6 %, gyroscope scale errors +1.0/-0.8/+0.9 % and cross-axis 0.4-0.7 %.
LSM9DS1_TYPICAL = dataclasses.replace(
    LSM9DS1,
    acc_scale_misalignment=(1.008, 0.005, -0.004, -0.003, 0.994, 0.006, 0.005, -0.004, 1.004),
    gyr_scale_misalignment=(1.010, 0.006, -0.005, -0.004, 0.992, 0.007, 0.006, -0.005, 1.009),
)

# The typical part at the ranges of most foot-mounted IMUs (VN-200, LSM6DSO and MPU-9250 at their widest settings):
# +-16 g and +-2000 deg/s. A sprint (GAITS["sprint"]) drives both beyond them, and the part clips.
LSM9DS1_CLIPPING = dataclasses.replace(LSM9DS1_TYPICAL, acc_range_ms2=16.0 * G, gyr_range_rads=2000.0 * DEG)

# Names of the error models for command lines (`pednav energy simulate --imu-errors NAME`).
IMU_ERRORS: dict[str, SensorErrors] = {"noise-only": LSM9DS1, "typical-part": LSM9DS1_TYPICAL, "shoe-iron": LSM9DS1_SHOE}

EARTH_FIELD_UT = np.array([22.0, 1.5, 42.0])  # NED [uT]: ~47 uT, inclination ~62 deg (mid-latitude Europe)
STEEL_UT = 25.0  # uT, peak disturbance magnitude near steel structures


def _s(S: list[Segment]) -> tuple[Segment, ...]:
    return tuple(S)


_SCENARIOS: dict[str, Scenario] = {
    "stand": Scenario("stand", _s([Segment("stand", 30.0)])),
    "walk": Scenario(
        "walk",
        _s([Segment("stand", 5.0), Segment("walk", 30.0, 90.0), Segment("walk", 30.0, -90.0), Segment("stand", 5.0)]),
    ),
    "run": Scenario("run", _s([Segment("stand", 5.0), Segment("run", 40.0, 90.0), Segment("stand", 5.0)])),
    # a 100-m dash and back, with a jog to the start line: synthesize("sprint", errors=LSM9DS1_CLIPPING) clips
    "sprint": Scenario("sprint", _s([Segment("stand", 5.0), Segment("run", 10.0), Segment("sprint", 12.0),
                                     Segment("stand", 5.0), Segment("sprint", 12.0, 180.0), Segment("stand", 5.0)])),
    "demo": Scenario(
        "demo",
        _s(
            [
                Segment("stand", 10.0),
                Segment("walk", 25.0, 90.0),
                Segment("walk", 15.0),
                Segment("run", 25.0, 90.0),
                Segment("walk_fast", 15.0, 90.0),
                Segment("walk_slow", 15.0),
                Segment("stand", 10.0),
            ]
        ),
    ),
    "mixed-day": Scenario(
        "mixed-day",
        _s(
            [
                Segment("stand", 40.0),
                Segment("walk_slow", 30.0, 90.0),
                Segment("stand", 20.0),
                Segment("walk", 45.0, 90.0),
                Segment("walk", 20.0, 0.0, steel=True),
                Segment("walk_fast", 30.0, -90.0),
                Segment("stand", 30.0),
                Segment("run", 30.0, 90.0),
                Segment("walk", 30.0, 180.0),
                Segment("stand", 60.0),
                Segment("walk", 40.0, -90.0, steel=True),
                Segment("walk_slow", 20.0),
                Segment("stand", 30.0),
            ]
        ),
    ),
}


RANDOM_DAY = "random-day"


def random_day(seed: int) -> Scenario:
    """A day laid out from ``seed``, unlike the fixed ones: a held-out check that what was tuned on the mixed
    day carries over (the product meets recordings it has not seen).

    After 20 s of standing, 14 gait segments of 15-45 s (walk three times in six, slow walk, fast walk and run
    once each), each turning by 0, +-45, +-90 or 180 deg mid-segment and passing steel one time in four, a stop
    of 2-40 s after about a third of them, and 20 s of standing at the end; the start heading is uniform. The
    layout comes from its own generator (``seed`` + 10000), so the synthesiser's draws for the same seed are
    those of any other scenario.
    """
    rng = np.random.default_rng(10_000 + int(seed))
    segs = [Segment("stand", 20.0)]
    for _ in range(14):
        kind = str(rng.choice(["walk", "walk", "walk", "walk_slow", "walk_fast", "run"]))
        turn = float(rng.choice([0.0, 90.0, -90.0, 45.0, -45.0, 180.0]))
        segs.append(Segment(kind, float(rng.uniform(15.0, 45.0)), turn, bool(rng.random() < 0.25)))
        if rng.random() < 0.35:
            segs.append(Segment("stand", float(rng.uniform(2.0, 40.0))))
    segs.append(Segment("stand", 20.0))
    return Scenario(RANDOM_DAY, tuple(segs), float(rng.uniform(0.0, 360.0)))


def scenario_names() -> list[str]:
    """Names accepted by :func:`synthesize` (``random-day``: laid out from the seed, :func:`random_day`)."""
    return [*_SCENARIOS, RANDOM_DAY]


def get_scenario(name: str, seed: int = 0) -> Scenario:
    """The named scenario (``KeyError`` listing the names when unknown); ``seed`` lays out ``random-day``."""
    if name == RANDOM_DAY:
        return random_day(seed)
    try:
        return _SCENARIOS[name]
    except KeyError:
        raise KeyError(f"unknown scenario {name!r}; known: {', '.join(scenario_names())}") from None


# ---------------------------------------------------------------------------------------------- profiles
def _minjerk(tau: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Minimum-jerk 0 -> 1 and its first two derivatives with respect to ``tau``."""
    s = 10 * tau**3 - 15 * tau**4 + 6 * tau**5
    ds = 30 * tau**2 - 60 * tau**3 + 30 * tau**4
    dds = 60 * tau - 180 * tau**2 + 120 * tau**3
    return s, ds, dds


def _lift(tau: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unit bump ``64 tau^3 (1 - tau)^3`` (peak 1 at 0.5; zero rate and acceleration at both ends), derivatives."""
    u = 1 - tau
    z = 64 * tau**3 * u**3
    dz = 192 * tau**2 * u**2 * (1 - 2 * tau)
    ddz = 384 * tau * u * ((1 - 2 * tau) ** 2 - tau * u)
    return z, dz, ddz


def _pitch_shape(tau: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pitch shape ``sin(2 pi tau) sin^2(pi tau)`` and its derivative (zero value and rate at both ends)."""
    a, b = np.sin(2 * np.pi * tau), np.sin(np.pi * tau)
    val = a * b**2
    der = 2 * np.pi * np.cos(2 * np.pi * tau) * b**2 + a * 2 * np.pi * b * np.cos(np.pi * tau)
    return val, der


_TAU = np.linspace(0.0, 1.0, 2001)
_PITCH_SHAPE_MAX_RATE = float(np.max(np.abs(_pitch_shape(_TAU)[1])))


def _dcm_nb(roll: np.ndarray, pitch: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """Body-to-NED DCMs ``Rz(yaw) Ry(pitch) Rx(roll)``, shape (N, 3, 3)."""
    cr, sr, cp, sp, cy, sy = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch), np.cos(yaw), np.sin(yaw)
    c = np.empty(roll.shape + (3, 3))
    c[..., 0, 0] = cy * cp
    c[..., 0, 1] = cy * sp * sr - sy * cr
    c[..., 0, 2] = cy * sp * cr + sy * sr
    c[..., 1, 0] = sy * cp
    c[..., 1, 1] = sy * sp * sr + cy * cr
    c[..., 1, 2] = sy * sp * cr - cy * sr
    c[..., 2, 0] = -sp
    c[..., 2, 1] = cp * sr
    c[..., 2, 2] = cp * cr
    return c


# ---------------------------------------------------------------------------------------------- synthesis
@dataclass
class _Strides:
    t0: list[float] = field(default_factory=list)  # swing start [s]
    dur: list[float] = field(default_factory=list)  # swing duration [s]
    p0: list[np.ndarray] = field(default_factory=list)  # foot position at swing start (NED) [m]
    length: list[float] = field(default_factory=list)
    direction: list[float] = field(default_factory=list)  # travel direction [rad]
    yaw0: list[float] = field(default_factory=list)
    dyaw: list[float] = field(default_factory=list)
    pitch_amp: list[float] = field(default_factory=list)
    lift: list[float] = field(default_factory=list)


def _plan(scn: Scenario, rng: np.random.Generator) -> tuple[_Strides, list[tuple[float, float, str]], list[tuple[float, float]], float]:
    """Lay out strides; return them, behaviour intervals ``(t0, t1, label)``, steel intervals, total duration."""
    st = _Strides()
    labels: list[tuple[float, float, str]] = []
    steel: list[tuple[float, float]] = []
    t = 0.0
    pos = np.zeros(3)
    yaw = scn.heading_deg * DEG
    for seg in scn.segments:
        t_end = t + seg.duration_s
        if seg.steel:
            steel.append((t, t_end))
        if seg.kind == "stand":
            labels.append((t, t_end, "stand"))
            t = t_end
            continue
        gp = GAITS[seg.kind]
        n = int(seg.duration_s // gp.stride_period_s)
        n_turn = min(4, n)
        first_turn = max(0, (n - n_turn) // 2)
        seg_start = t
        for i in range(n):
            period = gp.stride_period_s * (1 + 0.03 * rng.standard_normal())
            length = gp.stride_length_m * (1 + 0.03 * rng.standard_normal())
            t_stance = period * gp.duty_factor
            t_swing = period - t_stance
            dyaw = seg.turn_deg * DEG / n_turn if first_turn <= i < first_turn + n_turn else 0.0
            st.t0.append(t + t_stance)
            st.dur.append(t_swing)
            st.p0.append(pos.copy())
            st.length.append(length)
            st.direction.append(yaw + dyaw / 2)
            st.yaw0.append(yaw)
            st.dyaw.append(dyaw)
            st.pitch_amp.append(gp.peak_pitch_rate * t_swing / _PITCH_SHAPE_MAX_RATE)
            st.lift.append(gp.lift_m)
            pos = pos + length * np.array([np.cos(yaw + dyaw / 2), np.sin(yaw + dyaw / 2), 0.0])
            yaw += dyaw
            t += period
        # The gait lasts until the last heel strike; the remaining time is a rest (the person stops). Starting
        # from standing, the gait begins at the first toe-off (the first flat-foot phase is still standing).
        if n and (not labels or labels[-1][2] == "stand"):
            first_toe_off = st.t0[len(st.t0) - n]
            if labels and labels[-1][2] == "stand":
                labels[-1] = (labels[-1][0], first_toe_off, "stand")
            else:
                labels.append((seg_start, first_toe_off, "stand"))
            seg_start = first_toe_off
        labels.append((seg_start, t, BEHAVIOUR_OF[seg.kind]))
        if t_end > t:
            labels.append((t, t_end, "stand"))
        # the strides' periods vary (3 %), so the whole strides that fit on average can overrun the segment by a
        # few tenths of a second: the next segment then starts at the last heel strike, not before it (starting
        # at t_end put its first stance, or swing, inside the last swing: demo seed 0 had a 15 ms stance)
        t = max(t, t_end)
    return st, labels, steel, t


def synthesize(
    scenario: str | Scenario,
    seed: int = 0,
    rate_hz: float = 200.0,
    errors: SensorErrors = LSM9DS1,
    mag_rate_hz: float | None = None,
    earth_field_ut: np.ndarray | None = None,
) -> Recording:
    """Synthesise a foot-mounted MARG recording with ground truth.

    Parameters
    ----------
    scenario : str or Scenario
        A name from :func:`scenario_names` or a custom :class:`Scenario`.
    seed : int
        Seed of every random choice (stride variability, noise, biases; the layout of ``random-day``): same
        seed, same recording.
    rate_hz : float
        Accelerometer and gyroscope rate [Hz].
    errors : SensorErrors
        Sensor error model (default: 002 Table 3, LSM9DS1).
    mag_rate_hz : float, optional
        Magnetometer rate [Hz]; default ``rate_hz``.
    earth_field_ut : ndarray (3,), optional
        The Earth's field in the truth's (true-north) NED frame [uT]; default :data:`EARTH_FIELD_UT`. A field
        with a declination (e.g. ``models.geo.magnetic_elements(anchor).field_true_ned_ut``) makes a recording
        whose magnetic north differs from the truth's north.

    Returns
    -------
    Recording
        ``batch`` in SI (m/s^2, rad/s, uT; body frame x forward, y right, z down through the sole);
        ``truth.positions`` NED foot position [m] per accelerometer sample; ``truth.extra`` holds per-sample
        ``behaviour`` (array of str), ``heading_rad``, ``stance`` (bool), ``velocity`` (N, 3) [m/s],
        ``attitude_euler`` (N, 3) [rad], and per stride ``step_t_s`` (heel strikes), ``step_lengths_m``,
        plus ``segments`` (t0, t1, label) and ``steel_intervals``.
    """
    scn = get_scenario(scenario, seed) if isinstance(scenario, str) else scenario
    rng = np.random.default_rng(seed)
    st, labels, steel, duration = _plan(scn, rng)
    n = int(np.floor(duration * rate_hz)) + 1
    t = np.arange(n) / rate_hz

    pos = np.zeros((n, 3))
    vel = np.zeros((n, 3))
    acc_n = np.zeros((n, 3))
    pitch = np.zeros(n)
    dpitch = np.zeros(n)
    yaw = np.full(n, scn.heading_deg * DEG)
    dyaw = np.zeros(n)
    stance = np.ones(n, dtype=bool)
    # Rest positions/attitude between swings: fill forward from each stride's end.
    for k in range(len(st.t0)):
        t0, T = st.t0[k], st.dur[k]
        i0 = int(np.ceil(t0 * rate_hz - 1e-9))
        i1 = int(np.ceil((t0 + T) * rate_hz - 1e-9))
        u = np.array([np.cos(st.direction[k]), np.sin(st.direction[k]), 0.0])
        p_end = st.p0[k] + st.length[k] * u
        yaw_end = st.yaw0[k] + st.dyaw[k]
        pos[i0:] = p_end
        yaw[i0:] = yaw_end
        if i1 <= i0:
            continue
        tau = (t[i0:i1] - t0) / T
        s, ds, dds = _minjerk(tau)
        z, dz, ddz = _lift(tau)
        pos[i0:i1] = st.p0[k] + np.outer(st.length[k] * s, u)
        pos[i0:i1, 2] -= st.lift[k] * z
        vel[i0:i1] = np.outer(st.length[k] * ds / T, u)
        vel[i0:i1, 2] = -st.lift[k] * dz / T
        acc_n[i0:i1] = np.outer(st.length[k] * dds / T**2, u)
        acc_n[i0:i1, 2] = -st.lift[k] * ddz / T**2
        pv, pd = _pitch_shape(tau)
        pitch[i0:i1] = st.pitch_amp[k] * pv
        dpitch[i0:i1] = st.pitch_amp[k] * pd / T
        y, dy, _ = _minjerk(tau)
        yaw[i0:i1] = st.yaw0[k] + st.dyaw[k] * y
        dyaw[i0:i1] = st.dyaw[k] * dy / T
        stance[i0:i1] = False
    roll = np.zeros(n)
    droll = np.zeros(n)

    c_nb = _dcm_nb(roll, pitch, yaw)
    g_n = np.array([0.0, 0.0, G])
    f_b = np.einsum("nji,nj->ni", c_nb, acc_n - g_n)  # f_b = C_n^b (a_n - g_n)
    # Body rates from ZYX Euler rates.
    w_b = np.stack(
        [
            droll - dyaw * np.sin(pitch),
            dpitch * np.cos(roll) + dyaw * np.cos(pitch) * np.sin(roll),
            -dpitch * np.sin(roll) + dyaw * np.cos(pitch) * np.cos(roll),
        ],
        axis=1,
    )
    # Magnetic field: Earth field plus smooth disturbances near steel (direction fixed per interval).
    d_n = np.zeros((n, 3))
    for a, b in steel:
        m = (t >= a) & (t < b)
        bump = np.sin(np.pi * (t[m] - a) / (b - a)) ** 2
        direction = rng.standard_normal(3)
        direction /= np.linalg.norm(direction)
        d_n[m] = STEEL_UT * np.outer(bump, direction)
    m_e = EARTH_FIELD_UT if earth_field_ut is None else np.asarray(earth_field_ut, dtype=np.float64).reshape(3)
    m_b = np.einsum("nji,nj->ni", c_nb, m_e + d_n)

    # Sensor errors (per-sample white noise sigma = density * sqrt(rate)).
    def bias_process(sigma: float, turn_on: float) -> np.ndarray:
        phi = np.exp(-1.0 / (rate_hz * errors.bias_tau_s))
        e = rng.standard_normal((n, 3)) * sigma * np.sqrt(1 - phi**2)
        e[0] = rng.standard_normal(3) * sigma
        b = lfilter([1.0], [1.0, -phi], e, axis=0)  # first-order Gauss-Markov: b_i = phi b_(i-1) + e_i
        return b + rng.standard_normal(3) * turn_on

    # f = T_a f_b, w = T_g w_b (device scale-factor and cross-axis errors; no random draw, so the noise and bias
    # draws are those of the same seed without them)
    t_a = np.asarray(errors.acc_scale_misalignment, dtype=np.float64).reshape(3, 3)
    t_g = np.asarray(errors.gyr_scale_misalignment, dtype=np.float64).reshape(3, 3)
    f_meas = f_b @ t_a.T + bias_process(errors.acc_bias_instability, errors.acc_turn_on_bias)
    f_meas += rng.standard_normal((n, 3)) * errors.acc_noise_density * np.sqrt(rate_hz)
    w_meas = w_b @ t_g.T + bias_process(errors.gyr_bias_instability, errors.gyr_turn_on_bias)
    w_meas += rng.standard_normal((n, 3)) * errors.gyr_noise_density * np.sqrt(rate_hz)
    if errors.has_iron:  # m = S m_b + b (device hard/soft iron; no random draw, so other outputs are unchanged)
        s_iron = np.asarray(errors.mag_soft_iron, dtype=np.float64).reshape(3, 3)
        m_b = m_b @ s_iron.T + np.asarray(errors.mag_hard_iron_ut, dtype=np.float64)
    m_meas = m_b + rng.standard_normal((n, 3)) * errors.mag_noise_rms
    # the output registers saturate at the part's full scale (after noise and bias: what the part would report)
    np.clip(f_meas, -errors.acc_range_ms2, errors.acc_range_ms2, out=f_meas)
    np.clip(w_meas, -errors.gyr_range_rads, errors.gyr_range_rads, out=w_meas)

    t_ns = np.round(t * 1e9).astype(np.int64)
    mag_step = max(1, int(round(rate_hz / mag_rate_hz))) if mag_rate_hz else 1
    batch = SensorBatch(
        acc_t_ns=t_ns, acc=f_meas, gyr_t_ns=t_ns.copy(), gyr=w_meas, mag_t_ns=t_ns[::mag_step].copy(), mag=m_meas[::mag_step]
    )
    behaviour = np.empty(n, dtype=object)
    for a, b, lab in labels:
        behaviour[(t >= a - 1e-12) & (t < b)] = lab
    behaviour[behaviour == None] = "stand"  # noqa: E711  (last sample)
    step_t = np.array([a + d for a, d in zip(st.t0, st.dur)])
    truth = Truth(
        t_ns=t_ns.copy(),
        positions=pos,
        extra={
            "behaviour": behaviour.astype(str),
            "heading_rad": yaw,
            "stance": stance,
            "velocity": vel,
            "attitude_euler": np.stack([roll, pitch, yaw], axis=1),
            "specific_force_true": f_b,
            "angular_rate_true": w_b,
            "step_t_s": step_t,
            "step_lengths_m": np.array(st.length),
            "segments": labels,
            "steel_intervals": steel,
            "seed": seed,
            "mag_hard_iron_ut": np.asarray(errors.mag_hard_iron_ut, dtype=np.float64),
            "mag_soft_iron": np.asarray(errors.mag_soft_iron, dtype=np.float64).reshape(3, 3),
            "acc_scale_misalignment": t_a,
            "gyr_scale_misalignment": t_g,
        },
    )
    meta = RecordingMeta(
        source_format="synthetic",
        rate_hz=float(rate_hz),
        units_converted={},
        mount="foot (x forward, y right, z down through the sole)",
        notes=(f"scenario {scn.name}, seed {seed}",),
    )
    return Recording(name=f"synthetic:{scn.name}:{seed}", batch=batch, meta=meta, truth=truth)
