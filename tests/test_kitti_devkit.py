"""KITTI devkit drift: segment choice, constructed drifts with known answers, KITTI 00."""

import numpy as np
import pytest
from conftest import require
from scipy.spatial.transform import Rotation

from pld_slam.errors import TrajectoryError
from pld_slam.eval.kitti_devkit import (
    SEGMENT_LENGTHS_M,
    kitti_relative_errors,
    segment_endpoints,
    segment_errors,
)
from pld_slam.geometry.se3 import make_pose
from pld_slam.io.trajectory import read_kitti

STEP_M = 0.5
N_POSES = 2001  # 1000 m straight ahead along z


def straight_drive() -> tuple[np.ndarray, np.ndarray]:
    """Path distances (N,) [m] and poses (N, 4, 4) of a straight drive, STEP_M per frame."""
    distances = STEP_M * np.arange(N_POSES)
    poses = np.array([make_pose(np.eye(3), [0.0, 0.0, d]) for d in distances])
    return distances, poses


def mean_over_segments(per_length) -> float:
    """Mean of ``per_length(L)`` over the straight drive's segments, enumerated one by one.

    A segment of length L ends at the first frame strictly beyond L metres from its start
    (as in the devkit), i.e. L + STEP_M metres on; it must end inside the drive.
    """
    values = []
    for length in SEGMENT_LENGTHS_M:
        for first in range(0, N_POSES, 10):
            if first + round(length / STEP_M) + 1 < N_POSES:
                values.append(per_length(length))
    return float(np.mean(values))


def test_segments_start_every_tenth_frame_and_end_just_past_the_length():
    first, last, length = segment_endpoints(np.arange(250.0), lengths=(100.0, 200.0))
    np.testing.assert_array_equal(first, np.r_[np.arange(0, 141, 10), np.arange(0, 41, 10)])
    np.testing.assert_array_equal(last, first + length + 1)
    np.testing.assert_array_equal(length, [100.0] * 15 + [200.0] * 5)


def test_identical_trajectories_have_no_drift():
    _, poses = straight_drive()
    assert kitti_relative_errors(poses, poses) == (0.0, 0.0)


def test_one_percent_scale_error_is_one_percent_translation_drift():
    _, poses = straight_drive()
    scaled = poses.copy()
    scaled[:, :3, 3] *= 1.01
    t_rel, r_rel = kitti_relative_errors(poses, scaled)
    expected = 100.0 * mean_over_segments(lambda length: 0.01 * (length + STEP_M) / length)
    assert t_rel == pytest.approx(expected, rel=1e-9)
    assert round(t_rel, 2) == 1.0
    assert r_rel == 0.0


def test_constant_yaw_rate_error_is_its_rotation_drift():
    distances, poses = straight_drive()
    yaw_error_rad_per_m = 0.001
    yawing = poses.copy()
    yaw = yaw_error_rad_per_m * distances[:, None]
    yawing[:, :3, :3] = Rotation.from_euler("y", yaw).as_matrix()
    _, r_rel = kitti_relative_errors(poses, yawing)
    expected = mean_over_segments(lambda length: yaw_error_rad_per_m * (length + STEP_M) / length)
    assert r_rel == pytest.approx(100.0 * np.degrees(expected), rel=1e-6)
    assert round(r_rel, 2) == 5.74  # 0.001 rad/m = 5.73 deg/100 m, plus the half-metre overshoot


def test_path_shorter_than_100_m_has_no_drift():
    _, poses = straight_drive()
    assert kitti_relative_errors(poses[:200], poses[:200]) == (None, None)  # 99.5 m


def test_poses_must_be_matched_by_index():
    _, poses = straight_drive()
    with pytest.raises(TrajectoryError, match="ground truth 2001 poses, estimate 2000"):
        segment_errors(poses, poses[:-1])


def test_kitti_00_orb_slam2_published_drift(data_dir):
    groundtruth = read_kitti(require(data_dir / "kitti_odometry/poses_full/00.txt"))
    estimate = read_kitti(require(data_dir / "reference_trajectories/KITTI_00_ORB.txt"))
    t_rel, r_rel = kitti_relative_errors(groundtruth.poses, estimate.poses)
    assert (round(t_rel, 2), round(r_rel, 2)) == (0.70, 0.25)
