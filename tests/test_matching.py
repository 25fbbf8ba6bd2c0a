"""Frame-to-frame matching (`pld_slam.matching.frames`, `pld_slam.matching.windows`) on hand-built stereo features.

The previous frame's features are random 3D points (and segments) with random 32-byte
descriptors; the current frame sees the same structure moved by a known ``T_c_p``, with a
few descriptor bits flipped, shuffled among random distractors. With the true motion as
the prior the matcher must return exactly the true pairs; the window, the ratio test, the
one-use-per-current-feature rule and the line direction check each get a case that breaks
one true pair.
"""

import numpy as np
import pytest

from pld_slam.frontend import StereoLines, StereoPoints
from pld_slam.geometry.camera import StereoCamera
from pld_slam.geometry.se3 import make_pose, so3_exp, transform_points
from pld_slam.matching.frames import (
    FrameMatches,
    match_lines,
    match_points,
    predict_pixels,
)
from pld_slam.matching.windows import pairs_within

CAMERA = StereoCamera(fx=192.0, fy=192.0, cx=160.0, cy=120.0, baseline=0.5, width=320, height=240)
T_C_P = make_pose(so3_exp(np.array([0.01, 0.05, -0.02])), np.array([0.1, -0.03, -0.8]))
"""The true motion, previous camera to current: 0.8 m forward with a slight turn."""

POINT_RADIUS, LINE_RADIUS = 15.0, 30.0
MAX_DISTANCE, RATIO, MAX_TURN = 64, 0.9, 0.2
ORB_SCALE_FACTOR = 1.2
FLIPPED_BITS = 6


def flip_bits(descriptors: np.ndarray, n_bits: int, rng: np.random.Generator) -> np.ndarray:
    """Copies of (N, 32) descriptors with ``n_bits`` distinct random bits flipped in each row."""
    bits = np.unpackbits(descriptors, axis=1)
    for row in bits:
        row[rng.choice(row.size, n_bits, replace=False)] ^= 1
    return np.packbits(bits, axis=1)


def random_descriptors(n: int, rng: np.random.Generator) -> np.ndarray:
    return rng.integers(0, 256, size=(n, 32), dtype=np.uint8)


def hamming(a: np.ndarray, b: np.ndarray) -> int:
    return int(np.unpackbits(a ^ b).sum())


def stereo_points(points_c: np.ndarray, descriptors: np.ndarray, octave=None, uv=None) -> StereoPoints:
    """Stereo points seen at ``uv`` (default: the projection of ``points_c``), exact disparity."""
    uv = CAMERA.project(points_c) if uv is None else uv
    disparity = CAMERA.bf / points_c[:, 2]
    octave = np.zeros(len(points_c), dtype=np.int64) if octave is None else np.asarray(octave, dtype=np.int64)
    return StereoPoints(uv=uv, octave=octave, descriptors=descriptors, disparity=disparity,
                        u_right=uv[:, 0] - disparity, points_c=points_c)


def points_in_view(n: int, rng: np.random.Generator) -> np.ndarray:
    """Points (n, 3) of the previous camera, 6-25 m deep, that both cameras see inside a margin."""
    depth = rng.uniform(6.0, 25.0, n)
    uv = np.column_stack([rng.uniform(40.0, 280.0, n), rng.uniform(40.0, 200.0, n)])
    return CAMERA.backproject(uv, depth)


def concat_points(parts: list[StereoPoints], order: np.ndarray) -> StereoPoints:
    """The features of ``parts`` stacked, then reordered by ``order``."""
    fields = ("uv", "octave", "descriptors", "disparity", "u_right", "points_c")
    return StereoPoints(**{f: np.concatenate([getattr(p, f) for p in parts])[order] for f in fields})


