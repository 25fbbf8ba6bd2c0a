"""`LocalMapping` on hand-made keyframes: landmark creation, recent-landmark and dynamic culling,
keyframe culling; and the map invariants after a short synthetic run with mapping on.

The keyframes see exact stereo features of a few world points and segments
(`map_fixtures`), so fusion and local BA have nothing to correct; each test follows
one step of `pld_slam.mapping.local_mapping` (step 4's reprojection test:
`pld_slam.matching.fusion`).
"""

import dataclasses

import numpy as np
import pytest
from map_fixtures import (
    CAMERA,
    check_map_consistency,
    empty_features,
    make_keyframe,
    pose_near_origin,
    random_descriptors,
    reaches_root,
    scene_lines,
    scene_points,
    world_features,
)

from pld_slam.config import Config, load_config
from pld_slam.datasets import open_sequence
from pld_slam.geometry.se3 import inverse, transform_points
from pld_slam.mapping.local_mapping import LocalMapping
from pld_slam.mapping.map import Map
from pld_slam.matching.fusion import line_reprojects
from pld_slam.synth import write_sequence
from pld_slam.system import System

N_POINTS, N_LINES = 30, 6
POINTS_W = scene_points(N_POINTS, seed=1)
LINES_W = scene_lines(N_LINES, seed=2)
POINT_DESCRIPTORS = random_descriptors(N_POINTS, seed=3)
LINE_DESCRIPTORS = random_descriptors(N_LINES, seed=4)
POSES = [pose_near_origin(seed) for seed in range(10, 20)]


def config_with(**mapping) -> Config:
    """Default configuration with ``mapping`` fields replaced."""
    config = Config()
    return dataclasses.replace(config, mapping=dataclasses.replace(config.mapping, **mapping))


def local_mapping(config: Config | None = None) -> LocalMapping:
    config = config or Config()
    return LocalMapping(Map(config.mapping.covisibility_min_shared), CAMERA, config)


def keyframe_seeing(
    mapping: LocalMapping,
    points=(),
    lines=(),
    tracked_points=None,
    tracked_lines=None,
    **labels,
):
    """The map's next keyframe, seeing world points ``points`` and segments ``lines`` (indices into
    POINTS_W / LINES_W) from pose ``POSES[its id]``; ``tracked_*`` gives the
    landmark tracking matched to each feature (-1: none)."""
    keyframe_id = mapping.map.next_keyframe_id()
    T_c_w = POSES[keyframe_id]
    points, lines = list(points), list(lines)
    features = world_features(
        T_c_w, POINTS_W[points].reshape(-1, 3), POINT_DESCRIPTORS[points], LINES_W[lines].reshape(-1, 2, 3),
        LINE_DESCRIPTORS[lines],
    )
    return make_keyframe(keyframe_id, features, T_c_w, tracked_points, tracked_lines, **labels)


def empty_keyframe(mapping: LocalMapping):
    """The map's next keyframe, without a single feature."""
    keyframe_id = mapping.map.next_keyframe_id()
    return make_keyframe(keyframe_id, empty_features(), POSES[keyframe_id])


def landmark_of(mapping: LocalMapping, keyframe_id: int, point: int) -> int:
    """The landmark that ``keyframe_id``'s feature of world point ``point`` observes (its features
    follow the order the keyframe was built with)."""
    return int(mapping.map.keyframes[keyframe_id].point_ids[point])


# --- local BA cadence ------------------------------------------------------------------


@pytest.mark.parametrize("min_frames, adjusted", [(1, [False, True, True, True]), (2, [False, True, False, True])])
def test_local_ba_skips_a_keyframe_that_follows_the_last_adjusted_one_too_closely(min_frames, adjusted):
    """Keyframes at frames 0-3 track the first one's landmarks; the first has nothing to adjust yet."""
    mapping = local_mapping(config_with(local_ba_min_frames=min_frames))
    insertions = [mapping.insert_keyframe(keyframe_seeing(mapping, points=range(N_POINTS)))]
    for _ in range(3):
        keyframe = keyframe_seeing(mapping, points=range(N_POINTS), tracked_points=range(N_POINTS))
        insertions.append(mapping.insert_keyframe(keyframe))
    assert [insertion.local_ba is not None for insertion in insertions] == adjusted


