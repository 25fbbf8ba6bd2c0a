"""Line vertical and horizontal errors: constructed cases, sign conventions and Jacobians."""

import dataclasses

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
    LineErrorRows,
    detected_line_coefficients,
    detected_line_directions,
    endpoints_away_from_border,
    line_horizontal_error,
    line_row_errors,
    line_vertical_error,
    line_vertical_rows,
)
from pld_slam.optim.observations import LineObservations, stereo_vertical_rows
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


# The right image: rows measuring the right-camera projection u_right = u_left - fx * baseline / z.


def right_pixels(points_c: np.ndarray) -> np.ndarray:
    """Right-image pixels (N, 2) of camera-frame points (N, 3), written out from the stereo geometry."""
    left = CAMERA.project(points_c)
    return np.column_stack([left[:, 0] - CAMERA.fx * CAMERA.baseline / points_c[:, 2], left[:, 1]])


def random_stereo_rows(rng: np.random.Generator, n: int):
    """A pose and the 4n vertical rows of n segments seen in both images (left rows, then right rows),
    the detections 3 px off their projections."""
    T_c_w, start_w, end_w, start_px, end_px = random_observed_segments(rng, n)
    right_start_px = right_pixels(transform_points(T_c_w, start_w)) + rng.normal(0.0, 3.0, (n, 2))
    right_end_px = right_pixels(transform_points(T_c_w, end_w)) + rng.normal(0.0, 3.0, (n, 2))
    rows = LineErrorRows.concatenate(
        [
            line_vertical_rows(start_w, end_w, start_px, end_px),
            line_vertical_rows(start_w, end_w, right_start_px, right_end_px, right=True),
        ]
    )
    return T_c_w, rows


def test_right_rows_are_flagged_right_and_left_rows_are_not():
    T_c_w, rows = random_stereo_rows(np.random.default_rng(20), 10)
    assert rows.right.tolist() == [False] * 20 + [True] * 20


@pytest.mark.parametrize("seed", range(4))
def test_pose_jacobian_of_left_and_right_rows_matches_central_differences(seed):
    T_c_w, rows = random_stereo_rows(np.random.default_rng(60 + seed), 30)
    numeric = pose_jacobian_by_central_differences(lambda T: line_row_errors(CAMERA, T, rows).residual, T_c_w)
    assert_jacobian_matches(numeric, line_row_errors(CAMERA, T_c_w, rows).jac_pose)


@pytest.mark.parametrize("seed", range(4))
def test_endpoint_jacobian_of_left_and_right_rows_matches_central_differences(seed):
    T_c_w, rows = random_stereo_rows(np.random.default_rng(70 + seed), 30)
    numeric = point_jacobian_by_central_differences(
        lambda P: line_row_errors(CAMERA, T_c_w, dataclasses.replace(rows, endpoints_w=P)).residual, rows.endpoints_w
    )
    assert_jacobian_matches(numeric, line_row_errors(CAMERA, T_c_w, rows).jac_endpoint)


def test_jacobians_of_whitened_right_rows_at_one_pose_per_row_match_central_differences():
    rng = np.random.default_rng(80)
    T_c_w, rows = random_stereo_rows(rng, 12)
    rows = rows.scaled(rng.uniform(0.5, 2.0, len(rows.offsets)))
    poses = np.repeat(T_c_w[None], len(rows.offsets), axis=0)
    errors = line_row_errors(CAMERA, poses, rows)
    numeric_pose = pose_jacobian_by_central_differences(
        lambda T: line_row_errors(CAMERA, np.repeat(T[None], len(rows.offsets), axis=0), rows).residual, T_c_w
    )
    numeric_endpoint = point_jacobian_by_central_differences(
        lambda P: line_row_errors(CAMERA, poses, dataclasses.replace(rows, endpoints_w=P)).residual, rows.endpoints_w
    )
    assert_jacobian_matches(numeric_pose, errors.jac_pose)
    assert_jacobian_matches(numeric_endpoint, errors.jac_endpoint)


def test_a_segment_projected_exactly_into_the_right_camera_has_zero_right_vertical_error():
    rng = np.random.default_rng(21)
    T_c_w = random_pose(rng)
    start_w, end_w = random_points_in_view(rng, T_c_w, 20), random_points_in_view(rng, T_c_w, 20)
    right_start_px = right_pixels(transform_points(T_c_w, start_w))
    right_end_px = right_pixels(transform_points(T_c_w, end_w))
    right = line_vertical_rows(start_w, end_w, right_start_px, right_end_px, right=True)
    as_left = line_vertical_rows(start_w, end_w, right_start_px, right_end_px)
    assert np.allclose(line_row_errors(CAMERA, T_c_w, right).residual, 0.0, atol=1e-8)
    # the same detections read as left-image segments miss the left projections by the disparity
    assert np.all(np.abs(line_row_errors(CAMERA, T_c_w, as_left).residual) > 1e-3)


