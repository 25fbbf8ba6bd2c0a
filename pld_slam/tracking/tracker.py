"""`Tracker`: the tracking thread of PLD-SLAM without the map (a stereo point-line VO).

The tracker owns a reference frame's stereo features and the constant-velocity motion
model. For each new frame it predicts the pose from the last inter-frame motion, matches
the reference features to the current ones around their predictions (`matching`),
removes mismatches with the paper's two filters (`outliers`), leaves out the features that
disagree with the motion model (`dynamic`: dynamic grid and dynamic LLG), and estimates the pose
relative to the reference by pose-only least squares over the point reprojection and line
vertical/horizontal errors (`pld_slam.optim.pose_only`), rejecting outliers over rounds.

Reference frame. The paper tracks the previous frame and then the local map; the map
arrives with the mapping issue. Until then we track against a reference frame a few
frames back, renewed (the current frame becomes the reference) after
``tracking.reference_max_age`` frames or when the inliers fall below
``tracking.reference_min_inlier_ratio`` of those of the reference's first tracked frame.
Adjacent frames are too close for a moving object to stand out: on KITTI raw 0005 a
near van moves ~0.08 m per frame against the scene, which a frame-to-frame solve
absorbed as ego-motion (ATE 0.37 m); over several frames its disagreement grows past the
inlier thresholds, and the drift only accumulates at reference changes.

Tracking failure. The paper does not say what happens when a frame cannot be tracked.
Fewer than ``tracking.min_inliers`` inlier points + lines, or a failed solve, keeps the
motion model's prediction for that frame (flagged `TrackingStatus.LOST`): the trajectory
stays continuous, and the next frame is tracked against this one's features, so tracking
recovers as soon as a frame has enough matches. The first frame has no previous frame; it
defines the world (``T_w_c = I``).
"""

import dataclasses
import enum
import time
from dataclasses import dataclass, field

import numpy as np

from pld_slam.config import Config
from pld_slam.frontend import StereoFeatures
from pld_slam.geometry.camera import StereoCamera
from pld_slam.geometry.se3 import inverse, nearest_pose
from pld_slam.optim.line_reprojection import endpoints_away_from_border
from pld_slam.optim.pose_only import (
    LineObservations,
    ObservationMasks,
    PointObservations,
    PoseOnlyOptions,
    PoseOnlyResult,
    optimize_pose,
    optimize_pose_rejecting_outliers,
)
from pld_slam.tracking.dynamic import DynamicLabels, dynamic_grid, dynamic_llg, predict_stereo_with_depth_sigma
from pld_slam.tracking.matching import FrameMatches, match_lines, match_points, predict_segments
from pld_slam.tracking.moving_masks import features_on_mask
from pld_slam.tracking.outliers import line_llg_filter, point_grid_filter


class TrackingStatus(enum.Enum):
    """How a frame's pose was obtained."""

    FIRST = "first"
    """The first frame: it defines the world."""
    TRACKED = "tracked"
    """Estimated from matched points and lines."""
    LOST = "lost"
    """Too few inliers: the motion model's prediction is kept."""


@dataclass(frozen=True)
class TrackingCounts:
    """What survived each step of tracking one frame (points, lines)."""

    point_matches: int = 0
    line_matches: int = 0
    points_after_filter: int = 0
    lines_after_filter: int = 0
    dynamic_points: int = 0
    dynamic_lines: int = 0
    point_inliers: int = 0
    line_inliers: int = 0


@dataclass(frozen=True)
class TrackedFrame:
    """The tracker's answer for one frame.

    Attributes
    ----------
    T_w_c : (4, 4) camera-to-world pose of the frame.
    T_c_p : (4, 4) motion from the previous camera to this one (identity for the first).
    status : how the pose was obtained.
    counts : matches, filter survivors, dynamic features and inliers.
    stage_ms : wall time of each tracking stage [ms]: ``matching``, ``filters``, ``dynamic``, ``pose``.
    dynamic : the matched features of this frame and their dynamic labels (None when
        nothing was matched: the first frame, a skipped one).
    """

    T_w_c: np.ndarray
    T_c_p: np.ndarray
    status: TrackingStatus
    counts: TrackingCounts = TrackingCounts()
    stage_ms: dict[str, float] = field(default_factory=dict)
    dynamic: DynamicLabels | None = None


