"""ORB points of a rectified stereo pair: detection bucketed over the image, stereo matching.

The paper says "ORB" and "the local matching scheme of DynPL-SVO" (left-right candidates
restricted to a local region) and nothing more. We follow ORB-SLAM2's stereo front end,
which that scheme amounts to on rectified images, and decide what neither fixes (the
measurements behind each choice: docs/decisions/0012-orb-stereo-points.md):

- Detection: OpenCV's ORB (FAST threshold 20, 8 levels, scale 1.2, as ORB-SLAM2) asked for
  ``oversampling * n_features`` corners, then bucketed: the image is cut into square cells
  and corners are taken round-robin by strength rank inside their cell (every cell's
  strongest, then every cell's second strongest, ...) until ``n_features`` are kept. So
  no cell holds more than one corner above the last round reached, and textured areas
  cannot starve the rest of the image. ORB-SLAM2 gets the same effect with per-cell FAST
  and a quadtree; from Python, per-cell detection costs one OpenCV call per cell, so we
  detect once and oversample. Before bucketing, only the strongest corner of each
  ``min_separation_px`` cell is kept: OpenCV finds a strong corner again at several
  octaves, and the round-robin would take those copies as a cell's second and third
  corners, stacking points on one corner of a near vehicle.
- Keypoint pixels: OpenCV reports a corner found at pixel ``x_l`` of level ``l`` at
  ``x_l * s`` (``s = scale_factor^l``), as ORB-SLAM2 uses it. That level pixel's centre
  lies at ``(x_l + 0.5) W / W_l - 0.5`` of the image (`cv2.resize` aligns pixel centres;
  ``W_l = round(W / s)``): 0.1 px away at level 1, 1.3 px at level 7, plus the rounding
  of ``W_l``. The offset cancels between two observations at one level, not when a
  corner changes level as the camera nears it. We keep OpenCV's pixels: corrected, and
  with stereo matches straddling a depth edge dropped, the bias went but the runs were
  no better (the bias is not what limits the ATE).
- Stereo candidates: right keypoints at the same or a neighbouring octave, within
  ``stereo_row_tolerance * scale^octave`` rows, with a disparity inside the depth limits.
- Matching: the smallest Hamming distance under ``stereo_max_distance`` (64; ORB-SLAM2
  uses 75), a ratio test (0.8) against the best rival more than one octave pixel away
  along the row, then each right keypoint is kept by its closest left keypoint only.
  ORB-SLAM2 has neither of the last two; against SGBM disparities they cut the wrong
  matches for fewer right ones. The ratio test only sees keypoints that both images
  kept: a repeated pattern whose true counterpart was not kept on the right can still
  match a copy.
- Sub-pixel disparity: as ORB-SLAM2, a SAD search of an 11 x 11 window along the row at
  the keypoint's octave, +- 5 columns, and a parabola through the three SAD values around
  the minimum. We subtract each window's mean (ORB-SLAM2 subtracts the centre pixel),
  which cancels a brightness offset between the cameras with less noise. A minimum at
  either end of the search is no match. ORB-SLAM2's second filter (SAD above 2.1 times
  the median) is left out: on KITTI it dropped many matches to remove few that disagree
  with SGBM.
- Depth limits: ``fx / max_depth_baselines <= disparity <= fx / min_depth_baselines``.
  ORB-SLAM2 accepts 1 to infinitely many baselines and labels points beyond 35-40
  baselines "far". We keep far points, which fix rotation, up to 200 baselines (3.5 px
  on KITTI, where a 0.2 px error is a 6 % depth error), and start at 3 baselines
  (1.6 m on KITTI, 0.33 m on EuRoC): the few KITTI matches nearer than that were wrong.

Stereo points (`StereoPoints`) are the ones with a depth: tracking against the reference
frame, the dynamic detectors and new map points start from them. The map also needs
the others: a map point is found again in a later frame wherever its corner is detected
in the left image, stereo-matched there or not (on KITTI most left corners have no
stereo match; ORB-SLAM2 likewise tracks map points in keypoints without one, as
monocular observations). `LeftKeypoints` holds every left keypoint, the stereo points
first.
"""

from collections.abc import Sequence
from dataclasses import dataclass, replace

import cv2
import numpy as np

