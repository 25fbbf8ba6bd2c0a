"""Self-calibration of the stereo rig's disparity offset from the sequence's own images.

A rectified pair measures ``d = u_left - u_right = bf / z + offset``: the offset is the
difference of the two images' principal points, ``cx_left - cx_right``. Calibration files
state it (KITTI's and `cv2.stereoRectify`'s right projection matrix may carry its own
``cx``), but a rig's calibration is not exact, and a residual offset of a fraction of a
pixel biases every depth by ``offset / d``: the same sign for every point, so the whole
trajectory comes out too long or too short (KITTI 06's uncorrected trajectory is about
1 % long: docs/decisions/0006-disparity-offset-self-calibration.md).

The offset is observable without ground truth, because an offset and a depth error are
not the same thing for a moving camera: the image flow of a static point between two
frames measures the ratio of its depths in the two frames (through its depth in the
first), its disparities measure the same ratio only when the offset is right. We
estimate it as the offset that lets the most frame pairs be explained by one rigid motion
each (`estimate_disparity_offset`):

1. Frames: ``calibration.anchors`` anchors spread evenly over the sequence, each with two
   later frames a gap ``g`` apart; pairs (a, a+g), (a+g, a+2g) and (a, a+2g). Spread,
   because a run may start standing still (no motion: no information) and one stretch
   may be untextured. No two anchors share a frame, and fewer than
   ``calibration.min_anchors`` (6) anchors with a pair pose give no estimate (anchors
   sharing frames gave a confident wrong estimate). Unreadable frames are left out. The
   gap (`frame_gap`) makes the camera move about ``calibration.pair_motion_baselines``
   (5) stereo baselines between an anchor's frames, judged from the median motion of a
   few pairs of consecutive frames: KITTI (1.2 m per frame, 0.54 m baseline) gets 2, the
   synthetic streets (0.8 m, 0.5 m) 3. Between frames close together a point's sub-pixel
   disparity error repeats, and the profile reads it as an offset (below); a wider gap
   changes the point's disparity, and with it its error, and gives the offset more depth
   change to act on. The gap is never below ``calibration.min_frame_gap`` (2), however
   fast the camera: consecutive frames mislead even with the true motion
   (docs/decisions/0006-disparity-offset-self-calibration.md).
2. Each pair's stereo points are matched by descriptor (`pair_matches`). At the current
   offset, its relative pose is found by stereo PnP RANSAC on the first frame's 3D points
   (`pnp_pose`) and refined by the pose-only solver, which also picks the inliers
   (`gate_pair`): ``calibration.pair_pose_rounds`` (2) solves, the first
   ``calibration.pair_pose_robust_rounds`` (1) robust (the tracker's four rounds cost more
   and move the estimate within its sigma: docs/decisions/0006-disparity-offset-self-calibration.md).
3. The profile cost of an offset change ``delta``: every pair's first-frame points are
   triangulated again with disparities ``d - delta``, its second-frame right columns
   moved by ``+delta``, its pose solved again on the same inliers without a robust loss,
   and the whitened squared errors summed over all pairs. A Newton step on this profile
   (`profile_minimum`) moves the offset to its minimum inside
   ``[-calibration.max_offset_px, +calibration.max_offset_px]``; steps 2 and 3 repeat
   from there until the offset moves by less than ``calibration.gating_tolerance_px``
   (0.005 px), ``calibration.gating_rounds`` (4) at most:
   inliers picked at a wrong offset favour matches that the wrong offset explains.
4. Its standard deviation: for whitened errors the profile is ``C0 + kappa (delta -
   offset)^2 / 2`` near the minimum and the offset's variance ``1 / kappa``, times the
   residual variance ``2 C0 / (n_rows - n_unknowns)`` where that exceeds 1 (the assumed
   sigmas are too small), never less (identical frames fit perfectly but say nothing
   about the offset). That deviation assumes independent errors; they are not (a point's
   sub-pixel error repeats in every frame, and on real images the offset may vary over
   the image), so the deviation used is the larger of it and the standard error of the
   anchors' own minima about the pooled one (`_spread_over_anchors`).
5. The estimate is used only when the minimum is not at the bound and its deviation is
   under ``calibration.max_sigma_px``. What is applied then depends on what is known of
   the rig. With ``calibration.prior_sigma_px`` 0 (the default) the estimate must lie
   ``calibration.min_significance`` (2.5) deviations from zero (a two-sided test at the
   1.2 % level) and is applied as it is: a rig of unknown quality keeps its calibration
   unless its images clearly say otherwise (a camera that hardly moved, too few anchors,
   no clear offset). Where the rig is known to be off, as KITTI's rectified pairs are
   (Krešo and Šegvić, VISAPP 2015; the ground-truth motion of KITTI 04 and 06 asks for
   -0.09 and -0.15 px), the KITTI family file sets a prior spread of 0.15 px and no test:
   the applied offset is the posterior mean ``estimate * prior**2 / (prior**2 + sigma**2)``.
   The paper does not calibrate; we shrink rather than test on KITTI because the test
   applies all or nothing, and we do not shrink everywhere because on exact synthetic
   rigs the estimate is off by a few hundredths of a pixel, more on low texture
   (docs/decisions/0006-disparity-offset-self-calibration.md;
   ``docs/decisions/0001-stereo-scale.md``, "Shrinking the estimate").

How wrong the estimate can be: on synthetic streets rendered with an exact rig (true
offset 0; their family file switches the estimate off) it is biased by a point's
sub-pixel disparity error repeating between nearby frames, mostly through far points;
a seed can pass the test. A user whose rig is well calibrated loses nothing by
``calibration.disparity_offset: false``.

The paper does not calibrate; it assumes the rig's calibration. We do because the offset
was the largest error on our real KITTI extracts. It costs a few seconds per run (the
stereo points of the probe pairs' 12 frames and of up to 36 anchor frames, then per round
up to 36 pair poses and three profile costs). Points only: lines would add little
information on one number and cost time.

Not in bundle adjustment: the offset can be one more unknown of BA (every row's derivative
is minus its ``u_right`` weight), but the cost barely changes along the offset, a map
tracked at the wrong offset has already absorbed the error, and BA fits the offset to
whatever else is wrong in the map (docs/decisions/0006-disparity-offset-self-calibration.md).
"""

