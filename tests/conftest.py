"""Shared fixtures: where the real dataset extracts are; hypothesis held to one sequence of examples.

Tests that need real data take ``data_dir`` and skip with the reason when it is missing,
so a fresh clone without ``../shared/data`` still passes. Hypothesis draws its examples
derandomized (from each test's own fixed seed) and keeps no example database, so every
run, on CI or not, tries the same examples.
"""

import os
from pathlib import Path

import pytest
from hypothesis import settings

REPO_ROOT = Path(__file__).resolve().parents[1]

settings.register_profile("deterministic", derandomize=True, database=None)
settings.load_profile("deterministic")


@pytest.fixture(scope="session")
def data_dir() -> Path:
    """The folder of real extracts: ``$PLD_SLAM_DATA`` or ``<repo>/../shared/data``."""
    path = Path(os.environ.get("PLD_SLAM_DATA", REPO_ROOT.parent / "shared" / "data"))
    if not path.is_dir():
        pytest.skip(f"real data folder {path} not found; set PLD_SLAM_DATA to run these tests")
    return path


def require(path: Path) -> Path:
    """``path`` if it exists, else skip the test saying which extract is missing."""
    if not path.exists():
        pytest.skip(f"{path} not found; set PLD_SLAM_DATA to a folder holding the extracts")
    return path
