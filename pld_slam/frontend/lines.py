"""Line segments of a rectified stereo pair: detection, LBD descriptors, stereo matching.

The paper says "LSD" and defers the rest to DynPL-SVO, which follows PL-SLAM's stereo
line matching. Where they are silent we decide as follows (the measurements, on KITTI 06
against SGBM disparities sampled along each line: docs/decisions/0017-stereo-lines.md):

- Detection: OpenCV's LSD (standard refinement) on the image scaled by
  ``detection_scale`` = 0.5 (OpenCV's default is 0.8): less than half the time per KITTI
  image, as many long segments, for a slightly larger disparity error. OpenCV's LSD puts
  scaled-image points 0.5 px up and left at scale 0.5; they are moved back. Segments
  shorter than ``min_length`` (1.5 % of the image diagonal: 19 px on KITTI) are dropped.
- ``lines.detector`` offers two cheaper detectors on the same half image:
  FastLineDetector and EDLines (EdgeDrawing). Both fit their segments to edge pixels of
  the half image, whole pixels there, so their kept segments are moved onto the
  sub-pixel gradient maximum of the full image (`refined_to_edges`), which brings their
  endpoint disparity error to LSD's. They save front-end CPU, but a run is hardly faster
  (the front end runs beside tracking and mapping, which set the pace). LSD stays the
  default: the paper's detector, and the cheaper ones are not better on every sequence
  (docs/decisions/0017-stereo-lines.md; docs/decisions/0002-front-end-speed.md).
- Segments closer to horizontal than ``min_angle_from_horizontal`` (15 deg) are dropped at
  detection: their disparity is ill-posed, since a lateral error ``e`` of the right
  segment moves its crossing with a left endpoint's row by ``e / sin(angle)`` (3.9 e at
  15 deg). A line without depth is of no use to this stereo system, and dropping them
  before the cap and before LBD saves time.
- The ``max_lines`` longest remaining segments are kept (long segments are the most
  repeatable and the best conditioned), then described by LBD (OpenCV's
  ``BinaryDescriptor.compute``, 32 bytes) on KeyLines built from the LSD segments.
  OpenCV's ``LSDDetector`` + LBD measured slower.
- Stereo matching, as PL-SLAM: candidates are right segments whose oriented direction
  (LSD orients a segment by its gradient, so polarity must agree too) is within
  ``stereo_max_angle_difference``, whose row range shares at least
  ``stereo_min_row_overlap`` of the shorter one, and whose endpoint disparities are within
  the depth limits (3 to 200 baselines, as points). Among them the smallest LBD Hamming
  distance under ``stereo_max_distance`` wins if it passes the ratio test against the best
  rival (a candidate crossing the left segment's middle row more than 1 px away), and
  each right segment is kept by its closest left segment only.
- Endpoint disparities: the left endpoints stay as detected; the right segment's infinite
  line is intersected with each left endpoint's row, ``d = u_left - u_right(v)``, which
  also holds where the two segments cover different parts of the line.
"""

import math
from dataclasses import dataclass

import cv2
import numpy as np

from pld_slam.config import LinesConfig
from pld_slam.frontend.descriptors import DESCRIPTOR_BYTES, best_matches, hamming_distances, unique_train
from pld_slam.frontend.points import disparity_limits
from pld_slam.geometry.camera import StereoCamera
from pld_slam.geometry.segments import oriented_angle_differences, segment_directions


@dataclass(frozen=True)
class ImageLines:
    """LSD segments of one image with their LBD descriptors.

    Attributes
    ----------
    segments : (M, 2, 2) float64
        Endpoints ``[[u_s, v_s], [u_e, v_e]]`` [px], longest segment first.
    descriptors : (M, 32) uint8
        Binary LBD descriptors.
    """

    segments: np.ndarray
    descriptors: np.ndarray


