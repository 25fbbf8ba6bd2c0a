"""Search of map landmarks by projection, into one frame or into several side by side.

A snapshot of some landmarks (`LandmarkSnapshot`: copies of their map columns) is
projected into frames at given poses and matched to their features. Called by tracking
for its local map (`pld_slam.localisation.local_map`, which loop verification's geometric
check also runs, `pld_slam.loop.verify`) and by fusion, which projects a keyframe's
landmarks into all its neighbours at once (`pld_slam.matching.fusion`).

Visibility. A landmark is searched for when it lies in front of the camera, projects
inside the image, is seen within ``mapping.max_viewing_angle`` of its mean viewing
direction and, for points, from a distance within its scale-invariance range
(``mapping.search_nearest_scale`` (0.8) times its nearest to ``mapping.search_farthest_scale``
(1.2) times its farthest distance, as ORB-SLAM2). Such landmarks count as
*visible* in this frame (the culling test of local mapping compares how often a landmark
is found with how often it is visible).

Points. The window around the projection is ``mapping.point_search_radius_px`` times
``scale_factor**octave`` at the octave predicted from the distance
(`pld_slam.mapping.landmarks.predicted_octaves`); candidates are current points found at
that octave or the one below or above among all left keypoints (`LeftKeypoints`: a map
point is found again where its corner is detected, stereo-matched or not); for a stereo
keypoint, its right-image column must also lie within the window of the predicted one.
Keypoints without a stereo match are monocular observations (`pld_slam.optim.observations`).
The smallest Hamming distance under the caller's bound wins if it passes the caller's
ratio test (tracking's bounds: `pld_slam.localisation.local_map`; fusion's:
`pld_slam.matching.fusion`).

Lines: as frame-to-frame line matching (`pld_slam.matching.frames.match_predicted_segments`),
in a window of ``mapping.line_search_radius_px`` around the predicted midpoint, within
tracking's line bounds.

What a search uses of the configuration is a `ProjectionSearch`; the point descriptor
bound and ratio are the caller's.
"""

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from pld_slam.config import Config
from pld_slam.frontend import LeftKeypoints, StereoLines
from pld_slam.geometry.camera import StereoCamera
from pld_slam.geometry.se3 import inverse, transform_points
from pld_slam.geometry.segments import segment_midpoints
from pld_slam.mapping.landmarks import Landmarks, PointLandmarks, predicted_octaves
from pld_slam.matching.frames import (
    MIN_SEARCH_DEPTH,
    FrameMatches,
    match_predicted_segments,
    predict_segments,
    select_matches,
)
from pld_slam.matching.windows import pairs_within


@dataclass(frozen=True)
class ProjectionSearch:
    """What a search by projection uses of the configuration (module docstring).

    Attributes
    ----------
    scale_factor, n_levels : the ORB pyramid (``points``): octaves predicted from distance.
    max_viewing_angle : [deg] largest angle from a landmark's mean viewing direction (``mapping``).
    nearest_scale, farthest_scale : a point is searched between this times its nearest and this times
        its farthest distance (``mapping.search_nearest_scale``, ``mapping.search_farthest_scale``).
    point_radius_px : window radius at octave 0 [px] (``mapping.point_search_radius_px``).
    line_radius_px : window radius around a line's predicted midpoint [px] (``mapping.line_search_radius_px``).
    line_max_angle_change : [deg], line_max_distance [bits], line_ratio : the line matching bounds
        (``tracking.line_max_angle_change``, ``tracking.max_line_distance``, ``tracking.ratio``).
    """

    scale_factor: float
    n_levels: int
    max_viewing_angle: float
    nearest_scale: float
    farthest_scale: float
    point_radius_px: float
    line_radius_px: float
    line_max_angle_change: float
    line_max_distance: int
    line_ratio: float

    @classmethod
    def of(cls, config: Config) -> "ProjectionSearch":
        """The search ``config`` sets (attributes name their keys)."""
        return cls(
            scale_factor=config.points.scale_factor,
            n_levels=config.points.n_levels,
            max_viewing_angle=config.mapping.max_viewing_angle,
            nearest_scale=config.mapping.search_nearest_scale,
            farthest_scale=config.mapping.search_farthest_scale,
            point_radius_px=config.mapping.point_search_radius_px,
            line_radius_px=config.mapping.line_search_radius_px,
            line_max_angle_change=config.tracking.line_max_angle_change,
            line_max_distance=config.tracking.max_line_distance,
            line_ratio=config.tracking.ratio,
        )