# --- landmark creation ----------------------------------------------------------------


def test_features_whose_reference_match_the_pose_rejected_make_no_landmark():
    mapping = local_mapping()
    features = world_features(POSES[0], POINTS_W[:6], POINT_DESCRIPTORS[:6], LINES_W[:3], LINE_DESCRIPTORS[:3])
    keyframe = make_keyframe(0, features, POSES[0], point_rejected=[1, 4], line_rejected=[2])
    insertion = mapping.insert_keyframe(keyframe)
    assert (insertion.created_points, insertion.created_lines) == (4, 2)
    assert keyframe.point_ids.tolist() == [0, -1, 1, 2, -1, 3]
    assert keyframe.line_ids.tolist() == [0, 1, -1]


def test_the_first_keyframe_creates_a_landmark_from_every_static_stereo_point_and_line():
    mapping = local_mapping()
    features = world_features(
        POSES[0], POINTS_W[:6], POINT_DESCRIPTORS[:6], LINES_W[:3], LINE_DESCRIPTORS[:3],
        mono_uv=np.array([[50.0, 60.0], [200.0, 100.0]]), mono_descriptors=random_descriptors(2, 99),
    )
    keyframe = make_keyframe(0, features, POSES[0], point_dynamic=[2], line_dynamic=[1])
    insertion = mapping.insert_keyframe(keyframe)
    assert insertion.keyframe == 0
    assert (insertion.created_points, insertion.created_lines) == (5, 2)
    # Stereo points 0, 1, 3, 4, 5 get landmarks; the dynamic point 2 and the two monocular keypoints none.
    assert keyframe.point_ids.tolist() == [0, 1, -1, 2, 3, 4, -1, -1]
    assert keyframe.line_ids.tolist() == [0, -1, 1]
    points, lines = mapping.map.points, mapping.map.lines
    assert points.n_alive == 5 and lines.n_alive == 2
    assert points.observers[:5] == [{0: 0}, {0: 1}, {0: 3}, {0: 4}, {0: 5}]
    assert lines.observers == [{0: 0}, {0: 2}]
    assert np.all(points.first_keyframe == 0) and np.all(lines.first_keyframe == 0)
    assert np.array_equal(points.descriptor, POINT_DESCRIPTORS[[0, 1, 3, 4, 5]])
    assert np.array_equal(lines.descriptor, LINE_DESCRIPTORS[[0, 2]])
    assert insertion.local_ba is None  # nothing seen twice yet
    check_map_consistency(mapping.map)


def test_new_landmarks_are_placed_in_the_world_through_the_keyframe_pose():
    mapping = local_mapping()
    T_c_w = pose_near_origin(seed=5, scale=2.0)
    assert not np.allclose(T_c_w, np.eye(4), atol=0.05)
    features = world_features(T_c_w, POINTS_W, POINT_DESCRIPTORS, LINES_W, LINE_DESCRIPTORS)
    mapping.insert_keyframe(make_keyframe(0, features, T_c_w))
    np.testing.assert_allclose(mapping.map.points.geometry, POINTS_W, atol=1e-9)
    np.testing.assert_allclose(mapping.map.lines.geometry, LINES_W, atol=1e-9)
    # Normals point from the camera to the landmark, unit length.
    camera_centre = np.linalg.inv(T_c_w)[:3, 3]
    rays = POINTS_W - camera_centre
    np.testing.assert_allclose(mapping.map.points.normal, rays / np.linalg.norm(rays, axis=1, keepdims=True),
                               atol=1e-9)
    # The max distance of an octave-0 observation is its distance.
    np.testing.assert_allclose(mapping.map.points.max_distance, np.linalg.norm(rays, axis=1), atol=1e-9)


