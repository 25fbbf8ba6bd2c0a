"""`StereoSequence`: the one interface every dataset layout is read into.

A sequence knows its rectified `StereoCamera`, the timestamp of every frame, its nominal
`FrameRate`, where its raw stereo pairs come from (a `FrameSource`: image files, or the
messages of a ROS bag), and (where the dataset has it) ground truth ``T_w_c`` of the
rectified left camera with the first ground-truth pose at identity. Images are read only
when a frame is asked for, so opening a 4,541-frame KITTI sequence costs a directory
listing.

A frame is produced in three steps: the source reads the raw pair (checked to be of the
calibrated size), the rectifier (if any) rectifies it, and `StereoSequence.scaled`
sequences shrink it to the scaled camera's size.
"""

import os
import sys
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import ClassVar, Protocol

import cv2
import numpy as np

from pld_slam.errors import DatasetError
from pld_slam.geometry.camera import StereoCamera
from pld_slam.trajectory import Trajectory

Rectifier = Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]
"""Maps a raw (left, right) grey pair to the rectified pair."""


@dataclass(frozen=True)
class StereoFrame:
    """One rectified grey stereo pair: ``left`` and ``right`` are (H, W) uint8."""

    index: int
    timestamp: float
    left: np.ndarray
    right: np.ndarray


@dataclass(frozen=True)
class FrameRate:
    """A sequence's nominal frame rate and where it comes from.

    Attributes
    ----------
    hz : float or None
        Frames per second; None when it cannot be told (a single frame and no nominal rate).
    source : str
        Where the rate was read, for reports: ``"KITTI nominal rate"``, ``"fps of calib.yaml"``,
        ``"median step of the frame times"``.
    """

    hz: float | None
    source: str

    @classmethod
    def from_times(cls, timestamps: np.ndarray, source: str) -> "FrameRate":
        """The rate of frame times (N,) [s]: one over their median step (None for one frame).

        The median, not the mean, so that a few dropped frames do not lower the rate.
        """
        if len(timestamps) < 2:
            return cls(None, source)
        return cls(1.0 / float(np.median(np.diff(timestamps))), source)

    def every(self, step: int) -> "FrameRate":
        """The rate of every ``step``-th frame."""
        if step == 1 or self.hz is None:
            return self
        return FrameRate(self.hz / step, f"{self.source}, every {step} frames")


def read_grey(path: Path, from_colour: bool = False) -> np.ndarray:
    """Read an image file as (H, W) uint8 grey, or raise `DatasetError` naming the file.

    ``from_colour``: the file is a colour image, converted as `decode_grey` says.
    """
    try:
        data = np.fromfile(path, dtype=np.uint8)
    except OSError as error:
        raise DatasetError(f"{path}: cannot read image ({error.strerror or error})") from None
    if data.size == 0:
        raise DatasetError(f"{path}: cannot read image (empty file)")
    return decode_grey(data, str(path), from_colour)


def decode_grey(data: np.ndarray, source: str, from_colour: bool = False) -> np.ndarray:
    """Decode the bytes (K,) uint8 of an encoded image (PNG, JPEG, ...) as (H, W) uint8 grey.

    ``source`` (a file, or a bag message) is named in the `DatasetError` raised for
    missing or undecodable bytes. We decode with ``cv2.imdecode`` under
    `_native_stderr_discarded`, because the decoders OpenCV calls print to the process's
    stderr on bad bytes (libpng's ``libpng error: Read Error`` for a truncated file),
    noise around the one line that names the source and the problem.

    ``from_colour`` (KITTI's colour pair): the image is decoded in colour and converted
    with ``cv2.cvtColor(BGR2GRAY)``, as ORB-SLAM2 converts its colour input. Decoding
    straight to grey lets libpng convert instead, with its own rounding: 1 grey level
    off in half the pixels of a random colour PNG.
    """
    if data.size == 0:
        raise DatasetError(f"{source}: cannot read image (no data)")
    with _native_stderr_discarded():
        image = cv2.imdecode(data, cv2.IMREAD_COLOR if from_colour else cv2.IMREAD_GRAYSCALE)
    if image is None:
        raise DatasetError(f"{source}: cannot read image (not an image, or corrupt)")
    return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if from_colour else image


@contextmanager
def _native_stderr_discarded() -> Iterator[None]:
    """Send what native code writes to file descriptor 2 (stderr) to the null device meanwhile.

    libpng reports a corrupt file on stderr itself, not through OpenCV's log, so neither
    OpenCV's log level nor Python's ``sys.stderr`` reaches it; only the descriptor does.
    Python's own ``sys.stderr`` is flushed first so that nothing written before is lost.
    """
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        with open(os.devnull, "wb") as devnull:
            os.dup2(devnull.fileno(), 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)


