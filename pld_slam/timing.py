"""Wall-clock helpers: `ms_since`, `StageClock` (the wall time of named stages lap by lap),
and `one_blas_thread`, how the pipeline keeps BLAS from taking the cores it needs."""

import time

from threadpoolctl import threadpool_limits


def ms_since(start: float) -> float:
    """Milliseconds since ``start``, a `time.perf_counter` reading."""
    return 1e3 * (time.perf_counter() - start)


class StageClock:
    """Wall time between laps [ms], by stage name (a stage lapped twice keeps the later time)."""

    def __init__(self) -> None:
        self.laps: dict[str, float] = {}
        self._last = time.perf_counter()

    def lap(self, stage: str) -> None:
        """Close the stage that ran since the last lap (or since the clock started)."""
        now = time.perf_counter()
        self.laps[stage] = 1e3 * (now - self._last)
        self._last = now


def one_blas_thread() -> threadpool_limits:
    """A context in which every loaded BLAS library runs one thread (the previous setting after).

    The pipeline's dense algebra is small, and OpenBLAS's idle threads spin, taking the
    core that the front end's worker needs (`pld_slam.frame_extraction`). `pld_slam`
    also sets ``OPENBLAS_NUM_THREADS=1``, but that only counts when numpy is imported
    after it; a program that imports numpy first (most do) kept two threads: on KITTI 06,
    107-112 ms per frame against 89-93 with one (front end in a process, 3 frames ahead).
    """
    return threadpool_limits(limits=1, user_api="blas")
