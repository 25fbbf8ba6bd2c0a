"""Regression of trajectory error against a recorded baseline (``pld-slam regress``).

A baseline is a JSON file::

    {
      "description": "what it guards",
      "tolerance": {"relative": 0.10, "absolute_m": 0.001},
      "cells": [
        {"name": "synthetic static", "sequence": {"synthetic": "static", "seed": 0, "frames": 80},
         "overrides": [], "ate_rmse_m": 0.0123},
        {"name": "kitti 06", "sequence": {"data": "kitti_odometry/sequences/06"}, "ate_rmse_m": 0.181}
      ]
    }

A cell's sequence is one the package generates (``synthetic``: scenario, seed, frames, and
optionally ``"camera": "kitti"`` for KITTI's camera instead of the default one; so every
clone has it), one under the data folder ``$PLD_SLAM_DATA`` (``data``: a relative
path; the cell is skipped, saying so, where the folder is missing) or an absolute
``path``. A cell regresses when its run fails or its ATE exceeds the recorded one by more
than ``relative`` x recorded + ``absolute_m`` (a cell may carry its own ``tolerance``):
10 % leaves room for the last digits that another BLAS or OpenCV build moves, 1 mm for
figures of a few millimetres (EuRoC) where 10 % is within noise.

The cells run as ablation cells (`runner.run_cells`), always afresh: a regression check
must see the code as it is, which the cell key (package version, not code) cannot tell.
"""

import json
import math
import os
import shutil
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from pld_slam.datasets import open_sequence
from pld_slam.errors import ConfigError, PldSlamError
from pld_slam.report.cells import CellSpec, plan_cells
from pld_slam.report.runner import run_cells
from pld_slam.report.store import folder_name, read_cell, read_json, same_folder_names
from pld_slam.report.suite import Suite, Variant, check_overrides
from pld_slam.synth.scenarios import CAMERAS, SCENARIOS
from pld_slam.synth.writer import ensure_sequence

DEFAULT_TOLERANCE = {"relative": 0.10, "absolute_m": 0.001}


@dataclass(frozen=True)
class Verdict:
    """The check of one baseline cell.

    Attributes
    ----------
    name : str
        The cell's name.
    baseline_m, current_m : float or None
        Recorded and current ATE RMSE [m] (None: none recorded, or the run gave none).
    allowed_m : float or None
        The largest ATE that passes.
    status : str
        ``pass``, ``worse`` (over the allowed ATE), ``failed`` (the run failed or gave no
        ATE), ``new`` (no recorded ATE yet) or ``skipped`` (sequence not found).
    note : str
        Why a cell was skipped or failed.
    """

    name: str
    baseline_m: float | None
    current_m: float | None
    allowed_m: float | None
    status: str
    note: str = ""

    @property
    def regressed(self) -> bool:
        """Whether this verdict fails the check."""
        return self.status in ("worse", "failed")


def read_baseline(path: Path, missing_ok: bool = False) -> dict:
    """The baseline at ``path``, checked; an empty one when it does not exist and ``missing_ok``.

    Raises
    ------
    ConfigError
        For an unreadable file, one that is not UTF-8 or not JSON, a tolerance or a value
        of the wrong type, or a cell without name or sequence or with an invalid override,
        naming the file and the cell: all found before any cell runs.
    """
    path = Path(path)
    if not path.exists() and missing_ok:
        return {"description": "", "tolerance": dict(DEFAULT_TOLERANCE), "cells": []}
    baseline = read_json(path, ConfigError, "baseline")
    if not isinstance(baseline, dict) or not isinstance(baseline.get("cells"), list):
        raise ConfigError(f"{path}: a baseline needs a 'cells' list")
    _check_tolerance(baseline.get("tolerance", {}), f"{path}: tolerance")
    names = [cell.get("name") for cell in baseline["cells"] if isinstance(cell, dict)]
    for n, cell in enumerate(baseline["cells"]):
        where = f"{path}: cell {n + 1}"
        if not isinstance(cell, dict) or not isinstance(cell.get("name"), str) or "sequence" not in cell:
            raise ConfigError(f"{where}: needs a 'name' and a 'sequence'")
        if names.count(cell["name"]) > 1:
            raise ConfigError(f"{where}: name {cell['name']!r} is used twice")
        _sequence_kind(cell["sequence"], where)
        _check_cell_values(cell, f"{where} ({cell['name']})")
    clash = same_folder_names(names)
    if clash is not None:
        raise ConfigError(f"{path}: cell {names.index(clash[1]) + 1}: names {clash[0]!r} and {clash[1]!r} would write "
                          f"the same cell folder ({folder_name(clash[1])}); rename one")
    baseline.setdefault("tolerance", dict(DEFAULT_TOLERANCE))
    return baseline


