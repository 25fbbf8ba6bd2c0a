"""Overlay images of dynamic labels: the left image with its matched features coloured.

Static features are drawn green, dynamic ones red (points as dots, lines as segments);
where the sequence has a moving-object mask, its outline is drawn in yellow so a person
can see at a glance whether the red features sit on the moving objects.
"""

from pathlib import Path

import cv2
import numpy as np

from pld_slam.tracking.dynamic import DynamicLabels

STATIC_BGR = (0, 200, 0)
DYNAMIC_BGR = (0, 0, 255)
MASK_BGR = (0, 220, 255)


def draw_dynamic_overlay(left: np.ndarray, labels: DynamicLabels, mask: np.ndarray | None = None) -> np.ndarray:
    """Colour image (H, W, 3) uint8: ``left`` (H, W) uint8 with labelled features and the mask outline."""
    image = cv2.cvtColor(left, cv2.COLOR_GRAY2BGR)
    if mask is not None:
        contours, _ = cv2.findContours(mask.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
        cv2.drawContours(image, contours, -1, MASK_BGR, 1)
    for segment, dynamic in zip(np.rint(labels.line_segments).astype(int), labels.line_dynamic):
        cv2.line(image, tuple(segment[:2]), tuple(segment[2:]), DYNAMIC_BGR if dynamic else STATIC_BGR, 2)
    for (u, v), dynamic in zip(np.rint(labels.point_uv).astype(int), labels.point_dynamic):
        cv2.circle(image, (u, v), 3, DYNAMIC_BGR if dynamic else STATIC_BGR, -1)
    return image


def write_dynamic_overlay(path: Path, left: np.ndarray, labels: DynamicLabels, mask: np.ndarray | None) -> None:
    """Write `draw_dynamic_overlay` as a PNG at ``path``."""
    cv2.imwrite(str(path), draw_dynamic_overlay(left, labels, mask))
