"""Power profiles and energy accounting: sources, datasheet figures, exact sums, hand-calculated baseline."""

from __future__ import annotations

import json

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from energy.power import (
    ComputeCosts,
    Interval,
    Timeline,
    account,
    load_compute_costs,
    load_profile,
    profile_names,
)

COSTS = ComputeCosts({"zupt": 20.0, "pdr": 2.0, "idle": 1.0}, {"zupt": 0.0, "pdr": 50.0, "idle": 0.0}, {"date": "test"})


@pytest.mark.parametrize("name", ["foot-004", "foot-lsm9ds1", "phone-bmi270"])
def test_profiles_load_with_sources(name):
    assert name in profile_names()
    p = load_profile(name, COSTS)
    for s in ("acc", "gyr", "mag"):
        assert p.sensors[s].source and p.sensors[s].part
        assert all(i >= 0 for i in p.sensors[s].current_ua)
    assert p.processor.source and p.radio.source and p.supply_v > 0


def test_missing_source_is_refused(tmp_path):
    from energy.power import _profiles_dir

    d = json.loads((_profiles_dir() / "foot-004.json").read_text())
    d["sensors"]["gyr"]["source"] = ""
    f = tmp_path / "bad.json"
    f.write_text(json.dumps(d))
    with pytest.raises(ValueError, match="gyr.source"):
        load_profile(f, COSTS)


def test_004_datasheet_figures():
    """004 Section 4.1: L3GD20 gyroscope 6.1 mA vs LIS3DH accelerometer 11 uA (at 50 Hz)."""
    p = load_profile("foot-004", COSTS)
    assert p.sensors["gyr"].current(200.0) == pytest.approx(6100.0)
    assert p.sensors["acc"].current(50.0) == pytest.approx(11.0)
    assert p.sensors["acc"].current(0.0) == p.sensors["acc"].off_current_ua
    assert p.sensors["acc"].current(75.0) == pytest.approx(15.5)  # linear between 50 and 100 Hz


def test_always_on_baseline_matches_hand_calculation():
    """100 s of ZUPT-KF at 200 Hz, gyroscope on, magnetometer 50 Hz, on foot-004, 1 s batches."""
    p = load_profile("foot-004", COSTS)
    n = 100
    tl = Timeline(
        [Interval(float(i), float(i + 1), 200.0, 200.0, 50.0) for i in range(n)],
        samples_by_mode={"zupt": 20000},
        steps_by_mode={"zupt": 90},
        bytes_sent=1_000_000,
        requests=n,
    )
    rep = account(tl, p)
    # By hand from the profile's figures: LIS3DH 38 uA at 200 Hz, L3GD20 6.1 mA, LIS2MDL 125 uA at 50 Hz, 3 V.
    assert rep.components_mj["acc"] == pytest.approx(100 * 38e-6 * 3.0 * 1e3)
    assert rep.components_mj["gyr"] == pytest.approx(100 * 6.1e-3 * 3.0 * 1e3)
    assert rep.components_mj["mag"] == pytest.approx(100 * 125e-6 * 3.0 * 1e3)
    # 20000 samples x 20 us on the bench x 100 (slowdown) = 40 s on the MCU at 9.9 mW.
    assert rep.components_mj["compute"] == pytest.approx(20000 * 20e-6 * 100 * 9.9)
    # 1e6 bytes x 0.17 uJ + 100 requests x 10 uJ.
    assert rep.components_mj["radio"] == pytest.approx((1e6 * 0.17 + 100 * 10.0) / 1e3)
    assert rep.total_mj == pytest.approx(1878.9 + 396.0 + 171.0)