@dataclass(frozen=True)
class LandmarkSnapshot:
    """The landmarks of one kind in the local map: copies of their map columns.

    Attributes
    ----------
    ids : (N,) int64 landmark ids, ascending.
    geometry : (N, 3) points or (N, 2, 3) line endpoints, world [m].
    descriptors : (N, 32) uint8.
    normals : (N, 3) mean viewing directions (world).
    max_distance : (N,) farthest distance at which a point is seen at octave 0 [m] (inf for lines).
    """

    ids: np.ndarray
    geometry: np.ndarray
    descriptors: np.ndarray
    normals: np.ndarray
    max_distance: np.ndarray

    @classmethod
    def of(cls, kind: Landmarks, ids: np.ndarray) -> "LandmarkSnapshot":
        """The landmarks ``ids`` (N,) of ``kind`` as they are now (lines: no scale range, ``max_distance`` inf)."""
        max_distance = kind.max_distance[ids] if isinstance(kind, PointLandmarks) else np.full(len(ids), np.inf)
        return cls(ids, kind.geometry[ids], kind.descriptor[ids], kind.normal[ids], max_distance)

    def __len__(self) -> int:
        return len(self.ids)


@dataclass(frozen=True)
class MapMatches:
    """Matches of snapshot landmarks (``matches.previous``: snapshot rows) to current features,
    and which landmarks were visible (N,) bool."""

    matches: FrameMatches
    visible: np.ndarray


def match_map_points(
    camera: StereoCamera, T_c_w: np.ndarray, points: LandmarkSnapshot, current: LeftKeypoints,
    search: ProjectionSearch, max_distance: int, ratio: float,
) -> MapMatches:
    """Match the snapshot's points to the current left keypoints around their projections, within
    ``max_distance`` bits of Hamming distance and passing the ``ratio`` test (module docstring)."""
    return match_map_points_in_frames(camera, T_c_w[None], points, (current,), search, max_distance, ratio)[0]


def match_map_points_in_frames(
    camera: StereoCamera, T_c_w: np.ndarray, points: LandmarkSnapshot, frames: Sequence[LeftKeypoints],
    search: ProjectionSearch, max_distance: int, ratio: float,
) -> list[MapMatches]:
    """`match_map_points` into F >= 1 frames at once: poses ``T_c_w`` (F, 4, 4) and left keypoints
    ``frames`` (F); a `MapMatches` per frame, each what a search of that frame alone finds.

    The frames are searched side by side, as one image (`_frame_strides`): local mapping
    projects a keyframe's landmarks into its ~11 neighbours, and one set of array
    operations for all of them costs far less than one per neighbour.
    """
    n_points, n_frames, sizes = len(points), len(frames), _sizes(frames)
    scale, levels = search.scale_factor, search.n_levels
    p_c = np.stack([transform_points(T, points.geometry) for T in T_c_w]).reshape(-1, 3)  # frame by frame
    in_front = p_c[:, 2] > MIN_SEARCH_DEPTH
    stereo_px = camera.project_stereo(np.where(in_front[:, None], p_c, [0.0, 0.0, 1.0]))
    distance = np.linalg.norm(p_c, axis=1)
    max_distances = np.tile(points.max_distance, n_frames)
    nearest = max_distances / scale ** (levels - 1)
    visible = (
        in_front
        & camera.inside_image(stereo_px[:, :2])
        & (distance >= search.nearest_scale * nearest)
        & (distance <= search.farthest_scale * max_distances)
        & _within_viewing_angle(T_c_w, points.geometry, points.normals, search.max_viewing_angle).ravel()
    )
    octave = predicted_octaves(max_distances, distance, scale, levels)
    radius = search.point_radius_px * scale ** octave.astype(np.float64)
    keypoints = LeftKeypoints.concatenate(frames)
    query_shift, feature_shift = _frame_strides(camera, n_points, sizes, radius)
    query, train = pairs_within(stereo_px[:, :2] + query_shift, visible, keypoints.uv + feature_shift, radius)
    near_octave = np.abs(keypoints.octave[train] - octave[query]) <= 1
    right_error = np.abs(keypoints.u_right[train] - stereo_px[query, 2])
    same_right_column = np.isnan(right_error) | (right_error <= radius[query])
    keep = near_octave & same_right_column
    matches = select_matches(
        query[keep], train[keep], np.tile(points.descriptors, (n_frames, 1)), keypoints.descriptors, keypoints.uv,
        max_distance, ratio,
    )
    return _per_frame(matches, visible, n_points, sizes)


