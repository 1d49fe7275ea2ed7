"""Shared pytest fixtures."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from osgd.kernels import pin_kernels

# Before anything imports numpy: the kernels the osgd command pins, so that
# what the tests build in this process and in the processes they start is
# what `osgd` builds (osgd/kernels.py).
pin_kernels()

sys.path.insert(0, str(Path(__file__).resolve().parent))

from helpers import OSGD_MODELS, run_golden  # noqa: E402


@pytest.fixture(scope="session")
def golden_data_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The golden pipeline built once per test session by two worker processes (``helpers.run_golden``): its
    data dir. Tests only read it."""
    data_dir = tmp_path_factory.mktemp("golden-build")
    run_golden(data_dir)
    return data_dir


@pytest.fixture
def osgd_models_dir() -> Path:
    """The paper authors' models in ../shared/osgd-models; skips where absent."""
    if not OSGD_MODELS.is_dir():
        pytest.skip(f"the shared OSGD models are not at {OSGD_MODELS} (clone the original repository there)")
    return OSGD_MODELS
