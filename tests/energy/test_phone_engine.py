"""The step-and-heading engine keeps the engine contract (DESIGN.md): chunk invariance, state round trip, profile
in and out, sensor configuration out; it navigates synthetic phones and, where present, the IPIN trials."""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from clients.phone_synth import PHONE_SCENARIOS, synthesize_phone
from energy.device import replay
from energy.engines import EngineSpec, engine_from_bytes, new_engine, profile_for
from energy.phone_engine import PROFILE_KEY, PhoneEngine, PhoneEngineConfig
from models.batch import BatchError, SensorBatch

ANCHOR = (49.4612, 11.1113, 300.0)


@lru_cache(maxsize=None)
def _rec(name: str, seed: int = 1):  # type: ignore[no-untyped-def]
    return synthesize_phone(name, seed=seed)


def _positions(engine: PhoneEngine, batches: list[SensorBatch]) -> np.ndarray:
    rows = []
    for b in batches:
        rows += [[p.t_ns, p.north, p.east, p.heading_rad, p.step_length_m] for p in engine.feed(b).positions]
    rows += [[p.t_ns, p.north, p.east, p.heading_rad, p.step_length_m] for p in engine.flush().positions]
    return np.array(rows)


def _cut(batch: SensorBatch, fractions: list[float]) -> list[SensorBatch]:
    t0, t1 = int(batch.t_start_ns), int(batch.t_end_ns) + 1
    edges = [t0] + sorted(int(t0 + f * (t1 - t0)) for f in fractions) + [t1]
    return [batch.time_slice(a, b) for a, b in zip(edges[:-1], edges[1:]) if b > a]


@settings(max_examples=8, deadline=None)
@given(fractions=st.lists(st.floats(0.001, 0.999), min_size=1, max_size=12))
def test_chunk_invariance(fractions: list[float]) -> None:
    rec = _rec("phone-walk")
    whole = _positions(PhoneEngine("always-on", placement="phone-hand", anchor=ANCHOR), [rec.batch])
    parts = _positions(PhoneEngine("always-on", placement="phone-hand", anchor=ANCHOR), _cut(rec.batch, fractions))
    assert whole.shape == parts.shape and len(whole) > 50
    np.testing.assert_allclose(parts, whole, atol=1e-9, rtol=0)


@pytest.mark.parametrize("cut", [0.13, 0.5, 0.87])
def test_state_round_trip_mid_walk(cut: float) -> None:
    rec = _rec("phone-pocket-walk")
    first, second = _cut(rec.batch, [cut])
    ref = _positions(PhoneEngine("auto", anchor=ANCHOR), [first, second])
    e = PhoneEngine("auto", anchor=ANCHOR)
    a = [[p.t_ns, p.north, p.east, p.heading_rad, p.step_length_m] for p in e.feed(first).positions]
    blob = e.to_bytes()
    e2 = engine_from_bytes(blob)
    assert isinstance(e2, PhoneEngine) and e2.to_bytes() == blob
    rest = _positions(e2, [second])
    got = np.array(a + rest.tolist())
    np.testing.assert_allclose(got, ref, atol=1e-9, rtol=0)


def test_works_with_what_the_device_sends() -> None:
    """No gyroscope at all (a cheap phone, or one that is off), a lower accelerometer rate, a gap: steps still
    come, headed by the compass."""
    rec = _rec("phone-walk")
    b = rec.batch
    keep = (b.acc_t_ns < b.acc_t_ns[0] + 15_000_000_000) | (b.acc_t_ns > b.acc_t_ns[0] + 16_000_000_000)  # 1-s gap
    slim = SensorBatch(acc_t_ns=b.acc_t_ns[keep][::2], acc=b.acc[keep][::2], mag_t_ns=b.mag_t_ns, mag=b.mag)
    pos = _positions(PhoneEngine("auto", placement="phone-hand", anchor=ANCHOR), [slim])
    truth = rec.truth
    assert len(pos) >= 0.9 * len(truth.t_ns)
    assert not any(np.isnan(pos).ravel())


