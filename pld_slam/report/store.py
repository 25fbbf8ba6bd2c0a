"""The output folder of an ablation: what is finished, and one tidy row per cell.

Layout::

    OUT/ablation.json                  the suite, its variants and sequences in table order
    OUT/groundtruth/SEQUENCE.tum.txt   each sequence's ground truth (for the plots)
    OUT/cells/SEQUENCE/VARIANT/        the run's files (trajectories, summary.json, ...)
                              ate.zip    evo's result file of its ATE (``evo_res OUT/cells/*/*/ate.zip``),
                                         where the ground truth is kept (ablate's, not regress's)
                              cell.json  the cell's row, written last

``cell.json`` is written after the run's files, by a rename, so a cell with one is
finished however the ablation stopped. A cell whose ``cell.json`` holds the key it would
now have and status ``ok`` or ``stopped`` is reused; a ``failed`` one is run again (a
killed worker or an interrupt fails a cell that may well pass), as is one whose key
changed (the config, the sequence or the version did).
"""

import json
import os
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

from pld_slam.errors import PldSlamError, read_user_text
from pld_slam.eval.metrics import ate_result
from pld_slam.io.evo_results import write_evo_result
from pld_slam.io.run_output import TRAJECTORY_TUM
from pld_slam.io.trajectory import read_tum, write_tum
from pld_slam.report.cells import CellOutcome, CellSpec
from pld_slam.report.suite import Suite

CELL_FILE = "cell.json"
ATE_RESULT = "ate.zip"
ABLATION_FILE = "ablation.json"

ROW_COLUMNS = (
    "sequence", "variant", "status", "reason", "frames", "frames_in_sequence", "lost_frames",
    "ate_rmse_m", "ate_rot_rmse_deg", "rpe_trans_rmse_m", "rpe_rot_rmse_deg", "t_rel_pct",
    "r_rel_deg_per_100m", "keyframes", "loops", "ms_per_frame_mean", "ms_per_frame_median",
    "real_time_factor", "seconds", "config_hash",
)
"""The columns of ``results.csv``, one row per cell (t_rel / r_rel: None under 100 m of path)."""


def cell_folder(out: Path, sequence: str, variant: str) -> Path:
    """The folder of the cell (``sequence``, ``variant``) in the output folder ``out``."""
    return Path(out) / "cells" / folder_name(sequence) / folder_name(variant)


def cell_dir(out: Path, spec: CellSpec) -> Path:
    """The folder of cell ``spec`` in the output folder ``out``."""
    return cell_folder(out, spec.sequence, spec.variant)


def folder_name(name: str) -> str:
    """``name`` usable as one file or folder name."""
    return name.replace(os.sep, "_").replace("/", "_") or "_"


def same_folder_names(names: Iterable[str]) -> tuple[str, str] | None:
    """The first two of ``names`` that differ but have one `folder_name` (``a/b`` and ``a_b``): their cells
    would write one folder. None when there are none."""
    first_of = {}
    for name in names:
        first = first_of.setdefault(folder_name(name), name)
        if first != name:
            return first, name
    return None


def read_json(path: Path, error: type[PldSlamError] = PldSlamError, what: str = "JSON file") -> Any:
    """The JSON value of the file ``path`` (read by `pld_slam.errors.read_user_text`: UTF-8, a byte-order
    mark dropped); ``error`` naming it when it cannot be read (``cannot read WHAT (why)``), is not UTF-8
    text or is not valid JSON. A caller to whom a missing file means something else checks first."""
    text = read_user_text(path, error, what)
    try:
        return json.loads(text)
    except json.JSONDecodeError as problem:
        raise error(f"{path}:{problem.lineno}: not valid JSON ({problem.msg})") from None


def read_cell_file(path: Path) -> dict:
    """The row of a cell's ``cell.json``, checked to hold every `ROW_COLUMNS` key; `PldSlamError` naming the
    file otherwise."""
    row = read_json(path, what="cell file")
    if not isinstance(row, dict) or not set(ROW_COLUMNS) <= set(row):
        raise PldSlamError(f"{path}: expected an object with the keys {', '.join(ROW_COLUMNS)}; run the "
                           "ablation again to redo the cell")
    return row


def read_cell(out: Path, spec: CellSpec) -> dict | None:
    """The row recorded for ``spec``'s cell, None when there is none or it is unreadable."""
    try:
        return read_cell_file(cell_dir(out, spec) / CELL_FILE)
    except PldSlamError:
        return None


def is_finished(out: Path, spec: CellSpec) -> bool:
    """Whether ``spec``'s cell has a result to reuse (module docstring)."""
    row = read_cell(out, spec)
    return row is not None and row.get("config_hash") == spec.key and row.get("status") in ("ok", "stopped")


