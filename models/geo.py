"""Geo-referencing: a session's anchor, local NED <-> WGS-84 geodetic, and the World Magnetic Model's
declination that turns the engine's magnetic-north frame into a true-north one.

The engine navigates in local NED with the origin at the session's first stance. Its north is either
**magnetic** north (a filter whose alignment and heading updates take the measured horizontal field as north,
e.g. ``ZuptConfig(mag_on=True)``) or the sensor's **initial heading** (the ZUPT-KF without magnetic updates
aligns the body's forward axis to north, and the compass is fitted in that frame); an engine class says which
through its ``NORTH_REFERENCE`` attribute (:func:`engine_north`; none = the initial heading). A rotation about
the vertical leaves gravity, the ZUPT-KF's observations and every learned direction unchanged, so turning each
magnetic observation by the declination D and turning the engine's output once by D about the session origin
give the same trajectory. :func:`georeference` is that one turn:
the server applies it when it serves an anchored session's positions (it stores the engine's output as it
came, so an anchor set or changed later needs no rewrite) and ``pednav replay --anchor`` applies it locally,
so both give the same positions.

Frames and units: NED north/east/down [m]; heading [rad] clockwise from north; latitude/longitude [deg]
(WGS-84), altitude [m] above the ellipsoid; declination and dip [rad] (declination positive east of true
north, dip positive down). The WMM comes from ``ahrs.utils.WMM`` (nT, converted to uT here).
"""

from __future__ import annotations

import datetime as _dt
import math
from collections.abc import Iterable
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Literal

import numpy as np

__all__ = [
    "ANCHOR_SOURCES",
    "GOOD_FIX_ACCURACY_M",
    "Anchor",
    "Fix",
    "GeoTrack",
    "MagneticElements",
    "NorthReference",
    "anchor_from_fixes",
    "date_of",
    "engine_north",
    "georeference",
    "geodetic_to_ned",
    "magnetic_elements",
    "magnetic_north_of",
    "ned_to_geodetic",
    "parse_anchor",
    "to_true_north",
]

NorthReference = Literal["true", "magnetic", "initial-heading"]
"""What a trajectory's north is: ``true`` (anchored, the WMM declination applied), ``magnetic`` (no anchor: the
field's horizontal direction), ``initial-heading`` (no magnetometer: the sensor's forward axis at the start)."""

_EPOCH_2000_NS = 946_684_800 * 10**9  # 2000-01-01T00:00:00Z: earlier sample times are not UTC (a boot clock)

ANCHOR_SOURCES = ("user", "location", "gnss", "replay")

GOOD_FIX_ACCURACY_M = 25.0
"""Default largest horizontal accuracy [m] of a fix that anchors (a phone outdoors reaches 3-10 m; a first fix
from cell towers or Wi-Fi is often 30-100 m and would move the whole track)."""


def _check_range(name: str, v: float, lo: float, hi: float) -> None:
    if not isinstance(v, (int, float)) or isinstance(v, bool) or not math.isfinite(v) or not lo <= v <= hi:
        raise ValueError(f"{name}: must be a number within {lo:g}..{hi:g}, got {v!r}")


@dataclass(frozen=True)
class Anchor:
    """The geodetic position of a session's NED origin (its first stance) and the date the World Magnetic Model
    is evaluated at.

    Parameters
    ----------
    latitude_deg, longitude_deg : float
        WGS-84 [deg], -90..90 and -180..180.
    altitude_m : float
        Height above the WGS-84 ellipsoid [m], -500..10 000 (0 when unknown).
    date : datetime.date
        Date of the WMM's declination and dip (the recording's date; the declination moves ~0.1 deg a year).
    accuracy_m : float or None
        Horizontal accuracy of the position [m] (a location fix's), None when given by hand.
    source : str
        ``user`` (session creation or PATCH), ``location`` (a phone's location stream), ``gnss`` (a logged GNSS
        fix), ``replay`` (``pednav replay --anchor``).
    """

    latitude_deg: float
    longitude_deg: float
    altitude_m: float = 0.0
    date: _dt.date = field(default_factory=lambda: _dt.datetime.now(_dt.timezone.utc).date())
    accuracy_m: float | None = None
    source: str = "user"

    def __post_init__(self) -> None:
        _check_range("latitude_deg", self.latitude_deg, -90.0, 90.0)
        _check_range("longitude_deg", self.longitude_deg, -180.0, 180.0)
        _check_range("altitude_m", self.altitude_m, -500.0, 10_000.0)
        if self.accuracy_m is not None:
            _check_range("accuracy_m", self.accuracy_m, 0.0, 1e7)
        if not isinstance(self.date, _dt.date):
            raise ValueError(f"date: must be a date, got {self.date!r}")
        if self.source not in ANCHOR_SOURCES:
            raise ValueError(f"source: one of {', '.join(ANCHOR_SOURCES)}, got {self.source!r}")

    def to_dict(self) -> dict[str, object]:
        return {"latitude_deg": self.latitude_deg, "longitude_deg": self.longitude_deg, "altitude_m": self.altitude_m,
                "date": self.date.isoformat(), "accuracy_m": self.accuracy_m, "source": self.source}


