"""`Tracker`: the tracking thread of PLD-SLAM.

`Tracker.track` reads as ORB-SLAM's ``Track()``: the tracking state left by the last frame
(`TrackingState`) decides what runs, then named strategies, each a public method:

- `track_reference` (ORB-SLAM's "track with motion model"): the motion model's prediction
  (`motion_model`) seeds a guided search against the reference frame (`reference`); mismatch
  filters, dynamic labels and a pose-only solve follow (`reference_tracking`).
- `track_local_map` (with a map, ``mapping.enabled``): that pose (or the prediction) is the
  first estimate of tracking the local map (`local_map`), whose pose is the frame's.
- `relocalise`: a frame whose guided pose is suspect is posed again without the prior
  (`relocalisation`), and the better of the two is kept (below).
- `need_new_keyframe`: whether the tracked frame becomes a keyframe (`pld_slam.keyframes`).

The state a frame leaves (OK: tracked normally; RECOVERED; LOST) is reported as its
`TrackingStatus` (TRACKED, RECOVERED, LOST), and decides whether the motion model is
trusted for the next frame. The tracker reads the map
and never changes it: what it saw goes back to local mapping in `TrackedFrame`.

Reference frame (`reference`): a frame a few frames back, renewed when worn, after a
failure, after a recovered pose, and with a map at every keyframe (`use_keyframe`).

Tracking failure. The paper does not say what happens when a frame cannot be tracked.
With a map, a frame whose guided search had to widen its window (the prediction was
off: a run that starts moving, dropped frames, a sudden change of speed), that the local
map does not confirm, or that tracks fewer than ``keyframes.min_tracked_ratio`` of its
reference keyframe's landmarks is also posed without the prior (`relocalisation`: descriptor
matches to the local map, seeded PnP RANSAC, then the local map tracked from there; then
the keyframes most similar by GGS), and the pose the local map confirms with more
landmarks wins (`TrackingStatus.RECOVERED` when it is the one without the prior): a
widened guided search can lock onto a facade's repeated texture one period off, a silently
wrong trajectory. A frame whose local-map pose is the one a trusted motion model predicted
(the last frame tracked normally, the guided search not widened, the pose within the
model's expected error: `static_world.motion_model_distance`) is not posed again when it
merely tracks few landmarks: where movers hide most of the static world, a pose from
scratch matches the landmarks they left in the map. Nor does a pose from scratch that lies
farther from a trusted prediction than the guided one replace it, however many landmarks
it tracks (repeated windows matched one period off). See
docs/decisions/0020-tracking-failure.md.
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
from pld_slam.localisation.local_map import LocalMap, LocalMapTracking, gather_local_map
from pld_slam.localisation.local_map import track_local_map as track_against_local_map
from pld_slam.localisation.static_world import StaticWorldOptions
from pld_slam.mapping.keyframe import KeyFrame
from pld_slam.mapping.map import Map
from pld_slam.optim.pose_only import PoseOnlyOptions
from pld_slam.timing import StageClock
from pld_slam.tracking.dynamic import DynamicLabels
from pld_slam.tracking.motion_model import MotionModel
from pld_slam.tracking.moving_masks import features_on_mask
from pld_slam.tracking.reference import DynamicIndices, LandmarkIds, ReferenceFrame, can_be_reference
from pld_slam.tracking.reference_tracking import ReferenceTracker, ReferenceTracking, TrackingCounts, detectors_on
from pld_slam.tracking.relocalisation import Relocalised, candidate_local_maps, track_from_scratch
from pld_slam.tracking.see_through import SeeThroughOptions, landmarks_found_at_another_depth, landmarks_seen_through


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


class TrackingState(enum.Enum):
    """Where tracking stands after the last frame: it decides what runs for the next one.

    ORB-SLAM's tracking state (not initialised, OK, recently lost, lost) in our terms: a frame
    is always posed (its prediction when nothing else), so what the state decides is whether
    the next frame is the first, and whether the motion model is trusted (`motion_trusted`):
    only after a frame tracked normally. A trusted prediction is the static world's motion
    where movers pull the solve (`static_world`), a local-map pose it predicted is not posed
    again from scratch, and a pose from scratch must lie no farther from it than the guided
    one (`Tracker.relocalise`).
    """

    NOT_INITIALISED = "not initialised"
    """No frame yet: the next one is the first, and defines the world."""
    INITIALISED = "initialised"
    """The last frame was the first: no motion known yet (the model predicts standing still)."""
    OK = "ok"
    """The last frame was tracked with the prior, against the reference frame and the local map."""
    RECOVERED = "recovered"
    """The last frame was posed without the prior (`relocalisation`): its motion says little of the next."""
    LOST = "lost"
    """The last frame kept the motion model's prediction, or was skipped."""

    @property
    def motion_trusted(self) -> bool:
        """Whether the motion model's prediction of the next frame can be relied on: after a frame tracked normally."""
        return self is TrackingState.OK

    @property
    def status(self) -> TrackingStatus:
        """The `TrackingStatus` reported for the frame that left this state."""
        return _STATUS[self]


