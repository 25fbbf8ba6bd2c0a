"""Frame-to-frame matching of stereo points and lines, guided by a motion-model prediction.

Each previous feature has a 3D position in the previous camera frame (from its stereo
match). The predicted motion ``T_c_p`` (previous camera to current camera) projects it
into the current image; the current features inside a window around the prediction are
its candidates, and the candidate with the smallest Hamming distance wins if it is close
enough and passes the ratio test against the other candidates (`best_matches`). Each
current feature is used at most once (`unique_train`). Lines also need a direction close
to the predicted one.

The window is fixed in pixels (scaled by the ORB octave for points): the paper does not
size it; 15 px holds KITTI's constant-velocity prediction errors at 10 Hz, and the
tracker retries with a wider window when too few matches come back.

Called by tracking for the reference frame (`pld_slam.tracking.tracker`). `FrameMatches`,
`select_matches` and `match_predicted_segments` serve every matcher of the package (the
projection search of map landmarks, `pld_slam.matching.projection`, matches its lines as
predicted segments).
"""

from dataclasses import dataclass

import numpy as np

from pld_slam.frontend.descriptors import best_matches, hamming_distances, unique_train
from pld_slam.frontend.lines import StereoLines
from pld_slam.frontend.points import StereoPoints
from pld_slam.geometry.camera import StereoCamera
from pld_slam.geometry.se3 import transform_points
from pld_slam.geometry.segments import oriented_angle_differences, segment_directions, segment_midpoints
from pld_slam.matching.windows import pairs_within

MIN_SEARCH_DEPTH = 0.1
"""A predicted feature or landmark nearer than this to the camera plane [m] is not searched for
(nor judged missed)."""


@dataclass(frozen=True)
class FrameMatches:
    """Index pairs of matched features: ``previous[k]`` matches ``current[k]``; (K,) int64 each."""

    previous: np.ndarray
    current: np.ndarray

    def __len__(self) -> int:
        return self.previous.size

    @classmethod
    def empty(cls) -> "FrameMatches":
        """No matches."""
        return cls(np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64))

    def subset(self, keep: np.ndarray) -> "FrameMatches":
        """The matches where ``keep`` (K,) bool is True."""
        return FrameMatches(self.previous[keep], self.current[keep])


def predict_segments(
    camera: StereoCamera, T_c_p: np.ndarray, endpoints_p: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Current-image segments (M, 4) of 3D segments (M, 2, 3) of the previous camera, and
    which have both endpoints in front (M,)."""
    starts, start_in_front = predict_pixels(camera, T_c_p, endpoints_p[:, 0])
    ends, end_in_front = predict_pixels(camera, T_c_p, endpoints_p[:, 1])
    return np.column_stack([starts, ends]), start_in_front & end_in_front


def predict_pixels(camera: StereoCamera, T_c_p: np.ndarray, points_p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Current-image pixels (N, 2) of points (N, 3) of the previous camera, and which are in front (N,)."""
    points_c = transform_points(T_c_p, points_p)
    in_front = points_c[:, 2] > MIN_SEARCH_DEPTH
    depth = np.where(in_front, points_c[:, 2], 1.0)
    pixels = camera.project(np.column_stack([points_c[:, :2], depth]))
    return pixels, in_front


def select_matches(query, train, prev_descriptors, curr_descriptors, train_positions, max_distance, ratio):
    """The unambiguous best candidate of each query, each train feature used once."""
    distance = hamming_distances(prev_descriptors[query], curr_descriptors[train])
    matches = unique_train(best_matches(query, train, distance, train_positions[train], max_distance, ratio))
    return FrameMatches(matches.query, matches.train)


def match_points(
    camera: StereoCamera,
    T_c_p: np.ndarray,
    previous: StereoPoints,
    current: StereoPoints,
    radius_px: float,
    scale_factor: float,
    max_distance: int,
    ratio: float,
) -> FrameMatches:
    """Match previous stereo points to current ones around their predicted pixels.

    Parameters
    ----------
    camera : the rectified stereo camera.
    T_c_p : (4, 4) predicted motion, previous camera to current camera.
    previous, current : stereo points of the two frames (``previous.points_c`` in the
        previous camera frame).
    radius_px : search window at octave 0 [px]; a point found at octave ``o`` in the
        previous image is searched within ``radius_px * scale_factor**o``.
    scale_factor : ORB pyramid scale between octaves (``points.scale_factor``).
    max_distance, ratio : Hamming threshold [bits] and ratio test.
    """
    if len(previous) == 0 or len(current) == 0:
        return FrameMatches.empty()
    predicted, in_front = predict_pixels(camera, T_c_p, previous.points_c)
    radius = radius_px * scale_factor ** previous.octave.astype(np.float64)
    query, train = pairs_within(predicted, in_front, current.uv, radius)
    return select_matches(
        query, train, previous.descriptors, current.descriptors, current.uv, max_distance, ratio
    )


def match_lines(
    camera: StereoCamera,
    T_c_p: np.ndarray,
    previous: StereoLines,
    current: StereoLines,
    radius_px: float,
    max_angle_change: float,
    max_distance: int,
    ratio: float,
) -> FrameMatches:
    """Match previous stereo lines to current ones around their predicted segments.

    The predicted segment joins the two projected 3D endpoints of ``previous.endpoints_c``
    (`match_predicted_segments` says how candidates are chosen).
    """
    if len(previous) == 0 or len(current) == 0:
        return FrameMatches.empty()
    predicted, usable = predict_segments(camera, T_c_p, previous.endpoints_c)
    return match_predicted_segments(
        predicted, usable, previous.descriptors, current.endpoints, current.descriptors, radius_px,
        max_angle_change, max_distance, ratio,
    )


def match_predicted_segments(
    predicted: np.ndarray,
    usable: np.ndarray,
    descriptors: np.ndarray,
    detected: np.ndarray,
    detected_descriptors: np.ndarray,
    radius_px: float,
    max_angle_change: float,
    max_distance: int,
    ratio: float,
) -> FrameMatches:
    """Match segments predicted in the current image (M, 4) to its ``detected`` segments (K, 4).

    A candidate's midpoint lies within ``radius_px`` of the predicted midpoint and its
    oriented direction (LSD orients segments by their gradient, so a match keeps its
    orientation) within ``max_angle_change`` [rad] of the predicted one; ``usable`` (M,)
    bool selects the predictions to search for, ``descriptors`` (M, 32) are theirs and
    ``detected_descriptors`` (K, 32) the detected segments'.
    """
    midpoints = segment_midpoints(detected)
    radius = np.full(len(predicted), radius_px)
    query, train = pairs_within(segment_midpoints(predicted), usable, midpoints, radius)
    turn = oriented_angle_differences(segment_directions(predicted)[query], segment_directions(detected)[train])
    query, train = query[turn <= max_angle_change], train[turn <= max_angle_change]
    return select_matches(query, train, descriptors, detected_descriptors, midpoints, max_distance, ratio)