def test_a_later_keyframe_creates_landmarks_only_for_the_stereo_features_tracking_did_not_match():
    mapping = local_mapping(config_with(covisibility_min_shared=5))
    mapping.insert_keyframe(keyframe_seeing(mapping, points=range(0, 20), lines=range(0, 3)))
    tracked = np.arange(10)  # of its 15 points, the first 10 are landmarks 0..9 (from keyframe 0)
    second = keyframe_seeing(
        mapping, points=[*range(10), *range(20, 25)], lines=[0, 1, 3, 4],
        tracked_points=[*tracked, -1, -1, -1, -1, -1], tracked_lines=[0, 1, -1, -1],
        point_dynamic=[13], line_dynamic=[3],
    )
    insertion = mapping.insert_keyframe(second)
    assert (insertion.created_points, insertion.created_lines) == (4, 1)  # 20..24 minus dynamic 23; line 3
    assert second.point_ids[:10].tolist() == tracked.tolist()
    assert second.point_ids[10:].tolist() == [20, 21, 22, -1, 23]
    assert second.line_ids.tolist() == [0, 1, 3, -1]
    points = mapping.map.points
    assert all(points.observers[i] == {0: i, 1: i} for i in range(10))
    assert all(points.observers[i] == {0: i} for i in range(10, 20))
    assert points.first_keyframe[20:].tolist() == [1, 1, 1, 1]
    np.testing.assert_allclose(points.geometry[[20, 21, 22, 23]], POINTS_W[[20, 21, 22, 24]], atol=1e-6)
    assert mapping.map.covisibility.shared(1) == {0: 10 + 2}
    check_map_consistency(mapping.map)


def test_the_neighbour_search_adds_the_observations_tracking_missed():
    mapping = local_mapping(config_with(covisibility_min_shared=5))
    mapping.insert_keyframe(keyframe_seeing(mapping, points=range(20), lines=range(4)))
    # The second keyframe sees the same points and lines, but tracking matched only half of them.
    second = keyframe_seeing(
        mapping, points=range(20), lines=range(4), tracked_points=[*range(10), *[-1] * 10],
        tracked_lines=[0, 1, -1, -1],
    )
    insertion = mapping.insert_keyframe(second)
    # The unmatched features first got landmarks of their own, then were fused with keyframe 0's:
    # each world point is one live landmark seen by both keyframes.
    assert insertion.created_points == 10 and insertion.created_lines == 2
    assert insertion.fused == 12
    points, lines = mapping.map.points, mapping.map.lines
    assert points.n_alive == 20 and lines.n_alive == 4
    assert second.point_ids.tolist() == list(range(20)) and second.line_ids.tolist() == [0, 1, 2, 3]
    assert all(points.n_observers[i] == 2 for i in range(20))
    assert mapping.map.covisibility.shared(1) == {0: 24}
    check_map_consistency(mapping.map)


# --- culling recent landmarks ---------------------------------------------------------


def mapping_with_old_landmarks(config: Config, points=(), lines=()) -> LocalMapping:
    """A local mapping whose first keyframe made landmarks of ``points`` and ``lines``, followed by three empty
    keyframes: the landmarks are no longer recent, so only the rules for landmarks of any age can remove them."""
    mapping = local_mapping(config)
    mapping.insert_keyframe(keyframe_seeing(mapping, points=points, lines=lines))
    for _ in range(3):
        mapping.insert_keyframe(empty_keyframe(mapping))
    return mapping


def sighted(sightings: dict[str, list[str]], frame: int, marks: str) -> tuple[np.ndarray, np.ndarray]:
    """(point ids, line ids) whose sighting in ``frame`` is one of ``marks``; ``sightings`` holds one string per
    landmark of each kind ("points", "lines"), a character per frame."""
    return tuple(np.array([k for k, seen in enumerate(sightings[kind]) if seen[frame] in marks], dtype=np.int64)
                 for kind in ("points", "lines"))


def test_fusion_tests_a_line_in_both_images_as_the_solvers_measure_it():
    """A segment moved along the viewing rays keeps its left-image projection; the right image
    shows its wrong depth, and fusion refuses it."""
    mapping = local_mapping()
    keyframe = keyframe_seeing(mapping, lines=range(N_LINES))
    truth = LINES_W.reshape(-1, 2, 3)
    centre = inverse(keyframe.T_c_w)[:3, 3]
    farther = centre + 2.0 * (truth - centre)  # the same rays, twice as deep
    features = np.arange(N_LINES)
    assert line_reprojects(keyframe, truth, features, CAMERA, Config().tracking).all()
    assert not line_reprojects(keyframe, farther, features, CAMERA, Config().tracking).any()