@settings(max_examples=60, deadline=None)
@given(
    rates=st.lists(
        st.tuples(st.sampled_from([0.0, 12.5, 25.0, 50.0, 200.0]), st.booleans(), st.sampled_from([0.0, 20.0, 50.0])),
        min_size=1,
        max_size=30,
    ),
    zupt=st.integers(0, 10**6),
    pdr=st.integers(0, 10**6),
    steps=st.integers(0, 5000),
    nbytes=st.integers(0, 10**8),
    requests=st.integers(0, 10**5),
    profile=st.sampled_from(["foot-004", "foot-lsm9ds1", "phone-bmi270"]),
)
def test_components_add_up_exactly(rates, zupt, pdr, steps, nbytes, requests, profile):
    p = load_profile(profile, COSTS)
    ivs = [Interval(i * 1.5, (i + 1) * 1.5, a, a if g else 0.0, m) for i, (a, g, m) in enumerate(rates)]
    rep = account(Timeline(ivs, {"zupt": zupt, "pdr": pdr}, {"pdr": steps}, nbytes, requests), p)
    c = rep.components_mj
    assert rep.total_mj == c["acc"] + c["gyr"] + c["mag"] + c["compute"] + c["radio"]
    assert all(v >= 0 for v in c.values())
    assert rep.sensors_mj == c["acc"] + c["gyr"] + c["mag"]


def test_gyro_dominates_and_gating_saves():
    """Turning the gyroscope off saves energy in proportion to the time it is off."""
    p = load_profile("foot-004", COSTS)
    on = account(Timeline([Interval(0, 10, 200, 200, 50)]), p)
    off = account(Timeline([Interval(0, 10, 25, 0, 50)]), p)
    assert on.components_mj["gyr"] > 100 * on.components_mj["acc"]
    assert off.components_mj["gyr"] == pytest.approx(10 * 5e-6 * 3.0 * 1e3)  # power-down current only


def test_unknown_mode_cost_is_refused():
    p = load_profile("foot-004", ComputeCosts({"zupt": 1.0}, {}, {}))
    with pytest.raises(ValueError, match="pdr"):
        account(Timeline([Interval(0, 1, 25, 0, 0)], {"pdr": 25}), p)


def test_stored_compute_costs_have_provenance():
    c = load_compute_costs()
    assert c.measured["date"] and c.measured["machine"] and c.measured["command"]
    assert c.us_per_sample.get("zupt", 0) > 0
    for mode in ("zupt", "auto"):  # each engine's own costs, measured with the batching of the simulated day
        own = c.for_engine(mode)
        assert own is not c and own.us_per_sample.get("zupt", 0) > 0
    assert "batch" in c.measured["command"] and c.measured["load_average"]


def test_per_batch_costs_are_charged_per_batch():
    """The same samples in 4x fewer batches cost 4x less per-batch overhead; the per-sample part is unchanged."""
    p = load_profile("foot-004", ComputeCosts({"pdr": 2.0}, {}, {"date": "test"}, us_per_batch={"pdr": 100.0}))
    iv = [Interval(0.0, 100.0, 25.0, 0.0, 25.0)]
    one = account(Timeline(iv, {"pdr": 2500}, batches_by_mode={"pdr": 100}), p)
    four = account(Timeline(iv, {"pdr": 2500}, batches_by_mode={"pdr": 25}), p)
    assert one.compute_us_by_mode["pdr"] == pytest.approx(2500 * 2.0 + 100 * 100.0)
    assert four.compute_us_by_mode["pdr"] == pytest.approx(2500 * 2.0 + 25 * 100.0)
    legacy = account(Timeline(iv, {"pdr": 2500}), p)  # no batch counts: per-sample part only
    assert legacy.compute_us_by_mode["pdr"] == pytest.approx(2500 * 2.0)


def test_engine_costs_replace_the_top_level_ones(tmp_path):
    """compute_costs.json: an engine's own table is used for it; files without one (older) load as before."""
    d = {"us_per_sample": {"zupt": 3.0, "pdr": 12.0, "idle": 7.0}, "us_per_step": {"zupt": 0.0, "pdr": 0.0, "idle": 0.0},
         "measured": {"date": "d", "machine": "m", "command": "c"}}
    f = tmp_path / "old.json"
    f.write_text(json.dumps(d))
    old = load_compute_costs(f)
    assert old.for_engine("auto") is old and old.us_per_batch == {} and old.engines == {}
    d["engines"] = {"auto": {"us_per_sample": {"zupt": 4.0, "pdr": 3.0, "idle": None}, "us_per_batch": {"zupt": 200.0, "pdr": 120.0}},
                    "zupt": {"us_per_sample": {"zupt": 2.5}, "us_per_batch": {"zupt": 0.0}}}
    f.write_text(json.dumps(d))
    new = load_compute_costs(f)
    auto = new.for_engine("auto")
    assert auto.us_per_sample == {"zupt": 4.0, "pdr": 3.0} and auto.us_per_batch == {"zupt": 200.0, "pdr": 120.0}
    assert auto.us_per_step == d["us_per_step"] and auto.measured == new.measured
    assert new.for_engine("zupt").us_per_sample == {"zupt": 2.5}
    assert new.for_engine("pdr") is new  # not measured on its own: the top-level figures
    assert new.us_per_sample == {"zupt": 3.0, "pdr": 12.0, "idle": 7.0}


