"""``pld-slam ablate``: sequences x the variants of a suite, resumable, locally or on Dask; the paper's tables."""

import os
import time
from pathlib import Path

import click
from tqdm import tqdm

from pld_slam.errors import PldSlamError
from pld_slam.io.output_folder import create_output_folder
from pld_slam.report.ablation import prepare_ablation, write_report
from pld_slam.report.cells import memory_limit_enforced
from pld_slam.report.runner import pending_cells, run_cells
from pld_slam.report.suite import BUILTIN_SUITES, load_suite
from pld_slam.report.tables import to_markdown
from pld_slam_cli.config import set_option


def run_with_progress(out: Path, cells, workers: int, scheduler: str | None, timeout: float | None,
                      max_memory_mb: int | None, pending: int) -> list[dict]:
    """Run the ``pending`` unfinished cells of ``cells`` with one progress bar (on a terminal) and
    a line per finished cell (`cell_line`); return the rows that failed."""
    rows = []
    with tqdm(total=pending, desc="cells", unit="cell", disable=None) as bar:
        def done(row: dict) -> None:
            rows.append(row)
            bar.update()
            with bar.external_write_mode():
                click.echo(cell_line(row, len(rows), pending))  # flushed: a line per cell in a log file too

        run_cells(out, cells, workers=workers, scheduler=scheduler, timeout=timeout, max_memory_mb=max_memory_mb,
                  on_done=done)
    return [row for row in rows if row["status"] == "failed"]


def cell_line(row: dict, done: int, pending: int) -> str:
    """The progress line of a finished cell: ``cell 3/8 SEQUENCE / VARIANT: ok, 600 frames, ATE 0.0304 m, 61.2 s``."""
    what = [row["status"] if not row["reason"] else f"{row['status']} ({row['reason']})"]
    if row["frames"] is not None:
        what.append(f"{row['frames']} frames")
    if row["ate_rmse_m"] is not None:
        what.append(f"ATE {row['ate_rmse_m']:.4f} m")
    what.append(f"{row['seconds']:.1f} s")
    return f"cell {done}/{pending} {row['sequence']} / {row['variant']}: " + ", ".join(what)


@click.command("ablate")
@click.argument("sequence_dirs", nargs=-1, type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--suite", "suite_name", default="table1", show_default=True,
              help=f"A built-in suite ({', '.join(BUILTIN_SUITES)}) or a suite YAML file.")
@click.option("--out", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Output folder [default: runs/ablate-<suite>]; rerunning into it redoes only unfinished cells.")
@click.option("--workers", type=click.IntRange(min=1), default=os.cpu_count() or 1, show_default="cores",
              help="Cells run at once on this machine.")
@click.option("--scheduler", metavar="ADDRESS", default=None,
              help='Run the cells on a Dask cluster (tcp://HOST:PORT; pip install "pld-slam[cluster]").')
@set_option
@click.option("--max-frames", type=click.IntRange(min=1), default=None, help="Process only the first N frames.")
@click.option("--timeout", type=click.FloatRange(min=0, min_open=True), default=None,
              help="Time limit per cell [s]; a cell over it is recorded as failed.")
@click.option("--max-memory-mb", type=click.IntRange(min=1), default=None, metavar="N",
              help="Memory limit per cell [MiB] on the run's resident memory, its front-end process included "
                   "(Linux); a cell over it is stopped and recorded as failed.")
@click.option("--report", "report_dir", type=click.Path(exists=True, file_okay=False, path_type=Path),
              default=None, help="Rebuild the tables and plots of this ablation folder; run nothing.")
def ablate_command(sequence_dirs: tuple[Path, ...], suite_name: str, out: Path | None, workers: int,
                   scheduler: str | None, overrides: tuple[str, ...], max_frames: int | None,
                   timeout: float | None, max_memory_mb: int | None, report_dir: Path | None) -> None:
    """Run every SEQUENCE_DIR under every variant of a suite and write the paper's tables.

    Each cell (sequence x variant) is one `pld-slam run` in its own process, in
    OUT/cells/SEQUENCE/VARIANT/. A cell that fails is recorded with its reason and the
    others go on; running the same command again redoes only the unfinished and failed
    cells. --set applies to every cell, before the variant's own settings. A line per
    finished cell shows its status, frames, ATE and time.

    Writes results.csv (one row per cell), table.md / table.tex / table.csv (rows:
    sequences; per variant t = translation ATE RMSE [m] and R = rotation RMSE [deg], best in
    bold, a mean row) and plots/.
    """
    if report_dir is not None:
        if sequence_dirs:
            raise PldSlamError("--report rebuilds an existing ablation: give no SEQUENCE_DIR with it")
        create_output_folder(report_dir)
        click.echo(to_markdown(write_report(report_dir)) + f"wrote {report_dir}/")
        return
    if not sequence_dirs:
        raise PldSlamError("give at least one SEQUENCE_DIR (or --report DIR to rebuild the tables)")
    if max_memory_mb is not None and scheduler is None and not memory_limit_enforced():
        click.echo("warning: --max-memory-mb is not enforced on this system (it needs Linux's /proc)", err=True)
    suite = load_suite(suite_name)
    out = out if out is not None else Path("runs") / f"ablate-{suite.name}"
    create_output_folder(out)
    start = time.perf_counter()
    cells = prepare_ablation(out, sequence_dirs, suite, overrides, max_frames)
    to_run = len(pending_cells(out, cells))
    failed = run_with_progress(out, cells, workers, scheduler, timeout, max_memory_mb, to_run)
    table = write_report(out)
    click.echo(to_markdown(table))
    click.echo(f"{len(cells)} cells: {to_run} run ({len(failed)} failed), {len(cells) - to_run} reused; "
               f"wall time {time.perf_counter() - start:.1f} s")
    click.echo(f"wrote {out}/")
