"""`FramePrefetcher`: the next frame extracted in a background thread or forked process, one reader at a time."""

import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from types import SimpleNamespace

import cv2
import numpy as np
import pytest
from processes import ends_within, running
from tqdm import tqdm

from pld_slam import frame_extraction
from pld_slam.datasets.base import ImageFiles
from pld_slam.datasets.rosbag import BagImages
from pld_slam.errors import DatasetError
from pld_slam.frame_extraction import ExtractedFrame, FramePrefetcher, background_worker

linux_only = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the front end forks only on Linux")


def fake_frame(index: int, fail_at: int | None, unreadable_at: int | None, stage_ms: dict) -> ExtractedFrame:
    """Frame ``index`` with nothing extracted: a failure at ``fail_at``, unreadable at ``unreadable_at``."""
    if index == fail_at:
        raise ValueError(f"broken extraction of frame {index}")
    error = DatasetError(f"frame {index} unreadable") if index == unreadable_at else None
    return ExtractedFrame(index, None, None, error, stage_ms)


class RecordingExtractor:
    """Extracts nothing but records which thread asked for which frame, and whether two overlapped."""

    def __init__(self, fail_at: int | None = None, unreadable_at: int | None = None) -> None:
        self.calls: list[tuple[int, str]] = []
        self.overlapped = False
        self._busy = threading.Lock()
        self._fail_at, self._unreadable_at = fail_at, unreadable_at

    def __call__(self, index: int) -> ExtractedFrame:
        if not self._busy.acquire(blocking=False):
            self.overlapped = True
            self._busy.acquire()
        try:
            self.calls.append((index, threading.current_thread().name))
            time.sleep(0.02)
            return fake_frame(index, self._fail_at, self._unreadable_at, {})
        finally:
            self._busy.release()


def test_the_prefetched_frame_is_extracted_in_the_background_and_handed_out_once():
    extractor = RecordingExtractor()
    frames = FramePrefetcher(extractor)
    first = frames.take(0)
    frames.prefetch([1])
    second = frames.take(1)
    frames.close()
    assert (first.index, second.index) == (0, 1)
    assert extractor.calls[0] == (0, threading.current_thread().name)
    assert extractor.calls[1][0] == 1 and extractor.calls[1][1].startswith("pld-slam-frontend")
    assert len(extractor.calls) == 2


def test_asking_for_another_frame_than_the_prefetched_one_extracts_it_after_the_one_in_flight():
    extractor = RecordingExtractor()
    frames = FramePrefetcher(extractor)
    frames.prefetch([5])
    assert frames.take(2).index == 2
    frames.close()
    assert [index for index, _ in extractor.calls] == [5, 2]
    assert not extractor.overlapped  # never two readers at once


def test_without_prefetching_every_frame_is_extracted_in_the_callers_thread():
    extractor = RecordingExtractor()
    frames = FramePrefetcher(extractor, worker=None)
    for index in range(3):
        assert frames.take(index).index == index
        frames.prefetch([index + 1])
    assert {thread for _, thread in extractor.calls} == {threading.current_thread().name}


def test_an_unreadable_frame_is_handed_out_with_its_error_and_a_failure_is_raised_to_the_caller():
    frames = FramePrefetcher(RecordingExtractor(fail_at=2, unreadable_at=1))
    frames.prefetch([1])
    assert "frame 1 unreadable" in str(frames.take(1).error)
    frames.prefetch([2])
    with pytest.raises(ValueError, match="frame 2"):
        frames.take(2)
    frames.close()


def test_after_close_frames_are_still_extracted_in_the_callers_thread():
    extractor = RecordingExtractor()
    frames = FramePrefetcher(extractor)
    frames.prefetch([0])
    frames.close()
    frames.prefetch([1])
    assert frames.take(1).index == 1
    assert extractor.calls[-1] == (1, threading.current_thread().name)


# --- the forked worker -----------------------------------------------------------------