from pld_slam.config import PointsConfig
from pld_slam.frontend.descriptors import (
    DESCRIPTOR_BYTES,
    CandidateMatches,
    best_matches,
    hamming_distances,
    unique_train,
)
from pld_slam.geometry.camera import StereoCamera
from pld_slam.jit import kernel

ORB_EDGE_THRESHOLD = 19
"""Border [px at each level] where ORB finds no corner (ORB-SLAM2's EDGE_THRESHOLD)."""

ORB_PATCH_SIZE = 31
"""Side of the ORB descriptor patch [px at the keypoint's level]."""


AGREEMENT_BAND = 4.0
"""`stereo_agreement` searches this many times the stereo row tolerance off the row."""

AGREEMENT_STRIDE = 4
"""`stereo_agreement` searches every this-many-th left keypoint: 1.6 ms a KITTI pair (all of them: 9 ms)."""


@dataclass(frozen=True)
class StereoAgreement:
    """How well one pair agrees with a rectified, synchronised rig (`stereo_agreement`; a run is judged
    on their sums by `pld_slam.eval.stereo_pair`).

    Attributes
    ----------
    keypoints, stereo : int
        Left keypoints, and those with a stereo match.
    band_matches, on_row : int
        Descriptor matches of a sample of left keypoints in a band wider than the stereo
        search's, and those of them within the stereo row tolerance.
    """

    keypoints: int = 0
    stereo: int = 0
    band_matches: int = 0
    on_row: int = 0


@dataclass(frozen=True)
class ImagePoints:
    """Bucketed ORB keypoints of one image, with the pyramid they were found in.

    Attributes
    ----------
    uv : (N, 2) float64
        Pixels (u, v) at full resolution.
    octave : (N,) int64
        Pyramid level of each keypoint; level ``l`` is the image scaled by ``scale_factor^-l``.
    descriptors : (N, 32) uint8
        ORB descriptors.
    pyramid : tuple of (H_l, W_l) uint8
        The image at every level, for the sub-pixel stereo refinement.
    """

    uv: np.ndarray
    octave: np.ndarray
    descriptors: np.ndarray
    pyramid: tuple[np.ndarray, ...]


@dataclass(frozen=True)
class StereoPoints:
    """Stereo-matched ORB points of a rectified pair, in the left image and camera frame.

    Attributes
    ----------
    uv : (N, 2) float64
        Left-image pixels (u, v).
    octave : (N,) int64
        ORB pyramid level of the left keypoint.
    descriptors : (N, 32) uint8
        ORB descriptors of the left keypoints.
    disparity : (N,) float64
        ``u_left - u_right`` [px], sub-pixel, > 0.
    u_right : (N,) float64
        Right-image column of each point [px].
    points_c : (N, 3) float64
        Triangulated points in the left camera frame [m].
    """

    uv: np.ndarray
    octave: np.ndarray
    descriptors: np.ndarray
    disparity: np.ndarray
    u_right: np.ndarray
    points_c: np.ndarray

    def __len__(self) -> int:
        return self.uv.shape[0]


@dataclass(frozen=True)
class LeftKeypoints:
    """Every bucketed ORB keypoint of the left image: the stereo points first, then the others.

    Rows ``0 .. n_stereo - 1`` are the `StereoPoints` of the same pair, in the same order
    (a stereo point has the same index in both); the rest found no stereo match.

    Attributes
    ----------
    uv : (N, 2) float64
        Left-image pixels (u, v).
    octave : (N,) int64
        ORB pyramid level.
    descriptors : (N, 32) uint8
        ORB descriptors.
    u_right : (N,) float64
        Right-image column [px] of the stereo points, NaN for the others.
    n_stereo : int
        How many rows are stereo points.
    """

    uv: np.ndarray
    octave: np.ndarray
    descriptors: np.ndarray
    u_right: np.ndarray
    n_stereo: int

    def __len__(self) -> int:
        return self.uv.shape[0]

    @classmethod
    def empty(cls) -> "LeftKeypoints":
        """No keypoints."""
        return cls(np.zeros((0, 2)), np.zeros(0, dtype=np.int64), np.zeros((0, DESCRIPTOR_BYTES), dtype=np.uint8),
                   np.zeros(0), 0)

    @classmethod
    def concatenate(cls, frames: Sequence["LeftKeypoints"]) -> "LeftKeypoints":
        """The keypoints of ``frames`` one after the other, for searches over several frames at once
        (their stereo rows are no longer first: ``n_stereo`` is 0)."""
        return cls(
            uv=np.concatenate([frame.uv for frame in frames]),
            octave=np.concatenate([frame.octave for frame in frames]),
            descriptors=np.concatenate([frame.descriptors for frame in frames]),
            u_right=np.concatenate([frame.u_right for frame in frames]),
            n_stereo=0,
        )


