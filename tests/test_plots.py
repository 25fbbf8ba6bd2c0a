"""PNG plots: written off-screen, the expected size, with the curves drawn, and labelled truthfully."""

import numpy as np
import pytest
from matplotlib.image import imread
from trajectories import WORLD_CHANGE, drive

from pld_slam.errors import TrajectoryError
from pld_slam.eval import evaluate
from pld_slam.eval.plots import (
    comparison_top_view_figure,
    error_over_time_figure,
    plot_error_over_time,
    plot_trajectory_top_view,
    top_view_figure,
)
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


def test_the_error_plot_refuses_unmatched_trajectories_the_top_view_draws_them_unaligned(tmp_path):
    groundtruth = drive()
    later = Trajectory(groundtruth.timestamps + 1000.0, groundtruth.poses)
    with pytest.raises(TrajectoryError, match="no estimate time is within 0.01 s of a ground-truth time"):
        plot_error_over_time(tmp_path / "ate.png", groundtruth, later)  # there is no error to draw
    assert not (tmp_path / "ate.png").exists()
    plot_trajectory_top_view(tmp_path / "top.png", groundtruth, later)  # says "not aligned" on it
    assert (tmp_path / "top.png").stat().st_size > 1000


def line_labelled(axes, label: str):
    """The one line of ``axes`` whose legend entry is ``label``."""
    (line,) = [line for line in axes.get_lines() if line.get_label() == label]
    return line


def test_top_view_says_the_estimate_is_aligned_and_gives_the_ate_in_the_title():
    groundtruth = drive()
    estimate = noisy_estimate(groundtruth)
    axes = top_view_figure(groundtruth, estimate, title="seq").axes[0]
    line_labelled(axes, "estimate (SE(3)-aligned)")
    ate = evaluate(groundtruth, estimate).ate_rmse_m
    assert axes.get_title() == f"seq\nATE RMSE {ate:.3f} m (SE(3)-aligned)"
    sim3 = top_view_figure(groundtruth, estimate, title="seq", align="sim3").axes[0]
    assert sim3.get_title().endswith("(Sim(3)-aligned)")


def test_top_view_draws_the_ground_truth_over_the_estimate_and_starts_at_its_start():
    groundtruth = drive()
    axes = top_view_figure(groundtruth, noisy_estimate(groundtruth)).axes[0]
    truth, estimate = line_labelled(axes, "ground truth"), line_labelled(axes, "estimate (SE(3)-aligned)")
    assert truth.get_zorder() > estimate.get_zorder()
    assert truth.get_linewidth() > estimate.get_linewidth()
    start = line_labelled(axes, "start")
    assert start.get_xydata()[0] == pytest.approx(groundtruth.positions[0, [0, 2]])


def test_top_view_without_ground_truth_starts_at_the_estimate_and_claims_no_alignment():
    estimate = drive()
    axes = top_view_figure(None, estimate, title="estimate only").axes[0]
    assert axes.get_title() == "estimate only"
    assert line_labelled(axes, "start").get_xydata()[0] == pytest.approx(estimate.positions[0, [0, 2]])
    line_labelled(axes, "estimate")


def test_an_estimate_that_cannot_be_aligned_is_drawn_as_it_is_and_labelled_so_in_both_top_views():
    groundtruth = drive()
    elsewhere = Trajectory(groundtruth.timestamps + 1000.0, groundtruth.poses)  # no time in common
    single = top_view_figure(groundtruth, elsewhere, title="seq").axes[0]
    assert single.get_title().startswith("seq\nnot aligned: ")
    assert line_labelled(single, "estimate (not aligned)").get_xydata() == pytest.approx(
        elsewhere.positions[:, [0, 2]])
    several = comparison_top_view_figure(groundtruth, {"a": noisy_estimate(groundtruth), "b": elsewhere}).axes[0]
    (b_line,) = [line for line in several.get_lines() if line.get_label().startswith("b (not aligned: ")]
    assert b_line.get_xydata() == pytest.approx(elsewhere.positions[:, [0, 2]])
    (a_line,) = [line for line in several.get_lines() if line.get_label().startswith("a: ATE RMSE ")]
    assert a_line.get_label().endswith("(SE(3)-aligned)")


def test_error_over_time_labels_rows_as_rows_and_times_as_seconds():
    groundtruth = drive()
    estimate = noisy_estimate(groundtruth)
    by_row = error_over_time_figure(groundtruth, estimate, by_index=True).axes[0]
    assert by_row.get_xlabel() == "pose (row of the file)"
    assert by_row.get_lines()[0].get_xdata()[-1] == len(estimate) - 1
    by_time = error_over_time_figure(groundtruth, estimate).axes[0]
    assert by_time.get_xlabel() == "time [s]"
