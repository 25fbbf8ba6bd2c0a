"""`LoopClosing`: detect, verify and correct loops, one new keyframe at a time (ORB-SLAM2's
``LoopClosing::Run``, inline after local mapping).

For each new keyframe: its candidates from the configured detector (``loop.detector``:
`pld_slam.loop.ggs_detector`, the paper's, or `pld_slam.loop.bow_detector`, the
bag-of-words rival), each that passed its detector's consistency test verified
(`pld_slam.loop.verify`: geometric check, drift gate, lc_rat), at most ``loop.candidates``,
until one passes (bag of words with ``loop.bow_covisible_check``: the others too, after
them, confirmed by the keyframe's covisible keyframes, `pld_slam.loop.bow_detector`
step 5); then the loop is corrected:

1. The current keyframe takes the pose the geometric check found in the candidate's map,
   and its covisible neighbours move with it, rigidly (ORB-SLAM2's corrected Sim(3)s; SE(3)
   here), with the landmarks whose reference keyframe (step 4) is among them. ORB-SLAM2
   moves every map point the group observes and records which keyframe corrected it
   (``mnCorrectedReference``) so that step 4 does not move it again; we move only the
   landmarks the group is the reference of, which needs no record: a landmark referenced
   outside the group (on the loop side, or a current-side keyframe too little covisible to
   be in the group) stays, and step 4 moves it once, with its reference keyframe (moved
   in step 1 as well, it was corrected twice). Only neighbours from the current side move
   (ids after the candidate's plus ``loop.exclude_recent_keyframes``): near the end of a
   loop, tracking may already have linked the current keyframe to a few keyframes of the
   loop's start, and moving those with it moved the first keyframe, and the start of the
   trajectory, by the whole correction (see docs/decisions/0021-loop-correction.md).
2. Fusion: each inlier of the check makes the current keyframe's feature observe the
   candidate's landmark (fused with the one it observed, if any), and the landmarks of the
   candidate's local map are projected into the moved keyframes and fused (ORB-SLAM2's
   ``SearchAndFuse``; `pld_slam.matching.fusion`, as local mapping fuses). The two ends
   of the loop now share landmarks.
3. Pose graph (`pld_slam.loop.pose_graph`) over every keyframe: the essential graph as it
   was before the correction, measured with the poses before it, plus every loop edge
   closed so far.
4. Every landmark moves with its reference keyframe (the keyframe that created it, or its
   first observer when that one was culled), as ORB-SLAM2 corrects map points, its mean
   viewing direction turning with it; the group's landmarks are then refreshed (normal,
   descriptor, distance: fusion gave them observations from the other end), as ORB-SLAM2's
   ``Replace`` and ``UpdateNormalAndDepth`` do. Frames follow their reference keyframes
   through their relative storage (`pld_slam.system`).

The loop keyframes are not protected from culling (ORB-SLAM2 protects them); a loop edge
whose keyframe was culled is dropped from later graphs.
"""

import time
from collections.abc import Container
from dataclasses import dataclass

import numpy as np

from pld_slam.config import Config
from pld_slam.errors import ConfigError
from pld_slam.geometry.camera import StereoCamera
from pld_slam.geometry.se3 import inverse, motion_size
from pld_slam.loop.bow_detector import BowDetector
from pld_slam.loop.detection import Detection, LoopDetector
from pld_slam.loop.ggs_detector import GgsDetector
from pld_slam.loop.pose_graph import (
    PoseGraph,
    PoseGraphResult,
    essential_edges,
    optimize_pose_graph,
    relative_poses,
)
from pld_slam.loop.verify import (
    GeometricCheck,
    covisible_support,
    geometric_check,
    lc_rat,
    path_length,
    plausible_drift,
    relative_motion,
    same_place,
)
from pld_slam.loop.vocabulary import Vocabulary
from pld_slam.mapping.keyframe import KeyFrame
from pld_slam.mapping.landmarks import Landmarks
from pld_slam.mapping.map import Map
from pld_slam.matching.fusion import FusionOptions, fuse
from pld_slam.optim.pose_only import PoseOnlyOptions


