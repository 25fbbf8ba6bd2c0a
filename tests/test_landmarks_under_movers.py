"""Missed point landmarks judged by the movers near them (`pld_slam.localisation.local_map.missed_near_movers`):
under a mover at their depth, and missed in view unless a nearer mover hides them."""

import numpy as np
import pytest

from pld_slam.config import MappingConfig, load_config
from pld_slam.frontend import StereoPoints
from pld_slam.geometry.camera import StereoCamera
from pld_slam.localisation.local_map import missed_in_image, missed_near_movers
from pld_slam.matching.projection import LandmarkSnapshot

CAMERA = StereoCamera(fx=400.0, fy=400.0, cx=320.0, cy=240.0, baseline=0.5, width=640, height=480)
RADIUS_PX = 64.0
DEPTH_TOLERANCE = MappingConfig().mover_depth_tolerance


def snapshot(points_w: np.ndarray) -> LandmarkSnapshot:
    n = len(points_w)
    return LandmarkSnapshot(
        ids=np.arange(10, 10 + n), geometry=points_w, descriptors=np.zeros((n, 32), np.uint8),
        normals=np.tile([0.0, 0.0, 1.0], (n, 1)), max_distance=np.full(n, 100.0),
    )


def stereo_points(points_c: np.ndarray) -> StereoPoints:
    disparity = CAMERA.fx * CAMERA.baseline / points_c[:, 2]
    uv = CAMERA.project(points_c)
    n = len(points_c)
    return StereoPoints(uv=uv, octave=np.zeros(n, np.int64), descriptors=np.zeros((n, 32), np.uint8),
                        disparity=disparity, u_right=uv[:, 0] - disparity, points_c=points_c)


def judged(points_w: LandmarkSnapshot, found: np.ndarray, points: StereoPoints, dynamic: np.ndarray,
           depth_tolerance: float = DEPTH_TOLERANCE):
    """`missed_near_movers` for a camera at the world origin looking down +z."""
    return missed_near_movers(missed_in_image(CAMERA, np.eye(4), points_w, found), points, dynamic, RADIUS_PX,
                              depth_tolerance)


def test_only_a_missed_landmark_with_a_mover_at_its_depth_nearby_lies_under_a_mover():
    # Camera at the world origin looking down +z; landmarks at least 100 px apart in the image, and
    # what stands near each one's pixel now (all within 10 px of it but the last):
    landmarks = np.array([
        [0.0, 0.0, 20.0],  # 0: missed, a mover 1 m deeper: under a mover
        [-6.0, 0.0, 20.0],  # 1: missed, a mover 10 m nearer, in front of it: hidden, not under
        [6.0, 0.0, 10.0],  # 2: missed, a mover 10 m behind it: not under
        [-6.0, -5.0, 20.0],  # 3: missed, a static point at its depth: not under
        [0.0, -5.0, 20.0],  # 4: found again, a mover at its depth: not missed
        [16.5, -5.0, 20.0],  # 5: outside the image (u = 650), a mover at its depth 20 px away: not judged
        [0.0, 5.0, 20.0],  # 6: missed, a mover at its depth 100 px away
    ])
    mover_points = np.array([[0.5, 0.0, 21.0], [-2.875, 0.0, 10.0], [11.75, 0.0, 20.0], [0.3, -5.0, 20.0],
                             [15.5, -5.0, 20.0], [5.0, 5.0, 20.0]])
    static_points = np.array([[-5.9, -5.0, 20.0]])
    points = stereo_points(np.concatenate([mover_points, static_points]))
    dynamic = np.array([True] * len(mover_points) + [False])
    ids = snapshot(landmarks).ids
    under = judged(snapshot(landmarks), ids[[4]], points, dynamic).under_movers
    assert under.tolist() == [ids[0]]


@pytest.mark.parametrize("tolerance", [DEPTH_TOLERANCE, 0.05])
def test_the_depth_band_is_relative_to_the_landmark_depth(tolerance):
    """The band is ``mapping.mover_depth_tolerance`` of the landmark's depth, whatever the key says."""
    landmark = np.array([[0.0, 0.0, 30.0]])
    inside = 30.0 * (1.0 + 0.9 * tolerance)
    outside = 30.0 * (1.0 + 1.1 * tolerance)
    for depth, expected in ((inside, [10]), (outside, [])):
        points = stereo_points(np.array([[0.3, 0.0, depth]]))
        under = judged(snapshot(landmark), np.zeros(0, np.int64), points, np.array([True]), tolerance).under_movers
        assert under.tolist() == expected, depth


def test_a_landmark_beyond_its_search_range_is_judged_too():
    """The search skips a point landmark outside 0.8 x its nearest to 1.2 x its farthest distance;
    a mover at its depth still marks it: the range bounds where its descriptor matches, not where
    it can be seen (`missed_near_movers`)."""
    landmark = np.array([[0.0, 0.0, 5.0]])
    seen_from_far = LandmarkSnapshot(
        ids=np.array([10]), geometry=landmark, descriptors=np.zeros((1, 32), np.uint8),
        normals=np.array([[0.0, 0.0, 1.0]]), max_distance=np.array([40.0]),
    )
    config = load_config()
    points_config = config.points
    nearest_searched = (config.mapping.search_nearest_scale * 40.0
                        / points_config.scale_factor ** (points_config.n_levels - 1))
    assert nearest_searched > 5.0  # the search of the local map skips it
    points = stereo_points(np.array([[0.2, 0.0, 5.2]]))
    under = judged(seen_from_far, np.zeros(0, np.int64), points, np.array([True])).under_movers
    assert under.tolist() == [10]


def test_a_landmark_hidden_by_a_nearer_mover_is_not_missed_in_view():
    # Camera at the world origin looking down +z; landmarks 100 px or more apart in the image:
    landmarks = np.array([
        [0.0, 0.0, 20.0],  # 0: a mover 10 m nearer 10 px away: hidden, not missed
        [-6.0, 0.0, 20.0],  # 1: a mover at its depth: missed (the mover stands where it was)
        [6.0, 0.0, 10.0],  # 2: a mover 10 m behind it: missed
        [-6.0, -5.0, 20.0],  # 3: a static point nearer: missed (only movers hide)
        [0.0, -5.0, 20.0],  # 4: found: not missed
        [6.0, 5.0, 20.0],  # 5: a nearer mover 100 px away, outside the radius: missed
        [0.0, 0.0, -5.0],  # 6: behind the camera: not in view
    ])
    mover_points = np.array([[0.25, 0.0, 10.0], [-5.8, 0.0, 20.5], [11.5, 0.0, 20.0], [0.1, -2.5, 10.0],
                             [5.5, 2.5, 10.0]])
    static_points = np.array([[-2.9, -2.5, 10.0]])
    points = stereo_points(np.concatenate([mover_points, static_points]))
    dynamic = np.array([True] * len(mover_points) + [False])
    ids = snapshot(landmarks).ids
    missed = judged(snapshot(landmarks), ids[[4]], points, dynamic).in_view
    assert missed.tolist() == ids[[1, 2, 3, 5]].tolist()
    everything_static = judged(snapshot(landmarks), ids[[4]], points, np.zeros(len(dynamic), dtype=bool)).in_view
    assert everything_static.tolist() == ids[[0, 1, 2, 3, 5]].tolist()
