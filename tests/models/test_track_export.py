"""Trajectory files: GPX 1.1 against its schema, GeoJSON against RFC 7946's rules, KML, CSV; each read back to
the same NED positions within 1 mm."""

from __future__ import annotations

import datetime as dt
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from models.geo import Anchor, GeoTrack, geodetic_to_ned, georeference
from models.track_export import (
    TrackLabels,
    read_csv,
    read_geojson,
    read_gpx,
    read_kml,
    to_csv,
    to_geojson,
    to_gpx,
    to_kml,
)

XSD = Path(__file__).parent / "data" / "gpx11_subset.xsd"
T0 = 1_764_000_000 * 10**9  # a UTC epoch time (2025-11-24)


def _track(n: int, anchor: Anchor | None, t0: int = T0, seed: int = 0, north: str = "magnetic") -> tuple[GeoTrack, TrackLabels]:
    rng = np.random.default_rng(seed)
    ned = np.cumsum(rng.normal(0, 0.7, (n, 3)) * [1, 1, 0.05], axis=0)
    head = rng.uniform(-math.pi, math.pi, n)
    g = georeference(ned[:, 0], ned[:, 1], ned[:, 2], head, anchor, north)  # type: ignore[arg-type]
    modes = ["zupt", "pdr", "idle"]
    labels = TrackLabels([t0 + i * 500_000_000 for i in range(n)], ["walk"] * n, [modes[i % 3] for i in range(n)],
                         [0.7] * n, [i % 2 == 0 for i in range(n)])
    return g, labels


def check_rfc7946(doc: Any) -> None:
    """RFC 7946's rules for what pednav writes: a FeatureCollection (3.3) of Features (3.2) whose geometry is null
    or a Point / LineString (3.1.2, 3.1.4; a LineString has two or more positions); positions are [lon, lat] or
    [lon, lat, height] numbers (3.1.1) with lon in [-180, 180], lat in [-90, 90] (WGS-84, 4); no "crs" member
    (4); a bbox has 2n numbers, south <= north (5); the text is JSON without NaN or infinities (RFC 8259)."""
    json.dumps(doc, allow_nan=False)
    assert doc["type"] == "FeatureCollection" and isinstance(doc["features"], list)
    assert "crs" not in doc

    def position(p: Any) -> None:
        assert isinstance(p, list) and len(p) in (2, 3) and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in p)
        assert -180.0 <= p[0] <= 180.0 and -90.0 <= p[1] <= 90.0

    def bbox(b: Any, dims: int) -> None:
        assert isinstance(b, list) and len(b) == 2 * dims
        assert b[1] <= b[1 + dims]  # south <= north (west > east only across the antimeridian)

    for f in doc["features"]:
        assert f["type"] == "Feature" and "geometry" in f and "properties" in f and "crs" not in f
        assert f["properties"] is None or isinstance(f["properties"], dict)
        g = f["geometry"]
        if g is None:
            continue
        assert g["type"] in ("Point", "LineString")
        if g["type"] == "Point":
            position(g["coordinates"])
        else:
            assert len(g["coordinates"]) >= 2
            for p in g["coordinates"]:
                position(p)
        if "bbox" in f:
            bbox(f["bbox"], 3)
    if "bbox" in doc:
        bbox(doc["bbox"], 3)


def _back_to_ned(latlonalt: np.ndarray, anchor: Anchor) -> np.ndarray:
    n, e, d = geodetic_to_ned(latlonalt[:, 0], latlonalt[:, 1], latlonalt[:, 2], anchor)
    return np.column_stack([n, e, d])


ANCHORS = [Anchor(33.6405, -117.8443, 15.0, dt.date(2026, 12, 3)), Anchor(-33.86, 151.21, 40.0, dt.date(2026, 6, 1)),
           Anchor(64.1, -21.9, 0.0, dt.date(2026, 1, 1)), Anchor(0.0, 179.9999, 0.0, dt.date(2026, 1, 1))]