@dataclass(frozen=True)
class _FrameMatches:
    points: FrameMatches
    lines: FrameMatches


@dataclass(frozen=True)
class _DynamicIndices:
    """Indices of a frame's points (P,) and lines (L,) found dynamic."""

    points: np.ndarray
    lines: np.ndarray


class Tracker:
    """Stereo point-line tracking against a reference frame, with a constant-velocity motion model."""

    def __init__(self, camera: StereoCamera, config: Config) -> None:
        self._camera = camera
        self._config = config
        self._pose_options = PoseOnlyOptions(
            use_line_vertical=config.lines.vertical_error,
            use_line_horizontal=config.lines.horizontal_error,
        )
        self._reference: StereoFeatures | None = None
        self._T_w_r = np.eye(4)
        self._reference_age = 0
        self._reference_inliers = 0
        self._seen_dynamic_points = np.zeros(0, dtype=bool)
        self._seen_dynamic_lines = np.zeros(0, dtype=bool)
        self._T_w_p = np.eye(4)
        self._velocity = np.eye(4)

    def track(self, features: StereoFeatures, moving_mask: np.ndarray | None = None) -> TrackedFrame:
        """Estimate the pose of the frame whose stereo features are ``features``.

        ``moving_mask`` (H, W) bool, the frame's moving-object pixels, replaces the two
        detectors when given: the features on it are the dynamic ones (`moving_masks`).
        """
        if self._reference is None:
            self._set_reference(features, np.eye(4))
            return TrackedFrame(np.eye(4), np.eye(4), TrackingStatus.FIRST)
        clock = _StageClock()
        T_c_r_predicted = self._velocity @ inverse(self._T_w_p) @ self._T_w_r
        matched = self._match(self._reference, features, T_c_r_predicted)
        clock.lap("matching")
        kept = self._filter(self._reference, features, matched)
        clock.lap("filters")
        points = _point_observations(self._reference, features, kept.points, self._config.points.scale_factor)
        lines = _line_observations(self._camera, self._reference, features, kept.lines, self._config)
        solution = optimize_pose_rejecting_outliers(
            self._camera, T_c_r_predicted, points=points, lines=lines, options=self._pose_options
        )
        clock.lap("pose")
        if moving_mask is None:
            labels = self._label_dynamic(self._reference, features, kept, solution)
        else:
            labels = _labels_from_mask(features, kept, moving_mask)
        solution = self._without_dynamic(solution, points, lines, labels)
        clock.lap("dynamic")
        counts = _counts(matched, kept, labels, solution)
        tracked = solution.success and counts.point_inliers + counts.line_inliers >= self._config.tracking.min_inliers
        T_w_c, T_c_p = self._advance(solution, tracked)
        self._update_reference(features, T_w_c, tracked, counts, kept, labels)
        status = TrackingStatus.TRACKED if tracked else TrackingStatus.LOST
        return TrackedFrame(T_w_c.copy(), T_c_p, status, counts, clock.laps, labels)

    def _advance(self, solution: PoseOnlyResult, tracked: bool) -> tuple[np.ndarray, np.ndarray]:
        """The frame's ``T_w_c`` (solved, or the motion model's when not tracked) and ``T_c_p``.

        Both become the tracker's state: the last pose and the motion model.
        """
        T_w_c = nearest_pose(
            self._T_w_r @ inverse(solution.T_c_w) if tracked else self._T_w_p @ inverse(self._velocity)
        )
        T_c_p = nearest_pose(inverse(T_w_c) @ self._T_w_p)
        self._velocity, self._T_w_p = T_c_p, T_w_c
        return T_w_c, T_c_p

    def _update_reference(
        self,
        features: StereoFeatures,
        T_w_c: np.ndarray,
        tracked: bool,
        counts: TrackingCounts,
        kept: _FrameMatches,
        labels: DynamicLabels,
    ) -> None:
        """Record the dynamic features seen, age the reference, and renew it when worn or after a failure."""
        self._seen_dynamic_points[kept.points.previous[labels.point_dynamic]] = True
        self._seen_dynamic_lines[kept.lines.previous[labels.line_dynamic]] = True
        inliers = counts.point_inliers + counts.line_inliers
        self._reference_age += 1
        if self._reference_age == 1:
            self._reference_inliers = inliers
        renew = self._reference_is_worn(inliers) if tracked else self._can_be_reference(features)
        if renew:
            found = _DynamicIndices(kept.points.current[labels.point_dynamic], kept.lines.current[labels.line_dynamic])
            self._set_reference(features, T_w_c, found)

    def skip(self) -> TrackedFrame:
        """Advance over a frame without images (unreadable): the motion model's pose, flagged LOST.

        The reference stays, so the next frame is matched against it as usual.
        """
        self._T_w_p = nearest_pose(self._T_w_p @ inverse(self._velocity))
        return TrackedFrame(self._T_w_p.copy(), self._velocity, TrackingStatus.LOST)

    def _set_reference(
        self, features: StereoFeatures, T_w_c: np.ndarray, dynamic: _DynamicIndices | None = None
    ) -> None:
        """Make the frame with ``features`` at pose ``T_w_c`` the reference of the next frames.

        ``dynamic`` lists the frame's features found dynamic: they stay known as dynamic
        while it is the reference (`dynamic` module docstring).

        After a failure the reference is the failed frame itself (at its motion-model
        pose) if it has features enough to be tracked against (`_can_be_reference`):
        tracking goes on from the newest features, which is how it recovers from a wrong
        prediction. A frame without them (blank, blinded) keeps the old reference.
        """
        self._reference, self._T_w_r = features, T_w_c
        self._reference_age, self._reference_inliers = 0, 0
        self._seen_dynamic_points = np.zeros(len(features.points), dtype=bool)
        self._seen_dynamic_lines = np.zeros(len(features.lines), dtype=bool)
        if dynamic is not None:
            self._seen_dynamic_points[dynamic.points] = True
            self._seen_dynamic_lines[dynamic.lines] = True

    def _can_be_reference(self, features: StereoFeatures) -> bool:
        """Whether a frame has the stereo points + lines for ``min_inliers`` twice over."""
        return len(features.points) + len(features.lines) >= 2 * self._config.tracking.min_inliers

    def _reference_is_worn(self, inliers: int) -> bool:
        """Whether the reference is old, or keeps too few of its first inliers."""
        cfg = self._config.tracking
        return (
            self._reference_age >= cfg.reference_max_age
            or inliers < cfg.reference_min_inlier_ratio * self._reference_inliers
        )

    def _match(self, reference: StereoFeatures, current: StereoFeatures, T_c_r: np.ndarray) -> _FrameMatches:
        """Points and lines matched around the predicted pose ``T_c_r``, widening the window once if needed."""
        cfg = self._config.tracking
        point_radius, line_radius = cfg.point_search_radius_px, cfg.line_search_radius_px
        for attempt in range(2):
            matches = _FrameMatches(
                match_points(
                    self._camera, T_c_r, reference.points, current.points,
                    point_radius, self._config.points.scale_factor, cfg.max_point_distance, cfg.ratio,
                ),
                match_lines(
                    self._camera, T_c_r, reference.lines, current.lines,
                    line_radius, cfg.line_max_angle_change, cfg.max_line_distance, cfg.ratio,
                ),
            )
            if len(matches.points) + len(matches.lines) >= 3 * cfg.min_inliers:
                break
            point_radius *= cfg.wide_search_factor
            line_radius *= cfg.wide_search_factor
        return matches

    def _filter(self, reference: StereoFeatures, current: StereoFeatures, matches: _FrameMatches) -> _FrameMatches:
        """The matches that pass the enabled mismatch filters."""
        filters = self._config.filters
        points, lines = matches.points, matches.lines
        if filters.point_grid:
            keep = point_grid_filter(
                reference.points.uv[points.previous], current.points.uv[points.current], filters
            )
            points = FrameMatches(points.previous[keep], points.current[keep])
        if filters.line_llg:
            keep = line_llg_filter(
                reference.lines.endpoints[lines.previous], current.lines.endpoints[lines.current], filters
            )
            lines = FrameMatches(lines.previous[keep], lines.current[keep])
        return _FrameMatches(points, lines)

    def _label_dynamic(
        self, reference: StereoFeatures, current: StereoFeatures, matches: _FrameMatches, solution: PoseOnlyResult
    ) -> DynamicLabels:
        """Dynamic labels of the matched features, predicted with the robustly fitted pose (`dynamic`).

        Nothing is dynamic when both detectors are off or the fit failed.
        """
        labels = DynamicLabels.none(
            current.points.uv[matches.points.current], current.lines.endpoints[matches.lines.current]
        )
        if not solution.success:
            return labels
        if self._config.dynamic.grid:
            dynamic_points = self._dynamic_points(reference, current, matches.points, solution.T_c_w)
            labels = dataclasses.replace(labels, point_dynamic=dynamic_points)
        if self._config.dynamic.llg:
            dynamic_lines = self._dynamic_lines(reference, current, matches.lines, solution.T_c_w)
            labels = dataclasses.replace(labels, line_dynamic=dynamic_lines)
        return labels

    def _dynamic_points(
        self, reference: StereoFeatures, current: StereoFeatures, matches: FrameMatches, T_c_r: np.ndarray
    ) -> np.ndarray:
        """The dynamic grid over matched points (K,) bool, their stereo observations
        predicted with ``T_c_r`` and judged in sigmas of the detections and the reference depth."""
        config = self._config
        points_r = reference.points.points_c[matches.previous]
        detected = np.column_stack([current.points.uv, current.points.u_right])[matches.current]
        octaves = np.column_stack([reference.points.octave[matches.previous], current.points.octave[matches.current]])
        octave_sigma = config.points.scale_factor ** octaves.astype(np.float64)
        disparity_sigma = config.dynamic.disparity_sigma_px * octave_sigma[:, 0]
        predicted, depth_shift = predict_stereo_with_depth_sigma(self._camera, T_c_r, points_r, disparity_sigma)
        sigma = np.sqrt(np.sum(octave_sigma**2, axis=1) + depth_shift**2)
        cell_size = (config.filters.point_grid_cell_width, config.filters.point_grid_cell_height)
        seen = self._seen_dynamic_points[matches.previous]
        return dynamic_grid(predicted, detected, sigma, cell_size, config.dynamic, seen)

    def _dynamic_lines(
        self, reference: StereoFeatures, current: StereoFeatures, matches: FrameMatches, T_c_r: np.ndarray
    ) -> np.ndarray:
        """The dynamic LLG over matched lines (L,) bool, their segments predicted with ``T_c_r``."""
        predicted, _ = predict_segments(self._camera, T_c_r, reference.lines.endpoints_c[matches.previous])
        seen = self._seen_dynamic_lines[matches.previous]
        return dynamic_llg(predicted, current.lines.endpoints[matches.current], self._config.dynamic, seen)

    def _without_dynamic(
        self, solution: PoseOnlyResult, points: PointObservations, lines: LineObservations, labels: DynamicLabels
    ) -> PoseOnlyResult:
        """``solution`` refined without the dynamic features: one plain least-squares solve
        from it over its inliers less the dynamic ones (the first solve's robust loss and
        rejection rounds have done the rest); ``solution`` itself when nothing is dynamic."""
        if not (labels.point_dynamic.any() or labels.line_dynamic.any()):
            return solution
        include = ObservationMasks(
            points=solution.inliers.points & ~labels.point_dynamic,
            lines=solution.inliers.lines & ~labels.line_dynamic,
            line_horizontal=solution.inliers.line_horizontal & ~labels.line_dynamic,
        )
        refined = optimize_pose(
            self._camera, solution.T_c_w, points=points, lines=lines, options=self._pose_options,
            include=include, robust=False,
        )
        if not refined.success:
            return solution
        inliers = ObservationMasks(
            refined.inliers.points & include.points,
            refined.inliers.lines & include.lines,
            refined.inliers.line_horizontal & include.line_horizontal,
        )
        return dataclasses.replace(refined, inliers=inliers)


