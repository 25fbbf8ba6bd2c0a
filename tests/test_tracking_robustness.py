"""Tracking that does not depend on the constant-velocity prediction being right.

A synthetic street (``static``, 320 x 240) run with every second frame dropped (the camera
then moves twice as far per frame as the motion model learnt from nothing predicts), and
started mid-way (the first frame is already moving, so the second frame's prediction,
standing still, is wrong by a whole frame's motion). Every frame must be tracked, and the
trajectory must stay close to the ground truth: with the map on, a frame whose guided
search goes wrong is posed again without the prior (`pld_slam.tracking.relocalisation`).
"""

import numpy as np
import pytest

from pld_slam.config import load_config
from pld_slam.datasets import open_sequence
from pld_slam.eval import evaluate
from pld_slam.frontend import extract_stereo_features
from pld_slam.geometry.se3 import inverse
from pld_slam.synth import write_sequence
from pld_slam.system import System
from pld_slam.tracking import tracker as tracker_module
from pld_slam.tracking.tracker import TrackingStatus

N_FRAMES = 30


@pytest.fixture(scope="module")
def street(tmp_path_factory):
    folder = tmp_path_factory.mktemp("robustness") / "static"
    write_sequence(folder, "static", N_FRAMES, (320, 240), seed=3)
    return open_sequence(folder)


def run_ate(sequence) -> tuple[float, list[TrackingStatus]]:
    """ATE [m] of a run on ``sequence`` and the status of every frame."""
    result = System(sequence, load_config()).run()
    return evaluate(sequence.groundtruth, result.trajectory()).ate_rmse_m, [r.status for r in result.records]


@pytest.fixture(scope="module")
def intact_ate(street) -> float:
    ate, statuses = run_ate(street)
    assert TrackingStatus.LOST not in statuses
    return ate


@pytest.mark.parametrize("start, step", [(0, 2), (12, 1), (12, 2)])
def test_every_frame_is_tracked_with_frames_dropped_or_a_moving_start(street, intact_ate, start, step):
    ate, statuses = run_ate(street.subsequence(start, step))
    assert TrackingStatus.LOST not in statuses
    # measured: ATE 0.042, 0.051, 0.052 m against 0.061 m for the intact run
    assert ate < 1.5 * intact_ate


def test_the_sub_sequence_keeps_the_chosen_frames_and_rebases_the_ground_truth(street):
    part = street.subsequence(12, 2)
    assert len(part) == (N_FRAMES - 12 + 1) // 2
    assert list(part.timestamps) == list(street.timestamps[12::2])
    assert part.frames.left_paths == street.frames.left_paths[12::2]
    expected = inverse(street.groundtruth.poses[12]) @ street.groundtruth.poses[12:]  # every pose from then on
    np.testing.assert_allclose(part.groundtruth.poses, expected, atol=1e-12)
    np.testing.assert_allclose(part.groundtruth.poses[0], np.eye(4), atol=1e-12)
    assert part.name.endswith("_from12_every2")


def test_posing_without_the_prior_against_another_keyframe_leaves_the_tracker_on_its_own(street, monkeypatch):
    """Relocalisation against another keyframe's local map is only a proposal: the tracker keeps its
    reference keyframe and local map until `track` takes the pose (it may keep the guided one)."""
    config = load_config()
    system = System(street, config)
    try:
        for index in range(16):
            system.process_frame(index)
        tracker = system.tracker
        reference, local_map = tracker._reference_keyframe, tracker._local_map
        first = min(system.local_mapping.map.keyframes)
        assert reference.id != first
        real_pose_without_prior = tracker_module.pose_without_prior
        calls = []

        def fails_on_own_local_map(*args, **kwargs):
            calls.append(len(calls))
            return None if len(calls) == 1 else real_pose_without_prior(*args, **kwargs)

        monkeypatch.setattr(tracker_module, "pose_without_prior", fails_on_own_local_map)
        monkeypatch.setattr(tracker_module, "keyframes_by_similarity", lambda *args: [first])
        frame = street[16]
        features = extract_stereo_features(frame.left, frame.right, street.camera, config.points, config.lines,
                                           config.ggs)
        proposal = tracker._track_without_prior(features, np.zeros(len(features.keypoints), dtype=bool),
                                                np.zeros(len(features.lines), dtype=bool))
    finally:
        system.close()
    assert len(calls) == 2  # the own local map failed, the first keyframe's gave a pose
    assert tracker._reference_keyframe is reference and tracker._local_map is local_map
    assert proposal is not None and proposal[1].keyframes[0] == first