@pytest.fixture
def scene():
    """40 previous points; the current frame holds them moved by T_C_P and 25 distractors, shuffled.

    Returns the previous points, the current points, and ``true[i]``: the current index of
    previous point ``i``.
    """
    rng = np.random.default_rng(7)
    n, n_distractors = 40, 25
    previous_c = points_in_view(n, rng)
    descriptors = random_descriptors(n, rng)
    previous = stereo_points(previous_c, descriptors)
    moved = stereo_points(transform_points(T_C_P, previous_c), flip_bits(descriptors, FLIPPED_BITS, rng))
    distractors = stereo_points(points_in_view(n_distractors, rng), random_descriptors(n_distractors, rng))
    order = rng.permutation(n + n_distractors)
    current = concat_points([moved, distractors], order)
    true = np.argsort(order)[:n]
    return previous, current, true


def pairs(matches: FrameMatches) -> set[tuple[int, int]]:
    return set(zip(matches.previous.tolist(), matches.current.tolist()))


def true_pairs(true: np.ndarray, excluded=()) -> set[tuple[int, int]]:
    return {(i, int(c)) for i, c in enumerate(true) if i not in excluded}


def with_current_uv(current: StereoPoints, index: int, uv) -> StereoPoints:
    moved_uv = current.uv.copy()
    moved_uv[index] = uv
    return StereoPoints(moved_uv, current.octave, current.descriptors,
                        current.disparity, current.u_right, current.points_c)


def appended(current: StereoPoints, uv, descriptor: np.ndarray) -> StereoPoints:
    """``current`` with one more feature at ``uv`` (depth 10 m) with ``descriptor``."""
    extra = stereo_points(CAMERA.backproject(np.array([uv], dtype=float), np.array([10.0])), descriptor[None])
    return concat_points([current, extra], np.arange(len(current) + 1))


def match(previous, current, prior=T_C_P, radius=POINT_RADIUS, ratio=RATIO) -> FrameMatches:
    return match_points(CAMERA, prior, previous, current, radius, ORB_SCALE_FACTOR, MAX_DISTANCE, ratio)


# --- predict_pixels -------------------------------------------------------------------


def test_predict_pixels_is_the_camera_projection_of_the_moved_points():
    rng = np.random.default_rng(1)
    points_p = points_in_view(30, rng)
    pixels, in_front = predict_pixels(CAMERA, T_C_P, points_p)
    expected = CAMERA.project(points_p @ T_C_P[:3, :3].T + T_C_P[:3, 3])
    assert in_front.all()
    np.testing.assert_allclose(pixels, expected, rtol=0, atol=1e-9)


def test_predict_pixels_flags_points_behind_or_at_the_current_camera_and_keeps_pixels_finite():
    forward = make_pose(np.eye(3), np.array([0.0, 0.0, -5.0]))  # the camera moves 5 m forward
    points_p = np.array([[0.0, 0.0, 10.0], [1.0, 1.0, 5.05], [1.0, 0.0, 5.0], [0.0, 1.0, 2.0], [0.5, 0.5, 5.2]])
    pixels, in_front = predict_pixels(CAMERA, forward, points_p)
    assert in_front.tolist() == [True, False, False, False, True]
    assert np.isfinite(pixels).all()
    np.testing.assert_allclose(pixels[0], [CAMERA.cx, CAMERA.cy])
    np.testing.assert_allclose(pixels[4], [160.0 + 192.0 * 0.5 / 0.2, 120.0 + 192.0 * 0.5 / 0.2])


# --- match_points ---------------------------------------------------------------------


def test_match_points_with_the_true_motion_recovers_exactly_the_true_pairs(scene):
    previous, current, true = scene
    matches = match(previous, current)
    assert matches.previous.dtype == np.int64 and matches.current.dtype == np.int64
    assert pairs(matches) == true_pairs(true)


def test_match_points_with_a_prior_far_from_the_motion_finds_nothing(scene):
    previous, current, _ = scene
    wrong = make_pose(np.eye(3), np.array([8.0, 0.0, -0.8]))  # > 60 px off for points up to 25 m deep
    assert len(match(previous, current, prior=wrong)) == 0