@dataclass(frozen=True)
class StereoLines:
    """Stereo-matched line segments of a rectified pair, in the left image and camera frame.

    Attributes
    ----------
    endpoints : (M, 4) float64
        Left-image endpoints ``(u_s, v_s, u_e, v_e)`` [px].
    disparity : (M, 2) float64
        Disparity at the start and end point [px], > 0.
    descriptors : (M, 32) uint8
        LBD descriptors of the left segments.
    endpoints_c : (M, 2, 3) float64
        Start and end point triangulated in the left camera frame [m].
    """

    endpoints: np.ndarray
    disparity: np.ndarray
    descriptors: np.ndarray
    endpoints_c: np.ndarray

    def __len__(self) -> int:
        return self.endpoints.shape[0]

    @property
    def right_endpoints(self) -> np.ndarray:
        """(M, 4) two points ``(u_s, v_s, u_e, v_e)`` of each segment in the right image [px]: the
        left endpoints' rows, shifted by their disparities (on the right segment's line, in
        columns that share the left image's principal point: `StereoCamera.disparity_offset`)."""
        shifted = self.endpoints.copy()
        shifted[:, [0, 2]] -= self.disparity
        return shifted

    @classmethod
    def empty(cls) -> "StereoLines":
        """No lines (lines disabled, or none found)."""
        return cls(
            endpoints=np.zeros((0, 4)),
            disparity=np.zeros((0, 2)),
            descriptors=np.zeros((0, DESCRIPTOR_BYTES), dtype=np.uint8),
            endpoints_c=np.zeros((0, 2, 3)),
        )


def detect_image_lines(image: np.ndarray, config: LinesConfig) -> ImageLines:
    """Segments of a grey image (H, W) uint8 with LBD descriptors (see the module docstring)."""
    segments = DETECTORS[config.detector](image, config)
    upright = segments[~near_horizontal(segments, config.min_angle_from_horizontal)]
    kept = longest_segments(upright, min_length_px(image, config), config.max_lines)
    if config.detector in PIXEL_ACCURATE_DETECTORS:
        kept = refined_to_edges(image, kept, config)
    return ImageLines(segments=kept, descriptors=lbd_descriptors(image, kept))


def min_length_px(image: np.ndarray, config: LinesConfig) -> float:
    """The shortest segment kept in a grey image (H, W) [px]: ``min_length`` times its diagonal."""
    return config.min_length * float(np.hypot(*image.shape))


def as_segments(found: np.ndarray | None) -> np.ndarray:
    """OpenCV's detected lines (N, 1, 4) float32, or None for none, as segments (N, 2, 2) float64."""
    return np.zeros((0, 2, 2)) if found is None else found.reshape(-1, 2, 2).astype(np.float64)


def lsd_segments(image: np.ndarray, config: LinesConfig) -> np.ndarray:
    """LSD segments (M, 2, 2) [px] of a grey image (H, W) uint8, detected on it scaled by ``detection_scale``.

    OpenCV's LSD returns scaled-image pixel-centre coordinates divided by the scale, so
    points lie ``0.5 / scale - 0.5`` px up and left of where they are (0.5 px at scale
    0.5); they are moved back.
    """
    scale = config.detection_scale
    found = cv2.createLineSegmentDetector(cv2.LSD_REFINE_STD, scale).detect(image)[0]
    return as_segments(found) + (0.5 / scale - 0.5)


def fld_segments(image: np.ndarray, config: LinesConfig) -> np.ndarray:
    """FastLineDetector segments (M, 2, 2) [px] of a grey image (H, W) uint8, detected on it scaled by
    ``detection_scale``.

    OpenCV's defaults but for the length threshold, which is ``min_length`` at the
    detection scale (rounded down): the default 10 px would drop segments that
    ``min_length`` keeps on small images, and 1 px takes five times as long.
    """
    small = scaled_image(image, config.detection_scale)
    shortest = int(min_length_px(image, config) * config.detection_scale)
    found = cv2.ximgproc.createFastLineDetector(length_threshold=shortest).detect(small)
    return full_resolution(as_segments(found), small.shape, image.shape)


def edlines_segments(image: np.ndarray, config: LinesConfig) -> np.ndarray:
    """EDLines segments (M, 2, 2) [px] of a grey image (H, W) uint8, detected on it scaled by
    ``detection_scale``.

    EdgeDrawing with OpenCV's defaults; its segments run the way the edge was traced, so
    they are oriented by their gradient afterwards (`oriented_by_gradient`).
    """
    small = scaled_image(image, config.detection_scale)
    edges = cv2.ximgproc.createEdgeDrawing()
    edges.detectEdges(small)
    segments = oriented_by_gradient(small, as_segments(edges.detectLines()))
    return full_resolution(segments, small.shape, image.shape)


DETECTORS = {"lsd": lsd_segments, "fld": fld_segments, "edlines": edlines_segments}
"""Segment detector of each ``lines.detector``: (image (H, W) uint8, config) -> segments (M, 2, 2) [px]."""
PIXEL_ACCURATE_DETECTORS = ("fld", "edlines")
"""Detectors whose segments sit on whole pixels of the scaled image: their kept segments are
moved onto the edge (`refined_to_edges`); LSD's are sub-pixel already."""


