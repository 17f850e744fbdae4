"""Step length of a step-and-heading device (phone, watch) and its per-user calibration from known distances.

Models (``d`` [m] per step; :mod:`models.step_length` holds the regressors):

* ``"weinberg"`` — 000 eq. (35): ``d = K (a_max - a_min)^(1/4)`` with ``a_max``, ``a_min`` the peak and valley
  of the filtered specific-force magnitude over the step (:mod:`models.step_detector`);
* ``"height_freq"`` — 003 eq. (28): ``d = h (j f + l) + q`` with the user's height ``h`` and step frequency ``f``;
  ``j``, ``l``, ``q`` are population values for steps of a hand-held phone (:data:`HEIGHT_FREQ`: the smartphone
  PDR model of Tian et al., IEEE Sensors J. 2016, ``d = 0.7 + 0.371 (h - 1.75) + 0.227 (f - 1.79) h / 1.75``,
  rewritten in eq. 28's form; :func:`models.step_length.default_prior` holds a foot *stride's*) and one scale
  ``K`` (``d = K h (j f + l) + q``, ``K = 1`` for a new user) is what a known distance calibrates.

A new user's ``K``: the configured population value, or, for the Weinberg model with a height given, ``K =
0.415 h / (a_max - a_min)^(1/4)_typ``: the step length of 0.415 times the body height of the classic
anthropometric rule (Dean 1965, men 0.415, women 0.413) over the typical Weinberg feature of a hand-held phone
(1.28, the median over the IPIN 2023 dev trials).

Calibration from any known distance (a user-entered distance, a foot-sensor session of the same user, a GNSS
stretch outdoors): the steps walked over it give ``K_obs = distance / sum of the model's unscaled lengths``,
merged with the current ``K`` by their precisions (a stretch's relative error ``distance_rel_std`` plus the
per-step scatter averaged over its steps). The result lives in the profile per placement.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields
from typing import Any

import numpy as np

__all__ = ["StepLengthConfig", "PdrStepLength", "HEIGHT_RATIO", "WEINBERG_FEATURE_TYP", "HEIGHT_FREQ"]

MODELS = ("weinberg", "height_freq")
HEIGHT_RATIO = 0.415  # step length / body height (Dean 1965)
WEINBERG_FEATURE_TYP = 1.28  # typical (a_max - a_min)^(1/4) of a hand-held phone [(m/s^2)^(1/4)]
# 003 eq. (28) j [1/Hz], l [-], q [m] of a step: 0.227 / 1.75, 0.371 - 0.227 * 1.79 / 1.75, 0.7 - 0.371 * 1.75
HEIGHT_FREQ = (0.227 / 1.75, 0.371 - 0.227 * 1.79 / 1.75, 0.7 - 0.371 * 1.75)


@dataclass(frozen=True)
class StepLengthConfig:
    """Parameters of the step length (units in the names).

    Attributes
    ----------
    model : {"weinberg", "height_freq"}
    weinberg_k : float
        Population Weinberg constant [m per (m/s^2)^(1/4)] for a user without height or calibration.
    height_m : float
        The user's height [m]; 0 when not given.
    k_rel_std : float
        Relative uncertainty of a new user's ``K`` [-].
    step_rel_std : float
        Relative scatter of one step's length about the model [-] (its mean over a stretch of n steps has
        ``step_rel_std / sqrt(n)``).
    min_steps : int
        A known distance needs at least this many steps to calibrate.
    """

    model: str = "weinberg"
    weinberg_k: float = 0.45
    height_m: float = 0.0
    k_rel_std: float = 0.10
    step_rel_std: float = 0.10
    min_steps: int = 10

    def __post_init__(self) -> None:
        if self.model not in MODELS:
            raise ValueError(f"StepLengthConfig: model must be one of {MODELS}, got {self.model!r}")
        for f in fields(self):
            if f.name == "model":
                continue
            v = float(getattr(self, f.name))
            if not math.isfinite(v) or v < 0:
                raise ValueError(f"StepLengthConfig: {f.name} must be a finite non-negative number, got {v!r}")
        if self.weinberg_k <= 0:
            raise ValueError("StepLengthConfig: weinberg_k must be positive")
        if self.model == "height_freq" and not 0.5 <= self.height_m <= 2.5:
            raise ValueError(f"StepLengthConfig: the height_freq model needs height_m within 0.5-2.5 m, got {self.height_m}")
        if self.height_m and not 0.5 <= self.height_m <= 2.5:
            raise ValueError(f"StepLengthConfig: height_m must be within 0.5-2.5 m (or 0: not given), got {self.height_m}")

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> StepLengthConfig:
        return cls(**{**d, "min_steps": int(d.get("min_steps", 10))})


class PdrStepLength:
    """One user's step length for one placement, and its calibration.

    Parameters
    ----------
    config : StepLengthConfig
    calibration : dict, optional
        ``{"k": K, "k_var": var, "n_steps": n, "distance_m": m}`` from a profile (:meth:`calibration`).
    """

    def __init__(self, config: StepLengthConfig, calibration: dict[str, Any] | None = None) -> None:
        self.config = config
        self.k, self.k_var = self._new_user_k()
        self.n_steps = 0
        self.distance_m = 0.0
        if calibration:
            k, var = float(calibration["k"]), float(calibration["k_var"])
            if not (math.isfinite(k) and k > 0 and math.isfinite(var) and var > 0):
                raise ValueError(f"step length calibration: k and k_var must be positive finite numbers, got {k!r}, {var!r}")
            self.k, self.k_var = k, var
            self.n_steps = int(calibration.get("n_steps", 0))
            self.distance_m = float(calibration.get("distance_m", 0.0))

    def _new_user_k(self) -> tuple[float, float]:
        c = self.config
        if c.model == "height_freq":
            k = 1.0
        elif c.height_m > 0:
            k = HEIGHT_RATIO * c.height_m / WEINBERG_FEATURE_TYP
        else:
            k = c.weinberg_k
        return k, (c.k_rel_std * k) ** 2

    @property
    def calibrated(self) -> bool:
        return self.n_steps > 0

    def unscaled(self, a_max: float, a_min: float, f_hz: float) -> float:
        """The model's step length for ``K = 1`` [m]."""
        if self.config.model == "weinberg":
            return max(a_max - a_min, 0.0) ** 0.25  # 000 eq. (35)
        j, l_, _ = HEIGHT_FREQ
        f = f_hz if math.isfinite(f_hz) and f_hz > 0 else 1.79
        return self.config.height_m * (j * f + l_)  # 003 eq. (28) without q

    def _offset(self) -> float:
        return HEIGHT_FREQ[2] if self.config.model == "height_freq" else 0.0

    def length(self, a_max: float, a_min: float, f_hz: float) -> float:
        """Step length [m] of one step."""
        return max(self.k * self.unscaled(a_max, a_min, f_hz) + self._offset(), 0.0)

    def calibrate(self, distance_m: float, unscaled: np.ndarray) -> dict[str, float]:
        """Merge a known distance [m] walked over steps whose unscaled lengths are ``unscaled``; returns what was
        observed and the new ``K``.

        Raises
        ------
        ValueError
            Distance not positive and finite, too few steps.
        """
        u = np.asarray(unscaled, dtype=float)
        if not (math.isfinite(distance_m) and distance_m > 0):
            raise ValueError(f"distance_m: must be a positive number of metres, got {distance_m!r}")
        if u.size < self.config.min_steps:
            raise ValueError(f"steps: {u.size} steps over the distance; at least {self.config.min_steps} needed")
        n = u.size
        k_obs = (distance_m - n * self._offset()) / float(np.sum(u))
        var_obs = (k_obs * self.config.step_rel_std) ** 2 / n
        w = self.k_var / (self.k_var + var_obs)
        self.k += w * (k_obs - self.k)
        self.k_var = self.k_var * var_obs / (self.k_var + var_obs)
        self.n_steps += n
        self.distance_m += float(distance_m)
        return {"k_observed": k_obs, "k": self.k, "k_std": math.sqrt(self.k_var), "steps": n}

    def calibration(self) -> dict[str, float]:
        return {"k": self.k, "k_var": self.k_var, "n_steps": self.n_steps, "distance_m": self.distance_m}

    def get_state(self) -> dict[str, Any]:
        return {"config": self.config.to_dict(), **self.calibration()}

    @classmethod
    def from_state(cls, d: dict[str, Any]) -> PdrStepLength:
        obj = cls(StepLengthConfig.from_dict(d["config"]))
        obj.k, obj.k_var, obj.n_steps, obj.distance_m = float(d["k"]), float(d["k_var"]), int(d["n_steps"]), float(d["distance_m"])
        return obj
