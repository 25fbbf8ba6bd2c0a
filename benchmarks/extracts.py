"""The real dataset extracts the benchmarks run on, found through ``$PLD_SLAM_DATA``.

The extracts live outside the repository (``../shared/data`` by default); a benchmark
skips, saying so, the ones it cannot find.
"""

import os
from pathlib import Path

from pld_slam.datasets import StereoSequence, open_sequence

REAL_EXTRACTS = (
    "kitti_odometry/sequences/06",
    "kitti_raw/2011_09_26/2011_09_26_drive_0005_sync",
    "euroc/V1_01_easy_static",
    "euroc/V1_01_easy_flight",
)
"""Every real extract with ground truth, relative to the data folder."""


def data_dir() -> Path:
    """``$PLD_SLAM_DATA``, or ``../shared/data`` next to the repository."""
    return Path(os.environ.get("PLD_SLAM_DATA", Path(__file__).resolve().parents[2] / "shared" / "data"))


def existing_extracts(relatives: tuple[str, ...] = REAL_EXTRACTS) -> list[Path]:
    """The folders of ``relatives`` that exist in `data_dir`; each missing one is reported."""
    found = []
    for relative in relatives:
        folder = data_dir() / relative
        if folder.is_dir():
            found.append(folder)
        else:
            print(f"skipped {folder}: not found (set PLD_SLAM_DATA)")
    return found


def real_sequences(relatives: tuple[str, ...] = REAL_EXTRACTS) -> list[StereoSequence]:
    """The `StereoSequence` of each extract of ``relatives`` found (`existing_extracts`)."""
    return [open_sequence(folder) for folder in existing_extracts(relatives)]
