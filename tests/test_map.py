"""`Landmarks` columns and the `Map`: observations kept twice, links, culled keyframe poses, summaries."""

import numpy as np
import pytest
from map_fixtures import (
    add_landmarks,
    camera_at,
    camera_features,
    check_map_consistency,
    insert_observer,
    make_keyframe,
    random_descriptors,
    scene_lines,
    scene_points,
    simple_features,
)

from pld_slam.frontend.descriptors import hamming_distances
from pld_slam.geometry.se3 import inverse, se3_exp
from pld_slam.mapping.landmarks import LineLandmarks, PointLandmarks, predicted_octaves
from pld_slam.mapping.map import Map, representative_descriptors


def descriptor_with_bits(n_bits: int) -> np.ndarray:
    """(32,) uint8 descriptor whose first ``n_bits`` bits are set, the rest clear."""
    bits = np.zeros(256, dtype=np.uint8)
    bits[:n_bits] = 1
    return np.packbits(bits)


# --- Landmarks columns ----------------------------------------------------------------


def test_landmark_ids_are_rows_in_creation_order():
    points = PointLandmarks()
    first = points.add(scene_points(3, 0), random_descriptors(3, 1), first_keyframe=4)
    second = points.add(scene_points(2, 2), random_descriptors(2, 3), first_keyframe=5)
    assert first.tolist() == [0, 1, 2] and second.tolist() == [3, 4]
    assert len(points) == 5 and points.n_alive == 5
    assert points.first_keyframe.tolist() == [4, 4, 4, 5, 5]
    assert np.array_equal(points.geometry[3:], scene_points(2, 2))


def test_a_removed_landmark_keeps_its_row_and_its_id_is_never_reused():
    world_map = Map(covisibility_min_shared=20)
    add_landmarks(world_map, 3)
    world_map.remove_landmarks(world_map.points, np.array([1]))
    again = world_map.points.add(scene_points(2, 9), random_descriptors(2, 9), 0)
    assert again.tolist() == [3, 4]
    assert world_map.points.alive.tolist() == [True, False, True, True, True]
    assert len(world_map.points) == 5 and world_map.points.n_alive == 4


def test_columns_grow_past_the_initial_capacity_and_keep_their_values():
    points = PointLandmarks()
    first_geometry, first_descriptors = scene_points(200, 0), random_descriptors(200, 1)
    points.add(first_geometry, first_descriptors, first_keyframe=0)
    points.writable("found")[:200] = np.arange(200)
    points.writable("max_distance")[:200] = np.arange(200) + 0.5
    more = points.add(scene_points(700, 2), random_descriptors(700, 3), first_keyframe=1)
    assert more[0] == 200 and more[-1] == 899 and len(points) == 900
    assert np.array_equal(points.geometry[:200], first_geometry)
    assert np.array_equal(points.descriptor[:200], first_descriptors)
    assert np.array_equal(points.found[:200], np.arange(200))
    assert np.array_equal(points.max_distance[:200], np.arange(200) + 0.5)
    # New rows start from the columns' fills.
    assert np.all(points.found[200:] == 0) and np.all(np.isinf(points.max_distance[200:]))
    assert np.all(points.alive) and np.all(points.first_keyframe[200:] == 1)
    assert points.geometry.shape == (900, 3) and points.descriptor.shape == (900, 32)
    assert len(points.observers) == 900


def test_line_columns_hold_two_endpoints_per_landmark_and_grow_too():
    lines = LineLandmarks()
    segments = scene_lines(300, 0)
    ids = lines.add(segments, random_descriptors(300, 1), first_keyframe=2)
    assert ids.tolist() == list(range(300))
    assert lines.geometry.shape == (300, 2, 3)
    assert np.array_equal(lines.geometry, segments)
    np.testing.assert_allclose(lines.centres(np.array([0, 299])), segments[[0, 299]].mean(axis=1))


