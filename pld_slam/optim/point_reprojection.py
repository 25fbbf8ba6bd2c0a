"""Stereo point reprojection error with analytic Jacobians.

Pose convention, shared by every residual of `pld_slam.optim`
-------------------------------------------------------------
The optimised pose is ``T_c_w`` (world to left camera): one (4, 4) for all observations
(pose-only), or one per observation (bundle adjustment: K poses and each row's index). It
is perturbed on the left, ``T_c_w <- se3_exp(delta) @ T_c_w``, with the twist
``delta = (rho, phi)`` (translation first, as in `pld_slam.geometry.se3`). A camera-frame
point ``p_c = R p_w + t`` then moves by ``d p_c / d delta = [I, -hat(p_c)]`` (3, 6), and
``d p_c / d p_w = R`` (3, 3).

Residuals are *predicted minus observed*, in pixels.

Points at or behind the camera
------------------------------
A point whose camera-frame depth is at most ``min_depth`` has no meaningful projection.
It is flagged ``valid = False`` and projected as if its depth were ``min_depth`` (the
depth is clamped; the Jacobians are those of the clamped projection, so they stay exact).
We do not zero its residual: a zero would reward a solver for pushing points behind the
camera (moving everything behind it would cost nothing), whereas the clamped projection
lands far outside the image and keeps the cost continuous, a wall at ``min_depth``.
Callers treat invalid observations as outliers.

Rows
----
Every residual of the solvers is an affine function of a point's stereo pixels,
``a . (u_left, v, u_right) + b``, with a fixed axis ``a`` (3,) and offset ``b``: a pixel
of a point (unit axis), a whitened disparity ``(u_left - u_right) / sigma_d``
(`pld_slam.optim.observations`), a line's vertical or horizontal error in either image
(`pld_slam.optim.line_reprojection`). `stereo_row_errors` evaluates such rows, one world
point and one pose each, with their pose and point Jacobians; it is the one
implementation of the projection every residual and solver uses (`point_reprojection_error`
is its rows with unit axes).

Speed. The solvers evaluate their rows at every iteration (pose-only tracking ~9 solves
per frame, local BA ~12 evaluations of ~21,000 rows per keyframe), so the rows are
evaluated by one numba kernel (`_stereo_row_kernel`), each row's pose read through an
index instead of a gathered (K, 4, 4) copy. The numpy version it replaced built the
(N, 3, 3) pixel Jacobians, then the pose Jacobians by cross products and the point ones
by batched products with the rotations, point and line rows apart, then whitened and
concatenated them: on 12 local BA problems saved from KITTI 06 (21,700 rows), one
evaluation of every row (`pld_slam.optim.bundle_adjustment`) took 3.1 ms, now 0.8 ms
(median over the problems of the fastest of 5), to the same values within 1e-12. One
kernel for points and lines, rather than one each and a third for the point whitening,
also compiles faster: 0.35 s (three kernels: 1.8 s), once per machine.
The compiled kernel is cached on disk (`pld_slam.jit`).
"""

from dataclasses import dataclass

import numpy as np

from pld_slam.geometry.camera import StereoCamera
from pld_slam.jit import kernel

MIN_DEPTH = 1e-3
"""Default smallest camera-frame depth [m] at which a point still projects."""


@dataclass(frozen=True)
class StereoProjection:
    """Stereo pixels of N world points and their Jacobians (depth clamped where not valid).

    Attributes
    ----------
    pixels : (N, 3) predicted ``(u_left, v, u_right)`` [px].
    jac_pose : (N, 3, 6) derivative w.r.t. the left perturbation ``delta`` of ``T_c_w``.
    jac_point : (N, 3, 3) derivative w.r.t. the world point ``p_w``.
    valid : (N,) bool, the point lies deeper than ``min_depth`` in the left camera.
    """

    pixels: np.ndarray
    jac_pose: np.ndarray
    jac_point: np.ndarray
    valid: np.ndarray


@dataclass(frozen=True)
class PointReprojection:
    """Stereo reprojection residuals of N points and their Jacobians (depth clamped where not valid).

    Attributes
    ----------
    residual : (N, 3) ``project_stereo(T_c_w p_w) - (u_left, v, u_right)`` [px].
    jac_pose : (N, 3, 6) derivative w.r.t. the left perturbation ``delta`` of ``T_c_w``.
    jac_point : (N, 3, 3) derivative w.r.t. the world point ``p_w``.
    valid : (N,) bool, the point lies deeper than ``min_depth`` in the left camera.
    """

    residual: np.ndarray
    jac_pose: np.ndarray
    jac_point: np.ndarray
    valid: np.ndarray


