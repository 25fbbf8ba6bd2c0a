"""`Tracker` against its reference frame, without a map, on a short synthetic street
(``static``, 15 frames, 320 x 240, seed 0). Tracking with a map (the local map, its
strategies, relocalisation) is tested in ``test_tracking_robustness.py`` and
``test_local_mapping.py``; runs here switch mapping off.

Accuracy: the bounds are about 2.5 times what the tracker achieved when these tests were
written, over 11.2 m of path: ATE 0.041 m with lines (largest position error 0.14 m),
0.074 m on points alone, 0.029 m with a new reference every frame. Failure: a frame whose
features are all gone is LOST at the motion model's pose, and tracking picks up again on
the following frames (largest position error 0.14 m over the run; 0.12 m when the frame
is skipped instead).
"""

import numpy as np
import pytest

from pld_slam.config import load_config
from pld_slam.datasets import open_sequence
from pld_slam.eval import evaluate
from pld_slam.frontend import StereoFeatures, StereoLines, StereoPoints, extract_stereo_features
from pld_slam.geometry.se3 import inverse, nearest_pose
from pld_slam.matching.frames import FrameMatches
from pld_slam.synth import write_sequence
from pld_slam.system import System
from pld_slam.tracking.dynamic import DynamicLabels
from pld_slam.tracking.reference import DynamicIndices, FeatureMatches, ReferenceFrame, can_be_reference
from pld_slam.tracking.tracker import Tracker, TrackingState, TrackingStatus

N_FRAMES = 15
FAILED = 7
"""The frame whose features are taken away in the failure tests."""


@pytest.fixture(scope="module")
def sequence(tmp_path_factory):
    folder = tmp_path_factory.mktemp("tracker") / "static"
    write_sequence(folder, "static", N_FRAMES, (320, 240), seed=0)
    return open_sequence(folder)


@pytest.fixture(scope="module")
def features(sequence):
    """The stereo features of every frame, default configuration."""
    config = load_config()
    return [extract_stereo_features(f.left, f.right, sequence.camera, config.points, config.lines) for f in sequence]


def run_system(sequence, *overrides: str):
    """A run without a map (the tracker's visual odometry), ``overrides`` laid on top."""
    return System(sequence, load_config(overrides=("mapping.enabled=false", *overrides))).run()


@pytest.fixture(scope="module")
def default_run(sequence):
    return run_system(sequence)


def statuses(records) -> list[TrackingStatus]:
    return [r.status for r in records]


def position_errors(sequence, poses: np.ndarray) -> np.ndarray:
    """Distance [m] of each estimated position from the ground truth (both worlds = first camera)."""
    return np.linalg.norm(poses[:, :3, 3] - sequence.groundtruth.poses[: len(poses), :3, 3], axis=1)


def no_features() -> StereoFeatures:
    """Empty stereo points and lines, built with the shapes the front end gives."""
    points = StereoPoints(
        uv=np.zeros((0, 2)),
        octave=np.zeros(0, dtype=np.int64),
        descriptors=np.zeros((0, 32), dtype=np.uint8),
        disparity=np.zeros(0),
        u_right=np.zeros(0),
        points_c=np.zeros((0, 3)),
    )
    return StereoFeatures(points=points, lines=StereoLines.empty())


def blank_pair_features(sequence) -> StereoFeatures:
    """What the front end finds in a uniform grey pair: nothing."""
    config = load_config()
    blank = np.full((sequence.camera.height, sequence.camera.width), 128, dtype=np.uint8)
    return extract_stereo_features(blank, blank, sequence.camera, config.points, config.lines)


def track_all(sequence, frames: list[StereoFeatures]):
    tracker = Tracker(sequence.camera, load_config())
    return [tracker.track(f) for f in frames]


# --- a normal run ---------------------------------------------------------------------


def test_the_first_frame_is_the_world_and_every_later_frame_is_tracked(default_run):
    records = default_run.records
    assert len(records) == N_FRAMES
    assert statuses(records) == [TrackingStatus.FIRST] + [TrackingStatus.TRACKED] * (N_FRAMES - 1)
    assert np.array_equal(records[0].T_w_c, np.eye(4))


