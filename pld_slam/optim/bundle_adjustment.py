"""Sparse bundle adjustment: keyframe poses, map points and map lines optimised together.

The cost is the pose-only cost (`pose_only`) summed over keyframes, with the landmarks
free too: the whitened rows of `observations` (stereo point reprojection, line vertical
and horizontal errors, the horizontal one only where the detected endpoints are away
from the border) under the Huber loss of `robust`. Local BA (`pld_slam.mapping.local_ba`)
and the final global BA build a `BundleProblem` and call `bundle_adjust`.

Unknowns. ``x`` holds a twist (6) per free pose, ``T_c_w = se3_exp(x_k) @ T_c_w_init``
as in `pose_only`, then a shift (3) per point and per line endpoint (a line is its two
endpoints, `pld_slam.mapping.landmarks`). Poses marked ``fixed`` are not unknowns; the
caller fixes at least one to remove the gauge freedom.

Preconditioning. A BA Jacobian is ill-conditioned block by block (a landmark's depth
against its lateral position, a pose's translation against its rotation), which column
scaling cannot fix, and LSMR then needs many iterations per step, most of local BA's time.
The solver's unknowns are therefore whitened block by block (`_whitening`), the
block-Jacobi preconditioner applied as a change of variables
(docs/decisions/0011-bundle-adjustment-solver.md).

Jacobian. Every row depends on one pose and one world point (a map point, or the line
endpoint the row measures): 6 + 3 non-zeros, or 3 when its pose is fixed. The column
indices of each row are the same at every evaluation, so the CSR structure is built once
per solve and only its values are filled at each evaluation, from the residuals'
analytic Jacobians (times the SE(3) left Jacobian for the twists): no dense Jacobian and
no finite differences. `scipy.optimize.least_squares` solves it with ``method="trf"``
and ``tr_solver="lsmr"`` (the one combination that takes a sparse Jacobian), the unknowns
scaled by the Jacobian's column norms at the solve's start: columns differ by orders of
magnitude (a pose twist moves every observation of a keyframe, a point shift three
rows), and scaling by column norms is what makes LSMR converge in few iterations.

Memory. The Jacobian reaches the solver as a `LinearOperator` over our CSR matrix, with
the column norms as a fixed ``x_scale``, rather than as the matrix with ``x_scale="jac"``
(norms updated at every step): given a matrix, `least_squares` copies it at every
evaluation, squares a copy for the norms and transposes another for LSMR: on a long run
global BA's memory was most of the run's peak
(docs/decisions/0011-bundle-adjustment-solver.md). No evaluation of every row is held with
its Jacobians: the chi-square tests and the solver's trial steps evaluate residuals only;
a solve evaluates its rows' Jacobians at its start, hands that matrix to the solver and
drops them, and later Jacobians are evaluated `JACOBIAN_CHUNK_ROWS` rows at a time; the
rows are evaluated from their pose and world point indices and axes made once per problem
(`_BundleRows`), a solve keeps the indices of its rows rather than copies of them, and the
CSR structure and column norms are filled by kernels without (R, 9) temporaries, and each
Jacobian handed to the solver is written over the one before
(`_SparseProblem.jacobian_operator`).

Speed (issue 8). The rows are one numba kernel (`pld_slam.optim.point_reprojection`), the
Jacobian's values are filled by `_fill_jacobian_values` into int32 CSR indices, and a
solve evaluates its rows with Jacobians once at its start, for the whitening, the column
scale and the solver's first Jacobian. What remains is `least_squares` itself, mostly
LSMR's sparse products. With the unknowns block-whitened, ``x_scale=1.0`` moved poses
within the stopping tolerance and was not taken (the profile:
docs/decisions/0011-bundle-adjustment-solver.md).

Line endpoints. The horizontal error assumes that an observation's detected endpoints are
the map line's endpoints; a segment seen shorter or longer (occlusion, LSD cutting it
elsewhere) breaks that, and its horizontal error cannot be met by any geometry. Under the
Huber loss such a term still pulls linearly and can throw an endpoint hundreds of metres
away (docs/decisions/0011-bundle-adjustment-solver.md). A horizontal term enters the solve
only where it passes its chi-square test at the start, at the tracked poses; the vertical
error (distance to the infinite line) has no such assumption and always enters.

Rounds, as ORB-SLAM2's ``LocalBundleAdjustment``: a robust solve; the observations that
fail their chi-square test at its solution (or whose landmark lies behind the camera)
are left out of a second, plain solve; every observation is then tested at the result,
and `BundleResult.inliers` tells the caller which to drop from the map.
"""

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares
from scipy.sparse import csr_matrix
from scipy.sparse.linalg import LinearOperator

