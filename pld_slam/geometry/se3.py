"""SE(3) and SO(3) on plain 4x4 / 3x3 float64 arrays.

Poses are named ``T_a_b``: they map a point expressed in frame b into frame a,
``p_a = T_a_b @ p_b``. Twists are ``xi = (rho, phi)``: translation part first, then the
rotation vector, so that ``exp(xi)`` is ``[[exp(phi^), J(phi) rho], [0, 1]]``.
"""

import numpy as np

_SMALL_ANGLE = 1e-8


def hat(w: np.ndarray) -> np.ndarray:
    """Skew-symmetric matrix of a 3-vector, ``hat(w) @ v == cross(w, v)``: (3,) -> (3, 3), or (N, 3) -> (N, 3, 3)."""
    w = np.asarray(w, dtype=np.float64)
    if w.ndim == 1:  # the common single vector, without the stacked path's overhead
        wx, wy, wz = w
        return np.array([[0.0, -wz, wy], [wz, 0.0, -wx], [-wy, wx, 0.0]])
    K = np.zeros((*w.shape[:-1], 3, 3))
    K[..., 0, 1], K[..., 0, 2], K[..., 1, 2] = -w[..., 2], w[..., 1], -w[..., 0]
    K[..., 1, 0], K[..., 2, 0], K[..., 2, 1] = w[..., 2], -w[..., 1], w[..., 0]
    return K


