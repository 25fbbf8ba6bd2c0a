"""Trajectory files: round trips, malformed input, format detection, and evo reading ours."""

import os
import re
import subprocess

import numpy as np
import pytest
from conftest import require
from evo.tools import file_interface
from scipy.spatial.transform import Rotation

from pld_slam.errors import TrajectoryError
from pld_slam.eval.metrics import evaluate
from pld_slam.geometry.se3 import make_pose
from pld_slam.io.trajectory import (
    FORMATS,
    detect_format,
    read_euroc,
    read_kitti,
    read_trajectory,
    read_tum,
    write_euroc,
    write_kitti,
    write_trajectory,
    write_tum,
)
from pld_slam.trajectory import Trajectory

EUROC_T0_NS = 1403715273262142976
IDENTITY_ROW = "1 0 0 0 0 1 0 0 0 0 1 0\n"


def random_trajectory(n: int = 50, seed: int = 0, t0: float = 0.0) -> Trajectory:
    """``n`` random poses at irregular increasing times from ``t0`` [s]."""
    rng = np.random.default_rng(seed)
    rotations = Rotation.random(n, random_state=seed).as_matrix()
    positions = rng.uniform(-100.0, 100.0, (n, 3))
    timestamps = t0 + np.cumsum(rng.uniform(0.01, 0.2, n))
    poses = np.array([make_pose(R, t) for R, t in zip(rotations, positions)])
    return Trajectory(timestamps, poses)


def write_text(tmp_path, name: str, text: str):
    path = tmp_path / name
    path.write_text(text)
    return path


# --- round trips ---------------------------------------------------------------------


def test_kitti_round_trip_is_exact_to_ten_significant_digits(tmp_path):
    traj = random_trajectory()
    write_kitti(tmp_path / "poses.txt", traj)
    back = read_kitti(tmp_path / "poses.txt")
    np.testing.assert_allclose(back.poses, traj.poses, rtol=5e-10, atol=0.0)
    np.testing.assert_array_equal(back.timestamps, np.arange(len(traj)))


def test_kitti_reads_given_timestamps(tmp_path):
    traj = random_trajectory(n=5)
    write_kitti(tmp_path / "poses.txt", traj)
    back = read_trajectory(tmp_path / "poses.txt", timestamps=traj.timestamps)
    np.testing.assert_array_equal(back.timestamps, traj.timestamps)


def test_tum_round_trip_is_exact_to_nine_decimals(tmp_path):
    traj = random_trajectory(t0=1_400_000_000.0)
    write_tum(tmp_path / "traj.txt", traj)
    back = read_tum(tmp_path / "traj.txt")
    np.testing.assert_array_equal(back.timestamps, traj.timestamps)  # 1e-9 s < float64 ulp here
    np.testing.assert_allclose(back.positions, traj.positions, rtol=0.0, atol=5e-10)
    np.testing.assert_allclose(back.poses[:, :3, :3], traj.poses[:, :3, :3], rtol=0.0, atol=5e-9)


def test_euroc_round_trip_keeps_nanoseconds_to_float64_resolution(tmp_path):
    traj = random_trajectory(t0=EUROC_T0_NS / 1e9)
    write_euroc(tmp_path / "data.csv", traj)
    back = read_euroc(tmp_path / "data.csv")
    np.testing.assert_array_equal(back.timestamps, traj.timestamps)
    np.testing.assert_allclose(back.positions, traj.positions, rtol=0.0, atol=5e-10)
    np.testing.assert_allclose(back.poses[:, :3, :3], traj.poses[:, :3, :3], rtol=0.0, atol=5e-9)


@pytest.mark.parametrize("fmt", FORMATS)
def test_writing_is_deterministic_and_a_fixed_point_of_reading(tmp_path, fmt):
    traj = random_trajectory(t0=EUROC_T0_NS / 1e9)
    write_trajectory(tmp_path / "a", traj, fmt)
    write_trajectory(tmp_path / "b", read_trajectory(tmp_path / "a", fmt), fmt)
    assert (tmp_path / "a").read_bytes() == (tmp_path / "b").read_bytes()


