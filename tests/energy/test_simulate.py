"""Duty-cycle simulation: error metric, determinism, and the scheduler vs baseline comparison."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from energy.simulate import position_errors, step_errors


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


@pytest.mark.parametrize("ang", [-2.0, 0.3, 1.5])
def test_position_errors_align_on_the_first_metres_only(ang):
    """The alignment is fitted on the path until it first leaves ALIGN_RADIUS_M of the start: a return near
    the start later in the day, with the error gathered meanwhile, does not turn the whole estimate."""
    from energy.simulate import ALIGN_RADIUS_M

    out = np.stack([np.linspace(0.0, 3 * ALIGN_RADIUS_M, 40), np.zeros(40)], axis=1)  # east and back
    truth = np.concatenate([out, out[::-1][1:] + [0.0, 2.0]])
    est = truth.copy()
    est[40:] += [0.0, 3.0]  # an error that appears on the way back (it ends 3 m off, near the start)
    rot = np.array([[np.cos(ang), -np.sin(ang)], [np.sin(ang), np.cos(ang)]])
    t = np.arange(len(truth), dtype=np.int64) * 10**9
    e = position_errors(t, est @ rot.T, t, truth)
    assert e["align_deg"] == pytest.approx(-np.degrees(ang), abs=1e-9)
    assert e["final_m"] == pytest.approx(3.0, abs=1e-9)


@settings(max_examples=30, deadline=None)
@given(ang_deg=st.floats(-40.0, 40.0), scale=st.floats(0.8, 1.2), seed=st.integers(0, 1000))
def test_step_errors_are_each_steps_direction_and_length(ang_deg, scale, seed):
    """Steps turned by ``ang_deg`` and scaled by ``scale`` read that direction and length error; the fitted
    alignment of the whole path is not an error of its steps; each step counts for the mode that reported it."""
    rng = np.random.default_rng(seed)
    heading = np.cumsum(rng.normal(0.0, 0.3, 40))
    truth = np.concatenate([[[0.0, 0.0]], np.cumsum(1.3 * np.c_[np.cos(heading), np.sin(heading)], axis=0)])
    a = np.radians(ang_deg)
    rot = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    t = np.arange(len(truth), dtype=np.int64) * 10**9
    modes = ["zupt"] * 11 + ["pdr"] * (len(truth) - 11)
    e = step_errors(t, scale * truth @ rot.T, modes, t, truth)
    assert e["zupt"]["steps"] == 10 and e["pdr"]["steps"] == len(truth) - 11
    for m in ("zupt", "pdr"):
        assert e[m]["direction_err_deg"] == pytest.approx(abs(ang_deg), abs=1e-6)
        assert e[m]["length_err_pct"] == pytest.approx(100.0 * abs(scale - 1.0), abs=1e-6)
    aligned = step_errors(t, truth @ rot.T, modes, t, truth, align_deg=-ang_deg)
    assert aligned["pdr"]["direction_err_deg"] == pytest.approx(0.0, abs=1e-6)


def test_step_errors_leave_out_steps_shorter_than_a_stride():
    t = np.arange(4, dtype=np.int64) * 10**9
    truth = np.array([[0.0, 0.0], [1.3, 0.0], [1.5, 0.0], [2.8, 0.0]])  # a 0.2-m shuffle between two strides
    est = truth + np.array([[0.0, 0.0], [0.0, 0.0], [0.0, 0.3], [0.0, 0.0]])
    e = step_errors(t, est, ["zupt", "pdr", "pdr", "pdr"], t, truth)
    assert e["pdr"]["steps"] == 2  # the shuffle is not compared
    assert step_errors(t[:1], est[:1], ["zupt"], t, truth) == {}


def test_step_errors_leave_out_a_jump_only_where_its_time_is_given():
    """A 0.6-m sideways jump (a ``strides_corrected`` move) made after the position at 5 s was reported lies in
    the step 5 s -> 6 s: with that time given, that step is left out of its mode (and counted), without it the
    step reads a large direction error; the step ending at the jump's time is not the one."""
    t = np.arange(10, dtype=np.int64) * 10**9
    truth = np.c_[1.3 * np.arange(10.0), np.zeros(10)]
    est = truth.copy()
    est[6:, 1] += 0.6
    modes = ["pdr"] * 6 + ["zupt"] * 4  # the jump falls in a ZUPT-KF step (charged to its end), as on the mixed day
    plain = step_errors(t, est, modes, t, truth)
    assert plain["zupt"]["steps"] == 4 and plain["zupt"]["jumps_left_out"] == 0
    assert plain["zupt"]["direction_err_deg"] == pytest.approx(np.degrees(np.arctan2(0.6, 1.3)) / 4, rel=1e-9)
    assert plain["pdr"] == step_errors(t, est, modes, t, truth, jump_t_ns=[])["pdr"]
    cut = step_errors(t, est, modes, t, truth, jump_t_ns=[int(t[5])])
    assert cut["zupt"]["steps"] == 3 and cut["zupt"]["jumps_left_out"] == 1
    assert cut["zupt"]["direction_err_deg"] == pytest.approx(0.0, abs=1e-9)
    assert cut["zupt"]["length_err_pct"] == pytest.approx(0.0, abs=1e-9)
    assert cut["pdr"] == plain["pdr"]  # the other mode is untouched
    between = step_errors(t, est, modes, t, truth, jump_t_ns=[int(t[5]) + 400_000_000])  # inside the step
    assert between["zupt"] == cut["zupt"]
    wrong = step_errors(t, est, modes, t, truth, jump_t_ns=[int(t[6])])  # the step after the jump's step
    assert wrong["zupt"]["jumps_left_out"] == 1
    assert wrong["zupt"]["direction_err_deg"] > 5.0