def check_calibrated_size(source: str, image: np.ndarray, size: tuple[int, int]) -> None:
    """Raise `DatasetError` naming ``source`` when ``image`` is not ``size`` = (width, height) [px].

    Images of another size would be tracked with intrinsics that do not describe them
    (and a rectifier's pixel maps of another size), silently wrong; a raw image's size is
    its rectified size (`pld_slam.datasets.rectify`), so one check serves every layout.
    """
    height, width = image.shape
    if (width, height) != tuple(size):
        raise DatasetError(
            f"{source}: image is {width}x{height} but the calibration is for {size[0]}x{size[1]}"
        )


class FrameSource(Protocol):
    """Where the raw stereo pairs of a sequence come from, read one frame at a time.

    Every folder layout stores image files (`ImageFiles`); a ROS bag stores messages
    (`pld_slam.datasets.rosbag.BagImages`). `StereoSequence` rectifies and scales what
    the source reads, so a source only reads and decodes.

    ``forks_safely`` says whether a forked child process may read frames while the parent
    holds the source open (`pld_slam.frame_extraction` extracts in one).
    """

    forks_safely: ClassVar[bool]

    def __len__(self) -> int:
        """The number of stereo pairs."""

    def read(self, index: int) -> tuple[np.ndarray, np.ndarray]:
        """The raw (H, W) uint8 grey (left, right) pair of frame ``index``, of the calibrated size.

        Raises `DatasetError` naming the unreadable image or the one of another size (the
        left one when both are).
        """

    def describe(self, index: int) -> str:
        """Where the left image of frame ``index`` comes from (a file, a bag message), for messages."""

    def select(self, indices: np.ndarray) -> "FrameSource":
        """The source of frames ``indices`` (K,) only, in that order."""


@dataclass(frozen=True)
class ImageFiles:
    """Stereo pairs stored as one image file per camera and frame (every folder layout).

    Attributes
    ----------
    left_paths, right_paths : sequence of Path
        (N,) image files of the left and right cameras, paired by position.
    size : tuple of int
        ``(width, height)`` [px] of the calibration, which every image must have.
    colour : bool
        The files are colour images, read as grey (`decode_grey`'s ``from_colour``).
    """

    forks_safely: ClassVar[bool] = True
    """Each read opens its own file, so a forked child reads as the parent does."""

    left_paths: Sequence[Path]
    right_paths: Sequence[Path]
    size: tuple[int, int]
    colour: bool = False

    def __post_init__(self) -> None:
        if len(self.left_paths) != len(self.right_paths):
            folder = self.left_paths[0].parent if self.left_paths else self.right_paths[0].parent
            raise DatasetError(
                f"{folder}: {len(self.left_paths)} left images but {len(self.right_paths)} right images"
            )

    def __len__(self) -> int:
        return len(self.left_paths)

    def read(self, index: int) -> tuple[np.ndarray, np.ndarray]:
        """The grey pair of frame ``index`` (`read_grey`), each checked to be of the calibrated size."""
        return self._read_calibrated(self.left_paths[index]), self._read_calibrated(self.right_paths[index])

    def _read_calibrated(self, path: Path) -> np.ndarray:
        """The grey image of ``path``, checked to be of the calibrated size."""
        image = read_grey(path, self.colour)
        check_calibrated_size(str(path), image, self.size)
        return image

    def describe(self, index: int) -> str:
        return str(self.left_paths[index])

    def select(self, indices: np.ndarray) -> "ImageFiles":
        return replace(
            self,
            left_paths=[self.left_paths[i] for i in indices],
            right_paths=[self.right_paths[i] for i in indices],
        )


