"""`ReferenceTracker`: the strategy "track reference", a frame against the reference frame.

The motion model's prediction of the reference-to-frame motion seeds a guided search
(`pld_slam.matching.frames`), widened once when it finds too few matches (the prediction
was off); the paper's two filters remove mismatches (`outliers`); a pose-only least-squares
solve over the point reprojection and line vertical/horizontal errors
(`pld_slam.optim.pose_only`) rejects outliers over rounds; the static world's motion is
found where movers pulled it (`static_world`), the features that disagree with it are
labelled dynamic (`dynamic`: dynamic grid and dynamic LLG), and the pose is refined without
them. With a moving-object mask, the features on it are the dynamic ones, left out of the
solve from the start (`moving_masks`). The frame is tracked when the solve converged on
``tracking.min_inliers`` point + line inliers (`ReferenceTracking`).
"""

import dataclasses
from dataclasses import dataclass

import numpy as np

from pld_slam.config import Config
from pld_slam.frontend import StereoFeatures
from pld_slam.geometry.camera import StereoCamera
from pld_slam.geometry.se3 import inverse
from pld_slam.localisation.static_world import StaticWorldOptions, static_world_solution
from pld_slam.matching.frames import FrameMatches, match_lines, match_points, predict_segments
from pld_slam.matching.observations import line_observations, point_observations
from pld_slam.optim.observations import LineObservations, ObservationMasks, PointObservations
from pld_slam.optim.pose_only import (
    PoseOnlyOptions,
    PoseOnlyResult,
    optimize_pose,
    optimize_pose_rejecting_outliers,
)
from pld_slam.timing import StageClock
from pld_slam.tracking.dynamic import DynamicLabels, dynamic_grid, dynamic_llg, predict_stereo_with_depth_sigma
from pld_slam.tracking.motion_model import MotionModel
from pld_slam.tracking.moving_masks import features_on_mask
from pld_slam.tracking.outliers import line_llg_filter, point_grid_filter
from pld_slam.tracking.reference import FeatureMatches, ReferenceFrame


@dataclass(frozen=True)
class TrackingCounts:
    """What survived each step of tracking one frame (points, lines).

    ``point_inliers`` / ``line_inliers`` count the inliers against the reference frame,
    ``map_point_inliers`` / ``map_line_inliers`` those against the local map.
    """

    point_matches: int = 0
    line_matches: int = 0
    points_after_filter: int = 0
    lines_after_filter: int = 0
    dynamic_points: int = 0
    dynamic_lines: int = 0
    point_inliers: int = 0
    line_inliers: int = 0
    map_point_inliers: int = 0
    map_line_inliers: int = 0


@dataclass(frozen=True)
class ReferenceTracking:
    """What tracking a frame against the reference frame found.

    Attributes
    ----------
    matched : the guided search's matches (reference side ``previous``, frame side ``current``).
    kept : those that passed the mismatch filters: the observations of the solve.
    widened : whether the search had to widen its window (the prediction was off).
    labels : the dynamic labels of the kept matches.
    solution : the pose-only solve over the kept matches; its ``T_c_w`` is ``T_c_r``, reference
        camera to this camera (4, 4).
    point_dynamic, line_dynamic : (P_all,), (L,) bool, the frame's keypoints and lines labelled dynamic.
    counts : matches, filter survivors, dynamic features and inliers (no map counts).
    T_w_c : (4, 4) camera-to-world pose of the frame from the solve; None when not tracked (the solve
        failed or kept fewer than ``tracking.min_inliers`` point + line inliers).
    """

    matched: FeatureMatches
    kept: FeatureMatches
    widened: bool
    labels: DynamicLabels
    solution: PoseOnlyResult
    point_dynamic: np.ndarray
    line_dynamic: np.ndarray
    counts: TrackingCounts
    T_w_c: np.ndarray | None

    @property
    def tracked(self) -> bool:
        """Whether the reference gave the frame a pose."""
        return self.T_w_c is not None

    def rejected_features(self, current: StereoFeatures, pose_taken: bool) -> tuple[np.ndarray, np.ndarray]:
        """The keypoints (P_all,) and lines (L,) of the frame (``current``: its features) matched to the
        reference that the solve rejected and that are not labelled dynamic, as bool masks; none unless
        the frame's pose is the one this solve led to (``pose_taken``)."""
        points = np.zeros(len(current.keypoints), dtype=bool)
        lines = np.zeros(len(current.lines), dtype=bool)
        if pose_taken and self.solution.success:
            solution, labels = self.solution, self.labels
            points[self.kept.points.current[~solution.inliers.points & ~labels.point_dynamic]] = True
            lines[self.kept.lines.current[~solution.inliers.lines & ~labels.line_dynamic]] = True
        return points, lines


def detectors_on(config: Config) -> bool:
    """Whether either dynamic detector is switched on."""
    return config.dynamic.grid or config.dynamic.llg


