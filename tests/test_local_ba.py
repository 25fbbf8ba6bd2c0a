"""Local bundle adjustment on hand-built maps: the window, the gauge, what is left out, and outliers erased.

The map: five keyframes 1.2 m apart along a street (ids 0-4, 4 the new one) and landmarks
in groups seen by chosen keyframes:

====== ============= ====== ======
group  observers     points lines
====== ============= ====== ======
A      2, 3, 4       50     4
B      1, 2, 3, 4    30     3
C      0, 1          40     3
D      4             10     2
E      1, 2          20     0
====== ============= ====== ======

Keyframe 4 then shares 87 landmarks with keyframes 2 and 3 and 33 with keyframe 1: with
``local_ba_window = 2`` the window is keyframes 4, 2, 3 (ties go to the lower id). Its
landmarks seen twice or more are A, B and E; keyframe 1 sees B and E from outside the
window and is held fixed; keyframe 0 sees none of them and stays out, as do group C (not
seen from the window) and group D (seen by keyframe 4 alone).

Features are the true projections with noise of a third of their sigma; the window's poses
start 3 cm per axis and 0.3 degrees off, every landmark 5 cm per axis; keyframes 0 and 1
sit at their true poses. Four point observations in the window are moved 40 px (outliers).
The map is built by hand (`Map.add_keyframe` on keyframes whose ``point_ids`` name the
landmarks), without images or local mapping.
"""

import dataclasses
from dataclasses import dataclass

import numpy as np
import pytest
from finite_differences import CAMERA

from pld_slam.config import Config, load_config
from pld_slam.frontend import LeftKeypoints, StereoFeatures, StereoLines, StereoPoints
from pld_slam.geometry.se3 import inverse, make_pose, se3_exp, so3_exp, so3_log, transform_points
from pld_slam.mapping.keyframe import KeyFrame
from pld_slam.mapping.local_ba import local_bundle_adjustment
from pld_slam.mapping.map import Map
from pld_slam.mapping.map_ba import BaReport, MapBaOptions, adjust_keyframes

CONFIG = dataclasses.replace(Config(), mapping=dataclasses.replace(Config().mapping, local_ba_window=2))
CORNER_NOISE_PX = 1.0 / 3.0
DISPARITY_NOISE_PX = CONFIG.points.disparity_sigma_px / 3.0
LINE_NOISE_PX = CONFIG.tracking.line_sigma_px / 3.0

POINT_GROUPS = {"A": ((2, 3, 4), 50), "B": ((1, 2, 3, 4), 30), "C": ((0, 1), 40), "D": ((4,), 10), "E": ((1, 2), 20)}
LINE_GROUPS = {"A": ((2, 3, 4), 4), "B": ((1, 2, 3, 4), 3), "C": ((0, 1), 3), "D": ((4,), 2)}


@dataclass
class HandMadeMap:
    """A map and the truth behind it."""

    world_map: Map
    T_c_w: np.ndarray
    points_w: np.ndarray
    lines_w: np.ndarray
    point_group: np.ndarray
    line_group: np.ndarray
    point_outliers: list[tuple[int, int]]
    """(keyframe id, feature index) of the observations moved 40 px."""


def true_poses(rng: np.random.Generator, n_keyframes: int) -> np.ndarray:
    """``T_c_w`` (K, 4, 4) 1.2 m apart along +z, a little lateral wander and yaw."""
    return np.array(
        [
            inverse(make_pose(so3_exp([0.0, rng.uniform(-0.02, 0.02), 0.0]), [rng.uniform(-0.1, 0.1), 0.0, 1.2 * k]))
            for k in range(n_keyframes)
        ]
    )


def visible_points(rng: np.random.Generator, n: int) -> np.ndarray:
    """(n, 3) facade points 16-40 m ahead of the origin, in view from every keyframe."""
    side = rng.choice([-1.0, 1.0], n)
    return np.column_stack([side * rng.uniform(3.0, 7.0, n), rng.uniform(-2.0, 1.2, n), rng.uniform(16.0, 40.0, n)])


def visible_lines(rng: np.random.Generator, n: int) -> np.ndarray:
    """(n, 2, 3) facade segments, steep in the image, in view from every keyframe."""
    start = np.column_stack(
        [rng.choice([-1.0, 1.0], n) * rng.uniform(4.0, 7.0, n), rng.uniform(-2.0, -1.5, n), rng.uniform(18.0, 35.0, n)]
    )
    end = start + np.column_stack([rng.uniform(-0.5, 0.5, n), rng.uniform(1.5, 2.5, n), rng.uniform(-1.0, 1.0, n)])
    return np.stack([start, end], axis=1)


