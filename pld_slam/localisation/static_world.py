"""Which coherent motion is the static world's: the detectors' check of the robust solve.

Both detectors (`pld_slam.tracking.dynamic`) judge each feature against the pose the
robust solve fitted to the frame, and a robust solve follows the largest coherent group of
matches, or a compromise between two: the Huber loss does not let go of a large group that
disagrees. Where movers are a small minority that is the static world, and the detectors
find the movers. Where they are not, it is not: a bus alongside and a truck ahead driving
at our speed (synthetic ``convoy``, 30-40 % of the image) say "the camera stands still",
the fitted pose follows them, and the detectors then mark the static world as moving
(docs/decisions/0015-static-world-check.md). The paper's detectors take the motion model
as their reference; we make that explicit here, as a check between the robust solve and
the detectors (on whenever a detector is):

1. When. With a trusted motion model (below), the robust solve lies outside the model's
   expected error; without one, it left at least ``dynamic.rival_min_share`` (15 %) of the
   matches as outliers. Otherwise the solve stands, at no cost; it also stands when the
   static world's motion found below lies within the expected error of it. (Testing the
   outlier share with a trusted model too runs the check, and its re-solve, on nearly
   every frame of a busy street for little gain; the budget is at most 5 ms for both
   detectors: docs/decisions/0015-static-world-check.md.)
2. The paper says the motion model tells static from dynamic; it does not say what to do
   when a large part of the image disagrees with it, nor when there is none. We decide:
   with a motion model that can be trusted (the previous frame was tracked normally, and
   this frame's guided search found its matches where the model predicted them), the
   static world moves as predicted: the prediction, refined by least squares on the point
   matches that pass the pose solve's chi-square test at it (`predicted_motion`), is the
   static world's motion when at least ``tracking.min_inliers`` and the share above agree
   with it. (The refinement may move it by more than the expected error below: the
   prediction carries the last frame's estimation noise where movers hide most of the
   scene, and refusing such a refinement lets the movers' pull stand and become the next
   prediction.) The model's expected error
   is ``dynamic.motion_prior_m`` (5 cm) and ``dynamic.motion_prior_deg`` (0.5 deg) per
   frame, distances in those units, the larger of the two (`motion_model_distance`); a
   robust solve outside it is suspect (step 1). At 10 Hz that is the error of a
   constant-velocity prediction (``a dt^2``) of a vehicle braking at 5 m/s^2 or changing
   its rate of turn by 50 deg/s^2; at EuRoC's 20 Hz it allows four times that. It must be
   tight: a looser bound let a crossing crowd pull the solve of a stopped camera along
   with it (docs/decisions/0015-static-world-check.md). Far points cannot tell such motions apart, so the prediction is
   tested directly rather than searched for.
3. Without a trusted motion model (the second frame of a run, which has none; after a
   lost or recovered frame; a prediction too few matches agree with): sequential RANSAC
   over the stereo point matches finds the coherent motions (`coherent_motions`): rigid
   motions from three 3D-3D pairs (the reference point, the current stereo point;
   `rigid_motions`), scored by the pose solve's chi-square test (`stereo_point_chi2`), the
   best refined on its inliers; the same on the matches it leaves gives the second. Of two
   with that support, the one that looks like the background is the static world's: its
   inlier points lie farther, by median depth (`background_motion`). Movers that fill the
   view are near: a bus alongside is 2-10 m away, a crowd crossing 4-8 m; the road and the
   facades behind them reach 10-60 m. With fewer than two, a static scene's outliers
   (mismatches, a few movers), nothing is decided and the robust solve stands.
4. The frame is solved again (the robust solve with its rejection rounds) from the static
   world's motion, on its inlier points and the lines that pass their test at it. The
   detectors then judge every feature against that pose; the points that the robust solve
   (or another coherent motion) took and the static world's motion rejects are dynamic
   too: they are what pulled the solve away; unmarked, they become landmarks, and the
   local map they fill takes the camera along with the movers. When the static world itself exceeds the
   expected error (harder braking, a noisy velocity), the frame only pays for the RANSAC.

RANSAC draws ``dynamic.static_world_hypotheses`` (200) triples per motion: at least one lies
wholly in a group of a quarter of the matches with probability 1 - (1 - 0.25**3)**200 = 0.96,
of a third 0.9995. It draws from a generator seeded with ``system.seed``: the same input gives
the same labels.
"""

