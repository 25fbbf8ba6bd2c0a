"""Frame-to-frame mismatch filters: grid_cval for points, local line groups for lines, on
constructed matches and on brute-force matches of a real KITTI pair labelled by ground truth."""

import cv2
import numpy as np
import pytest
from conftest import require

from pld_slam.config import Config, FiltersConfig, load_config
from pld_slam.datasets import open_sequence
from pld_slam.frontend import extract_stereo_features
from pld_slam.tracking.outliers import (
    angle_changes,
    grid_cells,
    grid_cval,
    grid_cval_deviations,
    group_medians,
    line_llg_filter,
    local_line_groups,
    midpoint_shifts,
    point_grid_filter,
)

FILTERS = FiltersConfig()
KITTI_SIZE = (1226, 370)


def similarity_motion(uv: np.ndarray, angle_deg: float, scale: float, shift: tuple[float, float]) -> np.ndarray:
    """Pixels (N, 2) rotated by ``angle_deg`` and scaled about the KITTI image centre, then shifted."""
    centre = 0.5 * np.array(KITTI_SIZE)
    angle = np.deg2rad(angle_deg)
    rotation = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    return centre + scale * (uv - centre) @ rotation.T + np.array(shift)


def moved_segments(endpoints: np.ndarray, angle_deg: float, scale: float, shift: tuple[float, float]) -> np.ndarray:
    """Segments (M, 4) with both endpoints moved by `similarity_motion`."""
    return similarity_motion(endpoints.reshape(-1, 2), angle_deg, scale, shift).reshape(-1, 4)


def turned_about_midpoint(segment: np.ndarray, angle_deg: float) -> np.ndarray:
    """Segment (4,) rotated by ``angle_deg`` about its midpoint."""
    midpoint = 0.5 * (segment[:2] + segment[2:])
    angle = np.deg2rad(angle_deg)
    rotation = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    return (midpoint + (segment.reshape(2, 2) - midpoint) @ rotation.T).reshape(4)


# --- helpers -----------------------------------------------------------------------------


def test_group_medians_match_numpy_per_group():
    rng = np.random.default_rng(0)
    groups = rng.integers(0, 7, 200)
    values = rng.normal(size=200)
    expected = [np.median(values[groups == g]) for g in range(7)]
    np.testing.assert_allclose(group_medians(values, groups), expected)


def test_grid_cells_are_64_by_48_pixel_cells():
    uv = np.array([[10.0, 10.0], [63.9, 47.9], [64.0, 10.0], [10.0, 48.0], [70.0, 50.0]])
    cells = grid_cells(uv, 64, 48)
    assert cells[0] == cells[1]
    assert len(set(cells[[0, 2, 3, 4]])) == 4


def test_grid_cval_is_the_papers_mean_cross_product_over_the_cell():
    rng = np.random.default_rng(1)
    uv = rng.uniform(0, 64, size=(5, 2)) + [320.0, 96.0]
    origin = np.array([3.0, -2.0])
    p = uv - origin
    papers = [np.mean([p[k, 0] * p[i, 1] - p[k, 1] * p[i, 0] for i in range(5)]) for k in range(5)]
    np.testing.assert_allclose(grid_cval(uv, np.zeros(5, dtype=int), origin), papers)


def test_grid_cval_deviation_is_the_flow_deviation_across_the_cell_direction():
    rng = np.random.default_rng(2)
    uv_prev = rng.uniform(0, 64, size=(6, 2)) + [640.0, 192.0]
    flows = np.array([12.0, -4.0]) + rng.normal(scale=3.0, size=(6, 2))
    deviations = grid_cval_deviations(uv_prev, uv_prev + flows, np.zeros(6, dtype=int))
    centroid = uv_prev.mean(axis=0)
    across = np.array([centroid[1], -centroid[0]]) / np.linalg.norm(centroid)  # d x m = (d . across) |m|
    np.testing.assert_allclose(deviations, (flows - flows.mean(axis=0)) @ across)


# --- point filter ------------------------------------------------------------------------


def displaced_match_in_a_cell() -> tuple[np.ndarray, np.ndarray]:
    """Seven matches of one cell moving together, but the fifth, 25 px off."""
    rng = np.random.default_rng(3)
    uv_prev = rng.uniform(0, 1, size=(7, 2)) * [60.0, 44.0] + [322.0, 194.0]
    uv_curr = uv_prev + [14.0, -3.0] + rng.normal(scale=0.5, size=(7, 2))
    uv_curr[4] += [-15.0, 20.0]
    return uv_prev, uv_curr