def test_live_treats_minus_one_out_of_range_and_dead_ids_as_no_landmark():
    points = PointLandmarks()
    points.add(scene_points(3, 0), random_descriptors(3, 1), 0)
    points.writable("alive")[1] = False
    assert points.live(np.array([-1, 0, 1, 2, 3, 500])).tolist() == [False, True, False, True, False, False]


def test_predicted_octaves_follow_the_distance_ratio_and_are_clipped_to_the_pyramid():
    max_distance = np.full(6, 10.0)
    distance = np.array([20.0, 10.0, 9.0, 10.0 / 1.3, 10.0 / 1.2 ** 5.5, 0.001])
    # ratios 0.5, 1, 1.11 (< 1.2), 1.3 (in (1.2, 1.44)), 1.2**5.5, 1e4
    assert predicted_octaves(max_distance, distance, 1.2, 8).tolist() == [0, 0, 1, 2, 6, 7]
    assert predicted_octaves(np.array([np.inf]), np.array([5.0]), 1.2, 8).tolist() == [7]


def test_a_point_is_predicted_at_the_octave_it_was_observed_at_from_the_same_distance():
    octaves = np.arange(8)
    for distance in (1.0, 3.7, 10.0):
        max_distance = distance * 1.2 ** octaves.astype(np.float64)  # as refresh_landmarks sets it
        predicted = predicted_octaves(max_distance, np.full(8, distance), 1.2, 8)
        assert predicted.tolist() == octaves.tolist()


# --- observations ---------------------------------------------------------------------


def test_add_keyframe_rejects_an_id_out_of_order():
    world_map = Map(covisibility_min_shared=20)
    with pytest.raises(ValueError, match="expected 0"):
        world_map.add_keyframe(make_keyframe(1, simple_features(2)))
    insert_observer(world_map)
    with pytest.raises(ValueError, match="expected 1"):
        world_map.add_keyframe(make_keyframe(0, simple_features(2)))
    assert list(world_map.keyframes) == [0] and world_map.next_keyframe_id() == 1


def test_add_keyframe_turns_tracked_ids_into_observations_and_clears_dead_and_repeated_ones():
    world_map = Map(covisibility_min_shared=20)
    points, lines = add_landmarks(world_map, 4, 2)
    world_map.points.writable("alive")[2] = False
    keyframe = insert_observer(world_map, point_ids=[0, -1, 2, 1, 0, 3], line_ids=[1, 0])
    assert keyframe.point_ids.tolist() == [0, -1, -1, 1, -1, 3]  # dead 2 and the second sighting of 0 cleared
    assert keyframe.line_ids.tolist() == [1, 0]
    assert [world_map.points.observers[i] for i in range(4)] == [{0: 0}, {0: 3}, {}, {0: 5}]
    assert world_map.points.n_observers.tolist() == [1, 1, 0, 1]
    assert world_map.lines.observers == [{0: 1}, {0: 0}]
    check_map_consistency(world_map)


def test_add_observations_keeps_both_copies_in_step():
    world_map = Map(covisibility_min_shared=20)
    add_landmarks(world_map, 5, 2)
    first = insert_observer(world_map, point_ids=[-1] * 4, line_ids=[-1, -1])
    world_map.add_observations(world_map.points, first, np.array([3, 0]), np.array([4, 1]))
    world_map.add_observations(world_map.lines, first, np.array([1]), np.array([0]))
    assert first.point_ids.tolist() == [1, -1, -1, 4]
    assert first.line_ids.tolist() == [-1, 0]
    assert world_map.points.observers[4] == {0: 3} and world_map.points.observers[1] == {0: 0}
    assert world_map.lines.observers[0] == {0: 1}
    assert world_map.points.n_observers.tolist() == [0, 1, 0, 0, 1]
    check_map_consistency(world_map)


