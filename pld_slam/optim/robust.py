"""Robust estimation shared by every solver: the Huber loss and the chi-square inlier bounds.

Residuals are whitened (divided by their sigma) before they reach a solver, so the loss
scale and the bounds are in units of standard deviations.
"""

import numpy as np

CHI2_95_2DOF = 5.991
"""95% quantile of the chi-square distribution with 2 dof: the test of a line term."""
CHI2_95_3DOF = 7.815
"""95% quantile of the chi-square distribution with 3 dof: the test of a stereo point."""
CHI2_95_4DOF = 9.488
"""95% quantile of the chi-square distribution with 4 dof: the test of a line's vertical term in both images."""
HUBER_SCALE = float(np.sqrt(3.841))
"""Default Huber scale [whitened units]: sqrt of the 1-dof 95% chi-square quantile."""


def huber_without_curvature(z: np.ndarray) -> np.ndarray:
    """Huber loss of squared scaled residuals ``z`` (m,) for `least_squares`: rows rho, rho', 0 (3, m).

    ``rho(z) = z`` for ``z <= 1``, ``2 sqrt(z) - 1`` beyond, as scipy's ``"huber"``, but with
    the second derivative reported as 0. scipy's trust-region model scales each row by
    ``sqrt(rho' + 2 z rho'')`` (Triggs' correction); beyond the scale that is
    ``sqrt(z**-0.5 - z**-0.5) = 0``, clipped to ``sqrt(EPS)``: every residual beyond the
    scale drops out of the model. From a constant-velocity guess (0.2 m / 1 deg off) most
    residuals start there, and with scipy's ``"huber"`` the first round took a median of
    15.5 evaluations (``tr_solver="exact"``) or failed to converge in 100 (``"lsmr"``).
    With rho'' = 0 the rows are scaled by ``sqrt(rho')``, the iteratively reweighted
    least-squares model of g2o (ORB-SLAM2), which is also what Ceres' Corrector does
    whenever rho'' <= 0: 5 evaluations, the same optimum (cost and gradient are unchanged).
    """
    root = np.sqrt(z)
    rho = np.zeros((3, len(z)))
    rho[0] = np.where(z <= 1.0, z, 2.0 * root - 1.0)
    rho[1] = 1.0 / np.maximum(root, 1.0)  # 1 within the scale, z**-0.5 beyond
    return rho
