"""Gait-DR pipeline: KF II turn gate, the compass through the heading estimator, state round trip."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from energy.config import EngineConfig
from energy.codec import dumps, loads
from energy.gait_dr import GaitPipeline
from models.heading_deviation import wrap_angle
from models.step_length import StepFeatures
from models.steps import StepEvent
from models.zupt_nav import Stance


def _pair(k: int, heading: float, walk_dir: float, d: float = 1.3, period: float = 1.2) -> tuple[Stance, StepEvent]:
    t = 1.0 + k * period
    delta = np.array([d * math.cos(walk_dir), d * math.sin(walk_dir), 0.0])
    st = Stance(t, t + 0.3, np.zeros(3), heading, delta, 1.5, 60, False)
    e = StepEvent(t, period, 1.0 / period, 12.0, 25.0, 5.0, (0.0, 0.0, -9.81), False, k)
    return st, e


def test_kf2_skips_turning_strides() -> None:
    gp = GaitPipeline(EngineConfig())
    dev = math.radians(5.0)
    k = 0
    for _ in range(12):  # straight north: walking direction = heading + 5 deg
        gp.learn(*_pair(k, 0.0, dev), "walk")
        k += 1
    n = gp.kf2["walk"].n_updates
    # a 20 deg turn over one stride: the chord points half-way, gamma - psi = -5 deg (inside the innovation
    # gate, 10 deg from the deviation) but it is not an observation of the deviation
    gp.learn(*_pair(k, math.radians(20.0), math.radians(15.0)), "walk")
    k += 1
    assert gp.kf2["walk"].n_updates == n
    for _ in range(5):  # straight again in the new direction: observed again
        gp.learn(*_pair(k, math.radians(20.0), math.radians(20.0) + dev), "walk")
        k += 1
    assert gp.kf2["walk"].n_updates == n + 5
    assert gp.kf2["walk"].deviation == pytest.approx(dev, abs=math.radians(0.5))
    back = GaitPipeline.from_state(EngineConfig(), loads(dumps(gp.get_state())))
    assert back._prev_stance == gp._prev_stance


def test_kf2_observes_the_heading_half_way_through_the_swing() -> None:
    """The foot's heading wobbles by 8 deg from stance to stance while the walk goes straight: each stride's chord
    lies half-way between the stance headings before and after its swing. Against the mid-swing heading every
    observation is the deviation itself; against the heel-strike heading they would alternate by +-4 deg."""
    gp = GaitPipeline(EngineConfig())
    dev = math.radians(3.0)
    wobble = math.radians(8.0)
    devs = []
    for k in range(30):
        psi = wobble if k % 2 else 0.0
        gp.learn(*_pair(k, psi, 0.5 * wobble + dev), "walk")
        devs.append(gp.kf2["walk"].deviation)
    # the first stride (no stance before it) initialises at the heel-strike heading, 7 deg; then every
    # observation is 3 deg: the estimate converges monotonically
    assert abs(devs[-1] - dev) < math.radians(0.3)
    assert np.all(np.diff(devs) <= 0)  # heel strike: alternating steps of +-0.3 deg up and down


def test_conventional_pipeline_uses_the_generic_model_and_no_deviation() -> None:
    from models.step_length import StepFeatures, StepLengthCalibrator

    gps = {c: GaitPipeline(EngineConfig().override({"pdr_conventional": c})) for c in (False, True)}
    for gp in gps.values():
        for k in range(12):  # a person with 1.6 m strides walking 20 deg off the sensor's x axis
            gp.learn(*_pair(k, 0.0, math.radians(20.0), d=1.6), "walk")
        gp.fit("walk")
        gp.start(np.zeros(3))
        gp.start_frame(0.0)
    e = _pair(20, 0.0, 0.0)[1]
    generic = StepLengthCalibrator().predict("walk", StepFeatures(e.f_s, e.acc_mean, e.acc_max, e.acc_min))[0]
    assert gps[True].step_length(e, "walk")[0] == pytest.approx(generic)
    assert gps[False].step_length(e, "walk")[0] == pytest.approx(1.6, abs=0.05)
    assert gps[False].kf2["walk"].deviation == pytest.approx(math.radians(20.0), abs=math.radians(0.5))
    assert gps[True].dr is not None and not gps[True].dr.compensate


def test_unfitted_stride_follows_the_cadence_at_the_persons_scale() -> None:
    """Before the walking model is fitted, Gait-DR's stride is the generic model at this step's cadence times the
    person's own ratio to it on the latest ZUPT-KF strides (the median of those strides alone kept a slow walk's
    1.07 m when the walk sped up to 1.38 m on the synthetic mixed day)."""
    from models.step_length import StepLengthCalibrator

    generic = StepLengthCalibrator()
    gp = GaitPipeline(EngineConfig())
    slow = [_pair(k, 0.0, 0.0, period=1.4) for k in range(6)]
    for st, e in slow:
        d = 1.2 * generic.predict("walk", StepFeatures(e.f_s, e.acc_mean, e.acc_max, e.acc_min))[0]
        gp.learn(dataclasses.replace(st, delta=np.array([d, 0.0, 0.0])), e, "walk")
    assert not gp.cal.calibrated("walk")
    fast = _pair(10, 0.0, 0.0, period=1.0)[1]
    want = 1.2 * generic.predict("walk", StepFeatures(fast.f_s, fast.acc_mean, fast.acc_max, fast.acc_min))[0]
    assert gp.step_length(fast, "walk")[0] == pytest.approx(want)
    assert want > 1.05 * float(np.median(gp.recent_d["walk"]))
    back = GaitPipeline.from_state(EngineConfig(), loads(dumps(gp.get_state())))
    assert back.step_length(fast, "walk")[0] == gp.step_length(fast, "walk")[0]


def test_a_paused_stride_takes_its_own_behaviours_cadence() -> None:
    """A stride after a short pause carries the pace before the pause (models.steps: ``paused``), one after a
    rest a nominal one. After a run and a stop, that pace is the run's: the walking stride takes the median
    cadence of the latest measured walking strides instead, as does one after a rest; measured strides, and a
    paused one of a behaviour without measured strides, keep their own. The cadences survive the state round
    trip and the event rows keep the marks."""
    from models.steps import StepEvent

    gp = GaitPipeline(EngineConfig())
    for k in range(6):
        st, e = _pair(k, 0.0, 0.0, period=1.1 + 0.02 * k)  # walking strides of 1.10-1.20 s
        gp.learn(st, e, "walk")
    run_pace = _pair(20, 0.0, 0.0, period=0.74)[1]
    paused = dataclasses.replace(run_pace, paused=True)
    want = float(np.median([1.0 / (1.1 + 0.02 * k) for k in range(1, 6)]))  # the latest five
    assert gp.features(paused, "walk").f_s == pytest.approx(want)
    assert gp.features(dataclasses.replace(run_pace, after_rest=True), "walk").f_s == pytest.approx(want)
    assert gp.features(run_pace, "walk").f_s == run_pace.f_s  # measured: its own
    assert gp.features(paused, "run").f_s == paused.f_s  # no measured running stride to take one from
    assert gp.step_length(paused, "walk")[0] == gp.step_length(dataclasses.replace(paused, f_s=want, paused=False), "walk")[0]
    assert gp.step_length(paused, "walk")[0] != gp.step_length(run_pace, "walk")[0]
    back = GaitPipeline.from_state(EngineConfig(), loads(dumps(gp.get_state())))
    assert back.features(paused, "walk") == gp.features(paused, "walk")
    for ev in (paused, run_pace, dataclasses.replace(run_pace, after_rest=True)):
        assert StepEvent.from_row(ev.to_row()) == ev


def test_profile_fitted_with_the_older_step_model_form_is_refitted_on_load() -> None:
    """A profile whose walking fit predates K3 on the mean acceleration is refitted from its pairs."""
    src = GaitPipeline(EngineConfig())
    for k in range(20):
        src.learn(*_pair(k, 0.0, 0.0, d=1.25 + 0.01 * (k % 3)), "walk")
    src.fit("walk")
    fresh = src.calibration_state()
    old = loads(dumps(fresh))
    del old["calibrator"]["form"]
    for v in old["calibrator"]["fits"].values():
        v["coef"][3] = -0.014  # a K3 fitted on the ~30 m/s^2 peak
    gp = GaitPipeline(EngineConfig())
    gp.load_calibration("walk", old, 0.0, 1e-4)
    e = _pair(30, 0.0, 0.0)[1]
    assert gp.step_length(e, "walk") == src.step_length(e, "walk")


G = 9.80665
M_N = np.array([20.0, 2.0, 42.0])  # uT, NED


def _field_stance(rng: np.random.Generator, yaw: float, steel: np.ndarray | None = None,
                  place: np.ndarray = M_N) -> tuple[np.ndarray, np.ndarray]:
    """Specific force and field [uT] (body) of a stance at heading ``yaw`` [rad] where the field is ``place``."""
    from models.rotations import euler_to_dcm

    roll, pitch = rng.normal(scale=0.03, size=2)
    c = euler_to_dcm(np.float64(roll), np.float64(pitch), np.float64(yaw))
    field = place if steel is None else place + steel
    return c.T @ np.array([0.0, 0.0, -G]), c.T @ field + rng.normal(scale=0.3, size=3)


def _calibrated_compass(rng: np.random.Generator, frame_offset: float = 0.0):
    from models.compass import MagCalibrator

    cal = MagCalibrator()
    for yaw in rng.uniform(-math.pi, math.pi, 40):
        acc, mag = _field_stance(rng, yaw)
        cal.add(acc, mag, math.remainder(float(yaw) + frame_offset, 2 * math.pi))
    assert cal.fit() and cal.trusted
    return cal


def _event(k: int, acc: np.ndarray) -> StepEvent:
    return StepEvent(100.0 + 1.1 * k, 1.1, 0.9, 12.0, 25.0, 5.0, tuple(acc), False, 1000 + k)


def _zupt_stride(gp: GaitPipeline, k: int, yaw: float, delta: float, acc: np.ndarray, mag: np.ndarray) -> None:
    """A ZUPT-KF stride ending at heading ``yaw`` [rad] after a gyroscope-measured turn ``delta`` [rad]: the
    compass calibration (learn) and the heading estimator (track), as the engine runs them."""
    st, e = _pair(k, yaw, yaw)
    e = dataclasses.replace(e, acc_stance=tuple(acc), index=k)
    gp.stance_mag[e.index] = mag
    gp.stance_acc[e.index] = acc
    gp.learn(st, e, "walk")
    gp.track(e, delta, 0.0)


def _reckon_one(gp: GaitPipeline, k: int, acc: np.ndarray, mag: np.ndarray):
    """One Gait-DR stride whose stance reads ``acc``, ``mag``; returns (step, drift forecast %)."""
    e = _event(k, acc)
    gp.queue.append(e)
    gp.stance_mag[e.index] = mag
    gp.stance_acc[e.index] = acc
    (step, _, drift), = gp.reckon(e.t_s + 0.1, lambda t: "walk")
    return step, drift


def _walking(gp: GaitPipeline, rng: np.random.Generator, yaw: float = 0.3, n: int = 12, **field) -> None:
    """Start the session frame at ``yaw`` and walk ``n`` ZUPT-KF strides on it."""
    gp.has_mag = True
    gp.start_frame(yaw)
    for k in range(n):
        _zupt_stride(gp, k, yaw, 0.0, *_field_stance(rng, yaw, **field))
    gp.start(np.zeros(3))


def test_a_profiles_compass_reads_in_its_own_frame_and_the_estimator_learns_the_offset() -> None:
    """A stored calibration's field azimuth is in the frame of the session that fitted it; this session's frame
    began elsewhere (here 40 deg apart). The heading estimator takes the difference as the compass's frame
    offset from the ZUPT-KF strides, and Gait-DR then follows a turn in this session's frame."""
    rng = np.random.default_rng(21)
    stored = _calibrated_compass(rng, frame_offset=math.radians(40.0))
    gp = GaitPipeline(EngineConfig())
    gp.load_calibration("walk", {"compass": stored.get_state()}, 0.0, 1e-4)
    _walking(gp, rng)
    assert gp.compass() is gp.loaded and gp.in_use == "loaded"
    assert wrap_angle(gp.est.offset - math.radians(40.0)) == pytest.approx(0.0, abs=math.radians(2.0))
    for k in range(20, 24):
        step, _ = _reckon_one(gp, k, *_field_stance(rng, 1.3))
    assert gp.est.heading == pytest.approx(1.3, abs=math.radians(3.0))
    back = GaitPipeline.from_state(EngineConfig(), loads(dumps(gp.get_state())))
    assert back.est.heading == gp.est.heading and back.compass() is back.loaded