def record_cell(out: Path, spec: CellSpec, outcome: CellOutcome) -> dict:
    """Write ``outcome``'s files into the cell's folder, then its row as ``cell.json``; return the row."""
    folder = cell_dir(out, spec)
    folder.mkdir(parents=True, exist_ok=True)
    for stale in folder.iterdir():
        if stale.is_file():
            stale.unlink()
    for name, content in outcome.files.items():
        (folder / name).write_bytes(content)
    summary = json.loads(outcome.files["summary.json"]) if "summary.json" in outcome.files else None
    if summary is not None and summary["ate_rmse_m"] is not None and groundtruth_path(out, spec.sequence).is_file():
        write_ate_result(out, spec, folder)
    row = cell_row(spec, outcome, summary)
    scratch = folder / (CELL_FILE + ".part")
    scratch.write_text(json.dumps(row, indent=2) + "\n")
    scratch.replace(folder / CELL_FILE)
    return row


def write_ate_result(out: Path, spec: CellSpec, folder: Path) -> None:
    """evo's result file of the cell's ATE, ``ate.zip`` in its ``folder``: its ``trajectory.tum.txt``
    against the sequence's kept ground truth, as the run's summary measured it, named
    ``SEQUENCE_VARIANT`` (the name ``evo_res`` shows)."""
    result = ate_result(read_tum(groundtruth_path(out, spec.sequence)), read_tum(folder / TRAJECTORY_TUM),
                        f"{folder_name(spec.sequence)}_{folder_name(spec.variant)}")
    write_evo_result(folder / ATE_RESULT, result)


def cell_row(spec: CellSpec, outcome: CellOutcome, summary: dict | None) -> dict:
    """The `ROW_COLUMNS` of a cell from its outcome and run summary (None: the run wrote none)."""
    row = dict.fromkeys(ROW_COLUMNS)
    row.update(sequence=spec.sequence, variant=spec.variant, status=outcome.status, reason=outcome.reason,
               seconds=outcome.seconds, config_hash=spec.key)
    if summary is None:
        return row
    total = summary["timing_ms"].get("total") or {}
    mapping, loop = summary.get("mapping"), summary.get("loop")
    row.update(
        frames=summary["frames"],
        frames_in_sequence=summary["frames_in_sequence"],
        lost_frames=len(summary["tracking_failures"]),
        **{key: summary[key] for key in ("ate_rmse_m", "ate_rot_rmse_deg", "rpe_trans_rmse_m",
                                         "rpe_rot_rmse_deg", "t_rel_pct", "r_rel_deg_per_100m")},
        keyframes=None if mapping is None else mapping["keyframes"],
        loops=None if loop is None else len(loop["loops"]),
        ms_per_frame_mean=total.get("mean"),
        ms_per_frame_median=total.get("median"),
        real_time_factor=summary["real_time_factor"],
    )
    return row


def write_ablation(out: Path, suite: Suite, labels: Sequence[str], sequence_dirs: Sequence[str]) -> None:
    """Write ``ablation.json``: the suite and the sequences, in table order."""
    Path(out).mkdir(parents=True, exist_ok=True)
    content = {
        "suite": suite.name,
        "description": suite.description,
        "variants": [variant.name for variant in suite.variants],
        "sequences": list(labels),
        "sequence_dirs": list(sequence_dirs),
    }
    (Path(out) / ABLATION_FILE).write_text(json.dumps(content, indent=2) + "\n")


def read_ablation(out: Path) -> dict:
    """``ablation.json`` of ``out``, checked to list its ``variants`` and ``sequences``; `PldSlamError` saying
    the folder is no ablation output, or naming the file and its problem."""
    path = Path(out) / ABLATION_FILE
    if not path.exists():
        raise PldSlamError(f"{out}: no {ABLATION_FILE}; not the output folder of pld-slam ablate")
    ablation = read_json(path, what="ablation file")
    if not isinstance(ablation, dict) or not all(is_list_of_names(ablation.get(key)) for key in LISTED):
        raise PldSlamError(f"{path}: expected an object listing the {' and the '.join(LISTED)} (lists of names)")
    return ablation


LISTED = ("variants", "sequences")
"""The lists of ``ablation.json`` the report reads."""


def is_list_of_names(value) -> bool:
    """Whether ``value`` is a list of strings."""
    return isinstance(value, list) and all(isinstance(item, str) for item in value)


def recorded_rows(out: Path) -> list[dict]:
    """The row of every cell of ``ablation.json`` that has one, in table order; `PldSlamError` naming the first
    ``cell.json`` that is unreadable or malformed (`read_cell_file`)."""
    ablation = read_ablation(out)
    rows = []
    for sequence in ablation["sequences"]:
        for variant in ablation["variants"]:
            path = cell_folder(out, sequence, variant) / CELL_FILE
            if path.is_file():
                rows.append(read_cell_file(path))
    return rows


def groundtruth_path(out: Path, label: str) -> Path:
    """Where the ground truth of sequence ``label`` is kept in the output folder."""
    return Path(out) / "groundtruth" / f"{folder_name(label)}.tum.txt"


def write_groundtruth(out: Path, label: str, groundtruth) -> None:
    """Keep sequence ``label``'s ground truth (a `Trajectory`, or None: nothing written)."""
    if groundtruth is None:
        return
    path = groundtruth_path(out, label)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_tum(path, groundtruth)
