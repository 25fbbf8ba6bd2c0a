"""The files of a run: trajectories (KITTI, TUM, EuRoC), summary.json, frames.csv (a row per
frame), loops.csv, a trajectory plot and a plot of the cost per frame, the map (map.ply) and
the keyframe trajectory (keyframes.tum.txt), and the partial trajectory streamed while the
run goes.

An output folder holds one run's files only: `prepare_output_folder` deletes the files
an earlier run left there (`RUN_FILES`, nothing else of the user's) before a run writes
its first, so a run that writes fewer files (under 2 frames: no plot) or stops half way
never sits beside the plot or loops of the run before.

Every OSError on output becomes an `OutputError` naming the path, so that an output
folder that cannot be written reaches the user as one line, like bad input, and not as
an internal error.
"""

import dataclasses
import json
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from pld_slam.errors import OutputError
from pld_slam.eval.plots import plot_trajectory_top_view
from pld_slam.eval.timing_plot import plot_frame_times
from pld_slam.io.map_ply import MapCloud, write_map_ply
from pld_slam.io.trajectory import TUM_HEADER, tum_rows, write_trajectory
from pld_slam.loop.loop_closing import LoopCandidate
from pld_slam.system import STAGES, FrameRecord
from pld_slam.trajectory import Trajectory

TRAJECTORY_KITTI = "trajectory.kitti.txt"
TRAJECTORY_TUM = "trajectory.tum.txt"
TRAJECTORY_EUROC = "trajectory.euroc.csv"
TRAJECTORY_FILES = {"kitti": TRAJECTORY_KITTI, "tum": TRAJECTORY_TUM, "euroc": TRAJECTORY_EUROC}
"""The trajectory file of each format of `pld_slam.io.trajectory.FORMATS`."""
DEFAULT_FORMATS = ("kitti", "tum")
"""The trajectory formats a run writes unless asked (``pld-slam run --formats``)."""
TRAJECTORY_PARTIAL = "trajectory.partial.tum.txt"
SUMMARY = "summary.json"
PLOT = "trajectory.png"
LOOPS = "loops.csv"
FRAMES = "frames.csv"
TIMING_PLOT = "timing.png"
MAP_PLY = "map.ply"
KEYFRAMES_TUM = "keyframes.tum.txt"
RUN_FILES = (*TRAJECTORY_FILES.values(), TRAJECTORY_PARTIAL, SUMMARY, FRAMES, PLOT, LOOPS, TIMING_PLOT, MAP_PLY,
             KEYFRAMES_TUM)
"""Every file a run may write into its output folder; `prepare_output_folder` deletes these."""