def groups(spec: dict[str, tuple[tuple[int, ...], int]]) -> tuple[np.ndarray, list[tuple[int, ...]]]:
    """Group name (N,) and observers of each landmark of ``spec``."""
    names = np.concatenate([[name] * count for name, (_, count) in spec.items()])
    return names, [spec[name][0] for name in names]


def keyframe_features(
    rng: np.random.Generator, T_c_w: np.ndarray, points_w: np.ndarray, lines_w: np.ndarray
) -> StereoFeatures:
    """Stereo features of the given points and lines seen from ``T_c_w``: true projections plus noise."""
    n_points, n_lines = len(points_w), len(lines_w)
    p_c = transform_points(T_c_w, points_w)
    exact = CAMERA.project_stereo(p_c)
    uv = exact[:, :2] + rng.normal(0.0, CORNER_NOISE_PX, (n_points, 2))
    disparity = exact[:, 0] - exact[:, 2] + rng.normal(0.0, DISPARITY_NOISE_PX, n_points)
    descriptors = np.zeros((n_points, 32), dtype=np.uint8)
    octave = np.zeros(n_points, dtype=np.int64)
    u_right = uv[:, 0] - disparity
    ends_c = transform_points(T_c_w, lines_w.reshape(-1, 3))
    ends = CAMERA.project_stereo(ends_c).reshape(n_lines, 2, 3)
    endpoints = ends[:, :, :2].reshape(n_lines, 4) + rng.normal(0.0, LINE_NOISE_PX, (n_lines, 4))
    line_disparity = ends[:, :, 0] - ends[:, :, 2] + rng.normal(0.0, LINE_NOISE_PX, (n_lines, 2))
    assert np.all(p_c[:, 2] > 5.0) and np.all(ends_c[:, 2] > 5.0)
    for pixels in (uv, endpoints.reshape(-1, 2)):
        assert np.all((pixels > 12.0) & (pixels < [CAMERA.width - 13.0, CAMERA.height - 13.0]))
    return StereoFeatures(
        points=StereoPoints(uv, octave, descriptors, disparity, u_right, CAMERA.triangulate(uv, disparity)),
        lines=StereoLines(
            endpoints,
            line_disparity,
            np.zeros((n_lines, 32), dtype=np.uint8),
            np.stack([CAMERA.triangulate(endpoints[:, :2], line_disparity[:, 0]),
                      CAMERA.triangulate(endpoints[:, 2:], line_disparity[:, 1])], axis=1),
        ),
        keypoints=LeftKeypoints(uv, octave, descriptors, u_right, n_points),
    )


def perturbed(rng: np.random.Generator, T_c_w: np.ndarray) -> np.ndarray:
    """``T_c_w`` moved by ~3 cm per axis and 0.3 degrees about a random axis."""
    axis = rng.normal(size=3)
    return se3_exp(np.concatenate([rng.normal(0.0, 0.03, 3), np.radians(0.3) * axis / np.linalg.norm(axis)])) @ T_c_w


