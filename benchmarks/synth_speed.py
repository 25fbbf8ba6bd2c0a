"""How fast the synthetic world renders: stereo pairs per second for each scenario.

Builds each scenario (time shown apart), then renders ``--frames`` stereo pairs spread over
the sequence (both images, sensor noise and the dynamic mask; no disk writes) and prints a
table. Run from the repository root:

    python benchmarks/synth_speed.py [--frames 30] [--size 640x480]
"""

import argparse
import time

import numpy as np

from pld_slam.synth import SCENARIOS, build_scenario


def parse_size(text: str) -> tuple[int, int]:
    """``"640x480"`` -> ``(640, 480)``."""
    width, height = text.lower().split("x")
    return int(width), int(height)


def measure(name: str, size: tuple[int, int], frames: int) -> tuple[float, float]:
    """Build time [s] of scenario ``name`` and mean wall time [s] of one rendered pair."""
    start = time.perf_counter()
    world = build_scenario(name, size=size)
    built = time.perf_counter() - start
    indices = np.linspace(0, world.n_frames - 1, frames).astype(int)
    world.render_frame(int(indices[0]))  # warm-up
    start = time.perf_counter()
    for index in indices:
        world.render_frame(int(index))
    return built, (time.perf_counter() - start) / frames


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=30, help="pairs rendered per scenario")
    parser.add_argument("--size", type=parse_size, default=(640, 480), help="WIDTHxHEIGHT")
    args = parser.parse_args()
    header = f"{'scenario':<11} {'size':>9} {'frames':>6} {'build s':>8} {'pairs/s':>8} {'ms/pair':>8}"
    print(header)
    print("-" * len(header))
    for name in SCENARIOS:
        built, per_pair = measure(name, args.size, args.frames)
        size = f"{args.size[0]}x{args.size[1]}"
        print(f"{name:<11} {size:>9} {args.frames:>6} {built:>8.2f} {1.0 / per_pair:>8.1f} {1000.0 * per_pair:>8.1f}")


if __name__ == "__main__":
    main()