class ProcessReporter:
    """Extracts nothing but says which process extracted each frame (in ``stage_ms["pid"]``).

    ``die_at``: a child asked for that frame exits at once, as one killed would.
    """

    def __init__(self, die_at: int | None = None, fail_at: int | None = None, unreadable_at: int | None = None) -> None:
        self._parent = os.getpid()
        self._die_at, self._fail_at, self._unreadable_at = die_at, fail_at, unreadable_at

    def __call__(self, index: int) -> ExtractedFrame:
        if index == self._die_at and os.getpid() != self._parent:
            os._exit(1)
        return fake_frame(index, self._fail_at, self._unreadable_at, {"pid": float(os.getpid())})


def pid_of(extracted: ExtractedFrame) -> int:
    return int(extracted.stage_ms["pid"])


def prefetcher_with_a_child() -> tuple[FramePrefetcher, int]:
    """A process prefetcher whose child has extracted frame 0, and the child's process id."""
    frames = FramePrefetcher(ProcessReporter(), worker="process")
    frames.prefetch([0])
    return frames, pid_of(frames.take(0))


@linux_only
def test_with_a_process_worker_prefetched_frames_are_extracted_in_one_forked_child():
    frames = FramePrefetcher(ProcessReporter(), worker="process")
    frames.prefetch([0])
    first = frames.take(0)
    frames.prefetch([1])
    second = frames.take(1)
    third = frames.take(7)  # not the one prefetched: extracted here
    frames.close()
    assert (first.index, second.index, third.index) == (0, 1, 7)
    assert pid_of(first) == pid_of(second) != os.getpid()
    assert pid_of(third) == os.getpid()


@linux_only
def test_errors_come_back_from_the_child_as_from_a_thread():
    frames = FramePrefetcher(ProcessReporter(fail_at=2, unreadable_at=1), worker="process")
    frames.prefetch([1])
    unreadable = frames.take(1)
    assert pid_of(unreadable) != os.getpid()  # came back from the child
    assert isinstance(unreadable.error, DatasetError) and "frame 1 unreadable" in str(unreadable.error)
    frames.prefetch([2])
    with pytest.raises(ValueError, match="frame 2") as raised:
        frames.take(2)
    assert "_RemoteTraceback" in type(raised.value.__cause__).__name__  # raised in the child
    assert frames.worker == "process"
    frames.close()


@linux_only
def test_frames_dropped_by_a_take_further_on_are_waited_for_and_their_errors_not_raised():
    frames = FramePrefetcher(ProcessReporter(fail_at=5), worker="process")
    frames.prefetch([4, 5, 6, 7])
    sixth = frames.take(6)
    seventh = frames.take(7)
    frames.close()
    assert (sixth.index, seventh.index) == (6, 7)
    assert pid_of(sixth) == pid_of(seventh) != os.getpid()


@linux_only
def test_a_child_that_dies_costs_only_the_background_its_frames_are_extracted_again_here():
    frames = FramePrefetcher(ProcessReporter(die_at=2), worker="process")
    frames.prefetch([1])
    child = pid_of(frames.take(1))
    frames.prefetch([2, 3, 4])
    again = frames.take(2)
    frames.prefetch([3, 4, 5])
    after = [frames.take(index) for index in (3, 4, 5)]
    frames.close()
    assert child != os.getpid()
    assert again.index == 2 and pid_of(again) == os.getpid()
    assert [extracted.index for extracted in after] == [3, 4, 5]
    assert {pid_of(extracted) for extracted in after} == {os.getpid()}  # a thread of this process from then on
    assert frames.worker == "thread"


@linux_only
def test_a_child_that_dies_while_waiting_for_work_leaves_the_next_frames_to_a_thread():
    frames, child = prefetcher_with_a_child()
    os.kill(child, signal.SIGKILL)
    while running(child):
        time.sleep(0.01)
    time.sleep(0.2)  # the pool notices
    frames.prefetch([1, 2])
    taken = [frames.take(1), frames.take(2)]
    frames.close()
    assert [extracted.index for extracted in taken] == [1, 2]
    assert {pid_of(extracted) for extracted in taken} == {os.getpid()}
    assert frames.worker == "thread"


