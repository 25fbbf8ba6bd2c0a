"""`ReferenceFrame`: the frame a few frames back that each new frame is matched against.

The paper tracks the previous frame and then the local map. We track a reference frame a
few frames back, renewed (the current frame becomes the reference) after
``tracking.reference_max_age`` frames, when the inliers fall below
``tracking.reference_min_inlier_ratio`` of those of the reference's first tracked frame
(`ReferenceFrame.is_worn`), and with a map at every keyframe, whose BA-corrected pose it
takes. Adjacent frames are too close for a moving object to stand out: on KITTI raw 0005 a
near van moves ~0.08 m per frame against the scene, which a frame-to-frame solve absorbed
as ego-motion (ATE 0.37 m); over several frames its disagreement grows past the inlier
thresholds, and the dynamic detectors see it.

A reference keeps the features found dynamic while it is the reference (the ones it was
made with, and those later frames label: `dynamic` module docstring), and the map landmarks
its features observe, which frames matched to it inherit (`ReferenceFrame.map_matches`).
"""

from dataclasses import dataclass

import numpy as np

from pld_slam.config import Config
from pld_slam.frontend import StereoFeatures
from pld_slam.geometry.se3 import transform_points
from pld_slam.localisation.local_map import ReferenceMatches
from pld_slam.mapping.landmarks import Landmarks
from pld_slam.mapping.map import Map
from pld_slam.matching.frames import FrameMatches
from pld_slam.optim.pose_only import PoseOnlyResult
from pld_slam.tracking.dynamic import DynamicLabels


@dataclass(frozen=True)
class FeatureMatches:
    """Matches of the reference frame's stereo points and lines (previous side) to a frame's (current side)."""

    points: FrameMatches
    lines: FrameMatches


@dataclass(frozen=True)
class LandmarkIds:
    """The map landmark of each of a frame's stereo points (P,) and lines (L,), ``-1`` for none."""

    points: np.ndarray
    lines: np.ndarray

    @classmethod
    def none(cls, features: StereoFeatures) -> "LandmarkIds":
        """No landmark for any stereo point or line of ``features``."""
        return cls(np.full(len(features.points), -1), np.full(len(features.lines), -1))

    @classmethod
    def of(cls, features: StereoFeatures, point_ids: np.ndarray, line_ids: np.ndarray) -> "LandmarkIds":
        """From ids over all left keypoints (P_all,), stereo points first, and over the lines (L,)."""
        return cls(point_ids[: len(features.points)].copy(), line_ids.copy())


@dataclass(frozen=True)
class DynamicIndices:
    """Indices of a frame's keypoints (P_all,; stereo points first) and lines (L,) found dynamic."""

    points: np.ndarray
    lines: np.ndarray


def can_be_reference(features: StereoFeatures, config: Config) -> bool:
    """Whether a frame has the stereo points + lines for ``tracking.min_inliers`` twice over."""
    return len(features.points) + len(features.lines) >= 2 * config.tracking.min_inliers


class ReferenceFrame:
    """A frame's stereo features at its pose, as the reference of the next frames.

    Parameters
    ----------
    features : the frame's stereo features.
    T_w_r : (4, 4) camera-to-world pose of the frame (kept as given, not copied).
    dynamic : the frame's features found dynamic: they stay known as dynamic while it is the
        reference (only stereo points among the keypoints can be: the first ones).
    landmarks : the map landmarks its features observe (none by default).

    Attributes
    ----------
    age : frames tracked against it so far.
    first_inliers : point + line inliers of the first frame tracked against it.
    seen_dynamic_points, seen_dynamic_lines : (P,), (L,) bool, its stereo points and lines
        known to be dynamic.
    """

    def __init__(
        self,
        features: StereoFeatures,
        T_w_r: np.ndarray,
        dynamic: DynamicIndices,
        landmarks: LandmarkIds | None = None,
    ) -> None:
        self.features, self.T_w_r = features, T_w_r
        self.landmarks = LandmarkIds.none(features) if landmarks is None else landmarks
        self.age, self.first_inliers = 0, 0
        self.seen_dynamic_points = np.zeros(len(features.points), dtype=bool)
        self.seen_dynamic_lines = np.zeros(len(features.lines), dtype=bool)
        stereo = dynamic.points[dynamic.points < len(features.points)]  # the stereo points: the first keypoints
        self.seen_dynamic_points[stereo] = True
        self.seen_dynamic_lines[dynamic.lines] = True

    def record(self, matches: FeatureMatches, labels: DynamicLabels, inliers: int) -> None:
        """Count one more frame tracked against it, with ``inliers`` point + line inliers, and remember
        the reference features whose ``matches`` ``labels`` found dynamic."""
        self.seen_dynamic_points[matches.points.previous[labels.point_dynamic]] = True
        self.seen_dynamic_lines[matches.lines.previous[labels.line_dynamic]] = True
        self.age += 1
        if self.age == 1:
            self.first_inliers = inliers

    def is_worn(self, inliers: int, config: Config) -> bool:
        """Whether it is ``tracking.reference_max_age`` frames old, or the last frame's ``inliers`` fell
        below ``tracking.reference_min_inlier_ratio`` of its first frame's."""
        cfg = config.tracking
        return self.age >= cfg.reference_max_age or inliers < cfg.reference_min_inlier_ratio * self.first_inliers

    def map_matches(
        self, matches: FeatureMatches, solution: PoseOnlyResult, labels: DynamicLabels, world_map: Map
    ) -> ReferenceMatches:
        """The inlier, static ``matches`` of the reference solve, the reference side in the world frame.

        A reference feature that observes a live landmark of ``world_map`` passes it on
        (`ReferenceMatches`): its world side is the landmark's position.
        """
        if not solution.success:
            return ReferenceMatches.empty()
        reference = self.features
        points = solution.inliers.points & ~labels.point_dynamic
        lines = solution.inliers.lines & ~labels.line_dynamic
        previous_points, previous_lines = matches.points.previous[points], matches.lines.previous[lines]
        segments = reference.lines.endpoints_c[previous_lines].reshape(-1, 3)
        points_w = transform_points(self.T_w_r, reference.points.points_c[previous_points])
        lines_w = transform_points(self.T_w_r, segments).reshape(-1, 2, 3)
        point_landmarks = _live_landmarks(world_map.points, self.landmarks.points, previous_points, points_w)
        line_landmarks = _live_landmarks(world_map.lines, self.landmarks.lines, previous_lines, lines_w)
        return ReferenceMatches(
            points_w=points_w,
            point_index=matches.points.current[points],
            lines_w=lines_w,
            line_index=matches.lines.current[lines],
            point_landmarks=point_landmarks,
            line_landmarks=line_landmarks,
        )


def _live_landmarks(
    kind: Landmarks, reference_ids: np.ndarray, previous: np.ndarray, geometry_w: np.ndarray
) -> np.ndarray:
    """The live landmark (K,) of reference features ``previous`` (K,), -1 for none; where there is one,
    its row of ``geometry_w`` (K, ...) becomes the landmark's position (in place)."""
    ids = reference_ids[previous]
    live = kind.live(ids)
    geometry_w[live] = kind.geometry[ids[live]]
    return np.where(live, ids, -1)