@pytest.mark.parametrize("mode", ["always-on", "auto"])
def test_a_phone_without_magnetometer_is_navigated(mode: str) -> None:
    """No magnetometer at all (a phone without one): the same steps and step lengths as with it, headed by the
    gyroscope from the device's first attitude, which the output says (``heading_reference`` with north
    "initial-heading", the trajectories' word), and chunk-invariant. (The heading is only relative: the
    gyroscope's bias is then unobserved, docs/phone.md.)"""
    rec = _rec("phone-walk")
    kw = dict(rec.batch._kwargs())
    kw["mag_t_ns"], kw["mag"] = kw["mag_t_ns"][:0], kw["mag"][:0]
    blind = SensorBatch(**kw)
    with_mag = _positions(PhoneEngine(mode, placement="phone-hand", anchor=ANCHOR), rec.batch.split_seconds(1.0))
    eng = PhoneEngine(mode, placement="phone-hand", anchor=ANCHOR)
    events = []
    rows = []
    for b in blind.split_seconds(1.0):
        u = eng.feed(b)
        events += u.events
        rows += [[p.t_ns, p.north, p.east, p.heading_rad, p.step_length_m] for p in u.positions]
    rows += [[p.t_ns, p.north, p.east, p.heading_rad, p.step_length_m] for p in eng.flush().positions]
    got = np.array(rows)
    assert len(got) == len(with_mag) > 50
    np.testing.assert_array_equal(got[:, 0], with_mag[:, 0])
    np.testing.assert_allclose(got[:, 4], with_mag[:, 4], rtol=1e-12)
    assert np.isfinite(got).all()
    refs = [e.detail.get("north") for e in events if e.kind == "heading_reference"]
    assert refs[-1] == "initial-heading"
    whole = _positions(PhoneEngine(mode, placement="phone-hand", anchor=ANCHOR), [blind])
    np.testing.assert_allclose(whole, got, atol=1e-9, rtol=0)


def _lagged(batch: SensorBatch, lag_s: float, edges_s: list[float]) -> list[SensorBatch]:
    """Upload batches ending ``edges_s`` [s] after the recording's start (and one with the rest) in which the
    magnetometer's samples arrive ``lag_s`` after their time stamps (as a decimating filter's delay delivers them:
    the emulated 10-Hz magnetometer's is 0.8 s), the other streams at once; the last batch brings everything left."""
    t0, t1 = int(batch.t_start_ns), int(batch.t_end_ns) + 1
    lag = int(lag_s * 1e9)
    ends = sorted({min(t0 + int(e * 1e9), t1) for e in edges_s} | {t1})
    out, a = [], t0
    for b in ends:
        if b <= a:
            continue
        now = batch.time_slice(a, b)
        m = (batch.mag_t_ns >= a - lag) & (batch.mag_t_ns < (b - lag if b < t1 else t1))
        out.append(SensorBatch(acc_t_ns=now.acc_t_ns, acc=now.acc, gyr_t_ns=now.gyr_t_ns, gyr=now.gyr,
                               mag_t_ns=batch.mag_t_ns[m], mag=batch.mag[m]))
        a = b
    return out


def _every(batch: SensorBatch, every_s: float) -> list[float]:
    return list(np.arange(every_s, (int(batch.t_end_ns) - int(batch.t_start_ns)) / 1e9 + every_s, every_s))


@pytest.mark.parametrize("mode", ["auto", "always-on"])
@pytest.mark.parametrize("every_s", [0.25, 0.5, 1.0])
def test_lagging_stream_is_waited_for(mode: str, every_s: float) -> None:
    """A magnetometer whose samples arrive 0.3 s more behind their time stamps than ``stream_wait_s`` (the
    emulated 10-Hz magnetometer's filter delay, 0.8 s) still delivers with every upload: it is waited for, loses
    no sample and the track is the one of the whole recording in one batch, whatever the upload period (it lost
    ``(lag - wait) / period`` of its samples, all of them with 0.25-s uploads)."""
    rec = _rec("phone-walk")
    whole = _positions(PhoneEngine(mode, placement="phone-hand", anchor=ANCHOR), [rec.batch])
    e = PhoneEngine(mode, placement="phone-hand", anchor=ANCHOR)
    lag = e.config.stream_wait_s + 0.3
    parts = _positions(e, _lagged(rec.batch, lag, [1.0] + [1.0 + x for x in _every(rec.batch, every_s)]))
    assert e.late_samples == {"acc": 0, "gyr": 0, "mag": 0}
    assert whole.shape == parts.shape and len(whole) > 50
    np.testing.assert_allclose(parts, whole, atol=1e-9, rtol=0)