@linux_only
def test_a_child_that_cannot_start_leaves_the_work_to_a_thread(monkeypatch):
    def broken_start(*_):
        raise RuntimeError("no child today")

    monkeypatch.setattr(frame_extraction, "_become_extractor", broken_start)
    frames = FramePrefetcher(ProcessReporter(), worker="process")
    assert frames.worker == "thread"
    frames.prefetch([0, 1])
    assert [pid_of(frames.take(index)) for index in (0, 1)] == [os.getpid()] * 2
    frames.close()


@linux_only
def test_ctrl_c_is_left_to_the_parent_the_child_goes_on():
    frames, child = prefetcher_with_a_child()
    os.kill(child, signal.SIGINT)
    time.sleep(0.05)
    frames.prefetch([1])
    assert pid_of(frames.take(1)) == child
    frames.close()


def image_files() -> ImageFiles:
    return ImageFiles([Path("left.png")], [Path("right.png")], (640, 480))


@linux_only
def test_the_worker_is_a_process_only_where_forking_is_safe(monkeypatch):
    files = image_files()
    tqdm(range(1), disable=True)  # starts tqdm's monitor thread, which takes no lock the child needs
    assert tqdm.monitor is not None
    # The threads that earlier tests left (dask's, say) are not this test's: say which run.
    monkeypatch.setattr(threading, "enumerate", lambda: [threading.current_thread(), tqdm.monitor])
    assert background_worker("process", files) == "process"
    assert background_worker("thread", files) == "thread"
    assert not BagImages.forks_safely  # a bag's open reader would be shared with the child
    assert background_worker("process", SimpleNamespace(forks_safely=False)) == "thread"
    other = threading.Thread(target=print)  # another thread could hold a lock the child needs
    monkeypatch.setattr(threading, "enumerate", lambda: [threading.current_thread(), other])
    assert background_worker("process", files) == "thread"


@linux_only
def test_the_child_dies_with_a_killed_parent():
    script = (
        "import os, time\n"
        "from pld_slam.frame_extraction import ExtractedFrame, FramePrefetcher\n"
        "frames = FramePrefetcher(lambda i: ExtractedFrame(i, None, None, None, {'pid': float(os.getpid())}),"
        " worker='process')\n"
        "frames.prefetch([0])\n"
        "print(int(frames.take(0).stage_ms['pid']), flush=True)\n"
        "time.sleep(60)\n"
    )
    parent = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True)
    child = int(parent.stdout.readline())
    assert running(child)
    parent.kill()
    parent.wait()
    assert ends_within(child, 5.0)


def opencv_pool_in_the_child(index: int) -> ExtractedFrame:
    """Says, in ``stage_ms``, the child's OpenCV thread count, then lets OpenCV's pool grow to two
    threads and counts the process's threads before and after a parallel loop: a clean pool
    starts a worker for it, one inherited from the parent believes it has one already."""
    image = (np.random.default_rng(index).random((376, 1241)) * 255).astype(np.uint8)
    inherited = cv2.getNumThreads()
    cv2.setNumThreads(2)
    before = len(os.listdir("/proc/self/task"))
    cv2.ORB_create().detectAndCompute(image, None)
    after = len(os.listdir("/proc/self/task"))
    return ExtractedFrame(index, None, None, None,
                          {"pid": float(os.getpid()), "opencv": inherited, "before": before, "after": after})


@linux_only
def test_the_child_runs_opencv_on_one_thread_with_no_workers_inherited_from_the_parent():
    opencv_threads = cv2.getNumThreads()
    cv2.ORB_create().detectAndCompute(np.zeros((376, 1241), np.uint8), None)  # the parent's workers run
    frames = FramePrefetcher(opencv_pool_in_the_child, worker="process")
    frames.prefetch([1])
    in_child = frames.take(1)
    frames.close()
    assert pid_of(in_child) != os.getpid()
    assert in_child.stage_ms["opencv"] == 1
    assert in_child.stage_ms["after"] > in_child.stage_ms["before"]
    assert cv2.getNumThreads() == opencv_threads  # the parent's setting is back
