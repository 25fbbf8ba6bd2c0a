"""Local mapping (paper, section "Local mapping"), run inline after each new keyframe.

`LocalMapping.insert_keyframe` runs the steps of ORB-SLAM2's ``LocalMapping::Run``, each
a method below:

1. `_process_new_keyframe`: the landmarks the keyframe tracked become its observations;
   their descriptors and viewing directions are refreshed; covisibility links updated.
2. `_cull_recent_landmarks`: a landmark created in the last keyframes dies if tracking
   finds it in fewer than ``mapping.min_found_ratio`` (25 %) of the frames that should
   see it, or if ``mapping.min_observation_age`` (2) keyframes after its creation its
   observations weigh less than ``mapping.min_observation_weight`` (4), a stereo observation
   counting 2 and a left-image-only one 1, as ORB-SLAM2 counts them: two stereo keyframes
   keep a landmark. After ``mapping.recent_landmark_keyframes`` (3) keyframes a landmark is
   no longer recent. A landmark of any age seen moving
   in ``mapping.dynamic_streak`` (2) frames since tracking last found it among the static
   features dies too (the paper: movers must not stay in the map): matched to a feature
   labelled dynamic, predicted where it is missed under a mover
   (`pld_slam.localisation.local_map.missed_near_movers`), or missed where the stereo pair
   shows a farther surface (`pld_slam.tracking.see_through`). A find within
   ``mapping.dynamic_memory`` (10) tracked frames after a frame that saw the landmark
   moving does not end its streak. A landmark of any age in view that tracking misses in
   ``mapping.max_missed_frames`` (10) frames, with no find in between, dies too: a point
   in front of the camera and inside the image, beyond its search range or not (the range
   bounds where its descriptor matches, not where it can be seen), and not hidden by a
   nearer mover (`pld_slam.localisation.local_map.missed_near_movers`); a line predicted in
   view. The paper leaves culling open; ORB-SLAM2 judges only new landmarks. We add the
   streaks because a parked car that pulls out was found static in dozens of frames
   (a streak, not a share of all sightings), a creeping car is labelled only now and
   then (the memory), and a place that now shows a flat background gives no evidence but
   the misses (docs/decisions/0003-landmark-culling.md).
3. `_create_landmarks`: the paper creates landmarks "for the new common features
   observed in the current KF and previous KF". A stereo keyframe has the depth of every
   stereo point and line already, so, as ORB-SLAM2 does for stereo, we create a landmark
   from each of its stereo points and lines that has none, except those labelled
   dynamic, those matched to the reference frame whose match the frame's pose
   rejected (keypoints without a stereo match only observe existing landmarks), and
   those whose landmark step 2 has just removed as moving: a slow mover found static
   within ``mapping.dynamic_memory`` is tracked by the keyframe, and a fresh landmark
   from its feature would start without the streak that removed the old one; step 4
   gives it the observations of the neighbours that see it too, and step 2 removes it if
   none do. A rejected match is a mismatch or a mover the detectors missed, which mapped
   at each keyframe leaves landmarks on movers; a feature the frame has no match for yet
   is mapped (docs/decisions/0004-landmark-creation.md).
4. `_search_neighbours`: the keyframe's landmarks are projected into its covisible
   keyframes (``mapping.local_ba_window`` strongest, and the
   ``mapping.fusion_second_neighbours`` (5) strongest of each) and
   theirs into it, and fused (`pld_slam.matching.fusion`: the matcher of tracking within
   the frame-to-frame descriptor bounds, and a chi-square test on the reprojection);
   a match to a feature without a landmark adds an observation, a match to a feature with
   another landmark fuses the two (the one with more observers stays).
5. Local BA (`pld_slam.mapping.local_ba`), which drops the observations it finds outliers.
   The paper runs it after each keyframe insertion; we skip it for a keyframe inserted
   fewer than ``mapping.local_ba_min_frames`` (2) frames after the keyframe of the last
   local BA (`_local_ba_due`). ORB-SLAM2 does the like by timing: a local BA is aborted,
   or never started, when keyframes come faster than it runs. A skipped keyframe keeps its
   tracked pose and is optimised by the next local BA, a frame or more later, whose window
   (the new keyframe's strongest covisible keyframes) holds it. The KITTI family file runs
   local BA at most every 3 frames over a window of 7 keyframes; the default stays at 2
   frames and 10 keyframes, which the synthetic streets need
   (docs/decisions/0005-local-ba-cadence.md).
6. `_cull_keyframes`: a covisible keyframe (never the first, nor one not yet in the spanning tree) whose landmarks are
   ``mapping.redundant_keyframe_ratio`` (90 %) observed by at least
   ``mapping.redundant_observers`` (3) other keyframes is removed (ORB-SLAM2 also asks
   that they see it at the same or a finer scale; we count observers only).

Tracking tells local mapping, frame by frame, which landmarks were visible, found, missed
in view and seen moving (`record_tracking`): the counters of step 2.
"""

from dataclasses import dataclass, field

import numpy as np