@pytest.mark.parametrize("anchor", ANCHORS, ids=["irvine", "sydney", "reykjavik", "antimeridian"])
@pytest.mark.parametrize("n", [0, 1, 2, 300])
def test_exports_validate_and_round_trip(anchor: Anchor, n: int) -> None:
    import xmlschema

    g, labels = _track(n, anchor)
    ned = np.column_stack([g.north, g.east, g.down])
    gj = to_geojson(g, labels, {"session_id": 1})
    check_rfc7946(json.loads(json.dumps(gj)))
    gpx = to_gpx(g, labels, "session 1")
    xmlschema.XMLSchema(str(XSD)).validate(gpx)  # raises with the reason when invalid
    kml = to_kml(g, labels, "session 1")
    for text, reader in ((json.dumps(gj), read_geojson), (gpx, read_gpx), (kml, read_kml)):
        back = reader(text)
        assert back.shape == (n, 3)
        if n:
            assert np.max(np.abs(_back_to_ned(back, anchor) - ned)) < 1e-3  # 1 mm
    rows = read_csv(to_csv(g, labels))
    assert len(rows) == n
    if n:
        lla = np.array([[float(r["latitude_deg"]), float(r["longitude_deg"]), float(r["altitude_m"])] for r in rows])
        assert np.max(np.abs(_back_to_ned(lla, anchor) - ned)) < 1e-3
        np.testing.assert_array_equal([float(r["north"]) for r in rows], g.north)  # NED kept exactly


@settings(max_examples=25, deadline=None)
@given(st.floats(-89, 89), st.floats(-180, 179.999), st.integers(2, 50), st.integers(0, 10_000))
def test_round_trip_anywhere(lat: float, lon: float, n: int, seed: int) -> None:
    import xmlschema

    anchor = Anchor(lat, lon, 0.0, dt.date(2026, 1, 1))
    g, labels = _track(n, anchor, seed=seed)
    ned = np.column_stack([g.north, g.east, g.down])
    gpx = to_gpx(g, labels)
    xmlschema.XMLSchema(str(XSD)).validate(gpx)
    check_rfc7946(to_geojson(g, labels))
    for back in (read_gpx(gpx), read_kml(to_kml(g, labels)), read_geojson(to_geojson(g, labels))):
        assert np.max(np.abs(_back_to_ned(back, anchor) - ned)) < 1e-3


def test_gpx_times_only_for_utc_sample_times() -> None:
    a = ANCHORS[0]
    g, labels = _track(3, a)
    assert "<time>2025-11-24T16:00:00.000Z</time>" in to_gpx(g, labels)
    g2, boot = _track(3, a, t0=5 * 10**9)  # a boot clock: no date to write
    assert "<time>" not in to_gpx(g2, boot)


def test_the_schema_check_refuses_what_gpx_refuses() -> None:
    """The schema check can fail: a longitude of 180 (GPX: -180 <= lon < 180), a missing lat, elements out of
    order and an ele in exponent notation are each refused."""
    import xmlschema

    schema = xmlschema.XMLSchema(str(XSD))
    g, labels = _track(2, ANCHORS[0])
    good = to_gpx(g, labels)
    assert schema.is_valid(good)
    first = good.index("<trkpt ")
    lat_attr = good[first:].split('"')[1]
    bad = [good.replace(f'lat="{lat_attr}"', 'lat="95.0"', 1), good.replace(f'lat="{lat_attr}" ', "", 1),
           good.replace("<ele>", "<ele>1e", 1),
           good.replace("<trk><name>", "<trk><type>x</type><name>", 1)]
    for b in bad:
        assert b != good
        assert not schema.is_valid(b)


def test_rfc7946_check_can_fail() -> None:
    g, labels = _track(3, ANCHORS[0])
    doc = to_geojson(g, labels)
    broken = json.loads(json.dumps(doc))
    broken["features"][0]["geometry"]["coordinates"][0] = [doc["features"][0]["geometry"]["coordinates"][0][1],
                                                            200.0]  # lat/lon swapped out of range
    with pytest.raises(AssertionError):
        check_rfc7946(broken)
    broken2 = {**doc, "crs": {"type": "name"}}
    with pytest.raises(AssertionError):
        check_rfc7946(broken2)


def test_csv_without_anchor_has_no_geodetic_columns() -> None:
    g, labels = _track(4, None)
    header = to_csv(g, labels).splitlines()[0].split(",")
    assert "latitude_deg" not in header and header[:4] == ["t_ns", "north", "east", "down"]
    with pytest.raises(ValueError, match="anchor"):
        to_gpx(g, labels)


def test_geojson_says_its_north_and_declination() -> None:
    g, labels = _track(5, ANCHORS[0], north="magnetic")
    p = to_geojson(g, labels)["features"][0]["properties"]
    assert p["north"] == "true" and 10.5 < p["declination_deg"] < 12.0 and p["anchor"]["latitude_deg"] == 33.6405
    g2, labels2 = _track(5, ANCHORS[0], north="initial-heading")
    assert to_geojson(g2, labels2)["features"][0]["properties"]["north"] == "initial-heading"
