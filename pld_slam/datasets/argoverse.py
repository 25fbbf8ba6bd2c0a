"""Argoverse 1.1 stereo layout: one log folder of rectified stereo JPEGs named by timestamp.

Folder (``rectified_stereo_images_v1.1/{train,val,test}/LOG_ID/`` of the release)::

    LOG_ID/
      stereo_front_left_rect/stereo_front_left_rect_<timestamp ns>.jpg
      stereo_front_right_rect/stereo_front_right_rect_<timestamp ns>.jpg
      vehicle_calibration_stereo_info.json
      poses/city_SE3_egovehicle_<timestamp ns>.json      optional (see Ground truth)

The names and fields are those of the public argoverse-api (``ArgoverseStereoLoader``,
``argoverse.utils.calibration``, ``argoverse.data_loading.pose_loader``,
``camera_stats``); we read the files, not the API.

- Images: 2464 x 2056 rectified colour JPEGs at 5 Hz, read as grey. The left and right
  stamps of one pair differ by a few hundred nanoseconds (the cameras are triggered
  together, but stamped apart), so the API pairs them by sorted position. We pair each
  left image with the right image nearest in time within `PAIR_TOLERANCE` (5 ms, 1/40
  of the 200 ms frame period) instead, for the reason every layout pairs by key
  (`pld_slam.datasets.files.paired_images`): a frame missing on one side must not shift
  every later pair. An image without a partner raises `DatasetError` naming it. The
  image size is read from the first readable left JPEG's header (`jpeg_size`), not assumed.
- Times: the left image's nanosecond timestamp / 1e9 [s] (the GPS-epoch nanoseconds of
  the release). Frame rate: the nominal 5 Hz (`FRAME_RATE`).
- Camera: ``vehicle_calibration_stereo_info.json`` holds ``camera_data_``, a list of
  ``{"key": "image_raw_<camera>", "value": {...}}``; for ``stereo_front_left_rect`` and
  ``stereo_front_right_rect`` we read ``focal_length_x_px_``, ``focal_length_y_px_``,
  ``focal_center_x_px_``, ``focal_center_y_px_`` and ``vehicle_SE3_camera_``
  (``{"rotation": {"coefficients": [qw, qx, qy, qz]}, "translation": [x, y, z]}``, maps a
  point of the camera frame into the vehicle frame). The calibration carries no
  baseline (the API's intrinsic matrix has a zero fourth column, and its tutorial writes
  the rig's 0.2986 m as a constant); we take it from the two extrinsics, as the distance
  between the camera centres, which rectification does not change, and require the right
  camera to lie to the right (positive x in the left camera). Intrinsics come from the
  left camera (a rectified pair shares them).
- Ground truth (when ``poses/`` exists): each ``city_SE3_egovehicle_<ns>.json`` is
  ``{"rotation": [qw, qx, qy, qz], "translation": [x, y, z]}``, the vehicle's pose in the
  city frame ``T_city_vehicle`` at that sensor time. The stereo release has no poses;
  the 3D tracking release's log of the same id (``argoverse-tracking/SPLIT/LOG_ID/poses``)
  has them, at every sensor's timestamps: link or copy that folder into the stereo log.
  Each frame takes the pose nearest in time within 5 ms
  (`pld_slam.datasets.generic.groundtruth_in_camera`), moved to the rectified left
  camera, ``T_city_cam = T_city_vehicle T_vehicle_cam``, and the first pose to identity.

Left open, unverified against a real download here: whether the rectified cameras'
``vehicle_SE3_camera_`` carries the rectified rotation (we use the left one as the
rectified left camera's orientation, as the API does for projection), and whether every
frame's timestamp has a pose file (frames without one within 5 ms get no ground truth).
"""

import re
from pathlib import Path

import numpy as np

from pld_slam.datasets.base import FrameRate, ImageFiles, StereoSequence
from pld_slam.datasets.calibration import Calibration, read_json_calibration, stereo_camera_from_projections
from pld_slam.datasets.files import first_image_size, image_files, jpeg_size, nearest_within, paired_images
from pld_slam.datasets.generic import groundtruth_in_camera
from pld_slam.errors import DatasetError
from pld_slam.geometry.camera import StereoCamera
from pld_slam.geometry.se3 import inverse, make_pose
from pld_slam.io.trajectory import rotations_from_quaternions
from pld_slam.trajectory import Trajectory

