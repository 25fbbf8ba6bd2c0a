"""`StereoSequence`: the one interface every dataset layout is read into.

A sequence knows its rectified `StereoCamera`, the timestamp of every frame, the image
files, and (where the dataset has it) ground truth ``T_w_c`` of the rectified left camera
with the first ground-truth pose at identity. Images are read only when a frame is asked
for, so opening a 4,541-frame KITTI sequence costs a directory listing.
"""

import os
import sys
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path

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


def read_grey(path: Path) -> np.ndarray:
    """Read an image file as (H, W) uint8 grey, or raise `DatasetError` naming the file.

    We read the bytes ourselves and decode them with ``cv2.imdecode`` under
    `_native_stderr_discarded`, because ``cv2.imread`` and the decoders it calls print to
    the process's stderr on a bad file (OpenCV's ``WARN`` line for a missing one, libpng's
    ``libpng error: Read Error`` for a truncated one), noise around the one line that
    names the file and the problem.
    """
    try:
        data = np.fromfile(path, dtype=np.uint8)
    except OSError as error:
        raise DatasetError(f"{path}: cannot read image ({error.strerror or error})") from None
    if data.size == 0:
        raise DatasetError(f"{path}: cannot read image (empty file)")
    with _native_stderr_discarded():
        image = cv2.imdecode(data, cv2.IMREAD_GRAYSCALE)
    if image is None:
        raise DatasetError(f"{path}: cannot read image (not an image, or corrupt)")
    return image


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


def _check_calibrated_size(path: Path, image: np.ndarray, camera: StereoCamera) -> None:
    """Raise `DatasetError` naming ``path`` when ``image`` is not of the calibration's size.

    Images of another size would be tracked with intrinsics that do not describe them
    (and a rectifier's pixel maps of another size), silently wrong; a raw image's size is
    its rectified size (`pld_slam.datasets.rectify`), so one check serves every layout.
    """
    height, width = image.shape
    if (width, height) != (camera.width, camera.height):
        raise DatasetError(
            f"{path}: image is {width}x{height} but the calibration is for {camera.width}x{camera.height}"
        )


@dataclass(frozen=True)
class StereoSequence:
    """A stereo sequence on disk, read lazily frame by frame.

    Attributes
    ----------
    name : str
        Short name for reports (e.g. ``kitti_06``).
    layout : str
        Detected layout: ``kitti_odometry``, ``kitti_raw``, ``euroc`` or ``generic``.
    root : Path
        The folder the sequence was opened from.
    camera : StereoCamera
        The rectified stereo camera the frames are delivered in.
    timestamps : np.ndarray
        (N,) frame times [s], strictly increasing.
    left_paths, right_paths : sequence of Path
        (N,) image files of the left and right cameras.
    groundtruth : Trajectory or None
        ``T_w_c`` of the rectified left camera at (a subset of) the frame times, first
        ground-truth pose = identity; None where the dataset has none.
    rectifier : callable or None
        Applied to each raw pair (EuRoC and unrectified generic rigs); None when the
        files are already rectified.
    dynamic_mask_paths : sequence of Path or None
        (N,) masks of the left images, non-zero where a pixel belongs to a moving object
        (synthetic sequences only).
    """

    name: str
    layout: str
    root: Path
    camera: StereoCamera
    timestamps: np.ndarray
    left_paths: Sequence[Path]
    right_paths: Sequence[Path]
    groundtruth: Trajectory | None = None
    rectifier: Rectifier | None = field(default=None, repr=False)
    dynamic_mask_paths: Sequence[Path] | None = None

    def __post_init__(self) -> None:
        if len(self.left_paths) != len(self.right_paths):
            raise DatasetError(
                f"{self.root}: {len(self.left_paths)} left images but "
                f"{len(self.right_paths)} right images"
            )
        if len(self.timestamps) != len(self.left_paths):
            raise DatasetError(
                f"{self.root}: {len(self.timestamps)} timestamps for "
                f"{len(self.left_paths)} image pairs"
            )
        if len(self.left_paths) == 0:
            raise DatasetError(f"{self.root}: no images")

    def __len__(self) -> int:
        return len(self.left_paths)

    def __getitem__(self, index: int) -> StereoFrame:
        """Read, and rectify where needed, frame ``index``.

        An unreadable image, or one of another size than the calibration's
        (`_check_calibrated_size`), raises `DatasetError` naming that file (the left one
        when both are); a run skips such a frame (`pld_slam.system.System.process_frame`).
        """
        if not -len(self) <= index < len(self):
            raise IndexError(f"frame {index} out of range for {len(self)} frames")
        index %= len(self)
        left, right = (self._read_calibrated(paths[index]) for paths in (self.left_paths, self.right_paths))
        if self.rectifier is not None:
            left, right = self.rectifier(left, right)
        return StereoFrame(index, float(self.timestamps[index]), left, right)

    def _read_calibrated(self, path: Path) -> np.ndarray:
        """The grey image of ``path`` (`read_grey`), checked to be of the calibration's size."""
        image = read_grey(path)
        _check_calibrated_size(path, image, self.camera)
        return image

    def __iter__(self) -> Iterator[StereoFrame]:
        for index in range(len(self)):
            yield self[index]

    def subsequence(self, start: int = 0, step: int = 1) -> "StereoSequence":
        """Every ``step``-th frame from frame ``start``, with the ground truth re-based on the first.

        Frames keep their timestamps; the ground truth keeps its poses from the first kept
        frame's time on, moved so that the pose at that time is the identity (the world of
        a run is its first camera). Ground truth without a pose within 10 ms of the first
        kept frame cannot be re-based and is dropped. The name says which frames were kept
        (``kitti_06_from10_every2``). For checks of tracking from a moving start or with
        dropped frames.
        """
        if not 0 <= start < len(self) or step < 1:
            raise DatasetError(f"{self.root}: no frames from {start} every {step} in {len(self)} frames")
        keep = np.arange(start, len(self), step)
        masks = None if self.dynamic_mask_paths is None else [self.dynamic_mask_paths[i] for i in keep]
        return replace(
            self,
            name=f"{self.name}_from{start}_every{step}",
            timestamps=self.timestamps[keep],
            left_paths=[self.left_paths[i] for i in keep],
            right_paths=[self.right_paths[i] for i in keep],
            groundtruth=_rebased_from(self.groundtruth, float(self.timestamps[start])),
            dynamic_mask_paths=masks,
        )

    def dynamic_mask(self, index: int) -> np.ndarray | None:
        """Boolean (H, W) mask of moving-object pixels in left frame ``index``, or None."""
        if self.dynamic_mask_paths is None:
            return None
        return read_grey(self.dynamic_mask_paths[index]) > 0


def _rebased_from(groundtruth: Trajectory | None, start_time: float) -> Trajectory | None:
    """``groundtruth`` from ``start_time`` [s] on, its pose there the identity; None without one within 10 ms."""
    if groundtruth is None:
        return None
    later = groundtruth.timestamps >= start_time - 0.01
    if not later.any() or abs(groundtruth.timestamps[later][0] - start_time) > 0.01:
        return None
    return Trajectory(groundtruth.timestamps[later], groundtruth.poses[later]).relative_to_first()