def test_add_observations_skips_dead_landmarks_taken_features_and_a_second_feature_on_the_same_landmark():
    world_map = Map(covisibility_min_shared=20)
    add_landmarks(world_map, 4)
    keyframe = insert_observer(world_map, point_ids=[0, -1, -1, -1, -1])
    world_map.points.writable("alive")[3] = False
    world_map.add_observations(
        world_map.points, keyframe, np.array([0, 1, 2, 3]), np.array([1, 3, 2, 2])
    )
    # feature 0 already observes landmark 0; landmark 3 is dead; landmark 2 goes to feature 2 only.
    assert keyframe.point_ids.tolist() == [0, -1, 2, -1, -1]
    assert world_map.points.observers[:4] == [{0: 0}, {}, {0: 2}, {}]
    assert world_map.points.n_observers.tolist() == [1, 0, 1, 0]
    check_map_consistency(world_map)


def test_add_observations_gives_a_feature_listed_twice_in_one_call_to_one_landmark_only():
    world_map = Map(covisibility_min_shared=20)
    add_landmarks(world_map, 2)
    keyframe = insert_observer(world_map, point_ids=[-1, -1])
    world_map.add_observations(world_map.points, keyframe, np.array([0, 0]), np.array([0, 1]))
    assert keyframe.point_ids.tolist() == [0, -1]
    check_map_consistency(world_map)


def test_a_landmark_dies_when_its_last_observation_is_erased():
    world_map = Map(covisibility_min_shared=20)
    add_landmarks(world_map, 2)
    first = insert_observer(world_map, point_ids=[0, 1])
    second = insert_observer(world_map, point_ids=[0])
    world_map.erase_observations(world_map.points, first, np.array([0, 1]))
    assert first.point_ids.tolist() == [-1, -1]
    assert world_map.points.alive.tolist() == [True, False]  # 0 still seen by the second keyframe
    assert world_map.points.observers[:2] == [{1: 0}, {}]
    world_map.erase_observations(world_map.points, second, np.array([0, 0]))  # a repeat is harmless
    assert world_map.points.alive.tolist() == [False, False]
    assert world_map.points.n_observers.tolist() == [0, 0]
    check_map_consistency(world_map)


def test_remove_landmarks_clears_the_id_in_every_observing_keyframe():
    world_map = Map(covisibility_min_shared=20)
    add_landmarks(world_map, 3, 1)
    first = insert_observer(world_map, point_ids=[0, 1, 2], line_ids=[0])
    second = insert_observer(world_map, point_ids=[2, 1], line_ids=[0])
    world_map.remove_landmarks(world_map.points, np.array([1, 2]))
    world_map.remove_landmarks(world_map.lines, np.array([0]))
    assert first.point_ids.tolist() == [0, -1, -1] and second.point_ids.tolist() == [-1, -1]
    assert first.line_ids.tolist() == [-1] and second.line_ids.tolist() == [-1]
    assert world_map.points.alive.tolist() == [True, False, False]
    assert world_map.points.n_observers.tolist() == [1, 0, 0]
    assert not world_map.lines.alive[0]
    check_map_consistency(world_map)


def test_replace_landmark_moves_the_observations_adds_up_the_counts_and_keeps_the_longer_streak_and_later_motion():
    world_map = Map(covisibility_min_shared=20)
    add_landmarks(world_map, 2)
    points = world_map.points
    first = insert_observer(world_map, point_ids=[0, -1])  # sees old only
    both = insert_observer(world_map, point_ids=[0, 1])  # sees old and new
    third = insert_observer(world_map, point_ids=[-1, 1])  # sees new only
    points.writable("found")[:2] = [3, 4]
    points.writable("visible")[:2] = [5, 9]
    points.writable("dynamic_streak")[:2] = [3, 2]
    points.writable("moving_frame")[:2] = [12, 7]
    world_map.replace_landmark(points, old=0, new=1)
    assert first.point_ids.tolist() == [1, -1]
    assert both.point_ids.tolist() == [-1, 1]  # keeps its own observation of the new landmark
    assert third.point_ids.tolist() == [-1, 1]
    assert points.observers[1] == {both.id: 1, third.id: 1, first.id: 0}
    assert points.n_observers.tolist() == [0, 3]
    assert points.alive.tolist() == [False, True]
    assert points.found[1] == 7 and points.visible[1] == 14 and points.dynamic_streak[1] == 3
    assert points.moving_frame[1] == 12
    check_map_consistency(world_map)