@pytest.mark.parametrize("mode", ["auto", "always-on"])
def test_a_stream_lagging_beyond_the_bound_does_not_hold_the_answers_back(mode: str) -> None:
    """A magnetometer that keeps delivering but whose clock falls ever further behind (its samples arrive 0.6 s
    later per second of recording: 30 s at the end of the walk) is waited for while it lags by at most
    ``stream_max_lag_s``, and no longer: the last steps come about that bound after their time, not as late as
    the clock lags, and the samples that arrive too late are counted, not held (the accelerometer's buffer stays
    bounded)."""
    rec = _rec("phone-walk")
    e = PhoneEngine(mode, placement="phone-hand", anchor=ANCHOR)
    bound_s = e.config.stream_max_lag_s
    b0 = rec.batch
    t0, t1 = int(b0.t_start_ns), int(b0.t_end_ns) + 1
    arrival = t0 + (b0.mag_t_ns - t0) * 1.6
    ends = [t0 + int(x * 1e9) for x in _every(b0, 1.0)]
    newest_ns, behind_s, a = None, [], t0
    for b in ends:
        now = b0.time_slice(a, min(b, t1))
        m = (arrival >= a) & (arrival < b)
        batch = SensorBatch(acc_t_ns=now.acc_t_ns, acc=now.acc, gyr_t_ns=now.gyr_t_ns, gyr=now.gyr,
                            mag_t_ns=b0.mag_t_ns[m], mag=b0.mag[m])
        a = b
        for p in e.feed(batch).positions:
            newest_ns = p.t_ns
        if newest_ns is not None and len(now.acc_t_ns):
            behind_s.append((int(now.acc_t_ns[-1]) - newest_ns) / 1e9)
    # the walk's last seconds (walking: a step answered once the look-ahead has passed it)
    assert len(behind_s) > 10 and max(behind_s[-5:]) < bound_s + 2.0
    assert e.late_samples["mag"] > 0


@settings(max_examples=8, deadline=None)
@given(fractions=st.lists(st.floats(0.02, 0.999), min_size=1, max_size=40), lag_s=st.floats(0.0, 1.5))
def test_chunk_invariance_auto_lagged(fractions: list[float], lag_s: float) -> None:
    """``auto`` fed the same samples (not following its own configuration) is chunk invariant, also when the
    magnetometer's samples arrive late by up to 1.5 s: after the first upload (which outlasts the lag) the upload
    periods are arbitrary."""
    rec = _rec("phone-walk")
    dur = (int(rec.batch.t_end_ns) - int(rec.batch.t_start_ns)) / 1e9
    whole = _positions(PhoneEngine("auto", placement="phone-hand", anchor=ANCHOR), [rec.batch])
    e = PhoneEngine("auto", placement="phone-hand", anchor=ANCHOR)
    parts = _positions(e, _lagged(rec.batch, lag_s, [2.0] + [2.0 + f * (dur - 2.0) for f in fractions]))
    assert e.late_samples["mag"] == 0
    assert whole.shape == parts.shape and len(whole) > 50
    np.testing.assert_allclose(parts, whole, atol=1e-9, rtol=0)


def test_late_samples_are_counted_per_stream() -> None:
    """A magnetometer that falls silent for longer than ``stream_wait_s`` is not waited for; the samples it then
    delivers late, behind the time the merge has passed, are counted on their stream (none when it is on time),
    and the count survives the state round trip."""
    rec = _rec("phone-walk")
    e = PhoneEngine("always-on", placement="phone-hand", anchor=ANCHOR)
    _positions(e, _lagged(rec.batch, 0.0, _every(rec.batch, 1.0)))
    assert e.late_samples == {"acc": 0, "gyr": 0, "mag": 0}
    e = PhoneEngine("always-on", placement="phone-hand", anchor=ANCHOR)
    batches = _lagged(rec.batch, 0.0, _every(rec.batch, 1.0))
    silent = batches[5:9]  # 4 s without a magnetometer sample, then its backlog at once
    backlog = (np.concatenate([b.mag_t_ns for b in silent]), np.concatenate([b.mag for b in silent]))
    for i, b in enumerate(batches[:8]):
        e.feed(b if i < 5 else SensorBatch(acc_t_ns=b.acc_t_ns, acc=b.acc, gyr_t_ns=b.gyr_t_ns, gyr=b.gyr))
    b = batches[8]
    e.feed(SensorBatch(acc_t_ns=b.acc_t_ns, acc=b.acc, gyr_t_ns=b.gyr_t_ns, gyr=b.gyr, mag_t_ns=backlog[0], mag=backlog[1]))
    late = e.late_samples
    assert late["mag"] > 0 and late["acc"] == late["gyr"] == 0
    assert engine_from_bytes(e.to_bytes()).late_samples == late  # type: ignore[attr-defined]


