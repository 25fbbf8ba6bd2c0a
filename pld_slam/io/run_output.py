"""The files of a run: trajectories (KITTI, TUM), summary.json and a trajectory plot."""

import json
from pathlib import Path

from pld_slam.eval.plots import plot_trajectory_top_view
from pld_slam.io.trajectory import write_kitti, write_tum
from pld_slam.trajectory import Trajectory

TRAJECTORY_KITTI = "trajectory.kitti.txt"
TRAJECTORY_TUM = "trajectory.tum.txt"
SUMMARY = "summary.json"
PLOT = "trajectory.png"


def write_run_outputs(
    out_dir: Path, estimate: Trajectory, summary: dict, groundtruth: Trajectory | None, title: str
) -> list[Path]:
    """Write the run's files into ``out_dir`` (created if needed); return their paths.

    The trajectory files hold one row per processed frame (``T_w_c``, world = first
    camera). The plot is skipped for fewer than 2 frames.
    """
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    if len(estimate) > 0:
        write_kitti(out_dir / TRAJECTORY_KITTI, estimate)
        write_tum(out_dir / TRAJECTORY_TUM, estimate)
        written += [out_dir / TRAJECTORY_KITTI, out_dir / TRAJECTORY_TUM]
    (out_dir / SUMMARY).write_text(json.dumps(summary, indent=2) + "\n")
    written.append(out_dir / SUMMARY)
    if len(estimate) >= 2:
        plot_trajectory_top_view(out_dir / PLOT, groundtruth, estimate, title=title)
        written.append(out_dir / PLOT)
    return written