def test_replacing_a_landmark_by_itself_changes_nothing():
    world_map = Map(covisibility_min_shared=20)
    add_landmarks(world_map, 1)
    keyframe = insert_observer(world_map, point_ids=[0])
    world_map.points.writable("found")[0] = 2
    world_map.replace_landmark(world_map.points, 0, 0)
    assert world_map.points.alive[0] and keyframe.point_ids.tolist() == [0] and world_map.points.found[0] == 2


def test_observation_table_lists_every_observation_grouped_by_landmark():
    world_map = Map(covisibility_min_shared=20)
    add_landmarks(world_map, 3)
    insert_observer(world_map, point_ids=[2, 0])
    insert_observer(world_map, point_ids=[-1, 2])
    rows, keyframes, features = world_map.observation_table(world_map.points, np.array([2, 1, 0]))
    assert rows.tolist() == [0, 0, 2]
    assert keyframes.tolist() == [0, 1, 0]
    assert features.tolist() == [0, 1, 1]
    assert rows.dtype == keyframes.dtype == features.dtype == np.int64


def test_observation_table_lists_the_keyframes_of_a_landmark_in_the_order_they_observed_it():
    world_map = Map(covisibility_min_shared=20)
    add_landmarks(world_map, 1)
    older = insert_observer(world_map, point_ids=[-1])
    insert_observer(world_map, point_ids=[0])
    world_map.add_observations(world_map.points, older, np.array([0]), np.array([0]))  # as fusion does
    _, keyframes, _ = world_map.observation_table(world_map.points, np.array([0]))
    assert keyframes.tolist() == [1, 0]


# --- covisibility links ---------------------------------------------------------------


def test_links_count_the_points_and_lines_shared_with_every_other_keyframe_as_observations_change():
    world_map = Map(covisibility_min_shared=3)
    add_landmarks(world_map, 6, 4)
    k0 = insert_observer(world_map, point_ids=[0, 1, 2, 3], line_ids=[0, 1])
    k1 = insert_observer(world_map, point_ids=[1, 2, 4], line_ids=[1, 2, 3])
    k2 = insert_observer(world_map, point_ids=[5, 2], line_ids=[3, 0])
    shared = world_map.covisibility.shared
    assert shared(k0.id) == {1: 2 + 1, 2: 1 + 1}
    assert shared(k1.id) == {0: 3, 2: 1 + 1}
    assert shared(k2.id) == {0: 2, 1: 2}
    k3 = insert_observer(world_map, point_ids=[4, 5])
    assert shared(k3.id) == {1: 1, 2: 1}
    assert shared(k1.id) == {0: 3, 2: 2, 3: 1}  # updated from k3's side
    world_map.erase_observations(world_map.points, k1, np.array([0]))  # k1 no longer sees point 1
    assert shared(k1.id) == {0: 2, 2: 2, 3: 1}
    assert shared(k0.id) == {1: 2, 2: 2}


def test_removing_landmarks_drops_the_links_they_made():
    world_map = Map(covisibility_min_shared=3)
    add_landmarks(world_map, 4, 1)
    k0 = insert_observer(world_map, point_ids=[0, 1, 2], line_ids=[0])
    k1 = insert_observer(world_map, point_ids=[0, 1, 3], line_ids=[0])
    assert world_map.covisibility.shared(k1.id) == {0: 3}
    world_map.remove_landmarks(world_map.points, np.array([0, 1]))
    assert world_map.covisibility.shared(k0.id) == {1: 1}
    assert world_map.covisibility.shared(k1.id) == {0: 1}
    world_map.remove_landmarks(world_map.lines, np.array([0]))
    assert world_map.covisibility.shared(k0.id) == {} and world_map.covisibility.shared(k1.id) == {}


