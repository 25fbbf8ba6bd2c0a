"""Pose-only least squares on synthetic scenes: accuracy, outliers, line switches, failures."""

import dataclasses

import numpy as np
import pytest
from finite_differences import CAMERA, random_points_in_view, random_pose
from scipy.optimize import least_squares

from pld_slam.config import load_config
from pld_slam.geometry.se3 import inverse, se3_exp, so3_log, transform_points
from pld_slam.optim.line_reprojection import detected_line_directions
from pld_slam.optim.observations import LineObservations, PointObservations, WhitenedRows
from pld_slam.optim.pose_only import (
    PoseOnlyOptions,
    PoseOnlyStatus,
    _PoseProblem,
    optimize_pose,
    optimize_pose_rejecting_outliers,
)
from pld_slam.optim.robust import huber_without_curvature

INITIAL_ERROR = np.array([0.15, -0.05, 0.2, 0.02, -0.03, 0.015])  # ~2 degrees and 25 cm


def observe_points(rng: np.random.Generator, T_c_w: np.ndarray, n: int, noise_px: float) -> PointObservations:
    """Stereo observations of n world points in view, declared sigma 1 px.

    Noise as the cost models it (`pld_slam.optim.observations`): std ``noise_px`` on the
    corner ``(u_left, v)``, and an independent one of the same std on the disparity.
    """
    points_w = random_points_in_view(rng, T_c_w, n)
    exact = CAMERA.project_stereo(transform_points(T_c_w, points_w))
    corner = rng.normal(0.0, noise_px, (n, 2))
    disparity = exact[:, 0] - exact[:, 2] + rng.normal(0.0, noise_px, n)
    stereo_px = np.column_stack([exact[:, :2] + corner, exact[:, 0] + corner[:, 0] - disparity])
    return PointObservations(points_w, stereo_px, np.ones(n))


