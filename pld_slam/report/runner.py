"""Running the cells of an ablation: a local pool of child processes, or a Dask cluster.

Each pending cell (`store.is_finished` false) goes to `cells.execute_cell`, which runs it
in a child process; its outcome is recorded (`store.record_cell`) as soon as it arrives,
so an interrupted ablation keeps every cell that finished. Locally, ``workers`` threads
each wait on one child process. With a scheduler address, the cells are submitted to a
Dask distributed cluster (``pip install "pld-slam[cluster]"``); the workers need
pld-slam installed and the sequences at the same path, and send the run's files back,
so no shared output folder is needed. A worker that dies mid-cell takes that cell's run
with it (`cells.execute_cell`) and the scheduler gives the cell to another worker; a
cell that more workers than Dask's ``allowed-failures`` (3) died running is recorded as
failed (``KilledWorker``).
"""

from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor, as_completed
from pathlib import Path

from pld_slam.errors import PldSlamError
from pld_slam.kernels import compile_kernels
from pld_slam.report.cells import CellOutcome, CellSpec, execute_cell
from pld_slam.report.store import is_finished, record_cell


def pending_cells(out: Path, cells: Sequence[CellSpec]) -> list[CellSpec]:
    """The cells of ``cells`` without a reusable result in ``out``."""
    return [spec for spec in cells if not is_finished(out, spec)]


def run_cells(
    out: Path,
    cells: Sequence[CellSpec],
    workers: int = 1,
    scheduler: str | None = None,
    timeout: float | None = None,
    max_memory_mb: int | None = None,
    on_done: Callable[[dict], None] | None = None,
) -> list[CellSpec]:
    """Run the pending cells of ``cells`` and record each in ``out``; return those that ran.

    Parameters
    ----------
    out : Path
        The ablation's output folder.
    cells : sequence of CellSpec
        Every cell; the finished ones are skipped.
    workers : int
        Cells run at once on this machine (ignored with ``scheduler``).
    scheduler : str or None
        Address of a Dask distributed scheduler (``tcp://HOST:PORT``) to run on instead.
    timeout : float or None
        Time limit per cell [s].
    max_memory_mb : int or None
        Memory limit per cell [MiB] (`cells.execute_cell`).
    on_done : callable or None
        Called with each recorded row, as cells finish (progress).
    """
    pending = pending_cells(out, cells)
    if scheduler:
        outcomes = _dask_outcomes(scheduler, pending, timeout, max_memory_mb)
    else:
        outcomes = _local_outcomes(pending, workers, timeout, max_memory_mb)
    for spec, outcome in outcomes:
        row = record_cell(out, spec, outcome)
        if on_done is not None:
            on_done(row)
    return pending


def _outcome(spec: CellSpec, future) -> CellOutcome:
    """The outcome a finished future holds, or a failed one saying why the task itself failed
    (``KilledWorker``: more workers than ``allowed-failures`` died running it; a cell that could not start)."""
    try:
        return future.result()
    except Exception as error:  # the task, not the run, failed: record it, go on with the others
        return CellOutcome(spec.key, "failed", f"{type(error).__name__}: {error}", 0.0)


def _local_outcomes(
    cells: Sequence[CellSpec], workers: int, timeout: float | None, max_memory_mb: int | None
) -> Iterator[tuple[CellSpec, CellOutcome]]:
    """Each cell with its outcome, run by ``workers`` threads each waiting on a child process, as they finish."""
    if not cells:
        return
    compile_kernels()  # once, into the disk cache every cell loads from, instead of in each child at once
    with ThreadPoolExecutor(max_workers=max(1, workers)) as pool:
        futures = {pool.submit(execute_cell, spec, timeout, max_memory_mb): spec for spec in cells}
        try:
            for future in as_completed(futures):
                yield futures[future], _outcome(futures[future], future)
        finally:
            for future in futures:
                future.cancel()


def _dask_outcomes(
    address: str, cells: Sequence[CellSpec], timeout: float | None, max_memory_mb: int | None
) -> Iterator[tuple[CellSpec, CellOutcome]]:
    """Each cell with its outcome, run on the Dask cluster at ``address``, as they finish."""
    try:
        from distributed import Client
        from distributed import as_completed as dask_as_completed
    except ImportError:
        raise PldSlamError(
            '--scheduler needs Dask distributed: pip install "pld-slam[cluster]"'
        ) from None
    if not cells:
        return
    try:
        client = Client(address, timeout="20s")
    except OSError as error:
        raise PldSlamError(f"--scheduler {address}: cannot connect to a Dask scheduler ({error})") from None
    with client:
        futures = {client.submit(execute_cell, spec, timeout, max_memory_mb, pure=False): spec for spec in cells}
        try:
            for future in dask_as_completed(list(futures)):
                yield futures[future], _outcome(futures[future], future)
        finally:
            client.cancel(list(futures))
