"""Tracking the local map: project its landmarks into the frame, match them, solve the pose.

After the frame's first pose (against the reference frame, `pld_slam.tracking.tracker`),
the paper measures it against the local map; we follow ORB-SLAM2's ``TrackLocalMap``.

Local map. The reference keyframe (the last one inserted), then its covisible keyframes,
strongest first, then theirs, up to ``mapping.tracking_keyframes``; the local map is the
live landmarks they observe (`gather_local_map`). It changes only when local mapping
changes the map, so the tracker keeps one snapshot per keyframe.

Search. The local map's landmarks are projected into the frame and matched there
(`pld_slam.matching.projection`: which count as visible, the windows, the candidates);
its points within ``mapping.max_point_distance`` bits of Hamming distance and passing the
ratio test ``mapping.ratio``. These are ORB-SLAM2's for tracking its local map (100 bits,
ratio 0.8), where frame-to-frame matching allows 64 bits and 0.9
(``tracking.max_point_distance``, ``tracking.ratio``): a map point's descriptor was taken
at a keyframe, from farther away than the last frame, so the right match lies farther in
Hamming distance, and the stricter ratio pays for the looser bound: the frame-to-frame
pair tracked fewer map points, and 100 bits with the 0.9 ratio kept a convoy's landmarks
alive (`tests/test_dynamic_scenes.py`; see docs/decisions/0019-local-map-tracking.md).
Fusion searches within the frame-to-frame bound and ratio (`pld_slam.matching.fusion`).

Frame-to-frame points. The pose is solved over the map matches and, as ORB-SLAM2's stereo
tracking does with its temporary "visual odometry" points, over the reference frame's
matches whose current feature found no map point (`ReferenceMatches`, expressed in the
world frame through the reference pose). Near points change appearance fastest and are
found again in the map least; without these matches a frame's translation rested on
far map points only and drifted between keyframes (see docs/decisions/0019-local-map-tracking.md).

Landmarks passed on. A reference feature that observes a landmark (the reference is a
keyframe, or a frame that tracked the map) passes it on through its frame-to-frame match,
as ORB-SLAM2 tracks the last frame's map points: the current feature observes that
landmark, whatever the search of the local map found for it. The frame-to-frame match is
made at a close viewpoint, against the reference's own descriptor, so it keeps finding a
landmark after its map descriptor, seen from the keyframes, has stopped matching. Without
it, landmarks were found again too rarely for keyframes a few frames apart to share
them, and local BA moved the keyframes away from good tracked poses (see
docs/decisions/0019-local-map-tracking.md). Each landmark and each feature enters the
solve once, the landmark passed on first; the solve's chi-square test then drops a
landmark whose association went wrong.

Dynamic features. A feature labelled dynamic (by the detectors, on the reference-frame
matches) is matched like any other but never enters the pose: the landmark it matched is
reported (``dynamic_point_ids``) so that local mapping can remove landmarks that keep
landing on movers, and tracking never re-admits them. So is a point landmark missed
where a mover now stands at its depth (`missed_near_movers`): a parked car that pulls
out takes its corners along. (The tracker adds the missed points its stereo pair sees
through, `pld_slam.tracking.see_through`.) A mover that entered the map before
the detectors caught it (the first keyframe has no labels; a parked car that pulls out)
can still pull the solve; with ``check_static_world`` the local map's solve gets the same
check as the reference solve (`pld_slam.localisation.static_world`), the pose it started from
(the reference solve's, already checked) as the prediction, and the landmarks found
moving there are reported as dynamic too.
"""

from dataclasses import dataclass

import numpy as np

from pld_slam.config import Config
from pld_slam.frontend import StereoFeatures, StereoPoints
from pld_slam.geometry.camera import StereoCamera
from pld_slam.geometry.se3 import transform_points
from pld_slam.localisation.static_world import StaticWorldOptions, static_world_solution
from pld_slam.mapping.map import Map
from pld_slam.matching.frames import MIN_SEARCH_DEPTH, FrameMatches
from pld_slam.matching.observations import line_observations, point_observations
from pld_slam.matching.projection import LandmarkSnapshot, ProjectionSearch, match_map_lines, match_map_points
from pld_slam.matching.windows import pairs_within
from pld_slam.optim.pose_only import PoseOnlyOptions, PoseOnlyResult, optimize_pose_rejecting_outliers


