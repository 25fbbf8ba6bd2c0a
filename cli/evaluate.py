"""``pld-slam eval``: accuracy of an estimated trajectory against ground truth."""

import json
from pathlib import Path

import click

from pld_slam.datasets import open_sequence
from pld_slam.errors import DatasetError, TrajectoryError
from pld_slam.eval import EvalResult, evaluate, plot_error_over_time, plot_trajectory_top_view
from pld_slam.eval.metrics import ate_result
from pld_slam.eval.plots import comparison_error_figure, comparison_top_view_figure, save_figure
from pld_slam.io.evo_results import write_evo_result
from pld_slam.io.output_folder import create_output_folder
from pld_slam.io.trajectory import FORMATS, detect_format, is_euroc_body_groundtruth, read_trajectory
from pld_slam.trajectory import Trajectory

SCALE_LABEL = "scale (sim3) / path"
"""The label of `scale_text`'s row, in the ``eval`` and ``run`` tables alike."""

_ROWS = (
    ("ATE RMSE", "ate_rmse_m", "m", "{:.4f}"),
    ("ATE RMSE after Sim(3)", "ate_sim3_rmse_m", "m", "{:.4f}"),
    (SCALE_LABEL, "sim3_scale", "", ""),
    ("ATE rotation RMSE", "ate_rot_rmse_deg", "deg", "{:.4f}"),
    ("RPE trans RMSE (1 frame)", "rpe_trans_rmse_m", "m", "{:.4f}"),
    ("RPE rot RMSE (1 frame)", "rpe_rot_rmse_deg", "deg", "{:.4f}"),
    ("KITTI t_rel", "t_rel_pct", "%", "{:.2f}"),
    ("KITTI r_rel", "r_rel_deg_per_100m", "deg/100 m", "{:.2f}"),
    ("matched poses", "n_matched", "", "{:d}"),
)


def coverage_note(n_matched: int | None, n_frames: int) -> str | None:
    """``evaluated on N of M frames`` when the accuracy covers fewer than all ``n_frames`` frames, else None.

    A ground truth shorter than the run, or timestamps that do not pair, leave frames out
    of every metric; we say so, because the numbers alone read as the whole run's.
    """
    if n_matched is None or n_matched >= n_frames:
        return None
    return f"evaluated on {n_matched} of {n_frames} frames"


def scale_text(sim3_scale: float | None, path_ratio: float | None) -> str:
    """The estimate's scale in one line: ``1.0091 / 1.0089 (0.91 % long)``.

    Both figures are the estimate's size over the ground truth's (`EvalResult`): the Sim(3)
    scale, then the path-length ratio. The percentage is the Sim(3) scale's, which noise
    does not lengthen as it does a path. ``n/a`` for a figure not computed (no ground
    truth; for the path, a ground truth standing still).
    """
    if sim3_scale is None:
        return "n/a"
    path = "n/a" if path_ratio is None else f"{path_ratio:.4f}"
    error_pct = 100.0 * (sim3_scale - 1.0)
    return f"{sim3_scale:.4f} / {path} ({abs(error_pct):.2f} % {'long' if error_pct >= 0.0 else 'short'})"


def format_result_table(result: EvalResult, n_estimated: int) -> str:
    """The metrics as an aligned two-column text table (None shows as n/a).

    ``n_estimated`` is the number of poses in the estimate, for `coverage_note`.
    """
    lines = [f"{label:<26}{text}" for (label, *_), text in zip(_ROWS, metric_texts(result), strict=True)]
    coverage = coverage_note(result.n_matched, n_estimated)
    if coverage:
        lines.append(f"{'':<26}{coverage}")
    return "\n".join(lines)


def metric_texts(result: EvalResult) -> list[str]:
    """The value of each row of `_ROWS` as the tables print it."""
    values = result.as_dict()
    texts = []
    for _, key, unit, fmt in _ROWS:
        value = values[key]
        if key == "sim3_scale":
            texts.append(scale_text(value, values["path_ratio"]))
        else:
            texts.append("n/a (path < 100 m)" if value is None else f"{fmt.format(value)} {unit}".rstrip())
    return texts


