"""When two cameras see the same place: the definition the loop truth scores against and the
synthetic city builds its revisits by.

Two cameras ``T_w_c`` see the same place when their centres are within `SAME_PLACE_M` (3 m)
and their optical axes within `SAME_PLACE_DEG` (30 deg). It lives here, below evaluation
and the synthetic scenes, so that both use one definition.
"""

import numpy as np

from pld_slam.geometry.se3 import viewpoint_change

SAME_PLACE_M = 3.0
SAME_PLACE_DEG = 30.0


def same_place(
    T_w_a: np.ndarray, T_w_b: np.ndarray, max_distance_m: float = SAME_PLACE_M, max_angle_deg: float = SAME_PLACE_DEG
) -> np.ndarray:
    """Whether cameras ``T_w_c`` (..., 4, 4) stand within ``max_distance_m`` of each other with their
    optical axes within ``max_angle_deg``: (...,) bool, False where either pose is NaN."""
    distance, angle = viewpoint_change(T_w_a, T_w_b)
    with np.errstate(invalid="ignore"):
        return (distance <= max_distance_m) & (angle <= max_angle_deg)
