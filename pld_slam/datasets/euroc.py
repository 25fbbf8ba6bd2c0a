"""EuRoC MAV layout (ASL): ``SEQUENCE/mav0/{cam0/, cam1/, state_groundtruth_estimate0/}``.

Either the sequence folder or its ``mav0`` folder may be given.

- Images: ``camK/data.csv`` (``timestamp [ns],filename``) lists ``camK/data/<filename>``;
  cam0 (left) and cam1 (right) rows are paired by equal timestamps
  (`pld_slam.datasets.files.paired_images`); an image whose timestamp the other camera's
  list lacks raises `DatasetError` naming that image and the other list.
  Frame times are the nanosecond timestamps divided by 1e9 [s]; the frame rate is
  EuRoC's nominal 20 Hz (`FRAME_RATE`).
- Camera: the raw images are distorted; they are rectified as they are read (see
  `pld_slam.datasets.rectify`, ``alpha = 0``) from the two ``sensor.yaml`` files:
  ``intrinsics`` (fu fv cu cv), ``distortion_coefficients`` (radial-tangential k1 k2 p1 p2),
  ``resolution`` and ``T_BS`` (sensor to body, ``data`` read row-major as 4x4), with
  ``T_c1_c0 = inv(T_B_c1) T_B_c0``.
- Ground truth (optional): ``state_groundtruth_estimate0/data.csv``, body poses ``T_w_b``
  read with `pld_slam.io.trajectory.read_euroc`, moved to the rectified left camera:
  ``T_w_rect = T_w_b T_b_c0 T_c0_rect`` with ``T_c0_rect = [R1^T | 0]``. Each frame takes
  the ground-truth row nearest in time. The tolerance is open; we accept rows within
  `GROUNDTRUTH_MAX_OFFSET` = 5 ms, one period of EuRoC's 200 Hz ground truth: every
  frame inside the recorded span is at most 2.5 ms from a row and gets a pose, while
  frames past its ends or in its gaps get none. The first pose is moved to identity.
"""

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pld_slam.datasets.base import FrameRate, ImageFiles, StereoSequence
from pld_slam.datasets.calibration import check_intrinsics, read_yaml_calibration
from pld_slam.datasets.files import groundtruth_at_frames, paired_images
from pld_slam.datasets.rectify import StereoRectification, rectify_stereo
from pld_slam.errors import DatasetError, read_user_text
from pld_slam.geometry.se3 import inverse
from pld_slam.io.trajectory import read_euroc
from pld_slam.trajectory import Trajectory

LAYOUT = "euroc"
EXPECTED = "EuRoC ASL (mav0/cam0/, mav0/cam1/, each with data.csv, data/ and sensor.yaml)"

FRAME_RATE = FrameRate(20.0, "EuRoC nominal rate")
"""The MAV's stereo camera (VI-Sensor) runs at 20 Hz."""

GROUNDTRUTH_MAX_OFFSET = 0.005
"""Largest time difference [s] between a frame and its ground-truth row."""

_SUPPORTED_MODELS = {"camera_model": "pinhole", "distortion_model": "radial-tangential"}
_INTRINSICS_ENTRIES = {(0,): "fu", (1,): "fv", (2,): "cu", (3,): "cv"}


@dataclass(frozen=True)
class CameraSensor:
    """One EuRoC camera's ``sensor.yaml``.

    Attributes
    ----------
    K : np.ndarray
        (3, 3) raw intrinsics [px].
    distortion : np.ndarray
        (4,) radial-tangential coefficients k1 k2 p1 p2.
    T_B_S : np.ndarray
        (4, 4) maps a point of the camera frame into the body frame.
    size : tuple of int
        ``(width, height)`` [px].
    """

    K: np.ndarray
    distortion: np.ndarray
    T_B_S: np.ndarray
    size: tuple[int, int]


def matches(folder: Path) -> bool:
    """Whether ``folder`` is an EuRoC sequence (it has ``mav0/``) or its ``mav0`` (``cam0/``)."""
    return (folder / "mav0").is_dir() or (folder / "cam0").is_dir()


def load(folder: Path) -> StereoSequence:
    """Open the EuRoC sequence in ``folder`` or its ``mav0`` (see the module docstring)."""
    folder = folder.resolve()
    mav0 = folder if (folder / "cam0").is_dir() else folder / "mav0"
    left_csv, right_csv = mav0 / "cam0" / "data.csv", mav0 / "cam1" / "data.csv"
    left_ns, left_names = read_image_list(left_csv)
    right_ns, right_names = read_image_list(right_csv)
    left_paths, right_paths = paired_images(
        _images_by_timestamp(left_ns, left_names, mav0 / "cam0" / "data"),
        _images_by_timestamp(right_ns, right_names, mav0 / "cam1" / "data"),
        (left_csv, right_csv),
        "timestamp",
    )
    rectification, T_b_rect = _rectify_cameras(mav0)
    timestamps = left_ns / 1e9
    return StereoSequence(
        name=f"euroc_{mav0.parent.name}",
        layout=LAYOUT,
        root=folder,
        camera=rectification.camera,
        timestamps=timestamps,
        frame_rate=FRAME_RATE,
        frames=ImageFiles(left_paths, right_paths, rectification.camera.size),
        groundtruth=_groundtruth(mav0, timestamps, T_b_rect),
        rectifier=rectification,
    )