def detect_image_points(image: np.ndarray, config: PointsConfig) -> ImagePoints:
    """ORB keypoints of a grey image (H, W) uint8, bucketed over the image (module docstring)."""
    orb = cv2.ORB_create(
        nfeatures=round(config.oversampling * config.n_features),
        scaleFactor=config.scale_factor,
        nlevels=config.n_levels,
        edgeThreshold=ORB_EDGE_THRESHOLD,
        fastThreshold=config.fast_threshold,
        patchSize=ORB_PATCH_SIZE,
    )
    keypoints = orb.detect(image, None)
    uv = keypoint_pixels(keypoints)
    response = np.array([keypoint.response for keypoint in keypoints], dtype=np.float64)
    distinct = np.flatnonzero(rank_in_cell(bucket_cells(uv, config.min_separation_px), response) == 0)
    kept = distinct[bucket_strongest(uv[distinct], response[distinct], config.bucket_size, config.n_features)]
    keypoints, descriptors = orb.compute(image, [keypoints[i] for i in kept])
    if descriptors is None:
        descriptors = np.zeros((0, DESCRIPTOR_BYTES), dtype=np.uint8)
    return ImagePoints(
        uv=keypoint_pixels(keypoints),
        octave=np.array([keypoint.octave for keypoint in keypoints], dtype=np.int64),
        descriptors=descriptors,
        pyramid=image_pyramid(image, config),
    )


def keypoint_pixels(keypoints: tuple) -> np.ndarray:
    """Pixels (N, 2) float64 of OpenCV keypoints (``cv2.KeyPoint_convert`` returns () for none)."""
    return np.asarray(cv2.KeyPoint_convert(keypoints), dtype=np.float64).reshape(-1, 2)


def bucket_cells(uv: np.ndarray, cell_size: int) -> np.ndarray:
    """Index (N,) of the square cell of side ``cell_size`` [px] holding each pixel (N, 2)."""
    cell = np.floor(uv / cell_size).astype(np.int64)
    columns = cell[:, 0].max(initial=0) + 1
    return cell[:, 1] * columns + cell[:, 0]


def rank_in_cell(cell: np.ndarray, response: np.ndarray) -> np.ndarray:
    """Strength rank (N,) of each keypoint within its cell: 0 for the strongest.

    Ties in ``response`` go to the lower index (``lexsort`` is stable), so the ranking is
    deterministic.
    """
    order = np.lexsort((-response, cell))
    starts = np.flatnonzero(np.diff(cell[order], prepend=-1))
    counts = np.diff(np.r_[starts, cell.size])
    rank = np.empty(cell.size, dtype=np.int64)
    rank[order] = np.arange(cell.size) - np.repeat(starts, counts)
    return rank


def bucket_strongest(uv: np.ndarray, response: np.ndarray, cell_size: int, n_keep: int) -> np.ndarray:
    """Indices (<= n_keep,) of keypoints taken round-robin over cells, strongest first.

    Parameters
    ----------
    uv : (N, 2) float64
        Keypoint pixels.
    response : (N,) float64
        Corner strength (ORB's Harris score).
    cell_size : int
        Side of the square cells [px].
    n_keep : int
        How many to keep.

    Returns
    -------
    (K,) int64, sorted
        Every cell's strongest keypoint, then every cell's second strongest, and so on
        (within a round, the stronger first) until ``n_keep`` are taken.
    """
    rank = rank_in_cell(bucket_cells(uv, cell_size), response)
    order = np.lexsort((-response, rank))
    return np.sort(order[:n_keep])


def level_scales(config: PointsConfig) -> np.ndarray:
    """Scale (n_levels,) of every pyramid level relative to the full image: ``scale_factor^l``."""
    return config.scale_factor ** np.arange(config.n_levels)


