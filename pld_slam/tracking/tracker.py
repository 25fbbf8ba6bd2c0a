"""`Tracker`: the tracking thread of PLD-SLAM.

The tracker owns a reference frame's stereo features and the constant-velocity motion
model. For each new frame it predicts the pose from the last inter-frame motion, matches
the reference features to the current ones around their predictions (`pld_slam.matching.frames`),
removes mismatches with the paper's two filters (`outliers`), leaves out the features that
disagree with the motion model (`dynamic`: dynamic grid and dynamic LLG), and estimates the pose
relative to the reference by pose-only least squares over the point reprojection and line
vertical/horizontal errors (`pld_slam.optim.pose_only`), rejecting outliers over rounds.
With a map (``mapping.enabled``), that pose is the first estimate: the frame is then
tracked against the local map (`local_map`), whose pose is the frame's, and the tracker
decides whether the frame becomes a keyframe (`pld_slam.keyframes`). The tracker reads
the map and never changes it: what it saw goes back to local mapping in `TrackedFrame`.

Reference frame (`reference`): a frame a few frames back, renewed when worn, after a
failure, after a recovered pose, and with a map at every keyframe (`use_keyframe`).

Tracking failure. The paper does not say what happens when a frame cannot be tracked.
With a map, a frame whose guided search had to widen its window (the prediction was
off: a run that starts moving, dropped frames, a sudden change of speed), that the local
map does not confirm, or that tracks fewer than ``keyframes.min_tracked_ratio`` of its
reference keyframe's landmarks is also posed without the prior (`relocalisation`: descriptor
matches to the local map, seeded PnP RANSAC, then the local map tracked from there; then
the keyframes most similar by GGS), and the pose the local map confirms with more
landmarks wins (`TrackingStatus.RECOVERED` when it is the one without the prior). On the
synthetic street started from rest with two frames in three dropped, the widened guided
search locked onto the facades' repeated texture one period off and ran 1.6 m per frame
fast with 70-110 inliers per frame, a silently wrong trajectory (ATE 1.1 m). A frame whose
local-map pose is the one a trusted motion model predicted (the last frame tracked
normally, the guided search not widened, the pose within the model's expected error:
`static_world.motion_model_distance`) is not posed again when it merely tracks few
landmarks: on the synthetic ``convoy`` a bus and a truck hid most of the static world,
and the pose from scratch matched landmarks the convoy had left in the map (115 against
106) and put the camera back 1.7 m, where it then drove along with the convoy. Nor does a
pose from scratch that lies farther from a trusted prediction than the guided one replace
it, however many landmarks it tracks: on ``convoy`` seed 1 (true masks) a guided pose 7 cm
from the prediction lost to one 2.9 m away with 125 landmarks against 97, the facades'
repeated windows matched one period off.
Otherwise (or without a map), fewer than ``tracking.min_inliers`` inlier points + lines,
or a failed solve, keeps the motion model's prediction for that frame (flagged
`TrackingStatus.LOST`): the trajectory stays continuous, and the next frame is tracked
against this one's features, so tracking recovers as soon as a frame has enough
matches. The first frame has no previous frame; it defines the world (``T_w_c = I``).
"""

import dataclasses
import enum
from dataclasses import dataclass, field

import numpy as np

