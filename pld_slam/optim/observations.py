"""Point and line observations, the whitened residual rows every solver minimises, and what
every solver's options share (`ResidualOptions`: the terms used, the loss, the inlier tests).

Pose-only tracking (`pose_only`) and bundle adjustment (`bundle_adjustment`) share these
rows: stereo point reprojection errors (`point_reprojection`) and line vertical and
horizontal errors (`line_reprojection`), each divided by its observation's sigma so that
all residuals are in standard deviations. The paper leaves the covariances open. What we chose:

- A stereo point is observed as ``(u_left, v, u_right)``, but ``u_left`` and ``u_right``
  are not independent: the right column is the left one minus a sub-pixel disparity, so
  they share the corner's localisation error, and their difference errs several times
  less than either. Treating the three as independent with one sigma gives the disparity
  too large an effective sigma: depth and therefore scale are under-weighted, and local
  BA drifted in scale (docs/decisions/0018-observation-covariances.md). The rows are
  therefore whitened as ``u_left / sigma``, ``v / sigma`` and the disparity
  ``(u_left - u_right) / sigma_d``: the third sigma of `PointObservations.sigma_px` is the
  disparity's.
- Corners: ``sigma = 1.2**octave`` (ORB-SLAM2); disparities ``points.disparity_sigma_px``
  times the same factor.
- Lines: one sigma per observation for both line terms. A line's vertical term has four
  rows, the start and end in the left image and, where the right segment is known, in
  the right image (`pld_slam.optim.line_reprojection` says why); without it the right
  rows weigh nothing and the term has 2 dof instead of 4.
"""

from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from pld_slam.geometry.camera import StereoCamera
from pld_slam.optim.line_reprojection import (
    LineErrorRows,
    line_horizontal_rows,
    line_vertical_rows,
)
from pld_slam.optim.point_reprojection import MIN_DEPTH, poses_and_index, stereo_row_errors
from pld_slam.optim.robust import CHI2_95_2DOF, CHI2_95_3DOF, CHI2_95_4DOF, HUBER_SCALE


