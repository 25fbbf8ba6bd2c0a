"""Sparse bundle adjustment on a synthetic street: the solver's Jacobian against central
differences, and what `bundle_adjust` does with perturbed poses and landmarks, outliers,
fixed poses and the line switches.

The street: the KITTI-like camera of `finite_differences`, keyframes 1.2 m apart along
the street (a few cm of lateral wander and up to 1.7 degrees of yaw), points on the two
facades 8-45 m ahead, segments on the facades (steep in the image, 2-3 m long). Every
landmark in view of a keyframe is observed by it. Observations carry Gaussian noise of
half their declared sigma, so every clean observation passes its chi-square test at the
truth with a wide margin; some points lack ``u_right`` (monocular) and some segments
lack the right-image segment (NaN). The Jacobian tests use a small street as it comes; the
`bundle_adjust` tests keep the landmarks local BA would adjust (`seen_twice`), and add a
landmark seen once only where that is the point of the test.

The residual function of the solver is private; these tests use exactly three of its
names, `_BundleRows.of`, `_State.initial` and `_SparseProblem`, and otherwise only the
public row layout of `pld_slam.optim.observations.WhitenedRows` (3 rows per point
observation, then 4 per vertical term, then 2 per horizontal term).
"""

import dataclasses
from dataclasses import dataclass

import numpy as np
import pytest
from finite_differences import CAMERA, assert_jacobian_matches, point_jacobian_by_central_differences

from pld_slam.geometry.se3 import inverse, make_pose, se3_exp, so3_exp, so3_log, transform_points
from pld_slam.optim import bundle_adjustment
from pld_slam.optim.bundle_adjustment import (
    BundleLineObservations,
    BundleOptions,
    BundlePointObservations,
    BundleProblem,
    BundleResult,
    bundle_adjust,
)
from pld_slam.optim.line_reprojection import detected_line_coefficients, detected_line_directions

NOISE_PX = 0.5
"""Std of the corner and endpoint noise [px]; the declared sigmas are twice that."""
DISPARITY_NOISE_PX = 0.15
"""Std of the disparity noise [px]; its declared sigma is twice that."""


@dataclass(frozen=True)
class Street:
    """A synthetic street: the true geometry and its observations."""

    T_c_w: np.ndarray
    points_w: np.ndarray
    lines_w: np.ndarray
    point_observations: BundlePointObservations
    line_observations: BundleLineObservations


def street_poses(rng: np.random.Generator, n_keyframes: int) -> np.ndarray:
    """``T_c_w`` (K, 4, 4) of keyframes 1.2 m apart along +z, wandering a little."""
    poses = []
    for k in range(n_keyframes):
        R_w_c = so3_exp([0.0, rng.uniform(-0.03, 0.03), 0.0])
        poses.append(inverse(make_pose(R_w_c, [rng.uniform(-0.2, 0.2), 0.0, 1.2 * k])))
    return np.array(poses)


def street_points(rng: np.random.Generator, n: int) -> np.ndarray:
    """(n, 3) points on the facades on either side, 8-45 m ahead."""
    side = rng.choice([-1.0, 1.0], n)
    return np.column_stack([side * rng.uniform(4.0, 10.0, n), rng.uniform(-3.0, 1.6, n), rng.uniform(8.0, 45.0, n)])


def street_lines(rng: np.random.Generator, n: int) -> np.ndarray:
    """(n, 2, 3) segments on the facades, start above end, steep in the image."""
    side = rng.choice([-1.0, 1.0], n)
    start = np.column_stack([side * rng.uniform(5.0, 9.0, n), rng.uniform(-3.0, -1.5, n), rng.uniform(12.0, 40.0, n)])
    end = start + np.column_stack([rng.uniform(-1.0, 1.0, n), rng.uniform(2.0, 3.0, n), rng.uniform(-1.5, 1.5, n)])
    return np.stack([start, end], axis=1)


def inside_image(pixels: np.ndarray, margin_px: float) -> np.ndarray:
    """Whether pixels (..., 2) lie ``margin_px`` inside the image (...)."""
    high = np.array([CAMERA.width - 1.0 - margin_px, CAMERA.height - 1.0 - margin_px])
    return np.all((pixels >= margin_px) & (pixels <= high), axis=-1)


