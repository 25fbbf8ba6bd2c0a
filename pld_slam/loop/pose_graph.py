"""Pose-graph optimisation over the keyframes (paper, section "Loop correction").

The paper's graph: a node per keyframe, an edge between keyframes "which have at least
20 % common features", solved with g2o "as PL-SLAM". What it leaves open, and what we do:

- Edges (ORB-SLAM2's essential graph): the spanning tree (each keyframe to its parent),
  every loop edge closed so far, and the covisibility links of at least
  ``loop.pose_graph_min_shared_ratio`` of the smaller keyframe's landmarks (the paper's
  "20 % common features": a share, since the number of features differs per keyframe).
- Measurements: an edge measures the relative pose of its two keyframes before the loop
  was corrected (what tracking and local BA made of them); a loop edge measures the
  relative pose the loop's geometric check found. Links the loop's fusion created are not
  edges (they would measure the drift the graph is meant to remove); the loop edge
  stands for them.
- Residual: the SE(3) relative-pose twist of `pld_slam.optim.relative_pose`, every edge
  with unit information (ORB-SLAM2 does the same on its Sim(3) graph). Stereo has metric
  scale, so SE(3) suffices.
- Gauge: the first keyframe is held fixed, so the world frame stays the first camera's.
- Solver: `scipy.optimize.least_squares` (trust region, LSMR) with the analytic sparse
  Jacobian; no robust loss, since every edge was verified.
- Unknowns whitened. A keyframe graph is mostly a long chain, and on a chain the plain
  unknowns (one update per keyframe) are badly conditioned: closing a loop moves the last
  keyframes of the chain by metres, which LSMR can only build up from many small steps
  along it. Each round of the solve therefore whitens its unknowns by the Gauss-Newton
  matrix at its start (`_Whitening`): with ``J^T J = P L D L^T P^T`` (a sparse LDL^T,
  SuperLU in symmetric mode with a fill-reducing order), the update is ``M y`` with
  ``M = P L^-T D^-1/2``, so that the Jacobian in ``y`` has orthonormal columns there and
  LSMR solves a step in a few iterations. The trust region starts as wide as the
  residual's norm there (``x_scale``; a whitened Gauss-Newton step is no longer), not at
  `least_squares`' unit radius, which would take a round's few evaluations to grow to a
  metres-long loop correction. It replaced one rigid motion per keyframe and
  its subtree (the parameterisation of Olson's and TORO's graphs), which on a long graph
  stopped after its evaluations metres from the optimum; whitened, it converges in a few
  (see docs/decisions/0021-loop-correction.md). Trial steps evaluate the residuals alone
  (`relative_pose_error`), without the Jacobians.
"""

import dataclasses
import time
from dataclasses import dataclass

import numpy as np
import scipy.sparse
from scipy.optimize import least_squares
from scipy.sparse.linalg import LinearOperator, splu

from pld_slam.geometry.se3 import inverse, se3_exp, se3_log
from pld_slam.mapping.keyframe import KeyFrame
from pld_slam.mapping.map import Map
from pld_slam.optim.relative_pose import RelativePoseResidual, relative_pose_error, relative_pose_residual


@dataclass(frozen=True)
class PoseGraph:
    """A pose graph over N nodes and E edges.

    Attributes
    ----------
    T_c_w : (N, 4, 4) initial world-to-camera poses.
    fixed : (N,) bool, nodes held fixed.
    edge_i, edge_j : (E,) int64 node indices of each edge's two ends.
    T_i_j : (E, 4, 4) measured pose of camera j in camera i.
    """

    T_c_w: np.ndarray
    fixed: np.ndarray
    edge_i: np.ndarray
    edge_j: np.ndarray
    T_i_j: np.ndarray


@dataclass(frozen=True)
class PoseGraphResult:
    """The optimised ``T_c_w`` (N, 4, 4), residual evaluations, cost (half the squared residual) before and
    after, and wall time [ms]."""

    T_c_w: np.ndarray
    nfev: int
    initial_cost: float
    final_cost: float
    ms: float


def relative_poses(T_c_w: np.ndarray, edge_i: np.ndarray, edge_j: np.ndarray) -> np.ndarray:
    """``T_i_j = T_ci_w @ inverse(T_cj_w)`` (E, 4, 4) of edges between poses (N, 4, 4)."""
    return T_c_w[edge_i] @ inverse(T_c_w[edge_j])


