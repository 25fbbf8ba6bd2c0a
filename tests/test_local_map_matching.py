"""Matching map landmarks into several frames at once (`pld_slam.matching.projection`).

Local mapping's fusion projects a keyframe's landmarks into all its neighbours in one
search (`match_map_points_in_frames`, `match_map_lines_in_frames`); each frame must get
exactly what a search of that frame alone finds (`match_map_points`, `match_map_lines`).
The frames here see random landmarks from three poses, with a few descriptor bits
flipped, among random distractors.
"""

import dataclasses

import numpy as np
import pytest

from pld_slam.config import load_config
from pld_slam.frontend import LeftKeypoints, StereoLines
from pld_slam.geometry.camera import StereoCamera
from pld_slam.geometry.se3 import make_pose, so3_exp, transform_points
from pld_slam.matching.frames import predict_segments
from pld_slam.matching.projection import (
    LandmarkSnapshot,
    ProjectionSearch,
    match_map_lines,
    match_map_lines_in_frames,
    match_map_points,
    match_map_points_in_frames,
)

CAMERA = StereoCamera(fx=300.0, fy=300.0, cx=320.0, cy=120.0, baseline=0.5, width=640, height=240)
CONFIG = load_config()
SEARCH = ProjectionSearch.of(CONFIG)
POSES = np.stack([
    make_pose(so3_exp(np.array([0.0, 0.02 * k, 0.0])), np.array([0.1 * k, 0.0, -0.5 * k])) for k in range(3)
])
"""``T_c_w`` of the three frames: 0.5 m apart, turning slightly."""


