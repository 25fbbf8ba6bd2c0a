"""``pld-slam run``: the whole pipeline on a sequence folder or ROS bag, writing trajectories and a summary."""

import json
from pathlib import Path

import click

from pld_slam.datasets import BagOptions, open_sequence
from pld_slam.errors import DatasetError, TrackingError
from pld_slam.io.run_output import DEFAULT_FORMATS
from pld_slam.io.trajectory import FORMATS
from pld_slam.report.run_files import run_and_write
from pld_slam.system import STAGES
from pld_slam_cli.config import config_files_option, set_option
from pld_slam_cli.evaluate import SCALE_LABEL, coverage_note, scale_text

KERNELS_FROM_CACHE_SECONDS = 1.0
"""Loading the numba kernels from the disk cache takes well under this [s]; longer, they were compiled."""
SKIPPED_FRAMES_SHOWN = 3
"""How many skipped frames the run table names; summary.json lists them all."""


def skipped_frame_rows(skipped: list[dict]) -> list[tuple[str, str]]:
    """Table rows of a summary's ``skipped_frames``: their count, then the first few reasons (each names its file)."""
    if not skipped:
        return []
    rows = [("skipped frames", str(len(skipped)))]
    rows += [("", f"frame {frame['index']}: {frame['reason']}") for frame in skipped[:SKIPPED_FRAMES_SHOWN]]
    if len(skipped) > SKIPPED_FRAMES_SHOWN:
        rows.append(("", f"and {len(skipped) - SKIPPED_FRAMES_SHOWN} more in summary.json (skipped_frames)"))
    return rows


def frame_rate_text(frame_rate: dict) -> str:
    """A summary's ``frame_rate`` in words: ``10 Hz, KITTI nominal rate``."""
    hz = "unknown rate" if frame_rate["hz"] is None else f"{frame_rate['hz']:.4g} Hz"
    return f"{hz}, {frame_rate['source']}"


def format_run_table(summary: dict) -> str:
    """Frames, failures, accuracy and per-stage speed of a run summary as aligned text.

    Rows without a label continue the row above: the skipped frames named
    (`skipped_frame_rows`), and the frames the accuracy covers when not all
    (`pld_slam_cli.evaluate.coverage_note`). The scale row is `eval`'s
    (`pld_slam_cli.evaluate.scale_text`). The values start two spaces after the longest
    label, whatever the stages' names.
    """

    def number(value, fmt: str, unit: str) -> str:
        return "n/a" if value is None else f"{fmt.format(value)} {unit}".rstrip()

    coverage = coverage_note(summary["n_matched"], summary["frames"])
    rows = [
        ("sequence", summary["sequence"]),
        *([("cameras", f"{summary['cameras']} pair")] if summary["cameras"] else []),
        ("frames", f"{summary['frames']} of {summary['frames_in_sequence']}"
                   + ("" if summary["completed"] else f" (stopped: {summary['stop_reason']})")),
        ("tracking failures", str(len(summary["tracking_failures"]))),
        stereo_pair_row(summary["stereo_pair"]),
        *skipped_frame_rows(summary["skipped_frames"]),
        ("ATE RMSE", number(summary["ate_rmse_m"], "{:.4f}", "m")),
        ("ATE RMSE after Sim(3)", number(summary["ate_sim3_rmse_m"], "{:.4f}", "m")),
        (SCALE_LABEL, scale_text(summary["sim3_scale"], summary["path_ratio"])),
        ("RPE trans / rot (1 frame)", number(summary["rpe_trans_rmse_m"], "{:.4f}", "m")
         + " / " + number(summary["rpe_rot_rmse_deg"], "{:.4f}", "deg")),
        *([("", coverage)] if coverage else []),
        ("real-time factor", number(summary["real_time_factor"], "{:.2f}", "")
         + f" (sequence time at {frame_rate_text(summary['frame_rate'])} / wall time;"
         " above 1 is faster than real time)"),
        *kernel_compile_rows(summary.get("kernels_seconds", 0.0)),
        ("marked dynamic", number(100.0 * (summary["dynamic"]["marked_fraction"] or 0.0), "{:.1f}", "%")),
        *disparity_offset_rows(summary["disparity_offset"]),
    ]
    mapping = summary["mapping"]
    if mapping is not None:
        landmarks = mapping["landmarks"]
        rows += [
            ("keyframes (kept)", f"{mapping['keyframes']} ({mapping['keyframes_alive']})"),
            ("landmarks points / lines", f"{landmarks['points']} / {landmarks['lines']}"),
            ("local BA ms (median / max)", number(mapping["local_ba"]["ms_median"], "{:.0f}", "")
             + " / " + number(mapping["local_ba"]["ms_max"], "{:.0f}", "")),
        ]
    loop = summary["loop"]
    if loop is not None:
        rows.append(("loops closed (candidates)", f"{len(loop['loops'])} ({len(loop['candidates'])})"))
        if loop["global_ba"] is not None:
            rows.append(("global BA ms", number(loop["global_ba"]["ms"], "{:.0f}", "")))
    for kind in ("points", "lines"):
        quality = summary["dynamic"][kind]
        if quality["on_moving_objects"]:
            rows.append((f"dynamic {kind} P / R", number(quality["precision"], "{:.2f}", "")
                         + " / " + number(quality["recall"], "{:.2f}", "")))
    for stage in STAGES:
        timing = summary["timing_ms"].get(stage)
        if timing:
            per = "keyframe" if stage in ("mapping", "loop") else "frame"
            rows.append((f"{stage} ms/{per} (median)", f"{timing['median']:.1f} (mean {timing['mean']:.1f})"))
    width = max(len(label) for label, _ in rows) + 2
    return "\n".join(f"{label:<{width}}{value}" for label, value in rows)