LAYOUT = "argoverse"
EXPECTED = (
    "Argoverse stereo (stereo_front_left_rect/, stereo_front_right_rect/, "
    "vehicle_calibration_stereo_info.json; optional poses/)"
)

LEFT, RIGHT = "stereo_front_left_rect", "stereo_front_right_rect"
CALIBRATION_FILE = "vehicle_calibration_stereo_info.json"
POSE_PREFIX = "city_SE3_egovehicle_"

FRAME_RATE = FrameRate(5.0, "Argoverse stereo nominal rate")
"""The stereo pair is captured at 5 Hz (the release's documentation and API)."""

PAIR_TOLERANCE_NS = 5_000_000
"""Largest time difference [ns] between the left and right image of a pair."""


def matches(folder: Path) -> bool:
    """Whether ``folder`` looks like an Argoverse stereo log (it has ``stereo_front_left_rect/``)."""
    return (folder / LEFT).is_dir()


def load(folder: Path) -> StereoSequence:
    """Open the Argoverse stereo log in ``folder`` (see the module docstring)."""
    folder = folder.resolve()
    left_ns, left_paths, right_paths = _paired_images(folder)
    calibration = _camera_entries(read_json_calibration(folder / CALIBRATION_FILE, "Argoverse calibration file"))
    camera = _stereo_camera(calibration, first_image_size(left_paths, jpeg_size))
    timestamps = left_ns / 1e9
    return StereoSequence(
        name=f"argoverse_{folder.name}",
        layout=LAYOUT,
        root=folder,
        camera=camera,
        timestamps=timestamps,
        frame_rate=FRAME_RATE,
        frames=ImageFiles(left_paths, right_paths, camera.size),
        groundtruth=_groundtruth(folder / "poses", timestamps, vehicle_from_camera(calibration, LEFT)),
    )


def _paired_images(folder: Path) -> tuple[np.ndarray, list[Path], list[Path]]:
    """Left timestamps (N,) [ns] and the left and right image files, paired within `PAIR_TOLERANCE_NS`.

    Each right image is keyed by the stamp of the left image it pairs with (its own when
    none), so that `paired_images` names the first image without a partner.
    """
    left = _images_by_timestamp(folder / LEFT)
    right = _images_by_timestamp(folder / RIGHT)
    left_ns, right_ns = np.array(sorted(left)), np.array(sorted(right))
    partner = nearest_within(left_ns, right_ns, PAIR_TOLERANCE_NS)
    right_by_left = {int(left_ns[p]) if p >= 0 else int(r): right[int(r)] for r, p in zip(right_ns, partner)}
    pairs = paired_images(
        {int(stamp): left[int(stamp)] for stamp in left_ns},
        right_by_left,
        (folder / LEFT, folder / RIGHT),
        f"timestamp (within {PAIR_TOLERANCE_NS / 1e6:g} ms)",
    )
    return left_ns, *pairs


def _images_by_timestamp(image_folder: Path) -> dict[int, Path]:
    """The JPEGs ``<folder name>_<ns>.jpg`` of ``image_folder`` by their timestamps [ns]."""
    pattern = re.compile(rf"{re.escape(image_folder.name)}_(\d+)\.jpg")
    images = {}
    for path in image_files(image_folder, (".jpg",)):
        named = pattern.fullmatch(path.name)
        if named is None:
            raise DatasetError(f"{path}: expected the name {image_folder.name}_<timestamp ns>.jpg")
        images[int(named.group(1))] = path
    return images


