"""Write a synthetic scenario to disk in the KITTI odometry layout.

``OUT/image_0/000000.png ...`` (left), ``OUT/image_1/`` (right), ``OUT/calib.txt`` (``P0:`` and
``P1:``, 12 numbers each, ``P1[0, 3] = -fx * baseline`` as in KITTI), ``OUT/times.txt``
(seconds, ``%e``), ``OUT/poses.txt`` (ground-truth ``T_w_c``, the top three rows of each
pose, row-major, first = identity), ``OUT/dynamic_masks/000000.png`` (uint8, 255 where the
left pixel shows a moving object) and ``OUT/synth.json`` (what was generated). Poses and
calibration are written with 13 significant digits (KITTI's own files use 7).

The files depend only on the arguments: the same call writes the same bytes.
"""

import json
import shutil
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from pld_slam.errors import OutputError, PldSlamError
from pld_slam.geometry.camera import StereoCamera
from pld_slam.synth.scenarios import FRAME_RATE, Scenario, build_scenario, make_camera

METADATA = "synth.json"
OUTPUTS = ("image_0", "image_1", "dynamic_masks", "calib.txt", "times.txt", "poses.txt", METADATA)
"""Everything `write_sequence` writes into its folder (and removes before rewriting it)."""


@dataclass(frozen=True)
class SynthSummary:
    """What `write_sequence` did: the folder, the scenario and frame count, the image size,
    the wall time [s] and rate [stereo pairs/s] of rendering and writing, and the mean
    fraction of left-image pixels on moving objects."""

    out_dir: Path
    scenario: str
    n_frames: int
    width: int
    height: int
    seconds: float
    pairs_per_second: float
    mean_dynamic_fraction: float


def prepare_folder(out_dir: Path) -> None:
    """Create ``out_dir``, or empty the outputs of an earlier synthetic sequence in it.

    Raises
    ------
    PldSlamError
        If ``out_dir`` is a file, or a non-empty folder without a ``synth.json``.
    """
    if out_dir.exists():
        if not out_dir.is_dir():
            raise PldSlamError(f"{out_dir}: exists and is not a folder")
        if any(out_dir.iterdir()) and not (out_dir / METADATA).is_file():
            raise PldSlamError(
                f"{out_dir}: folder is not empty and holds no earlier synthetic sequence ({METADATA});"
                " choose a new or empty folder")
        for name in OUTPUTS:
            entry = out_dir / name
            if entry.is_dir():
                shutil.rmtree(entry)
            elif entry.exists():
                entry.unlink()
    for name in ("image_0", "image_1", "dynamic_masks"):
        (out_dir / name).mkdir(parents=True, exist_ok=True)


def projection_matrices(camera: StereoCamera) -> tuple[np.ndarray, np.ndarray]:
    """KITTI's rectified projections (3, 4) of the left (``P0``) and right (``P1``) cameras."""
    P0 = np.hstack([camera.K, np.zeros((3, 1))])
    P1 = P0.copy()
    P1[0, 3] = -camera.bf
    return P0, P1


def format_row(values: np.ndarray) -> str:
    """Numbers as KITTI writes them: space separated, exponent notation (13 digits)."""
    return " ".join(f"{v:.12e}" for v in np.asarray(values, dtype=np.float64).ravel())


def write_text_files(out_dir: Path, scenario: Scenario) -> None:
    """``calib.txt``, ``times.txt``, ``poses.txt`` and ``synth.json`` of ``scenario``."""
    P0, P1 = projection_matrices(scenario.camera)
    (out_dir / "calib.txt").write_text(f"P0: {format_row(P0)}\nP1: {format_row(P1)}\n")
    (out_dir / "times.txt").write_text("".join(f"{t:e}\n" for t in scenario.timestamps))
    # Adding 0.0 turns any -0.0 into 0.0, so the identity prints as plain zeros and ones.
    rows = scenario.poses[:, :3, :].reshape(len(scenario.poses), 12) + 0.0
    (out_dir / "poses.txt").write_text("".join(format_row(row) + "\n" for row in rows))
    metadata = {
        "generator": "pld_slam.synth",
        "scenario": scenario.name,
        "seed": scenario.seed,
        "n_frames": scenario.n_frames,
        "frame_rate": FRAME_RATE,
        **camera_metadata(scenario.camera),
    }
    (out_dir / METADATA).write_text(json.dumps(metadata, indent=2, sort_keys=True) + "\n")