def refined_to_edges(image: np.ndarray, segments: np.ndarray, config: LinesConfig) -> np.ndarray:
    """Segments (M, 2, 2) [px] of a grey image (H, W) uint8 moved across their direction onto the
    sub-pixel maximum of the image gradient: the same segments, endpoints shifted sideways.

    FastLineDetector and EDLines fit their segments to edge pixels found at whole pixels
    of the scaled image, LSD to the gradient field, which places it to a fraction of a
    pixel. Every ``edge_sample_spacing_px`` (3 px) along a segment (``edge_min_samples`` to
    ``edge_max_samples`` times, 6 to 32), the full image is sampled across it,
    ``+-edge_search_px`` (3 px); the largest central difference, refined by a parabola
    through its neighbours, is the edge there. Samples with a gradient not above
    ``edge_min_gradient`` (4 levels / px), a maximum at the search's end, or more than
    ``edge_outlier_px`` (1 px) from the segment's median offset are dropped; the offset is
    then fitted as a straight function of the position along the segment (least squares)
    and each endpoint moved by it, at most ``edge_search_px``. Segments with fewer than
    ``edge_min_samples // 2`` usable samples stay as detected. The endpoints keep their
    position along the line. (The keys are ``config``'s, section ``lines``.)
    """
    if len(segments) == 0:
        return segments
    reach = config.edge_search_px
    start, delta = segments[:, 0], segments[:, 1] - segments[:, 0]
    normal = segment_normals(segments)
    samples = np.clip(
        (segment_lengths(segments) / config.edge_sample_spacing_px).astype(np.int64), config.edge_min_samples,
        config.edge_max_samples,
    )
    along = (np.arange(samples.max())[None, :] + 0.5) / samples[:, None]  # (M, K) fraction of the length
    in_segment = along < 1.0
    across = np.arange(-reach - 1, reach + 2, dtype=np.float64)  # (T,) [px]
    centres = start[:, None] + np.minimum(along, 1.0)[..., None] * delta[:, None]  # (M, K, 2)
    where = centres[:, :, None] + across[None, None, :, None] * normal[:, None, None]  # (M, K, T, 2)
    n_segments, n_samples, n_across, _ = where.shape
    where = where.reshape(n_segments * n_samples, n_across, 2).astype(np.float32)
    grey = cv2.remap(
        image.astype(np.float32),
        np.ascontiguousarray(where[..., 0]),
        np.ascontiguousarray(where[..., 1]),
        cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_REPLICATE,
    ).reshape(n_segments, n_samples, n_across)
    gradient = 0.5 * np.abs(grey[..., 2:] - grey[..., :-2])  # (M, K, T - 2), at across[1:-1]
    peak = np.argmax(gradient, axis=2)
    inside = (peak > 0) & (peak < gradient.shape[2] - 1)
    peak = np.clip(peak, 1, gradient.shape[2] - 2)
    before, top, after = (np.take_along_axis(gradient, (peak + k)[..., None], 2)[..., 0] for k in (-1, 0, 1))
    curvature = before - 2.0 * top + after
    vertex = np.where(curvature < 0, 0.5 * (before - after) / np.where(curvature < 0, curvature, -1.0), 0.0)
    offset = peak - reach + np.clip(vertex, -0.5, 0.5)  # (M, K) [px] along the normal
    usable = in_segment & inside & (top > config.edge_min_gradient)
    usable_offsets = np.where(usable, offset, np.nan)
    usable_offsets[~usable.any(axis=1)] = 0.0  # no usable sample: no median needed, and no all-NaN warning
    usable &= np.abs(offset - np.nanmedian(usable_offsets, axis=1, keepdims=True)) <= config.edge_outlier_px
    shift = np.clip(_fitted_offsets(along, offset, usable), -reach, reach)  # (M, 2) at the endpoints
    enough = usable.sum(axis=1) >= config.edge_min_samples // 2
    return segments + np.where(enough[:, None, None], shift[..., None] * normal[:, None], 0.0)


