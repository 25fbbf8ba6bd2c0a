"""Stereo point reprojection error: residual values and Jacobians against central differences."""


import numpy as np
import pytest
from finite_differences import (
    CAMERA,
    assert_jacobian_matches,
    point_jacobian_by_central_differences,
    pose_jacobian_by_central_differences,
    random_points_in_view,
    random_pose,
)

from pld_slam.geometry.se3 import inverse, transform_points
from pld_slam.optim.point_reprojection import MIN_DEPTH, point_reprojection_error, stereo_row_errors


@pytest.mark.parametrize("seed", range(5))
def test_residual_is_zero_at_the_true_pose(seed):
    rng = np.random.default_rng(seed)
    T_c_w = random_pose(rng)
    points_w = random_points_in_view(rng, T_c_w, 30)
    observed = CAMERA.project_stereo(transform_points(T_c_w, points_w))
    error = point_reprojection_error(CAMERA, T_c_w, points_w, observed)
    assert np.all(error.valid)
    assert np.allclose(error.residual, 0.0, atol=1e-9)


def test_residual_is_predicted_minus_observed():
    p_c = np.array([[1.0, -0.5, 10.0]])
    observed = CAMERA.project_stereo(p_c) + np.array([2.0, -3.0, 0.5])
    error = point_reprojection_error(CAMERA, np.eye(4), p_c, observed)
    assert np.allclose(error.residual, [[-2.0, 3.0, -0.5]])


@pytest.mark.parametrize("seed", range(5))
def test_pose_jacobian_matches_central_differences(seed):
    rng = np.random.default_rng(seed)
    T_c_w = random_pose(rng)
    points_w = random_points_in_view(rng, T_c_w, 40)
    observed = CAMERA.project_stereo(transform_points(T_c_w, points_w)) + rng.normal(0.0, 2.0, (40, 3))
    numeric = pose_jacobian_by_central_differences(
        lambda T: point_reprojection_error(CAMERA, T, points_w, observed).residual, T_c_w
    )
    assert_jacobian_matches(numeric, point_reprojection_error(CAMERA, T_c_w, points_w, observed).jac_pose)


@pytest.mark.parametrize("seed", range(5))
def test_point_jacobian_matches_central_differences(seed):
    rng = np.random.default_rng(100 + seed)
    T_c_w = random_pose(rng)
    points_w = random_points_in_view(rng, T_c_w, 40)
    observed = CAMERA.project_stereo(transform_points(T_c_w, points_w))
    numeric = point_jacobian_by_central_differences(
        lambda P: point_reprojection_error(CAMERA, T_c_w, P, observed).residual, points_w
    )
    assert_jacobian_matches(numeric, point_reprojection_error(CAMERA, T_c_w, points_w, observed).jac_point)


def test_points_at_or_behind_the_camera_are_flagged_and_projected_at_min_depth():
    p_c = np.array([[1.0, 0.5, 10.0], [1.0, 0.5, -4.0], [1.0, 0.5, 0.0], [1.0, 0.5, MIN_DEPTH]])
    observed = np.full((4, 3), 300.0)
    error = point_reprojection_error(CAMERA, np.eye(4), p_c, observed)
    assert error.valid.tolist() == [True, False, False, False]
    at_min_depth = point_reprojection_error(CAMERA, np.eye(4), p_c[3:], observed[3:]).residual
    assert np.allclose(error.residual[1:], at_min_depth)
    assert np.all(np.abs(error.residual[1:, 0]) > 1e5)  # far outside the image: a wall, not a reward


def test_jacobians_behind_the_camera_are_those_of_the_clamped_projection():
    rng = np.random.default_rng(9)
    T_c_w = random_pose(rng)
    p_c = rng.uniform([-3.0, -2.0, -5.0], [3.0, 2.0, -0.1], size=(20, 3))
    points_w = transform_points(inverse(T_c_w), p_c)
    observed = np.full((20, 3), 300.0)
    error = point_reprojection_error(CAMERA, T_c_w, points_w, observed)
    assert not np.any(error.valid)
    numeric_pose = pose_jacobian_by_central_differences(
        lambda T: point_reprojection_error(CAMERA, T, points_w, observed).residual, T_c_w
    )
    numeric_point = point_jacobian_by_central_differences(
        lambda P: point_reprojection_error(CAMERA, T_c_w, P, observed).residual, points_w
    )
    assert_jacobian_matches(numeric_pose, error.jac_pose)
    assert_jacobian_matches(numeric_point, error.jac_point)


def test_rows_without_jacobians_have_the_same_residuals_and_validity():
    rng = np.random.default_rng(7)
    T_c_w = random_pose(rng)
    points_w = np.vstack([random_points_in_view(rng, T_c_w, 20), transform_points(inverse(T_c_w), [[0.0, 0.0, -1.0]])])
    axes, offsets = rng.normal(size=(len(points_w), 3)), rng.normal(size=len(points_w))
    full = stereo_row_errors(CAMERA, T_c_w, points_w, axes, offsets)
    bare = stereo_row_errors(CAMERA, T_c_w, points_w, axes, offsets, with_jacobians=False)
    np.testing.assert_array_equal(bare.residual, full.residual)
    np.testing.assert_array_equal(bare.valid, full.valid)
    assert not full.valid[-1]  # the point behind the camera
    assert bare.jac_pose.shape == (0, 6) and bare.jac_point.shape == (0, 3)