from pld_slam.config import MappingConfig
from pld_slam.geometry.camera import StereoCamera
from pld_slam.geometry.se3 import se3_exp, se3_left_jacobian
from pld_slam.jit import kernel
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
from pld_slam.optim.point_reprojection import stereo_row_errors
from pld_slam.optim.robust import huber_without_curvature

_STOPPING_TOLERANCES = dict(xtol=1e-8, gtol=1e-8)
"""`least_squares`' step and gradient tolerances; its cost tolerance is `BundleOptions.ftol`."""

TO_CONVERGENCE = dict(ftol=1e-6, lsmr_max_iterations=100)
"""`BundleOptions` fields that solve a problem to its optimum instead of refining it. The drift
of a long trajectory is a problem's flattest direction, and steps of
``mapping.ba_lsmr_iterations`` (10) stopped at a ``mapping.ba_cost_tolerance`` (0.1 %) gain
leave it nearly untouched (docs/decisions/0011-bundle-adjustment-solver.md;
`benchmarks/ba_truth.py` solves this way)."""


@dataclass(frozen=True)
class BundlePointObservations:
    """M stereo observations of map points by keyframes.

    Attributes
    ----------
    keyframe : (M,) int64 index of the observing pose in `BundleProblem.T_c_w`.
    point : (M,) int64 index of the observed point in `BundleProblem.points_w`.
    stereo_px : (M, 3) observed ``(u_left, v, u_right)`` [px], ``u_right`` NaN without a stereo match.
    sigma_px : (M,) or (M, 3) sigmas of each observation, as `pld_slam.optim.observations.PointObservations`.
    """

    keyframe: np.ndarray
    point: np.ndarray
    stereo_px: np.ndarray
    sigma_px: np.ndarray


@dataclass(frozen=True)
class BundleLineObservations:
    """N observations of map lines by keyframes, as detected left-image segments.

    Attributes
    ----------
    keyframe : (N,) int64 index of the observing pose.
    line : (N,) int64 index of the observed line in `BundleProblem.lines_w`.
    start_px, end_px : (N, 2) detected endpoints [px], ``start_px`` matched to the line's start.
    sigma_px : (N,) pixel sigma of each observation.
    horizontal_eligible : (N,) bool, the horizontal term may be used.
    right_start_px, right_end_px : (N, 2) the segment in the right image, or None
        (`pld_slam.optim.observations.LineObservations`).
    """

    keyframe: np.ndarray
    line: np.ndarray
    start_px: np.ndarray
    end_px: np.ndarray
    sigma_px: np.ndarray
    horizontal_eligible: np.ndarray
    right_start_px: np.ndarray | None = None
    right_end_px: np.ndarray | None = None


@dataclass(frozen=True)
class BundleProblem:
    """A bundle adjustment problem.

    Attributes
    ----------
    T_c_w : (K, 4, 4) initial world-to-camera poses.
    fixed : (K,) bool, poses held fixed.
    points_w : (P, 3) initial map points [m].
    lines_w : (L, 2, 3) initial map lines, start and end [m].
    point_observations, line_observations : the observations.
    """

    T_c_w: np.ndarray
    fixed: np.ndarray
    points_w: np.ndarray
    lines_w: np.ndarray
    point_observations: BundlePointObservations
    line_observations: BundleLineObservations


@dataclass(frozen=True)
class BundleOptions(ResidualOptions):
    """Settings of `bundle_adjust`: those every solver shares (`ResidualOptions`), and the following.

    Attributes
    ----------
    max_nfev : residual evaluations allowed per round.
    ftol, lsmr_max_iterations : `least_squares`' relative cost tolerance, and the LSMR iterations
        allowed per step (each step is then an inexact Gauss-Newton step, which the trust region
        accepts or shrinks like any other). The defaults, those of ``mapping.ba_cost_tolerance``
        (0.1 %) and ``mapping.ba_lsmr_iterations`` (10), refine a map that tracking already put
        near its optimum, as local and global BA do: a tighter stop, or uncapped steps spending
        their iterations on the last digits of a step the next evaluation corrects anyway, cost
        time for the same trajectory (docs/decisions/0011-bundle-adjustment-solver.md).
        `TO_CONVERGENCE` solves to the optimum.
    """

    max_nfev: int = 10
    ftol: float = MappingConfig.ba_cost_tolerance
    lsmr_max_iterations: int = MappingConfig.ba_lsmr_iterations