@pytest.mark.parametrize("seed, off_deg, replaced", [(23, 20.0, False), (24, 4.0, False), (25, 0.0, True)])
def test_an_own_fit_supersedes_a_trusted_profile_compass_only_when_it_agrees_at_least_as_well(seed, off_deg,
                                                                                            replaced) -> None:
    """A returning user's own fit from a few examination stances can be ready but not trusted (headings 20 deg off
    the ZUPT-KF's), or trusted yet noisier than the loaded one (4 deg): the loaded one stays. An own fit as good
    takes over (this place's field, this session's frame: offset 0)."""
    rng = np.random.default_rng(seed)
    stored = _calibrated_compass(rng)
    gp = GaitPipeline(EngineConfig())
    gp.has_mag = True
    gp.load_calibration("walk", {"compass": stored.get_state()}, 0.0, 1e-4)
    gp.start_frame(0.0)
    for k, yaw in enumerate(rng.uniform(-math.pi, math.pi, 60)):
        off = float(rng.normal(scale=math.radians(off_deg))) if off_deg else 0.0
        _zupt_stride(gp, k, float(yaw), 0.0, *_field_stance(rng, float(yaw) + off))
    assert gp.mag.ready
    assert (gp.compass() is gp.mag) == replaced
    assert gp.in_use == ("own" if replaced else "loaded")


