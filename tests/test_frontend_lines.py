"""Stereo lines: the three segment detectors on rendered squares, segment geometry helpers,
stereo line matching and endpoint disparities, on rendered planes of known pose and on a
real KITTI pair."""

import dataclasses
import typing

import cv2
import numpy as np
import pytest
from conftest import require

from pld_slam.config import LinesConfig, PointsConfig, load_config
from pld_slam.datasets import open_sequence
from pld_slam.errors import ConfigError
from pld_slam.frontend import extract_stereo_features
from pld_slam.frontend.lines import (
    DETECTORS,
    detect_image_lines,
    endpoint_disparities,
    match_stereo_lines,
    near_horizontal,
    refined_to_edges,
    row_overlap,
)
from pld_slam.frontend.points import disparity_limits
from pld_slam.geometry.camera import StereoCamera
from pld_slam.geometry.segments import oriented_angle_differences, segment_directions

CAMERA = StereoCamera(fx=500.0, fy=500.0, cx=320.0, cy=240.0, baseline=0.1, width=640, height=480)
SUPERSAMPLING = 8
"""Polygons are filled at 8x and averaged down: edges placed to 1/8 px."""


# --- segment geometry --------------------------------------------------------------------


def test_near_horizontal_uses_the_angle_from_the_image_rows():
    segments = np.array([[[0, 0], [100, 10]], [[0, 0], [100, 40]], [[100, 40], [0, 0]], [[0, 0], [0, 50]]], float)
    np.testing.assert_array_equal(near_horizontal(segments, np.deg2rad(15)), [True, False, False, False])


def test_direction_difference_compares_oriented_directions():
    left = np.array([[[0, 0], [0, 10]]], float)
    right = np.array([[[5, 0], [6, 10]], [[0, 10], [0, 0]]], float)
    differences = oriented_angle_differences(
        segment_directions(left.reshape(-1, 4))[:, None], segment_directions(right.reshape(-1, 4))[None, :]
    )
    np.testing.assert_allclose(differences, [[np.arctan(0.1), np.pi]])


def test_row_overlap_is_relative_to_the_shorter_row_range():
    left = np.array([[[0, 0], [0, 100]]], float)
    right = np.array([[[0, 50], [0, 70]], [[0, 80], [0, 180]], [[0, 120], [0, 150]]], float)
    np.testing.assert_allclose(row_overlap(left, right), [[1.0, 0.2, -0.666666666]], atol=1e-6)


def test_endpoint_disparities_take_the_right_line_at_the_left_endpoint_rows():
    left = np.array([[[100, 10], [120, 50]]], float)
    right = np.array([[[70, 0], [80, 20]]], float)  # u = 70 + v / 2, extended beyond its ends
    np.testing.assert_allclose(endpoint_disparities(left, right), [[[100 - 75, 120 - 95]]])


# --- rendered planes ---------------------------------------------------------------------


def render_polygons(polygons_c: list[np.ndarray], shades: list[int]) -> tuple[np.ndarray, np.ndarray]:
    """Left and right (480, 640) uint8 images of flat polygons (K, 3) [m, left camera] on grey."""
    images = []
    for column in (0, 2):  # u_left, u_right of project_stereo
        canvas = np.full((CAMERA.height * SUPERSAMPLING, CAMERA.width * SUPERSAMPLING), 60, dtype=np.uint8)
        for polygon, shade in zip(polygons_c, shades):
            pixels = CAMERA.project_stereo(polygon)[:, [column, 1]]
            fine = ((pixels + 0.5) * SUPERSAMPLING - 0.5) * 16  # 4 fractional bits for fillPoly
            cv2.fillPoly(canvas, [np.rint(fine).astype(np.int32)], shade, lineType=cv2.LINE_8, shift=4)
        images.append(cv2.resize(canvas, (CAMERA.width, CAMERA.height), interpolation=cv2.INTER_AREA))
    return images[0], images[1]


