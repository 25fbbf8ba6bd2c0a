"""Generic stereo layout, for rigs users record themselves: ``left/``, ``right/``, ``calib.yaml``.

Folder::

    SEQUENCE/
      left/            left images, .png or .jpg, paired with right/ by file name
      right/           right images, one of the same name (suffix included) per left image
      calib.yaml       the calibration below (required)
      times.txt        optional: one time [s] per line and per image pair
      groundtruth.txt  optional: TUM format, "timestamp tx ty tz qx qy qz qw"

``calib.yaml``::

    image_size: [width, height]                 # px, of the raw images
    left:  {K: [[fx, 0, cx], [0, fy, cy], [0, 0, 1]], distortion: [k1, k2, p1, p2]}
    right: {K: [[...], [...], [...]], distortion: [k1, k2, p1, p2, k3]}
    R: [[...], [...], [...]]   # rotation of the right camera w.r.t. the left:
    t: [tx, ty, tz]            #   p_right = R p_left + t, t in metres
    rectified: false           # optional, default false (see below)
    fps: 10                    # optional, default 10 (see below)
    T_gt_left: [[...], [...], [...], [...]]   # optional, default identity (see below)

- Frames are in natural order of the left file names (``2.png`` before ``10.png``,
  `pld_slam.datasets.files.natural_key`), so names need no zero padding.
- Images are paired by file name (`pld_slam.datasets.files.paired_images`), so both
  folders must name a pair alike (``left/0001.png`` and ``right/0001.png``); a file
  without a partner of the same name raises, naming it.
- ``distortion``: OpenCV radial-tangential coefficients, 4 (k1 k2 p1 p2) or 5 (+ k3).
- ``rectified: false`` (the default): the images are raw; they are rectified as they
  are read (`pld_slam.datasets.rectify`, ``alpha = 0``, same image size), which needs
  every key above. Rectifying is the default because it is always correct: an
  already rectified pair with zero distortion comes out unchanged.
- ``rectified: true``: the images are already rectified. Only ``image_size``, ``left.K``
  and ``t`` are read: both images share ``left.K``, ``R`` is the identity and
  ``t = (-baseline, 0, 0)``; the other keys may be absent.
- A right camera that is not to the right of the left one (``tx >= 0`` when rectified)
  raises `DatasetError`: the images are swapped or ``t`` has the wrong sign. So do a
  number that is not finite, a focal length that is not positive and a principal point
  outside the image (`pld_slam.datasets.calibration.check_intrinsics`), naming the value.
- Times: ``times.txt`` when present (strictly increasing), else frame index / ``fps``
  with ``fps`` from ``calib.yaml`` (default 10 Hz, KITTI's rate), frame 0 at 0 s.
- Frame rate: ``fps`` when given (the rig's nominal rate), else the median step of
  ``times.txt``, else the default 10 Hz.
- Ground truth: ``groundtruth.txt`` gives ``T_w_gt`` of some frame ``gt`` on the clock of
  the frame times: the *raw left camera* unless ``T_gt_left`` (4x4, maps a point of the
  raw left camera frame into ``gt``: e.g. EuRoC's ``T_BS`` of cam0 when the poses are
  the body's) says otherwise; that it does is the user's responsibility (a pose of the
  rig body or of another sensor cannot be told apart). We move it into the rectified
  left camera (``T_w_rect = T_w_gt T_gt_left [R1^T | 0]``; ``R1`` the identity for
  ``rectified: true``), give each frame the row nearest in time within
  `GROUNDTRUTH_MAX_OFFSET`, and move the first pose to identity.

The calibration part (`read_rig_calibration`) also serves ROS bags (``pld-slam run
RECORDING.bag --calib calib.yaml``, `pld_slam.datasets.rosbag`).

The sequence name is the folder name.
"""

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pld_slam.datasets.base import FrameRate, ImageFiles, StereoSequence
from pld_slam.datasets.calibration import (
    PINHOLE_ENTRIES,
    Calibration,
    check_intrinsics,
    check_rotation,
    read_yaml_calibration,
    stereo_camera_from_projections,
)
from pld_slam.datasets.files import (
    IMAGE_SUFFIXES,
    groundtruth_at_frames,
    paired_image_folders,
    read_times,
)
from pld_slam.datasets.rectify import StereoRectification, rectify_stereo
from pld_slam.geometry.camera import StereoCamera
from pld_slam.geometry.se3 import make_pose
from pld_slam.io.trajectory import read_tum
from pld_slam.trajectory import Trajectory

