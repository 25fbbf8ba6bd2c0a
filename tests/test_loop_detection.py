"""Loop candidates of both detectors on constructed maps, and the verification tests on constructed values."""

import dataclasses

import cv2
import numpy as np
import pytest
from map_fixtures import (
    CAMERA,
    camera_at,
    camera_features,
    empty_features,
    make_keyframe,
    random_descriptors,
    scene_points,
    simple_features,
    world_features,
)

from pld_slam.config import Config, GgsConfig, LoopConfig
from pld_slam.frontend.ggs import ggs_and_place_descriptors
from pld_slam.geometry.se3 import inverse, make_pose, so3_exp, transform_points
from pld_slam.localisation.local_map import local_map_of
from pld_slam.loop.bow_detector import BowDatabase, BowDetector
from pld_slam.loop.ggs_detector import GgsDetector, ggs_loop_candidates
from pld_slam.loop.verify import (
    GeometricCheck,
    around,
    covisible_support,
    lc_rat,
    plausible_drift,
    present_landmarks,
    same_place,
)
from pld_slam.loop.vocabulary import bow_score, build_vocabulary
from pld_slam.mapping.map import Map
from pld_slam.optim.pose_only import PoseOnlyOptions

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
        window = np.ascontiguousarray(view[:, STEP * place: STEP * place + WIDTH])
        _, keyframe.place_ggs = ggs_and_place_descriptors(window, GgsConfig())
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


def test_the_ggs_detector_checks_the_neighbourhood_of_a_revisit():
    places = [*range(30), 3]
    world_map = corridor_map(places)
    detections = GgsDetector(world_map, CONFIG).detect(world_map.keyframes[30])
    assert detections[0].candidate == 3 and detections[0].consistent
    assert np.isnan(detections[0].consistency)


# Bag of words: the keyframe at place p sees the descriptors of segments p and p + 1 of a
# long street (30 each), with a few bits flipped; neighbours share a segment.
SEGMENT = 30


def segment_descriptors(segment: int) -> np.ndarray:
    return random_descriptors(SEGMENT, seed=500 + segment)


def flipped(descriptors: np.ndarray, seed: int) -> np.ndarray:
    bits = np.random.default_rng(seed).random((len(descriptors), 256)) < 0.01
    return descriptors ^ np.packbits(bits, axis=1)


def street_vocabulary(n_segments: int):
    training = [flipped(segment_descriptors(s), seed=900 + s) for s in range(n_segments)]
    return build_vocabulary(training, branching=8, depth=3, seed=0)


def street_map(places: list[int]) -> Map:
    """Keyframe k at street place ``places[k]``; each shares 20 landmarks with the next."""
    world_map = Map(covisibility_min_shared=20)
    n = len(places)
    world_map.points.add(scene_points(20 * (n + 1), 1), random_descriptors(20 * (n + 1), 2), 0)
    for k, place in enumerate(places):
        descriptors = flipped(np.concatenate([segment_descriptors(place), segment_descriptors(place + 1)]), seed=k)
        rng = np.random.default_rng(k)
        points_c = np.column_stack([rng.uniform(-2, 2, 2 * SEGMENT), rng.uniform(-1, 1, 2 * SEGMENT),
                                    rng.uniform(5, 15, 2 * SEGMENT)])
        point_ids = np.concatenate([np.arange(20 * k, 20 * k + 40), np.full(2 * SEGMENT - 40, -1)])
        world_map.add_keyframe(make_keyframe(k, camera_features(points_c, descriptors), point_ids=point_ids))
    return world_map


def bow_detections(places: list[int], config: LoopConfig = CONFIG) -> list[list]:
    """Every keyframe's BoW detections, keyframes looked up in order."""
    world_map = street_map(places)
    detector = BowDetector(world_map, street_vocabulary(max(places) + 2), config)
    return [detector.detect(world_map.keyframes[k]) for k in range(len(places))]


