"""A recording: a sensor batch in SI units plus what is known about where it came from and its truth."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from models.batch import SensorBatch

__all__ = ["RecordingMeta", "Truth", "Recording", "require_gyroscope"]


@dataclass(frozen=True)
class RecordingMeta:
    """Provenance of a recording.

    Parameters
    ----------
    source_format : str
        Importer that read it, e.g. ``"vicon-mat"``, ``"sensorconnect-a"``, ``"synthetic"``.
    rate_hz : float
        Nominal accelerometer rate [Hz].
    units_converted : dict of str to str
        Per stream, the conversion applied, e.g. ``{"acc": "g -> m/s^2 (x 9.80665)"}``; empty when the file
        was already SI.
    mount : str
        Where the sensor sat (``"foot"``, ``"phone"``, ``"watch"``) and anything known about its axes.
    notes : tuple of str
        Anything the importer repaired or flagged (logged as well).
    anchor : models.geo.Anchor or None
        Where the recording started, when it says (a phone's first good location fix,
        ``models.geo.anchor_from_fixes``); ``pednav replay`` uses it unless ``--anchor`` is given.
    """

    source_format: str
    rate_hz: float
    units_converted: dict[str, str] = field(default_factory=dict)
    mount: str = "foot"
    notes: tuple[str, ...] = ()
    anchor: Any = None


@dataclass(frozen=True)
class Truth:
    """Ground truth in the form the recording provides; fields are ``None`` where it does not exist.

    Parameters
    ----------
    t_ns : ndarray of int64, shape (K,), optional
        Times of ``positions`` [ns], same clock as the batch.
    positions : ndarray, shape (K, 3), optional
        Reference positions [m] in the truth's own frame (VICON, synthetic: NED).
    extra : dict
        Format-specific truth (gdin ground-control points, stride tables, synthetic behaviour labels ...).
    """

    t_ns: np.ndarray | None = None
    positions: np.ndarray | None = None
    extra: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class Recording:
    """A named recording: samples, metadata and (optional) truth.

    ``aux`` holds what the file records besides the engine's streams and the truth, by name (e.g. GNSS location
    fixes ``"gnss"``, the phone's own orientation ``"ahrs"``, ``"device"`` facts); empty when there is none.
    """

    name: str
    batch: SensorBatch
    meta: RecordingMeta
    truth: Truth | None = None
    aux: dict[str, Any] = field(default_factory=dict)


def require_gyroscope(rec: Recording, spec: str) -> None:
    """``ValueError`` naming ``spec`` when ``rec`` has no gyroscope samples: every engine mode starts on the
    ZUPT-KF, which integrates the gyroscope; without one a replay would end with no position at all and look
    like a success."""
    if len(rec.batch.gyr_t_ns) == 0:
        raise ValueError(f"{spec}: the recording has no gyroscope samples; the engine needs a gyroscope to start "
                         "(record or export the gyroscope too)")