def test_match_points_with_empty_inputs_returns_no_matches(scene):
    previous, current, _ = scene
    nothing = concat_points([current], np.arange(0))
    assert len(match(previous, nothing)) == 0
    assert len(match(nothing, current)) == 0


def test_a_point_whose_match_lies_outside_the_window_is_not_matched(scene):
    previous, current, true = scene
    k = 3
    displaced = with_current_uv(current, true[k], current.uv[true[k]] + [2.0 * POINT_RADIUS, 0.0])
    matches = match(previous, displaced)
    assert k not in matches.previous
    assert pairs(matches) == true_pairs(true, excluded={k})


def test_the_point_window_grows_with_the_previous_octave(scene):
    previous, current, true = scene
    k, offset = 5, 18.0  # beyond 15 px at octave 0, inside 15 * 1.2**2 = 21.6 px at octave 2
    displaced = with_current_uv(current, true[k], current.uv[true[k]] + [0.0, offset])
    assert (k, true[k]) not in pairs(match(previous, displaced))
    octave = previous.octave.copy()
    octave[k] = 2
    coarse = StereoPoints(previous.uv, octave, previous.descriptors, previous.disparity,
                          previous.u_right, previous.points_c)
    assert (k, true[k]) in pairs(match(coarse, displaced))


def test_a_rival_in_the_window_as_close_in_descriptor_makes_the_match_ambiguous(scene):
    previous, current, true = scene
    k = 8
    rng = np.random.default_rng(3)
    lookalike = flip_bits(previous.descriptors[k : k + 1], FLIPPED_BITS, rng)[0]
    assert hamming(lookalike, previous.descriptors[k]) == hamming(current.descriptors[true[k]], previous.descriptors[k])
    crowded = appended(current, current.uv[true[k]] + [4.0, 3.0], lookalike)
    matches = match(previous, crowded)
    assert k not in matches.previous
    assert pairs(matches) == true_pairs(true, excluded={k})


def test_a_rival_clearly_worse_than_the_true_match_passes_the_ratio_test(scene):
    previous, current, true = scene
    k = 8
    rng = np.random.default_rng(4)
    worse = flip_bits(previous.descriptors[k : k + 1], 40, rng)[0]
    crowded = appended(current, current.uv[true[k]] + [4.0, 3.0], worse)
    assert pairs(match(previous, crowded)) == true_pairs(true)


def test_each_current_feature_is_matched_at_most_once_by_its_closest_previous_feature(scene):
    previous, current, true = scene
    k = 11
    rng = np.random.default_rng(6)
    # A second previous point at the same 3D position whose descriptor is farther from the
    # current feature than point k's: both predict the same pixel and want the same feature.
    twin_descriptor = flip_bits(current.descriptors[true[k] : true[k] + 1], 20, rng)
    twin = stereo_points(previous.points_c[k : k + 1], twin_descriptor)
    doubled = concat_points([previous, twin], np.arange(len(previous) + 1))
    matches = match(doubled, current)
    assert np.unique(matches.current).size == matches.current.size
    assert pairs(matches) == true_pairs(true)
    # Put the twin first in distance: it takes the feature and point k goes without.
    closer = stereo_points(previous.points_c[k : k + 1], current.descriptors[true[k] : true[k] + 1])
    swapped = match(concat_points([previous, closer], np.arange(len(previous) + 1)), current)
    assert (len(previous), true[k]) in pairs(swapped)
    assert k not in swapped.previous


# --- match_lines ----------------------------------------------------------------------


def project_segments(endpoints_c: np.ndarray) -> np.ndarray:
    """Left-image segments (M, 4) of 3D segments (M, 2, 3)."""
    return np.column_stack([CAMERA.project(endpoints_c[:, 0]), CAMERA.project(endpoints_c[:, 1])])


