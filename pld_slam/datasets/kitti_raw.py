"""KITTI raw layout: ``.../DATE/DATE_drive_NNNN_sync/{image_00/, image_01/, oxts/}``.

- Images: ``image_00/data/*.png`` (left grey) and ``image_01/data/*.png`` (right grey),
  synced and rectified, paired by file name (`pld_slam.datasets.files.paired_images`):
  a file without a partner of the same name raises, naming it. Or the colour pair,
  ``image_02/data/`` and ``image_03/data/`` (read as grey), where the drive has no
  ``image_00/`` or ``dataset.cameras`` asks for it (`pld_slam.datasets.kitti_cameras`).
- Frame rate: KITTI's nominal 10 Hz (`pld_slam.datasets.kitti_odometry.FRAME_RATE`).
- Times: ``image_00/timestamps.txt`` (colour: ``image_02/``), datetimes such as
  ``2011-09-26 13:04:32.351950336``, read as UTC seconds since the Unix epoch; the whole
  seconds and the nanoseconds are added once in float64, which keeps them to float64's
  resolution (about 0.2 us).
- Camera: ``P_rect_00`` and ``P_rect_01`` of ``calib_cam_to_cam.txt`` one folder up
  (``S_rect_00`` gives the image size); colour: ``P_rect_02``, ``P_rect_03``, ``S_rect_02``.
- Ground truth (when ``oxts/data/`` exists): one OXTS packet per frame (in natural name
  order, as the images), turned into poses as the KITTI raw devkit's
  ``convertOxtsToPose`` does (Mercator projection scaled by the
  first latitude, ``R = Rz(yaw) Ry(pitch) Rx(roll)``), then moved from the IMU to the
  rectified left camera with ``T_cam0rect_imu = R_rect_00 T_cam0_velo T_velo_imu``
  (``calib_velo_to_cam.txt``, ``calib_imu_to_velo.txt``; the colour pair's left camera
  cam2 is ``T_cam2rect_imu = T_cam2rect_cam0rect T_cam0rect_imu``, the first factor from
  ``P_rect_02``, `pld_slam.datasets.calibration.camera_from_reference`):
  ``T_w_c_i = T_c_imu inv(T_oxts(t_0)) T_oxts(t_i) inv(T_c_imu)``, so the first is
  identity. The ``_sync`` product pairs packet i with image i, but the packet was taken
  at its own time (``oxts/timestamps.txt``), -5 to +5 ms from the image's on drive 0005
  (2.9 ms RMS): at 10 m/s, up to 5 cm away from where the camera was. So the OXTS poses
  are interpolated to the image times ``t_i`` (`pld_slam.geometry.se3.interpolate_poses`;
  the first and last image may lie a few ms outside the packets' span and are
  extrapolated). On drive 0005 (3.3 m/s) that moved the poses by 1.0 cm RMS and brought
  our trajectory's RPE from 0.0335 to 0.0299 m and 0.064 to 0.051 deg, its ATE from
  0.0881 to 0.0871 m: the interpolated poses agree better with the images. Without
  ``oxts/timestamps.txt`` (or with a single frame) packet i keeps image i's time. A
  packet more than half a frame (at KITTI's nominal 10 Hz) from its image means the file
  does not belong to the drive: opening the drive raises, naming the file.
"""

from pathlib import Path

import numpy as np

from pld_slam.datasets.base import ImageFiles, StereoSequence
from pld_slam.datasets.calibration import (
    PINHOLE_ENTRIES,
    Calibration,
    camera_from_reference,
    read_kitti_calibration,
    stereo_camera_from_projections,
)
from pld_slam.datasets.files import natural_sorted, paired_image_folders, read_times
from pld_slam.datasets.kitti_cameras import CameraPair, chosen_pair
from pld_slam.datasets.kitti_odometry import FRAME_RATE
from pld_slam.errors import DatasetError, read_user_text
from pld_slam.geometry.se3 import interpolate_poses, inverse, make_pose
from pld_slam.trajectory import Trajectory

LAYOUT = "kitti_raw"
EXPECTED = (
    "KITTI raw (DATE_drive_NNNN_sync/ with image_00/data/, image_01/data/, "
    "image_00/timestamps.txt or the same of image_02/, image_03/, and calib_cam_to_cam.txt one folder up)"
)

_SIZE_KEYS = {"grey": "S_rect_00", "colour": "S_rect_02"}
"""The key of each pair's rectified image size (width, height) [px] in ``calib_cam_to_cam.txt``."""

