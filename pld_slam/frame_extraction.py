"""A frame's images and features, read and extracted a few frames ahead in a background worker.

The front end has no state (`pld_slam.frontend`): a frame's features depend on its
images and the configuration only. So while the main thread tracks and maps frame i,
`FramePrefetcher` reads and extracts the next frames in a background worker, and the run
gets the same features, bit for bit, in less wall time. ``system.prefetch: false`` reads
and extracts each frame when it is processed, for timing one stage at a time.

The worker (``system.prefetch_worker``) is a forked child process by default, else a
thread. A thread shares the GIL with tracking and mapping (OpenCV and the numba kernels
release it, the Python between them does not), so on two cores the front end in a thread
and the main thread slow each other down; a process has its own interpreter, and costs
only the pickling of each frame's images and features (1.1 MB and 0.3 ms on KITTI). The
figures are below.

Forking is safe only in some places, and elsewhere the worker is a thread
(`background_worker`):

- the platform must be Linux: Windows cannot fork, and on macOS Apple's system libraries
  (which OpenCV's threads use there) are not safe in a forked child, which is why Python
  does not fork there by default;
- no other Python thread may run when it forks (tqdm's progress-bar monitor aside): a lock
  that another thread holds at the fork (numba's compiler lock, a logging handler's) stays
  locked forever in the child. So the child is forked when the prefetcher is made, before
  the run starts any thread, and a program that runs several sequences in threads, or a
  notebook, gets a thread;
- the process must not be a daemon (a `multiprocessing.Pool` worker), which may not have
  children;
- the frame source must be readable from two processes (``FrameSource.forks_safely``):
  files opened per read are; a ROS bag's open reader (one file offset, one SQLite
  connection shared by the parent and the child) is not.

OpenCV's own worker threads are not Python threads, but a child forked after them would
inherit OpenCV's pool without them: it would believe it has workers that do not exist
(its parallel loops then happen to run on the calling thread alone, but resizing the
pool joins threads that are not there, and hung the child). So OpenCV's workers are
stopped for the fork (``cv2.setNumThreads(1)``), and only the parent restarts them. The
child keeps OpenCV on one thread: the front end's own two threads (left and right image)
fill one core, and the main thread needs the other. KITTI 06, three interleaved runs,
mean / median ms per frame: 98 / 65, against 105 / 64 with two OpenCV threads in the
child; synthetic static, two runs: 70 / 36 against 74 / 40.

The child ignores Ctrl-C (the parent stops the run and shuts it down) and is killed when
the parent is (a time limit's kill: it would otherwise wait for work forever). A child that
cannot start, or dies (killed, out of memory), costs only speed: the frames in flight are
extracted again, the one asked for in the caller's thread, and from then on the worker is a
thread (`FramePrefetcher.worker`, ``frontend_worker`` in ``summary.json``).

Why ``system.prefetch_frames`` (3) frames ahead: the main thread's time per frame is uneven (a
keyframe's local mapping and BA more than doubles it), and with one frame ahead the worker
sat idle through a keyframe and the main thread then waited for it on the next frames. On
KITTI 06 (2 cores, mean / median ms per frame, medians of two interleaved runs each):
process 1 frame ahead 103 / 86, 2 ahead 101 / 66, 3 ahead 91-93 / 58, 5 ahead 92 / 60; a
thread 1 ahead 106 / 85, 3 ahead 108 / 80; no prefetching 124-125 / 105-108. A frame in
flight holds its images and features, about 1 MB on KITTI.

One reader at a time: a frame source may not be safe to read from two threads at once,
so the main thread reads a frame itself only after the frames in flight, if any, are done.
"""

import multiprocessing
import os
import signal
import sys
import threading
from collections import deque
from collections.abc import Callable, Iterable
from concurrent.futures import Executor, Future, ProcessPoolExecutor, ThreadPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from typing import Literal

import cv2
from tqdm import tqdm

from pld_slam.blas import one_blas_thread
from pld_slam.config import Config
from pld_slam.datasets import StereoFrame, StereoSequence
from pld_slam.datasets.base import FrameSource
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


BackgroundWorker = Literal["process", "thread"]
"""Where `FramePrefetcher` extracts ahead (module docstring)."""


def background_worker(requested: BackgroundWorker, source: FrameSource) -> BackgroundWorker:
    """``requested``, unless it is a process and forking here is not safe (module docstring): then a thread.

    A frame source that does not say whether it forks safely (``forks_safely``) is taken
    not to.
    """
    forks_safely = (sys.platform.startswith("linux") and not multiprocessing.current_process().daemon
                    and _no_other_thread_runs() and getattr(source, "forks_safely", False))
    return "process" if requested == "process" and forks_safely else "thread"


def _no_other_thread_runs() -> bool:
    """Whether the calling thread is the only Python thread, tqdm's monitor aside: a progress bar
    starts it, and it takes only tqdm's lock and writes only progress bars, which the child never does."""
    others = [thread for thread in threading.enumerate()
              if thread is not threading.current_thread() and thread is not tqdm.monitor]
    return not others


