"""Line reprojection errors (vertical and horizontal) with analytic Jacobians.

A map line is a 3D segment with world endpoints ``P`` (start) and ``Q`` (end). It is
observed in the left image as a detected segment from ``s`` to ``e`` [px]; ``P`` must be
the endpoint matched to ``s`` and ``Q`` the one matched to ``e`` (the horizontal error
depends on this pairing, the vertical error does not). The projected endpoints are
``p = pi(T_c_w P)`` and ``q = pi(T_c_w Q)`` in the left image.

Pose convention and points behind the camera: as in `point_reprojection` (left
perturbation ``T_c_w <- se3_exp(delta) @ T_c_w``, ``delta = (rho, phi)``; an endpoint at
depth ``<= min_depth`` is projected at that depth and flags its segment not valid).

Which line is measured. The paper's formula for ``d_s`` takes the detected endpoint's
distance to the *projected* line, but its Jacobian ``[m, -l] de/dxi / sqrt(l^2 + m^2)``
holds the line direction ``(l, m)`` constant, which is exact only if the line is the
detected one. We follow the Jacobian (and the design notes): the projected endpoints are
measured against the *detected* line, fixed during a solve.

Units. The paper writes the vertical error on the normalised image plane; we use pixels,
so one pixel sigma weighs points and lines alike and the chi-square tests of both use
the same units.

Signs. The detected direction is ``d = (e - s) / |e - s|`` and the detected line's unit
normal is ``n = (-d_v, d_u)``, i.e. ``d`` turned by +90 degrees in (u, v): with v pointing
down, ``n`` points to the *right* of the direction of travel ``s -> e`` as the image is
displayed. Then, for each projected endpoint ``x`` paired with detected endpoint ``y``:

- vertical error ``n . (x - y)``: the signed perpendicular distance of ``x`` to the
  detected infinite line (the same for any ``y`` on it), positive on the right of
  ``s -> e``;
- horizontal error ``d . (x - y)``: the signed offset along the line, positive when
  ``x`` lies beyond ``y`` in the direction ``s -> e``.

The paper leaves the horizontal sign open. We take the component along ``d`` of the
endpoint reprojection error ``x - y`` (predicted minus observed, as for points), so the
two errors are the coordinates of the endpoint error in the orthonormal frame
``(n, d)`` of the detected line: vertical**2 + horizontal**2 = |x - y|**2.

The right image. The paper measures both errors in the left image, where a segment's
depth is free: it rests on the other keyframes' views alone, and for a line along the
direction of travel (a kerb, a facade's edge) those are nearly the same plane, so map
lines slid tens to hundreds of metres in local BA. A stereo observation also sees the
segment in the right image, at the endpoint disparities the front end measured; the
vertical error of the projected endpoints to that right line (projected into the right
camera, ``u_right = u_left - bf / z``) fixes the depth, as PL-SLAM's stereo formulation
does. A row therefore measures an endpoint's projection in the left or the right image
(`LineErrorRows.right`); the horizontal error stays in the left image, as the paper has it.

Rows. Both errors are affine in a projected endpoint, ``axis . x + offset``, with an axis
and offset fixed by the detection: `LineErrorRows`, one scalar row per endpoint. A solver
that evaluates them at many poses builds the rows once (`line_vertical_rows`,
`line_horizontal_rows`, scaled to whiten them) and evaluates them per pose;
`line_vertical_error` and `line_horizontal_error` are the same computation in one call.
A row is an affine function of the endpoint's stereo pixels (`LineErrorRows.stereo_axes`),
evaluated by `pld_slam.optim.point_reprojection.stereo_row_errors`, the one projection
kernel of every residual: `line_row_errors` for the rows alone, and
`pld_slam.optim.observations.WhitenedRows.evaluate` with the point rows of a solve.
"""

from dataclasses import dataclass

import numpy as np

from pld_slam.geometry.camera import StereoCamera
from pld_slam.optim.point_reprojection import MIN_DEPTH, stereo_row_errors


@dataclass(frozen=True)
class LineReprojection:
    """A two-row line error (start term, end term) of N segments and its Jacobians.

    Attributes
    ----------
    residual : (N, 2) the error of the start endpoint ``P`` and of the end endpoint ``Q`` [px].
    jac_pose : (N, 2, 6) derivative w.r.t. the left perturbation ``delta`` of ``T_c_w``.
    jac_start : (N, 2, 3) derivative w.r.t. the world start point ``P`` (second row zero).
    jac_end : (N, 2, 3) derivative w.r.t. the world end point ``Q`` (first row zero).
    valid : (N,) bool, both endpoints lie deeper than ``min_depth`` in the left camera.
    """

    residual: np.ndarray
    jac_pose: np.ndarray
    jac_start: np.ndarray
    jac_end: np.ndarray
    valid: np.ndarray


