"""The summary of a run: frames, failures, per-stage timing, real-time factor, accuracy.

`summarise_run` returns plain JSON-ready data; its accuracy keys are those of
``pld-slam eval --json`` (`EvalResult`), null where the sequence has no ground truth or
too few frames overlap it.
"""

import dataclasses
from collections import Counter
from collections.abc import Sequence

import numpy as np

from pld_slam.config import Config, config_to_dict
from pld_slam.datasets import StereoSequence
from pld_slam.errors import TrajectoryError
from pld_slam.eval.dynamic_labels import LabelCounts, MaskScores
from pld_slam.eval.loop_truth import score_loops
from pld_slam.eval.metrics import EvalResult, evaluate
from pld_slam.eval.stereo_pair import stereo_pair_summary
from pld_slam.eval.tracked_frames import tracked_frames_summary
from pld_slam.loop.loop_closing import LoopClosing
from pld_slam.system import STAGES, RunResult
from pld_slam.tracking.tracker import TrackingStatus
from pld_slam.trajectory import Trajectory

_ACCURACY_KEYS = tuple(EvalResult.__dataclass_fields__)


def stage_timing(result: RunResult) -> dict[str, dict[str, float]]:
    """Median and mean wall time [ms] of each stage over the frames that ran it."""
    timing = {}
    for stage in STAGES:
        values = [record.stage_ms[stage] for record in result.records if stage in record.stage_ms]
        if values:
            timing[stage] = {"median": float(np.median(values)), "mean": float(np.mean(values))}
    return timing


def real_time_factor(sequence: StereoSequence, result: RunResult) -> float | None:
    """Sequence time covered by the processed frames over the wall time spent on them.

    The covered time is the number of frames over the sequence's nominal frame rate
    (`StereoSequence.frame_rate`: KITTI 10 Hz, EuRoC 20 Hz, Argoverse 5 Hz, or measured
    from the times where the dataset states none), so that a run of N frames of a 10 Hz
    sequence covers N / 10 s whatever gaps its times have. None for fewer than 2 frames
    or an unknown rate.
    """
    hz = sequence.frame_rate.hz
    if len(result.records) < 2 or hz is None or result.wall_seconds <= 0.0:
        return None
    return len(result.records) / hz / result.wall_seconds


def world_frame(result: RunResult) -> int | None:
    """The index of the first usable frame, whose camera is the run's world; None before one.

    See `pld_slam.system`: the frames before it hold the identity as a placeholder.
    """
    return next((r.index for r in result.records if r.status is TrackingStatus.FIRST), None)


def accuracy_from_world_frame(sequence: StereoSequence, result: RunResult) -> dict[str, float | int | None]:
    """`accuracy` of the frames from the `world_frame` on: the rows before it are placeholders, not estimates.

    Counting the placeholders would add the motion before the world frame as error. The
    estimate's world (the world frame's camera) and the ground truth's (frame 0's) differ
    then, which the SE(3) alignment of `evaluate` absorbs. ``n_matched`` says how many
    frames were compared; every key is null before a usable frame.
    """
    first = world_frame(result)
    if first is None:
        return dict.fromkeys(_ACCURACY_KEYS)
    trajectory = result.trajectory()
    from_first = np.array([record.index >= first for record in result.records], dtype=bool)
    return accuracy(sequence.groundtruth, Trajectory(trajectory.timestamps[from_first], trajectory.poses[from_first]))


def accuracy(groundtruth: Trajectory | None, estimate: Trajectory) -> dict[str, float | int | None]:
    """The `EvalResult` keys of the estimate against the ground truth, null where not computable."""
    if groundtruth is None:
        return dict.fromkeys(_ACCURACY_KEYS)
    try:
        return evaluate(groundtruth, estimate).as_dict()
    except TrajectoryError:  # too few matched poses to align, e.g. a run stopped after 2 frames
        return dict.fromkeys(_ACCURACY_KEYS)