def slanted_plane(angle: float, depth: float) -> tuple[np.ndarray, float, np.ndarray, np.ndarray]:
    """A plane through (0, 0, depth) turned by ``angle`` [rad] about the camera's y axis.

    Returns its normal ``n`` and offset ``c`` (points x with n . x = c) and two in-plane unit
    axes, horizontal and vertical.
    """
    normal = np.array([np.sin(angle), 0.0, np.cos(angle)])
    across = np.array([np.cos(angle), 0.0, -np.sin(angle)])
    return normal, depth * np.cos(angle), across, np.array([0.0, 1.0, 0.0])


def squares_on_plane(angle: float, depth: float) -> list[np.ndarray]:
    """Squares (4, 3) [m] on the plane of `slanted_plane`, turned in-plane by 0, 30, 45 or 60 deg."""
    _, _, across, down = slanted_plane(angle, depth)
    centre = np.array([0.0, 0.0, depth])
    corners = np.deg2rad([45, 135, 225, 315])
    squares = []
    for i, s in enumerate([-1.6, -0.8, 0.0, 0.8, 1.6]):
        for j, t in enumerate([-0.7, 0.0, 0.7]):
            turn = np.deg2rad([0, 45, 30, 60][(i + j) % 4])
            offsets = 0.25 * np.sqrt(2) * np.column_stack([np.cos(corners + turn), np.sin(corners + turn)])
            squares.append(centre + (s + offsets[:, :1]) * across + (t + offsets[:, 1:]) * down)
    return squares


def plane_disparity(pixels: np.ndarray, normal: np.ndarray, offset: float) -> np.ndarray:
    """Disparity (N,) [px] of the plane n . x = c seen at left pixels (N, 2)."""
    rays = np.column_stack([(pixels - [CAMERA.cx, CAMERA.cy]) / CAMERA.fx, np.ones(len(pixels))])
    return CAMERA.bf * (rays @ normal) / offset


def stereo_lines(left: np.ndarray, right: np.ndarray, config: LinesConfig):
    return match_stereo_lines(detect_image_lines(left, config), detect_image_lines(right, config), CAMERA, config)


def test_endpoint_disparities_on_a_slanted_plane_match_its_geometry():
    normal, offset, _, _ = slanted_plane(np.deg2rad(35), 4.0)
    squares = squares_on_plane(np.deg2rad(35), 4.0)
    left, right = render_polygons(squares, [200, 140, 230, 170] * 4)
    lines = stereo_lines(left, right, LinesConfig())
    expected = plane_disparity(lines.endpoints.reshape(-1, 2), normal, offset).reshape(-1, 2)
    error = np.abs(lines.disparity - expected)
    assert len(lines) > 40  # of 60 edges, the near-horizontal ones dropped
    assert np.median(error) < 0.15
    assert error.max() < 0.5
    assert np.ptp(lines.disparity) > 2.0  # depth really varies
    depth = lines.endpoints_c[:, :, 2].reshape(-1)
    np.testing.assert_allclose(depth, CAMERA.bf / lines.disparity.reshape(-1))
    np.testing.assert_allclose(lines.endpoints_c.reshape(-1, 3) @ normal, offset, rtol=0.04)


def test_near_horizontal_edges_are_dropped_and_upright_ones_kept():
    config = LinesConfig()
    square = [np.array([[-0.5, -0.5, 3.0], [0.5, -0.5, 3.0], [0.5, 0.5, 3.0], [-0.5, 0.5, 3.0]])]
    left, right = render_polygons(square, [200])
    raw = cv2.createLineSegmentDetector(cv2.LSD_REFINE_STD, config.detection_scale).detect(left)[0].reshape(-1, 2, 2)
    assert near_horizontal(raw, config.min_angle_from_horizontal).sum() >= 2  # the top and bottom edges
    lines = stereo_lines(left, right, config)
    angles = np.abs(segment_directions(lines.endpoints))
    assert len(lines) == 2
    np.testing.assert_allclose(angles, np.pi / 2, atol=0.01)
    np.testing.assert_allclose(lines.disparity, CAMERA.bf / 3.0, atol=0.1)


