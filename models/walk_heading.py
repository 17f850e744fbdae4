"""Walking heading of a step-and-heading device, step by step, and how well it is known (gyroscope on demand).

A scalar Kalman filter of the walking heading ``psi`` [rad] (clockwise from north) and its variance, with the
small interface the energy-aware scheduler needs: :meth:`WalkHeading.predict` with the gyroscope's heading
increment over the step (``None`` when the gyroscope was off: the person walks on straight, a random walk of
``straight_sigma_rad`` per step), :meth:`WalkHeading.update` with the compass's walking direction of the step
(:meth:`WalkHeading.observe` with another filter's absolute heading and its variance),
:meth:`WalkHeading.std` and :meth:`WalkHeading.forecast_std` (the standard deviation one gyroscope-off step
ahead, compass included), against which the scheduler turns the gyroscope on.

The compass's noise is not assumed but estimated: from the innovations of steps whose heading the gyroscope
carried (``E[nu^2] = P + R``), an exponential mean over ``noise_steps`` steps, floored at
``compass_floor_rad``. With the gyroscope off, a compass change beyond ``turn_gate`` standard deviations of the
innovation is a turn (the straight model cannot explain it): the compass is taken as it is and the scheduler is
told (:attr:`WalkHeading.turned`).

Kept deliberately small so that the project's shared walking-heading estimator (the foot engine's) can take its
place behind the same four calls.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields
from typing import Any

__all__ = ["WalkHeadingConfig", "WalkHeading", "wrap"]


def wrap(a: float) -> float:
    """Angle [rad] wrapped to [-pi, pi)."""
    return (a + math.pi) % (2.0 * math.pi) - math.pi


@dataclass(frozen=True)
class WalkHeadingConfig:
    """Parameters of :class:`WalkHeading` (angles in radians).

    Attributes
    ----------
    straight_sigma_rad : float
        Heading change per step walking without a gyroscope: the path's own wander between turns.
    gyro_sigma_rad : float
        Error of a gyroscope heading increment over one step (bias residual and noise).
    compass_floor_rad : float
        Smallest compass noise per step.
    compass_prior_rad : float
        Compass noise assumed before any gyroscope-carried step has measured it.
    noise_steps : float
        Steps of the exponential mean of the compass innovations.
    turn_gate : float
        With the gyroscope off, a compass innovation beyond this many standard deviations is a turn.
    turn_rad : float
        With the gyroscope off and ``hold``, a change of the compass beyond this since the last step the heading
        was known at is a turn, taken as that change (relative: the building's error where the walker turned is
        the same before and after).
    """

    straight_sigma_rad: float = math.radians(3.0)
    gyro_sigma_rad: float = math.radians(0.5)
    compass_floor_rad: float = math.radians(5.0)
    compass_prior_rad: float = math.radians(30.0)
    noise_steps: float = 30.0
    turn_gate: float = 3.0
    turn_rad: float = math.radians(25.0)

    def __post_init__(self) -> None:
        for f in fields(self):
            v = float(getattr(self, f.name))
            if not math.isfinite(v) or v <= 0:
                raise ValueError(f"WalkHeadingConfig: {f.name} must be a positive finite number, got {v!r}")

    def to_dict(self) -> dict[str, float]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> WalkHeadingConfig:
        return cls(**{k: float(v) for k, v in d.items()})


class WalkHeading:
    """Scalar Kalman filter of the walking heading (see the module docstring).

    Parameters
    ----------
    config : WalkHeadingConfig
    """

    def __init__(self, config: WalkHeadingConfig | None = None) -> None:
        self.config = config or WalkHeadingConfig()
        self.heading = math.nan  # [rad]
        self.var = math.inf  # [rad^2]
        self.compass_var = self.config.compass_prior_rad ** 2  # estimated R [rad^2]
        self.n_noise = 0  # innovations that estimated it
        self.gyro_step = False  # the last prediction was the gyroscope's
        self.turned = False  # the last update took a turn the gyroscope did not see
        self.ref_compass = math.nan  # compass at the last step whose heading was known [rad] (hold mode)

    @property
    def initialised(self) -> bool:
        return math.isfinite(self.heading)

    def set(self, heading_rad: float, var: float) -> None:
        """Take a heading from elsewhere (the first step; a gyroscope that carried it all along)."""
        self.heading = wrap(heading_rad)
        self.var = var

    def predict(self, increment_rad: float | None) -> None:
        """One step: the gyroscope's heading increment [rad], or ``None`` when it was off."""
        c = self.config
        self.gyro_step = increment_rad is not None
        if not self.initialised:
            return
        if increment_rad is None:
            self.var += c.straight_sigma_rad ** 2
        else:
            self.heading = wrap(self.heading + increment_rad)
            self.var += c.gyro_sigma_rad ** 2

    def observe(self, heading_rad: float, var: float) -> None:
        """An absolute heading [rad] with its variance [rad^2] from another filter (the MARG filter's, whose
        gyroscope-propagated heading already averages the compass)."""
        if not (math.isfinite(heading_rad) and math.isfinite(var) and var > 0):
            return
        if not self.initialised:
            self.set(heading_rad, var)
            return
        k = self.var / (self.var + var)
        self.heading = wrap(self.heading + k * wrap(heading_rad - self.heading))
        self.var *= 1.0 - k

    def hold(self, compass_rad: float) -> None:
        """A gyroscope-off step that keeps the heading (the walker goes straight, as the building's dominant
        directions say) unless the compass changed by more than ``turn_rad`` since :attr:`ref_compass`: a turn,
        taken as that change (:attr:`turned`)."""
        self.turned = False
        if not math.isfinite(compass_rad):
            return
        if not math.isfinite(self.ref_compass):
            self.ref_compass = compass_rad
            return
        d = wrap(compass_rad - self.ref_compass)
        if abs(d) > self.config.turn_rad:
            self.heading = wrap(self.heading + d)
            self.var += 2.0 * self.compass_var
            self.ref_compass = compass_rad
            self.turned = True

    def update(self, compass_rad: float, apply: bool = True) -> dict[str, float]:
        """The compass's walking direction of the step [rad].

        After a gyroscope-carried step the innovation estimates the compass noise; ``apply=False`` then leaves the
        heading to the gyroscope (whose filter already weighs the compass). After a gyroscope-off step the compass
        corrects the heading, or, beyond ``turn_gate``, replaces it (:attr:`turned`).
        """
        c = self.config
        self.turned = False
        if not math.isfinite(compass_rad):
            return {"innovation_rad": math.nan, "sigma_rad": math.nan}
        if self.gyro_step:
            self.ref_compass = compass_rad
        if not self.initialised:
            self.set(compass_rad, self.compass_var)
            return {"innovation_rad": 0.0, "sigma_rad": math.sqrt(self.var)}
        nu = wrap(compass_rad - self.heading)
        s = self.var + self.compass_var
        if self.gyro_step:
            a = 1.0 / min(self.n_noise + 1.0, c.noise_steps)
            est = (1.0 - a) * (self.compass_var + self.var) + a * nu * nu - self.var
            self.compass_var = max(est, c.compass_floor_rad ** 2)
            self.n_noise += 1
        if self.gyro_step and not apply:
            return {"innovation_rad": nu, "sigma_rad": math.sqrt(s)}
        if not self.gyro_step and nu * nu > c.turn_gate ** 2 * s:
            self.turned = True
            self.set(compass_rad, self.compass_var)
            return {"innovation_rad": nu, "sigma_rad": math.sqrt(s)}
        k = self.var / s
        self.heading = wrap(self.heading + k * nu)
        self.var *= 1.0 - k
        return {"innovation_rad": nu, "sigma_rad": math.sqrt(s)}

    def std(self) -> float:
        """Standard deviation of the heading now [rad]."""
        return math.sqrt(self.var) if math.isfinite(self.var) else math.inf

    def forecast_std(self) -> float:
        """Standard deviation after one more gyroscope-off step and its compass update [rad]."""
        if not math.isfinite(self.var):
            return math.inf
        p = self.var + self.config.straight_sigma_rad ** 2
        return math.sqrt(p * self.compass_var / (p + self.compass_var))

    def get_state(self) -> dict[str, Any]:
        return {"config": self.config.to_dict(), "heading": self.heading, "var": self.var,
                "compass_var": self.compass_var, "n_noise": self.n_noise, "gyro_step": self.gyro_step,
                "turned": self.turned, "ref_compass": self.ref_compass}

    @classmethod
    def from_state(cls, d: dict[str, Any]) -> WalkHeading:
        obj = cls(WalkHeadingConfig.from_dict(d["config"]))
        obj.heading, obj.var, obj.compass_var = float(d["heading"]), float(d["var"]), float(d["compass_var"])
        obj.n_noise, obj.gyro_step, obj.turned = int(d["n_noise"]), bool(d["gyro_step"]), bool(d["turned"])
        obj.ref_compass = float(d["ref_compass"])
        return obj
