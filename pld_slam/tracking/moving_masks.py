"""Features on moving-object masks: which points and lines lie on a moving object.

A mask (H, W) bool marks the pixels of moving objects in a left image: the synthetic
sequences' ground truth (``dynamic_masks/``), or a segmentation a user supplies in the
same layout. The tracker takes its dynamic labels from it when ``dynamic.from_masks`` is
set, and the run summary scores the detectors against it.

A point belongs to a moving object when the mask, dilated by ``dynamic.mask_margin_px`` (2 px), is set
at its (rounded) pixel: a corner on an object's outline (the object against the
background behind it) moves with the object, yet its rounded pixel falls on either side
of the mask's edge by chance. A line belongs to one when most of it does: at least 3 of
5 samples evenly spaced from start to end (the endpoints included) fall on the dilated
mask, so a static edge that merely touches an object is not counted as moving.
"""

import cv2
import numpy as np

_LINE_SAMPLES = np.linspace(0.0, 1.0, 5)


def dilated(mask: np.ndarray, margin_px: int) -> np.ndarray:
    """The mask (H, W) bool grown by ``margin_px`` in every direction."""
    size = 2 * margin_px + 1
    return cv2.dilate(mask.astype(np.uint8), np.ones((size, size), np.uint8)) > 0


def mask_at(mask: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Mask value (N,) bool at pixels (N, 2), rounded and clipped into the image."""
    height, width = mask.shape
    u = np.clip(np.rint(uv[:, 0]).astype(np.int64), 0, width - 1)
    v = np.clip(np.rint(uv[:, 1]).astype(np.int64), 0, height - 1)
    return mask[v, u]


def features_on_mask(
    point_uv: np.ndarray, segments: np.ndarray, mask: np.ndarray, margin_px: int
) -> tuple[np.ndarray, np.ndarray]:
    """Whether each point (N, 2) lies, and most of each segment (M, 4) lies, on the
    moving-object mask (H, W), outline included (``margin_px``, ``dynamic.mask_margin_px``): (N,)
    and (M,) bool."""
    grown = dilated(mask, margin_px)
    samples = segments[:, None, :2] + _LINE_SAMPLES[None, :, None] * (segments[:, None, 2:] - segments[:, None, :2])
    on = mask_at(grown, samples.reshape(-1, 2)).reshape(len(segments), len(_LINE_SAMPLES))
    return mask_at(grown, point_uv), on.sum(axis=1) >= 3
