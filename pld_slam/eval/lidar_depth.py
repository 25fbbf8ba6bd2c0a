"""True depths under image pixels from the LiDAR scans of a KITTI odometry sequence.

KITTI odometry keeps a Velodyne scan per frame in ``velodyne/NNNNNN.bin`` (float32 x, y, z,
reflectance, LiDAR frame) and the LiDAR-to-left-camera transform ``Tr`` (3 x 4) in
``calib.txt``. A scan projected into the rectified left image is sparse: about 1 px apart
along a scan line, 5 px between the 64 lines on KITTI. The depth under a keypoint is read
off the surface the neighbouring scan points lie on: a plane's inverse depth is affine in
the pixel, ``1 / z = a u + b v + c``, so the plane fitted to the neighbours' inverse depths
gives the keypoint's exactly, where they do lie on one plane (`inverse_depth_at`). Where
they do not (a depth edge, foliage the laser sees into, too few or one-line neighbours)
the pixel gets no depth.

Limits of this truth, measured on KITTI 04 (`benchmarks/stereo_depth.py`): the scan is not
taken where the camera is (on KITTI 04, 0.33 m behind and 0.07 m above the left camera), so the
two see different sides of depth edges, and ``Tr``'s translation is known to a few
centimetres, which shifts every LiDAR depth by the same amount and a disparity by
``d^2 eps / bf``: a few hundredths of a pixel at 20 px, a tenth at 40 px. The scan's own
motion during a sweep (1.4 m per sweep at 14 m/s), compensated or not, changed the median
disparity errors of the middle image columns by under 0.05 px (the camera is triggered as
the laser looks ahead), but of the outer sixths by up to 0.5 px: it is not compensated, so
read the outer columns with care.
"""

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from pld_slam.datasets.calibration import read_kitti_calibration
from pld_slam.errors import DatasetError
from pld_slam.geometry.camera import StereoCamera

NEIGHBOUR_RADIUS_PX = 7.0
"""Scan points within this distance of a pixel [px] define its surface (two or three scan lines on KITTI)."""
MIN_NEIGHBOURS = 6
"""Fewest scan points for a plane."""
MIN_SPREAD_PX = 3.0
"""The neighbours must spread over at least this many columns and rows [px]: more than one scan line."""
MAX_PLANE_RESIDUAL = 0.004
"""RMS of the plane fit's inverse depths relative to the fitted one, at most this (0.4 % of the depth)."""
MAX_POINT_RESIDUAL = 0.015
"""No neighbour's inverse depth off the plane by more than this, relative (a second surface: a depth edge)."""
MAX_DEPTH_CHANGE = 0.2
"""The plane's inverse depth changes by at most this share over `NEIGHBOUR_RADIUS_PX`: steeper is a
surface seen edge-on or a plane fitted across a depth edge (the road 35 px below the horizon changes 20 %)."""
MIN_DEPTH_M = 1.0
"""Scan points nearer than this in front of the camera are left out [m]."""


@dataclass(frozen=True)
class ScanInImage:
    """A LiDAR scan projected into the rectified left image.

    Attributes
    ----------
    uv : (N, 2) float64
        Pixels (u, v) of the scan points inside the image.
    inverse_depth : (N,) float64
        ``1 / z`` of each point in the left camera frame [1/m].
    """

    uv: np.ndarray
    inverse_depth: np.ndarray


def scan_path(sequence_root: Path, index: int) -> Path:
    """``velodyne/NNNNNN.bin`` of frame ``index`` in a KITTI odometry sequence folder."""
    return sequence_root / "velodyne" / f"{index:06d}.bin"


def scanned_frames(sequence_root: Path) -> list[int]:
    """The frame indices that have a scan in ``velodyne/``, ascending (none without the folder)."""
    folder = sequence_root / "velodyne"
    return sorted(int(path.stem) for path in folder.glob("*.bin") if path.stem.isdigit()) if folder.is_dir() else []


def lidar_to_camera(sequence_root: Path) -> np.ndarray:
    """``T_c_l`` (4, 4): ``Tr`` of ``calib.txt``, LiDAR points into the left camera frame."""
    calibration = read_kitti_calibration(sequence_root / "calib.txt")
    if not calibration.has("Tr"):
        raise DatasetError(f"{calibration.path}: no 'Tr' (LiDAR to left camera): no LiDAR calibration")
    return np.vstack([calibration.array("Tr", (3, 4)), [0.0, 0.0, 0.0, 1.0]])


def read_scan(path: Path) -> np.ndarray:
    """The points (N, 3) float64 of a KITTI ``.bin`` scan in the LiDAR frame [m]."""
    raw = np.fromfile(path, dtype=np.float32)
    if raw.size % 4:
        raise DatasetError(f"{path}: {raw.size} floats, not a multiple of 4 (x, y, z, reflectance)")
    return raw.reshape(-1, 4)[:, :3].astype(np.float64)


def project_scan(points_l: np.ndarray, T_c_l: np.ndarray, camera: StereoCamera) -> ScanInImage:
    """The scan points (N, 3) in the LiDAR frame that fall inside the left image, as pixels and inverse depths."""
    points_c = points_l @ T_c_l[:3, :3].T + T_c_l[:3, 3]
    points_c = points_c[points_c[:, 2] > MIN_DEPTH_M]
    uv = camera.project(points_c)
    inside = camera.inside_image(uv)
    return ScanInImage(uv[inside], 1.0 / points_c[inside, 2])


def inverse_depth_at(scan: ScanInImage, pixels: np.ndarray) -> np.ndarray:
    """The surface's inverse depth (K,) [1/m] under each pixel (K, 2), NaN where the scan cannot say.

    A plane through the scan points within `NEIGHBOUR_RADIUS_PX`, fitted in inverse depth
    (affine in the pixel for a plane), evaluated at the pixel; no value where there are
    too few neighbours, they lie on one scan line, they fit no plane (a depth edge,
    foliage), or the plane is too steep (the module constants).
    """
    result = np.full(len(pixels), np.nan)
    if len(scan.uv) == 0:
        return result
    tree = cKDTree(scan.uv)
    for k, neighbours in enumerate(tree.query_ball_point(pixels, NEIGHBOUR_RADIUS_PX)):
        if len(neighbours) < MIN_NEIGHBOURS:
            continue
        offsets = scan.uv[neighbours] - pixels[k]
        inverse = scan.inverse_depth[neighbours]
        if np.ptp(offsets[:, 0]) < MIN_SPREAD_PX or np.ptp(offsets[:, 1]) < MIN_SPREAD_PX:
            continue
        design = np.column_stack([offsets, np.ones(len(neighbours))])
        plane, *_ = np.linalg.lstsq(design, inverse, rcond=None)
        off_plane = np.abs(design @ plane - inverse) / plane[2]
        steepness = np.hypot(plane[0], plane[1]) * NEIGHBOUR_RADIUS_PX / plane[2]
        planar = np.sqrt(np.mean(off_plane**2)) <= MAX_PLANE_RESIDUAL and off_plane.max() <= MAX_POINT_RESIDUAL
        if planar and steepness <= MAX_DEPTH_CHANGE:
            result[k] = plane[2]
    return result