from pld_slam.config import Config
from pld_slam.geometry.camera import StereoCamera
from pld_slam.geometry.se3 import transform_points
from pld_slam.mapping.keyframe import KeyFrame
from pld_slam.mapping.landmarks import Landmarks
from pld_slam.mapping.local_ba import local_bundle_adjustment
from pld_slam.mapping.map import Map
from pld_slam.mapping.map_ba import BaReport
from pld_slam.matching.fusion import FusionOptions, fuse
from pld_slam.timing import StageClock


@dataclass(frozen=True)
class KeyframeInsertion:
    """What inserting one keyframe did.

    Attributes
    ----------
    keyframe : its id.
    created_points, created_lines : landmarks created from its stereo features.
    fused : landmarks fused into others, and observations added, by the neighbour search.
    culled_landmarks : recent landmarks culled (step 2), dynamic ones included.
    culled_keyframes : ids of the keyframes removed as redundant.
    local_ba : the local BA report (None when there was nothing to adjust, or step 5 skipped it).
    stage_ms : wall time of each step [ms].
    """

    keyframe: int
    created_points: int
    created_lines: int
    fused: int
    culled_landmarks: int
    culled_keyframes: tuple[int, ...]
    local_ba: BaReport | None
    stage_ms: dict[str, float]


@dataclass
class _Recent:
    """Ids of the landmarks created by the last keyframes, per kind (the culling of step 2)."""

    points: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    lines: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))


