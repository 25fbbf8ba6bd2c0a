"""The synthetic stereo world: geometry, determinism, masks, scenarios and the writer."""

import json
from functools import cache
from pathlib import Path

import cv2
import numpy as np
import pytest

from pld_slam.errors import PldSlamError
from pld_slam.geometry.camera import StereoCamera
from pld_slam.geometry.se3 import make_pose, so3_exp
from pld_slam.synth import MIN_FRAMES, SCENARIOS, build_scenario, write_sequence
from pld_slam.synth.render import render_stereo_views, render_view
from pld_slam.synth.scene import STATIC_OBJECT, Quads, Scene, floor, wall
from pld_slam.synth.textures import TextureAtlas, flat

SMALL = (320, 240)
TINY = (160, 120)


@cache
def scenario(name: str, size=SMALL, n_frames: int | None = 12, seed: int = 0):
    return build_scenario(name, n_frames, size, seed)


def one_surface_scene(quads: Quads) -> Scene:
    return Scene(static=quads, moving=(), atlas=TextureAtlas.build([flat()]), light=np.array([0.0, -1.0, 0.0]))


CAMERA = StereoCamera(fx=192.0, fy=192.0, cx=160.0, cy=120.0, baseline=0.5, width=320, height=240)


# --- the ray caster --------------------------------------------------------------------------


def test_fronto_parallel_wall_has_its_depth_and_projected_outline():
    quads = wall(np.array([0.0, 1.0, 5.0]), np.array([0.0, 0.0, -1.0]), 2.0, 2.0, 0)
    view = render_view(one_surface_scene(quads), quads, CAMERA, np.eye(4))
    covered = view.quad_id == 0
    np.testing.assert_allclose(view.inv_depth[covered], 0.2, rtol=1e-6)
    u, v = np.meshgrid(np.arange(CAMERA.width), np.arange(CAMERA.height))
    half = CAMERA.fx * 1.0 / 5.0
    inside = (np.abs(u - CAMERA.cx) < half - 1e-3) & (np.abs(v - CAMERA.cy) < half - 1e-3)
    outside = (np.abs(u - CAMERA.cx) > half + 1e-3) | (np.abs(v - CAMERA.cy) > half + 1e-3)
    assert covered[inside].all()
    assert not covered[outside].any()
    assert (view.inv_depth[~covered] == 0.0).all() and (view.quad_id[~covered] == -1).all()


def test_ground_plane_depth_matches_the_analytic_plane_for_a_turned_camera():
    quads = floor(np.array([0.0, 1.6, 0.0]), np.array([0.0, 0.0, 1.0]), 400.0, 400.0, 0)
    T_w_c = make_pose(so3_exp(np.array([0.0, 0.7, 0.0])), np.array([3.0, 0.0, -2.0]))
    view = render_view(one_surface_scene(quads), quads, CAMERA, T_w_c)
    rows = np.arange(CAMERA.height)[:, None] * np.ones((1, CAMERA.width))
    expected = (rows - CAMERA.cy) / (CAMERA.fy * 1.6)
    covered = view.quad_id == 0
    assert covered[rows > CAMERA.cy + 1].all()
    assert not covered[rows <= CAMERA.cy].any()
    np.testing.assert_allclose(view.inv_depth[covered], expected[covered], rtol=1e-4, atol=1e-6)


def test_stereo_views_agree_on_surface_identity_depth_and_brightness():
    world = scenario("static")
    left, right = world.render_views(6)
    camera = world.camera
    v, u = np.nonzero(left.quad_id >= 0)
    u_right = u - camera.bf * left.inv_depth[v, u]
    on_image = (u_right >= 1) & (u_right <= camera.width - 2)
    v, u, u_right = v[on_image], u[on_image], u_right[on_image]
    col0 = np.floor(u_right).astype(int)
    frac = u_right - col0
    left_quad = left.quad_id[v, u]
    same_quad = (right.quad_id[v, col0] == left_quad) & (right.quad_id[v, col0 + 1] == left_quad)
    assert same_quad.mean() > 0.9  # the rest: occlusions and outline pixels
    right_inv_depth = (1.0 - frac) * right.inv_depth[v, col0] + frac * right.inv_depth[v, col0 + 1]
    np.testing.assert_allclose(right_inv_depth[same_quad], left.inv_depth[v, u][same_quad], rtol=1e-4)
    warped = (1.0 - frac) * right.radiance[v, col0] + frac * right.radiance[v, col0 + 1]
    matched = np.abs(warped - left.radiance[v, u])[same_quad]
    unshifted = np.abs(right.radiance[v, u] - left.radiance[v, u])[same_quad]
    assert np.median(matched) < 2.0
    assert np.median(unshifted) > 3.0 * np.median(matched)


