"""A frame's images and features, read and extracted one frame ahead in a background thread.

The front end has no state (`pld_slam.frontend`): a frame's features depend on its
images and the configuration only. So while the main thread tracks and maps frame i,
`FramePrefetcher` reads and extracts frame i + 1 in another thread, and the run gets the
same features, bit for bit, in less wall time: on KITTI 06 (2 cores) the front end's
50-55 ms per frame then mostly overlaps tracking and local mapping (the figures are in
the mapping benchmark, ``benchmarks/mapping.py``). ``system.prefetch: false`` reads and
extracts each frame when it is processed, for timing one stage at a time.

Why a thread and one frame ahead: OpenCV's ORB, LSD and LBD and the numba kernels
release the GIL, so the two threads share the two cores; a process would have to
pickle every frame's features back, and more frames ahead would only hold more images
in memory, since the main thread takes about as long per frame as the front end.

One reader at a time: a frame source may not be safe to read from two threads (a ROS
bag reader is one file handle), so the main thread reads a frame itself only after the
frame in flight, if any, is done.
"""

from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass

from pld_slam.config import Config
from pld_slam.datasets import StereoFrame, StereoSequence
from pld_slam.errors import DatasetError
from pld_slam.frontend import StereoFeatures, extract_stereo_features
from pld_slam.geometry.camera import StereoCamera
from pld_slam.timing import StageClock


@dataclass(frozen=True)
class ExtractedFrame:
    """One frame read and its features extracted, or why its images could not be used.

    Attributes
    ----------
    index : frame number in the sequence.
    frame : the rectified pair, None when it could not be read.
    features : its stereo features, None when it could not be read.
    error : why the frame could not be read (the `DatasetError` naming the file), else None.
    stage_ms : wall time [ms] of the stages that ran, wherever they ran: ``load``, then ``frontend``.
    """

    index: int
    frame: StereoFrame | None
    features: StereoFeatures | None
    error: DatasetError | None
    stage_ms: dict[str, float]


def extract_frame(sequence: StereoSequence, index: int, camera: StereoCamera, config: Config,
                  with_ggs: bool) -> ExtractedFrame:
    """Read frame ``index`` of ``sequence`` and extract its features (with its GGS when ``with_ggs``)."""
    clock = StageClock()
    try:
        frame = sequence[index]
    except DatasetError as error:
        clock.lap("load")
        return ExtractedFrame(index, None, None, error, clock.laps)
    clock.lap("load")
    features = extract_stereo_features(frame.left, frame.right, camera, config.points, config.lines,
                                       config.ggs if with_ggs else None)
    clock.lap("frontend")
    return ExtractedFrame(index, frame, features, None, clock.laps)


class FramePrefetcher:
    """Hands out `ExtractedFrame`s, extracting the one asked next in a background thread (module docstring).

    ``extract`` reads and extracts one frame by index. Call `take` for the frame about to
    be processed, then `prefetch` with the one that will follow; `close` when done.
    Without ``enabled``, `prefetch` does nothing and `take` extracts in the caller's thread.
    """

    def __init__(self, extract: Callable[[int], ExtractedFrame], enabled: bool = True) -> None:
        self._extract = extract
        self._executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix="pld-slam-frontend") if enabled else None
        self._pending: tuple[int, Future] | None = None

    def take(self, index: int) -> ExtractedFrame:
        """Frame ``index``: the one prefetched if it is that frame, else extracted now.

        An error other than an unreadable frame, raised while extracting in the
        background, is raised here.
        """
        pending, self._pending = self._pending, None
        if pending is not None:
            pending_index, future = pending
            extracted = future.result()  # also waits for a frame in flight before this thread reads one
            if pending_index == index:
                return extracted
        return self._extract(index)

    def prefetch(self, index: int) -> None:
        """Start extracting frame ``index`` in the background (nothing when prefetching is off)."""
        if self._executor is not None:
            if self._pending is not None:
                self._pending[1].result()
            self._pending = (index, self._executor.submit(self._extract, index))

    def close(self) -> None:
        """Drop the frame in flight, if any, and stop the background thread; `take` extracts in the
        caller's thread from then on."""
        self._pending = None
        if self._executor is not None:
            self._executor.shutdown(wait=True, cancel_futures=True)
            self._executor = None