def parse_anchor(text: str, date: _dt.date | None = None, source: str = "replay") -> Anchor:
    """``"LAT,LON[,ALT]"`` (degrees, metres) as an :class:`Anchor`; ``ValueError`` saying what is wrong."""
    parts = [p.strip() for p in str(text).split(",")]
    if len(parts) not in (2, 3):
        raise ValueError(f"anchor {text!r}: expected LAT,LON or LAT,LON,ALT (degrees, metres)")
    try:
        vals = [float(p) for p in parts]
    except ValueError:
        raise ValueError(f"anchor {text!r}: LAT,LON[,ALT] must be numbers") from None
    kw: dict[str, object] = {"source": source}
    if date is not None:
        kw["date"] = date
    return Anchor(vals[0], vals[1], vals[2] if len(vals) == 3 else 0.0, **kw)  # type: ignore[arg-type]


@dataclass(frozen=True)
class Fix:
    """One location fix (a phone's location stream, a logged GNSS line).

    Parameters
    ----------
    t_ns : int
        Time of the fix [ns] (UTC epoch when known: it dates the WMM).
    latitude_deg, longitude_deg : float
        WGS-84 [deg].
    altitude_m : float or None
        Height [m] (None when the fix has none).
    accuracy_m : float or None
        Horizontal accuracy (1-sigma radius) [m]; None when the source does not give one.
    """

    t_ns: int
    latitude_deg: float
    longitude_deg: float
    altitude_m: float | None = None
    accuracy_m: float | None = None


def date_of(t_ns: int) -> _dt.date | None:
    """UTC date of a sample time [ns], or None when it is not a UTC epoch time (before 2000: a boot clock)."""
    if t_ns < _EPOCH_2000_NS:
        return None
    return _dt.datetime.fromtimestamp(t_ns / 1e9, tz=_dt.timezone.utc).date()


def anchor_from_fixes(fixes: Iterable[Fix], max_accuracy_m: float = GOOD_FIX_ACCURACY_M,
                      source: str = "location") -> Anchor | None:
    """The first good fix as an anchor: the first whose accuracy is known and at most ``max_accuracy_m`` [m] and
    whose coordinates are in range; None when there is none. Its date is the fix's UTC date (today's when its
    time is not a UTC time). Importers (GetSensorData GNSS lines, Sensor Logger ``Location``) give their fixes
    here; so does the server for the Sensor Logger location stream.
    """
    for f in fixes:
        if f.accuracy_m is None or not math.isfinite(f.accuracy_m) or not 0.0 <= f.accuracy_m <= max_accuracy_m:
            continue
        alt = f.altitude_m if f.altitude_m is not None and math.isfinite(f.altitude_m) else 0.0
        kw: dict[str, object] = {"accuracy_m": float(f.accuracy_m), "source": source}
        d = date_of(int(f.t_ns))
        if d is not None:
            kw["date"] = d
        try:
            return Anchor(float(f.latitude_deg), float(f.longitude_deg), float(min(max(alt, -500.0), 10_000.0)), **kw)  # type: ignore[arg-type]
        except ValueError:
            continue  # a fix out of range is not a good fix
    return None