def format_comparison_table(results: dict[str, EvalResult], n_estimated: dict[str, int]) -> str:
    """The metrics of several estimates side by side, a column per estimate (its name on top),
    and under the table each estimate's `coverage_note` where it has one."""
    columns = {name: metric_texts(result) for name, result in results.items()}
    widths = {name: max(len(name), *(len(text) for text in texts)) + 2 for name, texts in columns.items()}
    lines = [f"{'':<26}" + "".join(f"{name:<{widths[name]}}" for name in columns)]
    for row, (label, *_) in enumerate(_ROWS):
        lines.append(f"{label:<26}" + "".join(f"{texts[row]:<{widths[name]}}" for name, texts in columns.items()))
    for name, result in results.items():
        coverage = coverage_note(result.n_matched, n_estimated[name])
        if coverage:
            lines.append(f"{name}: {coverage}")
    return "\n".join(line.rstrip() for line in lines)


def estimate_names(paths: tuple[Path, ...]) -> dict[str, Path]:
    """A name for each estimate file: its stem, or ``FOLDER_STEM`` where stems repeat (runs'
    ``trajectory.tum.txt``), or its whole path where those repeat too."""
    def unique(name_of) -> bool:
        return len({name_of(path) for path in paths}) == len(paths)

    for name_of in (lambda path: path.stem, lambda path: f"{path.parent.name}_{path.stem}", str):
        if unique(name_of):
            return {name_of(path): path for path in paths}
    raise click.BadParameter("the same estimate file is given twice", param_hint="EST")


def _stamp_by_frame(estimate: Trajectory, frame_times, est_path: Path) -> Trajectory:
    """A KITTI-format estimate (no timestamps) given the times of the sequence's frames."""
    if len(estimate) > len(frame_times):
        raise TrajectoryError(
            f"{est_path}: {len(estimate)} poses but the sequence has {len(frame_times)} frames"
        )
    return Trajectory(frame_times[: len(estimate)], estimate.poses)


def load_pair(gt: Path, est: Path, fmt: str) -> tuple[Trajectory, Trajectory, bool]:
    """Ground truth, estimate, and whether to pair them by row index instead of timestamp.

    ``gt`` is a trajectory file or a sequence folder (its ground truth in rectified cam0,
    first pose identity). KITTI files carry no timestamps: two KITTI files pair by row;
    a KITTI estimate against a sequence folder takes the frame times of the sequence.
    EuRoC's body-frame ground truth file is compared as given, with a warning on stderr
    (`is_euroc_body_groundtruth`): we do not convert it, because the file alone does not
    say which camera the estimate is of; the sequence folder does.
    """
    est_format = detect_format(est) if fmt == "auto" else fmt
    estimate = read_trajectory(est, fmt)
    if gt.is_dir():
        sequence = open_sequence(gt)
        if sequence.groundtruth is None:
            raise DatasetError(f"{gt}: this sequence has no ground truth")
        if est_format == "kitti":
            estimate = _stamp_by_frame(estimate, sequence.timestamps, est)
        return sequence.groundtruth, estimate, False
    if is_euroc_body_groundtruth(gt):
        click.echo(f"warning: {gt} is EuRoC's ground truth of the body (IMU) frame, not of the camera; "
                   "pass the sequence folder as GT to compare in the rectified left camera", err=True)
    gt_format = detect_format(gt) if fmt == "auto" else fmt
    if (gt_format == "kitti") != (est_format == "kitti"):
        raise TrajectoryError(
            f"cannot pair {gt} ({gt_format}) with {est} ({est_format}): KITTI files have no "
            "timestamps; give both in KITTI format, or the sequence folder as GT"
        )
    return read_trajectory(gt, fmt), estimate, gt_format == "kitti"


@click.command("eval")
@click.argument("gt", type=click.Path(exists=True, path_type=Path))
@click.argument("est", nargs=-1, required=True, type=click.Path(exists=True, dir_okay=False, path_type=Path))
@click.option("--format", "fmt", type=click.Choice(("auto",) + FORMATS), default="auto",
              show_default=True, help="Format of the trajectory files (auto: from their content).")
@click.option("--align", type=click.Choice(("se3", "sim3", "none")), default="se3", show_default=True,
              help="Alignment before the ATE: rigid (SE(3) Umeyama), with scale, or none.")
@click.option("--max-diff", type=click.FloatRange(min=0.0), default=0.01, show_default=True,
              help="Largest timestamp difference [s] when pairing poses by time.")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object instead of a table.")