@dataclass(frozen=True)
class LoopCandidate:
    """One candidate of one keyframe and what verification made of it.

    Attributes
    ----------
    keyframe, frame, time : the query keyframe's id, frame index and timestamp [s].
    candidate, candidate_frame, candidate_time : the candidate's.
    score, bar, previous_distance, neighbour_distance, consistency : the detector's
        (`pld_slam.loop.detection.Detection`).
    matches, inliers, inlier_ratio, motion, lc_rat : the geometric check and stage 1 (NaN
        where not reached).
    correction_m, correction_deg : the correction the loop would make to the keyframe.
    covisible : bow candidates not consistent in time (``loop.bow_covisible_check``): the
        covisible keyframes that confirmed the check's pose (`pld_slam.loop.verify.covisible_support`);
        NaN where not reached.
    accepted : whether the loop was closed with it.
    reason : ``"accepted"``, the test it failed (``"consistency"``, the detector's; ``"pnp"``: fewer
        than ``loop.min_inliers`` descriptor matches or no PnP pose; ``"inliers"``, ``"drift"``,
        ``"distance"``, ``"lc_rat"``, ``"covisible"``), or ``"not verified"`` (``loop.candidates``
        others were verified first).
    """

    keyframe: int
    frame: int
    time: float
    candidate: int
    candidate_frame: int
    candidate_time: float
    score: float
    bar: float
    previous_distance: float
    neighbour_distance: float
    consistency: float
    matches: float
    inliers: float
    inlier_ratio: float
    motion: float
    lc_rat: float
    correction_m: float
    correction_deg: float
    covisible: float
    accepted: bool
    reason: str


@dataclass(frozen=True)
class ClosedLoop:
    """A corrected loop: its keyframes and frames, the correction of the current keyframe
    (translation [m], rotation [deg]), landmark observations fused, pose-graph edges and solve,
    and the whole correction's wall time [ms]."""

    keyframe: int
    candidate: int
    frame: int
    candidate_frame: int
    correction_m: float
    correction_deg: float
    fused: int
    graph_edges: int
    pose_graph: PoseGraphResult
    ms: float


@dataclass(frozen=True)
class _LoopEdge:
    """A closed loop's edge: keyframe ids and the measured pose ``T_i_j`` (4, 4) of j in i."""

    i: int
    j: int
    T_i_j: np.ndarray


