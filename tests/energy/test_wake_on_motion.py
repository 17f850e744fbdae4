"""Wake-on-motion gyroscope: the device wakes it from the accelerometer alone, energy is charged from the wake,
the scheduler asks for it on a new user's first stand, and the engine navigates the walk that starts the
gyroscope on its own (first stride included), chunk-invariant and restorable."""

from __future__ import annotations

import numpy as np
import pytest

from clients.synth import synthesize
from energy.device import GYRO_TURN_ON_S, DeviceEmulator, replay
from energy.engine import Engine
from energy.power import Timeline
from energy.types import SensorConfig
from models.batch import SensorBatch

WAKE = SensorConfig(gyro_on=False, acc_rate_hz=25.0, gyr_rate_hz=200.0, mag_rate_hz=0.0, gyro_wake_on_motion=True,
                    wake_threshold_ms2=0.5, sleep_after_s=1.0)


@pytest.fixture(scope="module")
def day():
    """The mixed day's first 60 s: 40 s standing, then a slow walk (truth included)."""
    rec = synthesize("mixed-day", seed=0)
    t0 = int(rec.batch.t_start_ns or 0)
    return rec, rec.batch.time_slice(None, t0 + int(60e9))


def onset_s(batch: SensorBatch, after_s: float, thr: float = 0.5) -> float:
    """First native accelerometer sample after ``after_s`` departing from the still foot by ``thr`` [s]."""
    t, a = batch.stream("acc")
    ts = (t - t[0]) / 1e9
    ref = a[(ts > after_s - 5) & (ts < after_s - 4)].mean(axis=0)
    m = ts > after_s - 4
    return float(ts[m][np.argmax(np.abs(a[m] - ref).max(axis=1) > thr)])


def test_refuses_contradictory_or_incomplete_wake_configs() -> None:
    with pytest.raises(ValueError, match="gyro_on must be False"):
        SensorConfig(gyro_on=True, acc_rate_hz=200.0, gyr_rate_hz=200.0, mag_rate_hz=0.0, gyro_wake_on_motion=True,
                     wake_threshold_ms2=0.5, sleep_after_s=1.0)
    for bad in ({"wake_threshold_ms2": 0.0}, {"sleep_after_s": float("nan")}, {"gyr_rate_hz": 0.0}):
        kw = {**WAKE.to_dict(), **bad}
        with pytest.raises(ValueError, match="positive finite"):
            SensorConfig(**kw)
    assert SensorConfig(**WAKE.to_dict()) == WAKE  # the server's JSON form round-trips


def _emit_seconds(batch, cfg: SensorConfig, stream: str, seconds: int = 60) -> tuple[np.ndarray, list]:
    """A device on ``batch`` under one configuration, emitting 1-s batches: the ``stream``'s sample times [s
    from the recording's start] and the spans it ran (``DeviceEmulator.last_spans``, concatenated)."""
    dev = DeviceEmulator(batch)
    t0 = int(batch.t_start_ns or 0)
    times, spans = [], []
    for k in range(seconds):
        out = dev.emit(t0 + k * 10**9, t0 + (k + 1) * 10**9, cfg)
        times.append(out.stream(stream)[0])
        spans += dev.last_spans
    return (np.concatenate(times) - t0) / 1e9, spans


def test_device_wakes_the_gyro_from_the_accelerometer_alone(day) -> None:
    """Configuration never changes: the gyroscope sleeps through the stand and starts when the foot moves."""
    _, batch = day
    t0 = int(batch.t_start_ns or 0)
    g, spans = _emit_seconds(batch, WAKE, "gyr")
    motion = onset_s(batch, 40.0)
    assert len(g) > 1000
    assert g[0] >= motion + GYRO_TURN_ON_S - 1e-6  # nothing before the motion plus the turn-on time
    assert g[0] <= motion + 1 / 25 + GYRO_TURN_ON_S + 0.006  # detected within one 25-Hz period
    on = [(a, b) for a, b, _, gyr, _ in spans if gyr > 0]
    wake = (on[0][0] - t0) / 1e9
    assert motion <= wake <= motion + 1 / 25 + 1e-6  # charged from the detector's decision...
    assert abs(wake + GYRO_TURN_ON_S - g[0]) < 0.006  # ... which is the turn-on time before the first sample
    assert all(b <= a2 for (_, b), (a2, _) in zip(on[:-1], on[1:]))
    # awake: the accelerometer shares the gyroscope's rate
    rates = {acc for a, b, acc, gyr, _ in spans if gyr > 0 and (a - t0) / 1e9 > wake + GYRO_TURN_ON_S}
    assert rates == {200.0}


