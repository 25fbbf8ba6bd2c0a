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
"""

from dataclasses import dataclass

import numpy as np

from pld_slam.geometry.camera import StereoCamera
from pld_slam.optim.point_reprojection import MIN_DEPTH, project_stereo_with_jacobians


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
    endpoints = np.stack([start_px, end_px], axis=1)
    high = np.array([camera.width - 1.0 - margin_px, camera.height - 1.0 - margin_px])
    return np.all((endpoints >= margin_px) & (endpoints <= high), axis=(1, 2))


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
    line = detected_line_coefficients(start_px, end_px)
    return _projected_endpoints_along_axis(
        camera, T_c_w, start_w, end_w, line[:, :2], line[:, 2], line[:, 2], min_depth
    )


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
    direction = detected_line_directions(start_px, end_px)
    return _projected_endpoints_along_axis(
        camera,
        T_c_w,
        start_w,
        end_w,
        direction,
        -_row_dot(direction, start_px),
        -_row_dot(direction, end_px),
        min_depth,
    )


def _projected_endpoints_along_axis(
    camera: StereoCamera,
    T_c_w: np.ndarray,
    start_w: np.ndarray,
    end_w: np.ndarray,
    axis: np.ndarray,
    offset_start: np.ndarray,
    offset_end: np.ndarray,
    min_depth: float,
) -> LineReprojection:
    """The affine functions ``axis . p + offset_start`` and ``axis . q + offset_end`` with Jacobians.

    Both line errors have this form, with ``axis`` (N, 2) a unit vector in the image and
    ``p``, ``q`` the left-image projections of ``start_w``, ``end_w`` (N, 3).
    """
    start = project_stereo_with_jacobians(camera, T_c_w, start_w, min_depth)
    end = project_stereo_with_jacobians(camera, T_c_w, end_w, min_depth)
    residual = np.column_stack(
        [_row_dot(axis, start.pixels[:, :2]) + offset_start, _row_dot(axis, end.pixels[:, :2]) + offset_end]
    )
    jac_start = np.zeros((len(axis), 2, 3))
    jac_start[:, 0] = _left_pixel_jacobian_along(axis, start.jac_point)
    jac_end = np.zeros((len(axis), 2, 3))
    jac_end[:, 1] = _left_pixel_jacobian_along(axis, end.jac_point)
    jac_pose = np.stack(
        [_left_pixel_jacobian_along(axis, start.jac_pose), _left_pixel_jacobian_along(axis, end.jac_pose)],
        axis=1,
    )
    return LineReprojection(residual, jac_pose, jac_start, jac_end, valid=start.valid & end.valid)


def _row_dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise dot products (N,) of two (N, k) arrays."""
    return np.einsum("ij,ij->i", a, b)


def _left_pixel_jacobian_along(axis: np.ndarray, stereo_jacobian: np.ndarray) -> np.ndarray:
    """``axis . d(u_left, v)`` (N, k) for image axes (N, 2) and a stereo-pixel Jacobian (N, 3, k)."""
    return np.einsum("ij,ijk->ik", axis, stereo_jacobian[:, :2])