def optimize_pose_graph(graph: PoseGraph, max_nfev: int) -> PoseGraphResult:
    """Solve the pose graph (module docstring), in rounds of at most `_ROUND_NFEV` evaluations.

    Each round starts from the last one's poses, with the change of variables re-made
    there (`_Whitening`): the Gauss-Newton matrix changes as the poses move.
    """
    start = time.perf_counter()
    initial_cost = final_cost = _cost(graph)
    nfev = 0
    while nfev < max_nfev and len(graph.edge_i) and np.any(~graph.fixed):
        solution, T_c_w = _solve_round(graph, min(_ROUND_NFEV, max_nfev - nfev))
        nfev += int(solution.nfev)
        converged = final_cost - solution.cost <= _ROUND_FTOL * final_cost
        graph, final_cost = dataclasses.replace(graph, T_c_w=T_c_w), float(solution.cost)
        if converged:
            break
    return PoseGraphResult(graph.T_c_w.copy(), nfev, initial_cost, final_cost, 1e3 * (time.perf_counter() - start))


_ROUND_NFEV = 4
"""Residual evaluations per round of `optimize_pose_graph` (Gauss-Newton steps from one linearisation)."""
_ROUND_FTOL = 1e-6
"""A round that lowers the cost by less than this share of it ends the solve."""


def _cost(graph: PoseGraph) -> float:
    """Half the squared residual of the graph at its poses."""
    residual = _GraphProblem(graph).residuals(np.zeros(6 * int(np.count_nonzero(~graph.fixed))))
    return 0.5 * float(residual @ residual)


def _solve_round(graph: PoseGraph, max_nfev: int):
    """One `least_squares` solve in the whitened unknowns of `_Whitening`; returns it and the poses it reached."""
    problem = _GraphProblem(graph)
    start = np.zeros(problem.n_unknowns)
    at_start, jac_at_start = problem.residuals(start), problem.jacobian(start)
    whitening = _Whitening(jac_at_start)

    def residuals(y: np.ndarray) -> np.ndarray:  # the start's, computed above, when least_squares asks for them
        return at_start.copy() if not np.any(y) else problem.residuals(whitening.updates(y))

    def jacobian(y: np.ndarray) -> LinearOperator:
        jac = jac_at_start if not np.any(y) else problem.jacobian(whitening.updates(y))
        return LinearOperator(
            jac.shape, dtype=np.float64,
            matvec=lambda v: jac @ whitening.updates(v), rmatvec=lambda u: whitening.transpose(jac.T @ u),
        )

    solution = least_squares(
        residuals, start, jac=jacobian,
        method="trf", tr_solver="lsmr", tr_options=dict(maxiter=_LSMR_MAX_ITERATIONS), max_nfev=max_nfev,
        x_scale=max(1.0, float(np.linalg.norm(at_start))), ftol=1e-12, xtol=1e-12, gtol=1e-12,
    )
    return solution, problem.poses(whitening.updates(solution.x))


_LSMR_MAX_ITERATIONS = 30
"""LSMR iterations per step: in the whitened unknowns a step's linear problem is near the
identity, and more iterations per step take fewer steps (see docs/decisions/0021-loop-correction.md)."""
_DAMPING = 1e-9
"""Added to the Gauss-Newton matrix, times its largest diagonal entry, before it is factored:
a chain's weakest direction may be nearly unseen, and the factor must exist."""


def _free_columns(fixed: np.ndarray) -> np.ndarray:
    """Per node (N,), its index among the free nodes (N,) bool ``~fixed`` in order, -1 for a fixed one."""
    column = np.full(len(fixed), -1)
    column[~fixed] = np.arange(np.count_nonzero(~fixed))
    return column


class _Whitening:
    """The change of variables ``x = M y`` of a round (module docstring), from the Jacobian ``J`` (6E, 6F)
    w.r.t. the left updates ``x`` at the round's start: ``M^T J^T J M = I`` up to `_DAMPING`.

    SuperLU factors ``Pr A Pr^T = L U`` with ``A = J^T J``; in symmetric mode without
    pivoting ``U = D L^T`` (D the diagonal of U), so ``A = Pr^T L D L^T Pr`` and ``M = Pr^T
    L^-T D^-1/2``. The triangular solves with L are SuperLU's own (L factored again, as is).
    """

    def __init__(self, jac: scipy.sparse.csr_matrix) -> None:
        gram = (jac.T @ jac).tocsc()
        n = gram.shape[0]
        self._n = n
        if n == 0:
            return
        gram = gram + _DAMPING * gram.diagonal().max() * scipy.sparse.identity(n, format="csc")
        factor = splu(gram, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options=dict(SymmetricMode=True))
        self._order = factor.perm_r
        self._sqrt_d = np.sqrt(np.maximum(factor.U.diagonal(), np.finfo(float).tiny))
        self._lower = splu(factor.L.tocsc(), permc_spec="NATURAL", diag_pivot_thresh=0.0)

    def updates(self, y: np.ndarray) -> np.ndarray:
        """Left updates ``x = M y`` (6F,) of the free nodes' ``T_c_w`` from whitened unknowns ``y`` (6F,)."""
        if self._n == 0:
            return np.ravel(y)
        return self._lower.solve(np.ravel(y) / self._sqrt_d, trans="T")[self._order]

    def transpose(self, g: np.ndarray) -> np.ndarray:
        """``M^T g`` (6F,) of ``g`` (6F,) (a gradient w.r.t. the left updates)."""
        if self._n == 0:
            return np.ravel(g)
        permuted = np.empty(self._n)
        permuted[self._order] = np.ravel(g)
        return self._lower.solve(permuted) / self._sqrt_d