def test_tum_quaternion_slightly_off_unit_is_normalised(tmp_path):
    path = write_text(tmp_path, "t.txt", "1.0 1 2 3 0 0 0.7071078 0.7071078\n")  # norm 1+1e-6
    R = read_tum(path).poses[0, :3, :3]
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
    quarter_turn = Rotation.from_euler("z", 90, degrees=True).as_matrix()
    np.testing.assert_allclose(R, quarter_turn, atol=1e-12)


def test_written_quaternions_have_non_negative_w(tmp_path):
    write_tum(tmp_path / "t.txt", random_trajectory())
    assert np.all(np.loadtxt(tmp_path / "t.txt")[:, 7] >= 0.0)


# --- real files ----------------------------------------------------------------------


def test_euroc_ground_truth_reads_pose_columns(data_dir):
    path = require(data_dir / "euroc/V1_01_easy_static/mav0/state_groundtruth_estimate0/data.csv")
    traj = read_euroc(path)
    assert len(traj) == 40
    assert traj.timestamps[0] == pytest.approx(EUROC_T0_NS / 1e9, abs=1e-6)
    np.testing.assert_allclose(traj.positions[0], [0.878895, 2.1834, 0.948427])
    q_xyzw = [-0.824237, -0.106942, -0.551702, 0.069433]
    np.testing.assert_allclose(
        traj.poses[0, :3, :3], Rotation.from_quat(q_xyzw).as_matrix(), atol=1e-12
    )


def test_euroc_further_columns_are_ignored(tmp_path):
    header = "#timestamp,p_x,p_y,p_z,q_w,q_x,q_y,q_z,v_x,v_y,v_z,bw_x,bw_y,bw_z,ba_x,ba_y,ba_z\n"
    row = f"{EUROC_T0_NS},1,2,3,1,0,0,0,0.1,0.2,0.3,0,0,0,9,9,9\n"
    traj = read_euroc(write_text(tmp_path, "gt.csv", header + row))
    np.testing.assert_array_equal(traj.poses[0], make_pose(np.eye(3), [1.0, 2.0, 3.0]))


def test_kitti_ground_truth_reads_as_is(data_dir):
    path = require(data_dir / "kitti_odometry/poses_full/00.txt")
    traj = read_trajectory(path)
    first_row = np.array(path.read_text().split("\n")[1].split(), dtype=float)
    assert len(traj) == 4541
    np.testing.assert_array_equal(traj.poses[1, :3, :].reshape(-1), first_row)


# --- malformed files -----------------------------------------------------------------


@pytest.mark.parametrize(
    ("reader", "text", "message"),
    [
        (read_kitti, IDENTITY_ROW * 6 + "1 0 0 0 0 1 0 0 0\n", ":7: expected 12 numbers, got 9"),
        (read_kitti, "1 0 0 0 0 1 0 0 0 0 1 x\n", ":1: not a number: 'x'"),
        (read_kitti, "1 0 0 0 0 1 0 0 0 0 1 nan\n", ":1: not a finite number: 'nan'"),
        (read_kitti, "# c\n1 0 0 0 0 1 0 0 0 0 2 0\n", ":2: not a rotation matrix"),
        (read_kitti, "1 0 0 0 0 1 0 0 0 0 -1 0\n", ":1: not a rotation matrix"),
        (read_tum, "1 0 0 0 0 0 0 1\n\n2 0 0 0 0 0 0\n", ":3: expected 8 numbers, got 7"),
        (read_tum, "1 0 0 0 0 0 0 1\n1 0 0 0 0 0 0 1\n", ":2: timestamp 1.000000000 is not after"),
        (read_tum, "1 0 0 0 0 0 0 0\n", ":1: quaternion norm is 0, not 1"),
        (read_tum, "1 0 0 0 0 0 0 2\n", ":1: quaternion norm is 2, not 1"),
        (read_euroc, "#h\n5,0,0,0,1,0,0\n", ":2: expected at least 8 numbers, got 7"),
        (read_euroc, "#h\n5.5,0,0,0,1,0,0,0\n", ":2: timestamp must be integer nanoseconds"),
        (read_euroc, "#\n5,0,0,0,1,0,0,0\n4,0,0,0,1,0,0,0\n", ":3: timestamp 0.000000004 is not"),
        (read_tum, "# only a comment\n\n", ": no poses (empty file)"),
    ],
)
def test_malformed_file_raises_naming_file_and_line(tmp_path, reader, text, message):
    path = write_text(tmp_path, "poses.txt", text)
    with pytest.raises(TrajectoryError) as error:
        reader(path)
    assert str(error.value).startswith(f"{path}{message}")
    assert "\n" not in str(error.value)