_STATUS = {
    TrackingState.INITIALISED: TrackingStatus.FIRST,
    TrackingState.OK: TrackingStatus.TRACKED,
    TrackingState.RECOVERED: TrackingStatus.RECOVERED,
    TrackingState.LOST: TrackingStatus.LOST,
}


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
    """Stereo point-line tracking against a reference frame and, given a map, its local map.

    Parameters
    ----------
    camera : the rectified stereo camera.
    config : the run's configuration.
    world_map : the map to track against (None: the reference frame only, visual odometry).
    """

    def __init__(self, camera: StereoCamera, config: Config, world_map: Map | None = None) -> None:
        self._camera = camera
        self._config = config
        self._map = world_map
        self._local_map: LocalMap | None = None
        self._reference_keyframe: KeyFrame | None = None
        self._frames_since_keyframe = 0
        self._keyframes = KeyframeSelector(config.keyframes)
        self._pose_options = PoseOnlyOptions.of(config)
        self._reference_tracker = ReferenceTracker(camera, config, self._pose_options)
        self._see_through = SeeThroughOptions.of(config.mapping)
        self._reference: ReferenceFrame | None = None
        self._motion = MotionModel()
        self._state = TrackingState.NOT_INITIALISED

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
        if self._state is TrackingState.NOT_INITIALISED:
            return self._first_frame(features, moving_mask)
        clock = StageClock()
        guided = self.track_reference(features, moving_mask, clock)
        state = TrackingState.OK if guided.tracked else TrackingState.LOST
        T_w_c = guided.T_w_c if guided.tracked else self._motion.predicted_T_w_c()
        counts, map_tracking = guided.counts, None
        if self._local_map is not None:
            map_tracking = self.track_local_map(features, guided, T_w_c, moving_mask)
            relocalised = self.relocalise(features, guided, map_tracking)
            if relocalised is not None:
                map_tracking = relocalised.tracking
                self._use_local_map(relocalised.local_map)
            clock.lap("local_map")
            if map_tracking.posed(self._config.tracking.min_inliers):
                T_w_c = inverse(map_tracking.solution.T_c_w)
                state = TrackingState.OK if relocalised is None else TrackingState.RECOVERED
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
        self._update_reference(features, T_w_c, state, guided, landmarks)
        self._state = state
        tracked = state is not TrackingState.LOST
        keyframe = self.need_new_keyframe(features, map_tracking) if tracked and map_tracking is not None else None
        rejected = guided.rejected_features(features, pose_taken=guided.tracked and state is TrackingState.OK)
        return TrackedFrame(T_w_c.copy(), T_c_p, state.status, counts, clock.laps, guided.labels, map_tracking,
                            keyframe, guided.point_dynamic, guided.line_dynamic, *rejected)

    def track_reference(
        self, features: StereoFeatures, moving_mask: np.ndarray | None = None, clock: StageClock | None = None
    ) -> ReferenceTracking:
        """Strategy "track reference": the frame with ``features`` against the reference frame, from the
        motion model's prediction, trusted as the state says (`reference_tracking`). Changes nothing."""
        return self._reference_tracker.track(self._reference, features, self._motion, self._state.motion_trusted,
                                             moving_mask, clock)

    def track_local_map(
        self, features: StereoFeatures, guided: ReferenceTracking, T_w_c: np.ndarray,
        moving_mask: np.ndarray | None = None,
    ) -> LocalMapTracking:
        """Strategy "track local map": the frame tracked against the local map from ``T_w_c`` (4, 4, camera
        to world: the reference's pose, else the prediction), with the inlier static matches of
        ``guided`` passed on (`local_map`). The static world is checked there when the detectors
        judged the frame and the guided search found it where predicted. Changes nothing."""
        return track_against_local_map(
            self._camera, inverse(T_w_c), self._local_map, features, guided.point_dynamic, guided.line_dynamic,
            self._config, self._pose_options,
            self._reference.map_matches(guided.kept, guided.solution, guided.labels, self._map),
            check_static_world=moving_mask is None and detectors_on(self._config) and guided.tracked
            and not guided.widened,
        )

    def relocalise(
        self, features: StereoFeatures, guided: ReferenceTracking, map_tracking: LocalMapTracking
    ) -> Relocalised | None:
        """Strategy "relocalise": the pose found without the prior that replaces ``map_tracking``, or None.

        The frame is posed again without the prior (`relocalisation`) when its guided pose is
        suspect: the guided search widened, the reference or the local map gave no pose, or the
        frame tracks few landmarks (`_tracks_few`); but not when the local map confirmed the pose a
        trusted motion model predicted (`_predicted`). The proposal replaces the guided pose when
        `_better_from_scratch`. Changes nothing: `track` takes the proposal (module docstring).
        """
        widened = guided.widened
        posed = map_tracking.posed(self._config.tracking.min_inliers)
        suspect = widened or not (guided.tracked and posed) or self._tracks_few(map_tracking)
        if not suspect or self._predicted(map_tracking, widened):
            return None
        candidates = candidate_local_maps(self._map, self._local_map, self._reference_keyframe.id,
                                          features.place_ggs, self._config)
        proposal = track_from_scratch(self._camera, candidates, features, guided.point_dynamic, guided.line_dynamic,
                                      self._config, self._pose_options)
        if proposal is None or not self._better_from_scratch(proposal.tracking, map_tracking, widened):
            return None
        return proposal

    def _first_frame(self, features: StereoFeatures, moving_mask: np.ndarray | None) -> TrackedFrame:
        """The first frame: the world (``T_w_c = I``) and the first keyframe. Without a motion
        nothing can be judged dynamic, but for the features on ``moving_mask`` when given."""
        if moving_mask is None:
            point_dynamic = np.zeros(len(features.keypoints), dtype=bool)
            line_dynamic = np.zeros(len(features.lines), dtype=bool)
        else:
            point_dynamic, line_dynamic = features_on_mask(features.keypoints.uv, features.lines.endpoints, moving_mask,
                                                           self._config.dynamic.mask_margin_px)
        dynamic = DynamicIndices(np.flatnonzero(point_dynamic), np.flatnonzero(line_dynamic))
        self._reference = ReferenceFrame(features, np.eye(4), dynamic)
        self._state = TrackingState.INITIALISED
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
        if widened or not self._state.motion_trusted or not map_tracking.posed(self._config.tracking.min_inliers):
            return None
        return self._motion.distance(map_tracking.solution.T_c_w, StaticWorldOptions.of(self._config))

    def _with_stereo_evidence(self, map_tracking: LocalMapTracking, features: StereoFeatures, left: np.ndarray,
                              right: np.ndarray) -> LocalMapTracking:
        """``map_tracking`` with, among its dynamic point landmarks, the missed ones the pair sees through and
        the ones found by a keypoint without a stereo match where the pair shows another depth
        (`pld_slam.tracking.see_through`)."""
        seen_through = landmarks_seen_through(self._camera, map_tracking.missed, left, right, self._see_through)
        mono = np.flatnonzero(map_tracking.point_ids >= 0)
        mono = mono[mono >= features.keypoints.n_stereo]
        ids = map_tracking.point_ids[mono]
        p_c = transform_points(map_tracking.solution.T_c_w, self._map.points.geometry[ids])
        elsewhere = landmarks_found_at_another_depth(self._camera, ids, features.keypoints.uv[mono], p_c, left, right,
                                                     self._see_through)
        return dataclasses.replace(
            map_tracking, dynamic_point_ids=np.union1d(map_tracking.dynamic_point_ids,
                                                       np.union1d(seen_through, elsewhere))
        )

    def _tracks_few(self, map_tracking: LocalMapTracking) -> bool:
        """Whether the frame tracks fewer than ``keyframes.min_tracked_ratio`` of its reference keyframe's
        landmarks: the keyframe rule's emergency, and a sign that the prior may have been wrong."""
        established = _established_landmarks(self._map, self._reference_keyframe)
        return map_tracking.tracked_landmarks < self._config.keyframes.min_tracked_ratio * established

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
        """The constant-velocity model that predicts the next frame."""
        return self._motion

    @property
    def state(self) -> TrackingState:
        """Where tracking stands after the last frame (`TrackingState`)."""
        return self._state

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

    def need_new_keyframe(self, features: StereoFeatures, map_tracking: LocalMapTracking) -> KeyframeReason | None:
        """Strategy "need new keyframe": why the frame with ``features``, tracked against the local map as
        ``map_tracking``, becomes a keyframe, or None (`pld_slam.keyframes`); counts the frame since the
        last keyframe."""
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
        self, features: StereoFeatures, T_w_c: np.ndarray, state: TrackingState, guided: ReferenceTracking,
        landmarks: LandmarkIds,
    ) -> None:
        """Record the dynamic features the frame found on the reference, age it, and renew it (the frame at
        ``T_w_c``, with its ``landmarks``, becomes the reference) as the frame's ``state`` says: when worn
        after a frame tracked normally or recovered; always after a recovered one (the reference's
        matches are not to be trusted); after a lost one, if the frame can be a reference.

        After a failure the reference is the failed frame itself (at its motion-model
        pose) if it has features enough to be tracked against (`can_be_reference`):
        tracking goes on from the newest features, which is how it recovers from a wrong
        prediction. A frame without them (blank, blinded) keeps the old reference.
        """
        counts, kept, labels = guided.counts, guided.kept, guided.labels
        inliers = counts.point_inliers + counts.line_inliers
        self._reference.record(kept, labels, inliers)
        if state is TrackingState.LOST:
            due = self.can_be_reference(features)
        else:
            due = state is TrackingState.RECOVERED or self._reference.is_worn(inliers, self._config)
        if due:
            found = DynamicIndices(kept.points.current[labels.point_dynamic], kept.lines.current[labels.line_dynamic])
            self._reference = ReferenceFrame(features, T_w_c, found, landmarks)

    def skip(self) -> TrackedFrame:
        """Advance over a frame without images (unreadable): the motion model's pose, flagged LOST.

        The reference stays, so the next frame is matched against it as usual; the state
        becomes `TrackingState.LOST` (the motion model is not trusted for the next frame), but
        before the first frame, which stays to come.
        """
        if self._state is not TrackingState.NOT_INITIALISED:
            self._state = TrackingState.LOST
        return TrackedFrame(self._motion.coast().copy(), self._motion.velocity, TrackingStatus.LOST)

    def can_be_reference(self, features: StereoFeatures) -> bool:
        """Whether a frame has the stereo points + lines for ``min_inliers`` twice over (`reference`)."""
        return can_be_reference(features, self._config)


def _established_landmarks(world_map: Map, keyframe: KeyFrame) -> int:
    """Live landmarks of ``keyframe`` that at least two keyframes observe (`pld_slam.keyframes`);
    all of them while the map holds one keyframe.

    ORB-SLAM2 counts points seen by two keyframes there too, which at its first keyframe is
    none, so its ratio rules cannot ask for the second keyframe. Counting all of them, the
    frame after the first keyframe usually tracks under ``min_tracked_ratio`` of them and
    becomes the second, whose GGS then sets the keyframe spacing of the run (the ``FEW_TRACKED``
    rule of `pld_slam.keyframes`); counted as ORB-SLAM2 does, keyframes came sparser and ATE
    was higher, for about half the mapping time (see docs/decisions/0016-keyframe-selection.md)."""
    min_observers = min(2, len(world_map.keyframes))
    count = 0
    for kind in world_map.kinds:
        ids = getattr(keyframe, kind.IDS_FIELD)
        ids = ids[kind.live(ids)]
        count += int(np.count_nonzero(kind.n_observers[ids] >= min_observers))
    return count
