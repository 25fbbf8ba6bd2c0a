"""The file formats of a run's output folder: the names of its files, summary.json, frames.csv
(a row per frame), loops.csv and the partial trajectory streamed while the run goes; the
trajectories and the map are written by `pld_slam.io.trajectory` and `pld_slam.io.map_ply`.
Which files a run writes, its plots included, is `pld_slam.report.run_files`'s.

An output folder holds one run's files only: `prepare_output_folder` deletes the files
an earlier run left there (`RUN_FILES`, nothing else of the user's) before a run writes
its first, so a run that writes fewer files (under 2 frames: no plot) or stops half way
never sits beside the plot or loops of the run before. The one exception is the partial
trajectory of a run that did not finish (killed, or its final files not written): the
only record of that run, it is kept under a numbered name (`keep_partial_trajectory`).

An output folder holds one run at a time: a run takes the folder's lock (`RUN_LOCK`,
`lock_output_folder`) before it deletes or writes anything there, so a second run into
the same folder is refused instead of deleting the first one's files as it writes them.

Every OSError on output becomes an `OutputError` naming the path, so that an output
folder that cannot be written reaches the user as one line, like bad input, and not as
an internal error.
"""

import itertools
import json
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from pld_slam.errors import OutputError
from pld_slam.io.output_folder import create_output_folder
from pld_slam.io.trajectory import TUM_HEADER, tum_rows
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
RUN_LOCK = "run.lock"
"""The output folder's lock while a run writes there: the process id of the run, a line."""
RUN_FILES = (*TRAJECTORY_FILES.values(), TRAJECTORY_PARTIAL, SUMMARY, FRAMES, PLOT, LOOPS, TIMING_PLOT, MAP_PLY,
             KEYFRAMES_TUM)
"""Every file a run may write into its output folder; `prepare_output_folder` deletes these."""


def prepare_output_folder(folder: Path) -> Path | None:
    """Delete the `RUN_FILES` an earlier run left in ``folder``, keeping its partial trajectory; return the
    name that was kept under (`keep_partial_trajectory`), None when there was none.

    Other files and subfolders (yours, or an ablation cell's ``cell.json``) are kept.
    `OutputError` when a file cannot be renamed or deleted.
    """
    kept = keep_partial_trajectory(folder)
    for name in RUN_FILES:
        try:
            (folder / name).unlink(missing_ok=True)
        except OSError as error:
            raise OutputError.from_os_error(folder / name, error) from None
    return kept


def keep_partial_trajectory(folder: Path) -> Path | None:
    """Rename the `TRAJECTORY_PARTIAL` of a run that did not finish to ``trajectory.partial.N.tum.txt``, the first
    free N from 1, and return that path; None when there is no such file."""
    partial = folder / TRAJECTORY_PARTIAL
    if not partial.exists():
        return None
    stem = TRAJECTORY_PARTIAL.removesuffix(".tum.txt")
    kept = next(folder / f"{stem}.{n}.tum.txt" for n in itertools.count(1)
                if not (folder / f"{stem}.{n}.tum.txt").exists())
    try:
        partial.rename(kept)
    except OSError as error:
        raise OutputError.from_os_error(partial, error) from None
    return kept


def lock_output_folder(folder: Path) -> str | None:
    """Create ``folder`` if needed and take its lock: `RUN_LOCK` created atomically (``O_CREAT | O_EXCL``) with
    this process's id. Return the ended run whose lock was taken over as the lock names it (``pid 123``, or
    ``no pid`` when a run was killed before writing it), None when there was no lock.

    `OutputError` naming the folder and the process when a running process holds the lock (or when another
    run took it over at the same moment), or when the lock cannot be written.
    """
    create_output_folder(folder)
    lock = folder / RUN_LOCK
    ended = None
    for _ in range(2):  # the second attempt after an ended run's lock was removed
        try:
            descriptor = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        except FileExistsError:
            owner = lock_owner(lock)
            if owner is not None and process_is_running(owner):
                raise OutputError(f"{folder}: in use by another run (pid {owner}); wait for it to end, or delete "
                                  f"{lock} if no run is writing there") from None
            ended = "no pid" if owner is None else f"pid {owner}"
            remove_lock(lock)
            continue
        except OSError as error:
            raise OutputError.from_os_error(lock, error) from None
        with os.fdopen(descriptor, "w") as file:
            file.write(f"{os.getpid()}\n")
        return ended
    raise OutputError(f"{folder}: another run took its lock ({lock}) at the same moment")


