"""The real dataset extracts the benchmarks run on, found under ``$PLD_SLAM_DATA``.

The extracts live outside the repository (``../shared/data`` by default). Every sequence
there is found, not a fixed list, so that a default is judged on every sequence we have:
a folder laid out as a KITTI odometry sequence (``sequences/NN`` with ``image_*``
folders), a KITTI raw drive (``DATE/DATE_drive_NNNN_sync``) or an EuRoC sequence (with
``mav0/``, or ``cam0/`` directly), kept where `open_sequence` opens it with ground truth
and its frames follow each other. Each folder left out is printed with the reason: it
cannot be opened, it has no ground truth, or its frames are far apart somewhere (the
EuRoC loop pairs: four frames, 98 s apart, for place recognition, not a drive to track).
"""

import os
import re
from pathlib import Path

import numpy as np

from pld_slam.datasets import StereoSequence, open_sequence
from pld_slam.errors import PldSlamError

MAX_GAP_FRAMES = 10
"""Frames further apart than this many nominal frame periods somewhere make a set of
frames, not a sequence (KITTI's frame times wander by 5 %, a dropped frame doubles one)."""

KITTI_RAW_DRIVE = re.compile(r"(?P<date>\d{4}_\d{2}_\d{2})_drive_\d{4}_sync")


def data_dir() -> Path:
    """``$PLD_SLAM_DATA``, or ``../shared/data`` next to the repository."""
    return Path(os.environ.get("PLD_SLAM_DATA", Path(__file__).resolve().parents[2] / "shared" / "data"))


def is_sequence_folder(folder: Path) -> bool:
    """Whether ``folder`` is laid out as a KITTI odometry sequence, a KITTI raw drive or an EuRoC sequence.

    KITTI odometry: ``sequences/NN`` holding an ``image_*`` folder; KITTI raw:
    ``DATE/DATE_drive_NNNN_sync``; EuRoC: a folder with ``mav0/``, or with ``cam0/`` that is
    not itself the ``mav0`` of one.
    """
    if folder.parent.name == "sequences" and folder.name.isdigit():
        return any(child.is_dir() for child in folder.glob("image_*"))
    drive = KITTI_RAW_DRIVE.fullmatch(folder.name)
    if drive is not None:
        return folder.parent.name == drive["date"]
    return (folder / "mav0").is_dir() or ((folder / "cam0").is_dir() and folder.name != "mav0")


def sequence_folders(root: Path) -> list[Path]:
    """Every folder under ``root`` that `is_sequence_folder`, sorted; a sequence's own folders are not searched."""
    found = []
    for parent, children, _ in os.walk(root):
        if is_sequence_folder(Path(parent)):
            found.append(Path(parent))
            children.clear()
        else:
            children.sort()
    return sorted(found)


def largest_gap_frames(sequence: StereoSequence) -> float:
    """The largest step between frame times [frame periods at the nominal rate]; 0 without a rate."""
    if sequence.frame_rate.hz is None or len(sequence) < 2:
        return 0.0
    return float(np.max(np.diff(sequence.timestamps)) * sequence.frame_rate.hz)


def why_left_out(sequence: StereoSequence) -> str | None:
    """Why ``sequence`` is no benchmark sequence (no ground truth, frames far apart); None when it is one."""
    if sequence.groundtruth is None:
        return "no ground truth"
    gap = largest_gap_frames(sequence)
    if gap > MAX_GAP_FRAMES:
        return (f"frames up to {gap / sequence.frame_rate.hz:.3g} s apart ({gap:.0f} frame periods at "
                f"{sequence.frame_rate.hz:g} Hz): a set of frames, not a sequence")
    return None


def found_sequences(root: Path | None = None) -> list[tuple[Path, StereoSequence]]:
    """Each benchmark sequence under ``root`` (default `data_dir`) with its folder; the others printed with why.

    Returns
    -------
    list of (Path, StereoSequence)
        The folders `sequence_folders` lists whose sequence opens, has ground truth and
        has no gap over `MAX_GAP_FRAMES` frame periods, in folder order.
    """
    root = data_dir() if root is None else root
    if not root.is_dir():
        print(f"skipped the real extracts: {root} not found (set PLD_SLAM_DATA)")
        return []
    found = []
    for folder in sequence_folders(root):
        try:
            sequence = open_sequence(folder)
        except PldSlamError as error:
            print(f"skipped {folder}: cannot be opened ({error})")
            continue
        reason = why_left_out(sequence)
        if reason is None:
            found.append((folder, sequence))
        else:
            print(f"skipped {folder}: {reason}")
    return found


def named_extracts(relatives: tuple[str, ...]) -> list[Path]:
    """The folders of ``relatives`` (relative to `data_dir`) that exist; each missing one is printed."""
    found = []
    for relative in relatives:
        folder = data_dir() / relative
        if folder.is_dir():
            found.append(folder)
        else:
            print(f"skipped {folder}: not found (set PLD_SLAM_DATA)")
    return found


def existing_extracts(relatives: tuple[str, ...] | None = None) -> list[Path]:
    """The folders of the named extracts ``relatives`` found (`named_extracts`), or of every
    benchmark sequence (`found_sequences`) when None."""
    if relatives is not None:
        return named_extracts(relatives)
    return [folder for folder, _ in found_sequences()]


def real_sequences(relatives: tuple[str, ...] | None = None) -> list[StereoSequence]:
    """The `StereoSequence` of each named extract of ``relatives`` found, or of every benchmark
    sequence (`found_sequences`) when None."""
    if relatives is not None:
        return [open_sequence(folder) for folder in named_extracts(relatives)]
    return [sequence for _, sequence in found_sequences()]
