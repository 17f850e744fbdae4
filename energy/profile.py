"""Per-user calibration profile: what the engine learned about a person's gait, per behaviour.

Stored by the server per user and behaviour, handed to new sessions so a returning user with a calibrated
behaviour resumes in Gait-DR after a short examination instead of a full initialisation (004 Table 2).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, fields
from typing import Any

__all__ = ["BehaviourCalibration", "Profile", "PROFILE_BEHAVIOURS"]

# "pdr": the step-and-heading engines' calibration (energy.phone_engine: step length per placement)
PROFILE_BEHAVIOURS: tuple[str, ...] = ("walk", "run", "pdr")
_VERSION = 1


@dataclass
class BehaviourCalibration:
    """Calibration of one behaviour.

    Parameters
    ----------
    step_model : dict
        Serialised step-length model (models.step_length), opaque here.
    sigma_d_m : float
        Prior precision of the step-length model (004 Table 3) [m].
    heading_deviation_rad : float
        Gait heading deviation, moving direction minus foot heading (004 eq. 16) [rad].
    heading_deviation_var : float
        Its variance [rad^2].
    n_steps : int
        Steps the calibration is based on.
    calibrated : bool
        Whether the behaviour may run in Gait-DR.
    """

    step_model: dict[str, Any] = field(default_factory=dict)
    sigma_d_m: float = float("nan")
    heading_deviation_rad: float = 0.0
    heading_deviation_var: float = float("nan")
    n_steps: int = 0
    calibrated: bool = False

    def to_dict(self, copy: bool = True) -> dict[str, Any]:
        """As plain data; ``copy=False`` shares the nested values (for immediate serialisation only)."""
        return asdict(self) if copy else {f.name: getattr(self, f.name) for f in fields(self)}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> BehaviourCalibration:
        if not isinstance(d, dict):
            raise ValueError("behaviour calibration must be an object")
        known = {"step_model", "sigma_d_m", "heading_deviation_rad", "heading_deviation_var", "n_steps", "calibrated"}
        unknown = set(d) - known
        if unknown:
            raise ValueError(f"unknown calibration fields {sorted(unknown)}")
        obj = cls(**d)
        if not isinstance(obj.step_model, dict):
            raise ValueError("step_model must be an object")
        obj.n_steps = int(obj.n_steps)
        if obj.n_steps < 0:
            raise ValueError("n_steps must be >= 0")
        obj.calibrated = bool(obj.calibrated)
        return obj


@dataclass
class Profile:
    """All behaviours' calibrations of one user."""

    behaviours: dict[str, BehaviourCalibration] = field(default_factory=dict)

    def get(self, behaviour: str) -> BehaviourCalibration | None:
        return self.behaviours.get(behaviour)

    def is_calibrated(self, behaviour: str) -> bool:
        cal = self.behaviours.get(behaviour)
        return bool(cal and cal.calibrated)

    def to_dict(self, copy: bool = True) -> dict[str, Any]:
        """As plain data; ``copy=False`` shares the nested values (for immediate serialisation only)."""
        return {"version": _VERSION, "behaviours": {k: v.to_dict(copy) for k, v in sorted(self.behaviours.items())}}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Profile:
        """Parse and validate; raises ``ValueError`` naming the problem."""
        if not isinstance(d, dict):
            raise ValueError("profile must be an object")
        if d.get("version", _VERSION) != _VERSION:
            raise ValueError(f"profile version {d.get('version')!r} is not supported (expected {_VERSION})")
        raw = d.get("behaviours", {})
        if not isinstance(raw, dict):
            raise ValueError("profile.behaviours must be an object")
        out: dict[str, BehaviourCalibration] = {}
        for name, cal in raw.items():
            if name not in PROFILE_BEHAVIOURS:
                raise ValueError(f"profile.behaviours: unknown behaviour {name!r} (expected one of {PROFILE_BEHAVIOURS})")
            try:
                out[name] = BehaviourCalibration.from_dict(cal)
            except (TypeError, ValueError) as exc:
                raise ValueError(f"profile.behaviours.{name}: {exc}") from None
        return cls(out)
