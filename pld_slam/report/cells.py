"""Cells of an ablation: one sequence under one variant's config, run in its own process.

`plan_cells` turns sequences x variants into `CellSpec`s: plain data a worker on any
machine can run, carrying the cell's effective config (defaults, the sequence's family
file, the ablation's ``--set``, then the variant's overlay, so that the variant always
says what it says) and its key. `execute_cell` runs one in a child process
(`pld_slam.report.cell_run`: `pld_slam.report.run_files.run_and_write`, what ``pld-slam
run`` calls), so a crash, a killed worker or an exhausted memory costs that cell only, and a
time limit and a memory limit can stop it. It returns the run's files as bytes
(`CellOutcome`), so a Dask worker needs no shared output folder, only the sequences at the
same path.

The memory limit. A thread of the process that started the child measures the resident
memory of the child and of its own children (the run's forked front end) every
`MEMORY_POLL_SECONDS` from Linux's ``/proc``; Dask's memory monitor sees only its worker
process, not the cell it started. A limit on address space (``RLIMIT_AS``) cannot stand
in: numba, OpenCV and OpenBLAS reserve far more than they use (a 600-frame ``city`` run on
two cores peaks at 1.6 GiB of address space for 0.64 GiB resident; numpy and OpenCV alone
take some 70 MiB more of it per thread, so per core), and running out of it is a
``bad_alloc`` somewhere, not a limit reached. The child also dies with the thread that
started it (``prctl(PR_SET_PDEATHSIG)``): a Dask worker killed mid-cell does not leave
its cell running, unwatched, beside the cell's retry.

The key. A finished cell is reused when its key is unchanged: the SHA-256 of the
sequence's identity (resolved path, layout, frame count, first and last timestamps),
the effective config, ``--max-frames`` and the package version. Hashing every image
would cost more than many cells; the identity catches a moved, cut or re-extracted
sequence. Files the config names (``loop.vocabulary``) count by path, not content; a
code change without a version bump is not seen either (`pld-slam regress` therefore
always runs afresh).
"""

import hashlib
import json
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from pld_slam import __version__
from pld_slam.config import Config, config_to_dict, dump_config
from pld_slam.datasets import StereoSequence, require_cameras
from pld_slam.frame_extraction import die_with_parent
from pld_slam.io.run_output import RUN_LOCK
from pld_slam.loop.loop_closing import check_vocabulary_given
from pld_slam.report.suite import Suite
from pld_slam.run_config import load_run_config
from pld_slam.timing import process_resident_mb

INTERRUPT_GRACE_SECONDS = 30.0
"""After its time or memory limit a cell gets SIGTERM, which a cell's run handles as
Ctrl-C (it then writes its trajectory so far), and this long to exit before it is killed."""

MEMORY_POLL_SECONDS = 0.5
"""How often a cell with a memory limit has its resident memory measured [s]."""

STATUSES = ("ok", "stopped", "failed")
"""A cell's outcome: ``ok`` (the run completed), ``stopped`` (the run ended early by itself,
e.g. tracking lost for good; its trajectory so far is kept), ``failed`` (error, crash,
time or memory limit, interrupt: the reason says which)."""


@dataclass(frozen=True)
class CellSpec:
    """Everything needed to run one cell, as plain data (picklable, JSON-able).

    Attributes
    ----------
    key : str
        The cell's key (module docstring).
    sequence : str
        The sequence's label, unique within the ablation (its folder in the output).
    variant : str
        The variant's name.
    sequence_dir : str
        The sequence folder, resolved.
    config_yaml : str
        The effective config (`dump_config`), given to the run as its only ``--config``.
    max_frames : int or None
        ``--max-frames`` of the run.
    """

    key: str
    sequence: str
    variant: str
    sequence_dir: str
    config_yaml: str
    max_frames: int | None = None


@dataclass(frozen=True)
class CellOutcome:
    """What running a cell gave.

    Attributes
    ----------
    key : str
        The spec's key.
    status : str
        One of `STATUSES`.
    reason : str
        Why a cell stopped or failed (the run's one-line error); empty for ``ok``.
    seconds : float
        Wall time of the run, process start included [s].
    files : dict of str to bytes
        The run's output files (trajectories, summary.json, ...) by name.
    """

    key: str
    status: str
    reason: str
    seconds: float
    files: dict[str, bytes] = field(default_factory=dict)