def test_disturbed_stances_stay_out_of_a_trusted_compass_calibration() -> None:
    rng = np.random.default_rng(5)
    gp = GaitPipeline(EngineConfig())
    gp.has_mag = True
    gp.mag = _calibrated_compass(rng)
    n = gp.mag.n_stances
    for k, steel in enumerate((None, np.array([15.0, -10.0, 5.0]), None)):
        st, e = _pair(k, 0.2, 0.2)
        acc, mag = _field_stance(rng, 0.2, steel)
        e = StepEvent(e.t_s, e.period_s, e.f_s, e.acc_mean, e.acc_max, e.acc_min, tuple(acc), False, e.index)
        gp.stance_mag[e.index] = mag
        gp.learn(st, e, "walk")
    assert gp.mag.n_stances == n + 2  # the steel stance is not the Earth's field


def test_turning_stride_goes_half_way_and_the_drift_forecast_stays_within_budget_on_a_clean_field() -> None:
    """A 40 deg turn between two stances on a clean field: the compass change is the foot's (the field kept its
    shape), the stride's chord lies half-way, and the drift forecast stays within the default budget."""
    rng = np.random.default_rng(8)
    gp = GaitPipeline(EngineConfig())
    gp.mag = _calibrated_compass(rng)
    _walking(gp, rng, yaw=0.0, n=20)
    _reckon_one(gp, 30, *_field_stance(rng, 0.0))
    step, drift = _reckon_one(gp, 31, *_field_stance(rng, math.radians(40.0)))
    assert math.degrees(step.direction) == pytest.approx(20.0, abs=2.5)
    assert math.degrees(gp.est.heading) == pytest.approx(40.0, abs=3.0)
    _, drift = _reckon_one(gp, 32, *_field_stance(rng, math.radians(40.0)))
    assert drift < EngineConfig().scheduler.cross_track_pct


