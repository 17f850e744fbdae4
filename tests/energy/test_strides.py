"""Strides that moved: the definition, the threshold against the VICON truth, the count against gdin's per-stride
truth."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from clients.evaluation import harness
from clients.importers.gdin import find_gdin, load_gdin
from energy.strides import STRIDE_MIN_M, count_moved, moved


def _walk_with_restances(strides: list[float], restances: int, jitter_m: float, heading: float) -> np.ndarray:
    """Positions of a walk of ``strides`` [m] along ``heading`` [rad], then ``restances`` re-stances on the spot,
    each within ``jitter_m`` of the last stride's end."""
    u = np.array([np.cos(heading), np.sin(heading)])
    p = np.vstack([[0.0, 0.0], np.cumsum(np.array(strides)[:, None] * u, axis=0)])
    rng = np.random.default_rng(0)
    a = rng.uniform(0.0, 2 * np.pi, restances)
    r = jitter_m * rng.uniform(0.0, 1.0, restances)
    spot = p[-1] + np.column_stack([r * np.cos(a), r * np.sin(a)])
    return np.vstack([p, spot])


@given(strides=st.lists(st.floats(0.12, 2.5), min_size=0, max_size=30), restances=st.integers(0, 20),
       heading=st.floats(-np.pi, np.pi), shift=st.floats(-1e4, 1e4))
def test_strides_count_and_restances_on_the_spot_do_not(strides: list[float], restances: int, heading: float,
                                                        shift: float) -> None:
    # re-stances within 4 cm of one another never add up to a stride, wherever and whichever way one walks
    ne = _walk_with_restances(strides, restances, 0.02, heading) + shift
    assert count_moved(ne) == len(strides)
    down = np.column_stack([ne, np.linspace(0.0, -3.0, len(ne))])  # a third (down) column is ignored
    assert count_moved(down) == len(strides)
    assert moved(ne).shape == (len(ne) - 1,)


def test_threshold_is_inclusive_and_shapes_are_checked() -> None:
    ne = np.array([[0.0, 0.0], [STRIDE_MIN_M, 0.0], [STRIDE_MIN_M, 0.0999], [STRIDE_MIN_M, 0.0999]])
    assert moved(ne).tolist() == [True, False, False]
    assert count_moved(ne[:1]) == 0 and count_moved(np.zeros((0, 2))) == 0
    assert count_moved(ne, min_m=0.05) == 2
    with pytest.raises(ValueError, match="shape"):
        moved(np.zeros(5))


# ---------------------------------------------------------------------------------------------- real recordings
@pytest.mark.slow
def test_vicon_restances_stay_under_the_threshold(vicon_dir: Path) -> None:
    """The threshold's evidence: wherever the motion-capture truth says the foot moved less than 5 cm between two
    consecutive stances, the engine's displacement is below STRIDE_MIN_M; the truth's real strides of at least
    0.13 m (slow and shuffling walking) are counted."""
    still, short = [], []
    for f in harness.vicon_files(vicon_dir):
        rec = harness.load_vicon_trial(f)
        run = harness.run_engine(rec.batch, "zupt")
        t = run.stances[:, 0].astype(np.int64)
        if t.size < 2:
            continue
        i = np.clip(np.searchsorted(rec.truth.t_ns, t), 0, rec.truth.t_ns.size - 1)
        truth = np.linalg.norm(np.diff(rec.truth.positions[i, :2], axis=0), axis=1)
        est = np.linalg.norm(np.diff(run.stances[:, 1:3], axis=0), axis=1)
        still += list(est[truth < 0.05])
        short += list(moved(run.stances[:, 1:3])[(truth >= 0.13) & (truth < 0.3)])
    assert len(still) > 300 and max(still) < STRIDE_MIN_M
    assert len(short) > 30 and np.mean(short) > 0.9


_GDIN_STRIDE_TRUTH = ("exp31", "exp32", "exp33", "exp34", "exp35", "exp36", "exp37", "exp41", "exp42", "exp43")
# exp43 (250 Hz, no magnetometer, 1.66-m strides) had stances inside three strides (0.12-0.23 m from the previous
# stance, 0.30-0.37 s after toe-off at 2.8-3.4 m/s: +5.0 % in zupt) until ZuptConfig.swing_min_s went 0.3 -> 0.4 s
# (the shortest fast real swing before a stride: 0.435 s); now counted strictly like the others.


@pytest.fixture(scope="module")
def gdin_counts(gdin_dir: Path) -> dict[tuple[str, str], tuple[int, int, int]]:
    """(mode, recording) -> (strides that moved, positions reported, true strides)."""
    out: dict[tuple[str, str], tuple[int, int, int]] = {}
    entries = {e.name: e for e in find_gdin(gdin_dir)}
    for name in _GDIN_STRIDE_TRUTH:
        if name not in entries:
            continue
        rec = load_gdin(entries[name])
        for mode in ("zupt", "pdr"):
            st = harness.run_engine(rec.batch, mode).stances
            out[(mode, name)] = (count_moved(st[:, 1:3]), st.shape[0], int(rec.truth.extra["number_of_strides"]))
    return out


@pytest.mark.slow
@pytest.mark.parametrize("mode", ["zupt", "pdr"])
@pytest.mark.parametrize("name", _GDIN_STRIDE_TRUTH)
def test_gdin_stride_count_within_2pct_of_the_footprints(gdin_counts: dict, mode: str, name: str) -> None:
    if (mode, name) not in gdin_counts:
        pytest.skip(f"{name} not in the gdin folder")
    n, positions, truth = gdin_counts[(mode, name)]
    assert abs(n - truth) <= 0.02 * truth, f"{name} {mode}: {n} strides that moved against {truth} footprints"
    assert positions - 1 >= n  # the re-stances are reported, only not counted
