"""`Map`: keyframes, map points and lines, their observations, and the covisibility graph.

The map is the only writer of its data: keyframe poses, landmark columns (read-only
views everywhere else, `pld_slam.mapping.landmarks.Landmarks.writable`) and observations
change through its methods, which local mapping, loop closing, the BA write-back and
tracking's frame counts call; `tests/test_map_writes.py` holds every other module to that.
Tracking reads it through `pld_slam.localisation.local_map`. Observations change through a few
methods that keep the two copies of an observation in step (a keyframe's landmark id per
feature, a landmark's ``{keyframe: feature}``, see `pld_slam.mapping.landmarks`), the
observer counts, and the covisibility links: each observation added or removed changes
the keyframe's link to every other observer of the landmark by one, so the links always
count the landmarks two keyframes share (ORB-SLAM2 recounts them only at some steps), and
are never recounted: local mapping recounted them after every fusion, 8 of fusion's 40 ms per
KITTI 06 keyframe (5 ms per frame), and the recount, checked at each of its 415 calls on
KITTI 06 and 544 on raw 0005, never differed from them.
`attach_to_tree` gives a keyframe its spanning-tree parent once it has links.

A landmark left without observers dies (``alive`` False). A culled keyframe leaves its
pose relative to its spanning-tree parent behind (`culled_keyframe_pose`), so that frames
whose poses were stored relative to it still follow every later correction of the map.
"""

from itertools import chain

import numpy as np

from pld_slam.frontend.descriptors import hamming_distances
from pld_slam.frontend.ggs import GgsDatabase
from pld_slam.geometry.se3 import inverse, transform_points
from pld_slam.mapping.covisibility import CovisibilityGraph
from pld_slam.mapping.keyframe import KeyFrame
from pld_slam.mapping.landmarks import Landmarks, LineLandmarks, PointLandmarks
from pld_slam.trajectory import Trajectory


