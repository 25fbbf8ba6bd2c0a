"""Pose-only least squares: the left-camera pose ``T_c_w`` from landmarks of known position.

The cost is the paper's equation (Track_1): stereo point reprojection errors, line
vertical errors and line horizontal errors (the latter only for segments whose detected
endpoints are away from the image border), each weighted by its inverse covariance,
under a robust loss; solved by `scipy.optimize.least_squares` with analytic Jacobians.

Parametrisation. The unknown is a twist ``x = (rho, phi)`` (6,) around the initial pose,
``T_c_w(x) = se3_exp(x) @ T_c_w_init``. The residual Jacobians of `point_reprojection`
and `line_reprojection` are w.r.t. a left perturbation ``delta`` of ``T_c_w(x)``; since
``se3_exp(x + dx) = se3_exp(J_l(x) dx) @ se3_exp(x)`` to first order, the Jacobian w.r.t.
``x`` is theirs times the SE(3) left Jacobian ``J_l(x)`` (`pld_slam.geometry.se3.se3_left_jacobian`).

Whitening. The paper leaves the covariances open. Every observation gets an isotropic
pixel sigma, ``Sigma = sigma**2 I``, shared by all rows of its term: stereo points
``sigma = 1.2**octave`` (as ORB-SLAM2), lines a sigma per observation used for both line
terms. Residual rows and their Jacobian rows are divided by sigma, so all residuals are
in whitened (unit-variance) units.

Robust loss. A Huber loss with ``f_scale`` in whitened units, `huber_without_curvature`
(scipy's ``"huber"`` values and slopes, but the reweighting model of g2o: its docstring
says why). scipy applies the loss to each scalar residual, not to an observation's block
as g2o does, so the default scale is the 95% quantile of one degree of freedom,
``sqrt(3.841) = 1.96`` (ORB-SLAM2 puts a Huber of ``sqrt(7.815)`` on the norm of a
stereo point's 3-vector). The loss needs the trust-region method ``"trf"``; plain solves
use ``"lm"`` (`_method_settings` says why).

Inliers. After a solve every observation, used or not, is tested at the new pose: its
squared whitened norm (chi2) against the 95% chi-square quantile of its dof, 7.815 for a
stereo point (3 dof) and 5.991 for a line term (2 dof). A line failing its vertical test
is an outlier. A line passing its vertical test but failing the horizontal one keeps its
vertical term and loses only the horizontal one: the paper reserves that term for
trustworthy endpoints, and a failed test says that the endpoint (often cut short by an
occlusion), not the line, is off. `optimize_pose_rejecting_outliers` repeats the solve
over rounds as ORB-SLAM2's ``PoseOptimization`` does (4 rounds, Huber in the first 3),
except that each round starts from the previous estimate instead of the initial one, and
that rounds which would repeat a fixed point are skipped.

Speed. The tracker calls this once per frame, with a budget of ~15 ms for ~700 points
and ~100 lines (`benchmarks/pose_solver_speed.py` measures it). Each round evaluates the
rows of every observation once at its solution, for the inlier tests, and the next round
starts from that evaluation instead of computing its first one again; residuals and
Jacobian come from one evaluation per pose; the stopping tolerances are
`_STOPPING_TOLERANCES`.

Observations whose landmark lies at depth ``<= min_depth`` at the initial pose are left
out of the solve (chi2 ``inf``, outliers); one that crosses that depth during the solve
meets the clamped-depth wall of `point_reprojection`.

Failure rule. A solve is not attempted, and the initial pose comes back with a failure
status, when the included observations that project give fewer than
``min_residuals`` scalar residuals (default 12, twice the pose's 6 dof, so a fit has the
redundancy to expose one bad observation), or when their whitened Jacobian at the
initial pose is rank deficient (smallest singular value below ``rank_tolerance`` times
the largest: e.g. points all on one 3D line leave the rotation about it free). The rank
test catches exact degeneracy only: lines parallel in space with only vertical errors
leave the translation along them weak but, with noisy detections, not exactly free; the
tracker judges such poses by its inlier counts. A solve that stops at ``max_nfev`` is a
failure too.
"""

import dataclasses
import enum
from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from scipy.optimize import least_squares

