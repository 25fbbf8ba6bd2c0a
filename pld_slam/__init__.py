"""PLD-SLAM: stereo point-line SLAM that stays accurate in dynamic scenes.

OpenBLAS runs single-threaded unless the user says otherwise (``OPENBLAS_NUM_THREADS``,
set here; it takes effect when numpy is first imported after this package, as in the
``pld-slam`` command): the pipeline's dense algebra is small (6 x 6 to a few hundred
columns), the front end already runs on the other core (`pld_slam.frame_extraction`), and
OpenBLAS's threads only spin. Measured on KITTI 06 with another process on the 2-core
machine: local BA median 852 ms per keyframe with OpenBLAS's threads, 163 ms with one;
the whole run 735 against 292-368 ms per frame. A program that imported numpy first still
gets one BLAS thread while a `System` calibrates and runs (`pld_slam.blas.one_blas_thread`).
"""

import os
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
# Before any numba import: the compiled kernels' cache folder (see `pld_slam.jit`).
os.environ.setdefault(
    "NUMBA_CACHE_DIR",
    str(Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "pld-slam" / "numba"),
)

from pld_slam.errors import ConfigError, DatasetError, PldSlamError, TrajectoryError  # noqa: E402

__version__ = "0.1.0"

__all__ = ["ConfigError", "DatasetError", "PldSlamError", "TrajectoryError", "__version__"]