@pytest.mark.parametrize("detector", sorted(DETECTORS))
def test_blank_images_give_no_lines(detector):
    blank = np.full((CAMERA.height, CAMERA.width), 128, dtype=np.uint8)
    lines = stereo_lines(blank, blank, LinesConfig(detector=detector))
    assert len(lines) == 0
    assert lines.endpoints_c.shape == (0, 2, 3) and lines.descriptors.shape == (0, 32)


def step_edge_image(point: np.ndarray, angle: float) -> np.ndarray:
    """An image (240, 320) uint8, grey 60 on one side of the line through ``point`` (2,) [px] at
    ``angle`` [rad] from the image rows and 200 on the other, each pixel the area-weighted mix."""
    v, u = np.mgrid[0:240, 0:320].astype(np.float64)
    normal = np.array([-np.sin(angle), np.cos(angle)])
    distance = (u - point[0]) * normal[0] + (v - point[1]) * normal[1]
    return np.rint(60 + 140 * np.clip(distance + 0.5, 0.0, 1.0)).astype(np.uint8)


def distance_to_line(points: np.ndarray, point: np.ndarray, angle: float) -> np.ndarray:
    """Distance (N,) [px] of points (N, 2) from the line through ``point`` at ``angle``."""
    return np.abs((points - point) @ np.array([-np.sin(angle), np.cos(angle)]))


def test_refined_segments_move_onto_a_sub_pixel_edge_and_keep_their_extent():
    point, angle = np.array([160.3, 120.0]), np.deg2rad(70.0)
    image = step_edge_image(point, angle)
    direction = np.array([np.cos(angle), np.sin(angle)])
    normal = np.array([-np.sin(angle), np.cos(angle)])
    on_edge = point + np.outer([-60.0, 60.0], direction)
    off_edge = on_edge + np.outer([1.2, -0.6], normal)  # 1.2 and 0.6 px off, on either side: turned too
    refined = refined_to_edges(image, off_edge[None], LinesConfig())[0]
    assert distance_to_line(off_edge, point, angle).max() > 1.0
    assert distance_to_line(refined, point, angle).max() < 0.05
    own_direction = (off_edge[1] - off_edge[0]) / np.linalg.norm(off_edge[1] - off_edge[0])
    np.testing.assert_allclose((refined - off_edge) @ own_direction, 0.0, atol=1e-9)  # moved sideways only


def test_segments_without_an_edge_under_them_stay_as_detected():
    image = np.full((240, 320), 128, dtype=np.uint8)
    segments = np.array([[[50.0, 20.0], [60.0, 200.0]], [[200.0, 30.0], [250.0, 220.0]]])
    np.testing.assert_array_equal(refined_to_edges(image, segments, LinesConfig()), segments)
    assert refined_to_edges(image, np.zeros((0, 2, 2)), LinesConfig()).shape == (0, 2, 2)


@pytest.mark.parametrize(("reach", "found"), [(None, False), (7, True)])
def test_the_edge_is_searched_as_far_as_configured(reach, found):
    """``lines.edge_search_px``: a segment 5 px off its edge stays where it was detected with the
    default 3 px reach, and moves onto the edge with a 7 px one."""
    point, angle = np.array([160.3, 120.0]), np.deg2rad(70.0)
    image = step_edge_image(point, angle)
    direction, normal = np.array([np.cos(angle), np.sin(angle)]), np.array([-np.sin(angle), np.cos(angle)])
    off_edge = point + np.outer([-60.0, 60.0], direction) + 5.0 * normal
    config = LinesConfig() if reach is None else dataclasses.replace(LinesConfig(), edge_search_px=reach)
    refined = refined_to_edges(image, off_edge[None], config)[0]
    if found:
        assert distance_to_line(refined, point, angle).max() < 0.05
    else:
        np.testing.assert_array_equal(refined, off_edge)