def _check_cell_values(cell: dict, where: str) -> None:
    """`ConfigError` at ``where`` for a cell's overrides, ATE, frame count or tolerance of the wrong type."""
    overrides = cell.get("overrides", [])
    if not isinstance(overrides, list) or not all(isinstance(override, str) for override in overrides):
        raise ConfigError(f"{where}: 'overrides' must be a list of section.key=value strings, got {overrides!r}")
    check_overrides(tuple(overrides), where)
    ate = cell.get("ate_rmse_m")
    if ate is not None and not _is_size(ate):
        raise ConfigError(f"{where}: 'ate_rmse_m' must be a finite number >= 0 or null, got {ate!r}")
    frames = cell.get("max_frames")
    if frames is not None and (isinstance(frames, bool) or not isinstance(frames, int) or frames < 1):
        raise ConfigError(f"{where}: 'max_frames' must be a positive integer or null, got {frames!r}")
    _check_tolerance(cell.get("tolerance", {}), f"{where}: tolerance")


def _check_tolerance(tolerance, where: str) -> None:
    """`ConfigError` at ``where`` unless ``tolerance`` maps keys of `DEFAULT_TOLERANCE` to finite numbers >= 0."""
    if not isinstance(tolerance, dict):
        raise ConfigError(f"{where}: expected an object with {', '.join(DEFAULT_TOLERANCE)}, got {tolerance!r}")
    for key, value in tolerance.items():
        if key not in DEFAULT_TOLERANCE:
            raise ConfigError(f"{where}: unknown key {key!r} (one of {', '.join(DEFAULT_TOLERANCE)})")
        if not _is_size(value):
            raise ConfigError(f"{where}: {key!r} must be a finite number >= 0, got {value!r}")


def _is_size(value) -> bool:
    """Whether ``value`` is a finite number >= 0 (a JSON number, not true or false)."""
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value) and value >= 0


def write_baseline(path: Path, baseline: dict) -> None:
    """Write ``baseline`` as indented JSON."""
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    Path(path).write_text(json.dumps(baseline, indent=2) + "\n")


def _sequence_kind(reference, where: str) -> str:
    """``synthetic``, ``data`` or ``path``: the kind of a cell's sequence reference, checked."""
    kinds = [kind for kind in ("synthetic", "data", "path") if isinstance(reference, dict) and kind in reference]
    if len(kinds) != 1:
        raise ConfigError(f"{where}: 'sequence' must hold exactly one of synthetic, data, path")
    if kinds[0] != "synthetic" and not isinstance(reference[kinds[0]], str):
        raise ConfigError(f"{where}: the sequence's {kinds[0]!r} must be a string, got {reference[kinds[0]]!r}")
    if kinds[0] == "synthetic" and not all(isinstance(reference.get(k), int) for k in ("seed", "frames")):
        raise ConfigError(f"{where}: a synthetic sequence needs an integer 'seed' and 'frames'")
    if kinds[0] == "synthetic" and reference["synthetic"] not in SCENARIOS:
        raise ConfigError(f"{where}: unknown synthetic scenario {reference['synthetic']!r} (one of "
                          f"{', '.join(SCENARIOS)})")
    if kinds[0] == "synthetic" and reference.get("camera", "default") not in CAMERAS:
        raise ConfigError(f"{where}: a synthetic sequence's 'camera' must be one of {', '.join(CAMERAS)}")
    return kinds[0]


def data_root() -> Path | None:
    """``$PLD_SLAM_DATA``, None when it is not set."""
    root = os.environ.get("PLD_SLAM_DATA")
    return Path(root) if root else None


def resolve_sequence(reference: dict, work: Path) -> tuple[Path | None, str]:
    """The folder of a cell's sequence (generating a synthetic one into ``work``), or None and why not."""
    if "synthetic" in reference:
        return synthetic_sequence(work, reference["synthetic"], reference["seed"], reference["frames"],
                                  reference.get("camera", "default")), ""
    if "data" in reference:
        root = data_root()
        if root is None:
            return None, "PLD_SLAM_DATA is not set"
        folder = root / reference["data"]
    else:
        folder = Path(reference["path"])
    return (folder, "") if folder.is_dir() else (None, f"{folder} not found")


def synthetic_sequence(work: Path, scenario: str, seed: int, frames: int, camera: str = "default") -> Path:
    """The folder of a generated sequence, rendered into ``work/sequences`` unless already there
    (``SCENARIO-seedS-Nf``, plus ``-CAMERA`` for another camera than the default)."""
    name = f"{scenario}-seed{seed}-{frames}f" + ("" if camera == "default" else f"-{camera}")
    return ensure_sequence(Path(work) / "sequences" / name, scenario, frames, seed, camera)


def baseline_cells(
    baseline: dict, work: Path, overrides: Sequence[str] = ()
) -> tuple[list[tuple[dict, CellSpec]], list[Verdict]]:
    """Each runnable baseline cell with its `CellSpec`, and a ``skipped`` verdict for the others.

    The cell's ``variant`` is its name, so its outputs land in ``work/cells/SEQUENCE/NAME``.
    ``overrides`` (``--set``) apply to every cell, before the cell's own.
    """
    runnable, skipped = [], []
    for cell in baseline["cells"]:
        folder, why = resolve_sequence(cell["sequence"], work)
        if folder is None:
            skipped.append(Verdict(cell["name"], cell.get("ate_rmse_m"), None, None, "skipped", why))
            continue
        suite = Suite(cell["name"], "", (Variant(cell["name"], tuple(cell.get("overrides", ()))),))
        (spec,) = plan_cells([open_sequence(folder)], suite, overrides, cell.get("max_frames"))
        runnable.append((cell, spec))
    return runnable, skipped