def test_missing_file_raises(tmp_path):
    with pytest.raises(TrajectoryError, match=re.escape(f"{tmp_path / 'nope.txt'}: no such file")):
        read_trajectory(tmp_path / "nope.txt")


def test_kitti_timestamps_must_match_the_pose_count(tmp_path):
    write_kitti(tmp_path / "poses.txt", random_trajectory(n=3))
    with pytest.raises(TrajectoryError, match="3 poses but 2 timestamps"):
        read_kitti(tmp_path / "poses.txt", timestamps=np.array([0.0, 1.0]))


def test_timestamps_are_refused_for_formats_that_carry_their_own(tmp_path):
    write_tum(tmp_path / "t.txt", random_trajectory(n=3))
    with pytest.raises(TrajectoryError, match="only be given for a KITTI file"):
        read_trajectory(tmp_path / "t.txt", timestamps=np.arange(3.0))


def test_unknown_format_and_empty_trajectory_are_refused(tmp_path):
    with pytest.raises(TrajectoryError, match="unknown trajectory format 'g2o'"):
        write_trajectory(tmp_path / "t.txt", random_trajectory(n=3), "g2o")
    with pytest.raises(TrajectoryError, match="cannot write an empty trajectory"):
        write_tum(tmp_path / "t.txt", Trajectory(np.zeros(0), np.zeros((0, 4, 4))))


# --- format detection ----------------------------------------------------------------


@pytest.mark.parametrize("fmt", FORMATS)
def test_detect_format_of_written_files(tmp_path, fmt):
    write_trajectory(tmp_path / "traj", random_trajectory(n=3), fmt)
    assert detect_format(tmp_path / "traj") == fmt


def test_detect_format_refuses_other_column_counts(tmp_path):
    path = write_text(tmp_path, "odd.txt", "# header\n1 2 3 4 5\n")
    message = re.escape(f"{path}:2: cannot tell the trajectory format from 5 whitespace")
    with pytest.raises(TrajectoryError, match=message):
        detect_format(path)


def test_detect_format_reads_the_file_only_up_to_its_first_data_line(tmp_path):
    path = tmp_path / "traj.txt"
    path.write_bytes(b"\xef\xbb\xbf# header\n\n1.0 0 0 0 0 0 0 1\n" + b"\xff" * 10 + b"\n")
    assert detect_format(path) == "tum"  # the bytes after the first data line are not read
    with pytest.raises(TrajectoryError, match="cannot read the file"):
        read_trajectory(path)  # reading the poses reads them


def test_detect_format_numbers_lines_as_the_readers_do(tmp_path):
    path = write_text(tmp_path, "odd.txt", "# a\x0c# b\r\n\r\n1 2 3\n")  # a form feed ends a line too
    with pytest.raises(TrajectoryError, match=re.escape(f"{path}:4: cannot tell the trajectory format")):
        detect_format(path)
    with pytest.raises(TrajectoryError, match=re.escape(f"{path}:4: expected 8 numbers, got 3")):
        read_trajectory(path, "tum")