def stereo_lines(endpoints_c: np.ndarray, descriptors: np.ndarray, endpoints=None) -> StereoLines:
    endpoints = project_segments(endpoints_c) if endpoints is None else endpoints
    return StereoLines(endpoints=endpoints, disparity=CAMERA.bf / endpoints_c[:, :, 2],
                       descriptors=descriptors, endpoints_c=endpoints_c)


def concat_lines(parts: list[StereoLines], order: np.ndarray) -> StereoLines:
    fields = ("endpoints", "disparity", "descriptors", "endpoints_c")
    return StereoLines(**{f: np.concatenate([getattr(p, f) for p in parts])[order] for f in fields})


def upright_segments(n: int, rng: np.random.Generator) -> np.ndarray:
    """3D segments (n, 2, 3), 1.5-3 m long and near vertical, spread over the view at 8-20 m."""
    uv = np.column_stack([rng.uniform(60.0, 260.0, n), rng.uniform(110.0, 200.0, n)])
    starts = CAMERA.backproject(uv, rng.uniform(8.0, 20.0, n))
    direction = np.column_stack([rng.uniform(-0.3, 0.3, n), -np.ones(n), rng.uniform(-0.2, 0.2, n)])
    direction *= (rng.uniform(1.5, 3.0, n) / np.linalg.norm(direction, axis=1))[:, None]
    return np.stack([starts, starts + direction], axis=1)


@pytest.fixture
def line_scene():
    """12 previous segments; the current frame holds them moved by T_C_P and 6 distractors, shuffled."""
    rng = np.random.default_rng(11)
    n, n_distractors = 12, 6
    previous_c = upright_segments(n, rng)
    descriptors = random_descriptors(n, rng)
    previous = stereo_lines(previous_c, descriptors)
    moved_c = transform_points(T_C_P, previous_c.reshape(-1, 3)).reshape(n, 2, 3)
    moved = stereo_lines(moved_c, flip_bits(descriptors, FLIPPED_BITS, rng))
    distractors = stereo_lines(upright_segments(n_distractors, rng), random_descriptors(n_distractors, rng))
    order = rng.permutation(n + n_distractors)
    current = concat_lines([moved, distractors], order)
    return previous, current, np.argsort(order)[:n]


def match_segments(previous, current, max_turn=MAX_TURN) -> FrameMatches:
    return match_lines(CAMERA, T_C_P, previous, current, LINE_RADIUS, max_turn, MAX_DISTANCE, RATIO)


def with_segment(current: StereoLines, index: int, segment) -> StereoLines:
    endpoints = current.endpoints.copy()
    endpoints[index] = segment
    return StereoLines(endpoints, current.disparity, current.descriptors, current.endpoints_c)


def rotated_about_midpoint(segment: np.ndarray, angle: float) -> np.ndarray:
    mid = 0.5 * (segment[:2] + segment[2:])
    c, s = np.cos(angle), np.sin(angle)
    R = np.array([[c, -s], [s, c]])
    return np.concatenate([R @ (segment[:2] - mid) + mid, R @ (segment[2:] - mid) + mid])


def test_match_lines_with_the_true_motion_recovers_exactly_the_true_pairs(line_scene):
    previous, current, true = line_scene
    assert pairs(match_segments(previous, current)) == true_pairs(true)


def test_match_lines_with_empty_inputs_returns_no_matches(line_scene):
    previous, current, _ = line_scene
    assert len(match_segments(previous, StereoLines.empty())) == 0
    assert len(match_segments(StereoLines.empty(), current)) == 0


def test_a_line_seen_with_the_opposite_orientation_is_rejected_by_the_angle_check(line_scene):
    previous, current, true = line_scene
    k = 2
    segment = current.endpoints[true[k]]
    flipped = with_segment(current, true[k], np.concatenate([segment[2:], segment[:2]]))
    matches = match_segments(previous, flipped)
    assert k not in matches.previous
    assert pairs(matches) == true_pairs(true, excluded={k})
    assert (k, true[k]) in pairs(match_segments(previous, flipped, max_turn=np.pi))


