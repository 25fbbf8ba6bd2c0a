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

Robust loss. scipy's ``"huber"`` loss with ``f_scale`` in whitened units. scipy applies
the loss to each scalar residual, not to an observation's block as g2o does, so the
default scale is the 95% quantile of one degree of freedom, ``sqrt(3.841) = 1.96``
(ORB-SLAM2 puts a Huber of ``sqrt(7.815)`` on the norm of a stereo point's 3-vector).
The loss needs the trust-region method ``"trf"`` (``"lm"`` takes no loss).

Inliers. After a solve every observation, used or not, is tested at the new pose: its
squared whitened norm (chi2) against the 95% chi-square quantile of its dof, 7.815 for a
stereo point (3 dof) and 5.991 for a line term (2 dof). A line failing its vertical test
is an outlier. A line passing its vertical test but failing the horizontal one keeps its
vertical term and loses only the horizontal one: the paper reserves that term for
trustworthy endpoints, and a failed test says that the endpoint (often cut short by an
occlusion), not the line, is off. `optimize_pose_rejecting_outliers` repeats the solve
over rounds as ORB-SLAM2's ``PoseOptimization`` does (4 rounds, Huber in the first 3),
except that each round starts from the previous estimate instead of the initial one.

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
from dataclasses import dataclass
from typing import NamedTuple, TypeVar

import numpy as np
from scipy.optimize import least_squares

from pld_slam.geometry.camera import StereoCamera
from pld_slam.geometry.se3 import se3_exp, se3_left_jacobian
from pld_slam.optim.line_reprojection import LineReprojection, line_horizontal_error, line_vertical_error
from pld_slam.optim.point_reprojection import (
    MIN_DEPTH,
    PointReprojection,
    point_reprojection_error,
    project_stereo_with_jacobians,
)

CHI2_95_2DOF = 5.991
"""95% quantile of the chi-square distribution with 2 dof: the test of a line term."""
CHI2_95_3DOF = 7.815
"""95% quantile of the chi-square distribution with 3 dof: the test of a stereo point."""
HUBER_SCALE = float(np.sqrt(3.841))
"""Default Huber scale [whitened units]: sqrt of the 1-dof 95% chi-square quantile."""

_SMALL_ANGLE = 1e-2  # [rad]: below it, Q(rho, phi) takes its Taylor series (the closed form loses digits)


@dataclass(frozen=True)
class PointObservations:
    """N stereo observations of world points.

    Attributes
    ----------
    points_w : (N, 3) landmark positions in the world frame [m].
    stereo_px : (N, 3) observed ``(u_left, v, u_right)`` [px].
    sigma_px : (N,) pixel standard deviation of each observation (``1.2**octave``).
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
    """

    T_c_w: np.ndarray
    status: PoseOnlyStatus
    point_chi2: np.ndarray
    line_vertical_chi2: np.ndarray
    line_horizontal_chi2: np.ndarray
    inliers: ObservationMasks
    nfev: int

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
    include = _drop_not_projecting(camera, T_c_w_init, points, lines, include, options.min_depth)
    problem = _PoseProblem(
        camera, T_c_w_init, *_used_observations(points, lines, options, include), options.min_depth
    )
    failure = _check_solvable(problem, options)
    if failure is not None:
        return _result_at(camera, T_c_w_init, failure, points, lines, options, nfev=0)
    solution = least_squares(
        problem.residuals,
        np.zeros(6),
        jac=problem.jacobian,
        method="trf",
        loss="huber" if robust else "linear",
        f_scale=options.huber_scale,
        max_nfev=options.max_nfev,
    )
    status = PoseOnlyStatus.CONVERGED if solution.status > 0 else PoseOnlyStatus.NOT_CONVERGED
    return _result_at(camera, problem.pose(solution.x), status, points, lines, options, solution.nfev)


def optimize_pose_rejecting_outliers(
    camera: StereoCamera,
    T_c_w_init: np.ndarray,
    points: PointObservations | None = None,
    lines: LineObservations | None = None,
    options: PoseOnlyOptions = PoseOnlyOptions(),
) -> PoseOnlyResult:
    """`optimize_pose` over ``options.rounds`` rounds, each using the inliers of the last.

    Round k starts from the estimate of round k - 1 with its chi-square inliers (so an
    observation rejected once may come back), with the Huber loss in the first
    ``options.robust_rounds`` rounds. Stops at the first failed round and returns it;
    ``nfev`` counts all rounds. Arguments as in `optimize_pose`.
    """
    points = PointObservations.empty() if points is None else points
    lines = LineObservations.empty() if lines is None else lines
    include = ObservationMasks.all_usable(points, lines, options)
    T_c_w, nfev = T_c_w_init, 0
    for round_index in range(options.rounds):
        result = optimize_pose(
            camera, T_c_w, points, lines, options, include, robust=round_index < options.robust_rounds
        )
        nfev += result.nfev
        if not result.success:
            break
        T_c_w, include = result.T_c_w, result.inliers
    return dataclasses.replace(result, nfev=nfev)


class _WhitenedTerm(NamedTuple):
    """One error term of n observations in whitened units: residual (n, k), jac_pose (n, k, 6), valid (n,)."""

    residual: np.ndarray
    jac_pose: np.ndarray
    valid: np.ndarray

    def chi2(self) -> np.ndarray:
        """Squared whitened norm (n,) of each observation; ``inf`` where it does not project."""
        return np.where(self.valid, np.sum(self.residual**2, axis=1), np.inf)


def _whitened_terms(
    camera: StereoCamera,
    T_c_w: np.ndarray,
    points: PointObservations,
    vertical_lines: LineObservations,
    horizontal_lines: LineObservations,
    min_depth: float,
) -> tuple[_WhitenedTerm, _WhitenedTerm, _WhitenedTerm]:
    """The point, line vertical and line horizontal terms at ``T_c_w``, each divided by its sigma."""
    point = point_reprojection_error(camera, T_c_w, points.points_w, points.stereo_px, min_depth)
    vertical = line_vertical_error(
        camera,
        T_c_w,
        vertical_lines.start_w,
        vertical_lines.end_w,
        vertical_lines.start_px,
        vertical_lines.end_px,
        min_depth,
    )
    horizontal = line_horizontal_error(
        camera,
        T_c_w,
        horizontal_lines.start_w,
        horizontal_lines.end_w,
        horizontal_lines.start_px,
        horizontal_lines.end_px,
        min_depth,
    )
    return (
        _whiten(point, points.sigma_px),
        _whiten(vertical, vertical_lines.sigma_px),
        _whiten(horizontal, horizontal_lines.sigma_px),
    )


def _whiten(error: PointReprojection | LineReprojection, sigma_px: np.ndarray) -> _WhitenedTerm:
    """A `PointReprojection` or `LineReprojection` with residual and pose Jacobian divided by sigma (n,)."""
    return _WhitenedTerm(
        error.residual / sigma_px[:, None], error.jac_pose / sigma_px[:, None, None], error.valid
    )


class _PoseProblem:
    """Whitened residuals and their Jacobian w.r.t. ``x``, ``T_c_w = se3_exp(x) @ T_c_w_init``.

    Residuals and Jacobian of the same ``x`` are evaluated once (scipy asks for both).
    """

    def __init__(
        self,
        camera: StereoCamera,
        T_c_w_init: np.ndarray,
        points: PointObservations,
        vertical_lines: LineObservations,
        horizontal_lines: LineObservations,
        min_depth: float,
    ) -> None:
        self._camera = camera
        self._T_c_w_init = T_c_w_init
        self._observations = (points, vertical_lines, horizontal_lines)
        self._min_depth = min_depth
        self._cached_x: np.ndarray | None = None
        self._cached_terms: tuple[_WhitenedTerm, ...] = ()

    def pose(self, x: np.ndarray) -> np.ndarray:
        """``T_c_w`` (4, 4) of the twist ``x`` (6,)."""
        return se3_exp(x) @ self._T_c_w_init

    def terms(self, x: np.ndarray) -> tuple[_WhitenedTerm, ...]:
        """The whitened terms at ``x`` (6,)."""
        if self._cached_x is None or not np.array_equal(x, self._cached_x):
            self._cached_terms = _whitened_terms(
                self._camera, self.pose(x), *self._observations, self._min_depth
            )
            self._cached_x = np.array(x, dtype=np.float64)
        return self._cached_terms

    def residuals(self, x: np.ndarray) -> np.ndarray:
        """All whitened residuals (K,) at ``x`` (6,)."""
        return np.concatenate([term.residual.ravel() for term in self.terms(x)])

    def jacobian(self, x: np.ndarray) -> np.ndarray:
        """Jacobian (K, 6) of `residuals` w.r.t. ``x``."""
        jac_delta = np.concatenate([term.jac_pose.reshape(-1, 6) for term in self.terms(x)])
        return jac_delta @ se3_left_jacobian(x)


def _drop_not_projecting(
    camera: StereoCamera,
    T_c_w: np.ndarray,
    points: PointObservations,
    lines: LineObservations,
    include: ObservationMasks,
    min_depth: float,
) -> ObservationMasks:
    """``include`` without the observations with a landmark at depth ``<= min_depth`` at ``T_c_w``."""

    def in_front(points_w: np.ndarray) -> np.ndarray:
        return project_stereo_with_jacobians(camera, T_c_w, points_w, min_depth).valid

    lines_in_front = in_front(lines.start_w) & in_front(lines.end_w)
    return ObservationMasks(
        points=include.points & in_front(points.points_w),
        lines=include.lines & lines_in_front,
        line_horizontal=include.line_horizontal & lines_in_front,
    )


def _used_observations(
    points: PointObservations, lines: LineObservations, options: PoseOnlyOptions, include: ObservationMasks
) -> tuple[PointObservations, LineObservations, LineObservations]:
    """The point, vertical-line and horizontal-line observations a solve uses."""
    vertical = include.lines & options.use_line_vertical
    horizontal = (
        include.lines & include.line_horizontal & lines.horizontal_eligible & options.use_line_horizontal
    )
    return _select(points, include.points), _select(lines, vertical), _select(lines, horizontal)


_Observations = TypeVar("_Observations", PointObservations, LineObservations)


def _select(observations: _Observations, mask: np.ndarray) -> _Observations:
    """The observations (a `PointObservations` or `LineObservations`) where ``mask`` is True."""
    return type(observations)(
        *(getattr(observations, f.name)[mask] for f in dataclasses.fields(observations))
    )


def _check_solvable(problem: _PoseProblem, options: PoseOnlyOptions) -> PoseOnlyStatus | None:
    """The failure status of a problem that must not be solved (module docstring), else None."""
    x0 = np.zeros(6)
    if len(problem.residuals(x0)) < options.min_residuals:
        return PoseOnlyStatus.TOO_FEW_OBSERVATIONS
    singular_values = np.linalg.svd(problem.jacobian(x0), compute_uv=False)
    if singular_values[-1] <= options.rank_tolerance * singular_values[0]:
        return PoseOnlyStatus.DEGENERATE
    return None


def _result_at(
    camera: StereoCamera,
    T_c_w: np.ndarray,
    status: PoseOnlyStatus,
    points: PointObservations,
    lines: LineObservations,
    options: PoseOnlyOptions,
    nfev: int,
) -> PoseOnlyResult:
    """The result at ``T_c_w``: chi2 of every observation and the chi-square inlier masks."""
    point, vertical, horizontal = _whitened_terms(camera, T_c_w, points, lines, lines, options.min_depth)
    point_chi2, vertical_chi2, horizontal_chi2 = point.chi2(), vertical.chi2(), horizontal.chi2()
    line_inliers = vertical_chi2 <= options.chi2_line if options.use_line_vertical else vertical.valid
    inliers = ObservationMasks(
        points=point_chi2 <= options.chi2_point,
        lines=line_inliers,
        line_horizontal=line_inliers
        & lines.horizontal_eligible
        & options.use_line_horizontal
        & (horizontal_chi2 <= options.chi2_line),
    )
    return PoseOnlyResult(T_c_w, status, point_chi2, vertical_chi2, horizontal_chi2, inliers, nfev)
