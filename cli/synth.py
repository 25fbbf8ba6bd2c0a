"""``pld-slam synth``: generate a synthetic stereo sequence in the KITTI odometry layout."""

from pathlib import Path

import click

from pld_slam.synth import CAMERAS, DEFAULT_FRAMES, SCENARIOS, write_sequence


def _parse_size(ctx: click.Context, param: click.Parameter, value: str | None) -> tuple[int, int] | None:
    """``"WxH"`` as ``(width, height)``; None when not given."""
    if value is None:
        return None
    width, sep, height = value.lower().partition("x")
    if not sep or not width.isdigit() or not height.isdigit():
        raise click.BadParameter(f"expected WIDTHxHEIGHT such as 640x480, got {value!r}")
    return int(width), int(height)


@click.command("synth")
@click.argument("out", type=click.Path(file_okay=False, path_type=Path))
@click.option("--scenario", type=click.Choice(SCENARIOS), default="static", show_default=True)
@click.option("--frames", type=click.IntRange(min=2), default=None,
              help="Number of stereo pairs [default: the scenario's own: "
                   + ", ".join(f"{n} for {name}" for name, n in DEFAULT_FRAMES.items()) + "].")
@click.option("--camera", type=click.Choice(CAMERAS), default="default", show_default=True,
              help="default: fx = fy = 0.6 x width, principal point at the image centre, baseline 0.5 m, "
                   "at --size. kitti: KITTI odometry 00-02's rectified grey pair (fx = fy = 718.856, "
                   "cx = 607.1928, cy = 185.2157, baseline 0.5372 m), 1241x376 images; --size must then "
                   "be left out (or be 1241x376).")
@click.option("--size", default=None, callback=_parse_size,
              help="Image size WIDTHxHEIGHT of the default camera [default: 640x480]; an error with "
                   "--camera kitti unless 1241x376.")
@click.option("--seed", type=int, default=0, show_default=True)
def synth_command(out: Path, scenario: str, frames: int | None, camera: str, size: tuple[int, int] | None,
                  seed: int) -> None:
    """Render a synthetic stereo sequence with exact ground truth into OUT.

    OUT gets image_0/, image_1/, calib.txt, times.txt, poses.txt (ground truth) and
    dynamic_masks/ (moving-object pixels of the left images); `pld-slam` reads it as a
    KITTI odometry sequence. The camera changes only the images: a scenario and seed
    give the same scene and poses with either.
    """
    summary = write_sequence(out, scenario, n_frames=frames, size=size, seed=seed, camera=camera, progress=True)
    click.echo(
        f"wrote {summary.n_frames} {summary.width}x{summary.height} stereo pairs "
        f"({summary.scenario}, seed {seed}) to {summary.out_dir} "
        f"in {summary.seconds:.1f} s ({summary.pairs_per_second:.1f} pairs/s)"
    )