def test_a_recent_landmark_found_in_fewer_than_a_quarter_of_the_frames_that_should_see_it_is_culled():
    mapping = local_mapping()
    mapping.insert_keyframe(keyframe_seeing(mapping, points=range(4)))
    nothing = np.zeros(0, dtype=np.int64)
    for frame in range(8):
        found = [landmark for landmark, times in ((0, 2), (1, 1), (2, 8)) if frame < times]
        mapping.record_tracking(
            visible=(np.array([0, 1, 2]), nothing), found=(np.array(found, dtype=np.int64), nothing),
            missed=(nothing, nothing), dynamic=(nothing, nothing),
        )
    points = mapping.map.points
    assert points.visible.tolist() == [8, 8, 8, 0] and points.found.tolist() == [2, 1, 8, 0]
    insertion = mapping.insert_keyframe(empty_keyframe(mapping))
    # 2 of 8 is a quarter (kept); 1 of 8 is not; a landmark never predicted in view is not judged.
    assert points.alive.tolist() == [True, False, True, True]
    assert insertion.culled_landmarks == 1
    assert mapping.map.keyframes[0].point_ids.tolist() == [0, -1, 2, 3]
    check_map_consistency(mapping.map)


def test_a_landmark_whose_observations_weigh_too_little_two_keyframes_after_its_creation_is_culled():
    mapping = local_mapping(config_with(covisibility_min_shared=2))
    mapping.insert_keyframe(keyframe_seeing(mapping, points=range(6)))
    # Keyframe 1 sees points 0..3, keyframe 2 sees 0 and 1, all in stereo (weight 2 each):
    # weights 6, 6, 4, 4, 2, 2; the default bound keeps two stereo keyframes' landmarks.
    first = mapping.insert_keyframe(keyframe_seeing(mapping, points=range(4), tracked_points=range(4)))
    assert first.culled_landmarks == 0 and mapping.map.points.n_alive == 6  # one keyframe later: none yet
    second = mapping.insert_keyframe(keyframe_seeing(mapping, points=[0, 1], tracked_points=[0, 1]))
    points = mapping.map.points
    assert second.culled_landmarks == 2 and second.created_points == 0
    assert points.alive.tolist() == [True, True, True, True, False, False]
    assert mapping.map.keyframes[0].point_ids.tolist() == [0, 1, 2, 3, -1, -1]
    check_map_consistency(mapping.map)


def test_a_left_image_only_observation_weighs_half_a_stereo_one():
    mapping = local_mapping(config_with(covisibility_min_shared=1))
    mapping.insert_keyframe(keyframe_seeing(mapping, points=range(3)))
    # Keyframe 1 sees point 0 in stereo and point 1 in its left image only (a keypoint without
    # a stereo match tracked to landmark 1): weights 4, 3, 2.
    keyframe_id = mapping.map.next_keyframe_id()
    features = world_features(
        POSES[keyframe_id], POINTS_W[[0]], POINT_DESCRIPTORS[[0]],
        mono_uv=CAMERA.project(transform_points(POSES[keyframe_id], POINTS_W[[1]])),
        mono_descriptors=POINT_DESCRIPTORS[[1]],
    )
    mapping.insert_keyframe(make_keyframe(keyframe_id, features, POSES[keyframe_id], point_ids=[0, 1]))
    assert mapping.map.observation_weights(mapping.map.points, np.arange(3)).tolist() == [4, 3, 2]
    mapping.insert_keyframe(empty_keyframe(mapping))
    assert mapping.map.points.alive.tolist() == [True, False, False]
    check_map_consistency(mapping.map)


@pytest.mark.parametrize("age", [None, 1, 3])
def test_the_observation_weight_is_judged_two_keyframes_after_creation_not_one(age):
    """``mapping.min_observation_age`` keyframes after creation (2 by default), not before."""
    config = config_with(min_observation_weight=4, **({} if age is None else {"min_observation_age": age}))
    mapping = local_mapping(config)
    mapping.insert_keyframe(keyframe_seeing(mapping, points=range(3)))
    for _ in range(config.mapping.min_observation_age - 1):
        mapping.insert_keyframe(empty_keyframe(mapping))
        assert mapping.map.points.n_alive == 3
    mapping.insert_keyframe(empty_keyframe(mapping))
    assert mapping.map.points.n_alive == 0


