"""Front end: the stereo point and line features of one rectified image pair, without state.

`extract_stereo_features` detects ORB points and LSD lines in both images, two threads at
a time (OpenCV releases the GIL), then matches each kind between the two images.

Timing on KITTI 06 (1226 x 370, 2,000 ORB points) on a 2-core machine: the stages cost
about 80 ms of CPU per pair (ORB 27, LSD 24, LBD 12, matching 8); with two worker threads
the wall time is about 46 ms. The pool is made per call: 0.5 ms, against 0.05 ms for a
module-level pool that would outlive its caller.
"""

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from pld_slam.config import LinesConfig, PointsConfig
from pld_slam.frontend.lines import StereoLines, detect_image_lines, match_stereo_lines
from pld_slam.frontend.points import StereoPoints, detect_image_points, match_stereo_points
from pld_slam.geometry.camera import StereoCamera

__all__ = ["StereoFeatures", "StereoLines", "StereoPoints", "extract_stereo_features"]


@dataclass(frozen=True)
class StereoFeatures:
    """The stereo-matched features of one rectified pair (left image, left camera frame)."""

    points: StereoPoints
    lines: StereoLines


def extract_stereo_features(
    left: np.ndarray,
    right: np.ndarray,
    camera: StereoCamera,
    points_config: PointsConfig,
    lines_config: LinesConfig,
) -> StereoFeatures:
    """Stereo points and lines of a rectified grey pair (H, W) uint8.

    Points are detected in both images first, two threads at a time; their stereo
    matching then runs in this thread while the two line detections run in the pool, so
    the two cores stay busy. Lines are empty when ``lines_config.enabled`` is false. The
    output depends on the images and configs only: the same input gives bit-identical
    arrays.
    """
    with ThreadPoolExecutor(max_workers=2) as pool:
        point_jobs = [pool.submit(detect_image_points, image, points_config) for image in (left, right)]
        line_jobs = (
            [pool.submit(detect_image_lines, image, lines_config) for image in (left, right)]
            if lines_config.enabled
            else []
        )
        left_points, right_points = (job.result() for job in point_jobs)
        points = match_stereo_points(left_points, right_points, camera, points_config)
        if not line_jobs:
            return StereoFeatures(points=points, lines=StereoLines.empty())
        left_lines, right_lines = (job.result() for job in line_jobs)
    lines = match_stereo_lines(left_lines, right_lines, camera, lines_config)
    return StereoFeatures(points=points, lines=lines)