def lock_owner(lock: Path) -> int | None:
    """The process id a `RUN_LOCK` file holds; None when it holds none (a run killed as it took the lock) or is
    gone."""
    try:
        pid = int(lock.read_text())
    except (OSError, ValueError):
        return None
    return pid if pid > 0 else None


def process_is_running(pid: int) -> bool:
    """Whether process ``pid`` exists (signal 0 tests that; a process of another user raises PermissionError)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        pass
    return True


def remove_lock(lock: Path) -> None:
    """Delete a `RUN_LOCK` file; one that cannot be deleted is left, to be taken over as an ended run's."""
    try:
        lock.unlink(missing_ok=True)
    except OSError:
        pass


class PartialTrajectory:
    """``T_w_c`` of each frame as tracked, appended to a TUM file while a run goes.

    The final trajectory files are written once, at the end of a run, so a run killed
    hard (SIGKILL, out of memory, a lost machine) would leave nothing; this file keeps
    what was tracked until then. Each row goes to the operating system whole, as it is
    written (the file is unbuffered), which survives a killed process (not a power cut:
    we do not fsync, as that would cost a disk write per frame). A row that cannot be
    written whole (a full disk) is cut off again, so the file stays readable to its last
    whole row, and the error is the run's (`OutputError`). The poses are those at
    tracking time; the final files carry the later corrections of BA and loop closing,
    so the two may differ.

    Opening the file (`start`) is also the check that the output folder can be created
    and written, done before the first frame so that a bad ``--out`` costs nothing.
    """

    def __init__(self, path: Path) -> None:
        self.path = path
        self._file = None  # opened by start
        self._whole_rows_bytes = 0  # the file's size up to its last whole row
        self._write_failed = False

    def start(self) -> None:
        """Create the folder and write the `TUM_HEADER` line; `OutputError` when either fails."""
        create_output_folder(self.path.parent)
        try:
            self._file = self.path.open("wb", buffering=0)
        except OSError as error:
            raise OutputError.from_os_error(self.path, error) from None
        self._write_row(TUM_HEADER)

    def append(self, timestamp: float, T_w_c: np.ndarray) -> None:
        """Append the TUM row of one frame (time [s], (4, 4) pose)."""
        self._write_row(tum_rows(Trajectory(np.array([timestamp]), T_w_c[None]))[0])

    def _write_row(self, line: str) -> None:
        """Write ``line`` and a newline to the operating system; on an OSError cut the file back to its last
        whole row and raise `OutputError`."""
        row = memoryview((line + "\n").encode())
        try:
            while row:  # an unbuffered write may take part of a row
                row = row[self._file.write(row):]
        except OSError as error:
            self._write_failed = True
            self._cut_to_whole_rows()
            raise OutputError.from_os_error(self.path, error) from None
        self._whole_rows_bytes = self._file.tell()

    def _cut_to_whole_rows(self) -> None:
        """Truncate the file after its last whole row (the part of a row a full disk took would make the file
        unreadable); a failure here leaves it as it is, the write's error being the one reported."""
        try:
            self._file.seek(self._whole_rows_bytes)
            self._file.truncate()
        except OSError:
            pass

    def close(self) -> None:
        """Close the file; it stays on disk. `OutputError` when closing fails, unless a write failed before
        (that error is the one the run reports)."""
        file, self._file = self._file, None
        if file is None:
            return
        try:
            file.close()
        except OSError as error:
            if not self._write_failed:
                raise OutputError.from_os_error(self.path, error) from None

    def discard(self) -> None:
        """Close and delete the file, once the final trajectory files hold every frame."""
        self.close()
        try:
            self.path.unlink(missing_ok=True)
        except OSError as error:
            raise OutputError.from_os_error(self.path, error) from None


def write_summary(path: Path, summary: dict) -> None:
    """Write ``summary.json``: the run summary as indented JSON and a newline."""
    path.write_text(json.dumps(summary, indent=2) + "\n")


def write_frame_table(path: Path, table: pd.DataFrame) -> None:
    """Write ``frames.csv``: the `frame_table`, times and milliseconds with 3 decimals."""
    table.to_csv(path, index=False, float_format="%.3f")


def write_loop_candidates(path: Path, candidates: Sequence[dict], columns: Sequence[str]) -> None:
    """Write ``loops.csv``: a row per loop candidate (a summary's ``loop.candidates``), ``columns``
    in order (the header alone when there is none)."""
    pd.DataFrame(list(candidates), columns=list(columns)).to_csv(path, index=False)


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

