"""Point landmarks the stereo pair sees through (`pld_slam.tracking.see_through`)."""

import numpy as np
import pytest

from pld_slam.config import load_config
from pld_slam.geometry.camera import StereoCamera
from pld_slam.localisation.local_map import missed_in_image
from pld_slam.matching.projection import LandmarkSnapshot
from pld_slam.tracking.see_through import (
    SeeThroughOptions,
    landmarks_found_at_another_depth,
    landmarks_seen_through,
    shows_farther_surface,
)

OPTIONS = SeeThroughOptions.of(load_config().mapping)
HALF_WINDOW, SEARCH_REACH, MARGIN_PX, MATCH_RATIO = (OPTIONS.half_window, OPTIONS.reach, OPTIONS.margin_px,
                                                     OPTIONS.match_ratio)
DEPTH_TOLERANCE = OPTIONS.depth_tolerance

CAMERA = StereoCamera(fx=400.0, fy=400.0, cx=320.0, cy=240.0, baseline=0.5, width=640, height=480)
WALL_DEPTH = 20.0
"""A textured wall fills the view at this depth: disparity 10 px."""


def texture(rng: np.random.Generator, shape: tuple[int, int]) -> np.ndarray:
    """Grey levels varying every pixel (float, about 40-215)."""
    return rng.uniform(40.0, 215.0, size=shape)


def paste(left: np.ndarray, right: np.ndarray, patch: np.ndarray, u0: int, v0: int, depth: float) -> None:
    """Draw ``patch`` at column ``u0``, row ``v0`` of ``left``, and where a surface at ``depth`` shows it
    in ``right``."""
    disparity = int(round(CAMERA.bf / depth))
    rows, cols = patch.shape
    left[v0 : v0 + rows, u0 : u0 + cols] = patch
    right[v0 : v0 + rows, u0 - disparity : u0 - disparity + cols] = patch