def test_sensor_configuration_follows_behaviour() -> None:
    """always-on: every sensor at its full rate. auto: walking, the gyroscope on at the low rates; standing, the low
    rates and the gyroscope off once its vertical bias has settled. walk_gyro="on-demand": the gyroscope also goes
    off walking, and less of the time is spent with it."""
    rec = _rec("phone-walk")
    cfg = PhoneEngineConfig()
    on = replay(PhoneEngine("always-on", anchor=ANCHOR), rec.batch, 1.0)
    assert all(c.gyro_on and (c.acc_rate_hz, c.gyr_rate_hz, c.mag_rate_hz) == (cfg.acc_rate_hz, cfg.gyr_rate_hz, cfg.mag_rate_hz)
               for _, c in on.configs)
    auto = replay(PhoneEngine("auto", anchor=ANCHOR), rec.batch, 1.0)
    cfgs = [c for _, c in auto.configs]
    settled, standing, walking = False, [], []
    for c, u in zip(cfgs[1:], auto.updates):
        settled = settled or any(e.kind == "gyro_bias" and e.detail["settled"] for e in u.events)
        (standing if u.behaviour == "stand" else walking).append((c, settled))
    assert standing and all(c.acc_rate_hz == cfg.stand_acc_rate_hz and c.mag_rate_hz == cfg.stand_mag_rate_hz
                            for c, _ in standing)
    # standing, the gyroscope runs only until its vertical bias has settled (the quasi-static field settles it)
    assert all(c.gyro_on != s for c, s in standing)
    assert walking and all(c.gyro_on and (c.acc_rate_hz, c.gyr_rate_hz, c.mag_rate_hz)
                           == (cfg.auto_acc_rate_hz, cfg.auto_gyr_rate_hz, cfg.walk_mag_rate_hz) for c, _ in walking)
    assert sum(auto.samples_sent.values()) < 0.6 * sum(on.samples_sent.values())
    demand = replay(PhoneEngine("auto", anchor=ANCHOR, config=PhoneEngineConfig(walk_gyro="on-demand")), rec.batch, 1.0)
    went_off = [c for c, u in zip([c for _, c in demand.configs][1:], demand.updates) if u.behaviour != "stand" and not c.gyro_on]
    assert went_off and demand.gyro_on_fraction < auto.gyro_on_fraction
    assert demand.configs[0][1].gyro_on  # the first steps learn the compass's noise with the gyroscope on


def test_walk_gyro_is_validated() -> None:
    with pytest.raises(ValueError, match="walk_gyro"):
        PhoneEngineConfig(walk_gyro="sometimes")


def test_synthetic_walks_are_navigated() -> None:
    """Closing error and path of the synthetic square walk held in the hand (compass clean, a gyroscope bias)."""
    rec = _rec("phone-walk")
    res = replay(PhoneEngine("always-on", placement="phone-hand", anchor=ANCHOR), rec.batch, 1.0)
    p = np.array([[q.north, q.east] for q in res.positions])
    truth = rec.truth.positions[:, :2]
    length = sum(q.step_length_m for q in res.positions)
    assert length == pytest.approx(rec.truth.extra["path_m"], rel=0.08)  # default Weinberg constant, no calibration
    assert np.linalg.norm((p[-1] - p[0]) - (truth[-1] - truth[0])) < 0.05 * rec.truth.extra["path_m"]