class _GraphProblem:
    """Residuals (6E,) and their sparse Jacobian w.r.t. the left updates (6F,) of the F free nodes."""

    def __init__(self, graph: PoseGraph) -> None:
        self._graph = graph
        self._column = _free_columns(graph.fixed)
        self.n_unknowns = 6 * int(np.count_nonzero(~graph.fixed))

    def _deltas(self, x: np.ndarray) -> np.ndarray:
        deltas = np.zeros((len(self._column), 6))
        free = self._column >= 0
        deltas[free] = x.reshape(-1, 6)[self._column[free]]
        return deltas

    def poses(self, x: np.ndarray) -> np.ndarray:
        """The nodes' ``T_c_w`` (N, 4, 4) at left updates ``x`` (6F,)."""
        return se3_exp(self._deltas(x)) @ self._graph.T_c_w

    def _evaluate(self, x: np.ndarray) -> RelativePoseResidual:
        graph, deltas = self._graph, self._deltas(x)
        return relative_pose_residual(
            deltas[graph.edge_i], deltas[graph.edge_j], graph.T_c_w[graph.edge_i], graph.T_c_w[graph.edge_j],
            graph.T_i_j,
        )

    def residuals(self, x: np.ndarray) -> np.ndarray:
        """Residuals (6E,) at left updates ``x`` (6F,), without their Jacobians (most evaluations are trial steps)."""
        poses, graph = self.poses(x), self._graph
        return se3_log(relative_pose_error(poses[graph.edge_i], poses[graph.edge_j], graph.T_i_j)).ravel()

    def jacobian(self, x: np.ndarray) -> scipy.sparse.csr_matrix:
        """(6E, 6F) Jacobian of `residuals` w.r.t. the left updates ``x``."""
        evaluated = self._evaluate(x)
        rows, cols, values = [], [], []
        for ends, blocks in ((self._graph.edge_i, evaluated.jac_i), (self._graph.edge_j, evaluated.jac_j)):
            edges = np.flatnonzero(self._column[ends] >= 0)
            row = 6 * edges[:, None, None] + np.arange(6)[None, :, None]
            col = 6 * self._column[ends[edges]][:, None, None] + np.arange(6)[None, None, :]
            rows.append(np.broadcast_to(row, (len(edges), 6, 6)).ravel())
            cols.append(np.broadcast_to(col, (len(edges), 6, 6)).ravel())
            values.append(blocks[edges].ravel())
        shape = (6 * len(self._graph.edge_i), self.n_unknowns)
        return scipy.sparse.csr_matrix(
            (np.concatenate(values), (np.concatenate(rows), np.concatenate(cols))), shape=shape
        )


def essential_edges(world_map: Map, min_shared_ratio: float) -> np.ndarray:
    """Keyframe id pairs (E, 2) of the map's essential graph without loop edges (module docstring):
    each keyframe with its spanning-tree parent, and covisibility links sharing at least
    ``min_shared_ratio`` of the smaller keyframe's live landmarks; each pair once, lower id first."""
    landmarks = {k: _live_landmarks(world_map, keyframe) for k, keyframe in world_map.keyframes.items()}
    pairs = set()
    for keyframe, parent in world_map.covisibility.parent.items():
        if parent is not None:
            pairs.add((min(keyframe, parent), max(keyframe, parent)))
    for keyframe in world_map.keyframes:
        for other, shared in world_map.covisibility.shared(keyframe).items():
            if keyframe < other and shared >= min_shared_ratio * min(landmarks[keyframe], landmarks[other]):
                pairs.add((keyframe, other))
    return np.array(sorted(pairs), dtype=np.int64).reshape(-1, 2)


def _live_landmarks(world_map: Map, keyframe: KeyFrame) -> int:
    """How many live landmarks (points and lines) a keyframe observes."""
    return sum(int(np.count_nonzero(kind.live(getattr(keyframe, kind.IDS_FIELD)))) for kind in world_map.kinds)
