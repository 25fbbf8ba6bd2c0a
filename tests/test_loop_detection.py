"""GGS loop candidates on a constructed map, and the verification tests on constructed values."""

import cv2
import numpy as np
from map_fixtures import make_keyframe, random_descriptors, scene_points, simple_features

from pld_slam.config import GgsConfig, LoopConfig
from pld_slam.frontend.ggs import ggs_descriptor
from pld_slam.geometry.se3 import inverse, make_pose, so3_exp
from pld_slam.loop.ggs_detector import ggs_loop_candidates
from pld_slam.loop.verify import lc_rat, plausible_drift
from pld_slam.mapping.map import Map

WIDTH, STEP = 160, 12
"""Each keyframe sees a WIDTH-pixel window of one long panorama, STEP pixels on from the last one's."""


def panorama(seed: int, width: int) -> np.ndarray:
    """A smooth random grey panorama (120, width) uint8."""
    noise = np.random.default_rng(seed).uniform(0, 255, (12, width // 10)).astype(np.float32)
    return cv2.resize(noise, (width, 120), interpolation=cv2.INTER_CUBIC).clip(0, 255).astype(np.uint8)


def corridor_map(places: list[int]) -> Map:
    """A map of keyframes 0..len(places)-1, keyframe k seeing panorama window ``places[k]``; each
    keyframe shares 20 landmarks with the next (a covisibility edge), none with any other."""
    world_map = Map(covisibility_min_shared=20)
    view = panorama(seed=7, width=WIDTH + STEP * (max(places) + 1))
    n = len(places)
    world_map.points.add(scene_points(20 * (n + 1), 1), random_descriptors(20 * (n + 1), 2), 0)
    for k, place in enumerate(places):
        keyframe = make_keyframe(k, simple_features(40, seed=k), point_ids=np.arange(20 * k, 20 * k + 40))
        keyframe.ggs = ggs_descriptor(np.ascontiguousarray(view[:, STEP * place: STEP * place + WIDTH]), GgsConfig())
        world_map.add_keyframe(keyframe)
    return world_map


CONFIG = LoopConfig(exclude_recent_keyframes=5, candidates=3)


def test_a_revisit_is_a_candidate_and_recent_or_covisible_keyframes_are_not():
    places = [*range(30), 3]  # keyframe 30 returns to the place of keyframe 3
    world_map = corridor_map(places)
    found = ggs_loop_candidates(world_map, world_map.keyframes[30], CONFIG)
    assert found.keyframes[0] == 3
    assert np.all(found.keyframes < 30 - CONFIG.exclude_recent_keyframes)
    assert np.all(found.distances <= found.bar)
    assert 29 not in found.keyframes  # covisible (shares landmarks) with keyframe 30


def test_a_new_place_next_to_the_last_one_has_no_candidate():
    world_map = corridor_map(list(range(31)))
    found = ggs_loop_candidates(world_map, world_map.keyframes[30], CONFIG)
    assert len(found.keyframes) == 0


def test_lc_rat_is_the_inlier_ratio_discounted_by_the_motion():
    assert lc_rat(0.6, 0.0, CONFIG) == 0.6
    assert lc_rat(0.6, 20.0, CONFIG) < lc_rat(0.6, 1.0, CONFIG) < 0.6
    assert lc_rat(0.15, 0.0, CONFIG) < CONFIG.lc_rat_threshold <= lc_rat(0.5, 20.0, CONFIG)


def test_drift_gate_accepts_drift_sized_corrections_only():
    def correction(metres: float, degrees: float) -> np.ndarray:
        return inverse(make_pose(so3_exp([0.0, np.radians(degrees), 0.0]), [metres, 0.0, 0.0]))

    assert plausible_drift(correction(2.0, 3.0), path=50.0, config=CONFIG)  # 4 % of the path
    assert not plausible_drift(correction(23.0, 3.0), path=25.0, config=CONFIG)  # an aliased facade
    assert not plausible_drift(correction(1.0, 61.0), path=500.0, config=CONFIG)