@pytest.fixture(scope="module")
def demo_doc():
    pytest.importorskip("energy.engine")
    from clients.synth import synthesize
    from energy.power import load_profile
    from energy.simulate import simulate

    r = synthesize("demo", seed=0)
    p = load_profile("foot-004")
    args = (p, r.batch, r.truth.t_ns, r.truth.positions, len(r.truth.extra["step_t_s"]))
    # Stored per-sample costs: the accounting is deterministic (measured CPU time is not).
    return simulate(*args, measure=False), simulate(*args, measure=False)


UPLOAD_BYTES = 1000  # a fake encoder: every upload is this long


@pytest.fixture(scope="module")
def measured_doc():
    pytest.importorskip("energy.engine")
    from clients.synth import synthesize
    from energy.power import load_profile
    from energy.simulate import simulate

    r = synthesize("demo", seed=0)
    p = load_profile("foot-004")
    doc = simulate(p, r.batch, r.truth.t_ns, r.truth.positions, len(r.truth.extra["step_t_s"]),
                   encode=lambda b: UPLOAD_BYTES)
    return doc, p


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


@pytest.mark.slow
def test_targets_block_states_the_figures_it_tests(demo_doc):
    a, _ = demo_doc
    t = a["targets"]
    assert t["energy_ratio_le_0.25"] == (a["energy_ratio"] <= 0.25)
    assert t["compute_reduction_ge_80pct"] == (a["compute_reduction_pct"] >= 80.0)
    assert t["mode_compute_reduction_ge_80pct"] == (a["mode_cost_per_step_us"]["reduction_pct"] >= 80.0)
    assert t["position_error_ratio_le_1.5"] == (a["position_error_m"]["ratio"] <= 1.5)


def test_split_costs_recovers_per_sample_and_per_batch_costs():
    """1-s and 4-s batches at 25 Hz: the fixed cost of a feed and the cost per sample are told apart, and the
    fitted costs add up to the measured total; batches of one length cannot tell them apart (all per sample)."""
    from energy.simulate import _split_costs

    rng = np.random.default_rng(0)
    n = np.array([25] * 30 + [100] * 40 + [26, 99, 24])
    cpu = 3.0 * n + 120.0 + rng.normal(0.0, 5.0, n.size)
    a, b = _split_costs(n, cpu)
    assert a == pytest.approx(3.0, abs=0.2) and b == pytest.approx(120.0, abs=10.0)
    assert a * n.sum() + b * n.size == pytest.approx(cpu.sum(), rel=1e-12)
    one = np.array([200] * 50 + [201])
    a1, b1 = _split_costs(one, 2.0 * one + 100.0)
    assert b1 == 0.0 and a1 == pytest.approx((2.0 * one + 100.0).sum() / one.sum())


def test_cost_class_is_the_one_of_energy_power():
    import energy.power
    import energy.simulate

    assert energy.simulate.cost_class is energy.power.cost_class  # one definition for simulation and accounting


def test_component_meter_restores_the_engine():
    from energy.simulate import _COMPONENTS, component_meter
    import importlib

    def methods():
        return [getattr(getattr(importlib.import_module(m), c, None), "__dict__", {}).get(f) for _, m, c, f in _COMPONENTS]

    before = methods()
    with component_meter():
        assert methods() != before
    assert methods() == before


