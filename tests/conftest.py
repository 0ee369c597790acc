"""Shared fixtures."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import rerun as rr

from tests.helpers.scenes import write_scene_folder


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


def pytest_unconfigure(config):
    """Leave without interpreter teardown once pytest has reported.

    OMPL's nanobind bindings print dozens of harmless "nanobind: leaked ..." lines at
    interpreter exit (a known binding issue), burying pytest's closing summary; the
    exit status is pytest's own.
    """
    import os
    import sys

    if "ompl" in sys.modules and not hasattr(config, "workerinput"):
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(getattr(config, "_mmwsim_exitstatus", 0))


def pytest_sessionfinish(session, exitstatus):
    session.config._mmwsim_exitstatus = int(exitstatus)