def test_steel_holds_the_heading_and_a_turn_inside_it_is_still_the_foots() -> None:
    """Walking into steel changes the field's shape (vertical +15 uT, horizontal +12 uT: the compass swings by 20
    deg): the heading is held and the drift forecast leaves the budget (the scheduler would ask for the
    gyroscope). Inside the steel, where the field keeps its disturbed shape, a 60-deg turn of the foot is taken
    from the compass change."""
    rng = np.random.default_rng(9)
    gp = GaitPipeline(EngineConfig())
    gp.mag = _calibrated_compass(rng)
    _walking(gp, rng, yaw=0.0, n=20)
    steel = np.array([10.0, 10.0, 15.0])
    step, drift = _reckon_one(gp, 30, *_field_stance(rng, 0.0, steel))
    assert abs(math.degrees(gp.est.heading)) < 8.0
    assert drift > EngineConfig().scheduler.cross_track_pct
    for k in range(31, 34):
        _reckon_one(gp, k, *_field_stance(rng, 0.0, steel))
    assert abs(math.degrees(gp.est.heading)) < 8.0
    for k in range(34, 37):
        _reckon_one(gp, k, *_field_stance(rng, math.radians(60.0), steel))
    # steel fixed in the building frame turns with the foot in the body frame: the same field, read 60 deg on
    assert math.degrees(gp.est.heading) == pytest.approx(60.0, abs=12.0)


