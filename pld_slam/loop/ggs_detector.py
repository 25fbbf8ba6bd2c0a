"""GGS place recognition (paper, section "Loop detection"): loop candidates of a new keyframe.

Each new keyframe is compared by GGS ``sim_v`` (`pld_slam.frontend.ggs`: a distance,
smaller is more similar) with every keyframe of the map's `GgsDatabase` in one vectorised
query. What the paper leaves open, and what we do:

- Never candidates: the keyframe's covisible keyframes (any shared landmark: they are
  already joined to it, there is no loop to close) and the ``loop.exclude_recent_keyframes``
  keyframes inserted just before it (the same place seen moments ago).
- The similarity bar, as ORB-SLAM2 sets it for bag-of-words scores: a candidate must be at
  least as similar as the keyframe's least similar covisible neighbour (distance at most
  the largest distance to an edge neighbour). It adapts to the scene: on a texture-poor or
  fast stretch, neighbours are far apart in GGS, and the bar is looser; without any
  neighbour there is no bar, and no candidate.
- The ``loop.candidates`` most similar candidates below the bar go to verification
  (`pld_slam.loop.verify`), the most similar first.
"""

from dataclasses import dataclass

import numpy as np

from pld_slam.config import LoopConfig
from pld_slam.mapping.keyframe import KeyFrame
from pld_slam.mapping.map import Map


@dataclass(frozen=True)
class GgsCandidates:
    """Loop candidates of one keyframe: ids (K,) most similar first, their GGS distances (K,), and the bar."""

    keyframes: np.ndarray
    distances: np.ndarray
    bar: float


def similarity_bar(world_map: Map, keyframe: KeyFrame, distances: np.ndarray) -> float:
    """The largest GGS distance from ``keyframe`` to its covisible edge neighbours (NaN without any).

    ``distances`` (N,): the keyframe's distances to the database, in the order of its ids.
    """
    neighbours = np.isin(world_map.ggs.ids, world_map.covisibility.neighbours(keyframe.id))
    return float(distances[neighbours].max()) if neighbours.any() else float("nan")


def ggs_loop_candidates(world_map: Map, keyframe: KeyFrame, config: LoopConfig) -> GgsCandidates:
    """The keyframe's loop candidates (module docstring)."""
    ids = world_map.ggs.ids
    if len(ids) == 0 or keyframe.ggs is None:
        return GgsCandidates(np.zeros(0, dtype=np.int64), np.zeros(0), float("nan"))
    distances = world_map.ggs.distances(keyframe.ggs)
    bar = similarity_bar(world_map, keyframe, distances)
    joined = [*world_map.covisibility.shared(keyframe.id), keyframe.id]
    eligible = (ids < keyframe.id - config.exclude_recent_keyframes) & ~np.isin(ids, joined) & (distances <= bar)
    order = np.flatnonzero(eligible)[np.argsort(distances[eligible], kind="stable")][: config.candidates]
    return GgsCandidates(ids[order].astype(np.int64), distances[order], bar)
