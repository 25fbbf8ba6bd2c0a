"""KITTI odometry layout: ``.../sequences/NN/{image_0/, image_1/, calib.txt, times.txt}``.

- Images: ``image_0/*.png`` (left) and ``image_1/*.png`` (right), already rectified,
  paired by file name (`pld_slam.datasets.files.paired_images`): a file without a
  partner of the same name raises, naming it. Or the colour pair, ``image_2/`` and
  ``image_3/`` (read as grey), where the folder has no ``image_0/`` or
  ``dataset.cameras`` asks for it (`pld_slam.datasets.kitti_cameras`).
- Camera: ``P0`` and ``P1`` of ``calib.txt`` (colour: ``P2`` and ``P3``); fx, fy, cx,
  cy from ``P0`` and ``baseline = (P0[0, 3] - P1[0, 3]) / fx`` (the colour pair's also
  counts the two cameras' offsets along the optical axis:
  `pld_slam.datasets.calibration.stereo_camera_from_projections`). ``calib.txt`` has no
  image size; we read it from the header of the first readable left PNG (24 bytes), so
  opening decodes no image.
- Times: ``times.txt``, one time [s] per line and per frame. It is required: every KITTI
  download has it, and a guessed frame rate would silently distort time-based metrics.
- Frame rate: KITTI's nominal 10 Hz (`FRAME_RATE`); for what ``pld-slam synth`` wrote,
  ``frame_rate`` of its ``synth.json``, else the median step of ``times.txt``.
- Ground truth (optional): the official ``.../poses/NN.txt`` two folders up, else
  ``poses.txt`` inside the sequence folder (how the project's synthetic generator writes
  one sequence), read with `pld_slam.io.trajectory.read_kitti` (a malformed row raises
  its `TrajectoryError` naming ``file:line``). Row i is frame i. More rows than frames is
  open: we keep the first N, so that the official poses still serve a truncated image
  folder (the shared extract holds the first 51 frames). Fewer rows give ground truth for
  the first frames only. The poses are of cam0; the colour pair's are moved to cam2
  (`pld_slam.datasets.kitti_cameras`). The first ground-truth pose is moved to identity.
- Dynamic masks (optional, synthetic sequences): ``dynamic_masks/*.png``, one per frame
  in natural file-name order (as the images); a different count raises, as a
  half-written mask folder would silently corrupt the dynamic-feature metrics.
"""

import json
import math
from pathlib import Path

import numpy as np

from pld_slam.datasets.base import FrameRate, ImageFiles, StereoSequence
from pld_slam.datasets.calibration import (
    PINHOLE_ENTRIES,
    camera_from_reference,
    read_kitti_calibration,
    stereo_camera_from_projections,
)
from pld_slam.datasets.files import first_image_size, natural_sorted, paired_image_folders, png_size, read_times
from pld_slam.datasets.kitti_cameras import CameraPair, chosen_pair
from pld_slam.errors import DatasetError
from pld_slam.geometry.se3 import inverse
from pld_slam.io.trajectory import read_kitti
from pld_slam.trajectory import Trajectory

LAYOUT = "kitti_odometry"
EXPECTED = "KITTI odometry (image_0/, image_1/ or image_2/, image_3/, calib.txt, times.txt)"

FRAME_RATE = FrameRate(10.0, "KITTI nominal rate")
"""KITTI's cameras are triggered by the Velodyne at 10 Hz (odometry and raw alike)."""


def matches(folder: Path) -> bool:
    """Whether ``folder`` looks like a KITTI odometry sequence (it has ``image_0/`` or ``image_2/``)."""
    return (folder / "image_0").is_dir() or (folder / "image_2").is_dir()


def camera_pairs(folder: Path) -> tuple[CameraPair, CameraPair]:
    """The grey and the colour pair of the sequence ``folder``."""
    return (
        CameraPair("grey", folder / "image_0", folder / "image_1", ("P0", "P1")),
        CameraPair("colour", folder / "image_2", folder / "image_3", ("P2", "P3")),
    )


