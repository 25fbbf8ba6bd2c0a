"""Files shared by the dataset layouts: image listings in natural name order, left/right
pairing, PNG sizes, times files, and ground truth sampled at frame times."""

import math
import re
import struct
from collections.abc import Callable, Hashable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import BinaryIO

import numpy as np

from pld_slam.errors import DatasetError, read_user_text
from pld_slam.trajectory import Trajectory

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_PNG_HEADER_BYTES = 24


def natural_key(name: str) -> tuple:
    """Sort key of a file name in natural order: digit runs compare as numbers, text case-insensitively.

    ``"img2.png" < "img10.png"``; the name itself is the last element, so the order is
    total (``"01.png"`` and ``"1.png"`` still sort the same way every time).
    """
    parts = re.split(r"(\d+)", name)
    return tuple(int(part) if index % 2 else part.casefold() for index, part in enumerate(parts)), name


def natural_sorted(paths: Iterable[Path]) -> list[Path]:
    """``paths`` in natural order of their file names (`natural_key`): ``2.png`` before ``10.png``."""
    return sorted(paths, key=lambda path: natural_key(path.name))


def image_files(folder: Path, suffixes: tuple[str, ...]) -> list[Path]:
    """The files of ``folder`` with one of ``suffixes`` (lower case), in natural name order
    (`natural_sorted`: frames named ``0.png ... 11.png`` are read in that order).

    A missing folder, or one without such files, raises `DatasetError` naming it.
    """
    if not folder.is_dir():
        raise DatasetError(f"{folder}: image folder not found")
    paths = natural_sorted(path for path in folder.iterdir() if path.suffix.lower() in suffixes)
    if not paths:
        raise DatasetError(f"{folder}: no {' or '.join(suffixes)} images")
    return paths


def paired_image_folders(
    left_folder: Path, right_folder: Path, suffixes: tuple[str, ...]
) -> tuple[list[Path], list[Path]]:
    """The images of two folders (`image_files`) paired by file name (`paired_images`).

    Names must match exactly, suffix included (``000002.png`` pairs with ``000002.png``
    only), as every folder layout we read names both sides alike.
    """
    left = {path.name: path for path in image_files(left_folder, suffixes)}
    right = {path.name: path for path in image_files(right_folder, suffixes)}
    return paired_images(left, right, (left_folder, right_folder), "name")


def paired_images(
    left: Mapping[Hashable, Path],
    right: Mapping[Hashable, Path],
    sources: tuple[Path, Path],
    key: str,
) -> tuple[list[Path], list[Path]]:
    """The left and right image files paired by equal keys, in the left list's order (its
    frame order: the timestamps of EuRoC's ``data.csv`` rows stay aligned with the paths).

    Every layout pairs its images here: by file name (`paired_image_folders`: KITTI odometry,
    KITTI raw, generic) or by timestamp (EuRoC's ``data.csv``). We pair by key, never by
    position, because a frame missing on each side leaves the counts equal and would
    shift every later pair by one without any error, and the run would silently track
    wrong stereo pairs.

    Parameters
    ----------
    left, right : mapping of key to Path
        The image files of each camera by key (sortable, e.g. a name or integer ns).
    sources : (Path, Path)
        Where the left and right lists come from (folders or image lists), for messages.
    key : str
        What the key is (``name``, ``timestamp``), for messages.

    Raises `DatasetError` naming the first file (in key order) that has no partner,
    where its partner was looked for and, for a list file, the list that names it.
    """
    unpaired = sorted(left.keys() ^ right.keys())
    if unpaired:
        first = unpaired[0]
        path, own, other = (left[first], *sources) if first in left else (right[first], *reversed(sources))
        listed = f"; {path.name} is listed in {own}" if own.is_file() else ""
        raise DatasetError(f"{path}: no image with the same {key} in {other}{listed}")
    return list(left.values()), [right[k] for k in left]


def first_image_size(paths: Sequence[Path], image_size: Callable[[Path], tuple[int, int]]) -> tuple[int, int]:
    """``(width, height)`` [px] of the first of ``paths`` whose header ``image_size`` reads (`png_size`,
    `jpeg_size`): the size of a sequence's images.

    A first image that cannot be read (a broken link, an empty file, not the format its
    name says) does not stop the sequence: the run skips that frame as it skips any
    unreadable one, and its world is the first usable frame. `DatasetError` naming the
    folder and the first image's problem when no image's size can be read.
    """
    first_error = None
    for path in paths:
        try:
            return image_size(path)
        except DatasetError as error:
            first_error = first_error or error
    raise DatasetError(f"{paths[0].parent}: no image whose size can be read, the first: {first_error}")


