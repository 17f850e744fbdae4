"""Which engine serves a session: the placement decides the pipeline (DESIGN.md, "Placement").

``foot``: :class:`energy.engine.Engine` (ZUPT-KF / Gait-DR); ``phone-hand``, ``phone-pocket``, ``watch`` (and a
phone whose placement is to be recognised): :class:`energy.phone_engine.PhoneEngine` (step and heading). Both
keep the same contract; a stored state says which engine it is (:func:`engine_from_bytes`). The modes keep the
foot engine's names where they mean the same thing to a phone: ``zupt`` (every sensor always on) is the phone's
``always-on``, ``pdr`` and ``auto`` its energy-aware ``auto``.

The user's profile holds both kinds of calibration (``walk``/``run`` of the foot, ``pdr`` of the step-and-heading
engines); each engine gets only its own (:func:`profile_for`).
"""

from __future__ import annotations

import datetime as _dt
from dataclasses import dataclass
from typing import Any

from energy import codec
from models.placement import DEVICE_PLACEMENTS, PLACEMENTS

__all__ = ["EngineSpec", "new_engine", "engine_class", "engine_from_bytes", "engine_from_state", "profile_for",
           "phone_mode", "check_spec", "FOOT_BEHAVIOURS"]

FOOT_BEHAVIOURS: tuple[str, ...] = ("walk", "run")
_PHONE_MODES = {"auto": "auto", "pdr": "auto", "zupt": "always-on", "always-on": "always-on"}


@dataclass(frozen=True)
class EngineSpec:
    """What a session's engine is built for.

    Attributes
    ----------
    device_kind : {"foot", "phone", "watch"}
    placement : str or None
        Given by the client; None: recognised by the engine (a phone: hand or pocket).
    anchor : (latitude_deg, longitude_deg, altitude_m) or None
        The session's geodetic start (magnetic declination there); None: headings refer to magnetic north.
    date : datetime.date or None
        Date of the session (World Magnetic Model).
    """

    device_kind: str = "foot"
    placement: str | None = "foot"
    anchor: tuple[float, float, float] | None = None
    date: _dt.date | None = None

    @property
    def pipeline(self) -> str:
        """``foot`` or ``step-and-heading`` (a device whose placement is recognised: step and heading)."""
        if self.placement is None:
            return "foot" if self.device_kind == "foot" else "step-and-heading"
        return "foot" if self.placement == "foot" else "step-and-heading"


def check_spec(device_kind: str, placement: str | None) -> None:
    """ValueError naming the problem when ``placement`` is unknown or impossible for ``device_kind``."""
    if device_kind not in DEVICE_PLACEMENTS:
        raise ValueError(f"device_kind: expected one of {', '.join(DEVICE_PLACEMENTS)}, got {device_kind!r}")
    if placement is None:
        return
    if placement not in PLACEMENTS:
        raise ValueError(f"placement: expected one of {', '.join(PLACEMENTS)}, got {placement!r}")
    if placement not in DEVICE_PLACEMENTS[device_kind]:
        raise ValueError(f"placement: a {device_kind} is carried as {' or '.join(DEVICE_PLACEMENTS[device_kind])}, "
                         f"not {placement!r}")


def phone_mode(mode: str) -> str:
    """The step-and-heading engine's mode for an engine mode name (see the module docstring)."""
    try:
        return _PHONE_MODES[mode]
    except KeyError:
        raise ValueError(f"mode: expected one of {sorted(_PHONE_MODES)}, got {mode!r}") from None


def profile_for(profile: dict[str, Any] | None, pipeline: str) -> dict[str, Any] | None:
    """The part of a user's profile an engine of ``pipeline`` (``foot`` / ``step-and-heading``) takes."""
    if not profile:
        return None
    from energy.phone_engine import PROFILE_KEY

    keep = FOOT_BEHAVIOURS if pipeline == "foot" else (PROFILE_KEY,)
    behaviours = {b: c for b, c in (profile.get("behaviours") or {}).items() if b in keep}
    return {**profile, "behaviours": behaviours} if behaviours else None


def engine_class(spec: EngineSpec) -> Any:
    """The engine class of ``spec``'s pipeline (its ``NORTH_REFERENCE`` says what north its positions have)."""
    if spec.pipeline == "foot":
        from energy.engine import Engine

        return Engine
    from energy.phone_engine import PhoneEngine

    return PhoneEngine


def new_engine(mode: str, profile: dict[str, Any] | None = None, spec: EngineSpec | None = None,
               trace: bool = False) -> Any:
    """A fresh engine for ``spec`` (default: a foot sensor), with the part of ``profile`` it takes."""
    spec = spec or EngineSpec()
    check_spec(spec.device_kind, spec.placement)
    if spec.pipeline == "foot":
        from energy.engine import Engine

        return Engine(mode=mode, profile=profile_for(profile, "foot"), trace=trace)  # type: ignore[arg-type]
    from energy.phone_engine import PhoneEngine

    return PhoneEngine(mode=phone_mode(mode), profile=profile_for(profile, "step-and-heading"),
                       device_kind=spec.device_kind, placement=spec.placement, anchor=spec.anchor, date=spec.date,
                       trace=trace)


def engine_from_state(d: dict[str, Any], trace: bool = False) -> Any:
    """The engine a decoded state belongs to."""
    if d.get("engine") == "step-and-heading":
        from energy.phone_engine import PhoneEngine

        return PhoneEngine.from_state(d, trace=trace)
    from energy.engine import Engine

    return Engine.from_state(d, trace=trace)


def engine_from_bytes(blob: bytes, trace: bool = False) -> Any:
    """Restore whichever engine ``blob`` (``to_bytes``) holds."""
    return engine_from_state(codec.loads(blob), trace=trace)