def test_device_puts_the_gyro_down_after_the_inactivity_duration(day) -> None:
    """A gyroscope left on by the host sleeps ``sleep_after_s`` after the foot stopped moving."""
    _, batch = day
    dev = DeviceEmulator(batch)
    t0 = int(batch.t_start_ns or 0)
    on = SensorConfig(gyro_on=True, acc_rate_hz=200.0, gyr_rate_hz=200.0, mag_rate_hz=0.0)
    dev.emit(t0, t0 + 10**9, on)
    out = dev.emit(t0 + 10**9, t0 + 3 * 10**9, WAKE)
    g = (out.stream("gyr")[0] - t0) / 1e9
    assert len(g) and 1.9 <= g[-1] <= 2.01  # standing still: 1 s after the first sample under the new config
    assert [s[3] for s in dev.last_spans] == [200.0, 0.0]


def test_the_magnetometer_sleeps_and_wakes_with_the_gyro(day) -> None:
    """With ``mag_follows_gyro`` the magnetometer sends nothing and is not charged while the gyroscope sleeps;
    awake, it samples at its rate (without it, it samples throughout, as before)."""
    _, batch = day
    t0 = int(batch.t_start_ns or 0)
    base = {**WAKE.to_dict(), "mag_rate_hz": 50.0}
    for follows in (True, False):
        cfg = SensorConfig(**{**base, "mag_follows_gyro": follows})
        m, spans = _emit_seconds(batch, cfg, "mag")
        awake = [((a - t0) / 1e9, (b - t0) / 1e9) for a, b, _, gyr, _ in spans if gyr > 0]
        inside = np.zeros(len(m), dtype=bool)
        for a, b in awake:
            inside |= (m >= a) & (m < b)
        if follows:
            assert inside.all() and len(m) > 0.8 * 50.0 * sum(b - a for a, b in awake) - 50
            assert all((mag > 0) == (gyr > 0) for _, _, _, gyr, mag in spans)
        else:
            assert (~inside).sum() > 0.9 * 50.0 * 40.0  # the 40-s stand
            assert all(mag == 50.0 for *_, mag in spans)


def test_energy_is_charged_from_the_wake_only(day) -> None:
    rec, batch = day
    res = replay(Engine(mode="auto"), batch, batch_seconds=None)
    t0 = int(batch.t_start_ns or 0)
    wake = [i for i, (_, c) in enumerate(res.configs) if c.gyro_wake_on_motion]
    assert wake, "the scheduler never asked for wake-on-motion on the new user's first stand"
    asleep = sum(b - a for i in wake for a, b, _, gyr, _ in res.spans[i] if gyr == 0) / 1e9
    assert asleep > 30.0  # most of the 40-s stand
    tl = Timeline.from_replay(res, int(batch.t_end_ns or 0))
    on_s = sum(iv.t1_s - iv.t0_s for iv in tl.intervals if iv.gyr_rate_hz > 0)
    assert abs(on_s - res.gyro_on_fraction * (int(batch.t_end_ns or 0) + 1 - t0) / 1e9) < 1e-3
    # the batch in which the foot starts moving is charged only from the wake
    motion = onset_s(batch, 40.0)
    k = max(i for i, (t, _) in enumerate(res.configs) if (t - t0) / 1e9 <= motion)
    charged = sum(b - a for a, b, _, gyr, _ in res.spans[k] if gyr > 0) / 1e9
    end = (res.configs[k + 1][0] - res.configs[k][0]) / 1e9
    assert 0 < charged < end - (motion - (res.configs[k][0] - t0) / 1e9) + 1e-6


