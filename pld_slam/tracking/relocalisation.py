"""Relocalisation: the map points a frame without a usable motion prior is posed against.

Guided matching needs the constant-velocity prediction to be roughly right. It is not on
the first moving frame of a run that starts in motion, after dropped or unreadable
frames, at a sudden change of speed, or after a failure. The tracker then asks for a pose
from scratch (`pld_slam.matching.prior_free.pose_without_prior`: descriptor matches over
the whole image, seeded stereo PnP RANSAC).

Which map points: the local map of the reference keyframe first (tracking went wrong
recently, so the camera is still near it); when that fails, the map points of keyframes
ranked by GGS similarity to the frame (`keyframes_by_similarity`, the paper's global
descriptor), the most similar first: relocalisation (`candidate_local_maps`). The first
whose local map, tracked from the pose, gives a pose is the proposal (`track_from_scratch`);
whether it replaces the guided pose is the tracker's choice (`Tracker.relocalise`).
"""

from dataclasses import dataclass

import numpy as np

from pld_slam.config import Config
from pld_slam.frontend import StereoFeatures
from pld_slam.geometry.camera import StereoCamera
from pld_slam.localisation.local_map import (
    LocalMap,
    LocalMapTracking,
    ReferenceMatches,
    gather_local_map,
    track_local_map,
)
from pld_slam.mapping.map import Map
from pld_slam.matching.prior_free import PriorFreeOptions, pose_without_prior
from pld_slam.optim.pose_only import PoseOnlyOptions


@dataclass(frozen=True)
class Relocalised:
    """A frame posed without the motion prior: the local map tracked from that pose, and the local map."""

    tracking: LocalMapTracking
    local_map: LocalMap


def keyframes_by_similarity(world_map: Map, ggs: np.ndarray, limit: int) -> list[int]:
    """The ``limit`` keyframes whose GGS is most similar to ``ggs`` (2, C, B), the most similar first."""
    database = world_map.ggs
    if len(database) == 0:
        return []
    order = np.argsort(database.distances(ggs), kind="stable")
    return database.ids[order[:limit]].tolist()


def candidate_local_maps(
    world_map: Map, local_map: LocalMap, reference_keyframe: int, place_ggs: np.ndarray | None, config: Config
) -> list[LocalMap]:
    """The local maps to pose a frame against without the prior, in order (module docstring).

    ``local_map``, the reference keyframe's, first; then those of the
    ``tracking.relocalisation_keyframes`` keyframes most similar to the frame's place GGS
    ``place_ggs`` (2, C, B), but ``reference_keyframe`` itself (none without a GGS).
    """
    candidates = [local_map]
    if place_ggs is not None:
        limit = config.tracking.relocalisation_keyframes
        for keyframe in keyframes_by_similarity(world_map, place_ggs, limit):
            if keyframe != reference_keyframe:
                candidates.append(gather_local_map(world_map, keyframe, config.mapping.tracking_keyframes))
    return candidates


def track_from_scratch(
    camera: StereoCamera,
    candidates: list[LocalMap],
    features: StereoFeatures,
    point_dynamic: np.ndarray,
    line_dynamic: np.ndarray,
    config: Config,
    options: PoseOnlyOptions,
) -> Relocalised | None:
    """The first of ``candidates`` that gives the frame a pose without the prior.

    Each is tried in turn: a pose without the prior from its points
    (`pld_slam.matching.prior_free.pose_without_prior`), then the local map tracked from
    there (`local_map.track_local_map`, without reference matches), leaving out the frame's
    keypoints (P_all,) and lines (L,) labelled dynamic (``point_dynamic``, ``line_dynamic``).
    None when none gave a pose on ``tracking.min_inliers`` landmarks.
    """
    prior_free = PriorFreeOptions.of(config)
    for local_map in candidates:
        points = local_map.points
        pose = pose_without_prior(camera, features.keypoints, points.geometry, points.descriptors, prior_free)
        if pose is None:
            continue
        tracking = track_local_map(
            camera, pose.T_c_w, local_map, features, point_dynamic, line_dynamic, config, options,
            ReferenceMatches.empty(),
        )
        if tracking.posed(config.tracking.min_inliers):
            return Relocalised(tracking, local_map)
    return None