def stereo_pair_row(stereo_pair: dict) -> tuple[str, str]:
    """The report row of the stereo pair's check (`pld_slam.eval.stereo_pair`): its measures, or its warning."""
    if stereo_pair["warning"] is not None:
        return "stereo pair", f"WARNING: {stereo_pair['warning']}"
    if stereo_pair["verdict"] == "unknown":
        return "stereo pair", "not judged (no frame read)"
    agreement = stereo_pair["row_agreement"]
    on_row = "" if agreement is None else f", {100.0 * agreement:.0f} % of matches on their row"
    return "stereo pair", f"agrees ({100.0 * stereo_pair['keypoint_share']:.0f} % of keypoints matched{on_row})"


def kernel_compile_rows(seconds: float) -> list[tuple[str, str]]:
    """The report row of a first run on a machine, whose numba kernels were compiled before it (`pld_slam.kernels`);
    none when they came from the cache (a second at most)."""
    if seconds <= KERNELS_FROM_CACHE_SECONDS:
        return []
    return [("numba kernels", f"compiled in {seconds:.1f} s before the first frame "
                              "(once per machine, cached; not in the times above or below)")]


def disparity_offset_rows(estimate: dict | None) -> list[tuple[str, str]]:
    """The report row of the disparity-offset self-calibration (`pld_slam.stereo_calibration`); none when off."""
    if estimate is None:
        return []
    basis = f"{estimate['pairs']} frame pairs, frame gap {estimate['frame_gap']}, {estimate['ms'] / 1e3:.1f} s"
    if estimate["used"]:
        applied, estimated = estimate["offset_px"], estimate["estimate_px"]
        shrunk = f"shrunk from {estimated:+.3f}, " if applied != estimated else ""
        return [("disparity offset", f"{applied:+.3f} px ({shrunk}sigma {estimate['sigma_px']:.3f}, {basis})")]
    return [("disparity offset", f"not changed: {estimate['reason']} ({basis})")]