from pld_slam.geometry.camera import StereoCamera
from pld_slam.geometry.se3 import se3_exp, se3_left_jacobian
from pld_slam.optim.line_reprojection import (
    LineErrorRows,
    line_horizontal_rows,
    line_row_errors,
    line_vertical_rows,
)
from pld_slam.optim.point_reprojection import MIN_DEPTH, point_reprojection_error

CHI2_95_2DOF = 5.991
"""95% quantile of the chi-square distribution with 2 dof: the test of a line term."""
CHI2_95_3DOF = 7.815
"""95% quantile of the chi-square distribution with 3 dof: the test of a stereo point."""
HUBER_SCALE = float(np.sqrt(3.841))
"""Default Huber scale [whitened units]: sqrt of the 1-dof 95% chi-square quantile."""

_STOPPING_TOLERANCES = dict(ftol=1e-5, xtol=1e-8, gtol=1e-8)
"""`least_squares` stopping rule: scipy's defaults but ``ftol``, the relative cost decrease of
the last step (which is still taken). Measured on 90 benchmark frames against a 1e-12
solve: 1e-8 (the default) and 1e-5 moved no pose by more than 0.02 um / 2.1 udeg, with 17
and 13 evaluations per call; 1e-4 saves 2 more but moved poses up to 34 um / 0.2 mdeg."""
_GRAM_RATIO_FLOOR = 1e-6
"""``s_min / s_max`` above which the Gram matrix gives it accurately (`_relative_smallest_singular_value`)."""


@dataclass(frozen=True)
class PointObservations:
    """N stereo observations of world points.

    Attributes
    ----------
    points_w : (N, 3) landmark positions in the world frame [m].
    stereo_px : (N, 3) observed ``(u_left, v, u_right)`` [px].
    sigma_px : (N,) pixel standard deviation of each observation (``1.2**octave``), or (N, 3)
        one per row ``u_left, v, u_right``.
    """

    points_w: np.ndarray
    stereo_px: np.ndarray
    sigma_px: np.ndarray

    @classmethod
    def empty(cls) -> "PointObservations":
        """No point observations."""
        return cls(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0))


@dataclass(frozen=True)
class LineObservations:
    """M observations of world segments as detected segments in the left image.

    Attributes
    ----------
    start_w, end_w : (M, 3) world endpoints ``P``, ``Q`` [m], ``P`` matched to ``start_px``.
    start_px, end_px : (M, 2) detected endpoints ``s``, ``e`` in the left image [px].
    sigma_px : (M,) pixel standard deviation of each observation, for both line terms.
    horizontal_eligible : (M,) bool, the horizontal term may be used (endpoints away from
        the border: `pld_slam.optim.line_reprojection.endpoints_away_from_border`).
    """

    start_w: np.ndarray
    end_w: np.ndarray
    start_px: np.ndarray
    end_px: np.ndarray
    sigma_px: np.ndarray
    horizontal_eligible: np.ndarray

    @classmethod
    def empty(cls) -> "LineObservations":
        """No line observations."""
        no_points, no_pixels = np.zeros((0, 3)), np.zeros((0, 2))
        return cls(no_points, no_points, no_pixels, no_pixels, np.zeros(0), np.zeros(0, dtype=bool))


@dataclass(frozen=True)
class PoseOnlyOptions:
    """Settings of the pose-only solve (the module docstring explains the choices).

    Attributes
    ----------
    use_line_vertical, use_line_horizontal : switch the two line terms (ablations).
    huber_scale : Huber ``f_scale`` [whitened units] of the robust rounds.
    chi2_point, chi2_line : chi-square inlier thresholds of a stereo point (3 dof) and of
        a line term (2 dof).
    rounds, robust_rounds : solves of `optimize_pose_rejecting_outliers`, and how many of
        the first use the Huber loss.
    max_nfev : residual evaluations allowed per solve.
    min_residuals : fewest scalar residuals a solve needs.
    rank_tolerance : relative singular-value threshold of the rank test.
    min_depth : smallest landmark depth [m] that counts as in front of the camera.
    """

    use_line_vertical: bool = True
    use_line_horizontal: bool = True
    huber_scale: float = HUBER_SCALE
    chi2_point: float = CHI2_95_3DOF
    chi2_line: float = CHI2_95_2DOF
    rounds: int = 4
    robust_rounds: int = 3
    max_nfev: int = 100
    min_residuals: int = 12
    rank_tolerance: float = 1e-9
    min_depth: float = MIN_DEPTH