def test_low_rate_stream_has_no_gap_where_the_device_lowers_its_rate() -> None:
    """200 Hz (decimated to 25 Hz) then 25 Hz: the decimator's held-back group delay comes out at the switch,
    in one piece or many alike."""
    from energy.gait_dr import _LowRate

    t = np.concatenate([np.arange(0, 400) / 200.0, 2.0 + np.arange(1, 60) / 25.0])
    x = np.c_[np.sin(t), np.cos(t), t, np.zeros((len(t), 4))]
    outs = []
    for cuts in ([len(t)], [150, 399, 401, 430, len(t)]):
        low, lo, ot = _LowRate(25.0), 0, []
        for hi in cuts:
            ot.append(low.process(t[lo:hi], x[lo:hi])[0])
            lo = hi
        outs.append(np.concatenate(ot))
    assert np.max(np.diff(outs[0])) < 2.0 / 25.0  # was 0.36 s: the 0.32-s group delay never came out
    np.testing.assert_array_equal(outs[0], outs[1])


# KF II on real walks: ZUPT-KF throughout (``--mode pdr`` with L0 beyond the walk), the deviation after every
# update. The filter counts as converged at std < 1 deg (HeadingDeviationKF.converged); issue 3 asks the estimate
# to stay within 2 deg of its value at convergence for the rest of the walk.
_GDIN = [f"exp{n:02d}" for n in (6, 11, 13, 14, 15, 16, 17, 18, 19, 20, 21, 22, 23, 25, 27, 28, 31, 32, 33, 34, 35,
                                 36, 37, 41, 42, 43)]


def kf2_movement_after_convergence(rec) -> dict[str, float]:
    """Per behaviour whose KF II converged: the largest |deviation - deviation at convergence| afterwards [deg]."""
    from clients.evaluation.harness import run_engine

    hist: dict[str, list[tuple[float, bool]]] = {}
    learn = GaitPipeline.learn

    def recording_learn(self: GaitPipeline, st: Stance, e: StepEvent, behaviour: str, step_model: bool = True) -> None:
        before = {b: k.n_updates for b, k in self.kf2.items()}
        learn(self, st, e, behaviour, step_model)
        for b, k in self.kf2.items():
            if k.n_updates != before[b]:
                hist.setdefault(b, []).append((k.deviation, k.converged))

    GaitPipeline.learn = recording_learn  # type: ignore[method-assign]
    try:
        run_engine(rec.batch, "pdr", l0_m=1e9)
    finally:
        GaitPipeline.learn = learn  # type: ignore[method-assign]
    out = {}
    for b, h in hist.items():
        conv = [c for _, c in h]
        if any(conv):
            i = conv.index(True)
            d = np.array([x for x, _ in h[i:]])
            out[b] = float(np.degrees(np.max(np.abs(np.angle(np.exp(1j * (d - d[0])))))))
    return out


@pytest.mark.slow
@pytest.mark.parametrize("name", [
    pytest.param(n, marks=pytest.mark.xfail(strict=True, reason=(
        "the observations themselves differ by leg: mean gamma - psi per straight leg 177.2-182.9 deg (two laps, "
        "north legs 178.3 vs 182.6, standard errors 0.2-1.0 deg) with no turn strides in them, so the filter "
        "that tracks them moves by 3.0 deg; a stiffer filter would be stable and wrong"))) if n == "exp23" else n
    for n in _GDIN])
def test_kf2_deviation_stays_within_2_deg_after_convergence(gdin_dir, name: str) -> None:
    from clients.importers.gdin import find_gdin, load_gdin

    entries = {e.name: e for e in find_gdin(gdin_dir)}
    if name not in entries:
        pytest.skip(f"{name} not in this copy of gdin")
    moved = kf2_movement_after_convergence(load_gdin(entries[name]))
    assert all(v <= 2.0 for v in moved.values()), moved


