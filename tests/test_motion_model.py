"""`MotionModel`: the constant-velocity prediction, its advance over tracked and skipped frames, and
distances from it in units of its expected error."""

import numpy as np

from pld_slam.config import load_config
from pld_slam.geometry.se3 import inverse
from pld_slam.localisation.static_world import StaticWorldOptions
from pld_slam.tracking.motion_model import MotionModel


def pose(yaw_deg: float, t: tuple[float, float, float]) -> np.ndarray:
    """A camera-to-world pose (4, 4): a rotation about the camera's y axis, then ``t``."""
    a = np.deg2rad(yaw_deg)
    T = np.eye(4)
    T[:3, :3] = [[np.cos(a), 0.0, np.sin(a)], [0.0, 1.0, 0.0], [-np.sin(a), 0.0, np.cos(a)]]
    T[:3, 3] = t
    return T


def test_a_new_model_predicts_standing_still_at_the_origin():
    model = MotionModel()
    np.testing.assert_array_equal(model.predicted_T_w_c(), np.eye(4))
    np.testing.assert_array_equal(model.predicted_T_c_w(), np.eye(4))


def test_after_two_poses_the_prediction_repeats_the_last_motion():
    model = MotionModel()
    first, second = pose(0.0, (0.0, 0.0, 0.0)), pose(3.0, (0.1, 0.0, 1.0))
    model.advance(first)
    T_w_c, T_c_p = model.advance(second)
    np.testing.assert_allclose(T_w_c, second, atol=1e-12)
    np.testing.assert_allclose(T_c_p, inverse(second) @ first, atol=1e-12)
    expected = second @ inverse(first) @ second  # the motion first -> second once more
    np.testing.assert_allclose(model.predicted_T_w_c(), expected, atol=1e-12)
    np.testing.assert_allclose(model.predicted_T_c_w(), inverse(expected), atol=1e-12)
    # 6 degrees turned and the second step along the same turn: not the second pose again
    assert np.linalg.norm(model.predicted_T_w_c()[:3, 3] - second[:3, 3]) > 0.9


def test_advance_projects_the_pose_onto_se3():
    model = MotionModel()
    noisy = pose(10.0, (1.0, 2.0, 3.0))
    noisy[:3, :3] *= 1.001  # not a rotation any more
    T_w_c, _ = model.advance(noisy)
    np.testing.assert_allclose(T_w_c[:3, :3] @ T_w_c[:3, :3].T, np.eye(3), atol=1e-12)
    assert model.T_w_p is T_w_c


def test_coasting_over_a_skipped_frame_takes_the_prediction_and_keeps_the_velocity():
    model = MotionModel()
    model.advance(pose(0.0, (0.0, 0.0, 0.0)))
    model.advance(pose(0.0, (0.0, 0.0, 1.0)))
    coasted = model.coast()
    np.testing.assert_allclose(coasted[:3, 3], [0.0, 0.0, 2.0], atol=1e-12)
    np.testing.assert_allclose(model.predicted_T_w_c()[:3, 3], [0.0, 0.0, 3.0], atol=1e-12)  # same velocity


def test_distance_is_in_units_of_the_expected_error_the_larger_of_translation_and_rotation():
    config = load_config()
    metres, degrees = config.dynamic.motion_prior_m, config.dynamic.motion_prior_deg
    model = MotionModel()
    model.advance(pose(0.0, (0.0, 0.0, 1.0)))
    predicted = model.predicted_T_w_c()
    assert model.distance(inverse(predicted), StaticWorldOptions.of(config)) == 0.0
    shifted = predicted @ pose(0.0, (3 * metres, 0.0, 0.0))
    np.testing.assert_allclose(model.distance(inverse(shifted), StaticWorldOptions.of(config)), 3.0, rtol=1e-9)
    turned = predicted @ pose(5 * degrees, (metres, 0.0, 0.0))
    np.testing.assert_allclose(model.distance(inverse(turned), StaticWorldOptions.of(config)), 5.0, rtol=1e-6)
