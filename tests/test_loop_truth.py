"""Loop closing scored against ground truth: same place, precision, recall of revisits."""

import numpy as np
import pytest

from pld_slam.eval.loop_truth import score_loops, true_poses_at
from pld_slam.geometry.places import same_place
from pld_slam.geometry.se3 import make_pose, so3_exp
from pld_slam.trajectory import Trajectory


def pose(z: float, heading_deg: float, x: float = 0.0) -> np.ndarray:
    """``T_w_c`` at (x, 0, z) looking along the ground at ``heading_deg`` from +z."""
    return make_pose(so3_exp([0.0, np.radians(heading_deg), 0.0]), [x, 0.0, z])


def out_back_and_out_again() -> Trajectory:
    """Frames 0-29 drive out along z (2 m per frame), 30-59 come back facing the other way,
    60-69 drive out again over frames 0-9's places."""
    poses = ([pose(2.0 * i, 0.0) for i in range(30)] + [pose(2.0 * (59 - i), 180.0) for i in range(30, 60)]
             + [pose(2.0 * (i - 60), 0.0) for i in range(60, 70)])
    return Trajectory(0.1 * np.arange(70), np.array(poses))


def test_same_place_needs_both_position_and_heading():
    assert same_place(pose(0.0, 0.0), pose(2.9, 29.0))
    assert not same_place(pose(0.0, 0.0), pose(0.0, 0.0, x=3.1))
    assert not same_place(pose(0.0, 0.0), pose(0.0, 31.0))
    assert not same_place(pose(0.0, 0.0), np.full((4, 4), np.nan))


def test_precision_and_recall_of_a_drive_that_returns():
    truth = out_back_and_out_again()
    ids = np.arange(70)
    scores = score_loops(truth, ids, truth.timestamps, candidate_pairs=[(62, 2), (65, 40), (66, 6)],
                         loop_pairs=[(62, 2), (65, 40)], exclude_recent=5)
    assert (scores.candidates, scores.true_candidates) == (3, 2)
    assert (scores.loops, scores.true_loops, scores.precision) == (2, 1, 0.5)
    assert (scores.revisits, scores.found_revisits, scores.recall) == (1, 1, 1.0)  # frames 60-69: one revisit
    assert scores.candidate_precision == pytest.approx(2 / 3)


def test_a_run_without_loops_has_no_precision_and_no_recall():
    truth = out_back_and_out_again()
    scores = score_loops(truth, np.arange(70), truth.timestamps, np.zeros((0, 2)), np.zeros((0, 2)), 5)
    assert scores.precision is None and scores.recall == 0.0 and scores.revisits == 1
    outbound = score_loops(truth, np.arange(30), truth.timestamps[:30], np.zeros((0, 2)), np.zeros((0, 2)), 5)
    assert outbound.revisits == 0 and outbound.recall is None


def test_keyframes_without_ground_truth_take_no_part():
    truth = out_back_and_out_again()
    poses = true_poses_at(truth, np.array([0.1, 0.104, 0.15, 100.0]))
    np.testing.assert_array_equal(poses[0], truth.poses[1])
    np.testing.assert_array_equal(poses[1], truth.poses[1])
    assert np.isnan(poses[2]).all() and np.isnan(poses[3]).all()
