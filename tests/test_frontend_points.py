"""Stereo ORB points: descriptor matching helpers, bucketing, row-band stereo matching with
sub-pixel disparity, on rendered pairs of known disparity and on a real KITTI pair."""

import dataclasses

import cv2
import numpy as np
import pytest
from conftest import require

from pld_slam.config import LinesConfig, PointsConfig
from pld_slam.datasets import open_sequence
from pld_slam.frontend import extract_stereo_features
from pld_slam.frontend.descriptors import CandidateMatches, best_matches, hamming_distances, unique_train
from pld_slam.frontend.points import (
    bucket_cells,
    bucket_strongest,
    detect_image_points,
    disparity_limits,
    match_stereo_points,
    sad_along_row,
)
from pld_slam.geometry.camera import StereoCamera

CAMERA = StereoCamera(fx=500.0, fy=500.0, cx=320.0, cy=240.0, baseline=0.1, width=640, height=480)
SUPERSAMPLING = 4
"""Rendered pairs are drawn at 4x and averaged down, so disparities are exact to 1/4 px."""


def smooth_texture(height: int, width: int, seed: int) -> np.ndarray:
    """Blurred noise (height, width) float32 in [0, 255]: blobs a few pixels wide, many corners."""
    noise = np.random.default_rng(seed).random((height, width)).astype(np.float32)
    blurred = cv2.GaussianBlur(noise, (0, 0), 1.2 * SUPERSAMPLING)
    return 255.0 * (blurred - blurred.min()) / (blurred.max() - blurred.min())


def shifted_pair(texture: np.ndarray, disparity: float) -> tuple[np.ndarray, np.ndarray]:
    """Left and right (480, 640) uint8 views of a fronto-parallel textured plane.

    ``texture`` is at 4x resolution and wider than the image by at least the disparity;
    right pixel ``u`` shows what left pixel ``u + disparity`` shows.
    """
    shift = round(disparity * SUPERSAMPLING)
    assert shift == disparity * SUPERSAMPLING, "disparity must be a multiple of 1/4 px"
    width = CAMERA.width * SUPERSAMPLING

    def downsample(hi: np.ndarray) -> np.ndarray:
        small = cv2.resize(hi, (CAMERA.width, CAMERA.height), interpolation=cv2.INTER_AREA)
        return np.clip(np.rint(small), 0, 255).astype(np.uint8)

    return downsample(texture[:, :width]), downsample(texture[:, shift : shift + width])


def stereo_points(left: np.ndarray, right: np.ndarray, config: PointsConfig):
    return match_stereo_points(detect_image_points(left, config), detect_image_points(right, config), CAMERA, config)


# --- descriptor helpers ------------------------------------------------------------------


def test_hamming_distances_count_differing_bits():
    rng = np.random.default_rng(0)
    a, b = rng.integers(0, 256, (2, 50, 32), dtype=np.uint8)
    expected = np.unpackbits(a ^ b, axis=1).sum(axis=1)
    np.testing.assert_array_equal(hamming_distances(a, b), expected)


def test_best_matches_applies_threshold_ratio_test_and_rivals():
    # query: 0 ambiguous, 1 its second candidate is the same feature (no rival),
    # 2 clear, 3 too far, 4 no rival at all.
    query = np.array([0, 0, 1, 1, 2, 2, 3, 4])
    train = np.array([0, 1, 2, 3, 4, 5, 6, 7])
    distance = np.array([10, 11, 10, 11, 10, 30, 70, 20])
    position = np.array([0.0, 5.0, 0.0, 0.5, 0.0, 5.0, 0.0, 0.0])
    matches = best_matches(query, train, distance, position, max_distance=64, ratio=0.8)
    np.testing.assert_array_equal(matches.query, [1, 2, 4])
    np.testing.assert_array_equal(matches.train, [2, 4, 7])


def test_unique_train_keeps_the_closest_query():
    matches = CandidateMatches(
        query=np.array([0, 1, 2, 3]), train=np.array([5, 5, 6, 5]), distance=np.array([9, 4, 7, 4])
    )
    unique = unique_train(matches)
    np.testing.assert_array_equal(unique.query, [1, 2])
    np.testing.assert_array_equal(unique.train, [5, 6])


# --- bucketing ---------------------------------------------------------------------------