def png_size(path: Path) -> tuple[int, int]:
    """``(width, height)`` [px] of a PNG file from its IHDR header, without decoding it."""
    with _opened_image(path) as file:
        header = file.read(_PNG_HEADER_BYTES)
    if (
        len(header) < _PNG_HEADER_BYTES
        or not header.startswith(_PNG_SIGNATURE)
        or header[12:16] != b"IHDR"
    ):
        raise DatasetError(f"{path}: not a PNG image (cannot read the image size)")
    width, height = struct.unpack(">II", header[16:24])
    return width, height


def _opened_image(path: Path) -> BinaryIO:
    """``path`` opened for reading bytes; `DatasetError` naming it when it cannot be (missing, a broken link,
    no permission)."""
    try:
        return path.open("rb")
    except OSError as error:
        raise DatasetError(f"{path}: cannot read image ({error.strerror or error})") from None


_JPEG_START = b"\xff\xd8"
_JPEG_FRAME_MARKERS = frozenset(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}
"""Start-of-frame markers SOF0..SOF15 (C4 = Huffman tables, C8 = reserved, CC = arithmetic coding)."""


def jpeg_size(path: Path) -> tuple[int, int]:
    """``(width, height)`` of a JPEG file from its start-of-frame segment, without decoding it.

    Walks the segments from the start of the file (a few hundred bytes in practice).
    """
    with _opened_image(path) as file:
        if file.read(2) != _JPEG_START:
            raise DatasetError(f"{path}: not a JPEG image (cannot read the image size)")
        while len(segment := file.read(4)) == 4 and segment[0] == 0xFF:
            marker, length = segment[1], struct.unpack(">H", segment[2:])[0]
            if marker in _JPEG_FRAME_MARKERS:
                header = file.read(5)  # precision (1 byte), height, width
                if len(header) == 5:
                    height, width = struct.unpack(">HH", header[1:])
                    return width, height
                break
            file.seek(length - 2, 1)
    raise DatasetError(f"{path}: JPEG without a frame header (cannot read the image size)")


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
    parse or is not finite (``nan``, ``inf``), the count differs from ``n_frames`` or the
    times do not increase strictly.
    """
    if not path.is_file():
        raise DatasetError(f"{path}: times file not found")
    numbered = [
        (number, line.strip())
        for number, line in enumerate(read_user_text(path, DatasetError, "times").splitlines(), start=1)
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
    """The time [s] written on one line of a times file; finite (``nan`` and ``inf`` raise)."""
    try:
        seconds = parse_line(text)
    except ValueError:
        raise DatasetError(f"{path}:{line_number}: not a time: {text[:40]!r}") from None
    if not math.isfinite(seconds):
        raise DatasetError(f"{path}:{line_number}: not a finite time: {text[:40]!r}")
    return seconds


def groundtruth_at_frames(
    trajectory: Trajectory, times: np.ndarray, max_offset: float, source: Path | str
) -> Trajectory:
    """The pose of ``trajectory`` nearest to each of ``times`` (N,) [s], stamped with that time.

    Times whose nearest pose is more than ``max_offset`` [s] away are left out; when all
    are, `DatasetError` names ``source``, the ground-truth file (or bag topic).
    """
    nearest = nearest_within(trajectory.timestamps, times, max_offset)
    within = nearest >= 0
    if not within.any():
        raise DatasetError(
            f"{source}: no ground-truth pose within {max_offset * 1e3:g} ms of any frame time"
        )
    return Trajectory(times[within], trajectory.poses[nearest[within]])


def nearest_within(stamps: np.ndarray, times: np.ndarray, max_offset: float) -> np.ndarray:
    """For each of ``times`` (N,), the index of the nearest of ``stamps`` (M,), -1 when farther than ``max_offset``.

    ``stamps`` must be sorted; both in the same unit (seconds, or integer nanoseconds).
    """
    after = np.clip(np.searchsorted(stamps, times), 0, len(stamps) - 1)
    before = np.clip(after - 1, 0, len(stamps) - 1)
    nearest = np.where(np.abs(stamps[after] - times) < np.abs(stamps[before] - times), after, before)
    return np.where(np.abs(stamps[nearest] - times) <= max_offset, nearest, -1)