@pytest.mark.parametrize("name", ["foot-004", "foot-lsm9ds1", "phone-bmi270"])
def test_every_sensor_says_what_was_verified(name):
    """Each sensor figure carries its verification status (what was checked against the datasheet text)."""
    p = load_profile(name, COSTS)
    for s in ("acc", "gyr", "mag"):
        assert p.sensors[s].verified != "not checked", f"{name} {s}: no verification status"


def test_lis3dh_table_matches_the_datasheet():
    """LIS3DH DocID17530 Rev 2, Table 12, normal mode (checked against the datasheet text, 2026-11-22)."""
    p = load_profile("foot-004", COSTS)
    table = {1: 2, 10: 4, 25: 6, 50: 11, 100: 20, 200: 38, 400: 73, 1344: 185}
    for odr, ua in table.items():
        assert p.sensors["acc"].current(float(odr)) == pytest.approx(ua)
    assert p.sensors["acc"].verified.startswith("verified")


def test_cost_class_counts_standing_as_idle():
    from energy.power import cost_class

    assert cost_class(True, "stand") == "zupt"
    assert cost_class(False, "stand") == "idle"
    assert cost_class(False, "walk") == "pdr"


@pytest.mark.slow
def test_timeline_from_replay_puts_standing_in_idle():
    """A replayed day: standing batches (gyroscope off, behaviour stand) are charged as idle, and the
    accelerometer samples of all classes add up to those sent."""
    pytest.importorskip("energy.engine")
    from clients.synth import synthesize
    from energy.device import replay
    from energy.engine import Engine

    r = synthesize("demo", seed=0)
    res = replay(Engine(mode="auto"), r.batch)
    tl = Timeline.from_replay(res, int(r.batch.t_end_ns))
    assert tl.samples_by_mode.get("idle", 0) > 0
    assert abs(sum(tl.samples_by_mode.values()) - res.samples_sent["acc"]) <= len(tl.samples_by_mode)


@pytest.mark.slow
def test_timeline_windows_add_up_to_the_whole():
    """A replay's timeline cut at any time into two windows: each sensor's energy, the steps, the batches and the
    accelerometer samples of the two add up to the whole replay's; a window over everything is the whole."""
    from clients.phone_synth import synthesize_phone
    from energy.device import replay
    from energy.phone_engine import PhoneEngine

    r = synthesize_phone("phone-out-and-back", seed=3)
    res = replay(PhoneEngine(mode="auto", device_kind="phone", placement="phone-hand"), r.batch, 1.0)
    t0, t1 = int(r.batch.t_start_ns), int(r.batch.t_end_ns) + 1
    prof = load_profile("phone-bmi270")
    whole = Timeline.from_replay(res, t1)
    assert account(Timeline.from_replay(res, t1, (t0, t1)), prof).total_mj == pytest.approx(account(whole, prof).total_mj)
    for f in (0.2, 0.5, 0.77):
        cut = int(t0 + f * (t1 - t0))
        a, b = Timeline.from_replay(res, t1, (t0, cut)), Timeline.from_replay(res, t1, (cut, t1))
        ea, eb, ew = account(a, prof), account(b, prof), account(whole, prof)
        for s in ("acc", "gyr", "mag"):
            assert ea.components_mj[s] + eb.components_mj[s] == pytest.approx(ew.components_mj[s])
        assert a.steps + b.steps == whole.steps
        assert a.requests + b.requests == whole.requests
        assert abs(sum(a.samples_by_mode.values()) + sum(b.samples_by_mode.values())
                   - sum(whole.samples_by_mode.values())) <= 2 * len(whole.samples_by_mode)
        assert a.duration_s + b.duration_s == pytest.approx(whole.duration_s)