def test_bucketing_takes_every_cells_strongest_before_any_second():
    rng = np.random.default_rng(1)
    cluster = np.column_stack([rng.uniform(0, 31, 100), rng.uniform(0, 31, 100)])
    sparse = np.column_stack([40.0 + 32.0 * np.arange(20), np.full(20, 100.0)])
    uv = np.vstack([cluster, sparse])
    response = np.r_[rng.uniform(10, 20, 100), np.full(20, 1.0)]
    kept = bucket_strongest(uv, response, cell_size=32, n_keep=30)
    assert kept.size == 30
    assert set(range(100, 120)) <= set(kept.tolist())
    strongest_in_cluster = np.argsort(-response[:100])[:10]
    assert set(strongest_in_cluster.tolist()) <= set(kept.tolist())


def test_bucketing_fills_every_cell_to_the_same_round():
    rng = np.random.default_rng(2)
    uv = np.column_stack([rng.gamma(2.0, 60.0, 3000) % 640, rng.uniform(0, 480, 3000)])
    kept = bucket_strongest(uv, rng.random(3000), cell_size=32, n_keep=500)
    cells = bucket_cells(uv, 32)
    per_cell = np.bincount(cells[kept], minlength=cells.max() + 1)
    available = np.bincount(cells, minlength=cells.max() + 1)
    quota = per_cell.max()
    assert quota < available.max()  # the dense cells were capped
    # each cell gave min(available, quota), or one fewer where the last round ran out
    shortfall = np.minimum(available, quota) - per_cell
    assert set(np.unique(shortfall).tolist()) <= {0, 1}


# --- rendered pairs of known disparity ---------------------------------------------------


@pytest.mark.parametrize("disparity", [7.5, 20.25, 41.75])
def test_plane_at_known_depth_gives_its_disparity_to_subpixel_accuracy(disparity):
    texture = smooth_texture(CAMERA.height * SUPERSAMPLING, (CAMERA.width + 60) * SUPERSAMPLING, seed=3)
    left, right = shifted_pair(texture, disparity)
    points = stereo_points(left, right, PointsConfig(n_features=1000))
    error = points.disparity - disparity
    assert len(points) > 300
    assert np.median(np.abs(error)) < 0.15
    assert np.percentile(np.abs(error), 95) < 0.4
    np.testing.assert_allclose(points.u_right, points.uv[:, 0] - points.disparity)
    np.testing.assert_allclose(np.median(points.points_c[:, 2]), CAMERA.bf / disparity, rtol=0.01)
    np.testing.assert_allclose(CAMERA.project(points.points_c), points.uv, atol=1e-9)


def test_planted_copy_makes_a_match_ambiguous_and_the_ratio_test_rejects_it():
    # One pyramid level and every corner kept, so that both copies are candidates.
    config = PointsConfig(n_features=20000, oversampling=1.0, n_levels=1, min_separation_px=1)
    texture = smooth_texture(CAMERA.height * SUPERSAMPLING, (CAMERA.width + 60) * SUPERSAMPLING, seed=4)
    left, right = shifted_pair(texture, 20.0)
    rows, columns = slice(200, 300), slice(360, 460)  # a patch of the right image ...
    planted = right.copy()
    planted[rows, columns.start - 110 : columns.stop - 110] = right[rows, columns]  # ... copied 110 px left

    def inside_patch(points) -> np.ndarray:
        u_right, v = points.u_right, points.uv[:, 1]
        return (v > 220) & (v < 280) & (u_right > 380) & (u_right < 440)

    clean = stereo_points(left, right, config)
    ambiguous = stereo_points(left, planted, config)
    assert inside_patch(clean).sum() > 10
    assert inside_patch(ambiguous).sum() == 0
    assert np.all(np.abs(ambiguous.disparity - 20.0) < 0.5)


def test_blank_images_give_no_points():
    blank = np.full((CAMERA.height, CAMERA.width), 128, dtype=np.uint8)
    points = stereo_points(blank, blank, PointsConfig())
    assert len(points) == 0
    assert points.points_c.shape == (0, 3) and points.descriptors.shape == (0, 32)


# --- KITTI -------------------------------------------------------------------------------

KITTI_POINTS = PointsConfig(n_features=2000)
"""ORB-SLAM2's KITTI setting, as ``configs/kitti.yaml``."""


@pytest.fixture(scope="module")
def kitti(data_dir):
    """Frame 0 of the KITTI odometry 06 extract: (camera, left, right)."""
    sequence = open_sequence(require(data_dir / "kitti_odometry" / "sequences" / "06"))
    frame = sequence[0]
    return sequence.camera, frame.left, frame.right


