"""PNG plots: written off-screen, the expected size, and with the curves drawn."""

import numpy as np
import pytest
from matplotlib.image import imread
from trajectories import WORLD_CHANGE, drive

from pld_slam.errors import TrajectoryError
from pld_slam.eval.plots import plot_error_over_time, plot_trajectory_top_view
from pld_slam.trajectory import Trajectory

ESTIMATE_BLUE = np.array([0.0, 0.0, 1.0])  # the "b-" line


def noisy_estimate(groundtruth: Trajectory) -> Trajectory:
    """The ground truth with 0.5 m position noise, in another world frame."""
    noisy = groundtruth.poses.copy()
    noisy[:, :3, 3] += np.random.default_rng(0).normal(0.0, 0.5, (len(groundtruth), 3))
    return Trajectory(groundtruth.timestamps, WORLD_CHANGE @ noisy)


def blue_pixel_count(path_png) -> int:
    image = imread(path_png)
    assert image.shape == (480, 640, 4)
    return int(np.count_nonzero(np.all(np.abs(image[:, :, :3] - ESTIMATE_BLUE) < 0.1, axis=2)))


def test_top_view_draws_ground_truth_and_estimate(tmp_path):
    groundtruth = drive()
    plot_trajectory_top_view(tmp_path / "top.png", groundtruth, noisy_estimate(groundtruth))
    assert blue_pixel_count(tmp_path / "top.png") > 500


def test_top_view_without_ground_truth(tmp_path):
    plot_trajectory_top_view(tmp_path / "top.png", None, drive(), title="estimate only")
    assert blue_pixel_count(tmp_path / "top.png") > 500


def test_error_over_time_draws_the_error_curve(tmp_path):
    groundtruth = drive()
    plot_error_over_time(tmp_path / "ate.png", groundtruth, noisy_estimate(groundtruth))
    assert blue_pixel_count(tmp_path / "ate.png") > 500


def test_plots_refuse_unmatched_trajectories(tmp_path):
    groundtruth = drive()
    later = Trajectory(groundtruth.timestamps + 1000.0, groundtruth.poses)
    with pytest.raises(TrajectoryError, match="no matching timestamps"):
        plot_trajectory_top_view(tmp_path / "top.png", groundtruth, later)
    assert not (tmp_path / "top.png").exists()