@pytest.mark.parametrize(("recent_keyframes", "culled"), [(None, []), (5, [0])])
def test_a_landmark_stops_being_recent_three_keyframes_after_its_creation(recent_keyframes, culled):
    """... after ``mapping.recent_landmark_keyframes`` (3 by default): at 5, three keyframes later the
    landmark is still recent, and culled as rarely found."""
    more = {} if recent_keyframes is None else {"recent_landmark_keyframes": recent_keyframes}
    mapping = mapping_with_old_landmarks(config_with(min_observation_weight=1, max_missed_frames=0, **more),
                                         points=range(2))
    nothing = np.zeros(0, dtype=np.int64)
    for _ in range(10):  # visible, never found: would be culled if still recent
        mapping.record_tracking(
            visible=(np.array([0]), nothing), found=(nothing, nothing), missed=(np.array([0]), nothing),
            dynamic=(nothing, nothing),
        )
    insertion = mapping.insert_keyframe(empty_keyframe(mapping))
    assert insertion.culled_landmarks == len(culled)
    assert np.flatnonzero(~mapping.map.points.alive[:2]).tolist() == culled


def test_a_landmark_seen_moving_in_two_frames_since_it_was_last_found_static_is_removed():
    mapping = mapping_with_old_landmarks(config_with(min_observation_weight=1, dynamic_streak=2, dynamic_memory=0),
                                         points=range(5), lines=range(2))
    # What tracking saw of each point, frame by frame: found static (F), seen moving (M), or neither (-).
    # A parked car found for long, then moving (0); moving twice, found in between (1); moving twice
    # with a miss between (2); moving once (3); found throughout (4).
    sightings = ["FFFFFMM", "MFM----", "M-M----", "M------", "FFFFFFF"]
    nothing = np.zeros(0, dtype=np.int64)
    for frame in range(7):
        found = np.array([p for p, seen in enumerate(sightings) if seen[frame] == "F"], dtype=np.int64)
        moving = np.array([p for p, seen in enumerate(sightings) if seen[frame] == "M"], dtype=np.int64)
        moving_line = np.array([0] if frame < 2 else [], dtype=np.int64)
        mapping.record_tracking(
            visible=(np.arange(5), np.arange(2)), found=(found, nothing), missed=(nothing, nothing),
            dynamic=(moving, moving_line),
        )
    insertion = mapping.insert_keyframe(empty_keyframe(mapping))
    assert mapping.map.points.alive.tolist() == [False, True, False, True, True]
    assert mapping.map.lines.alive.tolist() == [False, True]
    assert insertion.culled_landmarks == 3
    check_map_consistency(mapping.map)


def test_a_find_soon_after_a_landmark_was_seen_moving_does_not_end_its_dynamic_streak():
    mapping = mapping_with_old_landmarks(config_with(min_observation_weight=1, dynamic_streak=2, dynamic_memory=3),
                                         points=range(3), lines=range(1))
    # Seen moving (M), found static (F), neither (-). A slow mover found in the 3 frames after it was
    # seen moving, then seen moving again (point 0, line 0); found 4 frames after, which clears the
    # streak (point 1); found throughout (point 2).
    sightings = {"points": ["MFFM--", "MFFFFM", "FFFFFF"], "lines": ["MFFM--"]}
    nothing = np.zeros(0, dtype=np.int64)
    for frame in range(6):
        mapping.record_tracking(visible=sighted(sightings, frame, "F"), found=sighted(sightings, frame, "F"),
                                missed=(nothing, nothing), dynamic=sighted(sightings, frame, "M"))
    insertion = mapping.insert_keyframe(empty_keyframe(mapping))
    assert mapping.map.points.alive.tolist() == [False, True, True]
    assert mapping.map.lines.alive.tolist() == [False]
    assert insertion.culled_landmarks == 2
    assert mapping.map.points.dynamic_streak[1] == 1
    check_map_consistency(mapping.map)


