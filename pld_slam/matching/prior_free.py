"""A pose without a motion prior: descriptor matches to map points, then stereo PnP RANSAC.

Called by tracking when its motion-model prediction cannot be trusted
(`pld_slam.tracking.relocalisation`), by loop verification's geometric check
(`pld_slam.loop.verify`) and by the stereo calibration's frame-pair poses
(`pld_slam.stereo_calibration`, which uses `match_without_prior` and `pnp_pose`).
`pose_without_prior`:

1. Match the frame's left keypoints to the map points by descriptor alone, over the whole
   image: each keypoint's two nearest map descriptors (OpenCV's brute-force Hamming
   matcher, deterministic), kept when the best is within ``tracking.max_point_distance``
   and passes Lowe's ratio test (``tracking.prior_free_ratio``, 0.8, ORB-SLAM2's for
   relocalisation), each map point used once.
2. ``cv2.solvePnPRansac`` on the matched 3D map points and left pixels (EPnP hypotheses,
   ``tracking.pnp_reprojection_px`` (3 px) reprojection threshold at octave 0,
   ``tracking.pnp_iterations`` (300) iterations, confidence ``tracking.pnp_confidence``
   (0.999)), with OpenCV's random generator seeded from ``system.seed`` so that the same
   input gives the same pose.
3. Accepted with at least ``tracking.pnp_min_inliers`` (30) inliers; the caller then
   refines the pose (tracking and loop verification: by tracking a local map from it).

Every caller reads these keys once into `PriorFreeOptions`.
"""

from dataclasses import dataclass

import cv2
import numpy as np

from pld_slam.config import Config
from pld_slam.frontend import LeftKeypoints
from pld_slam.frontend.descriptors import CandidateMatches, unique_train
from pld_slam.geometry.camera import StereoCamera
from pld_slam.geometry.se3 import make_pose
from pld_slam.matching.frames import FrameMatches


@dataclass(frozen=True)
class PriorFreeOptions:
    """What matching and PnP without a prior read of the configuration (module docstring).

    max_distance : largest Hamming distance of a match [bits] (``tracking.max_point_distance``).
    ratio : Lowe's ratio test (``tracking.prior_free_ratio``).
    min_inliers : fewest PnP inliers, and matches to try PnP on (``tracking.pnp_min_inliers``).
    iterations, confidence, reprojection_px : PnP RANSAC's (``tracking.pnp_iterations``,
        ``tracking.pnp_confidence``, ``tracking.pnp_reprojection_px``).
    seed : seed of OpenCV's random generator (``system.seed``).
    """

    max_distance: int
    ratio: float
    min_inliers: int
    iterations: int
    confidence: float
    reprojection_px: float
    seed: int

    @classmethod
    def of(cls, config: Config) -> "PriorFreeOptions":
        tracking = config.tracking
        return cls(tracking.max_point_distance, tracking.prior_free_ratio, tracking.pnp_min_inliers,
                   tracking.pnp_iterations, tracking.pnp_confidence, tracking.pnp_reprojection_px, config.system.seed)


@dataclass(frozen=True)
class PnpPose:
    """A pose found without a prior: ``T_c_w`` (4, 4) and its PnP inlier count."""

    T_c_w: np.ndarray
    inliers: int


def match_without_prior(
    keypoints: LeftKeypoints, map_descriptors: np.ndarray, options: PriorFreeOptions
) -> FrameMatches:
    """Map points (``previous``: rows of ``map_descriptors`` (N, 32)) matched to keypoints by descriptor alone,
    within ``options.max_distance`` and ``options.ratio``."""
    if len(keypoints) == 0 or len(map_descriptors) < 2:
        return FrameMatches.empty()
    matcher = cv2.BFMatcher(cv2.NORM_HAMMING)
    pairs = matcher.knnMatch(keypoints.descriptors, map_descriptors, k=2)
    best = np.array([[p[0].queryIdx, p[0].trainIdx, p[0].distance, p[1].distance] for p in pairs if len(p) == 2])
    if len(best) == 0:
        return FrameMatches.empty()
    keep = (best[:, 2] <= options.max_distance) & (best[:, 2] < options.ratio * best[:, 3])
    chosen = best[keep].astype(np.int64)
    matches = unique_train(CandidateMatches(chosen[:, 0], chosen[:, 1], chosen[:, 2]))
    return FrameMatches(previous=matches.train, current=matches.query)


def pnp_pose(
    camera: StereoCamera, points_w: np.ndarray, pixels: np.ndarray, options: PriorFreeOptions
) -> PnpPose | None:
    """``T_c_w`` from map points (K, 3) seen at left pixels (K, 2) by seeded PnP RANSAC, or None
    with fewer than ``options.min_inliers`` points or inliers."""
    if len(points_w) < options.min_inliers:
        return None
    cv2.setRNGSeed(options.seed)
    found, rotation, translation, inliers = cv2.solvePnPRansac(
        points_w.astype(np.float64),
        pixels.astype(np.float64),
        camera.K,
        None,
        iterationsCount=options.iterations,
        reprojectionError=options.reprojection_px,
        confidence=options.confidence,
        flags=cv2.SOLVEPNP_EPNP,
    )
    if not found or inliers is None or len(inliers) < options.min_inliers:
        return None
    return PnpPose(make_pose(cv2.Rodrigues(rotation)[0], translation.ravel()), len(inliers))


def pose_without_prior(
    camera: StereoCamera,
    keypoints: LeftKeypoints,
    points_w: np.ndarray,
    descriptors: np.ndarray,
    options: PriorFreeOptions,
    min_matches: int | None = None,
) -> PnpPose | None:
    """The frame's pose from map points (N, 3) with descriptors (N, 32), without a prior (module
    docstring); None without ``min_matches`` (default ``options.min_inliers``) matches to try PnP on."""
    matches = match_without_prior(keypoints, descriptors, options)
    if len(matches) < (options.min_inliers if min_matches is None else min_matches):
        return None
    return pnp_pose(camera, points_w[matches.previous], keypoints.uv[matches.current], options)