@dataclass(frozen=True)
class LocalMap:
    """The keyframes (ids, ``keyframes[0]`` the reference) and landmarks a frame is tracked against."""

    keyframes: tuple[int, ...]
    points: LandmarkSnapshot
    lines: LandmarkSnapshot


@dataclass(frozen=True)
class ReferenceMatches:
    """Static matches of the current frame to its reference frame, the reference side in the world frame.

    Attributes
    ----------
    points_w : (K, 3) reference stereo points [m]; point_index : (K,) current keypoint of each.
    lines_w : (M, 2, 3) reference segments [m]; line_index : (M,) current line of each.
    point_landmarks, line_landmarks : (K,), (M,) int64, the live landmark the reference feature
        observes, ``-1`` for none; where there is one, ``points_w`` / ``lines_w`` hold its
        position (the match passes the landmark on, module docstring).
    """

    points_w: np.ndarray
    point_index: np.ndarray
    lines_w: np.ndarray
    line_index: np.ndarray
    point_landmarks: np.ndarray
    line_landmarks: np.ndarray

    @classmethod
    def empty(cls) -> "ReferenceMatches":
        """No reference matches (a pose found without the reference frame)."""
        no_ids = np.zeros(0, dtype=np.int64)
        return cls(np.zeros((0, 3)), no_ids, np.zeros((0, 2, 3)), no_ids, no_ids, no_ids)


@dataclass(frozen=True)
class _MapObservations:
    """Current features (K,) matched to landmarks (K,) at world positions (K, ...): the map side of a solve."""

    current: np.ndarray
    landmarks: np.ndarray
    geometry: np.ndarray

    def __len__(self) -> int:
        return len(self.current)


@dataclass(frozen=True)
class MissedPoints:
    """The point landmarks of a local-map snapshot that a frame missed (`missed_in_image`).

    Attributes
    ----------
    ids : (N,) int64 landmark ids of the snapshot.
    p_c : (N, 3) the landmarks in the camera frame [m].
    uv : (N, 2) their pixels (those behind the camera at the principal point).
    missed : (N,) bool in front of the camera, projecting inside the image, and not among the
        ids the frame's solve found as inliers (matched to nothing, or to a feature the
        solve rejected).
    """

    ids: np.ndarray
    p_c: np.ndarray
    uv: np.ndarray
    missed: np.ndarray


@dataclass(frozen=True)
class LocalMapTracking:
    """The outcome of tracking the local map.

    Attributes
    ----------
    solution : the pose-only solve (``T_c_w`` world to camera) over the static map matches and
        the reference matches of the features without one.
    point_ids, line_ids : (P_all,), (L,) int64 landmark of each keypoint / line that matched
        one and is an inlier of ``solution``, ``-1`` otherwise.
    visible_point_ids, visible_line_ids : landmarks predicted in view (within the search's bounds).
    missed : the local map's points the solve missed (`missed_in_image`).
    missed_point_ids, missed_line_ids : landmarks in view the solve did not find: points
        missed and not hidden by a mover (`missed_near_movers`), lines predicted in view.
    dynamic_point_ids, dynamic_line_ids : landmarks matched to features labelled dynamic, and
        points missed under a mover (`missed_near_movers`) or, once the tracker has added
        them, seen through (`pld_slam.tracking.see_through`).
    point_matches, line_matches : static matches that entered the solve.
    """

    solution: PoseOnlyResult
    point_ids: np.ndarray
    line_ids: np.ndarray
    visible_point_ids: np.ndarray
    visible_line_ids: np.ndarray
    missed: MissedPoints
    missed_point_ids: np.ndarray
    missed_line_ids: np.ndarray
    dynamic_point_ids: np.ndarray
    dynamic_line_ids: np.ndarray
    point_matches: int
    line_matches: int

    @property
    def tracked_landmarks(self) -> int:
        """Landmarks (points + lines) matched as inliers."""
        return int(np.count_nonzero(self.point_ids >= 0) + np.count_nonzero(self.line_ids >= 0))

    def posed(self, min_inliers: int) -> bool:
        """Whether it gave a pose: a converged solve on at least ``min_inliers`` landmarks."""
        return self.solution.success and self.tracked_landmarks >= min_inliers