def test_engine_navigates_a_walk_that_starts_with_the_gyro_asleep(day) -> None:
    """The first stride after the stand comes from the self-started segment's own samples."""
    rec, batch = day
    res = replay(Engine(mode="auto"), batch, batch_seconds=None)
    t0 = int(batch.t_start_ns or 0)
    tr = rec.truth
    walk = [p for p in res.positions if (p.t_ns - t0) / 1e9 > 40.0]
    assert len(walk) >= 10
    first = walk[0]
    assert first.mode == "zupt" and first.gyro_on
    k = np.searchsorted(tr.t_ns, [p.t_ns for p in walk])
    truth = tr.positions[np.minimum(k, len(tr.t_ns) - 1), :2] - tr.positions[0, :2]
    est = np.array([[p.north, p.east] for p in walk])
    first_truth = float(np.linalg.norm(truth[0]))
    assert abs(first.step_length_m - first_truth) < 0.25 * first_truth
    # a straight stretch: rotation-free comparison of the distances walked
    d_est, d_true = np.linalg.norm(est[:8], axis=1), np.linalg.norm(truth[:8], axis=1)
    assert np.abs(d_est - d_true).max() < 0.3


def _device_output(batch: SensorBatch) -> SensorBatch:
    """What the device sent in a replay (wake-on-motion included), as one recording."""
    parts: list[SensorBatch] = []
    eng = Engine(mode="auto")
    dev = DeviceEmulator(batch)
    t0, t_end = int(batch.t_start_ns or 0), int(batch.t_end_ns or 0)
    t = t0
    while t <= t_end:
        c = eng.sensor_config
        t1 = min(t + int(c.batch_s * 1e9), t_end + 1)
        out = dev.emit(t, t1, c)
        eng.feed(out)
        parts.append(out)
        t = t1
    return SensorBatch.concat(parts)


def test_self_started_segment_is_chunk_invariant_and_restorable(day) -> None:
    _, batch = day
    sent = _device_output(batch)
    t0 = int(sent.t_start_ns or 0)

    def run(cuts_s: list[float], restore_at: float | None = None) -> np.ndarray:
        eng = Engine(mode="auto")
        edges = [None] + [t0 + int(c * 1e9) for c in cuts_s] + [None]
        ups = []
        for a, b in zip(edges[:-1], edges[1:]):
            ups.append(eng.feed(sent.time_slice(a, b)))
            if restore_at is not None and b is not None and b == t0 + int(restore_at * 1e9):
                eng = Engine.from_bytes(eng.to_bytes())
        ups.append(eng.flush())
        return np.array([[p.t_ns, p.north, p.east, p.down, p.step_length_m] for u in ups for p in u.positions])

    whole = run([])
    assert len(whole) >= 10
    for cuts, restore in (([40.83, 40.91, 41.2, 42.05], None), ([13.0, 40.9, 41.3, 47.7], 40.9), ([41.1], 41.1)):
        got = run(cuts, restore)
        assert got.shape == whole.shape
        np.testing.assert_array_equal(got[:, 0], whole[:, 0])
        assert np.abs(got[:, 1:] - whole[:, 1:]).max() <= 1e-9


def test_a_short_gyro_power_down_ends_the_segment_a_dropout_does_not() -> None:
    """A device that powers its gyroscope down and up again within 0.12 s (accelerometer still sampling) ends
    the ZUPT-KF segment: the filter must not bridge the gap at the foot's first motion. A dropout of all streams
    that short does not (only gaps over 0.25 s do)."""
    from energy import engine as engine_mod

    b = synthesize("walk", seed=3).batch.time_slice(None, None)
    t0 = int(b.t_start_ns or 0)
    (at, a), (gt, g), (mt, m) = b.stream("acc"), b.stream("gyr"), b.stream("mag")

    def cut(t: np.ndarray, lo: float = 3.0, hi: float = 3.12) -> np.ndarray:
        return ~((t >= t0 + int(lo * 1e9)) & (t < t0 + int(hi * 1e9)))

    starts = {}
    for name, drop_acc in (("power-down", False), ("dropout", True)):
        ka = cut(at) if drop_acc else np.ones(len(at), dtype=bool)
        batch = SensorBatch(acc_t_ns=at[ka], acc=a[ka], gyr_t_ns=gt[cut(gt)], gyr=g[cut(gt)], mag_t_ns=mt, mag=m)
        eng = engine_mod.Engine(mode="auto")
        seen: list[float] = []
        orig = eng._ingest

        def spy(*args, _orig=orig, _seen=seen, _eng=eng, **kw):  # type: ignore[no-untyped-def]
            n = len(_eng._ops)
            out = _orig(*args, **kw)
            _seen += [op[1] for op in _eng._ops[n:] if op[0] == "start"]
            return out

        eng._ingest = spy  # type: ignore[method-assign]
        eng.feed(batch)
        starts[name] = seen
    assert len(starts["dropout"]) == 1
    assert len(starts["power-down"]) == 2 and 3.12 <= starts["power-down"][1] <= 3.13


