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
- The ``loop.candidates`` most similar candidates below the bar, the most similar first.
- Stage 2, neighbourhood consistency (`neighbourhood`): "the previous keyframe has
  significant similarity with the looped keyframe, and there is a significant similarity
  between the current keyframe and the adjacent frames of the looped keyframe". We read
  "significant" as the bar the candidate itself passed: the previous keyframe's distance
  to the candidate, and the current keyframe's smallest distance to the candidate's
  covisible neighbours, must both be within it. A candidate without neighbours fails.
  The consistent ones go to verification (`pld_slam.loop.verify`).
"""

from dataclasses import dataclass

import numpy as np

from pld_slam.config import LoopConfig
from pld_slam.frontend.ggs import ggs_distance
from pld_slam.loop.detection import Detection
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
    if len(ids) == 0 or keyframe.place_ggs is None:
        return GgsCandidates(np.zeros(0, dtype=np.int64), np.zeros(0), float("nan"))
    distances = world_map.ggs.distances(keyframe.place_ggs)
    bar = similarity_bar(world_map, keyframe, distances)
    joined = [*world_map.covisibility.shared(keyframe.id), keyframe.id]
    eligible = (ids < keyframe.id - config.exclude_recent_keyframes) & ~np.isin(ids, joined) & (distances <= bar)
    order = np.flatnonzero(eligible)[np.argsort(distances[eligible], kind="stable")][: config.candidates]
    return GgsCandidates(ids[order].astype(np.int64), distances[order], bar)


@dataclass(frozen=True)
class Neighbourhood:
    """Stage 2: the previous keyframe's GGS distance to the candidate, and the current keyframe's
    smallest distance to the candidate's covisible neighbours (inf without any)."""

    previous_distance: float
    neighbour_distance: float

    def passes(self, bar: float) -> bool:
        return self.previous_distance <= bar and self.neighbour_distance <= bar


def previous_keyframe(world_map: Map, keyframe: KeyFrame) -> KeyFrame | None:
    """The live keyframe inserted last before ``keyframe`` (None for the first)."""
    earlier = [k for k in world_map.keyframes if k < keyframe.id]
    return world_map.keyframes[max(earlier)] if earlier else None


def neighbourhood(world_map: Map, keyframe: KeyFrame, candidate: KeyFrame) -> Neighbourhood:
    """Stage 2's two distances (module docstring)."""
    previous = previous_keyframe(world_map, keyframe)
    previous_distance = np.inf if previous is None else ggs_distance(previous.place_ggs, candidate.place_ggs)
    around = [world_map.keyframes[k] for k in world_map.covisibility.neighbours(candidate.id) if k != keyframe.id]
    neighbour_distance = min((ggs_distance(keyframe.place_ggs, k.place_ggs) for k in around), default=np.inf)
    return Neighbourhood(float(previous_distance), float(neighbour_distance))


class GgsDetector:
    """The paper's loop detector over the map's GGS database (module docstring)."""

    def __init__(self, world_map: Map, config: LoopConfig) -> None:
        self._map = world_map
        self._config = config

    def detect(self, keyframe: KeyFrame) -> list[Detection]:
        """The keyframe's candidates with their stage 2, the most similar first."""
        found = ggs_loop_candidates(self._map, keyframe, self._config)
        detections = []
        for candidate, distance in zip(found.keyframes.tolist(), found.distances.tolist()):
            stage_2 = neighbourhood(self._map, keyframe, self._map.keyframes[candidate])
            detections.append(Detection(
                candidate=candidate, score=distance, bar=found.bar, previous_distance=stage_2.previous_distance,
                neighbour_distance=stage_2.neighbour_distance, consistency=np.nan,
                consistent=stage_2.passes(found.bar),
            ))
        return detections