def test_pocket_is_recognised_as_an_event() -> None:
    res = replay(PhoneEngine("always-on", anchor=ANCHOR), _rec("phone-pocket-walk").batch, 1.0)
    ev = [e for u in res.updates for e in u.events if e.kind == "placement_changed"]
    assert ev and ev[0].detail["placement"] == "phone-pocket"
    given = replay(PhoneEngine("always-on", placement="phone-hand", anchor=ANCHOR), _rec("phone-pocket-walk").batch, 1.0)
    assert not [e for u in given.updates for e in u.events if e.kind == "placement_changed"]


def test_profile_in_and_out() -> None:
    rec = _rec("phone-walk")
    e = PhoneEngine("always-on", placement="phone-hand", anchor=ANCHOR)
    res = replay(e, rec.batch, 1.0)
    walked = sum(q.step_length_m for q in res.positions)
    t0, t1 = res.positions[0].t_ns - 1, res.positions[-1].t_ns
    ev = e.calibrate_distance(t0, t1, 1.1 * walked)  # the user says: 10 % more than I thought
    assert ev.kind == "calibration" and ev.detail["placement"] == "phone-hand"
    prof = e.profile_dict()
    cal = prof["behaviours"][PROFILE_KEY]
    assert cal["calibrated"] and cal["step_model"]["placements"]["phone-hand"]["k"] > e.config.step_length.weinberg_k
    again = replay(PhoneEngine("always-on", profile=prof, placement="phone-hand", anchor=ANCHOR), rec.batch, 1.0)
    assert sum(q.step_length_m for q in again.positions) == pytest.approx(1.1 * walked, rel=0.03)
    # the foot engine gets none of it, the phone none of the foot's
    assert profile_for(prof, "foot") is None
    assert profile_for({"version": 1, "behaviours": {"walk": {}}}, "step-and-heading") is None
    with pytest.raises(ValueError, match="steps"):
        e.calibrate_distance(t1 + 1, t1 + 2, 5.0)


def test_refusals() -> None:
    e = PhoneEngine("auto")
    b = _rec("phone-walk").batch
    e.feed(b.time_slice(None, int(b.t_start_ns) + 5_000_000_000))
    with pytest.raises(BatchError, match="acc_t_ns"):
        e.feed(b.time_slice(None, int(b.t_start_ns) + 1_000_000_000))
    with pytest.raises(ValueError, match="mode"):
        PhoneEngine("zupt")
    with pytest.raises(ValueError, match="placement"):
        PhoneEngine("auto", device_kind="watch", placement="phone-pocket")
    with pytest.raises(ValueError, match="placement"):
        new_engine("auto", None, EngineSpec("watch", "phone-hand"))


@pytest.mark.parametrize("name", sorted(PHONE_SCENARIOS))
def test_synthesiser_is_physical(name: str) -> None:
    """At rest the specific force reads g and the field the Earth's; the device never teleports."""
    rec = _rec(name)
    b = rec.batch
    still = b.acc_t_ns < b.acc_t_ns[0] + 2_000_000_000
    assert np.linalg.norm(b.acc[still], axis=1).mean() == pytest.approx(9.80665, abs=0.05)
    assert np.linalg.norm(b.mag, axis=1).mean() == pytest.approx(math.hypot(20.30, 1.43, 44.60), abs=0.5)
    steps = np.diff(rec.truth.positions[:, :2], axis=0)
    assert np.all(np.linalg.norm(steps, axis=1) < 1.0)


def test_ipin_trial_beats_standing_still(ipin_dir) -> None:  # type: ignore[no-untyped-def]
    """One IPIN trial, always-on, the default constant: the walk is followed (far better than never leaving the
    first landmark) and its length is right to a few percent."""
    from clients.evaluation.ipin import landmark_errors, run_phone
    from clients.importers import load

    rec = load(ipin_dir / "IPIN2023_T3_TrainingTrial24_repetition01.txt")
    run = run_phone(rec, "always-on", PhoneEngine().config.step_length.weinberg_k)
    T, L = rec.truth.t_ns, rec.truth.positions[:, :2]
    e = landmark_errors(T, L, run.t_ns, run.ne, run.step_m)
    standing = float(np.mean(np.linalg.norm(L[1:] - L[0], axis=1)))
    assert e.mean_err_m < 0.35 * standing
    assert e.path_ratio == pytest.approx(1.0, abs=0.08)


