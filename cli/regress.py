"""``pld-slam regress``: run the cells of a baseline and fail when trajectory error got worse."""

import os
from pathlib import Path

import click
from tqdm import tqdm

from pld_slam.errors import PldSlamError
from pld_slam.io.output_folder import create_output_folder
from pld_slam.report.regress import (
    add_sequences,
    check_baseline,
    format_verdicts,
    read_baseline,
    select_cells,
    updated_baseline,
    write_baseline,
)
from pld_slam_cli.config import set_option

EXIT_REGRESSED = 1


@click.command("regress")
@click.argument("baseline_path", metavar="BASELINE.json", type=click.Path(dir_okay=False, path_type=Path))
@click.argument("sequence_dirs", nargs=-1, type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--update", is_flag=True,
              help="Rewrite the baseline's ATE values from this run (and add cells for new SEQUENCE_DIRs).")
@set_option
@click.option("--out", type=click.Path(file_okay=False, path_type=Path), default=Path("runs") / "regress",
              show_default=True, help="Where the cells run (always afresh) and synthetic sequences are generated.")
@click.option("--workers", type=click.IntRange(min=1), default=os.cpu_count() or 1, show_default="cores",
              help="Cells run at once.")
@click.option("--allow-skipped", is_flag=True,
              help="Exit 0 when every cell is skipped (nothing checked) instead of with an error.")
@click.pass_context
def regress_command(ctx: click.Context, baseline_path: Path, sequence_dirs: tuple[Path, ...], update: bool,
                    overrides: tuple[str, ...], out: Path, workers: int, allow_skipped: bool) -> None:
    """Run the cells BASELINE.json lists and compare each ATE with the recorded one.

    Exits 1 with a table of what got worse when a cell's ATE exceeds its baseline by more
    than the tolerance (default 10 % + 1 mm) or its run fails. Real sequences are found
    under $PLD_SLAM_DATA (cells without it are skipped, saying so). With SEQUENCE_DIRs,
    only the cells on those sequences run. --set applies to every cell (e.g. to check
    that a change of parameter worsens nothing). A check where every cell is skipped (or
    none is selected) checked nothing: an error (exit 2) unless --allow-skipped.
    """
    baseline = read_baseline(baseline_path, missing_ok=update)
    create_output_folder(out)
    if update:
        create_output_folder(baseline_path.parent)
    if update and sequence_dirs:
        baseline = add_sequences(baseline, sequence_dirs)
    checked = select_cells(baseline, sequence_dirs, out)
    with tqdm(total=len(checked["cells"]), desc="cells", unit="cell", disable=None) as bar:
        verdicts = check_baseline(checked, out, overrides, workers, on_done=lambda row: bar.update())
    click.echo(format_verdicts(verdicts))
    if update:
        write_baseline(baseline_path, updated_baseline(baseline, verdicts))
        click.echo(f"updated {baseline_path}")
        return
    regressed = [v for v in verdicts if v.regressed]
    if regressed:
        click.echo(f"regression: {len(regressed)} of {len(verdicts)} cells got worse or failed", err=True)
        ctx.exit(EXIT_REGRESSED)
    skipped = sum(v.status == "skipped" for v in verdicts)
    if skipped == len(verdicts):
        if not allow_skipped:
            raise PldSlamError(f"{baseline_path}: nothing checked: {nothing_checked(len(verdicts))}; "
                               "--allow-skipped accepts that")
        click.echo(f"nothing checked ({skipped} skipped)")
        return
    click.echo(f"no regression ({sum(v.status == 'pass' for v in verdicts)} passed, {skipped} skipped)")


def nothing_checked(n_cells: int) -> str:
    """Why a check of ``n_cells`` cells, all skipped, checked nothing."""
    if n_cells == 0:
        return "no cell selected"
    skipped = "its 1 cell was skipped" if n_cells == 1 else f"all its {n_cells} cells were skipped"
    return f"{skipped} (the table says why)"
