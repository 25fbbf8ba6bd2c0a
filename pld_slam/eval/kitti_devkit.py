"""The KITTI odometry devkit drift metric (``evaluate_odometry.cpp``), vectorised.

Every `FIRST_FRAME_STEP`-th frame starts one segment of each length in
`SEGMENT_LENGTHS_M`; the segment ends at the first frame whose ground-truth path
distance from the start exceeds the length (segments running past the end are dropped).
The segment error is ``inv(inv(gt_a) @ gt_b) @ (inv(est_a) @ est_b)``; its translation
norm and rotation angle, each divided by the nominal length, are averaged over all
segments of all lengths. The devkit prints the means as m/m and rad/m; papers (and this
module) report ``t_rel`` [%] and ``r_rel`` [deg / 100 m].

Poses are matched by index: row i of the estimate is the same frame as row i of the
ground truth, as in the devkit.
"""

from dataclasses import dataclass

import numpy as np

from pld_slam.errors import TrajectoryError
from pld_slam.geometry.se3 import inverse, rotation_angle

SEGMENT_LENGTHS_M = (100.0, 200.0, 300.0, 400.0, 500.0, 600.0, 700.0, 800.0)
FIRST_FRAME_STEP = 10


@dataclass(frozen=True)
class SegmentErrors:
    """Drift of each evaluated segment (S segments).

    Attributes
    ----------
    first, last : np.ndarray
        (S,) int frame indices where the segment starts and ends.
    length_m : np.ndarray
        (S,) nominal segment length [m].
    translation : np.ndarray
        (S,) translation error over the length [m/m].
    rotation : np.ndarray
        (S,) rotation error over the length [rad/m].
    """

    first: np.ndarray
    last: np.ndarray
    length_m: np.ndarray
    translation: np.ndarray
    rotation: np.ndarray


def path_distances(poses: np.ndarray) -> np.ndarray:
    """Distance travelled from the first pose to each pose (N,) [m]; poses (N, 4, 4) ``T_w_c``."""
    steps = np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1)
    return np.concatenate([[0.0], np.cumsum(steps)])


def segment_endpoints(
    distances: np.ndarray,
    lengths: tuple[float, ...] = SEGMENT_LENGTHS_M,
    step: int = FIRST_FRAME_STEP,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """First frames, last frames and nominal lengths (each (S,)) of the segments that fit.

    ``distances`` (N,) is the ground-truth path distance of each frame (non-decreasing).
    """
    firsts = np.arange(0, len(distances), step)
    all_firsts, all_lasts, all_lengths = [], [], []
    for length in lengths:
        lasts = np.searchsorted(distances, distances[firsts] + length, side="right")
        fits = lasts < len(distances)
        all_firsts.append(firsts[fits])
        all_lasts.append(lasts[fits])
        all_lengths.append(np.full(np.count_nonzero(fits), length))
    return np.concatenate(all_firsts), np.concatenate(all_lasts), np.concatenate(all_lengths)


def segment_errors(
    groundtruth_poses: np.ndarray,
    estimate_poses: np.ndarray,
    lengths: tuple[float, ...] = SEGMENT_LENGTHS_M,
    step: int = FIRST_FRAME_STEP,
) -> SegmentErrors:
    """Devkit error of every segment.

    Parameters
    ----------
    groundtruth_poses, estimate_poses : np.ndarray
        (N, 4, 4) ``T_w_c`` of the same N frames, matched by index.
    lengths : tuple of float
        Segment lengths [m] along the ground-truth path.
    step : int
        Frames between two segment starts.
    """
    if groundtruth_poses.shape != estimate_poses.shape:
        raise TrajectoryError(
            f"the KITTI metric needs poses matched by index: ground truth "
            f"{groundtruth_poses.shape[0]} poses, estimate {estimate_poses.shape[0]}"
        )
    first, last, length = segment_endpoints(path_distances(groundtruth_poses), lengths, step)
    gt_motion = inverse(groundtruth_poses[first]) @ groundtruth_poses[last]
    est_motion = inverse(estimate_poses[first]) @ estimate_poses[last]
    error = inverse(gt_motion) @ est_motion
    return SegmentErrors(
        first=first,
        last=last,
        length_m=length,
        translation=np.linalg.norm(error[:, :3, 3], axis=1) / length,
        rotation=rotation_angle(error[:, :3, :3]) / length,
    )


def kitti_relative_errors(
    groundtruth_poses: np.ndarray, estimate_poses: np.ndarray
) -> tuple[float | None, float | None]:
    """KITTI ``t_rel`` [%] and ``r_rel`` [deg / 100 m] averaged over all segments.

    Poses are (N, 4, 4) ``T_w_c`` matched by index. Both are None when the ground-truth
    path is too short for a single 100 m segment.
    """
    errors = segment_errors(groundtruth_poses, estimate_poses)
    if errors.first.size == 0:
        return None, None
    t_rel_pct = 100.0 * float(np.mean(errors.translation))
    r_rel_deg_per_100m = 100.0 * float(np.degrees(np.mean(errors.rotation)))
    return t_rel_pct, r_rel_deg_per_100m
