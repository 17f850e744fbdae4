"""Trajectory files: GeoJSON (RFC 7946), GPX 1.1, KML 2.2 and CSV, written from a :class:`models.geo.GeoTrack`
and read back (round trips, imports).

Pure text in, text out (no files). Coordinates are written with enough digits to come back within 0.1 mm:
GeoJSON as JSON numbers (full float64), GPX and KML as fixed-point decimals (1e-10 deg ~ 0.01 mm, heights
to 0.1 mm; ``xsd:decimal`` allows no exponent). Heights are WGS-84 ellipsoidal heights as the anchor's
``altitude_m`` is; KML's ``absolute`` mode reads them as above sea level (tens of metres apart, the geoid),
so KML sets none and lies on the ground. GPX times are UTC ``xsd:dateTime`` and only written when the sample
times are UTC epoch times (a device's boot clock has no date).
"""

from __future__ import annotations

import csv
import datetime as _dt
import io
import json
import math
import xml.etree.ElementTree as ET
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from models.geo import GeoTrack, date_of

__all__ = [
    "FORMATS",
    "MEDIA_TYPES",
    "TrackLabels",
    "to_csv",
    "to_geojson",
    "to_gpx",
    "to_kml",
    "read_csv",
    "read_geojson",
    "read_gpx",
    "read_kml",
]

GPX_NS = "http://www.topografix.com/GPX/1/1"
KML_NS = "http://www.opengis.net/kml/2.2"

FORMATS = ("json", "geojson", "gpx", "kml", "csv")
MEDIA_TYPES = {"json": "application/json", "geojson": "application/geo+json", "gpx": "application/gpx+xml",
               "kml": "application/vnd.google-earth.kml+xml", "csv": "text/csv"}
"""Media type of each export format (GeoJSON: RFC 7946 section 12)."""


@dataclass(frozen=True)
class TrackLabels:
    """What the engine said about each position (same length as the track).

    ``t_ns`` [ns] int64; ``behaviour``, ``mode`` strings; ``step_length_m`` [m]; ``gyro_on`` bool.
    """

    t_ns: Sequence[int]
    behaviour: Sequence[str]
    mode: Sequence[str]
    step_length_m: Sequence[float]
    gyro_on: Sequence[bool]


def _needs_anchor(track: GeoTrack, fmt: str) -> None:
    if track.latitude_deg is None or track.longitude_deg is None or track.altitude_m is None:
        raise ValueError(f"{fmt} needs an anchor (the session's latitude_deg/longitude_deg)")


def _lon180(lon: float) -> float:
    return lon if -180.0 <= lon < 180.0 else (lon + 180.0) % 360.0 - 180.0  # GPX: -180 <= lon < 180


