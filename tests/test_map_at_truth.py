"""A map moved onto the ground truth (`pld_slam.eval.map_at_truth`), on the hand-built street map of
`test_local_ba`: every keyframe starts 3 cm and 0.3 degrees off its true pose, every landmark 5 cm."""

import numpy as np
import pytest
from test_local_ba import CAMERA, LINE_GROUPS, POINT_GROUPS, build_map, pose_errors

from pld_slam.eval.map_at_truth import move_map_to_truth, true_keyframe_poses
from pld_slam.geometry.se3 import inverse, transform_points


@pytest.fixture(scope="module")
def moved():
    """The street map (first keyframe off its true pose too) before and after `move_map_to_truth`."""
    made = build_map(seed=3, point_spec=POINT_GROUPS, line_spec=LINE_GROUPS, n_keyframes=5, exact_keyframes=())
    groundtruth = np.array([inverse(T_c_w) for T_c_w in made.T_c_w])  # T_g_c of frame k = keyframe k
    root_before = made.world_map.keyframes[0].T_c_w.copy()
    move_map_to_truth(made.world_map, groundtruth)
    return made, groundtruth, root_before


def test_the_first_keyframe_keeps_its_pose_and_the_others_take_their_true_poses_relative_to_it(moved):
    made, _, root_before = moved
    keyframes = made.world_map.keyframes
    assert np.allclose(keyframes[0].T_c_w, root_before, atol=1e-12)
    for k in range(1, 5):
        relative = keyframes[k].T_c_w @ inverse(keyframes[0].T_c_w)
        distance, angle = pose_errors(relative, made.T_c_w[k] @ inverse(made.T_c_w[0]))
        assert distance < 1e-9 and angle < 1e-6


def test_the_true_poses_are_given_in_the_maps_world_frame(moved):
    made, groundtruth, _ = moved
    poses = true_keyframe_poses(made.world_map, groundtruth)
    assert set(poses) == set(made.world_map.keyframes)
    for k, T_w_c in poses.items():
        assert np.allclose(T_w_c, made.world_map.keyframes[k].T_w_c, atol=1e-12)


def test_each_landmark_sits_where_its_first_stereo_observation_puts_it_from_the_true_pose(moved):
    made, groundtruth, _ = moved
    world_map = made.world_map
    T_w_g = world_map.keyframes[0].T_w_c @ inverse(groundtruth[0])
    for kind, attribute in ((world_map.points, "points"), (world_map.lines, "lines")):
        for landmark in np.flatnonzero(kind.alive).tolist():
            keyframe_id, feature = next(iter(kind.observers[landmark].items()))
            observed = getattr(world_map.keyframes[keyframe_id].features, attribute)
            if attribute == "points":
                seen_c = CAMERA.triangulate(observed.uv[feature][None], observed.disparity[feature][None])
            else:
                ends = observed.endpoints[feature].reshape(2, 2)
                seen_c = CAMERA.triangulate(ends, observed.disparity[feature])
            expected = transform_points(T_w_g @ groundtruth[keyframe_id], seen_c)
            assert np.allclose(kind.geometry[landmark].reshape(-1, 3), expected, atol=1e-9)