@dataclass(frozen=True)
class StereoSequence:
    """A stereo sequence, read lazily frame by frame.

    Attributes
    ----------
    name : str
        Short name for reports (e.g. ``kitti_06``).
    layout : str
        Detected layout: ``kitti_odometry``, ``kitti_raw``, ``euroc``, ``generic``,
        ``argoverse`` or ``rosbag``.
    root : Path
        The folder (or bag file) the sequence was opened from.
    camera : StereoCamera
        The rectified stereo camera the frames are delivered in (scaled by ``scale``).
    timestamps : np.ndarray
        (N,) frame times [s], strictly increasing.
    frame_rate : FrameRate
        The nominal frame rate (the dataset's, or measured from the times where the
        dataset states none); the real-time factor of a run is measured against it.
    frames : FrameSource
        Reads the (N,) raw stereo pairs.
    groundtruth : Trajectory or None
        ``T_w_c`` of the rectified left camera at (a subset of) the frame times, first
        ground-truth pose = identity; None where the dataset has none.
    rectifier : callable or None
        Applied to each raw pair (EuRoC, unrectified generic rigs and bags); None when the
        source is already rectified.
    dynamic_mask_paths : sequence of Path or None
        (N,) masks of the left images, non-zero where a pixel belongs to a moving object
        (synthetic sequences only).
    scale : float
        The factor (`scaled`) the rectified images are resized by before delivery; 1 as read.
    cameras : str or None
        Which of the rig's stereo pairs the frames come from, where it has two: KITTI's
        ``grey`` or ``colour`` pair (`pld_slam.datasets.kitti_cameras`); None for a rig of
        one pair. The camera and the ground truth are those of the pair's left camera.
    """

    name: str
    layout: str
    root: Path
    camera: StereoCamera
    timestamps: np.ndarray
    frame_rate: FrameRate
    frames: FrameSource = field(repr=False)
    groundtruth: Trajectory | None = None
    rectifier: Rectifier | None = field(default=None, repr=False)
    dynamic_mask_paths: Sequence[Path] | None = None
    scale: float = 1.0
    cameras: str | None = None

    def __post_init__(self) -> None:
        if len(self.timestamps) != len(self.frames):
            raise DatasetError(f"{self.root}: {len(self.timestamps)} timestamps for {len(self.frames)} image pairs")
        if len(self.frames) == 0:
            raise DatasetError(f"{self.root}: no images")

    def __len__(self) -> int:
        return len(self.frames)

    def __getitem__(self, index: int) -> StereoFrame:
        """Read, rectify where needed and scale frame ``index``.

        An unreadable image, or one of another size than the calibration's
        (`check_calibrated_size`), raises `DatasetError` naming it (the left one when
        both are); a run skips such a frame (`pld_slam.system.System.process_frame`).
        """
        if not -len(self) <= index < len(self):
            raise IndexError(f"frame {index} out of range for {len(self)} frames")
        index %= len(self)
        left, right = self.frames.read(index)
        if self.rectifier is not None:
            left, right = self.rectifier(left, right)
        if self.scale != 1.0:
            left, right = (self._resized(image, cv2.INTER_AREA) for image in (left, right))
        return StereoFrame(index, float(self.timestamps[index]), left, right)

    def _resized(self, image: np.ndarray, interpolation: int) -> np.ndarray:
        """``image`` resized to the camera's size."""
        return cv2.resize(image, (self.camera.width, self.camera.height), interpolation=interpolation)

    def __iter__(self) -> Iterator[StereoFrame]:
        for index in range(len(self)):
            yield self[index]

    def scaled(self, factor: float) -> "StereoSequence":
        """The sequence with its frames and camera resized by ``factor`` (0 < factor <= 1).

        Each rectified frame is resized with ``cv2.INTER_AREA`` (an average over the
        pixels each new pixel covers: no aliasing when shrinking) to the size of
        `StereoCamera.scaled`, whose intrinsics follow the resize; the baseline is
        unchanged. Dynamic masks follow with nearest-neighbour resizing. For images too
        large to track at full size (Argoverse's 2464 x 2056).
        """
        if not 0.0 < factor <= 1.0:
            raise DatasetError(f"{self.root}: scale must be in (0, 1], got {factor:g}")
        if factor == 1.0:
            return self
        return replace(self, camera=self.camera.scaled(factor), scale=self.scale * factor)

    def subsequence(self, start: int = 0, step: int = 1) -> "StereoSequence":
        """Every ``step``-th frame from frame ``start``, with the ground truth re-based on the first.

        Frames keep their timestamps; the ground truth keeps its poses from the first kept
        frame's time on, moved so that the pose at that time is the identity (the world of
        a run is its first camera). Ground truth without a pose within 10 ms of the first
        kept frame cannot be re-based and is dropped. The frame rate is divided by
        ``step``. The name says which frames were kept (``kitti_06_from10_every2``). For
        checks of tracking from a moving start or with dropped frames.
        """
        if not 0 <= start < len(self) or step < 1:
            raise DatasetError(f"{self.root}: no frames from {start} every {step} in {len(self)} frames")
        keep = np.arange(start, len(self), step)
        masks = None if self.dynamic_mask_paths is None else [self.dynamic_mask_paths[i] for i in keep]
        return replace(
            self,
            name=f"{self.name}_from{start}_every{step}",
            timestamps=self.timestamps[keep],
            frame_rate=self.frame_rate.every(step),
            frames=self.frames.select(keep),
            groundtruth=_rebased_from(self.groundtruth, float(self.timestamps[start])),
            dynamic_mask_paths=masks,
        )

    def dynamic_mask(self, index: int) -> np.ndarray | None:
        """Boolean (H, W) mask of moving-object pixels in left frame ``index``, or None."""
        if self.dynamic_mask_paths is None:
            return None
        mask = read_grey(self.dynamic_mask_paths[index])
        if self.scale != 1.0:
            mask = self._resized(mask, cv2.INTER_NEAREST)
        return mask > 0


def _rebased_from(groundtruth: Trajectory | None, start_time: float) -> Trajectory | None:
    """``groundtruth`` from ``start_time`` [s] on, its pose there the identity; None without one within 10 ms."""
    if groundtruth is None:
        return None
    later = groundtruth.timestamps >= start_time - 0.01
    if not later.any() or abs(groundtruth.timestamps[later][0] - start_time) > 0.01:
        return None
    return Trajectory(groundtruth.timestamps[later], groundtruth.poses[later]).relative_to_first()