def pair_with_wall(seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A rectified pair of a textured wall at `WALL_DEPTH` (float, not yet rounded)."""
    rng = np.random.default_rng(seed)
    disparity = int(round(CAMERA.bf / WALL_DEPTH))
    wall = texture(rng, (CAMERA.height, CAMERA.width + disparity))
    return wall[:, :CAMERA.width].copy(), wall[:, disparity:].copy()


def at_pixel(u: float, v: float, depth: float) -> np.ndarray:
    """The point (3,) at ``depth`` that the camera at the world origin sees at pixel (u, v)."""
    return CAMERA.backproject(np.array([[u, v]]), np.array([depth]))[0]


def snapshot(points_w: np.ndarray) -> LandmarkSnapshot:
    n = len(points_w)
    return LandmarkSnapshot(
        ids=np.arange(10, 10 + n), geometry=points_w, descriptors=np.zeros((n, 32), np.uint8),
        normals=np.tile([0.0, 0.0, 1.0], (n, 1)), max_distance=np.full(n, 100.0),
    )


def as_images(left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(1)
    noisy = [np.clip(np.rint(image + rng.normal(0.0, 1.5, image.shape)), 0, 255).astype(np.uint8)
             for image in (left, right)]
    return noisy[0], noisy[1]


def test_only_a_missed_landmark_in_front_of_the_surface_the_pair_shows_is_seen_through():
    left, right = pair_with_wall()
    rng = np.random.default_rng(2)
    paste(left, right, texture(rng, (60, 60)), 100, 300, depth=8.0)  # a box 2.5 x nearer than the wall
    paste(left, right, texture(rng, (60, 60)), 500, 300, depth=4.0)  # a box 5 x nearer: beyond the search
    left[50:110, 300:360] = right[50:110, 290:350] = 128.0  # a flat patch of the wall
    landmarks = np.array([
        at_pixel(200, 100, 12.0),  # 0: 12 m, where the wall shows at 20 m: seen through
        at_pixel(400, 100, WALL_DEPTH),  # 1: on the wall: matches where predicted
        at_pixel(130, 330, WALL_DEPTH),  # 2: on the wall behind the box: hidden, not seen through
        at_pixel(530, 330, WALL_DEPTH),  # 3: on the wall behind the nearer box: hidden
        at_pixel(330, 80, 12.0),  # 4: 12 m, in front of the flat patch: no evidence
        at_pixel(200, 400, 12.0),  # 5: as 0, but the frame's solve found it: not tested
        at_pixel(2, 100, 12.0),  # 6: too near the left border for its window: not tested
        at_pixel(250, 200, -5.0),  # 7: behind the camera: not tested
    ])
    points = snapshot(landmarks)
    seen = landmarks_seen_through(CAMERA, missed_in_image(CAMERA, np.eye(4), points, points.ids[[5]]),
                                  *as_images(left, right), OPTIONS)
    assert seen.tolist() == [points.ids[0]]


@pytest.mark.parametrize("tolerance", [DEPTH_TOLERANCE, 0.3])
@pytest.mark.parametrize("share", [0.5, 2.0])
def test_the_surface_seen_must_lie_farther_than_the_depth_tolerance(share, tolerance):
    """``mapping.see_through_depth_tolerance`` decides, at its default and at another value."""
    left, right = pair_with_wall()
    options = SeeThroughOptions.of(load_config(overrides=[f"mapping.see_through_depth_tolerance={tolerance}"]).mapping)
    # A landmark whose disparity exceeds the wall's by `share` of the tolerance plus the margin.
    disparity = CAMERA.bf / WALL_DEPTH * (1.0 + share * tolerance) + MARGIN_PX
    points = snapshot(np.array([at_pixel(320, 240, CAMERA.bf / disparity)]))
    seen = landmarks_seen_through(CAMERA, missed_in_image(CAMERA, np.eye(4), points, np.zeros(0, np.int64)),
                                  *as_images(left, right), options)
    assert len(seen) == (share > 1.0)


def reference_shows_farther_surface(left, right, u, v, predicted):
    """`shows_farther_surface` by brute force: every shift's cost, then the module docstring's tests."""
    h = HALF_WINDOW
    shown = []
    for uk, vk, pk in zip(u, v, predicted):
        window = left[vk - h : vk + h + 1, uk - h : uk + h + 1].astype(float)
        window -= window.mean()
        shifts = np.arange(0, min(int(SEARCH_REACH * pk) + 1, uk - h) + 1)
        costs = []
        for shift in shifts:
            other = right[vk - h : vk + h + 1, uk - shift - h : uk - shift + h + 1].astype(float)
            costs.append(np.abs(other - other.mean() - window).sum())
        costs = np.array(costs)
        best = np.argmin(costs)
        at_prediction = costs[np.abs(shifts - round(pk)) <= 1].min()
        shown.append(bool(shifts[best] < pk / (1.0 + DEPTH_TOLERANCE) - MARGIN_PX
                          and costs[best] < MATCH_RATIO * min(at_prediction, np.abs(window).sum())))
    return np.array(shown)


def test_the_search_decides_as_the_best_disparity_over_every_shift_would():
    left, right = pair_with_wall(seed=4)
    rng = np.random.default_rng(5)
    for u0 in range(140, 590, 90):  # boxes nearer than the wall, some beyond the search
        paste(left, right, texture(rng, (50, 50)), u0, int(rng.integers(0, 400)), depth=float(rng.uniform(3.0, 15.0)))
    left, right = as_images(left, right)
    n = 400
    u = rng.integers(60, CAMERA.width - HALF_WINDOW, n)
    v = rng.integers(HALF_WINDOW, CAMERA.height - HALF_WINDOW, n)
    predicted = np.minimum(CAMERA.bf / rng.uniform(3.0, 40.0, n), u - HALF_WINDOW - 2.0)
    shown = shows_farther_surface(left, right, u, v, predicted, OPTIONS)
    assert shown.tolist() == reference_shows_farther_surface(left, right, u, v, predicted).tolist()
    assert 20 < np.count_nonzero(shown) < n - 20  # both answers are exercised


@pytest.mark.parametrize(("copy_contrast", "shown"), [(1.0, True), (0.3, False)])
def test_a_farther_match_counts_only_when_it_matches_clearly(copy_contrast, shown):
    # The landmark's disparity is 20 px; 10 px away the right image holds the left window with
    # `copy_contrast` of its contrast. At 0.3 the copy matches better than anything else, but at 70 %
    # of the window's own contrast: chance, as on an occluder nearer than the search reaches.
    rng = np.random.default_rng(6)
    left = texture(rng, (CAMERA.height, CAMERA.width))
    right = 255.0 - left  # matches nowhere
    u, v, h = 300, 200, HALF_WINDOW
    window = left[v - h : v + h + 1, u - h : u + h + 1]
    right[v - h : v + h + 1, u - 10 - h : u - 10 + h + 1] = window.mean() + copy_contrast * (window - window.mean())
    left, right = as_images(left, right)
    found = shows_farther_surface(left, right, np.array([u]), np.array([v]), np.array([20.0]), OPTIONS)
    assert found.tolist() == [shown]


@pytest.mark.parametrize(("nearer_copy", "shown"), [(False, True), (True, False)])
def test_a_farther_match_does_not_count_when_a_nearer_shift_matches_better(nearer_copy, shown):
    # The landmark's disparity is 20 px; at 8 px the right image holds the left window at 90 % of its
    # contrast (a clear match) and, when `nearer_copy`, the exact window at 24 px: something nearer.
    rng = np.random.default_rng(7)
    left = texture(rng, (CAMERA.height, CAMERA.width))
    right = 255.0 - left
    u, v, h = 300, 200, HALF_WINDOW
    window = left[v - h : v + h + 1, u - h : u + h + 1]
    right[v - h : v + h + 1, u - 8 - h : u - 8 + h + 1] = window.mean() + 0.9 * (window - window.mean())
    if nearer_copy:
        right[v - h : v + h + 1, u - 24 - h : u - 24 + h + 1] = window
    left, right = as_images(left, right)
    found = shows_farther_surface(left, right, np.array([u]), np.array([v]), np.array([20.0]), OPTIONS)
    assert found.tolist() == [shown]


def test_a_landmark_found_where_the_pair_shows_another_depth_nearer_or_farther_is_flagged():
    left, right = pair_with_wall()
    rng = np.random.default_rng(3)
    paste(left, right, texture(rng, (60, 60)), 100, 300, depth=8.0)  # a box 2.5 x nearer than the wall
    left[50:110, 300:360] = right[50:110, 290:350] = 128.0  # a flat patch of the wall
    found = np.array([
        [400, 100, WALL_DEPTH],  # 0: on the wall, at the wall's depth
        [200, 100, 12.0],  # 1: on the wall, mapped 8 m in front of it: the pair shows it farther
        [130, 330, WALL_DEPTH],  # 2: on the box, mapped at the wall behind it: the pair shows it nearer
        [130, 330, 8.0],  # 3: on the box, at the box's depth
        [330, 80, 12.0],  # 4: on the flat patch: matches everywhere alike, no evidence
        [250, 200, -5.0],  # 5: behind the camera: not tested
    ])
    ids = np.arange(20, 20 + len(found))
    p_c = np.array([at_pixel(u, v, depth) for u, v, depth in found])
    flagged = landmarks_found_at_another_depth(CAMERA, ids, found[:, :2], p_c, *as_images(left, right), OPTIONS)
    assert flagged.tolist() == [ids[1], ids[2]]


@pytest.mark.parametrize("share", [0.5 * DEPTH_TOLERANCE, 2.0 * DEPTH_TOLERANCE])
@pytest.mark.parametrize("side", [-1.0, 1.0])
def test_another_depth_must_differ_by_more_than_the_depth_tolerance_on_either_side(share, side):
    left, right = pair_with_wall()
    wall = CAMERA.bf / WALL_DEPTH
    # The landmark's disparity is the wall's moved by `share` of it plus the margin, to either side.
    disparity = wall * (1.0 + share) + MARGIN_PX if side > 0 else (wall - MARGIN_PX) / (1.0 + share)
    p_c = at_pixel(320, 240, CAMERA.bf / disparity)[None]
    flagged = landmarks_found_at_another_depth(CAMERA, np.array([7]), np.array([[320.0, 240.0]]), p_c,
                                               *as_images(left, right), OPTIONS)
    assert len(flagged) == (share > DEPTH_TOLERANCE)
