"""Dynamic labels against masks (precision, recall, outline margin) and their overlay images."""

import numpy as np
import pytest

from pld_slam.config import DynamicConfig
from pld_slam.eval.dynamic_labels import LabelCounts, label_counts
from pld_slam.io.dynamic_overlays import DYNAMIC_BGR, STATIC_BGR, draw_dynamic_overlay
from pld_slam.tracking.dynamic import DynamicLabels
from pld_slam.tracking.moving_masks import features_on_mask


def car_mask() -> np.ndarray:
    mask = np.zeros((120, 160), dtype=bool)
    mask[40:80, 60:120] = True
    return mask


MARGIN_PX = DynamicConfig().mask_margin_px


@pytest.mark.parametrize(("margin_px", "outline"), [(MARGIN_PX, True), (0, False)])
def test_points_on_the_mask_or_its_outline_count_as_moving(margin_px, outline):
    """The outline is ``dynamic.mask_margin_px`` wide: 2 px by default, none at 0."""
    uv = np.array([[90.0, 60.0], [61.0, 41.0], [58.4, 60.0], [50.0, 60.0], [10.0, 10.0]])
    on_points, _ = features_on_mask(uv, np.zeros((0, 4)), car_mask(), margin_px)
    assert on_points.tolist() == [True, True, outline, False, False]


def test_a_line_counts_as_moving_when_most_of_it_is_on_the_mask():
    segments = np.array([
        [70.0, 45.0, 70.0, 75.0],  # inside
        [30.0, 60.0, 100.0, 60.0],  # 3 of 5 samples inside (65, 82.5, 100)
        [10.0, 60.0, 70.0, 60.0],  # only the end touches
    ])
    _, on_lines = features_on_mask(np.zeros((0, 2)), segments, car_mask(), MARGIN_PX)
    assert on_lines.tolist() == [True, True, False]


def test_precision_and_recall_from_counts():
    counts = label_counts(np.array([True, True, False, False, True]), np.array([True, False, True, False, True]))
    assert counts == LabelCounts(true_positive=2, false_positive=1, false_negative=1, true_negative=1)
    assert counts.precision == 2 / 3 and counts.recall == 2 / 3
    total = counts + LabelCounts(true_positive=1)
    assert total.precision == 3 / 4 and total.recall == 3 / 4
    assert LabelCounts().precision is None and LabelCounts().recall is None


def test_overlay_colours_static_and_dynamic_features():
    left = np.full((120, 160), 100, dtype=np.uint8)
    labels = DynamicLabels(
        point_uv=np.array([[20.0, 20.0], [90.0, 60.0]]),
        point_dynamic=np.array([False, True]),
        line_segments=np.array([[140.0, 10.0, 140.0, 110.0]]),
        line_dynamic=np.array([False]),
    )
    image = draw_dynamic_overlay(left, labels, car_mask())
    assert image.shape == (120, 160, 3)
    assert tuple(image[20, 20]) == STATIC_BGR
    assert tuple(image[60, 90]) == DYNAMIC_BGR
    assert tuple(image[60, 140]) == STATIC_BGR