def test_the_tracked_trajectory_stays_close_to_the_ground_truth(sequence, default_run):
    estimate = default_run.trajectory()
    result = evaluate(sequence.groundtruth, estimate)
    assert result.n_matched == N_FRAMES
    assert result.ate_rmse_m < 0.1
    assert result.rpe_rot_rmse_deg < 0.3
    assert position_errors(sequence, estimate.poses).max() < 0.35


def test_tracked_frames_rest_on_enough_point_and_line_inliers(default_run):
    min_inliers = load_config().tracking.min_inliers
    for record in default_run.records[1:]:
        counts = record.counts
        assert counts.point_inliers + counts.line_inliers >= min_inliers
        assert counts.line_inliers > 0
        assert counts.point_inliers <= counts.points_after_filter <= counts.point_matches <= record.n_points
        assert counts.line_inliers <= counts.lines_after_filter <= counts.line_matches <= record.n_lines


def test_with_lines_disabled_the_tracker_still_tracks_on_points_alone(sequence):
    result = run_system(sequence, "lines.enabled=false")
    assert statuses(result.records)[1:] == [TrackingStatus.TRACKED] * (N_FRAMES - 1)
    assert all(r.n_lines == 0 and r.counts.line_matches == 0 for r in result.records)
    assert evaluate(sequence.groundtruth, result.trajectory()).ate_rmse_m < 0.2


def test_a_new_reference_every_frame_also_tracks_and_changes_the_estimate(sequence, default_run):
    result = run_system(sequence, "tracking.reference_max_age=1")
    assert statuses(result.records)[1:] == [TrackingStatus.TRACKED] * (N_FRAMES - 1)
    assert evaluate(sequence.groundtruth, result.trajectory()).ate_rmse_m < 0.08
    # The second frame is tracked against the first either way; later ones see other references.
    assert np.array_equal(result.records[1].T_w_c, default_run.records[1].T_w_c)
    assert not np.array_equal(result.trajectory().poses, default_run.trajectory().poses)


# --- tracking failure -----------------------------------------------------------------


@pytest.mark.parametrize("empty", ["constructed", "blank_pair"])
def test_a_frame_without_features_is_lost_at_the_motion_model_pose(sequence, features, empty):
    nothing = no_features() if empty == "constructed" else blank_pair_features(sequence)
    assert len(nothing.points) == 0 and len(nothing.lines) == 0
    frames = features[:FAILED] + [nothing] + features[FAILED + 1 :]
    tracked = track_all(sequence, frames)
    lost, before = tracked[FAILED], tracked[FAILED - 1]
    assert before.status is TrackingStatus.TRACKED
    assert lost.status is TrackingStatus.LOST
    assert lost.counts.point_matches == 0 and lost.counts.line_matches == 0
    continued = nearest_pose(before.T_w_c @ inverse(before.T_c_p))  # the previous velocity, once more
    np.testing.assert_allclose(lost.T_w_c, continued, rtol=0, atol=1e-12)
    np.testing.assert_allclose(lost.T_c_p, before.T_c_p, rtol=0, atol=1e-12)


def test_tracking_recovers_after_a_frame_without_features(sequence, features, default_run):
    frames = features[:FAILED] + [no_features()] + features[FAILED + 1 :]
    tracked = track_all(sequence, frames)
    poses = np.array([t.T_w_c for t in tracked])
    # Frames before the failure are exactly those of the undisturbed run.
    assert np.array_equal(poses[:FAILED], default_run.trajectory().poses[:FAILED])
    # The featureless frame cannot be a reference (`can_be_reference`): frame FAILED + 1 is
    # matched against the reference before it, two frames' motion away, with the motion model
    # no longer trusted, so its status is left out; from FAILED + 2 on every frame must be
    # tracked again.
    assert [t.status for t in tracked[FAILED + 2 :]] == [TrackingStatus.TRACKED] * (N_FRAMES - FAILED - 2)
    assert position_errors(sequence, poses).max() < 0.4


