"""The ``pld-slam`` commands: output, JSON keys, exit codes and one-line errors."""

import dataclasses
import errno
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml
from click.testing import CliRunner
from conftest import REPO_ROOT, require
from evo.tools import file_interface

from pld_slam.config import FiltersConfig
from pld_slam.datasets import open_sequence
from pld_slam.errors import OutputError, stop_on_sigterm
from pld_slam.eval.stereo_pair import stereo_pair_verdict
from pld_slam.geometry.se3 import make_pose
from pld_slam.io.run_output import PartialTrajectory
from pld_slam.io.trajectory import (
    TUM_HEADER,
    read_kitti,
    read_trajectory,
    read_tum,
    write_euroc,
    write_kitti,
    write_tum,
)
from pld_slam.report import run_files
from pld_slam.synth.writer import write_sequence
from pld_slam.system import STAGES, System
from pld_slam.trajectory import Trajectory
from pld_slam_cli.demo import DEMO_FOLDER, demo_command
from pld_slam_cli.evaluate import scale_text
from pld_slam_cli.main import EXIT_INTERRUPTED, EXIT_TERMINATED, EXIT_USER_ERROR, cli
from pld_slam_cli.run import format_run_table, not_a_stereo_pair, skipped_frame_rows

JSON_KEYS = {
    "ate_rmse_m", "ate_rot_rmse_deg", "ate_sim3_rmse_m", "sim3_scale", "path_ratio", "rpe_trans_rmse_m",
    "rpe_rot_rmse_deg", "t_rel_pct", "r_rel_deg_per_100m", "n_matched",
}


def run(*args: str):
    return CliRunner().invoke(cli, [str(a) for a in args])


@pytest.fixture(scope="module")
def synthetic_sequence(tmp_path_factory):
    """A small dynamic sequence written by ``pld-slam synth``: every frame tracked (at 160 x 120 it tracked
    1 of 6, a run that now ends with an error, `pld_slam.eval.tracked_frames`)."""
    out = tmp_path_factory.mktemp("synth") / "seq"
    result = run("synth", out, "--scenario", "dynamic", "--frames", 6, "--size", "240x180", "--seed", 3)
    assert result.exit_code == 0, result.output
    return out


def test_synth_writes_a_sequence_the_loader_reads_with_ground_truth_and_masks(synthetic_sequence):
    sequence = open_sequence(synthetic_sequence)
    assert sequence.layout == "kitti_odometry"
    assert len(sequence) == 6
    assert (sequence.camera.width, sequence.camera.height) == (240, 180)
    assert sequence.camera.baseline == pytest.approx(0.5)
    assert sequence.groundtruth is not None and len(sequence.groundtruth) == 6
    assert np.allclose(sequence.groundtruth.poses[0], np.eye(4))
    assert sequence.groundtruth.path_length() > 1.0
    masks = [sequence.dynamic_mask(i) for i in range(len(sequence))]
    assert all(0.0 < mask.mean() < 0.6 for mask in masks)
    frame = sequence[5]
    assert frame.left.shape == (180, 240) and frame.left.dtype == np.uint8


def test_synth_rejects_a_bad_size_as_a_usage_error(tmp_path):
    result = run("synth", tmp_path / "x", "--size", "640by480")
    assert result.exit_code == 2
    assert "WIDTHxHEIGHT" in result.output


def test_eval_prints_the_table_and_json_with_the_documented_keys(synthetic_sequence, tmp_path):
    truth = read_kitti(synthetic_sequence / "poses.txt")
    shifted = truth.poses.copy()
    shifted[:, 0, 3] += 0.1 * np.arange(len(truth))  # drifts sideways
    estimate = tmp_path / "estimate.kitti.txt"
    write_kitti(estimate, Trajectory(truth.timestamps, shifted))

    table = run("eval", synthetic_sequence / "poses.txt", estimate)
    assert table.exit_code == 0, table.output
    assert "ATE RMSE" in table.output and "n/a (path < 100 m)" in table.output

    result = run("eval", synthetic_sequence / "poses.txt", estimate, "--json")
    values = json.loads(result.output)
    assert set(values) == JSON_KEYS
    assert values["n_matched"] == len(truth)
    assert values["ate_rmse_m"] > 0.01
    assert values["t_rel_pct"] is None and values["r_rel_deg_per_100m"] is None


def test_eval_shows_an_estimate_2_percent_too_long_on_the_scale_line_whatever_the_alignment(
        synthetic_sequence, tmp_path):
    truth = read_kitti(synthetic_sequence / "poses.txt")
    longer = truth.poses.copy()
    longer[:, :3, 3] = truth.positions[0] + 1.02 * (truth.positions - truth.positions[0])
    estimate = tmp_path / "longer.kitti.txt"
    write_kitti(estimate, Trajectory(truth.timestamps, longer))
    for align in ("se3", "sim3", "none"):
        output = run("eval", synthetic_sequence / "poses.txt", estimate, "--align", align).output
        assert re.search(r"^scale \(sim3\) / path +1\.0200 / 1\.0200 \(2\.00 % long\)$", output, re.M), output
        assert re.search(r"^ATE RMSE after Sim\(3\) +0\.0000 m$", output, re.M), output
    assert scale_text(0.99, None) == "0.9900 / n/a (1.00 % short)"
    assert scale_text(None, None) == "n/a"


def test_eval_against_a_sequence_folder_stamps_a_kitti_estimate_with_frame_times(synthetic_sequence, tmp_path):
    truth = read_kitti(synthetic_sequence / "poses.txt")
    estimate = tmp_path / "first_four.kitti.txt"
    write_kitti(estimate, truth.head(4))  # a run stopped early
    values = json.loads(run("eval", synthetic_sequence, estimate, "--json").output)
    assert values["n_matched"] == 4
    assert values["ate_rmse_m"] < 1e-6


def test_eval_writes_plots(synthetic_sequence, tmp_path):
    truth = synthetic_sequence / "poses.txt"
    result = run("eval", truth, truth, "--plot", tmp_path / "plots")
    assert result.exit_code == 0, result.output
    assert (tmp_path / "plots" / "trajectory_top_view.png").stat().st_size > 1000
    assert (tmp_path / "plots" / "ate_over_time.png").stat().st_size > 1000


def drifting_estimates(synthetic_sequence, tmp_path) -> list:
    """Two KITTI estimates of the synthetic sequence, both ``estimate.kitti.txt`` in folders a and b,
    drifting sideways 0.05 and 0.1 m per frame."""
    truth = read_kitti(synthetic_sequence / "poses.txt")
    paths = []
    for folder, drift in (("a", 0.05), ("b", 0.1)):
        poses = truth.poses.copy()
        poses[:, 0, 3] += drift * np.arange(len(truth))
        (tmp_path / folder).mkdir()
        write_kitti(tmp_path / folder / "estimate.kitti.txt", Trajectory(truth.timestamps, poses))
        paths.append(tmp_path / folder / "estimate.kitti.txt")
    return paths