# --- removing keyframes ---------------------------------------------------------------


def chain_map() -> tuple[Map, list]:
    """Keyframes 0 - 1 - 2 - 3, each the parent of the next, at different rotated poses."""
    world_map = Map(covisibility_min_shared=3)
    add_landmarks(world_map, 12)
    twists = [[0.0] * 6, [0.3, -0.1, 0.5, 0.05, -0.1, 0.08], [-0.4, 0.2, 1.1, -0.12, 0.2, 0.1],
              [0.1, 0.6, 1.4, 0.2, 0.05, -0.25]]
    poses = [se3_exp(np.array(twist)) for twist in twists]  # rotations about different axes: no two commute
    keyframes = [
        insert_observer(world_map, point_ids=[0, 1, 2, 3, 4], T_c_w=poses[0]),
        insert_observer(world_map, point_ids=[0, 1, 2, 3, 5, 6, 7, 8], T_c_w=poses[1]),
        insert_observer(world_map, point_ids=[0, 5, 6, 7, 8, 9, 10], T_c_w=poses[2]),
        insert_observer(world_map, point_ids=[9, 10, 11], T_c_w=poses[3]),
    ]
    assert world_map.covisibility.parent == {0: None, 1: 0, 2: 1, 3: 2}
    return world_map, keyframes


def test_removing_a_keyframe_erases_its_observations_and_kills_the_landmarks_only_it_saw():
    world_map, keyframes = chain_map()
    world_map.remove_keyframe(keyframes[3])
    assert 3 not in world_map.keyframes and 3 not in world_map.covisibility
    assert world_map.points.alive.tolist() == [True] * 11 + [False]
    assert world_map.points.observers[9] == {2: 5} and world_map.points.observers[11] == {}
    assert world_map.next_keyframe_id() == 4  # ids are not reused
    check_map_consistency(world_map)


def test_the_root_keyframe_cannot_be_removed():
    world_map, keyframes = chain_map()
    with pytest.raises(ValueError, match="root"):
        world_map.remove_keyframe(keyframes[0])
    assert 0 in world_map.keyframes and world_map.points.observers[4] == {0: 4}
    check_map_consistency(world_map)


def test_removing_a_keyframe_reattaches_its_children_in_the_map_tree():
    world_map, keyframes = chain_map()
    world_map.remove_keyframe(keyframes[1])
    assert world_map.covisibility.parent == {0: None, 2: 0, 3: 2}
    check_map_consistency(world_map)


def test_a_culled_keyframe_keeps_its_pose_and_follows_later_changes_of_its_parent():
    world_map, keyframes = chain_map()
    culled, parent = keyframes[3], keyframes[2]
    T_w_c_at_culling = culled.T_w_c
    world_map.remove_keyframe(culled)
    np.testing.assert_allclose(world_map.keyframe_T_w_c(culled.id), T_w_c_at_culling, atol=1e-12)
    relative = inverse(parent.T_w_c) @ T_w_c_at_culling
    corrected = se3_exp(np.array([0.4, 0.1, -0.2, 0.1, 0.2, -0.15])) @ parent.T_c_w  # a BA correction
    world_map.set_keyframe_poses(np.array([parent.id]), corrected[None])
    np.testing.assert_allclose(world_map.keyframe_T_w_c(culled.id), parent.T_w_c @ relative, atol=1e-12)
    np.testing.assert_allclose(world_map.keyframe_T_w_c(parent.id), parent.T_w_c, atol=1e-12)


