"""Shared fixtures."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import rerun as rr
from scene_helpers import write_scene_folder


@pytest.fixture(autouse=True)
def _strict_rerun():
    rr.set_strict_mode(True)
    yield


@pytest.fixture
def scene_folder(tmp_path: Path) -> Path:
    return write_scene_folder(tmp_path / "tiny")


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(0)