def dynamic_summary(result: RunResult, mask_scores: MaskScores | None = None) -> dict:
    """Features marked dynamic per frame, and (with ``mask_scores``) precision and recall of the labels.

    ``per_frame`` lists, for every frame, how many matched points and lines were marked
    dynamic and how many were matched; ``points`` / ``lines`` hold precision and recall
    over the whole run against the moving-object masks (``mask_scores``, the run's
    observer), and the counts behind them (``flagged``, ``on_moving_objects``,
    ``flagged_on_them``), null without scores or when a frame has none (its images could
    not be used).
    """
    records = result.records
    per_frame = [
        {
            "index": r.index,
            "points": r.counts.dynamic_points,
            "lines": r.counts.dynamic_lines,
            "matched_points": r.counts.points_after_filter,
            "matched_lines": r.counts.lines_after_filter,
        }
        for r in records
    ]
    points, lines = ({}, {}) if mask_scores is None else (mask_scores.points, mask_scores.lines)
    marked = sum(f["points"] + f["lines"] for f in per_frame)
    matched = sum(f["matched_points"] + f["matched_lines"] for f in per_frame)
    return {
        "marked_fraction": marked / matched if matched else None,
        "points": _label_quality([points.get(r.index) for r in records]),
        "lines": _label_quality([lines.get(r.index) for r in records]),
        "per_frame": per_frame,
    }


def _label_quality(per_frame: list[LabelCounts | None]) -> dict[str, float | int | None]:
    """Precision, recall and counts of dynamic labels summed over frames; nulls without masks."""
    if not per_frame or any(counts is None for counts in per_frame):
        return dict.fromkeys(("precision", "recall", "flagged", "on_moving_objects", "flagged_on_them"))
    total = sum(per_frame, LabelCounts())
    return {
        "precision": total.precision,
        "recall": total.recall,
        "flagged": total.true_positive + total.false_positive,
        "on_moving_objects": total.true_positive + total.false_negative,
        "flagged_on_them": total.true_positive,
    }


def mapping_summary(result: RunResult) -> dict | None:
    """What local mapping did over the run; None without a map (``mapping.enabled: false``).

    ``keyframes`` were inserted (``keyframe_reasons`` says why, `pld_slam.keyframes`) and
    ``keyframes_alive`` remain after culling; ``landmarks`` are alive at the end and
    ``landmarks_created`` over the run; ``culled`` counts landmarks and keyframes removed;
    ``local_ba`` has the runs and their median and max wall time [ms] and residual
    evaluations, and the outlier observations they removed; ``step_ms_median`` the median
    wall time of each step of a keyframe's insertion.
    """
    world_map = result.map
    if world_map is None:
        return None
    insertions = result.insertions
    reasons = Counter(r.keyframe.value for r in result.records if r.keyframe is not None)
    ba = [i.local_ba for i in insertions if i.local_ba is not None]
    steps = sorted({step for i in insertions for step in i.stage_ms})
    return {
        "keyframes": len(insertions),
        "keyframes_alive": len(world_map.keyframes),
        "keyframe_reasons": dict(sorted(reasons.items())),
        "landmarks": {"points": world_map.points.n_alive, "lines": world_map.lines.n_alive},
        "landmarks_created": {"points": len(world_map.points), "lines": len(world_map.lines)},
        "culled": {
            "landmarks": sum(i.culled_landmarks for i in insertions),
            "keyframes": sum(len(i.culled_keyframes) for i in insertions),
        },
        "fused": sum(i.fused for i in insertions),
        "local_ba": {
            "runs": len(ba),
            "ms_median": _median_or_none([b.ms for b in ba]),
            "ms_max": max((b.ms for b in ba), default=None),
            "nfev_median": _median_or_none([b.nfev for b in ba]),
            "nfev_max": max((b.nfev for b in ba), default=None),
            "removed_observations": sum(b.removed_observations for b in ba),
        },
        "step_ms_median": {step: _median_or_none([i.stage_ms[step] for i in insertions if step in i.stage_ms])
                           for step in steps},
    }


def loop_summary(result: RunResult, config: Config, groundtruth: Trajectory | None) -> dict | None:
    """What loop closing and global BA did; None without a loop stage (no map, or ``loop.detector: none``).

    ``detector``: ``loop.detector``; ``candidates``: every candidate (query and candidate
    keyframe, frame and time, the detector's score and bar, each test's value, NaN written
    as null where not reached, accepted or the test it failed,
    `pld_slam.loop.loop_closing.LoopCandidate`); ``loops``: the closed loops with their
    correction, fusion and pose-graph solve; ``ground_truth``: precision and recall against
    the ground truth (`pld_slam.eval.loop_truth`, null without one); ``global_ba``: the
    final BA.
    """
    loop_closing = result.loop_closing
    if loop_closing is None:
        return None
    ba = result.global_ba
    return {
        "detector": config.loop.detector,
        "ground_truth": None if groundtruth is None else loop_truth(loop_closing, groundtruth, config),
        "candidates": [_json_ready(dataclasses.asdict(c)) for c in loop_closing.candidates],
        "loops": [
            {
                "keyframe": loop.keyframe, "candidate": loop.candidate, "frame": loop.frame,
                "candidate_frame": loop.candidate_frame, "correction_m": loop.correction_m,
                "correction_deg": loop.correction_deg, "fused": loop.fused, "graph_edges": loop.graph_edges,
                "pose_graph_ms": loop.pose_graph.ms, "pose_graph_nfev": loop.pose_graph.nfev, "ms": loop.ms,
            }
            for loop in loop_closing.loops
        ],
        "global_ba": None if ba is None else {
            "ms": ba.ms, "nfev": ba.nfev, "keyframes": ba.free_keyframes + ba.fixed_keyframes,
            "points": ba.points, "lines": ba.lines, "removed_observations": ba.removed_observations,
        },
    }