def test_a_keyframe_culled_before_its_parent_keeps_its_pose_through_the_chain():
    world_map, keyframes = chain_map()
    T_w_c_at_culling = keyframes[3].T_w_c
    world_map.remove_keyframe(keyframes[3])  # parent 2
    world_map.remove_keyframe(keyframes[2])  # parent 1
    np.testing.assert_allclose(world_map.keyframe_T_w_c(3), T_w_c_at_culling, atol=1e-9)
    grandparent = keyframes[1]
    relative = inverse(grandparent.T_w_c) @ T_w_c_at_culling
    corrected = se3_exp(np.array([0.4, 0.1, -0.2, 0.1, 0.2, -0.15])) @ grandparent.T_c_w
    world_map.set_keyframe_poses(np.array([grandparent.id]), corrected[None])
    np.testing.assert_allclose(world_map.keyframe_T_w_c(3), grandparent.T_w_c @ relative, atol=1e-9)


def test_a_live_keyframe_pose_is_its_own():
    world_map, keyframes = chain_map()
    for keyframe in keyframes:
        np.testing.assert_allclose(world_map.keyframe_T_w_c(keyframe.id), keyframe.T_w_c, atol=1e-12)


# --- landmark summaries ---------------------------------------------------------------


def summary_map(descriptors: np.ndarray, octaves: list[int], centres: list) -> Map:
    """One point landmark at (0, 0, 10) seen by one keyframe per descriptor, from ``centres`` (world)."""
    world_map = Map(covisibility_min_shared=1)
    landmark_w = np.array([[0.0, 0.0, 10.0]])
    world_map.points.add(landmark_w, np.zeros((1, 32), dtype=np.uint8), 0)
    for descriptor, octave, centre in zip(descriptors, octaves, centres):
        T_c_w = camera_at(centre)
        features = camera_features(landmark_w - np.asarray(centre), descriptor[None], octave=np.array([octave]))
        keyframe = make_keyframe(world_map.next_keyframe_id(), features, T_c_w, point_ids=[0])
        world_map.add_keyframe(keyframe)
    return world_map


def test_refresh_points_the_normal_from_the_observers_to_the_landmark():
    centres = [[0.0, 0.0, 0.0], [3.0, 0.0, 6.0], [0.0, -5.0, 5.0]]
    world_map = summary_map(random_descriptors(3, 0), [0, 0, 0], centres)
    world_map.refresh_landmarks(world_map.points, np.array([0]), scale_factor=1.2)
    rays = np.array([[0, 0, 1.0], [-0.6, 0, 0.8], [0, np.sqrt(0.5), np.sqrt(0.5)]])  # camera -> landmark
    expected = rays.sum(axis=0) / np.linalg.norm(rays.sum(axis=0))
    np.testing.assert_allclose(world_map.points.normal[0], expected, atol=1e-12)
    assert np.isclose(np.linalg.norm(world_map.points.normal[0]), 1.0)


def test_refresh_sets_the_line_normal_from_the_observers_to_the_segment_midpoint():
    world_map = Map(covisibility_min_shared=1)
    segment_w = np.array([[[-1.0, 2.0, 8.0], [1.0, 2.0, 8.0]]])  # midpoint (0, 2, 8)
    world_map.lines.add(segment_w, random_descriptors(1, 0), 0)
    for centre in ([0.0, 2.0, 0.0], [0.0, 2.0, 4.0], [6.0, 2.0, 0.0]):
        segment_c = segment_w - np.asarray(centre)
        features = camera_features(np.zeros((0, 3)), np.zeros((0, 32), dtype=np.uint8), segment_c,
                                   random_descriptors(1, 0))
        world_map.add_keyframe(make_keyframe(world_map.next_keyframe_id(), features, camera_at(centre), line_ids=[0]))
    world_map.refresh_landmarks(world_map.lines, np.array([0]), scale_factor=1.2)
    expected = np.array([-0.6, 0.0, 2.8]) / np.linalg.norm([-0.6, 0.0, 2.8])  # (0,0,1) + (0,0,1) + (-.6,0,.8)
    np.testing.assert_allclose(world_map.lines.normal[0], expected, atol=1e-12)