def test_eval_of_several_estimates_prints_a_column_each_and_writes_evo_results_evo_res_reads(
        synthetic_sequence, tmp_path):
    estimates = drifting_estimates(synthetic_sequence, tmp_path)
    gt = synthetic_sequence / "poses.txt"
    singles = [json.loads(run("eval", gt, path, "--json").output) for path in estimates]
    table = run("eval", gt, *estimates, "--save-results", tmp_path / "results", "--plot", tmp_path / "plots")
    assert table.exit_code == 0, table.output
    header, ate = table.output.splitlines()[:2]
    assert header.split() == ["a_estimate.kitti", "b_estimate.kitti"]  # same stems: named by folder
    assert ate.split()[2::2] == [f"{single['ate_rmse_m']:.4f}" for single in singles]
    both = json.loads(run("eval", gt, *estimates, "--json").output)
    assert [both[name]["ate_rmse_m"] for name in ("a_estimate.kitti", "b_estimate.kitti")] == [
        single["ate_rmse_m"] for single in singles]
    for name, single in zip(("a_estimate.kitti", "b_estimate.kitti"), singles, strict=True):
        saved = file_interface.load_res_file(tmp_path / "results" / f"{name}.zip")
        assert saved.info["est_name"] == name
        assert saved.stats["rmse"] == pytest.approx(single["ate_rmse_m"], rel=1e-12)
        assert len(saved.np_arrays["error_array"]) == single["n_matched"]
    assert (tmp_path / "plots" / "trajectory_top_view.png").stat().st_size > 1000


def test_eval_of_one_estimate_saves_its_evo_result_as_the_file_given(synthetic_sequence, tmp_path):
    estimate = drifting_estimates(synthetic_sequence, tmp_path)[1]
    result = run("eval", synthetic_sequence / "poses.txt", estimate, "--save-results", tmp_path / "b.zip",
                 "--align", "sim3")
    assert result.exit_code == 0, result.output
    saved = file_interface.load_res_file(tmp_path / "b.zip")
    assert saved.info["alignment"] == "sim3" and saved.info["title"] == "ATE (sim3 alignment)"


def test_kitti_and_tum_files_cannot_be_paired(tmp_path):
    poses = np.stack([make_pose(np.eye(3), [0.0, 0.0, float(i)]) for i in range(5)])
    write_kitti(tmp_path / "a.txt", Trajectory(np.arange(5.0), poses))
    write_tum(tmp_path / "b.txt", Trajectory(np.arange(5.0), poses))
    result = run("eval", tmp_path / "a.txt", tmp_path / "b.txt")
    assert result.exit_code == EXIT_USER_ERROR
    assert result.output.startswith("error: cannot pair") and result.output.count("\n") == 1


def test_library_errors_are_one_line_with_exit_code_2_and_verbose_shows_the_traceback(tmp_path):
    bad = tmp_path / "bad.txt"
    bad.write_text("1 2 3\n")
    result = run("eval", bad, bad)
    assert result.exit_code == EXIT_USER_ERROR
    assert result.output.startswith(f"error: {bad}") and result.output.count("\n") == 1
    verbose = CliRunner().invoke(cli, ["--verbose", "eval", str(bad), str(bad)])
    assert verbose.exit_code == EXIT_USER_ERROR  # --verbose adds the traceback and changes nothing else
    assert verbose.stderr.startswith("Traceback (most recent call last):")
    assert verbose.stderr.endswith(result.output) and "TrajectoryError" in verbose.stderr


def test_eval_against_kitti_raw_uses_its_oxts_ground_truth(tmp_path, data_dir):
    folder = require(data_dir / "kitti_raw" / "2011_09_26" / "2011_09_26_drive_0005_sync")
    truth = open_sequence(folder).groundtruth
    estimate = tmp_path / "est.txt"
    write_kitti(estimate, truth.head(10))
    values = json.loads(run("eval", folder, estimate, "--json").output)
    assert values["n_matched"] == 10
    assert values["ate_rmse_m"] < 1e-6


def test_eval_of_a_folder_without_ground_truth_says_so(synthetic_sequence, tmp_path):
    folder = tmp_path / "no_truth"
    shutil.copytree(synthetic_sequence, folder)
    (folder / "poses.txt").unlink()
    result = run("eval", folder, synthetic_sequence / "poses.txt")
    assert result.exit_code == EXIT_USER_ERROR
    assert result.output == f"error: {folder}: this sequence has no ground truth\n"


def test_config_prints_the_effective_configuration(tmp_path):
    override = tmp_path / "mine.yaml"
    override.write_text("dynamic:\n  grid: false\n")
    result = run("config", "--config", override, "--set", "loop.detector=bow")
    assert result.exit_code == 0, result.output
    printed = yaml.safe_load(result.output)
    assert printed["dynamic"]["grid"] is False
    assert printed["loop"]["detector"] == "bow"
    assert printed["filters"]["point_grid_alpha"] == 1.5


def test_config_error_names_the_key():
    result = run("config", "--set", "filters.point_grid_alpfa=2")
    assert result.exit_code == EXIT_USER_ERROR
    known = ", ".join(sorted(spec.name for spec in dataclasses.fields(FiltersConfig)))
    assert "point_grid_alpha, point_grid_cell_height" in known
    assert result.output == (
        f"error: --set filters.point_grid_alpfa=2: unknown key filters.point_grid_alpfa (known: {known})\n"
    )


def test_run_writes_trajectories_summary_and_plot(synthetic_sequence, tmp_path):
    out = tmp_path / "run"
    result = run("run", synthetic_sequence, "--out", out, "--max-frames", 4)
    assert result.exit_code == 0, result.output
    assert "ATE RMSE" in result.output and "total ms/frame" in result.output
    assert re.search(r"^tracking failures +0$", result.output, re.M)
    assert re.search(r"^scale \(sim3\) / path +[0-9.]+ / [0-9.]+ \([0-9.]+ % (long|short)\)$", result.output, re.M)
    assert "loop ms/keyframe" in result.output and re.search(r"loops closed \(candidates\) +0 \(0\)", result.output)
    kitti = read_kitti(out / "trajectory.kitti.txt")
    assert len(kitti) == 4 and np.allclose(kitti.poses[0], np.eye(4))
    assert len((out / "trajectory.tum.txt").read_text().splitlines()) == 4 + 1  # a '#' header line
    assert (out / "trajectory.png").stat().st_size > 1000
    summary = json.loads((out / "summary.json").read_text())
    assert summary["frames"] == 4 and summary["frames_in_sequence"] == 6 and summary["completed"]
    assert JSON_KEYS <= set(summary) and summary["n_matched"] == 4
    assert summary["config"]["filters"]["point_grid_alpha"] == 1.5


def test_run_json_prints_the_summary_and_applies_overrides(synthetic_sequence, tmp_path):
    result = run("run", synthetic_sequence, "--out", tmp_path / "run", "--set", "lines.enabled=false", "--json")
    assert result.exit_code == 0, result.output
    summary = json.loads(result.output)
    assert summary["config"]["lines"]["enabled"] is False
    assert summary["features_median"]["stereo_lines"] == 0


def test_run_rejects_a_bad_override_before_running(synthetic_sequence, tmp_path):
    result = run("run", synthetic_sequence, "--out", tmp_path / "run", "--set", "lines.enabled=maybe")
    assert result.exit_code == EXIT_USER_ERROR
    assert result.output.startswith("error: --set lines.enabled=maybe: lines.enabled must be true or false")