def _labels_from_mask(current: StereoFeatures, matches: _FrameMatches, moving_mask: np.ndarray) -> DynamicLabels:
    """Dynamic labels of the matched features: those on the moving-object mask (H, W)."""
    point_uv = current.points.uv[matches.points.current]
    segments = current.lines.endpoints[matches.lines.current]
    point_dynamic, line_dynamic = features_on_mask(point_uv, segments, moving_mask)
    return DynamicLabels(point_uv, point_dynamic, segments, line_dynamic)


def _point_observations(
    reference: StereoFeatures, current: StereoFeatures, matches: FrameMatches, scale_factor: float
) -> PointObservations:
    """Reference 3D points (reference camera frame) observed as current stereo pixels ``(u_l, v, u_r)``.

    A point found at ORB octave ``o`` has a pixel sigma of ``scale_factor**o`` (as ORB-SLAM2).
    """
    now = current.points
    stereo_px = np.column_stack([now.uv, now.u_right])[matches.current]
    sigma = scale_factor ** now.octave[matches.current].astype(np.float64)
    return PointObservations(reference.points.points_c[matches.previous], stereo_px, sigma)


def _line_observations(
    camera: StereoCamera, reference: StereoFeatures, current: StereoFeatures, matches: FrameMatches, config: Config
) -> LineObservations:
    """Reference 3D segments (reference camera frame) observed as current left-image segments.

    The horizontal error is used only where both detected endpoints lie
    ``tracking.border_margin_px`` inside the image (paper: a segment cut by the border has
    no reliable endpoint).
    """
    endpoints_3d = reference.lines.endpoints_c[matches.previous]
    detected = current.lines.endpoints[matches.current]
    start_px, end_px = detected[:, :2], detected[:, 2:]
    return LineObservations(
        start_w=endpoints_3d[:, 0],
        end_w=endpoints_3d[:, 1],
        start_px=start_px,
        end_px=end_px,
        sigma_px=np.full(len(matches), config.tracking.line_sigma_px),
        horizontal_eligible=endpoints_away_from_border(camera, start_px, end_px, config.tracking.border_margin_px),
    )


def _counts(
    matched: _FrameMatches, kept: _FrameMatches, labels: DynamicLabels, solution: PoseOnlyResult
) -> TrackingCounts:
    return TrackingCounts(
        point_matches=len(matched.points),
        line_matches=len(matched.lines),
        points_after_filter=len(kept.points),
        lines_after_filter=len(kept.lines),
        dynamic_points=int(np.count_nonzero(labels.point_dynamic)),
        dynamic_lines=int(np.count_nonzero(labels.line_dynamic)),
        point_inliers=int(np.count_nonzero(solution.inliers.points)),
        line_inliers=int(np.count_nonzero(solution.inliers.lines)),
    )


class _StageClock:
    """Wall time between laps [ms], by stage name."""

    def __init__(self) -> None:
        self.laps: dict[str, float] = {}
        self._last = time.perf_counter()

    def lap(self, stage: str) -> None:
        now = time.perf_counter()
        self.laps[stage] = 1e3 * (now - self._last)
        self._last = now
