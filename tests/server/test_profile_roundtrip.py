"""Stored profiles come back into an engine: JSON has no NaN, so the stored form writes null for them.

Found by `pednav replay --server` on three gdin recordings for one user: the second (format B, no
magnetometer) stored a walk profile whose compass never got its fit (field m_n, residual_std, heading_rms
NaN -> null); every later session start of that user failed with HTTP 500 (float(None) in the compass's
from_state).
"""

from __future__ import annotations

import json
import math

import numpy as np

from energy.engine import Engine
from models.compass import MagCalibrator
from server.ingest import _calibration_in, json_safe
from tests.server.conftest import auth, still_batch

T0 = 1_700_000_000_000_000_000


def _calibration_with_unfitted_compass() -> dict:  # type: ignore[type-arg]
    """A walk calibration as an engine hands it out after a session whose compass got no fit."""
    compass = MagCalibrator().get_state()
    assert not np.all(np.isfinite(compass["m_n"])) and math.isnan(compass["heading_rms"])
    return {"step_model": {"kind": "test", "a": 0.7, "compass": compass}, "sigma_d_m": float("nan"),
            "heading_deviation_rad": 0.1, "heading_deviation_var": 0.01, "n_steps": 40, "calibrated": True}


def test_a_stored_profile_with_non_finite_floats_loads_into_an_engine() -> None:
    stored = json.loads(json.dumps(json_safe(_calibration_with_unfitted_compass()), allow_nan=False))
    assert stored["step_model"]["compass"]["heading_rms"] is None  # what the database holds
    back = _calibration_in(stored)
    assert math.isnan(back["sigma_d_m"]) and math.isnan(back["step_model"]["compass"]["residual_std"])
    engine = Engine(mode="auto", profile={"version": 1, "behaviours": {"walk": back}})
    engine.feed(still_batch(T0))


def test_nulls_outside_the_float_fields_are_not_turned_into_numbers() -> None:
    data = {**json_safe(_calibration_with_unfitted_compass()), "calibrated": None, "n_steps": None}
    back = _calibration_in(data)
    assert back["calibrated"] is None and back["n_steps"] is None  # invalid input stays invalid


def test_session_start_over_http_with_such_a_profile(client, make_user) -> None:  # type: ignore[no-untyped-def]
    _, token = make_user()
    data = json_safe(_calibration_with_unfitted_compass())
    assert client.put("/v1/profiles/walk", json={"data": data}, headers=auth(token)).status_code == 200
    r = client.post("/v1/sessions", json={"device_kind": "foot"}, headers=auth(token))
    assert r.status_code == 201, r.text


def test_an_engine_rebuilt_from_a_sessions_stored_profile_in() -> None:
    """A session without an engine state yet is rebuilt from its stored profile_in (json_safe form)."""
    from server.ingest import EngineHost

    stored = json.loads(json.dumps(
        json_safe({"version": 1, "behaviours": {"walk": _calibration_with_unfitted_compass()}}), allow_nan=False))
    engine = EngineHost().restore_at(1, 0, lambda: None, "auto", stored)
    engine.feed(still_batch(T0))