def sequence_identity(sequence: StereoSequence) -> dict:
    """What identifies a sequence in a cell key: resolved path, layout, frames, first and last time."""
    return {
        "root": str(Path(sequence.root).resolve()),
        "layout": sequence.layout,
        "frames": len(sequence),
        "first_time": float(sequence.timestamps[0]),
        "last_time": float(sequence.timestamps[-1]),
    }


def cell_key(identity: dict, config: Config, max_frames: int | None) -> str:
    """The key of a cell: 16 hex digits of SHA-256 over identity, config, max_frames and version."""
    content = {
        "sequence": identity,
        "config": config_to_dict(config),
        "max_frames": max_frames,
        "version": __version__,
    }
    return hashlib.sha256(json.dumps(content, sort_keys=True).encode()).hexdigest()[:16]


def unique_labels(sequences: Sequence[StereoSequence]) -> list[str]:
    """A table label per sequence: its name, or its folder's name where names repeat (synthetic
    sequences of several seeds are all ``synth_dynamic``), then a suffix ``-2``, ``-3`` if still repeated."""
    names = [sequence.name for sequence in sequences]
    names = [Path(s.root).name if names.count(s.name) > 1 else s.name for s in sequences]
    seen: dict[str, int] = {}
    labels = []
    for name in names:
        seen[name] = seen.get(name, 0) + 1
        labels.append(name if seen[name] == 1 else f"{name}-{seen[name]}")
    return labels


def plan_cells(
    sequences: Sequence[StereoSequence],
    suite: Suite,
    overrides: Sequence[str] = (),
    max_frames: int | None = None,
) -> list[CellSpec]:
    """Every cell of ``sequences`` x the suite's variants, sequence by sequence.

    Parameters
    ----------
    sequences : sequence of StereoSequence
        The opened sequences, in table row order.
    suite : Suite
        Its variants, in table column order.
    overrides : sequence of str
        ``--set`` overrides common to every cell, applied before the variant's own.
    max_frames : int or None
        Process only the first N frames of each sequence.

    Raises
    ------
    ConfigError
        When a cell's config is invalid (e.g. ``loop.detector: bow`` without a
        vocabulary), or asks for another stereo pair than its sequence is read from
        (``dataset.cameras``: the ablation keeps one ground truth per sequence): before
        anything runs.
    """
    cells = []
    for sequence, label in zip(sequences, unique_labels(sequences), strict=True):
        identity = sequence_identity(sequence)
        for variant in suite.variants:
            config = load_run_config(sequence, (), (*overrides, *variant.overrides)).config
            check_vocabulary_given(config)
            require_cameras(sequence, config.dataset.cameras,
                            f"variant {variant.name} cannot choose the pair, as the ablation has one ground truth "
                            "per sequence (ablate --set dataset.cameras=... chooses it for every cell)")
            cells.append(CellSpec(
                key=cell_key(identity, config, max_frames),
                sequence=label,
                variant=variant.name,
                sequence_dir=identity["root"],
                config_yaml=dump_config(config),
                max_frames=max_frames,
            ))
    return cells


def run_command(spec: CellSpec, run_dir: Path, config_path: Path) -> list[str]:
    """The child process's command line: `pld_slam.report.cell_run` with the cell's config only."""
    command = [sys.executable, "-m", "pld_slam.report.cell_run", spec.sequence_dir, str(run_dir), str(config_path)]
    if spec.max_frames is not None:
        command.append(str(spec.max_frames))
    return command


def execute_cell(spec: CellSpec, timeout: float | None = None, max_memory_mb: int | None = None) -> CellOutcome:
    """Run ``spec`` in a child process and collect its files; never raises for a failed run.

    Parameters
    ----------
    spec : CellSpec
        The cell.
    timeout : float or None
        Time limit [s]: the child then gets SIGTERM (and writes what it has, as after
        Ctrl-C), and is killed `INTERRUPT_GRACE_SECONDS` later if still running.
    max_memory_mb : int or None
        Memory limit [MiB] on `tree_resident_mb` of the child, checked every
        `MEMORY_POLL_SECONDS`; over it the child is stopped as at the time limit. Not
        enforced where ``/proc`` does not list children (`memory_limit_enforced`).
    """
    start = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="pld-slam-cell-") as scratch:
        config_path = Path(scratch) / "config.yaml"
        config_path.write_text(spec.config_yaml)
        run_dir = Path(scratch) / "run"
        command = run_command(spec, run_dir, config_path)
        returncode, stderr, limit_reached = _run_child(command, timeout, max_memory_mb)
        files = {path.name: path.read_bytes() for path in sorted(run_dir.glob("*"))
                 if path.is_file() and path.name != RUN_LOCK}  # the lock a killed run leaves is no result
    status, reason = _status(returncode, stderr, limit_reached, files)
    return CellOutcome(spec.key, status, reason, time.perf_counter() - start, files)


