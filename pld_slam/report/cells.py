"""Cells of an ablation: one sequence under one variant's config, run in its own process.

`plan_cells` turns sequences x variants into `CellSpec`s: plain data a worker on any
machine can run, carrying the cell's effective config (defaults, the sequence's family
file, the ablation's ``--set``, then the variant's overlay, so that the variant always
says what it says) and its key. `execute_cell` runs one: ``pld-slam run`` in a child
process, so a crash, a killed worker or an exhausted memory costs that cell only, and a
time limit can stop it. It returns the run's files as bytes (`CellOutcome`), so a Dask
worker needs no shared output folder, only the sequences at the same path.

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
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from pld_slam import __version__
from pld_slam.config import Config, config_to_dict, dump_config
from pld_slam.datasets import StereoSequence
from pld_slam.loop.loop_closing import check_vocabulary_given
from pld_slam.report.suite import Suite
from pld_slam.run_config import load_run_config

INTERRUPT_GRACE_SECONDS = 30.0
"""After its time limit a cell gets SIGTERM, which ``pld-slam run`` handles as Ctrl-C (it
then writes its trajectory so far), and this long to exit before it is killed."""

STATUSES = ("ok", "stopped", "failed")
"""A cell's outcome: ``ok`` (the run completed), ``stopped`` (the run ended early by itself,
e.g. tracking lost for good; its trajectory so far is kept), ``failed`` (error, crash,
time limit, interrupt: the reason says which)."""


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
        vocabulary): before anything runs.
    """
    cells = []
    for sequence, label in zip(sequences, unique_labels(sequences), strict=True):
        identity = sequence_identity(sequence)
        for variant in suite.variants:
            config = load_run_config(sequence, (), (*overrides, *variant.overrides)).config
            check_vocabulary_given(config)
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
    """The child process's command line: ``pld-slam run`` with the cell's config only."""
    command = [sys.executable, "-m", "pld_slam_cli", "run", spec.sequence_dir,
               "--out", str(run_dir), "--config", str(config_path)]
    if spec.max_frames is not None:
        command += ["--max-frames", str(spec.max_frames)]
    return command


def execute_cell(spec: CellSpec, timeout: float | None = None) -> CellOutcome:
    """Run ``spec`` in a child process and collect its files; never raises for a failed run.

    Parameters
    ----------
    spec : CellSpec
        The cell.
    timeout : float or None
        Time limit [s]: the child then gets SIGTERM (and writes what it has, as after
        Ctrl-C), and is killed `INTERRUPT_GRACE_SECONDS` later if still running.
    """
    start = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="pld-slam-cell-") as scratch:
        config_path = Path(scratch) / "config.yaml"
        config_path.write_text(spec.config_yaml)
        run_dir = Path(scratch) / "run"
        returncode, stderr, timed_out = _run_child(run_command(spec, run_dir, config_path), timeout)
        files = {path.name: path.read_bytes() for path in sorted(run_dir.glob("*")) if path.is_file()}
    status, reason = _status(returncode, stderr, timed_out, timeout, files)
    return CellOutcome(spec.key, status, reason, time.perf_counter() - start, files)


def _run_child(command: list[str], timeout: float | None) -> tuple[int, str, bool]:
    """Run ``command``; its return code, stderr, and whether the time limit stopped it."""
    child = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                             env={**os.environ, "PYTHONUNBUFFERED": "1"})
    try:
        _, stderr = child.communicate(timeout=timeout)
        return child.returncode, stderr, False
    except subprocess.TimeoutExpired:
        child.send_signal(signal.SIGTERM)  # not SIGINT, which a shell's background job ignores
        try:
            _, stderr = child.communicate(timeout=INTERRUPT_GRACE_SECONDS)
        except subprocess.TimeoutExpired:
            child.kill()
            _, stderr = child.communicate()
        return child.returncode, stderr, True
    except BaseException:  # Ctrl-C or a cancelled task: take the child down with us
        child.kill()
        child.wait()
        raise


def _status(returncode: int, stderr: str, timed_out: bool, timeout: float | None,
            files: dict[str, bytes]) -> tuple[str, str]:
    """The `STATUSES` entry and reason of a finished child process."""
    if timed_out:
        return "failed", f"time limit of {timeout:g} s reached"
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