import dataclasses
import time
from dataclasses import dataclass

import numpy as np

from pld_slam.config import Config, LinesConfig
from pld_slam.datasets.base import StereoSequence
from pld_slam.errors import DatasetError
from pld_slam.frontend import StereoFeatures, extract_stereo_features
from pld_slam.geometry.camera import StereoCamera
from pld_slam.matching.observations import point_observations
from pld_slam.matching.prior_free import PriorFreeOptions, match_without_prior, pnp_pose
from pld_slam.optim.observations import PointObservations
from pld_slam.optim.pose_only import PoseOnlyOptions, optimize_pose, optimize_pose_rejecting_outliers

PROFILE_STEP_PX = 0.05
"""Offset step [px] of the finite differences that give the profile's slope and curvature."""


@dataclass(frozen=True)
class PairMatches:
    """A frame pair's point matches between stereo points of both frames.

    Attributes
    ----------
    uv_first : (K, 2) left pixels of the points in the first frame.
    disparity_first : (K,) their disparities [px] (the camera's offset already removed).
    stereo_px_second, sigma_second : (K, 3) their ``(u_left, v, u_right)`` [px] in the second
        frame and the sigmas of those (`pld_slam.matching.observations.point_observations`).
    """

    uv_first: np.ndarray
    disparity_first: np.ndarray
    stereo_px_second: np.ndarray
    sigma_second: np.ndarray

    def __len__(self) -> int:
        return len(self.disparity_first)

    def subset(self, keep: np.ndarray) -> "PairMatches":
        """The matches ``keep`` (K,) bool."""
        return PairMatches(self.uv_first[keep], self.disparity_first[keep], self.stereo_px_second[keep],
                           self.sigma_second[keep])


@dataclass(frozen=True)
class GatedPair:
    """A frame pair's inlier matches at one offset, its relative pose ``T_second_first`` (4, 4)
    there, and the anchor (module docstring, step 1) it belongs to."""

    matches: PairMatches
    T_second_first: np.ndarray
    anchor: int


@dataclass(frozen=True)
class DisparityOffsetEstimate:
    """The outcome of `estimate_disparity_offset`.

    Attributes
    ----------
    offset_px : the change of the camera's disparity offset applied to the run [px]: the
        estimate, shrunk when ``calibration.prior_sigma_px`` is set (0 when not used).
    estimate_px : the profile's minimum [px], before any shrinking.
    sigma_px : its standard deviation [px] (inf when the profile has no curvature).
    used : whether ``offset_px`` is applied to the run's camera.
    reason : why not, when not used ("" when used).
    pairs, points : frame pairs and point matches the estimate rests on.
    frame_gap : frames between an anchor's frames (`frame_gap`).
    ms : wall time of the whole estimate [ms].
    """

    offset_px: float
    estimate_px: float
    sigma_px: float
    used: bool
    reason: str
    pairs: int
    points: int
    frame_gap: int
    ms: float

    def as_dict(self) -> dict:
        """The estimate as plain JSON values (`summary.json`)."""
        return dataclasses.asdict(self) | {"sigma_px": self.sigma_px if np.isfinite(self.sigma_px) else None}


