"""The pose-graph residual: zero at agreeing poses, Jacobians against finite differences."""

import numpy as np
import pytest
from finite_differences import EPS

from pld_slam.geometry.se3 import inverse, se3_exp
from pld_slam.optim.relative_pose import relative_pose_residual


def random_edges(seed: int, count: int, spread: float) -> tuple[np.ndarray, ...]:
    """Updates (E, 6) of both ends, their poses (E, 4, 4) and measurements (E, 4, 4); ``spread`` scales the updates."""
    rng = np.random.default_rng(seed)
    delta_i, delta_j = rng.normal(0.0, spread, (2, count, 6))
    T_i_w, T_j_w, T_i_j = se3_exp(rng.normal(0.0, 1.0, (3, count, 6)).reshape(-1, 6)).reshape(3, count, 4, 4)
    return delta_i, delta_j, T_i_w, T_j_w, T_i_j


def test_residual_is_zero_when_the_poses_agree_with_the_measurement():
    _, _, T_i_w, T_j_w, _ = random_edges(0, 5, 0.0)
    zero = np.zeros((5, 6))
    result = relative_pose_residual(zero, zero, T_i_w, T_j_w, T_i_w @ inverse(T_j_w))
    np.testing.assert_allclose(result.residual, 0.0, atol=1e-12)


@pytest.mark.parametrize("spread", [0.0, 0.05, 0.5])  # at the linearisation point, near it, far from it
def test_jacobians_match_central_differences(spread):
    delta_i, delta_j, T_i_w, T_j_w, T_i_j = random_edges(1, 6, spread)
    result = relative_pose_residual(delta_i, delta_j, T_i_w, T_j_w, T_i_j)
    assert np.linalg.norm(result.residual, axis=1).min() > 0.5  # large residuals: a loop edge before the solve
    for end, analytic in (("i", result.jac_i), ("j", result.jac_j)):
        numeric = np.zeros_like(analytic)
        for axis in range(6):
            step = np.zeros(6)
            step[axis] = EPS
            moved = [delta_i + step * (end == "i"), delta_j + step * (end == "j")]
            back = [delta_i - step * (end == "i"), delta_j - step * (end == "j")]
            plus = relative_pose_residual(*moved, T_i_w, T_j_w, T_i_j).residual
            minus = relative_pose_residual(*back, T_i_w, T_j_w, T_i_j).residual
            numeric[:, :, axis] = (plus - minus) / (2 * EPS)
        np.testing.assert_allclose(analytic, numeric, atol=1e-7)