def _rectify_cameras(mav0: Path) -> tuple[StereoRectification, np.ndarray]:
    """The rectification of cam0 and cam1, and ``T_b_rect`` (4, 4).

    ``T_b_rect`` maps the rectified left camera frame into the body frame.
    """
    left_yaml, right_yaml = mav0 / "cam0" / "sensor.yaml", mav0 / "cam1" / "sensor.yaml"
    left, right = read_camera_sensor(left_yaml), read_camera_sensor(right_yaml)
    if right.size != left.size:
        raise DatasetError(f"{right_yaml}: resolution {right.size} differs from cam0's {left.size}")
    rectification = rectify_stereo(
        left.K,
        left.distortion,
        right.K,
        right.distortion,
        inverse(right.T_B_S) @ left.T_B_S,
        left.size,
        source=f"{left_yaml} and {right_yaml}",
    )
    return rectification, left.T_B_S @ rectification.T_raw_rect


MAX_TIMESTAMP_NS = np.iinfo(np.int64).max
"""The last time [ns] an int64 holds (April 2262)."""


def read_image_list(path: Path) -> tuple[np.ndarray, list[str]]:
    """Timestamps (N,) [ns] (int64, increasing) and image file names of a camera ``data.csv``.

    Lines starting with ``#`` are comments. Rows are sorted by timestamp; a malformed row
    or a repeated timestamp raises `DatasetError` naming ``file:line``.
    """
    if not path.is_file():
        raise DatasetError(f"{path}: image list not found")
    rows = []
    for number, line in enumerate(read_user_text(path, DatasetError, "image list").splitlines(), start=1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        fields = [field.strip() for field in line.split(",")]
        if len(fields) != 2 or not (fields[0].isascii() and fields[0].isdigit()) or not fields[1]:
            raise DatasetError(
                f"{path}:{number}: expected 'timestamp [ns],filename', got {line[:60]!r}"
            )
        if int(fields[0]) > MAX_TIMESTAMP_NS:
            raise DatasetError(f"{path}:{number}: timestamp {fields[0][:30]} ns is past the year 2262 (int64 ns)")
        rows.append((int(fields[0]), fields[1], number))
    if not rows:
        raise DatasetError(f"{path}: no images listed")
    rows.sort()
    for (previous, _, _), (stamp, _, number) in zip(rows, rows[1:]):
        if stamp == previous:
            raise DatasetError(f"{path}:{number}: timestamp {stamp} listed twice")
    return np.array([row[0] for row in rows], dtype=np.int64), [row[1] for row in rows]


def _images_by_timestamp(stamps_ns: np.ndarray, names: list[str], data_folder: Path) -> dict[int, Path]:
    """The files ``data_folder/name`` of an image list keyed by their timestamps [ns]."""
    return {int(stamp): data_folder / name for stamp, name in zip(stamps_ns, names, strict=True)}


def read_camera_sensor(path: Path) -> CameraSensor:
    """The pinhole radial-tangential camera of an EuRoC ``sensor.yaml``."""
    sensor = read_yaml_calibration(path)
    for key, supported in _SUPPORTED_MODELS.items():
        if sensor.value(key) != supported:
            raise sensor.error(key, f"is {sensor.value(key)!r}; only {supported!r} is supported")
    fu, fv, cu, cv = sensor.array("intrinsics", (4,), _INTRINSICS_ENTRIES)
    width, height = sensor.array("resolution", (2,)).astype(int)
    K = np.array([[fu, 0.0, cu], [0.0, fv, cv], [0.0, 0.0, 1.0]])
    check_intrinsics(K, (int(width), int(height)), path, "intrinsics")
    return CameraSensor(
        K=K,
        distortion=sensor.array("distortion_coefficients", (4,)),
        T_B_S=sensor.array("T_BS.data", (4, 4)),
        size=(int(width), int(height)),
    )


def _groundtruth(mav0: Path, timestamps: np.ndarray, T_b_rect: np.ndarray) -> Trajectory | None:
    """``T_w_c`` of the rectified left camera at the frame times, first = identity, or None.

    ``T_b_rect`` (4, 4) maps the rectified left camera frame into the body frame.
    """
    path = mav0 / "state_groundtruth_estimate0" / "data.csv"
    if not path.is_file():
        return None
    body = read_euroc(path)
    at_frames = groundtruth_at_frames(body, timestamps, GROUNDTRUTH_MAX_OFFSET, path)
    return Trajectory(at_frames.timestamps, at_frames.poses @ T_b_rect).relative_to_first()