def test_right_vertical_error_is_the_signed_pixel_distance_in_the_right_image():
    # a vertical right-image segment at u = 500 travelling down (+v): its right side is -u
    right_start_px, right_end_px = np.array([[500.0, 100.0]]), np.array([[500.0, 300.0]])
    depth = 10.0
    disparity = CAMERA.fx * CAMERA.baseline / depth
    P = points_at_pixels([[503.0 + disparity, 150.0]], depth)  # right projection 3 px right of the segment
    Q = points_at_pixels([[498.0 + disparity, 250.0]], depth)  # 2 px left of it
    rows = line_vertical_rows(P, Q, right_start_px, right_end_px, right=True)
    assert np.allclose(line_row_errors(CAMERA, np.eye(4), rows).residual, [-3.0, 2.0])


def test_stereo_vertical_rows_weigh_nothing_in_the_right_image_where_the_right_segment_is_unknown():
    rng = np.random.default_rng(22)
    T_c_w, start_w, end_w, start_px, end_px = random_observed_segments(rng, 6)
    right_start_px = right_pixels(transform_points(T_c_w, start_w)) + rng.normal(0.0, 3.0, (6, 2))
    right_end_px = right_pixels(transform_points(T_c_w, end_w)) + rng.normal(0.0, 3.0, (6, 2))
    right_start_px[1] = np.nan  # unknown: both points NaN
    right_start_px[3, 0] = np.nan  # one coordinate of one point is enough to make it unknown
    right_end_px[4, 1] = np.nan
    sigma_px = rng.uniform(0.5, 2.0, 6)
    lines = LineObservations(
        start_w, end_w, start_px, end_px, sigma_px, np.ones(6, dtype=bool), right_start_px, right_end_px
    )
    known = np.array([True, False, True, False, False, True])

    rows = stereo_vertical_rows(lines)
    errors = line_row_errors(CAMERA, T_c_w, rows)

    per_observation = rows.axes.reshape(6, 4, 2)
    assert rows.right.reshape(6, 4).tolist() == [[False, False, True, True]] * 6
    left = line_vertical_rows(start_w, end_w, start_px, end_px).scaled(np.repeat(1.0 / sigma_px, 2))
    assert np.allclose(per_observation[:, :2].reshape(-1, 2), left.axes)
    assert np.allclose(rows.offsets.reshape(6, 4)[:, :2].ravel(), left.offsets)
    right = line_vertical_rows(
        start_w[known], end_w[known], right_start_px[known], right_end_px[known], right=True
    ).scaled(np.repeat(1.0 / sigma_px[known], 2))
    assert np.allclose(per_observation[known, 2:].reshape(-1, 2), right.axes)
    assert np.allclose(rows.offsets.reshape(6, 4)[known, 2:].ravel(), right.offsets)
    unknown_rows = np.zeros((6, 4), dtype=bool)
    unknown_rows[~known, 2:] = True
    unknown_rows = unknown_rows.ravel()
    assert np.all(rows.axes[unknown_rows] == 0.0) and np.all(rows.offsets[unknown_rows] == 0.0)
    assert np.all(errors.residual[unknown_rows] == 0.0)
    assert np.all(errors.jac_pose[unknown_rows] == 0.0) and np.all(errors.jac_endpoint[unknown_rows] == 0.0)
    assert np.all(np.abs(errors.residual[~unknown_rows]) > 0.0)


def test_stereo_vertical_rows_without_any_right_segment_weigh_nothing_in_the_right_image():
    rng = np.random.default_rng(23)
    T_c_w, start_w, end_w, start_px, end_px = random_observed_segments(rng, 5)
    lines = LineObservations(start_w, end_w, start_px, end_px, np.ones(5), np.ones(5, dtype=bool))
    rows = stereo_vertical_rows(lines)
    right_rows = rows.right
    assert right_rows.sum() == 10
    assert np.all(rows.axes[right_rows] == 0.0) and np.all(rows.offsets[right_rows] == 0.0)
    assert np.all(line_row_errors(CAMERA, T_c_w, rows).residual[right_rows] == 0.0)
    left = line_vertical_rows(start_w, end_w, start_px, end_px)
    assert np.allclose(rows.axes[~right_rows], left.axes) and np.allclose(rows.offsets[~right_rows], left.offsets)
