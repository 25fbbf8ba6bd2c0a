"""A run and its files: `run_and_write` runs the pipeline on a sequence and writes its output folder.

The library's entry point for "run a sequence and write its files": ``pld-slam run`` and
``pld-slam demo`` call it, and so does every ablation cell (`pld_slam.report.cell_run`,
the cell's child process), so a cell measures exactly what a user runs. It attaches the
run's observers: the partial trajectory streamed to disk (`PartialTrajectory`), the
dynamic-label overlays when asked (`overlay_writer`), the recording for the rerun viewer
when asked (`pld_slam.report.rerun_recording`), and the evaluation of the dynamic
labels against the sequence's moving-object masks when it has them
(`pld_slam.eval.dynamic_labels.MaskScores`; without masks no mask is read). It then
decides which files the run writes (`write_run_outputs`: trajectories, summary, frame
table, loops, plots, map), each in its format from `pld_slam.io`.
"""

import dataclasses
import sys
from collections.abc import Callable, Sequence
from contextlib import contextmanager, nullcontext
from pathlib import Path

import numpy as np
from tqdm import tqdm

from pld_slam.datasets import StereoFrame, StereoSequence, with_cameras
from pld_slam.errors import OutputError, deferred_interrupts
from pld_slam.eval.dynamic_labels import MaskScores
from pld_slam.eval.plots import plot_trajectory_top_view
from pld_slam.eval.run_summary import summarise_run
from pld_slam.eval.timing_plot import plot_frame_times
from pld_slam.frontend import StereoFeatures
from pld_slam.io.dynamic_overlays import write_dynamic_overlay
from pld_slam.io.map_ply import MapCloud, map_cloud, write_map_ply
from pld_slam.io.output_folder import create_output_folder
from pld_slam.io.run_output import (
    DEFAULT_FORMATS,
    FRAMES,
    KEYFRAMES_TUM,
    LOOPS,
    MAP_PLY,
    PLOT,
    RUN_LOCK,
    SUMMARY,
    TIMING_PLOT,
    TRAJECTORY_FILES,
    TRAJECTORY_PARTIAL,
    PartialTrajectory,
    frame_table,
    lock_output_folder,
    prepare_output_folder,
    remove_lock,
    write_frame_table,
    write_loop_candidates,
    write_summary,
)
from pld_slam.io.trajectory import write_trajectory
from pld_slam.loop.loop_closing import LoopCandidate
from pld_slam.report.rerun_recording import RerunRecording, open_recording
from pld_slam.run_config import RunConfig, load_run_config
from pld_slam.system import FrameObserver, FrameRecord, System
from pld_slam.tracking.tracker import TrackedFrame
from pld_slam.trajectory import Trajectory

LOOP_COLUMNS = [field.name for field in dataclasses.fields(LoopCandidate)]
"""The columns of ``loops.csv``: those of `pld_slam.loop.loop_closing.LoopCandidate`."""


class RunInterrupted(KeyboardInterrupt):
    """Ctrl-C or SIGTERM stopped a run after its files were written; the message says how far it got and what
    it wrote."""