def test_a_skipped_frame_keeps_the_reference_so_the_next_frame_is_tracked(sequence, features):
    tracker = Tracker(sequence.camera, load_config())
    before = [tracker.track(f) for f in features[:FAILED]]
    assert tracker.state is TrackingState.OK and tracker.state.motion_trusted  # the last frame was tracked normally
    skipped = tracker.skip()
    # the next frame is two frames' motion from the last tracked one: the model is no longer trusted
    assert tracker.state is TrackingState.LOST and not tracker.state.motion_trusted
    after = [tracker.track(f) for f in features[FAILED + 1 :]]
    assert skipped.status is TrackingStatus.LOST
    expected = nearest_pose(before[-1].T_w_c @ inverse(before[-1].T_c_p))
    np.testing.assert_allclose(skipped.T_w_c, expected, rtol=0, atol=1e-12)
    assert [t.status for t in after] == [TrackingStatus.TRACKED] * len(after)
    poses = np.array([t.T_w_c for t in before + [skipped] + after])
    assert position_errors(sequence, poses).max() < 0.4


def test_the_frame_after_a_featureless_frame_is_tracked(sequence, features):
    """A blank frame fails alone: it does not become the reference of the next frame."""
    frames = features[:FAILED] + [no_features()] + features[FAILED + 1 :]
    tracked = track_all(sequence, frames)
    assert tracked[FAILED].status is TrackingStatus.LOST
    assert tracked[FAILED + 1].status is TrackingStatus.TRACKED


# --- the reference frame --------------------------------------------------------------


def matches_of(points: list[int], lines: list[int]) -> FeatureMatches:
    """Reference features ``points`` / ``lines`` matched to the same indices of the current frame."""
    points, lines = np.array(points, dtype=np.int64), np.array(lines, dtype=np.int64)
    return FeatureMatches(FrameMatches(points, points), FrameMatches(lines, lines))


def test_a_new_reference_knows_its_dynamic_stereo_features_and_no_landmarks(features):
    frame = features[0]
    n_stereo = len(frame.points)
    assert len(frame.keypoints) > n_stereo  # some keypoints without a stereo match: not reference points
    reference = ReferenceFrame(frame, np.eye(4), DynamicIndices(np.array([2, n_stereo]), np.array([1])))
    assert np.flatnonzero(reference.seen_dynamic_points).tolist() == [2]
    assert np.flatnonzero(reference.seen_dynamic_lines).tolist() == [1]
    assert (reference.landmarks.points == -1).all() and len(reference.landmarks.points) == n_stereo
    assert reference.age == 0 and reference.first_inliers == 0


def test_the_reference_remembers_what_later_frames_found_dynamic(features):
    reference = ReferenceFrame(features[0], np.eye(4), DynamicIndices(np.zeros(0, int), np.zeros(0, int)))
    labels = DynamicLabels(np.zeros((3, 2)), np.array([False, True, True]), np.zeros((2, 4)), np.array([True, False]))
    reference.record(matches_of([4, 5, 6], [7, 8]), labels, inliers=50)
    assert np.flatnonzero(reference.seen_dynamic_points).tolist() == [5, 6]
    assert np.flatnonzero(reference.seen_dynamic_lines).tolist() == [7]
    assert reference.age == 1 and reference.first_inliers == 50


def test_the_reference_wears_out_with_age_and_with_lost_inliers(features):
    config = load_config(overrides=("tracking.reference_max_age=3", "tracking.reference_min_inlier_ratio=0.5"))
    nothing = DynamicLabels.none(np.zeros((0, 2)), np.zeros((0, 4)))
    reference = ReferenceFrame(features[0], np.eye(4), DynamicIndices(np.zeros(0, int), np.zeros(0, int)))
    worn = []
    for _ in range(3):
        reference.record(matches_of([], []), nothing, inliers=100)
        worn.append(reference.is_worn(100, config))
    assert worn == [False, False, True]
    young = ReferenceFrame(features[0], np.eye(4), DynamicIndices(np.zeros(0, int), np.zeros(0, int)))
    young.record(matches_of([], []), nothing, inliers=100)  # the first frame sets the inliers to keep
    young.record(matches_of([], []), nothing, inliers=10)
    assert not young.is_worn(50, config) and young.is_worn(49, config)


def test_a_frame_can_be_a_reference_with_twice_min_inliers_features(sequence, features):
    config = load_config()
    assert can_be_reference(features[0], config)
    assert not can_be_reference(no_features(), config)
    tracker = Tracker(sequence.camera, config)
    assert tracker.can_be_reference(features[0]) and not tracker.can_be_reference(no_features())


