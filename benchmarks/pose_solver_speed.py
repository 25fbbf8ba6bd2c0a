"""How fast and how accurate the tracker's pose-only solve is on KITTI-like synthetic frames.

Each case builds ``--calls`` random frames (a random true pose ``T_c_w``, stereo points
3-40 m deep seen with 1 px noise, optionally line segments and 20% gross outliers), starts
`optimize_pose_rejecting_outliers` from the truth moved by 0.2 m and 1 degree (a
constant-velocity prediction), and prints the median wall time per call, rounds and
residual evaluations, and the median pose error against the truth. Run from the
repository root:

    python benchmarks/pose_solver_speed.py [--calls 30] [--seed 0]

Timings depend on the BLAS threads (``OPENBLAS_NUM_THREADS``, printed under the table; one
unless set, as the ``pld-slam`` command runs) and on what else runs on the machine: OpenBLAS
threads stall when the other core is busy.
"""

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # before numpy loads OpenBLAS, as `pld-slam` runs (`pld_slam`)

import argparse
import time
from dataclasses import dataclass

import numpy as np

from pld_slam.geometry.camera import StereoCamera
from pld_slam.geometry.se3 import inverse, rotation_angle, se3_exp, transform_points
from pld_slam.optim.line_reprojection import detected_line_directions, endpoints_away_from_border
from pld_slam.optim.observations import LineObservations, PointObservations
from pld_slam.optim.pose_only import PoseOnlyResult, optimize_pose_rejecting_outliers

CAMERA = StereoCamera(
    fx=707.0912, fy=707.0912, cx=601.8873, cy=183.1104, baseline=0.537, width=1226, height=370
)
NOISE_PX = 1.0
INITIAL_TRANSLATION_M = 0.2
INITIAL_ROTATION_RAD = np.radians(1.0)
BORDER_MARGIN_PX = 10.0


@dataclass(frozen=True)
class Case:
    """One row of the table: how many points and lines a frame has, and its outlier fraction."""

    name: str
    n_points: int
    n_lines: int
    outlier_fraction: float


CASES = (
    Case("points 700", 700, 0, 0.0),
    Case("points 700 + lines 100", 700, 100, 0.0),
    Case("points 700 + lines 100, 20% outliers", 700, 100, 0.2),
)


@dataclass(frozen=True)
class Frame:
    """One synthetic solve: the true and initial ``T_c_w`` (4, 4) and the observations."""

    T_c_w_true: np.ndarray
    T_c_w_init: np.ndarray
    points: PointObservations
    lines: LineObservations | None


def random_unit_vector(rng: np.random.Generator) -> np.ndarray:
    """A direction (3,) uniform on the sphere."""
    v = rng.normal(size=3)
    return v / np.linalg.norm(v)


def random_true_pose(rng: np.random.Generator) -> np.ndarray:
    """A random ``T_c_w`` (4, 4): any rotation up to 0.6 rad per axis, translation within 50 m."""
    return se3_exp(np.concatenate([rng.uniform(-50.0, 50.0, 3), rng.uniform(-0.6, 0.6, 3)]))


def constant_velocity_guess(rng: np.random.Generator, T_c_w: np.ndarray) -> np.ndarray:
    """``T_c_w`` (4, 4) moved by 0.2 m and turned by 1 degree, both about random axes."""
    twist = np.concatenate(
        [INITIAL_TRANSLATION_M * random_unit_vector(rng), INITIAL_ROTATION_RAD * random_unit_vector(rng)]
    )
    return se3_exp(twist) @ T_c_w


def random_camera_points(rng: np.random.Generator, n: int, depth_range: tuple[float, float]) -> np.ndarray:
    """Left-camera points (n, 3) projecting uniformly into the image, depths uniform in the range [m]."""
    pixels = rng.uniform([0.0, 0.0], [CAMERA.width - 1.0, CAMERA.height - 1.0], (n, 2))
    return CAMERA.backproject(pixels, rng.uniform(*depth_range, n))


def observe_points(rng: np.random.Generator, T_c_w: np.ndarray, n: int, outlier_fraction: float) -> PointObservations:
    """Stereo observations of n points 3-40 m deep; a fraction of them shifted 15-60 px per coordinate."""
    p_c = random_camera_points(rng, n, (3.0, 40.0))
    stereo_px = CAMERA.project_stereo(p_c) + rng.normal(0.0, NOISE_PX, (n, 3))
    outliers = rng.permutation(n)[: round(outlier_fraction * n)]
    stereo_px[outliers] += rng.choice([-1.0, 1.0], (len(outliers), 3)) * rng.uniform(15.0, 60.0, (len(outliers), 3))
    return PointObservations(transform_points(inverse(T_c_w), p_c), stereo_px, np.full(n, NOISE_PX))