def _iso(t_ns: int) -> str:
    s, ns = divmod(int(t_ns), 10**9)
    base = _dt.datetime.fromtimestamp(s, tz=_dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%S")
    return f"{base}.{ns // 10**6:03d}Z"


def to_geojson(track: GeoTrack, labels: TrackLabels, properties: dict[str, Any] | None = None) -> dict[str, Any]:
    """A FeatureCollection holding one Feature: a LineString (a Point for a single position, null geometry for
    none) of ``[longitude, latitude, height]`` positions (RFC 7946 sections 3.1.1, 3.1.4, 3.2), its ``bbox``
    (section 5), and per-position properties (``t_ns``, ``behaviour``, ``mode``, ``gyro_on``, ``heading_rad``)
    plus the frame (``north``, ``declination_deg``, ``anchor``) and ``properties``.
    """
    _needs_anchor(track, "geojson")
    assert track.latitude_deg is not None and track.longitude_deg is not None and track.altitude_m is not None
    coords = [[_lon180(float(lo)), float(la), float(h)]
              for lo, la, h in zip(track.longitude_deg, track.latitude_deg, track.altitude_m)]
    if len(coords) >= 2:
        geometry: dict[str, Any] | None = {"type": "LineString", "coordinates": coords}
    elif coords:
        geometry = {"type": "Point", "coordinates": coords[0]}
    else:
        geometry = None
    props = {
        **(properties or {}), **track.frame_dict(),
        "t_ns": [int(t) for t in labels.t_ns], "behaviour": list(labels.behaviour), "mode": list(labels.mode),
        "gyro_on": [bool(g) for g in labels.gyro_on], "heading_rad": [float(h) for h in track.heading_rad],
    }
    feature: dict[str, Any] = {"type": "Feature", "geometry": geometry, "properties": props}
    doc: dict[str, Any] = {"type": "FeatureCollection", "features": [feature]}
    if coords:
        a = np.asarray(coords)
        bbox = [float(a[:, 0].min()), float(a[:, 1].min()), float(a[:, 2].min()),
                float(a[:, 0].max()), float(a[:, 1].max()), float(a[:, 2].max())]
        feature["bbox"] = doc["bbox"] = bbox
    return doc


def read_geojson(doc: dict[str, Any] | str) -> np.ndarray:
    """``(N, 3)`` latitude [deg], longitude [deg], height [m] of the first Feature's LineString or Point."""
    d = json.loads(doc) if isinstance(doc, str) else doc
    geom = d["features"][0]["geometry"]
    if geom is None:
        return np.zeros((0, 3))
    c = np.asarray([geom["coordinates"]] if geom["type"] == "Point" else geom["coordinates"], dtype=float)
    return np.column_stack([c[:, 1], c[:, 0], c[:, 2] if c.shape[1] > 2 else np.zeros(len(c))])


def to_gpx(track: GeoTrack, labels: TrackLabels, name: str = "pednav track") -> str:
    """GPX 1.1: one ``trk`` with one ``trkseg`` of ``trkpt`` (lat, lon; ``ele``; ``time`` when the sample times
    are UTC; ``type`` = ``behaviour/mode``), in the schema's element order."""
    _needs_anchor(track, "gpx")
    assert track.latitude_deg is not None and track.longitude_deg is not None and track.altitude_m is not None
    ET.register_namespace("", GPX_NS)
    q = f"{{{GPX_NS}}}"
    root = ET.Element(q + "gpx", {"version": "1.1", "creator": "pednav"})
    meta = ET.SubElement(root, q + "metadata")
    ET.SubElement(meta, q + "name").text = name
    desc = (f"north: {track.north_reference}; declination {math.degrees(track.declination_rad):.3f} deg applied; "
            "heights above the WGS-84 ellipsoid")
    ET.SubElement(meta, q + "desc").text = desc
    utc = len(labels.t_ns) > 0 and date_of(int(labels.t_ns[0])) is not None
    if utc:
        ET.SubElement(meta, q + "time").text = _iso(int(labels.t_ns[0]))
    trk = ET.SubElement(root, q + "trk")
    ET.SubElement(trk, q + "name").text = name
    seg = ET.SubElement(trk, q + "trkseg")
    for i, (la, lo, h) in enumerate(zip(track.latitude_deg, track.longitude_deg, track.altitude_m)):
        pt = ET.SubElement(seg, q + "trkpt", {"lat": f"{float(la):.10f}", "lon": f"{_lon180(float(lo)):.10f}"})
        ET.SubElement(pt, q + "ele").text = f"{float(h):.4f}"
        if utc:
            ET.SubElement(pt, q + "time").text = _iso(int(labels.t_ns[i]))
        ET.SubElement(pt, q + "type").text = f"{labels.behaviour[i]}/{labels.mode[i]}"
    return '<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="unicode") + "\n"


def read_gpx(text: str) -> np.ndarray:
    """``(N, 3)`` latitude, longitude [deg], height [m] of every ``trkpt`` in document order."""
    root = ET.fromstring(text)
    q = f"{{{GPX_NS}}}"
    rows = []
    for pt in root.iter(q + "trkpt"):
        ele = pt.find(q + "ele")
        rows.append((float(pt.get("lat", "nan")), float(pt.get("lon", "nan")), float(ele.text) if ele is not None and ele.text else 0.0))
    return np.asarray(rows, dtype=float).reshape(-1, 3)


def to_kml(track: GeoTrack, labels: TrackLabels, name: str = "pednav track") -> str:
    """KML 2.2: a Placemark with a LineString (``lon,lat,height`` tuples; clamped to the ground) and one Placemark
    Point per position named by its mode (a single position: the Point only)."""
    _needs_anchor(track, "kml")
    assert track.latitude_deg is not None and track.longitude_deg is not None and track.altitude_m is not None
    ET.register_namespace("", KML_NS)
    q = f"{{{KML_NS}}}"
    root = ET.Element(q + "kml")
    doc = ET.SubElement(root, q + "Document")
    ET.SubElement(doc, q + "name").text = name
    ET.SubElement(doc, q + "description").text = (
        f"north: {track.north_reference}; declination {math.degrees(track.declination_rad):.3f} deg applied")
    tuples = [f"{_lon180(float(lo)):.10f},{float(la):.10f},{float(h):.4f}"
              for la, lo, h in zip(track.latitude_deg, track.longitude_deg, track.altitude_m)]
    if len(tuples) >= 2:
        pm = ET.SubElement(doc, q + "Placemark")
        ET.SubElement(pm, q + "name").text = name
        ls = ET.SubElement(pm, q + "LineString")
        ET.SubElement(ls, q + "coordinates").text = " ".join(tuples)
    elif tuples:
        pm = ET.SubElement(doc, q + "Placemark")
        ET.SubElement(pm, q + "name").text = name
        ET.SubElement(ET.SubElement(pm, q + "Point"), q + "coordinates").text = tuples[0]
    return '<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="unicode") + "\n"


def read_kml(text: str) -> np.ndarray:
    """``(N, 3)`` latitude, longitude [deg], height [m] of the first LineString (or Point) in the document."""
    root = ET.fromstring(text)
    q = f"{{{KML_NS}}}"
    el = next(root.iter(q + "LineString"), None)
    if el is None:
        el = next(root.iter(q + "Point"), None)
    if el is None:
        return np.zeros((0, 3))
    coords = el.find(q + "coordinates")
    rows = []
    for tup in (coords.text or "").split() if coords is not None else []:
        parts = [float(v) for v in tup.split(",")]
        rows.append((parts[1], parts[0], parts[2] if len(parts) > 2 else 0.0))
    return np.asarray(rows, dtype=float).reshape(-1, 3)


CSV_FIELDS = ("t_ns", "north", "east", "down", "heading_rad", "behaviour", "mode", "step_length_m", "gyro_on")
GEO_FIELDS = ("latitude_deg", "longitude_deg", "altitude_m")


def to_csv(track: GeoTrack, labels: TrackLabels) -> str:
    """One row per position: the NED fields (in the frame the track's ``north_reference`` names) and, when
    anchored, ``latitude_deg``, ``longitude_deg``, ``altitude_m``; floats as ``repr`` (exact round trip)."""
    fields = list(CSV_FIELDS) + (list(GEO_FIELDS) if track.latitude_deg is not None else [])
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(fields)
    for i in range(len(track.north)):
        row: list[Any] = [int(labels.t_ns[i]), repr(float(track.north[i])), repr(float(track.east[i])),
                          repr(float(track.down[i])), repr(float(track.heading_rad[i])), labels.behaviour[i],
                          labels.mode[i], repr(float(labels.step_length_m[i])), bool(labels.gyro_on[i])]
        if track.latitude_deg is not None:
            assert track.longitude_deg is not None and track.altitude_m is not None
            row += [repr(float(track.latitude_deg[i])), repr(float(track.longitude_deg[i])), repr(float(track.altitude_m[i]))]
        w.writerow(row)
    return buf.getvalue()


def read_csv(text: str) -> list[dict[str, str]]:
    """The rows of :func:`to_csv` as dictionaries of strings."""
    return list(csv.DictReader(io.StringIO(text)))
