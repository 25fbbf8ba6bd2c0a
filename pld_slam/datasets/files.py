"""Files shared by the dataset layouts: image listings, PNG sizes, times files, and
ground truth sampled at frame times."""

import struct
from collections.abc import Callable
from pathlib import Path

import numpy as np

from pld_slam.errors import DatasetError
from pld_slam.trajectory import Trajectory

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_PNG_HEADER_BYTES = 24


def image_files(folder: Path, suffixes: tuple[str, ...]) -> list[Path]:
    """The files of ``folder`` with one of ``suffixes`` (lower case), sorted by name.

    A missing folder, or one without such files, raises `DatasetError` naming it.
    """
    if not folder.is_dir():
        raise DatasetError(f"{folder}: image folder not found")
    paths = sorted(path for path in folder.iterdir() if path.suffix.lower() in suffixes)
    if not paths:
        raise DatasetError(f"{folder}: no {' or '.join(suffixes)} images")
    return paths


def png_size(path: Path) -> tuple[int, int]:
    """``(width, height)`` [px] of a PNG file from its IHDR header, without decoding it."""
    with path.open("rb") as file:
        header = file.read(_PNG_HEADER_BYTES)
    if (
        len(header) < _PNG_HEADER_BYTES
        or not header.startswith(_PNG_SIGNATURE)
        or header[12:16] != b"IHDR"
    ):
        raise DatasetError(f"{path}: not a PNG image (cannot read the image size)")
    width, height = struct.unpack(">II", header[16:24])
    return width, height


def read_times(
    path: Path, n_frames: int, parse_line: Callable[[str], float] = float
) -> np.ndarray:
    """Frame times (N,) [s] from a file of one time per line (blank lines skipped).

    Parameters
    ----------
    path : Path
        The times file.
    n_frames : int
        The number of image pairs, which the number of times must equal.
    parse_line : callable
        Turns the text of one line into seconds; raises ValueError on bad text. Plain
        numbers by default (KITTI odometry ``times.txt``).

    Raises `DatasetError` naming the file (and line) when it is missing, a line does not
    parse, the count differs from ``n_frames`` or the times do not increase strictly.
    """
    if not path.is_file():
        raise DatasetError(f"{path}: times file not found")
    numbered = [
        (number, line.strip())
        for number, line in enumerate(path.read_text().splitlines(), start=1)
        if line.strip()
    ]
    times = np.array([_parse_time(path, number, text, parse_line) for number, text in numbered])
    if len(times) != n_frames:
        raise DatasetError(f"{path}: {len(times)} times for {n_frames} image pairs")
    not_increasing = np.flatnonzero(np.diff(times) <= 0.0)
    if not_increasing.size:
        raise DatasetError(f"{path}:{numbered[not_increasing[0] + 1][0]}: times must increase strictly")
    return times


def _parse_time(
    path: Path, line_number: int, text: str, parse_line: Callable[[str], float]
) -> float:
    """The time [s] written on one line of a times file."""
    try:
        return parse_line(text)
    except ValueError:
        raise DatasetError(f"{path}:{line_number}: not a time: {text[:40]!r}") from None


def groundtruth_at_frames(
    trajectory: Trajectory, times: np.ndarray, max_offset: float, source: Path
) -> Trajectory:
    """The pose of ``trajectory`` nearest to each of ``times`` (N,) [s], stamped with that time.

    Times whose nearest pose is more than ``max_offset`` [s] away are left out; when all
    are, `DatasetError` names ``source``, the ground-truth file.
    """
    stamps = trajectory.timestamps
    after = np.clip(np.searchsorted(stamps, times), 0, len(stamps) - 1)
    before = np.clip(after - 1, 0, len(stamps) - 1)
    nearest = np.where(
        np.abs(stamps[after] - times) < np.abs(stamps[before] - times), after, before
    )
    within = np.abs(stamps[nearest] - times) <= max_offset
    if not within.any():
        raise DatasetError(
            f"{source}: no ground-truth pose within {max_offset * 1e3:g} ms of any frame time"
        )
    return Trajectory(times[within], trajectory.poses[nearest[within]])
