"""How right are our stereo disparities on real images? Three measurements, three truths.

For every KITTI odometry sequence under ``$PLD_SLAM_DATA`` with ``velodyne/`` scans and
``Tr`` in ``calib.txt`` (or the folders given), with the sequence's run configuration:

1. LiDAR: the disparity error of our stereo points and line endpoints against the scans'
   depths (`pld_slam.eval.lidar_depth`), by ORB octave, by true disparity, by sub-pixel
   position of the level-pixel disparity and by image column.
2. SGBM against LiDAR at every scan point: a matcher that shares no code with ours, and a
   fit of ``d_sgbm = bf / (z_lidar - eps) + offset``: a disparity offset of the images and
   a depth offset of the LiDAR (``Tr``'s translation is known to centimetres), which the
   LiDAR alone cannot tell apart from each other at a tenth of a pixel. Our disparities
   against SGBM's at our keypoints, by octave.
3. Ground-truth motion (every sequence with poses, no LiDAR needed; a synthetic one too,
   whose rig is exact: the measurement's own bias): stereo points matched between frames
   1 to 3 apart; the disparity offset that makes their depths agree with the known
   motion, fitted over all pairs (robust) and per frame gap, and by image column. This is
   what the scale of a trajectory sees: depths as they change with motion.

Also the distribution of the sub-pixel part of the level-pixel disparities (flat without
pixel locking).

    python benchmarks/stereo_depth.py [SEQUENCE_DIR ...] [--set section.key=value ...]
"""

import argparse
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
from extracts import found_sequences
from scipy.optimize import least_squares
from scipy.spatial import cKDTree

from pld_slam.config import Config
from pld_slam.datasets import StereoSequence, open_sequence
from pld_slam.eval.lidar_depth import (
    inverse_depth_at,
    lidar_to_camera,
    project_scan,
    read_scan,
    scan_path,
    scanned_frames,
)
from pld_slam.frontend import StereoFeatures, extract_stereo_features
from pld_slam.frontend.descriptors import hamming_distances
from pld_slam.frontend.points import level_scales
from pld_slam.run_config import load_run_config

DISPARITY_BINS = (3.5, 7, 10, 15, 20, 30, 40, 60, 130)
MAX_ERROR_PX = 3.0
"""Disparity errors beyond this [px] are wrong matches, left out of the tables (counted)."""
MOTION_GAPS = (1, 2, 3)
MATCH_RADIUS_PX = 4.0
"""A stereo point's match in the later frame lies this close to where the ground-truth motion puts it [px]."""
MAX_MATCH_DISTANCE = 40
"""Largest ORB Hamming distance of such a match [bits]."""


def robust_sigma(values: np.ndarray) -> float:
    """1.4826 times the median absolute deviation."""
    return float(1.4826 * np.median(np.abs(values - np.median(values))))


def summary_by(table: pd.DataFrame, key: pd.Series, error: str = "error") -> pd.DataFrame:
    """Median, robust sigma and median relative error [%] of ``error`` per value of ``key``."""
    grouped = table.groupby(key, observed=True)
    return pd.DataFrame({
        "n": grouped[error].size(),
        "median [px]": grouped[error].median(),
        "mean [px]": grouped[error].mean(),
        "sigma [px]": grouped[error].apply(robust_sigma),
        "median rel [%]": grouped.apply(lambda g: 100 * np.median(g[error] / g.true), include_groups=False),
    }).round(3)


def features_of(sequence: StereoSequence, index: int, config: Config, camera) -> StereoFeatures:
    left, right = sequence.frames.read(index)
    return extract_stereo_features(left, right, camera, config.points, config.lines)


def lidar_errors(sequence: StereoSequence, config: Config) -> tuple[pd.DataFrame, pd.DataFrame, pd.DataFrame]:
    """Points' and line endpoints' disparity errors against the scans, and SGBM's disparities at the scans."""
    camera = sequence.camera
    T_c_l = lidar_to_camera(sequence.root)
    points, endpoints, sgbm_samples = [], [], []
    matcher = sgbm()
    for index in scanned_frames(sequence.root):
        if index >= len(sequence):
            continue
        scan = project_scan(read_scan(scan_path(sequence.root, index)), T_c_l, camera)
        left, right = sequence.frames.read(index)
        features = extract_stereo_features(left, right, camera, config.points, config.lines)
        stereo = features.points
        true = camera.bf * inverse_depth_at(scan, stereo.uv)
        known = np.isfinite(true)
        scale = level_scales(config.points)[stereo.octave]
        points.append(pd.DataFrame({
            "frame": index, "u": stereo.uv[known, 0], "octave": stereo.octave[known],
            "measured": stereo.disparity[known], "true": true[known],
            "level_fraction": ((stereo.disparity / scale) % 1.0)[known],
        }))
        line_true = camera.bf * inverse_depth_at(scan, features.lines.endpoints.reshape(-1, 2))
        line_known = np.isfinite(line_true)
        endpoints.append(pd.DataFrame({"true": line_true[line_known],
                                       "measured": features.lines.disparity.reshape(-1)[line_known]}))
        sgbm_samples.append(sgbm_at(matcher, left, right, scan, camera))
    tables = [pd.concat(found, ignore_index=True) for found in (points, endpoints, sgbm_samples)]
    for table, measured in zip(tables, ("measured", "measured", "sgbm")):
        table["error"] = table[measured] - table.true
    return tuple(tables)