def image_pyramid(image: np.ndarray, config: PointsConfig) -> tuple[np.ndarray, ...]:
    """The image (H, W) at every level: level ``l`` is ``round(W / s), round(H / s)`` for
    ``s = scale_factor^l``, each level resized from the one before, as OpenCV's ORB does."""
    height, width = image.shape
    levels = [image]
    for scale in level_scales(config)[1:]:
        size = (round(width / scale), round(height / scale))
        levels.append(cv2.resize(levels[-1], size, interpolation=cv2.INTER_LINEAR_EXACT))
    return tuple(levels)


def disparity_limits(
    camera: StereoCamera, min_depth_baselines: float, max_depth_baselines: float
) -> tuple[float, float]:
    """Smallest and largest accepted disparity [px]: depths between the two limits, in baselines.

    A depth of ``k`` baselines has disparity ``fx * b / (k * b) = fx / k``.
    """
    return camera.fx / max_depth_baselines, camera.fx / min_depth_baselines


def row_band_candidates(
    left: ImagePoints, right: ImagePoints, config: PointsConfig, d_min: float, d_max: float
) -> tuple[np.ndarray, np.ndarray]:
    """Candidate stereo pairs (left index (P,), right index (P,)) along each left keypoint's row band.

    A right keypoint is a candidate when its octave differs by at most one, its row is
    within ``stereo_row_tolerance * scale_factor^octave`` of the left keypoint's, and the
    disparity ``u_left - u_right`` lies in ``[d_min, d_max]``. Right keypoints are sorted
    by (octave, row) once, so each left keypoint's band at each of the three octaves is
    one contiguous slice.
    """
    octave_stride = 2.0 * (right.pyramid[0].shape[0] + config.stereo_row_tolerance * level_scales(config)[-1])
    key = right.octave * octave_stride + right.uv[:, 1]
    by_key = np.argsort(key, kind="stable")
    sorted_key = key[by_key]
    radius = config.stereo_row_tolerance * level_scales(config)[left.octave]
    centre = (left.octave + np.array([[-1], [0], [1]])) * octave_stride + left.uv[:, 1]
    start = np.searchsorted(sorted_key, (centre - radius).ravel(), side="left")
    stop = np.searchsorted(sorted_key, (centre + radius).ravel(), side="right")
    counts = stop - start
    query = np.repeat(np.tile(np.arange(left.octave.size), 3), counts)
    offset = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
    train = by_key[np.repeat(start, counts) + offset]
    disparity = left.uv[query, 0] - right.uv[train, 0]
    keep = (disparity >= d_min) & (disparity <= d_max)
    return query[keep], train[keep]


def sad_along_row(
    left_level: np.ndarray,
    right_level: np.ndarray,
    left_px: np.ndarray,
    right_u: np.ndarray,
    half_window: int,
    radius: int,
) -> tuple[np.ndarray, np.ndarray]:
    """Mean-free SAD of a left window against right windows shifted along the row.

    Parameters
    ----------
    left_level, right_level : (H, W) uint8
        The left and right image at one pyramid level.
    left_px : (K, 2) int64
        Window centres (column, row) in ``left_level``.
    right_u : (K,) int64
        Column of the initial match in ``right_level`` (same row).
    half_window, radius : int
        Windows are ``2 * half_window + 1`` square; shifts run over ``[-radius, radius]``.

    Returns
    -------
    sad : (K', 2 * radius + 1) float64
        SAD per shift, for the keypoints whose windows lie inside both images.
    inside : (K,) bool
        Which keypoints those are.

    One numba kernel (`_mean_free_sad`) computes every window in float64 (faster than numpy on
    (K', shifts, pixels) float32 arrays, with the same minima:
    docs/decisions/0012-orb-stereo-points.md).
    """
    height, width = left_level.shape
    reach = half_window + radius
    u, v = left_px[:, 0], left_px[:, 1]
    inside = (
        (v >= half_window)
        & (v < height - half_window)
        & (u >= half_window)
        & (u < width - half_window)
        & (right_u >= reach)
        & (right_u < width - reach)
    )
    sad = _mean_free_sad(left_level, right_level, u[inside], v[inside], right_u[inside], half_window, radius)
    return sad, inside


