"""A PNG of a run's cost per frame over the run (``timing.png``), from its ``frames.csv`` table.

Two panels over the frame index: the stages every frame runs (each as a running median,
and the main thread's whole ``total`` per frame behind them), and the stages that run at
keyframes only (``mapping``, ``loop``), one dot per keyframe. Stage names are those of
`pld_slam.system.STAGES`; ``load`` and ``frontend`` run in the background with
``system.prefetch``, so the stages add up to more than ``total``.
"""

import numpy as np
import pandas as pd
from matplotlib.figure import Figure

from pld_slam.eval.plots import save_figure

KEYFRAME_STAGES = ("mapping", "loop")
"""Stages that run at keyframes only: drawn as dots, one per keyframe."""
RUNNING_MEDIAN_FRAMES = 25
"""Frames in the running median of each per-frame stage (fewer in a shorter run)."""


def plot_frame_times(path_png, table: pd.DataFrame, title: str = "Cost per frame") -> None:
    """Write `frame_times_figure` of ``table`` (a ``frames.csv`` table) as a PNG at ``path_png``."""
    save_figure(frame_times_figure(table, title), path_png)


def frame_times_figure(table: pd.DataFrame, title: str = "Cost per frame") -> Figure:
    """The figure of the module docstring for ``table``: columns ``index`` and ``<stage>_ms``."""
    figure = Figure(figsize=(8.0, 6.0))
    per_frame, per_keyframe = figure.subplots(2, 1, sharex=True, height_ratios=(2, 1))
    frames = table["index"].to_numpy()
    window = max(1, min(RUNNING_MEDIAN_FRAMES, len(table) // 4))
    per_frame.plot(frames, table["total_ms"], color="0.8", linewidth=0.6, label="total (each frame)")
    for stage in _stages_that_ran(table, per_keyframe=False):
        median = table[f"{stage}_ms"].rolling(window, min_periods=1, center=True).median()
        per_frame.plot(frames, median, linewidth=1.2, label=stage)
    per_frame.set_ylabel(f"ms per frame (median of {window})")
    per_frame.set_title(title)
    per_frame.legend(fontsize="small", ncol=3)
    for stage in _stages_that_ran(table, per_keyframe=True):
        ran = table[f"{stage}_ms"].notna().to_numpy()
        per_keyframe.plot(frames[ran], table.loc[ran, f"{stage}_ms"], ".", markersize=3, label=stage)
    per_keyframe.set_ylabel("ms per keyframe")
    per_keyframe.set_xlabel("frame")
    if per_keyframe.has_data():
        per_keyframe.legend(fontsize="small")
    for axes in (per_frame, per_keyframe):
        axes.set_ylim(bottom=0.0)
        axes.grid(True, alpha=0.3)
    return figure


def _stages_that_ran(table: pd.DataFrame, per_keyframe: bool) -> list[str]:
    """The stages with a time in ``table`` (not ``total``), those of keyframes or the others."""
    stages = [column.removesuffix("_ms") for column in table.columns if column.endswith("_ms")]
    return [stage for stage in stages
            if stage != "total" and (stage in KEYFRAME_STAGES) == per_keyframe and np.any(table[f"{stage}_ms"].notna())]
