"""`LoopClosing`'s correction of a verified loop on a hand-made chain of keyframes: every landmark moves
once, with its reference keyframe, its viewing direction turning with it, and the loop side's landmarks
are projected into the moved keyframes (`pld_slam.loop.loop_closing`)."""

import dataclasses
from types import SimpleNamespace

import numpy as np
from map_fixtures import CAMERA, camera_at, make_keyframe, random_descriptors, simple_features

from pld_slam.config import Config
from pld_slam.geometry.se3 import se3_exp, transform_points
from pld_slam.localisation.local_map import local_map_of
from pld_slam.loop import loop_closing
from pld_slam.loop.loop_closing import LoopClosing
from pld_slam.loop.verify import GeometricCheck, around, present_landmarks
from pld_slam.mapping.map import Map

N_KEYFRAMES, SHARED = 12, 20
"""Keyframe k observes points ``SHARED*k .. SHARED*k + 2*SHARED - 1``: it shares SHARED with each neighbour in
the chain and none with any other keyframe; a point's creator is the first keyframe observing it."""
CONFIG = dataclasses.replace(Config(), loop=dataclasses.replace(Config().loop, exclude_recent_keyframes=5))


def chain_map() -> Map:
    """Keyframes 0..N_KEYFRAMES-1 a metre apart along x, each seeing its 2*SHARED points 10 m ahead."""
    world_map = Map(covisibility_min_shared=SHARED)
    n_points = SHARED * (N_KEYFRAMES + 1)
    first = np.arange(n_points) // SHARED
    geometry = np.column_stack([first, np.tile(np.linspace(-2, 2, SHARED), N_KEYFRAMES + 1), np.full(n_points, 10.0)])
    ids = world_map.points.add(geometry, random_descriptors(n_points, seed=1), 0)
    world_map.points.writable("first_keyframe")[ids] = np.maximum(first - 1, 0)
    for k in range(N_KEYFRAMES):
        features = simple_features(2 * SHARED, seed=k)
        keyframe = make_keyframe(k, features, camera_at([k, 0.0, 0.0]), point_ids=np.arange(SHARED * k,
                                                                                              SHARED * (k + 2)))
        world_map.add_keyframe(keyframe)
        world_map.attach_to_tree(keyframe)
    return world_map


def close_loop(world_map: Map, correction: np.ndarray, matched: dict[int, int] | None = None) -> None:
    """Close the loop last keyframe -> keyframe 0, the geometric check placing the last keyframe at
    ``T_c_w @ correction`` ((4, 4)) against the candidate's local map (as `geometric_check` takes it)
    and matching its features to the loop side's points as ``matched`` (feature: point id; none by
    default)."""
    closing = LoopClosing(world_map, CAMERA, CONFIG)
    current, candidate = world_map.keyframes[N_KEYFRAMES - 1], world_map.keyframes[0]
    point_ids = np.full(len(current.point_ids), -1)
    point_ids[list((matched or {}).keys())] = list((matched or {}).values())
    found = SimpleNamespace(point_ids=point_ids, line_ids=np.full(0, -1))
    local_map = local_map_of(world_map, around(world_map, candidate), present_landmarks(world_map, current))
    check = GeometricCheck(T_c_w=current.T_c_w @ correction, matches=50, inliers=50, tracking=found,
                           local_map=local_map)
    closing._close(current, candidate, check)


def in_creator_frames(world_map: Map) -> np.ndarray:
    """(N, 3) each live point in its creating keyframe's camera frame."""
    points = world_map.points
    live = np.flatnonzero(points.alive)
    return np.array([transform_points(world_map.keyframes[int(points.first_keyframe[i])].T_c_w, points.geometry[i])
                     for i in live.tolist()])


def test_every_landmark_keeps_its_place_in_its_reference_keyframe_through_a_loop_correction():
    """Points of keyframe 9 seen by keyframe 10 (in the moved group) move once, with keyframe 9."""
    world_map = chain_map()
    before = in_creator_frames(world_map)
    close_loop(world_map, se3_exp(np.array([0.0, 0.0, 0.5, 0.0, 0.05, 0.0])))
    np.testing.assert_allclose(in_creator_frames(world_map), before, atol=1e-9)


def test_a_landmark_outside_the_moved_group_turns_its_viewing_direction_with_its_reference_keyframe():
    world_map = chain_map()
    points = world_map.points
    world_map.refresh_landmarks(points, np.flatnonzero(points.alive), CONFIG.points.scale_factor)
    outside = np.flatnonzero(points.alive)[: SHARED * (N_KEYFRAMES - 2)]  # not seen by keyframes 10 and 11

    def directions_in_creators() -> np.ndarray:
        rotations = np.array([world_map.keyframes[int(k)].T_c_w[:3, :3] for k in points.first_keyframe[outside]])
        return np.einsum("nij,nj->ni", rotations, points.normal[outside])

    before = directions_in_creators()
    close_loop(world_map, se3_exp(np.array([0.0, 0.0, 0.5, 0.0, 0.3, 0.0])))
    np.testing.assert_allclose(directions_in_creators(), before, atol=1e-9)


def test_the_loop_side_landmarks_the_current_side_did_not_observe_are_projected_into_the_moved_group(monkeypatch):
    """Fusing the check's inliers makes the current keyframe covisible with the candidate; the landmarks
    projected are still all of the check's local map (those of keyframes 0 and 1)."""
    world_map = chain_map()
    projected = []

    def recorded(fused_map, kind, keyframes, ids, camera, config):
        projected.append((kind, [k.id for k in keyframes], ids))
        return 0

    monkeypatch.setattr(loop_closing, "fuse", recorded)
    close_loop(world_map, np.eye(4), matched={f: f for f in range(SHARED)})
    points_call = next(call for call in projected if call[0] is world_map.points)
    assert points_call[1] == [N_KEYFRAMES - 1, N_KEYFRAMES - 2]
    np.testing.assert_array_equal(points_call[2], np.arange(3 * SHARED))  # keyframes 0 and 1 observe these
    assert set(world_map.points.observers[0]) == {0, N_KEYFRAMES - 2, N_KEYFRAMES - 1}  # fused with 11 and 10's point
