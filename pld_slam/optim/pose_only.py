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

Whitening. The residual rows are those of `pld_slam.optim.observations`, shared with
bundle adjustment: each divided by its observation's pixel sigma (the paper leaves the
covariances open; that module says what we chose), so all residuals are in whitened
(unit-variance) units.

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
over rounds as ORB-SLAM2's ``PoseOptimization`` does (``tracking.pose_rounds`` (4) rounds,
Huber in the first ``tracking.pose_robust_rounds`` (3)), except that each round starts
from the previous estimate instead of the initial one, and that rounds which would repeat
a fixed point are skipped.

Speed. The tracker calls this once per frame, with a budget of ~15 ms for ~700 points
and ~100 lines (`benchmarks/pose_solver_speed.py` measures it). Each round evaluates the
rows of every observation once at its solution, for the inlier tests, and the next round
starts from that evaluation instead of computing its first one again; residuals and
Jacobian come from one evaluation per pose; the stopping tolerances are
`_STOPPING_TOLERANCES` and ``PoseOnlyOptions.ftol``. The rows are evaluated by the numba kernel of
`pld_slam.optim.point_reprojection` (issue 8). Most of what remains is `least_squares`'s
own work. The paper leaves the solver open; we take ``"trf"``'s exact step for robust
rounds and ``"lm"`` for plain ones because, with OpenBLAS single-threaded, they are the
fastest for the same poses (`_method_settings`; the measurements, taken at different
times: docs/decisions/0013-pose-only-solver.md).

Observations whose landmark lies at depth ``<= min_depth`` at the initial pose are left
out of the solve (chi2 ``inf``, outliers); one that crosses that depth during the solve
meets the clamped-depth wall of `point_reprojection`.