def parse_formats(ctx: click.Context, param: click.Parameter, value: str) -> tuple[str, ...]:
    """``--formats``: comma-separated names of `FORMATS`, in the order given, repeats dropped."""
    names = tuple(dict.fromkeys(name.strip() for name in value.split(",") if name.strip()))
    unknown = [name for name in names if name not in FORMATS]
    if unknown or not names:
        raise click.BadParameter(f"{value!r}: expected one or more of {','.join(FORMATS)}, separated by commas")
    return names


def run_warnings(summary: dict) -> list[str]:
    """The warnings of a run that ended normally, each a ``warning:`` line on stderr: a stereo pair that
    disagrees, frames lost short of an error, a rig known to be off left uncorrected."""
    return [warning for warning in (stereo_pair_warning(summary), lost_frames_warning(summary),
                                    uncalibrated_rig(summary)) if warning is not None]


def lost_frames_warning(summary: dict) -> str | None:
    """The warning of a run that lost frames short of an error (`pld_slam.eval.tracked_frames`); None otherwise."""
    tracking = summary["tracking"]
    return f"{summary['root']}: {tracking['message']}" if tracking["verdict"] == "some_lost" else None


def uncalibrated_rig(summary: dict) -> str | None:
    """The warning of a run whose rig is known to be off (its family's ``calibration.prior_sigma_px``, KITTI's)
    but whose disparity offset could not be estimated (a short or fast drive: too few frame pairs); None otherwise.
    Uncorrected, such an offset scales the whole trajectory (docs/decisions/0006-disparity-offset-self-calibration.md).
    """
    estimate = summary["disparity_offset"]
    prior = summary["config"]["calibration"]["prior_sigma_px"]
    if estimate is None or estimate["used"] or prior <= 0.0:
        return None
    return (f"{summary['root']}: the rig's disparity offset was not estimated ({estimate['reason']}); rigs of "
            f"this kind are off by about {prior:g} px (calibration.prior_sigma_px), which at 15 px of disparity "
            f"scales the trajectory by about {100.0 * prior / 15.0:.0f} %: a longer or slower drive gives the estimate")


def not_a_stereo_pair(summary: dict) -> str | None:
    """The error of a run whose images are not a stereo pair (`pld_slam.eval.stereo_pair`: swapped, the same
    image twice): the sequence and the check's warning; None for any other verdict, whose warning the table shows."""
    stereo_pair = summary["stereo_pair"]
    return f"{summary['root']}: {stereo_pair['warning']}" if stereo_pair["verdict"] == "not_a_pair" else None


def stereo_pair_warning(summary: dict) -> str | None:
    """The warning of a stereo pair's check that warns short of an error (`not_a_stereo_pair`); None otherwise."""
    stereo_pair = summary["stereo_pair"]
    if stereo_pair["warning"] is None or stereo_pair["verdict"] == "not_a_pair":
        return None
    return f"{summary['root']}: {stereo_pair['warning']}"


@click.command("run")
@click.argument("sequence_path", metavar="SEQUENCE", type=click.Path(exists=True, path_type=Path))
@config_files_option
@set_option
@click.option("--scale", type=click.FloatRange(0.05, 1.0), default=None,
              help="Resize frames and intrinsics by this factor on load (= --set dataset.scale=S).")
@click.option("--left-topic", default=None, help="ROS bag: the left image topic (when the bag has other images).")
@click.option("--right-topic", default=None, help="ROS bag: the right image topic.")
@click.option("--gt-topic", default=None,
              help="ROS bag: ground-truth poses (PoseStamped, TransformStamped or Odometry).")
@click.option("--calib", type=click.Path(exists=True, dir_okay=False, path_type=Path), default=None,
              help="ROS bag: a calib.yaml (generic layout's schema) instead of the bag's CameraInfo.")
