"""PNG plots of a trajectory against its ground truth, drawn off-screen (Agg).

Figures are built with ``matplotlib.figure.Figure`` rather than pyplot, so plotting never
needs a display and never touches the global pyplot state of the caller. Each plot has a
``*_figure`` function returning the unsaved `Figure` (what the tests inspect) and a
``plot_*`` function writing it as a PNG.
"""

import textwrap
from collections.abc import Mapping
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from pld_slam.errors import TrajectoryError
from pld_slam.eval.metrics import associate, ate_errors, fit_alignment
from pld_slam.trajectory import Trajectory

FIGURE_SIZE_IN = (6.4, 4.8)
DPI = 100
WHY_NOT_WIDTH = 80
"""Characters per line of the reason an estimate is drawn unaligned (a plot title or legend entry)."""
ALIGNMENT_NAMES = {"se3": "SE(3)-aligned", "sim3": "Sim(3)-aligned", "none": "not aligned"}
"""How the estimate's legend entry and the title name each ``align`` of `pld_slam.eval.metrics`."""
GROUND_TRUTH_ZORDER = 3
"""Above the estimate (matplotlib's lines default to 2), so an estimate on top of the truth does not hide it."""


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
    """Write `top_view_figure` (same parameters) as a PNG at ``path_png``."""
    save_figure(top_view_figure(groundtruth, estimate, title, align, by_index, max_diff, loop_edges), path_png)


def top_view_figure(
    groundtruth: Trajectory | None,
    estimate: Trajectory,
    title: str = "Trajectory, top view",
    align: str = "se3",
    by_index: bool = False,
    max_diff: float = 0.01,
    loop_edges: np.ndarray | None = None,
) -> Figure:
    """The x-z plane (seen from above) of the estimate and ground truth.

    In the camera convention of the world frame (world = first camera: x right, y down,
    z forward) the x-z plane is the ground plane, so this is the bird's-eye view with
    forward pointing up the page.

    Parameters
    ----------
    groundtruth : Trajectory or None
        Drawn black, dashed and thicker, on top of the estimate (`GROUND_TRUTH_ZORDER`):
        where the estimate follows it closely, the truth stays visible through the
        dashes. The start marker is on its first pose. Without it the estimate is drawn
        as it is, its start marked, and the title is ``title`` alone.
    estimate : Trajectory
        Moved as a whole by the alignment of the ATE (`fit_alignment` on the matched
        poses); its legend entry says which (`ALIGNMENT_NAMES`).
    title : str
        The first title line; with ground truth a second line gives the ATE RMSE [m]
        and the alignment, so a pasted figure carries its number.
    align, by_index, max_diff
        As in `pld_slam.eval.metrics.evaluate`.
    loop_edges : (K, 2) array or None
        Timestamps [s] of the two ends of each closed loop, drawn as red segments
        between the aligned estimate's nearest poses.
    """
    figure = Figure(figsize=FIGURE_SIZE_IN)
    axes = figure.add_subplot()
    start_xz = estimate.positions[0, [0, 2]]
    label = "estimate"
    if groundtruth is not None:
        start_xz = draw_groundtruth_top_view(axes, groundtruth)
        aligned, why_not = aligned_if_possible(groundtruth, estimate, align, by_index, max_diff)
        if why_not is None:
            title = f"{title}\n{ate_title_line(groundtruth, estimate, align, by_index, max_diff)}"
            estimate, label = aligned, f"estimate ({ALIGNMENT_NAMES[align]})"
        else:
            title, label = f"{title}\nnot aligned: {why_not}", "estimate (not aligned)"
    est_xz = estimate.positions[:, [0, 2]]
    axes.plot(est_xz[:, 0], est_xz[:, 1], "b-", label=label)
    axes.plot(start_xz[0], start_xz[1], "go", zorder=GROUND_TRUTH_ZORDER + 1, label="start")
    for n, ends in enumerate(np.zeros((0, 2)) if loop_edges is None else loop_edges):
        rows = np.abs(estimate.timestamps[None, :] - np.asarray(ends)[:, None]).argmin(axis=1)
        axes.plot(est_xz[rows, 0], est_xz[rows, 1], "r-o", markersize=3, label="loop" if n == 0 else None)
    finish_top_view(axes, title)
    return figure