@dataclass(frozen=True)
class StereoRowErrors:
    """K rows ``a . (u_left, v, u_right) + b`` of world points, with Jacobians (depth clamped where not valid).

    Attributes
    ----------
    residual : (K,) the rows' values.
    jac_pose : (K, 6) derivative w.r.t. the left perturbation ``delta`` of the row's ``T_c_w``.
    jac_point : (K, 3) derivative w.r.t. the row's world point.
    valid : (K,) bool, the row's point lies deeper than ``min_depth`` in the left camera.
    """

    residual: np.ndarray
    jac_pose: np.ndarray
    jac_point: np.ndarray
    valid: np.ndarray


def poses_and_index(T_c_w: np.ndarray, n: int, pose_index: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """The poses of ``n`` rows as the kernel takes them: poses (K, 4, 4) and the pose of each row (n,).

    ``T_c_w`` is one pose (4, 4) for all rows, one per row (n, 4, 4), or, with
    ``pose_index`` (n,), K poses (K, 4, 4) shared by the rows (bundle adjustment: no
    (n, 4, 4) copy per evaluation).
    """
    T_c_w = np.ascontiguousarray(T_c_w, dtype=np.float64)
    if pose_index is not None:
        return T_c_w, np.ascontiguousarray(pose_index, dtype=np.int64)
    if T_c_w.ndim == 3:
        return T_c_w, np.arange(n)
    return T_c_w[None], np.zeros(n, dtype=np.int64)


def stereo_row_errors(
    camera: StereoCamera,
    T_c_w: np.ndarray,
    points_w: np.ndarray,
    axes: np.ndarray,
    offsets: np.ndarray,
    min_depth: float = MIN_DEPTH,
    pose_index: np.ndarray | None = None,
    with_jacobians: bool = True,
    point_index: np.ndarray | None = None,
) -> StereoRowErrors:
    """Rows ``axes . (u_left, v, u_right) + offsets`` (K,) of world points (K, 3), with Jacobians.

    Parameters
    ----------
    camera : the rectified stereo camera.
    T_c_w : (4, 4) world-to-left-camera pose, one per row (K, 4, 4), or several (P, 4, 4)
        with ``pose_index`` (`poses_and_index`).
    points_w : (K, 3) the world point of each row [m], or several (W, 3) with ``point_index``.
    axes : (K, 3) each row's weights of ``u_left``, ``v`` and ``u_right``.
    offsets : (K,) each row's constant.
    min_depth : a point at depth ``<= min_depth`` [m] is projected at that depth and flags
        its row not valid (module docstring).
    pose_index : (K,) the pose of each row in ``T_c_w`` (P, 4, 4), or None.
    with_jacobians : False computes the residuals and validity only; the Jacobians are then
        (0, 6) and (0, 3) (a solver's trial steps: no memory or time for Jacobians it may not use).
    point_index : (K,) the world point of each row in ``points_w`` (W, 3), or None (bundle
        adjustment: no (K, 3) copy of the points per evaluation).
    """
    n = len(offsets)
    poses, pose_index = poses_and_index(T_c_w, n, pose_index)
    point_index = np.arange(n) if point_index is None else np.ascontiguousarray(point_index, dtype=np.int64)
    n_jac = n if with_jacobians else 0
    errors = StereoRowErrors(np.empty(n), np.empty((n_jac, 6)), np.empty((n_jac, 3)), np.empty(n, dtype=bool))
    _stereo_row_kernel(
        np.array([camera.fx, camera.fy, camera.cx, camera.cy, camera.bf]),
        poses,
        pose_index,
        np.ascontiguousarray(points_w, dtype=np.float64),
        point_index,
        np.ascontiguousarray(axes, dtype=np.float64),
        np.ascontiguousarray(offsets, dtype=np.float64),
        float(min_depth),
        with_jacobians,
        errors.residual,
        errors.jac_pose,
        errors.jac_point,
        errors.valid,
    )
    return errors


@kernel
def _stereo_row_kernel(
    intrinsics, poses, pose_index, points_w, point_index, axes, offsets, min_depth, with_jacobians, residual, jac_pose,
    jac_point, valid
):
    """Fill the outputs of `stereo_row_errors`: residual (K,), valid (K,) and, ``with_jacobians``,
    jac_pose (K, 6) and jac_point (K, 3).

    Per row: ``p_c = R p_w + t``; depth clamped at ``min_depth``; ``u_left = fx x/z + cx``,
    ``v = fy y/z + cy``, ``u_right = u_left - bf/z``; the gradient ``g`` (3,) of the row
    w.r.t. ``p_c`` is ``a`` times the pixel Jacobian (without its depth column where
    clamped); then ``d/d delta = g [I, -hat(p_c)] = [g, p_c x g]`` and ``d/d p_w = g R``.
    The row is computed as ``(a_0 + a_2) u_left + a_1 v - a_2 bf/z``: a disparity row
    (``a_0 = -a_2``) then never subtracts two columns of ~600 px, whose rounding put its
    central-difference derivative 1.1e-6 (relative) off, beyond the tests' 1e-6.
    """
    fx, fy, cx, cy, bf = intrinsics[0], intrinsics[1], intrinsics[2], intrinsics[3], intrinsics[4]
    for i in range(len(offsets)):
        T = poses[pose_index[i]]
        point = points_w[point_index[i]]
        px, py, pz = point[0], point[1], point[2]
        x = T[0, 0] * px + T[0, 1] * py + T[0, 2] * pz + T[0, 3]
        y = T[1, 0] * px + T[1, 1] * py + T[1, 2] * pz + T[1, 3]
        z = T[2, 0] * px + T[2, 1] * py + T[2, 2] * pz + T[2, 3]
        in_front = z > min_depth
        depth = z if in_front else min_depth
        inv_z = 1.0 / depth
        depth_weight = inv_z * inv_z if in_front else 0.0
        a_v, a_right = axes[i, 1], axes[i, 2]
        a_u = axes[i, 0] + a_right  # a . (u_left, v, u_right) = a_u u_left + a_v v - a_right bf / z
        residual[i] = a_u * (fx * x / depth + cx) + a_v * (fy * y / depth + cy) - a_right * bf / depth + offsets[i]
        valid[i] = in_front
        if not with_jacobians:
            continue
        gx = a_u * fx * inv_z
        gy = a_v * fy * inv_z
        gz = (-(a_u * fx * x) - a_v * fy * y + a_right * bf) * depth_weight
        jac_pose[i, 0] = gx
        jac_pose[i, 1] = gy
        jac_pose[i, 2] = gz
        jac_pose[i, 3] = y * gz - z * gy
        jac_pose[i, 4] = z * gx - x * gz
        jac_pose[i, 5] = x * gy - y * gx
        for j in range(3):
            jac_point[i, j] = gx * T[0, j] + gy * T[1, j] + gz * T[2, j]


def project_stereo_with_jacobians(
    camera: StereoCamera, T_c_w: np.ndarray, points_w: np.ndarray, min_depth: float = MIN_DEPTH
) -> StereoProjection:
    """Stereo pixels of world points (N, 3) seen from ``T_c_w`` (4, 4) or (N, 4, 4), with Jacobians.

    Points at depth ``<= min_depth`` [m] are flagged not valid and projected at depth
    ``min_depth`` (module docstring).
    """
    error = point_reprojection_error(camera, T_c_w, points_w, np.zeros((len(points_w), 3)), min_depth)
    return StereoProjection(error.residual, error.jac_pose, error.jac_point, error.valid)


def point_reprojection_error(
    camera: StereoCamera,
    T_c_w: np.ndarray,
    points_w: np.ndarray,
    stereo_px: np.ndarray,
    min_depth: float = MIN_DEPTH,
) -> PointReprojection:
    """Stereo reprojection error of world points (N, 3) against observations (N, 3).

    Parameters
    ----------
    camera : the rectified stereo camera.
    T_c_w : (4, 4) world-to-left-camera pose, or one per point (N, 4, 4).
    points_w : (N, 3) points in the world frame [m].
    stereo_px : (N, 3) observed ``(u_left, v, u_right)`` [px].
    min_depth : smallest depth [m] at which a point counts as in front of the camera.

    Returns
    -------
    PointReprojection, residual ``predicted - observed``: the `stereo_row_errors` of unit axes.
    """
    n = len(points_w)
    poses, point_pose = poses_and_index(T_c_w, n, None)
    rows = stereo_row_errors(
        camera,
        poses,
        np.repeat(points_w, 3, axis=0),
        np.tile(np.eye(3), (n, 1)),
        -np.ravel(stereo_px),
        min_depth,
        np.repeat(point_pose, 3),
    )
    return PointReprojection(
        rows.residual.reshape(n, 3), rows.jac_pose.reshape(n, 3, 6), rows.jac_point.reshape(n, 3, 3), rows.valid[::3]
    )