@dataclass(frozen=True)
class BundleResult:
    """The outcome of `bundle_adjust`.

    Attributes
    ----------
    T_c_w : (K, 4, 4) optimised poses (fixed ones unchanged).
    points_w : (P, 3) and lines_w : (L, 2, 3) optimised landmarks.
    inliers : per observation, the chi-square tests at the result (``lines`` the vertical
        term and the line as a whole, ``line_horizontal`` its horizontal term).
    initial_cost, final_cost : half the sum of squared whitened residuals of the
        observations of the final inlier set, before and after [whitened units].
    nfev : residual evaluations of both rounds.
    """

    T_c_w: np.ndarray
    points_w: np.ndarray
    lines_w: np.ndarray
    inliers: ObservationMasks
    initial_cost: float
    final_cost: float
    nfev: int


def bundle_adjust(
    camera: StereoCamera, problem: BundleProblem, options: BundleOptions = BundleOptions()
) -> BundleResult:
    """Optimise poses, points and lines of ``problem``: a robust round, then a plain one without outliers.

    Returns the optimised geometry and the observations that pass their chi-square test
    at it (module docstring).
    """
    every_row = _BundleRows.of(problem, options)
    state = _State.initial(problem)
    at_state = every_row.evaluate(camera, state, options.min_depth, with_jacobians=False)
    start_residual = at_state.residual
    include = every_row.usable(at_state)
    nfev = 0
    for robust in (True, False):
        state, solve_nfev = _solve(camera, every_row, state, include, robust, options)
        nfev += solve_nfev
        at_state = every_row.evaluate(camera, state, options.min_depth, with_jacobians=False)
        include = every_row.inliers(at_state, options) if robust else include
    inliers = every_row.inliers(at_state, options)
    used = every_row.row_mask(used_terms(inliers, every_row.horizontal_eligible, options))
    return BundleResult(
        T_c_w=state.T_c_w,
        points_w=state.points_w,
        lines_w=state.lines_w,
        inliers=inliers,
        initial_cost=_half_squared_sum(start_residual[used]),
        final_cost=_half_squared_sum(at_state.residual[used]),
        nfev=nfev,
    )


@dataclass(frozen=True)
class _State:
    """Poses (K, 4, 4), points (P, 3) and lines (L, 2, 3) at one point of the solve."""

    T_c_w: np.ndarray
    points_w: np.ndarray
    lines_w: np.ndarray

    @classmethod
    def initial(cls, problem: BundleProblem) -> "_State":
        return cls(problem.T_c_w.copy(), problem.points_w.copy(), problem.lines_w.copy())

    @property
    def world_points(self) -> np.ndarray:
        """Every point of the state (P + 2 L, 3): the points, then each line's start and end."""
        return np.concatenate([self.points_w, self.lines_w.reshape(-1, 3)])