def observe_street(
    rng: np.random.Generator, T_c_w: np.ndarray, points_w: np.ndarray, lines_w: np.ndarray
) -> tuple[BundlePointObservations, BundleLineObservations]:
    """Every landmark in view of every keyframe, with noise (module docstring).

    Every fifth point observation is monocular; every third segment has no right segment.
    """
    keyframe, point, stereo_px = [], [], []
    for k, T in enumerate(T_c_w):
        p_c = transform_points(T, points_w)
        exact = CAMERA.project_stereo(p_c)
        seen = np.flatnonzero((p_c[:, 2] > 2.0) & inside_image(exact[:, :2], 5.0))
        corner = exact[seen, :2] + rng.normal(0.0, NOISE_PX, (len(seen), 2))
        disparity = exact[seen, 0] - exact[seen, 2] + rng.normal(0.0, DISPARITY_NOISE_PX, len(seen))
        keyframe.append(np.full(len(seen), k))
        point.append(seen)
        stereo_px.append(np.column_stack([corner, corner[:, 0] - disparity]))
    stereo_px = np.concatenate(stereo_px)
    stereo_px[::5, 2] = np.nan
    points = BundlePointObservations(
        keyframe=np.concatenate(keyframe),
        point=np.concatenate(point),
        stereo_px=stereo_px,
        sigma_px=np.tile([2.0 * NOISE_PX, 2.0 * NOISE_PX, 2.0 * DISPARITY_NOISE_PX], (len(stereo_px), 1)),
    )
    keyframe, line, left, right = [], [], [], []
    for k, T in enumerate(T_c_w):
        ends_c = transform_points(T, lines_w.reshape(-1, 3)).reshape(-1, 2, 3)
        exact = CAMERA.project_stereo(ends_c.reshape(-1, 3)).reshape(-1, 2, 3)
        in_front = np.all(ends_c[:, :, 2] > 2.0, axis=1)
        seen = np.flatnonzero(in_front & np.all(inside_image(exact[:, :, :2], 12.0), axis=1))
        keyframe.append(np.full(len(seen), k))
        line.append(seen)
        left.append(exact[seen][:, :, :2] + rng.normal(0.0, NOISE_PX, (len(seen), 2, 2)))
        right.append(exact[seen][:, :, [2, 1]] + rng.normal(0.0, NOISE_PX, (len(seen), 2, 2)))
    left, right = np.concatenate(left), np.concatenate(right)
    right[::3] = np.nan
    n = len(left)
    lines = BundleLineObservations(
        keyframe=np.concatenate(keyframe),
        line=np.concatenate(line),
        start_px=left[:, 0],
        end_px=left[:, 1],
        sigma_px=np.full(n, 2.0 * NOISE_PX),
        horizontal_eligible=np.ones(n, dtype=bool),
        right_start_px=right[:, 0],
        right_end_px=right[:, 1],
    )
    return points, lines


def make_street(seed: int, n_keyframes: int, n_points: int, n_lines: int) -> Street:
    rng = np.random.default_rng(seed)
    T_c_w = street_poses(rng, n_keyframes)
    points_w, lines_w = street_points(rng, n_points), street_lines(rng, n_lines)
    return Street(T_c_w, points_w, lines_w, *observe_street(rng, T_c_w, points_w, lines_w))


def perturbed_poses(rng: np.random.Generator, T_c_w: np.ndarray, fixed: np.ndarray) -> np.ndarray:
    """The free poses moved by ~3 cm per axis and 0.5 degrees about a random axis; the fixed ones kept."""
    moved = T_c_w.copy()
    for k in np.flatnonzero(~fixed):
        axis = rng.normal(size=3)
        twist = np.concatenate([rng.normal(0.0, 0.03, 3), np.radians(0.5) * axis / np.linalg.norm(axis)])
        moved[k] = se3_exp(twist) @ T_c_w[k]
    return moved


def perturbed_problem(street: Street, fixed: np.ndarray, seed: int, landmark_sigma_m: float = 0.1) -> BundleProblem:
    """The street's problem started from perturbed free poses and landmarks (``landmark_sigma_m`` per axis)."""
    rng = np.random.default_rng(seed)
    return BundleProblem(
        T_c_w=perturbed_poses(rng, street.T_c_w, fixed),
        fixed=fixed,
        points_w=street.points_w + rng.normal(0.0, landmark_sigma_m, street.points_w.shape),
        lines_w=street.lines_w + rng.normal(0.0, landmark_sigma_m, street.lines_w.shape),
        point_observations=street.point_observations,
        line_observations=street.line_observations,
    )


