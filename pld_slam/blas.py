"""`one_blas_thread`: how the pipeline keeps BLAS from taking the cores it needs."""

from threadpoolctl import threadpool_limits


def one_blas_thread() -> threadpool_limits:
    """A context in which every loaded BLAS library runs one thread (the previous setting after).

    The pipeline's dense algebra is small, and OpenBLAS's idle threads spin, taking the
    core that the front end's worker needs (`pld_slam.frame_extraction`). `pld_slam`
    also sets ``OPENBLAS_NUM_THREADS=1``, but that only counts when numpy is imported
    after it; a program that imports numpy first (most do) kept two threads: on KITTI 06,
    107-112 ms per frame against 89-93 with one (front end in a process, 3 frames ahead).
    """
    return threadpool_limits(limits=1, user_api="blas")
