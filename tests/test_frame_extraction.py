"""`FramePrefetcher`: the next frame extracted in a background thread, one reader at a time."""

import threading
import time

import pytest

from pld_slam.errors import DatasetError
from pld_slam.frame_extraction import ExtractedFrame, FramePrefetcher


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
            if index == self._fail_at:
                raise ValueError(f"broken extraction of frame {index}")
            error = DatasetError(f"frame {index} unreadable") if index == self._unreadable_at else None
            return ExtractedFrame(index, None, None, error, {})
        finally:
            self._busy.release()


def test_the_prefetched_frame_is_extracted_in_the_background_and_handed_out_once():
    extractor = RecordingExtractor()
    frames = FramePrefetcher(extractor)
    first = frames.take(0)
    frames.prefetch(1)
    second = frames.take(1)
    frames.close()
    assert (first.index, second.index) == (0, 1)
    assert extractor.calls[0] == (0, threading.current_thread().name)
    assert extractor.calls[1][0] == 1 and extractor.calls[1][1].startswith("pld-slam-frontend")
    assert len(extractor.calls) == 2


def test_asking_for_another_frame_than_the_prefetched_one_extracts_it_after_the_one_in_flight():
    extractor = RecordingExtractor()
    frames = FramePrefetcher(extractor)
    frames.prefetch(5)
    assert frames.take(2).index == 2
    frames.close()
    assert [index for index, _ in extractor.calls] == [5, 2]
    assert not extractor.overlapped  # never two readers at once


def test_without_prefetching_every_frame_is_extracted_in_the_callers_thread():
    extractor = RecordingExtractor()
    frames = FramePrefetcher(extractor, enabled=False)
    for index in range(3):
        assert frames.take(index).index == index
        frames.prefetch(index + 1)
    assert {thread for _, thread in extractor.calls} == {threading.current_thread().name}


def test_an_unreadable_frame_is_handed_out_with_its_error_and_a_failure_is_raised_to_the_caller():
    frames = FramePrefetcher(RecordingExtractor(fail_at=2, unreadable_at=1))
    frames.prefetch(1)
    assert "frame 1 unreadable" in str(frames.take(1).error)
    frames.prefetch(2)
    with pytest.raises(ValueError, match="frame 2"):
        frames.take(2)
    frames.close()


def test_after_close_frames_are_still_extracted_in_the_callers_thread():
    extractor = RecordingExtractor()
    frames = FramePrefetcher(extractor)
    frames.prefetch(0)
    frames.close()
    frames.prefetch(1)
    assert frames.take(1).index == 1
    assert extractor.calls[-1] == (1, threading.current_thread().name)
