"""Plots of an ablation: every variant's trajectory per sequence, and ATE per variant.

Drawn off-screen with ``matplotlib.figure.Figure``, as `pld_slam.eval.plots`.
"""

from collections.abc import Mapping

import numpy as np
from matplotlib.figure import Figure

from pld_slam.errors import TrajectoryError
from pld_slam.eval.plots import FIGURE_SIZE_IN, aligned_onto, finish_top_view, save_figure
from pld_slam.report.tables import PaperTable
from pld_slam.trajectory import Trajectory

LOG_SCALE_SPAN = 30.0
"""The bar chart's ATE axis turns logarithmic when the largest value exceeds the smallest this
many times: millimetre EuRoC bars beside decimetre KITTI ones are otherwise invisible."""


def plot_variant_trajectories(path_png, groundtruth: Trajectory | None, estimates: Mapping[str, Trajectory],
                              title: str) -> None:
    """Top view (x-z) of each variant's estimate, aligned onto the ground truth as for the ATE.

    Parameters
    ----------
    path_png : path
        The PNG to write.
    groundtruth : Trajectory or None
        Drawn dashed; without it the estimates are drawn as they are.
    estimates : mapping of str to Trajectory
        Each variant's estimate (``T_w_c``), in legend order. One that cannot be aligned
        (too few poses matched) is drawn unaligned.
    title : str
        The figure's title (the sequence).
    """
    figure = Figure(figsize=FIGURE_SIZE_IN)
    axes = figure.add_subplot()
    if groundtruth is not None:
        axes.plot(groundtruth.positions[:, 0], groundtruth.positions[:, 2], "k--", label="ground truth")
    for name, estimate in estimates.items():
        if groundtruth is not None and len(estimate) >= 2:
            try:
                estimate = aligned_onto(groundtruth, estimate)
            except TrajectoryError:
                pass
        axes.plot(estimate.positions[:, 0], estimate.positions[:, 2], "-", linewidth=1.2, label=name)
    finish_top_view(axes, title)
    save_figure(figure, path_png)


def plot_ate_bars(path_png, table: PaperTable) -> None:
    """Grouped bar chart of the translation ATE: one group per sequence, one bar per variant."""
    values = table.values.xs("t", axis=1, level=1).drop(index="mean")
    sequences, variants = list(values.index), list(values.columns)
    figure = Figure(figsize=(max(FIGURE_SIZE_IN[0], 1.2 + 0.5 * len(sequences) * len(variants)), FIGURE_SIZE_IN[1]))
    axes = figure.add_subplot()
    width = 0.8 / max(1, len(variants))
    positions = np.arange(len(sequences))
    for n, variant in enumerate(variants):
        heights = values[variant].to_numpy(dtype=float)
        axes.bar(positions + (n - (len(variants) - 1) / 2) * width, np.nan_to_num(heights), width, label=variant)
    axes.set_xticks(positions, sequences, rotation=30, ha="right")
    shown = values.to_numpy(dtype=float)
    shown = shown[np.isfinite(shown) & (shown > 0)]
    if len(shown) and shown.max() > LOG_SCALE_SPAN * shown.min():
        axes.set_yscale("log")
    axes.set_ylabel("ATE RMSE [m]")
    axes.set_title("Translation ATE per variant (missing cells: no bar)")
    axes.grid(True, axis="y", alpha=0.3)
    axes.legend()
    save_figure(figure, path_png)