@dataclass(frozen=True)
class ObservationMasks:
    """Which observations a solve uses, or which passed the chi-square tests.

    Attributes
    ----------
    points : (N,) bool, per point observation.
    lines : (M,) bool, per line observation (its vertical term, and the line as a whole).
    line_horizontal : (M,) bool, per line observation, its horizontal term.
    """

    points: np.ndarray
    lines: np.ndarray
    line_horizontal: np.ndarray

    @classmethod
    def all_usable(
        cls, points: PointObservations, lines: LineObservations, options: PoseOnlyOptions
    ) -> "ObservationMasks":
        """Every observation, and the horizontal term wherever it is eligible and switched on."""
        return cls(
            points=np.ones(len(points.sigma_px), dtype=bool),
            lines=np.ones(len(lines.sigma_px), dtype=bool),
            line_horizontal=lines.horizontal_eligible & options.use_line_horizontal,
        )


class PoseOnlyStatus(enum.Enum):
    """How a pose-only solve ended; only `CONVERGED` is a success."""

    CONVERGED = "converged"
    NOT_CONVERGED = "not_converged"
    TOO_FEW_OBSERVATIONS = "too_few_observations"
    DEGENERATE = "degenerate"


@dataclass(frozen=True)
class PoseOnlyResult:
    """The outcome of a pose-only solve.

    Attributes
    ----------
    T_c_w : (4, 4) the estimated world-to-left-camera pose (the initial one if no solve ran).
    status : how the solve ended.
    point_chi2 : (N,) squared whitened residual norm of every point observation at
        ``T_c_w``, used or not; ``inf`` where the point does not project.
    line_vertical_chi2, line_horizontal_chi2 : (M,) the same for both line terms of every
        line observation, eligible or not.
    inliers : the chi-square tests at ``T_c_w`` (module docstring).
    nfev : number of residual evaluations.
    rounds : solves run (`optimize_pose_rejecting_outliers` may run several; 0 when the
        failure rule stopped the first before it began).
    """

    T_c_w: np.ndarray
    status: PoseOnlyStatus
    point_chi2: np.ndarray
    line_vertical_chi2: np.ndarray
    line_horizontal_chi2: np.ndarray
    inliers: ObservationMasks
    nfev: int
    rounds: int = 1

    @property
    def success(self) -> bool:
        """Whether the solve converged."""
        return self.status is PoseOnlyStatus.CONVERGED


def optimize_pose(
    camera: StereoCamera,
    T_c_w_init: np.ndarray,
    points: PointObservations | None = None,
    lines: LineObservations | None = None,
    options: PoseOnlyOptions = PoseOnlyOptions(),
    include: ObservationMasks | None = None,
    robust: bool = True,
) -> PoseOnlyResult:
    """One robust least-squares solve of ``T_c_w`` (4, 4) from point and line observations.

    Parameters
    ----------
    camera : the rectified stereo camera.
    T_c_w_init : (4, 4) initial world-to-left-camera pose.
    points, lines : the observations (None: none of that kind).
    options : switches of the line terms, loss, thresholds and the failure rule.
    include : the observations to use (None: `ObservationMasks.all_usable`); a horizontal
        term is used only where it is included, eligible and switched on, and its line included.
    robust : Huber loss (True) or plain least squares (False).

    Returns
    -------
    PoseOnlyResult; on failure (module docstring) ``status`` says why.
    """
    points = PointObservations.empty() if points is None else points
    lines = LineObservations.empty() if lines is None else lines
    include = ObservationMasks.all_usable(points, lines, options) if include is None else include
    every_row = _WhitenedRows.of(points, lines, lines)
    at_init = every_row.evaluate(camera, T_c_w_init, options.min_depth)
    result, _ = _solve_round(camera, T_c_w_init, every_row, at_init, lines, options, include, robust)
    return result


