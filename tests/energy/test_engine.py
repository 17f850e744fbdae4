"""The engine contract of DESIGN.md: chunk invariance, state round trip, refusals, sensor configuration."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from clients.synth import synthesize
from energy.engine import Engine
from models.batch import BatchError, SensorBatch


@pytest.fixture(scope="module")
def walk() -> SensorBatch:
    return synthesize("walk", seed=3).batch.time_slice(None, int(25e9))


def positions(updates: list) -> np.ndarray:
    return np.array([[p.t_ns, p.north, p.east, p.down] for u in updates for p in u.positions])


def run_pieces(batch: SensorBatch, cuts_s: list[float], mode: str = "zupt") -> tuple[Engine, np.ndarray]:
    eng = Engine(mode=mode)
    t0 = batch.t_start_ns
    edges = [None] + [t0 + int(c * 1e9) for c in sorted(cuts_s)] + [None]
    ups = [eng.feed(batch.time_slice(a, b)) for a, b in zip(edges[:-1], edges[1:])]
    ups.append(eng.flush())
    return eng, positions(ups)


@pytest.fixture(scope="module")
def whole(walk: SensorBatch) -> np.ndarray:
    return run_pieces(walk, [])[1]


def test_walk_produces_one_position_per_stride(walk: SensorBatch, whole: np.ndarray) -> None:
    assert len(whole) >= 10
    assert np.all(np.diff(whole[:, 0]) > 0)
    assert np.abs(whole[0, 1:3]).max() < 0.5  # origin at the first stance


@settings(max_examples=6, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(cuts=st.lists(st.floats(0.01, 24.99), max_size=6, unique=True))
def test_chunk_invariance(walk: SensorBatch, whole: np.ndarray, cuts: list[float]) -> None:
    got = run_pieces(walk, cuts)[1]
    assert got.shape == whole.shape
    np.testing.assert_array_equal(got[:, 0], whole[:, 0])
    assert np.abs(got[:, 1:] - whole[:, 1:]).max() <= 1e-9


@pytest.mark.parametrize("cut_s", [3.3, 11.7])
def test_restore_mid_stream_continues_identically(walk: SensorBatch, whole: np.ndarray, cut_s: float) -> None:
    t_cut = walk.t_start_ns + int(cut_s * 1e9)
    eng = Engine(mode="zupt")
    first = [eng.feed(walk.time_slice(None, t_cut))]
    restored = Engine.from_bytes(eng.to_bytes())
    rest = [restored.feed(walk.time_slice(t_cut, None)), restored.flush()]
    got = positions(first + rest)
    assert got.shape == whole.shape and np.abs(got[:, 1:] - whole[:, 1:]).max() <= 1e-9


def test_zupt_mode_always_wants_the_gyro_at_full_rate(walk: SensorBatch) -> None:
    eng = Engine(mode="zupt")
    for piece in walk.split_seconds(5.0):
        cfg = eng.feed(piece).sensor_config
        assert cfg.gyro_on and cfg.acc_rate_hz == 200.0


def test_refuses_samples_older_than_processed(walk: SensorBatch) -> None:
    eng = Engine(mode="zupt")
    eng.feed(walk.time_slice(None, walk.t_start_ns + int(2e9)))
    with pytest.raises(BatchError, match="acc_t_ns: .*not after the last one processed"):
        eng.feed(walk.time_slice(walk.t_start_ns + int(1e9), walk.t_start_ns + int(3e9)))


@pytest.mark.parametrize("stream", ["gyr", "mag"])
def test_a_late_gyroscope_or_magnetometer_sample_is_refused_not_dropped(walk: SensorBatch, stream: str) -> None:
    """A batch that carries the previous batch's gyroscope samples again (they moved the end point 0.29 m when
    they were dropped without a word): refused, naming the stream; nothing of the batch is taken."""
    eng = Engine(mode="auto")
    t0 = walk.t_start_ns
    eng.feed(walk.time_slice(None, t0 + int(2e9)))
    nxt = walk.time_slice(t0 + int(2e9), t0 + int(3e9))
    t_late, v_late = walk.stream(stream)
    keep = (t_late >= t0 + int(1.5e9)) & (t_late < t0 + int(3e9))
    late = SensorBatch(**{**{f"{n}_t_ns": nxt.stream(n)[0] for n in ("acc", "gyr", "mag")},
                          **{n: nxt.stream(n)[1] for n in ("acc", "gyr", "mag")},
                          f"{stream}_t_ns": t_late[keep], stream: v_late[keep]})
    before = eng.to_bytes()
    with pytest.raises(BatchError, match=f"{stream}_t_ns: .*not after the last one received"):
        eng.feed(late)
    assert eng.to_bytes() == before
    eng.feed(nxt)  # the same batch without the stale samples is taken


@pytest.mark.parametrize(
    "mutate, field",
    [
        (lambda b: SensorBatch(b.acc_t_ns, np.where(np.arange(len(b))[:, None] == 5, np.nan, b.acc)), "acc"),
        (lambda b: SensorBatch(b.acc_t_ns[::-1].copy(), b.acc), "acc_t_ns"),
        (lambda b: SensorBatch(b.acc_t_ns, b.acc / 9.80665), "acc"),
        (lambda b: SensorBatch(b.acc_t_ns, b.acc, b.gyr_t_ns, np.degrees(b.gyr) + 100.0), "gyr"),
    ],
)
def test_bad_batches_are_refused_and_nothing_changes(walk: SensorBatch, mutate, field: str) -> None:
    eng = Engine(mode="zupt")
    piece = walk.time_slice(None, walk.t_start_ns + int(2e9))
    before = eng.to_bytes()
    with pytest.raises(BatchError) as err:
        eng.feed(mutate(piece))
    assert err.value.field == field
    assert eng.to_bytes() == before


def test_unknown_mode_and_state_version_are_refused() -> None:
    with pytest.raises(ValueError, match="mode"):
        Engine(mode="fly")  # type: ignore[arg-type]
    state = Engine().get_state()
    state["version"] = 99
    with pytest.raises(ValueError, match="version"):
        Engine.from_state(state)
