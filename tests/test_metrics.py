"""ATE / RPE through evo: association, alignment, known answers, KITTI 00 reference figures."""

import re

import numpy as np
import pytest
from conftest import require
from scipy.spatial.transform import Rotation
from trajectories import WORLD_CHANGE, drive

from pld_slam.errors import TrajectoryError
from pld_slam.eval.metrics import (
    associate,
    ate_errors,
    evaluate,
    fit_alignment,
    relative_pose_errors,
)
from pld_slam.geometry.se3 import make_pose
from pld_slam.io.trajectory import read_kitti
from pld_slam.trajectory import Trajectory


def with_poses(traj: Trajectory, poses: np.ndarray) -> Trajectory:
    return Trajectory(traj.timestamps, poses)


def test_estimate_in_another_world_frame_has_zero_error_after_se3_alignment():
    groundtruth = drive()
    result = evaluate(groundtruth, with_poses(groundtruth, WORLD_CHANGE @ groundtruth.poses))
    assert result.ate_rmse_m == pytest.approx(0.0, abs=1e-9)
    assert result.ate_rot_rmse_deg == pytest.approx(0.0, abs=1e-5)
    assert result.rpe_trans_rmse_m == pytest.approx(0.0, abs=1e-9)
    assert result.rpe_rot_rmse_deg == pytest.approx(0.0, abs=1e-5)
    assert result.t_rel_pct == pytest.approx(0.0, abs=1e-9)
    assert result.n_matched == 200


def test_without_alignment_a_constant_offset_is_the_ate():
    groundtruth = drive()
    shifted = groundtruth.poses.copy()
    shifted[:, :3, 3] += [3.0, 0.0, 4.0]
    estimate = with_poses(groundtruth, shifted)
    assert evaluate(groundtruth, estimate, align="none").ate_rmse_m == pytest.approx(5.0)
    assert evaluate(groundtruth, estimate, align="se3").ate_rmse_m == pytest.approx(0.0, abs=1e-9)


def test_without_alignment_a_constant_camera_rotation_is_the_rotation_ate():
    groundtruth = drive()
    tilt = make_pose(Rotation.from_euler("x", 2.0, degrees=True).as_matrix(), np.zeros(3))
    estimate = with_poses(groundtruth, groundtruth.poses @ tilt)
    result = evaluate(groundtruth, estimate, align="none")
    assert result.ate_rot_rmse_deg == pytest.approx(2.0)
    assert result.ate_rmse_m == pytest.approx(0.0, abs=1e-9)


def test_rotation_ate_is_free_of_the_roll_a_straight_drive_leaves_to_the_position_alignment():
    sway = [[0.1 * np.sin(0.5 * n), 0.02 * np.cos(0.7 * n), 1.2 * n] for n in range(12)]
    straight = np.array([make_pose(np.eye(3), position) for position in sway])
    groundtruth = Trajectory(np.arange(12) / 10.0, straight)
    noisy = straight.copy()
    noisy[:, :3, 3] += np.random.default_rng(0).normal(0.0, 0.01, (12, 3))
    estimate = with_poses(groundtruth, WORLD_CHANGE @ noisy)
    rolled = fit_alignment(groundtruth, estimate).apply(estimate).poses[:, :3, :3]
    assert np.degrees(Rotation.from_matrix(rolled[0]).magnitude()) > 0.5  # the positions' fit misses the roll
    assert evaluate(groundtruth, estimate).ate_rot_rmse_deg == pytest.approx(0.0, abs=1e-6)


def test_sim3_alignment_removes_a_scale_error_that_se3_cannot():
    groundtruth = drive()
    scaled = WORLD_CHANGE @ groundtruth.poses
    scaled[:, :3, 3] *= 0.5
    estimate = with_poses(groundtruth, scaled)
    assert evaluate(groundtruth, estimate, align="sim3").ate_rmse_m == pytest.approx(0.0, abs=1e-9)
    assert evaluate(groundtruth, estimate, align="se3").ate_rmse_m > 5.0
    assert fit_alignment(groundtruth, estimate, "sim3").scale == pytest.approx(2.0)


def scaled_about_start(traj: Trajectory, factor: float) -> Trajectory:
    """``traj`` with every position moved ``factor`` times as far from the first one."""
    poses = traj.poses.copy()
    poses[:, :3, 3] = traj.positions[0] + factor * (traj.positions - traj.positions[0])
    return with_poses(traj, poses)


