"""A frame's matched features as pose-only observations of known 3D points and segments.

Tracking solves a frame's pose twice, against the reference frame's stereo features and
against the local map's landmarks; both build their observations here, the 3D side
expressed in the frame the solve estimates the pose from (reference camera or world).
So do fusion's reprojection test (`pld_slam.matching.fusion`) and the stereo calibration's
frame-pair poses (`pld_slam.stereo_calibration`).
"""

import numpy as np

from pld_slam.config import PointsConfig, TrackingConfig
from pld_slam.frontend import LeftKeypoints, StereoLines, StereoPoints
from pld_slam.geometry.camera import StereoCamera
from pld_slam.optim.line_reprojection import endpoints_away_from_border
from pld_slam.optim.observations import LineObservations, PointObservations


def point_observations(
    points_3d: np.ndarray, current: StereoPoints | LeftKeypoints, current_index: np.ndarray, config: PointsConfig
) -> PointObservations:
    """3D points (K, 3) observed as the pixels ``(u_l, v, u_r)`` of current points ``current_index`` (K,).

    ``u_r`` is NaN for keypoints without a stereo match (monocular observations). A point
    found at ORB octave ``o`` has a pixel sigma of ``scale_factor**o`` (as ORB-SLAM2) and a
    disparity sigma of ``disparity_sigma_px`` times that (`pld_slam.optim.observations`).
    """
    stereo_px = np.column_stack([current.uv, current.u_right])[current_index]
    octave_sigma = config.scale_factor ** current.octave[current_index].astype(np.float64)
    sigma = np.column_stack([octave_sigma, octave_sigma, config.disparity_sigma_px * octave_sigma])
    return PointObservations(points_3d, stereo_px, sigma)


def line_observations(
    camera: StereoCamera, endpoints_3d: np.ndarray, current: StereoLines, current_index: np.ndarray,
    config: TrackingConfig,
) -> LineObservations:
    """3D segments (K, 2, 3), start then end, observed as current stereo lines ``current_index`` (K,).

    The horizontal error is used only where both detected endpoints lie
    ``tracking.border_margin_px`` inside the image (paper: a segment cut by the border has
    no reliable endpoint).
    """
    detected = current.endpoints[current_index]
    right = current.right_endpoints[current_index]
    start_px, end_px = detected[:, :2], detected[:, 2:]
    return LineObservations(
        start_w=endpoints_3d[:, 0],
        end_w=endpoints_3d[:, 1],
        start_px=start_px,
        end_px=end_px,
        sigma_px=np.full(len(current_index), config.line_sigma_px),
        horizontal_eligible=endpoints_away_from_border(camera, start_px, end_px, config.border_margin_px),
        right_start_px=right[:, :2],
        right_end_px=right[:, 2:],
    )