def test_kitti_pair_gives_many_stereo_points_at_plausible_depths(kitti):
    camera, left, right = kitti
    points = match_stereo_points(
        detect_image_points(left, KITTI_POINTS), detect_image_points(right, KITTI_POINTS), camera, KITTI_POINTS
    )
    d_min, d_max = disparity_limits(camera, KITTI_POINTS.min_depth_baselines, KITTI_POINTS.max_depth_baselines)
    assert len(points) > 300
    assert np.all((points.disparity >= d_min) & (points.disparity <= d_max))
    assert 5.0 < np.median(points.points_c[:, 2]) < 40.0
    assert len(np.unique(points.descriptors, axis=0)) > 0.95 * len(points)


def test_kitti_bucketing_covers_more_of_the_image_than_plain_orb(kitti):
    _, left, _ = kitti
    bucketed = detect_image_points(left, KITTI_POINTS)
    orb = cv2.ORB_create(nfeatures=KITTI_POINTS.n_features, edgeThreshold=19, fastThreshold=20)
    plain = cv2.KeyPoint_convert(orb.detect(left, None))
    n_cells = np.ceil(left.shape[0] / 32) * np.ceil(left.shape[1] / 32)

    def coverage(uv: np.ndarray) -> float:
        return np.unique(bucket_cells(uv, 32)).size / n_cells

    assert len(bucketed.uv) == KITTI_POINTS.n_features
    assert coverage(bucketed.uv) > 0.35
    assert coverage(bucketed.uv) > 1.5 * coverage(plain)


def test_extraction_is_deterministic(kitti):
    camera, left, right = kitti
    first = extract_stereo_features(left, right, camera, KITTI_POINTS, LinesConfig())
    second = extract_stereo_features(left, right, camera, KITTI_POINTS, LinesConfig())
    for kind in ("points", "lines"):
        a, b = getattr(first, kind), getattr(second, kind)
        for spec in dataclasses.fields(a):
            np.testing.assert_array_equal(getattr(a, spec.name), getattr(b, spec.name), err_msg=f"{kind}.{spec.name}")


def test_kitti_keeps_a_corner_found_at_several_octaves_once(kitti):
    _, left, _ = kitti
    kept = detect_image_points(left, KITTI_POINTS)
    cells = bucket_cells(kept.uv, KITTI_POINTS.min_separation_px)
    assert np.unique(cells).size == len(kept.uv)
    with_copies = detect_image_points(left, dataclasses.replace(KITTI_POINTS, min_separation_px=1))
    close = np.linalg.norm(with_copies.uv[:, None] - with_copies.uv[None], axis=2) < 1.0
    assert (close.sum() - len(with_copies.uv)) > 50  # without it, copies are common


def test_best_matches_judges_rivals_by_euclidean_distance_in_2d():
    # query 0: its second candidate is the same feature found 0.3 px lower (no rival);
    # query 1: the second candidate is 3 px away (a rival with an equal distance).
    query = np.array([0, 0, 1, 1])
    train = np.array([0, 1, 2, 3])
    distance = np.array([10, 10, 10, 10])
    position = np.array([[100.0, 50.0], [100.0, 50.3], [200.0, 50.0], [203.0, 50.0]])
    matches = best_matches(query, train, distance, position, max_distance=64, ratio=0.8)
    assert matches.query.tolist() == [0]


@pytest.mark.parametrize("shift", [-3, 0, 2])
def test_sad_along_row_is_smallest_at_the_true_shift_whatever_the_brightness_offset(shift):
    rng = np.random.default_rng(7)
    left = rng.integers(0, 200, (60, 120), dtype=np.uint8)
    right = np.clip(np.roll(left, shift, axis=1).astype(np.int64) + 40, 0, 255).astype(np.uint8)  # brighter copy
    left_px = np.array([[50, 30], [70, 20], [2, 30]])  # the last window leaves the image
    right_u = left_px[:, 0]  # the initial match: no disparity
    sad, inside = sad_along_row(left, right, left_px, right_u, half_window=5, radius=5)
    assert inside.tolist() == [True, True, False]
    assert sad.shape == (2, 11)
    assert np.argmin(sad, axis=1).tolist() == [5 + shift, 5 + shift]
    assert np.allclose(sad[:, 5 + shift], 0.0)  # the mean-free windows are equal