def test_bow_finds_a_revisit_once_it_is_group_consistent():
    places = [*range(30), 3, 4, 5, 6]
    detections = bow_detections(places)
    assert all(not d.consistent for found in detections[:30] for d in found)
    revisit = detections[30:]
    assert all(found and abs(places[found[0].candidate] - places[30 + n]) <= 1 for n, found in enumerate(revisit))
    assert [found[0].consistency for found in revisit] == [0, 1, 2, 3]
    assert revisit[-1][0].consistent and not revisit[-2][0].consistent
    assert all(d.score >= d.bar for found in revisit for d in found)


@pytest.mark.parametrize("kept", ["bow_common_words_ratio", "bow_retain_ratio"])
def test_bow_keeps_the_candidates_both_configured_shares_keep(kept):
    """``loop.bow_common_words_ratio`` and ``loop.bow_retain_ratio``: with either at 0, the other alone
    keeps only the revisited place; with both at 0 its neighbours along the street are candidates too."""
    places = [*range(30), 3]
    one = dataclasses.replace(CONFIG, **{kept: 0.0})
    both = dataclasses.replace(one, bow_common_words_ratio=0.0, bow_retain_ratio=0.0)
    assert [d.candidate for d in bow_detections(places, one)[30]] == [3]
    assert [d.candidate for d in bow_detections(places, both)[30]] == [3, 2, 1]


def test_bow_rejects_a_single_aliased_keyframe():
    detections = bow_detections([*range(30), 3, 40, 41, 42])
    assert detections[30] and detections[30][0].candidate == 3  # looks like a revisit...
    assert not any(d.consistent for found in detections for d in found)  # ...but no group follows it


def test_the_inverse_index_scores_as_the_pairwise_l1_score():
    vocabulary = street_vocabulary(12)
    vectors = [vocabulary.bow_vector(flipped(segment_descriptors(s), seed=s)) for s in range(10)]
    database = BowDatabase()
    for k, vector in enumerate(vectors):
        database.add(k, vector)
    query = vocabulary.bow_vector(np.concatenate([segment_descriptors(4), segment_descriptors(5)]))
    ids, shared, scores = database.query(query)
    for k, n_shared, score in zip(ids, shared, scores):
        assert score == pytest.approx(bow_score(query, vectors[k]))
        assert n_shared == len(np.intersect1d(query.words, vectors[k].words))
    assert set(ids[np.argsort(-scores)[:2]]) == {4, 5}


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
    # 3 % of 10 m plus ``loop.drift_allowance_m``: 1.3 m by default, 0.3 m without the allowance
    assert plausible_drift(correction(1.2, 3.0), path=10.0, config=CONFIG)
    no_allowance = dataclasses.replace(CONFIG, drift_allowance_m=0.0)
    assert not plausible_drift(correction(1.2, 3.0), path=10.0, config=no_allowance)


def test_a_loop_joins_keyframes_at_the_same_place_only():
    def camera(z: float, yaw_deg: float, x: float = 0.0) -> np.ndarray:  # T_c_w
        return inverse(make_pose(so3_exp([0.0, np.radians(yaw_deg), 0.0]), [x, 0.0, z]))

    assert same_place(camera(0.0, 0.0), camera(2.5, 20.0), CONFIG)
    assert not same_place(camera(0.0, 0.0), camera(8.5, 0.0), CONFIG)  # recognised from 8.5 m back
    assert not same_place(camera(0.0, 0.0), camera(0.0, 0.0, x=3.5), CONFIG)  # the next lane
    assert not same_place(camera(0.0, 0.0), camera(0.0, 40.0), CONFIG)


# --- ORB-SLAM3's check in the covisibility window (bag of words) ---------------------------

COVISIBLE_CONFIG = dataclasses.replace(Config(), loop=dataclasses.replace(Config().loop, exclude_recent_keyframes=5))
CURRENT_SIDE = range(10, 15)
"""Ids of the revisiting keyframes, the last the current one; the loop side is keyframe 0."""