def _camera_entries(calibration: Calibration) -> Calibration:
    """The ``camera_data_`` list of the calibration file as a `Calibration` keyed by camera name.

    ``image_raw_stereo_front_left_rect`` becomes the key ``stereo_front_left_rect``; an
    unknown schema (no such list, entries without ``key`` and ``value``) raises naming the file.
    """
    entries = calibration.value("camera_data_")
    if not isinstance(entries, list) or not all(isinstance(e, dict) and {"key", "value"} <= e.keys() for e in entries):
        raise calibration.error("camera_data_", "is not a list of {\"key\": ..., \"value\": ...} camera entries")
    cameras = {str(entry["key"]).removeprefix("image_raw_"): entry["value"] for entry in entries}
    return Calibration(calibration.path, cameras)


def vehicle_from_camera(calibration: Calibration, camera: str) -> np.ndarray:
    """``T_vehicle_camera`` (4, 4) of ``camera``: its ``vehicle_SE3_camera_`` (maps camera points into the vehicle)."""
    key = f"{camera}.vehicle_SE3_camera_"
    return _pose(calibration, f"{key}.rotation.coefficients", f"{key}.translation")


def _pose(calibration: Calibration, rotation_key: str, translation_key: str) -> np.ndarray:
    """(4, 4) pose of an Argoverse scalar-first quaternion ``[qw, qx, qy, qz]`` and a translation [m]."""
    q_wxyz = calibration.array(rotation_key, (4,))
    (R,) = rotations_from_quaternions(
        np.roll(q_wxyz, -1)[None], lambda _, problem: calibration.error(rotation_key, problem)
    )
    return make_pose(R, calibration.array(translation_key, (3,)))


def _stereo_camera(calibration: Calibration, size: tuple[int, int]) -> StereoCamera:
    """The rectified camera: the left intrinsics, the baseline between the two camera centres."""
    T_left_right = inverse(vehicle_from_camera(calibration, LEFT)) @ vehicle_from_camera(calibration, RIGHT)
    offset = T_left_right[:3, 3]
    if not offset[0] > 0.0:
        raise calibration.error(
            f"{RIGHT}.vehicle_SE3_camera_",
            f"puts the right camera at x = {offset[0]:.4g} m of the left one, not to its right",
        )

    def intrinsic(name: str) -> float:
        return float(calibration.array(f"{LEFT}.{name}", (1,))[0])

    K = np.array([
        [intrinsic("focal_length_x_px_"), 0.0, intrinsic("focal_center_x_px_")],
        [0.0, intrinsic("focal_length_y_px_"), intrinsic("focal_center_y_px_")],
        [0.0, 0.0, 1.0],
    ])
    P_right = K @ make_pose(np.eye(3), np.array([-np.linalg.norm(offset), 0.0, 0.0]))[:3]
    return stereo_camera_from_projections(K @ np.eye(3, 4), P_right, *size, source=calibration.path, keys=(LEFT, RIGHT))


def _groundtruth(poses: Path, timestamps: np.ndarray, T_vehicle_cam: np.ndarray) -> Trajectory | None:
    """``T_w_c`` of the rectified left camera at the frame times, first = identity; None without ``poses/``."""
    if not poses.is_dir():
        return None
    paths = sorted(poses.glob(f"{POSE_PREFIX}*.json"), key=_pose_timestamp_ns)
    if not paths:
        raise DatasetError(f"{poses}: no {POSE_PREFIX}<timestamp ns>.json files")
    stamps = np.array([_pose_timestamp_ns(path) for path in paths]) / 1e9
    T_city_vehicle = np.array([_vehicle_pose(path) for path in paths])
    return groundtruth_in_camera(Trajectory(stamps, T_city_vehicle), timestamps, T_vehicle_cam, poses)


def _pose_timestamp_ns(path: Path) -> int:
    """The timestamp [ns] in the name of a pose file."""
    stamp = path.stem.removeprefix(POSE_PREFIX)
    if not stamp.isdigit():
        raise DatasetError(f"{path}: expected the name {POSE_PREFIX}<timestamp ns>.json")
    return int(stamp)


def _vehicle_pose(path: Path) -> np.ndarray:
    """``T_city_vehicle`` (4, 4) of one ``city_SE3_egovehicle_<ns>.json``."""
    return _pose(read_json_calibration(path, "pose file"), "rotation", "translation")
