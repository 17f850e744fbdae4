"""A building's dominant directions learnt from the walk's own compass (003 Section 6.1, its refs [41], [44]-[46]).

People walk straight along a building's walls, and a building's walls run in two perpendicular directions. While
the walker goes straight (the heading changed less than ``straight_rad`` over the last ``window_steps`` steps),
every step's compass walking direction votes for the building's orientation modulo 90 degrees (the circular mean
of four times the angle): the compass errs by place, but over many places its errors average out, whereas a
single place's error is what the heading inherits. Once ``min_votes`` straight steps of a steady gait have voted,
each straight step reports the orientation, and the heading estimator
(:meth:`models.heading.HeadingEstimator.update_dominant`) pulls a heading within ``gate_rad`` of one of the four
directions onto it with the noise ``sigma_rad`` (heuristic drift elimination); steps off them (a diagonal
corridor, a gentle curve) are left alone.

The foot engine learns its directions inside the ZUPT-KF (the first straight segment's heading, in its session
frame); a phone's heading is absolute (magnetic north) and its first segment's heading carries that one place's
compass error, which the votes of many places average out.
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
    min_votes : int
        Straight steps before the building's orientation is used.
    """

    straight_rad: float = math.radians(10.0)
    window_steps: int = 4
    gate_rad: float = math.radians(15.0)
    sigma_rad: float = math.radians(4.0)
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
    """The building's orientation modulo 90 degrees, voted by straight steps (see the module docstring)."""

    def __init__(self, config: DominantDirectionsConfig) -> None:
        self.config = config
        self.vote = 0j  # sum of exp(4 i compass direction) of straight steps
        self.votes = 0
        self._recent: list[float] = []  # the last headings (straightness)

    @property
    def orientation_rad(self) -> float:
        """The building's orientation modulo 90 degrees (NaN before any vote)."""
        return cmath.phase(self.vote) / 4.0 if self.votes else math.nan

    def orientation_std_rad(self, rho: float) -> float:
        """Standard error [rad] of :attr:`orientation_rad` for votes whose compass errors are correlated by ``rho``
        from one step to the next (AR(1)): the votes' circular spread (of four times the angle, ``sqrt(-2 ln R)``
        with ``R`` the mean resultant length, divided by 4) over the square root of the number of independent
        votes, ``n (1 - rho) / (1 + rho)`` (at least one). Infinite before any vote."""
        if not self.votes:
            return math.inf
        r = min(abs(self.vote) / self.votes, 1.0)
        spread = math.sqrt(-2.0 * math.log(max(r, 1e-12))) / 4.0
        n_eff = max(self.votes * (1.0 - rho) / (1.0 + rho), 1.0)
        return spread / math.sqrt(n_eff)

    def step(self, heading_rad: float, compass_rad: float, walking: bool = True) -> float | None:
        """One step's heading [rad] and compass walking direction [rad] (NaN: none); ``walking``: the step is part
        of a steady gait (a device waved about or shuffled with makes steps that are not a walk along anything).
        Returns the building's orientation [rad] when the step is straight and the orientation is known (the
        directions ``ref + k * 90 deg`` the step may be pulled onto), else None."""
        c = self.config
        if not walking:
            self._recent.clear()
            return None
        self._recent.append(heading_rad)
        if len(self._recent) > c.window_steps + 1:
            del self._recent[0]
        straight = len(self._recent) > c.window_steps and abs(_wrap(heading_rad - self._recent[0])) < c.straight_rad
        if not straight:
            return None
        if math.isfinite(compass_rad):
            self.vote += cmath.exp(4j * compass_rad)
            self.votes += 1
        return self.orientation_rad if self.votes >= c.min_votes else None

    def get_state(self) -> dict[str, Any]:
        return {"config": self.config.to_dict(), "vote": [self.vote.real, self.vote.imag], "votes": self.votes,
                "recent": list(self._recent)}

    @classmethod
    def from_state(cls, d: dict[str, Any]) -> DominantDirections:
        obj = cls(DominantDirectionsConfig.from_dict(d["config"]))
        obj.vote, obj.votes = complex(float(d["vote"][0]), float(d["vote"][1])), int(d["votes"])
        obj._recent = [float(x) for x in d["recent"]]
        return obj
