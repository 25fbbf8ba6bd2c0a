"""Stereo datasets read into one `StereoSequence`, the layout detected from the path.

`open_sequence` recognises a ROS bag (`rosbag`: a ROS 1 ``.bag`` file, or a ROS 2 bag
folder with ``metadata.yaml``), else, in this order, the folder layouts:

- ``kitti_odometry`` (`kitti_odometry`): ``image_0/``, ``image_1/`` (or the colour
  ``image_2/``, ``image_3/``), ``calib.txt``, ``times.txt``; also what ``pld-slam synth`` writes;
- ``kitti_raw`` (`kitti_raw`): a ``DATE_drive_NNNN_sync`` folder with ``image_00/`` (or ``image_02/``);
- ``euroc`` (`euroc`): an EuRoC ASL sequence (``mav0/``) or its ``mav0`` folder;
- ``generic`` (`generic`): ``left/``, ``right/``, ``calib.yaml`` (schema in its docstring);
- ``argoverse`` (`argoverse`): an Argoverse 1.1 stereo log (``stereo_front_left_rect/``).

KITTI's folders may hold two stereo pairs, grey and colour (`kitti_cameras`): a folder
opens from the grey pair where it has one (else the colour pair), and `with_cameras`
reopens it from the pair ``dataset.cameras`` asks for (a run does, once its config is
known, since the config depends on the opened sequence's family).

Every problem with the input is a one-line `DatasetError` naming the file or folder.
Malformed ground-truth rows are the exception to the type: the trajectory readers of
`pld_slam.io.trajectory` raise `TrajectoryError` naming ``file:line``, and we let it
through unchanged, because it is already one line of the same `PldSlamError` family the
CLI reports, and wrapping it would only repeat the message.
"""

from pathlib import Path

from pld_slam.datasets import argoverse, euroc, generic, kitti_odometry, kitti_raw, rosbag
from pld_slam.datasets.base import FrameRate, StereoFrame, StereoSequence
from pld_slam.datasets.rosbag import BagOptions
from pld_slam.errors import ConfigError, DatasetError

LAYOUTS = (kitti_odometry, kitti_raw, euroc, generic, argoverse)
"""The folder layout modules, tried in this order; each has ``LAYOUT`` (its name),
``EXPECTED`` (its folder structure, for error messages), ``matches(folder)`` and
``load(folder)``. ROS bags (`rosbag`) are told apart before them, and take `BagOptions`."""


def open_sequence(path: str | Path, bag_options: BagOptions = BagOptions()) -> StereoSequence:
    """Open the stereo sequence at ``path`` (a folder, or a ROS bag), detecting its layout.

    Opening lists files (or, for a bag, the stamps of its image messages) and reads
    calibration, times and ground truth; images are read (and rectified where needed)
    only when a frame is asked for. ``bag_options`` (topics, calibration file) apply to
    ROS bags only.

    Raises
    ------
    DatasetError
        The path does not exist, is empty or matches no layout (the message lists the
        layouts expected), ``bag_options`` are given for what is not a bag, or the files
        of its layout are missing or malformed.
    """
    source = Path(path).expanduser()
    if not source.exists():
        raise DatasetError(f"{source}: no such file or folder")
    if rosbag.matches(source):
        return rosbag.load(source, bag_options)
    if bag_options != BagOptions():
        raise DatasetError(f"{source}: not a ROS bag; topics and --calib apply to bags only")
    if not source.is_dir():
        raise DatasetError(f"{source}: not a folder or a ROS 1 .bag file; give the sequence folder or the bag")
    if not any(source.iterdir()):
        raise DatasetError(f"{source}: the folder is empty")
    for layout in LAYOUTS:
        if layout.matches(source):
            return layout.load(source)
    expected = "; ".join(layout.EXPECTED for layout in (*LAYOUTS, rosbag))
    raise DatasetError(f"{source}: unknown dataset layout; expected one of: {expected}")


def with_cameras(sequence: StereoSequence, cameras: str) -> StereoSequence:
    """``sequence`` read from the stereo pair ``cameras`` (``dataset.cameras``) names.

    ``auto``, or the pair ``sequence`` was read from, returns it as it is; else its
    folder is opened again from that pair (KITTI odometry and raw,
    `kitti_cameras.chosen_pair`). For a sequence as `open_sequence` returned it: a
    scaled copy or a subsequence would be reopened whole and unscaled.

    Raises
    ------
    DatasetError
        The folder has no such pair (naming the image folder missing).
    ConfigError
        ``grey`` or ``colour`` asked of a sequence of one pair (not KITTI).
    """
    if cameras in ("auto", sequence.cameras):
        return sequence
    if sequence.cameras is None:
        require_cameras(sequence, cameras, "grey and colour choose between the pairs of KITTI's folders (set auto)")
    layout = next(layout for layout in LAYOUTS if layout.LAYOUT == sequence.layout)
    return layout.load(Path(sequence.root), cameras)


def require_cameras(sequence: StereoSequence, cameras: str, remedy: str) -> None:
    """Raise `ConfigError` unless ``sequence`` is read from the pair ``cameras`` (``dataset.cameras``)
    names (``auto`` takes any); the message ends with ``remedy``, what to do instead."""
    if cameras in ("auto", sequence.cameras):
        return
    read_from = "one stereo pair" if sequence.cameras is None else f"its {sequence.cameras} pair"
    raise ConfigError(f"dataset.cameras is {cameras} but {sequence.root} is read from {read_from}; {remedy}")


__all__ = [
    "LAYOUTS", "BagOptions", "FrameRate", "StereoFrame", "StereoSequence", "open_sequence", "require_cameras",
    "with_cameras",
]