class Map:
    """The SLAM map (module docstring)."""

    def __init__(self, covisibility_min_shared: int) -> None:
        self.keyframes: dict[int, KeyFrame] = {}
        """Live keyframes by id, in insertion order."""
        self.points = PointLandmarks()
        self.lines = LineLandmarks()
        self.covisibility = CovisibilityGraph(covisibility_min_shared)
        self.ggs = GgsDatabase()
        """The place GGS (`KeyFrame.place_ggs`) of the live keyframes that have one (relocalisation and loop
        detection query it)."""
        self._next_keyframe_id = 0
        self._culled: dict[int, tuple[int, np.ndarray]] = {}
        """Culled keyframe id -> (its parent's id, ``T_c_p`` from the parent camera to it)."""
        self._tracked_frames = 0
        """Frames `count_tracked_frame` counted (the clock of ``Landmarks.moving_frame``)."""

    @property
    def kinds(self) -> tuple[Landmarks, Landmarks]:
        """The two landmark kinds, points then lines."""
        return self.points, self.lines

    def next_keyframe_id(self) -> int:
        """The id the next keyframe gets (ids increase in insertion order)."""
        return self._next_keyframe_id

    def add_keyframe(self, keyframe: KeyFrame) -> None:
        """Insert a keyframe; the live landmarks its ``point_ids`` / ``line_ids`` name become its observations.

        Ids naming a dead landmark, or a landmark another feature of the keyframe already
        observes, are cleared to -1. Links are updated.
        """
        if keyframe.id != self._next_keyframe_id:
            raise ValueError(f"keyframe id {keyframe.id}, expected {self._next_keyframe_id}")
        self._next_keyframe_id += 1
        self.keyframes[keyframe.id] = keyframe
        self.covisibility.add_keyframe(keyframe.id)
        if keyframe.place_ggs is not None:
            self.ggs.add(keyframe.id, keyframe.place_ggs)
        for kind in self.kinds:
            ids = getattr(keyframe, kind.IDS_FIELD)
            features = np.flatnonzero(ids >= 0)
            landmarks = ids[features]
            ids[:] = -1
            self.add_observations(kind, keyframe, features, landmarks)
        self.attach_to_tree(keyframe)

    def add_observations(
        self, kind: Landmarks, keyframe: KeyFrame, features: np.ndarray, landmarks: np.ndarray
    ) -> None:
        """``keyframe``'s features (K,) observe ``landmarks`` (K,) of ``kind``.

        Skipped: dead landmarks, features that already observe a landmark, and landmarks
        the keyframe already observes through another feature (the first one kept).
        """
        ids = getattr(keyframe, kind.IDS_FIELD)
        keep = kind.live(landmarks)
        for feature, landmark in zip(features[keep].tolist(), landmarks[keep].tolist()):
            observers = kind.observers[landmark]
            if ids[feature] >= 0 or keyframe.id in observers:
                continue
            self.covisibility.change_shared(keyframe.id, observers.keys(), +1)
            observers[keyframe.id] = feature
            ids[feature] = landmark
            kind.writable("n_observers")[landmark] += 1

    def erase_observations(self, kind: Landmarks, keyframe: KeyFrame, features: np.ndarray) -> None:
        """``keyframe``'s features (K,) no longer observe their landmarks; a landmark left unobserved dies."""
        ids = getattr(keyframe, kind.IDS_FIELD)
        for feature in features.tolist():
            landmark = int(ids[feature])
            if landmark < 0:
                continue
            ids[feature] = -1
            observers = kind.observers[landmark]
            del observers[keyframe.id]
            self.covisibility.change_shared(keyframe.id, observers.keys(), -1)
            n_observers = kind.writable("n_observers")
            n_observers[landmark] -= 1
            if n_observers[landmark] == 0:
                kind.writable("alive")[landmark] = False

    def create_landmarks(
        self, kind: Landmarks, keyframe: KeyFrame, features: np.ndarray, geometry_w: np.ndarray, descriptors: np.ndarray
    ) -> np.ndarray:
        """New landmarks (K,) at ``geometry_w`` observed by ``keyframe``'s features (K,); returns their ids."""
        ids = kind.add(geometry_w, descriptors, keyframe.id)
        self.add_observations(kind, keyframe, features, ids)
        return ids

    def remove_landmarks(self, kind: Landmarks, landmarks: np.ndarray) -> None:
        """Remove landmarks (K,) and every observation of them."""
        for landmark in landmarks.tolist():
            observers = kind.observers[landmark]
            for keyframe, feature in observers.items():
                getattr(self.keyframes[keyframe], kind.IDS_FIELD)[feature] = -1
            self.covisibility.unlink_all(list(observers))
            kind.observers[landmark] = {}
            kind.writable("n_observers")[landmark] = 0
            kind.writable("alive")[landmark] = False

    def replace_landmark(self, kind: Landmarks, old: int, new: int) -> None:
        """Fuse landmark ``old`` into ``new``: its observations move to ``new``, then it dies.

        A keyframe observing both keeps its observation of ``new``. Found and visible
        counts add up, as in ORB-SLAM2's ``Replace``; the dynamic streak is the longer of
        the two (the fused landmark is as suspect as the more suspect of them).
        """
        if old == new:
            return
        old_observers = list(kind.observers[old].items())
        self.covisibility.unlink_all([keyframe_id for keyframe_id, _ in old_observers])
        for keyframe_id, feature in old_observers:
            keyframe = self.keyframes[keyframe_id]
            getattr(keyframe, kind.IDS_FIELD)[feature] = -1
            if keyframe_id not in kind.observers[new]:
                self.covisibility.change_shared(keyframe_id, kind.observers[new].keys(), +1)
                kind.observers[new][keyframe_id] = feature
                getattr(keyframe, kind.IDS_FIELD)[feature] = new
                kind.writable("n_observers")[new] += 1
        for name in ("found", "visible"):
            kind.writable(name)[new] += kind.writable(name)[old]
        for name in ("dynamic_streak", "moving_frame"):
            kind.writable(name)[new] = max(kind.writable(name)[new], kind.writable(name)[old])
        kind.observers[old] = {}
        kind.writable("n_observers")[old] = 0
        kind.writable("alive")[old] = False

    def observe_or_fuse(
        self, kind: Landmarks, keyframe: KeyFrame, features: np.ndarray, landmarks: np.ndarray, keep_matched: bool
    ) -> int:
        """Make each feature (K,) of ``keyframe`` observe its matched landmark (K,); returns the changes made.

        A feature without a live landmark observes the matched one; a feature with another
        landmark fuses the two: the matched one survives with ``keep_matched`` (loop
        closing: the old map's landmark), else the one with more observers (local
        mapping). Skipped: features labelled dynamic, dead landmarks, and landmarks the
        keyframe already observes.
        """
        dynamic = getattr(keyframe, kind.DYNAMIC_FIELD)
        ids = getattr(keyframe, kind.IDS_FIELD)
        changes = 0
        for feature, landmark in zip(features.tolist(), landmarks.tolist()):
            if dynamic[feature] or not kind.alive[landmark] or keyframe.id in kind.observers[landmark]:
                continue
            existing = int(ids[feature])
            if existing < 0:
                self.add_observations(kind, keyframe, np.array([feature]), np.array([landmark]))
            elif keep_matched:
                self.replace_landmark(kind, existing, landmark)
            else:
                keep, drop = sorted((existing, landmark), key=lambda i: (-kind.n_observers[i], i))
                self.replace_landmark(kind, drop, keep)
            changes += 1
        return changes

    def attach_to_tree(self, keyframe: KeyFrame) -> None:
        """Give ``keyframe`` its spanning-tree parent if it has none yet (`CovisibilityGraph.attach_to_tree`)."""
        self.covisibility.attach_to_tree(keyframe.id)

    def remove_keyframe(self, keyframe: KeyFrame) -> None:
        """Cull a keyframe: its observations go, its children re-attach, its pose stays relative to its parent.

        The root (first keyframe) is never removed.
        """
        parent = self.covisibility.parent[keyframe.id]
        if parent is None:
            raise ValueError(f"keyframe {keyframe.id} has no parent: the root cannot be removed")
        self._culled[keyframe.id] = (parent, keyframe.T_c_w @ self.keyframes[parent].T_w_c)
        for kind in self.kinds:
            ids = getattr(keyframe, kind.IDS_FIELD)
            self.erase_observations(kind, keyframe, np.flatnonzero(ids >= 0))
        self.covisibility.remove_keyframe(keyframe.id)
        if keyframe.place_ggs is not None:
            self.ggs.remove(keyframe.id)
        del self.keyframes[keyframe.id]

    def set_keyframe_poses(self, keyframe_ids: np.ndarray, T_c_w: np.ndarray) -> None:
        """Move live keyframes ``keyframe_ids`` (K,) to the world-to-camera poses ``T_c_w`` (K, 4, 4)."""
        for keyframe_id, pose in zip(np.asarray(keyframe_ids).tolist(), T_c_w):
            self.keyframes[keyframe_id].T_c_w = pose

    def set_landmark_geometry(self, kind: Landmarks, landmarks: np.ndarray, geometry_w: np.ndarray) -> None:
        """Put landmarks (K,) of ``kind`` at ``geometry_w`` (K, *kind.GEOMETRY_SHAPE) world coordinates [m].

        Their summaries (viewing direction, distance range, descriptor) stay as they are:
        refreshed after every BA, as ORB-SLAM2 does, they cost accuracy on five of seven
        sequences (`docs/decisions/0001-stereo-scale.md`, "Hypotheses measured and rejected").
        """
        kind.writable("geometry")[landmarks] = geometry_w

    def move_landmarks(self, kind: Landmarks, landmarks: np.ndarray, T_new_old: np.ndarray) -> None:
        """Apply the world motion ``T_new_old`` (4, 4) to landmarks (K,) of ``kind``: their geometry and
        their mean viewing direction (``normal``, world)."""
        if len(landmarks) == 0:
            return
        geometry = kind.geometry[landmarks]
        moved = transform_points(T_new_old, geometry.reshape(-1, 3)).reshape(geometry.shape)
        kind.writable("geometry")[landmarks] = moved
        kind.writable("normal")[landmarks] = kind.normal[landmarks] @ T_new_old[:3, :3].T

    def count_tracked_frame(
        self,
        visible: tuple[np.ndarray, np.ndarray],
        found: tuple[np.ndarray, np.ndarray],
        missed: tuple[np.ndarray, np.ndarray],
        dynamic: tuple[np.ndarray, np.ndarray],
        dynamic_memory: int,
    ) -> None:
        """Count one tracked frame in the landmarks' statistics, each argument (point ids, line ids).

        ``visible`` (within the search's bounds), ``found`` (static inliers), ``missed`` in view
        (`pld_slam.localisation.local_map.LocalMapTracking.missed_point_ids`), ``dynamic``: seen
        moving (matched to a feature labelled dynamic, lying under one, or seen through). Found
        ends the missed streak, and the dynamic one unless the landmark was seen moving in the
        last ``dynamic_memory`` tracked frames (``moving_frame`` counts frames by this clock).
        """
        self._tracked_frames += 1
        for kind, seen, matched, lost, moving in zip(self.kinds, visible, found, missed, dynamic):
            kind.writable("visible")[seen] += 1
            kind.writable("found")[matched] += 1
            missed_streak = kind.writable("missed_streak")
            missed_streak[lost] += 1
            missed_streak[matched] = 0
            cleared = matched[self._tracked_frames - kind.moving_frame[matched] > dynamic_memory]
            dynamic_streak = kind.writable("dynamic_streak")
            dynamic_streak[cleared] = 0
            dynamic_streak[moving] += 1
            kind.writable("moving_frame")[moving] = self._tracked_frames

    def keyframe_trajectory(self) -> Trajectory:
        """The poses ``T_w_c`` of the keyframes alive, by time (ORB-SLAM's ``KeyFrameTrajectory.txt``)."""
        keyframes = sorted(self.keyframes.values(), key=lambda keyframe: keyframe.timestamp)
        return Trajectory(np.array([keyframe.timestamp for keyframe in keyframes]),
                          np.array([keyframe.T_w_c for keyframe in keyframes]).reshape(-1, 4, 4))

    def keyframe_T_w_c(self, keyframe_id: int) -> np.ndarray:
        """(4, 4) pose of a keyframe, live or culled (a culled one follows its parent chain).

        ``chain`` is ``T_k_p`` from the live ancestor ``p`` reached to the keyframe ``k`` asked for.
        """
        chain = np.eye(4)
        while keyframe_id not in self.keyframes:
            keyframe_id, T_c_p = self._culled[keyframe_id]
            chain = chain @ T_c_p
        return self.keyframes[keyframe_id].T_w_c @ inverse(chain)

    def observation_table(self, kind: Landmarks, landmarks: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Every observation of ``landmarks`` (K,): landmark row in ``landmarks``, keyframe id, feature index.

        Three (M,) int64 arrays, grouped by landmark in the order of ``landmarks``, and
        within a group in the order the observations were made (the creating keyframe
        first while it observes the landmark; fusion appends the observations it moves).
        """
        observers = [kind.observers[landmark] for landmark in landmarks.tolist()]
        counts = np.fromiter(map(len, observers), dtype=np.int64, count=len(observers))
        total = int(counts.sum())
        keyframes = np.fromiter(chain.from_iterable(observers), dtype=np.int64, count=total)
        features = np.fromiter(chain.from_iterable(map(dict.values, observers)), dtype=np.int64, count=total)
        return np.repeat(np.arange(len(observers), dtype=np.int64), counts), keyframes, features

    def observation_weights(self, kind: Landmarks, landmarks: np.ndarray) -> np.ndarray:
        """Weight (K,) of the observations of ``landmarks`` (K,): 2 per stereo observation, 1 per left-image-only one.

        Lines are stereo; a point observation is stereo when its keypoint has a stereo
        match (it is among the keyframe's first ``n_stereo`` keypoints).
        """
        rows, keyframes, features = self.observation_table(kind, landmarks)
        if isinstance(kind, PointLandmarks):
            n_stereo = np.array([self.keyframes[k].features.keypoints.n_stereo for k in keyframes.tolist()], dtype=int)
            weight = np.where(features < n_stereo, 2, 1)
        else:
            weight = np.full(len(rows), 2)
        return np.bincount(rows, weights=weight, minlength=len(landmarks)).astype(np.int64)

    def refresh_landmarks(self, kind: Landmarks, landmarks: np.ndarray, scale_factor: float) -> None:
        """Recompute the summaries of landmarks (K,) from their observations (ORB-SLAM2's
        ``ComputeDistinctiveDescriptors`` and ``UpdateNormalAndDepth``).

        ``normal``: the mean unit direction from the observing cameras; ``descriptor``: the
        representative one (`representative_descriptors`); for points, ``max_distance``:
        the distance from the earliest observer (`observation_table`) times
        ``scale_factor**octave`` of its observation (ORB-SLAM2 uses the creating keyframe,
        `pld_slam.mapping.landmarks.PointLandmarks`).
        """
        landmarks = landmarks[kind.n_observers[landmarks] > 0]
        if len(landmarks) == 0:
            return
        rows, keyframes, features = self.observation_table(kind, landmarks)
        observers, observer_of = np.unique(keyframes, return_inverse=True)
        centres = np.array([self.keyframes[k].centre for k in observers.tolist()]).reshape(-1, 3)
        rays = kind.centres(landmarks)[rows] - centres[observer_of]
        distance = np.linalg.norm(rays, axis=1)
        normal = np.zeros((len(landmarks), 3))
        np.add.at(normal, rows, rays / np.maximum(distance, 1e-12)[:, None])
        kind.writable("normal")[landmarks] = normal / np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-12)
        descriptors = self.feature_attribute(kind, "descriptors", keyframes, features)
        kind.writable("descriptor")[landmarks] = representative_descriptors(rows, descriptors, len(landmarks))
        if isinstance(kind, PointLandmarks):
            first = np.flatnonzero(np.diff(rows, prepend=-1))
            octave = self.feature_attribute(kind, "octave", keyframes[first], features[first])
            kind.writable("max_distance")[landmarks] = distance[first] * scale_factor ** octave.astype(np.float64)

    def feature_attribute(
        self, kind: Landmarks, attribute: str, keyframes: np.ndarray, features: np.ndarray
    ) -> np.ndarray:
        """An attribute (``descriptors``, ``octave``, ...) of features (M,) of keyframes (M,) of ``kind``: (M, ...)."""
        def of(keyframe_id: int) -> np.ndarray:
            return getattr(getattr(self.keyframes[keyframe_id].features, kind.FEATURES_FIELD), attribute)

        sample = of(int(keyframes[0]) if len(keyframes) else next(iter(self.keyframes)))
        values = np.empty((len(features), *sample.shape[1:]), dtype=sample.dtype)
        for keyframe_id in np.unique(keyframes).tolist():
            at = keyframes == keyframe_id
            values[at] = of(keyframe_id)[features[at]]
        return values


def representative_descriptors(rows: np.ndarray, descriptors: np.ndarray, n_groups: int) -> np.ndarray:
    """Per group, the descriptor whose median Hamming distance to the group's others is smallest.

    Parameters
    ----------
    rows : (M,) int64 group of each descriptor, grouped (equal rows contiguous), 0..n_groups-1.
    descriptors : (M, 32) uint8.
    n_groups : number of groups; each must hold at least one descriptor.

    Returns
    -------
    (n_groups, 32) uint8. ORB-SLAM2's ``ComputeDistinctiveDescriptors``: the lower median,
    ties to the first listed.
    """
    sizes = np.bincount(rows, minlength=n_groups)
    starts = np.cumsum(sizes) - sizes
    per_member = sizes[rows]
    member = np.repeat(np.arange(len(rows)), per_member)
    offset = np.arange(len(member)) - np.repeat(np.cumsum(per_member) - per_member, per_member)
    other = starts[rows[member]] + offset
    distance = hamming_distances(descriptors[member], descriptors[other])
    order = np.lexsort((distance, member))
    block_start = np.cumsum(per_member) - per_member
    median = distance[order][block_start + (per_member - 1) // 2]
    best = np.lexsort((np.arange(len(rows)), median, rows))
    first_of_group = best[starts[np.arange(n_groups)]]
    return descriptors[first_of_group]
