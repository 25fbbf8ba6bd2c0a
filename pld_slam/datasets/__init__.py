"""Stereo datasets read into one `StereoSequence`, the layout detected from the folder.

`open_sequence` recognises, in this order:

- ``kitti_odometry`` (`kitti_odometry`): ``image_0/``, ``image_1/``, ``calib.txt``,
  ``times.txt``; also what ``pld-slam synth`` writes;
- ``kitti_raw`` (`kitti_raw`): a ``DATE_drive_NNNN_sync`` folder with ``image_00/``;
- ``euroc`` (`euroc`): an EuRoC ASL sequence (``mav0/``) or its ``mav0`` folder;
- ``generic`` (`generic`): ``left/``, ``right/``, ``calib.yaml`` (schema in its docstring).

Every problem with the input is a one-line `DatasetError` naming the file or folder.
Malformed ground-truth rows are the exception to the type: the trajectory readers of
`pld_slam.io.trajectory` raise `TrajectoryError` naming ``file:line``, and we let it
through unchanged, because it is already one line of the same `PldSlamError` family the
CLI reports, and wrapping it would only repeat the message.
"""

from pathlib import Path

from pld_slam.datasets import euroc, generic, kitti_odometry, kitti_raw
from pld_slam.datasets.base import StereoFrame, StereoSequence
from pld_slam.errors import DatasetError

LAYOUTS = (kitti_odometry, kitti_raw, euroc, generic)
"""The layout modules, tried in this order; each has ``LAYOUT`` (its name), ``EXPECTED``
(its folder structure, for error messages), ``matches(folder)`` and ``load(folder)``."""


def open_sequence(path: str | Path) -> StereoSequence:
    """Open the stereo sequence in folder ``path``, detecting its layout.

    Opening lists files and reads calibration, times and ground truth; images are read
    (and rectified where needed) only when a frame is asked for.

    Raises
    ------
    DatasetError
        The folder does not exist, is empty or matches no layout (the message lists the
        layouts expected), or the files of its layout are missing or malformed.
    """
    folder = Path(path).expanduser()
    if not folder.exists():
        raise DatasetError(f"{folder}: no such folder")
    if not folder.is_dir():
        raise DatasetError(f"{folder}: not a folder; give the sequence folder")
    if not any(folder.iterdir()):
        raise DatasetError(f"{folder}: the folder is empty")
    for layout in LAYOUTS:
        if layout.matches(folder):
            return layout.load(folder)
    expected = "; ".join(layout.EXPECTED for layout in LAYOUTS)
    raise DatasetError(f"{folder}: unknown dataset layout; expected one of: {expected}")


__all__ = ["LAYOUTS", "StereoFrame", "StereoSequence", "open_sequence"]