@dataclass(frozen=True)
class _BundleRows:
    """Every residual row of a problem, and what each row depends on.

    Rows are those of `WhitenedRows` (3 per point observation, 2 per vertical term, 2 per
    horizontal term). ``row_pose`` (R,) is the pose of each row; ``row_world_point`` (R,)
    the index of the world point it measures in `_State.world_points`; ``row_axes`` (R, 3)
    and ``row_offsets`` (R,) the rows as `stereo_row_errors` evaluates them
    (`WhitenedRows.stacked_axes`, made once per problem); ``fixed_pose`` (K,) the poses held
    fixed.
    """

    rows: WhitenedRows
    row_pose: np.ndarray
    row_world_point: np.ndarray
    row_axes: np.ndarray
    row_offsets: np.ndarray
    fixed_pose: np.ndarray
    horizontal_eligible: np.ndarray
    options: BundleOptions

    @classmethod
    def of(cls, problem: BundleProblem, options: BundleOptions) -> "_BundleRows":
        points, lines = problem.point_observations, problem.line_observations
        n_points = len(problem.points_w)
        line_observations = LineObservations(
            start_w=problem.lines_w[lines.line, 0],
            end_w=problem.lines_w[lines.line, 1],
            start_px=lines.start_px,
            end_px=lines.end_px,
            sigma_px=lines.sigma_px,
            horizontal_eligible=lines.horizontal_eligible,
            right_start_px=lines.right_start_px,
            right_end_px=lines.right_end_px,
        )
        rows = WhitenedRows.of(
            PointObservations(problem.points_w[points.point], points.stereo_px, points.sigma_px),
            line_observations,
            line_observations,
        )
        start_end = n_points + 2 * lines.line[:, None] + np.arange(2)  # (N, 2) world points of each line
        vertical_endpoint = np.tile(start_end, 2).ravel()  # left start, end, right start, end
        row_axes, row_offsets = rows.stacked_axes()
        return cls(
            rows=rows,
            row_axes=row_axes,
            row_offsets=row_offsets,
            row_pose=np.concatenate(
                [np.repeat(points.keyframe, 3), np.repeat(lines.keyframe, 4), np.repeat(lines.keyframe, 2)]
            ),
            row_world_point=np.concatenate([np.repeat(points.point, 3), vertical_endpoint, start_end.ravel()]),
            fixed_pose=np.asarray(problem.fixed, dtype=bool),
            horizontal_eligible=lines.horizontal_eligible,
            options=options,
        )

    def row_mask(self, masks: ObservationMasks) -> np.ndarray:
        """(R,) bool, the rows of the observations and line terms that ``masks`` selects."""
        return self.rows.row_mask(masks)

    @property
    def row_is_horizontal(self) -> np.ndarray:
        """(R,) bool, the rows of horizontal line terms (the last ``2 Mh``)."""
        flags = np.zeros(len(self.row_pose), dtype=bool)
        flags[len(flags) - 2 * self.rows.n_horizontal :] = True
        return flags

    def evaluate(self, camera: StereoCamera, state: _State, min_depth: float,
                 with_jacobians: bool = True, rows: slice | np.ndarray = slice(None)) -> RowEvaluation:
        """The rows ``rows`` (a slice or row indices; every row by default) at ``state``, without
        Jacobians residuals and validity only: the rows of `WhitenedRows.evaluate`, each
        measuring its pose and world point by index."""
        errors = stereo_row_errors(camera, state.T_c_w, state.world_points, self.row_axes[rows], self.row_offsets[rows],
                                   min_depth, self.row_pose[rows], with_jacobians, self.row_world_point[rows])
        return RowEvaluation(errors.residual, errors.jac_pose, errors.jac_point, errors.valid)

    def usable(self, evaluation: RowEvaluation) -> ObservationMasks:
        """Every observation whose landmark projects (``lines``: the observation, whose vertical term
        `used_terms` switches); a horizontal term only where it is switched on and passes its
        chi-square test at the start (module docstring)."""
        point_chi2, vertical_chi2, horizontal_chi2 = self.rows.chi2(evaluation)
        in_front = np.isfinite(vertical_chi2)
        corresponding = horizontal_chi2 <= self.options.chi2_line
        return ObservationMasks(
            points=np.isfinite(point_chi2),
            lines=in_front,
            line_horizontal=in_front & self.horizontal_eligible & self.options.use_line_horizontal & corresponding,
        )

    def inliers(self, evaluation: RowEvaluation, options: BundleOptions) -> ObservationMasks:
        """The observations passing their chi-square tests (`chi2_inliers`)."""
        return chi2_inliers(self.rows, *self.rows.chi2(evaluation), self.horizontal_eligible, options)


def _solve(
    camera: StereoCamera,
    every_row: _BundleRows,
    state: _State,
    include: ObservationMasks,
    robust: bool,
    options: BundleOptions,
) -> tuple[_State, int]:
    """One `least_squares` solve over the included rows from ``state``; the new state and its nfev."""
    used = every_row.row_mask(used_terms(include, every_row.horizontal_eligible, options))
    problem = _SparseProblem(camera, every_row, state, used)
    if problem.n_rows == 0:
        return state, 0
    loss = dict(loss=huber_without_curvature, f_scale=options.huber_scale) if robust else {}
    solution = least_squares(
        problem.residuals,
        np.zeros(problem.n_unknowns),
        jac=problem.jacobian_operator,
        method="trf",
        tr_solver="lsmr",
        tr_options=dict(maxiter=options.lsmr_max_iterations),
        x_scale=problem.column_scale,
        max_nfev=options.max_nfev,
        ftol=options.ftol,
        **_STOPPING_TOLERANCES,
        **loss,
    )
    return problem.state(solution.x), solution.nfev