from pld_slam.config import Config
from pld_slam.frontend import StereoFeatures
from pld_slam.frontend.ggs import ggs_distance
from pld_slam.geometry.camera import StereoCamera
from pld_slam.geometry.se3 import inverse, transform_points
from pld_slam.keyframes import KeyframeEvidence, KeyframeReason, KeyframeSelector
from pld_slam.mapping.keyframe import KeyFrame
from pld_slam.mapping.map import Map
from pld_slam.matching.frames import FrameMatches, match_lines, match_points, predict_segments
from pld_slam.matching.observations import line_observations, point_observations
from pld_slam.matching.prior_free import pose_without_prior
from pld_slam.optim.observations import LineObservations, ObservationMasks, PointObservations
from pld_slam.optim.pose_only import (
    PoseOnlyOptions,
    PoseOnlyResult,
    optimize_pose,
    optimize_pose_rejecting_outliers,
)
from pld_slam.timing import StageClock
from pld_slam.tracking.dynamic import DynamicLabels, dynamic_grid, dynamic_llg, predict_stereo_with_depth_sigma
from pld_slam.tracking.local_map import (
    LocalMap,
    LocalMapTracking,
    ReferenceMatches,
    gather_local_map,
    track_local_map,
)
from pld_slam.tracking.motion_model import MotionModel
from pld_slam.tracking.moving_masks import features_on_mask
from pld_slam.tracking.outliers import line_llg_filter, point_grid_filter
from pld_slam.tracking.reference import DynamicIndices, FeatureMatches, LandmarkIds, ReferenceFrame, can_be_reference
from pld_slam.tracking.relocalisation import keyframes_by_similarity
from pld_slam.tracking.see_through import landmarks_found_at_another_depth, landmarks_seen_through
from pld_slam.tracking.static_world import static_world_solution


class TrackingStatus(enum.Enum):
    """How a frame's pose was obtained."""

    FIRST = "first"
    """The first frame: it defines the world."""
    TRACKED = "tracked"
    """Estimated from matched points and lines."""
    RECOVERED = "recovered"
    """Posed without the motion-model prior, by PnP against the map (`relocalisation`)."""
    LOST = "lost"
    """Too few inliers: the motion model's prediction is kept."""


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
class TrackedFrame:
    """The tracker's answer for one frame.

    Attributes
    ----------
    T_w_c : (4, 4) camera-to-world pose of the frame.
    T_c_p : (4, 4) motion from the previous camera to this one (identity for the first).
    status : how the pose was obtained.
    counts : matches, filter survivors, dynamic features and inliers.
    stage_ms : wall time of each tracking stage [ms]: ``matching``, ``filters``, ``dynamic``,
        ``pose``, and with a map ``local_map`` and ``see_through``.
    dynamic : the matched features of this frame and their dynamic labels (empty labels when
        nothing was matched; None for the first frame and a skipped one).
    map : what tracking the local map found (None without a map, or when not tracked against it).
    keyframe : why the frame becomes a keyframe, or None (always None without a map).
    point_dynamic, line_dynamic : (P_all,), (L,) bool, the frame's keypoints and lines labelled
        dynamic (empty when the frame had no features).
    point_rejected, line_rejected : (P_all,), (L,) bool, the frame's keypoints and lines matched to
        the reference frame whose match its pose rejected (none when the pose did not come
        from the reference: the first frame, a lost or recovered one).
    """

    T_w_c: np.ndarray
    T_c_p: np.ndarray
    status: TrackingStatus
    counts: TrackingCounts = TrackingCounts()
    stage_ms: dict[str, float] = field(default_factory=dict)
    dynamic: DynamicLabels | None = None
    map: LocalMapTracking | None = None
    keyframe: KeyframeReason | None = None
    point_dynamic: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))
    line_dynamic: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))
    point_rejected: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))
    line_rejected: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))


