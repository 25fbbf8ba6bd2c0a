"""Line vertical and horizontal errors: constructed cases, sign conventions and Jacobians."""

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

from pld_slam.geometry.se3 import transform_points
from pld_slam.optim.line_reprojection import (
    detected_line_coefficients,
    detected_line_directions,
    endpoints_away_from_border,
    line_horizontal_error,
    line_vertical_error,
)
from pld_slam.optim.point_reprojection import MIN_DEPTH

LINE_ERRORS = [line_vertical_error, line_horizontal_error]


def points_at_pixels(pixels: np.ndarray, depth: float = 10.0) -> np.ndarray:
    """Camera-frame points (N, 3) at ``depth`` [m] that project to left pixels (N, 2)."""
    return CAMERA.backproject(np.asarray(pixels, dtype=float), np.full(len(pixels), depth))


def random_observed_segments(rng: np.random.Generator, n: int):
    """A pose, world segments (n, 3) x 2 in view, and detected endpoints (n, 2) x 2 near their projections."""
    T_c_w = random_pose(rng)
    start_w, end_w = random_points_in_view(rng, T_c_w, n), random_points_in_view(rng, T_c_w, n)
    start_px = CAMERA.project(transform_points(T_c_w, start_w)) + rng.normal(0.0, 3.0, (n, 2))
    end_px = CAMERA.project(transform_points(T_c_w, end_w)) + rng.normal(0.0, 3.0, (n, 2))
    return T_c_w, start_w, end_w, start_px, end_px


def test_detected_line_coefficients_are_normalised_and_pass_through_the_endpoints():
    rng = np.random.default_rng(0)
    start_px, end_px = rng.uniform(0, 1000, (20, 2)), rng.uniform(0, 1000, (20, 2))
    line = detected_line_coefficients(start_px, end_px)
    assert np.allclose(np.hypot(line[:, 0], line[:, 1]), 1.0)
    for endpoint in (start_px, end_px):
        assert np.allclose(np.einsum("ij,ij->i", line[:, :2], endpoint) + line[:, 2], 0.0, atol=1e-9)


def test_line_normal_points_right_of_the_detected_direction():
    line = detected_line_coefficients(np.array([[0.0, 0.0]]), np.array([[10.0, 0.0]]))
    assert np.allclose(line, [[0.0, 1.0, 0.0]])  # travelling +u, the right side is +v (down)
    assert np.allclose(
        detected_line_directions(np.array([[0.0, 0.0]]), np.array([[10.0, 0.0]])), [[1.0, 0.0]]
    )


def test_vertical_error_is_the_signed_perpendicular_pixel_distance():
    start_px, end_px = np.array([[100.0, 200.0]]), np.array([[300.0, 200.0]])
    P, Q = points_at_pixels([[150.0, 203.0]]), points_at_pixels([[250.0, 195.0]], depth=20.0)
    error = line_vertical_error(CAMERA, np.eye(4), P, Q, start_px, end_px)
    assert np.allclose(error.residual, [[3.0, -5.0]])
    reversed_error = line_vertical_error(CAMERA, np.eye(4), Q, P, end_px, start_px)
    assert np.allclose(reversed_error.residual, [[5.0, -3.0]])


def test_vertical_error_is_the_signed_point_to_line_distance_on_a_slanted_line():
    start_px, end_px = np.array([[120.0, 40.0]]), np.array([[420.0, 310.0]])
    pixels = np.array([[200.0, 250.0], [500.0, 100.0]])
    error = line_vertical_error(
        CAMERA, np.eye(4), points_at_pixels(pixels[:1]), points_at_pixels(pixels[1:]), start_px, end_px
    )
    du, dv = (end_px - start_px)[0]
    offset = pixels - start_px
    # the 2D cross product d x (x - s) / |d|: the distance, positive on the right of d (v down)
    signed_distance = (du * offset[:, 1] - dv * offset[:, 0]) / np.hypot(du, dv)
    assert np.allclose(error.residual[0], signed_distance)


def test_horizontal_error_is_positive_beyond_the_detected_endpoint_along_s_to_e():
    start_px, end_px = np.array([[100.0, 200.0]]), np.array([[300.0, 200.0]])
    P, Q = points_at_pixels([[95.0, 200.0]]), points_at_pixels([[310.0, 204.0]])
    error = line_horizontal_error(CAMERA, np.eye(4), P, Q, start_px, end_px)
    assert np.allclose(error.residual, [[-5.0, 10.0]])


def test_vertical_and_horizontal_errors_decompose_the_endpoint_error():
    rng = np.random.default_rng(3)
    T_c_w, start_w, end_w, start_px, end_px = random_observed_segments(rng, 30)
    vertical = line_vertical_error(CAMERA, T_c_w, start_w, end_w, start_px, end_px).residual
    horizontal = line_horizontal_error(CAMERA, T_c_w, start_w, end_w, start_px, end_px).residual
    start_error = CAMERA.project(transform_points(T_c_w, start_w)) - start_px
    end_error = CAMERA.project(transform_points(T_c_w, end_w)) - end_px
    assert np.allclose(vertical[:, 0] ** 2 + horizontal[:, 0] ** 2, np.sum(start_error**2, axis=1))
    assert np.allclose(vertical[:, 1] ** 2 + horizontal[:, 1] ** 2, np.sum(end_error**2, axis=1))