class LoopClosing:
    """Loop detection and correction over the map (module docstring)."""

    def __init__(self, world_map: Map, camera: StereoCamera, config: Config) -> None:
        self.map = world_map
        self.detector = make_detector(world_map, config)
        self._camera = camera
        self._config = config
        self._fusion = FusionOptions.of(config)
        self._pose_options = PoseOnlyOptions.of(config)
        self._loop_edges: list[_LoopEdge] = []
        self.candidates: list[LoopCandidate] = []
        """Every candidate verified so far."""
        self.loops: list[ClosedLoop] = []
        """Every loop closed so far."""
        self.queries: list[tuple[int, float]] = []
        """Every keyframe looked up for a loop: id and timestamp [s]."""

    def process(self, keyframe: KeyFrame) -> ClosedLoop | None:
        """Look for a loop of ``keyframe`` (just inserted, after local mapping) and close the first verified one."""
        self.queries.append((keyframe.id, keyframe.timestamp))
        closed = None
        verified = 0
        detections = self.detector.detect(keyframe)
        if self._checks_covisible:  # consistent in time first: they need no more evidence
            detections = sorted(detections, key=lambda d: not d.consistent)
        for detection in detections:
            candidate = self.map.keyframes[detection.candidate]
            verify = closed is None and self._verifiable(detection) and verified < self._config.loop.candidates
            verified += verify
            record, check = self._verify(keyframe, candidate, detection, verify)
            self.candidates.append(record)
            if check is not None:
                closed = self._close(keyframe, candidate, check)
                self.loops.append(closed)
        return closed

    @property
    def _checks_covisible(self) -> bool:
        """Whether candidates not yet consistent in time are verified too (bag of words with
        ``loop.bow_covisible_check``, `pld_slam.loop.bow_detector` step 5)."""
        return self._config.loop.detector == "bow" and self._config.loop.bow_covisible_check

    def _verifiable(self, detection: Detection) -> bool:
        """Whether ``detection`` may be verified: it passed its detector's consistency test, or
        the covisible keyframes will be asked instead (`_checks_covisible`)."""
        return detection.consistent or self._checks_covisible

    def _verify(
        self, keyframe: KeyFrame, candidate: KeyFrame, detection: Detection, verify: bool
    ) -> tuple[LoopCandidate, GeometricCheck | None]:
        """The candidate's record, and its geometric check when it was verified and passed every test."""
        config = self._config.loop
        values = dict(matches=np.nan, inliers=np.nan, inlier_ratio=np.nan, motion=np.nan, lc_rat=np.nan,
                      correction_m=np.nan, correction_deg=np.nan, covisible=np.nan)
        check, reason = None, "not verified" if self._verifiable(detection) else "consistency"
        if verify:
            check = geometric_check(self.map, keyframe, candidate, self._camera, self._config, self._pose_options)
            reason = "pnp"
        if check is not None:
            motion = relative_motion(check.T_c_w, candidate.T_c_w)
            score = lc_rat(check.inlier_ratio, motion, config)
            values |= dict(matches=check.matches, inliers=check.inliers, inlier_ratio=check.inlier_ratio,
                           motion=motion, lc_rat=score)
            correction = check.T_c_w @ keyframe.T_w_c
            drift = plausible_drift(correction, path_length(self.map, candidate.id, keyframe.id), config)
            values["correction_m"], values["correction_deg"] = motion_size(correction)
            if check.inliers < config.min_inliers:
                reason = "inliers"
            elif not drift:
                reason = "drift"
            elif not same_place(check.T_c_w, candidate.T_c_w, config):
                reason = "distance"
            elif score < config.lc_rat_threshold:
                reason = "lc_rat"
            elif detection.consistent:
                reason = "accepted"
            else:
                values["covisible"] = float(covisible_support(self.map, keyframe, candidate, check, self._camera,
                                                              self._config, self._pose_options,
                                                              config.bow_consistency))
                reason = "accepted" if values["covisible"] >= config.bow_consistency else "covisible"
        record = LoopCandidate(
            keyframe=keyframe.id, frame=keyframe.frame_index, time=keyframe.timestamp, candidate=candidate.id,
            candidate_frame=candidate.frame_index, candidate_time=candidate.timestamp, score=detection.score,
            bar=detection.bar,
            previous_distance=detection.previous_distance, neighbour_distance=detection.neighbour_distance,
            consistency=detection.consistency, accepted=reason == "accepted", reason=reason, **values,
        )
        return record, check if record.accepted else None

    def _close(self, keyframe: KeyFrame, candidate: KeyFrame, check: GeometricCheck) -> ClosedLoop:
        """Correct the loop ``keyframe`` -> ``candidate`` found by ``check`` (module docstring)."""
        start = time.perf_counter()
        before = {k: frame.T_c_w.copy() for k, frame in self.map.keyframes.items()}
        edges = essential_edges(self.map, self._config.loop.pose_graph_min_shared_ratio)
        correction_m, correction_deg = motion_size(check.T_c_w @ keyframe.T_w_c)
        group = [keyframe.id, *(k for k in self.map.covisibility.neighbours(keyframe.id)
                                if k > candidate.id + self._config.loop.exclude_recent_keyframes)]
        self._move_rigidly(group, inverse(check.T_c_w) @ keyframe.T_c_w)
        fused = self._fuse(keyframe, check, group)
        self._loop_edges.append(_LoopEdge(keyframe.id, candidate.id, keyframe.T_c_w @ candidate.T_w_c))
        graph_result, n_edges = self._optimise(edges, before)
        for kind in self.map.kinds:
            group_landmarks = kind.observed_by(self.map.keyframes[k] for k in group)
            self.map.refresh_landmarks(kind, group_landmarks, self._config.points.scale_factor)
        return ClosedLoop(
            keyframe=keyframe.id, candidate=candidate.id, frame=keyframe.frame_index,
            candidate_frame=candidate.frame_index, correction_m=correction_m, correction_deg=correction_deg,
            fused=fused, graph_edges=n_edges, pose_graph=graph_result, ms=1e3 * (time.perf_counter() - start),
        )

    def _move_rigidly(self, group: list[int], world_motion: np.ndarray) -> None:
        """Step 1: move the keyframes ``group`` (ids) and the landmarks they are the reference of by
        one rigid motion of the world, ``world_motion`` (4, 4) ``T_w_new_w_old``; the keyframes keep
        their relative poses."""
        for kind in self.map.kinds:
            observed = kind.observed_by(self.map.keyframes[k] for k in group)
            references = [_reference_keyframe(kind, landmark, self.map.keyframes) for landmark in observed.tolist()]
            self.map.move_landmarks(kind, observed[np.isin(references, group)], world_motion)
        moved = np.array([self.map.keyframes[keyframe_id].T_c_w @ inverse(world_motion) for keyframe_id in group])
        self.map.set_keyframe_poses(np.array(group, dtype=np.int64), moved.reshape(-1, 4, 4))

    def _fuse(self, keyframe: KeyFrame, check: GeometricCheck, group: list[int]) -> int:
        """Step 2: join the two ends of the loop; returns the observations added or fused.

        The landmarks projected are those of the check's local map, taken before the inliers
        are fused: taken after, the keyframe is covisible with the candidate's neighbourhood,
        and none would be left to project.
        """
        found = check.tracking
        fused = 0
        for kind, loop_ids in zip(self.map.kinds, (found.point_ids, found.line_ids)):
            features = np.flatnonzero(loop_ids >= 0)
            fused += self.map.observe_or_fuse(kind, keyframe, features, loop_ids[features], keep_matched=True)
        for kind, ids in zip(self.map.kinds, (check.local_map.points.ids, check.local_map.lines.ids)):
            fused += fuse(self.map, kind, [self.map.keyframes[keyframe_id] for keyframe_id in group], ids,
                          self._camera, self._fusion)
        for keyframe_id in group:
            self.map.attach_to_tree(self.map.keyframes[keyframe_id])
        return fused

    def _optimise(self, edges: np.ndarray, before: dict[int, np.ndarray]) -> tuple[PoseGraphResult, int]:
        """Steps 3 and 4: the pose graph, then every landmark with its reference keyframe."""
        ids = np.array(sorted(self.map.keyframes), dtype=np.int64)
        live = np.isin(edges, ids).all(axis=1)
        edges = edges[live]
        node = {k: n for n, k in enumerate(ids.tolist())}
        old_poses = np.array([before[k] for k in ids.tolist()])
        loops = [edge for edge in self._loop_edges if edge.i in node and edge.j in node]
        loop_ends = np.array([(edge.i, edge.j) for edge in loops], dtype=np.int64).reshape(-1, 2)
        edge_i, edge_j = np.searchsorted(ids, np.concatenate([edges, loop_ends])).T
        measured = np.concatenate([
            relative_poses(old_poses, edge_i[: len(edges)], edge_j[: len(edges)]),
            np.array([edge.T_i_j for edge in loops]).reshape(-1, 4, 4),
        ])
        T_c_w = np.array([self.map.keyframes[k].T_c_w for k in ids.tolist()])
        graph = PoseGraph(T_c_w=T_c_w, fixed=ids == ids.min(), edge_i=edge_i, edge_j=edge_j, T_i_j=measured)
        result = optimize_pose_graph(graph, self._config.loop.pose_graph_max_nfev)
        self._move_landmarks_with_keyframes(ids, T_c_w, result.T_c_w)
        self.map.set_keyframe_poses(ids, result.T_c_w)
        return result, len(edge_i)

    def _move_landmarks_with_keyframes(self, ids: np.ndarray, old: np.ndarray, new: np.ndarray) -> None:
        """Step 4: each live landmark keeps its place in its reference keyframe's camera frame."""
        motion = inverse(new) @ old  # per keyframe, T_w_new_w_old
        row = {k: n for n, k in enumerate(ids.tolist())}
        for kind in self.map.kinds:
            landmarks = np.flatnonzero(kind.alive)
            references = np.array([row[_reference_keyframe(kind, landmark, row)] for landmark in landmarks.tolist()],
                                  dtype=np.int64)
            for reference in np.unique(references).tolist():
                at = landmarks[references == reference]
                self.map.move_landmarks(kind, at, motion[reference])


def make_detector(world_map: Map, config: Config) -> LoopDetector:
    """The detector ``loop.detector`` names; bag of words reads the vocabulary ``loop.vocabulary``."""
    if config.loop.detector != "bow":
        return GgsDetector(world_map, config.loop)
    check_vocabulary_given(config)
    return BowDetector(world_map, Vocabulary.load(config.loop.vocabulary), config.loop)


def check_vocabulary_given(config: Config) -> None:
    """Raise `ConfigError` saying how to build a vocabulary when the bow detector has none."""
    if config.loop.detector == "bow" and not config.loop.vocabulary:
        raise ConfigError(
            "loop.detector: bow needs a vocabulary: build one with `pld-slam vocabulary build IMAGE_DIR... "
            "--out vocab.npz`, then pass --set loop.vocabulary=vocab.npz"
        )


def _reference_keyframe(kind: Landmarks, landmark: int, live: Container[int]) -> int:
    """Id of a landmark's reference keyframe: its creator if among the ``live`` keyframe ids, else its first
    observer."""
    creator = int(kind.first_keyframe[landmark])
    return creator if creator in live else next(iter(kind.observers[landmark]))