def random_segments_in_view(
    rng: np.random.Generator, T_c_w: np.ndarray, n: int
) -> tuple[np.ndarray, np.ndarray]:
    """World endpoints (n, 3) x 2 of 1-4 m segments with random directions, both ends in front."""
    start_c = rng.uniform([-6.0, -2.0, 5.0], [6.0, 2.0, 30.0], size=(n, 3))
    direction = rng.normal(size=(n, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    end_c = start_c + rng.uniform(1.0, 4.0, (n, 1)) * direction
    end_c[:, 2] = np.maximum(end_c[:, 2], 3.0)
    T_w_c = inverse(T_c_w)
    return transform_points(T_w_c, start_c), transform_points(T_w_c, end_c)


def observe_segments(
    rng: np.random.Generator, T_c_w: np.ndarray, start_w: np.ndarray, end_w: np.ndarray, noise_px: float
) -> LineObservations:
    """Detected endpoints = projected endpoints plus Gaussian noise; all eligible for the horizontal term."""
    n = len(start_w)
    start_px = CAMERA.project(transform_points(T_c_w, start_w)) + rng.normal(0.0, noise_px, (n, 2))
    end_px = CAMERA.project(transform_points(T_c_w, end_w)) + rng.normal(0.0, noise_px, (n, 2))
    return LineObservations(start_w, end_w, start_px, end_px, np.ones(n), np.ones(n, dtype=bool))


def observe_lines(rng: np.random.Generator, T_c_w: np.ndarray, n: int, noise_px: float) -> LineObservations:
    """Observations of n random segments in view."""
    return observe_segments(rng, T_c_w, *random_segments_in_view(rng, T_c_w, n), noise_px)


def slide_endpoints_along(lines: LineObservations, rows: np.ndarray, slide_px: float) -> LineObservations:
    """The observations with the detected endpoints of ``rows`` slid ``slide_px`` outwards along the line."""
    direction = detected_line_directions(lines.start_px, lines.end_px)
    start_px, end_px = lines.start_px.copy(), lines.end_px.copy()
    start_px[rows] -= slide_px * direction[rows]
    end_px[rows] += slide_px * direction[rows]
    return dataclasses.replace(lines, start_px=start_px, end_px=end_px)


def pose_errors(T_est: np.ndarray, T_true: np.ndarray) -> tuple[float, float]:
    """Camera-centre distance [m] and rotation angle [rad] of ``T_est`` relative to ``T_true``."""
    T_diff = T_est @ inverse(T_true)
    return float(np.linalg.norm(inverse(T_diff)[:3, 3])), float(np.linalg.norm(so3_log(T_diff[:3, :3])))


def perturbed(T_c_w: np.ndarray) -> np.ndarray:
    """The initial guess: ``T_c_w`` moved by `INITIAL_ERROR`."""
    return se3_exp(INITIAL_ERROR) @ T_c_w


def test_solver_jacobian_matches_central_differences_away_from_the_initial_pose():
    rng = np.random.default_rng(5)
    T_true = random_pose(rng)
    points, lines = observe_points(rng, T_true, 20, 1.0), observe_lines(rng, T_true, 10, 1.0)
    problem = _PoseProblem(CAMERA, perturbed(T_true), WhitenedRows.of(points, lines, lines), min_depth=1e-3)
    x, h = rng.normal(0.0, 0.05, 6), 1e-6
    numeric = np.column_stack(
        [
            (problem.residuals(x + h * axis) - problem.residuals(x - h * axis)) / (2.0 * h)
            for axis in np.eye(6)
        ]
    )
    assert np.allclose(numeric, problem.jacobian(x), rtol=0.0, atol=1e-6 * np.abs(numeric).max())


def test_huber_without_curvature_is_the_huber_loss_with_its_slope():
    z = np.array([0.0, 0.25, 1.0, 4.0, 100.0])
    h = 1e-6
    rho = huber_without_curvature(z)
    slope = (huber_without_curvature(z + h)[0] - huber_without_curvature(np.maximum(z - h, 0.0))[0]) / (
        z + h - np.maximum(z - h, 0.0)
    )
    assert np.allclose(rho[0], [0.0, 0.25, 1.0, 3.0, 19.0])
    assert np.allclose(rho[1], slope, atol=1e-6) and np.all(rho[2] == 0.0)


def test_huber_without_curvature_has_the_optimum_of_scipys_huber():
    rng = np.random.default_rng(7)
    T_true = random_pose(rng)
    points, lines = observe_points(rng, T_true, 100, 1.0), observe_lines(rng, T_true, 30, 1.0)
    problem = _PoseProblem(CAMERA, T_true, WhitenedRows.of(points, lines, lines), min_depth=1e-3)
    solutions = [
        least_squares(problem.residuals, np.zeros(6), jac=problem.jacobian, loss=loss, f_scale=2.0, ftol=1e-12).x
        for loss in ("huber", huber_without_curvature)
    ]
    assert np.allclose(solutions[0], solutions[1], rtol=0.0, atol=1e-9)


def chi2_at(T_c_w: np.ndarray, points: PointObservations) -> tuple[np.ndarray, np.ndarray]:
    """Each point's chi2 at ``T_c_w`` and its inlier test, without solving."""
    rows = WhitenedRows.of(points, LineObservations.empty(), LineObservations.empty())
    point_chi2, _, _ = rows.chi2(rows.evaluate(CAMERA, T_c_w, T_c_w, 1e-3))
    options = PoseOnlyOptions()
    return point_chi2, rows.point_inliers(point_chi2, options.chi2_point, options.chi2_monocular_point)


def test_chi2_is_the_squared_whitened_norm_of_the_image_and_disparity_errors():
    """A stereo point's rows are u_left / sigma, v / sigma and (u_left - u_right) / sigma_d."""
    rng = np.random.default_rng(6)
    T_true = random_pose(rng)
    points = observe_points(rng, T_true, 15, 0.0)
    stereo_px = points.stereo_px.copy()
    stereo_px[:5] += [6.0, -8.0, 6.0]  # 10 px off in the image, the disparity kept
    stereo_px[5:10, 2] += 1.0  # the disparity 1 px short, the left pixel kept
    points = dataclasses.replace(points, stereo_px=stereo_px, sigma_px=np.tile([2.0, 2.0, 0.5], (15, 1)))
    point_chi2, inliers = chi2_at(T_true, points)
    np.testing.assert_allclose(point_chi2, [25.0] * 5 + [4.0] * 5 + [0.0] * 5, atol=1e-9)
    assert inliers.tolist() == [False] * 5 + [True] * 10


def test_a_point_without_u_right_is_a_monocular_observation_with_a_two_dof_bound():
    rng = np.random.default_rng(7)
    T_true = random_pose(rng)
    points = observe_points(rng, T_true, 9, 0.0)
    stereo_px = points.stereo_px.copy()
    stereo_px[:, 0] += np.repeat([2.6, 2.2, 0.0], 3)  # chi2 6.76, 4.84, 0
    stereo_px[:6, 2] = np.nan  # the first six seen in the left image only
    point_chi2, inliers = chi2_at(T_true, dataclasses.replace(points, stereo_px=stereo_px))
    np.testing.assert_allclose(point_chi2, np.repeat([2.6**2, 2.2**2, 0.0], 3), atol=1e-9)
    # 6.76 fails the 2-dof bound 5.991; a stereo point with the same error would pass 7.815.
    assert inliers.tolist() == [False] * 3 + [True] * 6


def test_monocular_points_alone_fix_the_pose():
    rng = np.random.default_rng(8)
    T_true = random_pose(rng)
    points = observe_points(rng, T_true, 60, 0.0)
    stereo_px = points.stereo_px.copy()
    stereo_px[:, 2] = np.nan
    monocular = dataclasses.replace(points, stereo_px=stereo_px)
    result = optimize_pose_rejecting_outliers(CAMERA, perturbed(T_true), monocular)
    assert result.success and result.inliers.points.all()
    translation, rotation = pose_errors(result.T_c_w, T_true)
    assert translation < 1e-6 and rotation < 1e-8


@pytest.mark.parametrize("seed", range(3))
def test_noise_free_points_give_the_exact_pose(seed):
    rng = np.random.default_rng(seed)
    T_true = random_pose(rng)
    result = optimize_pose(CAMERA, perturbed(T_true), observe_points(rng, T_true, 50, noise_px=0.0))
    assert result.status is PoseOnlyStatus.CONVERGED and result.success
    translation, rotation = pose_errors(result.T_c_w, T_true)
    assert translation < 1e-8 and rotation < 1e-9


@pytest.mark.parametrize("seed", range(3))
def test_noisy_points_recover_the_pose(seed):
    rng = np.random.default_rng(seed)
    T_true = random_pose(rng)
    result = optimize_pose(CAMERA, perturbed(T_true), observe_points(rng, T_true, 200, noise_px=1.0))
    translation, rotation = pose_errors(result.T_c_w, T_true)
    assert result.success and translation < 0.02 and rotation < np.radians(0.05)
    assert np.mean(result.inliers.points) > 0.85


def test_the_solve_stops_at_the_configured_cost_tolerance():
    """``tracking.pose_cost_tolerance`` (`PoseOnlyOptions.of`): a looser one stops the solve sooner, a
    tighter one later."""
    rng = np.random.default_rng(0)
    T_true = random_pose(rng)
    points = observe_points(rng, T_true, 200, noise_px=1.0)
    nfev = {}
    for tolerance in ("1.0e-1", None, "1.0e-10"):
        config = load_config(overrides=[] if tolerance is None else [f"tracking.pose_cost_tolerance={tolerance}"])
        nfev[tolerance] = optimize_pose(CAMERA, perturbed(T_true), points, options=PoseOnlyOptions.of(config)).nfev
    assert nfev["1.0e-1"] < nfev[None] < nfev["1.0e-10"]


@pytest.mark.parametrize("seed", range(3))
def test_noisy_points_and_lines_recover_the_pose(seed):
    rng = np.random.default_rng(seed)
    T_true = random_pose(rng)
    points, lines = observe_points(rng, T_true, 100, 1.0), observe_lines(rng, T_true, 60, 1.0)
    result = optimize_pose(CAMERA, perturbed(T_true), points, lines)
    translation, rotation = pose_errors(result.T_c_w, T_true)
    assert result.success and translation < 0.02 and rotation < np.radians(0.05)
    assert np.mean(result.inliers.lines) > 0.85 and np.mean(result.inliers.line_horizontal) > 0.75


@pytest.mark.parametrize("use_horizontal", [False, True])
@pytest.mark.parametrize("seed", range(3))
def test_lines_alone_recover_the_pose(seed, use_horizontal):
    rng = np.random.default_rng(seed)
    T_true = random_pose(rng)
    options = PoseOnlyOptions(use_line_horizontal=use_horizontal)
    result = optimize_pose(
        CAMERA, perturbed(T_true), lines=observe_lines(rng, T_true, 80, 1.0), options=options
    )
    translation, rotation = pose_errors(result.T_c_w, T_true)
    assert result.success and translation < 0.03 and rotation < np.radians(0.1)
    assert np.any(result.inliers.line_horizontal) == use_horizontal


@pytest.mark.parametrize("seed", range(3))
def test_rejection_rounds_flag_twenty_percent_gross_outliers(seed):
    rng = np.random.default_rng(seed)
    T_true = random_pose(rng)
    points, lines = observe_points(rng, T_true, 150, 1.0), observe_lines(rng, T_true, 60, 1.0)
    point_outliers = rng.permutation(150)[:30]
    shifted_px = points.stereo_px.copy()
    shifted_px[point_outliers] += rng.choice([-1.0, 1.0], (30, 3)) * rng.uniform(15.0, 60.0, (30, 3))
    line_outliers = rng.permutation(60)[:12]
    direction = detected_line_directions(lines.start_px, lines.end_px)[line_outliers]
    offset = (
        rng.choice([-1.0, 1.0], (12, 1)) * rng.uniform(20.0, 60.0, (12, 1)) * direction[:, ::-1] * [-1.0, 1.0]
    )
    moved_start, moved_end = lines.start_px.copy(), lines.end_px.copy()
    moved_start[line_outliers] += offset  # across the line: an outlier of the vertical error
    moved_end[line_outliers] += offset
    points = dataclasses.replace(points, stereo_px=shifted_px)
    lines = dataclasses.replace(lines, start_px=moved_start, end_px=moved_end)

    result = optimize_pose_rejecting_outliers(CAMERA, perturbed(T_true), points, lines)

    translation, rotation = pose_errors(result.T_c_w, T_true)
    assert result.success and translation < 0.03 and rotation < np.radians(0.1)
    assert not np.any(result.inliers.points[point_outliers])
    assert not np.any(result.inliers.lines[line_outliers])
    assert np.mean(np.delete(result.inliers.points, point_outliers)) > 0.85
    assert np.mean(np.delete(result.inliers.lines, line_outliers)) > 0.85


def test_the_rounds_and_evaluations_are_the_configured_ones():
    """``tracking.pose_rounds``, ``tracking.pose_robust_rounds`` and ``tracking.pose_max_nfev`` reach the solve
    (`PoseOnlyOptions.of`): 20 % gross outliers take the default four rounds, one when asked; a plain first
    round ends elsewhere; two evaluations are too few to converge."""
    rng = np.random.default_rng(0)
    T_true = random_pose(rng)
    points = observe_points(rng, T_true, 150, 1.0)
    outliers = rng.permutation(150)[:30]
    shifted_px = points.stereo_px.copy()
    shifted_px[outliers] += rng.choice([-1.0, 1.0], (30, 3)) * rng.uniform(15.0, 60.0, (30, 3))
    points = dataclasses.replace(points, stereo_px=shifted_px)

    def solved(*overrides: str):
        options = PoseOnlyOptions.of(load_config(overrides=[f"tracking.{override}" for override in overrides]))
        return optimize_pose_rejecting_outliers(CAMERA, perturbed(T_true), points, options=options)

    default = solved()
    assert default.success and default.rounds == 4
    assert solved("pose_rounds=1").rounds == 1
    assert not np.array_equal(solved("pose_robust_rounds=0").T_c_w, default.T_c_w)
    assert not solved("pose_max_nfev=2").success


def test_rounds_skipped_at_a_fixed_point_do_not_change_the_result():
    rng = np.random.default_rng(10)
    T_true = random_pose(rng)
    points = observe_points(rng, T_true, 100, 0.5)
    stereo_px = points.stereo_px.copy()
    stereo_px[:10] += 40.0
    points = dataclasses.replace(points, stereo_px=stereo_px)
    result = optimize_pose_rejecting_outliers(CAMERA, perturbed(T_true), points)
    options, T_c_w, include = PoseOnlyOptions(), perturbed(T_true), None
    for round_index in range(options.rounds):
        every_round = optimize_pose(CAMERA, T_c_w, points, None, options, include, round_index < options.robust_rounds)
        T_c_w, include = every_round.T_c_w, every_round.inliers
    assert result.success and result.rounds < options.rounds
    translation, rotation = pose_errors(result.T_c_w, every_round.T_c_w)
    assert translation < 1e-7 and rotation < 1e-8
    assert np.array_equal(result.inliers.points, every_round.inliers.points)


def test_a_line_with_bad_endpoints_keeps_its_vertical_term_and_loses_the_horizontal():
    rng = np.random.default_rng(11)
    T_true = random_pose(rng)
    points, lines = observe_points(rng, T_true, 100, 1.0), observe_lines(rng, T_true, 40, 1.0)
    cut = np.arange(8)
    lines = slide_endpoints_along(lines, cut, slide_px=30.0)
    result = optimize_pose_rejecting_outliers(CAMERA, perturbed(T_true), points, lines)
    assert result.success
    assert np.all(result.inliers.lines[cut]) and not np.any(result.inliers.line_horizontal[cut])


def test_switching_the_horizontal_term_off_ignores_endpoints_along_the_line():
    rng = np.random.default_rng(12)
    T_true = random_pose(rng)
    lines = slide_endpoints_along(observe_lines(rng, T_true, 60, 0.0), np.arange(60), slide_px=25.0)
    result = optimize_pose(
        CAMERA, perturbed(T_true), lines=lines, options=PoseOnlyOptions(use_line_horizontal=False)
    )
    translation, rotation = pose_errors(result.T_c_w, T_true)
    assert result.success and translation < 1e-7 and rotation < 1e-8


def test_too_few_observations_fail_and_return_the_initial_pose():
    rng = np.random.default_rng(13)
    T_true = random_pose(rng)
    T_init = perturbed(T_true)
    for points, lines in (
        (observe_points(rng, T_true, 3, 1.0), None),
        (None, None),
        (None, observe_lines(rng, T_true, 2, 1.0)),
    ):
        result = optimize_pose_rejecting_outliers(CAMERA, T_init, points, lines)
        assert result.status is PoseOnlyStatus.TOO_FEW_OBSERVATIONS and not result.success
        assert np.array_equal(result.T_c_w, T_init) and result.nfev == 0


def test_points_behind_the_camera_do_not_count_towards_the_minimum():
    rng = np.random.default_rng(14)
    T_true = random_pose(rng)
    points = observe_points(rng, T_true, 6, 1.0)
    behind = transform_points(
        inverse(T_true), transform_points(T_true, points.points_w[:3]) * [1.0, 1.0, -1.0]
    )
    points = dataclasses.replace(points, points_w=np.vstack([behind, points.points_w[3:]]))
    result = optimize_pose(CAMERA, T_true, points)
    assert result.status is PoseOnlyStatus.TOO_FEW_OBSERVATIONS
    assert np.all(np.isinf(result.point_chi2[:3])) and not np.any(result.inliers.points[:3])


def test_points_on_one_3d_line_are_degenerate():
    rng = np.random.default_rng(15)
    T_true = random_pose(rng)
    along = rng.uniform(0.0, 10.0, (20, 1))
    on_line_c = np.array([[-3.0, 1.0, 6.0]]) + along * np.array([[0.6, -0.1, 0.8]])
    points = PointObservations(
        transform_points(inverse(T_true), on_line_c), CAMERA.project_stereo(on_line_c), np.ones(20)
    )
    result = optimize_pose_rejecting_outliers(CAMERA, perturbed(T_true), points)
    assert result.status is PoseOnlyStatus.DEGENERATE and not result.success
    assert np.array_equal(result.T_c_w, perturbed(T_true))