JACOBIAN_CHUNK_ROWS = 1 << 16
"""Rows whose Jacobians `_SparseProblem.jacobian` holds at once: a local BA's rows in one go, a
global BA's in pieces of 5 MB instead of all rows' (81 bytes each)."""


class _SparseProblem:
    """The included rows of a problem as a function of block-whitened unknowns ``y``, with their sparse Jacobian.

    The unknowns of the module docstring are ``x``; the solver sees ``y``, with ``x_b = W_b y_b``
    for each block ``b`` (a free pose's twist, a world point's shift) and ``W_b`` fixed for the
    solve (`_whitening`). The Jacobian w.r.t. ``y`` is the one w.r.t. ``x`` with each
    block's columns multiplied by its ``W_b``: still analytic and as sparse.
    """

    def __init__(self, camera: StereoCamera, every_row: _BundleRows, start: _State, row_mask: np.ndarray,
                 chunk_rows: int = JACOBIAN_CHUNK_ROWS) -> None:
        """The rows of ``every_row`` where ``row_mask`` (R,), from ``start``; `jacobian` evaluates
        ``chunk_rows`` rows at a time."""
        self._camera = camera
        self._chunk_rows = chunk_rows
        self._every_row = every_row
        self._row_ids = np.flatnonzero(row_mask)
        """(R,) the included rows of ``every_row``: indices, not copies of their data (memory: global BA)."""
        self._start = start
        self._min_depth = every_row.options.min_depth
        self._free = np.flatnonzero(~every_row.fixed_pose)
        n_free = len(self._free)
        free_index = np.full(len(start.T_c_w), -1)
        free_index[self._free] = np.arange(n_free)
        self._n_pose_unknowns = 6 * n_free
        self.n_unknowns = self._n_pose_unknowns + 3 * len(start.world_points)
        self.n_rows = int(row_mask.sum())
        self._row_free_pose = free_index[every_row.row_pose[row_mask]]
        """(R,) the free pose of each row (its index among the free poses), -1 for a fixed one."""
        self._row_world_point = every_row.row_world_point[row_mask]
        self._indptr = np.empty(self.n_rows + 1, dtype=np.int32)
        self._indices = np.empty(int(9 * self.n_rows - 6 * np.count_nonzero(self._row_free_pose < 0)), dtype=np.int32)
        """CSR structure in scipy's index type: given int64, every `csr_matrix` built from it
        checked and converted it (0.14 ms of the 0.16 ms construction at 21,000 rows)."""
        _fill_csr_structure(self._row_free_pose, self._row_world_point, self._n_pose_unknowns, self._indptr,
                            self._indices)
        at_start = every_row.evaluate(camera, start, self._min_depth, rows=self._row_ids)
        rows_of_pose = [np.flatnonzero(self._row_free_pose == pose) for pose in range(n_free)]
        self._pose_whitening = _whitening(_pose_grams(at_start.jac_pose, rows_of_pose))
        pinned = np.zeros(len(start.world_points), dtype=bool)
        pinned[every_row.row_world_point[row_mask & every_row.row_is_horizontal]] = True
        self._point_whitening = _whitening(
            _block_grams(at_start.jac_landmark, self._row_world_point, len(start.world_points)),
            _held_directions(start, pinned),
        )
        self._cached_y, self._cached_residual = np.zeros(self.n_unknowns), at_start.residual
        self._solver_values: np.ndarray | None = None
        """The values (nnz,) of the last Jacobian handed to the solver, written over by the next
        (`jacobian_operator`)."""
        self._solver_generation = 0
        self._jacobian_at_start: csr_matrix | None = self._jacobian_of(at_start, np.zeros(self.n_unknowns))
        """Handed to the solver's first Jacobian call and then dropped (memory: global BA)."""
        del at_start  # its Jacobians are in the CSR matrix now
        norms = np.sqrt(_column_square_sums(self._indices, self._jacobian_at_start.data, self.n_unknowns))
        self.column_scale = 1.0 / np.where(norms > 0.0, norms, 1.0)
        """The unknowns' scales (n_unknowns,) for ``x_scale``: the inverse column norms of the Jacobian at
        the start (1 for a column without entries), as ``x_scale="jac"`` takes them at its first step."""

    def state(self, y: np.ndarray) -> _State:
        """Poses and landmarks at ``y``."""
        return self._state_at(self._x_of(y))

    def residuals(self, y: np.ndarray) -> np.ndarray:
        """Whitened residuals (R,) at ``y``, evaluated without Jacobians (the solver's trial steps
        need none) and kept for a second call at the same ``y``."""
        if not np.array_equal(y, self._cached_y):
            state, residual = self.state(y), np.empty(self.n_rows)
            for rows in self._chunks():
                residual[rows] = self._evaluate(state, rows, with_jacobians=False).residual
            self._cached_y, self._cached_residual = np.array(y, dtype=np.float64), residual
        return self._cached_residual

    def jacobian(self, y: np.ndarray, into: np.ndarray | None = None) -> csr_matrix:
        """Sparse Jacobian (R, n_unknowns) of `residuals` w.r.t. ``y`` (`_jacobian_of`), its rows
        evaluated `JACOBIAN_CHUNK_ROWS` at a time (memory: global BA), its values written into
        ``into`` (nnz,) when given."""
        if self._jacobian_at_start is not None and not y.any():
            jac, self._jacobian_at_start = self._jacobian_at_start, None
            return jac
        state, pose_blocks = self.state(y), self._pose_blocks(y)
        values = np.empty(len(self._indices)) if into is None else into
        for rows in self._chunks():
            self._fill_values(self._evaluate(state, rows, with_jacobians=True), pose_blocks, rows,
                              values[self._indptr[rows.start]:self._indptr[rows.stop]])
        return csr_matrix((values, self._indices, self._indptr), shape=(self.n_rows, self.n_unknowns))

    def _chunks(self) -> list[slice]:
        """The included rows in runs of ``chunk_rows`` (positions among them)."""
        return [slice(start, min(start + self._chunk_rows, self.n_rows)) for start in range(0, self.n_rows,
                                                                                             self._chunk_rows)]

    def _evaluate(self, state: _State, rows: slice, with_jacobians: bool) -> RowEvaluation:
        """The included rows at positions ``rows`` evaluated at ``state``."""
        return self._every_row.evaluate(self._camera, state, self._min_depth, with_jacobians, self._row_ids[rows])

    def jacobian_operator(self, y: np.ndarray) -> LinearOperator:
        """`jacobian` at ``y`` as a `LinearOperator`, which `least_squares` does not copy (module docstring),
        its values written over those of the operator before.

        `least_squares` (``trf``) asks for a Jacobian only at an accepted step and never uses
        the one before after that, so one buffer of values serves the whole solve instead of
        two at once (memory: global BA). An operator used after the next one was made raises
        `RuntimeError` instead of giving products of the new values.
        """
        jac = self.jacobian(y, into=self._solver_values)
        self._solver_values, self._solver_generation = jac.data, self._solver_generation + 1
        generation = self._solver_generation

        def current(product):
            def apply(vector: np.ndarray) -> np.ndarray:
                if generation != self._solver_generation:
                    raise RuntimeError("least_squares used a Jacobian after asking for the next one")
                return product(vector)
            return apply

        return LinearOperator(jac.shape, matvec=current(jac.dot), rmatvec=current(jac.T.dot), dtype=np.float64)

    def _jacobian_of(self, evaluation: RowEvaluation, y: np.ndarray) -> csr_matrix:
        """The Jacobian w.r.t. ``y`` of every row, evaluated (with Jacobians) at ``y`` (`_fill_values`)."""
        values = np.empty(len(self._indices))
        self._fill_values(evaluation, self._pose_blocks(y), slice(0, self.n_rows), values)
        return csr_matrix((values, self._indices, self._indptr), shape=(self.n_rows, self.n_unknowns))

    def _pose_blocks(self, y: np.ndarray) -> np.ndarray:
        """``J_l(x_k) W_k`` (n_free, 6, 6) of each free pose at ``y``: a row's pose Jacobian times it is
        its Jacobian w.r.t. the pose's whitened unknowns."""
        return se3_left_jacobian(self._x_of(y)[: self._n_pose_unknowns].reshape(-1, 6)) @ self._pose_whitening

    def _fill_values(self, evaluation: RowEvaluation, pose_blocks: np.ndarray, rows: slice,
                     values: np.ndarray) -> None:
        """Fill ``values``, the CSR values of the rows ``rows`` evaluated with Jacobians: the rows'
        pose Jacobians times their pose's ``pose_blocks`` and landmark Jacobians times each world
        point's ``W_p`` (`_fill_jacobian_values`)."""
        _fill_jacobian_values(
            evaluation.jac_pose,
            evaluation.jac_landmark,
            self._row_free_pose[rows],
            pose_blocks,
            self._row_world_point[rows],
            self._point_whitening,
            values,
        )

    def _x_of(self, y: np.ndarray) -> np.ndarray:
        """The unknowns ``x`` of the module docstring at ``y``."""
        twists = np.einsum("kij,kj->ki", self._pose_whitening, y[: self._n_pose_unknowns].reshape(-1, 6))
        shifts = np.einsum("wij,wj->wi", self._point_whitening, y[self._n_pose_unknowns :].reshape(-1, 3))
        return np.concatenate([twists.ravel(), shifts.ravel()])

    def _state_at(self, x: np.ndarray) -> _State:
        T_c_w = self._start.T_c_w.copy()
        twists = x[: self._n_pose_unknowns].reshape(-1, 6)
        T_c_w[self._free] = se3_exp(twists) @ self._start.T_c_w[self._free]
        shifts = x[self._n_pose_unknowns :].reshape(-1, 3)
        n_points = len(self._start.points_w)
        points_w = self._start.points_w + shifts[:n_points]
        lines_w = self._start.lines_w + shifts[n_points:].reshape(-1, 2, 3)
        return _State(T_c_w, points_w, lines_w)