@kernel
def _mean_free_sad(left_level, right_level, u, v, right_u, half_window, radius):
    """`sad_along_row` for windows inside both images: (K, 2 radius + 1) float64."""
    side = 2 * half_window + 1
    sad = np.empty((len(u), 2 * radius + 1))
    left = np.empty(side * side)
    right = np.empty(side * side)
    for k in range(len(u)):
        mean_free_window(left_level, u[k], v[k], half_window, left)
        for shift in range(-radius, radius + 1):
            sad[k, shift + radius] = sad_to_window(left, right_level, right_u[k] + shift, v[k], half_window, right)
    return sad


@kernel
def mean_free_window(image, u, v, half_window, out):
    """Fill ``out`` ((2 half_window + 1)^2,) float64 with the window of ``image`` centred on
    column ``u``, row ``v``, row by row, less its mean."""
    i = 0
    for dv in range(-half_window, half_window + 1):
        for du in range(-half_window, half_window + 1):
            out[i] = image[v + dv, u + du]
            i += 1
    out -= out.mean()


@kernel
def sad_to_window(window, image, u, v, half_window, scratch, limit=np.inf):
    """Mean-free SAD between ``window`` (a `mean_free_window`) and the window of ``image``
    centred on column ``u``, row ``v``; ``scratch`` is overwritten. The sum stops after the
    row where it reaches ``limit`` (a search that only needs costs under it)."""
    i = 0
    for dv in range(-half_window, half_window + 1):
        for du in range(-half_window, half_window + 1):
            scratch[i] = image[v + dv, u + du]
            i += 1
    mean = scratch.mean()
    total = 0.0
    side = 2 * half_window + 1
    for row in range(side):
        for i in range(row * side, (row + 1) * side):
            total += abs(scratch[i] - mean - window[i])
        if total >= limit:
            break
    return total


