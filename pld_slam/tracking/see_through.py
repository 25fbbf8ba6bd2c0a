"""Point landmarks the stereo pair sees through: a farther surface shows where the landmark should be.

A parked car that pulls out leaves its landmarks in the map. Most of them die through
`pld_slam.localisation.local_map.missed_near_movers`: the car, labelled dynamic, still
stands at their depth. What that rule cannot see is a landmark with nothing moving at its
depth any more: the car has driven on, or the landmark was never on a surface at all (a
corner of the car's outline against the background, triangulated a few metres in front
of the car). The frame's own images can: at the landmark's projection the left window
should match the right image at the landmark's disparity; if it matches clearly better
at a *smaller* disparity, the camera sees a farther surface through the place where the
landmark should stand, so the landmark is not there (free-space evidence, as dense
mapping carves space with it). Something nearer in front of a landmark (a truck, a
pedestrian) makes the best disparity *larger*: that is an occlusion, and no evidence.

`landmarks_seen_through` tests every point landmark of the local map the frame's solve did
not find, in front of the camera and inside the image: the mean-free SAD of a window of
``mapping.see_through_half_window`` (7 x 7 px at full resolution) against the right image
at every disparity from 0 to ``mapping.see_through_reach`` (3) times the predicted one.
Seen through: the best disparity lies farther than the landmark by more than
``mapping.see_through_depth_tolerance`` (10 %) of its depth and
``mapping.see_through_margin_px`` (1 px), and its cost is at most
``mapping.see_through_match_ratio`` (0.5) times both the cost at the prediction (plus or
minus a pixel) and the window's own contrast (its SAD to a flat window). The second bound
asks for a real match: a surface seen through matches to the noise, while a window on an
occluder nearer than the search reaches matches nowhere and its best shift is chance. Flat
windows match everywhere alike and give no evidence. The ids go, with those under movers,
into local mapping's dynamic streak (`pld_slam.mapping.local_mapping`, step 2), which
removes a landmark after ``mapping.dynamic_streak`` (2) such frames unless tracking finds
it in between. ``mapping.see_through`` switches it off.

Not in the paper, which removes landmarks whose observations turn dynamic and says no more
about landmarks left behind by movers. We add this test because the seen-through places
are where the parked cars' remaining landmarks stood; on static streets most landmarks it
flags are phantoms with no surface near them (docs/decisions/0010-see-through.md).

Found at another depth. What is left on the parked cars after that are phantoms: landmarks
made on a car at a wrong depth (metres in front of it, or behind its side) that
tracking still finds now and then, mostly through keypoints without a stereo match, whose
depth no residual checks. So
`landmarks_found_at_another_depth` tests the landmarks the frame's solve found through
such a keypoint, at the keypoint: if the pair matches its window best and clearly (as
above) at a disparity outside the landmark's by the same tolerance, on either side, the
landmark is not where the map has it, and it joins the seen-through ones in the dynamic
streak. Nearer counts here, unlike for a missed landmark: the window is the landmark's
own match, not an occluder in front of it.

Why these numbers. A search only up to 1.5 times the prediction "sees through" static
landmarks behind crossing pedestrians much nearer than that; up to 3 times keeps them. A
depth tolerance of 20 % (the one of ``mapping.mover_depth_tolerance``)
missed outline landmarks a few metres in front of their background; 5 % changed one
landmark, as a different run's chaos also does, so 10 % stays. Testing only the
landmarks within a grid cell (64 px) of a feature labelled dynamic misses cars that drove
on: they are often no longer labelled near their landmarks
(docs/decisions/0010-see-through.md).
"""

from dataclasses import dataclass

import numpy as np

from pld_slam.config import MappingConfig
from pld_slam.frontend.points import mean_free_window, sad_to_window
from pld_slam.geometry.camera import StereoCamera
from pld_slam.jit import kernel
from pld_slam.localisation.local_map import MissedPoints