def flipped(descriptors: np.ndarray, rng: np.random.Generator, bits: int = 3) -> np.ndarray:
    """``descriptors`` (N, 32) with ``bits`` random bits flipped in each."""
    out = descriptors.copy()
    for row in range(len(out)):
        for bit in rng.choice(256, size=bits, replace=False):
            out[row, bit // 8] ^= np.uint8(1 << (bit % 8))
    return out


@pytest.fixture(scope="module")
def points():
    """A point snapshot (80 points 5-30 m ahead), per frame keypoints (60 of them, then 40 distractors),
    and per frame the snapshot row of each of the 60."""
    rng = np.random.default_rng(3)
    geometry = np.column_stack([rng.uniform(-6, 6, 80), rng.uniform(-2, 2, 80), rng.uniform(5, 30, 80)])
    descriptors = rng.integers(0, 256, (80, 32), dtype=np.uint8)
    snapshot = LandmarkSnapshot(
        ids=np.arange(100, 180), geometry=geometry, descriptors=descriptors,
        normals=geometry / np.linalg.norm(geometry, axis=1, keepdims=True),
        max_distance=1.1 * np.linalg.norm(geometry, axis=1),  # seen at octave 0 from every frame
    )
    frames, truths = [], []
    for T_c_w in POSES:
        seen = rng.permutation(80)[:60]
        truths.append(seen)
        stereo_px = CAMERA.project_stereo(transform_points(T_c_w, geometry[seen]))
        uv = np.concatenate([stereo_px[:, :2] + rng.normal(0, 0.3, (60, 2)), rng.uniform([0, 0], [640, 240], (40, 2))])
        frames.append(LeftKeypoints(
            uv=uv,
            octave=np.zeros(100, dtype=np.int64),
            descriptors=np.concatenate([flipped(descriptors[seen], rng), rng.integers(0, 256, (40, 32), np.uint8)]),
            u_right=np.concatenate([stereo_px[:, 2], np.full(40, np.nan)]),
            n_stereo=60,
        ))
    return snapshot, frames, truths


@pytest.fixture(scope="module")
def lines():
    """A line snapshot (30 segments 6-20 m ahead) and, per frame, the detected segments of 25 of them."""
    rng = np.random.default_rng(4)
    starts = np.column_stack([rng.uniform(-5, 5, 30), rng.uniform(-2, 2, 30), rng.uniform(6, 20, 30)])
    geometry = np.stack([starts, starts + rng.normal(0, 1.0, (30, 3))], axis=1)
    descriptors = rng.integers(0, 256, (30, 32), dtype=np.uint8)
    midpoints = geometry.mean(axis=1)
    snapshot = LandmarkSnapshot(
        ids=np.arange(30), geometry=geometry, descriptors=descriptors,
        normals=midpoints / np.linalg.norm(midpoints, axis=1, keepdims=True), max_distance=np.full(30, np.inf),
    )
    frames = []
    for T_c_w in POSES:
        seen = rng.permutation(30)[:25]
        segments, _ = predict_segments(CAMERA, T_c_w, geometry[seen])
        frames.append(StereoLines(
            endpoints=segments + rng.normal(0, 0.3, segments.shape),
            disparity=np.ones((25, 2)),
            descriptors=flipped(descriptors[seen], rng),
            endpoints_c=np.zeros((25, 2, 3)),
        ))
    return snapshot, frames


def assert_same_matches(together, alone):
    np.testing.assert_array_equal(together.matches.previous, alone.matches.previous)
    np.testing.assert_array_equal(together.matches.current, alone.matches.current)
    np.testing.assert_array_equal(together.visible, alone.visible)


def test_points_matched_into_several_frames_at_once_match_as_in_each_frame_alone(points):
    snapshot, frames, truths = points
    max_distance, ratio = CONFIG.mapping.max_point_distance, CONFIG.mapping.ratio
    together = match_map_points_in_frames(CAMERA, POSES, snapshot, frames, SEARCH, max_distance, ratio)
    assert len(together) == len(frames)
    for T_c_w, frame, truth, found in zip(POSES, frames, truths, together):
        assert_same_matches(found, match_map_points(CAMERA, T_c_w, snapshot, frame, SEARCH, max_distance, ratio))
        assert len(found.matches) >= 40
        assert np.all(found.matches.current < 60), "a distractor matched"
        np.testing.assert_array_equal(found.matches.previous, truth[found.matches.current])


@pytest.mark.parametrize(("farthest_scale", "searched"), [(None, True), (1.0, False)])
def test_points_are_searched_as_far_as_the_configured_share_of_their_range(points, farthest_scale, searched):
    """``mapping.search_farthest_scale``: points seen at 1 / 0.9 of their farthest distance are searched
    with the default 1.2, not at 1.0."""
    snapshot, frames, _ = points
    nearer_range = dataclasses.replace(snapshot, max_distance=0.9 * np.linalg.norm(snapshot.geometry, axis=1))
    overrides = [] if farthest_scale is None else [f"mapping.search_farthest_scale={farthest_scale}"]
    search = ProjectionSearch.of(load_config(overrides=overrides))
    found = match_map_points(CAMERA, POSES[0], nearer_range, frames[0], search, CONFIG.mapping.max_point_distance,
                             CONFIG.mapping.ratio)
    assert found.visible.any() == searched and (len(found.matches) >= 40) == searched


def test_lines_matched_into_several_frames_at_once_match_as_in_each_frame_alone(lines):
    snapshot, frames = lines
    together = match_map_lines_in_frames(CAMERA, POSES, snapshot, frames, SEARCH)
    for T_c_w, frame, found in zip(POSES, frames, together):
        assert_same_matches(found, match_map_lines(CAMERA, T_c_w, snapshot, frame, SEARCH))
        assert len(found.matches) >= 15


def test_a_frame_without_keypoints_among_others_finds_nothing_and_sees_nothing(points):
    snapshot, frames, _ = points
    empty = LeftKeypoints.empty()
    together = match_map_points_in_frames(
        CAMERA, POSES, snapshot, [frames[0], empty, frames[2]], SEARCH,
        CONFIG.mapping.max_point_distance, CONFIG.mapping.ratio,
    )
    assert len(together[1].matches) == 0 and not together[1].visible.any()
    assert len(together[0].matches) >= 40 and len(together[2].matches) >= 40
