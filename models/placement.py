"""Where the device is carried: the placement that decides the navigation pipeline (DESIGN.md, "Placement").

``foot`` (a shoe-mounted IMU: ZUPT-KF / Gait-DR), ``phone-hand`` (held in front: the device's forward axis is
the walking direction), ``phone-pocket`` (a trouser pocket or a swinging hand: the axes say nothing, the
horizontal acceleration's principal direction does) and ``watch`` (a wrist: the arm swings, as a pocket).

A client says the placement, or the engine recognises it. Only what a device kind can be is recognised: a foot
sensor is on the foot and a watch on the wrist; a phone is in the hand or in a pocket (or swinging), told apart
step by step by how steady its tilt is and how fast it turns: held in front, the tilt wobbles by a few degrees
(mean resultant length of the body's down direction over a step above 0.99 on every IPIN 2023 dev trial) and
the phone turns slowly (0.3 rad/s mean walking); a thigh or a swinging arm swings by +-20-40 degrees per stride
(resultant length 0.94-0.97) at 1-3 rad/s. A change is taken after ``confirm_steps`` consecutive steps of the
other kind, so a phone briefly raised or lowered does not flip the pipeline.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

__all__ = ["PLACEMENTS", "STEP_AND_HEADING", "DEVICE_PLACEMENTS", "RECOGNISED", "PlacementConfig",
           "PlacementRecognizer", "default_placement", "check_placement", "FootCheck", "check_foot", "STRIDE_LIKE_MIN",
           "MIN_GAIT_S"]

PLACEMENTS: tuple[str, ...] = ("foot", "phone-hand", "phone-pocket", "watch")
STEP_AND_HEADING: tuple[str, ...] = ("phone-hand", "phone-pocket", "watch")
# where each device kind can be carried (the first: the default when the client does not say); a phone strapped to a
# shoe is a foot sensor (the Sensor Logger route's use)
DEVICE_PLACEMENTS: dict[str, tuple[str, ...]] = {"foot": ("foot",), "phone": ("phone-hand", "phone-pocket", "foot"),
                                                 "watch": ("watch",)}
# what the step-and-heading engine tells apart by itself, per device kind
RECOGNISED: dict[str, tuple[str, ...]] = {"phone": ("phone-hand", "phone-pocket")}


def check_placement(placement: str) -> str:
    """``placement`` itself, or a ValueError naming the known ones."""
    if placement not in PLACEMENTS:
        raise ValueError(f"placement: expected one of {', '.join(PLACEMENTS)}, got {placement!r}")
    return placement


def default_placement(device_kind: str) -> str:
    """The placement a session of ``device_kind`` starts with when the client does not say."""
    try:
        return DEVICE_PLACEMENTS[device_kind][0]
    except KeyError:
        raise ValueError(f"device_kind: expected one of {', '.join(DEVICE_PLACEMENTS)}, got {device_kind!r}") from None


@dataclass(frozen=True)
class PlacementConfig:
    """Thresholds of :class:`PlacementRecognizer`.

    Attributes
    ----------
    steady_tilt : float
        A step whose body-down resultant length is at least this was held steadily (in front).
    slow_rate_rad_s : float
        ... and whose mean angular rate is below this [rad/s] (when the gyroscope was on).
    confirm_steps : int
        Consecutive steps of the other placement before a change is taken.
    """

    steady_tilt: float = 0.985
    slow_rate_rad_s: float = 1.0
    confirm_steps: int = 8

    def __post_init__(self) -> None:
        if not 0.0 < self.steady_tilt < 1.0:
            raise ValueError(f"PlacementConfig: steady_tilt must be within (0, 1), got {self.steady_tilt!r}")
        if not self.slow_rate_rad_s > 0 or int(self.confirm_steps) < 1:
            raise ValueError("PlacementConfig: slow_rate_rad_s must be positive and confirm_steps >= 1")

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


class PlacementRecognizer:
    """Recognises a phone's placement step by step (see the module docstring).

    Parameters
    ----------
    device_kind : {"phone", "watch"}
    placement : str, optional
        Given by the client: then it is not recognised (``fixed``); a step-and-heading placement.
    config : PlacementConfig
    """

    def __init__(self, device_kind: str, placement: str | None = None, config: PlacementConfig | None = None) -> None:
        self.config = config or PlacementConfig()
        self.device_kind = device_kind
        self.fixed = placement is not None
        self.placement = check_placement(placement) if placement is not None else default_placement(device_kind)
        if self.placement not in STEP_AND_HEADING:
            raise ValueError(f"placement: {self.placement!r} is not navigated by step and heading")
        self._other = 0  # consecutive steps that looked like the other placement

    def step(self, tilt_r: float, rate_rad_s: float) -> str | None:
        """One step's tilt steadiness and mean angular rate (NaN: gyroscope off); returns the new placement when
        it changes, else None."""
        if self.fixed or len(RECOGNISED.get(self.device_kind, ())) < 2:
            return None
        swinging = tilt_r < self.config.steady_tilt or (math.isfinite(rate_rad_s) and rate_rad_s > self.config.slow_rate_rad_s)
        looks = "phone-pocket" if swinging else "phone-hand"
        if looks == self.placement:
            self._other = 0
            return None
        self._other += 1
        if self._other < self.config.confirm_steps:
            return None
        self._other = 0
        self.placement = looks
        return looks

    def get_state(self) -> dict[str, Any]:
        return {"device_kind": self.device_kind, "placement": self.placement, "fixed": self.fixed, "other": self._other,
                "config": self.config.to_dict()}

    @classmethod
    def from_state(cls, d: dict[str, Any]) -> PlacementRecognizer:
        obj = cls(str(d["device_kind"]), None, PlacementConfig(**d["config"]))
        obj.placement, obj.fixed, obj._other = str(d["placement"]), bool(d["fixed"]), int(d["other"])
        return obj

# ------------------------------------------------------------------------------- does it look like a foot?
# Does a recording look like a foot? The stance phases of a walking or running foot, at a stride's rhythm.
#
# A foot rests flat on the ground once per stride (0.6-1.8 s apart), with the swing's fast rotation between: the
# ZUPT-KF's stance detector (:class:`models.zupt_nav.ZuptNavigator`) finds them at that rhythm. A phone in the hand
# or a pocket, or a wrist, is never still like that while its wearer walks: the detector fires at random, brief moments.
# Measured (``STRIDE_LIKE_MIN``): the fraction of consecutive detected stances 0.6-1.8 s apart is at least 0.50 on
# every walking or running foot of the development recordings (42 VICON trials' walks and runs, 26 gdin walks,
# gaitmap's feet and stairs: 0.50-0.94) and at most 0.35 on the 16 hand-held phone recordings of IPIN 2023 (0.17-0.33);
# a foot that does not walk (in-place foot lifts, crawling: VICON 0.22-0.49) does not look like a walking foot either.
# Judged only with at least ``MIN_GAIT_S`` of motion (2.5-s windows whose |a| varies by more than 1 m/s^2).
STRIDE_LIKE_MIN = 0.40  # fraction of stance intervals of a stride's length a walking foot has at least
MIN_GAIT_S = 20.0  # s of motion needed to judge
_WINDOW_S = 2.5  # s
_MOTION_STD = 1.0  # m/s^2
_STRIDE_S = (0.6, 1.8)  # s, stance-to-stance interval of one foot's stride


@dataclass(frozen=True)
class FootCheck:
    """Result of :func:`check_foot`.

    Attributes
    ----------
    gait_s : float
        Time in motion [s] (2.5-s windows whose |a| has a standard deviation above 1 m/s^2).
    stances : int
        Stances the ZUPT-KF's detector found.
    stride_like : float
        Fraction of consecutive stances 0.6-1.8 s apart (NaN with fewer than two).
    looks_like_foot : bool or None
        False: no stance phases at a stride's rhythm; None: too little motion to judge.
    reason : str
        One sentence saying what was measured.
    """

    gait_s: float
    stances: int
    stride_like: float
    looks_like_foot: bool | None
    reason: str


def check_foot(t_s: np.ndarray, acc: np.ndarray, gyr: np.ndarray) -> FootCheck:
    """Judge a recording (``t_s`` [s], ``acc`` [m/s^2], ``gyr`` [rad/s], (N, 3), one time axis)."""
    from models.zupt_nav import ZuptNavigator

    t = np.asarray(t_s, dtype=float)
    a = np.asarray(acc, dtype=float)
    n = np.linalg.norm(a, axis=1)
    gait = 0.0
    edges = np.searchsorted(t, np.arange(t[0], t[-1] + _WINDOW_S, _WINDOW_S))
    for i0, i1 in zip(edges[:-1], edges[1:]):
        if i1 - i0 >= 10 and float(np.std(n[i0:i1])) > _MOTION_STD:
            gait += _WINDOW_S
    out = ZuptNavigator().run(t - t[0], a, np.asarray(gyr, dtype=float))
    ts = np.array([s.t_end_s for s in out.stances])
    iv = np.diff(ts)
    frac = float(np.mean((iv >= _STRIDE_S[0]) & (iv <= _STRIDE_S[1]))) if iv.size else float("nan")
    if gait < MIN_GAIT_S:
        return FootCheck(gait, len(ts), frac, None, f"{gait:.0f} s of motion: too little to tell a foot")
    ok = bool(iv.size and frac >= STRIDE_LIKE_MIN)
    what = (f"{len(ts)} stance phases in {gait:.0f} s of motion, {frac:.0%} of them a stride apart "
            f"({_STRIDE_S[0]:g}-{_STRIDE_S[1]:g} s)" if iv.size else f"no stance phase in {gait:.0f} s of motion")
    if ok:
        return FootCheck(gait, len(ts), frac, True, f"{what}: a walking foot")
    return FootCheck(gait, len(ts), frac, False, f"{what}; a walking or running foot has a stance every stride "
                     f"(at least {STRIDE_LIKE_MIN:.0%} of them a stride apart): this does not look like a foot "
                     "(a hand-held phone, a pocket, a wrist), or the foot did not walk")