def test_point_filter_removes_a_displaced_match_in_a_consistent_cell():
    keep = point_grid_filter(*displaced_match_in_a_cell(), FILTERS)
    np.testing.assert_array_equal(keep, np.arange(7) != 4)


@pytest.mark.parametrize(
    "key", ["point_grid_min_deviation_px=30.0", "point_grid_min_cell_matches=8"]
)
def test_point_filter_floors_are_the_configured_ones(key):
    """The displaced match of the cell above (25 px off) stays under a 30 px floor, or in a cell of
    fewer than 8 matches, which is not judged."""
    filters = load_config(overrides=[f"filters.{key}"]).filters
    assert point_grid_filter(*displaced_match_in_a_cell(), filters).all()


@pytest.mark.parametrize(
    "angle_deg, scale, shift", [(0.0, 1.0, (25.0, -8.0)), (1.0, 1.0, (-6.0, 3.0)), (0.5, 1.03, (4.0, 2.0))]
)
def test_point_filter_keeps_a_clean_set_under_a_global_motion(angle_deg, scale, shift):
    rng = np.random.default_rng(4)
    uv_prev = rng.uniform([20, 20], np.array(KITTI_SIZE) - 20, size=(400, 2))
    uv_curr = similarity_motion(uv_prev, angle_deg, scale, shift) + rng.normal(scale=0.5, size=(400, 2))
    assert point_grid_filter(uv_prev, uv_curr, FILTERS).all()


def test_point_filter_judges_no_cell_of_fewer_than_three_matches():
    uv_prev = np.array([[100.0, 100.0], [110.0, 110.0], [500.0, 300.0]])
    uv_curr = uv_prev + [[0.0, 0.0], [80.0, -60.0], [-90.0, 40.0]]
    assert point_grid_filter(uv_prev, uv_curr, FILTERS).all()


@pytest.mark.parametrize("n", [0, 1])
def test_point_filter_keeps_no_or_one_match(n):
    uv = np.full((n, 2), 200.0)
    keep = point_grid_filter(uv, uv + 30.0, FILTERS)
    assert keep.dtype == bool and keep.shape == (n,) and keep.all()


# --- line filter -------------------------------------------------------------------------


def cluster(centre: tuple[float, float], count: int, rng: np.random.Generator) -> np.ndarray:
    """``count`` near-vertical segments (count, 4) 60-80 px long whose domains overlap, around ``centre``."""
    midpoints = np.array(centre) + rng.uniform(-15, 15, size=(count, 2))
    angles = np.deg2rad(rng.uniform(70, 110, count))
    half = 0.5 * rng.uniform(60, 80, count)[:, None] * np.column_stack([np.cos(angles), np.sin(angles)])
    return np.hstack([midpoints - half, midpoints + half])


def test_local_line_groups_of_two_clusters_and_a_lone_line():
    rng = np.random.default_rng(5)
    endpoints = np.vstack([cluster((200, 150), 4, rng), cluster((700, 200), 5, rng), [[1000, 100, 1010, 160]]])
    groups = local_line_groups(endpoints)
    assert len(set(groups)) == 3
    assert len(set(groups[:4])) == 1 and len(set(groups[4:9])) == 1
    assert groups[0] != groups[4] != groups[9] != groups[0]


def test_local_line_groups_chain_overlaps_transitively():
    chain = np.array([[0, 0, 0, 100], [0, 90, 0, 190], [0, 180, 0, 280]], float)  # first and last do not overlap
    np.testing.assert_array_equal(local_line_groups(chain), [0, 0, 0])


def test_angle_change_is_modulo_pi_and_shift_is_the_midpoint_distance():
    prev = np.array([[0, 0, 0, 10], [0, 0, 10, 0]], float)
    curr = np.array([[3, 14, 3, 4], [4, 3, 14, 3 + 10 * np.tan(0.1)]])
    np.testing.assert_allclose(angle_changes(prev, curr), [0.0, 0.1])
    np.testing.assert_allclose(midpoint_shifts(prev, curr)[0], 5.0)