def optimize_pose_rejecting_outliers(
    camera: StereoCamera,
    T_c_w_init: np.ndarray,
    points: PointObservations | None = None,
    lines: LineObservations | None = None,
    options: PoseOnlyOptions = PoseOnlyOptions(),
) -> PoseOnlyResult:
    """`optimize_pose` over up to ``options.rounds`` rounds, each using the inliers of the last.

    Round k starts from the estimate of round k - 1 with its chi-square inliers (so an
    observation rejected once may come back), with the Huber loss in the first
    ``options.robust_rounds`` rounds. A round whose inliers are the observations it used
    has reached a fixed point: the next rounds with the same loss would solve the same
    problem from its solution, so they are skipped. Stops at the first failed round and
    returns it; ``nfev`` and ``rounds`` count all rounds run. Arguments as in `optimize_pose`.
    """
    points = PointObservations.empty() if points is None else points
    lines = LineObservations.empty() if lines is None else lines
    include = ObservationMasks.all_usable(points, lines, options)
    every_row = _WhitenedRows.of(points, lines, lines)
    T_c_w, at_pose = T_c_w_init, every_row.evaluate(camera, T_c_w_init, options.min_depth)
    nfev, rounds, round_index = 0, 0, 0
    while round_index < options.rounds:
        robust = round_index < options.robust_rounds
        result, at_pose = _solve_round(camera, T_c_w, every_row, at_pose, lines, options, include, robust)
        nfev, rounds = nfev + result.nfev, rounds + result.rounds
        if not result.success:
            break
        fixed_point = _same_masks(result.inliers, include)
        T_c_w, include = result.T_c_w, result.inliers
        round_index = _first_round_with_another_loss(round_index, options) if fixed_point else round_index + 1
    return dataclasses.replace(result, nfev=nfev, rounds=rounds)


def huber_without_curvature(z: np.ndarray) -> np.ndarray:
    """Huber loss of squared scaled residuals ``z`` (m,) for `least_squares`: rows rho, rho', 0 (3, m).

    ``rho(z) = z`` for ``z <= 1``, ``2 sqrt(z) - 1`` beyond, as scipy's ``"huber"``, but with
    the second derivative reported as 0. scipy's trust-region model scales each row by
    ``sqrt(rho' + 2 z rho'')`` (Triggs' correction); beyond the scale that is
    ``sqrt(z**-0.5 - z**-0.5) = 0``, clipped to ``sqrt(EPS)``: every residual beyond the
    scale drops out of the model. From a constant-velocity guess (0.2 m / 1 deg off) most
    residuals start there, and with scipy's ``"huber"`` the first round took a median of
    15.5 evaluations (``tr_solver="exact"``) or failed to converge in 100 (``"lsmr"``).
    With rho'' = 0 the rows are scaled by ``sqrt(rho')``, the iteratively reweighted
    least-squares model of g2o (ORB-SLAM2), which is also what Ceres' Corrector does
    whenever rho'' <= 0: 5 evaluations, the same optimum (cost and gradient are unchanged).
    """
    root = np.sqrt(z)
    rho = np.zeros((3, len(z)))
    rho[0] = np.where(z <= 1.0, z, 2.0 * root - 1.0)
    rho[1] = 1.0 / np.maximum(root, 1.0)  # 1 within the scale, z**-0.5 beyond
    return rho


class _Evaluation(NamedTuple):
    """Whitened residual rows at one pose.

    residual : (K,) whitened residuals; jac_delta : (K, 6) their Jacobian w.r.t. the left
    perturbation ``delta`` of the pose; valid : (K,) bool, the row's landmark (point, or
    line endpoint) lies deeper than ``min_depth``.
    """

    residual: np.ndarray
    jac_delta: np.ndarray
    valid: np.ndarray

    def select(self, row_mask: np.ndarray) -> "_Evaluation":
        """The rows where ``row_mask`` (K,) is True."""
        return _Evaluation(self.residual[row_mask], self.jac_delta[row_mask], self.valid[row_mask])


