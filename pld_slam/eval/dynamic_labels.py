"""Dynamic-feature labels against ground-truth masks of moving objects: precision and recall.

Which features lie on a moving object is decided by `pld_slam.tracking.moving_masks`, with the
run's ``dynamic.mask_margin_px``.
`MaskScores` is the evaluation's observer of a run (`pld_slam.system.FrameObserver`):
attached, it reads each tracked frame's mask and scores the frame's labels; a run without
it reads no mask for scoring.
"""

from dataclasses import dataclass

import numpy as np

from pld_slam.config import DynamicConfig
from pld_slam.datasets import StereoFrame, StereoSequence
from pld_slam.frontend import StereoFeatures
from pld_slam.tracking.dynamic import DynamicLabels
from pld_slam.tracking.moving_masks import features_on_mask
from pld_slam.tracking.tracker import TrackedFrame


@dataclass(frozen=True)
class LabelCounts:
    """Confusion counts of dynamic labels: flagged/not against on-object/not."""

    true_positive: int = 0
    false_positive: int = 0
    false_negative: int = 0
    true_negative: int = 0

    def __add__(self, other: "LabelCounts") -> "LabelCounts":
        return LabelCounts(
            self.true_positive + other.true_positive,
            self.false_positive + other.false_positive,
            self.false_negative + other.false_negative,
            self.true_negative + other.true_negative,
        )

    @property
    def precision(self) -> float | None:
        """Flagged features that are on moving objects; None when nothing was flagged."""
        flagged = self.true_positive + self.false_positive
        return self.true_positive / flagged if flagged else None

    @property
    def recall(self) -> float | None:
        """Features on moving objects that were flagged; None when none was on one."""
        moving = self.true_positive + self.false_negative
        return self.true_positive / moving if moving else None


def label_counts(flagged: np.ndarray, moving: np.ndarray) -> LabelCounts:
    """Confusion counts of ``flagged`` (N,) bool against the truth ``moving`` (N,) bool."""
    return LabelCounts(
        int(np.count_nonzero(flagged & moving)),
        int(np.count_nonzero(flagged & ~moving)),
        int(np.count_nonzero(~flagged & moving)),
        int(np.count_nonzero(~flagged & ~moving)),
    )


def frame_label_counts(
    labels: DynamicLabels | None, mask: np.ndarray, margin_px: int
) -> tuple[LabelCounts, LabelCounts]:
    """A frame's dynamic labels of points and lines against its moving-object mask (H, W) grown by
    ``margin_px``; empty counts when the frame has no labels."""
    if labels is None:
        return LabelCounts(), LabelCounts()
    on_points, on_lines = features_on_mask(labels.point_uv, labels.line_segments, mask, margin_px)
    return label_counts(labels.point_dynamic, on_points), label_counts(labels.line_dynamic, on_lines)


class MaskScores:
    """A `System` frame observer scoring each tracked frame's dynamic labels against the
    sequence's moving-object mask of that frame (`StereoSequence.dynamic_mask`).

    ``points`` and ``lines`` hold the `LabelCounts` of each frame the observer saw, by frame
    index; frames it did not see (no images, or before the first usable frame) have none.
    The sequence must have masks; ``margin_px`` is the run's ``dynamic.mask_margin_px`` (default: its
    default).
    """

    def __init__(self, sequence: StereoSequence, margin_px: int = DynamicConfig.mask_margin_px) -> None:
        if sequence.dynamic_mask_paths is None:
            raise ValueError(f"{sequence.root} has no dynamic_masks/ folder to score the labels against")
        self.sequence = sequence
        self.margin_px = margin_px
        self.points: dict[int, LabelCounts] = {}
        self.lines: dict[int, LabelCounts] = {}

    def __call__(self, frame: StereoFrame, features: StereoFeatures, tracked: TrackedFrame) -> None:
        mask = self.sequence.dynamic_mask(frame.index)
        self.points[frame.index], self.lines[frame.index] = frame_label_counts(tracked.dynamic, mask, self.margin_px)