def calibrated_camera(sequence: StereoSequence, config: Config) -> tuple[StereoCamera, DisparityOffsetEstimate | None]:
    """The camera a run uses: the sequence's, with the disparity offset estimated from its images
    when ``calibration.disparity_offset`` is on, and the estimate (None when off)."""
    if not config.calibration.disparity_offset:
        return sequence.camera, None
    estimate = estimate_disparity_offset(sequence, config)
    if not estimate.used:
        return sequence.camera, estimate
    camera = sequence.camera
    return dataclasses.replace(camera, disparity_offset=camera.disparity_offset + estimate.offset_px), estimate


def estimate_disparity_offset(sequence: StereoSequence, config: Config) -> DisparityOffsetEstimate:
    """The change of ``sequence.camera``'s disparity offset that best explains its frame pairs (module docstring)."""
    start = time.perf_counter()
    calibration, camera = config.calibration, sequence.camera
    features: dict[int, StereoFeatures] = {}
    gap = frame_gap(sequence, features, config)
    anchored_pairs = _anchored_pairs(len(sequence), calibration.anchors, gap)
    _add_features(features, sequence, [frame for pair in anchored_pairs for frame in pair[:2]], config)
    matches = [
        (anchor, found)
        for first, second, anchor in anchored_pairs
        if first in features and second in features
        and (found := pair_matches(features[first], features[second], config)) is not None
    ]
    offset, sigma, pairs = 0.0, np.inf, []
    pose_options = pair_pose_options(config)
    for _ in range(calibration.gating_rounds):
        gated = (gate_pair(camera, found, anchor, offset, config) for anchor, found in matches)
        pairs = [pair for pair in gated if pair is not None]
        if _anchors_of(pairs) < calibration.min_anchors:
            break
        previous = offset
        offset, sigma = profile_minimum(camera, pairs, offset, calibration.max_offset_px, pose_options)
        if abs(offset - previous) < calibration.gating_tolerance_px:
            break

    def finish(reason: str) -> DisparityOffsetEstimate:
        used = not reason
        applied = posterior_mean(offset, sigma, calibration.prior_sigma_px) if used else 0.0
        return DisparityOffsetEstimate(applied, offset, sigma, used, reason, len(pairs),
                                       sum(len(pair.matches) for pair in pairs), gap,
                                       1e3 * (time.perf_counter() - start))

    bound = calibration.max_offset_px
    if _anchors_of(pairs) < calibration.min_anchors:
        return finish(f"{_anchors_of(pairs)} anchors with a pair pose, fewer than {calibration.min_anchors}")
    if abs(offset) >= bound:
        return finish(f"the best offset {offset:+.3f} px is at the search bound +-{bound:g} px")
    if not sigma <= calibration.max_sigma_px:
        return finish(f"offset {offset:+.3f} px is uncertain (sigma {sigma:.3f} px, more than "
                      f"{calibration.max_sigma_px:g})")
    if abs(offset) < calibration.min_significance * sigma:
        return finish(f"offset {offset:+.3f} px is within {calibration.min_significance:g} sigma ({sigma:.3f} px) "
                      "of zero")
    return finish("")


def posterior_mean(estimate: float, sigma: float, prior_sigma: float) -> float:
    """The offset [px] to apply for ``estimate`` +- ``sigma`` [px]: shrunk towards 0 for a prior
    N(0, ``prior_sigma``**2), as it is for ``prior_sigma`` 0 (no prior: module docstring, step 5)."""
    if prior_sigma == 0.0:
        return estimate
    return estimate * prior_sigma**2 / (prior_sigma**2 + sigma**2)


