"""High-dynamics input is taken: running and sprinting recordings fed to the engine upload by upload are never
refused and never crash (a per-batch median check refused every sprinting second, 'median |a| = 91 m/s^2 is
implausible'; 192 of 2100 uploads of the dev running trials and synthetic sprints)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from clients.synth import LSM9DS1_CLIPPING, synthesize
from energy.device import desample
from energy.engine import Engine
from models.batch import SensorBatch


def _feed_all(batch: SensorBatch, mode: str) -> int:
    """Feed 1-s uploads and flush; returns the positions (any BatchError or other exception fails the test)."""
    eng = Engine(mode=mode)
    n = sum(len(eng.feed(piece).positions) for piece in batch.split_seconds(1.0))
    return n + len(eng.flush().positions)


@pytest.mark.parametrize("rate_hz", [100.0, 200.0, 800.0])
@pytest.mark.parametrize("mode", ["auto", "zupt"])
def test_a_clipping_sprint_up_to_16_g_and_2000_deg_s_is_taken_upload_by_upload(rate_hz: float, mode: str) -> None:
    rec = synthesize("sprint", rate_hz=rate_hz, errors=LSM9DS1_CLIPPING)
    assert max(float(np.median(np.linalg.norm(p.acc, axis=1))) for p in rec.batch.split_seconds(1.0)) > 80.0
    strides = len(rec.truth.extra["step_t_s"])
    assert _feed_all(rec.batch, mode) >= 0.8 * strides


def _running_trials(vicon_dir: Path) -> list[Path]:
    """The VICON trials that run (datasets/vicon/ABOUT.md: 99th percentile |a| >= 4 g)."""
    from clients.importers import load

    out = []
    for f in sorted(vicon_dir.glob("*.mat")):
        if np.percentile(np.linalg.norm(load(f).batch.acc, axis=1), 99) >= 4 * 9.81:
            out.append(f)
    return out


@pytest.mark.slow
def test_every_vicon_running_trial_is_taken_at_200_and_100_hz(vicon_dir: Path) -> None:
    from clients.importers import load

    trials = _running_trials(vicon_dir)
    assert len(trials) >= 15
    for f in trials:
        b = load(f).batch
        for batch in (b, desample(b, 100.0)):
            assert _feed_all(batch, "auto") > 10, f.name