@pytest.mark.parametrize("text, message", [("", "no poses (empty file)"), ("# only\n\n", "no poses (empty file)")])
def test_detect_format_of_a_file_without_poses_says_so(tmp_path, text, message):
    path = write_text(tmp_path, "empty.txt", text)
    with pytest.raises(TrajectoryError, match=re.escape(f"{path}: {message}")):
        detect_format(path)
    with pytest.raises(TrajectoryError, match="no such file"):
        detect_format(tmp_path / "missing.txt")

# --- evo reads our files ---------------------------------------------------------------


@pytest.mark.parametrize(
    ("fmt", "evo_reader"),
    [
        ("kitti", file_interface.read_kitti_poses_file),
        ("tum", file_interface.read_tum_trajectory_file),
        ("euroc", file_interface.read_euroc_csv_trajectory),
    ],
)
def test_evo_reads_our_files_to_the_same_poses(tmp_path, fmt, evo_reader):
    traj = random_trajectory(t0=EUROC_T0_NS / 1e9)
    write_trajectory(tmp_path / "traj", traj, fmt)
    evo_traj = evo_reader(str(tmp_path / "traj"))
    np.testing.assert_allclose(np.array(evo_traj.poses_se3), traj.poses, rtol=0.0, atol=1e-8)
    if fmt != "kitti":
        np.testing.assert_allclose(evo_traj.timestamps, traj.timestamps, rtol=0.0, atol=1e-6)


def evo_ape_rmse(home, fmt: str, groundtruth_file, estimate_file) -> float:
    """RMSE printed by ``evo_ape <fmt> GT EST -a`` (SE(3) alignment); asserts exit code 0."""
    env = {**os.environ, "HOME": str(home), "MPLBACKEND": "Agg"}  # evo keeps settings in ~/.evo
    run = subprocess.run(
        ["evo_ape", fmt, str(groundtruth_file), str(estimate_file), "-a"],
        capture_output=True,
        text=True,
        env=env,
        timeout=60,
    )
    assert run.returncode == 0, run.stderr
    return float(re.search(r"^\s*rmse\s+(\S+)$", run.stdout, re.MULTILINE).group(1))


def test_evo_cli_loads_our_kitti_00_files_and_agrees_on_ate(data_dir, tmp_path):
    times = np.loadtxt(require(data_dir / "kitti_odometry/poses_full/00_times.txt"))
    groundtruth = read_kitti(require(data_dir / "kitti_odometry/poses_full/00.txt"), times)
    estimate = read_kitti(require(data_dir / "reference_trajectories/KITTI_00_ORB.txt"), times)
    ours = evaluate(groundtruth, estimate).ate_rmse_m
    for fmt in ("kitti", "tum"):
        write_trajectory(tmp_path / f"gt.{fmt}", groundtruth, fmt)
        write_trajectory(tmp_path / f"est.{fmt}", estimate, fmt)
        evo_rmse = evo_ape_rmse(tmp_path, fmt, tmp_path / f"gt.{fmt}", tmp_path / f"est.{fmt}")
        assert evo_rmse == pytest.approx(ours, abs=1e-6), fmt  # evo prints 6 decimals
    assert round(ours, 2) == 1.30


def test_a_comma_separated_tum_file_is_read_as_euroc_and_the_error_says_so(tmp_path):
    path = tmp_path / "tum_with_commas.txt"
    path.write_text("1.0,0,0,0,0,0,0,1\n2.0,1,0,0,0,0,0,1\n")
    with pytest.raises(TrajectoryError, match=re.escape(
            f"{path}:1: timestamp must be integer nanoseconds: '1.0' (read as EuRoC, for its comma-separated "
            "columns; a TUM file separates them by spaces)")):
        read_trajectory(path)
    with pytest.raises(TrajectoryError) as asked_for_euroc:
        read_trajectory(path, "euroc")
    assert "read as EuRoC" not in str(asked_for_euroc.value)  # the user named the format