def observe_lines(rng: np.random.Generator, T_c_w: np.ndarray, n: int, outlier_fraction: float) -> LineObservations:
    """Observations of n segments 5-30 m deep, 1 px endpoint noise; a fraction moved 20-60 px across."""
    start_c = random_camera_points(rng, n, (5.0, 30.0))
    end_pixels = CAMERA.project(start_c) + rng.uniform(30.0, 200.0, (n, 1)) * random_image_directions(rng, n)
    end_pixels = np.clip(end_pixels, 0.0, [CAMERA.width - 1.0, CAMERA.height - 1.0])
    end_c = CAMERA.backproject(end_pixels, start_c[:, 2] * rng.uniform(0.8, 1.25, n))
    start_px = CAMERA.project(start_c) + rng.normal(0.0, NOISE_PX, (n, 2))
    end_px = CAMERA.project(end_c) + rng.normal(0.0, NOISE_PX, (n, 2))
    outliers = rng.permutation(n)[: round(outlier_fraction * n)]
    normal = detected_line_directions(start_px, end_px)[outliers] @ np.array([[0.0, 1.0], [-1.0, 0.0]])
    across = rng.choice([-1.0, 1.0], (len(outliers), 1)) * rng.uniform(20.0, 60.0, (len(outliers), 1)) * normal
    start_px[outliers] += across
    end_px[outliers] += across
    T_w_c = inverse(T_c_w)
    return LineObservations(
        transform_points(T_w_c, start_c),
        transform_points(T_w_c, end_c),
        start_px,
        end_px,
        np.full(n, NOISE_PX),
        endpoints_away_from_border(CAMERA, start_px, end_px, BORDER_MARGIN_PX),
    )


def random_image_directions(rng: np.random.Generator, n: int) -> np.ndarray:
    """Unit image directions (n, 2), angles uniform."""
    angle = rng.uniform(0.0, 2.0 * np.pi, n)
    return np.column_stack([np.cos(angle), np.sin(angle)])


def make_frame(rng: np.random.Generator, case: Case) -> Frame:
    """A random frame of ``case``."""
    T_c_w = random_true_pose(rng)
    points = observe_points(rng, T_c_w, case.n_points, case.outlier_fraction)
    lines = observe_lines(rng, T_c_w, case.n_lines, case.outlier_fraction) if case.n_lines else None
    return Frame(T_c_w, constant_velocity_guess(rng, T_c_w), points, lines)


def pose_error_mm_mdeg(T_est: np.ndarray, T_true: np.ndarray) -> tuple[float, float]:
    """Camera-centre distance [mm] and rotation angle [mdeg] of ``T_est`` relative to ``T_true``."""
    T_diff = T_est @ inverse(T_true)
    return 1e3 * float(np.linalg.norm(inverse(T_diff)[:3, 3])), 1e3 * float(np.degrees(rotation_angle(T_diff[:3, :3])))


@dataclass(frozen=True)
class Row:
    """Medians over the calls of one case."""

    ms: float
    rounds: float
    nfev: float
    translation_mm: float
    rotation_mdeg: float
    successes: int


def solve_timed(frame: Frame) -> tuple[PoseOnlyResult, float]:
    """The solve of ``frame`` and its wall time [ms]."""
    start = time.perf_counter()
    result = optimize_pose_rejecting_outliers(CAMERA, frame.T_c_w_init, frame.points, frame.lines)
    return result, 1e3 * (time.perf_counter() - start)


def measure(case: Case, calls: int, seed: int) -> Row:
    """Solve ``calls`` random frames of ``case`` (after one warm-up solve) and take medians."""
    rng = np.random.default_rng(seed)
    frames = [make_frame(rng, case) for _ in range(calls)]
    solve_timed(frames[0])
    results, ms = zip(*(solve_timed(frame) for frame in frames))
    errors = np.array([pose_error_mm_mdeg(r.T_c_w, f.T_c_w_true) for r, f in zip(results, frames)])
    return Row(
        ms=float(np.median(ms)),
        rounds=float(np.median([r.rounds for r in results])),
        nfev=float(np.median([r.nfev for r in results])),
        translation_mm=float(np.median(errors[:, 0])),
        rotation_mdeg=float(np.median(errors[:, 1])),
        successes=sum(r.success for r in results),
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--calls", type=int, default=30, help="solves per case")
    parser.add_argument("--seed", type=int, default=0, help="seed of the random frames")
    args = parser.parse_args()
    header = (
        f"{'case':<38} {'ms/call':>8} {'rounds':>6} {'nfev':>5} {'t err mm':>9} {'R err mdeg':>10} {'ok':>6}"
    )
    print(header)
    print("-" * len(header))
    for case in CASES:
        row = measure(case, args.calls, args.seed)
        print(
            f"{case.name:<38} {row.ms:>8.1f} {row.rounds:>6.1f} {row.nfev:>5.0f} {row.translation_mm:>9.1f}"
            f" {row.rotation_mdeg:>10.1f} {row.successes:>3}/{args.calls:<2}"
        )
    print(f"OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS', 'unset')}")


if __name__ == "__main__":
    main()