EARTH_RADIUS = 6378137.0
"""Earth radius [m] of the devkit's Mercator projection."""

_OXTS_POSE_FIELDS = ("lat", "lon", "alt", "roll", "pitch", "yaw")
"""lat [deg], lon [deg], alt [m], roll, pitch, yaw [rad]: the first fields of a packet."""


def matches(folder: Path) -> bool:
    """Whether ``folder`` looks like a KITTI raw drive (it has ``image_00/`` or ``image_02/``)."""
    return (folder / "image_00").is_dir() or (folder / "image_02").is_dir()


def camera_pairs(folder: Path) -> tuple[CameraPair, CameraPair]:
    """The grey and the colour pair of the drive ``folder``."""
    return (
        CameraPair("grey", folder / "image_00" / "data", folder / "image_01" / "data", ("P_rect_00", "P_rect_01")),
        CameraPair("colour", folder / "image_02" / "data", folder / "image_03" / "data", ("P_rect_02", "P_rect_03")),
    )


def load(folder: Path, cameras: str = "auto") -> StereoSequence:
    """Open the KITTI raw drive in ``folder`` from the pair ``cameras`` names
    (`pld_slam.datasets.kitti_cameras.chosen_pair`; see the module docstring)."""
    folder = folder.resolve()
    pair = chosen_pair(*camera_pairs(folder), cameras)
    left_paths, right_paths = paired_image_folders(pair.left, pair.right, (".png",))
    image_times_path = pair.left.parent / "timestamps.txt"
    timestamps = read_times(image_times_path, len(left_paths), parse_line=datetime_seconds)
    cam_to_cam = read_kitti_calibration(folder.parent / "calib_cam_to_cam.txt")
    width, height = cam_to_cam.array(_SIZE_KEYS[pair.name], (2,)).astype(int)
    P_left, P_right = (cam_to_cam.array(key, (3, 4), PINHOLE_ENTRIES) for key in pair.keys)
    camera = stereo_camera_from_projections(P_left, P_right, width, height, source=cam_to_cam.path, keys=pair.keys)
    return StereoSequence(
        name=f"kitti_raw_{folder.name.removesuffix('_sync')}",
        layout=LAYOUT,
        root=folder,
        camera=camera,
        timestamps=timestamps,
        frame_rate=FRAME_RATE,
        frames=ImageFiles(left_paths, right_paths, camera.size, pair.colour),
        groundtruth=_groundtruth(folder, timestamps, image_times_path, cam_to_cam, camera_from_reference(P_left)),
        cameras=pair.name,
    )


def datetime_seconds(text: str) -> float:
    """UTC seconds since the Unix epoch of ``YYYY-MM-DD hh:mm:ss.fffffffff``; ValueError if bad
    (``NaT``, numpy's not-a-time, included)."""
    moment = np.datetime64(text.replace(" ", "T"), "ns")
    if np.isnat(moment):
        raise ValueError(f"not a time: {text!r}")
    nanoseconds = int(moment.astype(np.int64))
    whole, fraction = divmod(nanoseconds, 1_000_000_000)
    return whole + fraction * 1e-9


def _groundtruth(
    folder: Path, timestamps: np.ndarray, image_times_path: Path, cam_to_cam: Calibration, T_c_cam0rect: np.ndarray
) -> Trajectory | None:
    """``T_w_c`` of the pair's rectified left camera ``c`` from OXTS, first = identity; None without OXTS.

    ``timestamps`` are the image times, read from ``image_times_path``; ``T_c_cam0rect``
    (4, 4) is rectified cam0's pose in ``c`` (the identity for the grey pair).
    """
    oxts_folder = folder / "oxts" / "data"
    if not oxts_folder.is_dir():
        return None
    packet_paths = natural_sorted(oxts_folder.glob("*.txt"))
    if len(packet_paths) != len(timestamps):
        raise DatasetError(
            f"{oxts_folder}: {len(packet_paths)} OXTS packets for {len(timestamps)} frames"
        )
    T_w_imu = oxts_poses(np.array([read_oxts_pose_fields(path) for path in packet_paths]))
    T_w_imu = _at_image_times(T_w_imu, folder / "oxts" / "timestamps.txt", timestamps, image_times_path)
    T_imu0_imu = inverse(T_w_imu[0]) @ T_w_imu
    T_c_imu = T_c_cam0rect @ cam0_rect_from_imu(folder.parent, cam_to_cam)
    # The exact matrix inverse, not se3.inverse: the calibration rotations are printed to
    # 7 digits, ~1e-7 off SO(3), and a transpose would leave the first pose off identity.
    T_w_c = T_c_imu @ T_imu0_imu @ np.linalg.inv(T_c_imu)
    return Trajectory(timestamps, T_w_c)