def run_and_write(
    sequence: StereoSequence, out: Path, config_paths, overrides, max_frames: int | None,
    save_dynamic: Path | None = None, formats: tuple[str, ...] = DEFAULT_FORMATS, rerun: Path | None = None,
) -> dict:
    """Run the pipeline on ``sequence`` and write its files; on Ctrl-C or an error the files still get written.

    The configuration is `load_run_config`'s: defaults, the dataset family's file, then
    ``config_paths`` and ``overrides``; its ``dataset.cameras`` picks KITTI's stereo pair
    (`pld_slam.datasets.with_cameras`: the folder reopened from the colour pair) and its
    ``dataset.scale`` scales the sequence (`StereoSequence.scaled`). ``formats`` are the trajectory files' formats;
    ``save_dynamic`` a folder for each frame's dynamic-label overlay (`overlay_writer`).
    A sequence with moving-object masks has its dynamic labels scored against them
    (`MaskScores`), the summary's precision and recall. ``rerun`` an ``.rrd`` file the run is
    recorded to for the rerun viewer (`pld_slam.report.rerun_recording`), opened before the
    output folder is touched (a missing rerun SDK stops the run first) and finished when the
    run ends, however it ends.

    Once the config is checked, the run takes ``out``'s lock (`locked_output_folder`): a
    second run into the same folder stops there with an `OutputError`. The files an
    earlier run left in ``out`` are then deleted (`prepare_output_folder`), so the folder
    never mixes two runs, except the partial trajectory of a run that did not finish,
    which is kept under a numbered name. The output folder is written to
    (``trajectory.partial.tum.txt``, see `PartialTrajectory`) before the first frame, so
    a bad ``out`` stops the run at once with an `OutputError` instead of after every
    frame is lost. Each frame's tracked pose is appended to that file as the run goes,
    so a run killed hard keeps its poses so far; the file is deleted once the final
    trajectory files are written. Ctrl-C or SIGTERM during the frames raises `RunInterrupted`
    once the files are written, naming them (`interrupted_message`); one that comes while they
    are written waits until they all are (`pld_slam.errors.deferred_interrupts`). A lock taken over and a
    partial trajectory kept are each a ``warning:`` line on stderr (`warn`).

    Returns
    -------
    dict
        The run's summary (`pld_slam.eval.run_summary.summarise_run`), as written to ``summary.json``.
    """
    run_config = load_run_config(sequence, config_paths, overrides)
    sequence = with_cameras(sequence, run_config.config.dataset.cameras).scaled(run_config.config.dataset.scale)
    with nullcontext() if rerun is None else open_recording(rerun, sequence) as recording, locked_output_folder(out):
        return run_into_locked_folder(sequence, run_config, out, max_frames, save_dynamic, formats, recording)


def warn(message: str) -> None:
    """Print ``warning: message`` on stderr: something about the output folder the user should know."""
    print(f"warning: {message}", file=sys.stderr)


@contextmanager
def locked_output_folder(out: Path):
    """Hold ``out``'s lock (`lock_output_folder`) for the block, saying when an ended run's lock was taken over;
    the lock goes at the end of the block, however it ends."""
    ended = lock_output_folder(out)
    if ended is not None:
        warn(f"{out / RUN_LOCK}: took over the lock of a run that has ended ({ended})")
    try:
        yield
    finally:
        remove_lock(out / RUN_LOCK)


def run_into_locked_folder(
    sequence: StereoSequence, run_config: RunConfig, out: Path, max_frames: int | None, save_dynamic: Path | None,
    formats: tuple[str, ...], recording: RerunRecording | None,
) -> dict:
    """`run_and_write` once ``out`` is locked, ``sequence`` read from its pair and scaled, and the recording
    (if asked for) open."""
    margin_px = run_config.config.dynamic.mask_margin_px
    mask_scores = None if sequence.dynamic_mask_paths is None else MaskScores(sequence, margin_px)
    observers: list[FrameObserver] = [] if save_dynamic is None else [overlay_writer(save_dynamic, sequence)]
    observers += [] if mask_scores is None else [mask_scores]
    observers += [] if recording is None else [recording.frame]
    partial = PartialTrajectory(out / TRAJECTORY_PARTIAL)
    system = System(sequence, run_config.config, observers,
                    record_observer=lambda record: partial.append(record.timestamp, record.T_w_c),
                    keyframe_observer=None if recording is None else recording.keyframe)
    try:
        kept = prepare_output_folder(out)
        partial.start()
    except BaseException:  # an OutputError, Ctrl-C: end the front-end worker the system started
        system.close()
        raise
    if kept is not None:
        warn(f"kept the partial trajectory of an earlier run that did not finish as {kept}")
    n_frames = len(sequence) if max_frames is None else min(max_frames, len(sequence))

    def progress(indices):
        return tqdm(indices, total=n_frames, desc=sequence.name, unit="frame", disable=None, leave=False)

    interrupted = None
    try:
        system.run(max_frames=max_frames, progress=progress)
    except KeyboardInterrupt as interrupt:
        interrupted = interrupt  # raised again below, once the files are written
    finally:
        with deferred_interrupts() as held:  # a Ctrl-C or SIGTERM now waits until every file is written
            partial.close()
            summary = summarise_run(sequence, system.result, run_config.config, run_config.sources, mask_scores)
            world_map = system.result.map
            written = write_run_outputs(out, system.result.trajectory(), summary, sequence.groundtruth,
                                        title=sequence.name, formats=formats, records=system.result.records,
                                        cloud=None if world_map is None else map_cloud(world_map),
                                        keyframes=None if world_map is None else world_map.keyframe_trajectory())
            partial.discard()
    interrupted = interrupted or held.interrupt
    if interrupted is not None:
        raise RunInterrupted(interrupted_message(summary, n_frames, out, written)) from interrupted
    return summary