def match_map_lines(
    camera: StereoCamera, T_c_w: np.ndarray, lines: LandmarkSnapshot, current: StereoLines, search: ProjectionSearch
) -> MapMatches:
    """Match the snapshot's lines to the current stereo lines around their projections (module docstring)."""
    return match_map_lines_in_frames(camera, T_c_w[None], lines, (current,), search)[0]


def match_map_lines_in_frames(
    camera: StereoCamera, T_c_w: np.ndarray, lines: LandmarkSnapshot, frames: Sequence[StereoLines],
    search: ProjectionSearch,
) -> list[MapMatches]:
    """`match_map_lines` into F frames at once, as `match_map_points_in_frames` does for points."""
    n_lines, n_frames, sizes = len(lines), len(frames), _sizes(frames)
    predicted, in_front = (np.concatenate(arrays) for arrays in
                           zip(*(predict_segments(camera, T, lines.geometry) for T in T_c_w)))
    midpoints = lines.geometry.mean(axis=1)
    visible = (
        in_front
        & camera.inside_image(segment_midpoints(predicted))
        & _within_viewing_angle(T_c_w, midpoints, lines.normals, search.max_viewing_angle).ravel()
    )
    radius = search.line_radius_px
    query_shift, feature_shift = _frame_strides(camera, n_lines, sizes, radius)
    detected = np.concatenate([frame.endpoints for frame in frames]) + np.tile(feature_shift, 2)
    matches = match_predicted_segments(
        predicted + np.tile(query_shift, 2), visible, np.tile(lines.descriptors, (n_frames, 1)), detected,
        np.concatenate([frame.descriptors for frame in frames]), radius,
        search.line_max_angle_change, search.line_max_distance, search.line_ratio,
    )
    return _per_frame(matches, visible, n_lines, sizes)


def _sizes(frames: Sequence[LeftKeypoints] | Sequence[StereoLines]) -> np.ndarray:
    """Features (F,) of each frame."""
    return np.array([len(frame) for frame in frames], dtype=np.int64)


def _frame_strides(
    camera: StereoCamera, n_queries: int, sizes: np.ndarray, radius: np.ndarray | float
) -> tuple[np.ndarray, np.ndarray]:
    """Shifts (F N, 2) of N queries per frame and (K, 2) of the features (K = ``sizes.sum()``, ``sizes``
    (F,) per frame) that put F frames side by side, as one image: frame f's columns move by f
    times the image width plus the widest window (``radius``, scalar or per query), so that
    no query's window reaches another frame's features."""
    stride = camera.width + 2.0 * float(np.max(radius, initial=0.0)) + 1.0
    query_frame = np.repeat(np.arange(len(sizes)), n_queries)
    feature_frame = np.repeat(np.arange(len(sizes)), sizes)
    return (np.column_stack([stride * query_frame, np.zeros(len(query_frame))]),
            np.column_stack([stride * feature_frame, np.zeros(len(feature_frame))]))


def _per_frame(matches: FrameMatches, visible: np.ndarray, n_queries: int, sizes: np.ndarray) -> list[MapMatches]:
    """Matches of queries (F N) to features (``sizes.sum()``) side by side, split into a `MapMatches` per
    frame; in a frame without features no landmark counts as visible (nothing could be found)."""
    frame = matches.previous // max(n_queries, 1)
    first_feature = np.cumsum(sizes) - sizes
    return [
        MapMatches(
            FrameMatches(matches.previous[frame == f] - f * n_queries, matches.current[frame == f] - first_feature[f]),
            visible[f * n_queries : (f + 1) * n_queries] & (sizes[f] > 0),
        )
        for f in range(len(sizes))
    ]


def _within_viewing_angle(
    T_c_w: np.ndarray, centres_w: np.ndarray, normals: np.ndarray, max_angle: float
) -> np.ndarray:
    """Whether cameras ``T_c_w`` (F, 4, 4) see landmarks at ``centres_w`` (N, 3) within ``max_angle`` of
    their ``normals`` (N, 3): (F, N) bool."""
    rays = centres_w[None] - inverse(T_c_w)[:, None, :3, 3]
    cosine = np.einsum("fij,ij->fi", rays, normals) / np.maximum(np.linalg.norm(rays, axis=2), 1e-12)
    return cosine >= np.cos(max_angle)