def sgbm() -> cv2.StereoSGBM:
    """OpenCV's semi-global matcher (5 px blocks, 1/16 px disparities)."""
    return cv2.StereoSGBM_create(minDisparity=0, numDisparities=128, blockSize=5, P1=8 * 25, P2=32 * 25,
                                 uniquenessRatio=10, speckleWindowSize=100, speckleRange=2,
                                 mode=cv2.STEREO_SGBM_MODE_HH)


def sgbm_disparities(matcher: cv2.StereoSGBM, left: np.ndarray, right: np.ndarray) -> np.ndarray:
    """SGBM's disparity image (H, W) float32 [px]; <= 0 where it found none."""
    return matcher.compute(left, right).astype(np.float32) / 16.0


def sgbm_at(matcher, left, right, scan, camera) -> pd.DataFrame:
    """SGBM's disparity at every scan pixel with the scan's disparity (nearest pixel)."""
    disparity = sgbm_disparities(matcher, left, right)
    pixel = np.rint(scan.uv).astype(int)
    found = disparity[pixel[:, 1], pixel[:, 0]]
    valid = found > 0
    return pd.DataFrame({"true": camera.bf * scan.inverse_depth[valid], "sgbm": found[valid],
                         "v": scan.uv[valid, 1], "u": scan.uv[valid, 0]})


def offset_and_lidar_shift(samples: pd.DataFrame, bf: float) -> tuple[float, float]:
    """``(offset [px], eps [m])`` of ``d_sgbm = bf / (z_lidar - eps) + offset``, a robust fit."""
    def residuals(x):
        return bf / (bf / samples.true.to_numpy() - x[1]) + x[0] - samples.sgbm.to_numpy()
    return tuple(least_squares(residuals, [0.0, 0.0], loss="soft_l1", f_scale=0.3).x)


def motion_pairs(sequence: StereoSequence, config: Config) -> pd.DataFrame:
    """Stereo points matched between frames ``MOTION_GAPS`` apart, found where the ground truth moves them."""
    camera = sequence.camera
    poses = sequence.groundtruth.poses
    cache: dict[int, StereoFeatures] = {}

    def points_of(index):
        if index not in cache:
            cache[index] = features_of(sequence, index, config, camera).points
        return cache[index]

    rows = []
    for gap in MOTION_GAPS:
        for first in range(len(poses) - gap):
            a, b = points_of(first), points_of(first + gap)
            if len(a) == 0 or len(b) == 0:
                continue
            T_b_a = np.linalg.inv(poses[first + gap]) @ poses[first]
            moved = camera.triangulate(a.uv, a.disparity) @ T_b_a[:3, :3].T + T_b_a[:3, 3]
            ahead = moved[:, 2] > 0.5
            predicted = camera.project(moved[ahead])
            tree = cKDTree(b.uv)
            for k, near in zip(np.flatnonzero(ahead), tree.query_ball_point(predicted, MATCH_RADIUS_PX)):
                if not near:
                    continue
                distance = hamming_distances(np.repeat(a.descriptors[k:k + 1], len(near), axis=0), b.descriptors[near])
                if distance.min() > MAX_MATCH_DISTANCE:
                    continue
                m = near[int(np.argmin(distance))]
                rows.append((gap, *a.uv[k], a.disparity[k], *b.uv[m], b.disparity[m], *T_b_a[:3, :3].ravel(),
                             *T_b_a[:3, 3]))
    columns = ["gap", "u0", "v0", "d0", "u1", "v1", "d1"] + [f"r{i}" for i in range(9)] + ["tx", "ty", "tz"]
    return pd.DataFrame(rows, columns=columns)


def motion_residuals(pairs: pd.DataFrame, camera, offset: float) -> np.ndarray:
    """Disparity residuals (P,) [px] of the later frames when every measured disparity is less ``offset``."""
    d0 = pairs.d0.to_numpy() - offset
    points = camera.triangulate(pairs[["u0", "v0"]].to_numpy(), d0)
    rotations = pairs[[f"r{i}" for i in range(9)]].to_numpy().reshape(-1, 3, 3)
    moved = np.einsum("nij,nj->ni", rotations, points) + pairs[["tx", "ty", "tz"]].to_numpy()
    return pairs.d1.to_numpy() - offset - camera.bf / moved[:, 2]


def motion_offset(pairs: pd.DataFrame, camera) -> tuple[float, float]:
    """The offset [px] that makes the pairs' depths follow the ground-truth motion, and its standard error."""
    fit = least_squares(lambda x: motion_residuals(pairs, camera, x[0]), [0.0], loss="cauchy", f_scale=0.3)
    jacobian = fit.jac[:, 0]
    scale = robust_sigma(fit.fun)
    return float(fit.x[0]), float(scale / np.sqrt(jacobian @ jacobian))