def planted_line_mismatch(planted: str) -> tuple[np.ndarray, np.ndarray]:
    """Two LLGs moving together, but the third line turned by 20 deg ("rotated") or moved 54 px more ("shifted")."""
    rng = np.random.default_rng(6)
    prev = np.vstack([cluster((300, 150), 6, rng), cluster((800, 220), 5, rng)])
    curr = moved_segments(prev, 0.5, 1.0, (10.0, 2.0))
    if planted == "rotated":
        curr[2] = turned_about_midpoint(curr[2], 20.0)
    else:
        curr[2] += [45.0, 30.0, 45.0, 30.0]
    return prev, curr


@pytest.mark.parametrize("planted", ["rotated", "shifted"])
def test_line_filter_removes_a_planted_mismatch_in_an_llg(planted):
    keep = line_llg_filter(*planted_line_mismatch(planted), FILTERS)
    np.testing.assert_array_equal(keep, np.arange(11) != 2)


@pytest.mark.parametrize(("planted", "key"), [("rotated", "line_llg_min_angle_change_deg=25.0"),
                                              ("shifted", "line_llg_min_midpoint_shift_px=80.0")])
def test_line_filter_floors_are_the_configured_ones(planted, key):
    """The planted mismatch above (turned 20 deg, or moved about 64 px) stays under a floor set above it."""
    filters = load_config(overrides=[f"filters.{key}"]).filters
    assert line_llg_filter(*planted_line_mismatch(planted), filters).all()


def test_line_filter_judges_a_lone_line_by_the_image_wide_means():
    rng = np.random.default_rng(7)
    lone = np.array([[1000.0, 50.0, 1010.0, 110.0], [100.0, 250.0, 95.0, 320.0]])
    prev = np.vstack([cluster((300, 150), 6, rng), cluster((800, 220), 5, rng), lone])
    curr = moved_segments(prev, 0.0, 1.0, (8.0, 3.0))
    curr[11] += [-120.0, 60.0, -120.0, 60.0]
    keep = line_llg_filter(prev, curr, FILTERS)
    np.testing.assert_array_equal(keep, np.arange(13) != 11)


@pytest.mark.parametrize(
    "angle_deg, scale, shift", [(0.0, 1.0, (30.0, -10.0)), (2.0, 1.0, (5.0, 0.0)), (0.5, 1.05, (0.0, 0.0))]
)
def test_line_filter_keeps_a_clean_set_under_a_global_motion(angle_deg, scale, shift):
    rng = np.random.default_rng(8)
    prev = np.vstack([cluster((300, 150), 6, rng), cluster((800, 220), 5, rng), [[1000, 50, 1010, 110]]])
    curr = moved_segments(prev, angle_deg, scale, shift) + rng.normal(scale=0.5, size=prev.shape)
    assert line_llg_filter(prev, curr, FILTERS).all()


@pytest.mark.parametrize("m", [0, 1])
def test_line_filter_keeps_no_or_one_match(m):
    endpoints = np.tile([[100.0, 100.0, 110.0, 160.0]], (m, 1))
    keep = line_llg_filter(endpoints, endpoints + 200.0, FILTERS)
    assert keep.dtype == bool and keep.shape == (m,) and keep.all()
    assert local_line_groups(endpoints).shape == (m,)


# --- real data ---------------------------------------------------------------------------


