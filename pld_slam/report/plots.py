"""Plots of an ablation: every variant's trajectory per sequence, and ATE per variant.

Drawn off-screen with ``matplotlib.figure.Figure``, as `pld_slam.eval.plots`.
"""

from collections.abc import Mapping

import numpy as np
from matplotlib.figure import Figure

from pld_slam.eval.plots import FIGURE_SIZE_IN, comparison_top_view_figure, save_figure
from pld_slam.report.tables import PaperTable
from pld_slam.trajectory import Trajectory

LOG_SCALE_SPAN = 30.0
"""The bar chart's ATE axis turns logarithmic when the largest value exceeds the smallest this
many times: millimetre EuRoC bars beside decimetre KITTI ones are otherwise invisible."""


def plot_variant_trajectories(path_png, groundtruth: Trajectory | None, estimates: Mapping[str, Trajectory],
                              title: str) -> None:
    """Top view (x-z) of each variant's estimate (``T_w_c``, by name in legend order) over the
    ground truth, each aligned as for its ATE, or drawn as it is and labelled so where it
    cannot be (`pld_slam.eval.plots.comparison_top_view_figure`); ``title``: the sequence."""
    save_figure(comparison_top_view_figure(groundtruth, estimates, title), path_png)


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
