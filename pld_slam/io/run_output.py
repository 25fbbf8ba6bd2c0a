"""The files of a run: trajectories (KITTI, TUM), summary.json, loops.csv and a trajectory plot."""

import dataclasses
import json
from pathlib import Path

import numpy as np
import pandas as pd

from pld_slam.eval.plots import plot_trajectory_top_view
from pld_slam.io.trajectory import write_kitti, write_tum
from pld_slam.loop.loop_closing import LoopCandidate
from pld_slam.trajectory import Trajectory

TRAJECTORY_KITTI = "trajectory.kitti.txt"
TRAJECTORY_TUM = "trajectory.tum.txt"
SUMMARY = "summary.json"
PLOT = "trajectory.png"
LOOPS = "loops.csv"


def write_run_outputs(
    out_dir: Path, estimate: Trajectory, summary: dict, groundtruth: Trajectory | None, title: str
) -> list[Path]:
    """Write the run's files into ``out_dir`` (created if needed); return their paths.

    The trajectory files hold one row per processed frame (``T_w_c``, world = first
    camera). ``loops.csv`` lists the loop candidates of the summary's ``loop`` section, one
    row each (written when the run had a loop stage and a frame); the plot marks the closed loops and
    is skipped for fewer than 2 frames.
    """
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    if len(estimate) > 0:
        write_kitti(out_dir / TRAJECTORY_KITTI, estimate)
        write_tum(out_dir / TRAJECTORY_TUM, estimate)
        written += [out_dir / TRAJECTORY_KITTI, out_dir / TRAJECTORY_TUM]
    (out_dir / SUMMARY).write_text(json.dumps(summary, indent=2) + "\n")
    written.append(out_dir / SUMMARY)
    loop = summary.get("loop")
    if loop is not None and len(estimate) > 0:
        pd.DataFrame(loop["candidates"], columns=LOOP_COLUMNS).to_csv(out_dir / LOOPS, index=False)
        written.append(out_dir / LOOPS)
    if len(estimate) >= 2:
        plot_trajectory_top_view(out_dir / PLOT, groundtruth, estimate, title=title, loop_edges=closed_loop_times(loop))
        written.append(out_dir / PLOT)
    return written


LOOP_COLUMNS = [field.name for field in dataclasses.fields(LoopCandidate)]
"""The columns of ``loops.csv``: those of `pld_slam.loop.loop_closing.LoopCandidate`."""


def closed_loop_times(loop: dict | None) -> np.ndarray:
    """The timestamps (K, 2) [s] of the two keyframes of each closed loop in a summary's ``loop`` section."""
    accepted = [(c["time"], c["candidate_time"]) for c in (loop or {}).get("candidates", []) if c["accepted"]]
    return np.array(accepted, dtype=np.float64).reshape(-1, 2)
