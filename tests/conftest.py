from __future__ import annotations

import os
from pathlib import Path

import pytest
from hypothesis import settings

from clients.datasets import dataset_dir

# Property-based tests draw the same examples on every run, so that a run (CI's above all) never fails by the luck
# of the draw; HYPOTHESIS_PROFILE=explore draws new ones each run (hypothesis's default) to look for failures
# (one such draw found the step segmentation's dependence on where a stream was cut, tests/models/test_steps.py).
settings.register_profile("repeatable", derandomize=True)
settings.register_profile("explore", derandomize=False)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "repeatable"))


def _require(name: str) -> Path:
    d = dataset_dir(name)
    if d is None:
        pytest.skip(f"dataset '{name}' not found: set PEDNAV_DATA or place ../shared/datasets beside the project")
    return d


@pytest.fixture(scope="session")
def vicon_dir() -> Path:
    return _require("vicon")


@pytest.fixture(scope="session")
def gdin_dir() -> Path:
    return _require("gdin")


@pytest.fixture(scope="session")
def gaitmap_dir() -> Path:
    return _require("gaitmap-mocap")


@pytest.fixture(scope="session")
def gaitmap_mag_dir() -> Path:
    return _require("gaitmap-mag")


@pytest.fixture(scope="session")
def ipin_dir() -> Path:
    return _require("ipin2023-t3-phone") / "logfiles"