def test_the_feature_of_a_landmark_removed_as_moving_is_not_mapped_again_by_the_same_keyframe():
    """A slow mover found static within the dynamic memory is tracked by the new keyframe; the
    landmark goes for its streak, and its feature there must not start a fresh landmark (one
    without the streak) at the mover."""
    mapping = local_mapping(config_with(dynamic_streak=2, dynamic_memory=10))
    mapping.insert_keyframe(keyframe_seeing(mapping, points=range(5)))
    nothing, first = np.zeros(0, dtype=np.int64), np.array([0])
    for found, moving in [(np.arange(1, 5), first), (np.arange(1, 5), first), (np.arange(5), nothing)]:
        mapping.record_tracking(visible=(np.arange(5), nothing), found=(found, nothing),
                                missed=(nothing, nothing), dynamic=(moving, nothing))
    keyframe = keyframe_seeing(mapping, points=range(5), tracked_points=[0, 1, 2, 3, 4])
    insertion = mapping.insert_keyframe(keyframe)
    assert not mapping.map.points.alive[0]
    assert insertion.created_points == 0
    assert keyframe.point_ids[0] == -1
    check_map_consistency(mapping.map)


def test_a_landmark_of_any_age_missed_in_max_missed_frames_tracked_frames_in_a_row_is_removed():
    mapping = mapping_with_old_landmarks(config_with(min_observation_weight=1, max_missed_frames=4),
                                         points=range(4), lines=range(2))
    # What tracking did with each landmark, frame by frame: found (F), missed in view (x), or
    # neither, out of view (-). Four misses in a row (point 0, line 0); four misses broken by a find
    # (point 1); four misses with frames out of view between them, which count for nothing (point 2);
    # found throughout (point 3).
    sightings = {"points": ["FFxxxx", "xxFxxx", "xx--xx", "FFFFFF"], "lines": ["FFxxxx", "FFFFFF"]}
    nothing = np.zeros(0, dtype=np.int64)
    for frame in range(6):
        mapping.record_tracking(visible=sighted(sightings, frame, "Fx"), found=sighted(sightings, frame, "F"),
                                missed=sighted(sightings, frame, "x"), dynamic=(nothing, nothing))
    insertion = mapping.insert_keyframe(empty_keyframe(mapping))
    assert mapping.map.points.alive.tolist() == [False, True, False, True]
    assert mapping.map.lines.alive.tolist() == [False, True]
    assert insertion.culled_landmarks == 3
    assert mapping.map.points.missed_streak[[1, 3]].tolist() == [3, 0]
    check_map_consistency(mapping.map)


def test_max_missed_frames_zero_never_removes_a_missed_landmark():
    mapping = mapping_with_old_landmarks(config_with(min_observation_weight=1, max_missed_frames=0), points=range(2))
    nothing = np.zeros(0, dtype=np.int64)
    for _ in range(50):
        mapping.record_tracking(visible=(nothing, nothing), found=(nothing, nothing), missed=(np.array([0]), nothing),
                                dynamic=(nothing, nothing))
    mapping.insert_keyframe(empty_keyframe(mapping))
    assert mapping.map.points.alive.tolist() == [True, True]


def test_culling_a_landmark_two_keyframes_share_lowers_their_link():
    mapping = local_mapping(config_with(covisibility_min_shared=2))
    mapping.insert_keyframe(keyframe_seeing(mapping, points=range(5)))
    mapping.insert_keyframe(keyframe_seeing(mapping, points=range(5), tracked_points=range(5)))
    assert mapping.map.covisibility.shared(0) == {1: 5}
    nothing = np.zeros(0, dtype=np.int64)
    for _ in range(8):  # landmark 0: visible, never found
        mapping.record_tracking(
            visible=(np.array([0]), nothing), found=(nothing, nothing), missed=(np.array([0]), nothing),
            dynamic=(nothing, nothing),
        )
    mapping.insert_keyframe(empty_keyframe(mapping))
    assert not mapping.map.points.alive[0]
    assert mapping.map.covisibility.shared(0) == {1: 4}


# --- culling keyframes ----------------------------------------------------------------


