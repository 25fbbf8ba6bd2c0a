"""A picture of a run's map: ``map.ply`` drawn from above and from the side, off-screen.

Map points as dots coloured by height, line landmarks as segments, keyframe centres as a
path; the world frame is the trajectory's (the first camera: x right, y down, z forward),
so the top view is the x-z plane and the side view the z-y plane (up the page is up).

    python benchmarks/map_view.py RUN_DIR/map.ply OUT.png [--title TEXT]
"""

import argparse
from pathlib import Path

from matplotlib.figure import Figure

from pld_slam.io.map_ply import read_map_ply


def map_figure(ply: Path, title: str) -> Figure:
    """Top and side views of the map in ``ply``."""
    cloud = read_map_ply(ply)
    figure = Figure(figsize=(10.0, 8.0))
    top, side = figure.subplots(2, 1, height_ratios=(3, 1))
    for axes, (horizontal, vertical), sign in ((top, (0, 2), 1.0), (side, (2, 1), -1.0)):
        points, lines, centres = cloud.points_w, cloud.lines_w, cloud.keyframe_centres_w
        axes.scatter(points[:, horizontal], sign * points[:, vertical], s=0.5, c=-points[:, 1], cmap="viridis",
                     label=f"{len(points)} points")
        for n, line in enumerate(lines):
            axes.plot(line[:, horizontal], sign * line[:, vertical], "r-", linewidth=0.6,
                      label=f"{len(lines)} lines" if n == 0 else None)
        axes.plot(centres[:, horizontal], sign * centres[:, vertical], "k.-", markersize=3, linewidth=0.8,
                  label=f"{len(centres)} keyframes")
        axes.set_aspect("equal", adjustable="datalim")
        axes.grid(True, alpha=0.3)
    top.set(xlabel="x [m] (right)", ylabel="z [m] (forward)", title=title)
    side.set(xlabel="z [m] (forward)", ylabel="height [m] (up)")
    top.legend(loc="upper right", fontsize="small", markerscale=6)
    figure.tight_layout()
    return figure


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("ply", type=Path)
    parser.add_argument("out", type=Path)
    parser.add_argument("--title", default=None)
    args = parser.parse_args()
    map_figure(args.ply, args.title or str(args.ply)).savefig(args.out, dpi=100)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