from dataclasses import dataclass

import numpy as np

from pld_slam.config import Config
from pld_slam.geometry.camera import StereoCamera
from pld_slam.geometry.se3 import inverse, motion_size, transform_points
from pld_slam.optim.observations import (
    LineObservations,
    ObservationMasks,
    PointObservations,
    WhitenedRows,
    chi2_inliers,
)
from pld_slam.optim.pose_only import (
    PoseOnlyOptions,
    PoseOnlyResult,
    optimize_pose,
    optimize_pose_rejecting_outliers,
)


@dataclass(frozen=True)
class StaticWorldOptions:
    """What the static-world check reads of the configuration.

    min_inliers : inliers any candidate motion needs (``tracking.min_inliers``).
    rival_min_share : share of the matches a robust solve must reject to be suspect, and a
        coherent motion must hold to be a candidate (``dynamic.rival_min_share``).
    motion_prior_m, motion_prior_deg : the motion model's expected error, the units of
        `motion_model_distance` (``dynamic.motion_prior_m``, ``dynamic.motion_prior_deg``).
    seed : seed of the RANSAC hypotheses (``system.seed``).
    hypotheses : RANSAC hypotheses per motion (``dynamic.static_world_hypotheses``).
    """

    min_inliers: int
    rival_min_share: float
    motion_prior_m: float
    motion_prior_deg: float
    seed: int
    hypotheses: int

    @classmethod
    def of(cls, config: Config) -> "StaticWorldOptions":
        return cls(config.tracking.min_inliers, config.dynamic.rival_min_share, config.dynamic.motion_prior_m,
                   config.dynamic.motion_prior_deg, config.system.seed, config.dynamic.static_world_hypotheses)


@dataclass(frozen=True)
class Motion:
    """A coherent motion of point matches: ``T_c_r`` (4, 4) and its inlier points (N,) bool."""

    T_c_r: np.ndarray
    inliers: np.ndarray

    @property
    def support(self) -> int:
        return int(np.count_nonzero(self.inliers))


def rigid_motions(points_r: np.ndarray, points_c: np.ndarray) -> np.ndarray:
    """The rigid motions ``T_c_r`` (H, 4, 4) best mapping H sets of points (H, S, 3) of the
    reference camera onto their positions (H, S, 3) in the current one (Kabsch, least squares)."""
    centre_r, centre_c = points_r.mean(axis=1), points_c.mean(axis=1)
    covariance = np.einsum("hsi,hsj->hij", points_c - centre_c[:, None], points_r - centre_r[:, None])
    u, _, vt = np.linalg.svd(covariance)
    flip = np.sign(np.linalg.det(u @ vt))
    u[:, :, 2] *= flip[:, None]
    rotation = u @ vt
    motions = np.tile(np.eye(4), (len(points_r), 1, 1))
    motions[:, :3, :3] = rotation
    motions[:, :3, 3] = centre_c - np.einsum("hij,hj->hi", rotation, centre_r)
    return motions


def stereo_point_chi2(camera: StereoCamera, motions: np.ndarray, points: PointObservations,
                      options: PoseOnlyOptions) -> tuple[np.ndarray, np.ndarray]:
    """Chi-square (H, N) of every point observation under each of the motions (H, 4, 4), and
    whether it passes the pose solve's bound (H, N) bool: the residual of the pose solve
    (`pld_slam.optim.observations.WhitenedRows`), evaluated for all motions at once."""
    n_motions, n_points = len(motions), len(points.sigma_px)
    tiled = PointObservations(np.tile(points.points_w, (n_motions, 1)), np.tile(points.stereo_px, (n_motions, 1)),
                              np.tile(points.sigma_px, (n_motions,) + (1,) * (points.sigma_px.ndim - 1)))
    rows = WhitenedRows.of(tiled, LineObservations.empty(), LineObservations.empty())
    evaluation = rows.evaluate(camera, motions, np.eye(4), options.min_depth,
                               point_pose=np.repeat(np.arange(n_motions), n_points))
    chi2, _, _ = rows.chi2(evaluation)
    passed = rows.point_inliers(chi2, options.chi2_point, options.chi2_monocular_point)
    return chi2.reshape(n_motions, n_points), passed.reshape(n_motions, n_points)