def test_first_pose_is_identity_and_the_camera_rides_at_the_right_speed():
    world = scenario("static", n_frames=40)
    np.testing.assert_array_equal(world.poses[0], np.eye(4))
    steps = np.linalg.norm(np.diff(world.poses[:, :3, 3], axis=0), axis=1)
    assert steps.min() > 0.6 and steps.max() < 1.0
    np.testing.assert_allclose(np.diff(world.timestamps), 0.1)
    assert np.abs(world.poses[:, 1, 3]).max() < 0.1  # stays 1.6 m above the road


# --- determinism and images ----------------------------------------------------------------------


def test_same_seed_renders_identical_frames_and_another_seed_differs():
    a = build_scenario("dynamic", 4, TINY, seed=3).render_frame(2)
    b = build_scenario("dynamic", 4, TINY, seed=3).render_frame(2)
    c = build_scenario("dynamic", 4, TINY, seed=4).render_frame(2)
    for name in ("left", "right", "dynamic_mask"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert np.abs(a.left.astype(int) - c.left).mean() > 5.0


@pytest.mark.parametrize("name", ["loop2", "nearmiss"])
def test_new_scenarios_render_the_same_frames_every_time(name):
    index = {"loop2": 500, "nearmiss": 150}[name]
    a = build_scenario(name, None, TINY, seed=2).render_frame(index)
    b = build_scenario(name, None, TINY, seed=2).render_frame(index)
    for field in ("left", "right", "dynamic_mask"):
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field))


@pytest.mark.parametrize("name", SCENARIOS)
def test_images_are_structured_grey_stereo_pairs(name):
    frame = scenario(name, n_frames=None if name in MIN_FRAMES else 12).render_frame(0)
    assert frame.left.dtype == np.uint8 and frame.left.shape == (SMALL[1], SMALL[0])
    assert frame.right.shape == frame.left.shape and frame.dynamic_mask.dtype == bool
    assert frame.left.std() > 20.0 and frame.right.std() > 20.0
    assert not np.array_equal(frame.left, frame.right)


# --- dynamic masks ---------------------------------------------------------------------------------


def test_dynamic_masks_are_the_pixels_of_moving_objects_and_cover_10_to_40_percent():
    world = scenario("dynamic", size=TINY, n_frames=100)
    fractions = []
    for index in range(0, world.n_frames, 3):
        left, _ = world.render_views(index)
        quads = world.scene.quads_at(index)
        on_mover = np.zeros(left.quad_id.shape, dtype=bool)
        visible = left.quad_id >= 0
        on_mover[visible] = quads.object_id[left.quad_id[visible]] != STATIC_OBJECT
        np.testing.assert_array_equal(left.object_id != STATIC_OBJECT, on_mover)
        fractions.append(on_mover.mean())
    fractions = np.array(fractions)
    assert ((fractions >= 0.1) & (fractions <= 0.4)).mean() >= 0.95, fractions