def _at_image_times(
    T_w_imu: np.ndarray, times_path: Path, image_times: np.ndarray, image_times_path: Path
) -> np.ndarray:
    """OXTS poses (N, 4, 4) moved from their packets' times (``times_path``) to the image
    times (N,) [s] (read from ``image_times_path``; module docstring); unchanged when
    ``times_path`` does not exist or there is a single frame (nothing to interpolate between)."""
    if not times_path.is_file() or len(image_times) < 2:
        return T_w_imu
    packet_times = read_times(times_path, len(image_times), parse_line=datetime_seconds)
    gap = np.abs(packet_times - image_times)
    if gap.max() > 0.5 / FRAME_RATE.hz:
        frame = int(np.argmax(gap))
        raise DatasetError(
            f"{times_path}: packet {frame} is {gap[frame] * 1e3:.0f} ms from image {frame} "
            f"(of {image_times_path}), more than half a frame"
        )
    return interpolate_poses(packet_times, T_w_imu, image_times)


def read_oxts_pose_fields(path: Path) -> np.ndarray:
    """(6,) lat [deg], lon [deg], alt [m], roll, pitch, yaw [rad] of one OXTS packet file.

    Raises `DatasetError` naming the file (and the field) when they are not six finite numbers.
    """
    fields = read_user_text(path, DatasetError, "OXTS packet").split()[: len(_OXTS_POSE_FIELDS)]
    try:
        values = np.array(fields, dtype=np.float64)
    except ValueError:
        raise DatasetError(f"{path}: OXTS packet is not numbers") from None
    if values.size != len(_OXTS_POSE_FIELDS):
        raise DatasetError(f"{path}: OXTS packet has {values.size} fields, expected at least 6")
    not_finite = np.flatnonzero(~np.isfinite(values))
    if not_finite.size:
        name, text = _OXTS_POSE_FIELDS[not_finite[0]], fields[not_finite[0]]
        raise DatasetError(f"{path}: OXTS packet's {name} is {text!r}, not a finite number")
    return values


def oxts_poses(fields: np.ndarray) -> np.ndarray:
    """(N, 4, 4) ``T_w_imu`` of OXTS packets (N, 6), as the devkit's ``convertOxtsToPose``.

    The world is the devkit's local Mercator frame (x east, y north, z up [m]), scaled by
    ``cos(lat_0)`` of the first packet; not yet moved to the first pose.
    """
    lat, lon, alt, roll, pitch, yaw = fields.T
    scale = np.cos(np.deg2rad(lat[0]))
    translations = np.column_stack(
        [
            scale * EARTH_RADIUS * np.deg2rad(lon),
            scale * EARTH_RADIUS * np.log(np.tan(np.deg2rad(90.0 + lat) / 2.0)),
            alt,
        ]
    )
    return np.array(
        [
            make_pose(rotation_zyx(r, p, y), t)
            for r, p, y, t in zip(roll, pitch, yaw, translations, strict=True)
        ]
    )


def rotation_zyx(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """(3, 3) ``Rz(yaw) Ry(pitch) Rx(roll)`` [rad]: the OXTS body attitude."""
    cr, sr = np.cos(roll), np.sin(roll)
    cp, sp = np.cos(pitch), np.sin(pitch)
    cy, sy = np.cos(yaw), np.sin(yaw)
    Rx = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
    Ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    Rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    return Rz @ Ry @ Rx


def cam0_rect_from_imu(calibration_folder: Path, cam_to_cam: Calibration) -> np.ndarray:
    """(4, 4) ``T_cam0rect_imu = R_rect_00 T_cam0_velo T_velo_imu`` from the ``calib_*.txt``."""
    velo_to_cam = read_kitti_calibration(calibration_folder / "calib_velo_to_cam.txt")
    imu_to_velo = read_kitti_calibration(calibration_folder / "calib_imu_to_velo.txt")
    T_cam0rect_cam0 = make_pose(cam_to_cam.rotation("R_rect_00"), np.zeros(3))
    T_cam0_velo = make_pose(velo_to_cam.rotation("R"), velo_to_cam.array("T", (3,)))
    T_velo_imu = make_pose(imu_to_velo.rotation("R"), imu_to_velo.array("T", (3,)))
    return T_cam0rect_cam0 @ T_cam0_velo @ T_velo_imu