def refined_motion(camera: StereoCamera, T_c_r: np.ndarray, points: PointObservations, among: np.ndarray,
                   options: PoseOnlyOptions) -> Motion:
    """The motion ``T_c_r`` (4, 4) refined by a least-squares solve on its inlier points
    ``among`` the matches (N,) bool, with its inliers among them at the refined pose."""
    _, passed = stereo_point_chi2(camera, T_c_r[None], points, options)
    include = ObservationMasks(passed[0] & among, np.zeros(0, dtype=bool), np.zeros(0, dtype=bool))
    refined = optimize_pose(camera, T_c_r, points=points, options=options, include=include, robust=False)
    if refined.success:
        T_c_r = refined.T_c_w
    _, passed = stereo_point_chi2(camera, T_c_r[None], points, options)
    return Motion(T_c_r, passed[0] & among)


def dominant_motion(camera: StereoCamera, points: PointObservations, among: np.ndarray, rng: np.random.Generator,
                    options: PoseOnlyOptions, hypotheses: int) -> Motion | None:
    """The motion with the most inliers ``among`` the point matches (N,) bool (module docstring,
    step 3) of ``hypotheses`` RANSAC triples, refined on them; None with fewer than three stereo matches."""
    stereo = among & np.isfinite(points.stereo_px[:, 2]) & (points.stereo_px[:, 0] - points.stereo_px[:, 2] > 0.0)
    candidates = np.flatnonzero(stereo)
    if len(candidates) < 3:
        return None
    triples = candidates[np.argsort(rng.random((hypotheses, len(candidates))), axis=1)[:, :3]]
    current = points.stereo_px[triples.ravel()]
    points_c = camera.triangulate(current[:, :2], current[:, 0] - current[:, 2]).reshape(hypotheses, 3, 3)
    hypotheses = rigid_motions(points.points_w[triples], points_c)
    _, passed = stereo_point_chi2(camera, hypotheses, points, options)
    best = int(np.argmax((passed & among).sum(axis=1)))
    return refined_motion(camera, hypotheses[best], points, among, options)


def least_support(n_matches: int, options: StaticWorldOptions) -> float:
    """Inliers a motion needs to be a candidate for the static world's: ``min_inliers`` and
    ``rival_min_share`` of the ``n_matches`` (points and lines)."""
    return max(options.min_inliers, options.rival_min_share * n_matches)


def coherent_motions(camera: StereoCamera, points: PointObservations, n_matches: int, options: PoseOnlyOptions,
                     world: StaticWorldOptions) -> list[Motion]:
    """The (up to) two largest coherent motions of the point matches with `least_support`,
    the larger first (module docstring, step 3)."""
    rng = np.random.default_rng(world.seed)
    motions: list[Motion] = []
    remaining = np.ones(len(points.sigma_px), dtype=bool)
    while len(motions) < 2:
        motion = dominant_motion(camera, points, remaining, rng, options, world.hypotheses)
        if motion is None or motion.support < least_support(n_matches, world):
            break
        motions.append(motion)
        remaining &= ~motion.inliers
    return motions


def motion_model_distance(T_c_r: np.ndarray, T_c_r_predicted: np.ndarray, world: StaticWorldOptions) -> float:
    """How far a motion lies from the prediction, in units of the model's expected error
    (module docstring): the larger of translation / ``motion_prior_m`` and rotation /
    ``motion_prior_deg`` of ``T_c_r @ inverse(T_c_r_predicted)``."""
    translation, rotation = motion_size(T_c_r @ inverse(T_c_r_predicted))
    return max(translation / world.motion_prior_m, rotation / world.motion_prior_deg)


