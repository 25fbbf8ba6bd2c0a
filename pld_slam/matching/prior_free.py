"""A pose without a motion prior: descriptor matches to map points, then stereo PnP RANSAC.

Called by tracking when its motion-model prediction cannot be trusted
(`pld_slam.tracking.relocalisation`), by loop verification's geometric check
(`pld_slam.loop.verify`) and by the stereo calibration's frame-pair poses
(`pld_slam.stereo_calibration`, which uses `match_without_prior` and `pnp_pose`).
`pose_without_prior`:

1. Match the frame's left keypoints to the map points by descriptor alone, over the whole
   image: each keypoint's two nearest map descriptors (OpenCV's brute-force Hamming
   matcher, deterministic), kept when the best is within ``tracking.max_point_distance``
   and passes Lowe's ratio test (0.8, ORB-SLAM2's for relocalisation), each map point
   used once.
2. ``cv2.solvePnPRansac`` on the matched 3D map points and left pixels (EPnP hypotheses,
   3 px reprojection threshold at octave 0, 300 iterations, confidence 0.999), with
   OpenCV's random generator seeded from ``system.seed`` so that the same input gives the
   same pose.
3. Accepted with at least `MIN_PNP_INLIERS` inliers; the caller then refines the pose
   (tracking and loop verification: by tracking a local map from it).
"""

from dataclasses import dataclass

import cv2
import numpy as np

from pld_slam.frontend import LeftKeypoints
from pld_slam.frontend.descriptors import CandidateMatches, unique_train
from pld_slam.geometry.camera import StereoCamera
from pld_slam.geometry.se3 import make_pose
from pld_slam.matching.frames import FrameMatches

RATIO = 0.8
"""Lowe's ratio test of matching without a prior (ORB-SLAM2's relocalisation: 0.75-0.8)."""
MIN_PNP_INLIERS = 30
"""Fewest PnP inliers for a pose from scratch."""
_PNP_ITERATIONS = 300
_PNP_CONFIDENCE = 0.999
_PNP_REPROJECTION_PX = 3.0


@dataclass(frozen=True)
class PnpPose:
    """A pose found without a prior: ``T_c_w`` (4, 4) and its PnP inlier count."""

    T_c_w: np.ndarray
    inliers: int


def match_without_prior(
    keypoints: LeftKeypoints, map_descriptors: np.ndarray, max_distance: int, ratio: float = RATIO
) -> FrameMatches:
    """Map points (``previous``: rows of ``map_descriptors`` (N, 32)) matched to keypoints by descriptor alone."""
    if len(keypoints) == 0 or len(map_descriptors) < 2:
        return FrameMatches.empty()
    matcher = cv2.BFMatcher(cv2.NORM_HAMMING)
    pairs = matcher.knnMatch(keypoints.descriptors, map_descriptors, k=2)
    best = np.array([[p[0].queryIdx, p[0].trainIdx, p[0].distance, p[1].distance] for p in pairs if len(p) == 2])
    if len(best) == 0:
        return FrameMatches.empty()
    keep = (best[:, 2] <= max_distance) & (best[:, 2] < ratio * best[:, 3])
    chosen = best[keep].astype(np.int64)
    matches = unique_train(CandidateMatches(chosen[:, 0], chosen[:, 1], chosen[:, 2]))
    return FrameMatches(previous=matches.train, current=matches.query)


def pnp_pose(
    camera: StereoCamera, points_w: np.ndarray, pixels: np.ndarray, seed: int
) -> PnpPose | None:
    """``T_c_w`` from map points (K, 3) seen at left pixels (K, 2) by seeded PnP RANSAC, or None."""
    if len(points_w) < MIN_PNP_INLIERS:
        return None
    cv2.setRNGSeed(seed)
    found, rotation, translation, inliers = cv2.solvePnPRansac(
        points_w.astype(np.float64),
        pixels.astype(np.float64),
        camera.K,
        None,
        iterationsCount=_PNP_ITERATIONS,
        reprojectionError=_PNP_REPROJECTION_PX,
        confidence=_PNP_CONFIDENCE,
        flags=cv2.SOLVEPNP_EPNP,
    )
    if not found or inliers is None or len(inliers) < MIN_PNP_INLIERS:
        return None
    return PnpPose(make_pose(cv2.Rodrigues(rotation)[0], translation.ravel()), len(inliers))


def pose_without_prior(
    camera: StereoCamera,
    keypoints: LeftKeypoints,
    points_w: np.ndarray,
    descriptors: np.ndarray,
    max_distance: int,
    seed: int,
    min_matches: int = MIN_PNP_INLIERS,
) -> PnpPose | None:
    """The frame's pose from map points (N, 3) with descriptors (N, 32), without a prior (module
    docstring): descriptor matches within ``max_distance`` bits, PnP-RANSAC seeded by ``seed``; None
    without ``min_matches`` matches to try PnP on."""
    matches = match_without_prior(keypoints, descriptors, max_distance)
    if len(matches) < min_matches:
        return None
    return pnp_pose(camera, points_w[matches.previous], keypoints.uv[matches.current], seed)