def local_keyframes(world_map: Map, reference: int, limit: int) -> tuple[int, ...]:
    """The reference keyframe, its covisible keyframes strongest first, then theirs, up to ``limit`` ids."""
    chosen = [reference]
    frontier = [reference]
    while frontier and len(chosen) < limit:
        next_frontier = []
        for keyframe in frontier:
            for neighbour in world_map.covisibility.neighbours(keyframe):
                if neighbour not in chosen and len(chosen) < limit:
                    chosen.append(neighbour)
                    next_frontier.append(neighbour)
        frontier = next_frontier
    return tuple(chosen)


def gather_local_map(world_map: Map, reference: int, limit: int) -> LocalMap:
    """The local map of keyframe ``reference`` (module docstring)."""
    return local_map_of(world_map, local_keyframes(world_map, reference, limit))


def local_map_of(world_map: Map, keyframes: tuple[int, ...], excluded: tuple[np.ndarray, np.ndarray] | None = None
                 ) -> LocalMap:
    """The live landmarks ``keyframes`` (ids, the reference first) observe, but the point and line ids
    ``excluded`` (two int arrays; None for none)."""
    snapshots = []
    for n, (kind, ids) in enumerate(zip(world_map.kinds, observed_landmarks(world_map, keyframes))):
        if excluded is not None:
            ids = np.setdiff1d(ids, excluded[n])
        snapshots.append(LandmarkSnapshot.of(kind, ids))
    return LocalMap(tuple(keyframes), *snapshots)