def test_stance_tilt_and_field_come_from_the_same_still_samples() -> None:
    """The compass's tilt and field are averaged over the same low-rate samples, the stance's stillest window.
    Before, the field came from the end of the swing (foot still pitched) and the tilt from the segmenter's
    filtered stance force (heel strike smeared in): on exactly level synthetic stances that tilt erred by 1.35
    deg std and grew with the tilt, which the hard-iron fit took for 15-17 uT of vertical hard iron."""
    from clients.synth import EARTH_FIELD_UT, synthesize
    from models.compass import tilt_from_acc

    rec = synthesize("walk", seed=2)
    b = rec.batch
    gp = GaitPipeline(EngineConfig())
    t = (b.acc_t_ns - b.acc_t_ns[0]) / 1e9
    events, pitch_new, pitch_old, field_err, swings = [], [], [], [], []
    for lo in range(0, len(t), 400):  # 2-s batches at 200 Hz
        sl = slice(lo, lo + 400)
        gp.feed(t[sl], b.acc[sl], b.mag[sl])
        for e in gp.queue:
            if e.index in {x.index for x in events} or gp.mag_at(e) is None:
                continue
            events.append(e)
            pitch_new.append(math.degrees(tilt_from_acc(gp.acc_at(e))[1]))
            pitch_old.append(math.degrees(tilt_from_acc(np.asarray(e.acc_stance))[1]))
            yaw = rec.truth.extra["heading_rad"][np.searchsorted(t, e.t_s)]
            c = np.array([[math.cos(yaw), -math.sin(yaw), 0.0], [math.sin(yaw), math.cos(yaw), 0.0], [0.0, 0.0, 1.0]])
            field_err.append(float(np.linalg.norm(gp.mag_at(e) - c.T @ EARTH_FIELD_UT)))  # the level foot's field
            if e.index in gp.stance_swing:
                swings.append(gp.stance_swing[e.index])
        gp.queue = []
    walking = np.asarray(pitch_new)[[not e.after_rest for e in events]]
    assert len(walking) >= 40
    # the stances are level: 10 mg turn-on bias (<= 0.6 deg per axis) plus noise, no heel strike
    assert np.std(walking) < 0.3 and np.std(np.asarray(pitch_old)[[not e.after_rest for e in events]]) > 2 * np.std(walking)
    assert np.median(field_err) < 1.0
    # the swings between stances pitch the foot: their field changes direction, not magnitude
    sw = np.concatenate(swings)
    assert len(swings) >= 40 and all(len(s) <= 8 for s in swings)
    assert np.ptp(sw[:, 2]) > 10.0 and np.std(np.linalg.norm(sw, axis=1)) < 1.0


def _stillest_reference(a: np.ndarray, n: int, threshold: float, g0: float) -> int:
    """The quietest window search as the numpy loop wrote it before it was compiled."""
    best, best_q = 0, math.inf
    for k in range(max(a.shape[0] - n + 1, 1)):
        w = a[k:k + n]
        mu = w.mean(axis=0)
        mu2 = float(mu @ mu)
        q = math.sqrt(max(float(np.mean(np.sum(w * w, axis=1))) - mu2, 0.0) + (math.sqrt(mu2) - g0) ** 2)
        if k and q >= threshold:
            break
        if q < best_q:
            best, best_q = k, q
    return best


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), m=st.integers(4, 40), n=st.integers(2, 6),
       noise=st.sampled_from([0.01, 0.1, 0.5, 2.0]))
def test_stillest_window_equals_the_numpy_search(seed: int, m: int, n: int, noise: float) -> None:
    """The compiled stance-window search picks the same window as the numpy loop (quiet stances with
    heel-strike ringing at the start and the foot moving again at the end)."""
    from energy.gait_dr import _stillest_window

    rng = np.random.default_rng(seed)
    a = np.tile([0.5, -0.3, -9.78], (m, 1)) + rng.normal(0.0, noise, (m, 3))
    a[: rng.integers(0, 3)] += rng.normal(0.0, 3.0, 3)  # heel strike
    a[m - rng.integers(0, 4):] += rng.normal(0.0, 4.0, 3)  # the foot lifts
    for thr in (0.3, 1.0, 5.0):
        assert _stillest_window(a, n, thr, 9.80665) == _stillest_reference(a, n, thr, 9.80665)