def predicted_motion(camera: StereoCamera, T_c_r_predicted: np.ndarray, points: PointObservations, n_matches: int,
                     options: PoseOnlyOptions, world: StaticWorldOptions) -> Motion | None:
    """The motion model's prediction refined on the matches that agree with it, where it keeps
    `least_support`; else None (step 2)."""
    everything = np.ones(len(points.sigma_px), dtype=bool)
    motion = refined_motion(camera, T_c_r_predicted, points, everything, options)
    return motion if motion.support >= least_support(n_matches, world) else None


def median_inlier_depth(motion: Motion, points: PointObservations) -> float:
    """Median depth [m] in the current camera of a motion's inlier points."""
    return float(np.median(transform_points(motion.T_c_r, points.points_w[motion.inliers])[:, 2]))


def background_motion(motions: list[Motion], points: PointObservations) -> Motion | None:
    """Of two motions the one whose inlier points lie farther (step 3); None for fewer."""
    if len(motions) < 2:
        return None
    return motions[int(np.argmax([median_inlier_depth(m, points) for m in motions]))]


def line_inliers_at(camera: StereoCamera, T_c_r: np.ndarray, lines: LineObservations,
                    options: PoseOnlyOptions) -> np.ndarray:
    """Whether each line observation (M,) passes the pose solve's test at ``T_c_r`` (`chi2_inliers`)."""
    rows = WhitenedRows.of(PointObservations.empty(), lines, lines)
    chi2 = rows.chi2(rows.evaluate(camera, T_c_r, T_c_r, options.min_depth))
    return chi2_inliers(rows, *chi2, lines.horizontal_eligible, options).lines


def outlier_count(solution: PoseOnlyResult) -> int:
    """Point and line observations a solve rejected."""
    return int(np.count_nonzero(~solution.inliers.points) + np.count_nonzero(~solution.inliers.lines))


@dataclass(frozen=True)
class StaticWorld:
    """A frame's solve for the static world: ``solution`` and the point matches (N,) bool found
    ``moving``: those the robust solve or another coherent motion took, that the static
    world's motion rejects."""

    solution: PoseOnlyResult
    moving: np.ndarray


def static_world_solution(
    camera: StereoCamera,
    solution: PoseOnlyResult,
    T_c_r_predicted: np.ndarray,
    points: PointObservations,
    lines: LineObservations,
    prior_trusted: bool,
    options: PoseOnlyOptions,
    world: StaticWorldOptions,
) -> StaticWorld:
    """The robust ``solution`` of a frame (fitted to ``points`` and ``lines``, started from the
    motion model's ``T_c_r_predicted``), or the frame solved again for the static world's
    motion where the solve is suspect and that motion can be told (module docstring)."""
    unchanged = StaticWorld(solution, np.zeros(len(points.sigma_px), dtype=bool))
    n_matches = len(points.sigma_px) + len(lines.sigma_px)
    if prior_trusted:
        suspect = motion_model_distance(solution.T_c_w, T_c_r_predicted, world) > 1.0
    else:
        suspect = outlier_count(solution) >= world.rival_min_share * n_matches
    if not suspect:
        return unchanged
    motions = []
    static = predicted_motion(camera, T_c_r_predicted, points, n_matches, options, world) if prior_trusted else None
    if static is None:
        motions = coherent_motions(camera, points, n_matches, options, world)
        static = background_motion(motions, points)
    if static is None or motion_model_distance(static.T_c_r, solution.T_c_w, world) <= 1.0:
        return unchanged
    static_lines = line_inliers_at(camera, static.T_c_r, lines, options)
    within = ObservationMasks(static.inliers, static_lines, static_lines)
    resolved = optimize_pose_rejecting_outliers(camera, static.T_c_r, points, lines, options, within=within)
    if not resolved.success:
        return unchanged
    pulled = solution.inliers.points.copy()
    for motion in motions:
        pulled |= motion.inliers
    return StaticWorld(resolved, pulled & ~resolved.inliers.points)
