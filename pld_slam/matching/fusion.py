"""Fusion: landmarks projected into keyframes, matched, tested on their reprojection and written to the map.

ORB-SLAM2's ``ORBmatcher::Fuse``. Called by local mapping, which fuses a new keyframe's
landmarks with its neighbours' both ways (`pld_slam.mapping.local_mapping`, step 4), and
by loop closing, which fuses the two ends of a loop (`pld_slam.loop.loop_closing`, step 2).

The landmarks are searched by projection as tracking searches its local map
(`pld_slam.matching.projection`), within the frame-to-frame descriptor bound and ratio
(``tracking.max_point_distance``, ``tracking.ratio``), as ORB-SLAM2 fuses within a
stricter bound than it tracks (50 bits): a fusion merges two landmarks for good. A match
is kept when it passes a chi-square test on the reprojection (the stereo point error, or
the line vertical error in both images, as the solvers measure them).
"""

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from pld_slam.config import Config, PointsConfig, TrackingConfig
from pld_slam.frontend import LeftKeypoints
from pld_slam.geometry.camera import StereoCamera
from pld_slam.mapping.keyframe import KeyFrame
from pld_slam.mapping.landmarks import Landmarks, PointLandmarks
from pld_slam.mapping.map import Map
from pld_slam.matching.frames import FrameMatches
from pld_slam.matching.observations import line_observations, point_observations
from pld_slam.matching.projection import (
    LandmarkSnapshot,
    ProjectionSearch,
    match_map_lines_in_frames,
    match_map_points_in_frames,
)
from pld_slam.optim.observations import LineObservations, PointObservations, WhitenedRows
from pld_slam.optim.point_reprojection import MIN_DEPTH
from pld_slam.optim.robust import CHI2_95_2DOF, CHI2_95_3DOF, CHI2_95_4DOF


@dataclass(frozen=True)
class FusionOptions:
    """What fusion uses of the configuration: the projection search, the point sigmas (``points``) and
    tracking's descriptor bounds, ratio and line sigma (``tracking``)."""

    search: ProjectionSearch
    points: PointsConfig
    tracking: TrackingConfig

    @classmethod
    def of(cls, config: Config) -> "FusionOptions":
        """The fusion ``config`` sets."""
        return cls(ProjectionSearch.of(config), config.points, config.tracking)


def fuse(
    world_map: Map, kind: Landmarks, keyframes: Sequence[KeyFrame], landmark_ids: np.ndarray, camera: StereoCamera,
    options: FusionOptions,
) -> int:
    """Project ``landmark_ids`` (K,) of ``kind`` into each of ``keyframes`` and add or fuse what matches in
    ``world_map``; returns the changes made.

    A matched feature without a landmark observes the projected one; a feature with
    another landmark fuses the two, the one with more observers kept
    (`pld_slam.mapping.map.Map.observe_or_fuse`). Loop closing fuses the two ends of a
    loop the same way. The landmarks are matched into all the keyframes at once
    (`pld_slam.matching.projection.match_map_points_in_frames`), then the matches are
    applied keyframe by keyframe, in order; a landmark a fusion removed on the way keeps
    its matches in the later keyframes, which are then skipped (matched one keyframe at
    a time, it would no longer be searched, and a feature it took could go to another
    landmark). All at once costs less than one keyframe at a time, for the same trajectory
    (see docs/decisions/0023-matching-search-cost.md).
    """
    landmark_ids = landmark_ids[kind.alive[landmark_ids]]
    if len(landmark_ids) == 0 or len(keyframes) == 0:
        return 0
    snapshot = LandmarkSnapshot.of(kind, landmark_ids)
    poses = np.stack([keyframe.T_c_w for keyframe in keyframes])
    features = [getattr(keyframe.features, kind.FEATURES_FIELD) for keyframe in keyframes]
    if isinstance(kind, PointLandmarks):
        found = match_map_points_in_frames(camera, poses, snapshot, features, options.search,
                                           options.tracking.max_point_distance, options.tracking.ratio)
    else:
        found = match_map_lines_in_frames(camera, poses, snapshot, features, options.search)
    matches = [each.matches for each in found]
    changes = 0
    fits_of = _reprojects(kind, keyframes, poses, snapshot, matches, camera, options)
    for keyframe, matched, fits in zip(keyframes, matches, fits_of):
        changes += world_map.observe_or_fuse(kind, keyframe, matched.current[fits],
                                             snapshot.ids[matched.previous[fits]], keep_matched=False)
    return changes


def _reprojects(
    kind: Landmarks, keyframes: Sequence[KeyFrame], poses: np.ndarray, snapshot: LandmarkSnapshot,
    matches: list[FrameMatches], camera: StereoCamera, options: FusionOptions,
) -> list[np.ndarray]:
    """Per keyframe, whether each landmark of ``matches`` (snapshot rows to the keyframe's features)
    reprojects onto its feature within the chi-square bound ((K,) bool per keyframe); ``poses``
    (F, 4, 4) are the keyframes' ``T_c_w``.

    Points are tested in all the keyframes at once, each observation at its keyframe's pose."""
    counts = [len(matched) for matched in matches]
    if isinstance(kind, PointLandmarks):
        keypoints = [keyframe.features.keypoints for keyframe in keyframes]
        sizes = np.array([len(frame) for frame in keypoints])
        first_feature = np.cumsum(sizes) - sizes
        features = np.concatenate([matched.current + first for matched, first in zip(matches, first_feature)])
        geometry = snapshot.geometry[np.concatenate([matched.previous for matched in matches])]
        observed = point_observations(geometry, LeftKeypoints.concatenate(keypoints), features, options.points)
        rows = WhitenedRows.of(observed, LineObservations.empty(), LineObservations.empty())
        pose_of_row = np.repeat(np.arange(len(keyframes)), counts)
        evaluation = rows.evaluate(camera, poses, poses, MIN_DEPTH, pose_of_row, np.zeros(0, dtype=np.int64))
        point_chi2, _, _ = rows.chi2(evaluation)
        fits = rows.point_inliers(point_chi2, CHI2_95_3DOF, CHI2_95_2DOF)
        return np.split(fits, np.cumsum(counts)[:-1])
    return [line_reprojects(keyframe, snapshot.geometry[matched.previous], matched.current, camera, options.tracking)
            for keyframe, matched in zip(keyframes, matches)]


def line_reprojects(
    keyframe: KeyFrame, geometry: np.ndarray, features: np.ndarray, camera: StereoCamera, config: TrackingConfig
) -> np.ndarray:
    """Whether each line (K, 2, 3) reprojects onto its matched line (K,) of ``keyframe`` within the
    chi-square bound of its vertical error (left and right image, as the solvers measure it)."""
    observed = line_observations(camera, geometry, keyframe.features.lines, features, config)
    rows = WhitenedRows.of(PointObservations.empty(), observed, LineObservations.empty())
    evaluation = rows.evaluate(camera, keyframe.T_c_w, keyframe.T_c_w, MIN_DEPTH)
    _, vertical_chi2, _ = rows.chi2(evaluation)
    return rows.line_inliers(vertical_chi2, CHI2_95_4DOF, CHI2_95_2DOF)
