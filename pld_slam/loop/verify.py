"""Verification of a loop candidate (paper, section "Loop detection"): a geometric check, the drift gate and lc_rat.

A wrong loop is far worse than a missed one: it bends the whole map. A candidate that
passed its detector's consistency test (`pld_slam.loop.detection`; the paper's stage 2 for
GGS) is accepted only when it passes every test here, cheapest first:

1. Geometric check: the current keyframe's keypoints matched to the candidate's own map
   points by descriptor alone, seeded stereo PnP RANSAC on them
   (`pld_slam.matching.prior_free`), then the map around the candidate (the
   candidate's and its covisible neighbours' landmarks) tracked from that pose with point
   and line errors (the pose-only solve of tracking). Landmarks the current keyframe and
   its own neighbours observe are left out of both: the loop's other end must be matched
   to the old map only, or a candidate whose neighbourhood reaches back to the present
   would "verify" against the landmarks being tracked now. At least ``loop.min_inliers``
   point and line inliers. Stereo has metric scale: the loop constraint is the SE(3) pose
   found, ``T_c_w`` of the current keyframe in the candidate's part of the map.

   Cost. Nearly every candidate fails here (a detector proposes 2-3 per keyframe), so
   the check must fail cheaply. PnP runs only on at least ``loop.min_inliers``
   descriptor matches, the inliers the check needs in the end: a RANSAC that cannot find
   a pose runs all its ``tracking.pnp_iterations``, and checks that find a pose have many
   more matches. And the descriptor matching (brute force, no vocabulary with GGS) takes the
   candidate's own landmarks rather than its neighbourhood's, several times fewer, with
   as many poses found; the neighbourhood still serves the tracking from the pose found
   (docs/decisions/0014-loop-verification.md).
2. Drift gate (not in the paper): the correction the loop makes to the current keyframe
   (from its tracked pose to the pose found) must be one that drift could have caused
   since the candidate: at most ``loop.max_drift_ratio`` (3 %) of the keyframes' path
   between them plus ``loop.drift_allowance_m`` (1 m), and ``loop.max_drift_deg`` (20 deg).
   Our tracking drifts by about 1 % of the path or less, so a true loop passes with a
   margin; an aliased match (a repeated facade, matched with nearly all inliers) makes a
   correction of metres or tens of degrees, and a looser gate let one through and bent the
   map (docs/decisions/0014-loop-verification.md).
3. Same place (not in the paper): the current keyframe, where the check places it, and
   the candidate must see the scene from the same place: camera centres at most
   ``loop.max_distance_m`` (3 m) apart and optical axes within ``loop.max_view_angle_deg``
   (30 deg), the definition of a true loop the benchmarks score against. A forward
   camera recognises a place from well before it gets there: a loop closed metres before
   the place is a detection that place recognition benchmarks count as false, and a
   pose-graph edge measured across metres of PnP (docs/decisions/0014-loop-verification.md).
   Closing it a few keyframes later, at the place itself, costs nothing: until the loop is
   closed the current side shares no landmark with the old one, so the old keyframes stay
   candidates.
4. ``lc_rat`` (the paper's first stage), from that check's relative pose and inlier
   ratio. The paper writes ``lc_rat = alpha * ||log(T_i T_j^-1)|| * ratio_inl`` (alpha
   0.001, "initial inlier ratio" 50 %) and rejects a candidate whose ``lc_rat`` lies below
   20 %. Read literally, a larger motion between the two keyframes would make a candidate
   *more* acceptable, and with alpha = 0.001 no loop would pass unless the keyframes were
   hundreds of metres apart: the opposite of a consistency check. We read it as the inlier
   ratio discounted by the motion between the two keyframes,

       lc_rat = ratio_inl * (1 - alpha * ||log(T_i T_j^-1)||)

   with ``T_i`` the current keyframe's pose found by the check, ``T_j`` the candidate's, the
   twist norm in metres and radians, and ``ratio_inl`` the check's inliers over its matches.
   The paper's 50 % "initial" inlier ratio is not a parameter here: it is what a true loop
   is expected to reach, and PnP's RANSAC (``tracking.pnp_iterations``, 300) covers it with
   ``tracking.pnp_confidence`` (0.999). The paper's literal ``lc_rat`` would accept larger
   motions more readily; we discount the inlier ratio instead
   (docs/decisions/0014-loop-verification.md). The discount is small at alpha = 0.001 (2 %
   at 20 m): the test rejects above all a candidate whose matches are mostly wrong, which is
   what perceptual aliasing produces (a repeated facade matched by descriptor, fitting a
   pose with a few chance inliers).
"""