Failure rule. A solve is not attempted, and the initial pose comes back with a failure
status, when the included observations that project give fewer than
``min_residuals`` informative scalar residuals (rows of zero weight, such as the
disparity row of a point without a stereo match, do not count; default 12, twice the
pose's 6 dof, so a fit has the redundancy to expose one bad observation), or when their whitened Jacobian at the
initial pose is rank deficient (smallest singular value below ``rank_tolerance`` times
the largest: e.g. points all on one 3D line leave the rotation about it free). The rank
test catches exact degeneracy only: lines parallel in space with only vertical errors
leave the translation along them weak but, with noisy detections, not exactly free; the
tracker judges such poses by its inlier counts. A solve that stops at ``max_nfev``
(``tracking.pose_max_nfev``, 100) is a failure too.
"""

import dataclasses
import enum
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from pld_slam.config import Config, TrackingConfig
from pld_slam.geometry.camera import StereoCamera
from pld_slam.geometry.se3 import se3_exp, se3_left_jacobian
from pld_slam.optim.observations import (
    LineObservations,
    ObservationMasks,
    PointObservations,
    ResidualOptions,
    RowEvaluation,
    WhitenedRows,
    chi2_inliers,
    used_terms,
)
from pld_slam.optim.robust import huber_without_curvature

_STOPPING_TOLERANCES = dict(xtol=1e-8, gtol=1e-8)
"""`least_squares` stopping rule: scipy's defaults but ``ftol`` (`PoseOnlyOptions.ftol`)."""
_GRAM_RATIO_FLOOR = 1e-6
"""``s_min / s_max`` above which the Gram matrix gives it accurately (`_relative_smallest_singular_value`)."""


@dataclass(frozen=True)
class PoseOnlyOptions(ResidualOptions):
    """Settings of the pose-only solve (the module docstring explains the choices): those every
    solver shares (`ResidualOptions`), and the following.

    Attributes
    ----------
    rounds, robust_rounds : solves of `optimize_pose_rejecting_outliers`, and how many of
        the first use the Huber loss.
    max_nfev : residual evaluations allowed per solve.
    min_residuals : fewest scalar residuals a solve needs.
    rank_tolerance : relative singular-value threshold of the rank test.
    ftol : `least_squares`' relative cost decrease of the last step (which is still taken) at
        which a solve stops; default ``tracking.pose_cost_tolerance``'s: 1e-5 moves no pose
        measurably against scipy's 1e-8 for fewer evaluations, 1e-4 moves them more
        (docs/decisions/0013-pose-only-solver.md).
    """

    rounds: int = TrackingConfig.pose_rounds
    robust_rounds: int = TrackingConfig.pose_robust_rounds
    max_nfev: int = TrackingConfig.pose_max_nfev
    min_residuals: int = 12
    rank_tolerance: float = 1e-9
    ftol: float = TrackingConfig.pose_cost_tolerance

    @classmethod
    def of(cls, config: Config) -> "PoseOnlyOptions":
        """The solve ``config`` sets: the two line terms (``lines.vertical_error``,
        ``lines.horizontal_error``), the rounds, evaluations and cost tolerance (``tracking.pose_rounds``,
        ``tracking.pose_robust_rounds``, ``tracking.pose_max_nfev``, ``tracking.pose_cost_tolerance``)."""
        tracking = config.tracking
        return cls(use_line_vertical=config.lines.vertical_error, use_line_horizontal=config.lines.horizontal_error,
                   rounds=tracking.pose_rounds, robust_rounds=tracking.pose_robust_rounds,
                   max_nfev=tracking.pose_max_nfev, ftol=tracking.pose_cost_tolerance)


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
    include = ObservationMasks.all_usable(points, lines, options.use_line_horizontal) if include is None else include
    every_row = WhitenedRows.of(points, lines, lines)
    at_init = every_row.evaluate(camera, T_c_w_init, T_c_w_init, options.min_depth)
    result, _ = _solve_round(camera, T_c_w_init, every_row, at_init, lines, options, include, robust)
    return result


def optimize_pose_rejecting_outliers(
    camera: StereoCamera,
    T_c_w_init: np.ndarray,
    points: PointObservations | None = None,
    lines: LineObservations | None = None,
    options: PoseOnlyOptions = PoseOnlyOptions(),
    within: ObservationMasks | None = None,
) -> PoseOnlyResult:
    """`optimize_pose` over up to ``options.rounds`` rounds, each using the inliers of the last.

    Round k starts from the estimate of round k - 1 with its chi-square inliers (so an
    observation rejected once may come back), with the Huber loss in the first
    ``options.robust_rounds`` rounds. A round whose inliers are the observations it used
    has reached a fixed point: the next rounds with the same loss would solve the same
    problem from its solution, so they are skipped. Stops at the first failed round and
    returns it; ``nfev`` and ``rounds`` count all rounds run. ``within``: the only
    observations any round may use (None: all); the result's inliers are among them.
    Other arguments as in `optimize_pose`.
    """
    points = PointObservations.empty() if points is None else points
    lines = LineObservations.empty() if lines is None else lines
    allowed = ObservationMasks.all_usable(points, lines, options.use_line_horizontal)
    if within is not None:
        allowed = allowed & within
    include = allowed
    every_row = WhitenedRows.of(points, lines, lines)
    T_c_w, at_pose = T_c_w_init, every_row.evaluate(camera, T_c_w_init, T_c_w_init, options.min_depth)
    nfev, rounds, round_index = 0, 0, 0
    while round_index < options.rounds:
        robust = round_index < options.robust_rounds
        result, at_pose = _solve_round(camera, T_c_w, every_row, at_pose, lines, options, include, robust)
        nfev, rounds = nfev + result.nfev, rounds + result.rounds
        if not result.success:
            break
        inliers = result.inliers & allowed
        fixed_point = _same_masks(inliers, include)
        T_c_w, include = result.T_c_w, inliers
        round_index = _first_round_with_another_loss(round_index, options) if fixed_point else round_index + 1
    return dataclasses.replace(result, nfev=nfev, rounds=rounds, inliers=result.inliers & allowed)


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
        rows: WhitenedRows,
        min_depth: float,
        at_init: RowEvaluation | None = None,
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
        return self._evaluate(x).jac_pose @ se3_left_jacobian(x)

    def _evaluate(self, x: np.ndarray) -> RowEvaluation:
        """The rows at ``x`` (6,), computed once per ``x``."""
        if self._cached_x is None or not np.array_equal(x, self._cached_x):
            pose = self.pose(x)
            self._cached = self._rows.evaluate(self._camera, pose, pose, self._min_depth)
            self._cached_x = np.array(x, dtype=np.float64)
        return self._cached


def _solve_round(
    camera: StereoCamera,
    T_c_w_init: np.ndarray,
    every_row: WhitenedRows,
    at_init: RowEvaluation,
    lines: LineObservations,
    options: PoseOnlyOptions,
    include: ObservationMasks,
    robust: bool,
) -> tuple[PoseOnlyResult, RowEvaluation]:
    """One solve from ``T_c_w_init`` (4, 4) with the ``include``d observations.

    ``every_row`` holds the rows of every observation (both line terms of every line) and
    ``at_init`` their evaluation at ``T_c_w_init``. Returns the result and the evaluation of
    every row at its pose, which is where the next round starts.
    """
    include = _drop_not_projecting(every_row, at_init, include)
    used = every_row.row_mask(used_terms(include, lines.horizontal_eligible, options))
    problem = _PoseProblem(camera, T_c_w_init, every_row.select(used), options.min_depth, at_init.select(used))
    failure = _check_solvable(problem, options)
    if failure is not None:
        return _result_at(T_c_w_init, failure, every_row, at_init, lines, options, nfev=0, rounds=0), at_init
    solution = least_squares(
        problem.residuals,
        np.zeros(6),
        jac=problem.jacobian,
        max_nfev=options.max_nfev,
        ftol=options.ftol,
        **_STOPPING_TOLERANCES,
        **_method_settings(robust, options.huber_scale),
    )
    status = PoseOnlyStatus.CONVERGED if solution.status > 0 else PoseOnlyStatus.NOT_CONVERGED
    T_c_w = problem.pose(solution.x)
    at_solution = every_row.evaluate(camera, T_c_w, T_c_w, options.min_depth)
    return _result_at(T_c_w, status, every_row, at_solution, lines, options, solution.nfev, rounds=1), at_solution


def _method_settings(robust: bool, huber_scale: float) -> dict:
    """`least_squares` keywords choosing the method: robust (Huber) or plain least squares.

    A robust solve needs ``"trf"``, the one method that takes a loss, here with its
    default ``tr_solver="exact"`` (an SVD of the (K, 6) Jacobian per iteration); a plain
    one uses ``"lm"`` (MINPACK). ``"lsmr"`` was used while LAPACK ran on OpenBLAS's
    threads, which stall when the other core is busy; with OpenBLAS single-threaded
    (`pld_slam`'s default) the exact step is faster for the same rounds, evaluations and
    errors (docs/decisions/0013-pose-only-solver.md).
    """
    if robust:
        return dict(method="trf", tr_solver="exact", loss=huber_without_curvature, f_scale=huber_scale)
    return dict(method="lm")


def _drop_not_projecting(
    every_row: WhitenedRows, evaluation: RowEvaluation, include: ObservationMasks
) -> ObservationMasks:
    """``include`` without the observations with a landmark at depth ``<= min_depth`` in ``evaluation``."""
    point_chi2, vertical_chi2, _ = every_row.chi2(evaluation)
    lines_in_front = np.isfinite(vertical_chi2)
    return ObservationMasks(
        points=include.points & np.isfinite(point_chi2),
        lines=include.lines & lines_in_front,
        line_horizontal=include.line_horizontal & lines_in_front,
    )


def _check_solvable(problem: _PoseProblem, options: PoseOnlyOptions) -> PoseOnlyStatus | None:
    """The failure status of a problem that must not be solved (module docstring), else None."""
    x0 = np.zeros(6)
    jacobian = problem.jacobian(x0)
    if np.count_nonzero(np.any(jacobian != 0.0, axis=1)) < options.min_residuals:
        return PoseOnlyStatus.TOO_FEW_OBSERVATIONS
    if _relative_smallest_singular_value(jacobian) <= options.rank_tolerance:
        return PoseOnlyStatus.DEGENERATE
    return None


def _relative_smallest_singular_value(jac: np.ndarray) -> float:
    """``s_min / s_max`` of a Jacobian (K, 6), from its Gram matrix where that is accurate.

    The eigenvalues of ``J^T J`` are the squared singular values up to ``~eps s_max**2``,
    so a ratio above `_GRAM_RATIO_FLOOR` is accurate to ``~eps / ratio**2`` and needs no
    SVD; below it the ratio comes from the SVD of ``J``. We avoid the SVD because LAPACK
    on a tall matrix runs on OpenBLAS threads, which stall with the other core busy; the
    Gram product starts no threads (docs/decisions/0013-pose-only-solver.md).
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
    every_row: WhitenedRows,
    evaluation: RowEvaluation,
    lines: LineObservations,
    options: PoseOnlyOptions,
    nfev: int,
    rounds: int,
) -> PoseOnlyResult:
    """The result at ``T_c_w``: chi2 of every observation in ``evaluation`` (of ``every_row`` there) and the inliers."""
    point_chi2, vertical_chi2, horizontal_chi2 = every_row.chi2(evaluation)
    inliers = chi2_inliers(every_row, point_chi2, vertical_chi2, horizontal_chi2, lines.horizontal_eligible,
                           options)
    return PoseOnlyResult(T_c_w, status, point_chi2, vertical_chi2, horizontal_chi2, inliers, nfev, rounds)