LAYOUT = "generic"
EXPECTED = "generic (left/, right/, calib.yaml; optional times.txt, groundtruth.txt)"

DEFAULT_FPS = 10.0
"""Frame rate [Hz] when neither ``times.txt`` nor ``fps`` is given."""

GROUNDTRUTH_MAX_OFFSET = 0.005
"""Largest time difference [s] between a frame and its ground-truth row: ground truth
written at the frame times matches exactly up to rounding; 5 ms also admits 200 Hz
motion capture."""

_DISTORTION_SIZES = (4, 5)


def matches(folder: Path) -> bool:
    """Whether ``folder`` looks like a generic sequence (it has ``left/``)."""
    return (folder / "left").is_dir()


@dataclass(frozen=True)
class RigCalibration:
    """What a ``calib.yaml`` says of a stereo rig (schema in the module docstring).

    Attributes
    ----------
    camera : StereoCamera
        The rectified camera the frames are delivered in.
    rectifier : StereoRectification or None
        Rectifies the raw pairs; None for ``rectified: true``.
    T_gt_rect : np.ndarray
        (4, 4) maps a point of the rectified left camera frame into the frame ``gt``
        whose poses the ground truth gives: ``T_gt_left [R1^T | 0]``.
    fps : float or None
        ``fps`` [Hz], None when not given.
    """

    camera: StereoCamera
    rectifier: StereoRectification | None
    T_gt_rect: np.ndarray
    fps: float | None


def read_rig_calibration(path: Path) -> RigCalibration:
    """The `RigCalibration` of the ``calib.yaml`` at ``path``; every problem a `DatasetError` naming it."""
    calibration = read_yaml_calibration(path)
    if _is_rectified(calibration):
        camera, rectifier, T_left_rect = _rectified_camera(calibration), None, np.eye(4)
    else:
        rectifier = _rectification(calibration)
        camera, T_left_rect = rectifier.camera, rectifier.T_raw_rect
    return RigCalibration(camera, rectifier, _gt_from_left(calibration) @ T_left_rect, _fps(calibration))


def load(folder: Path) -> StereoSequence:
    """Open the generic sequence in ``folder`` (see the module docstring)."""
    folder = folder.resolve()
    left_paths, right_paths = paired_image_folders(folder / "left", folder / "right", IMAGE_SUFFIXES)
    rig = read_rig_calibration(folder / "calib.yaml")
    timestamps, frame_rate = _times_and_rate(folder, len(left_paths), rig.fps)
    return StereoSequence(
        name=folder.name,
        layout=LAYOUT,
        root=folder,
        camera=rig.camera,
        timestamps=timestamps,
        frame_rate=frame_rate,
        frames=ImageFiles(left_paths, right_paths, rig.camera.size),
        groundtruth=read_groundtruth(folder / "groundtruth.txt", timestamps, rig.T_gt_rect),
        rectifier=rig.rectifier,
    )


def _is_rectified(calibration: Calibration) -> bool:
    """The optional ``rectified`` flag (default false); anything but a boolean raises."""
    if not calibration.has("rectified"):
        return False
    flag = calibration.value("rectified")
    if not isinstance(flag, bool):
        raise calibration.error("rectified", f"must be true or false, got {flag!r}")
    return flag


def _image_size(calibration: Calibration) -> tuple[int, int]:
    """``(width, height)`` [px] of ``image_size``."""
    width, height = calibration.array("image_size", (2,))
    if width < 1 or height < 1 or width != int(width) or height != int(height):
        raise calibration.error("image_size", "must be two positive whole numbers")
    return int(width), int(height)


def _fps(calibration: Calibration) -> float | None:
    """The optional ``fps`` [Hz], positive; None when absent."""
    if not calibration.has("fps"):
        return None
    fps = float(calibration.array("fps", (1,))[0])
    if not fps > 0.0:
        raise calibration.error("fps", f"must be positive, got {fps:g}")
    return fps