@dataclass(frozen=True)
class MagneticElements:
    """The Earth's field at an anchor from the World Magnetic Model.

    ``declination_rad`` (positive: magnetic north east of true north), ``dip_rad`` (inclination, positive down),
    ``total_ut`` (intensity [uT]), ``field_true_ned_ut`` (the field in true-north NED [uT]),
    ``field_magnetic_ned_ut`` (the same field in the engine's magnetic-north NED frame: no east component; the
    reference a magnetic-frame filter compares its field with), ``model`` (the WMM's name, e.g. ``WMM2025``).
    """

    declination_rad: float
    dip_rad: float
    total_ut: float
    field_true_ned_ut: tuple[float, float, float]
    field_magnetic_ned_ut: tuple[float, float, float]
    model: str


@lru_cache(maxsize=256)
def _wmm(lat: float, lon: float, alt_m: float, date: _dt.date) -> MagneticElements:
    from ahrs.utils import WMM

    w = WMM(date=date)
    # explicitly: the constructor skips the computation when the latitude or the longitude is 0 (ahrs 0.4)
    w.magnetic_field(lat, lon, alt_m / 1000.0, date=date)  # height [km]
    x, y, z = float(w.X) / 1000.0, float(w.Y) / 1000.0, float(w.Z) / 1000.0  # nT -> uT
    dec = math.atan2(y, x)
    h = math.hypot(x, y)
    return MagneticElements(dec, math.atan2(z, h), math.sqrt(h * h + z * z), (x, y, z), (h, 0.0, z),
                            str(getattr(w, "model", "WMM")))


def magnetic_elements(anchor: Anchor) -> MagneticElements:
    """Declination, dip and field of the World Magnetic Model at ``anchor`` (its position, height and date)."""
    return _wmm(float(anchor.latitude_deg), float(anchor.longitude_deg), float(anchor.altitude_m), anchor.date)