def per_pair_offsets(pairs: pd.DataFrame, camera) -> np.ndarray:
    """Each pair's own offset [px] (one Newton step from 0 per pair; NaN where its depth does not change)."""
    step = 0.05
    slope = (motion_residuals(pairs, camera, step) - motion_residuals(pairs, camera, -step)) / (2 * step)
    at_zero = motion_residuals(pairs, camera, 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(np.abs(slope) > 0.05, -at_zero / slope, np.nan)


def print_table(title: str, table: pd.DataFrame) -> None:
    print(f"\n{title}\n{table.to_string()}")


def report_lidar(sequence: StereoSequence, config: Config) -> None:
    camera = sequence.camera
    points, lines, samples = lidar_errors(sequence, config)
    wrong = points.error.abs() > MAX_ERROR_PX
    kept = points[~wrong]
    print(f"\n## {sequence.name}: LiDAR (frames {', '.join(map(str, sorted(set(points.frame))))})")
    print(f"stereo points with a LiDAR depth: {len(points)}, of which {int(wrong.sum())} off by more than "
          f"{MAX_ERROR_PX} px (left out)")
    print_table("points by ORB octave", summary_by(kept, kept.octave))
    print_table("points by true disparity [px]", summary_by(kept, pd.cut(kept.true, DISPARITY_BINS)))
    print_table("points by sub-pixel part of the level-pixel disparity",
                summary_by(kept, pd.cut(kept.level_fraction, np.linspace(0, 1, 6))))
    print_table("points by image column [px]",
                summary_by(kept, pd.cut(kept.u, np.linspace(0, camera.width, 7).round())))
    lines = lines[lines.error.abs() <= MAX_ERROR_PX]
    print_table("line endpoints by true disparity [px]", summary_by(lines, pd.cut(lines.true, DISPARITY_BINS)))
    samples = samples[samples.error.abs() <= MAX_ERROR_PX]
    print_table("SGBM against LiDAR at every scan point, by true disparity [px]",
                summary_by(samples, pd.cut(samples.true, DISPARITY_BINS)))
    road = samples[(samples.v > camera.cy + 45) & ((samples.u - camera.cx).abs() < 250)]
    for name, subset in (("all scan points", samples), ("the road ahead", road)):
        offset, shift = offset_and_lidar_shift(subset, camera.bf)
        print(f"SGBM = bf / (z_lidar - eps) + offset over {name} ({len(subset)}): offset {offset:+.3f} px, "
              f"eps {100 * shift:+.1f} cm")


def report_motion(sequence: StereoSequence, config: Config) -> None:
    camera = sequence.camera
    pairs = motion_pairs(sequence, config)
    print(f"\n## {sequence.name}: ground-truth motion ({len(pairs)} matched stereo points, frame gaps "
          f"{', '.join(map(str, MOTION_GAPS))})")
    offset, error = motion_offset(pairs, camera)
    by_gap = ", ".join("gap {}: {:+.3f} +- {:.3f}".format(gap, *motion_offset(pairs[pairs.gap == gap], camera))
                       for gap in MOTION_GAPS)
    print(f"offset that makes depths follow the motion: {offset:+.3f} +- {error:.3f} px ({by_gap})")
    pairs["offset"] = per_pair_offsets(pairs, camera)
    usable = pairs[pairs.offset.abs() < 1.5].copy()
    usable["true"] = usable.d0
    print_table("each point's own offset, by image column [px]",
                summary_by(usable, pd.cut(usable.u0, np.linspace(0, camera.width, 9).round()), error="offset"))
    print_table("each point's own offset, by disparity [px]",
                summary_by(usable, pd.cut(usable.d0, DISPARITY_BINS), error="offset"))


def report_pixel_locking(sequence: StereoSequence, config: Config) -> None:
    camera = sequence.camera
    fractions = []
    for index in np.linspace(0, len(sequence) - 1, min(11, len(sequence))).round().astype(int):
        points = features_of(sequence, int(index), config, camera).points
        fractions.append((points.disparity / level_scales(config.points)[points.octave]) % 1.0)
    density = np.histogram(np.concatenate(fractions), bins=10, range=(0, 1), density=True)[0]
    print(f"\nsub-pixel part of the level-pixel disparity, density per tenth (flat = 1): "
          f"{' '.join(f'{x:.2f}' for x in density)}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("sequences", nargs="*", type=Path, help="sequence folders (default: every one found)")
    parser.add_argument("--set", dest="overrides", action="append", default=[], help="section.key=value")
    args = parser.parse_args()
    folders = args.sequences or [folder for folder, _ in found_sequences()]
    for folder in folders:
        sequence = open_sequence(folder)
        if sequence.layout != "kitti_odometry":
            continue
        config = load_run_config(sequence, overrides=args.overrides).config
        if scanned_frames(sequence.root):
            report_lidar(sequence, config)
        if sequence.groundtruth is not None:
            report_motion(sequence, config)
        report_pixel_locking(sequence, config)


if __name__ == "__main__":
    main()