def revisit_map(neighbours_see_the_place: bool) -> tuple[Map, GeometricCheck]:
    """Keyframe 0 maps 80 scene points. Keyframes 10-14 come back to the place, 0.3 m and 6 degrees
    of yaw apart, but tracking drifted (2 m, and 32 degrees about an axis off their yaw axis: had
    both turned about one axis, the rotations would commute, and a pose composed in the wrong
    order would be off by a few tenths of a metre only, which tracking absorbs): their own
    landmarks are copies of the scene points moved by the drift, which they share (covisible).
    Keyframe 14's geometric check found its true pose in keyframe 0's map. Its neighbours see
    the scene points too, or (a place that only keyframe 14 mistakes for keyframe 0's) other
    points with other descriptors."""
    world_map = Map(covisibility_min_shared=20)
    scene, descriptors = scene_points(80, seed=3), random_descriptors(80, seed=4)
    drift = make_pose(so3_exp(np.deg2rad([20.0, 25.0, 0.0])), np.array([2.0, 0.0, 0.0]))  # T_map_world
    loop_side = world_map.points.add(scene, descriptors, 0)
    current_side = world_map.points.add(transform_points(drift, scene), descriptors, 10)
    world_map.points.writable("normal")[:] = [0.0, 0.0, 1.0]  # seen along the world z axis
    world_map.points.writable("max_distance")[:] = np.tile(np.linalg.norm(scene, axis=1), 2)  # keypoints at octave 0
    elsewhere, other_descriptors = scene_points(80, seed=5), random_descriptors(80, seed=6)
    world_map.add_keyframe(make_keyframe(0, world_features(camera_at([0.0, 0.0, 0.0]), scene, descriptors),
                                         camera_at([0.0, 0.0, 0.0]), point_ids=loop_side))
    for k in range(1, CURRENT_SIDE[0]):  # the drive between the two visits: nothing in common with either
        world_map.add_keyframe(make_keyframe(k, empty_features(), camera_at([0.0, 0.0, -10.0 * k])))
    for k in CURRENT_SIDE:
        yaw = so3_exp(np.array([0.0, np.deg2rad(6.0 * (k - 12)), 0.0]))
        T_c_w = inverse(make_pose(yaw, np.array([0.3 * (k - 12), 0.0, 0.0])))
        sees_the_place = neighbours_see_the_place or k == CURRENT_SIDE[-1]
        features = (world_features(T_c_w, scene, descriptors) if sees_the_place
                    else world_features(T_c_w, elsewhere, other_descriptors))
        world_map.add_keyframe(make_keyframe(k, features, T_c_w @ inverse(drift), point_ids=current_side))
    current = world_map.keyframes[CURRENT_SIDE[-1]]
    check = GeometricCheck(T_c_w=T_c_w, matches=80, inliers=80, tracking=None,
                           local_map=local_map_of(world_map, around(world_map, world_map.keyframes[0]),
                                                  present_landmarks(world_map, current)))
    return world_map, check


@pytest.mark.parametrize("neighbours_see_the_place", [True, False])
def test_the_covisible_keyframes_confirm_a_loop_only_where_they_see_the_candidates_place(neighbours_see_the_place):
    world_map, check = revisit_map(neighbours_see_the_place)
    support = covisible_support(world_map, world_map.keyframes[CURRENT_SIDE[-1]], world_map.keyframes[0], check,
                                CAMERA, COVISIBLE_CONFIG, PoseOnlyOptions(), needed=3)
    assert support == (3 if neighbours_see_the_place else 0)


def test_only_the_configured_window_of_covisible_keyframes_is_tried():
    """``loop.bow_covisible_window``: two covisible keyframes tried, two confirmations at most."""
    world_map, check = revisit_map(True)
    loop = dataclasses.replace(COVISIBLE_CONFIG.loop, bow_covisible_window=2)
    config = dataclasses.replace(COVISIBLE_CONFIG, loop=loop)
    support = covisible_support(world_map, world_map.keyframes[CURRENT_SIDE[-1]], world_map.keyframes[0], check,
                                CAMERA, config, PoseOnlyOptions(), needed=3)
    assert support == 2