_WHITENING_FLOOR = 1e-4
"""Eigenvalues of a block's Gram matrix below this share of its largest are raised to it, so
that a direction the rows do not see (a line endpoint sliding along its line, the viewing
ray of a point seen once without a stereo match) gets a scale at most 100 times that of
the best-seen direction. A smaller floor lets such a direction become seen, and strongly
nonlinear, as soon as the poses move, and the trust region, measured in whitened units,
collapses (docs/decisions/0011-bundle-adjustment-solver.md)."""


@kernel
def _fill_jacobian_values(jac_pose, jac_landmark, row_free_pose, pose_blocks, row_world_point, point_whitening, values):
    """The CSR values (nnz,) of the Jacobian w.r.t. ``y``, row by row: the pose entries ``jac_pose[r] @
    pose_blocks[k]`` (6) where the row's pose is free (``row_free_pose`` (R,) ``k >= 0``), then
    the landmark entries ``jac_landmark[r] @ point_whitening[row_world_point[r]]`` (3).

    It replaced a loop over poses of (R_k, 6) x (6, 6) products, an ``einsum`` over the
    rows and a boolean gather of the (R, 9) values, with the same values. The Gram
    matrices of `_whitening` stay in numpy: once per solve, a kernel would save less than
    its compilation costs (docs/decisions/0011-bundle-adjustment-solver.md).
    """
    entry = 0
    for r in range(len(row_free_pose)):
        pose = row_free_pose[r]
        if pose >= 0:
            for j in range(6):
                value = 0.0
                for i in range(6):
                    value += jac_pose[r, i] * pose_blocks[pose, i, j]
                values[entry] = value
                entry += 1
        whitening = point_whitening[row_world_point[r]]
        for j in range(3):
            value = 0.0
            for i in range(3):
                value += jac_landmark[r, i] * whitening[i, j]
            values[entry] = value
            entry += 1