def _fitted_offsets(along: np.ndarray, offset: np.ndarray, usable: np.ndarray) -> np.ndarray:
    """The straight-line fit ``offset = a + b along`` over the ``usable`` samples of each segment
    (all (M, K)), evaluated at ``along`` 0 and 1: (M, 2). A segment whose samples cannot fix
    a slope gets its mean offset at both ends."""
    weight = usable.astype(np.float64)
    count = np.maximum(weight.sum(axis=1), 1.0)
    mean_along = (weight * along).sum(axis=1) / count
    mean_offset = (weight * offset).sum(axis=1) / count
    spread = (weight * (along - mean_along[:, None]) ** 2).sum(axis=1)
    covariance = (weight * (along - mean_along[:, None]) * (offset - mean_offset[:, None])).sum(axis=1)
    slope = np.where(spread > 1e-9, covariance / np.maximum(spread, 1e-9), 0.0)
    at_start = mean_offset - slope * mean_along
    return np.column_stack([at_start, at_start + slope])


def scaled_image(image: np.ndarray, scale: float) -> np.ndarray:
    """A grey image (H, W) uint8 resized by ``scale`` with pixel-area averaging."""
    return image if scale == 1.0 else cv2.resize(image, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)


def full_resolution(segments: np.ndarray, small_shape: tuple, full_shape: tuple) -> np.ndarray:
    """Segments (M, 2, 2) in pixel-centre coordinates of an image of ``small_shape`` (h, w) mapped to
    the same image resized to ``full_shape`` (H, W)."""
    ratio = np.array(full_shape[1::-1], dtype=np.float64) / small_shape[1::-1]
    return (segments + 0.5) * ratio - 0.5


