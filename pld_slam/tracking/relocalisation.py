"""Relocalisation: the map points a frame without a usable motion prior is posed against.

Guided matching needs the constant-velocity prediction to be roughly right. It is not on
the first moving frame of a run that starts in motion, after dropped or unreadable
frames, at a sudden change of speed, or after a failure. The tracker then asks for a pose
from scratch (`pld_slam.matching.prior_free.pose_without_prior`: descriptor matches over
the whole image, seeded stereo PnP RANSAC).

Which map points: the local map of the reference keyframe first (tracking went wrong
recently, so the camera is still near it); when that fails, the map points of keyframes
ranked by GGS similarity to the frame (`keyframes_by_similarity`, the paper's global
descriptor), the most similar first: relocalisation.
"""

import numpy as np

from pld_slam.mapping.map import Map


def keyframes_by_similarity(world_map: Map, ggs: np.ndarray, limit: int) -> list[int]:
    """The ``limit`` keyframes whose GGS is most similar to ``ggs`` (2, C, B), the most similar first."""
    database = world_map.ggs
    if len(database) == 0:
        return []
    order = np.argsort(database.distances(ggs), kind="stable")
    return database.ids[order[:limit]].tolist()
