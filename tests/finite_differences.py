"""Finite-difference Jacobians and random camera set-ups shared by the residual and solver tests."""

from collections.abc import Callable

import numpy as np

from pld_slam.geometry.camera import StereoCamera
from pld_slam.geometry.se3 import inverse, se3_exp, transform_points

CAMERA = StereoCamera(
    fx=707.0912, fy=707.0912, cx=601.8873, cy=183.1104, baseline=0.537, width=1241, height=376
)
EPS = 1e-6
RTOL = 1e-6


def random_pose(rng: np.random.Generator) -> np.ndarray:
    """A random ``T_c_w`` (4, 4): any rotation up to 1 rad, translation within 5 m."""
    return se3_exp(np.concatenate([rng.uniform(-5.0, 5.0, 3), rng.uniform(-0.6, 0.6, 3)]))


def random_points_in_view(rng: np.random.Generator, T_c_w: np.ndarray, n: int) -> np.ndarray:
    """World points (n, 3) in front of the camera ``T_c_w``, 3 to 40 m deep, mostly in the image."""
    p_c = rng.uniform([-8.0, -2.0, 3.0], [8.0, 2.0, 40.0], size=(n, 3))
    return transform_points(inverse(T_c_w), p_c)


def pose_jacobian_by_central_differences(
    residual_of_pose: Callable[[np.ndarray], np.ndarray], T_c_w: np.ndarray
) -> np.ndarray:
    """Jacobian (N, k, 6) of a residual (N, k) w.r.t. ``delta`` in ``se3_exp(delta) @ T_c_w``."""
    columns = []
    for axis in np.eye(6):
        plus = residual_of_pose(se3_exp(EPS * axis) @ T_c_w)
        minus = residual_of_pose(se3_exp(-EPS * axis) @ T_c_w)
        columns.append((plus - minus) / (2.0 * EPS))
    return np.stack(columns, axis=-1)


def point_jacobian_by_central_differences(
    residual_of_points: Callable[[np.ndarray], np.ndarray], points: np.ndarray
) -> np.ndarray:
    """Jacobian (N, k, 3) of a residual (N, k) whose row i depends only on ``points[i]`` (N, 3)."""
    columns = []
    for axis in np.eye(3):
        plus = residual_of_points(points + EPS * axis)
        minus = residual_of_points(points - EPS * axis)
        columns.append((plus - minus) / (2.0 * EPS))
    return np.stack(columns, axis=-1)


def assert_jacobian_matches(numeric: np.ndarray, analytic: np.ndarray) -> None:
    """Each observation's Jacobian agrees to ``RTOL`` relative to its largest entry."""
    scale = np.max(np.abs(analytic), axis=tuple(range(1, analytic.ndim)), keepdims=True)
    assert np.all(np.abs(numeric - analytic) <= RTOL * scale + 1e-12)
