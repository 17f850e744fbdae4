"""Heuristic drift elimination with magnetically aided dominant directions (003 Section 6.1, its refs [41], [44]-[46]).

People walk straight along a building's walls, and a building's walls run in two perpendicular directions. While
the walker goes straight (the heading changed less than ``straight_rad`` over the last ``window_steps`` steps),
every step's compass walking direction votes for the building's orientation modulo 90 degrees (the circular mean
of four times the angle): the compass errs by place, but over many places its errors average out, whereas a
single place's error is what the heading inherits. A straight step whose heading, corrected so far, lies within
``gate_rad`` of one of the four dominant directions observes that direction: a scalar Kalman filter estimates the
offset between the heading and the building (the gyroscope's drift, a turn it measured short), with a random walk
of ``drift_rad_per_step``. Steps off the dominant directions (a diagonal corridor, a gentle curve) are left alone.

Nothing here knows the building: its orientation is learnt from the walk's own compass, and needs
``min_votes`` straight steps of a steady gait before it corrects anything.
"""

from __future__ import annotations

import cmath
import math
from dataclasses import asdict, dataclass, fields
from typing import Any

__all__ = ["DominantDirectionsConfig", "DominantDirections"]


def _wrap(a: float) -> float:
    return (a + math.pi) % (2.0 * math.pi) - math.pi


@dataclass(frozen=True)
class DominantDirectionsConfig:
    """Parameters of :class:`DominantDirections` (angles in radians).

    Attributes
    ----------
    straight_rad : float
        Largest heading change over ``window_steps`` of a straight walk.
    window_steps : int
        Steps over which straightness is judged.
    gate_rad : float
        A straight step within this of a dominant direction observes it.
    sigma_rad : float
        Noise of that observation (how straight people walk along a wall).
    drift_rad_per_step : float
        Random walk of the offset per step (gyroscope drift).
    prior_rad : float
        Prior standard deviation of the offset.
    min_votes : int
        Straight steps before the building's orientation is used.
    """

    straight_rad: float = math.radians(10.0)
    window_steps: int = 4
    gate_rad: float = math.radians(15.0)
    sigma_rad: float = math.radians(4.0)
    drift_rad_per_step: float = math.radians(0.3)
    prior_rad: float = math.radians(30.0)
    min_votes: int = 8

    def __post_init__(self) -> None:
        for f in fields(self):
            v = float(getattr(self, f.name))
            if not math.isfinite(v) or v <= 0:
                raise ValueError(f"DominantDirectionsConfig: {f.name} must be a positive finite number, got {v!r}")

    def to_dict(self) -> dict[str, float]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> DominantDirectionsConfig:
        return cls(**{k: (int(v) if k in ("window_steps", "min_votes") else float(v)) for k, v in d.items()})


class DominantDirections:
    """The building's dominant directions and the heading's offset to them (see the module docstring)."""

    def __init__(self, config: DominantDirectionsConfig | None = None) -> None:
        self.config = config or DominantDirectionsConfig()
        self.offset = 0.0  # [rad] added to the heading
        self.var = self.config.prior_rad ** 2
        self.vote = 0j  # sum of exp(4 i compass direction) of straight steps
        self.votes = 0
        self._recent: list[float] = []  # the last headings (straightness)
        self.locked = False  # the last step was straight along a dominant direction

    @property
    def orientation_rad(self) -> float:
        """The building's orientation modulo 90 degrees (NaN before any vote)."""
        return cmath.phase(self.vote) / 4.0 if self.votes else math.nan

    def step(self, heading_rad: float, compass_rad: float, walking: bool = True) -> float:
        """One step's heading [rad] and compass walking direction [rad] (NaN: none); ``walking``: the step is part
        of a steady gait (a device waved about or shuffled with makes steps that are not a walk along anything).
        Returns the corrected heading."""
        c = self.config
        self.locked = False
        if not walking:
            self._recent.clear()
            self.var += c.drift_rad_per_step ** 2
            return _wrap(heading_rad + self.offset)
        self._recent.append(heading_rad)
        if len(self._recent) > c.window_steps + 1:
            del self._recent[0]
        self.var += c.drift_rad_per_step ** 2
        straight = len(self._recent) > c.window_steps and abs(_wrap(heading_rad - self._recent[0])) < c.straight_rad
        if straight and math.isfinite(compass_rad):
            self.vote += cmath.exp(4j * compass_rad)
            self.votes += 1
            if self.votes >= c.min_votes:
                th = self.orientation_rad
                h = heading_rad + self.offset
                axis = th + round((h - th) / (math.pi / 2.0)) * (math.pi / 2.0)
                nu = _wrap(axis - heading_rad - self.offset)
                if abs(nu) < c.gate_rad:
                    self.locked = True
                    k = self.var / (self.var + c.sigma_rad ** 2)
                    self.offset = _wrap(self.offset + k * nu)
                    self.var *= 1.0 - k
        return _wrap(heading_rad + self.offset)

    def get_state(self) -> dict[str, Any]:
        return {"config": self.config.to_dict(), "offset": self.offset, "var": self.var,
                "vote": [self.vote.real, self.vote.imag], "votes": self.votes, "recent": list(self._recent),
                "locked": self.locked}

    @classmethod
    def from_state(cls, d: dict[str, Any]) -> DominantDirections:
        obj = cls(DominantDirectionsConfig.from_dict(d["config"]))
        obj.offset, obj.var = float(d["offset"]), float(d["var"])
        obj.vote, obj.votes = complex(float(d["vote"][0]), float(d["vote"][1])), int(d["votes"])
        obj._recent = [float(x) for x in d["recent"]]
        obj.locked = bool(d["locked"])
        return obj