def create_output_folder(folder: Path) -> None:
    """Create ``folder`` and its parents if needed; `OutputError` when that fails (e.g. under a file)."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise OutputError.from_os_error(folder, error) from None


def prepare_output_folder(folder: Path) -> None:
    """Create ``folder`` if needed and delete the `RUN_FILES` an earlier run left in it.

    Other files and subfolders (yours, or an ablation cell's ``cell.json``) are kept.
    `OutputError` when the folder cannot be created or a file not deleted.
    """
    create_output_folder(folder)
    for name in RUN_FILES:
        try:
            (folder / name).unlink(missing_ok=True)
        except OSError as error:
            raise OutputError.from_os_error(folder / name, error) from None


class PartialTrajectory:
    """``T_w_c`` of each frame as tracked, appended to a TUM file while a run goes.

    The final trajectory files are written once, at the end of a run, so a run killed
    hard (SIGKILL, out of memory, a lost machine) would leave nothing; this file keeps
    what was tracked until then. Each row is flushed to the operating system as it is
    written, which survives a killed process (not a power cut: we do not fsync, as that
    would cost a disk write per frame). The poses are those at tracking time; the final
    files carry the later corrections of BA and loop closing, so the two may differ.

    Opening the file (`start`) is also the check that the output folder can be created
    and written, done before the first frame so that a bad ``--out`` costs nothing.
    """

    def __init__(self, path: Path) -> None:
        self.path = path
        self._file = None  # opened by start

    def start(self) -> None:
        """Create the folder and write the `TUM_HEADER` line; `OutputError` when either fails."""
        create_output_folder(self.path.parent)
        try:
            self._file = self.path.open("w")
            self._write_line(TUM_HEADER)
        except OSError as error:
            raise OutputError.from_os_error(self.path, error) from None

    def append(self, timestamp: float, T_w_c: np.ndarray) -> None:
        """Append the TUM row of one frame (time [s], (4, 4) pose) and flush it."""
        try:
            self._write_line(tum_rows(Trajectory(np.array([timestamp]), T_w_c[None]))[0])
        except OSError as error:
            raise OutputError.from_os_error(self.path, error) from None

    def _write_line(self, line: str) -> None:
        """Write ``line`` and a newline, flushed to the operating system."""
        self._file.write(line + "\n")
        self._file.flush()

    def close(self) -> None:
        """Close the file; it stays on disk."""
        self._file.close()

    def discard(self) -> None:
        """Close and delete the file, once the final trajectory files hold every frame."""
        self.close()
        try:
            self.path.unlink(missing_ok=True)
        except OSError as error:
            raise OutputError.from_os_error(self.path, error) from None


def write_run_outputs(
    out_dir: Path,
    estimate: Trajectory,
    summary: dict,
    groundtruth: Trajectory | None,
    title: str,
    formats: tuple[str, ...] = DEFAULT_FORMATS,
    records: Sequence[FrameRecord] = (),
    cloud: MapCloud | None = None,
    keyframes: Trajectory | None = None,
) -> list[Path]:
    """Write the run's files into ``out_dir`` (created if needed); return their paths.

    The trajectory files, one per format of ``formats`` (named by `TRAJECTORY_FILES`),
    hold one row per processed frame (``T_w_c``, world = first camera). ``frames.csv``
    has a row per frame of ``records`` (`frame_table`), written when there is one, and
    ``timing.png`` plots it (`pld_slam.eval.timing_plot`) from 2 frames on. ``loops.csv``
    lists the loop candidates of the summary's ``loop`` section, one row each (written
    when the run had a loop stage and a frame); the plot marks the closed loops and is
    skipped for fewer than 2 frames. A run with a map writes ``map.ply`` (``cloud``,
    `pld_slam.io.map_ply`) and ``keyframes.tum.txt`` (``keyframes``, when it has one). A
    file that cannot be written raises `OutputError` naming it.
    """
    create_output_folder(out_dir)
    try:
        return _write_run_files(out_dir, estimate, summary, groundtruth, title, formats, records, cloud, keyframes)
    except OSError as error:
        raise OutputError.from_os_error(out_dir, error) from None


def _write_run_files(
    out_dir: Path, estimate: Trajectory, summary: dict, groundtruth: Trajectory | None, title: str,
    formats: tuple[str, ...], records: Sequence[FrameRecord], cloud: MapCloud | None, keyframes: Trajectory | None,
) -> list[Path]:
    """`write_run_outputs` into the existing ``out_dir``, OSErrors left to the caller."""
    written = []
    if len(estimate) > 0:
        for fmt in formats:
            write_trajectory(out_dir / TRAJECTORY_FILES[fmt], estimate, fmt)
            written.append(out_dir / TRAJECTORY_FILES[fmt])
    (out_dir / SUMMARY).write_text(json.dumps(summary, indent=2) + "\n")
    written.append(out_dir / SUMMARY)
    if records:
        table = frame_table(records)
        table.to_csv(out_dir / FRAMES, index=False, float_format="%.3f")
        written.append(out_dir / FRAMES)
        if len(table) >= 2:
            plot_frame_times(out_dir / TIMING_PLOT, table, title=f"{title}: cost per frame")
            written.append(out_dir / TIMING_PLOT)
    loop = summary.get("loop")
    if loop is not None and len(estimate) > 0:
        pd.DataFrame(loop["candidates"], columns=LOOP_COLUMNS).to_csv(out_dir / LOOPS, index=False)
        written.append(out_dir / LOOPS)
    if len(estimate) >= 2:
        plot_trajectory_top_view(out_dir / PLOT, groundtruth, estimate, title=title, loop_edges=closed_loop_times(loop))
        written.append(out_dir / PLOT)
    if cloud is not None:
        write_map_ply(out_dir / MAP_PLY, cloud)
        written.append(out_dir / MAP_PLY)
    if keyframes is not None and len(keyframes) > 0:
        write_trajectory(out_dir / KEYFRAMES_TUM, keyframes, "tum")
        written.append(out_dir / KEYFRAMES_TUM)
    return written


def frame_table(records: Sequence[FrameRecord]) -> pd.DataFrame:
    """One row per frame: what tracking made of it, each stage's wall time and the map's size then.

    Columns: ``index``, ``time`` [s], ``status`` (`TrackingStatus` value), ``keyframe``
    (why the frame became one, empty otherwise), ``skipped`` (why its images could not be
    used, empty otherwise), the stereo ``points`` and ``lines`` of its pair, the inliers
    against the reference frame and the local map, then ``<stage>_ms`` for every stage of
    `pld_slam.system.STAGES` (empty where the stage did not run: ``mapping`` and
    ``loop`` run at keyframes), then ``keyframes``, ``point_landmarks`` and
    ``line_landmarks`` alive once the frame was mapped, and ``rss_mb``, the main
    process's resident memory then [MiB].
    """
    return pd.DataFrame(
        {
            "index": [r.index for r in records],
            "time": [r.timestamp for r in records],
            "status": [r.status.value for r in records],
            "keyframe": [r.keyframe.value if r.keyframe is not None else "" for r in records],
            "skipped": [r.skipped_reason or "" for r in records],
            "points": [r.n_points for r in records],
            "lines": [r.n_lines for r in records],
            "point_inliers": [r.counts.point_inliers for r in records],
            "line_inliers": [r.counts.line_inliers for r in records],
            "map_point_inliers": [r.counts.map_point_inliers for r in records],
            "map_line_inliers": [r.counts.map_line_inliers for r in records],
            **{f"{stage}_ms": [r.stage_ms.get(stage, np.nan) for r in records] for stage in STAGES},
            "keyframes": [r.map_size[0] for r in records],
            "point_landmarks": [r.map_size[1] for r in records],
            "line_landmarks": [r.map_size[2] for r in records],
            "rss_mb": [r.rss_mb for r in records],
        }
    )


LOOP_COLUMNS = [field.name for field in dataclasses.fields(LoopCandidate)]
"""The columns of ``loops.csv``: those of `pld_slam.loop.loop_closing.LoopCandidate`."""


def closed_loop_times(loop: dict | None) -> np.ndarray:
    """The timestamps (K, 2) [s] of the two keyframes of each closed loop in a summary's ``loop`` section."""
    accepted = [(c["time"], c["candidate_time"]) for c in (loop or {}).get("candidates", []) if c["accepted"]]
    return np.array(accepted, dtype=np.float64).reshape(-1, 2)