def parabola_minimum(sad: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sub-pixel shift (K,) of the SAD minimum of each row of ``sad`` (K, S), and validity (K,).

    The shift is relative to the centre column ``S // 2``; a minimum on the first or last
    column (the true one may lie outside the search) is invalid.
    """
    best = np.argmin(sad, axis=1)
    valid = (best > 0) & (best < sad.shape[1] - 1)
    at = np.clip(best, 1, sad.shape[1] - 2)
    rows = np.arange(sad.shape[0])
    before, centre, after = sad[rows, at - 1], sad[rows, at], sad[rows, at + 1]
    curvature = before + after - 2.0 * centre
    valid &= curvature > 0
    delta = np.where(valid, (before - after) / (2.0 * np.where(valid, curvature, 1.0)), 0.0)
    return at - sad.shape[1] // 2 + delta, valid


def refine_right_columns(
    left: ImagePoints, right: ImagePoints, query: np.ndarray, train: np.ndarray, config: PointsConfig
) -> tuple[np.ndarray, np.ndarray]:
    """Sub-pixel right columns (P,) [px, full resolution] of matched pairs, and validity (P,).

    Each pair is refined at the left keypoint's octave by `sad_along_row` and
    `parabola_minimum`; the window is centred on the left keypoint's pixel at that level,
    so the disparity is measured from ``scale * round(u_left / scale)``, which equals
    ``u_left`` for ORB keypoints (they lie on the level's pixel grid).
    """
    u_right = np.zeros(query.size)
    valid = np.zeros(query.size, dtype=bool)
    for octave in np.unique(left.octave[query]):
        pairs = np.flatnonzero(left.octave[query] == octave)
        scale = level_scales(config)[octave]
        left_px = np.rint(left.uv[query[pairs]] / scale).astype(np.int64)
        right_u = np.rint(right.uv[train[pairs], 0] / scale).astype(np.int64)
        sad, inside = sad_along_row(
            left.pyramid[octave],
            right.pyramid[octave],
            left_px,
            right_u,
            config.sad_half_window,
            config.sad_search_radius,
        )
        shift, ok = parabola_minimum(sad)
        refined = pairs[inside]
        u_right[refined] = scale * (right_u[inside] + shift)
        valid[refined] = ok
    return u_right, valid


def row_band_best_matches(
    left: ImagePoints, right: ImagePoints, config: PointsConfig, d_min: float, d_max: float
) -> CandidateMatches:
    """The best right keypoint of each left keypoint along its row band (`row_band_candidates`), kept
    when under ``stereo_max_distance`` and past the ratio test against rivals elsewhere on the row."""
    query, train = row_band_candidates(left, right, config, d_min, d_max)
    distance = hamming_distances(left.descriptors[query], right.descriptors[train])
    column_at_octave = right.uv[train, 0] / level_scales(config)[left.octave[query]]
    return best_matches(query, train, distance, column_at_octave, config.stereo_max_distance, config.stereo_ratio)


def stereo_agreement(
    left: ImagePoints, right: ImagePoints, n_stereo: int, camera: StereoCamera, config: PointsConfig
) -> StereoAgreement:
    """`StereoAgreement` of a pair whose stereo matching matched ``n_stereo`` left keypoints.

    The row agreement searches every `AGREEMENT_STRIDE`-th left keypoint along a band
    `AGREEMENT_BAND` times as wide as the stereo search's (the same disparity limits,
    descriptor bound and ratio test) and counts how many best matches lie within the
    stereo row tolerance: on a rectified, synchronised pair nearly all do, wherever
    the band reaches; when the right image is out of sync, the scene's motion moves them
    off the row.
    """
    d_min, d_max = disparity_limits(camera, config.min_depth_baselines, config.max_depth_baselines)
    offset = camera.disparity_offset
    sample = slice(None, None, AGREEMENT_STRIDE)
    sampled = ImagePoints(left.uv[sample], left.octave[sample], left.descriptors[sample], left.pyramid)
    band = replace(config, stereo_row_tolerance=AGREEMENT_BAND * config.stereo_row_tolerance)
    matches = row_band_best_matches(sampled, right, band, d_min + offset, d_max + offset)
    row_offset = np.abs(right.uv[matches.train, 1] - sampled.uv[matches.query, 1])
    tolerance = config.stereo_row_tolerance * level_scales(config)[sampled.octave[matches.query]]
    return StereoAgreement(len(left.uv), n_stereo, len(matches.query), int(np.count_nonzero(row_offset <= tolerance)))


def stereo_match_indices(
    left: ImagePoints, right: ImagePoints, camera: StereoCamera, config: PointsConfig
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The left keypoints with a stereo match (K,) int64, their disparity (K,) and right column (K,) [px].

    Candidates, descriptor match and sub-pixel disparity as the module docstring says;
    matches outside the depth limits are dropped. The disparity is ``bf / z``: the
    camera's ``disparity_offset`` is removed, and the right column is ``u_left`` minus it.
    """
    d_min, d_max = disparity_limits(camera, config.min_depth_baselines, config.max_depth_baselines)
    offset = camera.disparity_offset
    matches = unique_train(row_band_best_matches(left, right, config, d_min + offset, d_max + offset))
    u_right_image, valid = refine_right_columns(left, right, matches.query, matches.train, config)
    index = matches.query
    disparity = camera.image_disparity_to_metric(left.uv[index, 0] - u_right_image)
    u_right = left.uv[index, 0] - disparity
    keep = valid & (disparity >= d_min) & (disparity <= d_max)
    return index[keep], disparity[keep], u_right[keep]


def match_stereo_points(
    left: ImagePoints, right: ImagePoints, camera: StereoCamera, config: PointsConfig
) -> StereoPoints:
    """Stereo points of a rectified pair: candidates, descriptor match, sub-pixel disparity, depth."""
    index, disparity, u_right = stereo_match_indices(left, right, camera, config)
    return stereo_points(left, index, disparity, u_right, camera)


def stereo_points(
    left: ImagePoints, index: np.ndarray, disparity: np.ndarray, u_right: np.ndarray, camera: StereoCamera
) -> StereoPoints:
    """The `StereoPoints` of left keypoints ``index`` (K,) with their disparity and right column (K,)."""
    return StereoPoints(
        uv=left.uv[index],
        octave=left.octave[index],
        descriptors=left.descriptors[index],
        disparity=disparity,
        u_right=u_right,
        points_c=camera.triangulate(left.uv[index], disparity),
    )


def left_keypoints(left: ImagePoints, index: np.ndarray, u_right: np.ndarray) -> LeftKeypoints:
    """Every left keypoint, the stereo-matched ones ``index`` (K,) first with their right columns (K,)."""
    others = np.setdiff1d(np.arange(len(left.uv)), index)
    order = np.concatenate([index, others])
    right_columns = np.concatenate([u_right, np.full(len(others), np.nan)])
    return LeftKeypoints(left.uv[order], left.octave[order], left.descriptors[order], right_columns, len(index))