def test_a_line_turned_more_than_max_angle_change_is_rejected_and_less_is_kept(line_scene):
    previous, current, true = line_scene
    k = 4
    segment = current.endpoints[true[k]]
    turned = with_segment(current, true[k], rotated_about_midpoint(segment, 0.3))
    assert k not in match_segments(previous, turned).previous
    assert (k, true[k]) in pairs(match_segments(previous, turned, max_turn=0.4))
    slightly = with_segment(current, true[k], rotated_about_midpoint(segment, -0.1))
    assert (k, true[k]) in pairs(match_segments(previous, slightly))


def test_a_line_whose_midpoint_lies_outside_the_window_is_not_matched(line_scene):
    previous, current, true = line_scene
    k = 6
    shifted = with_segment(current, true[k], current.endpoints[true[k]] + 1.5 * LINE_RADIUS * np.array([1, 0, 1, 0]))
    matches = match_segments(previous, shifted)
    assert pairs(matches) == true_pairs(true, excluded={k})


def test_a_line_with_an_endpoint_behind_the_current_camera_is_not_searched(line_scene):
    previous, current, true = line_scene
    k = 1
    endpoints_c = previous.endpoints_c.copy()
    endpoints_c[k, 1, 2] = 0.5  # 0.5 m deep before the move, behind the camera after 0.8 m forward
    cut = StereoLines(previous.endpoints, previous.disparity, previous.descriptors, endpoints_c)
    assert pairs(match_segments(cut, current)) == true_pairs(true, excluded={k})


# --- angles ---------------------------------------------------------------------------


# --- candidate search -------------------------------------------------------------------


def pairs_by_brute_force(predicted, usable, observed, radius):
    """Every (query, train) within the radius, by query then observed column (ties by index)."""
    by_column = np.argsort(observed[:, 0], kind="stable")
    pairs = [(q, t) for q in np.flatnonzero(usable) for t in by_column
             if np.sum((observed[t] - predicted[q]) ** 2) <= radius[q] ** 2]
    return np.array(pairs, dtype=np.int64).reshape(-1, 2).T


@pytest.mark.parametrize("seed", range(40))
def test_pairs_within_finds_every_pair_in_the_circle_in_order(seed):
    rng = np.random.default_rng(seed)
    n_queries, n_observed = rng.integers(0, 40), rng.integers(0, 60)
    predicted = np.column_stack([rng.uniform(-300, 800, n_queries), rng.uniform(-50, 330, n_queries)])
    observed = np.round(rng.uniform(0, 280, (n_observed, 2)), int(rng.integers(0, 2)))
    observed[: n_observed // 3] = observed[:1]  # repeated pixels: ties in column
    radius = rng.uniform(1, 60, n_queries)
    usable = rng.random(n_queries) < 0.8
    query, train = pairs_within(predicted, usable, observed, radius)
    expected_query, expected_train = pairs_by_brute_force(predicted, usable, observed, radius)
    np.testing.assert_array_equal(query, expected_query)
    np.testing.assert_array_equal(train, expected_train)


def test_pairs_within_ignores_non_finite_predictions_and_copes_with_widely_spread_pixels():
    observed = np.array([[0.0, 0.0], [1e7, 1e7], [5.0, 5.0]])  # a grid of 4 px cells would need 6e12 of them
    predicted = np.array([[4.0, 4.0], [np.nan, 1.0], [np.inf, 3.0], [1e7 + 1.0, 1e7]])
    query, train = pairs_within(predicted, np.ones(4, dtype=bool), observed, np.full(4, 2.0))
    assert query.tolist() == [0, 3] and train.tolist() == [2, 1]