def test_sliding_detected_endpoints_along_their_line_changes_only_the_horizontal_error():
    rng = np.random.default_rng(4)
    T_c_w, start_w, end_w, start_px, end_px = random_observed_segments(rng, 30)
    direction = detected_line_directions(start_px, end_px)
    slide_start, slide_end = rng.uniform(-20, 20, (30, 1)), rng.uniform(-20, 20, (30, 1))
    slid = (start_px + slide_start * direction, end_px + slide_end * direction)
    before = [f(CAMERA, T_c_w, start_w, end_w, start_px, end_px).residual for f in LINE_ERRORS]
    after = [f(CAMERA, T_c_w, start_w, end_w, *slid).residual for f in LINE_ERRORS]
    assert np.allclose(after[0], before[0])
    assert np.allclose(after[1], before[1] - np.hstack([slide_start, slide_end]))


def test_sliding_a_3d_endpoint_along_its_line_changes_only_the_horizontal_error():
    P, Q = points_at_pixels([[300.0, 100.0]], depth=8.0), points_at_pixels([[700.0, 250.0]], depth=15.0)
    start_px, end_px = CAMERA.project(P), CAMERA.project(Q)
    slid_P = P + 0.2 * (Q - P)
    for P_used, moved in ((P, False), (slid_P, True)):
        vertical = line_vertical_error(CAMERA, np.eye(4), P_used, Q, start_px, end_px).residual
        horizontal = line_horizontal_error(CAMERA, np.eye(4), P_used, Q, start_px, end_px).residual
        assert np.allclose(vertical, 0.0, atol=1e-9)
        assert (abs(horizontal[0, 0]) > 1.0) == moved


@pytest.mark.parametrize("line_error", LINE_ERRORS)
@pytest.mark.parametrize("seed", range(4))
def test_pose_jacobian_matches_central_differences(line_error, seed):
    T_c_w, start_w, end_w, start_px, end_px = random_observed_segments(np.random.default_rng(seed), 30)
    numeric = pose_jacobian_by_central_differences(
        lambda T: line_error(CAMERA, T, start_w, end_w, start_px, end_px).residual, T_c_w
    )
    assert_jacobian_matches(numeric, line_error(CAMERA, T_c_w, start_w, end_w, start_px, end_px).jac_pose)


@pytest.mark.parametrize("line_error", LINE_ERRORS)
@pytest.mark.parametrize("seed", range(4))
def test_endpoint_jacobians_match_central_differences(line_error, seed):
    T_c_w, start_w, end_w, start_px, end_px = random_observed_segments(np.random.default_rng(50 + seed), 30)
    error = line_error(CAMERA, T_c_w, start_w, end_w, start_px, end_px)
    numeric_start = point_jacobian_by_central_differences(
        lambda P: line_error(CAMERA, T_c_w, P, end_w, start_px, end_px).residual, start_w
    )
    numeric_end = point_jacobian_by_central_differences(
        lambda Q: line_error(CAMERA, T_c_w, start_w, Q, start_px, end_px).residual, end_w
    )
    assert_jacobian_matches(numeric_start, error.jac_start)
    assert_jacobian_matches(numeric_end, error.jac_end)
    assert np.all(error.jac_start[:, 1] == 0.0) and np.all(error.jac_end[:, 0] == 0.0)


@pytest.mark.parametrize("line_error", LINE_ERRORS)
def test_segments_with_an_endpoint_behind_the_camera_are_flagged_and_clamped(line_error):
    P = np.array([[0.0, 0.0, 5.0], [0.0, 0.0, 5.0], [0.0, 0.0, 5.0]])
    Q = np.array([[1.0, 0.0, 6.0], [1.0, 0.0, -6.0], [1.0, 0.0, MIN_DEPTH]])
    detected = (np.array([[0.0, 0.0]] * 3), np.array([[10.0, 5.0]] * 3))
    error = line_error(CAMERA, np.eye(4), P, Q, *detected)
    assert error.valid.tolist() == [True, False, False]
    assert np.allclose(error.residual[1], error.residual[2])


def test_endpoints_away_from_border_needs_both_endpoints_inside_the_margin():
    inside = np.array([[20.0, 20.0]])
    near_left, near_bottom = np.array([[5.0, 100.0]]), np.array([[600.0, CAMERA.height - 3.0]])
    far_corner = np.array([[CAMERA.width - 11.0, CAMERA.height - 11.0]])
    starts, ends = np.vstack([inside, near_left, inside]), np.vstack([far_corner, inside, near_bottom])
    assert endpoints_away_from_border(CAMERA, starts, ends, margin_px=10.0).tolist() == [True, False, False]
