"""Shared, generic fixtures."""

from pathlib import Path

import pytest

import torchquat


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """The directory of real benchmark pose files (../shared/data beside the repository)."""
    path = Path(__file__).resolve().parents[1].parent / "shared" / "data"
    if not path.is_dir():
        pytest.skip(f"real pose files not found at {path} (they live outside the repository)")
    return path


@pytest.fixture
def compiled(monkeypatch):
    """The compiled kernels switched on for one test."""
    torchquat.use_compiled_kernels(True)
    yield
    torchquat.use_compiled_kernels(False)