def test_the_tracker_renews_its_reference_every_max_age_frames(sequence, features):
    tracker = Tracker(sequence.camera, load_config(overrides=("tracking.reference_max_age=3",)))
    assert tracker.reference is None
    references = []
    for frame in features[:8]:
        tracker.track(frame)
        references.append(next(k for k, f in enumerate(features) if f is tracker.reference.features))
    assert references == [0, 0, 0, 3, 3, 3, 6, 6]
    assert tracker.reference.age == 1


# --- the state and the strategies -----------------------------------------------------


def test_the_state_steps_from_not_initialised_through_the_first_frame_to_ok_and_lost(sequence, features):
    tracker = Tracker(sequence.camera, load_config())
    states = [tracker.state]
    for frame in [*features[:3], no_features(), features[4]]:
        tracker.track(frame)
        states.append(tracker.state)
    assert states == [TrackingState.NOT_INITIALISED, TrackingState.INITIALISED, TrackingState.OK, TrackingState.OK,
                      TrackingState.LOST, TrackingState.OK]
    assert [s.motion_trusted for s in states] == [False, False, True, True, False, True]
    assert [s.status for s in states[1:]] == [TrackingStatus.FIRST, TrackingStatus.TRACKED, TrackingStatus.TRACKED,
                                              TrackingStatus.LOST, TrackingStatus.TRACKED]


def test_a_skip_before_the_first_frame_leaves_the_next_frame_the_first(sequence, features):
    tracker = Tracker(sequence.camera, load_config())
    assert tracker.skip().status is TrackingStatus.LOST
    assert tracker.state is TrackingState.NOT_INITIALISED
    assert tracker.track(features[0]).status is TrackingStatus.FIRST


def test_tracking_the_reference_changes_nothing_and_gives_the_pose_track_takes(sequence, features):
    tracker = Tracker(sequence.camera, load_config())
    for frame in features[:4]:
        tracker.track(frame)
    reference, age, T_w_p = tracker.reference, tracker.reference.age, tracker.motion_model.T_w_p
    guided = tracker.track_reference(features[4])
    assert tracker.reference is reference and reference.age == age and tracker.motion_model.T_w_p is T_w_p
    assert tracker.state is TrackingState.OK
    assert guided.tracked and not guided.widened
    assert guided.counts.point_inliers + guided.counts.line_inliers >= load_config().tracking.min_inliers
    again = tracker.track_reference(features[4])
    np.testing.assert_array_equal(again.T_w_c, guided.T_w_c)
    tracked = tracker.track(features[4])
    np.testing.assert_allclose(tracked.T_w_c, guided.T_w_c, rtol=0, atol=1e-9)
    assert tracked.counts == guided.counts
    assert reference.age == age + 1


def test_a_frame_without_features_is_not_tracked_by_the_reference(sequence, features):
    tracker = Tracker(sequence.camera, load_config())
    for frame in features[:3]:
        tracker.track(frame)
    guided = tracker.track_reference(no_features())
    assert not guided.tracked and guided.T_w_c is None and guided.widened
    assert guided.counts.point_matches == 0


@pytest.mark.parametrize("margin", [None, 20])
def test_with_a_moving_mask_the_features_on_it_are_the_dynamic_ones_and_stay_out_of_the_solve(
    sequence, features, margin
):
    config = load_config(overrides=() if margin is None else (f"dynamic.mask_margin_px={margin}",))
    tracker = Tracker(sequence.camera, config)
    for frame in features[:3]:
        tracker.track(frame)
    mask = np.zeros((sequence.camera.height, sequence.camera.width), dtype=bool)
    mask[:, : sequence.camera.width // 3] = True  # the left third "moves"
    guided = tracker.track_reference(features[3], mask)
    outline = config.dynamic.mask_margin_px
    on_mask = np.rint(guided.labels.point_uv[:, 0]) < sequence.camera.width // 3 + outline
    assert on_mask.any() and not on_mask.all()
    np.testing.assert_array_equal(guided.labels.point_dynamic, on_mask)
    assert guided.counts.dynamic_points == np.count_nonzero(on_mask)
    assert not (guided.solution.inliers.points & guided.labels.point_dynamic).any()
    assert guided.tracked
