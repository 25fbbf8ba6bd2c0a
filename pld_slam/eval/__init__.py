"""Accuracy of trajectories: ATE and RPE through evo, the KITTI devkit drift, and plots.

`evaluate` is the one call most users need; `associate`, `fit_alignment`, `ate_errors`
and `relative_pose_errors` are its steps, `kitti_relative_errors` the devkit metric, and
`plot_trajectory_top_view` / `plot_error_over_time` write PNGs of the same comparison.
"""

from pld_slam.eval.kitti_devkit import kitti_relative_errors, segment_errors
from pld_slam.eval.metrics import (
    ALIGNMENTS,
    Alignment,
    EvalResult,
    associate,
    ate_errors,
    evaluate,
    fit_alignment,
    relative_pose_errors,
)
from pld_slam.eval.plots import plot_error_over_time, plot_trajectory_top_view

__all__ = [
    "ALIGNMENTS",
    "Alignment",
    "EvalResult",
    "associate",
    "ate_errors",
    "evaluate",
    "fit_alignment",
    "kitti_relative_errors",
    "plot_error_over_time",
    "plot_trajectory_top_view",
    "relative_pose_errors",
    "segment_errors",
]
