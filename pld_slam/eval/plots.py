"""PNG plots of a trajectory against its ground truth, drawn off-screen (Agg).

Figures are built with ``matplotlib.figure.Figure`` rather than pyplot, so plotting never
needs a display and never touches the global pyplot state of the caller.
"""

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from pld_slam.eval.metrics import associate, ate_errors, fit_alignment
from pld_slam.trajectory import Trajectory

FIGURE_SIZE_IN = (6.4, 4.8)
DPI = 100


def save_figure(figure: Figure, path_png) -> None:
    """Lay out ``figure`` and write it as a PNG at `DPI`."""
    figure.tight_layout()
    figure.savefig(Path(path_png), format="png", dpi=DPI)


def plot_trajectory_top_view(
    path_png,
    groundtruth: Trajectory | None,
    estimate: Trajectory,
    title: str = "Trajectory, top view",
    align: str = "se3",
    by_index: bool = False,
    max_diff: float = 0.01,
    loop_edges: np.ndarray | None = None,
) -> None:
    """Write the x-z plane (seen from above) of the estimate and ground truth as a PNG.

    In the camera convention of the world frame (world = first camera: x right, y down,
    z forward) the x-z plane is the ground plane, so this is the bird's-eye view with
    forward pointing up the page. The whole estimate is moved by the same alignment as
    the ATE (`fit_alignment` on the matched poses; ``align``, ``by_index`` and
    ``max_diff`` as in `pld_slam.eval.metrics.evaluate`). Without ground truth the
    estimate is drawn as it is. ``loop_edges`` (K, 2): timestamps [s] of the two ends of
    each closed loop, drawn as red segments between the estimate's nearest poses.
    """
    figure = Figure(figsize=FIGURE_SIZE_IN)
    axes = figure.add_subplot()
    if groundtruth is not None:
        estimate = aligned_onto(groundtruth, estimate, align, by_index, max_diff)
        gt_xz = groundtruth.positions[:, [0, 2]]
        axes.plot(gt_xz[:, 0], gt_xz[:, 1], "k--", label="ground truth")
    est_xz = estimate.positions[:, [0, 2]]
    axes.plot(est_xz[:, 0], est_xz[:, 1], "b-", label="estimate")
    axes.plot(est_xz[0, 0], est_xz[0, 1], "go", label="start")
    for n, ends in enumerate(np.zeros((0, 2)) if loop_edges is None else loop_edges):
        rows = np.abs(estimate.timestamps[None, :] - np.asarray(ends)[:, None]).argmin(axis=1)
        axes.plot(est_xz[rows, 0], est_xz[rows, 1], "r-o", markersize=3, label="loop" if n == 0 else None)
    finish_top_view(axes, title)
    save_figure(figure, path_png)


def aligned_onto(
    groundtruth: Trajectory, estimate: Trajectory, align: str = "se3", by_index: bool = False, max_diff: float = 0.01
) -> Trajectory:
    """The whole ``estimate`` moved by the alignment of its matched poses onto ``groundtruth`` (as the ATE)."""
    gt_matched, est_matched = associate(groundtruth, estimate, by_index, max_diff)
    return fit_alignment(gt_matched, est_matched, align).apply(estimate)


def finish_top_view(axes, title: str) -> None:
    """Equal axes, x-z labels, title, grid and legend of a top-view plot."""
    axes.set_aspect("equal", adjustable="datalim")
    axes.set_xlabel("x [m] (right)")
    axes.set_ylabel("z [m] (forward)")
    axes.set_title(title)
    axes.grid(True, alpha=0.3)
    axes.legend()


def plot_error_over_time(
    path_png,
    groundtruth: Trajectory,
    estimate: Trajectory,
    title: str = "Absolute trajectory error",
    align: str = "se3",
    by_index: bool = False,
    max_diff: float = 0.01,
) -> None:
    """Write the ATE position error of each matched pose against time as a PNG.

    Time runs from the first matched estimate pose [s]; the errors are those of
    `ate_errors` with the same ``align``, ``by_index`` and ``max_diff``.
    """
    timestamps, errors = ate_errors(groundtruth, estimate, align, by_index, max_diff)
    figure = Figure(figsize=FIGURE_SIZE_IN)
    axes = figure.add_subplot()
    axes.plot(timestamps - timestamps[0], errors, "b-")
    axes.set_xlabel("time [s]")
    axes.set_ylabel("position error [m]")
    axes.set_ylim(bottom=0.0)
    axes.set_title(title)
    axes.grid(True, alpha=0.3)
    save_figure(figure, path_png)
