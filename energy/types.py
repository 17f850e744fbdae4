"""Value types of the engine contract (DESIGN.md): what ``Engine.feed`` returns."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any, Literal

__all__ = ["Behaviour", "Mode", "SensorConfig", "Position", "Event", "Update"]

Behaviour = Literal["stand", "walk", "run", "other"]
Mode = Literal["zupt", "pdr", "idle"]
WAKE_MODES: tuple[str, ...] = ("motion", "high_g", "weak_field", "compass_swing")  # SensorConfig.wake_mode


@dataclass(frozen=True)
class SensorConfig:
    """Sensor settings the device must use next.

    Parameters
    ----------
    gyro_on : bool
        Whether the gyroscope must sample.
    acc_rate_hz, gyr_rate_hz, mag_rate_hz : float
        Output data rates [Hz]; ``gyr_rate_hz`` is 0 when the gyroscope is off, ``mag_rate_hz`` 0 when the
        magnetometer is not needed.
    batch_s : float
        How much data the device should collect before its next upload [s] (its sensor FIFO / batching
        period): fewer, larger uploads cost less radio wake-up and per-batch computation, at the price of
        a longer delay before the engine sees the data and answers with a new configuration.
    gyro_wake_on_motion : bool
        Gyroscope off now (``gyro_on`` False), but managed by the device itself, as an IMU's activity /
        inactivity function does (LSM9DS1 ``ACT_THS``/``ACT_DUR``): the accelerometer keeps sampling at
        ``acc_rate_hz``; when a sample departs from the still reference by more than ``wake_threshold_ms2`` on
        any axis the gyroscope turns on by itself (without waiting for the host) and, once it delivers, both
        sensors run at ``gyr_rate_hz``; after ``sleep_after_s`` without such a departure it powers down again.
        See :class:`energy.device.DeviceEmulator` for the exact semantics.
    wake_threshold_ms2 : float
        Activity threshold [m/s^2] per axis (used with ``gyro_wake_on_motion``).
    sleep_after_s : float
        Inactivity duration before the device powers the gyroscope down again [s] (with ``gyro_wake_on_motion``).
    wake_mode : {"motion", "high_g", "weak_field", "compass_swing"}
        With ``gyro_wake_on_motion``, what the threshold applies to. ``"motion"``: the departure of a sample
        from the still reference (the activity function above: a foot that starts to move). ``"high_g"``: the
        absolute specific force on an axis (an IMU's high-g interrupt, e.g. LSM9DS1 ``INT_GEN_CFG_XL``
        ``XHIE/YHIE/ZHIE`` with ``INT_GEN_THS_*_XL``, BMI270 high-g): a gait more vigorous than the one the
        host has a model for. ``"weak_field"``: a still stance whose magnetic field, calibrated by
        ``mag_offset_ut`` and ``mag_matrix``, has a horizontal part (the accelerometer gives the vertical) below
        ``wake_field_ut``: a field too weak for the compass to tell the foot's turns, which the gyroscope must see
        from the first stride (the host would ask for it only after its next upload). ``"compass_swing"``: a
        phone's tilt-compensated compass azimuth (its accelerometer and magnetometer, at the rates they run)
        changes by more than ``wake_swing_rad`` within ``wake_window_s`` (:mod:`energy.compass_swing`): a turn the
        host would hear of only after its next upload. In all, the gyroscope powers down after ``sleep_after_s``
        without an event.
    mag_follows_gyro : bool
        With ``gyro_wake_on_motion``: the magnetometer is powered down while the gyroscope sleeps and samples at
        ``mag_rate_hz`` while it is awake (the device's controller switches it on the same activity interrupt);
        False: it samples at ``mag_rate_hz`` throughout.
    wake_field_ut : float
        With ``wake_mode == "weak_field"``: horizontal field [uT] below which a still stance wakes the gyroscope.
    mag_offset_ut : tuple of 3 float
        With ``wake_mode == "weak_field"``: hard-iron offset b [uT] (sensor frame), removed first.
    mag_matrix : tuple of 9 float
        With ``wake_mode == "weak_field"``: soft-iron correction W, row-major: calibrated field = W (m - b) [uT].
    wake_swing_rad : float
        With ``wake_mode == "compass_swing"``: the azimuth change [rad] within ``wake_window_s`` that wakes the
        gyroscope.
    wake_window_s : float
        With ``wake_mode == "compass_swing"``: the window [s] of that change.
    gyr_duty_period_s, gyr_duty_on_s : float
        A duty-cycled gyroscope (both > 0; 0: not duty-cycled): with ``gyro_on``, the device itself powers the
        gyroscope up at the start of every period ``P`` = ``gyr_duty_period_s`` [s] of its own clock (the phase
        kept from the batch in which the duty cycle began), it delivers ``gyr_duty_on_s`` [s] of samples at
        ``gyr_rate_hz`` from its turn-on time after each power-up and powers down again until the next period
        (the host's uploads are too rare to switch it several times a second). See
        :class:`energy.device.DeviceEmulator`.

    Raises
    ------
    ValueError
        ``gyro_wake_on_motion`` together with ``gyro_on`` (contradictory), or without a positive
        ``gyr_rate_hz``, ``sleep_after_s`` and threshold (``wake_threshold_ms2``; ``"weak_field"``:
        ``wake_field_ut``, 3 offsets and 9 matrix entries, all finite; ``"compass_swing"``: ``wake_swing_rad`` and
        ``wake_window_s``). A duty cycle without ``gyro_on`` and a positive ``gyr_rate_hz``, with
        ``gyro_wake_on_motion``, with only one of its two fields positive, or with ``gyr_duty_on_s`` not below
        ``gyr_duty_period_s``.
    """

    gyro_on: bool
    acc_rate_hz: float
    gyr_rate_hz: float
    mag_rate_hz: float
    batch_s: float = 1.0
    gyro_wake_on_motion: bool = False
    wake_threshold_ms2: float = 0.0
    sleep_after_s: float = 0.0
    mag_follows_gyro: bool = False
    wake_mode: str = "motion"
    wake_field_ut: float = 0.0
    mag_offset_ut: tuple[float, ...] = (0.0, 0.0, 0.0)
    mag_matrix: tuple[float, ...] = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)
    wake_swing_rad: float = 0.0
    wake_window_s: float = 0.0
    gyr_duty_period_s: float = 0.0
    gyr_duty_on_s: float = 0.0

    @property
    def gyr_duty(self) -> bool:
        """Whether the gyroscope is duty-cycled (``gyr_duty_period_s`` and ``gyr_duty_on_s`` set)."""
        return self.gyr_duty_period_s > 0

    def __post_init__(self) -> None:
        if self.wake_mode not in WAKE_MODES:
            raise ValueError(f"SensorConfig: wake_mode must be one of {WAKE_MODES}, got {self.wake_mode!r}")
        # frozen: stored as tuples of floats whatever sequence came in (JSON gives lists)
        object.__setattr__(self, "mag_offset_ut", tuple(float(x) for x in self.mag_offset_ut))
        object.__setattr__(self, "mag_matrix", tuple(float(x) for x in self.mag_matrix))
        if self.gyro_wake_on_motion:
            if self.gyro_on:
                raise ValueError("SensorConfig: gyro_wake_on_motion means the gyroscope is off now; gyro_on must be False")
            by_field = self.wake_mode == "weak_field"
            names = {"weak_field": ("wake_field_ut",), "compass_swing": ("wake_swing_rad", "wake_window_s")}.get(
                self.wake_mode, ("wake_threshold_ms2",))
            for name in ("gyr_rate_hz", *names, "sleep_after_s"):
                v = float(getattr(self, name))
                if not v > 0 or v == float("inf"):
                    raise ValueError(f"SensorConfig: gyro_wake_on_motion needs a positive finite {name}, got {v!r}")
            if by_field and (len(self.mag_offset_ut) != 3 or len(self.mag_matrix) != 9
                          or not all(math.isfinite(x) for x in (*self.mag_offset_ut, *self.mag_matrix))):
                raise ValueError("SensorConfig: wake_mode 'weak_field' needs 3 finite mag_offset_ut and 9 finite "
                                 f"mag_matrix entries, got {self.mag_offset_ut!r}, {self.mag_matrix!r}")
        p, on = float(self.gyr_duty_period_s), float(self.gyr_duty_on_s)
        if not (math.isfinite(p) and math.isfinite(on) and p >= 0 and on >= 0):
            raise ValueError(f"SensorConfig: gyr_duty_period_s and gyr_duty_on_s must be finite and >= 0, got {p!r}, {on!r}")
        if (p > 0) != (on > 0):
            raise ValueError(f"SensorConfig: a duty cycle needs both gyr_duty_period_s and gyr_duty_on_s, got {p!r}, {on!r}")
        if p > 0:
            if not on < p:
                raise ValueError(f"SensorConfig: gyr_duty_on_s must be below gyr_duty_period_s, got {on!r} >= {p!r}")
            if not self.gyro_on or not self.gyr_rate_hz > 0 or self.gyro_wake_on_motion:
                raise ValueError("SensorConfig: a duty-cycled gyroscope needs gyro_on, a positive gyr_rate_hz and no "
                                 "gyro_wake_on_motion")

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass(frozen=True)
class Position:
    """One navigation output, emitted per detected stance (ZUPT-KF) or step (Gait-DR).

    Parameters
    ----------
    t_ns : int
        Time of the stance / heel strike [ns], device clock.
    north, east, down : float
        Position in the session's NED frame [m], origin at the first stance.
    heading_rad : float
        Walking heading, clockwise from north [rad].
    behaviour : Behaviour
        Behaviour label at that time.
    mode : Mode
        Navigation mode that produced the position.
    step_length_m : float
        Horizontal length of the step (stride of the instrumented foot) that ended here [m].
    gyro_on : bool
        Whether the gyroscope was on for that step.
    """

    t_ns: int
    north: float
    east: float
    down: float
    heading_rad: float
    behaviour: str
    mode: str
    step_length_m: float
    gyro_on: bool

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass(frozen=True)
class Event:
    """Something the client may want to show or log: mode switch, calibration done, examination failed."""

    t_ns: int
    kind: str
    detail: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass(frozen=True)
class Update:
    """Result of one ``Engine.feed`` call."""

    positions: list[Position]
    events: list[Event]
    sensor_config: SensorConfig
    behaviour: str
    mode: str

    def to_dict(self) -> dict[str, Any]:
        return {
            "positions": [p.to_dict() for p in self.positions],
            "events": [e.to_dict() for e in self.events],
            "sensor_config": self.sensor_config.to_dict(),
            "behaviour": self.behaviour,
            "mode": self.mode,
        }