def comparison_top_view_figure(
    groundtruth: Trajectory | None,
    estimates: Mapping[str, Trajectory],
    title: str = "Trajectories, top view",
    align: str = "se3",
    by_index: bool = False,
    max_diff: float = 0.01,
) -> Figure:
    """The x-z plane of several estimates over their ground truth (as ``evo_traj --ref``).

    Each estimate (by name) is aligned onto the ground truth on its own, as its ATE is
    (`aligned_if_possible`), and its legend entry gives that ATE, or says that it could
    not be aligned and why (it is then drawn as it is); the ground truth is drawn as in
    `top_view_figure`. Without ground truth the estimates are drawn as they are.
    """
    figure = Figure(figsize=FIGURE_SIZE_IN)
    axes = figure.add_subplot()
    if groundtruth is not None:
        start_xz = draw_groundtruth_top_view(axes, groundtruth)
        axes.plot(start_xz[0], start_xz[1], "go", zorder=GROUND_TRUTH_ZORDER + 1, label="start")
    for name, estimate in estimates.items():
        label, drawn = name, estimate
        if groundtruth is not None:
            drawn, why_not = aligned_if_possible(groundtruth, estimate, align, by_index, max_diff)
            label = (f"{name} (not aligned: {why_not})" if why_not
                     else f"{name}: {ate_title_line(groundtruth, estimate, align, by_index, max_diff)}")
        xz = drawn.positions[:, [0, 2]]
        axes.plot(xz[:, 0], xz[:, 1], "-", linewidth=1.2, label=label)
    finish_top_view(axes, title)
    return figure


def aligned_if_possible(
    groundtruth: Trajectory, estimate: Trajectory, align: str = "se3", by_index: bool = False, max_diff: float = 0.01
) -> tuple[Trajectory, str | None]:
    """``estimate`` aligned onto ``groundtruth`` (`aligned_onto`) and None, or, when too few of its
    poses match the ground truth to align it, ``estimate`` as it is and why (lines of `WHY_NOT_WIDTH`)."""
    if len(estimate) < 2:
        return estimate, "fewer than 2 poses"
    try:
        return aligned_onto(groundtruth, estimate, align, by_index, max_diff), None
    except TrajectoryError as error:
        return estimate, textwrap.fill(str(error), WHY_NOT_WIDTH)


def draw_groundtruth_top_view(axes, groundtruth: Trajectory) -> np.ndarray:
    """Draw the ground truth's x-z plane (black, dashed, on top) on ``axes``; its start (2,) [m]."""
    gt_xz = groundtruth.positions[:, [0, 2]]
    axes.plot(gt_xz[:, 0], gt_xz[:, 1], "k--", linewidth=2.0, zorder=GROUND_TRUTH_ZORDER, label="ground truth")
    return gt_xz[0]


def ate_title_line(groundtruth: Trajectory, estimate: Trajectory, align: str, by_index: bool, max_diff: float) -> str:
    """``ATE RMSE 0.123 m (SE(3)-aligned)``: the RMSE of `ate_errors`, the ATE of ``pld-slam eval``."""
    _, errors = ate_errors(groundtruth, estimate, align, by_index, max_diff)
    return f"ATE RMSE {np.sqrt(np.mean(errors**2)):.3f} m ({ALIGNMENT_NAMES[align]})"


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
    """Write `error_over_time_figure` (same parameters) as a PNG at ``path_png``."""
    save_figure(error_over_time_figure(groundtruth, estimate, title, align, by_index, max_diff), path_png)


def error_over_time_figure(
    groundtruth: Trajectory,
    estimate: Trajectory,
    title: str = "Absolute trajectory error",
    align: str = "se3",
    by_index: bool = False,
    max_diff: float = 0.01,
) -> Figure:
    """The ATE position error of each matched pose (`ate_errors`, same parameters).

    Poses paired by time are plotted against the time from the first matched estimate
    pose [s]. Poses paired by row (``by_index``: two KITTI files, which carry no times)
    are plotted against their row in the estimate file, and the axis says so: the
    times such a file is read with are made up (0, 1, 2, ...) and are not seconds.
    """
    return comparison_error_figure(groundtruth, {"": estimate}, title, align, by_index, max_diff)


def comparison_error_figure(
    groundtruth: Trajectory,
    estimates: Mapping[str, Trajectory],
    title: str = "Absolute trajectory error",
    align: str = "se3",
    by_index: bool = False,
    max_diff: float = 0.01,
) -> Figure:
    """`error_over_time_figure` of several estimates on one axes, a line each, labelled by name
    (no legend for a single unnamed estimate, ``""``)."""
    figure = Figure(figsize=FIGURE_SIZE_IN)
    axes = figure.add_subplot()
    style = "b-" if list(estimates) == [""] else "-"
    for name, estimate in estimates.items():
        timestamps, errors = ate_errors(groundtruth, estimate, align, by_index, max_diff)
        x = np.arange(len(errors)) if by_index else timestamps - timestamps[0]
        axes.plot(x, errors, style, label=name or None)
    axes.set_xlabel("pose (row of the file)" if by_index else "time [s]")
    axes.set_ylabel(f"position error [m] ({ALIGNMENT_NAMES[align]})")
    axes.set_ylim(bottom=0.0)
    axes.set_title(title)
    axes.grid(True, alpha=0.3)
    if style == "-":
        axes.legend()
    return figure
