"""Every numba kernel of the package compiled (or loaded from the disk cache) before a run's first frame.

A kernel (`pld_slam.jit.kernel`) compiles at its first call with each new set of argument
types. Left to itself, that happens inside the first frames of the first run on a
machine: about 7 s on KITTI 06, in the main process and in the forked front end, so the
first run reported a mean of 208 ms per frame against 85 ms for the second (issue 40).

The paper does not say (it runs C++). We compile every kernel up front
(`compile_kernels`), before the run's clock starts, by calling each through the public
function the pipeline calls, on tiny inputs of the same types: the cost is paid once per
machine (numba caches the result on disk, `pld_slam.jit`), is reported apart from the
run's timings, and never lands in a frame's time. On a warm cache the same calls load
the kernels in about 0.2 s. A test checks that a run compiles nothing after this.
Compiling at install time is not possible with a wheel (pip runs no code of the
package), and compiling in the background at import would contend with the run for the
interpreter.
"""

import time

import numpy as np

from pld_slam.config import MappingConfig
from pld_slam.frontend.ggs import ggs_distances
from pld_slam.frontend.points import sad_along_row
from pld_slam.geometry.camera import StereoCamera
from pld_slam.geometry.se3 import transform_points
from pld_slam.jit import compiled_kernels
from pld_slam.matching.windows import pairs_within
from pld_slam.optim.bundle_adjustment import (
    BundleLineObservations,
    BundlePointObservations,
    BundleProblem,
    bundle_adjust,
)
from pld_slam.tracking.see_through import SeeThroughOptions, shows_another_depth, shows_farther_surface

_CAMERA = StereoCamera(fx=100.0, fy=100.0, cx=40.0, cy=30.0, baseline=0.5, width=80, height=60)
"""The tiny camera of the warm-up calls."""


def compile_kernels() -> float:
    """Compile every kernel of the package (or load it from the cache); return the seconds it took."""
    start = time.perf_counter()
    rng = np.random.default_rng(0)
    left = rng.integers(0, 256, (_CAMERA.height, _CAMERA.width), dtype=np.uint8)
    right = np.roll(left, -5, axis=1)
    _stereo_refinement(left, right)
    _window_searches(left, right)
    _ggs_query(rng)
    pairs_within(rng.uniform(0, 60, (5, 2)), np.ones(5, dtype=bool), rng.uniform(0, 60, (9, 2)), np.full(5, 8.0))
    _bundle_adjustment()
    return time.perf_counter() - start


def kernel_signatures() -> dict[str, int]:
    """How many argument-type signatures each kernel has compiled so far, by qualified name."""
    return {name: len(dispatcher.signatures) for name, dispatcher in compiled_kernels().items()}


def _stereo_refinement(left: np.ndarray, right: np.ndarray) -> None:
    """The front end's SAD along the row (`pld_slam.frontend.points.sad_along_row`)."""
    sad_along_row(left, right, np.array([[30, 30]], dtype=np.int64), np.array([25], dtype=np.int64), 5, 5)


def _window_searches(left: np.ndarray, right: np.ndarray) -> None:
    """Both window searches of `pld_slam.tracking.see_through`, on pixel columns as it slices them."""
    pixels = np.array([[40.0, 30.0], [50.0, 20.0]]).astype(np.int64).T
    predicted = np.array([5.0, 4.0])
    options = SeeThroughOptions.of(MappingConfig())
    shows_farther_surface(left, right, pixels[0], pixels[1], predicted, options)
    shows_another_depth(left, right, pixels[0], pixels[1], predicted, options)


def _ggs_query(rng: np.random.Generator) -> None:
    """A GGS query against a database (`pld_slam.frontend.ggs.ggs_distances`)."""
    database = rng.integers(0, 50, (3, 2, 4, 16), dtype=np.uint8)
    ggs_distances(database[0], database)


def _bundle_adjustment() -> None:
    """A bundle adjustment of two cameras, six points and one line (the row kernel and the Jacobian fill)."""
    T_c_w = np.stack([np.eye(4), np.eye(4)])
    T_c_w[1, 2, 3] = -0.5
    points_w = np.array([[x, y, 8.0 + x] for x in (-1.0, 0.0, 1.0) for y in (-0.5, 0.5)])
    observed = np.concatenate([_stereo_pixels(T_c_w[k], points_w) for k in range(2)])
    points = BundlePointObservations(
        keyframe=np.repeat(np.arange(2), len(points_w)), point=np.tile(np.arange(len(points_w)), 2),
        stereo_px=observed, sigma_px=np.ones(len(observed)),
    )
    line_w = np.array([[[-1.0, 1.0, 9.0], [1.0, 1.0, 9.0]]])
    ends = [_stereo_pixels(T_c_w[k], line_w[0])[:, :2] for k in range(2)]
    lines = BundleLineObservations(
        keyframe=np.arange(2), line=np.zeros(2, dtype=np.int64), start_px=np.array([end[0] for end in ends]),
        end_px=np.array([end[1] for end in ends]), sigma_px=np.ones(2), horizontal_eligible=np.ones(2, dtype=bool),
    )
    problem = BundleProblem(T_c_w=T_c_w, fixed=np.array([True, False]), points_w=points_w + 0.01, lines_w=line_w,
                            point_observations=points, line_observations=lines)
    bundle_adjust(_CAMERA, problem)


def _stereo_pixels(T_c_w: np.ndarray, points_w: np.ndarray) -> np.ndarray:
    """``(u_left, v, u_right)`` (N, 3) [px] of world points (N, 3) seen by `_CAMERA` at ``T_c_w``."""
    return _CAMERA.project_stereo(transform_points(T_c_w, points_w))