def add_colour_copy_of_grey_pair(sequence: Path) -> None:
    """Give a KITTI-layout ``sequence`` a colour pair: its grey images written as BGR (which
    read back as the same grey) in ``image_2/``, ``image_3/``, and ``P2``, ``P3`` = ``P0``, ``P1``."""
    for grey, colour in (("image_0", "image_2"), ("image_1", "image_3")):
        (sequence / colour).mkdir()
        for path in (sequence / grey).iterdir():
            image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
            cv2.imwrite(str(sequence / colour / path.name), cv2.cvtColor(image, cv2.COLOR_GRAY2BGR))
    rows = (sequence / "calib.txt").read_text().splitlines()
    (sequence / "calib.txt").write_text("\n".join(rows + [rows[0].replace("P0", "P2"), rows[1].replace("P1", "P3")]))


def test_run_reads_the_kitti_colour_pair_when_set_and_says_so(synthetic_sequence, tmp_path):
    sequence = shutil.copytree(synthetic_sequence, tmp_path / "seq")
    add_colour_copy_of_grey_pair(sequence)
    grey = run("run", sequence, "--out", tmp_path / "grey", "--max-frames", 3, "--json")
    colour = run("run", sequence, "--out", tmp_path / "colour", "--max-frames", 3, "--set", "dataset.cameras=colour")
    assert grey.exit_code == 0 and colour.exit_code == 0, grey.output + colour.output
    assert json.loads(grey.output)["cameras"] == "grey"
    assert re.search(r"^cameras +colour pair$", colour.output, re.M)
    assert json.loads((tmp_path / "colour" / "summary.json").read_text())["cameras"] == "colour"
    # the same images through the same camera: the same poses
    trajectories = [(tmp_path / name / "trajectory.kitti.txt").read_text() for name in ("grey", "colour")]
    assert trajectories[0] == trajectories[1]


def test_run_asked_for_a_colour_pair_the_folder_lacks_names_the_folder(synthetic_sequence, tmp_path):
    result = run("run", synthetic_sequence, "--out", tmp_path / "run", "--set", "dataset.cameras=colour")
    assert result.exit_code == EXIT_USER_ERROR
    missing = synthetic_sequence.resolve() / "image_2"
    assert result.output == f"error: {missing}: image folder not found (dataset.cameras=colour reads the colour pair)\n"
    assert not (tmp_path / "run").exists()


def test_demo_generates_a_sequence_and_prints_accuracy_and_speed(tmp_path):
    result = run("demo", "--out", tmp_path / "demo", "--frames", 8)
    assert result.exit_code == 0, result.output
    assert "ATE RMSE" in result.output and "real-time factor" in result.output
    summary = json.loads((tmp_path / "demo" / "run" / "summary.json").read_text())
    assert summary["frames"] == 8 and summary["ate_rmse_m"] < 0.1
    assert result.stderr == ""  # no progress bar when stderr is not a terminal, as for run


def test_synth_draws_no_progress_bar_when_stderr_is_not_a_terminal(tmp_path):
    result = run("synth", tmp_path / "seq", "--frames", 2, "--size", "64x48")
    assert result.exit_code == 0, result.output
    assert result.stderr == ""


def test_run_reports_dynamic_labels_and_saves_overlays(synthetic_sequence, tmp_path):
    overlays = tmp_path / "overlays"
    result = run("run", synthetic_sequence, "--out", tmp_path / "run", "--save-dynamic", overlays)
    assert result.exit_code == 0, result.output
    assert "marked dynamic" in result.output
    assert sorted(path.name for path in overlays.iterdir()) == [f"{i:06d}.png" for i in range(1, 6)]
    dynamic = json.loads((tmp_path / "run" / "summary.json").read_text())["dynamic"]
    assert len(dynamic["per_frame"]) == 6
    assert dynamic["points"]["on_moving_objects"] > 0  # the synthetic sequence has masks


# ---------------------------------------------------------------- runs that fail safe


def test_run_stops_on_left_and_right_images_that_do_not_pair_naming_the_first(synthetic_sequence, tmp_path):
    sequence = shutil.copytree(synthetic_sequence, tmp_path / "seq")
    (sequence / "image_0" / "000001.png").unlink()  # a frame missing on each side: counts stay equal
    (sequence / "image_1" / "000002.png").unlink()
    result = run("run", sequence, "--out", tmp_path / "run")
    assert result.exit_code == EXIT_USER_ERROR
    unpaired, other = sequence / "image_1" / "000001.png", sequence / "image_0"
    assert result.output == f"error: {unpaired}: no image with the same name in {other}\n"


def with_line(sequence: Path, relative: str, line_number: int, text: str) -> Path:
    """Replace line ``line_number`` (from 1) of the file ``relative`` of ``sequence`` by ``text``."""
    path = sequence / relative
    lines = path.read_text().splitlines()
    lines[line_number - 1] = text
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.mark.parametrize("line_number, time", [(6, "inf"), (3, "nan")])
def test_a_time_that_is_not_finite_stops_the_run_naming_times_txt_and_its_line(
        synthetic_sequence, tmp_path, no_frame_may_run, line_number, time):
    sequence = shutil.copytree(synthetic_sequence, tmp_path / "seq")
    times = with_line(sequence, "times.txt", line_number, time)
    result = run("run", sequence, "--out", tmp_path / "run")
    assert result.exit_code == EXIT_USER_ERROR, result.output
    assert result.output == f"error: {times}:{line_number}: not a finite time: {time!r}\n"


def test_a_ground_truth_pose_that_is_not_finite_stops_the_run_naming_its_file_and_line(
        synthetic_sequence, tmp_path, no_frame_may_run):
    sequence = shutil.copytree(synthetic_sequence, tmp_path / "seq")
    poses = sequence / "poses.txt"
    row = poses.read_text().splitlines()[2].split()
    with_line(sequence, "poses.txt", 3, " ".join(["nan", *row[1:]]))
    result = run("run", sequence, "--out", tmp_path / "run")
    assert result.exit_code == EXIT_USER_ERROR, result.output
    assert result.output == f"error: {poses}:3: not a finite number: 'nan'\n"


@pytest.mark.parametrize(
    "line_number, index, number, problem",
    [
        (1, 2, "nan", "cx of P0 is nan, not a finite number"),
        (2, 3, "-inf", "tx of P1 is -inf, not a finite number"),
        (1, 0, "inf", "fx of P0 is inf, not a finite number"),
        (1, 2, "900", "cx of P0 is 900, outside the image (0 to its width, 240 px)"),
        (1, 5, "-192", "fy of P0 is -192; a focal length must be positive"),
    ],
)
def test_a_calibration_value_that_is_not_finite_or_implausible_stops_the_run_naming_it(
        synthetic_sequence, tmp_path, no_frame_may_run, line_number, index, number, problem):
    sequence = shutil.copytree(synthetic_sequence, tmp_path / "seq")
    row = (sequence / "calib.txt").read_text().splitlines()[line_number - 1].split()  # "P0:" then 12 numbers
    row[1 + index] = number
    calib = with_line(sequence, "calib.txt", line_number, " ".join(row))
    result = run("run", sequence, "--out", tmp_path / "run")
    assert result.exit_code == EXIT_USER_ERROR, result.output
    assert result.output == f"error: {calib}: {problem}\n"


