"""``pld-slam demo``: generate a synthetic sequence and run PLD-SLAM on it.

The default folder is `DEMO_FOLDER`, under ``runs/`` like ``pld-slam run``'s output: the
demo writes about 19 MB (60 frames), and ``runs/`` is ignored by the repository's
``.gitignore``, so running the quick start in a checkout adds nothing for git to track.
"""

from pathlib import Path

import click

from pld_slam.datasets import open_sequence
from pld_slam.io.output_folder import create_output_folder
from pld_slam.report.run_files import run_and_write
from pld_slam.synth import CAMERAS, SCENARIOS, write_sequence
from pld_slam_cli.config import set_option
from pld_slam_cli.run import format_run_table

DEMO_FOLDER = Path("runs") / "demo"


@click.command("demo")
@click.option("--out", type=click.Path(file_okay=False, path_type=Path), default=DEMO_FOLDER,
              show_default=True, help="Folder for the generated sequence (sequence/) and the run (run/).")
@click.option("--scenario", type=click.Choice(SCENARIOS), default="dynamic", show_default=True)
@click.option("--frames", type=click.IntRange(min=2), default=60, show_default=True)
@click.option("--seed", type=int, default=0, show_default=True)
@click.option("--camera", type=click.Choice(CAMERAS), default="default", show_default=True,
              help="default: 640x480, fx = 0.6 x width, baseline 0.5 m; kitti: KITTI odometry 00-02's "
                   "1241x376 rectified grey pair (see pld-slam synth --help).")
@set_option
def demo_command(out: Path, scenario: str, frames: int, seed: int, camera: str, overrides) -> None:
    """Render a synthetic stereo sequence with ground truth, run PLD-SLAM on it, print accuracy and speed.

    Prints where it writes before it starts: the sequence in OUT/sequence/, the run in OUT/run/.
    """
    create_output_folder(out)  # before rendering: a bad --out is a one-line error, not lost work
    click.echo(f"writing the sequence into {out / 'sequence'}/ and the run into {out / 'run'}/")
    write_sequence(out / "sequence", scenario, n_frames=frames, seed=seed, camera=camera, progress=True)
    summary = run_and_write(open_sequence(out / "sequence"), out / "run", (), overrides, None)
    click.echo(f"{format_run_table(summary)}\nwrote {out / 'run'}/")
