"""A frame's pose without a motion prior (`pld_slam.matching.prior_free`).

Map points with their own random descriptors seen exactly from a pose far from the
identity: descriptor matching over the whole image and seeded PnP RANSAC must find that
pose; matching must keep a map point once; wrong descriptors must give no pose.
"""

import numpy as np
from map_fixtures import CAMERA, random_descriptors, scene_points, world_features

from pld_slam.config import load_config
from pld_slam.geometry.se3 import se3_exp, se3_log, transform_points
from pld_slam.matching.prior_free import PriorFreeOptions, match_without_prior, pose_without_prior

POINTS_W = scene_points(120, seed=21)
DESCRIPTORS = random_descriptors(120, seed=22)
T_C_W = se3_exp(np.array([0.8, -0.1, 2.5, 0.02, 0.15, -0.01]))  # 2.6 m and 9 deg from the identity
OPTIONS = PriorFreeOptions.of(load_config())
"""The descriptor bounds, PnP RANSAC and seed of a default run."""


def frame_seeing(points_w: np.ndarray, descriptors: np.ndarray):
    """The left keypoints of a frame at `T_C_W` seeing ``points_w`` with ``descriptors``, in reversed order."""
    order = np.arange(len(points_w))[::-1]
    return world_features(T_C_W, points_w[order], descriptors[order]).keypoints


def in_view(points_w: np.ndarray) -> np.ndarray:
    """Which world points (N, 3) project inside the image of `CAMERA` at `T_C_W`."""
    p_c = transform_points(T_C_W, points_w)
    uv = CAMERA.project(np.where(p_c[:, 2:] > 0.1, p_c, 1.0))
    inside = (uv >= 0) & (uv < [CAMERA.width, CAMERA.height])
    return (p_c[:, 2] > 0.1) & inside.all(axis=1)


def test_the_pose_is_found_from_descriptor_matches_alone():
    seen = in_view(POINTS_W)
    assert seen.sum() > 2 * OPTIONS.min_inliers
    keypoints = frame_seeing(POINTS_W[seen], DESCRIPTORS[seen])
    pose = pose_without_prior(CAMERA, keypoints, POINTS_W, DESCRIPTORS, OPTIONS)
    assert pose is not None and pose.inliers >= OPTIONS.min_inliers
    error = se3_log(pose.T_c_w @ np.linalg.inv(T_C_W))
    assert np.linalg.norm(error[:3]) < 1e-3 and np.linalg.norm(error[3:]) < 1e-4


def test_matching_pairs_each_keypoint_with_its_own_map_point_once():
    keypoints = frame_seeing(POINTS_W, DESCRIPTORS)
    matches = match_without_prior(keypoints, np.concatenate([DESCRIPTORS, DESCRIPTORS[:5]]), OPTIONS)
    assert len(matches.previous) > 100
    assert np.all(matches.previous == len(POINTS_W) - 1 - matches.current)  # no duplicate wins a match
    assert len(np.unique(matches.previous)) == len(matches.previous)
    # the five duplicated descriptors fail the ratio test (best and second best tie): not matched
    assert not np.isin(len(POINTS_W) - 1 - np.arange(5), matches.current).any()


def test_unrelated_descriptors_give_no_pose():
    keypoints = frame_seeing(POINTS_W, random_descriptors(120, seed=99))
    assert pose_without_prior(CAMERA, keypoints, POINTS_W, DESCRIPTORS, OPTIONS) is None


def test_the_same_input_gives_the_same_pose():
    keypoints = frame_seeing(POINTS_W, DESCRIPTORS)
    noisy = POINTS_W + np.random.default_rng(5).normal(0.0, 0.05, POINTS_W.shape)
    first = pose_without_prior(CAMERA, keypoints, noisy, DESCRIPTORS, OPTIONS)
    second = pose_without_prior(CAMERA, keypoints, noisy, DESCRIPTORS, OPTIONS)
    assert first is not None and np.array_equal(first.T_c_w, second.T_c_w) and first.inliers == second.inliers


def prior_free(*overrides: str) -> PriorFreeOptions:
    return PriorFreeOptions.of(load_config(overrides=[f"tracking.{override}" for override in overrides]))


def test_a_pose_needs_the_configured_inliers():
    """``tracking.pnp_min_inliers``: the frame sees fewer points than a raised bound asks."""
    seen = np.flatnonzero(in_view(POINTS_W))
    keypoints = frame_seeing(POINTS_W[seen], DESCRIPTORS[seen])
    assert pose_without_prior(CAMERA, keypoints, POINTS_W, DESCRIPTORS, prior_free("pnp_min_inliers=40")) is not None
    raised = prior_free(f"pnp_min_inliers={len(seen) + 1}")
    assert pose_without_prior(CAMERA, keypoints, POINTS_W, DESCRIPTORS, raised) is None


def test_the_ratio_test_is_the_configured_one():
    """``tracking.prior_free_ratio`` reaches the matching: at 0 no match passes."""
    keypoints = frame_seeing(POINTS_W, DESCRIPTORS)
    assert len(match_without_prior(keypoints, DESCRIPTORS, OPTIONS)) > 100
    assert len(match_without_prior(keypoints, DESCRIPTORS, prior_free("prior_free_ratio=0.0"))) == 0


def test_the_ransac_inlier_bound_is_the_configured_one():
    """``tracking.pnp_reprojection_px``: map points 2 cm off their place reproject within the default 3 px,
    not all within 0.2 px."""
    keypoints = frame_seeing(POINTS_W, DESCRIPTORS)
    noisy = POINTS_W + np.random.default_rng(5).normal(0.0, 0.02, POINTS_W.shape)
    default = pose_without_prior(CAMERA, keypoints, noisy, DESCRIPTORS, OPTIONS)
    tight = pose_without_prior(CAMERA, keypoints, noisy, DESCRIPTORS, prior_free("pnp_reprojection_px=0.2"))
    assert default is not None
    assert tight is None or tight.inliers < default.inliers