def brute_force_matches(descriptors_prev: np.ndarray, descriptors_curr: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Indices (K,), (K,) of cross-checked Hamming nearest neighbours, no motion prior."""
    matches = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True).match(descriptors_prev, descriptors_curr)
    return np.array([m.queryIdx for m in matches]), np.array([m.trainIdx for m in matches])


def distances_to_lines(uv: np.ndarray, endpoints: np.ndarray) -> np.ndarray:
    """Distance (K,) [px] of pixels (K, 2) to the infinite lines through segments (K, 4)."""
    direction = endpoints[:, 2:] - endpoints[:, :2]
    normal = np.column_stack([-direction[:, 1], direction[:, 0]]) / np.linalg.norm(direction, axis=1)[:, None]
    return np.abs(np.sum((uv - endpoints[:, :2]) * normal, axis=1))


KITTI_PAIRS = 6
"""Consecutive frame pairs of KITTI 06 (0 -> 1 to 5 -> 6) the filters are measured on."""


@pytest.fixture(scope="module")
def kitti_matches(data_dir):
    """Brute-force point and line matches of KITTI 06 frames i -> i + 1, for each of the
    `KITTI_PAIRS` pairs, labelled by ground truth.

    A point match is correct when the previous stereo point, moved by the ground-truth
    ``T_c1_c0``, projects within 3 px of its match, and gross beyond 10 px; a line match
    is correct when both projected 3D endpoints lie within 3 px of the matched infinite
    line, gross beyond 10 px or 10 deg.
    """
    sequence = open_sequence(require(data_dir / "kitti_odometry" / "sequences" / "06"))
    config, camera = Config(), sequence.camera
    features = [
        extract_stereo_features(sequence[i].left, sequence[i].right, camera, config.points, config.lines)
        for i in range(KITTI_PAIRS + 1)
    ]
    poses = sequence.groundtruth.poses
    return [
        labelled_matches(features[n], features[n + 1], np.linalg.inv(poses[n + 1]) @ poses[n], camera)
        for n in range(KITTI_PAIRS)
    ]


def labelled_matches(prev, curr, T_c1_c0: np.ndarray, camera) -> dict:
    """Brute-force matches of two frames' features, labelled correct and gross by the true
    motion ``T_c1_c0`` (4, 4) (see `kitti_matches`)."""
    i, j = brute_force_matches(prev.points.descriptors, curr.points.descriptors)
    predicted = camera.project(prev.points.points_c[i] @ T_c1_c0[:3, :3].T + T_c1_c0[:3, 3])
    point_errors = np.linalg.norm(predicted - curr.points.uv[j], axis=1)
    k, m = brute_force_matches(prev.lines.descriptors, curr.lines.descriptors)
    ends_c1 = prev.lines.endpoints_c[k] @ T_c1_c0[:3, :3].T + T_c1_c0[:3, 3]
    projected = np.hstack([camera.project(ends_c1[:, 0]), camera.project(ends_c1[:, 1])])
    line_errors = np.maximum(
        distances_to_lines(projected[:, :2], curr.lines.endpoints[m]),
        distances_to_lines(projected[:, 2:], curr.lines.endpoints[m]),
    )
    turns = angle_changes(projected, curr.lines.endpoints[m])
    return {
        "points": (prev.points.uv[i], curr.points.uv[j], point_errors < 3.0, point_errors > 10.0),
        "lines": (
            prev.lines.endpoints[k],
            curr.lines.endpoints[m],
            (line_errors < 3.0) & (turns < np.deg2rad(5.0)),
            (line_errors > 10.0) | (turns > np.deg2rad(10.0)),
        ),
    }


def removed_counts(pairs: list[dict], kind: str, keep_mask) -> np.ndarray:
    """Over all pairs: [correct matches, correct ones removed, gross ones, gross ones removed]
    of the ``kind`` ("points" or "lines") matches under the filter ``keep_mask(prev, curr)``."""
    counts = np.zeros(4, dtype=int)
    for pair in pairs:
        prev, curr, correct, gross = pair[kind]
        removed = ~keep_mask(prev, curr)
        counts += [correct.sum(), removed[correct].sum(), gross.sum(), removed[gross].sum()]
    return counts


def test_point_filter_on_kitti_removes_mismatches_and_keeps_correct_matches(kitti_matches):
    correct, correct_removed, gross, gross_removed = removed_counts(
        kitti_matches, "points", lambda prev, curr: point_grid_filter(prev, curr, FILTERS)
    )
    assert correct > 500 and gross > 100
    # Measured: 149 of 290 gross mismatches removed (51 %), 11 of 842 correct matches lost (1.3 %).
    assert gross_removed / gross >= 0.4
    assert correct_removed / correct <= 0.05


def test_line_filter_on_kitti_removes_mismatches_and_keeps_correct_matches(kitti_matches):
    correct, correct_removed, gross, gross_removed = removed_counts(
        kitti_matches, "lines", lambda prev, curr: line_llg_filter(prev, curr, FILTERS)
    )
    assert correct > 100 and gross > 20
    # Measured: 34 of 36 gross mismatches removed (94 %), 4 of 158 correct matches lost (2.5 %).
    assert gross_removed / gross >= 0.8
    assert correct_removed / correct <= 0.05