@kernel
def _fill_csr_structure(row_free_pose, row_world_point, n_pose_unknowns, indptr, indices):
    """Fill the Jacobian's CSR row pointers (R + 1,) and column indices (nnz,): per row, the 6
    columns of its free pose (none for a fixed pose, ``row_free_pose`` -1), then the 3 of its
    world point (after the ``n_pose_unknowns`` pose columns); the order of `_fill_jacobian_values`."""
    entry = 0
    indptr[0] = 0
    for r in range(len(row_free_pose)):
        pose = row_free_pose[r]
        if pose >= 0:
            for j in range(6):
                indices[entry] = 6 * pose + j
                entry += 1
        for j in range(3):
            indices[entry] = n_pose_unknowns + 3 * row_world_point[r] + j
            entry += 1
        indptr[r + 1] = entry


@kernel
def _column_square_sums(indices, values, n_columns):
    """The sum of squared values (n_columns,) of each column of a sparse matrix's entries (nnz,)."""
    sums = np.zeros(n_columns)
    for entry in range(len(indices)):
        sums[indices[entry]] += values[entry] * values[entry]
    return sums


def _block_grams(jac: np.ndarray, block: np.ndarray, n_blocks: int) -> np.ndarray:
    """``J_b^T J_b`` (n_blocks, k, k) of the rows (R, k) of each block (R,) (zero for a block without rows)."""
    k = jac.shape[1]
    outer = (jac[:, :, None] * jac[:, None, :]).reshape(len(jac), k * k)
    gram = np.stack([np.bincount(block, weights=column, minlength=n_blocks) for column in outer.T], axis=1)
    return gram.reshape(n_blocks, k, k)