def detected_line_directions(start_px: np.ndarray, end_px: np.ndarray) -> np.ndarray:
    """Unit directions (N, 2) ``(e - s) / |e - s|`` of detected segments (N, 2) -> (N, 2) [px].

    Segments must have non-zero length.
    """
    delta = end_px - start_px
    return delta / np.linalg.norm(delta, axis=1, keepdims=True)


def detected_line_coefficients(start_px: np.ndarray, end_px: np.ndarray) -> np.ndarray:
    """Infinite lines ``(a, b, c)`` (N, 3) through detected segments ``s`` -> ``e`` (N, 2) [px].

    ``(a, b, c) = [s, 1] x [e, 1]`` scaled so that ``a**2 + b**2 = 1``; then
    ``a u + b v + c`` is the signed distance [px] of pixel ``(u, v)`` to the line, positive
    on the right of ``s -> e`` as displayed (``(a, b)`` is the normal ``n`` of the module
    docstring). Segments must have non-zero length.
    """
    ones = np.ones((len(start_px), 1))
    homogeneous = np.cross(np.hstack([start_px, ones]), np.hstack([end_px, ones]))
    return homogeneous / np.linalg.norm(homogeneous[:, :2], axis=1, keepdims=True)


def endpoints_away_from_border(
    camera: StereoCamera, start_px: np.ndarray, end_px: np.ndarray, margin_px: float
) -> np.ndarray:
    """Whether both detected endpoints (N, 2) lie at least ``margin_px`` inside the image (N,).

    The paper applies the horizontal error only to such segments: an endpoint at the
    border is where the image cut the segment, not where the 3D segment ends.
    """
    return camera.inside_image(start_px, margin_px) & camera.inside_image(end_px, margin_px)


@dataclass(frozen=True)
class LineErrorRows:
    """M scalar line errors ``axis . x + offset``, ``x`` the projection of a world endpoint in the left
    image, or in the right one where ``right``.

    Both line errors have this form, one row per endpoint of a segment, the axis being the
    detected line's normal ``n`` (vertical error) or direction ``d`` (horizontal error).
    Scaling a row by ``1 / sigma`` scales its axis and offset, so whitened rows are rows too.

    Attributes
    ----------
    endpoints_w : (M, 3) world endpoint of each row [m].
    axes : (M, 2) image axis of each row.
    offsets : (M,) offset of each row [px].
    right : (M,) bool, the row measures the right image.
    """

    endpoints_w: np.ndarray
    axes: np.ndarray
    offsets: np.ndarray
    right: np.ndarray

    @property
    def stereo_axes(self) -> np.ndarray:
        """(M, 3) each row's weights of ``(u_left, v, u_right)``: the axis on ``u_right`` and ``v``
        where the row measures the right image, on ``u_left`` and ``v`` elsewhere."""
        axes = np.zeros((len(self.axes), 3))
        axes[:, 1] = self.axes[:, 1]
        axes[np.arange(len(axes)), np.where(self.right, 2, 0)] = self.axes[:, 0]
        return axes

    def scaled(self, factor: np.ndarray) -> "LineErrorRows":
        """The rows multiplied by ``factor`` (M,) (e.g. whitened by ``1 / sigma``)."""
        return LineErrorRows(self.endpoints_w, self.axes * factor[:, None], self.offsets * factor, self.right)

    def select(self, mask: np.ndarray) -> "LineErrorRows":
        """The rows where ``mask`` (M,) is True."""
        return LineErrorRows(self.endpoints_w[mask], self.axes[mask], self.offsets[mask], self.right[mask])

    @staticmethod
    def concatenate(rows: "list[LineErrorRows]") -> "LineErrorRows":
        """All rows of several `LineErrorRows`, in order."""
        return LineErrorRows(
            np.concatenate([r.endpoints_w for r in rows]),
            np.concatenate([r.axes for r in rows]),
            np.concatenate([r.offsets for r in rows]),
            np.concatenate([r.right for r in rows]),
        )


@dataclass(frozen=True)
class LineRowErrors:
    """The values of M `LineErrorRows` at a pose, with Jacobians (depth clamped where not valid).

    Attributes
    ----------
    residual : (M,) ``axis . x + offset`` [px, or whitened units for scaled rows].
    jac_pose : (M, 6) derivative w.r.t. the left perturbation ``delta`` of ``T_c_w``.
    jac_endpoint : (M, 3) derivative w.r.t. the row's world endpoint.
    valid : (M,) bool, the endpoint lies deeper than ``min_depth`` in the left camera.
    """

    residual: np.ndarray
    jac_pose: np.ndarray
    jac_endpoint: np.ndarray
    valid: np.ndarray


def line_vertical_rows(
    start_w: np.ndarray, end_w: np.ndarray, start_px: np.ndarray, end_px: np.ndarray, right: bool = False
) -> LineErrorRows:
    """The 2N rows of `line_vertical_error`: row ``2i`` the start term, ``2i + 1`` the end term of segment i.

    Parameters as in `line_vertical_error`; with ``right`` the detected endpoints are in
    the right image and the rows measure the right-image projections.
    """
    line = detected_line_coefficients(start_px, end_px)
    return _segment_rows(start_w, end_w, line[:, :2], line[:, 2], line[:, 2], right)