def swap_left_and_right(sequence: Path) -> None:
    """Exchange the left and right image folders of a KITTI-layout ``sequence``."""
    (sequence / "image_0").rename(sequence / "left")
    (sequence / "image_1").rename(sequence / "image_0")
    (sequence / "left").rename(sequence / "image_1")


def right_copy_of_left(sequence: Path) -> None:
    """Make the right images of a KITTI-layout ``sequence`` copies of the left ones."""
    shutil.rmtree(sequence / "image_1")
    shutil.copytree(sequence / "image_0", sequence / "image_1")


@pytest.mark.parametrize("break_it", [swap_left_and_right, right_copy_of_left])
def test_a_run_that_tracks_no_frame_writes_its_files_and_ends_with_the_likely_causes(
        synthetic_sequence, tmp_path, break_it):
    sequence = shutil.copytree(synthetic_sequence, tmp_path / "seq")
    break_it(sequence)
    out = tmp_path / "run"
    result = run("run", sequence, "--out", out)
    assert result.exit_code == EXIT_USER_ERROR, result.output
    error = result.output.splitlines()[-1]
    assert error.startswith(f"error: tracked none of the 6 frames (frame 0: {sequence / 'image_0' / '000000.png'}: ")
    assert error.endswith("; likely causes: left and right images swapped or the same, images too dark "
                          "(e.g. 12-bit data in 16-bit PNGs), or a calibration that does not fit them")
    assert (out / "trajectory.tum.txt").is_file() and (out / "summary.json").is_file()


def right_camera_one_frame_late(sequence: Path) -> None:
    """Make each right image of a KITTI-layout ``sequence`` the one of the frame before (frame 0 keeps its own)."""
    rights = sorted((sequence / "image_1").glob("*.png"))
    for earlier, later in reversed(list(zip(rights, rights[1:]))):
        shutil.copyfile(earlier, later)


@pytest.fixture(scope="module")
def street(tmp_path_factory) -> Path:
    """A static street of 10 frames at 320 x 240, enough corners for the stereo pair's check."""
    folder = tmp_path_factory.mktemp("street") / "seq"
    write_sequence(folder, "static", 10, size=(320, 240), seed=3)
    return folder


@pytest.mark.parametrize("family_prior", [True, False])
def test_a_rig_known_to_be_off_warns_when_its_offset_could_not_be_estimated(street, tmp_path, family_prior):
    # Issue 39: a KITTI drive too short (or too fast) for the self-calibration keeps the rig's whole offset,
    # about 1 % of scale. Without synth.json the street reads as KITTI odometry: the family's prior says the
    # rig is off; 10 frames give 2 anchors of the 6 an estimate needs. With no prior, nothing to warn of.
    sequence = shutil.copytree(street, tmp_path / "seq")
    (sequence / "synth.json").unlink()
    prior = [] if family_prior else ["--set", "calibration.prior_sigma_px=0"]
    result = CliRunner().invoke(cli, ["run", str(sequence), "--out", str(tmp_path / "run"), *prior])
    assert result.exit_code == 0, result.output
    estimate = json.loads((tmp_path / "run" / "summary.json").read_text())["disparity_offset"]
    assert not estimate["used"] and "fewer than 6" in estimate["reason"]
    warnings = [line for line in result.output.splitlines() if line.startswith("warning:")]
    if family_prior:
        assert warnings == [f"warning: {sequence}: the rig's disparity offset was not estimated "
                            f"({estimate['reason']}); rigs of this kind are off by about 0.15 px "
                            "(calibration.prior_sigma_px), which at 15 px of disparity scales the trajectory by "
                            "about 1 %: a longer or slower drive gives the estimate"]
    else:
        assert warnings == []


@pytest.mark.parametrize("late", [False, True])
def test_a_run_warns_of_a_right_camera_one_frame_late_in_the_table_and_summary(street, tmp_path, late):
    sequence = shutil.copytree(street, tmp_path / "seq")
    if late:
        right_camera_one_frame_late(sequence)
    result = CliRunner().invoke(cli, ["run", str(sequence), "--out", str(tmp_path / "run")])
    assert result.exit_code == 0, result.output
    stereo_pair = json.loads((tmp_path / "run" / "summary.json").read_text())["stereo_pair"]
    row = next(line for line in result.output.splitlines() if line.startswith("stereo pair"))
    if late:
        assert stereo_pair["verdict"] == "rows_disagree"
        assert stereo_pair["row_agreement"] < 0.86
        assert stereo_pair["warning"].startswith("the stereo pair disagrees: ")
        assert row.endswith(f"WARNING: {stereo_pair['warning']}")
        assert f"warning: {sequence}: {stereo_pair['warning']}" in result.output.splitlines()
    else:
        assert stereo_pair["verdict"] == "agrees" and stereo_pair["warning"] is None
        assert stereo_pair["row_agreement"] > 0.92 and stereo_pair["keypoint_share"] > 0.3
        assert "agrees (" in row and "warning" not in result.output.lower()


def test_the_stereo_pair_verdict_from_its_two_measures():
    assert stereo_pair_verdict(0.30, 0.95) == "agrees"
    assert stereo_pair_verdict(0.30, 0.70) == "rows_disagree"
    assert stereo_pair_verdict(0.01, 0.95) == "few_matches"
    assert stereo_pair_verdict(0.01, 0.60) == "not_a_pair" and stereo_pair_verdict(0.01, None) == "not_a_pair"
    assert stereo_pair_verdict(None, None) == "unknown"


def test_a_run_on_images_that_are_not_a_stereo_pair_ends_with_an_error_naming_the_sequence():
    summary = {"root": "/data/seq", "stereo_pair": {"verdict": "not_a_pair", "warning": "not a stereo pair: ..."}}
    assert not_a_stereo_pair(summary) == "/data/seq: not a stereo pair: ..."
    assert not_a_stereo_pair({**summary, "stereo_pair": {"verdict": "rows_disagree", "warning": "x"}}) is None


@pytest.fixture
def no_frame_may_run(monkeypatch):
    """Makes processing any frame fail the test: the check must come before the first frame."""

    def refuse(self, index):
        raise AssertionError(f"frame {index} processed before the output folder was checked")

    monkeypatch.setattr("pld_slam.system.System.process_frame", refuse)


@pytest.mark.parametrize("command", ["run", "demo"])
def test_an_output_folder_under_a_file_is_a_one_line_error_before_the_first_frame(
        synthetic_sequence, tmp_path, no_frame_may_run, command):
    a_file = tmp_path / "a_file"
    a_file.write_text("not a folder\n")
    out = a_file / "run"
    args = ("run", synthetic_sequence, "--out", out) if command == "run" else ("demo", "--out", out, "--frames", 2)
    result = run(*args)
    assert result.exit_code == EXIT_USER_ERROR, result.output
    assert result.output.startswith(f"error: {out}: cannot write (") and result.output.count("\n") == 1


@pytest.mark.skipif(not hasattr(os, "geteuid") or os.geteuid() == 0, reason="root writes despite permission bits")
def test_an_output_folder_without_write_permission_is_a_one_line_error_before_the_first_frame(
        synthetic_sequence, tmp_path, no_frame_may_run):
    locked = tmp_path / "locked"
    locked.mkdir(mode=0o555)
    result = run("run", synthetic_sequence, "--out", locked)
    locked.chmod(0o755)
    assert result.exit_code == EXIT_USER_ERROR, result.output
    assert result.output.startswith(f"error: {locked / 'run.lock'}: cannot write (")