def load(folder: Path, cameras: str = "auto") -> StereoSequence:
    """Open the KITTI odometry sequence in ``folder`` from the pair ``cameras`` names
    (`pld_slam.datasets.kitti_cameras.chosen_pair`; see the module docstring)."""
    folder = folder.resolve()
    pair = chosen_pair(*camera_pairs(folder), cameras)
    left_paths, right_paths = paired_image_folders(pair.left, pair.right, (".png",))
    timestamps = read_times(folder / "times.txt", len(left_paths))
    calibration = read_kitti_calibration(folder / "calib.txt")
    P_left, P_right = (calibration.array(key, (3, 4), PINHOLE_ENTRIES) for key in pair.keys)
    camera = stereo_camera_from_projections(
        P_left, P_right, *first_image_size(left_paths, png_size), source=calibration.path, keys=pair.keys
    )
    synth = _synth_metadata(folder)
    return StereoSequence(
        name=f"kitti_{folder.name}" if synth is None else f"synth_{synth['scenario']}",
        layout=LAYOUT,
        root=folder,
        camera=camera,
        timestamps=timestamps,
        frame_rate=FRAME_RATE if synth is None else _synth_frame_rate(synth, timestamps),
        frames=ImageFiles(left_paths, right_paths, camera.size, pair.colour),
        groundtruth=_groundtruth(folder, timestamps, inverse(camera_from_reference(P_left))),
        dynamic_mask_paths=_dynamic_mask_paths(folder, len(left_paths)),
        cameras=pair.name,
    )


def _synth_metadata(folder: Path) -> dict | None:
    """The ``synth.json`` that ``pld-slam synth`` leaves (with its ``scenario``), or None for KITTI."""
    try:
        metadata = json.loads((folder / "synth.json").read_text())
    except (OSError, ValueError):
        return None
    return metadata if isinstance(metadata, dict) and "scenario" in metadata else None


def _synth_frame_rate(metadata: dict, timestamps: np.ndarray) -> FrameRate:
    """``frame_rate`` [Hz] of a ``synth.json``, else the median step of the frame times."""
    rate = metadata.get("frame_rate")
    if isinstance(rate, (int, float)) and math.isfinite(rate) and rate > 0:
        return FrameRate(float(rate), "frame_rate of synth.json")
    return FrameRate.from_times(timestamps, "median step of times.txt")


def _groundtruth_file(folder: Path) -> Path | None:
    """The official ``../../poses/NN.txt``, else ``poses.txt`` in the sequence, else None."""
    official = folder.parent.parent / "poses" / f"{folder.name}.txt"
    for candidate in (official, folder / "poses.txt"):
        if candidate.is_file():
            return candidate
    return None


def _groundtruth(folder: Path, timestamps: np.ndarray, T_c0_c: np.ndarray) -> Trajectory | None:
    """``T_w_c`` of the pair's left camera ``c`` at the first min(rows, frames) frames, first = identity.

    The poses file is of cam0 (``T_w_c0``); ``T_c0_c`` (4, 4) is the left camera's pose in
    cam0 (the identity for the grey pair).
    """
    path = _groundtruth_file(folder)
    if path is None:
        return None
    poses = read_kitti(path).poses[: len(timestamps)]
    return Trajectory(timestamps[: len(poses)], poses @ T_c0_c).relative_to_first()


def _dynamic_mask_paths(folder: Path, n_frames: int) -> list[Path] | None:
    """``dynamic_masks/*.png`` in natural name order (as the images), one per frame, or None without the folder."""
    mask_folder = folder / "dynamic_masks"
    if not mask_folder.is_dir():
        return None
    paths = natural_sorted(mask_folder.glob("*.png"))
    if len(paths) != n_frames:
        raise DatasetError(f"{mask_folder}: {len(paths)} masks for {n_frames} frames")
    return paths