@dataclass(frozen=True)
class PointObservations:
    """N observations of world points, stereo or left image only.

    A keypoint without a stereo match (``u_right`` NaN) is a monocular observation: its
    ``u_right`` row weighs nothing, so it measures ``(u_left, v)`` only (2 dof instead of 3),
    as ORB-SLAM2's monocular edges do beside its stereo ones.

    Attributes
    ----------
    points_w : (N, 3) landmark positions in the world frame [m].
    stereo_px : (N, 3) observed ``(u_left, v, u_right)`` [px], ``u_right`` NaN without a stereo match.
    sigma_px : (N,) pixel standard deviation of each observation (``1.2**octave``), used for
        ``u_left``, ``v`` and the disparity alike, or (N, 3) the standard deviations of
        ``u_left``, ``v`` and the disparity ``u_left - u_right`` (module docstring).
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
    """M observations of world segments as detected segments in the left image (and the right).

    Attributes
    ----------
    start_w, end_w : (M, 3) world endpoints ``P``, ``Q`` [m], ``P`` matched to ``start_px``.
    start_px, end_px : (M, 2) detected endpoints ``s``, ``e`` in the left image [px].
    sigma_px : (M,) pixel standard deviation of each observation, for both line terms.
    horizontal_eligible : (M,) bool, the horizontal term may be used (endpoints away from
        the border: `pld_slam.optim.line_reprojection.endpoints_away_from_border`).
    right_start_px, right_end_px : (M, 2) two points of the segment in the right image [px]
        (the left endpoints' rows, shifted by their disparities), NaN rows where unknown;
        None: unknown for every observation.
    """

    start_w: np.ndarray
    end_w: np.ndarray
    start_px: np.ndarray
    end_px: np.ndarray
    sigma_px: np.ndarray
    horizontal_eligible: np.ndarray
    right_start_px: np.ndarray | None = None
    right_end_px: np.ndarray | None = None

    @classmethod
    def empty(cls) -> "LineObservations":
        """No line observations."""
        no_points, no_pixels = np.zeros((0, 3)), np.zeros((0, 2))
        return cls(no_points, no_points, no_pixels, no_pixels, np.zeros(0), np.zeros(0, dtype=bool))


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
        cls, points: PointObservations, lines: LineObservations, use_line_horizontal: bool
    ) -> "ObservationMasks":
        """Every observation, and the horizontal term wherever it is eligible and switched on."""
        return cls(
            points=np.ones(len(points.sigma_px), dtype=bool),
            lines=np.ones(len(lines.sigma_px), dtype=bool),
            line_horizontal=lines.horizontal_eligible & use_line_horizontal,
        )

    def __and__(self, other: "ObservationMasks") -> "ObservationMasks":
        """The observations in both."""
        return ObservationMasks(self.points & other.points, self.lines & other.lines,
                                self.line_horizontal & other.line_horizontal)


@dataclass(frozen=True)
class ResidualOptions:
    """What every solver of these rows shares: the terms it uses, its robust loss, its inlier tests.

    Attributes
    ----------
    use_line_vertical, use_line_horizontal : switch the two line terms (ablations).
    huber_scale : Huber ``f_scale`` [whitened units] of the robust solves.
    chi2_point, chi2_monocular_point, chi2_line, chi2_stereo_line : chi-square inlier bounds
        of a stereo point (3 dof), a point seen in the left image only (2 dof), a line term in
        one image (2 dof) and a vertical term in both images (4 dof).
    min_depth : smallest landmark depth [m] that counts as in front of a camera.
    """

    use_line_vertical: bool = True
    use_line_horizontal: bool = True
    huber_scale: float = HUBER_SCALE
    chi2_point: float = CHI2_95_3DOF
    chi2_monocular_point: float = CHI2_95_2DOF
    chi2_line: float = CHI2_95_2DOF
    chi2_stereo_line: float = CHI2_95_4DOF
    min_depth: float = MIN_DEPTH


def used_terms(
    include: ObservationMasks, horizontal_eligible: np.ndarray, options: ResidualOptions
) -> ObservationMasks:
    """The points, vertical terms (``lines``) and horizontal terms (``line_horizontal``) a solve
    uses of ``include``: each line term only where ``options`` switches it on, a horizontal term
    only with its line and where it is eligible (``horizontal_eligible`` (M,) bool)."""
    return ObservationMasks(
        points=include.points,
        lines=include.lines & options.use_line_vertical,
        line_horizontal=include.lines & include.line_horizontal & horizontal_eligible & options.use_line_horizontal,
    )


class RowEvaluation(NamedTuple):
    """Whitened residual rows evaluated at their poses and landmarks.

    residual : (K,) whitened residuals; jac_pose : (K, 6) their Jacobian w.r.t. the left
    perturbation ``delta`` of the row's pose; jac_landmark : (K, 3) w.r.t. the row's world
    point (a point, or the line endpoint the row measures); valid : (K,) bool, that point
    lies deeper than ``min_depth``. Evaluated without Jacobians (``with_jacobians=False``),
    jac_pose and jac_landmark are (0, 6) and (0, 3), and `select` does not apply.
    """

    residual: np.ndarray
    jac_pose: np.ndarray
    jac_landmark: np.ndarray
    valid: np.ndarray

    def select(self, row_mask: np.ndarray) -> "RowEvaluation":
        """The rows where ``row_mask`` (K,) is True."""
        return RowEvaluation(
            self.residual[row_mask], self.jac_pose[row_mask], self.jac_landmark[row_mask], self.valid[row_mask]
        )


@dataclass(frozen=True)
class WhitenedRows:
    """The residual rows of a solve, each divided by its observation's sigma.

    Rows: 3 per point (``u_left, v``, disparity), then 4 per vertical line term (start and
    end in the left image, then in the right), then 2 per horizontal line term (start,
    end), as `LineErrorRows`. Row ``k`` of the line rows measures endpoint ``k % 2``
    (start, end) of its observation.

    Attributes
    ----------
    points_w, stereo_px : (N, 3) the points' world positions [m] and observations [px].
    point_weight : (N, 3) ``1 / sigma`` of each point's rows.
    line_rows : the 4 Mv + 2 Mh whitened line rows.
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
    ) -> "WhitenedRows":
        """The rows of the points and of the two line terms of the given lines."""
        vertical_rows = stereo_vertical_rows(vertical_lines)
        horizontal_rows = whitened_line_rows(line_horizontal_rows, horizontal_lines)
        monocular = np.isnan(points.stereo_px[:, 2])
        point_weight = 1.0 / point_row_sigmas(points.sigma_px)
        point_weight[monocular, 2] = 0.0
        stereo_px = points.stereo_px.copy()
        stereo_px[monocular, 2] = 0.0
        return cls(
            points.points_w,
            stereo_px,
            point_weight,
            LineErrorRows.concatenate([vertical_rows, horizontal_rows]),
            len(vertical_lines.sigma_px),
            len(horizontal_lines.sigma_px),
        )

    def row_mask(self, masks: ObservationMasks) -> np.ndarray:
        """(K,) bool, the rows of the points, vertical terms and horizontal terms selected by ``masks``.

        ``masks.lines`` selects vertical terms, ``masks.line_horizontal`` horizontal ones.
        """
        return np.concatenate(
            [np.repeat(masks.points, 3), np.repeat(masks.lines, 4), np.repeat(masks.line_horizontal, 2)]
        )

    def select(self, row_mask: np.ndarray) -> "WhitenedRows":
        """The rows where ``row_mask`` (K,) is True (a point's or a line term's rows all or none)."""
        point_mask = row_mask[: 3 * len(self.points_w) : 3]
        line_mask = row_mask[3 * len(self.points_w) :]
        vertical_rows = 4 * self.n_vertical
        return WhitenedRows(
            self.points_w[point_mask],
            self.stereo_px[point_mask],
            self.point_weight[point_mask],
            self.line_rows.select(line_mask),
            int(np.sum(line_mask[:vertical_rows])) // 4,
            int(np.sum(line_mask[vertical_rows:])) // 2,
        )

    @property
    def point_is_stereo(self) -> np.ndarray:
        """(N,) bool, the point observations with a ``u_right`` (3 dof; the others have 2)."""
        return self.point_weight[:, 2] > 0.0

    @property
    def line_is_stereo(self) -> np.ndarray:
        """(Mv,) bool, the vertical terms measured in both images (4 dof; the others have 2)."""
        right_rows = self.line_rows.axes[: 4 * self.n_vertical].reshape(-1, 4, 2)[:, 2:]
        return np.any(right_rows != 0.0, axis=(1, 2))

    def line_inliers(self, vertical_chi2: np.ndarray, chi2_stereo: float, chi2_left: float) -> np.ndarray:
        """(Mv,) bool, the vertical terms whose chi2 passes the bound of their dof (stereo 4, left only 2)."""
        return vertical_chi2 <= np.where(self.line_is_stereo, chi2_stereo, chi2_left)

    def point_inliers(self, point_chi2: np.ndarray, chi2_stereo: float, chi2_monocular: float) -> np.ndarray:
        """(N,) bool, the points whose chi2 (N,) passes the bound of their dof (stereo 3, monocular 2)."""
        return point_chi2 <= np.where(self.point_is_stereo, chi2_stereo, chi2_monocular)

    def evaluate(
        self,
        camera: StereoCamera,
        point_T_c_w: np.ndarray,
        line_T_c_w: np.ndarray,
        min_depth: float,
        point_pose: np.ndarray | None = None,
        line_pose: np.ndarray | None = None,
        with_jacobians: bool = True,
    ) -> RowEvaluation:
        """All rows at their poses: one ``T_c_w`` (4, 4) for all points / line rows, one per point
        (N, 4, 4) and per line row (4 Mv + 2 Mh, 4, 4), or K poses (K, 4, 4) with the pose of
        each point ``point_pose`` (N,) and of each line row ``line_pose``.

        Point and line rows are evaluated together, in one call of
        `pld_slam.optim.point_reprojection.stereo_row_errors` (`stacked_axes` gives their axes).
        """
        n_points, n_line_rows = len(self.points_w), len(self.line_rows.offsets)
        point_poses, point_index = poses_and_index(point_T_c_w, n_points, point_pose)
        line_poses, line_index = poses_and_index(line_T_c_w, n_line_rows, line_pose)
        axes, offsets = self.stacked_axes()
        rows = stereo_row_errors(
            camera,
            np.concatenate([point_poses, line_poses]),
            np.concatenate([np.repeat(self.points_w, 3, axis=0), self.line_rows.endpoints_w]),
            axes,
            offsets,
            min_depth,
            np.concatenate([np.repeat(point_index, 3), line_index + len(point_poses)]),
            with_jacobians,
        )
        return RowEvaluation(rows.residual, rows.jac_pose, rows.jac_point, rows.valid)

    def stacked_axes(self) -> tuple[np.ndarray, np.ndarray]:
        """Axes (R, 3) over ``(u_left, v, u_right)`` and offsets (R,) of every row, point rows first
        (`_point_rows`), then line rows (`LineErrorRows.stereo_axes`): what
        `pld_slam.optim.point_reprojection.stereo_row_errors` evaluates."""
        point_axes, point_offsets = self._point_rows()
        return (np.concatenate([point_axes, self.line_rows.stereo_axes]),
                np.concatenate([point_offsets, self.line_rows.offsets]))

    def _point_rows(self) -> tuple[np.ndarray, np.ndarray]:
        """Axes (3 N, 3) over ``(u_left, v, u_right)`` and offsets (3 N,) of the whitened point rows:
        ``u_left / sigma``, ``v / sigma`` and the disparity ``(u_left - u_right) / sigma_d``, each
        predicted minus observed (module docstring)."""
        n = len(self.points_w)
        axes = np.zeros((n, 3, 3))
        axes[:, 0, 0] = self.point_weight[:, 0]
        axes[:, 1, 1] = self.point_weight[:, 1]
        axes[:, 2, 0] = self.point_weight[:, 2]
        axes[:, 2, 2] = -self.point_weight[:, 2]
        offsets = -np.einsum("nij,nj->ni", axes, self.stereo_px)
        return axes.reshape(3 * n, 3), offsets.ravel()

    def chi2(self, evaluation: RowEvaluation) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Squared whitened norm of every point (N,), vertical term (Mv,, both images) and horizontal term (Mh,).

        ``inf`` where a row's landmark does not project (depth ``<= min_depth``).
        """
        squares = np.where(evaluation.valid, evaluation.residual**2, np.inf)
        point_end = 3 * len(self.points_w)
        vertical_end = point_end + 4 * self.n_vertical
        return (
            squares[:point_end].reshape(-1, 3).sum(axis=1),
            squares[point_end:vertical_end].reshape(-1, 4).sum(axis=1),
            squares[vertical_end:].reshape(-1, 2).sum(axis=1),
        )


def point_row_sigmas(sigma_px: np.ndarray) -> np.ndarray:
    """Sigmas (N, 3) (a new array) of the ``u_left, v``, disparity rows from one per point (N,) or per row (N, 3)."""
    sigma_px = np.asarray(sigma_px, dtype=np.float64)
    per_row = sigma_px if sigma_px.ndim == 2 else sigma_px[:, None]
    return np.array(np.broadcast_to(per_row, (len(sigma_px), 3)))


def whitened_line_rows(
    rows_of: Callable[[np.ndarray, np.ndarray, np.ndarray, np.ndarray], LineErrorRows], lines: LineObservations
) -> LineErrorRows:
    """The rows of one line term (`line_vertical_rows` or `line_horizontal_rows`) divided by their sigma."""
    rows = rows_of(lines.start_w, lines.end_w, lines.start_px, lines.end_px)
    return rows.scaled(np.repeat(1.0 / lines.sigma_px, 2))


def stereo_vertical_rows(lines: LineObservations) -> LineErrorRows:
    """The 4M whitened vertical rows of M observations: left start, left end, right start, right end.

    Where the right segment is unknown its two rows are zero (they weigh nothing).
    """
    n = len(lines.sigma_px)
    left = whitened_line_rows(line_vertical_rows, lines)
    no_right = np.full((n, 2), np.nan)
    right_start = no_right if lines.right_start_px is None else lines.right_start_px
    right_end = no_right if lines.right_end_px is None else lines.right_end_px
    known = np.all(np.isfinite(right_start), axis=1) & np.all(np.isfinite(right_end), axis=1)
    right_start = np.where(known[:, None], right_start, [0.0, 0.0])
    right_end = np.where(known[:, None], right_end, [0.0, 1.0])  # any segment: the rows are zeroed
    right = line_vertical_rows(lines.start_w, lines.end_w, right_start, right_end, right=True)
    right = right.scaled(np.repeat(known / lines.sigma_px, 2))
    return LineErrorRows(
        endpoints_w=_pairs_side_by_side(left.endpoints_w, right.endpoints_w),
        axes=_pairs_side_by_side(left.axes, right.axes),
        offsets=_pairs_side_by_side(left.offsets, right.offsets),
        right=_pairs_side_by_side(left.right, right.right),
    )


def _pairs_side_by_side(left: np.ndarray, right: np.ndarray) -> np.ndarray:
    """Rows (2M, ...) of two row sets, each in pairs per observation, as (4M, ...): left pair, right pair."""
    n = len(left) // 2
    return np.stack([left.reshape(n, 2, *left.shape[1:]), right.reshape(n, 2, *right.shape[1:])], axis=1).reshape(
        4 * n, *left.shape[1:]
    )


def chi2_inliers(
    rows: WhitenedRows,
    point_chi2: np.ndarray,
    vertical_chi2: np.ndarray,
    horizontal_chi2: np.ndarray,
    horizontal_eligible: np.ndarray,
    options: ResidualOptions,
) -> ObservationMasks:
    """The observations whose chi2 (`WhitenedRows.chi2` of ``rows``: points (N,), the vertical
    (M,) and horizontal (M,) line terms) passes the bound of its dof; with the vertical term
    switched off, every line that projects; a horizontal term only with its line, where it is
    eligible (``horizontal_eligible`` (M,) bool) and switched on."""
    line_inliers = (
        rows.line_inliers(vertical_chi2, options.chi2_stereo_line, options.chi2_line)
        if options.use_line_vertical
        else np.isfinite(vertical_chi2)
    )
    return ObservationMasks(
        points=rows.point_inliers(point_chi2, options.chi2_point, options.chi2_monocular_point),
        lines=line_inliers,
        line_horizontal=line_inliers
        & horizontal_eligible
        & options.use_line_horizontal
        & (horizontal_chi2 <= options.chi2_line),
    )