def test_sm_g930f_walker_takes_longer_steps_at_no_larger_feature(ipin_dir) -> None:  # type: ignore[no-untyped-def]
    """The diagnosis of docs/phone.md "Known limits" (clients.evaluation.phone_step_length): the SM-G930F walker's
    steps are more than 15 % longer than an SM-A520F walker's whose Weinberg feature and walking-band vertical
    power are larger: no amplitude feature tells his steps apart."""
    from clients.evaluation.phone_step_length import trial_statistics
    from clients.importers import load

    g = trial_statistics(load(ipin_dir / "IPIN2023_T3_TrainingTrial21_repetition01.txt"))
    a = trial_statistics(load(ipin_dir / "IPIN2023_T3_TrainingTrial24_repetition01.txt"))
    assert (g["phone"], a["phone"]) == ("SM-G930F", "SM-A520F")
    assert g["step_m"] > 1.15 * a["step_m"]
    assert g["weinberg"] < a["weinberg"] and g["vert_power"] < a["vert_power"] and g["period_s"] > a["period_s"]


def test_ipin_batch_phases(ipin_dir) -> None:  # type: ignore[no-untyped-def]
    """``evaluate_ipin(phases=2)``: phase 0 is the document's own rows; the other phase replays with the batch
    boundaries half a batch later (a different replay of the same walks: the energy-aware track changes, the
    always-on one hardly); the means are the means of the phases."""
    from clients.evaluation.ipin import evaluate_ipin
    from clients.importers import load

    recs = [load(ipin_dir / f"IPIN2023_T3_Training{n}.txt") for n in ("Trial23_repetition01", "Trial27_repetition01")]
    doc = evaluate_ipin(recs, mode="auto", phases=2)
    ph = doc["phases"]
    p0, p1 = ph["per_phase"]
    assert (p0["offset_s"], p1["offset_s"]) == (0.0, 0.5)
    assert p0["mean_err_m"] == pytest.approx(doc["summary"]["mean_err_m"]["median"], abs=1e-12)
    assert p0["always_on"]["mean_err_m"] == pytest.approx(doc["summary"]["always_on"]["mean_err_m"]["median"], abs=1e-12)
    assert p1["mean_err_m"] != p0["mean_err_m"]
    assert p1["always_on"]["mean_err_m"] == pytest.approx(p0["always_on"]["mean_err_m"], rel=0.25)
    assert ph["mean"]["mean_err_m"] == pytest.approx(0.5 * (p0["mean_err_m"] + p1["mean_err_m"]), abs=1e-12)
    assert [t["name"] for t in ph["trials"]] == [t["name"] for t in doc["trials"]]
    ratios = [t["mean_err_m"] / t["always_on_mean_err_m"] for t in ph["trials"]]
    paired = ph["mean"]["paired_ratio"]
    assert paired["n"] == 2 and paired["geomean"] == pytest.approx(math.sqrt(ratios[0] * ratios[1]), rel=1e-12)
    assert doc["summary"]["accuracy_ratio"]["paired"]["n"] == 2




def test_phone_heading_parameters_are_the_dev_trials_statistics(ipin_dir) -> None:  # type: ignore[no-untyped-def]
    """Each fitted value of PHONE_HEADING lies within the range of its leave-one-route-out folds (to the rounding
    of its last digit), so no value rests on one route."""
    from clients.evaluation.phone_heading import loro_statistics, step_table
    from clients.importers import load
    from energy.phone_engine import PHONE_HEADING as H

    files = sorted(ipin_dir.glob("*.txt"))
    rng = loro_statistics([step_table(load(f)) for f in files])["range"]
    deg = math.degrees
    for key, value, tol in (("straight_sigma_deg", deg(H.straight_sigma_rad), 0.05),
                            ("turn_sigma_deg", deg(H.turn_sigma_rad), 0.5),
                            ("p_turn_start", H.p_turn_start, 0.005), ("p_turn_stay", H.p_turn_stay, 0.005),
                            ("deflection_walk_deg", deg(H.deflection_walk_rad), 0.05),
                            ("deflection_floor_deg", deg(H.deflection_floor_rad), 0.5)):
        lo, hi = rng[key]
        assert lo - tol <= value <= hi + tol, (key, value, lo, hi)
    assert deg(H.compass_floor_rad) <= rng["compass_white_max_deg"][0]
    lo, hi = rng["compass_rho_per_step"]
    assert lo - 0.005 <= PhoneEngine().config.orientation_rho <= hi + 0.005
    assert deg(PhoneEngine().config.marg_settled_std_rad) > rng["marg_yaw_std_p95_deg"][1]


