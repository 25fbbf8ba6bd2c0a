"""Bundle adjustment of a set of the map's keyframes and the landmarks they observe.

`adjust_keyframes` is shared by local BA (`pld_slam.mapping.local_ba`: a new keyframe's
window) and global BA (`pld_slam.mapping.global_ba`: every keyframe): the given
keyframes are free with the landmarks they observe; every other keyframe that observes
those landmarks is held fixed. What it decides:

- Landmarks seen by a single keyframe are left out: an observation of a landmark no
  other keyframe sees can always be fitted exactly by moving the landmark, so it adds
  nothing to the poses, only unknowns to the solve.
- Gauge: the first keyframe (the root of the spanning tree, the world frame) is always
  held fixed, as ORB-SLAM2 does; when it is not in the problem and no keyframe outside
  the free set observes its landmarks, the free keyframe with the lowest id is held fixed
  instead. (Once a loop joins the end of a run to its start, the first keyframe enters
  the windows of new keyframes; left free, local BA moved it, and with it the start of
  the trajectory; see docs/decisions/0021-loop-correction.md.)
- Residuals, loss and rounds are those of `pld_slam.optim.bundle_adjustment`: point
  stereo reprojection, line vertical and horizontal errors of both endpoints in every
  observing keyframe, weighted by their inverse covariances, Huber loss, then a plain
  round without the outliers.

Afterwards the poses and landmarks go back into the map, and the observations failing
their chi-square test at the result are erased from it (a landmark left without
observers dies).
"""

import time
from dataclasses import dataclass

import numpy as np

from pld_slam.config import Config
from pld_slam.geometry.camera import StereoCamera
from pld_slam.mapping.landmarks import Landmarks
from pld_slam.mapping.map import Map
from pld_slam.optim.bundle_adjustment import (
    TO_CONVERGENCE,
    BundleLineObservations,
    BundleOptions,
    BundlePointObservations,
    BundleProblem,
    bundle_adjust,
)
from pld_slam.optim.line_reprojection import endpoints_away_from_border


@dataclass(frozen=True)
class MapBaOptions:
    """What a bundle adjustment of the map reads of the configuration.

    scale_factor : ORB pyramid scale (``points.scale_factor``): a point's sigmas grow with its octave.
    disparity_sigma_px : a disparity's sigma at octave 0 (``points.disparity_sigma_px``).
    line_sigma_px : a line endpoint's sigma (``tracking.line_sigma_px``).
    border_margin_px : endpoints this near the border take no horizontal term (``tracking.border_margin_px``).
    use_line_vertical, use_line_horizontal : the two line terms (``lines.vertical_error``, ``lines.horizontal_error``).
    ftol, lsmr_max_iterations : where a solve stops, and the LSMR iterations of its steps, when it
        refines (``mapping.ba_cost_tolerance``, ``mapping.ba_lsmr_iterations``).
    """

    scale_factor: float
    disparity_sigma_px: float
    line_sigma_px: float
    border_margin_px: float
    use_line_vertical: bool
    use_line_horizontal: bool
    ftol: float
    lsmr_max_iterations: int

    @classmethod
    def of(cls, config: Config) -> "MapBaOptions":
        return cls(config.points.scale_factor, config.points.disparity_sigma_px, config.tracking.line_sigma_px,
                   config.tracking.border_margin_px, config.lines.vertical_error, config.lines.horizontal_error,
                   config.mapping.ba_cost_tolerance, config.mapping.ba_lsmr_iterations)


@dataclass(frozen=True)
class BaReport:
    """What one bundle adjustment of the map did.

    Attributes
    ----------
    free_keyframes, fixed_keyframes : keyframes optimised and held fixed.
    points, lines : landmarks optimised.
    observations : point and line observations in the problem.
    removed_observations : observations erased as outliers afterwards.
    nfev : residual evaluations.
    initial_cost, final_cost : cost of the final inliers before and after [whitened units].
    ms : wall time [ms], building the problem and writing back included.
    """

    free_keyframes: int
    fixed_keyframes: int
    points: int
    lines: int
    observations: int
    removed_observations: int
    nfev: int
    initial_cost: float
    final_cost: float
    ms: float


@dataclass(frozen=True)
class _Observations:
    """The observations of one landmark kind in the window: landmark row, keyframe id, feature index (M,)."""

    row: np.ndarray
    keyframe: np.ndarray
    feature: np.ndarray


