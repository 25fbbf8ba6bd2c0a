"""The ``city`` scenario (issue 40): deterministic, about 1 m per frame on the streets of the
grid, revisits in both directions within the fewest frames, traffic that keeps clear of us,
and the view-distance culling that keeps a frame's cost flat."""

from functools import cache

import numpy as np
import pytest

from pld_slam.errors import PldSlamError
from pld_slam.synth import MIN_FRAMES, build_scenario
from pld_slam.synth.city import BLOCK, HALF_ROAD, VIEW_DISTANCE, city_grid, revisit_pairs
from pld_slam.synth.scenarios import CAMERA_HEIGHT
from pld_slam.synth.scene import STATIC_OBJECT, QuadGrid, Quads, ground_boxes, wall

TINY = (160, 120)
FEWEST = MIN_FRAMES["city"][0]


@cache
def city(n_frames: int = FEWEST, seed: int = 0, size=TINY):
    return build_scenario("city", n_frames, size, seed)


def test_two_builds_give_the_same_poses_and_frames_and_another_seed_another_city():
    first, again, other = (build_scenario("city", FEWEST, TINY, seed) for seed in (1, 1, 2))
    np.testing.assert_array_equal(first.poses, again.poses)
    a, b, c = (world.render_frame(450) for world in (first, again, other))
    for name in ("left", "right", "dynamic_mask"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert np.abs(a.left.astype(int) - c.left).mean() > 5.0


def test_the_fewest_frames_hold_a_same_direction_and_an_opposite_direction_revisit():
    world = city()
    assert world.n_frames == FEWEST
    same = revisit_pairs(world.poses, 100, opposite=False)
    opposite = revisit_pairs(world.poses, 100, opposite=True)
    assert len(same) >= 10 and len(opposite) >= 10  # a second of each at least
    for earlier, later in same:
        distance = np.linalg.norm(world.poses[later, :3, 3] - world.poses[earlier, :3, 3])
        assert distance <= 3.0 and world.poses[later, :3, 2] @ world.poses[earlier, :3, 2] > np.cos(np.radians(30))
    for earlier, later in opposite:
        assert world.poses[later, :3, 2] @ world.poses[earlier, :3, 2] < -np.cos(np.radians(30))


def test_fewer_frames_than_the_minimum_are_refused_naming_it():
    with pytest.raises(PldSlamError, match=f"at least {FEWEST} frames"):
        build_scenario("city", FEWEST - 1, TINY)


def test_the_camera_drives_about_a_metre_per_frame_slower_in_the_turns():
    world = city()
    np.testing.assert_array_equal(world.poses[0], np.eye(4))
    steps = np.linalg.norm(np.diff(world.poses[:, :3, 3], axis=0), axis=1)
    assert 0.8 <= steps.mean() <= 1.2
    assert steps.max() <= 1.01 and steps.min() >= 0.6
    assert np.abs(world.poses[:, 1, 3]).max() < 0.1  # 1.6 m above the road throughout


def on_street_offsets(poses: np.ndarray) -> np.ndarray:
    """Each camera's distance [m] (N,) on the ground to the nearest street centreline."""
    grid = city_grid()
    xz = (poses[:, :3, 3] - grid.origin)[:, [0, 2]]
    offset = np.abs(xz - BLOCK * np.round(xz / BLOCK))
    inside = ((xz >= -HALF_ROAD) & (xz <= BLOCK * (np.array(grid.nodes) - 1) + HALF_ROAD)).all(axis=1)
    return np.where(inside, offset.min(axis=1), np.inf)


def test_a_longer_drive_extends_the_tour_on_the_streets_at_the_same_speed():
    world = city(n_frames=5000, seed=3)
    steps = np.linalg.norm(np.diff(world.poses[:, :3, 3], axis=0), axis=1)
    assert 0.8 <= steps.mean() <= 1.2 and steps.max() <= 1.01
    assert on_street_offsets(world.poses).max() < HALF_ROAD - 1.0  # on the road, never in a block
    np.testing.assert_array_equal(world.poses[:FEWEST // 2], city().poses[:FEWEST // 2])  # the same start


def test_nothing_stands_in_the_driven_lane():
    """No static surface between 0.3 m (curbs) and 2.5 m (pole arms overhead) above the road
    comes within 1.5 m of the camera on the ground."""
    world = city()
    quads = world.scene.static
    height = CAMERA_HEIGHT - quads.corners()[:, :, 1]  # above the road [m]
    standing = (height.min(axis=1) < 2.5) & (height.max(axis=1) > 0.3)
    near = QuadGrid.build(quads.select(standing), 1.5, cell=10.0)
    assert standing.sum() > 5000
    assert not any(len(near.near(pose[:3, 3])) for pose in world.poses)


def test_the_camera_looks_down_streets_from_the_road_never_from_inside_a_facade():
    world = city()
    height, width = TINY[1], TINY[0]
    centre = (slice(height // 4, height // 2), slice(width // 3, 2 * width // 3))
    for index in range(0, world.n_frames, 40):
        left, _ = world.render_views(index)
        assert 0.05 < (left.quad_id < 0).mean() < 0.6  # some sky over the street
        static = left.object_id[centre] == STATIC_OBJECT
        assert left.inv_depth[centre][static].max() < 1.0 / 5.0  # nothing static within 5 m ahead
    assert on_street_offsets(world.poses).max() < HALF_ROAD - 1.0


def test_traffic_comes_both_ways_keeps_clear_of_us_and_is_masked():
    world = city()
    oncoming = following = 0
    for car in world.scene.moving:
        in_camera = np.linalg.inv(world.poses) @ car.poses
        ahead, across = in_camera[:, 2, 3], in_camera[:, 0, 3]
        assert not ((np.abs(across) < 2.5) & (np.abs(ahead) < 8.0)).any()  # nobody drives through us
        in_view = (ahead > 5.0) & (ahead < 60.0) & (np.abs(across) < 10.0)
        facing = in_camera[:, 2, 2]  # cosine between its heading and ours
        oncoming += int((in_view & (facing < -0.9)).any())
        following += int((in_view & (facing > 0.9)).any())
    assert oncoming >= 3 and following >= 1
    fractions = []
    for index in range(0, world.n_frames, 15):
        frame, (left, _) = world.render_frame(index), world.render_views(index)
        np.testing.assert_array_equal(frame.dynamic_mask, left.object_id != STATIC_OBJECT)  # cars always move
        fractions.append(frame.dynamic_mask.mean())
    assert np.mean(np.array(fractions) > 0.0) > 0.3


def test_the_movers_in_play_do_not_grow_with_the_drive():
    assert len(city(n_frames=5000, seed=3).scene.moving) <= 12


def test_a_frame_draws_exactly_the_quads_within_the_view_distance():
    world = city()
    pose = world.poses[300]
    low, high = ground_boxes(world.scene.static)
    point = pose[[0, 2], 3]
    gap = np.maximum(np.maximum(low - point, point - high), 0.0)
    within = np.linalg.norm(gap, axis=1) <= VIEW_DISTANCE
    drawn = world.scene.quads_near(300, pose[:3, 3])
    movers = len(drawn) - within.sum()
    assert 0 < within.sum() < 0.8 * len(world.scene.static)
    np.testing.assert_array_equal(drawn.origin[:within.sum()], world.scene.static.origin[within])
    assert movers % 5 == 0  # whole cars (five quads each) and nothing else


def test_the_quad_grid_finds_what_a_search_of_every_quad_finds():
    rng = np.random.default_rng(7)
    n = 400
    normal = np.column_stack([np.cos(a := rng.uniform(0, 2 * np.pi, n)), np.zeros(n), np.sin(a)])
    quads = Quads.concat([wall(rng.uniform(-300, 300, (n, 3)) * [1, 0, 1], normal, rng.uniform(0.5, 80, n), 3.0, 0),
                          wall(np.zeros(3), np.array([0.0, 0.0, -1.0]), 900.0, 1.0, 0)])  # one larger than the grid
    grid = QuadGrid.build(quads, 60.0, cell=25.0)
    low, high = ground_boxes(quads)
    for centre in rng.uniform(-400, 400, (30, 3)):
        gap = np.maximum(np.maximum(low - centre[[0, 2]], centre[[0, 2]] - high), 0.0)
        np.testing.assert_array_equal(grid.near(centre), np.flatnonzero(np.linalg.norm(gap, axis=1) <= 60.0))
    assert len(grid.near(np.array([5000.0, 0.0, 0.0]))) == 0


def test_scenes_without_a_view_distance_draw_every_quad_as_before():
    world = build_scenario("dynamic", 5, TINY)
    assert world.scene.view_index is None
    everything, drawn = world.scene.quads_at(3), world.scene.quads_near(3, world.poses[3][:3, 3] + 1000.0)
    for field in Quads.__dataclass_fields__:
        np.testing.assert_array_equal(getattr(drawn, field), getattr(everything, field))