def judge(cell: dict, row: dict | None, tolerance: dict) -> Verdict:
    """The verdict on one cell from its recorded row (None: it did not run)."""
    tolerance = {**tolerance, **cell.get("tolerance", {})}
    baseline = cell.get("ate_rmse_m")
    current = None if row is None else row.get("ate_rmse_m")
    if row is None or row["status"] != "ok" or current is None:
        note = "no result" if row is None else (row.get("reason") or f"status {row['status']}, no ATE")
        return Verdict(cell["name"], baseline, current, None, "failed", note)
    if baseline is None:
        return Verdict(cell["name"], None, current, None, "new")
    allowed = baseline * (1.0 + tolerance["relative"]) + tolerance["absolute_m"]
    return Verdict(cell["name"], baseline, current, allowed, "pass" if current <= allowed else "worse")


def check_baseline(
    baseline: dict, work: Path, overrides: Sequence[str] = (), workers: int = 1, on_done=None
) -> list[Verdict]:
    """Run every runnable cell of ``baseline`` afresh in ``work`` and judge each, in baseline order."""
    shutil.rmtree(Path(work) / "cells", ignore_errors=True)
    runnable, skipped = baseline_cells(baseline, work, overrides)
    run_cells(work, [spec for _, spec in runnable], workers=workers, on_done=on_done)
    verdicts = {v.name: v for v in skipped}
    for cell, spec in runnable:
        verdicts[cell["name"]] = judge(cell, read_cell(work, spec), baseline["tolerance"])
    return [verdicts[cell["name"]] for cell in baseline["cells"]]


def updated_baseline(baseline: dict, verdicts: Sequence[Verdict]) -> dict:
    """``baseline`` with each cell's ATE replaced by its current one where there is one (cells
    not checked or skipped keep theirs).

    Raises
    ------
    PldSlamError
        When a cell failed: a baseline must not record a failed run.
    """
    current = {v.name: v for v in verdicts}
    failed = [v for v in verdicts if v.status == "failed"]
    if failed:
        raise PldSlamError("cannot update the baseline: " + "; ".join(f"{v.name}: {v.note}" for v in failed))
    cells = []
    for cell in baseline["cells"]:
        verdict = current.get(cell["name"])
        unchanged = verdict is None or verdict.current_m is None  # not checked this time, or skipped
        cells.append(cell if unchanged else {**cell, "ate_rmse_m": verdict.current_m})
    return {**baseline, "cells": cells}


def add_sequences(baseline: dict, folders: Sequence[Path]) -> dict:
    """``baseline`` with a cell for each folder not yet in it (referenced under $PLD_SLAM_DATA when there)."""
    cells = list(baseline["cells"])
    for folder in folders:
        reference = _reference(Path(folder))
        if any(cell["sequence"] == reference for cell in cells):
            continue
        name = open_sequence(Path(folder)).name
        taken = {cell["name"] for cell in cells}
        cells.append({"name": name if name not in taken else f"{name} ({folder})", "sequence": reference,
                      "overrides": []})
    return {**baseline, "cells": cells}


def _reference(folder: Path) -> dict:
    """The sequence reference of ``folder``: relative to $PLD_SLAM_DATA when under it, else absolute."""
    root = data_root()
    resolved = folder.resolve()
    if root is not None and resolved.is_relative_to(root.resolve()):
        return {"data": str(resolved.relative_to(root.resolve()))}
    return {"path": str(resolved)}


def select_cells(baseline: dict, folders: Sequence[Path], work: Path) -> dict:
    """``baseline`` reduced to the cells on the sequence folders ``folders`` (all when none given)."""
    if not folders:
        return baseline
    wanted = {Path(f).resolve() for f in folders}
    keep = []
    for cell in baseline["cells"]:
        if "synthetic" in cell["sequence"]:
            continue
        folder, _ = resolve_sequence(cell["sequence"], work)
        if folder is not None and folder.resolve() in wanted:
            keep.append(cell)
    return {**baseline, "cells": keep}


def format_verdicts(verdicts: Sequence[Verdict]) -> str:
    """The verdicts as an aligned text table: cell, baseline, current, change, allowed, status."""
    def metres(value):
        return "-" if value is None else f"{value:.4f}"

    lines = [f"{'cell':<32}{'baseline m':>11}{'now m':>11}{'change':>10}{'allowed m':>11}  status"]
    for v in verdicts:
        change = (f"{100.0 * (v.current_m / v.baseline_m - 1.0):+.1f}%"
                  if v.current_m is not None and v.baseline_m else "-")
        note = f" ({v.note})" if v.note else ""
        lines.append(f"{v.name[:31]:<32}{metres(v.baseline_m):>11}{metres(v.current_m):>11}{change:>10}"
                     f"{metres(v.allowed_m):>11}  {v.status}{note}")
    return "\n".join(lines)
