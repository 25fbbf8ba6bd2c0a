"""The relative-pose residual of a pose graph, with its Jacobians.

An edge between keyframes ``i`` and ``j`` measures ``T_i_j``, the pose of camera ``j`` in
camera ``i`` (``T_ci_cj = T_ci_w @ inverse(T_cj_w)``). Its residual is the twist

    r = log(inverse(T_i_j) @ T_ci_w @ inverse(T_cj_w))      (6,), (rho, phi)

zero when the two poses agree with the measurement. Poses are updated on the left,
``T_c_w = se3_exp(delta) @ T_c_w_0``, so with ``E`` the pose inside the log:

    dr / d delta_i =  J_l(r)^-1  Ad(inverse(T_i_j))  J_l(delta_i)
    dr / d delta_j = -J_l(r)^-1  Ad(E)               J_l(delta_j)

(``exp(a + e) = exp(J_l(a) e) exp(a)`` and ``log(exp(e) E) = r + J_l(r)^-1 e`` to first
order; `tests/test_relative_pose.py` checks both against finite differences, far from the
solution too, where the loop edge of a pose graph starts).
"""

from dataclasses import dataclass

import numpy as np

from pld_slam.geometry.se3 import inverse, se3_adjoint, se3_exp, se3_left_jacobian, se3_log


@dataclass(frozen=True)
class RelativePoseResidual:
    """Residuals (E, 6) of E edges and their Jacobians (E, 6, 6) w.r.t. the two endpoint updates."""

    residual: np.ndarray
    jac_i: np.ndarray
    jac_j: np.ndarray


def relative_pose_residual(
    delta_i: np.ndarray, delta_j: np.ndarray, T_i_w0: np.ndarray, T_j_w0: np.ndarray, T_i_j: np.ndarray
) -> RelativePoseResidual:
    """Residuals and Jacobians of E relative-pose edges (module docstring).

    Parameters
    ----------
    delta_i, delta_j : (E, 6) left updates of the two endpoints' ``T_c_w``.
    T_i_w0, T_j_w0 : (E, 4, 4) the endpoints' ``T_c_w`` before the updates.
    T_i_j : (E, 4, 4) measured pose of camera j in camera i.
    """
    measured_inverse = inverse(T_i_j)
    error = relative_pose_error(se3_exp(delta_i) @ T_i_w0, se3_exp(delta_j) @ T_j_w0, T_i_j)
    residual = se3_log(error)
    log_jacobian = np.linalg.inv(se3_left_jacobian(residual))
    jac_i = log_jacobian @ se3_adjoint(measured_inverse) @ se3_left_jacobian(delta_i)
    jac_j = -log_jacobian @ se3_adjoint(error) @ se3_left_jacobian(delta_j)
    return RelativePoseResidual(residual, jac_i, jac_j)


def relative_pose_error(T_i_w: np.ndarray, T_j_w: np.ndarray, T_i_j: np.ndarray) -> np.ndarray:
    """The poses ``E = inverse(T_i_j) @ T_ci_w @ inverse(T_cj_w)`` (E, 4, 4) inside the log of the
    module docstring, of E edges between poses ``T_i_w``, ``T_j_w`` (E, 4, 4) measured as ``T_i_j``;
    ``se3_log`` of it is the residual, for a solver that needs no Jacobian at a point."""
    return inverse(T_i_j) @ T_i_w @ inverse(T_j_w)
