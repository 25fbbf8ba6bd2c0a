"""An ablation from start to report: plan the cells, run the pending ones, write the tables.

`prepare_ablation` opens the sequences, plans the cells (`cells.plan_cells`), and writes
``ablation.json`` and each sequence's ground truth into the output folder; `runner.run_cells`
runs what is not finished; `write_report` (also ``pld-slam ablate --report DIR``, which runs
nothing) builds from the recorded cells:

- ``results.csv``: one tidy row per cell (`store.ROW_COLUMNS`);
- ``table.md``, ``table.tex``, ``table.csv``: the paper's layout (`tables`);
- ``plots/trajectories_SEQUENCE.png`` and ``plots/ate.png`` (`plots`).
"""

from collections.abc import Sequence
from pathlib import Path

import pandas as pd

from pld_slam.datasets import open_sequence, with_cameras
from pld_slam.errors import PldSlamError
from pld_slam.io.run_output import TRAJECTORY_TUM
from pld_slam.io.trajectory import read_tum
from pld_slam.report.cells import CellSpec, plan_cells
from pld_slam.report.plots import plot_ate_bars, plot_variant_trajectories
from pld_slam.report.store import (
    ROW_COLUMNS,
    cell_folder,
    folder_name,
    groundtruth_path,
    read_ablation,
    recorded_rows,
    same_folder_names,
    write_ablation,
    write_groundtruth,
)
from pld_slam.report.suite import Suite
from pld_slam.report.tables import PaperTable, paper_table, to_csv, to_latex, to_markdown
from pld_slam.run_config import load_run_config

RESULTS = "results.csv"


def prepare_ablation(
    out: Path, sequence_dirs: Sequence[Path], suite: Suite, overrides: Sequence[str] = (),
    max_frames: int | None = None,
) -> list[CellSpec]:
    """Open the sequences, plan every cell, and write ``ablation.json`` and the ground truths.

    A KITTI sequence is read from the pair ``overrides`` choose (``dataset.cameras``), so
    that its ground truth is of the camera every cell runs on (`plan_cells` refuses a
    variant choosing another).

    Raises
    ------
    PldSlamError
        For variants whose cells would write one folder (`same_folder_names`), an
        unreadable sequence or an invalid cell config, before anything runs.
    """
    clash = same_folder_names(variant.name for variant in suite.variants)
    if clash is not None:
        raise PldSlamError(f"variants {clash[0]!r} and {clash[1]!r} of suite {suite.name} would write the same cell "
                           f"folder (cells/SEQUENCE/{folder_name(clash[1])}); rename one")
    sequences = [open_sequence(Path(folder)) for folder in sequence_dirs]
    sequences = [with_cameras(sequence, load_run_config(sequence, (), overrides).config.dataset.cameras)
                 for sequence in sequences]  # the pair --set dataset.cameras chooses, and its ground truth
    cells = plan_cells(sequences, suite, overrides, max_frames)
    labels = list(dict.fromkeys(spec.sequence for spec in cells))
    write_ablation(out, suite, labels, [str(Path(d).resolve()) for d in sequence_dirs])
    for label, sequence in zip(labels, sequences, strict=True):
        write_groundtruth(out, label, sequence.groundtruth)
    return cells


def write_report(out: Path) -> PaperTable:
    """Write results.csv, the tables and the plots of the cells recorded in ``out``; return the table.

    Raises
    ------
    PldSlamError
        When ``out`` is not the output folder of an ablation.
    """
    out = Path(out)
    ablation = read_ablation(out)
    rows = recorded_rows(out)
    pd.DataFrame(rows, columns=list(ROW_COLUMNS)).to_csv(out / RESULTS, index=False)
    table = paper_table(rows, ablation["sequences"], ablation["variants"])
    (out / "table.md").write_text(to_markdown(table))
    (out / "table.tex").write_text(to_latex(table))
    (out / "table.csv").write_text(to_csv(table))
    plots = out / "plots"
    plots.mkdir(exist_ok=True)
    plot_ate_bars(plots / "ate.png", table)
    for sequence in ablation["sequences"]:
        plot_variant_trajectories(plots / f"trajectories_{folder_name(sequence)}.png", _groundtruth(out, sequence),
                                  _estimates(out, [r for r in rows if r["sequence"] == sequence]), title=sequence)
    return table


def _groundtruth(out: Path, sequence: str):
    path = groundtruth_path(out, sequence)
    return read_tum(path) if path.is_file() else None


def _estimates(out: Path, rows: Sequence[dict]) -> dict:
    """The estimate of each cell of ``rows`` whose run completed (``ok``), by variant name: a
    failed or stopped run's partial trajectory would pass for the variant's result in the plot."""
    estimates = {}
    for row in rows:
        path = cell_folder(out, row["sequence"], row["variant"]) / TRAJECTORY_TUM
        if row["status"] == "ok" and path.is_file():
            estimates[row["variant"]] = read_tum(path)
    return estimates
