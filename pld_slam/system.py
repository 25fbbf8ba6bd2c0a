"""`System`: the stages of PLD-SLAM wired together, run in order for each frame.

For now the stages are the front end (stereo points and lines of each pair) and tracking
(frame-to-frame pose); mapping, loop closure and the final global BA join here as they
are built. `System` keeps a `FrameRecord` per frame, so a run stopped early (Ctrl-C, an
error) still has the trajectory of every frame it processed.
"""

import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

import numpy as np

from pld_slam.config import Config
from pld_slam.datasets import StereoFrame, StereoSequence
from pld_slam.errors import ConfigError, DatasetError
from pld_slam.eval.dynamic_labels import LabelCounts, label_counts
from pld_slam.frontend import extract_stereo_features
from pld_slam.tracking.dynamic import DynamicLabels
from pld_slam.tracking.moving_masks import features_on_mask
from pld_slam.tracking.tracker import TrackedFrame, Tracker, TrackingCounts, TrackingStatus
from pld_slam.trajectory import Trajectory

STAGES = ("load", "frontend", "matching", "filters", "pose", "dynamic", "total")
"""Timed stages of one frame, in order; ``total`` is the frame's whole wall time."""


@dataclass(frozen=True)
class FrameRecord:
    """What the system produced for one frame.

    Attributes
    ----------
    index, timestamp : frame number in the sequence and time [s].
    T_w_c : (4, 4) camera-to-world pose.
    status : how tracking obtained the pose.
    counts : matches, filter survivors and inliers.
    stage_ms : wall time per stage [ms] (keys from `STAGES`).
    n_points, n_lines : stereo points and lines the front end found.
    skipped_reason : why the frame's images could not be used, or None.
    dynamic_points, dynamic_lines : label counts of the matched points and lines against
        the sequence's moving-object masks (synthetic sequences), or None without masks.
    """

    index: int
    timestamp: float
    T_w_c: np.ndarray
    status: TrackingStatus
    counts: TrackingCounts
    stage_ms: dict[str, float]
    n_points: int = 0
    n_lines: int = 0
    skipped_reason: str | None = None
    dynamic_points: LabelCounts | None = None
    dynamic_lines: LabelCounts | None = None


@dataclass
class RunResult:
    """The records of a run so far, and whether it went to the end."""

    records: list[FrameRecord] = field(default_factory=list)
    wall_seconds: float = 0.0
    stop_reason: str | None = None

    def trajectory(self) -> Trajectory:
        """``T_w_c`` of every processed frame."""
        return Trajectory(
            np.array([r.timestamp for r in self.records]),
            np.array([r.T_w_c for r in self.records]).reshape(-1, 4, 4),
        )


FrameObserver = Callable[[StereoFrame, TrackedFrame], None]
"""Called with each frame that had images and what tracking made of it (e.g. to draw overlays)."""


class System:
    """PLD-SLAM on one stereo sequence: call `run`, or `process_frame` frame by frame."""

    def __init__(self, sequence: StereoSequence, config: Config, observer: FrameObserver | None = None) -> None:
        self.sequence = sequence
        self.config = config
        if config.dynamic.from_masks and sequence.dynamic_mask_paths is None:
            raise ConfigError(
                f"dynamic.from_masks is set but {sequence.root} has no dynamic_masks/ folder (one mask per left image)"
            )
        self.tracker = Tracker(sequence.camera, config)
        self.result = RunResult()
        self._observer = observer

    def process_frame(self, index: int) -> FrameRecord:
        """Load, extract and track frame ``index``; an unreadable frame is skipped, not fatal.

        The dataset raises `DatasetError` for an unreadable image when it is read; the
        run goes on (the motion model gives that frame's pose, flagged in its record),
        because one corrupt file in a 4,541-frame sequence should not cost the rest.
        """
        start = time.perf_counter()
        timestamp = float(self.sequence.timestamps[index])
        try:
            frame = self.sequence[index]
        except DatasetError as error:
            tracked = self.tracker.skip()
            record = FrameRecord(index, timestamp, tracked.T_w_c, tracked.status, tracked.counts,
                                 {"total": _ms_since(start)}, skipped_reason=str(error))
            self._add(record, start)
            return record
        loaded = time.perf_counter()
        features = extract_stereo_features(
            frame.left, frame.right, self.sequence.camera, self.config.points, self.config.lines
        )
        extracted = time.perf_counter()
        moving_mask = self.sequence.dynamic_mask(index) if self.config.dynamic.from_masks else None
        tracked = self.tracker.track(features, moving_mask)
        stage_ms = {"load": 1e3 * (loaded - start), "frontend": 1e3 * (extracted - loaded), **tracked.stage_ms}
        stage_ms["total"] = _ms_since(start)
        truth = moving_mask if moving_mask is not None else self.sequence.dynamic_mask(index)
        point_counts, line_counts = _label_counts_against(truth, tracked.dynamic)
        record = FrameRecord(index, timestamp, tracked.T_w_c, tracked.status, tracked.counts, stage_ms,
                             n_points=len(features.points), n_lines=len(features.lines),
                             dynamic_points=point_counts, dynamic_lines=line_counts)
        self._add(record, start)
        if self._observer is not None:
            self._observer(frame, tracked)
        return record

    def run(self, max_frames: int | None = None,
            progress: Callable[[Iterable[int]], Iterable[int]] = iter) -> RunResult:
        """Process the frames in order (the first ``max_frames`` if given).

        ``progress`` wraps the frame indices (e.g. ``tqdm``). Ctrl-C or an error stops the
        loop with `result` holding every frame processed so far and ``stop_reason`` set;
        the exception is re-raised for the caller to report.
        """
        n_frames = len(self.sequence) if max_frames is None else min(max_frames, len(self.sequence))
        try:
            for index in progress(range(n_frames)):
                self.process_frame(index)
        except KeyboardInterrupt:
            self.result.stop_reason = "interrupted"
            raise
        except Exception as error:
            self.result.stop_reason = f"{type(error).__name__}: {error}"
            raise
        return self.result

    def _add(self, record: FrameRecord, start: float) -> None:
        self.result.records.append(record)
        self.result.wall_seconds += time.perf_counter() - start


def _label_counts_against(
    mask: np.ndarray | None, labels: DynamicLabels | None
) -> tuple[LabelCounts | None, LabelCounts | None]:
    """A frame's dynamic labels against its moving-object mask (H, W); None, None without a mask."""
    if mask is None:
        return None, None
    if labels is None:
        return LabelCounts(), LabelCounts()
    on_points, on_lines = features_on_mask(labels.point_uv, labels.line_segments, mask)
    return label_counts(labels.point_dynamic, on_points), label_counts(labels.line_dynamic, on_lines)


def _ms_since(start: float) -> float:
    return 1e3 * (time.perf_counter() - start)