def relative_pose_errors(T_est: np.ndarray, T_true: np.ndarray, reference: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Camera-centre distance [m] and rotation angle [rad] (K,) of each pose relative to pose ``reference``,
    estimated against true: the gauge is the reference pose's."""
    translation, rotation = [], []
    for T_e, T_t in zip(T_est, T_true):
        T_diff = (T_e @ inverse(T_est[reference])) @ inverse(T_t @ inverse(T_true[reference]))
        translation.append(np.linalg.norm(inverse(T_diff)[:3, 3]))
        rotation.append(np.linalg.norm(so3_log(T_diff[:3, :3])))
    return np.array(translation), np.array(rotation)


def distance_to_lines(points_w: np.ndarray, lines_w: np.ndarray) -> np.ndarray:
    """Distance (L,) of points (L, 3) to the infinite lines through segments (L, 2, 3)."""
    direction = lines_w[:, 1] - lines_w[:, 0]
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    offset = points_w - lines_w[:, 0]
    return np.linalg.norm(offset - np.sum(offset * direction, axis=1, keepdims=True) * direction, axis=1)


# The solver's residual function and its sparse Jacobian.


def all_rows(problem: BundleProblem) -> np.ndarray:
    """(R,) True for every row of the problem: 3 per point observation, 4 + 2 per line observation."""
    return np.ones(3 * len(problem.point_observations.point) + 6 * len(problem.line_observations.line), dtype=bool)


def some_rows(problem: BundleProblem) -> np.ndarray:
    """A mask keeping whole terms only: every other point observation, every vertical term and the
    horizontal term of every third line observation."""
    n_points, n_lines = len(problem.point_observations.point), len(problem.line_observations.line)
    return np.concatenate(
        [
            np.repeat(np.arange(n_points) % 2 == 0, 3),
            np.ones(4 * n_lines, dtype=bool),
            np.repeat(np.arange(n_lines) % 3 == 0, 2),
        ]
    )


def sparse_problem(problem: BundleProblem, row_mask: np.ndarray):
    every_row = bundle_adjustment._BundleRows.of(problem, BundleOptions())
    state = bundle_adjustment._State.initial(problem)
    return bundle_adjustment._SparseProblem(CAMERA, every_row, state, row_mask)


def jacobian_by_central_differences(residuals, y: np.ndarray) -> np.ndarray:
    """Jacobian (R, n) of ``residuals`` at ``y`` (n,), with the shared helper of `finite_differences`.

    The unknowns are taken three at a time: row b of the stacked residual moves only
    unknowns 3b..3b+2, so the helper's per-row Jacobian of row b holds columns 3b..3b+2.
    """
    blocks = y.reshape(-1, 3)

    def stacked(moved_blocks: np.ndarray) -> np.ndarray:
        rows = []
        for b in range(len(blocks)):
            moved = blocks.copy()
            moved[b] = moved_blocks[b]
            rows.append(residuals(moved.ravel()))
        return np.array(rows)

    per_block = point_jacobian_by_central_differences(stacked, blocks)  # (n / 3, R, 3)
    return per_block.transpose(1, 0, 2).reshape(per_block.shape[1], -1)


@pytest.fixture(scope="module")
def small_street() -> Street:
    """4 keyframes, 30 points, 6 segments."""
    street = make_street(seed=1, n_keyframes=4, n_points=30, n_lines=6)
    assert np.all(np.bincount(street.line_observations.line, minlength=6) >= 2)
    return street


SMALL_FIXED = [np.array([True, False, False, False]), np.array([False, True, False, True])]


def test_the_small_street_has_every_kind_of_observation(small_street):
    points, lines = small_street.point_observations, small_street.line_observations
    assert np.any(np.isnan(points.stereo_px[:, 2])) and not np.all(np.isnan(points.stereo_px[:, 2]))
    right_known = np.all(np.isfinite(lines.right_start_px), axis=1)
    assert np.any(right_known) and not np.all(right_known)
    assert np.all(lines.horizontal_eligible)


@pytest.mark.parametrize("fixed", SMALL_FIXED, ids=["first-fixed", "second-and-fourth-fixed"])
def test_there_are_six_unknowns_per_free_pose_and_three_per_point_and_line_endpoint(small_street, fixed):
    problem = perturbed_problem(small_street, fixed, seed=2)
    expected = 6 * np.count_nonzero(~fixed) + 3 * (len(problem.points_w) + 2 * len(problem.lines_w))
    assert sparse_problem(problem, all_rows(problem)).n_unknowns == expected


@pytest.mark.parametrize("row_subset", [all_rows, some_rows])
@pytest.mark.parametrize("fixed", SMALL_FIXED, ids=["first-fixed", "second-and-fourth-fixed"])
def test_sparse_jacobian_matches_central_differences_at_the_initial_point(small_street, fixed, row_subset):
    problem = perturbed_problem(small_street, fixed, seed=3)
    solver_problem = sparse_problem(problem, row_subset(problem))
    y = np.zeros(solver_problem.n_unknowns)
    numeric = jacobian_by_central_differences(solver_problem.residuals, y)
    analytic = solver_problem.jacobian(y).toarray()
    assert analytic.shape == (np.count_nonzero(row_subset(problem)), solver_problem.n_unknowns)
    assert_jacobian_matches(numeric, analytic)


def test_a_jacobian_evaluated_in_chunks_of_rows_is_the_one_evaluated_at_once(small_street):
    problem = perturbed_problem(small_street, SMALL_FIXED[1], seed=4)
    every_row = bundle_adjustment._BundleRows.of(problem, BundleOptions())
    state, rows = bundle_adjustment._State.initial(problem), some_rows(problem)
    at_once = bundle_adjustment._SparseProblem(CAMERA, every_row, state, rows)
    in_chunks = bundle_adjustment._SparseProblem(CAMERA, every_row, state, rows, chunk_rows=7)  # cuts terms apart
    y = np.random.default_rng(5).normal(0.0, 2.0, at_once.n_unknowns)
    assert at_once.n_rows > 10 * 7
    np.testing.assert_array_equal(in_chunks.jacobian(y).toarray(), at_once.jacobian(y).toarray())


def test_the_solver_s_jacobians_share_one_buffer_and_an_old_one_used_raises(small_street):
    problem = perturbed_problem(small_street, SMALL_FIXED[1], seed=4)
    solver_problem, fresh = sparse_problem(problem, some_rows(problem)), sparse_problem(problem, some_rows(problem))
    start, moved = np.zeros(solver_problem.n_unknowns), np.random.default_rng(5).normal(0.0, 2.0, fresh.n_unknowns)
    vector = np.random.default_rng(6).normal(size=solver_problem.n_unknowns)
    first = solver_problem.jacobian_operator(start)
    second = solver_problem.jacobian_operator(moved)  # written over the first's values
    np.testing.assert_allclose(second.matvec(vector), fresh.jacobian(moved) @ vector, rtol=1e-12, atol=1e-12)
    with pytest.raises(RuntimeError, match="after asking for the next one"):
        first.matvec(vector)


def test_the_start_jacobian_handed_to_the_solver_is_the_one_evaluated_afresh_there(small_street):
    problem = perturbed_problem(small_street, SMALL_FIXED[1], seed=3)
    solver_problem = sparse_problem(problem, some_rows(problem))
    start = np.zeros(solver_problem.n_unknowns)
    handed = solver_problem.jacobian(start).toarray()  # built with the problem, then dropped
    np.testing.assert_array_equal(handed, solver_problem.jacobian(start).toarray())
    assert np.count_nonzero(handed) > 0


@pytest.mark.parametrize("row_subset", [all_rows, some_rows])
@pytest.mark.parametrize("fixed", SMALL_FIXED, ids=["first-fixed", "second-and-fourth-fixed"])
def test_sparse_jacobian_matches_central_differences_away_from_the_initial_point(small_street, fixed, row_subset):
    problem = perturbed_problem(small_street, fixed, seed=4)
    solver_problem = sparse_problem(problem, row_subset(problem))
    y = np.random.default_rng(5).normal(0.0, 2.0, solver_problem.n_unknowns)
    moved = solver_problem.residuals(y) - solver_problem.residuals(np.zeros(solver_problem.n_unknowns))
    assert np.max(np.abs(moved)) > 1.0  # a point the solver could step to, several sigmas away
    numeric = jacobian_by_central_differences(solver_problem.residuals, y)
    assert_jacobian_matches(numeric, solver_problem.jacobian(y).toarray())


def test_each_row_of_the_sparse_jacobian_touches_its_pose_and_the_world_point_it_measures(small_street):
    """Columns: 6 per free pose, then 3 per point, then 3 per line start and end (module docstring)."""
    fixed = SMALL_FIXED[1]
    problem = perturbed_problem(small_street, fixed, seed=6)
    solver_problem = sparse_problem(problem, all_rows(problem))
    jacobian = solver_problem.jacobian(np.zeros(solver_problem.n_unknowns)).toarray()
    n_pose_columns = 6 * np.count_nonzero(~fixed)
    pose_columns, landmark_columns = jacobian[:, :n_pose_columns], jacobian[:, n_pose_columns:]
    points, lines = problem.point_observations, problem.line_observations
    n_lines = len(lines.line)
    line_start = len(problem.points_w) + 2 * lines.line
    row_world_point = np.concatenate(
        [
            np.repeat(points.point, 3),
            (line_start[:, None] + [0, 1, 0, 1]).ravel(),  # vertical: left start, end, right start, end
            (line_start[:, None] + [0, 1]).ravel(),  # horizontal: start, end
        ]
    )
    row_keyframe = np.concatenate([np.repeat(points.keyframe, 3), np.repeat(lines.keyframe, 4),
                                   np.repeat(lines.keyframe, 2)])
    assert len(row_world_point) == len(jacobian) == 3 * len(points.point) + 6 * n_lines
    informative = np.any(landmark_columns != 0.0, axis=1)  # not a zero-weight row
    rows, columns = np.nonzero(landmark_columns)
    assert np.array_equal(columns // 3, row_world_point[rows])
    free_pose_block = np.cumsum(~fixed) - 1
    of_fixed_pose = fixed[row_keyframe]
    assert np.all(pose_columns[of_fixed_pose] == 0.0)
    rows, columns = np.nonzero(pose_columns)
    assert np.array_equal(columns // 6, free_pose_block[row_keyframe[rows]])
    assert np.all(np.count_nonzero(pose_columns[~of_fixed_pose & informative], axis=1) == 6)


def expected_whitened_residuals(problem: BundleProblem) -> np.ndarray:
    """Every non-zero whitened residual of the problem at its initial state, computed from first principles."""
    points, lines = problem.point_observations, problem.line_observations
    p_c = np.einsum("nij,nj->ni", problem.T_c_w[points.keyframe, :3, :3], problem.points_w[points.point])
    p_c += problem.T_c_w[points.keyframe, :3, 3]
    u = CAMERA.fx * p_c[:, 0] / p_c[:, 2] + CAMERA.cx
    v = CAMERA.fy * p_c[:, 1] / p_c[:, 2] + CAMERA.cy
    disparity = CAMERA.fx * CAMERA.baseline / p_c[:, 2]
    observed_disparity = points.stereo_px[:, 0] - points.stereo_px[:, 2]
    stereo = np.isfinite(observed_disparity)
    residuals = [
        (u - points.stereo_px[:, 0]) / points.sigma_px[:, 0],
        (v - points.stereo_px[:, 1]) / points.sigma_px[:, 1],
        (disparity - observed_disparity)[stereo] / points.sigma_px[stereo, 2],
    ]
    left_line = detected_line_coefficients(lines.start_px, lines.end_px)
    direction = detected_line_directions(lines.start_px, lines.end_px)
    known = np.all(np.isfinite(lines.right_start_px), axis=1)
    right_line = detected_line_coefficients(lines.right_start_px[known], lines.right_end_px[known])
    for endpoint, detected in ((0, lines.start_px), (1, lines.end_px)):
        ends_c = np.einsum("nij,nj->ni", problem.T_c_w[lines.keyframe, :3, :3], problem.lines_w[lines.line, endpoint])
        ends_c += problem.T_c_w[lines.keyframe, :3, 3]
        pixel = CAMERA.project(ends_c)
        right_pixel = pixel - np.column_stack([CAMERA.fx * CAMERA.baseline / ends_c[:, 2], np.zeros(len(ends_c))])
        residuals += [
            (np.sum(left_line[:, :2] * pixel, axis=1) + left_line[:, 2]) / lines.sigma_px,
            (np.sum(right_line[:, :2] * right_pixel[known], axis=1) + right_line[:, 2]) / lines.sigma_px[known],
            np.sum(direction * (pixel - detected), axis=1) / lines.sigma_px,
        ]
    residuals = np.concatenate(residuals)
    return residuals[residuals != 0.0]


def test_residuals_at_the_initial_point_are_the_whitened_point_and_line_errors(small_street):
    problem = perturbed_problem(small_street, SMALL_FIXED[0], seed=7)
    solver_problem = sparse_problem(problem, all_rows(problem))
    residuals = solver_problem.residuals(np.zeros(solver_problem.n_unknowns))
    expected = expected_whitened_residuals(problem)
    residuals = residuals[residuals != 0.0]
    assert len(residuals) == len(expected)
    assert np.allclose(np.sort(residuals), np.sort(expected), rtol=1e-9, atol=1e-9)


# bundle_adjust on the street.


def restricted(street: Street, keep_points: np.ndarray, keep_lines: np.ndarray) -> Street:
    """The street with only the landmarks ``keep_points`` (P,) and ``keep_lines`` (L,) bool, and their observations."""
    points, lines = street.point_observations, street.line_observations
    at_point, at_line = keep_points[points.point], keep_lines[lines.line]
    kept_points = {f.name: getattr(points, f.name)[at_point] for f in dataclasses.fields(points)}
    kept_lines = {f.name: getattr(lines, f.name)[at_line] for f in dataclasses.fields(lines)}
    kept_points["point"] = (np.cumsum(keep_points) - 1)[kept_points["point"]]
    kept_lines["line"] = (np.cumsum(keep_lines) - 1)[kept_lines["line"]]
    return Street(
        T_c_w=street.T_c_w,
        points_w=street.points_w[keep_points],
        lines_w=street.lines_w[keep_lines],
        point_observations=BundlePointObservations(**kept_points),
        line_observations=BundleLineObservations(**kept_lines),
    )


def seen_twice(street: Street) -> Street:
    """The street with the landmarks local BA would adjust: seen by two keyframes or more, a point at least
    once in stereo (a single view, or left images only, leaves a direction of the landmark unobserved)."""
    points, lines = street.point_observations, street.line_observations
    n_points, n_lines = len(street.points_w), len(street.lines_w)
    stereo = np.isfinite(points.stereo_px[:, 2])
    keep_points = (np.bincount(points.point, minlength=n_points) >= 2) & (
        np.bincount(points.point[stereo], minlength=n_points) >= 1
    )
    keep_lines = np.bincount(lines.line, minlength=n_lines) >= 2
    return restricted(street, keep_points, keep_lines)


@pytest.fixture(scope="module")
def street() -> Street:
    """6 keyframes, ~190 points and ~20 segments, each seen twice or more."""
    return seen_twice(make_street(seed=10, n_keyframes=6, n_points=200, n_lines=20))


FIRST_FIXED = np.array([True, False, False, False, False, False])


@pytest.fixture(scope="module")
def adjusted(street) -> tuple[BundleProblem, BundleResult]:
    """The street perturbed (poses 3-9 cm and 0.5 degrees, landmarks 0.1 m per axis) and adjusted with the defaults."""
    problem = perturbed_problem(street, FIRST_FIXED, seed=11)
    return problem, bundle_adjust(CAMERA, problem)


def test_the_street_has_enough_landmarks_and_starts_centimetres_and_half_a_degree_off(street, adjusted):
    assert len(street.points_w) > 180 and len(street.lines_w) >= 18
    problem, _ = adjusted
    translation, rotation = relative_pose_errors(problem.T_c_w, street.T_c_w)
    assert np.all(translation[1:] > 0.02) and np.allclose(np.degrees(rotation[1:]), 0.5)


def test_bundle_adjustment_brings_perturbed_poses_back_to_the_truth(street, adjusted):
    _, result = adjusted
    translation, rotation = relative_pose_errors(result.T_c_w, street.T_c_w)
    # measured: at most 7 mm and 0.025 degrees, in 14 evaluations
    assert np.all(translation < 0.02) and np.all(np.degrees(rotation) < 0.05)


def test_bundle_adjustment_brings_perturbed_points_back_to_the_truth(street, adjusted):
    problem, result = adjusted
    before = np.linalg.norm(problem.points_w - street.points_w, axis=1)
    after = np.linalg.norm(result.points_w - street.points_w, axis=1)
    # measured: median 0.15 m before, 0.045 m after (the depth of a point 40 m away is known to ~0.5 m)
    assert np.median(after) < 0.5 * np.median(before)


def test_bundle_adjustment_brings_perturbed_lines_closer_to_the_true_infinite_lines(street, adjusted):
    problem, result = adjusted

    def distances(lines_w):
        return np.concatenate([distance_to_lines(lines_w[:, k], street.lines_w) for k in range(2)])

    # measured: median 0.16 m before, 0.09 m after. Endpoints start decimetres off along their lines too,
    # where no horizontal term passes its test to hold them: they move only across their lines.
    assert np.median(distances(result.lines_w)) < 0.6 * np.median(distances(problem.lines_w))


def test_bundle_adjustment_lowers_the_cost(adjusted):
    _, result = adjusted
    assert result.final_cost < 0.05 * result.initial_cost
    assert result.nfev > 0


def test_the_fixed_pose_is_unchanged_to_the_bit_and_the_free_ones_move(adjusted):
    problem, result = adjusted
    assert np.array_equal(result.T_c_w[0], problem.T_c_w[0])
    assert not np.allclose(result.T_c_w[1:], problem.T_c_w[1:], rtol=0.0, atol=1e-4)


def test_several_fixed_poses_are_unchanged_to_the_bit_and_the_others_recovered(street):
    fixed = np.array([False, True, False, False, True, False])
    problem = perturbed_problem(street, fixed, seed=12)
    result = bundle_adjust(CAMERA, problem)
    assert np.array_equal(result.T_c_w[fixed], problem.T_c_w[fixed])
    translation, rotation = relative_pose_errors(result.T_c_w, street.T_c_w, reference=1)
    assert np.all(translation < 0.02) and np.all(np.degrees(rotation) < 0.05)


def test_the_input_problem_is_left_untouched(street):
    problem = perturbed_problem(street, FIRST_FIXED, seed=11)
    copies = [problem.T_c_w.copy(), problem.points_w.copy(), problem.lines_w.copy()]
    bundle_adjust(CAMERA, problem)
    assert all(np.array_equal(a, b) for a, b in zip(copies, [problem.T_c_w, problem.points_w, problem.lines_w]))


def test_clean_observations_are_inliers(adjusted):
    _, result = adjusted
    assert np.all(result.inliers.points) and np.all(result.inliers.lines)
    assert np.mean(result.inliers.line_horizontal) > 0.25  # endpoints that slid along their line fail it


def with_gross_outliers(street: Street, point_rows: np.ndarray, line_rows: np.ndarray) -> Street:
    """The street with the given point observations moved 50 px in the image (disparity kept), and the
    given line observations moved 50 px across their line in both images."""
    points, lines = street.point_observations, street.line_observations
    stereo_px = points.stereo_px.copy()
    stereo_px[point_rows] += [50.0, 0.0, 50.0]
    stereo_px[point_rows[1::2]] += [-100.0, 50.0, -100.0]  # half of them to the left and down
    shift = 50.0 * detected_line_coefficients(lines.start_px[line_rows], lines.end_px[line_rows])[:, :2]
    moved = {name: getattr(lines, name).copy() for name in ("start_px", "end_px", "right_start_px", "right_end_px")}
    for name in moved:
        moved[name][line_rows] += shift
    return dataclasses.replace(
        street,
        point_observations=dataclasses.replace(points, stereo_px=stereo_px),
        line_observations=dataclasses.replace(lines, **moved),
    )


def test_gross_point_outliers_come_back_as_not_inliers_and_clean_observations_stay_inliers(street):
    points = street.point_observations
    well_seen = np.flatnonzero(np.bincount(points.point)[points.point] >= 4)  # a point seen twice cannot tell
    outliers = np.random.default_rng(13).choice(well_seen, 12, replace=False)
    corrupted = with_gross_outliers(street, outliers, np.zeros(0, dtype=np.int64))
    result = bundle_adjust(CAMERA, perturbed_problem(corrupted, FIRST_FIXED, seed=11))
    assert not np.any(result.inliers.points[outliers])
    assert np.all(np.delete(result.inliers.points, outliers)) and np.all(result.inliers.lines)
    translation, rotation = relative_pose_errors(result.T_c_w, street.T_c_w)
    assert np.all(translation < 0.02) and np.all(np.degrees(rotation) < 0.05)


def test_gross_line_outliers_come_back_as_not_inliers_and_the_other_observations_of_their_lines_stay_inliers(street):
    rng = np.random.default_rng(14)
    lines = street.line_observations
    corrupted_lines = rng.permutation(len(street.lines_w))[:4]  # one outlier per line, 1 of its 5-6 observations
    outliers = np.array([rng.choice(np.flatnonzero(lines.line == line)) for line in corrupted_lines])
    corrupted = with_gross_outliers(street, np.zeros(0, dtype=np.int64), outliers)
    result = bundle_adjust(CAMERA, perturbed_problem(corrupted, FIRST_FIXED, seed=11))
    assert not np.any(result.inliers.lines[outliers]) and not np.any(result.inliers.line_horizontal[outliers])
    assert np.all(np.delete(result.inliers.lines, outliers))


def test_a_landmark_behind_a_camera_is_not_an_inlier_there(street):
    problem = perturbed_problem(street, FIRST_FIXED, seed=11)
    points_w = problem.points_w.copy()
    behind = street.point_observations.point[street.point_observations.keyframe == 5][0]
    points_w[behind] = [0.0, 0.0, -30.0]  # behind every keyframe
    result = bundle_adjust(CAMERA, dataclasses.replace(problem, points_w=points_w))
    of_behind = street.point_observations.point == behind
    assert not np.any(result.inliers.points[of_behind])
    assert np.all(result.inliers.points[~of_behind])


NO_LINES = BundleLineObservations(
    np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64), np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0),
    np.zeros(0, dtype=bool),
)


def without_lines(problem: BundleProblem) -> BundleProblem:
    return dataclasses.replace(problem, lines_w=np.zeros((0, 2, 3)), line_observations=NO_LINES)


def test_switching_both_line_terms_off_adjusts_as_if_there_were_no_lines(street, adjusted):
    problem, _ = adjusted
    lines_off = bundle_adjust(CAMERA, problem, BundleOptions(use_line_vertical=False, use_line_horizontal=False))
    no_lines = bundle_adjust(CAMERA, without_lines(problem))
    translation, rotation = relative_pose_errors(lines_off.T_c_w, street.T_c_w)
    assert np.all(translation < 0.02) and np.all(np.degrees(rotation) < 0.05)
    # measured: 1e-11 in the poses, 3e-9 m in the points
    assert np.allclose(lines_off.T_c_w, no_lines.T_c_w, rtol=0.0, atol=1e-7)
    assert np.allclose(lines_off.points_w, no_lines.points_w, rtol=0.0, atol=1e-6)
    assert np.array_equal(lines_off.inliers.points, no_lines.inliers.points) and np.all(lines_off.inliers.points)
    assert np.array_equal(lines_off.lines_w, problem.lines_w)  # nothing measures them
    assert np.all(lines_off.inliers.lines) and not np.any(lines_off.inliers.line_horizontal)


def test_costs_with_the_line_terms_off_are_those_of_the_points(adjusted):
    problem, _ = adjusted
    lines_off = bundle_adjust(CAMERA, problem, BundleOptions(use_line_vertical=False, use_line_horizontal=False))
    no_lines = bundle_adjust(CAMERA, without_lines(problem))
    assert np.isclose(lines_off.initial_cost, no_lines.initial_cost, rtol=1e-6)
    assert np.isclose(lines_off.final_cost, no_lines.final_cost, rtol=1e-6)


def test_switching_the_horizontal_term_off_keeps_the_points_and_the_vertical_terms(street, adjusted):
    problem, _ = adjusted
    result = bundle_adjust(CAMERA, problem, BundleOptions(use_line_horizontal=False))
    translation, rotation = relative_pose_errors(result.T_c_w, street.T_c_w)
    assert np.all(translation < 0.02) and np.all(np.degrees(rotation) < 0.05)
    assert result.final_cost < 0.05 * result.initial_cost
    assert np.all(result.inliers.points) and np.all(result.inliers.lines)
    assert not np.any(result.inliers.line_horizontal)
    assert not np.allclose(result.lines_w, problem.lines_w, rtol=0.0, atol=1e-3)  # the vertical terms moved them


def along_line_error(lines_w: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """(L, 2) distance [m] along each true line between estimated and true endpoints."""
    direction = truth[:, 1] - truth[:, 0]
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    return np.abs(np.einsum("lkj,lj->lk", lines_w - truth, direction))


def test_the_horizontal_term_holds_line_endpoints_where_their_observations_end(street):
    direction = street.lines_w[:, 1] - street.lines_w[:, 0]
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    slid = street.lines_w + 0.02 * direction[:, None]  # 2 cm along the line: within the horizontal gate
    problem = BundleProblem(
        street.T_c_w, FIRST_FIXED, street.points_w, slid, street.point_observations, street.line_observations
    )
    result = bundle_adjust(CAMERA, problem)
    # measured: median 2 cm; without the horizontal term the endpoints slide a median 1.3 m along their line
    assert np.median(along_line_error(result.lines_w, street.lines_w)) < 0.05
    assert np.mean(result.inliers.line_horizontal) > 0.9


def with_a_lone_monocular_point(street: Street, problem: BundleProblem, keyframe: int) -> BundleProblem:
    """``problem`` with one more point, 20 m in front of ``keyframe`` and seen by it alone, without a stereo match."""
    p_c = np.array([[3.0, -1.0, 20.0]])
    points = problem.point_observations
    observed = np.append(CAMERA.project(p_c)[0], np.nan)
    return dataclasses.replace(
        problem,
        points_w=np.vstack([problem.points_w, transform_points(inverse(street.T_c_w[keyframe]), p_c) + 0.1]),
        point_observations=BundlePointObservations(
            np.append(points.keyframe, keyframe),
            np.append(points.point, len(problem.points_w)),
            np.vstack([points.stereo_px, observed]),
            np.vstack([points.sigma_px, points.sigma_px[:1]]),
        ),
    )


def test_a_point_seen_once_without_a_stereo_match_changes_nothing_else(street, adjusted):
    problem, result = adjusted
    lone = bundle_adjust(CAMERA, with_a_lone_monocular_point(street, problem, keyframe=5))
    # the lone point can always be moved onto its observation: the other unknowns keep their optimum
    assert np.allclose(lone.T_c_w, result.T_c_w, rtol=0.0, atol=1e-3)
    assert np.allclose(lone.points_w[:-1], result.points_w, rtol=0.0, atol=1e-2)
    assert np.all(lone.inliers.points)