def camera_metadata(camera: StereoCamera) -> dict:
    """What ``synth.json`` records of the camera: ``width``, ``height`` [px] and ``camera``
    (fx, fy, cx, cy [px], baseline [m])."""
    return {
        "width": camera.width,
        "height": camera.height,
        "camera": {"fx": camera.fx, "fy": camera.fy, "cx": camera.cx, "cy": camera.cy,
                   "baseline": camera.baseline},
    }


def write_png(path: Path, image: np.ndarray) -> None:
    """Write a uint8 image as PNG, or raise `PldSlamError` naming the file."""
    if not cv2.imwrite(str(path), image):
        raise PldSlamError(f"{path}: cannot write image")


def write_sequence(out_dir: Path, scenario: str, n_frames: int | None = None,
                   size: tuple[int, int] | None = None, seed: int = 0, camera: str = "default",
                   progress: bool = False) -> SynthSummary:
    """Render scenario ``scenario`` and write it to ``out_dir`` in the KITTI layout.

    Parameters
    ----------
    out_dir : Path
        Target folder: new, empty, or holding an earlier synthetic sequence (overwritten).
    scenario : str
        One of `pld_slam.synth.SCENARIOS`.
    n_frames : int or None
        Frames to render; None for the scenario's default.
    size : tuple of int or None
        ``(width, height)`` [px] of the ``default`` camera; None for
        `pld_slam.synth.scenarios.DEFAULT_SIZE` (the ``kitti`` camera's size is fixed).
    seed : int
        Fixes the scene, motion and noise: the same arguments write the same bytes.
    camera : str
        One of `pld_slam.synth.scenarios.CAMERAS`: ``default`` (fx = 0.6 width, baseline
        0.5 m) or ``kitti`` (KITTI odometry 00-02's 1241 x 376 rectified grey pair).
    progress : bool
        Show a progress bar when stderr is a terminal (tqdm's ``disable=None``), as
        ``pld-slam run`` does: redrawn bars in a log file are noise.

    Raises
    ------
    PldSlamError
        For a bad scenario name, camera, size or frame count, a size given with the
        ``kitti`` camera, or an unrelated non-empty folder;
        `OutputError` for a folder that cannot be created or written.
    """
    out_dir = Path(out_dir)
    start = time.perf_counter()
    world = build_scenario(scenario, n_frames, size, seed, camera)
    try:
        prepare_folder(out_dir)
        write_text_files(out_dir, world)
    except OSError as error:  # a folder that cannot be created or written: the user's to fix
        raise OutputError.from_os_error(out_dir, error) from None
    fractions = np.empty(world.n_frames)
    with ThreadPoolExecutor(max_workers=1) as writer:
        pending = []
        frames = tqdm(range(world.n_frames), disable=None if progress else True, desc=f"synth {scenario}", unit="pair")
        for index in frames:
            frame = world.render_frame(index)
            fractions[index] = frame.dynamic_mask.mean()
            name = f"{index:06d}.png"
            for job in pending:  # PNGs of the previous frame are written while this one renders
                job.result()
            pending = [
                writer.submit(write_png, out_dir / "image_0" / name, frame.left),
                writer.submit(write_png, out_dir / "image_1" / name, frame.right),
                writer.submit(write_png, out_dir / "dynamic_masks" / name,
                              frame.dynamic_mask.astype(np.uint8) * 255),
            ]
        for job in pending:
            job.result()
    seconds = time.perf_counter() - start
    return SynthSummary(
        out_dir=out_dir,
        scenario=scenario,
        n_frames=world.n_frames,
        width=world.camera.width,
        height=world.camera.height,
        seconds=seconds,
        pairs_per_second=world.n_frames / seconds,
        mean_dynamic_fraction=float(fractions.mean()),
    )


def ensure_sequence(out_dir: Path, scenario: str, n_frames: int, seed: int = 0, camera: str = "default") -> Path:
    """``out_dir``, holding scenario ``scenario`` of ``n_frames`` frames and ``seed`` seen by
    ``camera`` (at the default size): written by `write_sequence` unless its ``synth.json``
    says it already is (the camera by its size and intrinsics).

    For callers that keep generated sequences between runs (regression cells, benchmarks):
    rendering a few hundred frames takes tens of seconds.
    """
    out_dir = Path(out_dir)
    metadata = out_dir / METADATA
    if metadata.is_file():
        written = json.loads(metadata.read_text())
        wanted = {"scenario": scenario, "n_frames": n_frames, "seed": seed,
                  **camera_metadata(make_camera(camera, None))}
        if all(written.get(key) == value for key, value in wanted.items()):
            return out_dir
    write_sequence(out_dir, scenario, n_frames, seed=seed, camera=camera)
    return out_dir