def _event_fields_reference(tm: np.ndarray, ma: np.ndarray, mv: np.ndarray, t_s: float, hi_s: float, dt: float,
                            n: int, thr: float, t0: float, t_end: float, gap: float) -> tuple:
    """The stance window, swing rows and stride peak as the numpy code found them before they were compiled."""
    from energy.gait_dr import _stillest_window

    stance = None
    idx = np.arange(int(tm.searchsorted(t_s - 1e-6, "left")), int(tm.searchsorted(hi_s, "right")))
    if idx.size and tm[idx[0]] <= t_s + 0.5 * dt:
        gaps = np.flatnonzero(np.diff(tm[idx]) > 1.5 * dt)
        if gaps.size:
            idx = idx[: gaps[0] + 1]
        best = idx[:n]
        if idx.size > n:
            k = _stillest_window(ma[idx[0]:idx[-1] + 1], n, thr, 9.80665)
            best = idx[k:k + n]
        stance = (ma[best].mean(axis=0), mv[best].mean(axis=0), float(tm[best[-1]]))
    swing = None
    lo, hi = int(tm.searchsorted(t0 + 1e-6, "right")), int(tm.searchsorted(t_s - 1e-6, "left"))
    if not (hi - lo < 2 or tm[lo] - t0 > gap or t_s - tm[hi - 1] > gap or float(np.diff(tm[lo:hi]).max()) > gap):
        swing = (lo, hi)
    peak = None
    lo, hi = int(tm.searchsorted(t0 - 1e-6, "left")), int(tm.searchsorted(t_end + 1e-6, "right"))
    if not (hi - lo < 2 or tm[lo] - t0 > gap or float(np.diff(tm[lo:hi]).max()) > gap):
        peak = float(np.abs(ma[lo:hi]).max())
    return stance, swing, peak


@settings(max_examples=80, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), m=st.integers(0, 60), n=st.integers(2, 6), pause=st.booleans())
def test_step_event_kernels_equal_the_numpy_form(seed: int, m: int, n: int, pause: bool) -> None:
    """The compiled stance window (with its means), swing rows and stride peak give what the array code gave,
    to the bit: 25 Hz field samples with jitter, sometimes a pause of the magnetometer, onsets anywhere."""
    from energy.gait_dr import _event_fields, _row_mean, _stance_rows, _stride_peak_of, _swing_rows

    rng = np.random.default_rng(seed)
    dt = 0.04
    tm = 10.0 + np.cumsum(dt * (1.0 + rng.uniform(-0.1, 0.1, m)))
    if pause and m > 4:
        tm[m // 2:] += rng.uniform(0.05, 0.5)
    ma = np.tile([0.5, -0.3, -9.78], (m, 1)) + rng.normal(0.0, rng.choice([0.01, 0.5, 3.0]), (m, 3))
    mv = rng.normal(0.0, 30.0, (m, 3))
    gap = 1.5 * dt
    for _ in range(6):
        t_s = 10.0 + rng.uniform(-0.2, 2.6)
        hi_s = t_s + (n - 1 + 5) * dt + 1e-6
        t0 = t_s - rng.uniform(0.1, 1.5)
        t_end = t_s + rng.uniform(-0.1, 0.5)
        for thr in (0.3, 5.0):
            stance, swing, peak = _event_fields_reference(tm, ma, mv, t_s, hi_s, dt, n, thr, t0, t_end, gap)
            b0, b1 = _stance_rows(tm, ma, t_s, hi_s, dt, n, thr, 9.80665)
            if stance is None:
                assert b0 < 0
            else:
                assert _row_mean(ma, b0, b1).tobytes() == stance[0].tobytes()
                assert _row_mean(mv, b0, b1).tobytes() == stance[1].tobytes()
                assert float(tm[b1 - 1]) == stance[2]
            lo, hi = _swing_rows(tm, t0, t_s, gap)
            assert (None if lo < 0 else (lo, hi)) == swing
            ok, pk = _stride_peak_of(tm, ma, t0, t_end, gap)
            assert (float(pk) if ok else None) == peak
            # the three in one call (a new step event): the swing after a window only, the peak to its end
            b0, acc, mag, t_win, lo, hi, ok, pk = _event_fields(tm, ma, mv, t_s, hi_s, dt, n, thr, 9.80665, t0, 10.0,
                                                                t0, gap)
            assert (b0 < 0) == (stance is None)
            if stance is not None:
                assert (acc.tobytes(), mag.tobytes(), float(t_win)) == (stance[0].tobytes(), stance[1].tobytes(),
                                                                        stance[2])
            assert (None if lo < 0 else (lo, hi)) == (None if stance is None else swing)
            t_to = -np.inf if stance is None else stance[2]
            assert (float(pk) if ok else None) == _event_fields_reference(tm, ma, mv, t_s, hi_s, dt, n, thr, t0, t_to,
                                                                          gap)[2]