def process_tree(pid: int) -> list[int]:
    """Process ``pid`` and its descendants, from Linux's ``/proc/PID/task/TID/children`` (every
    thread's: a child is listed under the thread that started it); ``[pid]`` elsewhere."""
    tree, pending = [], [pid]
    while pending:
        member = pending.pop()
        tree.append(member)
        for children in Path(f"/proc/{member}/task").glob("*/children"):
            try:
                pending += [int(child) for child in children.read_text().split()]
            except OSError:  # the thread ended meanwhile
                continue
    return tree


def tree_resident_mb(pid: int) -> float:
    """Resident memory of process ``pid`` and its descendants [MiB] (`process_resident_mb`; 0
    without ``/proc``). Pages a forked child still shares with its parent count in both:
    an upper bound."""
    total = 0.0
    for member in process_tree(pid):
        try:
            total += process_resident_mb(member)
        except OSError:  # exited meanwhile
            continue
    return total


def memory_limit_enforced() -> bool:
    """Whether this machine can enforce a cell's memory limit: ``/proc`` lists a process's children (Linux)."""
    return Path(f"/proc/{os.getpid()}/task/{os.getpid()}/children").is_file()


def _run_child(command: list[str], timeout: float | None, max_memory_mb: int | None) -> tuple[int, str, str]:
    """Run ``command`` until it ends or `_LimitWatch` stops it; its return code, stderr, and
    the limit it reached (empty if none)."""
    child = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                             env={**os.environ, "PYTHONUNBUFFERED": "1"},
                             preexec_fn=die_with_parent if os.name == "posix" else None)
    watch = _LimitWatch(child, timeout, max_memory_mb)
    watch.start()
    try:
        _, stderr = child.communicate()
    except BaseException:  # Ctrl-C or a cancelled task: take the child down with us
        child.kill()
        child.wait()
        raise
    finally:
        watch.finished.set()
        watch.join()
    return child.returncode, stderr, watch.reached


class _LimitWatch(threading.Thread):
    """A thread stopping a child process at its time or memory limit (`execute_cell`) until
    ``finished`` is set; ``reached`` then says which limit it reached (empty if none)."""

    def __init__(self, child: subprocess.Popen, timeout: float | None, max_memory_mb: int | None):
        super().__init__(name="pld-slam-cell-limits", daemon=True)
        self.child, self.timeout, self.max_memory_mb = child, timeout, max_memory_mb
        self.finished = threading.Event()
        self.reached = ""

    def run(self) -> None:
        self.reached = self._limit_reached()
        if self.reached:
            self.child.send_signal(signal.SIGTERM)  # not SIGINT, which a shell's background job ignores
            if not self.finished.wait(INTERRUPT_GRACE_SECONDS):
                self.child.kill()

    def _limit_reached(self) -> str:
        """Wait for a limit and return what it says, or return "" once ``finished`` is set."""
        deadline = None if self.timeout is None else time.monotonic() + self.timeout
        while True:
            waits = [] if self.max_memory_mb is None else [MEMORY_POLL_SECONDS]
            if deadline is not None:
                waits.append(max(0.0, deadline - time.monotonic()))
            if self.finished.wait(min(waits, default=None)):
                return ""
            if deadline is not None and time.monotonic() >= deadline:
                return f"time limit of {self.timeout:g} s reached"
            if self.max_memory_mb is not None and tree_resident_mb(self.child.pid) > self.max_memory_mb:
                return f"memory limit of {self.max_memory_mb} MiB reached"


def _status(returncode: int, stderr: str, limit_reached: str, files: dict[str, bytes]) -> tuple[str, str]:
    """The `STATUSES` entry and reason of a finished child process (``limit_reached``: see `_run_child`)."""
    if limit_reached:
        return "failed", limit_reached
    if returncode != 0:
        if returncode < 0:
            return "failed", f"killed by signal {-returncode} ({signal.Signals(-returncode).name})"
        lines = [line.strip() for line in stderr.splitlines() if line.strip()]
        return "failed", lines[-1] if lines else f"exit code {returncode}"
    if "summary.json" not in files:
        return "failed", "the run wrote no summary.json"
    summary = json.loads(files["summary.json"])
    if not summary["completed"]:
        return "stopped", str(summary["stop_reason"])
    return "ok", ""