# --- the three detectors on turned squares -----------------------------------------------

SQUARES_DEPTH = 4.0
"""Depth of the frontal plane of `noisy_squares` [m]: every point's disparity is bf / 4 = 12.5 px."""

EDGE_TOLERANCE = {"lsd": (0.4, 2.0), "fld": (4.0, 16.0), "edlines": (0.4, 3.5)}
"""Per detector, how far a segment's endpoints may lie across its square edge and past the
edge's corners [px]. Measured over eight noise seeds, on the image and on it one pixel
smaller: at most 0.26 and 1.5 (LSD), 3.4 and 13.7 (FLD: its segments run on past corners,
so an endpoint there lies across the next edge), 0.21 and 2.5 px (EDLines; 2.3 and 2.5
before `refined_to_edges` moved FLD's and EDLines' segments onto the edges)."""

DISPARITY_TOLERANCE = {"lsd": (0.1, 0.4), "fld": (0.1, 0.6), "edlines": (0.1, 0.6)}
"""Per detector, the largest median and largest single endpoint disparity error on the
frontal squares [px]. Measured over eight noise seeds: at most 0.057 and 0.28 (LSD), 0.058
and 0.38 (FLD), 0.056 and 0.37 px (EDLines); before `refined_to_edges`, FLD's and EDLines'
were 0.39 / 0.49 and 3.5 px."""


def add_noise(image: np.ndarray, seed: int) -> np.ndarray:
    """``image`` (H, W) uint8 with Gaussian noise of 4 grey levels added (rounded, clipped)."""
    noise = np.random.default_rng(seed).normal(0.0, 4.0, image.shape)
    return np.clip(np.rint(image + noise), 0, 255).astype(np.uint8)