@dataclass(frozen=True)
class SeeThroughOptions:
    """What the window tests read of the configuration (module docstring).

    half_window : windows are ``2 * half_window + 1`` px square, at full resolution
        (``mapping.see_through_half_window``).
    reach : disparities are searched from 0 to this times the predicted one (``mapping.see_through_reach``).
    depth_tolerance, margin_px : the best disparity must lie outside the predicted one by more than this
        share of the depth and this many pixels (``mapping.see_through_depth_tolerance``,
        ``mapping.see_through_margin_px``).
    match_ratio : and cost at most this times both the cost at the prediction and the window's contrast
        (``mapping.see_through_match_ratio``).
    """

    half_window: int
    reach: float
    depth_tolerance: float
    margin_px: float
    match_ratio: float

    @classmethod
    def of(cls, config: MappingConfig) -> "SeeThroughOptions":
        return cls(config.see_through_half_window, config.see_through_reach, config.see_through_depth_tolerance,
                   config.see_through_margin_px, config.see_through_match_ratio)


def landmarks_seen_through(camera: StereoCamera, missed: MissedPoints, left: np.ndarray, right: np.ndarray,
                           options: SeeThroughOptions) -> np.ndarray:
    """Ids (ascending) of the ``missed`` point landmarks (`missed_in_image`: in front of the
    camera, inside the image, not found by the frame's solve) that the rectified pair
    ``left``, ``right`` (H, W) uint8, taken where they were projected, sees through (module
    docstring)."""
    tested = np.flatnonzero(missed.missed)
    windowed, u, v, disparity = _testable_windows(camera, missed.uv[tested], missed.p_c[tested, 2],
                                                  options.half_window)
    return missed.ids[tested[windowed][shows_farther_surface(left, right, u, v, disparity, options)]]