def frame_gap(sequence: StereoSequence, features: dict[int, StereoFeatures], config: Config) -> int:
    """The gap [frames] between an anchor's frames (module docstring, step 1).

    ``calibration.min_anchors`` probe pairs of consecutive frames, spread over the sequence,
    give the camera's median motion per frame (their PnP poses' translations, in stereo
    baselines); the gap is ``calibration.pair_motion_baselines`` over it, rounded, at least
    ``calibration.min_frame_gap``, at most ``calibration.max_frame_gap`` and small enough
    that ``min_anchors`` anchors fit in the sequence (a sequence too short for them at the
    smallest gap gets the smallest gap, and too few anchors: no estimate). The probes'
    features are added to ``features``.
    """
    calibration = config.calibration
    lowest = calibration.min_frame_gap
    most = max(lowest, min(calibration.max_frame_gap, (len(sequence) // calibration.min_anchors - 1) // 2))
    if most == lowest or calibration.pair_motion_baselines == 0.0:
        return lowest
    starts = np.rint(np.linspace(0, len(sequence) - 2, calibration.min_anchors)).astype(int).tolist()
    _add_features(features, sequence, [frame for start in starts for frame in (start, start + 1)], config)
    motion = []
    for start in starts:
        if not {start, start + 1} <= features.keys():
            continue
        found = pair_matches(features[start], features[start + 1], config)
        gated = None if found is None else gate_pair(sequence.camera, found, 0, 0.0, config)
        if gated is not None:
            motion.append(np.linalg.norm(gated.T_second_first[:3, 3]) / sequence.camera.baseline)
    if not motion or np.median(motion) == 0.0:
        return most
    return int(np.clip(round(calibration.pair_motion_baselines / np.median(motion)), lowest, most))


def _anchored_pairs(n_frames: int, anchors: int, gap: int) -> list[tuple[int, int, int]]:
    """Frame pairs ``(first, second, anchor)``: up to ``anchors`` anchors spread over
    ``n_frames`` frames, each anchor ``a`` with frames ``a + gap`` and ``a + 2 gap``, paired
    (a, a + gap), (a + gap, a + 2 gap) and (a, a + 2 gap). No two anchors share a frame
    (a short sequence gets fewer anchors), so that their own minima are independent
    estimates (`_spread_over_anchors`)."""
    span = 2 * gap + 1
    count = min(anchors, n_frames // span)
    if count == 0:
        return []
    starts = np.rint(np.linspace(0, n_frames - span, count)).astype(int) if count > 1 else np.array([0])
    return [
        (start + first * gap, start + second * gap, anchor)
        for anchor, start in enumerate(starts.tolist())
        for first, second in ((0, 1), (1, 2), (0, 2))
    ]


def _anchors_of(pairs: list[GatedPair]) -> int:
    """How many anchors the pairs come from."""
    return len({pair.anchor for pair in pairs})


def _add_features(features: dict[int, StereoFeatures], sequence: StereoSequence, frames: list[int],
                  config: Config) -> None:
    """Add to ``features`` the stereo points (no lines) of the readable frames among ``frames``
    it does not hold yet, by index."""
    points_only = LinesConfig(enabled=False)
    for index in sorted(set(frames) - features.keys()):
        try:
            frame = sequence[index]
        except DatasetError:
            continue
        features[index] = extract_stereo_features(frame.left, frame.right, sequence.camera, config.points, points_only)


def pair_pose_options(config: Config) -> PoseOnlyOptions:
    """The pose-only solves of a frame pair: ``calibration.pair_pose_rounds`` rounds, the first
    ``calibration.pair_pose_robust_rounds`` robust, each within ``tracking.pose_max_nfev`` evaluations and
    stopping at ``tracking.pose_cost_tolerance``."""
    return dataclasses.replace(PoseOnlyOptions.of(config), rounds=config.calibration.pair_pose_rounds,
                               robust_rounds=config.calibration.pair_pose_robust_rounds)


def pair_matches(first: StereoFeatures, second: StereoFeatures, config: Config) -> PairMatches | None:
    """The stereo points of ``first`` matched by descriptor to stereo points of ``second``
    (`match_without_prior`); None with fewer than ``tracking.pnp_min_inliers``."""
    prior_free = PriorFreeOptions.of(config)
    found = match_without_prior(second.keypoints, first.points.descriptors, prior_free)
    stereo = found.current < second.keypoints.n_stereo
    before, after = found.previous[stereo], found.current[stereo]
    if len(before) < prior_free.min_inliers:
        return None
    observed = point_observations(np.zeros((len(after), 3)), second.keypoints, after, config.points)
    return PairMatches(first.points.uv[before], first.points.disparity[before], observed.stereo_px, observed.sigma_px)


def observations_at(camera: StereoCamera, matches: PairMatches, delta: float) -> PointObservations:
    """The second frame's observations of the first frame's points, at offset change ``delta`` [px].

    ``delta`` is added to every measured disparity offset: the first frame's points are
    triangulated from ``d - delta`` (in the first camera's frame, the "world" of the pair),
    the second frame's right columns move by ``+delta``.
    """
    return PointObservations(
        camera.triangulate(matches.uv_first, matches.disparity_first - delta),
        matches.stereo_px_second + np.array([0.0, 0.0, delta]),
        matches.sigma_second,
    )


def gate_pair(
    camera: StereoCamera, matches: PairMatches, anchor: int, delta: float, config: Config
) -> GatedPair | None:
    """The pair's relative pose and inliers at offset change ``delta`` (module docstring, step 2),
    or None when PnP or the pose-only solve fails."""
    observations = observations_at(camera, matches, delta)
    prior_free = PriorFreeOptions.of(config)
    pose = pnp_pose(camera, observations.points_w, observations.stereo_px[:, :2], prior_free)
    if pose is None:
        return None
    refined = optimize_pose_rejecting_outliers(camera, pose.T_c_w, observations, options=pair_pose_options(config))
    inliers = refined.inliers.points
    if not refined.success or inliers.sum() < prior_free.min_inliers:
        return None
    return GatedPair(matches.subset(inliers), refined.T_c_w, anchor)


def pair_cost(camera: StereoCamera, pair: GatedPair, delta: float, options: PoseOnlyOptions) -> float:
    """Half the sum of the pair's squared whitened errors, its pose re-solved (``options``) at offset change
    ``delta`` [px]."""
    solved = optimize_pose(camera, pair.T_second_first, observations_at(camera, pair.matches, delta), options=options,
                           robust=False)
    return 0.5 * float(solved.point_chi2.sum())


def profile_costs(camera: StereoCamera, pairs: list[GatedPair], delta: float, options: PoseOnlyOptions) -> np.ndarray:
    """`pair_cost` (P,) of every pair at offset change ``delta`` [px]; their sum is the profile cost."""
    return np.array([pair_cost(camera, pair, delta, options) for pair in pairs])


def profile_minimum(
    camera: StereoCamera, pairs: list[GatedPair], centre: float, bound: float, options: PoseOnlyOptions
) -> tuple[float, float]:
    """The offset change [px] at the profile's minimum, by one Newton step from ``centre``
    within ``[-bound, bound]``, and its standard deviation [px] (module docstring, step 4).

    The profile's slope and curvature come from three costs `PROFILE_STEP_PX` apart. A
    profile without positive curvature (no information: a camera that does not move)
    stays at ``centre``, with an infinite deviation.
    """
    step = PROFILE_STEP_PX
    below, cost, above = (profile_costs(camera, pairs, centre + k * step, options) for k in (-1, 0, 1))
    anchor = np.array([pair.anchor for pair in pairs])
    by_anchor = [np.bincount(anchor, weights=costs) for costs in (below, cost, above)]
    slope = (by_anchor[2] - by_anchor[0]) / (2.0 * step)
    curvature = (by_anchor[2] - 2.0 * by_anchor[1] + by_anchor[0]) / step**2
    if curvature.sum() <= 0:
        return centre, np.inf
    offset = centre - slope.sum() / curvature.sum()
    minimum_cost = cost.sum() - slope.sum() ** 2 / (2.0 * curvature.sum())
    n_rows = 3 * sum(len(pair.matches) for pair in pairs)
    residual_variance = max(2.0 * minimum_cost / max(n_rows - 6 * len(pairs) - 1, 1), 1.0)
    sigma = max(np.sqrt(residual_variance / curvature.sum()), _spread_over_anchors(centre, slope, curvature, offset))
    return float(np.clip(offset, -bound, bound)), float(sigma)


def _spread_over_anchors(centre: float, slope: np.ndarray, curvature: np.ndarray, offset: float) -> float:
    """The standard error [px] of ``offset`` from the spread of the anchors' own minima.

    Each anchor's Newton step ``centre - slope_a / curvature_a`` is an estimate of its own;
    the curvature-weighted standard error of their mean about ``offset`` holds whatever
    the residual model misses (step 4). 0 with fewer than two anchors of positive curvature.
    """
    informative = curvature > 0
    if informative.sum() < 2:
        return 0.0
    weight = curvature[informative]
    own = centre - slope[informative] / weight
    return float(np.sqrt((weight * (own - offset) ** 2).sum() / ((informative.sum() - 1) * weight.sum())))