@dataclass(frozen=True)
class _WhitenedRows:
    """The residual rows of a solve, each divided by its observation's sigma.

    Rows: 3 per point (``u_left, v, u_right``), then 2 per vertical line term, then 2 per
    horizontal line term (start, end), as `LineErrorRows`.

    Attributes
    ----------
    points_w, stereo_px : (N, 3) the points' world positions [m] and observations [px].
    point_weight : (N, 3) ``1 / sigma`` of each point's rows.
    line_rows : the 2 (Mv + Mh) whitened line rows.
    n_vertical, n_horizontal : line observations Mv, Mh in each line term.
    """

    points_w: np.ndarray
    stereo_px: np.ndarray
    point_weight: np.ndarray
    line_rows: LineErrorRows
    n_vertical: int
    n_horizontal: int

    @classmethod
    def of(
        cls, points: PointObservations, vertical_lines: LineObservations, horizontal_lines: LineObservations
    ) -> "_WhitenedRows":
        """The rows of the points and of the two line terms of the given lines."""
        vertical_rows = _whitened_line_rows(line_vertical_rows, vertical_lines)
        horizontal_rows = _whitened_line_rows(line_horizontal_rows, horizontal_lines)
        return cls(
            points.points_w,
            points.stereo_px,
            1.0 / _point_row_sigmas(points.sigma_px),
            LineErrorRows.concatenate([vertical_rows, horizontal_rows]),
            len(vertical_lines.sigma_px),
            len(horizontal_lines.sigma_px),
        )

    def row_mask(self, masks: ObservationMasks) -> np.ndarray:
        """(K,) bool, the rows of the points, vertical terms and horizontal terms selected by ``masks``.

        ``masks.lines`` selects vertical terms, ``masks.line_horizontal`` horizontal ones.
        """
        return np.concatenate(
            [np.repeat(masks.points, 3), np.repeat(masks.lines, 2), np.repeat(masks.line_horizontal, 2)]
        )

    def select(self, row_mask: np.ndarray) -> "_WhitenedRows":
        """The rows where ``row_mask`` (K,) is True (a point's or a line term's rows all or none)."""
        point_mask = row_mask[: 3 * len(self.points_w) : 3]
        line_mask = row_mask[3 * len(self.points_w) :]
        vertical_rows = 2 * self.n_vertical
        return _WhitenedRows(
            self.points_w[point_mask],
            self.stereo_px[point_mask],
            self.point_weight[point_mask],
            self.line_rows.select(line_mask),
            int(np.sum(line_mask[:vertical_rows])) // 2,
            int(np.sum(line_mask[vertical_rows:])) // 2,
        )

    def evaluate(self, camera: StereoCamera, T_c_w: np.ndarray, min_depth: float) -> _Evaluation:
        """All rows at ``T_c_w`` (4, 4)."""
        point = point_reprojection_error(camera, T_c_w, self.points_w, self.stereo_px, min_depth)
        line = line_row_errors(camera, T_c_w, self.line_rows, min_depth)
        return _Evaluation(
            residual=np.concatenate([(point.residual * self.point_weight).ravel(), line.residual]),
            jac_delta=np.concatenate([(point.jac_pose * self.point_weight[:, :, None]).reshape(-1, 6), line.jac_pose]),
            valid=np.concatenate([np.repeat(point.valid, 3), line.valid]),
        )

    def chi2(self, evaluation: _Evaluation) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Squared whitened norm of every point (N,), vertical term (Mv,) and horizontal term (Mh,).

        ``inf`` where a row's landmark does not project (depth ``<= min_depth``).
        """
        squares = np.where(evaluation.valid, evaluation.residual**2, np.inf)
        point_end = 3 * len(self.points_w)
        vertical_end = point_end + 2 * self.n_vertical
        return (
            squares[:point_end].reshape(-1, 3).sum(axis=1),
            squares[point_end:vertical_end].reshape(-1, 2).sum(axis=1),
            squares[vertical_end:].reshape(-1, 2).sum(axis=1),
        )


def _point_row_sigmas(sigma_px: np.ndarray) -> np.ndarray:
    """Sigmas (N, 3) of the ``u_left, v, u_right`` rows from one sigma per point (N,) or per row (N, 3)."""
    sigma_px = np.asarray(sigma_px, dtype=np.float64)
    per_row = sigma_px if sigma_px.ndim == 2 else sigma_px[:, None]
    return np.broadcast_to(per_row, (len(sigma_px), 3))


def _whitened_line_rows(
    rows_of: Callable[[np.ndarray, np.ndarray, np.ndarray, np.ndarray], LineErrorRows], lines: LineObservations
) -> LineErrorRows:
    """The rows of one line term (`line_vertical_rows` or `line_horizontal_rows`) divided by their sigma."""
    rows = rows_of(lines.start_w, lines.end_w, lines.start_px, lines.end_px)
    return rows.scaled(np.repeat(1.0 / lines.sigma_px, 2))


class _PoseProblem:
    """Whitened residuals (K,) and their Jacobian (K, 6) w.r.t. ``x``, ``T_c_w = se3_exp(x) @ T_c_w_init``.

    scipy asks for the residuals and then, at accepted steps, the Jacobian of the same
    ``x``: one evaluation computes both and is kept for it. ``at_init``, the evaluation
    at ``x = 0`` if the caller has it, saves the first.
    """

    def __init__(
        self,
        camera: StereoCamera,
        T_c_w_init: np.ndarray,
        rows: _WhitenedRows,
        min_depth: float,
        at_init: _Evaluation | None = None,
    ) -> None:
        self._camera = camera
        self._T_c_w_init = T_c_w_init
        self._rows = rows
        self._min_depth = min_depth
        self._cached_x = None if at_init is None else np.zeros(6)
        self._cached = at_init

    def pose(self, x: np.ndarray) -> np.ndarray:
        """``T_c_w`` (4, 4) of the twist ``x`` (6,)."""
        return se3_exp(x) @ self._T_c_w_init

    def residuals(self, x: np.ndarray) -> np.ndarray:
        """All whitened residuals (K,) at ``x`` (6,)."""
        return self._evaluate(x).residual

    def jacobian(self, x: np.ndarray) -> np.ndarray:
        """Jacobian (K, 6) of `residuals` w.r.t. ``x``: a new array (scipy scales it in place)."""
        return self._evaluate(x).jac_delta @ se3_left_jacobian(x)

    def _evaluate(self, x: np.ndarray) -> _Evaluation:
        """The rows at ``x`` (6,), computed once per ``x``."""
        if self._cached_x is None or not np.array_equal(x, self._cached_x):
            self._cached = self._rows.evaluate(self._camera, self.pose(x), self._min_depth)
            self._cached_x = np.array(x, dtype=np.float64)
        return self._cached


def _solve_round(
    camera: StereoCamera,
    T_c_w_init: np.ndarray,
    every_row: _WhitenedRows,
    at_init: _Evaluation,
    lines: LineObservations,
    options: PoseOnlyOptions,
    include: ObservationMasks,
    robust: bool,
) -> tuple[PoseOnlyResult, _Evaluation]:
    """One solve from ``T_c_w_init`` (4, 4) with the ``include``d observations.

    ``every_row`` holds the rows of every observation (both line terms of every line) and
    ``at_init`` their evaluation at ``T_c_w_init``. Returns the result and the evaluation of
    every row at its pose, which is where the next round starts.
    """
    include = _drop_not_projecting(every_row, at_init, include)
    used = every_row.row_mask(_used_terms(lines, options, include))
    problem = _PoseProblem(camera, T_c_w_init, every_row.select(used), options.min_depth, at_init.select(used))
    failure = _check_solvable(problem, options)
    if failure is not None:
        return _result_at(T_c_w_init, failure, every_row, at_init, lines, options, nfev=0, rounds=0), at_init
    solution = least_squares(
        problem.residuals,
        np.zeros(6),
        jac=problem.jacobian,
        max_nfev=options.max_nfev,
        **_STOPPING_TOLERANCES,
        **_method_settings(robust, options.huber_scale),
    )
    status = PoseOnlyStatus.CONVERGED if solution.status > 0 else PoseOnlyStatus.NOT_CONVERGED
    T_c_w = problem.pose(solution.x)
    at_solution = every_row.evaluate(camera, T_c_w, options.min_depth)
    return _result_at(T_c_w, status, every_row, at_solution, lines, options, solution.nfev, rounds=1), at_solution


def _method_settings(robust: bool, huber_scale: float) -> dict:
    """`least_squares` keywords choosing the method: robust (Huber) or plain least squares.

    A robust solve needs ``"trf"``, the one method that takes a loss; a plain one uses
    ``"lm"`` (MINPACK). Neither then runs LAPACK on the (K, 6) Jacobian: ``"trf"`` with its
    default ``tr_solver="exact"`` takes an SVD of it per iteration, and LAPACK runs on
    OpenBLAS threads, which stall when the other core is busy. Measured on 30 frames of
    the benchmark's 700 points + 100 lines with 20% outliers, median ms per
    `optimize_pose_rejecting_outliers` call with the other core idle / busy: ``"exact"``
    10.6 / 21.3, ``"lsmr"`` 12.8 / 12.4, ``"lsmr"`` and ``"lm"`` in the last round
    12.2 / 11.9 (same poses and evaluation counts).
    """
    if robust:
        return dict(method="trf", tr_solver="lsmr", loss=huber_without_curvature, f_scale=huber_scale)
    return dict(method="lm")


def _drop_not_projecting(
    every_row: _WhitenedRows, evaluation: _Evaluation, include: ObservationMasks
) -> ObservationMasks:
    """``include`` without the observations with a landmark at depth ``<= min_depth`` in ``evaluation``."""
    point_chi2, vertical_chi2, _ = every_row.chi2(evaluation)
    lines_in_front = np.isfinite(vertical_chi2)
    return ObservationMasks(
        points=include.points & np.isfinite(point_chi2),
        lines=include.lines & lines_in_front,
        line_horizontal=include.line_horizontal & lines_in_front,
    )


def _used_terms(lines: LineObservations, options: PoseOnlyOptions, include: ObservationMasks) -> ObservationMasks:
    """The points, vertical terms (``lines``) and horizontal terms (``line_horizontal``) a solve uses."""
    return ObservationMasks(
        points=include.points,
        lines=include.lines & options.use_line_vertical,
        line_horizontal=include.lines
        & include.line_horizontal
        & lines.horizontal_eligible
        & options.use_line_horizontal,
    )


def _check_solvable(problem: _PoseProblem, options: PoseOnlyOptions) -> PoseOnlyStatus | None:
    """The failure status of a problem that must not be solved (module docstring), else None."""
    x0 = np.zeros(6)
    if len(problem.residuals(x0)) < options.min_residuals:
        return PoseOnlyStatus.TOO_FEW_OBSERVATIONS
    if _relative_smallest_singular_value(problem.jacobian(x0)) <= options.rank_tolerance:
        return PoseOnlyStatus.DEGENERATE
    return None


def _relative_smallest_singular_value(jac: np.ndarray) -> float:
    """``s_min / s_max`` of a Jacobian (K, 6), from its Gram matrix where that is accurate.

    The eigenvalues of ``J^T J`` are the squared singular values up to ``~eps s_max**2``,
    so a ratio above `_GRAM_RATIO_FLOOR` is accurate to ``~eps / ratio**2`` and needs no
    SVD; below it the ratio comes from the SVD of ``J``. We avoid the SVD because LAPACK
    on a (2500, 6) matrix runs on OpenBLAS threads: with the other core busy, an SVD or
    QR took 2-4 ms on average instead of 0.1 ms; the Gram product starts no threads.
    Fewer than 6 rows: 0 (the SVD would list only K singular values).
    """
    if len(jac) < jac.shape[1]:
        return 0.0
    eigenvalues = np.linalg.eigvalsh(jac.T @ jac)
    ratio = float(np.sqrt(max(eigenvalues[0], 0.0) / eigenvalues[-1]))
    if ratio > _GRAM_RATIO_FLOOR:
        return ratio
    singular_values = np.linalg.svd(jac, compute_uv=False)
    return float(singular_values[-1] / singular_values[0])


def _same_masks(a: ObservationMasks, b: ObservationMasks) -> bool:
    """Whether two `ObservationMasks` select the same observations."""
    return all(np.array_equal(getattr(a, f.name), getattr(b, f.name)) for f in dataclasses.fields(a))


def _first_round_with_another_loss(round_index: int, options: PoseOnlyOptions) -> int:
    """The index of the first round after ``round_index`` whose loss differs from its loss.

    ``options.rounds`` when there is none: the rounds are over.
    """
    return options.robust_rounds if round_index < options.robust_rounds else options.rounds


def _result_at(
    T_c_w: np.ndarray,
    status: PoseOnlyStatus,
    every_row: _WhitenedRows,
    evaluation: _Evaluation,
    lines: LineObservations,
    options: PoseOnlyOptions,
    nfev: int,
    rounds: int,
) -> PoseOnlyResult:
    """The result at ``T_c_w``: chi2 of every observation in ``evaluation`` (of ``every_row`` there) and the inliers."""
    point_chi2, vertical_chi2, horizontal_chi2 = every_row.chi2(evaluation)
    line_inliers = vertical_chi2 <= options.chi2_line if options.use_line_vertical else np.isfinite(vertical_chi2)
    inliers = ObservationMasks(
        points=point_chi2 <= options.chi2_point,
        lines=line_inliers,
        line_horizontal=line_inliers
        & lines.horizontal_eligible
        & options.use_line_horizontal
        & (horizontal_chi2 <= options.chi2_line),
    )
    return PoseOnlyResult(T_c_w, status, point_chi2, vertical_chi2, horizontal_chi2, inliers, nfev, rounds)