def test_high_g_wake_takes_the_absolute_specific_force_not_its_departure(day) -> None:
    """``wake_mode="high_g"``: the largest absolute specific force on an axis decides, to within the 40-ms means
    the detector sees; a still foot (|a| = g) never wakes it."""
    rec, batch = day
    t, a = batch.stream("acc")
    ts = (t - t[0]) / 1e9
    k = int(round(batch.rate_hz("acc") / 25.0))
    n = len(a) // k * k
    means = a[:n].reshape(-1, k, 3).mean(axis=1)  # what the detector sees: 40-ms means
    peak = float(np.abs(means).max())
    for thr, wakes in ((peak * 1.02, False), (peak * 0.9, True)):
        cfg = SensorConfig(**{**WAKE.to_dict(), "wake_mode": "high_g", "wake_threshold_ms2": thr})
        g, spans = _emit_seconds(batch, cfg, "gyr")
        assert (len(g) > 0) == wakes, thr
        if wakes:  # at the first 40-ms mean beyond the threshold, and never during the stand
            first = float(ts[k - 1 :: k][: len(means)][np.argmax(np.abs(means).max(axis=1) > thr)])
            assert abs(g[0] - (first + GYRO_TURN_ON_S)) < 0.006 and g[0] > 40.0
    with pytest.raises(ValueError, match="wake_mode"):
        SensorConfig(**{**WAKE.to_dict(), "wake_mode": "shake"})


def test_the_device_wakes_the_gyro_at_a_run_while_gait_dr_walks_without_a_run_model() -> None:
    """The demo's first walk: Gait-DR walks on a walking calibration when the person breaks into a run. The
    device's high-g interrupt turns the gyroscope on within a stride of the run; before, the host heard of the run
    after the recognition delay and a 4-s upload, and Gait-DR placed the first 8 running strides with the walking
    model (1.1-1.8 m for 2.2-2.4 m)."""
    rec = synthesize("demo", seed=0)
    res = replay(Engine(mode="auto"), rec.batch, None)
    t0 = int(rec.batch.t_start_ns or 0)
    run_t0 = min(a for a, _, lab in rec.truth.extra["segments"] if lab == "run")
    assert any(c.gyro_wake_on_motion and c.wake_mode == "high_g" for t, c in res.configs if (t - t0) / 1e9 < run_t0)
    run = [p for p in res.positions if run_t0 < (p.t_ns - t0) / 1e9 < run_t0 + 25.0]  # the run segment
    first_zupt = next(i for i, p in enumerate(run) if p.mode == "zupt")
    assert first_zupt <= 2, [(round((p.t_ns - t0) / 1e9, 2), p.mode) for p in run[:10]]


# ---------------------------------------------------------------- weak-field wake (SensorConfig wake_mode "weak_field")
WEAK = SensorConfig(gyro_on=False, acc_rate_hz=25.0, gyr_rate_hz=200.0, mag_rate_hz=25.0, batch_s=4.0,
                    gyro_wake_on_motion=True, sleep_after_s=2.0, wake_mode="weak_field", wake_field_ut=6.6)


def test_weak_field_wake_configs_are_validated_and_round_trip_through_json() -> None:
    import json

    for bad, match in (({"wake_field_ut": 0.0}, "positive finite wake_field_ut"),
                       ({"mag_matrix": (1.0, 0.0, 0.0)}, "9 finite mag_matrix"),
                       ({"mag_offset_ut": (0.0, float("nan"), 0.0)}, "3 finite mag_offset_ut")):
        with pytest.raises(ValueError, match=match):
            SensorConfig(**{**WEAK.to_dict(), **bad})
    assert SensorConfig(**{**WEAK.to_dict(), "wake_threshold_ms2": 0.0}) == WEAK  # no acceleration threshold needed
    back = SensorConfig(**json.loads(json.dumps(WEAK.to_dict())))  # the server's JSON form (lists for tuples)
    assert back == WEAK and isinstance(back.mag_matrix, tuple)