def observed_landmarks(world_map: Map, keyframes: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
    """The live point and line ids (ascending) observed by any of ``keyframes`` (ids)."""
    points, lines = (kind.observed_by(world_map.keyframes[k] for k in keyframes) for kind in world_map.kinds)
    return points, lines


def track_local_map(
    camera: StereoCamera,
    T_c_w_init: np.ndarray,
    local_map: LocalMap,
    features: StereoFeatures,
    dynamic_points: np.ndarray,
    dynamic_lines: np.ndarray,
    config: Config,
    pose_options: PoseOnlyOptions,
    reference: ReferenceMatches,
    check_static_world: bool = False,
) -> LocalMapTracking:
    """Match the local map into the frame from ``T_c_w_init`` (4, 4) and solve ``T_c_w`` over the static
    matches and the ``reference`` matches of features without a map match (module docstring).

    ``dynamic_points`` (P_all,) and ``dynamic_lines`` (L,) bool label the frame's keypoints and lines.
    ``check_static_world``: ``T_c_w_init`` is a trusted pose of the static world (module docstring).
    """
    keypoints = features.keypoints
    search = ProjectionSearch.of(config)
    point_matches = match_map_points(camera, T_c_w_init, local_map.points, keypoints, search,
                                     config.mapping.max_point_distance, config.mapping.ratio)
    line_matches = match_map_lines(camera, T_c_w_init, local_map.lines, features.lines, search)
    map_points = _map_observations(
        local_map.points, _static(point_matches.matches, dynamic_points),
        reference.point_index, reference.point_landmarks, reference.points_w,
    )
    map_lines = _map_observations(
        local_map.lines, _static(line_matches.matches, dynamic_lines),
        reference.line_index, reference.line_landmarks, reference.lines_w,
    )
    extra_points = ~np.isin(reference.point_index, map_points.current)
    extra_lines = ~np.isin(reference.line_index, map_lines.current)
    points = point_observations(
        np.concatenate([map_points.geometry, reference.points_w[extra_points]]),
        keypoints,
        np.concatenate([map_points.current, reference.point_index[extra_points]]),
        config.points,
    )
    lines = line_observations(
        camera,
        np.concatenate([map_lines.geometry, reference.lines_w[extra_lines]]),
        features.lines,
        np.concatenate([map_lines.current, reference.line_index[extra_lines]]),
        config.tracking,
    )
    solution = optimize_pose_rejecting_outliers(camera, T_c_w_init, points=points, lines=lines, options=pose_options)
    moving_ids = np.zeros(0, dtype=np.int64)
    if check_static_world and solution.success:
        static = static_world_solution(camera, solution, T_c_w_init, points, lines, True, pose_options,
                                       StaticWorldOptions.of(config))
        solution, moving_ids = static.solution, map_points.landmarks[static.moving[: len(map_points)]]
    map_inliers = solution.inliers.points[: len(map_points)]
    line_ids = _inlier_ids(len(features.lines), map_lines, solution.inliers.lines[: len(map_lines)])
    matched_to_movers = local_map.points.ids[_dynamic(point_matches.matches, dynamic_points).previous]
    missed = missed_in_image(camera, solution.T_c_w, local_map.points, map_points.landmarks[map_inliers])
    near_movers = missed_near_movers(
        missed, features.points, dynamic_points[: len(features.points)], config.filters.point_grid_cell_width,
        config.mapping.mover_depth_tolerance,
    )
    return LocalMapTracking(
        solution=solution,
        point_ids=_inlier_ids(len(keypoints), map_points, map_inliers),
        line_ids=line_ids,
        visible_point_ids=local_map.points.ids[point_matches.visible],
        visible_line_ids=local_map.lines.ids[line_matches.visible],
        missed=missed,
        missed_point_ids=near_movers.in_view,
        missed_line_ids=np.setdiff1d(local_map.lines.ids[line_matches.visible], line_ids),
        dynamic_point_ids=np.unique(np.concatenate([matched_to_movers, moving_ids, near_movers.under_movers])),
        dynamic_line_ids=local_map.lines.ids[_dynamic(line_matches.matches, dynamic_lines).previous],
        point_matches=len(map_points),
        line_matches=len(map_lines),
    )


def missed_in_image(
    camera: StereoCamera, T_c_w: np.ndarray, points: LandmarkSnapshot, found: np.ndarray
) -> MissedPoints:
    """The point landmarks of ``points`` a frame at ``T_c_w`` (4, 4) missed, ``found`` (K,) holding
    the ids its solve found (`MissedPoints`)."""
    p_c, uv, in_view = points_in_view(camera, T_c_w, points.geometry)
    return MissedPoints(points.ids, p_c, uv, in_view & ~np.isin(points.ids, found))


def points_in_view(camera: StereoCamera, T_c_w: np.ndarray, p_w: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """World points ``p_w`` (N, 3) seen from a camera at ``T_c_w`` (4, 4): in the camera frame (N, 3),
    their pixels (N, 2) (those behind the camera at the principal point), and which lie in view (N,)
    bool: deeper than `MIN_SEARCH_DEPTH` and projecting inside the image."""
    p_c = transform_points(T_c_w, p_w)
    in_front = p_c[:, 2] > MIN_SEARCH_DEPTH
    uv = camera.project(np.where(in_front[:, None], p_c, [0.0, 0.0, 1.0]))
    return p_c, uv, in_front & camera.inside_image(uv)


@dataclass(frozen=True)
class MissedNearMovers:
    """What the movers near a frame's missed point landmarks say of them (`missed_near_movers`).

    Attributes
    ----------
    under_movers : ids (ascending) of the landmarks missed where a mover now stands at their depth.
    in_view : ids (ascending) of the landmarks missed and not hidden by a nearer mover.
    """

    under_movers: np.ndarray
    in_view: np.ndarray


def missed_near_movers(
    missed: MissedPoints, stereo_points: StereoPoints, dynamic: np.ndarray, radius_px: float, depth_tolerance: float
) -> MissedNearMovers:
    """Judge the ``missed`` point landmarks by the stereo points labelled dynamic (``dynamic``
    (S,) bool over ``stereo_points``) within ``radius_px`` of their projections: a landmark
    lies under a mover when such a point lies at its depth, within ``depth_tolerance``
    (``mapping.mover_depth_tolerance``, 0.2) of it; it is hidden when such a point lies nearer
    than that. Those under movers count
    toward local mapping's dynamic streak, those not hidden toward its missed streak
    (``mapping.max_missed_frames``; `pld_slam.mapping.local_mapping`, step 2).

    Under a mover, why: a parked car that pulls out takes its corners along, so its landmarks are not
    matched again, to dynamic features or any others, or only while it creeps, until the
    solve rejects them; they are merely missed, and misses alone cannot tell a mover from
    a static point that changed appearance or was briefly hidden. A mover standing where
    the landmark was predicted, at the landmark's depth, can: the thing there now moves.
    The background a mover hides lies behind it, outside the depth band, and a static
    landmark found again ends the streak that local mapping removes landmarks by
    (`pld_slam.mapping.local_mapping`, step 2).

    The depth tolerance: a car 4.5 m long seen from 20 m spans about 10 % in depth and its
    stereo depth errs by about 5 % there, while what it hides lies farther behind (0.35
    measured: docs/decisions/0019-local-map-tracking.md).

    The radius is one cell of the dynamic grid (``filters.point_grid_cell_width``, 64 px),
    the reach of the grid's own evidence (a hot cell marks points in its neighbours); half
    of it left more of a parked car's landmarks alive.

    In the image, not only searched. A landmark the search of the local map skipped, beyond
    its scale-invariance range or viewing angle
    (`pld_slam.matching.projection.match_map_points`), is judged too: those bounds say where
    its descriptor can match, not where it can be seen, and a car's corners mapped from 15 m
    fall out of the range as the camera closes in on the spot the car has left. A mover
    behind a landmark is not counted: a mover anywhere in the cell is not one seen through
    the landmark's place. The frame's stereo pair, which shows the farther surface wherever
    there is texture, does better (`pld_slam.tracking.see_through`).

    Hidden is not missed. Behind a truck that fills half the view for seconds, the static
    landmarks are merely hidden. Counting them as missed removed them, the local map thinned,
    and a frame's guided pose then lost to a wrong one from scratch.

    The measurements behind the radius, the landmarks judged and the hidden ones: see
    docs/decisions/0019-local-map-tracking.md.
    """
    movers = np.flatnonzero(dynamic)
    query = np.zeros(0, dtype=np.int64)
    mover_depth = np.zeros(0)
    if len(movers):
        query, train = pairs_within(missed.uv, missed.missed, stereo_points.uv[movers],
                                    np.full(len(missed.uv), radius_px))
        mover_depth = stereo_points.points_c[movers[train], 2]
    depth = missed.p_c[query, 2]
    at_its_depth = np.abs(mover_depth - depth) <= depth_tolerance * depth
    in_view = missed.missed.copy()
    in_view[query[mover_depth < (1.0 - depth_tolerance) * depth]] = False
    return MissedNearMovers(under_movers=missed.ids[np.unique(query[at_its_depth])], in_view=missed.ids[in_view])


def _map_observations(
    snapshot: LandmarkSnapshot,
    searched: FrameMatches,
    reference_index: np.ndarray,
    reference_landmarks: np.ndarray,
    reference_geometry: np.ndarray,
) -> _MapObservations:
    """The landmarks a frame observes: those passed on by its reference matches, then those the
    search found (``searched``: snapshot rows to current features) for the other features and
    landmarks. A landmark and a feature appear once each (module docstring)."""
    inherited = reference_landmarks >= 0
    current = np.concatenate([reference_index[inherited], searched.current])
    landmarks = np.concatenate([reference_landmarks[inherited], snapshot.ids[searched.previous]])
    geometry = np.concatenate([reference_geometry[inherited], snapshot.geometry[searched.previous]])
    _, first_of_feature = np.unique(current, return_index=True)
    keep = np.zeros(len(current), dtype=bool)
    keep[first_of_feature] = True
    _, first_of_landmark = np.unique(landmarks, return_index=True)
    once = np.zeros(len(current), dtype=bool)
    once[first_of_landmark] = True
    keep &= once
    return _MapObservations(current[keep], landmarks[keep], geometry[keep])


def _static(matches: FrameMatches, dynamic: np.ndarray) -> FrameMatches:
    """The matches whose current feature is not labelled dynamic (``dynamic``: bool over the current features)."""
    return matches.subset(~dynamic[matches.current])


def _dynamic(matches: FrameMatches, dynamic: np.ndarray) -> FrameMatches:
    """The matches whose current feature is labelled dynamic (``dynamic``: bool over the current features)."""
    return matches.subset(dynamic[matches.current])


def _inlier_ids(n_features: int, observed: _MapObservations, inliers: np.ndarray) -> np.ndarray:
    """(n_features,) int64 landmark id of each feature matched as an inlier, -1 elsewhere."""
    ids = np.full(n_features, -1, dtype=np.int64)
    ids[observed.current[inliers]] = observed.landmarks[inliers]
    return ids