def _times_and_rate(folder: Path, n_frames: int, fps: float | None) -> tuple[np.ndarray, FrameRate]:
    """Frame times (N,) [s] and the frame rate (module docstring: Times, Frame rate)."""
    times_path = folder / "times.txt"
    nominal = None if fps is None else FrameRate(fps, "fps of calib.yaml")
    if times_path.exists():
        times = read_times(times_path, n_frames)
        return times, nominal or FrameRate.from_times(times, "median step of times.txt")
    nominal = nominal or FrameRate(DEFAULT_FPS, "default rate (no fps in calib.yaml, no times.txt)")
    return np.arange(n_frames) / nominal.hz, nominal


def _gt_from_left(calibration: Calibration) -> np.ndarray:
    """``T_gt_left`` (4, 4), the identity when absent; a matrix that is not a rigid motion raises."""
    if not calibration.has("T_gt_left"):
        return np.eye(4)
    T = calibration.array("T_gt_left", (4, 4))
    if not np.allclose(T[3], [0.0, 0.0, 0.0, 1.0]):
        raise calibration.error("T_gt_left", "must end with the row 0 0 0 1")
    check_rotation(calibration, "T_gt_left", T[:3, :3])
    return T


def _rectified_camera(calibration: Calibration) -> StereoCamera:
    """The camera of an already rectified pair: ``left.K`` shared, right at ``-t``."""
    K = calibration.array("left.K", (3, 3), PINHOLE_ENTRIES)
    t = calibration.array("t", (3,))
    P_left = K @ np.eye(3, 4)
    P_right = K @ make_pose(np.eye(3), t)[:3]
    return stereo_camera_from_projections(
        P_left, P_right, *_image_size(calibration), source=calibration.path, keys=("left.K", "t")
    )


def _distortion(calibration: Calibration, key: str) -> np.ndarray:
    """The (4,) or (5,) radial-tangential coefficients of ``key``."""
    coefficients = calibration.array(key)
    if coefficients.size not in _DISTORTION_SIZES:
        raise calibration.error(key, f"has {coefficients.size} numbers, expected 4 or 5")
    return coefficients


def _rectification(calibration: Calibration) -> StereoRectification:
    """The `StereoRectification` of a raw rig described by ``calibration``."""
    size = _image_size(calibration)
    return rectify_stereo(
        _intrinsics(calibration, "left.K", size),
        _distortion(calibration, "left.distortion"),
        _intrinsics(calibration, "right.K", size),
        _distortion(calibration, "right.distortion"),
        make_pose(calibration.rotation("R"), calibration.array("t", (3,))),
        size,
        source=calibration.path,
    )


def _intrinsics(calibration: Calibration, key: str, size: tuple[int, int]) -> np.ndarray:
    """The (3, 3) intrinsic matrix of ``key`` of a raw camera, checked plausible for ``size`` (`check_intrinsics`)."""
    K = calibration.array(key, (3, 3), PINHOLE_ENTRIES)
    check_intrinsics(K, size, calibration.path, key)
    return K


def read_groundtruth(path: Path, timestamps: np.ndarray, T_gt_rect: np.ndarray) -> Trajectory | None:
    """``T_w_c`` of the rectified left camera at the frame times, first = identity, or None.

    ``path`` is a TUM file of ``T_w_gt``; ``T_gt_rect`` (4, 4) maps the rectified left
    camera frame into ``gt`` (`RigCalibration`).
    """
    if not path.exists():
        return None
    return groundtruth_in_camera(read_tum(path), timestamps, T_gt_rect, path)


def groundtruth_in_camera(
    T_w_gt: Trajectory, timestamps: np.ndarray, T_gt_rect: np.ndarray, source: Path | str
) -> Trajectory:
    """Poses ``T_w_gt`` moved to the rectified left camera at the frame times (N,) [s], first = identity.

    Each frame takes the pose nearest in time within `GROUNDTRUTH_MAX_OFFSET`
    (`groundtruth_at_frames`, which names ``source`` when none is).
    """
    at_frames = groundtruth_at_frames(T_w_gt, timestamps, GROUNDTRUTH_MAX_OFFSET, source)
    return Trajectory(at_frames.timestamps, at_frames.poses @ T_gt_rect).relative_to_first()