def build_map(
    seed: int,
    point_spec: dict[str, tuple[tuple[int, ...], int]],
    line_spec: dict[str, tuple[tuple[int, ...], int]],
    n_keyframes: int,
    exact_keyframes: tuple[int, ...],
    n_point_outliers: int = 0,
) -> HandMadeMap:
    """The map of the module docstring for the given groups; keyframes ``exact_keyframes`` at their true pose."""
    rng = np.random.default_rng(seed)
    T_c_w = true_poses(rng, n_keyframes)
    point_group, point_observers = groups(point_spec)
    line_group, line_observers = groups(line_spec)
    points_w, lines_w = visible_points(rng, len(point_group)), visible_lines(rng, len(line_group))
    world_map = Map(CONFIG.mapping.covisibility_min_shared)
    point_ids = world_map.points.add(
        points_w + rng.normal(0.0, 0.05, points_w.shape), np.zeros((len(points_w), 32), dtype=np.uint8), 0
    )
    line_ids = world_map.lines.add(
        lines_w + rng.normal(0.0, 0.05, lines_w.shape), np.zeros((len(lines_w), 32), dtype=np.uint8), 0
    )
    outliers = []
    for k in range(n_keyframes):
        seen_points = np.array([i for i, observers in enumerate(point_observers) if k in observers], dtype=np.int64)
        seen_lines = np.array([i for i, observers in enumerate(line_observers) if k in observers], dtype=np.int64)
        features = keyframe_features(rng, T_c_w[k], points_w[seen_points], lines_w[seen_lines])
        if k >= 2 and n_point_outliers:
            # outliers among the features of points the whole window sees (groups A and B), 40 px off
            candidates = np.flatnonzero(np.isin(point_group[seen_points], ["A", "B"]))
            moved = rng.choice(candidates, n_point_outliers // 2 if k == 3 else 1, replace=False)
            shift = np.column_stack([rng.choice([-1.0, 1.0], len(moved)) * 40.0, np.zeros(len(moved))])
            features.keypoints.uv[moved] += shift
            features.keypoints.u_right[moved] += shift[:, 0]
            outliers += [(k, int(feature)) for feature in moved]
        world_map.add_keyframe(
            KeyFrame(
                id=k,
                frame_index=k,
                timestamp=0.1 * k,
                T_c_w=T_c_w[k] if k in exact_keyframes else perturbed(rng, T_c_w[k]),
                features=features,
                ggs=np.zeros((2, 12, 256), dtype=np.uint8),
                place_ggs=np.zeros((2, 12, 256), dtype=np.uint8),
                point_ids=point_ids[seen_points].copy(),
                line_ids=line_ids[seen_lines].copy(),
                point_dynamic=np.zeros(len(seen_points), dtype=bool),
                line_dynamic=np.zeros(len(seen_lines), dtype=bool),
                point_rejected=np.zeros(len(seen_points), dtype=bool),
                line_rejected=np.zeros(len(seen_lines), dtype=bool),
            )
        )
    outliers = outliers[:n_point_outliers]
    return HandMadeMap(world_map, T_c_w, points_w, lines_w, point_group, line_group, outliers)


def pose_errors(T_est: np.ndarray, T_true: np.ndarray) -> tuple[float, float]:
    """Camera-centre distance [m] and rotation angle [degrees] of ``T_est`` relative to ``T_true``."""
    T_diff = T_est @ inverse(T_true)
    return float(np.linalg.norm(inverse(T_diff)[:3, 3])), float(np.degrees(np.linalg.norm(so3_log(T_diff[:3, :3]))))


@dataclass
class Adjusted:
    """A hand-made map before and after one local BA around its newest keyframe."""

    made: HandMadeMap
    report: BaReport | None
    poses_before: dict[int, np.ndarray]
    points_before: np.ndarray
    lines_before: np.ndarray
    observers_before: tuple[list[dict[int, int]], list[dict[int, int]]]
    n_observers_before: np.ndarray
    links_before: dict[int, int]


def adjust(made: HandMadeMap, new_keyframe: int) -> Adjusted:
    world_map = made.world_map
    before = dict(
        poses_before={k: keyframe.T_c_w.copy() for k, keyframe in world_map.keyframes.items()},
        points_before=world_map.points.geometry.copy(),
        lines_before=world_map.lines.geometry.copy(),
        observers_before=(
            [dict(o) for o in world_map.points.observers], [dict(o) for o in world_map.lines.observers]
        ),
        n_observers_before=world_map.points.n_observers.copy(),
        links_before=world_map.covisibility.shared(new_keyframe),
    )
    report = local_bundle_adjustment(world_map, world_map.keyframes[new_keyframe], CAMERA, CONFIG)
    return Adjusted(made, report, **before)


@pytest.fixture(scope="module")
def street() -> Adjusted:
    """The map of the module docstring after a local BA around keyframe 4."""
    made = build_map(seed=0, point_spec=POINT_GROUPS, line_spec=LINE_GROUPS, n_keyframes=5,
                     exact_keyframes=(0, 1), n_point_outliers=4)
    return adjust(made, new_keyframe=4)


def test_the_window_is_the_new_keyframe_and_its_strongest_covisible_neighbours(street):
    covisibility = street.made.world_map.covisibility
    assert street.links_before == {1: 33, 2: 87, 3: 87}
    assert covisibility.neighbours(4, limit=CONFIG.mapping.local_ba_window) == [2, 3]
    assert street.report.free_keyframes == 3


def test_window_keyframes_are_brought_back_near_their_true_poses(street):
    for k in (2, 3, 4):
        start = pose_errors(street.poses_before[k], street.made.T_c_w[k])
        end = pose_errors(street.made.world_map.keyframes[k].T_c_w, street.made.T_c_w[k])
        # measured: 4.6-7.5 cm and 0.3 degrees before, 0.8-2.3 cm and 0.04-0.07 degrees after; that is the
        # optimum (more evaluations leave it there): yaw and sideways motion look alike on points 16-40 m ahead
        assert start[0] > 0.04 and np.isclose(start[1], 0.3)
        assert end[0] < 0.03 and end[1] < 0.1 and end[0] < 0.5 * start[0]


def test_a_keyframe_outside_the_window_that_sees_its_landmarks_is_held_fixed(street):
    assert street.report.fixed_keyframes == 1
    assert np.array_equal(street.made.world_map.keyframes[1].T_c_w, street.poses_before[1])


def test_a_keyframe_that_sees_none_of_the_window_landmarks_is_left_out(street):
    assert street.report.free_keyframes + street.report.fixed_keyframes == 4
    assert np.array_equal(street.made.world_map.keyframes[0].T_c_w, street.poses_before[0])


def test_the_window_landmarks_seen_twice_or_more_are_adjusted(street):
    made, world_map = street.made, street.made.world_map
    assert street.report.points == 100 and street.report.lines == 7
    assert street.report.observations == 50 * 3 + 30 * 4 + 20 * 2 + 4 * 3 + 3 * 4
    in_window = np.isin(made.point_group, ["A", "B", "E"])
    before = np.linalg.norm(street.points_before[in_window] - made.points_w[in_window], axis=1)
    after = np.linalg.norm(world_map.points.geometry[in_window] - made.points_w[in_window], axis=1)
    # measured: median 7.7 cm before, 3.9 cm after (a disparity 0.05 px off puts a point 30 m away 12 cm deeper)
    assert np.median(after) < 0.6 * np.median(before)
    lines_in_window = np.isin(made.line_group, ["A", "B"])
    unmoved = world_map.lines.geometry[lines_in_window] == street.lines_before[lines_in_window]
    assert not np.any(np.all(unmoved, axis=(1, 2)))


def test_landmarks_seen_by_a_single_keyframe_are_left_out(street):
    made, world_map = street.made, street.made.world_map
    single_point, single_line = made.point_group == "D", made.line_group == "D"
    assert np.array_equal(world_map.points.geometry[single_point], street.points_before[single_point])
    assert np.array_equal(world_map.lines.geometry[single_line], street.lines_before[single_line])
    for landmark in np.flatnonzero(single_point).tolist():
        assert list(world_map.points.observers[landmark]) == [4]


def test_landmarks_not_seen_from_the_window_are_left_out(street):
    made, world_map = street.made, street.made.world_map
    outside_point, outside_line = made.point_group == "C", made.line_group == "C"
    assert np.array_equal(world_map.points.geometry[outside_point], street.points_before[outside_point])
    assert np.array_equal(world_map.lines.geometry[outside_line], street.lines_before[outside_line])


def test_outlier_observations_are_erased_from_the_map(street):
    world_map = street.made.world_map
    assert street.report.removed_observations == len(street.made.point_outliers) == 4
    for keyframe_id, feature in street.made.point_outliers:
        (landmark,) = [i for i, seen in enumerate(street.observers_before[0]) if seen.get(keyframe_id) == feature]
        assert world_map.keyframes[keyframe_id].point_ids[feature] == -1
        assert keyframe_id not in world_map.points.observers[landmark]
        assert world_map.points.n_observers[landmark] == street.n_observers_before[landmark] - 1
        assert world_map.points.alive[landmark]  # still seen by the other keyframes


def test_clean_observations_stay_in_the_map(street):
    world_map = street.made.world_map
    erased = set(street.made.point_outliers)
    for landmark, observers in enumerate(street.observers_before[0]):
        expected = {k: f for k, f in observers.items() if (k, f) not in erased}
        assert world_map.points.observers[landmark] == expected
    assert [dict(o) for o in world_map.lines.observers] == street.observers_before[1]
    for keyframe_id, keyframe in world_map.keyframes.items():
        for feature, landmark in enumerate(keyframe.point_ids.tolist()):
            if (keyframe_id, feature) not in erased:
                assert world_map.points.observers[landmark][keyframe_id] == feature


def test_local_ba_lowers_the_cost(street):
    assert street.report.final_cost < 0.1 * street.report.initial_cost
    assert street.report.nfev > 0


def test_with_no_keyframe_outside_the_window_the_oldest_is_held_fixed():
    spec = {"A": ((0, 1, 2), 60), "B": ((1, 2), 30)}
    made = build_map(seed=1, point_spec=spec, line_spec={"A": ((0, 1, 2), 4)}, n_keyframes=3, exact_keyframes=())
    adjusted = adjust(made, new_keyframe=2)
    assert adjusted.report.fixed_keyframes == 1 and adjusted.report.free_keyframes == 2
    keyframes = made.world_map.keyframes
    assert np.array_equal(keyframes[0].T_c_w, adjusted.poses_before[0])
    # the others move to agree with keyframe 0, which started 3 cm and 0.3 degrees off: relative poses recover
    for k in (1, 2):
        relative_before = adjusted.poses_before[k] @ inverse(adjusted.poses_before[0])
        relative_after = keyframes[k].T_c_w @ inverse(keyframes[0].T_c_w)
        relative_true = made.T_c_w[k] @ inverse(made.T_c_w[0])
        before, after = pose_errors(relative_before, relative_true), pose_errors(relative_after, relative_true)
        # measured: 1.7-3.1 cm and 0.52-0.54 degrees before, 1.0-1.2 cm and 0.03-0.05 degrees after
        assert after[0] < 0.02 and after[1] < 0.2 * before[1]


def test_a_map_whose_landmarks_are_each_seen_once_has_nothing_to_adjust():
    made = build_map(seed=2, point_spec={"A": ((0,), 30)}, line_spec={"A": ((0,), 2)}, n_keyframes=1,
                     exact_keyframes=())
    adjusted = adjust(made, new_keyframe=0)
    assert adjusted.report is None
    assert np.array_equal(made.world_map.keyframes[0].T_c_w, adjusted.poses_before[0])
    assert np.array_equal(made.world_map.points.geometry, adjusted.points_before)


def test_the_first_keyframe_stays_fixed_even_with_other_keyframes_held():
    """Keyframe 0 (the world frame) never moves, also when another keyframe anchors the problem."""
    spec = {"A": ((0, 1, 2, 3), 60), "B": ((1, 2, 3), 30)}
    made = build_map(seed=3, point_spec=spec, line_spec={"A": ((0, 1, 2, 3), 4)}, n_keyframes=4, exact_keyframes=())
    before = {k: keyframe.T_c_w.copy() for k, keyframe in made.world_map.keyframes.items()}
    report = adjust_keyframes(made.world_map, [0, 1, 3], CAMERA, MapBaOptions.of(CONFIG), max_nfev=10)
    assert report.fixed_keyframes == 2 and report.free_keyframes == 2  # keyframe 2 (outside) and keyframe 0
    assert np.array_equal(made.world_map.keyframes[0].T_c_w, before[0])
    assert not np.array_equal(made.world_map.keyframes[1].T_c_w, before[1])


@pytest.mark.parametrize("key", ["ba_cost_tolerance=1.0e-6", "ba_lsmr_iterations=2"])
def test_refining_stops_where_the_configuration_says(key):
    """``mapping.ba_cost_tolerance`` and ``mapping.ba_lsmr_iterations`` reach the solve (`MapBaOptions.of`):
    a tighter tolerance, or shorter steps, take more evaluations than the defaults."""
    nfev = []
    for overrides in ((), (f"mapping.{key}",)):
        made = build_map(seed=0, point_spec=POINT_GROUPS, line_spec=LINE_GROUPS, n_keyframes=5,
                         exact_keyframes=(0, 1), n_point_outliers=4)
        options = MapBaOptions.of(load_config(overrides=("mapping.local_ba_window=2", *overrides)))
        nfev.append(adjust_keyframes(made.world_map, [1, 2, 3, 4], CAMERA, options, max_nfev=200).nfev)
    # measured: 13 evaluations by default, 17 at a 1e-6 tolerance, 31 with 2 LSMR iterations per step
    assert nfev[1] > nfev[0]


def test_solving_to_convergence_goes_on_where_refining_stops():
    """``to_convergence`` (`benchmarks/ba_truth.py`) keeps stepping after local BA's 0.1 % rule stops it."""
    reports = {}
    for to_convergence in (False, True):
        made = build_map(seed=0, point_spec=POINT_GROUPS, line_spec=LINE_GROUPS, n_keyframes=5,
                         exact_keyframes=(0, 1), n_point_outliers=4)
        reports[to_convergence] = adjust_keyframes(made.world_map, [1, 2, 3, 4], CAMERA, MapBaOptions.of(CONFIG),
                                                   max_nfev=200, to_convergence=to_convergence)
    # measured: 13 evaluations to cost 50.92854 refining, 15 to 50.92841 solving to convergence
    assert reports[True].nfev > reports[False].nfev
    assert reports[True].final_cost <= reports[False].final_cost