class ReferenceTracker:
    """Tracks frames against a reference frame (module docstring).

    Parameters
    ----------
    camera : the rectified stereo camera.
    config : the run's configuration (``tracking``, ``filters``, ``dynamic``, ``points``, ``lines``).
    pose_options : the pose-only solve's error terms.
    """

    def __init__(self, camera: StereoCamera, config: Config, pose_options: PoseOnlyOptions) -> None:
        self._camera, self._config, self._pose_options = camera, config, pose_options
        self._static_world = StaticWorldOptions.of(config)

    def track(
        self,
        reference: ReferenceFrame,
        features: StereoFeatures,
        motion: MotionModel,
        trusted: bool,
        moving_mask: np.ndarray | None = None,
        clock: StageClock | None = None,
    ) -> ReferenceTracking:
        """Track the frame with ``features`` against ``reference``, from the prediction of ``motion``.

        ``trusted``: whether the motion model can be relied on (the last frame was tracked
        normally); the static world then moves as predicted unless the search widened
        (`static_world`). ``moving_mask`` (H, W) bool, the frame's moving-object pixels,
        replaces the two detectors when given. ``clock`` gets the laps ``matching``,
        ``filters``, ``pose`` and ``dynamic``.
        """
        clock = StageClock() if clock is None else clock
        T_c_r_predicted = motion.predicted_T_c_w() @ reference.T_w_r
        matched, widened = self._match(reference.features, features, T_c_r_predicted)
        clock.lap("matching")
        kept = self._filter(reference.features, features, matched)
        clock.lap("filters")
        points = point_observations(
            reference.features.points.points_c[kept.points.previous], features.points, kept.points.current,
            self._config.points,
        )
        lines = line_observations(
            self._camera, reference.features.lines.endpoints_c[kept.lines.previous], features.lines,
            kept.lines.current, self._config.tracking,
        )
        if moving_mask is None:
            solution = optimize_pose_rejecting_outliers(
                self._camera, T_c_r_predicted, points=points, lines=lines, options=self._pose_options
            )
            clock.lap("pose")
            solution, labels = self._detect_dynamic(reference, features, kept, points, lines, solution,
                                                    T_c_r_predicted, trusted and not widened)
            solution = self._without_dynamic(solution, points, lines, labels)
        else:
            labels = _labels_from_mask(features, kept, moving_mask, self._config.dynamic.mask_margin_px)
            solution = optimize_pose_rejecting_outliers(
                self._camera, T_c_r_predicted, points=points, lines=lines, options=self._pose_options,
                within=_static_observations(labels),
            )
            clock.lap("pose")
        clock.lap("dynamic")
        point_dynamic, line_dynamic = _dynamic_features(features, kept, labels)
        counts = _counts(matched, kept, labels, solution)
        min_inliers = self._config.tracking.min_inliers
        tracked = solution.success and counts.point_inliers + counts.line_inliers >= min_inliers
        T_w_c = reference.T_w_r @ inverse(solution.T_c_w) if tracked else None
        return ReferenceTracking(matched, kept, widened, labels, solution, point_dynamic, line_dynamic, counts, T_w_c)

    def _match(
        self, reference: StereoFeatures, current: StereoFeatures, T_c_r: np.ndarray
    ) -> tuple[FeatureMatches, bool]:
        """Points and lines matched around the predicted pose ``T_c_r``, widening the window once if needed;
        and whether it was (the prediction was off)."""
        cfg = self._config.tracking
        point_radius, line_radius = cfg.point_search_radius_px, cfg.line_search_radius_px
        for attempt in range(2):
            matches = FeatureMatches(
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
                return matches, attempt > 0
            point_radius *= cfg.wide_search_factor
            line_radius *= cfg.wide_search_factor
        return matches, True

    def _filter(self, reference: StereoFeatures, current: StereoFeatures, matches: FeatureMatches) -> FeatureMatches:
        """The matches that pass the enabled mismatch filters."""
        filters = self._config.filters
        points, lines = matches.points, matches.lines
        if filters.point_grid:
            keep = point_grid_filter(
                reference.points.uv[points.previous], current.points.uv[points.current], filters
            )
            points = points.subset(keep)
        if filters.line_llg:
            keep = line_llg_filter(
                reference.lines.endpoints[lines.previous], current.lines.endpoints[lines.current], filters
            )
            lines = lines.subset(keep)
        return FeatureMatches(points, lines)

    def _label_dynamic(
        self, reference: ReferenceFrame, current: StereoFeatures, matches: FeatureMatches, solution: PoseOnlyResult
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
        self, reference: ReferenceFrame, current: StereoFeatures, matches: FrameMatches, T_c_r: np.ndarray
    ) -> np.ndarray:
        """The dynamic grid over matched points (K,) bool, their stereo observations
        predicted with ``T_c_r`` and judged in sigmas of the detections and the reference depth."""
        config = self._config
        seen = reference.seen_dynamic_points[matches.previous]
        reference = reference.features
        points_r = reference.points.points_c[matches.previous]
        detected = np.column_stack([current.points.uv, current.points.u_right])[matches.current]
        octaves = np.column_stack([reference.points.octave[matches.previous], current.points.octave[matches.current]])
        octave_sigma = config.points.scale_factor ** octaves.astype(np.float64)
        disparity_sigma = config.dynamic.disparity_sigma_px * octave_sigma[:, 0]
        predicted, depth_shift = predict_stereo_with_depth_sigma(self._camera, T_c_r, points_r, disparity_sigma)
        sigma = np.sqrt(np.sum(octave_sigma**2, axis=1) + depth_shift**2)
        cell_size = (config.filters.point_grid_cell_width, config.filters.point_grid_cell_height)
        return dynamic_grid(predicted, detected, sigma, cell_size, config.dynamic, seen)

    def _dynamic_lines(
        self, reference: ReferenceFrame, current: StereoFeatures, matches: FrameMatches, T_c_r: np.ndarray
    ) -> np.ndarray:
        """The dynamic LLG over matched lines (L,) bool, their segments predicted with ``T_c_r``."""
        predicted, _ = predict_segments(self._camera, T_c_r, reference.features.lines.endpoints_c[matches.previous])
        seen = reference.seen_dynamic_lines[matches.previous]
        return dynamic_llg(predicted, current.lines.endpoints[matches.current], self._config.dynamic, seen)

    def _detect_dynamic(
        self, reference: ReferenceFrame, features: StereoFeatures, kept: FeatureMatches, points: PointObservations,
        lines: LineObservations, solution: PoseOnlyResult, T_c_r_predicted: np.ndarray, trusted: bool,
    ) -> tuple[PoseOnlyResult, DynamicLabels]:
        """The robust ``solution``, or the frame solved for the static world's motion where the
        solve is suspect (`static_world`), and the dynamic labels judged against it
        (with the points found moving there), ``trusted`` whether the motion model's prediction
        ``T_c_r_predicted`` is. Both detectors off: ``solution`` and no labels."""
        moving = np.zeros(len(points.sigma_px), dtype=bool)
        if solution.success and detectors_on(self._config):
            static = static_world_solution(self._camera, solution, T_c_r_predicted, points, lines,
                                           trusted, self._pose_options, self._static_world)
            solution, moving = static.solution, static.moving
        labels = self._label_dynamic(reference, features, kept, solution)
        return solution, dataclasses.replace(labels, point_dynamic=labels.point_dynamic | moving)

    def _without_dynamic(
        self, solution: PoseOnlyResult, points: PointObservations, lines: LineObservations, labels: DynamicLabels
    ) -> PoseOnlyResult:
        """``solution`` refined without the dynamic features: one plain least-squares solve
        from it over its inliers less the dynamic ones (the first solve's robust loss and
        rejection rounds have done the rest); ``solution`` itself when nothing is dynamic."""
        if not (labels.point_dynamic.any() or labels.line_dynamic.any()):
            return solution
        include = solution.inliers & _static_observations(labels)
        refined = optimize_pose(
            self._camera, solution.T_c_w, points=points, lines=lines, options=self._pose_options,
            include=include, robust=False,
        )
        if not refined.success:
            return solution
        inliers = refined.inliers & include
        return dataclasses.replace(refined, inliers=inliers)


def _dynamic_features(
    current: StereoFeatures, matches: FeatureMatches, labels: DynamicLabels
) -> tuple[np.ndarray, np.ndarray]:
    """The current frame's keypoints (P_all,) and lines (L,) labelled dynamic, as bool masks over all of them.

    The labels are on stereo points, which are the first keypoints (same indices).
    """
    points = np.zeros(len(current.keypoints), dtype=bool)
    points[matches.points.current[labels.point_dynamic]] = True
    lines = np.zeros(len(current.lines), dtype=bool)
    lines[matches.lines.current[labels.line_dynamic]] = True
    return points, lines


def _static_observations(labels: DynamicLabels) -> ObservationMasks:
    """The observations of the matched features not labelled dynamic."""
    return ObservationMasks(~labels.point_dynamic, ~labels.line_dynamic, ~labels.line_dynamic)


def _labels_from_mask(
    current: StereoFeatures, matches: FeatureMatches, moving_mask: np.ndarray, margin_px: int
) -> DynamicLabels:
    """Dynamic labels of the matched features: those on the moving-object mask (H, W) grown by ``margin_px``."""
    point_uv = current.points.uv[matches.points.current]
    segments = current.lines.endpoints[matches.lines.current]
    point_dynamic, line_dynamic = features_on_mask(point_uv, segments, moving_mask, margin_px)
    return DynamicLabels(point_uv, point_dynamic, segments, line_dynamic)


def _counts(
    matched: FeatureMatches, kept: FeatureMatches, labels: DynamicLabels, solution: PoseOnlyResult
) -> TrackingCounts:
    """What survived each step against the reference frame (`TrackingCounts`; no map counts yet)."""
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