def _pose_grams(jac_pose: np.ndarray, rows_of_pose: list[np.ndarray]) -> np.ndarray:
    """``J_p^T J_p`` (K, 6, 6) of the pose Jacobian rows (R, 6) of each of K poses (their row indices)."""
    return np.array([jac_pose[rows].T @ jac_pose[rows] for rows in rows_of_pose]).reshape(-1, 6, 6)


def _whitening(gram: np.ndarray, held: np.ndarray | None = None) -> np.ndarray:
    """``G_b^(-1/2)`` (n_blocks, k, k) of the Gram matrices ``G_b = J_b^T J_b`` (n_blocks, k, k) of
    the unknown blocks; identity for a block without rows.

    Multiplying a block's columns by it makes them orthonormal at the start of the solve:
    the block-Jacobi preconditioner of LSMR, applied as a change of variables because
    `least_squares` takes no preconditioner. It leaves the optimum where it is.

    ``held`` (n_blocks, k): a unit direction per block that the block must not move along
    (zero rows for none). The whitening is then projected on both sides onto the
    complement of that direction, so that no ``y`` moves the block along it (`_held_directions`).
    """
    k = gram.shape[1]
    projector = None
    if held is not None:
        projector = np.eye(k) - np.einsum("bi,bj->bij", held, held)
        gram = projector @ gram @ projector
    eigenvalues, vectors = np.linalg.eigh(gram)
    largest = eigenvalues[:, -1:]
    seen = largest[:, 0] > 0.0
    floor = np.maximum(eigenvalues, _WHITENING_FLOOR * largest)
    inverse_root = np.where(seen[:, None], 1.0 / np.sqrt(np.where(seen[:, None], floor, 1.0)), 1.0)
    whitening = np.einsum("bij,bj,bkj->bik", vectors, inverse_root, vectors)
    whitening[~seen] = np.eye(k)
    if projector is not None:
        whitening = projector @ whitening @ projector
    return whitening


def _held_directions(state: _State, pinned: np.ndarray) -> np.ndarray:
    """Per world point of ``state`` (P + 2 L, 3): the direction it must not move along (zeros: none).

    Map points, and line endpoints that a horizontal term of the solve measures
    (``pinned`` (P + 2 L,) bool), move freely. Any other line endpoint holds its line's
    direction: it moves only across its line. The vertical error (and its right-image
    twin) measures an endpoint's distance to the plane of an observed line; sliding along
    the line changes none of them, and with the planes of nearby views almost parallel an
    endpoint's least-squares point along the line is ill-determined: free, endpoints slide
    far from a good start (docs/decisions/0011-bundle-adjustment-solver.md). Held, a line
    keeps the 4 dof of an infinite 3D line and its endpoints their places along it; where a
    horizontal term measures an endpoint, that term holds it
    (`pld_slam.optim.line_reprojection`).
    """
    lines = state.lines_w
    direction = lines[:, 1] - lines[:, 0]
    direction /= np.maximum(np.linalg.norm(direction, axis=1, keepdims=True), 1e-12)
    held = np.zeros((len(state.points_w) + 2 * len(lines), 3))
    held[len(state.points_w):] = np.repeat(direction, 2, axis=0)
    held[pinned] = 0.0
    return held


def _half_squared_sum(residual: np.ndarray) -> float:
    return 0.5 * float(residual @ residual)
