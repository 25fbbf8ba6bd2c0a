"""Stereo rectification of a calibrated pinhole rig with radial-tangential distortion.

Used by the layouts whose images are raw (EuRoC, unrectified generic rigs): OpenCV's
``stereoRectify`` turns the two calibrations into a rectified pair, and the pixel maps of
``initUndistortRectifyMap`` are applied to every frame as it is read.

``alpha`` is open (0 keeps only valid pixels, 1 keeps every raw pixel); we use
``alpha = 0`` so that rectified images have no black border, whose straight edges would
otherwise feed spurious corners and line segments to the frontend, at the price of a
slightly narrower field of view. The rectified images keep the raw image size.
"""

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from pld_slam.datasets.calibration import stereo_camera_from_projections
from pld_slam.errors import DatasetError
from pld_slam.geometry.camera import StereoCamera
from pld_slam.geometry.se3 import make_pose

RECTIFY_ALPHA = 0.0
"""Free scaling of ``cv2.stereoRectify``: 0 = only valid pixels (see module docstring)."""


@dataclass(frozen=True)
class PixelMap:
    """An ``initUndistortRectifyMap`` pair for one camera (fixed-point, ``CV_16SC2``)."""

    coordinates: np.ndarray
    interpolation: np.ndarray

    def apply(self, raw: np.ndarray) -> np.ndarray:
        """The rectified (H, W) image of a raw (H, W) uint8 image (bilinear)."""
        return cv2.remap(raw, self.coordinates, self.interpolation, cv2.INTER_LINEAR)


@dataclass(frozen=True)
class StereoRectification:
    """A rectified stereo camera and the maps that produce its images; a `Rectifier`.

    Attributes
    ----------
    camera : StereoCamera
        The rectified pair (intrinsics of ``P1``, baseline ``-P2[0, 3] / P2[0, 0]``).
    R_rect_raw : np.ndarray
        (3, 3) ``R1`` of ``stereoRectify``: maps a point of the raw left camera frame into
        the rectified left camera frame (same centre, rotated).
    left_map, right_map : PixelMap
        Raw -> rectified pixel maps of each camera.
    """

    camera: StereoCamera
    R_rect_raw: np.ndarray
    left_map: PixelMap
    right_map: PixelMap

    @property
    def T_raw_rect(self) -> np.ndarray:
        """(4, 4) pose of the rectified left camera in the raw left camera: ``[R1^T | 0]``."""
        return make_pose(self.R_rect_raw.T, np.zeros(3))

    def __call__(self, left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Rectify a raw (H, W) uint8 pair of the calibrated size (`StereoSequence` checks it)."""
        return self.left_map.apply(left), self.right_map.apply(right)


def _pixel_map(
    K: np.ndarray,
    distortion: np.ndarray,
    R_rect_raw: np.ndarray,
    P: np.ndarray,
    size: tuple[int, int],
) -> PixelMap:
    """The raw -> rectified `PixelMap` of one camera (``size`` = (width, height))."""
    coordinates, interpolation = cv2.initUndistortRectifyMap(
        K, distortion, R_rect_raw, P, size, cv2.CV_16SC2
    )
    return PixelMap(coordinates, interpolation)


def rectify_stereo(
    K_left: np.ndarray,
    distortion_left: np.ndarray,
    K_right: np.ndarray,
    distortion_right: np.ndarray,
    T_right_left: np.ndarray,
    image_size: tuple[int, int],
    source: Path | str,
) -> StereoRectification:
    """Rectify a calibrated stereo rig.

    Parameters
    ----------
    K_left, K_right : np.ndarray
        (3, 3) raw intrinsics [px].
    distortion_left, distortion_right : np.ndarray
        (4,) or (5,) radial-tangential coefficients ``k1 k2 p1 p2 (k3)``.
    T_right_left : np.ndarray
        (4, 4) maps a point of the left camera frame into the right one:
        ``p_right = R p_left + t`` [m].
    image_size : tuple of int
        ``(width, height)`` of the raw images, also the rectified size.
    source : Path or str
        The calibration file (or files), named in errors; a rig OpenCV cannot rectify (the
        two cameras at one place) raises `DatasetError` naming it.
    """
    try:
        R1, R2, P1, P2, *_ = cv2.stereoRectify(
            K_left,
            distortion_left,
            K_right,
            distortion_right,
            image_size,
            T_right_left[:3, :3],
            T_right_left[:3, 3].reshape(3, 1),
            flags=cv2.CALIB_ZERO_DISPARITY,
            alpha=RECTIFY_ALPHA,
        )
    except cv2.error as error:
        raise DatasetError(f"{source}: OpenCV cannot rectify this rig ({error.err})") from None
    return rectification_of(
        RectifiedView(K_left, distortion_left, R1, P1), RectifiedView(K_right, distortion_right, R2, P2),
        image_size, source,
    )


@dataclass(frozen=True)
class RectifiedView:
    """How one raw camera maps to its rectified view: what ``stereoRectify`` (or ROS ``CameraInfo``) gives.

    Attributes
    ----------
    K : np.ndarray
        (3, 3) raw intrinsics [px].
    distortion : np.ndarray
        (4,), (5,) or (8,) OpenCV distortion coefficients ``k1 k2 p1 p2 (k3 (k4 k5 k6))``.
    R : np.ndarray
        (3, 3) rotates a point of the raw camera frame into the rectified one.
    P : np.ndarray
        (3, 4) projection of the rectified view (the right one's ``P[0, 3] = -fx * baseline``).
    """

    K: np.ndarray
    distortion: np.ndarray
    R: np.ndarray
    P: np.ndarray


def rectification_of(
    left: RectifiedView, right: RectifiedView, image_size: tuple[int, int], source: Path | str
) -> StereoRectification:
    """The `StereoRectification` of two cameras whose rectified views are given.

    ``image_size`` is ``(width, height)`` of the raw images, also the rectified size;
    ``source`` (the calibration) is named in errors.
    """
    return StereoRectification(
        camera=stereo_camera_from_projections(left.P, right.P, *image_size, source=source),
        R_rect_raw=left.R,
        left_map=_pixel_map(left.K, left.distortion, left.R, left.P, image_size),
        right_map=_pixel_map(right.K, right.distortion, right.R, right.P, image_size),
    )
