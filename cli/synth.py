"""``pld-slam synth``: generate a synthetic stereo sequence in the KITTI odometry layout."""

from pathlib import Path

import click

from pld_slam.synth import SCENARIOS, write_sequence


def _parse_size(ctx: click.Context, param: click.Parameter, value: str) -> tuple[int, int]:
    """``"WxH"`` as ``(width, height)``."""
    width, sep, height = value.lower().partition("x")
    if not sep or not width.isdigit() or not height.isdigit():
        raise click.BadParameter(f"expected WIDTHxHEIGHT such as 640x480, got {value!r}")
    return int(width), int(height)


@click.command("synth")
@click.argument("out", type=click.Path(file_okay=False, path_type=Path))
@click.option("--scenario", type=click.Choice(SCENARIOS), default="static", show_default=True)
@click.option("--frames", type=click.IntRange(min=2), default=None,
              help="Number of stereo pairs [default: the scenario's own: 360 for loop, 720 for loop2, "
                   "300 for nearmiss, 100 otherwise].")
@click.option("--size", default="640x480", show_default=True, callback=_parse_size,
              help="Image size WIDTHxHEIGHT.")
@click.option("--seed", type=int, default=0, show_default=True)
def synth_command(out: Path, scenario: str, frames: int | None, size: tuple[int, int], seed: int) -> None:
    """Render a synthetic stereo sequence with exact ground truth into OUT.

    OUT gets image_0/, image_1/, calib.txt, times.txt, poses.txt (ground truth) and
    dynamic_masks/ (moving-object pixels of the left images); `pld-slam` reads it as a
    KITTI odometry sequence.
    """
    summary = write_sequence(out, scenario, n_frames=frames, size=size, seed=seed, progress=True)
    click.echo(
        f"wrote {summary.n_frames} {summary.width}x{summary.height} stereo pairs "
        f"({summary.scenario}, seed {seed}) to {summary.out_dir} "
        f"in {summary.seconds:.1f} s ({summary.pairs_per_second:.1f} pairs/s)"
    )