from dataclasses import dataclass

import numpy as np

from pld_slam.config import Config, LoopConfig
from pld_slam.geometry import places
from pld_slam.geometry.camera import StereoCamera
from pld_slam.geometry.se3 import inverse, motion_size, se3_log
from pld_slam.localisation.local_map import (
    LocalMap,
    LocalMapTracking,
    ReferenceMatches,
    local_map_of,
    observed_landmarks,
    track_local_map,
)
from pld_slam.mapping.keyframe import KeyFrame
from pld_slam.mapping.map import Map
from pld_slam.matching.prior_free import PriorFreeOptions, pose_without_prior
from pld_slam.optim.pose_only import PoseOnlyOptions
from pld_slam.trajectory import polyline_length


@dataclass(frozen=True)
class GeometricCheck:
    """The current keyframe located in the candidate's map.

    Attributes
    ----------
    T_c_w : (4, 4) the current keyframe's pose in the candidate's map.
    matches, inliers : point and line matches of the local-map solve, and its inliers.
    tracking : the local-map solve (landmark of each inlier feature: the loop's fusion uses them).
    local_map : the map it was solved against: the landmarks the candidate and its covisible
        neighbours observe but the current side does not (the loop's fusion projects them).
    """

    T_c_w: np.ndarray
    matches: int
    inliers: int
    tracking: LocalMapTracking
    local_map: LocalMap

    @property
    def inlier_ratio(self) -> float:
        return self.inliers / self.matches if self.matches else 0.0


def geometric_check(
    world_map: Map, keyframe: KeyFrame, candidate: KeyFrame, camera: StereoCamera, config: Config,
    pose_options: PoseOnlyOptions,
) -> GeometricCheck | None:
    """Locate ``keyframe`` in the candidate's local map (module docstring); None when PnP finds no pose."""
    present = present_landmarks(world_map, keyframe)
    points = local_map_of(world_map, (candidate.id,), present).points
    found = pose_without_prior(camera, keyframe.features.keypoints, points.geometry, points.descriptors,
                               PriorFreeOptions.of(config), min_matches=config.loop.min_inliers)
    if found is None:
        return None
    local_map = local_map_of(world_map, around(world_map, candidate), present)
    tracking = track_local_map(
        camera, found.T_c_w, local_map, keyframe.features, keyframe.point_dynamic, keyframe.line_dynamic, config,
        pose_options, ReferenceMatches.empty(),
    )
    return GeometricCheck(
        T_c_w=tracking.solution.T_c_w,
        matches=tracking.point_matches + tracking.line_matches,
        inliers=tracking.tracked_landmarks,
        tracking=tracking,
        local_map=local_map,
    )