def test_dynamic_mask_follows_the_truck_ahead_and_matches_the_rendered_frame():
    world = scenario("dynamic")
    frame = world.render_frame(5)
    left, _ = world.render_views(5)
    np.testing.assert_array_equal(frame.dynamic_mask, left.object_id != STATIC_OBJECT)
    centre = (world.camera.height // 2, world.camera.width // 2)
    assert left.object_id[centre] == 1  # the truck in our lane
    assert 4.0 < 1.0 / left.inv_depth[centre] < 6.5


def test_convoy_movers_drive_with_the_camera_and_cover_a_third_of_the_image():
    world = scenario("convoy", size=TINY, n_frames=150)
    camera_path = world.poses[:, :3, 3]
    fractions = []
    for index in range(0, world.n_frames, 10):
        frame = world.render_frame(index)
        fractions.append(frame.dynamic_mask.mean())
        bus_in_camera = np.linalg.inv(world.poses[index]) @ world.scene.moving[0].poses[index]
        assert -2.0 < bus_in_camera[2, 3] < 9.0 and bus_in_camera[0, 3] < -3.0  # alongside, to the left
    bus_path = world.scene.moving[0].poses[:, :3, 3]
    assert np.linalg.norm(bus_path[-1] - bus_path[0]) > 0.8 * np.linalg.norm(camera_path[-1] - camera_path[0])
    fractions = np.array(fractions)
    assert fractions.mean() > 0.28 and fractions.min() > 0.2 and fractions.max() < 0.6, fractions


def test_crossing_crowd_crosses_while_the_camera_waits_and_is_unmasked_until_it_sets_off():
    world = scenario("crossing", size=TINY, n_frames=180)
    steps = np.linalg.norm(np.diff(world.poses[:, :3, 3], axis=0), axis=1)
    stopped = np.flatnonzero(steps < 1e-9)
    assert len(stopped) >= 80  # 9 s at 10 Hz, minus the frames either side
    middle = stopped[len(stopped) // 2]
    assert world.render_frame(middle).dynamic_mask.mean() > 0.15
    waiting = [obj for obj in world.scene.moving if not obj.moves_at(stopped[0] - 10)]
    assert len(waiting) > 30  # most of the crowd still waits at the kerb
    walking = {obj.object_id for obj in world.scene.moving if obj.moves_at(middle)}
    left, _ = world.render_views(middle)
    np.testing.assert_array_equal(world.render_frame(middle).dynamic_mask, np.isin(left.object_id, list(walking)))


def test_parked_cars_stay_put_and_unmasked_until_the_camera_comes_within_20_m():
    world = scenario("parked_then_moving", size=TINY, n_frames=150)
    started = 0
    for obj in world.scene.moving:
        moving = np.array([obj.moves_at(i) for i in range(world.n_frames)])
        if not moving.any():
            continue
        start = int(np.argmax(moving))
        assert start > 5 and moving[start:].all()  # parked for a while, then drives on
        assert np.allclose(obj.poses[:start], obj.poses[0])
        ahead = np.linalg.inv(world.poses[start]) @ obj.poses[start]
        assert 18.0 < np.linalg.norm(ahead[:3, 3]) < 22.0
        gaps = [np.linalg.norm((np.linalg.inv(world.poses[i]) @ obj.poses[i])[:3, 3]) for i in range(world.n_frames)]
        assert min(gaps) > 10.0  # it pulls out well clear of us
        started += 1
    assert started >= 2


def test_static_and_lowtexture_masks_are_empty():
    for name in ("static", "lowtexture"):
        assert not scenario(name).render_frame(3).dynamic_mask.any()


# --- scenarios ---------------------------------------------------------------------------------


def test_loop_returns_to_its_start_pose_exactly():
    world = scenario("loop", n_frames=None)
    assert world.n_frames == 360
    np.testing.assert_array_equal(world.poses[-1], world.poses[0])
    np.testing.assert_array_equal(world.poses[0], np.eye(4))
    assert np.linalg.norm(world.poses[:, :3, 3], axis=1).max() > 50.0
    assert np.linalg.norm(np.diff(world.poses[:, :3, 3], axis=0), axis=1).max() < 1.0
    first, _ = world.render_views(0)
    last, _ = world.render_views(world.n_frames - 1)
    np.testing.assert_array_equal(first.radiance, last.radiance)


def test_loop_needs_300_frames():
    with pytest.raises(PldSlamError, match="300"):
        build_scenario("loop", 299, TINY)


def test_loop2_and_nearmiss_refuse_too_few_frames():
    with pytest.raises(PldSlamError, match="600 frames to drive around the block twice"):
        build_scenario("loop2", 599, TINY)
    with pytest.raises(PldSlamError, match="150"):
        build_scenario("nearmiss", 149, TINY)


def rotation_angle_deg(T_a: np.ndarray, T_b: np.ndarray) -> float:
    cos = (np.trace(T_a[:3, :3].T @ T_b[:3, :3]) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))


def test_loop2_drives_the_block_twice_and_returns_to_its_start_pose_exactly():
    world = scenario("loop2", size=TINY, n_frames=None)
    assert world.n_frames == 720
    half = world.n_frames // 2
    np.testing.assert_array_equal(world.poses[0], np.eye(4))
    np.testing.assert_array_equal(world.poses[-1], world.poses[0])
    assert np.linalg.norm(world.poses[:, :3, 3], axis=1).max() > 50.0
    assert np.linalg.norm(np.diff(world.poses[:, :3, 3], axis=0), axis=1).max() < 1.0
    # frame i + N/2 is frame i half a frame (L / 719 = 0.42 m) further on
    gaps = np.linalg.norm(world.poses[half:, :3, 3] - world.poses[:half, :3, 3], axis=1)
    assert gaps.max() < 0.5
    assert max(rotation_angle_deg(a, b) for a, b in zip(world.poses[:half], world.poses[half:])) < 2.0
    # lap one is loop's world: the same quads, its parked cars only there for the first visit
    loop = scenario("loop", size=TINY, n_frames=None).scene
    first_visit = world.scene.transient.quads.select(world.scene.transient.first == 0)
    mine = Quads.concat([world.scene.static, first_visit]).corners().reshape(-1, 12)
    theirs = loop.static.corners().reshape(-1, 12)
    np.testing.assert_allclose(mine[np.lexsort(mine.T)], theirs[np.lexsort(theirs.T)])


def test_loop2_second_lap_looks_different_at_the_same_pose_and_loop_does_not():
    world = scenario("loop2", size=TINY, n_frames=None)
    loop = scenario("loop", size=TINY, n_frames=None)
    half = world.n_frames // 2
    for index in (0, 120, 240):
        T_w_c = world.poses[index + half]
        first, _ = render_stereo_views(world.scene, world.camera, T_w_c, index)
        second, _ = render_stereo_views(world.scene, world.camera, T_w_c, index + half)
        assert np.abs(first.radiance - second.radiance).mean() > 15.0
        assert second.radiance.mean() < 0.85 * first.radiance.mean()  # darker
        assert (np.abs(first.inv_depth - second.inv_depth) > 1e-4).mean() > 0.01  # other cars
        same, _ = render_stereo_views(loop.scene, loop.camera, T_w_c, index)
        again, _ = render_stereo_views(loop.scene, loop.camera, T_w_c, index + half)
        np.testing.assert_array_equal(same.radiance, again.radiance)
    start, end = world.render_frame(0), world.render_frame(world.n_frames - 1)
    assert np.abs(start.left.astype(float) - end.left).mean() > 15.0
    assert not end.dynamic_mask.any()  # parked cars never move: not in the dynamic masks


def test_loop2_parked_cars_change_only_out_of_sight():
    world = scenario("loop2", size=TINY, n_frames=None)
    transient, n_static = world.scene.transient, len(world.scene.static)
    swaps = np.unique(transient.first[transient.first > 0])
    assert len(swaps) > 20
    for swap in swaps:
        changing = (transient.first == swap) | (transient.end == swap)
        for index in (swap - 1, swap):
            present = np.flatnonzero((transient.first <= index) & (index < transient.end))
            for view in world.render_views(int(index)):
                ids = view.quad_id[(view.quad_id >= n_static) & (view.quad_id < n_static + len(present))]
                assert not changing[present[ids - n_static]].any(), (swap, index)


def test_nearmiss_comes_back_beside_its_way_out_but_never_to_an_earlier_place():
    world = scenario("nearmiss", size=TINY, n_frames=None)
    assert world.n_frames == 300
    position, forward = world.poses[:, :3, 3], world.poses[:, :3, 2]
    i, j = np.triu_indices(world.n_frames, 1)
    distance = np.linalg.norm(position[i] - position[j], axis=1)
    assert distance[j - i > 100].min() > 15.0
    alike = np.einsum("ij,ij->i", forward[i], forward[j]) > 0.0  # headings within 90 degrees
    assert distance[(j - i > 30) & alike].min() > 15.0
    assert 35.0 < np.linalg.norm(position[-1] - position[0]) < 45.0  # back level with the start
    assert forward[-1] @ forward[0] < -0.99


def test_nearmiss_sees_other_buildings_on_the_way_back():
    world = scenario("nearmiss", size=TINY, n_frames=None)
    x = world.poses[:, 0, 3]
    out, back = np.flatnonzero(x < 1.0), np.flatnonzero(x > 39.0)
    assert len(out) > 100 and len(back) > 100

    def surfaces(frames) -> set[int]:
        seen = set()
        for index in frames[::10]:
            left, _ = world.render_views(int(index))
            ids, counts = np.unique(left.quad_id[left.quad_id >= 0], return_counts=True)
            seen |= set(ids[counts > 0.002 * left.quad_id.size].tolist())
        return seen

    assert surfaces(out) & surfaces(back) <= {0}  # quad 0: the ground plane under everything


@pytest.mark.parametrize("size", [(0, 240), (320, -1), (32.5, 24)])
def test_bad_requests_are_refused(size):
    with pytest.raises(PldSlamError):
        build_scenario("static", 3, size)
    with pytest.raises(PldSlamError, match="unknown"):
        build_scenario("night", 3, TINY)


def feature_counts(name: str) -> tuple[float, float]:
    """Mean ORB keypoints (FAST threshold 20) and LSD segments of >= 10 px per left image."""
    orb = cv2.ORB_create(nfeatures=100000, fastThreshold=20)
    lsd = cv2.createLineSegmentDetector()
    points, lines = [], []
    for index in (0, 5, 10):
        image = scenario(name).render_frame(index).left
        points.append(len(orb.detect(image, None)))
        segments = lsd.detect(image)[0].reshape(-1, 4)
        lines.append(np.sum(np.hypot(segments[:, 2] - segments[:, 0], segments[:, 3] - segments[:, 1]) >= 10))
    return float(np.mean(points)), float(np.mean(lines))


def test_lowtexture_has_few_orb_points_but_plenty_of_lines():
    static_points, static_lines = feature_counts("static")
    low_points, low_lines = feature_counts("lowtexture")
    assert static_points > 500 and static_lines > 100
    assert low_points < 0.4 * static_points
    assert low_lines > 40 and low_lines > 0.4 * static_lines


# --- the writer ---------------------------------------------------------------------------------


def read_matrix_lines(path: Path) -> dict[str, np.ndarray]:
    rows = [line.split(":") for line in path.read_text().splitlines()]
    return {key: np.array(values.split(), dtype=float).reshape(3, 4) for key, values in rows}


def test_written_sequence_reads_back_and_rewrites_byte_identically(tmp_path):
    out = tmp_path / "seq"
    summary = write_sequence(out, "dynamic", n_frames=3, size=TINY, seed=1)
    assert (summary.n_frames, summary.width, summary.height) == (3, 160, 120)
    assert 0.1 < summary.mean_dynamic_fraction < 0.4 and summary.pairs_per_second > 0
    world = build_scenario("dynamic", 3, TINY, seed=1)

    calib = read_matrix_lines(out / "calib.txt")
    assert set(calib) == {"P0", "P1"}
    np.testing.assert_allclose(calib["P0"][:, :3], world.camera.K)
    assert calib["P0"][0, 0] == 0.6 * 160 and calib["P0"][0, 2] == 80 and calib["P0"][1, 2] == 60
    np.testing.assert_allclose(-calib["P1"][0, 3] / calib["P1"][0, 0], 0.5)
    poses = np.loadtxt(out / "poses.txt").reshape(-1, 3, 4)
    np.testing.assert_allclose(poses, world.poses[:, :3, :], atol=1e-12)
    np.testing.assert_array_equal(poses[0], np.eye(4)[:3])
    np.testing.assert_allclose(np.loadtxt(out / "times.txt"), [0.0, 0.1, 0.2])
    meta = json.loads((out / "synth.json").read_text())
    assert (meta["scenario"], meta["seed"], meta["n_frames"], meta["width"]) == ("dynamic", 1, 3, 160)

    frame = world.render_frame(2)
    np.testing.assert_array_equal(cv2.imread(str(out / "image_0" / "000002.png"), cv2.IMREAD_UNCHANGED), frame.left)
    np.testing.assert_array_equal(cv2.imread(str(out / "image_1" / "000002.png"), cv2.IMREAD_UNCHANGED), frame.right)
    mask = cv2.imread(str(out / "dynamic_masks" / "000002.png"), cv2.IMREAD_UNCHANGED)
    assert set(np.unique(mask)) <= {0, 255}
    np.testing.assert_array_equal(mask == 255, frame.dynamic_mask)

    before = {p.relative_to(out): p.read_bytes() for p in sorted(out.rglob("*")) if p.is_file()}
    write_sequence(out, "dynamic", n_frames=3, size=TINY, seed=1)
    after = {p.relative_to(out): p.read_bytes() for p in sorted(out.rglob("*")) if p.is_file()}
    assert before == after


def test_rewriting_a_sequence_removes_its_old_frames(tmp_path):
    write_sequence(tmp_path, "static", n_frames=4, size=TINY)
    write_sequence(tmp_path, "static", n_frames=2, size=TINY)
    assert sorted(p.name for p in (tmp_path / "image_0").iterdir()) == ["000000.png", "000001.png"]
    assert cv2.imread(str(tmp_path / "dynamic_masks" / "000001.png"), cv2.IMREAD_UNCHANGED).max() == 0


def test_writer_refuses_a_non_empty_unrelated_folder(tmp_path):
    (tmp_path / "notes.txt").write_text("mine")
    with pytest.raises(PldSlamError, match="not empty"):
        write_sequence(tmp_path, "static", n_frames=2, size=TINY)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["notes.txt"]