@click.option("--out", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Output folder [default: runs/<sequence name>].")
@click.option("--max-frames", type=click.IntRange(min=1), default=None, help="Process only the first N frames.")
@click.option("--formats", default=",".join(DEFAULT_FORMATS), show_default=True, callback=parse_formats,
              help=f"Trajectory files to write, separated by commas: {','.join(FORMATS)}.")
@click.option("--json", "as_json", is_flag=True, help="Print summary.json instead of a table.")
@click.option("--save-dynamic", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Write each frame's features, coloured static (green) / dynamic (red), as PNGs here.")
@click.option("--rerun", type=click.Path(dir_okay=False, path_type=Path), default=None, metavar="FILE.rrd",
              help="Record the run for the rerun viewer (rerun FILE.rrd): each frame's image, features and pose, "
                   'the map at each keyframe; needs pip install "pld-slam[viz]".')
def run_command(sequence_path: Path, config_paths, overrides, scale: float | None, left_topic: str | None,
                right_topic: str | None, gt_topic: str | None, calib: Path | None, out: Path | None,
                max_frames: int | None, formats: tuple[str, ...], as_json: bool, save_dynamic: Path | None,
                rerun: Path | None) -> None:
    """Run PLD-SLAM on the stereo sequence SEQUENCE: a folder (KITTI, KITTI raw, EuRoC,
    generic, Argoverse) or a ROS bag (a ROS 1 .bag file or a ROS 2 bag folder).

    The dataset family's config (kitti.yaml, euroc.yaml, argoverse.yaml or
    synthetic.yaml, from the detected layout) is applied first, then --config files,
    then --set, then --scale.

    Writes trajectory.kitti.txt and trajectory.tum.txt (T_w_c of every frame, world =
    first camera; --formats adds trajectory.euroc.csv or leaves one out), summary.json
    (frames, failures, timing, real-time factor, ATE/RPE when the sequence has ground
    truth, the config and its sources), frames.csv (a row per frame: counts, each
    stage's ms, the map's size, memory), loops.csv and trajectory.png.
    Ctrl-C, SIGTERM or an error mid-run still writes the trajectory so far; while the run
    goes, trajectory.partial.tum.txt holds each frame's pose as tracked (kept if the run
    is killed, deleted once the final files are written). The files of an earlier run in
    the output folder are deleted first, but for its partial trajectory, kept as
    trajectory.partial.N.tum.txt; other files there are kept. The folder is locked while
    the run goes (run.lock): a second run into it is refused. A run that tracks
    none of its frames writes its files, then ends with an error (exit 2) naming the
    first failed frame and the likely causes; so does a run on images that are not a
    stereo pair (swapped, the same image twice), and one that tracks under 90 % of its
    frames (with 2 lost or more; the error says where the losses start and the likely
    cause); one that tracks under 95 % gets a warning. A pair whose matches leave their rows
    (a right camera out of sync) gets a warning, and so does a KITTI-like rig whose disparity
    offset the sequence was too short or too fast to estimate. --rerun records the run into FILE.rrd
    for the rerun viewer (open it with: rerun FILE.rrd).
    """
    sequence = open_sequence(sequence_path, BagOptions(left_topic, right_topic, gt_topic, calib))
    overrides = overrides if scale is None else (*overrides, f"dataset.scale={scale}")
    out = out if out is not None else Path("runs") / sequence.name
    summary = run_and_write(sequence, out, config_paths, overrides, max_frames, save_dynamic, formats, rerun)
    click.echo(json.dumps(summary, indent=2) if as_json else f"{format_run_table(summary)}\nwrote {out}/")
    # Nothing tracked, not a stereo pair, too few tracked (record 0024): the run's files are written, but its
    # trajectory is mostly guesses and must not pass as a result. A pair that is no pair says more than a count.
    tracking = summary["tracking"]
    if tracking["verdict"] == "none_tracked":
        raise TrackingError(tracking["message"])
    not_a_pair = not_a_stereo_pair(summary)
    if not_a_pair is not None:
        raise DatasetError(not_a_pair)
    if tracking["verdict"] == "few_tracked":
        raise TrackingError(f"{summary['root']}: {tracking['message']}")
    for warning in run_warnings(summary):
        click.echo(f"warning: {warning}", err=True)
