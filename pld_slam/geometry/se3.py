"""SE(3) and SO(3) on plain 4x4 / 3x3 float64 arrays.

Poses are named ``T_a_b``: they map a point expressed in frame b into frame a,
``p_a = T_a_b @ p_b``. Twists are ``xi = (rho, phi)``: translation part first, then the
rotation vector, so that ``exp(xi)`` is ``[[exp(phi^), J(phi) rho], [0, 1]]``.
"""

import numpy as np

_SMALL_ANGLE = 1e-8


def hat(w: np.ndarray) -> np.ndarray:
    """Skew-symmetric matrix of a 3-vector, ``hat(w) @ v == cross(w, v)``. Shape (3, 3)."""
    wx, wy, wz = w
    return np.array([[0.0, -wz, wy], [wz, 0.0, -wx], [-wy, wx, 0.0]])


def so3_exp(phi: np.ndarray) -> np.ndarray:
    """Rotation matrix (3, 3) of a rotation vector ``phi`` (3,) [rad] (Rodrigues)."""
    phi = np.asarray(phi, dtype=np.float64)
    theta = np.linalg.norm(phi)
    K = hat(phi)
    if theta < _SMALL_ANGLE:
        return np.eye(3) + K + 0.5 * K @ K
    return (
        np.eye(3)
        + (np.sin(theta) / theta) * K
        + ((1.0 - np.cos(theta)) / theta**2) * K @ K
    )


def so3_log(R: np.ndarray) -> np.ndarray:
    """Rotation vector (3,) [rad] of a rotation matrix (3, 3); angle in [0, pi]."""
    cos_theta = np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)
    theta = np.arccos(cos_theta)
    vee = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    if theta < 1e-6:
        return 0.5 * vee
    if np.pi - theta < 1e-4:
        # Near pi the antisymmetric part vanishes: read the axis off R + I.
        B = 0.5 * (R + np.eye(3))
        axis = np.sqrt(np.clip(np.diag(B), 0.0, None))
        k = int(np.argmax(axis))
        axis = B[k] / axis[k]
        axis /= np.linalg.norm(axis)
        if np.dot(axis, vee) < 0.0:
            axis = -axis
        return theta * axis
    return theta / (2.0 * np.sin(theta)) * vee


def so3_left_jacobian(phi: np.ndarray) -> np.ndarray:
    """SO(3) left Jacobian J(phi), shape (3, 3)."""
    theta = np.linalg.norm(phi)
    K = hat(phi)
    if theta < _SMALL_ANGLE:
        return np.eye(3) + 0.5 * K
    return (
        np.eye(3)
        + ((1.0 - np.cos(theta)) / theta**2) * K
        + ((theta - np.sin(theta)) / theta**3) * K @ K
    )


def se3_left_jacobian(xi: np.ndarray) -> np.ndarray:
    """SE(3) left Jacobian (6, 6) of a twist ``xi = (rho, phi)`` (6,).

    ``se3_exp(xi + d) = se3_exp(J @ d) @ se3_exp(xi)`` to first order in ``d``;
    ``J = [[J_l(phi), Q(rho, phi)], [0, J_l(phi)]]`` (Barfoot, State Estimation for
    Robotics, eq. 7.85-7.86).
    """
    rho, phi = xi[:3], xi[3:]
    J = np.zeros((6, 6))
    J[:3, :3] = J[3:, 3:] = so3_left_jacobian(phi)
    J[:3, 3:] = _translation_coupling(rho, phi)
    return J


_COUPLING_SERIES_BELOW = 1e-2
"""Angle [rad] below which `_translation_coupling` uses its series: the closed form's
coefficients cancel catastrophically for small angles (``(theta^2/2 + cos - 1) / theta^4``)."""


def _translation_coupling(rho: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """The block ``Q(rho, phi)`` (3, 3) of the SE(3) left Jacobian; series below 1e-2 rad."""
    theta = np.linalg.norm(phi)
    R, P = hat(rho), hat(phi)
    if theta < _COUPLING_SERIES_BELOW:
        t2 = theta * theta
        c1, c2, c3 = 1 / 6 - t2 / 120, 1 / 24 - t2 / 720, 1 / 120 - t2 / 2520
    else:
        s, c = np.sin(theta), np.cos(theta)
        c1 = (theta - s) / theta**3
        c2 = (theta * theta / 2 + c - 1) / theta**4
        c3 = (2 * theta - 3 * s + theta * c) / (2 * theta**5)
    PRP = P @ R @ P
    return (
        0.5 * R
        + c1 * (P @ R + R @ P + PRP)
        + c2 * (P @ P @ R + R @ P @ P - 3 * PRP)
        + c3 * (PRP @ P + P @ PRP)
    )


def se3_exp(xi: np.ndarray) -> np.ndarray:
    """Pose (4, 4) of a twist ``xi = (rho, phi)`` (6,)."""
    xi = np.asarray(xi, dtype=np.float64)
    T = np.eye(4)
    T[:3, :3] = so3_exp(xi[3:])
    T[:3, 3] = so3_left_jacobian(xi[3:]) @ xi[:3]
    return T


def se3_log(T: np.ndarray) -> np.ndarray:
    """Twist ``(rho, phi)`` (6,) of a pose (4, 4); inverse of `se3_exp`."""
    phi = so3_log(T[:3, :3])
    rho = np.linalg.solve(so3_left_jacobian(phi), T[:3, 3])
    return np.concatenate([rho, phi])


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


def rotation_angle(R: np.ndarray) -> np.ndarray:
    """Rotation angle [rad] of a rotation (3, 3) or a stack (N, 3, 3), in [0, pi]."""
    trace = np.trace(R, axis1=-2, axis2=-1)
    return np.arccos(np.clip((trace - 1.0) / 2.0, -1.0, 1.0))


def transform_points(T_a_b: np.ndarray, p_b: np.ndarray) -> np.ndarray:
    """Points (N, 3) in frame b mapped into frame a, by one pose (4, 4) or one pose per point (N, 4, 4)."""
    if T_a_b.ndim == 3:
        return np.einsum("nij,nj->ni", T_a_b[:, :3, :3], p_b) + T_a_b[:, :3, 3]
    return p_b @ T_a_b[:3, :3].T + T_a_b[:3, 3]