def _json_ready(values: dict) -> dict:
    """``values`` with NaN floats as None (JSON has no NaN)."""
    return {key: None if isinstance(value, float) and np.isnan(value) else value for key, value in values.items()}


def loop_truth(loop_closing: LoopClosing, groundtruth: Trajectory, config: Config) -> dict | None:
    """The run's loop closing scored against ground truth (`pld_slam.eval.loop_truth`); None before any query."""
    if not loop_closing.queries:
        return None
    ids, times = np.array(loop_closing.queries).T
    candidates = np.array([(c.keyframe, c.candidate) for c in loop_closing.candidates], dtype=np.int64)
    loops = np.array([(loop.keyframe, loop.candidate) for loop in loop_closing.loops], dtype=np.int64)
    return score_loops(groundtruth, ids.astype(np.int64), times, candidates, loops,
                       config.loop.exclude_recent_keyframes).as_dict()


def _median_or_none(values: list[int]) -> float | None:
    """Median of ``values``, None for none (a run stopped at its first frame)."""
    return float(np.median(values)) if values else None


def summarise_run(
    sequence: StereoSequence, result: RunResult, config: Config, config_sources: Sequence[str] | None = None,
    mask_scores: MaskScores | None = None,
) -> dict:
    """JSON-ready summary of a run on ``sequence`` (see the module docstring).

    ``config_sources`` (`RunConfig.sources`: defaults, family file, ``--config`` files,
    ``--set`` overrides) is written as ``config_sources``, null when not given.
    ``mask_scores``, the observer that scored the run's dynamic labels against the
    sequence's masks, gives ``dynamic``'s precision and recall (`dynamic_summary`).
    """
    records = result.records
    return {
        "sequence": sequence.name,
        "layout": sequence.layout,
        "cameras": sequence.cameras,
        "root": str(sequence.root),
        "frames": len(records),
        "frames_in_sequence": len(sequence),
        "completed": result.stop_reason is None,
        "stop_reason": result.stop_reason,
        "tracking_failures": [r.index for r in records if r.status is TrackingStatus.LOST],
        "recovered_frames": [r.index for r in records if r.status is TrackingStatus.RECOVERED],
        "skipped_frames": [{"index": r.index, "reason": r.skipped_reason} for r in records if r.skipped_reason],
        "tracking": tracked_frames_summary(records),
        "timing_ms": stage_timing(result),
        "wall_seconds": result.wall_seconds,
        "kernels_seconds": result.kernels_seconds,
        "frontend_worker": result.frontend_worker,
        "real_time_factor": real_time_factor(sequence, result),
        "frame_rate": {"hz": sequence.frame_rate.hz, "source": sequence.frame_rate.source},
        "disparity_offset": None if result.disparity_offset is None else result.disparity_offset.as_dict(),
        "world_frame": world_frame(result),
        "stereo_pair": stereo_pair_summary(records),
        **accuracy_from_world_frame(sequence, result),
        "features_median": {
            "stereo_points": _median_or_none([r.n_points for r in records]),
            "stereo_lines": _median_or_none([r.n_lines for r in records]),
            "point_inliers": _median_or_none([r.counts.point_inliers for r in records[1:]]),
            "line_inliers": _median_or_none([r.counts.line_inliers for r in records[1:]]),
            "map_point_inliers": _median_or_none([r.counts.map_point_inliers for r in records[1:]]),
            "map_line_inliers": _median_or_none([r.counts.map_line_inliers for r in records[1:]]),
        },
        "mapping": mapping_summary(result),
        "loop": loop_summary(result, config, sequence.groundtruth),
        "dynamic": dynamic_summary(result, mask_scores),
        "config": config_to_dict(config),
        "config_sources": None if config_sources is None else list(config_sources),
    }