class Tracker:
    """Stereo point-line tracking against a reference frame and, given a map, its local map."""

    def __init__(self, camera: StereoCamera, config: Config, world_map: Map | None = None) -> None:
        self._camera = camera
        self._config = config
        self._map = world_map
        self._local_map: LocalMap | None = None
        self._reference_keyframe: KeyFrame | None = None
        self._frames_since_keyframe = 0
        self._keyframes = KeyframeSelector(config.keyframes)
        self._pose_options = PoseOnlyOptions(
            use_line_vertical=config.lines.vertical_error,
            use_line_horizontal=config.lines.horizontal_error,
        )
        self._reference: ReferenceFrame | None = None
        self._motion = MotionModel()

    def track(
        self,
        features: StereoFeatures,
        moving_mask: np.ndarray | None = None,
        images: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> TrackedFrame:
        """Estimate the pose of the frame whose stereo features are ``features``.

        ``moving_mask`` (H, W) bool, the frame's moving-object pixels, replaces the two
        detectors when given: the features on it are the dynamic ones (`moving_masks`), left
        out of the robust solve from the start, so that movers a solve would follow cannot
        pull it (the upper bound of the detectors must not share their failure).
        ``images``, the rectified (left, right) pair (H, W) uint8 the features come from,
        lets the map's missed points be tested for being seen through, and those found by a
        keypoint without a stereo match for another depth (`pld_slam.tracking.see_through`,
        ``mapping.see_through``).
        """
        if self._reference is None:
            return self._first_frame(features, moving_mask)
        clock = StageClock()
        T_c_r_predicted = self._motion.predicted_T_c_w() @ self._reference.T_w_r
        reference = self._reference.features
        matched, widened = self._match(reference, features, T_c_r_predicted)
        clock.lap("matching")
        kept = self._filter(reference, features, matched)
        clock.lap("filters")
        points = point_observations(
            reference.points.points_c[kept.points.previous], features.points, kept.points.current,
            self._config.points,
        )
        lines = line_observations(
            self._camera, reference.lines.endpoints_c[kept.lines.previous], features.lines, kept.lines.current,
            self._config,
        )
        if moving_mask is None:
            solution = optimize_pose_rejecting_outliers(
                self._camera, T_c_r_predicted, points=points, lines=lines, options=self._pose_options
            )
            clock.lap("pose")
            solution, labels = self._detect_dynamic(features, kept, points, lines, solution, T_c_r_predicted, widened)
            solution = self._without_dynamic(solution, points, lines, labels)
        else:
            labels = _labels_from_mask(features, kept, moving_mask)
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
        tracked_by_reference = tracked
        T_w_c = self._reference.T_w_r @ inverse(solution.T_c_w) if tracked else self._motion.predicted_T_w_c()
        map_tracking = None
        recovered = False
        if self._local_map is not None:
            map_tracking = track_local_map(
                self._camera, inverse(T_w_c), self._local_map, features, point_dynamic, line_dynamic,
                self._config, self._pose_options, self._reference.map_matches(kept, solution, labels, self._map),
                check_static_world=moving_mask is None and self._detectors_on and tracked and not widened,
            )
            suspect = widened or not (tracked and self._map_tracked(map_tracking)) or self._tracks_few(map_tracking)
            if suspect and not self._predicted(map_tracking, widened):
                proposal = self._track_without_prior(features, point_dynamic, line_dynamic)
                if proposal is not None:
                    from_scratch, its_local_map = proposal
                    if self._better_from_scratch(from_scratch, map_tracking, widened):
                        map_tracking, recovered = from_scratch, True
                        self._use_local_map(its_local_map)
            clock.lap("local_map")
            if self._map_tracked(map_tracking):
                T_w_c, tracked = inverse(map_tracking.solution.T_c_w), True
                if images is not None and self._config.mapping.see_through:
                    map_tracking = self._with_stereo_evidence(map_tracking, features, *images)
            clock.lap("see_through")
            counts = dataclasses.replace(
                counts,
                map_point_inliers=int(np.count_nonzero(map_tracking.point_ids >= 0)),
                map_line_inliers=int(np.count_nonzero(map_tracking.line_ids >= 0)),
            )
        T_w_c, T_c_p = self._motion.advance(T_w_c)
        landmarks = (
            LandmarkIds.none(features) if map_tracking is None
            else LandmarkIds.of(features, map_tracking.point_ids, map_tracking.line_ids)
        )
        self._update_reference(features, T_w_c, tracked, counts, kept, labels, landmarks, renew=recovered)
        status = _status(tracked, recovered)
        self._motion.trusted = status is TrackingStatus.TRACKED
        keyframe = self._decide_keyframe(features, map_tracking) if tracked and map_tracking is not None else None
        from_reference = tracked_by_reference and status is TrackingStatus.TRACKED
        rejected = _rejected_features(features, kept, solution, labels, from_reference)
        return TrackedFrame(T_w_c.copy(), T_c_p, status, counts, clock.laps, labels, map_tracking, keyframe,
                            point_dynamic, line_dynamic, *rejected)

    @property
    def _detectors_on(self) -> bool:
        """Whether either dynamic detector is switched on."""
        return self._config.dynamic.grid or self._config.dynamic.llg

    def _first_frame(self, features: StereoFeatures, moving_mask: np.ndarray | None) -> TrackedFrame:
        """The first frame: the world (``T_w_c = I``) and the first keyframe. Without a motion
        nothing can be judged dynamic, but for the features on ``moving_mask`` when given."""
        if moving_mask is None:
            point_dynamic = np.zeros(len(features.keypoints), dtype=bool)
            line_dynamic = np.zeros(len(features.lines), dtype=bool)
        else:
            point_dynamic, line_dynamic = features_on_mask(features.keypoints.uv, features.lines.endpoints, moving_mask)
        dynamic = DynamicIndices(np.flatnonzero(point_dynamic), np.flatnonzero(line_dynamic))
        self._reference = ReferenceFrame(features, np.eye(4), dynamic)
        first_keyframe = KeyframeReason.FIRST if self._map is not None else None
        return TrackedFrame(np.eye(4), np.eye(4), TrackingStatus.FIRST, keyframe=first_keyframe,
                            point_dynamic=point_dynamic, line_dynamic=line_dynamic,
                            point_rejected=np.zeros_like(point_dynamic), line_rejected=np.zeros_like(line_dynamic))

    def _better_from_scratch(self, from_scratch: LocalMapTracking, guided: LocalMapTracking, widened: bool) -> bool:
        """Whether the pose found without the prior replaces the guided one: it tracks more landmarks
        and, when a trusted motion model predicted the frame, lies no farther from the prediction
        (module docstring)."""
        if from_scratch.tracked_landmarks <= guided.tracked_landmarks:
            return False
        guided_distance = self._distance_from_prediction(guided, widened)
        return guided_distance is None or self._distance_from_prediction(from_scratch, widened) <= guided_distance

    def _predicted(self, map_tracking: LocalMapTracking, widened: bool) -> bool:
        """Whether the local map confirmed the pose a trusted motion model predicted (within its
        expected error): then tracking few landmarks is no sign that the prior was wrong (module docstring)."""
        distance = self._distance_from_prediction(map_tracking, widened)
        return distance is not None and distance <= 1.0

    def _distance_from_prediction(self, map_tracking: LocalMapTracking, widened: bool) -> float | None:
        """How far the local map's pose lies from the motion model's prediction, in units of the model's
        expected error (`static_world.motion_model_distance`); None when the model is not trusted (the
        last frame not tracked normally, or this frame's guided search widened) or the map gave no pose."""
        if widened or not self._motion.trusted or not self._map_tracked(map_tracking):
            return None
        return self._motion.distance(map_tracking.solution.T_c_w, self._config)

    def _map_tracked(self, map_tracking: LocalMapTracking) -> bool:
        """Whether tracking the local map gave a pose (a converged solve on ``min_inliers`` landmarks)."""
        return map_tracking.solution.success and map_tracking.tracked_landmarks >= self._config.tracking.min_inliers

    def _with_stereo_evidence(self, map_tracking: LocalMapTracking, features: StereoFeatures, left: np.ndarray,
                              right: np.ndarray) -> LocalMapTracking:
        """``map_tracking`` with, among its dynamic point landmarks, the missed ones the pair sees through and
        the ones found by a keypoint without a stereo match where the pair shows another depth
        (`pld_slam.tracking.see_through`)."""
        seen_through = landmarks_seen_through(self._camera, map_tracking.missed, left, right)
        mono = np.flatnonzero(map_tracking.point_ids >= 0)
        mono = mono[mono >= features.keypoints.n_stereo]
        ids = map_tracking.point_ids[mono]
        p_c = transform_points(map_tracking.solution.T_c_w, self._map.points.geometry[ids])
        elsewhere = landmarks_found_at_another_depth(self._camera, ids, features.keypoints.uv[mono], p_c, left, right)
        return dataclasses.replace(
            map_tracking, dynamic_point_ids=np.union1d(map_tracking.dynamic_point_ids,
                                                       np.union1d(seen_through, elsewhere))
        )

    def _tracks_few(self, map_tracking: LocalMapTracking) -> bool:
        """Whether the frame tracks fewer than ``keyframes.min_tracked_ratio`` of its reference keyframe's
        landmarks: the keyframe rule's emergency, and a sign that the prior may have been wrong."""
        established = _established_landmarks(self._map, self._reference_keyframe)
        return map_tracking.tracked_landmarks < self._config.keyframes.min_tracked_ratio * established

    def _track_without_prior(
        self, features: StereoFeatures, point_dynamic: np.ndarray, line_dynamic: np.ndarray
    ) -> tuple[LocalMapTracking, LocalMap] | None:
        """The local map tracked from a pose found without the motion model (`relocalisation`), and
        the local map it was tracked against; None when none gave a pose.

        First against the local map of the reference keyframe; failing that, against the
        local maps of the keyframes most similar by GGS (relocalisation). A frame without a
        GGS (not computed) skips the second. The tracker switches to the local map only if it
        takes the pose (`_use_local_map`).
        """
        candidates = [self._local_map]
        if features.place_ggs is not None:
            limit = self._config.tracking.relocalisation_keyframes
            for keyframe in keyframes_by_similarity(self._map, features.place_ggs, limit):
                if keyframe != self._reference_keyframe.id:
                    candidates.append(gather_local_map(self._map, keyframe, self._config.mapping.tracking_keyframes))
        for local_map in candidates:
            points = local_map.points
            pose = pose_without_prior(self._camera, features.keypoints, points.geometry, points.descriptors,
                                      self._config)
            if pose is None:
                continue
            tracking = track_local_map(
                self._camera, pose.T_c_w, local_map, features, point_dynamic, line_dynamic, self._config,
                self._pose_options, ReferenceMatches.empty(),
            )
            if self._map_tracked(tracking):
                return tracking, local_map
        return None

    def _use_local_map(self, local_map: LocalMap) -> None:
        """Track against ``local_map`` from now on; when it is another keyframe's (relocalisation),
        that keyframe becomes the reference keyframe."""
        if local_map is not self._local_map:
            self._local_map = local_map
            self._reference_keyframe = self._map.keyframes[local_map.keyframes[0]]

    @property
    def reference(self) -> ReferenceFrame | None:
        """The frame the next frame is matched against (None before the first frame)."""
        return self._reference

    @property
    def motion_model(self) -> MotionModel:
        """The constant-velocity model that predicts the next frame (trusted after a frame tracked normally)."""
        return self._motion

    @property
    def reference_keyframe_id(self) -> int | None:
        """The keyframe whose local map the next frame is tracked against (None before the first)."""
        return None if self._reference_keyframe is None else self._reference_keyframe.id

    def use_keyframe(self, keyframe: KeyFrame) -> None:
        """Track the next frames against the local map of ``keyframe``, just inserted into the map.

        The keyframe also becomes the reference frame, at its pose after local BA (which
        is also the last pose of the motion model), with its dynamic labels.
        """
        self._reference_keyframe = keyframe
        self._frames_since_keyframe = 0
        self._local_map = gather_local_map(self._map, keyframe.id, self._config.mapping.tracking_keyframes)
        self._motion.T_w_p = keyframe.T_w_c
        dynamic = DynamicIndices(np.flatnonzero(keyframe.point_dynamic), np.flatnonzero(keyframe.line_dynamic))
        landmarks = LandmarkIds.of(keyframe.features, keyframe.point_ids, keyframe.line_ids)
        self._reference = ReferenceFrame(keyframe.features, keyframe.T_w_c, dynamic, landmarks)

    def _decide_keyframe(self, features: StereoFeatures, map_tracking: LocalMapTracking) -> KeyframeReason | None:
        """Whether the tracked frame becomes a keyframe (`pld_slam.keyframes`)."""
        keyframe = self._reference_keyframe
        self._frames_since_keyframe += 1
        ggs = 0.0 if features.ggs is None else ggs_distance(features.ggs, keyframe.ggs)
        return self._keyframes.decide(KeyframeEvidence(
            frames_since_keyframe=self._frames_since_keyframe,
            ggs_distance=ggs,
            tracked_landmarks=map_tracking.tracked_landmarks,
            reference_landmarks=_established_landmarks(self._map, keyframe),
        ))

    def _update_reference(
        self,
        features: StereoFeatures,
        T_w_c: np.ndarray,
        tracked: bool,
        counts: TrackingCounts,
        kept: FeatureMatches,
        labels: DynamicLabels,
        landmarks: LandmarkIds,
        renew: bool,
    ) -> None:
        """Record the dynamic features seen, age the reference, and renew it when worn, after a failure,
        or when ``renew`` (a pose recovered without the prior: the reference's matches are not to be trusted).

        After a failure the reference is the failed frame itself (at its motion-model
        pose) if it has features enough to be tracked against (`can_be_reference`):
        tracking goes on from the newest features, which is how it recovers from a wrong
        prediction. A frame without them (blank, blinded) keeps the old reference.
        """
        inliers = counts.point_inliers + counts.line_inliers
        self._reference.record(kept, labels, inliers)
        due = self._reference.is_worn(inliers, self._config) if tracked else self.can_be_reference(features)
        if renew or due:
            found = DynamicIndices(kept.points.current[labels.point_dynamic], kept.lines.current[labels.line_dynamic])
            self._reference = ReferenceFrame(features, T_w_c, found, landmarks)

    def skip(self) -> TrackedFrame:
        """Advance over a frame without images (unreadable): the motion model's pose, flagged LOST.

        The reference stays, so the next frame is matched against it as usual; the motion
        model is not trusted for it (module docstring: only after a frame tracked normally).
        """
        return TrackedFrame(self._motion.coast().copy(), self._motion.velocity, TrackingStatus.LOST)

    def can_be_reference(self, features: StereoFeatures) -> bool:
        """Whether a frame has the stereo points + lines for ``min_inliers`` twice over (`reference`)."""
        return can_be_reference(features, self._config)

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
        self, reference: StereoFeatures, current: StereoFeatures, matches: FeatureMatches, solution: PoseOnlyResult
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
        seen = self._reference.seen_dynamic_points[matches.previous]
        return dynamic_grid(predicted, detected, sigma, cell_size, config.dynamic, seen)

    def _dynamic_lines(
        self, reference: StereoFeatures, current: StereoFeatures, matches: FrameMatches, T_c_r: np.ndarray
    ) -> np.ndarray:
        """The dynamic LLG over matched lines (L,) bool, their segments predicted with ``T_c_r``."""
        predicted, _ = predict_segments(self._camera, T_c_r, reference.lines.endpoints_c[matches.previous])
        seen = self._reference.seen_dynamic_lines[matches.previous]
        return dynamic_llg(predicted, current.lines.endpoints[matches.current], self._config.dynamic, seen)

    def _detect_dynamic(
        self, features: StereoFeatures, kept: FeatureMatches, points: PointObservations, lines: LineObservations,
        solution: PoseOnlyResult, T_c_r_predicted: np.ndarray, widened: bool,
    ) -> tuple[PoseOnlyResult, DynamicLabels]:
        """The robust ``solution``, or the frame solved for the static world's motion where the
        solve is suspect (`static_world`), and the dynamic labels judged against it
        (with the points found moving there). The motion model is trusted when the last frame
        was tracked normally and this one's guided search did not have to widen. Both detectors
        off: ``solution`` and no labels."""
        moving = np.zeros(len(points.sigma_px), dtype=bool)
        if solution.success and self._detectors_on:
            static = static_world_solution(self._camera, solution, T_c_r_predicted, points, lines,
                                           self._motion.trusted and not widened, self._pose_options, self._config)
            solution, moving = static.solution, static.moving
        labels = self._label_dynamic(self._reference.features, features, kept, solution)
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


def _status(tracked: bool, recovered: bool) -> TrackingStatus:
    """LOST when not tracked, RECOVERED when posed without the prior, else TRACKED."""
    if not tracked:
        return TrackingStatus.LOST
    return TrackingStatus.RECOVERED if recovered else TrackingStatus.TRACKED


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


def _established_landmarks(world_map: Map, keyframe: KeyFrame) -> int:
    """Live landmarks of ``keyframe`` that at least two keyframes observe (`pld_slam.keyframes`);
    all of them while the map holds one keyframe.

    ORB-SLAM2 counts points seen by two keyframes there too, which at its first keyframe is
    none, so its ratio rules cannot ask for the second keyframe. Counting all of them, the
    frame after the first keyframe usually tracks under ``min_tracked_ratio`` of them and
    becomes the second, whose GGS then sets the keyframe spacing of the run (the ``FEW_TRACKED``
    rule of `pld_slam.keyframes`): on KITTI 06 a keyframe every 1.6 frames and ATE 0.031 m;
    counted as ORB-SLAM2 does, 15 keyframes in 51 frames and 0.039 m (raw 0005: 0.107 against
    0.086 m), for about half the mapping time."""
    min_observers = min(2, len(world_map.keyframes))
    count = 0
    for kind in world_map.kinds:
        ids = getattr(keyframe, kind.IDS_FIELD)
        ids = ids[kind.live(ids)]
        count += int(np.count_nonzero(kind.n_observers[ids] >= min_observers))
    return count


def _rejected_features(
    current: StereoFeatures, matches: FeatureMatches, solution: PoseOnlyResult, labels: DynamicLabels,
    from_reference: bool,
) -> tuple[np.ndarray, np.ndarray]:
    """The current frame's keypoints (P_all,) and lines (L,) matched to the reference that ``solution``
    rejected and that are not labelled dynamic; none unless the pose came ``from_reference``."""
    points = np.zeros(len(current.keypoints), dtype=bool)
    lines = np.zeros(len(current.lines), dtype=bool)
    if from_reference and solution.success:
        points[matches.points.current[~solution.inliers.points & ~labels.point_dynamic]] = True
        lines[matches.lines.current[~solution.inliers.lines & ~labels.line_dynamic]] = True
    return points, lines


def _static_observations(labels: DynamicLabels) -> ObservationMasks:
    """The observations of the matched features not labelled dynamic."""
    return ObservationMasks(~labels.point_dynamic, ~labels.line_dynamic, ~labels.line_dynamic)


def _labels_from_mask(current: StereoFeatures, matches: FeatureMatches, moving_mask: np.ndarray) -> DynamicLabels:
    """Dynamic labels of the matched features: those on the moving-object mask (H, W)."""
    point_uv = current.points.uv[matches.points.current]
    segments = current.lines.endpoints[matches.lines.current]
    point_dynamic, line_dynamic = features_on_mask(point_uv, segments, moving_mask)
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
