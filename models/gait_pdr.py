"""Gait dead reckoning: one position per step from step length and walking direction (004 eq. 14, 16).

``GaitDeadReckoner`` advances a NED position by ``d_k [cos gamma_k, sin gamma_k]`` with
``gamma_k = psi_k + delta_gamma`` (004 eq. 16; eq. 14 writes x east, y north). ``compensate=False`` is the
"conventional PDR" of 004 Table 6: the heading is used as the walking direction (no KF II); pair it with
the generic step model (:func:`models.step_length.default_prior`) for the full baseline.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["PdrStep", "GaitDeadReckoner"]


@dataclass(frozen=True)
class PdrStep:
    """One dead-reckoned step.

    Attributes
    ----------
    t_s : float
        Step time [s] (stance onset).
    position : tuple of float
        NED position after the step [m] (down is carried unchanged).
    heading : float
        Sensor heading psi at the step [rad].
    direction : float
        Walking direction gamma used [rad] (004 eq. 16).
    length : float
        Step length [m].
    behaviour : str
        Behaviour label of the step (``"walk"``, ``"run"``, ...).
    """

    t_s: float
    position: tuple[float, float, float]
    heading: float
    direction: float
    length: float
    behaviour: str


class GaitDeadReckoner:
    """Per-step position integration, 004 eq. (14) and (16).

    Parameters
    ----------
    position : array-like, shape (3,)
        Start position, NED [m] (e.g. the ZUPT-KF position at the hand-over stance).
    compensate : bool
        Apply the heading deviation (Gait-PDR) or not (conventional PDR).
    """

    def __init__(self, position: np.ndarray | tuple[float, float, float] = (0.0, 0.0, 0.0),
                 compensate: bool = True) -> None:
        self.position = np.asarray(position, dtype=np.float64).reshape(3).copy()
        self.compensate = bool(compensate)
        self.distance = 0.0
        self.n_steps = 0

    def step(self, t_s: float, length: float, heading: float, deviation: float = 0.0,
             behaviour: str = "walk") -> PdrStep:
        """Advance by one step.

        Parameters
        ----------
        t_s : float
            Step time [s].
        length : float
            Step length d_k [m].
        heading : float
            Sensor heading psi_k at heel strike [rad], clockwise from north.
        deviation : float
            Heading deviation delta_gamma [rad] from KF II (ignored when ``compensate`` is False).
        behaviour : str
            Behaviour label carried to the output.
        """
        gamma = heading + (deviation if self.compensate else 0.0)  # 004 eq. (16)
        gamma = math.atan2(math.sin(gamma), math.cos(gamma))
        self.position[0] += length * math.cos(gamma)  # 004 eq. (14): north = y
        self.position[1] += length * math.sin(gamma)  # east = x
        self.distance += abs(length)
        self.n_steps += 1
        return PdrStep(float(t_s), (float(self.position[0]), float(self.position[1]), float(self.position[2])),
                       float(heading), float(gamma), float(length), behaviour)

    def get_state(self) -> dict:
        """Plain-data state for ``energy.codec``."""
        return {"position": self.position.copy(), "compensate": self.compensate, "distance": self.distance,
                "n_steps": self.n_steps}

    @classmethod
    def from_state(cls, d: dict) -> GaitDeadReckoner:
        """Rebuild from :meth:`get_state` output."""
        obj = cls(np.asarray(d["position"], dtype=np.float64), bool(d["compensate"]))
        obj.distance = float(d["distance"])
        obj.n_steps = int(d["n_steps"])
        return obj