@pytest.mark.parametrize("align", ["se3", "sim3", "none"])
def test_an_estimate_1_percent_too_long_reads_1_01_in_sim3_scale_and_path_ratio_whatever_the_alignment(align):
    """Scale and path ratio are the estimate's size over the truth's (> 1: too long), both
    from the matched poses before the ATE's alignment; the Sim(3) ATE of a noise-free
    estimate is 0."""
    groundtruth = drive()
    estimate = scaled_about_start(groundtruth, 1.01)
    result = evaluate(groundtruth, with_poses(estimate, WORLD_CHANGE @ estimate.poses), align=align)
    assert result.sim3_scale == pytest.approx(1.01, abs=1e-9)
    assert result.path_ratio == pytest.approx(1.01, abs=1e-9)
    assert result.ate_sim3_rmse_m == pytest.approx(0.0, abs=1e-9)
    assert fit_alignment(groundtruth, estimate, "sim3").scale == pytest.approx(1.0 / 1.01, abs=1e-9)
    shrunk = evaluate(groundtruth, scaled_about_start(groundtruth, 0.98), align=align)
    assert (shrunk.sim3_scale, shrunk.path_ratio) == (pytest.approx(0.98, abs=1e-9), pytest.approx(0.98, abs=1e-9))


def test_the_path_ratio_is_over_the_matched_poses_only_and_no_scale_is_read_off_a_ground_truth_at_rest():
    groundtruth = drive()
    half = scaled_about_start(groundtruth, 1.01).head(100)
    assert evaluate(groundtruth, half, by_index=True).path_ratio == pytest.approx(1.01, abs=1e-9)
    at_rest = Trajectory(np.arange(5.0), np.repeat(np.eye(4)[None], 5, axis=0))
    jitter = at_rest.poses.copy()
    jitter[:, :3, 3] = np.random.default_rng(0).normal(0.0, 0.01, (5, 3))
    result = evaluate(at_rest, with_poses(at_rest, jitter))
    assert result.path_ratio is None and result.sim3_scale is None


def test_no_scale_is_read_off_a_ground_truth_that_moves_less_than_ten_times_the_error():
    groundtruth = drive()
    noise = np.random.default_rng(1).normal(0.0, 1.0, (len(groundtruth), 3))
    lever = np.sqrt(np.mean(np.sum((groundtruth.positions - groundtruth.positions.mean(axis=0)) ** 2, axis=1)))
    for error_m, measurable in ((lever / 30.0, True), (lever / 5.0, False)):
        noisy = groundtruth.poses.copy()
        noisy[:, :3, 3] += noise * error_m / np.sqrt(3.0)
        result = evaluate(groundtruth, with_poses(groundtruth, noisy))
        assert (result.sim3_scale is not None) == measurable
        assert (result.path_ratio is not None) == measurable


def test_a_constant_per_frame_motion_error_is_the_per_frame_rpe():
    groundtruth = drive()
    error = make_pose(Rotation.from_rotvec([0.0, 0.002, 0.0]).as_matrix(), [0.03, 0.0, 0.04])
    motions = np.linalg.inv(groundtruth.poses[:-1]) @ groundtruth.poses[1:]
    poses = [groundtruth.poses[0]]
    for motion in motions:
        poses.append(poses[-1] @ motion @ error)
    estimate = with_poses(groundtruth, np.array(poses))
    trans_rmse, rot_rmse = relative_pose_errors(groundtruth, estimate)
    assert trans_rmse == pytest.approx(0.05)
    assert rot_rmse == pytest.approx(np.degrees(0.002))


def test_rpe_per_distance_sees_a_scale_error_over_each_segment():
    n = 301  # a straight 300 m drive, 1 m per frame: pairs exactly 100 m apart
    poses = np.array([make_pose(np.eye(3), [0.0, 0.0, float(i)]) for i in range(n)])
    groundtruth = Trajectory(np.arange(n, dtype=float), poses)
    scaled = poses.copy()
    scaled[:, :3, 3] *= 1.01
    estimate = with_poses(groundtruth, scaled)
    trans_rmse, rot_rmse = relative_pose_errors(groundtruth, estimate, 100, "m")
    assert trans_rmse == pytest.approx(1.0)
    assert rot_rmse == pytest.approx(0.0, abs=1e-9)
    with pytest.raises(TrajectoryError, match="no pose pairs 400 m apart"):
        relative_pose_errors(groundtruth, groundtruth, 400, "m")


def test_ate_errors_per_frame_give_the_rmse():
    groundtruth = drive()
    rng = np.random.default_rng(0)
    noisy = groundtruth.poses.copy()
    noisy[:, :3, 3] += rng.normal(0.0, 0.2, (len(groundtruth), 3))
    estimate = with_poses(groundtruth, WORLD_CHANGE @ noisy)
    timestamps, errors = ate_errors(groundtruth, estimate)
    np.testing.assert_array_equal(timestamps, groundtruth.timestamps)
    assert np.sqrt(np.mean(errors**2)) == pytest.approx(evaluate(groundtruth, estimate).ate_rmse_m)
    assert 0.2 < np.sqrt(np.mean(errors**2)) < 0.4  # ~ sqrt(3) * 0.2, less what alignment absorbs


