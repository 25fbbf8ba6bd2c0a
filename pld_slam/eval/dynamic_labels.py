"""Dynamic-feature labels against ground-truth masks of moving objects: precision and recall.

Which features lie on a moving object is decided by `pld_slam.tracking.moving_masks`.
"""

from dataclasses import dataclass

import numpy as np


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