def test_a_finished_run_leaves_no_partial_trajectory(synthetic_sequence, tmp_path):
    out = tmp_path / "run"
    result = run("run", synthetic_sequence, "--out", out, "--max-frames", 3)
    assert result.exit_code == 0, result.output
    assert (out / "trajectory.tum.txt").is_file() and not (out / "trajectory.partial.tum.txt").exists()


def run_until_poses(tmp_path, n_poses: int) -> tuple[subprocess.Popen, Path, Path]:
    """``pld-slam run`` on a 30-frame street in a child process, returned once it has tracked
    ``n_poses`` frames: the child (stderr piped), its sequence and its output folder."""
    sequence = tmp_path / "seq"
    write_sequence(sequence, "static", 30, size=(320, 240))
    out = tmp_path / "run"
    child = subprocess.Popen([sys.executable, "-m", "pld_slam_cli", "run", str(sequence), "--out", str(out)],
                             stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 300.0
    while pose_rows(out / "trajectory.partial.tum.txt") < n_poses and child.poll() is None:
        if time.monotonic() > deadline:
            child.kill()
        time.sleep(0.05)
    return child, sequence, out


def test_a_run_killed_hard_keeps_the_poses_tracked_so_far(tmp_path):
    child, sequence, out = run_until_poses(tmp_path, 4)
    partial = out / "trajectory.partial.tum.txt"
    try:
        assert child.poll() is None, "the run ended before it could be killed"
        child.send_signal(signal.SIGKILL)
    finally:
        child.kill()
        child.communicate()
    assert not (out / "trajectory.tum.txt").exists()  # killed before the end: only the partial file
    estimate = read_tum(partial)  # every row a valid TUM row (a half-written last row would fail here)
    truth = open_sequence(sequence).groundtruth
    assert len(estimate) >= 4 and np.array_equal(estimate.timestamps, truth.timestamps[: len(estimate)])
    assert np.allclose(estimate.poses[0], np.eye(4), atol=1e-9)
    np.testing.assert_allclose(estimate.positions, truth.positions[: len(estimate)], atol=0.05)


def test_sigterm_mid_run_writes_the_trajectory_so_far_as_ctrl_c_does(tmp_path):
    child, _, out = run_until_poses(tmp_path, 4)
    try:
        assert child.poll() is None, "the run ended before it could be stopped"
        child.send_signal(signal.SIGTERM)
        _, stderr = child.communicate(timeout=300)
    finally:
        child.kill()
    assert child.returncode == EXIT_TERMINATED, stderr
    summary = json.loads((out / "summary.json").read_text())
    assert stderr == (f"terminated after {summary['frames']} of 30 frames; wrote trajectory.kitti.txt, "
                      f"trajectory.tum.txt, summary.json, frames.csv, timing.png, loops.csv, trajectory.png, map.ply, "
                      f"keyframes.tum.txt in {out}/\n")
    assert 4 <= len(read_tum(out / "trajectory.tum.txt")) == summary["frames"] < 30
    assert summary["stop_reason"] == "terminated"
    assert not (out / "trajectory.partial.tum.txt").exists()


def test_sigterm_while_the_files_are_written_waits_for_them_and_lists_them(synthetic_sequence, tmp_path, monkeypatch):
    real_write_summary = run_files.write_summary

    def write_summary_terminated_midway(path, summary):
        os.kill(os.getpid(), signal.SIGTERM)  # the run is over; its files are being written
        real_write_summary(path, summary)

    monkeypatch.setattr(run_files, "write_summary", write_summary_terminated_midway)
    before = signal.signal(signal.SIGTERM, stop_on_sigterm)  # as the pld-slam command does
    try:
        result = CliRunner().invoke(cli, ["run", str(synthetic_sequence), "--out", str(tmp_path / "r")])
    finally:
        signal.signal(signal.SIGTERM, before)
    assert result.exit_code == EXIT_TERMINATED, result.output
    out = tmp_path / "r"
    written = "trajectory.kitti.txt, trajectory.tum.txt, summary.json, frames.csv, timing.png, loops.csv, " \
              "trajectory.png, map.ply, keyframes.tum.txt"
    assert result.stderr.strip().splitlines()[-1].endswith(f"; wrote {written} in {out}/")
    assert all((out / name).exists() for name in written.split(", "))
    assert json.loads((out / "summary.json").read_text())["completed"] is True


SIGTERM_WHEN_OVER = """
import atexit, os, signal, sys, time
import click
from pld_slam_cli.main import main

def sigterm_now():
    os.kill(os.getpid(), signal.SIGTERM)
    time.sleep(5)  # a Python handler runs here; the default action ends the process at once

moment = sys.argv.pop(1)
if moment == "atexit":  # registered first, so called last: during the interpreter's shutdown
    atexit.register(sigterm_now)
else:  # click's exit after the command returned
    click_exit = click.Context.exit
    click.Context.exit = lambda self, code=0: (sigterm_now(), click_exit(self, code))
main()
"""


@pytest.mark.parametrize("moment", ["atexit", "click exit"])
def test_sigterm_once_the_command_has_ended_ends_the_process_without_a_traceback(moment):
    # Issue 43: SIGTERM in an atexit callback printed a 14-line traceback and exited 0; in click's exit,
    # "Aborted!" and 1. The command's work is done: the signal ends the process, as late in shutdown.
    child = subprocess.run([sys.executable, "-c", SIGTERM_WHEN_OVER, moment, "config"],
                           capture_output=True, text=True, timeout=120)
    assert (child.returncode, child.stderr) == (-signal.SIGTERM, "")
    assert "\ntracking:\n" in child.stdout  # the command had printed the configuration


CELL_SIGTERM_AT_EXIT = """
import atexit, os, signal, sys, time
from pld_slam.report.cell_run import main

def sigterm_now():
    os.kill(os.getpid(), signal.SIGTERM)
    time.sleep(5)

atexit.register(sigterm_now)
sys.exit(main(sys.argv[1:]))
"""


def test_an_ablation_cells_run_ends_without_a_traceback_on_a_sigterm_after_its_files(synthetic_sequence, tmp_path):
    # The cell's child process had the same handler as pld-slam: a SIGTERM during its shutdown printed a
    # traceback ("Exception ignored in atexit callback") and exited 0. Its files are written: the signal ends it.
    config = tmp_path / "cell.yaml"
    config.write_text("")
    run_dir = tmp_path / "cell"
    child = subprocess.run([sys.executable, "-c", CELL_SIGTERM_AT_EXIT, str(synthetic_sequence), str(run_dir),
                            str(config)], capture_output=True, text=True, timeout=300)
    assert child.returncode == -signal.SIGTERM, child.stderr
    assert "Traceback" not in child.stderr and "Exception ignored" not in child.stderr
    assert (run_dir / "trajectory.tum.txt").exists()


def pose_rows(path) -> int:
    """Complete pose lines of a TUM file being written (0 while it does not exist)."""
    if not path.exists():
        return 0
    return sum(1 for line in path.read_text().splitlines(keepends=True) if line.endswith("\n") and line[0] != "#")


def test_run_table_names_skipped_files_and_says_what_the_accuracy_covers_with_a_quiet_stderr(
        synthetic_sequence, tmp_path):
    sequence = shutil.copytree(synthetic_sequence, tmp_path / "seq")
    truncated = sequence / "image_1" / "000002.png"
    truncated.write_bytes(truncated.read_bytes()[:-40])  # libpng: "libpng error: Read Error"
    for side in ("image_0", "image_1"):  # both images of frame 4 of another size than the calibration's
        cv2.imwrite(str(sequence / side / "000004.png"), np.zeros((60, 80), dtype=np.uint8))
    poses = (sequence / "poses.txt").read_text().splitlines()
    (sequence / "poses.txt").write_text("\n".join(poses[:5]) + "\n")  # ground truth of 5 of the 6 frames
    out = tmp_path / "run"
    child = subprocess.run([sys.executable, "-m", "pld_slam_cli", "run", str(sequence), "--out", str(out)],
                           capture_output=True, text=True, timeout=300)
    # 4 of 6 frames tracked is too few (`pld_slam.eval.tracked_frames`): the table, then one error line on stderr,
    # and nothing else there (no library noise: libpng, OpenCV WARN; no progress bar off a terminal)
    assert child.returncode == EXIT_USER_ERROR, child.stderr
    assert child.stderr.splitlines() == [
        f"error: {sequence}: tracked 4 of the 6 frames (67 %; a run must track 90 %): 2 lost, the first at frame 2; "
        f"2 of them unreadable (frame 2: {truncated}: cannot read image (not an image, or corrupt)); likely cause: "
        "image files missing, empty or corrupt"]
    table = child.stdout.splitlines()
    start = next(row for row, line in enumerate(table) if re.fullmatch(r"skipped frames +2", line))
    blank = " " * (len(table[start]) - 1)
    assert table[start + 1] == f"{blank}frame 2: {truncated}: cannot read image (not an image, or corrupt)"
    assert table[start + 2] == (f"{blank}frame 4: {sequence / 'image_0' / '000004.png'}: image is 80x60 "
                                "but the calibration is for 240x180")
    assert f"{blank}evaluated on 5 of 6 frames" in table
    assert any(re.fullmatch(r"real-time factor +[0-9.]+ \(sequence time at 10 Hz, frame_rate of synth.json "
                            r"/ wall time; above 1 is faster than real time\)", line) for line in table)
    summary = json.loads((out / "summary.json").read_text())
    assert [frame["index"] for frame in summary["skipped_frames"]] == [2, 4] and summary["n_matched"] == 5


def test_the_run_table_names_the_first_three_skipped_frames_and_counts_the_rest():
    skipped = [{"index": i, "reason": f"f{i}.png: cannot read image (empty file)"} for i in range(5)]
    assert skipped_frame_rows(skipped) == [
        ("skipped frames", "5"),
        ("", "frame 0: f0.png: cannot read image (empty file)"),
        ("", "frame 1: f1.png: cannot read image (empty file)"),
        ("", "frame 2: f2.png: cannot read image (empty file)"),
        ("", "and 2 more in summary.json (skipped_frames)"),
    ]
    assert skipped_frame_rows([]) == []


def test_eval_says_on_how_many_of_the_estimated_frames_it_evaluated(synthetic_sequence, tmp_path):
    truth = read_kitti(synthetic_sequence / "poses.txt")
    write_tum(tmp_path / "gt.tum.txt", truth.head(4))
    write_tum(tmp_path / "est.tum.txt", truth)
    result = run("eval", tmp_path / "gt.tum.txt", tmp_path / "est.tum.txt")
    assert result.exit_code == 0, result.output
    assert f"{'':<26}evaluated on 4 of 6 frames" in result.stdout.splitlines()
    whole = run("eval", tmp_path / "est.tum.txt", tmp_path / "est.tum.txt")
    assert "evaluated on" not in whole.stdout


def test_eval_warns_that_euroc_body_ground_truth_is_not_the_camera(tmp_path):
    mav0 = tmp_path / "MH_01" / "mav0" / "state_groundtruth_estimate0"
    mav0.mkdir(parents=True)
    gt = mav0 / "data.csv"
    rows = [f"{1403636580838555648 + i * 50_000_000},{0.1 * i},0,0,1,0,0,0,0,0,0,0,0,0,0,0,0" for i in range(5)]
    gt.write_text("#timestamp, p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], q_RS_y [], "
                  "q_RS_z [], v_RS_R_x [m s^-1]\n" + "\n".join(rows) + "\n")
    estimate = tmp_path / "est.euroc.csv"
    write_euroc(estimate, read_trajectory(gt, "euroc"))
    result = run("eval", gt, estimate)
    assert result.exit_code == 0, result.output
    assert result.stderr == (f"warning: {gt} is EuRoC's ground truth of the body (IMU) frame, not of the camera; "
                             "pass the sequence folder as GT to compare in the rectified left camera\n")
    assert run("eval", estimate, estimate).stderr == ""


def test_ctrl_c_mid_run_names_the_files_written_and_where(synthetic_sequence, tmp_path, monkeypatch):
    original = System.process_frame

    def process_frame(self, index):
        if index == 3:
            raise KeyboardInterrupt
        return original(self, index)

    monkeypatch.setattr(System, "process_frame", process_frame)
    out = tmp_path / "run"
    result = run("run", synthetic_sequence, "--out", out)
    assert result.exit_code == EXIT_INTERRUPTED
    assert result.stderr == (f"interrupted after 3 of 6 frames; wrote trajectory.kitti.txt, trajectory.tum.txt, "
                             f"summary.json, frames.csv, timing.png, loops.csv, trajectory.png, map.ply, "
                             f"keyframes.tum.txt in {out}/\n")
    assert len(read_kitti(out / "trajectory.kitti.txt")) == 3


def wait_until_importing_numpy(child: subprocess.Popen, timeout_s: float = 60.0) -> None:
    """Return once ``child`` has loaded numpy's core library (read from ``/proc/PID/maps``).

    A fixed sleep was flaky: on a busy machine in a fresh environment, the interpreter's own
    start-up (site's ``.pth`` files, compiling bytecode) could outlast it, and a Ctrl-C there
    is Python's traceback, before any code of ours runs.
    """
    maps = f"/proc/{child.pid}/maps"
    if not os.path.exists(maps):
        pytest.skip("needs /proc to see what the child process has loaded")
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            with open(maps) as lines:
                if "_multiarray_umath" in lines.read():
                    return
        except (FileNotFoundError, ProcessLookupError):
            break
        time.sleep(0.01)
    raise AssertionError(f"the child process never loaded numpy (exit code {child.poll()})")


def signal_dispositions(pid: int) -> str:
    """The blocked, ignored and caught signal masks of process ``pid`` (``/proc/PID/status``)."""
    try:
        with open(f"/proc/{pid}/status") as status:
            return " ".join(line.strip() for line in status if line.startswith(("SigBlk", "SigIgn", "SigCgt")))
    except OSError as error:
        return f"(no status: {error})"


def test_ctrl_c_during_start_up_is_one_line_and_no_traceback(synthetic_sequence, tmp_path):
    # The child gets SIGINT's default disposition, as a command typed at a terminal has: a
    # test run started in the background (`.ci/run &`, `nohup`) ignores SIGINT, the child
    # would inherit that, and the run went on to the end and exited 0 (twice on 2026-11-26).
    child = subprocess.Popen([sys.executable, "-m", "pld_slam_cli", "run", str(synthetic_sequence),
                              "--out", str(tmp_path / "run")], stderr=subprocess.PIPE, stdout=subprocess.DEVNULL,
                             text=True, preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    wait_until_importing_numpy(child)  # the command's imports (numpy first) take ~3 s, inside the error policy
    dispositions = signal_dispositions(child.pid)
    child.send_signal(signal.SIGINT)
    _, stderr = child.communicate(timeout=300)
    # The command exits with 130; in 1 to 3 of 10 runs on a busy machine (before and after
    # the changes of 2026-11-25) the interpreter instead ended itself by SIGINT after the
    # command had handled it (returncode -2), which a shell reports as 130 too.
    assert child.returncode in (EXIT_INTERRUPTED, -signal.SIGINT), f"{stderr!r}; {dispositions}"
    assert "Traceback" not in stderr and stderr.startswith("interrupted") and stderr.count("\n") == 1


def test_run_writes_the_euroc_format_when_asked_and_rejects_unknown_formats(synthetic_sequence, tmp_path):
    out = tmp_path / "run"
    result = run("run", synthetic_sequence, "--out", out, "--max-frames", 3, "--formats", "kitti,tum,euroc")
    assert result.exit_code == 0, result.output
    euroc = read_trajectory(out / "trajectory.euroc.csv", "euroc")
    np.testing.assert_allclose(euroc.poses, read_tum(out / "trajectory.tum.txt").poses, atol=1e-6)
    result = run("run", synthetic_sequence, "--out", tmp_path / "bad", "--formats", "kitti,ply")
    assert result.exit_code == EXIT_USER_ERROR and "--formats" in result.output
    assert not (tmp_path / "bad").exists()


def test_a_run_deletes_the_files_of_an_earlier_run_in_its_folder_but_no_other_file(synthetic_sequence, tmp_path):
    out = tmp_path / "run"
    first = run("run", synthetic_sequence, "--out", out, "--max-frames", 3, "--formats", "kitti,tum,euroc")
    assert first.exit_code == 0, first.output
    assert (out / "trajectory.png").exists() and (out / "trajectory.euroc.csv").exists()
    (out / "notes.txt").write_text("mine")
    result = run("run", synthetic_sequence, "--out", out, "--max-frames", 1)
    assert result.exit_code == 0, result.output
    assert sorted(path.name for path in out.iterdir()) == [
        "frames.csv", "keyframes.tum.txt", "loops.csv", "map.ply", "notes.txt", "summary.json", "trajectory.kitti.txt",
        "trajectory.tum.txt"]


def test_demo_writes_under_runs_which_git_ignores_and_says_where(tmp_path, monkeypatch):
    assert DEMO_FOLDER.parts[0] == "runs"
    assert "/runs/" in (REPO_ROOT / ".gitignore").read_text().splitlines()
    (out_option,) = [param for param in demo_command.params if param.name == "out"]
    assert out_option.default == DEMO_FOLDER
    monkeypatch.chdir(tmp_path)
    result = run("demo", "--frames", 2)
    assert result.exit_code == 0, result.output
    assert result.output.startswith(f"writing the sequence into {DEMO_FOLDER / 'sequence'}/ and the run into "
                                    f"{DEMO_FOLDER / 'run'}/\n")
    assert (tmp_path / DEMO_FOLDER / "run" / "summary.json").exists()
    assert sorted(path.name for path in tmp_path.iterdir()) == ["runs"]


def test_synth_into_a_folder_under_a_file_is_a_one_line_error(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    result = CliRunner().invoke(cli, ["synth", str(blocker / "seq"), "--frames", "2"])
    assert result.exit_code == 2
    assert result.output.strip().splitlines()[-1].startswith(f"error: {blocker}")


class FillingDisk:
    """A file on a disk that fills after ``room`` bytes: the write that crosses it keeps what fits and raises
    ENOSPC, as ``write(2)`` on a full disk does; from then on flushing or closing raises ENOSPC too (what a
    buffered file does with the bytes it could not write), once the file is closed."""

    def __init__(self, file, room: int) -> None:
        self.file, self.room = file, room

    def write(self, data):
        kept = data[: max(self.room, 0)]
        self.file.write(kept)
        self.room -= len(data)
        if self.room < 0:
            raise self.full()
        return len(data)

    def flush(self):
        self.file.flush()
        if self.room < 0:
            raise self.full()

    def close(self):
        self.file.close()
        if self.room < 0:
            raise self.full()

    @staticmethod
    def full() -> OSError:
        return OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    def __getattr__(self, name):
        return getattr(self.file, name)


@pytest.fixture
def partial_disk_fills(monkeypatch):
    """The partial trajectory's disk fills half way through its third pose row."""
    original = Path.open

    def open_on_a_filling_disk(path, mode="r", *args, **kwargs):
        file = original(path, mode, *args, **kwargs)
        if path.name != "trajectory.partial.tum.txt" or "r" in mode:
            return file
        return FillingDisk(file, room=len(TUM_HEADER) + 1 + 2 * 96 + 50)  # the first rows: 95 characters, \n

    monkeypatch.setattr(Path, "open", open_on_a_filling_disk)


def test_a_disk_that_fills_mid_run_is_a_one_line_error_naming_the_partial_trajectory(
        synthetic_sequence, tmp_path, partial_disk_fills):
    out = tmp_path / "run"
    result = run("run", synthetic_sequence, "--out", out)
    assert result.exit_code == EXIT_USER_ERROR, result.output
    assert result.output == f"error: {out / 'trajectory.partial.tum.txt'}: cannot write (No space left on device)\n"


def test_a_partial_trajectory_on_a_full_disk_keeps_its_whole_rows_and_closes_quietly(tmp_path, partial_disk_fills):
    partial = PartialTrajectory(tmp_path / "trajectory.partial.tum.txt")
    partial.start()
    partial.append(0.0, np.eye(4))
    partial.append(0.1, make_pose(np.eye(3), [1.0, 2.0, 3.0]))
    with pytest.raises(OutputError, match="No space left on device"):
        partial.append(0.2, make_pose(np.eye(3), [123.456, 2.0, 3.0]))
    partial.close()  # the error above is the one the user gets
    assert (tmp_path / "trajectory.partial.tum.txt").read_text().endswith("\n")
    assert len(read_tum(tmp_path / "trajectory.partial.tum.txt")) == 2


def test_a_second_run_into_a_folder_in_use_is_refused_naming_the_folder_and_the_pid(
        synthetic_sequence, tmp_path, no_frame_may_run):
    out = tmp_path / "run"
    out.mkdir()
    (out / "run.lock").write_text(f"{os.getpid()}\n")  # a live process: this one
    result = run("run", synthetic_sequence, "--out", out)
    assert result.exit_code == EXIT_USER_ERROR, result.output
    assert result.output == (f"error: {out}: in use by another run (pid {os.getpid()}); wait for it to end, or "
                             f"delete {out / 'run.lock'} if no run is writing there\n")
    assert (out / "run.lock").read_text() == f"{os.getpid()}\n"


def a_dead_pid() -> int:
    """The process id of a process that has ended."""
    child = subprocess.Popen([sys.executable, "-c", "pass"])
    child.wait()
    return child.pid


def test_a_run_holds_its_folder_while_it_goes_and_takes_over_the_lock_of_a_dead_run(
        synthetic_sequence, tmp_path, monkeypatch):
    out = tmp_path / "run"
    out.mkdir()
    dead = a_dead_pid()
    (out / "run.lock").write_text(f"{dead}\n")
    held = []
    original = System.process_frame

    def process_frame(self, index):
        held.append((out / "run.lock").read_text())
        return original(self, index)

    monkeypatch.setattr(System, "process_frame", process_frame)
    result = run("run", synthetic_sequence, "--out", out, "--max-frames", 2)
    assert result.exit_code == 0, result.output
    assert result.stderr == f"warning: {out / 'run.lock'}: took over the lock of a run that has ended (pid {dead})\n"
    assert held == [f"{os.getpid()}\n"] * 2 and not (out / "run.lock").exists()


def test_a_run_stopped_by_ctrl_c_or_an_error_releases_its_folder(synthetic_sequence, tmp_path, monkeypatch):
    def process_frame(self, index):
        raise KeyboardInterrupt if index == 1 else OSError(errno.EIO, "Input/output error")

    monkeypatch.setattr(System, "process_frame", process_frame)
    assert run("run", synthetic_sequence, "--out", tmp_path / "error").exit_code == 1
    monkeypatch.setattr(System, "process_frame", lambda self, index: process_frame(self, 1))
    assert run("run", synthetic_sequence, "--out", tmp_path / "ctrl_c").exit_code == EXIT_INTERRUPTED
    assert sorted(tmp_path.glob("*/run.lock")) == [] and (tmp_path / "ctrl_c" / "summary.json").exists()


def test_a_rerun_keeps_the_partial_trajectory_of_a_run_that_was_killed_and_says_so(synthetic_sequence, tmp_path):
    out = tmp_path / "run"
    out.mkdir()
    killed_runs = ["# timestamp tx ty tz qx qy qz qw\n0.0 0 0 0 0 0 0 1\n", "# timestamp tx ty tz qx qy qz qw\n"]
    for n, poses in enumerate(killed_runs, start=1):
        (out / "trajectory.partial.tum.txt").write_text(poses)
        result = run("run", synthetic_sequence, "--out", out, "--max-frames", 2)
        assert result.exit_code == 0, result.output
        kept = out / f"trajectory.partial.{n}.tum.txt"
        assert result.stderr == (f"warning: kept the partial trajectory of an earlier run that did not finish "
                                 f"as {kept}\n")
    assert [(out / f"trajectory.partial.{n}.tum.txt").read_text() for n in (1, 2)] == killed_runs
    assert not (out / "trajectory.partial.tum.txt").exists()


@pytest.mark.parametrize("bad_image", ["broken symlink", "empty file", "JPEG of another size"])
def test_an_unusable_frame_0_is_skipped_as_any_frame_is_and_the_world_is_the_first_usable_frame(
        synthetic_sequence, tmp_path, bad_image):
    sequence = shutil.copytree(synthetic_sequence, tmp_path / "seq")
    first = sequence / "image_0" / "000000.png"
    first.unlink()
    if bad_image == "broken symlink":
        first.symlink_to(tmp_path / "gone.png")
    elif bad_image == "empty file":
        first.write_bytes(b"")
    else:
        first.write_bytes(cv2.imencode(".jpg", np.full((60, 80), 128, dtype=np.uint8))[1].tobytes())
    out = tmp_path / "run"
    result = run("run", sequence, "--out", out)
    assert result.exit_code == 0, result.output
    summary = json.loads((out / "summary.json").read_text())
    assert [frame["index"] for frame in summary["skipped_frames"]] == [0]
    assert str(first) in summary["skipped_frames"][0]["reason"] and summary["world_frame"] == 1
    assert summary["frames"] == 6 and len(summary["tracking_failures"]) < 6


def test_a_sequence_without_one_readable_left_image_is_a_one_line_error_naming_the_first(
        synthetic_sequence, tmp_path):
    sequence = shutil.copytree(synthetic_sequence, tmp_path / "seq")
    for image in (sequence / "image_0").iterdir():
        image.write_bytes(b"")
    result = run("run", sequence, "--out", tmp_path / "run")
    assert result.exit_code == EXIT_USER_ERROR, result.output
    assert result.output == (f"error: {sequence / 'image_0'}: no image whose size can be read, the first: "
                             f"{sequence / 'image_0' / '000000.png'}: not a PNG image (cannot read the image size)\n")


WORK_BEFORE_OUTPUT_CHECK = {
    "eval --plot": "pld_slam_cli.evaluate.load_pair",
    "eval --save-results": "pld_slam_cli.evaluate.load_pair",
    "places": "pld_slam_cli.places.read_images",
    "vocabulary build": "pld_slam_cli.vocabulary.training_descriptors",
    "ablate": "pld_slam_cli.ablate.prepare_ablation",
    "regress": "pld_slam_cli.regress.select_cells",
}
"""Where each command's work starts: it must not be reached when the output path cannot be written."""


@pytest.mark.parametrize("command", WORK_BEFORE_OUTPUT_CHECK)
def test_every_command_checks_its_output_path_before_any_work(synthetic_sequence, tmp_path, monkeypatch, command):
    def refuse(*args, **kwargs):
        raise AssertionError(f"{command} started its work before checking its output path")

    monkeypatch.setattr(WORK_BEFORE_OUTPUT_CHECK[command], refuse)
    a_file = tmp_path / "a_file"
    a_file.write_text("not a folder\n")
    blocked = a_file / "out"
    baseline = tmp_path / "baseline.json"
    baseline.write_text(json.dumps({"cells": [{"name": "a", "sequence": {"path": str(synthetic_sequence)}}]}))
    poses = synthetic_sequence / "poses.txt"
    args = {
        "eval --plot": ("eval", poses, poses, "--plot", blocked),
        "eval --save-results": ("eval", poses, poses, "--save-results", blocked / "ate.zip"),
        "places": ("places", synthetic_sequence / "image_0", "--out", blocked),
        "vocabulary build": ("vocabulary", "build", synthetic_sequence, "--out", blocked / "vocabulary.npz"),
        "ablate": ("ablate", synthetic_sequence, "--out", blocked),
        "regress": ("regress", baseline, "--out", blocked),
    }[command]
    result = run(*args)
    assert result.exit_code == EXIT_USER_ERROR, result.output
    assert result.output.startswith(f"error: {blocked}: cannot write (") and result.output.count("\n") == 1


def test_run_table_labels_of_any_length_keep_two_spaces_before_their_values(
        synthetic_sequence, tmp_path, monkeypatch):
    result = run("run", synthetic_sequence, "--out", tmp_path / "run", "--max-frames", 2, "--json")
    summary = json.loads(result.output)
    stage = "a_stage_whose_name_is_long"  # its row's label: 43 characters
    monkeypatch.setattr("pld_slam_cli.run.STAGES", (*STAGES, stage))
    summary["timing_ms"][stage] = {"median": 1.0, "mean": 2.0}
    table = format_run_table(summary).splitlines()
    assert f"{stage} ms/frame (median)  1.0 (mean 2.0)" in table
    assert table[0] == "sequence" + " " * (len(stage) + len(" ms/frame (median)") + 2 - len("sequence")) + \
        summary["sequence"]