def to_true_north(north: np.ndarray, east: np.ndarray, heading_rad: np.ndarray,
                  declination_rad: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Turn magnetic-north NED positions and headings into true-north ones about the origin.

    A direction at magnetic azimuth psi points at true azimuth psi + D, so
    ``n_t = n cos D - e sin D``, ``e_t = n sin D + e cos D``, ``heading_t = wrap(heading + D)`` (down unchanged).
    """
    n = np.asarray(north, dtype=np.float64)
    e = np.asarray(east, dtype=np.float64)
    c, s = math.cos(declination_rad), math.sin(declination_rad)
    h = np.asarray(heading_rad, dtype=np.float64) + declination_rad
    return n * c - e * s, n * s + e * c, (h + math.pi) % (2.0 * math.pi) - math.pi


def ned_to_geodetic(north: np.ndarray, east: np.ndarray, down: np.ndarray,
                    anchor: Anchor) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """True-north NED [m] about ``anchor`` -> latitude, longitude [deg], altitude [m] (WGS-84, pymap3d)."""
    import pymap3d

    lat, lon, alt = pymap3d.ned2geodetic(np.asarray(north, float), np.asarray(east, float), np.asarray(down, float),
                                         anchor.latitude_deg, anchor.longitude_deg, anchor.altitude_m)
    return np.atleast_1d(np.asarray(lat, float)), np.atleast_1d(np.asarray(lon, float)), np.atleast_1d(np.asarray(alt, float))


def geodetic_to_ned(lat_deg: np.ndarray, lon_deg: np.ndarray, alt_m: np.ndarray,
                    anchor: Anchor) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Latitude, longitude [deg], altitude [m] -> true-north NED [m] about ``anchor`` (WGS-84, pymap3d)."""
    import pymap3d

    n, e, d = pymap3d.geodetic2ned(np.asarray(lat_deg, float), np.asarray(lon_deg, float), np.asarray(alt_m, float),
                                   anchor.latitude_deg, anchor.longitude_deg, anchor.altitude_m)
    return np.atleast_1d(np.asarray(n, float)), np.atleast_1d(np.asarray(e, float)), np.atleast_1d(np.asarray(d, float))


@dataclass(frozen=True)
class GeoTrack:
    """A trajectory ready to serve or export.

    ``north``, ``east``, ``down`` [m] and ``heading_rad`` in the frame ``north_reference`` names; ``latitude_deg``,
    ``longitude_deg``, ``altitude_m`` when anchored (else None); ``declination_rad`` applied (0 when none);
    ``anchor`` (or None); ``magnetic`` the WMM's elements at the anchor (None without one).
    """

    north: np.ndarray
    east: np.ndarray
    down: np.ndarray
    heading_rad: np.ndarray
    north_reference: NorthReference
    declination_rad: float
    anchor: Anchor | None
    latitude_deg: np.ndarray | None
    longitude_deg: np.ndarray | None
    altitude_m: np.ndarray | None
    magnetic: MagneticElements | None

    def frame_dict(self) -> dict[str, object]:
        """What a served trajectory says about its frame (JSON-ready)."""
        return {
            "north": self.north_reference,
            "declination_deg": math.degrees(self.declination_rad),
            "dip_deg": None if self.magnetic is None else math.degrees(self.magnetic.dip_rad),
            "magnetic_model": None if self.magnetic is None else self.magnetic.model,
            "anchor": None if self.anchor is None else self.anchor.to_dict(),
        }


def engine_north(declared: str | None, has_magnetometer: bool) -> NorthReference:
    """The north of an engine's output frame: what the engine class declares (its ``NORTH_REFERENCE``, None when
    it declares nothing: the initial heading), and the initial heading whenever the data had no magnetometer."""
    if declared not in (None, "magnetic", "initial-heading"):
        raise ValueError(f"NORTH_REFERENCE: 'magnetic' or 'initial-heading', got {declared!r}")
    return "magnetic" if (declared == "magnetic" and has_magnetometer) else "initial-heading"


def magnetic_north_of(events: Iterable[tuple[str, dict]]) -> float | None:
    """The latest ``north_reference`` event's azimuth of magnetic north in the engine's session frame [rad]
    (``(kind, detail)`` pairs in time order); None without one (no calibrated compass yet)."""
    found = None
    for kind, detail in events:
        if kind == "north_reference":
            found = float(detail["magnetic_north_rad"])
    return found


def georeference(north: np.ndarray, east: np.ndarray, down: np.ndarray, heading_rad: np.ndarray,
                 anchor: Anchor | None, frame_north: NorthReference,
                 magnetic_north_rad: float | None = None) -> GeoTrack:
    """The engine's output (NED about the first stance, north ``frame_north``) as served and exported.

    The one place where the declination is applied (server and ``pednav replay --anchor`` alike): with an anchor
    and a magnetic-north frame, positions and headings are turned by the WMM declination about the origin
    (:func:`to_true_north`) and placed on the WGS-84 ellipsoid (:func:`ned_to_geodetic`); with an anchor and a
    frame whose north is the initial heading, nothing can be corrected (the track's orientation is as unknown as
    that heading) and positions are placed as they are; without an anchor nothing changes. An engine whose frame's
    north is the initial heading but which has found magnetic north's azimuth in it (``magnetic_north_rad``, its
    ``north_reference`` events, :func:`magnetic_north_of`) gets its track turned onto magnetic north first.
    """
    if frame_north not in ("magnetic", "initial-heading"):
        raise ValueError(f"frame_north: 'magnetic' or 'initial-heading', got {frame_north!r}")
    n = np.asarray(north, dtype=np.float64).reshape(-1)
    e = np.asarray(east, dtype=np.float64).reshape(-1)
    d = np.asarray(down, dtype=np.float64).reshape(-1)
    h = np.asarray(heading_rad, dtype=np.float64).reshape(-1)
    if frame_north == "initial-heading" and magnetic_north_rad is not None:
        n, e, h = to_true_north(n, e, h, -float(magnetic_north_rad))  # the same turn, by minus that azimuth
        frame_north = "magnetic"
    if anchor is None:
        return GeoTrack(n, e, d, h, frame_north, 0.0, None, None, None, None, None)
    mag = magnetic_elements(anchor)
    dec = mag.declination_rad if frame_north == "magnetic" else 0.0
    if dec:
        n, e, h = to_true_north(n, e, h, dec)
    lat, lon, alt = ned_to_geodetic(n, e, d, anchor) if n.size else (np.zeros(0), np.zeros(0), np.zeros(0))
    return GeoTrack(n, e, d, h, "true" if frame_north == "magnetic" else "initial-heading", dec, anchor, lat, lon,
                    alt, mag)