def oriented_by_gradient(image: np.ndarray, segments: np.ndarray, samples: int = 8) -> np.ndarray:
    """Segments (M, 2, 2) of a grey image (H, W), each reversed where needed so that the image
    is brighter on its side ``(dv, -du)`` (on its left on screen, rows pointing down), as LSD
    and FastLineDetector orient theirs.

    The brightness difference is summed over ``samples`` points along the segment, 1 px to
    either side.
    """
    start, delta = segments[:, 0], segments[:, 1] - segments[:, 0]
    normal = segment_normals(segments)
    along = start[:, None] + ((np.arange(samples) + 0.5) / samples)[None, :, None] * delta[:, None]
    sides = np.concatenate([along + normal[:, None], along - normal[:, None]], axis=1).astype(np.float32)
    if len(sides) == 0:
        return segments
    grey = cv2.remap(image, sides[..., 0], sides[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    contrast = grey[:, :samples].astype(np.int64).sum(axis=1) - grey[:, samples:].astype(np.int64).sum(axis=1)
    return np.where((contrast < 0)[:, None, None], segments[:, ::-1], segments)


def segment_lengths(segments: np.ndarray) -> np.ndarray:
    """Length (M,) [px] of segments (M, 2, 2)."""
    return np.linalg.norm(segments[:, 1] - segments[:, 0], axis=1)


def segment_normals(segments: np.ndarray) -> np.ndarray:
    """Unit normals (M, 2) of segments (M, 2, 2): the direction ``(du, dv)`` turned to ``(dv, -du)``,
    the side LSD puts the brighter image on (zero for a segment of no length)."""
    delta = segments[:, 1] - segments[:, 0]
    return delta[:, ::-1] * [1.0, -1.0] / np.maximum(segment_lengths(segments), 1e-12)[:, None]


def near_horizontal(segments: np.ndarray, min_angle: float) -> np.ndarray:
    """Whether each segment (M, 2, 2) lies closer than ``min_angle`` [rad] to the image rows (M,)."""
    delta = segments[:, 1] - segments[:, 0]
    return np.abs(delta[:, 1]) < np.sin(min_angle) * np.linalg.norm(delta, axis=1)


def longest_segments(segments: np.ndarray, min_length: float, max_count: int) -> np.ndarray:
    """The at most ``max_count`` longest segments (K, 2, 2) at least ``min_length`` [px] long, longest first."""
    lengths = segment_lengths(segments)
    order = np.argsort(-lengths, kind="stable")
    return segments[order[lengths[order] >= min_length][:max_count]]


def keylines(segments: np.ndarray) -> list:
    """OpenCV ``KeyLine`` objects (octave 0) for segments (M, 2, 2), as ``LSDDetector`` fills them."""
    result = []
    for index, ((u_s, v_s), (u_e, v_e)) in enumerate(segments.tolist()):
        line = cv2.line_descriptor.KeyLine()
        line.startPointX, line.startPointY, line.endPointX, line.endPointY = u_s, v_s, u_e, v_e
        line.sPointInOctaveX, line.sPointInOctaveY = u_s, v_s
        line.ePointInOctaveX, line.ePointInOctaveY = u_e, v_e
        line.angle = math.atan2(v_e - v_s, u_e - u_s)
        line.lineLength = math.hypot(u_e - u_s, v_e - v_s)
        line.numOfPixels = max(abs(round(u_e) - round(u_s)), abs(round(v_e) - round(v_s))) + 1
        line.pt = ((u_s + u_e) / 2, (v_s + v_e) / 2)
        line.class_id = index
        line.octave = 0
        result.append(line)
    return result


def lbd_descriptors(image: np.ndarray, segments: np.ndarray) -> np.ndarray:
    """Binary LBD descriptors (M, 32) uint8 of segments (M, 2, 2) in a grey image (H, W).

    A new ``BinaryDescriptor`` per call: it keeps the gradient images of the last call in
    itself, so one instance must not serve two threads.
    """
    if segments.shape[0] == 0:
        return np.zeros((0, DESCRIPTOR_BYTES), dtype=np.uint8)
    describer = cv2.line_descriptor.BinaryDescriptor.createBinaryDescriptor()
    _, descriptors = describer.compute(image, keylines(segments))
    return descriptors


def columns_at_rows(segments: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """Column [px] where the infinite line through each segment crosses a row.

    Parameters
    ----------
    segments : (..., 2, 2) float64
        Segments ``[[u_s, v_s], [u_e, v_e]]``, none horizontal.
    rows : (...) float64
        Rows [px], broadcast against the segments' leading axes.
    """
    start = segments[..., 0, :]
    delta = segments[..., 1, :] - start
    return start[..., 0] + (rows - start[..., 1]) * delta[..., 0] / delta[..., 1]


def row_overlap(left: np.ndarray, right: np.ndarray) -> np.ndarray:
    """Shared row range of every left and right segment, as a fraction of the shorter range (L, R)."""
    left_rows = np.sort(left[:, :, 1], axis=1)
    right_rows = np.sort(right[:, :, 1], axis=1)
    shared = np.minimum(left_rows[:, None, 1], right_rows[None, :, 1]) - np.maximum(
        left_rows[:, None, 0], right_rows[None, :, 0]
    )
    shorter = np.minimum(np.diff(left_rows, axis=1), np.diff(right_rows, axis=1).T)
    return shared / shorter


def endpoint_disparities(left: np.ndarray, right: np.ndarray) -> np.ndarray:
    """Disparities (L, R, 2) [px] of every left segment's two endpoints (L, 2, 2) against the
    infinite line of every right segment (R, 2, 2), taken at the endpoints' rows."""
    crossing = columns_at_rows(right[None, :, None], left[:, None, :, 1])
    return left[:, None, :, 0] - crossing


def match_stereo_lines(left: ImageLines, right: ImageLines, camera: StereoCamera, config: LinesConfig) -> StereoLines:
    """Stereo lines of a rectified pair: geometric candidates, LBD match, endpoint disparities."""
    if len(left.segments) == 0 or len(right.segments) == 0:
        return StereoLines.empty()
    d_min, d_max = disparity_limits(camera, config.min_depth_baselines, config.max_depth_baselines)
    disparity = camera.image_disparity_to_metric(endpoint_disparities(left.segments, right.segments))
    candidate = (
        (
            oriented_angle_differences(
                segment_directions(left.segments.reshape(-1, 4))[:, None],
                segment_directions(right.segments.reshape(-1, 4))[None, :],
            )
            <= config.stereo_max_angle_difference
        )
        & (row_overlap(left.segments, right.segments) >= config.stereo_min_row_overlap)
        & np.all((disparity >= d_min) & (disparity <= d_max), axis=2)
    )
    query, train = np.nonzero(candidate)
    middle_rows = left.segments[query, :, 1].mean(axis=1)
    column_at_middle = columns_at_rows(right.segments[train], middle_rows)
    distance = hamming_distances(left.descriptors[query], right.descriptors[train])
    matches = unique_train(
        best_matches(query, train, distance, column_at_middle, config.stereo_max_distance, config.stereo_ratio)
    )
    segments = left.segments[matches.query]
    disparity = disparity[matches.query, matches.train]
    endpoints_c = camera.triangulate(segments.reshape(-1, 2), disparity.reshape(-1))
    return StereoLines(
        endpoints=segments.reshape(-1, 4),
        disparity=disparity,
        descriptors=left.descriptors[matches.query],
        endpoints_c=endpoints_c.reshape(-1, 2, 3),
    )