@pytest.mark.slow
def test_measured_compute_is_the_cpu_time_the_run_took(measured_doc):
    """Compute energy = this run's CPU time x slowdown x active power; classes and components add up."""
    doc, p = measured_doc
    for run in ("scheduler", "baseline"):
        r = doc[run]
        us = sum(r["compute_us_by_class"].values())
        assert us > 0 and r["compute_source"].startswith("measured")
        assert r["energy_mj"]["compute"] == pytest.approx(us * 1e-6 * p.processor.slowdown_vs_bench * p.processor.active_mw, rel=1e-9)
        comp = r["compute_us_by_component"]  # from its own metered replay: adds up to that replay's CPU time
        for k, v in r["compute_us_by_class_metered"].items():
            assert sum(c.get(k, 0.0) for c in comp.values()) == pytest.approx(v, rel=1e-9)
        assert set(r["compute_us_by_class_metered"]) == set(r["compute_us_by_class"])
        by = r["energy_by_class_mj"]
        for key in ("acc", "gyr", "mag", "compute", "radio", "total"):
            assert sum(d[key] for d in by.values()) == pytest.approx(r["energy_mj"][key], rel=1e-9)
        assert sum(d["time_s"] for d in by.values()) == pytest.approx(doc["duration_s"], abs=1.01)
    base = doc["baseline"]
    assert set(base["compute_us_by_class"]) == {"zupt"}  # always on: never idle, never Gait-DR
    sched = doc["scheduler"]
    assert sched["energy_by_class_mj"].get("idle", {}).get("gyr", 0.0) < 0.01 * sched["energy_mj"]["gyr"]  # gyro off when standing


@pytest.mark.slow
def test_radio_is_the_bytes_uploaded(measured_doc):
    doc, p = measured_doc
    for run in ("scheduler", "baseline"):
        r = doc[run]
        assert r["bytes_sent"] == UPLOAD_BYTES * r["requests"]
        assert r["energy_mj"]["radio"] == pytest.approx(r["requests"] * (UPLOAD_BYTES * p.radio.uj_per_byte + p.radio.uj_per_request) / 1e3)


def test_default_byte_model_counts_every_stream_sample():
    from energy.power import REQUEST_OVERHEAD_BYTES, SAMPLE_BYTES, TIMESTAMP_BYTES
    from energy.simulate import model_bytes
    from models.batch import SensorBatch

    t = np.arange(25, dtype=np.int64) * 40_000_000
    acc = np.tile([0.0, 0.0, 9.81], (25, 1))
    b = SensorBatch(acc_t_ns=t, acc=acc, mag_t_ns=t[::5], mag=np.tile([20.0, 0.0, 40.0], (5, 1)))
    assert model_bytes(b) == 30 * (SAMPLE_BYTES + TIMESTAMP_BYTES) + REQUEST_OVERHEAD_BYTES


@pytest.mark.slow
def test_returning_user_resumes_from_the_profile():
    """A profile learned on an earlier day (another seed): the day starts in Gait-DR, not with an L0
    initialisation; through the first stand, once the ZUPT-KF has levelled, both users' gyroscopes are left to
    the device, which wakes them on motion."""
    pytest.importorskip("energy.engine")
    from clients.synth import synthesize
    from energy.power import load_profile
    from energy.simulate import learn_profile, run_engine

    r = synthesize("demo", seed=0)  # starts with 10 s of standing
    prof = learn_profile(synthesize("demo", seed=1).batch)
    assert prof["behaviours"]["walk"]["calibrated"]
    p = load_profile("foot-004")
    runs = [run_engine("auto", r.batch, p, r.truth.t_ns, r.truth.positions, None, measure=False, user_profile=u)
            for u in (None, prof)]
    t0 = int(r.batch.t_start_ns)
    for run, returning in zip(runs, (False, True)):
        kinds = [e.kind for u in run.replay.updates for e in u.events]
        first_pdr = next(i for i, k in enumerate(kinds) if k == "mode_switch")
        # the new user reaches Gait-DR through an initialisation, the returning one through an examination
        assert ("calibration_done" in kinds[:first_pdr]) is not returning
        assert ("examination_passed" in kinds[:first_pdr]) is returning
        stand = [c for t, c in run.replay.configs if 5e9 <= t - t0 < 9e9]  # levelled by 5 s
        assert stand and not any(c.gyro_on for c in stand)
        # a new user's first steps need the ZUPT-KF (nothing else could place them); a returning user's first
        # ZUPT-KF strides examine the stored heading deviation (a re-mounted sensor fails it)
        assert all(c.gyro_wake_on_motion for c in stand)
    new, ret = runs
    assert abs(len(ret.replay.positions) - len(new.replay.positions)) <= 2  # no steps lost at the start
