"""A long stand: the engine state stays the same size, and cuts and restores inside it change nothing."""

from __future__ import annotations

import numpy as np
import pytest

from clients.synth import Scenario, Segment, synthesize
from energy.device import DeviceEmulator
from energy.engine import Engine
from models.batch import STREAMS, SensorBatch

STAND_MIN = 60.0  # [min]
MARKS_MIN = (10.0, STAND_MIN - 1.0)  # standing times at which the state size is taken [min]


class _Recording(SensorBatch):
    """A recording whose time slices are found by bisection (its streams are in time order): the same slices
    as :meth:`SensorBatch.time_slice`, whose masks over the whole recording made an hour's replay take 20 s."""

    def time_slice(self, t0_ns: int | None, t1_ns: int | None) -> SensorBatch:
        kw: dict[str, np.ndarray] = {}
        for name in STREAMS:
            t, v = self.stream(name)
            lo = 0 if t0_ns is None else int(np.searchsorted(t, t0_ns, "left"))
            hi = t.size if t1_ns is None else int(np.searchsorted(t, t1_ns, "left"))
            kw[f"{name}_t_ns"], kw[name] = t[lo:hi], v[lo:hi]
        return SensorBatch(**kw)


@pytest.fixture(scope="module")
def long_stand():
    """Walk 60 s, stand 60 min, walk 30 s (synthetic, 200 Hz) and the time the long stand starts [ns]."""
    segments = (Segment("stand", 10.0), Segment("walk", 60.0, 90.0), Segment("stand", 60.0 * STAND_MIN),
                Segment("walk", 30.0), Segment("stand", 5.0))
    rec = synthesize(Scenario("long-stand", segments), seed=0)
    t0 = min(a for a, _, lab in rec.truth.extra["segments"] if lab == "stand" and a > 5.0)
    kw = {}
    for name in STREAMS:
        kw[f"{name}_t_ns"], kw[name] = rec.batch.stream(name)
    return _Recording(**kw), rec.batch.t_start_ns + int(t0 * 1e9)


@pytest.fixture(scope="module")
def device_runs(long_stand) -> dict[str, tuple[list[SensorBatch], dict[float, int]]]:
    return {}


def _device_run(mode: str, rec: SensorBatch, stand_ns: int) -> tuple[list[SensorBatch], dict[float, int]]:
    """Stream as energy.device.replay does (the device batches as the engine asks); the batches sent and the
    state size [bytes] at the standing times of MARKS_MIN."""
    eng = Engine(mode=mode)
    dev = DeviceEmulator(rec)
    t0, t_end = rec.t_start_ns, rec.t_end_ns
    sent: list[SensorBatch] = []
    sizes: dict[float, int] = {}
    todo = list(MARKS_MIN)
    while t0 <= t_end:
        cfg = eng.sensor_config
        t1 = min(t0 + int(round(cfg.batch_s * 1e9)), t_end + 1)
        sent.append(dev.emit(t0, t1, cfg))
        eng.feed(sent[-1])
        if todo and t1 - stand_ns >= todo[0] * 60e9:
            sizes[todo.pop(0)] = len(eng.to_bytes())
        t0 = t1
    return sent, sizes


def _positions(eng: Engine, pieces: list[SensorBatch], restore_at: int | None = None) -> np.ndarray:
    ups = []
    for k, p in enumerate(pieces):
        if k == restore_at:
            eng = Engine.from_bytes(eng.to_bytes())
        ups.append(eng.feed(p))
    ups.append(eng.flush())
    return np.array([[p.t_ns, p.north, p.east, p.down] for u in ups for p in u.positions])


@pytest.mark.parametrize("mode", ["zupt", "pdr", "auto"])
def test_state_size_does_not_grow_while_standing(long_stand, device_runs, mode: str) -> None:
    """Before the step segmenter collapsed its quiet stretches: pdr 263 kB after 10 min, 1.46 MB after 60."""
    device_runs[mode] = _device_run(mode, *long_stand)
    sizes = device_runs[mode][1]
    small, large = sizes[MARKS_MIN[0]], sizes[MARKS_MIN[1]]
    assert abs(large - small) < 2_000, sizes
    assert large < 40_000, sizes


@pytest.mark.parametrize("mode", ["pdr", "auto"])
def test_cuts_and_a_restore_inside_a_long_stand_change_nothing(long_stand, device_runs, mode: str) -> None:
    """The batches the device sent, re-fed with the stand's batches merged into 7-min pieces, or with a state
    round trip after 30 min of standing: the same positions (to 1e-9 m) as fed as sent."""
    stand_ns = long_stand[1]
    if mode not in device_runs:
        device_runs[mode] = _device_run(mode, *long_stand)
    sent = device_runs[mode][0]
    whole = _positions(Engine(mode=mode), sent)
    mid = next(k for k, b in enumerate(sent) if b.t_start_ns is not None and b.t_start_ns >= stand_ns + int(1800e9))
    restored = _positions(Engine(mode=mode), sent, restore_at=mid)
    inside = [k for k, b in enumerate(sent) if b.t_start_ns is not None
              and stand_ns + int(60e9) <= b.t_start_ns < stand_ns + int((STAND_MIN - 1.0) * 60e9)]
    lo, hi = inside[0], inside[-1] + 1
    step = max(1, int(round(420.0 / (sent[lo + 1].t_start_ns - sent[lo].t_start_ns) * 1e9)))
    merged = sent[:lo] + [SensorBatch.concat(sent[i:min(i + step, hi)]) for i in range(lo, hi, step)] + sent[hi:]
    recut = _positions(Engine(mode=mode), merged)
    assert len(whole) > 40 and len(merged) < len(sent) - 100
    for got in (restored, recut):
        assert got.shape == whole.shape
        np.testing.assert_array_equal(got[:, 0], whole[:, 0])
        assert np.abs(got[:, 1:] - whole[:, 1:]).max() <= 1e-9
