"""Magnetic field: expected-field reference (rest period or WMM) and the disturbance test.

Units: uT everywhere (the ``ahrs`` WMM returns nT and is converted here).
"""

from __future__ import annotations

import datetime as _dt

import numpy as np

__all__ = ["reference_from_rest", "wmm_reference", "field_undisturbed", "inclination"]


def inclination(field_ned: np.ndarray) -> np.ndarray:
    """Dip angle [rad] of NED field vector(s): positive when the field points down."""
    m = np.asarray(field_ned, dtype=np.float64)
    return np.arctan2(m[..., 2], np.hypot(m[..., 0], m[..., 1]))


def reference_from_rest(mag_mean_body: np.ndarray, c_bn: np.ndarray) -> np.ndarray:
    """Expected field in NED [uT] from the mean body field [uT] at rest and the body-to-NED DCM."""
    m = np.asarray(mag_mean_body, dtype=np.float64).reshape(3)
    if not np.all(np.isfinite(m)) or not 5.0 < np.linalg.norm(m) < 200.0:
        raise ValueError(f"mag_mean_body: expected a finite field of 5-200 uT, got {m}")
    return np.asarray(c_bn, dtype=np.float64) @ m


def wmm_reference(
    latitude_deg: float, longitude_deg: float, height_km: float = 0.0, date: _dt.date | None = None
) -> np.ndarray:
    """Earth field in NED [uT] from the World Magnetic Model (``ahrs.utils.WMM``, which works in nT)."""
    from ahrs.utils import WMM

    if not (-90.0 <= latitude_deg <= 90.0 and -180.0 <= longitude_deg <= 360.0):
        raise ValueError(f"latitude/longitude out of range: {latitude_deg}, {longitude_deg}")
    d = date or _dt.date(2025, 1, 1)
    w = WMM(date=d, latitude=latitude_deg, longitude=longitude_deg, height=height_km)
    return np.array([w.X, w.Y, w.Z], dtype=np.float64) / 1000.0


def field_undisturbed(
    field_ned: np.ndarray,
    reference_ned: np.ndarray,
    magnitude_tol_ut: float = 3.0,
    inclination_tol_rad: float = float(np.radians(3.0)),
) -> np.ndarray:
    """Disturbance test: magnitude (002 eq. 4-5, 000 eq. 68) and inclination close to the reference.

    Parameters
    ----------
    field_ned : (..., 3) measured field rotated to NED [uT]; reference_ned : (3,) [uT].
    Returns a boolean (array): True where the field may be used for heading.
    """
    m = np.asarray(field_ned, dtype=np.float64)
    ref = np.asarray(reference_ned, dtype=np.float64)
    dmag = np.abs(np.linalg.norm(m, axis=-1) - np.linalg.norm(ref))
    dinc = np.abs(inclination(m) - inclination(ref))
    return (dmag < magnitude_tol_ut) & (dinc < inclination_tol_rad)