def noisy_squares(seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Left and right images of the 15 squares of `squares_on_plane` on a frontal plane, brighter
    than the background, each with its own noise (seeds ``seed`` and ``seed + 1``)."""
    left, right = render_polygons(squares_on_plane(0.0, SQUARES_DEPTH), [200, 140, 230, 170] * 4)
    return add_noise(left, seed), add_noise(right, seed + 1)


def upright_square_edges(config: LinesConfig) -> tuple[np.ndarray, np.ndarray]:
    """The square edges (K, 2, 2) [px] in the left image that are not near horizontal, and the
    centre (K, 2) [px] of each one's square."""
    corners = [CAMERA.project(square) for square in squares_on_plane(0.0, SQUARES_DEPTH)]
    edges = np.array([[c[i], c[(i + 1) % 4]] for c in corners for i in range(4)])
    centres = np.repeat([c.mean(axis=0) for c in corners], 4, axis=0)
    upright = ~near_horizontal(edges, config.min_angle_from_horizontal)
    return edges[upright], centres[upright]


@pytest.mark.parametrize("detector", sorted(DETECTORS))
def test_each_detector_finds_the_square_edges_at_full_resolution(detector):
    config = LinesConfig(detector=detector)
    across_tolerance, past_corner_tolerance = EDGE_TOLERANCE[detector]
    left, _ = noisy_squares(seed=1)
    segments = detect_image_lines(left[:-1, :-1], config).segments  # odd sizes: not exactly halved
    edges, centres = upright_square_edges(config)
    length = np.linalg.norm(edges[:, 1] - edges[:, 0], axis=1)
    along = (edges[:, 1] - edges[:, 0]) / length[:, None]
    offset = segments[:, None] - edges[None, :, :1]  # (M, K, 2, 2): endpoints from each edge's start
    across = np.abs(np.einsum("mkpi,ki->mkp", offset, along[:, ::-1] * [1.0, -1.0])).max(axis=2)
    position = np.einsum("mkpi,ki->mkp", offset, along)
    past_corner = np.maximum(-position.min(axis=2), position.max(axis=2) - length)
    edge = np.argmin(across + np.maximum(past_corner, 0.0), axis=1)  # the edge each segment lies on
    each = np.arange(len(segments))
    assert np.all(across[each, edge] <= across_tolerance)
    assert np.all(past_corner[each, edge] <= past_corner_tolerance)
    found = np.bincount(edge, weights=np.linalg.norm(segments[:, 1] - segments[:, 0], axis=1), minlength=len(edges))
    assert np.all(found >= 0.4 * length)  # every edge, along much of its length
    direction = segments[:, 1] - segments[:, 0]
    to_centre = centres[edge] - segments.mean(axis=1)
    assert np.all(np.sum(to_centre * direction[:, ::-1] * [1.0, -1.0], axis=1) > 0)  # the bright side is (dv, -du)


@pytest.mark.parametrize("detector", sorted(DETECTORS))
def test_each_detector_gives_the_disparity_of_a_frontal_plane(detector):
    config = LinesConfig(detector=detector)
    median_tolerance, max_tolerance = DISPARITY_TOLERANCE[detector]
    left, right = noisy_squares(seed=1)
    lines = stereo_lines(left, right, config)
    error = np.abs(lines.disparity - CAMERA.bf / SQUARES_DEPTH)
    assert len(lines) >= 0.7 * len(upright_square_edges(config)[0])
    assert np.median(error) < median_tolerance
    assert error.max() < max_tolerance


@pytest.mark.parametrize("detector", sorted(DETECTORS))
def test_each_detector_gives_the_same_bytes_for_the_same_image(detector):
    config = LinesConfig(detector=detector)
    left, _ = noisy_squares(seed=1)
    first, second = detect_image_lines(left, config), detect_image_lines(left.copy(), config)
    assert first.segments.tobytes() == second.segments.tobytes()
    assert first.descriptors.tobytes() == second.descriptors.tobytes()


def test_the_config_offers_exactly_the_implemented_detectors():
    assert set(typing.get_args(typing.get_type_hints(LinesConfig)["detector"])) == set(DETECTORS)


def test_an_unknown_detector_is_a_config_error_naming_the_key(tmp_path):
    message = "--set lines.detector=hough: lines.detector must be one of lsd, fld, edlines"
    with pytest.raises(ConfigError, match=message):
        load_config(overrides=["lines.detector=hough"])
    upper_case = tmp_path / "upper.yaml"
    upper_case.write_text("lines:\n  detector: LSD\n")
    with pytest.raises(ConfigError, match=r"upper\.yaml: lines\.detector must be one of lsd, fld, edlines, got 'LSD'"):
        load_config([upper_case])


# --- KITTI -------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def kitti(data_dir):
    """Frame 0 of the KITTI odometry 06 extract: (camera, left, right)."""
    sequence = open_sequence(require(data_dir / "kitti_odometry" / "sequences" / "06"))
    frame = sequence[0]
    return sequence.camera, frame.left, frame.right


def test_kitti_pair_gives_many_stereo_lines_at_plausible_depths(kitti):
    camera, left, right = kitti
    config = LinesConfig()
    lines = match_stereo_lines(detect_image_lines(left, config), detect_image_lines(right, config), camera, config)
    d_min, d_max = disparity_limits(camera, config.min_depth_baselines, config.max_depth_baselines)
    assert len(lines) > 50
    assert np.all((lines.disparity >= d_min) & (lines.disparity <= d_max))
    assert 5.0 < np.median(lines.endpoints_c[:, :, 2]) < 40.0
    assert not near_horizontal(lines.endpoints.reshape(-1, 2, 2), config.min_angle_from_horizontal).any()
    np.testing.assert_allclose(camera.project(lines.endpoints_c.reshape(-1, 3)), lines.endpoints.reshape(-1, 2))


def test_lines_disabled_gives_no_lines(kitti):
    camera, left, right = kitti
    features = extract_stereo_features(left, right, camera, PointsConfig(n_features=2000), LinesConfig(enabled=False))
    assert len(features.lines) == 0
    assert len(features.points) > 300