def line_horizontal_rows(
    start_w: np.ndarray, end_w: np.ndarray, start_px: np.ndarray, end_px: np.ndarray
) -> LineErrorRows:
    """The 2N rows of `line_horizontal_error`, ordered as in `line_vertical_rows`."""
    direction = detected_line_directions(start_px, end_px)
    return _segment_rows(
        start_w, end_w, direction, -_row_dot(direction, start_px), -_row_dot(direction, end_px), right=False
    )


def line_row_errors(
    camera: StereoCamera, T_c_w: np.ndarray, rows: LineErrorRows, min_depth: float = MIN_DEPTH
) -> LineRowErrors:
    """The values of line error rows at ``T_c_w`` (4, 4), or one pose per row (M, 4, 4), with Jacobians.

    An endpoint at depth ``<= min_depth`` [m] is projected at that depth and flags its row
    not valid (module docstring). The rows are `pld_slam.optim.point_reprojection.stereo_row_errors`
    with `LineErrorRows.stereo_axes`.
    """
    errors = stereo_row_errors(camera, T_c_w, rows.endpoints_w, rows.stereo_axes, rows.offsets, min_depth)
    return LineRowErrors(errors.residual, errors.jac_pose, errors.jac_point, errors.valid)


def line_vertical_error(
    camera: StereoCamera,
    T_c_w: np.ndarray,
    start_w: np.ndarray,
    end_w: np.ndarray,
    start_px: np.ndarray,
    end_px: np.ndarray,
    min_depth: float = MIN_DEPTH,
) -> LineReprojection:
    """Signed pixel distances of the projected endpoints to the detected infinite line.

    The paper's ``(d_s, d_e)``: ``(l . [p, 1], l . [q, 1])`` with ``l`` from
    `detected_line_coefficients`; sliding ``s`` or ``e`` along their line leaves it unchanged.

    Parameters
    ----------
    camera : the rectified stereo camera (left image).
    T_c_w : (4, 4) world-to-left-camera pose.
    start_w, end_w : (N, 3) world endpoints ``P``, ``Q`` of the 3D segments [m].
    start_px, end_px : (N, 2) detected endpoints ``s``, ``e`` in the left image [px].
    min_depth : smallest depth [m] at which an endpoint counts as in front of the camera.
    """
    rows = line_vertical_rows(start_w, end_w, start_px, end_px)
    return _two_row_error(line_row_errors(camera, T_c_w, rows, min_depth))


def line_horizontal_error(
    camera: StereoCamera,
    T_c_w: np.ndarray,
    start_w: np.ndarray,
    end_w: np.ndarray,
    start_px: np.ndarray,
    end_px: np.ndarray,
    min_depth: float = MIN_DEPTH,
) -> LineReprojection:
    """Signed offsets along the detected line of the projected endpoints from the detected ones.

    ``((p - s) . d, (q - e) . d)`` with ``d = (e - s) / |e - s|``: positive when the
    projected endpoint lies beyond its detected endpoint in the direction ``s -> e``.
    Parameters as in `line_vertical_error`.
    """
    rows = line_horizontal_rows(start_w, end_w, start_px, end_px)
    return _two_row_error(line_row_errors(camera, T_c_w, rows, min_depth))


def _segment_rows(
    start_w: np.ndarray,
    end_w: np.ndarray,
    axis: np.ndarray,
    offset_start: np.ndarray,
    offset_end: np.ndarray,
    right: bool,
) -> LineErrorRows:
    """Rows ``axis . p + offset_start``, ``axis . q + offset_end`` of N segments, interleaved (2N rows).

    ``axis`` (N, 2) is shared by both rows of a segment, ``p``, ``q`` are the projections
    of ``start_w``, ``end_w`` (N, 3).
    """
    return LineErrorRows(
        endpoints_w=np.stack([start_w, end_w], axis=1).reshape(-1, 3),
        axes=np.repeat(axis, 2, axis=0),
        offsets=np.column_stack([offset_start, offset_end]).ravel(),
        right=np.full(2 * len(start_w), right),
    )


def _two_row_error(row_errors: LineRowErrors) -> LineReprojection:
    """The `LineReprojection` of N segments from their 2N interleaved row errors."""
    n = len(row_errors.residual) // 2
    jac_start = np.zeros((n, 2, 3))
    jac_start[:, 0] = row_errors.jac_endpoint[0::2]
    jac_end = np.zeros((n, 2, 3))
    jac_end[:, 1] = row_errors.jac_endpoint[1::2]
    return LineReprojection(
        residual=row_errors.residual.reshape(n, 2),
        jac_pose=row_errors.jac_pose.reshape(n, 2, 6),
        jac_start=jac_start,
        jac_end=jac_end,
        valid=row_errors.valid[0::2] & row_errors.valid[1::2],
    )


def _row_dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise dot products (N,) of two (N, k) arrays."""
    return np.einsum("ij,ij->i", a, b)