def test_ipin_returning_user_calibration(ipin_dir) -> None:  # type: ignore[no-untyped-def]
    """``evaluate_ipin(calibration="returning-user")``: the SM-G930F walker's constant calibrated by the engine on
    his other walk of the route (a known distance) brings both walks' path lengths closer to the surveyed ones than
    the other routes' population constant does (docs/phone.md "Known limits"); a trial without another walk of
    its route keeps the population constant."""
    from clients.evaluation.ipin import evaluate_ipin
    from clients.importers import load

    names = ("Trial21_repetition01", "Trial21_repetition02", "Trial23_repetition01")
    recs = [load(ipin_dir / f"IPIN2023_T3_Training{n}.txt") for n in names]
    pop = {t["name"]: t for t in evaluate_ipin(recs, mode="always-on")["trials"]}
    doc = evaluate_ipin(recs, mode="always-on", calibration="returning-user")
    assert doc["calibration"] == "returning-user"
    ru = {t["name"]: t for t in doc["trials"]}
    for n in names[:2]:
        name = f"IPIN2023_T3_Training{n}"
        assert abs(ru[name]["path_ratio"] - 1.0) < abs(pop[name]["path_ratio"] - 1.0)
        assert ru[name]["weinberg_k"] > pop[name]["weinberg_k"]  # his steps are longer at the same feature
    alone = "IPIN2023_T3_TrainingTrial23_repetition01"
    assert ru[alone]["weinberg_k"] == pop[alone]["weinberg_k"]
    with pytest.raises(ValueError, match="calibration"):
        evaluate_ipin(recs[:1], calibration="per-trial")


def test_turn_standing_before_the_gyroscope_came_on_is_taken(ipin_dir) -> None:  # type: ignore[no-untyped-def]
    """A stand whose turn falls where the gyroscope was not yet on (it came on a moment after the walker stopped,
    as ``auto`` switches it at batch boundaries): most of the stand had the gyroscope, but the turn is the part it
    did not see, so the compass's change at that one place must still turn the heading. IPIN Trial27 rep01's
    34-s stand with its 100-deg turn, in an always-on replay with the gyroscope cut as ``auto`` had it: off for
    the last 15 s of walking before the stand (straight along a corridor) and the stand's first 2 s."""
    from clients.importers import load

    rec = load(ipin_dir / "IPIN2023_T3_TrainingTrial27_repetition01.txt")
    kw = dict(rec.batch._kwargs())

    def run(batch: SensorBatch) -> np.ndarray:
        eng = PhoneEngine(mode="always-on", device_kind="phone", placement="phone-hand", anchor=ANCHOR)
        return _positions(eng, batch.split_seconds(1.0))

    whole = run(rec.batch)
    t = whole[:, 0]
    i = int(np.argmax(np.diff(t)))  # the longest stand
    turned = math.degrees(abs(math.remainder(whole[i + 1, 3] - whole[i, 3], math.tau)))
    assert np.diff(t)[i] > 20e9 and turned > 60.0
    g = kw["gyr_t_ns"]
    keep = (g < t[i] - 15e9) | (g >= t[i] + 2e9)  # off for the walk's last 15 s and the stand's first 2 s
    kw["gyr_t_ns"], kw["gyr"] = g[keep], kw["gyr"][keep]
    cut = run(SensorBatch(**kw))
    j = int(np.argmin(np.abs(cut[:, 0] - t[i + 1])))
    assert cut[j, 0] == t[i + 1]
    after = slice(j, j + 5)  # the first steps after the stand
    miss = np.degrees(np.abs(np.remainder(cut[after, 3] - whole[i + 1: i + 6, 3] + math.pi, math.tau) - math.pi))
    assert np.max(miss) < 25.0, miss