@click.option("--plot", "plot_dir", type=click.Path(file_okay=False, path_type=Path),
              help="Also write trajectory_top_view.png and ate_over_time.png here (every EST on one plot).")
@click.option("--save-results", "results_path", type=click.Path(path_type=Path),
              help="Also write evo's result file of the ATE (a zip evo_res compares): this file for one EST, "
                   "NAME.zip in this folder for several (NAME as in the table).")
def eval_command(gt: Path, est: tuple[Path, ...], fmt: str, align: str, max_diff: float, as_json: bool,
                 plot_dir: Path | None, results_path: Path | None) -> None:
    """Compare the estimated trajectories EST (one or more) with the ground truth GT.

    GT is a trajectory file (KITTI, TUM or EuRoC) or a sequence folder whose ground truth
    pld-slam reads. Prints ATE RMSE (as --align, and after Sim(3)), the estimate's scale
    (Sim(3) scale and path-length ratio, estimate over ground truth: above 1 is too long),
    RPE, and the KITTI devkit t_rel / r_rel (on paths of at least 100 m); with several
    EST, a column each, named by file (or folder and file where names repeat).
    """
    paths = estimate_names(est)
    if plot_dir is not None:
        create_output_folder(plot_dir)
    if results_path is not None:
        create_output_folder(results_path if len(paths) > 1 else results_path.parent)
    loaded = {name: load_pair(gt, path, fmt) for name, path in paths.items()}
    results = {name: evaluated(paths[name], *pair, align, max_diff) for name, pair in loaded.items()}
    if plot_dir is not None:
        write_plots(plot_dir, loaded, align, max_diff)
    if results_path is not None:
        write_results(results_path, loaded, align, max_diff)
    if len(results) == 1:
        (name, result), = results.items()
        click.echo(json.dumps(result.as_dict()) if as_json else format_result_table(result, len(loaded[name][1])))
    elif as_json:
        click.echo(json.dumps({name: result.as_dict() for name, result in results.items()}))
    else:
        click.echo(format_comparison_table(results, {name: len(pair[1]) for name, pair in loaded.items()}))


def evaluated(path: Path, groundtruth: Trajectory, estimate: Trajectory, by_index: bool, align: str,
              max_diff: float) -> EvalResult:
    """`evaluate` of the estimate read from ``path``; a `TrajectoryError` names the file."""
    try:
        return evaluate(groundtruth, estimate, align=align, by_index=by_index, max_diff=max_diff)
    except TrajectoryError as error:
        raise TrajectoryError(f"{path}: {error}") from None


def write_plots(plot_dir: Path, loaded: dict[str, tuple[Trajectory, Trajectory, bool]], align: str,
                max_diff: float) -> None:
    """trajectory_top_view.png and ate_over_time.png of every estimate in ``plot_dir`` (created by the command
    before its work): one estimate as `plot_trajectory_top_view` draws it, several on one plot each."""
    (name, (groundtruth, estimate, by_index)), *_ = loaded.items()
    if len(loaded) == 1:
        plot_trajectory_top_view(plot_dir / "trajectory_top_view.png", groundtruth, estimate,
                                 title=name, align=align, by_index=by_index, max_diff=max_diff)
        plot_error_over_time(plot_dir / "ate_over_time.png", groundtruth, estimate,
                             align=align, by_index=by_index, max_diff=max_diff)
        return
    estimates = {name: estimate for name, (_, estimate, _) in loaded.items()}
    save_figure(comparison_top_view_figure(groundtruth, estimates, align=align, by_index=by_index,
                                           max_diff=max_diff), plot_dir / "trajectory_top_view.png")
    save_figure(comparison_error_figure(groundtruth, estimates, align=align, by_index=by_index, max_diff=max_diff),
                plot_dir / "ate_over_time.png")


def write_results(path: Path, loaded: dict[str, tuple[Trajectory, Trajectory, bool]], align: str,
                  max_diff: float) -> None:
    """evo's result zip of each estimate's ATE: ``path`` itself for one estimate, ``path/NAME.zip``
    for several (a name that is a whole path: its ``/`` as ``_``); the folder created by the command before its
    work."""
    for name, (groundtruth, estimate, by_index) in loaded.items():
        target = path if len(loaded) == 1 else path / f"{name.replace('/', '_')}.zip"
        write_evo_result(target, ate_result(groundtruth, estimate, name, align, by_index, max_diff))