class FramePrefetcher:
    """Hands out `ExtractedFrame`s, extracting the frames asked next in a background worker (module docstring).

    ``extract`` reads and extracts one frame by index. Call `take` for the frame about to
    be processed, then `prefetch` with the ones that will follow; `close` when done.
    ``worker`` is where `prefetch` extracts: a forked child process (forked here, see
    `background_worker` for when that is safe), a thread, or nowhere (None: `prefetch`
    does nothing and `take` extracts in the caller's thread). The worker extracts the
    frames in the order asked, one at a time. `worker` says where it runs now: a child
    that cannot start or dies leaves the work to a thread (module docstring).
    """

    def __init__(self, extract: Callable[[int], ExtractedFrame], worker: BackgroundWorker | None = "thread") -> None:
        self._extract = extract
        self._pending: deque[tuple[int, Future]] = deque()
        self._executor: Executor | None = None
        self.worker = worker
        if worker == "process":
            self._fork_child()
        elif worker == "thread":
            self._executor = _frontend_thread()

    def take(self, index: int) -> ExtractedFrame:
        """Frame ``index``: the one prefetched if it is in flight, else extracted now.

        Frames in flight before it are dropped, whatever became of them; when it is not
        in flight, all are, once finished, before this thread reads (one reader at a
        time). An error other than an unreadable frame, raised while extracting frame
        ``index`` in the background, is raised here.
        """
        while self._pending:
            pending_index, future = self._pending.popleft()
            if pending_index != index:
                wait([future])
                continue
            extracted = self._result(future)
            if extracted is not None:
                return extracted
        return self._extract(index)

    def prefetch(self, indices: Iterable[int]) -> None:
        """Start extracting frames ``indices`` in the background, in order, each not yet in flight
        (nothing when prefetching is off)."""
        if self._executor is None:
            return
        try:
            self._submit_new(indices)
        except BrokenProcessPool:  # the child died while it waited for work
            self._fall_back_to_thread()
            self._submit_new(indices)

    def close(self) -> None:
        """Drop the frames in flight and stop the background worker; `take` extracts in the
        caller's thread from then on."""
        self._pending.clear()
        if self._executor is not None:
            self._executor.shutdown(wait=True, cancel_futures=True)
            self._executor = None

    def _fork_child(self) -> None:
        """Fork the child now, with OpenCV's workers stopped for the fork (module docstring)."""
        self._executor = ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context("fork"),
                                             initializer=_become_extractor, initargs=(self._extract, os.getpid()))
        opencv_threads = cv2.getNumThreads()
        cv2.setNumThreads(1)  # the child keeps this: OpenCV on its own thread
        try:
            self._executor.submit(int).result()
        except BrokenProcessPool:
            self._fall_back_to_thread()
        finally:
            cv2.setNumThreads(opencv_threads)

    def _submit_new(self, indices: Iterable[int]) -> None:
        extract = _extract_in_child if self.worker == "process" else self._extract  # the child has its own
        in_flight = {index for index, _ in self._pending}
        for index in indices:
            if index not in in_flight:
                self._pending.append((index, self._executor.submit(extract, index)))

    def _result(self, future: Future) -> ExtractedFrame | None:
        """The frame extracted in the background; None when the child process died extracting it."""
        try:
            return future.result()
        except BrokenProcessPool:
            self._fall_back_to_thread()
            return None

    def _fall_back_to_thread(self) -> None:
        """The child died (or never started): drop every frame in flight, and extract in a thread from now on."""
        self._pending.clear()
        self._executor.shutdown(wait=False)
        self._executor, self.worker = _frontend_thread(), "thread"


def _frontend_thread() -> ThreadPoolExecutor:
    return ThreadPoolExecutor(max_workers=1, thread_name_prefix="pld-slam-frontend")


PR_SET_PDEATHSIG = 1
"""Linux's ``prctl`` option: the signal this process gets when its parent dies."""

_child_extract: Callable[[int], ExtractedFrame] | None = None
"""The child process's ``extract``, inherited through the fork (never pickled)."""


def _become_extractor(extract: Callable[[int], ExtractedFrame], parent: int) -> None:
    """Start of the forked child: keep ``extract``, leave Ctrl-C to the parent, end at once on
    SIGTERM (the parent's handler, inherited through the fork, would raise in the middle of
    an extraction and send the exception back as the frame), and die with the parent
    (process id ``parent``) when it is killed, instead of waiting for work forever."""
    global _child_extract
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    die_with_parent()
    if os.getppid() != parent:  # killed before that
        os._exit(1)
    one_blas_thread()  # takes effect at once, for the child's life
    _child_extract = extract


def die_with_parent() -> None:
    """Ask Linux for SIGKILL when the parent dies (``prctl(PR_SET_PDEATHSIG)``), where the C
    library gives ``prctl`` to ctypes; elsewhere (a static build) a killed parent leaves the
    child waiting, which costs memory, not the run."""
    try:
        import ctypes  # here: a Python without ctypes still runs, with the child of a killed parent waiting

        ctypes.CDLL(None).prctl(ctypes.c_int(PR_SET_PDEATHSIG), ctypes.c_ulong(signal.SIGKILL))
    except (ImportError, OSError, AttributeError):
        pass


def _extract_in_child(index: int) -> ExtractedFrame:
    return _child_extract(index)