def _testable_windows(camera: StereoCamera, uv: np.ndarray, depth: np.ndarray, half_window: int
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Which landmarks at pixels ``uv`` (K, 2) and depths ``depth`` (K,) [m] can be tested (K,) bool: in front
    of the camera, their window (``half_window`` [px]) inside both images at their disparity + 1; and of
    those, the whole pixel (u, v) int64 and the predicted disparity [px]."""
    pixels = np.rint(uv)
    disparity = camera.bf / np.where(depth > 0, depth, np.inf) + camera.disparity_offset
    windowed = ((depth > 0) & camera.inside_image(pixels, half_window)
                & (pixels[:, 0] - np.ceil(disparity) - 1 >= half_window))
    u, v = pixels[windowed].astype(np.int64).T
    return windowed, u, v, disparity[windowed]


def shows_farther_surface(
    left: np.ndarray, right: np.ndarray, u: np.ndarray, v: np.ndarray, predicted: np.ndarray,
    options: SeeThroughOptions,
) -> np.ndarray:
    """Whether the left windows centred on pixels ``u``, ``v`` (K,) int64 show a surface farther
    than disparity ``predicted`` (K,) [px] (K,) bool: their best whole-pixel disparity, searched
    from 0 to ``options.reach`` x ``predicted`` (as far as the right image reaches), passes the
    tests of the module docstring. Windows must lie inside both images at ``predicted`` + 1.

    The farther shifts are searched first; the nearer ones only when a farther one matched
    clearly, to check that none matches better. Most windows stop after the farther third
    of the search, and a window's sum stops once it cannot be the cost looked for.
    """
    return _windows_shown(left, right, u, v, predicted, options.half_window, options.reach, options.depth_tolerance,
                          options.margin_px, options.match_ratio, False)


@kernel
def _window_and_clear_match_bound(left, right, u, v, predicted, half_window, ratio, window, scratch):
    """Fill ``window`` with the mean-free left window at pixel ``u``, ``v``; return the cost a shift of it
    must stay under to be a clear match: ``ratio`` times both its cost at disparity ``predicted`` (plus or
    minus a pixel) and its contrast (module docstring)."""
    mean_free_window(left, u, v, half_window, window)
    nearest = int(round(predicted))
    at_prediction = np.inf
    for shift in range(max(nearest - 1, 0), nearest + 2):
        at_prediction = min(at_prediction, sad_to_window(window, right, u - shift, v, half_window, scratch))
    return ratio * min(at_prediction, np.abs(window).sum())


@kernel
def _windows_shown(left, right, u, v, predicted, half_window, reach, tolerance, margin, ratio, nearer_too):
    """Per window (K,) bool: `_farther_is_best`, or `_elsewhere_is_best` when ``nearer_too``."""
    side = 2 * half_window + 1
    window = np.empty(side * side)
    scratch = np.empty(side * side)
    shown = np.zeros(len(u), dtype=np.bool_)
    for k in range(len(u)):
        bound = _window_and_clear_match_bound(left, right, u[k], v[k], predicted[k], half_window, ratio, window,
                                              scratch)
        last = min(int(reach * predicted[k]) + 1, u[k] - half_window)
        farthest_near = predicted[k] / (1.0 + tolerance) - margin
        if nearer_too:
            nearest_far = predicted[k] * (1.0 + tolerance) + margin
            shown[k] = _elsewhere_is_best(window, right, u[k], v[k], bound, last, farthest_near, nearest_far,
                                          half_window, scratch)
        else:
            shown[k] = _farther_is_best(window, right, u[k], v[k], bound, last, farthest_near, half_window, scratch)
    return shown


@kernel
def _farther_is_best(window, right, u, v, bound, last, below, half_window, scratch):
    """Whether the best shift of ``window`` (pixel ``u``, ``v``) up to ``last`` costs under ``bound`` and is
    smaller than ``below``. The shifts under ``below`` are searched first, the others only when one of
    them matched clearly, and a sum stops once it cannot be the cost looked for."""
    shift = 0
    farther = np.inf
    while shift <= last and shift < below:
        farther = min(farther, sad_to_window(window, right, u - shift, v, half_window, scratch, min(farther, bound)))
        shift += 1
    if farther >= bound:
        return False
    while shift <= last:
        if sad_to_window(window, right, u - shift, v, half_window, scratch, farther) < farther:
            return False
        shift += 1
    return True


@kernel
def _elsewhere_is_best(window, right, u, v, bound, last, below, above, half_window, scratch):
    """Whether the best shift of ``window`` (pixel ``u``, ``v``) up to ``last`` costs under ``bound`` and is
    smaller than ``below`` or larger than ``above``."""
    best, best_shift = bound, -1
    for shift in range(last + 1):
        cost = sad_to_window(window, right, u - shift, v, half_window, scratch, best)
        if cost < best:
            best, best_shift = cost, shift
    return best_shift >= 0 and (best_shift < below or best_shift > above)


def landmarks_found_at_another_depth(
    camera: StereoCamera, ids: np.ndarray, uv: np.ndarray, p_c: np.ndarray, left: np.ndarray, right: np.ndarray,
    options: SeeThroughOptions,
) -> np.ndarray:
    """Ids of the point landmarks ``ids`` (K,) found by left-image-only keypoints at pixels ``uv`` (K, 2)
    whose window the rectified pair ``left``, ``right`` (H, W) uint8 matches clearly at another
    depth than the landmark's (camera frame ``p_c`` (K, 3)) (module docstring, "Found at another depth")."""
    windowed, u, v, disparity = _testable_windows(camera, uv, p_c[:, 2], options.half_window)
    return ids[windowed][shows_another_depth(left, right, u, v, disparity, options)]


def shows_another_depth(
    left: np.ndarray, right: np.ndarray, u: np.ndarray, v: np.ndarray, predicted: np.ndarray,
    options: SeeThroughOptions,
) -> np.ndarray:
    """Whether the left windows centred on pixels ``u``, ``v`` (K,) int64 match the right image best,
    and clearly (``options.match_ratio``), at a whole-pixel disparity from 0 to ``options.reach`` x
    ``predicted`` (K,) [px] that lies outside ``predicted`` by more than ``options.depth_tolerance`` of it
    and ``options.margin_px``, on either side (K,) bool. Windows must lie inside both images at
    ``predicted`` + 1."""
    return _windows_shown(left, right, u, v, predicted, options.half_window, options.reach, options.depth_tolerance,
                          options.margin_px, options.match_ratio, True)
