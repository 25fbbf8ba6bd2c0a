"""Dynamic grid and dynamic LLG: a planted moving object is flagged, the static scene is not."""

import shutil
from pathlib import Path

import numpy as np
import pytest

from pld_slam.config import DynamicConfig, load_config
from pld_slam.datasets import open_sequence
from pld_slam.errors import ConfigError
from pld_slam.eval.dynamic_labels import MaskScores
from pld_slam.eval.run_summary import summarise_run
from pld_slam.geometry.camera import StereoCamera
from pld_slam.geometry.se3 import se3_exp, transform_points
from pld_slam.synth import write_sequence
from pld_slam.system import System
from pld_slam.tracking.dynamic import (
    dynamic_grid,
    dynamic_llg,
    error_threshold,
    line_prediction_distances,
    moves_with_a_hot_cell,
    predict_stereo_with_depth_sigma,
)

CONFIGS = Path(__file__).resolve().parents[1] / "configs"

CAMERA = StereoCamera(fx=384.0, fy=384.0, cx=320.0, cy=240.0, baseline=0.5, width=640, height=480)
CELL = (64.0, 48.0)
MOTION = se3_exp(np.array([0.05, 0.0, -0.8, 0.0, 0.01, 0.0]))
"""Camera motion between the two frames, T_c_r: 0.8 m forward, a slight turn."""
OBJECT = (slice(380, 560), slice(200, 330))
"""Image region (u, v) where the moving object is: a car to the right."""


