"""``pld-slam demo``: generate a synthetic sequence and run PLD-SLAM on it."""

from pathlib import Path

import click

from pld_slam.io.run_output import create_output_folder
from pld_slam.synth import SCENARIOS, write_sequence
from pld_slam_cli.config import set_option
from pld_slam_cli.run import format_run_table, run_and_write


@click.command("demo")
@click.option("--out", type=click.Path(file_okay=False, path_type=Path), default=Path("pld_slam_demo"),
              show_default=True, help="Folder for the generated sequence (sequence/) and the run (run/).")
@click.option("--scenario", type=click.Choice(SCENARIOS), default="dynamic", show_default=True)
@click.option("--frames", type=click.IntRange(min=2), default=60, show_default=True)
@click.option("--seed", type=int, default=0, show_default=True)
@set_option
def demo_command(out: Path, scenario: str, frames: int, seed: int, overrides) -> None:
    """Render a synthetic stereo sequence with ground truth, run PLD-SLAM on it, print accuracy and speed."""
    create_output_folder(out)  # before rendering: a bad --out is a one-line error, not lost work
    write_sequence(out / "sequence", scenario, n_frames=frames, seed=seed, progress=True)
    summary = run_and_write(out / "sequence", out / "run", (), overrides, None)
    click.echo(f"{format_run_table(summary)}\nwrote {out / 'run'}/")