def test_a_keyframe_whose_landmarks_three_other_keyframes_see_is_culled_but_never_the_first():
    mapping = local_mapping()
    mapping.insert_keyframe(keyframe_seeing(mapping, points=range(N_POINTS), lines=range(N_LINES)))
    culled = []
    for _ in range(4):
        keyframe = keyframe_seeing(
            mapping, points=range(N_POINTS), lines=range(N_LINES), tracked_points=range(N_POINTS),
            tracked_lines=range(N_LINES),
        )
        culled.append(mapping.insert_keyframe(keyframe).culled_keyframes)
    # Keyframe 3 makes every landmark seen by 4 keyframes: keyframe 1 has 3 other observers for each
    # (culled); then keyframe 2 has only 2. Keyframe 4 brings keyframe 2 back to 3 others. Keyframe 0
    # is redundant as often but is the first.
    assert culled == [(), (), (1,), (2,)]
    assert list(mapping.map.keyframes) == [0, 3, 4]
    assert all(obs.keys() == {0, 3, 4} for obs in mapping.map.points.observers)
    assert mapping.map.points.n_alive == N_POINTS and mapping.map.lines.n_alive == N_LINES
    check_map_consistency(mapping.map)
    # The culled keyframes keep their poses (nothing moved them).
    for keyframe_id in (1, 2):
        np.testing.assert_allclose(mapping.map.keyframe_T_w_c(keyframe_id), np.linalg.inv(POSES[keyframe_id]),
                                   atol=1e-6)


def test_a_keyframe_with_more_than_a_tenth_of_its_landmarks_seen_by_too_few_others_is_kept():
    mapping = local_mapping(config_with(min_observation_weight=1))
    shared = range(20)
    mapping.insert_keyframe(keyframe_seeing(mapping, points=shared))
    # Keyframe 1 also sees 3 points nobody else sees: 20 of 23 redundant (87 %) is not enough.
    mapping.insert_keyframe(
        keyframe_seeing(mapping, points=[*shared, 25, 26, 27], tracked_points=[*shared, -1, -1, -1])
    )
    insertions = [
        mapping.insert_keyframe(keyframe_seeing(mapping, points=shared, tracked_points=shared)) for _ in range(2)
    ]
    # Keyframe 3 makes keyframe 2 (only shared points) redundant, never keyframe 1.
    assert [i.culled_keyframes for i in insertions] == [(), (2,)]
    assert 1 in mapping.map.keyframes
    assert mapping.map.points.n_alive == 23


def test_a_keyframe_inserted_without_shared_landmarks_joins_the_tree_under_the_root_side():
    mapping = local_mapping(config_with(covisibility_min_shared=5, min_observation_weight=1))
    mapping.insert_keyframe(keyframe_seeing(mapping, points=range(0, 10)))
    # After a fast turn: keyframe 1 sees none of keyframe 0's points.
    mapping.insert_keyframe(keyframe_seeing(mapping, points=range(10, 20)))
    assert mapping.map.covisibility.parent[1] is None
    # Keyframe 2 tracks keyframe 1's landmarks, and a few of keyframe 0's.
    tracked = [landmark_of(mapping, 1, i) for i in range(10)] + [0, 1]
    mapping.insert_keyframe(keyframe_seeing(mapping, points=[*range(10, 20), 0, 1], tracked_points=tracked))
    graph = mapping.map.covisibility
    assert graph.shared(2) == {0: 2, 1: 10}
    # Found: keyframe 2 took 1 as parent, then 1 (first linked while fusing) took 2: 1 -> 2 -> 1.
    assert all(reaches_root(graph, keyframe) for keyframe in mapping.map.keyframes)


# --- a short run ----------------------------------------------------------------------


@pytest.fixture(scope="module")
def mapped_run(tmp_path_factory):
    """A run with mapping on over a short synthetic street (``static``, 10 frames, 320 x 240)."""
    folder = tmp_path_factory.mktemp("local_mapping") / "static"
    write_sequence(folder, "static", 10, (320, 240), seed=0)
    return System(open_sequence(folder), load_config()).run()


def test_a_mapped_run_keeps_the_map_consistent(mapped_run):
    world_map = mapped_run.map
    assert len(mapped_run.insertions) >= 3
    assert world_map.points.n_alive > 0 and world_map.lines.n_alive > 0
    check_map_consistency(world_map)
    assert all(world_map.covisibility.shared(k) for k in world_map.keyframes)  # no keyframe left unlinked
    # Every keyframe inserted is in the map or was reported culled.
    assert sum(len(i.culled_keyframes) for i in mapped_run.insertions) == len(mapped_run.insertions) - len(
        world_map.keyframes
    )

