"""`KeyFrame`: a frame kept in the map, with its stereo features and the landmark of each."""

from dataclasses import dataclass

import numpy as np

from pld_slam.frontend import StereoFeatures
from pld_slam.geometry.se3 import inverse


@dataclass(eq=False)
class KeyFrame:
    """A keyframe of the map. Its pose is the one mutable geometry: BA and loop closure move it.

    Attributes
    ----------
    id : keyframe id, increasing in insertion order (0 is the first keyframe).
    frame_index : index of the frame in the sequence.
    timestamp : frame time [s].
    T_c_w : (4, 4) world-to-left-camera pose.
    features : its stereo points and lines (left image, left camera frame).
    ggs : (2, C, B) uint8 GGS descriptor of its left image (`pld_slam.frontend.ggs`): the keyframe rule's.
    place_ggs : (2, C', B) uint8, the one place recognition compares (`pld_slam.frontend.StereoFeatures`).
    point_ids : (P,) int64 map point of each left keypoint (``features.keypoints``, the
        stereo points first), ``-1`` for none.
    line_ids : (L,) int64 map line of each stereo line, ``-1`` for none.
    point_dynamic, line_dynamic : (P,), (L,) bool, keypoints and lines labelled dynamic in
        this frame: they never become landmarks.
    point_rejected, line_rejected : (P,), (L,) bool, keypoints and lines matched to the
        reference frame whose match the frame's pose rejected: they do not become landmarks
        either (`pld_slam.mapping.local_mapping`, step 3).
    """

    id: int
    frame_index: int
    timestamp: float
    T_c_w: np.ndarray
    features: StereoFeatures
    ggs: np.ndarray
    place_ggs: np.ndarray
    point_ids: np.ndarray
    line_ids: np.ndarray
    point_dynamic: np.ndarray
    line_dynamic: np.ndarray
    point_rejected: np.ndarray
    line_rejected: np.ndarray

    @property
    def T_w_c(self) -> np.ndarray:
        """(4, 4) left-camera-to-world pose."""
        return inverse(self.T_c_w)

    @property
    def centre(self) -> np.ndarray:
        """(3,) camera centre in the world frame [m]."""
        return self.T_w_c[:3, 3]
