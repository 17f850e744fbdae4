from __future__ import annotations

from pathlib import Path

import pytest

from clients.datasets import dataset_dir


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