def test_refresh_picks_one_of_the_observed_descriptors_and_the_middle_one_of_three_on_a_line():
    # Hamming distances: end_a - middle 20 bits, middle - end_b 40, end_a - end_b 60. With the lower
    # median (self included, as ORB-SLAM2) the middle ties with the nearer end (20 each): the middle
    # wins as it is listed first of the two; the farther end (40) never wins.
    end_a, middle, end_b = descriptor_with_bits(0), descriptor_with_bits(20), descriptor_with_bits(60)
    centres = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]]
    world_map = summary_map(np.array([end_b, middle, end_a]), [0, 0, 0], centres)
    world_map.refresh_landmarks(world_map.points, np.array([0]), scale_factor=1.2)
    assert np.array_equal(world_map.points.descriptor[0], middle)


def test_refresh_sets_the_max_distance_from_the_first_observer_and_its_octave():
    centres = [[0.0, 0.0, 2.0], [0.0, 0.0, 0.0]]  # 8 m away at octave 2, then 10 m at octave 0
    world_map = summary_map(random_descriptors(2, 0), [2, 0], centres)
    world_map.refresh_landmarks(world_map.points, np.array([0]), scale_factor=1.2)
    assert np.isclose(world_map.points.max_distance[0], 8.0 * 1.2 ** 2)


def test_refresh_leaves_landmarks_without_observers_alone():
    world_map = summary_map(random_descriptors(1, 0), [0], [[0.0, 0.0, 0.0]])
    world_map.points.add(np.array([[1.0, 1.0, 1.0]]), random_descriptors(1, 5), 0)
    world_map.refresh_landmarks(world_map.points, np.array([0, 1]), scale_factor=1.2)
    assert np.array_equal(world_map.points.normal[1], np.zeros(3))
    assert np.array_equal(world_map.points.descriptor[1], random_descriptors(1, 5)[0])
    np.testing.assert_allclose(world_map.points.normal[0], [0.0, 0.0, 1.0])


def test_representative_descriptors_on_a_hand_made_example():
    a, b, c, d, e = (descriptor_with_bits(n) for n in (0, 10, 30, 100, 8))
    # Group 0: a, b, c, d. Distances a-b 10, a-c 30, a-d 100, b-c 20, b-d 90, c-d 70.
    # Lower medians (self included, as ORB-SLAM2): a 10, b 10, c 20, d 70 -> a and b tie, a listed first.
    # Group 1: d alone. Group 2: c, b, e: c-b 20, c-e 22, b-e 2 -> c 20, b 2, e 2 -> b, listed before e.
    rows = np.array([0, 0, 0, 0, 1, 2, 2, 2])
    descriptors = np.array([a, b, c, d, d, c, b, e])
    chosen = representative_descriptors(rows, descriptors, 3)
    assert np.array_equal(chosen, np.array([a, d, b]))


def test_representative_descriptors_match_a_brute_force_median_per_group():
    rng = np.random.default_rng(7)
    sizes = rng.integers(1, 9, size=40)
    rows = np.repeat(np.arange(len(sizes)), sizes)
    # Descriptors near a few centres, so that medians differ and ties are rare but possible.
    centres = random_descriptors(4, 8)
    noise = np.packbits(rng.random((len(rows), 256)) < 0.1, axis=1)
    descriptors = centres[rng.integers(0, 4, len(rows))] ^ noise
    chosen = representative_descriptors(rows, descriptors, len(sizes))
    start = 0
    for group, size in enumerate(sizes.tolist()):
        members = descriptors[start : start + size]
        medians = []
        for member in members:
            distances = np.sort(hamming_distances(np.repeat(member[None], size, axis=0), members))
            medians.append(distances[(size - 1) // 2])
        assert np.array_equal(chosen[group], members[int(np.argmin(medians))]), f"group {group}"
        start += size