def test_association_by_time_keeps_pairs_within_max_diff():
    groundtruth = drive(n=400, frame_rate_hz=100.0)
    estimate = Trajectory(groundtruth.timestamps[::10] + 0.003, groundtruth.poses[::10])
    gt_matched, est_matched = associate(groundtruth, estimate, max_diff=0.004)
    np.testing.assert_array_equal(gt_matched.timestamps, groundtruth.timestamps[::10])
    np.testing.assert_array_equal(est_matched.poses, estimate.poses)
    assert evaluate(groundtruth, estimate, max_diff=0.004).n_matched == 40
    span = re.escape("(estimate 40 poses, 100.003 to 103.903 s; ground truth 400 poses, 100.000 to 103.990 s)")
    with pytest.raises(TrajectoryError, match=f"no estimate time is within 0.002 s of a ground-truth time {span}"):
        associate(groundtruth, estimate, max_diff=0.002)


def test_association_by_index_takes_the_first_ground_truth_rows():
    groundtruth = drive()
    short = groundtruth.head(50)
    assert evaluate(groundtruth, short, by_index=True).n_matched == 50
    with pytest.raises(TrajectoryError, match="has 200 poses but the ground truth only 50"):
        associate(short, groundtruth, by_index=True)


def test_too_few_matches_and_unknown_alignment_are_refused():
    groundtruth = drive()
    assert evaluate(groundtruth, groundtruth.head(2), by_index=True).ate_rmse_m < 1e-9
    with pytest.raises(TrajectoryError, match="only 1 estimate pose"):
        evaluate(groundtruth, groundtruth.head(1), align="none", by_index=True)
    with pytest.raises(TrajectoryError, match="unknown alignment 'rigid'"):
        evaluate(groundtruth, groundtruth, align="rigid")


def test_collinear_positions_are_anchored_on_the_first_pose():
    """A straight drive leaves Umeyama's rotation free; the first poses anchor the estimate."""
    poses = np.array([make_pose(np.eye(3), [0.0, 0.0, float(i)]) for i in range(10)])
    line = Trajectory(np.arange(10.0), poses)
    moved = Trajectory(line.timestamps, WORLD_CHANGE @ line.poses)
    assert evaluate(line, moved).ate_rmse_m < 1e-9
    stretched = poses.copy()
    stretched[:, 2, 3] *= 1.1  # 10 % too long: the error grows along the line
    result = evaluate(line, Trajectory(line.timestamps, WORLD_CHANGE @ stretched))
    expected = np.sqrt(np.mean((0.1 * np.arange(10.0)) ** 2))
    assert result.ate_rmse_m == pytest.approx(expected)
    assert evaluate(line, Trajectory(line.timestamps, stretched), align="sim3").ate_rmse_m < 1e-9


def test_short_path_has_no_kitti_drift_and_json_keys_are_fixed():
    groundtruth = drive().head(40)
    result = evaluate(groundtruth, groundtruth, by_index=True)
    assert groundtruth.path_length() < 100.0
    assert result.t_rel_pct is None and result.r_rel_deg_per_100m is None
    assert list(result.as_dict()) == [
        "ate_rmse_m",
        "ate_rot_rmse_deg",
        "ate_sim3_rmse_m",
        "sim3_scale",
        "path_ratio",
        "rpe_trans_rmse_m",
        "rpe_rot_rmse_deg",
        "t_rel_pct",
        "r_rel_deg_per_100m",
        "n_matched",
    ]


@pytest.fixture(scope="module")
def kitti_00(data_dir):
    """Ground truth of KITTI 00 and a reader of the reference estimates beside it."""
    groundtruth = read_kitti(require(data_dir / "kitti_odometry/poses_full/00.txt"))
    references = data_dir / "reference_trajectories"
    return groundtruth, lambda name: read_kitti(require(references / name))


@pytest.mark.parametrize(
    ("name", "ate", "t_rel", "r_rel"),
    [
        ("KITTI_00_ORB.txt", 1.30, 0.70, 0.25),  # ORB-SLAM2's published KITTI 00 figures
        ("KITTI_00_SPTAM.txt", 3.74, 1.49, 0.56),  # what this code gives; a regression value
    ],
)
def test_kitti_00_reference_figures(kitti_00, name, ate, t_rel, r_rel):
    groundtruth, read_estimate = kitti_00
    result = evaluate(groundtruth, read_estimate(name), by_index=True)
    assert result.n_matched == 4541
    assert (round(result.ate_rmse_m, 2), round(result.t_rel_pct, 2)) == (ate, t_rel)
    assert round(result.r_rel_deg_per_100m, 2) == r_rel