def adjust_keyframes(
    world_map: Map, free: list[int], camera: StereoCamera, options: MapBaOptions, max_nfev: int,
    to_convergence: bool = False,
) -> BaReport | None:
    """Bundle-adjust keyframes ``free`` (ids) and their landmarks, write the result into ``world_map``
    (module docstring); None with nothing to adjust. ``max_nfev``: evaluations per solve;
    ``to_convergence``: solve with `pld_slam.optim.bundle_adjustment.TO_CONVERGENCE`
    instead of refining as local BA does (``options.ftol``, ``options.lsmr_max_iterations``)."""
    start = time.perf_counter()
    point_ids = _landmarks_of(world_map, world_map.points, free)
    line_ids = _landmarks_of(world_map, world_map.lines, free)
    points = _observations(world_map, world_map.points, point_ids)
    lines = _observations(world_map, world_map.lines, line_ids)
    keyframes = np.unique(np.concatenate([free, points.keyframe, lines.keyframe])).astype(np.int64)
    fixed = ~np.isin(keyframes, free) | (keyframes == world_map.covisibility.root)
    if not fixed.any():
        fixed[np.argmin(keyframes)] = True
    if len(points.row) + len(lines.row) == 0 or fixed.all():
        return None
    problem = BundleProblem(
        T_c_w=np.array([world_map.keyframes[k].T_c_w for k in keyframes.tolist()]),
        fixed=fixed,
        points_w=world_map.points.geometry[point_ids],
        lines_w=world_map.lines.geometry[line_ids],
        point_observations=_point_observations(world_map, points, keyframes, options),
        line_observations=_line_observations(world_map, lines, keyframes, camera, options),
    )
    refine = dict(ftol=options.ftol, lsmr_max_iterations=options.lsmr_max_iterations)
    solve = BundleOptions(
        use_line_vertical=options.use_line_vertical,
        use_line_horizontal=options.use_line_horizontal,
        max_nfev=max_nfev,
        **(TO_CONVERGENCE if to_convergence else refine),
    )
    result = bundle_adjust(camera, problem, solve)
    world_map.set_keyframe_poses(keyframes[~fixed], result.T_c_w[~fixed])
    world_map.set_landmark_geometry(world_map.points, point_ids, result.points_w)
    world_map.set_landmark_geometry(world_map.lines, line_ids, result.lines_w)
    removed = _erase(world_map, world_map.points, points, ~result.inliers.points)
    removed += _erase(world_map, world_map.lines, lines, ~result.inliers.lines)
    return BaReport(
        free_keyframes=int(np.count_nonzero(~fixed)),
        fixed_keyframes=int(np.count_nonzero(fixed)),
        points=len(point_ids),
        lines=len(line_ids),
        observations=len(points.row) + len(lines.row),
        removed_observations=removed,
        nfev=result.nfev,
        initial_cost=result.initial_cost,
        final_cost=result.final_cost,
        ms=1e3 * (time.perf_counter() - start),
    )


def _landmarks_of(world_map: Map, kind: Landmarks, keyframes: list[int]) -> np.ndarray:
    """Live landmarks (K,) of ``kind`` observed by ``keyframes`` and by at least two keyframes in all, ascending."""
    live = kind.observed_by(world_map.keyframes[k] for k in keyframes)
    return live[kind.n_observers[live] >= 2]


def _observations(world_map: Map, kind: Landmarks, landmarks: np.ndarray) -> _Observations:
    return _Observations(*world_map.observation_table(kind, landmarks))


def _point_observations(
    world_map: Map, observed: _Observations, keyframes: np.ndarray, options: MapBaOptions
) -> BundlePointObservations:
    kind = world_map.points
    uv = world_map.feature_attribute(kind, "uv", observed.keyframe, observed.feature)
    u_right = world_map.feature_attribute(kind, "u_right", observed.keyframe, observed.feature)
    octave = world_map.feature_attribute(kind, "octave", observed.keyframe, observed.feature)
    octave_sigma = options.scale_factor ** octave.astype(np.float64)
    return BundlePointObservations(
        keyframe=np.searchsorted(keyframes, observed.keyframe),
        point=observed.row,
        stereo_px=np.column_stack([uv, u_right]),
        sigma_px=np.column_stack([octave_sigma, octave_sigma, options.disparity_sigma_px * octave_sigma]),
    )


def _line_observations(
    world_map: Map, observed: _Observations, keyframes: np.ndarray, camera: StereoCamera, options: MapBaOptions
) -> BundleLineObservations:
    endpoints = world_map.feature_attribute(world_map.lines, "endpoints", observed.keyframe, observed.feature)
    disparity = world_map.feature_attribute(world_map.lines, "disparity", observed.keyframe, observed.feature)
    start_px, end_px = endpoints[:, :2], endpoints[:, 2:]
    return BundleLineObservations(
        keyframe=np.searchsorted(keyframes, observed.keyframe),
        line=observed.row,
        start_px=start_px,
        end_px=end_px,
        sigma_px=np.full(len(observed.row), options.line_sigma_px),
        horizontal_eligible=endpoints_away_from_border(camera, start_px, end_px, options.border_margin_px),
        right_start_px=start_px - np.column_stack([disparity[:, 0], np.zeros(len(disparity))]),
        right_end_px=end_px - np.column_stack([disparity[:, 1], np.zeros(len(disparity))]),
    )


def _erase(world_map: Map, kind: Landmarks, observed: _Observations, outlier: np.ndarray) -> int:
    """Erase the outlier observations (M,) bool from the map; returns how many."""
    for keyframe_id in np.unique(observed.keyframe[outlier]).tolist():
        at = outlier & (observed.keyframe == keyframe_id)
        world_map.erase_observations(kind, world_map.keyframes[keyframe_id], observed.feature[at])
    return int(np.count_nonzero(outlier))