def _angles(phi: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Angle ``theta`` (...,), its square, and ``hat(phi)`` (..., 3, 3) of rotation vectors (..., 3)."""
    theta = np.linalg.norm(phi, axis=-1)
    return theta, theta * theta, hat(phi)


def _coefficient(theta: np.ndarray, small: np.ndarray, closed, series) -> np.ndarray:
    """``closed(theta)`` where the angle is not small, ``series(theta**2)`` where it is (...,)."""
    if np.ndim(theta) == 0:  # one angle: a plain branch, cheaper than the masked stack below
        return np.float64(series(float(theta) ** 2) if small else closed(float(theta)))
    safe = np.where(small, 1.0, theta)
    return np.where(small, series(theta * theta), closed(safe))


def _sin_over(theta: np.ndarray, small: np.ndarray) -> np.ndarray:
    return _coefficient(theta, small, lambda t: np.sin(t) / t, lambda t2: 1.0 - t2 / 6.0)


def _one_minus_cos_over(theta: np.ndarray, small: np.ndarray) -> np.ndarray:
    return _coefficient(theta, small, lambda t: (1.0 - np.cos(t)) / t**2, lambda t2: 0.5 - t2 / 24.0)


def _angle_minus_sin_over(theta: np.ndarray, small: np.ndarray) -> np.ndarray:
    return _coefficient(theta, small, lambda t: (t - np.sin(t)) / t**3, lambda t2: 1.0 / 6.0 - t2 / 120.0)


def so3_exp(phi: np.ndarray) -> np.ndarray:
    """Rotation matrix of a rotation vector ``phi`` [rad] (Rodrigues): (3,) -> (3, 3), or (N, 3) -> (N, 3, 3)."""
    theta, _, K = _angles(np.asarray(phi, dtype=np.float64))
    small = theta < _SMALL_ANGLE
    a, b = _sin_over(theta, small)[..., None, None], _one_minus_cos_over(theta, small)[..., None, None]
    return np.eye(3) + a * K + b * K @ K


def so3_log(R: np.ndarray) -> np.ndarray:
    """Rotation vector [rad] of a rotation matrix, angle in [0, pi]: (3, 3) -> (3,), or (N, 3, 3) -> (N, 3).

    The angle is ``atan2(sin, cos)`` of the antisymmetric part (``2 sin(theta) a``) and the
    trace (``1 + 2 cos(theta)``), accurate to rounding at any angle; ``arccos`` of the trace
    alone loses half the digits near 0 and pi (2e-8 rad of angle 1e-4 rad from pi).
    """
    R = np.asarray(R, dtype=np.float64)
    cos_theta = np.clip((np.trace(R, axis1=-2, axis2=-1) - 1.0) / 2.0, -1.0, 1.0)
    vee = np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], axis=-1)
    sin_theta = 0.5 * np.linalg.norm(vee, axis=-1)
    theta = np.arctan2(sin_theta, cos_theta)
    small, near_pi = theta < 1e-6, np.pi - theta < 1e-4
    general = np.where(small | near_pi, 0.5, theta / (2.0 * np.where(small | near_pi, 1.0, sin_theta)))
    phi = general[..., None] * vee
    if np.any(near_pi):
        phi = np.where(near_pi[..., None], _log_near_pi(R, theta, cos_theta, vee), phi)
    return phi


def _log_near_pi(R: np.ndarray, theta: np.ndarray, cos_theta: np.ndarray, vee: np.ndarray) -> np.ndarray:
    """Rotation vectors (..., 3) of rotations near pi, where the antisymmetric part ``vee`` vanishes and
    only gives the axis's sign: the axis from ``(1 - cos(theta)) a a^T = sym(R) - cos(theta) I``."""
    B = 0.5 * (R + np.swapaxes(R, -1, -2)) - cos_theta[..., None, None] * np.eye(3)
    diagonal = np.sqrt(np.clip(np.diagonal(B, axis1=-2, axis2=-1), 0.0, None))
    k = np.argmax(diagonal, axis=-1)
    row = np.take_along_axis(B, k[..., None, None], axis=-2)[..., 0, :]
    axis = row / np.maximum(np.take_along_axis(diagonal, k[..., None], axis=-1), 1e-300)
    axis /= np.maximum(np.linalg.norm(axis, axis=-1, keepdims=True), 1e-300)  # 0 for rotations far from pi
    axis = np.where((np.sum(axis * vee, axis=-1) < 0.0)[..., None], -axis, axis)
    return theta[..., None] * axis


def so3_left_jacobian(phi: np.ndarray) -> np.ndarray:
    """SO(3) left Jacobian J(phi): (3,) -> (3, 3), or (N, 3) -> (N, 3, 3)."""
    theta, _, K = _angles(np.asarray(phi, dtype=np.float64))
    small = theta < _SMALL_ANGLE
    b, c = _one_minus_cos_over(theta, small)[..., None, None], _angle_minus_sin_over(theta, small)[..., None, None]
    return np.eye(3) + b * K + c * K @ K


def se3_left_jacobian(xi: np.ndarray) -> np.ndarray:
    """SE(3) left Jacobian of a twist ``xi = (rho, phi)``: (6,) -> (6, 6), or (N, 6) -> (N, 6, 6).

    ``se3_exp(xi + d) = se3_exp(J @ d) @ se3_exp(xi)`` to first order in ``d``;
    ``J = [[J_l(phi), Q(rho, phi)], [0, J_l(phi)]]`` (Barfoot, State Estimation for
    Robotics, eq. 7.85-7.86).
    """
    xi = np.asarray(xi, dtype=np.float64)
    rho, phi = xi[..., :3], xi[..., 3:]
    J = np.zeros((*xi.shape[:-1], 6, 6))
    J[..., :3, :3] = J[..., 3:, 3:] = so3_left_jacobian(phi)
    J[..., :3, 3:] = _translation_coupling(rho, phi)
    return J


_COUPLING_SERIES_BELOW = 1e-2
"""Angle [rad] below which `_translation_coupling` uses its series: the closed form's
coefficients cancel catastrophically for small angles (``(theta^2/2 + cos - 1) / theta^4``)."""


def _translation_coupling(rho: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """The block ``Q(rho, phi)`` (..., 3, 3) of the SE(3) left Jacobian; series below 1e-2 rad."""
    theta, t2, P = _angles(phi)
    R = hat(rho)
    small = theta < _COUPLING_SERIES_BELOW
    c1 = _coefficient(theta, small, lambda t: (t - np.sin(t)) / t**3, lambda t2: 1 / 6 - t2 / 120)
    c2 = _coefficient(theta, small, lambda t: (t * t / 2 + np.cos(t) - 1) / t**4, lambda t2: 1 / 24 - t2 / 720)
    c3 = _coefficient(
        theta, small, lambda t: (2 * t - 3 * np.sin(t) + t * np.cos(t)) / (2 * t**5), lambda t2: 1 / 120 - t2 / 2520
    )
    c1, c2, c3 = (c[..., None, None] for c in (c1, c2, c3))
    PRP = P @ R @ P
    return (
        0.5 * R
        + c1 * (P @ R + R @ P + PRP)
        + c2 * (P @ P @ R + R @ P @ P - 3 * PRP)
        + c3 * (PRP @ P + P @ PRP)
    )


def se3_exp(xi: np.ndarray) -> np.ndarray:
    """Pose of a twist ``xi = (rho, phi)``: (6,) -> (4, 4), or (N, 6) -> (N, 4, 4)."""
    xi = np.asarray(xi, dtype=np.float64)
    T = np.zeros((*xi.shape[:-1], 4, 4))
    T[..., :3, :3] = so3_exp(xi[..., 3:])
    T[..., :3, 3] = np.einsum("...ij,...j->...i", so3_left_jacobian(xi[..., 3:]), xi[..., :3])
    T[..., 3, 3] = 1.0
    return T


def se3_log(T: np.ndarray) -> np.ndarray:
    """Twist ``(rho, phi)`` of a pose; inverse of `se3_exp`: (4, 4) -> (6,), or (N, 4, 4) -> (N, 6)."""
    phi = so3_log(T[..., :3, :3])
    rho = np.linalg.solve(so3_left_jacobian(phi), T[..., :3, 3:4])[..., 0]
    return np.concatenate([rho, phi], axis=-1)


def se3_adjoint(T: np.ndarray) -> np.ndarray:
    """Adjoint of a pose for twists ``(rho, phi)``: (4, 4) -> (6, 6), or (N, 4, 4) -> (N, 6, 6).

    ``T @ se3_exp(xi) @ inverse(T) == se3_exp(se3_adjoint(T) @ xi)``; ``[[R, hat(t) R], [0, R]]``.
    """
    R, t = T[..., :3, :3], T[..., :3, 3]
    adjoint = np.zeros((*T.shape[:-2], 6, 6))
    adjoint[..., :3, :3] = adjoint[..., 3:, 3:] = R
    adjoint[..., :3, 3:] = hat(t) @ R
    return adjoint


def make_pose(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Pose (4, 4) from a rotation (3, 3) and a translation (3,)."""
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t
    return T


def inverse(T: np.ndarray) -> np.ndarray:
    """Inverse of a pose (4, 4), or of a stack of poses (N, 4, 4), without a general solve."""
    R = T[..., :3, :3]
    t = T[..., :3, 3]
    R_inv = np.swapaxes(R, -1, -2)
    T_inv = np.zeros_like(T)
    T_inv[..., :3, :3] = R_inv
    T_inv[..., :3, 3] = -np.einsum("...ij,...j->...i", R_inv, t)
    T_inv[..., 3, 3] = 1.0
    return T_inv


def nearest_pose(T: np.ndarray) -> np.ndarray:
    """The pose (4, 4) whose rotation is the rotation nearest to ``T[:3, :3]`` (SVD projection).

    Poses built by chains of products drift off SO(3) by rounding; a chain that feeds
    back into itself (a motion model) makes the drift grow geometrically, so such chains
    re-project after each product.
    """
    U, _, Vt = np.linalg.svd(T[:3, :3])
    R = U @ Vt
    if np.linalg.det(R) < 0.0:
        R = U @ np.diag([1.0, 1.0, -1.0]) @ Vt
    return make_pose(R, T[:3, 3])


def viewpoint_change(T_w_a: np.ndarray, T_w_b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """How far apart [m] two cameras ``T_w_c`` (..., 4, 4) stand, and the angle [deg] between
    their optical axes (their z axes); NaN where either pose is NaN."""
    distance = np.linalg.norm(T_w_a[..., :3, 3] - T_w_b[..., :3, 3], axis=-1)
    axes_cos = np.einsum("...i,...i->...", T_w_a[..., :3, 2], T_w_b[..., :3, 2])
    return distance, np.degrees(np.arccos(np.clip(axes_cos, -1.0, 1.0)))


def motion_size(T: np.ndarray) -> tuple[float, float]:
    """How far [m] and how much [deg] a relative pose ``T`` (4, 4) moves and turns."""
    return float(np.linalg.norm(T[:3, 3])), float(np.degrees(rotation_angle(T[:3, :3])))


def rotation_angle(R: np.ndarray) -> np.ndarray:
    """Rotation angle [rad] of a rotation (3, 3) or a stack (N, 3, 3), in [0, pi]."""
    trace = np.trace(R, axis1=-2, axis2=-1)
    return np.arccos(np.clip((trace - 1.0) / 2.0, -1.0, 1.0))


def transform_points(T_a_b: np.ndarray, p_b: np.ndarray) -> np.ndarray:
    """Points (N, 3) in frame b mapped into frame a, by one pose (4, 4) or one pose per point (N, 4, 4)."""
    if T_a_b.ndim == 3:
        return np.einsum("nij,nj->ni", T_a_b[:, :3, :3], p_b) + T_a_b[:, :3, 3]
    return p_b @ T_a_b[:3, :3].T + T_a_b[:3, 3]


def interpolate_poses(times: np.ndarray, T: np.ndarray, at: np.ndarray) -> np.ndarray:
    """Poses (M, 4, 4) at times ``at`` (M,) of a trajectory ``T`` (N, 4, 4) sampled at
    increasing ``times`` (N,), N >= 2: between the two samples around each time, the
    translation linearly and the rotation along the geodesic (constant angular rate);
    before the first and after the last sample, extrapolated from the nearest two."""
    if len(times) < 2:
        raise ValueError(f"interpolating poses needs two samples or more, got {len(times)}")
    i = np.clip(np.searchsorted(times, at) - 1, 0, len(times) - 2)
    fraction = (at - times[i]) / (times[i + 1] - times[i])
    R0, R1 = T[i, :3, :3], T[i + 1, :3, :3]
    R = R0 @ so3_exp(fraction[:, None] * so3_log(np.swapaxes(R0, -1, -2) @ R1))
    poses = np.tile(np.eye(4), (len(at), 1, 1))
    poses[:, :3, :3] = R
    poses[:, :3, 3] = T[i, :3, 3] + fraction[:, None] * (T[i + 1, :3, 3] - T[i, :3, 3])
    return poses
