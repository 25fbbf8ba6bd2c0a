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
- Unknowns along the tree. A keyframe graph is mostly a long chain, and on a chain the
  plain unknowns (one update per keyframe) are badly conditioned: closing a loop moves
  the last keyframes of the chain by metres, which LSMR can only build up from many
  small steps along it (a 1,000-keyframe circle: 51 s for 30 evaluations and still 9 m
  off). The solver's unknowns are therefore one rigid motion per keyframe that moves it
  *and its whole subtree* (`_TreeUpdates`; the incremental parameterisation of Olson's
  and TORO's pose graphs): a loop's correction spreads over many of them, each small,
  and the chain's edges each depend mostly on one. It is a fixed linear change of
  variables, so the residuals, their Jacobian and the optimum are those of the plain
  unknowns (same circle: exact in a few evaluations).
"""

import dataclasses
import time
from dataclasses import dataclass

import numpy as np
import scipy.sparse
from scipy.optimize import least_squares
from scipy.sparse.linalg import LinearOperator, splu

from pld_slam.geometry.se3 import inverse, se3_adjoint, se3_exp
from pld_slam.mapping.keyframe import KeyFrame
from pld_slam.mapping.map import Map
from pld_slam.optim.relative_pose import RelativePoseResidual, relative_pose_residual


@dataclass(frozen=True)
class PoseGraph:
    """A pose graph over N nodes and E edges.

    Attributes
    ----------
    T_c_w : (N, 4, 4) initial world-to-camera poses.
    fixed : (N,) bool, nodes held fixed.
    edge_i, edge_j : (E,) int64 node indices of each edge's two ends.
    T_i_j : (E, 4, 4) measured pose of camera j in camera i.
    parent : (N,) int64 spanning-tree parent of each node, -1 for a root (the unknowns
        follow the tree, module docstring).
    """

    T_c_w: np.ndarray
    fixed: np.ndarray
    edge_i: np.ndarray
    edge_j: np.ndarray
    T_i_j: np.ndarray
    parent: np.ndarray


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
    there (`_TreeUpdates`): far from its starting poses, a loop correction's updates are
    large, and the subtree motions stop being independent of each other.
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
    """One `least_squares` solve in the subtree motions of `_TreeUpdates`; returns it and the poses it reached."""
    problem = _GraphProblem(graph)
    tree = _TreeUpdates(graph)

    def jacobian(y: np.ndarray) -> LinearOperator:
        jac = problem.jacobian(tree.deltas(y))
        return LinearOperator(
            jac.shape, dtype=np.float64,
            matvec=lambda v: jac @ tree.deltas(v), rmatvec=lambda u: tree.transpose(jac.T @ u),
        )

    solution = least_squares(
        lambda y: problem.residuals(tree.deltas(y)), np.zeros(tree.size), jac=jacobian, method="trf",
        tr_solver="lsmr", tr_options=dict(maxiter=_LSMR_MAX_ITERATIONS), max_nfev=max_nfev,
        ftol=1e-12, xtol=1e-12, gtol=1e-12,
    )
    return solution, problem.poses(tree.deltas(solution.x))


_LSMR_MAX_ITERATIONS = 30
"""LSMR iterations per step: the subtree motions make the step's linear problem well
conditioned (a loop edge adds a rank-6 coupling to a near block-diagonal Jacobian)."""


def _free_columns(fixed: np.ndarray) -> np.ndarray:
    """Per node (N,), its index among the free nodes (N,) bool ``~fixed`` in order, -1 for a fixed one."""
    column = np.full(len(fixed), -1)
    column[~fixed] = np.arange(np.count_nonzero(~fixed))
    return column


class _TreeUpdates:
    """The solver's unknowns: per free node ``a``, a rigid motion ``y_a`` (6,) of it and its subtree,
    expressed in its own camera frame, so that it turns the subtree about the node itself
    (module docstring).

    In the world frame the motion is ``exp(Ad(T_w_a) y_a)``; applied to a descendant's
    ``T_k_w`` on the right (``T_k_w @ exp(-e)``) it is the left update ``-Ad(T_k_w) e``. A
    node's left update (`deltas`) is therefore ``-Ad(T_k_w)`` times the sum of
    ``Ad(T_w_a) y_a`` over ``k`` and its ancestors: the sum is ``(I - P)^-1`` with ``P``
    the (free) parent matrix, solved by one sparse LU. The adjoints are those of the
    initial poses: the change of variables is linear and fixed.
    """

    def __init__(self, graph: PoseGraph) -> None:
        free = np.flatnonzero(~graph.fixed)
        column = _free_columns(graph.fixed)
        self.size = 6 * len(free)
        parent = graph.parent[free]
        has_parent = (parent >= 0) & (column[np.maximum(parent, 0)] >= 0)
        children = np.flatnonzero(has_parent)
        ancestry = scipy.sparse.identity(len(free), format="csc") - scipy.sparse.csc_matrix(
            (np.ones(len(children)), (children, column[parent[children]])), shape=(len(free), len(free))
        )
        self._ancestry = splu(ancestry.tocsc()) if len(free) else None
        self._to_camera = -se3_adjoint(graph.T_c_w[free])
        self._to_world = se3_adjoint(inverse(graph.T_c_w[free]))

    def deltas(self, y: np.ndarray) -> np.ndarray:
        """Left updates (6F,) of the free nodes' ``T_c_w`` from the subtree motions ``y`` (6F,)."""
        if self.size == 0:
            return y
        world = np.einsum("nij,nj->ni", self._to_world, y.reshape(-1, 6))
        summed = self._ancestry.solve(world)
        return np.einsum("nij,nj->ni", self._to_camera, summed).ravel()

    def transpose(self, g: np.ndarray) -> np.ndarray:
        """The transpose of `deltas` applied to ``g`` (6F,) (a gradient w.r.t. the left updates)."""
        if self.size == 0:
            return g
        moved = np.einsum("nji,nj->ni", self._to_camera, g.reshape(-1, 6))
        summed = self._ancestry.solve(moved, trans="T")
        return np.einsum("nji,nj->ni", self._to_world, summed).ravel()


class _GraphProblem:
    """Residuals (6E,) and their sparse Jacobian w.r.t. the left updates (6F,) of the F free nodes."""

    def __init__(self, graph: PoseGraph) -> None:
        self._graph = graph
        self._column = _free_columns(graph.fixed)
        self._n_free = int(np.count_nonzero(~graph.fixed))

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
        return self._evaluate(x).residual.ravel()

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
        shape = (6 * len(self._graph.edge_i), 6 * self._n_free)
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