def covisible_support(
    world_map: Map, keyframe: KeyFrame, candidate: KeyFrame, check: GeometricCheck, camera: StereoCamera,
    config: Config, pose_options: PoseOnlyOptions, needed: int,
) -> int:
    """How many of the keyframe's covisible keyframes confirm the loop ``check`` found, up to ``needed``.

    ORB-SLAM3's verification in the covisibility window
    (``LoopClosing::DetectCommonRegionsFromBoW``): the pose the check found for ``keyframe``
    is carried to each of its ``loop.bow_covisible_window`` (10, ORB-SLAM3's
    ``nNumCovisibles``) strongest covisible keyframes through their tracked relative pose,
    and the candidate's map (the check's local map) is tracked into that keyframe from
    there; a keyframe confirms the loop with at least ``loop.bow_covisible_inlier_share``
    (half) of ``loop.min_inliers`` inliers (ORB-SLAM3 asks 30 projection matches of each
    covisible keyframe against 50-80 of the current one). Only keyframes of the current side
    count: ids after the candidate's plus ``loop.exclude_recent_keyframes``, and not
    covisible with the candidate (after an earlier loop or a fusion a later keyframe can be,
    and would confirm the candidate's map from its own side). The evidence ORB-SLAM2 waits
    for from the next keyframes (group consistency) is taken from keyframes already in the
    map, with no delay. ORB-SLAM3 also carries a partial confirmation (fewer than
    ``needed``) to the next keyframes; we do not, because group consistency already carries
    a candidate that persists.
    """
    T_w_c = keyframe.T_w_c
    candidate_side = around(world_map, candidate)
    found = 0
    for other in world_map.covisibility.neighbours(keyframe.id, config.loop.bow_covisible_window):
        if found >= needed:
            break
        if other <= candidate.id + config.loop.exclude_recent_keyframes or other in candidate_side:
            continue
        frame = world_map.keyframes[other]
        T_j_w = frame.T_c_w @ T_w_c @ check.T_c_w
        tracking = track_local_map(
            camera, T_j_w, check.local_map, frame.features, frame.point_dynamic, frame.line_dynamic, config,
            pose_options, ReferenceMatches.empty(),
        )
        found += tracking.tracked_landmarks >= config.loop.bow_covisible_inlier_share * config.loop.min_inliers
    return found


def around(world_map: Map, keyframe: KeyFrame) -> tuple[int, ...]:
    """A keyframe's id and its covisible neighbours' ids."""
    return (keyframe.id, *world_map.covisibility.neighbours(keyframe.id))


def present_landmarks(world_map: Map, keyframe: KeyFrame) -> tuple[np.ndarray, np.ndarray]:
    """The live point and line ids observed by ``keyframe`` and its covisible neighbours."""
    return observed_landmarks(world_map, around(world_map, keyframe))


def path_length(world_map: Map, first: int, last: int) -> float:
    """Length [m] of the path through the live keyframes with ids from ``first`` to ``last``, in id order."""
    ids = [k for k in sorted(world_map.keyframes) if first <= k <= last]
    return polyline_length(np.array([world_map.keyframes[k].centre for k in ids]).reshape(-1, 3))


def plausible_drift(correction: np.ndarray, path: float, config: LoopConfig) -> bool:
    """Whether a keyframe's correction ``T_c_new_c_old`` (4, 4) could be drift over ``path`` [m] (module docstring)."""
    translation, angle = motion_size(correction)
    return translation <= config.max_drift_ratio * path + config.drift_allowance_m and angle <= config.max_drift_deg


def same_place(T_i_w: np.ndarray, T_j_w: np.ndarray, config: LoopConfig) -> bool:
    """Whether two ``T_c_w`` poses (4, 4) see from the same place (module docstring, test 3)."""
    return bool(places.same_place(inverse(T_i_w), inverse(T_j_w), config.max_distance_m, config.max_view_angle_deg))


def relative_motion(T_i_w: np.ndarray, T_j_w: np.ndarray) -> float:
    """``||log(T_i T_j^-1)||`` of two ``T_c_w`` poses (4, 4): the twist norm, metres and radians."""
    return float(np.linalg.norm(se3_log(T_i_w @ inverse(T_j_w))))


def lc_rat(inlier_ratio: float, motion: float, config: LoopConfig) -> float:
    """The paper's ``lc_rat`` as we read it (module docstring)."""
    return inlier_ratio * (1.0 - config.lc_rat_alpha * motion)
