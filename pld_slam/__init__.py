"""PLD-SLAM: stereo point-line SLAM that stays accurate in dynamic scenes."""

import os
from pathlib import Path

# Before any numba import: the compiled kernels' cache folder (see `pld_slam.jit`).
os.environ.setdefault(
    "NUMBA_CACHE_DIR",
    str(Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "pld-slam" / "numba"),
)

from pld_slam.errors import ConfigError, DatasetError, PldSlamError, TrajectoryError  # noqa: E402

__version__ = "0.1.0"

__all__ = ["ConfigError", "DatasetError", "PldSlamError", "TrajectoryError", "__version__"]
