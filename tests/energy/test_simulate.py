"""Duty-cycle simulation: error metric, determinism, and the scheduler vs baseline comparison."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from energy.simulate import position_errors


@settings(max_examples=30, deadline=None)
@given(ang=st.floats(-np.pi, np.pi), seed=st.integers(0, 1000))
def test_position_errors_remove_only_a_rotation(ang, seed):
    rng = np.random.default_rng(seed)
    truth = np.cumsum(rng.normal(0.0, 1.0, (50, 2)), axis=0)
    truth -= truth[0]
    rot = np.array([[np.cos(ang), -np.sin(ang)], [np.sin(ang), np.cos(ang)]])
    t = np.arange(50, dtype=np.int64) * 10**9
    e = position_errors(t, truth @ rot.T, t, truth)
    assert e["mean_m"] == pytest.approx(0.0, abs=1e-9)
    scaled = position_errors(t, 1.1 * truth @ rot.T, t, truth)  # a scale error is not aligned away
    assert scaled["mean_m"] == pytest.approx(0.1 * np.mean(np.linalg.norm(truth, axis=1)), rel=1e-9)


@pytest.fixture(scope="module")
def demo_doc():
    pytest.importorskip("energy.engine")
    from clients.synth import synthesize
    from energy.power import load_profile
    from energy.simulate import simulate

    r = synthesize("demo", seed=0)
    p = load_profile("foot-004")
    args = (p, r.batch, r.truth.t_ns, r.truth.positions, len(r.truth.extra["step_t_s"]))
    return simulate(*args), simulate(*args)


@pytest.mark.slow
def test_simulation_is_deterministic_and_adds_up(demo_doc):
    a, b = demo_doc
    for run in ("scheduler", "baseline"):
        assert a[run]["energy_mj"] == b[run]["energy_mj"]
        e = a[run]["energy_mj"]
        assert e["total"] == e["acc"] + e["gyr"] + e["mag"] + e["compute"] + e["radio"]
        assert e["sensors"] == e["acc"] + e["gyr"] + e["mag"]
    assert a["position_error_m"] == b["position_error_m"]


@pytest.mark.slow
def test_baseline_is_always_on(demo_doc):
    a, _ = demo_doc
    assert a["baseline"]["gyro_on_fraction"] == pytest.approx(1.0, abs=0.01)
    assert a["baseline"]["mean_rate_hz"] == pytest.approx(200.0, rel=0.01)


@pytest.mark.slow
def test_scheduler_saves_energy(demo_doc):
    """The scheduler must not cost more than the always-on baseline (the issue's <= 25 % is reported, not asserted here)."""
    a, _ = demo_doc
    assert a["energy_ratio"] < 1.0
    assert a["gyro_on_fraction"] < a["baseline"]["gyro_on_fraction"]