def interrupted_message(summary: dict, n_frames: int, out: Path, written: list[Path]) -> str:
    """How far an interrupted run got and which files it wrote where: ``after 5 of 12 frames; wrote ... in OUT/``."""
    names = ", ".join(path.name for path in written)
    return f"after {summary['frames']} of {n_frames} frames; wrote {names} in {out}/"


def overlay_writer(folder: Path, sequence: StereoSequence) -> FrameObserver:
    """A `System` observer writing each frame's dynamic-label overlay as ``folder/NNNNNN.png``.

    The folder is created here, before the first frame, so that one that cannot be
    created stops the run (`OutputError`) before any work is done.
    """
    create_output_folder(folder)

    def write(frame: StereoFrame, features: StereoFeatures, tracked: TrackedFrame) -> None:
        if tracked.dynamic is not None:
            path = folder / f"{frame.index:06d}.png"
            write_dynamic_overlay(path, frame.left, tracked.dynamic, sequence.dynamic_mask(frame.index))

    return write


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
    file that cannot be written raises `OutputError` naming it (the file, not the folder).
    """
    create_output_folder(out_dir)
    written: list[Path] = []

    def write(name: str, writer: Callable[[Path], object]) -> None:
        path = out_dir / name
        try:
            writer(path)
        except OSError as error:
            raise OutputError.from_os_error(path, error) from None
        written.append(path)

    if len(estimate) > 0:
        for fmt in formats:
            write(TRAJECTORY_FILES[fmt], lambda path, fmt=fmt: write_trajectory(path, estimate, fmt))
    write(SUMMARY, lambda path: write_summary(path, summary))
    if records:
        table = frame_table(records)
        write(FRAMES, lambda path: write_frame_table(path, table))
        if len(table) >= 2:
            write(TIMING_PLOT, lambda path: plot_frame_times(path, table, title=f"{title}: cost per frame"))
    loop = summary.get("loop")
    if loop is not None and len(estimate) > 0:
        write(LOOPS, lambda path: write_loop_candidates(path, loop["candidates"], LOOP_COLUMNS))
    if len(estimate) >= 2:
        write(PLOT, lambda path: plot_trajectory_top_view(path, groundtruth, estimate, title=title,
                                                          loop_edges=closed_loop_times(loop)))
    if cloud is not None:
        write(MAP_PLY, lambda path: write_map_ply(path, cloud))
    if keyframes is not None and len(keyframes) > 0:
        write(KEYFRAMES_TUM, lambda path: write_trajectory(path, keyframes, "tum"))
    return written


def closed_loop_times(loop: dict | None) -> np.ndarray:
    """The timestamps (K, 2) [s] of the two keyframes of each closed loop in a summary's ``loop`` section."""
    accepted = [(c["time"], c["candidate_time"]) for c in (loop or {}).get("candidates", []) if c["accepted"]]
    return np.array(accepted, dtype=np.float64).reshape(-1, 2)
