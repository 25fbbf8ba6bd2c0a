"""Residuals with analytic Jacobians and the least-squares solvers built on them.

Every stage that optimises (tracking, local BA, loop verification, global BA) uses these
residuals; none writes its own. Poses are ``T_c_w`` (world to left camera), perturbed on
the left, ``T_c_w <- se3_exp(delta) @ T_c_w`` with ``delta = (rho, phi)``; residuals are
predicted minus observed, in pixels (see `point_reprojection` and `line_reprojection`).
"""

from pld_slam.optim.line_reprojection import (
    LineReprojection,
    detected_line_coefficients,
    detected_line_directions,
    endpoints_away_from_border,
    line_horizontal_error,
    line_vertical_error,
)
from pld_slam.optim.observations import LineObservations, ObservationMasks, PointObservations
from pld_slam.optim.point_reprojection import (
    MIN_DEPTH,
    PointReprojection,
    StereoProjection,
    point_reprojection_error,
    project_stereo_with_jacobians,
)
from pld_slam.optim.pose_only import (
    PoseOnlyOptions,
    PoseOnlyResult,
    PoseOnlyStatus,
    optimize_pose,
    optimize_pose_rejecting_outliers,
)
from pld_slam.optim.robust import CHI2_95_2DOF, CHI2_95_3DOF, HUBER_SCALE, huber_without_curvature

__all__ = [
    "CHI2_95_2DOF",
    "CHI2_95_3DOF",
    "HUBER_SCALE",
    "MIN_DEPTH",
    "LineObservations",
    "LineReprojection",
    "ObservationMasks",
    "PointObservations",
    "PointReprojection",
    "PoseOnlyOptions",
    "PoseOnlyResult",
    "PoseOnlyStatus",
    "StereoProjection",
    "detected_line_coefficients",
    "detected_line_directions",
    "endpoints_away_from_border",
    "huber_without_curvature",
    "line_horizontal_error",
    "line_vertical_error",
    "optimize_pose",
    "optimize_pose_rejecting_outliers",
    "point_reprojection_error",
    "project_stereo_with_jacobians",
]