class LocalMapping:
    """The local mapping stage: inserts keyframes, makes and culls landmarks and keyframes, runs local BA,
    all through the map's methods (`Map` is the only writer of its data)."""

    def __init__(self, world_map: Map, camera: StereoCamera, config: Config) -> None:
        self.map = world_map
        self._camera = camera
        self._config = config
        self._fusion = FusionOptions.of(config)
        self._recent = _Recent()
        self._last_local_ba_frame: int | None = None
        """Frame index of the keyframe of the last local BA (None before the first)."""

    def record_tracking(
        self,
        visible: tuple[np.ndarray, np.ndarray],
        found: tuple[np.ndarray, np.ndarray],
        missed: tuple[np.ndarray, np.ndarray],
        dynamic: tuple[np.ndarray, np.ndarray],
    ) -> None:
        """Count one tracked frame in the landmarks' statistics (`Map.count_tracked_frame`, with
        ``mapping.dynamic_memory``): the counters of step 2."""
        self.map.count_tracked_frame(visible, found, missed, dynamic, self._config.mapping.dynamic_memory)

    def insert_keyframe(self, keyframe: KeyFrame) -> KeyframeInsertion:
        """Insert ``keyframe`` (``point_ids`` / ``line_ids`` from tracking); run the steps of the module docstring."""
        clock = StageClock()
        self._process_new_keyframe(keyframe)
        clock.lap("process")
        culled, seen_moving = self._cull_recent_landmarks(keyframe)
        clock.lap("cull_landmarks")
        created_points, created_lines = self._create_landmarks(keyframe, seen_moving)
        clock.lap("create")
        fused = self._search_neighbours(keyframe)
        clock.lap("fuse")
        local_ba = None
        if self._local_ba_due(keyframe):
            local_ba = local_bundle_adjustment(self.map, keyframe, self._camera, self._config)
            if local_ba is not None:
                self._last_local_ba_frame = keyframe.frame_index
        clock.lap("local_ba")
        culled_keyframes = self._cull_keyframes(keyframe)
        clock.lap("cull_keyframes")
        return KeyframeInsertion(
            keyframe.id, created_points, created_lines, fused, culled, culled_keyframes, local_ba, clock.laps
        )

    def _local_ba_due(self, keyframe: KeyFrame) -> bool:
        """Whether step 5 runs: ``mapping.local_ba_min_frames`` frames passed since the last local BA's keyframe."""
        last = self._last_local_ba_frame
        return last is None or keyframe.frame_index - last >= self._config.mapping.local_ba_min_frames

    def _process_new_keyframe(self, keyframe: KeyFrame) -> None:
        self.map.add_keyframe(keyframe)
        for kind in self.map.kinds:
            self._refresh(kind, getattr(keyframe, kind.IDS_FIELD))

    def _cull_recent_landmarks(self, keyframe: KeyFrame) -> tuple[int, tuple[np.ndarray, np.ndarray]]:
        """Step 2 of the module docstring; returns the landmarks removed, and which of the keyframe's
        points (P_all,) and lines (L,) bool observed one removed as moving: step 3 must not map
        them again (a fresh landmark there would start without the streak that removed the old one)."""
        config = self._config.mapping
        removed = 0
        seen_moving = []
        for kind, name in zip(self.map.kinds, ("points", "lines")):
            recent = getattr(self._recent, name)
            recent = recent[kind.alive[recent]]
            age = keyframe.id - kind.first_keyframe[recent]
            visible, found = kind.visible[recent], kind.found[recent]
            rarely_found = (visible > 0) & (found < config.min_found_ratio * visible)
            weights = self.map.observation_weights(kind, recent)
            unconfirmed = (age >= config.min_observation_age) & (weights < config.min_observation_weight)
            doomed = recent[rarely_found | unconfirmed]
            moving = np.flatnonzero(kind.alive & (kind.dynamic_streak >= config.dynamic_streak))
            seen_moving.append(np.isin(getattr(keyframe, kind.IDS_FIELD), moving))
            doomed = np.union1d(doomed, moving)
            if config.max_missed_frames > 0:
                missed = np.flatnonzero(kind.alive & (kind.missed_streak >= config.max_missed_frames))
                doomed = np.union1d(doomed, missed)
            self.map.remove_landmarks(kind, doomed)
            removed += len(doomed)
            keep = kind.alive[recent] & (age < config.recent_landmark_keyframes)
            setattr(self._recent, name, recent[keep])
        return removed, (seen_moving[0], seen_moving[1])

    def _create_landmarks(self, keyframe: KeyFrame, seen_moving: tuple[np.ndarray, np.ndarray]) -> tuple[int, int]:
        """Step 3: landmarks from the keyframe's stereo points and lines that have none and are neither
        dynamic, rejected, nor observers of a landmark step 2 removed as moving (``seen_moving``)."""
        T_w_c = keyframe.T_w_c
        features = keyframe.features
        stereo = np.arange(len(keyframe.point_ids)) < features.keypoints.n_stereo
        unmapped = (keyframe.point_ids < 0) & ~keyframe.point_dynamic & ~keyframe.point_rejected & ~seen_moving[0]
        new_points = np.flatnonzero(stereo & unmapped)
        point_ids = self.map.create_landmarks(
            self.map.points, keyframe, new_points, transform_points(T_w_c, features.points.points_c[new_points]),
            features.points.descriptors[new_points],
        )
        new_lines = np.flatnonzero(
            (keyframe.line_ids < 0) & ~keyframe.line_dynamic & ~keyframe.line_rejected & ~seen_moving[1]
        )
        endpoints_c = features.lines.endpoints_c[new_lines].reshape(-1, 3)
        line_ids = self.map.create_landmarks(
            self.map.lines, keyframe, new_lines, transform_points(T_w_c, endpoints_c).reshape(-1, 2, 3),
            features.lines.descriptors[new_lines],
        )
        self._refresh(self.map.points, point_ids)
        self._refresh(self.map.lines, line_ids)
        self._recent.points = np.concatenate([self._recent.points, point_ids])
        self._recent.lines = np.concatenate([self._recent.lines, line_ids])
        return len(point_ids), len(line_ids)

    def _search_neighbours(self, keyframe: KeyFrame) -> int:
        """Step 4: fuse the keyframe's landmarks with its neighbours' both ways; returns observations added or fused."""
        targets = self._neighbour_targets(keyframe)
        changes = 0
        for kind in self.map.kinds:
            own = kind.live_ids(getattr(keyframe, kind.IDS_FIELD))
            changes += fuse(self.map, kind, targets, own, self._camera, self._fusion)
            theirs = np.setdiff1d(kind.observed_by(targets), own)
            changes += fuse(self.map, kind, [keyframe], theirs, self._camera, self._fusion)
            self._refresh(kind, kind.live_ids(getattr(keyframe, kind.IDS_FIELD)))
        for touched in (keyframe, *targets):
            self.map.attach_to_tree(touched)
        return changes

    def _neighbour_targets(self, keyframe: KeyFrame) -> list[KeyFrame]:
        """The covisible keyframes searched by step 4, strongest first, without repeats."""
        covisibility = self.map.covisibility
        first = covisibility.neighbours(keyframe.id, limit=self._config.mapping.local_ba_window)
        chosen = list(first)
        for neighbour in first:
            for second in covisibility.neighbours(neighbour, limit=self._config.mapping.fusion_second_neighbours):
                if second != keyframe.id and second not in chosen:
                    chosen.append(second)
        return [self.map.keyframes[k] for k in chosen]

    def _cull_keyframes(self, keyframe: KeyFrame) -> tuple[int, ...]:
        """Step 6: remove covisible keyframes whose landmarks other keyframes see enough."""
        config = self._config.mapping
        culled = []
        for candidate_id in self.map.covisibility.neighbours(keyframe.id):
            if self.map.covisibility.parent[candidate_id] is None:  # the root, or not in the tree yet
                continue
            candidate = self.map.keyframes[candidate_id]
            observed = redundant = 0
            for kind in self.map.kinds:
                ids = kind.live_ids(getattr(candidate, kind.IDS_FIELD))
                observed += len(ids)
                redundant += int(np.count_nonzero(kind.n_observers[ids] - 1 >= config.redundant_observers))
            if observed and redundant >= config.redundant_keyframe_ratio * observed:
                self.map.remove_keyframe(candidate)
                culled.append(candidate_id)
        return tuple(culled)

    def _refresh(self, kind: Landmarks, ids: np.ndarray) -> None:
        self.map.refresh_landmarks(kind, kind.live_ids(ids), self._config.points.scale_factor)