def scene_points(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Reference-frame 3D points (N, 3) spread over the image, and whether each is on the object."""
    uv = rng.uniform([10.0, 10.0], [630.0, 470.0], size=(400, 2))
    depth = rng.uniform(6.0, 40.0, size=400)
    on_object = (uv[:, 0] > OBJECT[0].start) & (uv[:, 0] < OBJECT[0].stop)
    on_object &= (uv[:, 1] > OBJECT[1].start) & (uv[:, 1] < OBJECT[1].stop)
    depth[on_object] = 8.0
    return CAMERA.backproject(uv, depth), on_object


def moved_and_observed(points_r: np.ndarray, on_object: np.ndarray, object_motion: np.ndarray, rng):
    """Predicted (static-world) and detected current pixels, the object moved by ``object_motion`` [m]."""
    predicted = CAMERA.project(transform_points(MOTION, points_r))
    moved = points_r + on_object[:, None] * object_motion
    detected = CAMERA.project(transform_points(MOTION, moved)) + rng.normal(0.0, 0.3, size=predicted.shape)
    return predicted, detected


def test_a_moving_car_is_flagged_and_the_static_points_are_not():
    rng = np.random.default_rng(0)
    points_r, on_object = scene_points(rng)
    predicted, detected = moved_and_observed(points_r, on_object, np.array([-0.4, 0.0, 0.3]), rng)
    flagged = dynamic_grid(predicted, detected, np.ones(len(detected)), CELL, DynamicConfig())
    assert on_object.sum() > 20
    assert np.array_equal(flagged, on_object)


def test_a_static_scene_gives_no_dynamic_points():
    rng = np.random.default_rng(1)
    points_r, on_object = scene_points(rng)
    predicted, detected = moved_and_observed(points_r, on_object, np.zeros(3), rng)
    assert not dynamic_grid(predicted, detected, np.ones(len(detected)), CELL, DynamicConfig()).any()


def test_a_lone_mismatch_flags_none_of_its_static_neighbours():
    """A wrong match in a sparse cell may be marked itself (the pose leaves it out either
    way), but its cell and the 8 around it stay static."""
    rng = np.random.default_rng(2)
    points_r, on_object = scene_points(rng)
    predicted, detected = moved_and_observed(points_r, on_object, np.zeros(3), rng)
    detected[0] += np.array([25.0, -10.0])  # one wrong match, no mover
    flagged = dynamic_grid(predicted, detected, np.ones(len(detected)), CELL, DynamicConfig())
    assert not flagged[1:].any()


def test_errors_are_judged_in_units_of_each_points_sigma():
    rng = np.random.default_rng(3)
    points_r, on_object = scene_points(rng)
    predicted, detected = moved_and_observed(points_r, on_object, np.array([-0.4, 0.0, 0.3]), rng)
    coarse = np.where(on_object, 20.0, 1.0)  # the object's corners located to 20 px: no evidence
    assert not dynamic_grid(predicted, detected, coarse, CELL, DynamicConfig()).any()


def truck_ahead_observations(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Predicted and detected stereo pixels (N, 3) of a street with a truck 6 m ahead that
    drives on with the camera (0.8 m forward), and whether each point is on the truck.

    The truck's rear sits around the image centre, where driving forward barely moves a
    pixel, but its disparity stays that of 6 m while a static point's would grow.
    """
    static_uv = rng.uniform([10.0, 10.0], [630.0, 470.0], size=(300, 2))
    static_uv = static_uv[(np.abs(static_uv[:, 0] - 320.0) > 80.0) | (np.abs(static_uv[:, 1] - 240.0) > 70.0)]
    truck_uv = rng.uniform([300.0, 220.0], [340.0, 262.0], size=(30, 2))
    depth = np.concatenate([rng.uniform(6.0, 40.0, len(static_uv)), np.full(len(truck_uv), 6.0)])
    points_r = CAMERA.backproject(np.vstack([static_uv, truck_uv]), depth)
    on_truck = np.arange(len(points_r)) >= len(static_uv)
    predicted = CAMERA.project_stereo(transform_points(MOTION, points_r))
    moved = points_r + on_truck[:, None] * np.array([0.0, 0.0, 0.8])
    detected = CAMERA.project_stereo(transform_points(MOTION, moved)) + rng.normal(0.0, 0.3, size=predicted.shape)
    return predicted, detected, on_truck


def test_a_truck_driving_on_ahead_is_flagged_by_its_disparity():
    predicted, detected, on_truck = truck_ahead_observations(np.random.default_rng(5))
    sigma = np.ones(len(detected))
    assert np.array_equal(dynamic_grid(predicted, detected, sigma, CELL, DynamicConfig()), on_truck)
    left_only = dynamic_grid(predicted[:, :2], detected[:, :2], sigma, CELL, DynamicConfig())
    assert np.count_nonzero(left_only) < 0.5 * np.count_nonzero(on_truck)


def test_a_point_next_to_a_hot_cell_is_dynamic_only_if_it_moved_with_it():
    cells = np.array([[5, 5], [6, 5], [6, 6], [8, 5], [5, 5]])
    offsets = np.array([[6.0, 0.0], [4.0, 1.0], [-4.0, 0.0], [6.0, 0.0], [0.5, 0.0]])
    hot_cells, hot_means = np.array([[5, 5]]), np.array([[6.0, 0.0]])
    moved = moves_with_a_hot_cell(cells, offsets, hot_cells, hot_means)
    # in the cell; a neighbour moving alike; a neighbour moving the other way; two cells
    # away; in the cell but at rest (a static point beside the mover)
    assert moved.tolist() == [True, True, False, False, False]


def test_the_threshold_follows_the_frames_median_with_a_floor():
    assert error_threshold(np.array([0.2, 0.3, 0.4]), 4.0, 3.0) == 3.0
    assert error_threshold(np.array([1.0, 2.0, 3.0]), 4.0, 3.0) == pytest.approx(8.0)
    assert error_threshold(np.zeros(0), 4.0, 3.0) == np.inf


def test_a_depth_sigma_seen_from_the_same_pose_is_a_disparity_sigma():
    """Pushed along its own ray, a point keeps its left pixel; its disparity bf/z moves by
    sigma_d z / (z + sigma_z), with sigma_z = z**2 sigma_d / bf."""
    depth = np.array([5.0, 20.0, 60.0])
    points_r = CAMERA.backproject(np.array([[100.0, 50.0], [320.0, 240.0], [600.0, 400.0]]), depth)
    sigma_d = np.array([0.5, 0.5, 1.2])
    _, shift = predict_stereo_with_depth_sigma(CAMERA, np.eye(4), points_r, sigma_d)
    sigma_z = depth**2 * sigma_d / CAMERA.bf
    np.testing.assert_allclose(shift, sigma_d * depth / (depth + sigma_z), rtol=1e-9)


def test_driving_towards_a_point_magnifies_its_depth_sigma_in_the_prediction():
    """The nearer the camera gets to a point it predicts, the more the point's depth
    uncertainty moves the prediction: from 8 m to 4 m away, over 10 times its disparity sigma."""
    forward = se3_exp(np.array([0.0, 0.0, -4.0, 0.0, 0.0, 0.0]))
    points_r = CAMERA.backproject(np.array([[500.0, 300.0], [500.0, 300.0]]), np.array([8.0, 40.0]))
    sigma_d = np.array([0.5, 0.5])
    _, moved = predict_stereo_with_depth_sigma(CAMERA, forward, points_r, sigma_d)
    _, still = predict_stereo_with_depth_sigma(CAMERA, np.eye(4), points_r, sigma_d)
    assert np.all(moved > still)
    assert moved[0] > 10 * sigma_d[0] and moved[0] > moved[1]


def scene_segments(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Reference 3D segments (M, 2, 3): vertical edges of facades, and of the car; which are on the car."""
    facade_u = np.linspace(20.0, 360.0, 12)
    car_u = np.linspace(400.0, 540.0, 6)
    u = np.concatenate([facade_u, car_u])
    v0 = np.where(np.arange(len(u)) < len(facade_u), 60.0, 220.0)
    v1 = v0 + np.where(np.arange(len(u)) < len(facade_u), 150.0, 90.0)
    depth = np.where(np.arange(len(u)) < len(facade_u), rng.uniform(12.0, 20.0, len(u)), 8.0)
    starts = CAMERA.backproject(np.column_stack([u, v0]), depth)
    ends = CAMERA.backproject(np.column_stack([u + 3.0, v1]), depth)
    on_car = np.arange(len(u)) >= len(facade_u)
    return np.stack([starts, ends], axis=1), on_car, depth


def project_segments(T: np.ndarray, segments: np.ndarray) -> np.ndarray:
    starts = CAMERA.project(transform_points(T, segments[:, 0]))
    ends = CAMERA.project(transform_points(T, segments[:, 1]))
    return np.column_stack([starts, ends])


def test_a_moving_car_flags_its_line_group_and_not_the_facade():
    rng = np.random.default_rng(4)
    segments, on_car, _ = scene_segments(rng)
    predicted = project_segments(MOTION, segments)
    moved = segments + on_car[:, None, None] * np.array([-0.4, 0.0, 0.3])
    detected = project_segments(MOTION, moved) + rng.normal(0.0, 0.3, size=predicted.shape)
    assert np.array_equal(dynamic_llg(predicted, detected, DynamicConfig()), on_car)
    static = project_segments(MOTION, segments) + rng.normal(0.0, 0.3, size=predicted.shape)
    assert not dynamic_llg(predicted, static, DynamicConfig()).any()


def test_line_distance_ignores_sliding_along_the_line():
    detected = np.array([[100.0, 50.0, 100.0, 250.0]])
    slid = np.array([[100.0, 80.0, 100.0, 200.0]])  # same line, detected shorter
    shifted = np.array([[104.0, 50.0, 104.0, 250.0]])
    assert line_prediction_distances(slid, detected) == pytest.approx([0.0])
    assert line_prediction_distances(shifted, detected) == pytest.approx([4.0])


@pytest.fixture(scope="module")
def street_with_traffic(tmp_path_factory):
    """20 frames of the synthetic ``dynamic`` street (640x480, seed 1), with its moving-object masks."""
    folder = tmp_path_factory.mktemp("traffic") / "seq"
    write_sequence(folder, "dynamic", n_frames=20, seed=1)
    return folder


def test_rendered_traffic_is_flagged_and_the_street_is_not(street_with_traffic):
    """Over a real pipeline run: most flagged features lie on the moving vehicles and people.

    Bounds from a measured run (points P 0.81 R 0.64, lines P 0.87 R 0.79), with margin.
    """
    sequence = open_sequence(street_with_traffic)
    files = [CONFIGS / "default.yaml", CONFIGS / "synthetic.yaml"]
    config = load_config(files)
    scores = MaskScores(sequence)
    dynamic = summarise_run(sequence, System(sequence, config, [scores]).run(), config, mask_scores=scores)["dynamic"]
    assert dynamic["points"]["precision"] > 0.7 and dynamic["points"]["recall"] > 0.5
    assert dynamic["lines"]["precision"] > 0.7 and dynamic["lines"]["recall"] > 0.6
    off = load_config(files, ["dynamic.grid=false", "dynamic.llg=false"])
    assert summarise_run(sequence, System(sequence, off).run(), off)["dynamic"]["marked_fraction"] == 0.0


def test_labels_from_the_masks_are_exactly_the_features_on_them(street_with_traffic):
    """``dynamic.from_masks`` (the bound of the detectors) labels by the mask: precision and recall 1."""
    sequence = open_sequence(street_with_traffic)
    config = load_config([CONFIGS / "default.yaml", CONFIGS / "synthetic.yaml"], ["dynamic.from_masks=true"])
    scores = MaskScores(sequence)
    result = System(sequence, config, [scores]).run(max_frames=6)
    dynamic = summarise_run(sequence, result, config, mask_scores=scores)["dynamic"]
    for kind in ("points", "lines"):
        assert dynamic[kind]["precision"] == 1.0 and dynamic[kind]["recall"] == 1.0
        assert dynamic[kind]["flagged_on_them"] == dynamic[kind]["flagged"] == dynamic[kind]["on_moving_objects"] > 0


def test_labels_from_masks_need_a_sequence_with_masks(tmp_path):
    folder = tmp_path / "seq"
    write_sequence(folder, "static", n_frames=2, size=(320, 240), seed=0)
    shutil.rmtree(folder / "dynamic_masks")
    config = load_config([CONFIGS / "default.yaml"], ["dynamic.from_masks=true"])
    with pytest.raises(ConfigError, match="dynamic_masks"):
        System(open_sequence(folder), config)
