"""Speed of a whole run against ORB-SLAM2's tracking thread, and a machine's first run against its second.

Each round times, on the same frames and in turn:

- the ORB yardstick: ``cv2.ORB_create(2000, 1.2, 8)`` detecting and describing both images
  of every pair, one OpenCV thread: a figure of the machine, so that the speed of a run
  is a ratio that holds on another machine;
- ``pld-slam run`` (a child process, default config, as a user runs it), whose per-frame
  times come from its ``frames.csv``.

ORB-SLAM2 stereo's tracking thread (built here, KITTI 06 frames 0-50, idle machine) took
2.9 times the yardstick by its mean and 2.5 times by its median (issue 40): the targets
the table's ratios are read against. Its local mapping and loop closing run in other
threads; ours run inline and count in every frame's ``total``.

``--first-run`` makes round 1's run start from an empty numba cache (a fresh machine)
and adds a second run on the now warm cache: the table then gives the first run's mean
over the second's, and the seconds the kernels took to compile before the first frame
(`pld_slam.kernels`, outside the frame times).

Time only on an otherwise idle machine.

    python benchmarks/speed.py [SEQUENCE ...] [--frames 51] [--rounds 3] [--first-run]
"""

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
from extracts import data_dir

from pld_slam.datasets import open_sequence

DEFAULT_SEQUENCE = Path("kitti_odometry/sequences/06")
"""Relative to ``$PLD_SLAM_DATA``: the extract issue 40's figures were measured on."""
ORB_SLAM2_TRACKING = {"mean": 2.9, "median": 2.5}
"""ORB-SLAM2 stereo's tracking thread in yardstick units (module docstring)."""


def yardstick_ms(sequence_path: Path, frames: int) -> float:
    """Mean ms per stereo pair of the ORB yardstick (module docstring) over the first ``frames`` pairs."""
    sequence = open_sequence(sequence_path)
    pairs = [sequence.frames.read(index) for index in range(min(frames, len(sequence)))]
    orb = cv2.ORB_create(2000, 1.2, 8)
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        start = time.perf_counter()
        for left, right in pairs:
            orb.detectAndCompute(left, None)
            orb.detectAndCompute(right, None)
        return 1e3 * (time.perf_counter() - start) / len(pairs)
    finally:
        cv2.setNumThreads(threads)


def cli_run(sequence_path: Path, out: Path, *options: str, env: dict | None = None) -> tuple[pd.DataFrame, dict]:
    """``pld-slam run SEQUENCE --out OUT OPTIONS`` in a child process (environment ``env``, default
    ours): its ``frames.csv`` and ``summary.json``."""
    subprocess.run([sys.executable, "-m", "pld_slam_cli", "run", str(sequence_path), "--out", str(out), *options],
                   check=True, env=env, stdout=subprocess.DEVNULL)
    return pd.read_csv(out / "frames.csv"), json.loads((out / "summary.json").read_text())


def timed_run(sequence_path: Path, frames: int, out: Path, cache: Path | None = None) -> tuple[pd.DataFrame, dict]:
    """`cli_run` on the first ``frames`` frames, with the numba cache ``cache`` if given."""
    env = None if cache is None else {**os.environ, "NUMBA_CACHE_DIR": str(cache)}
    return cli_run(sequence_path, out, "--max-frames", str(frames), env=env)


def stage_means(table: pd.DataFrame) -> dict[str, float]:
    """Mean ms per frame of each stage, over every frame (a stage that did not run counts 0)."""
    columns = [column for column in table.columns if column.endswith("_ms")]
    return {column[:-3]: float(table[column].fillna(0.0).mean()) for column in columns}


def run_row(label: str, table: pd.DataFrame, summary: dict, yardstick: float) -> dict:
    """A row of the table: per-frame mean and median [ms], and both over the yardstick."""
    total = table["total_ms"]
    return {
        "run": label,
        "yardstick ms": yardstick,
        "mean ms": total.mean(),
        "median ms": total.median(),
        "mean / yardstick": total.mean() / yardstick,
        "median / yardstick": total.median() / yardstick,
        "kernels s": summary.get("kernels_seconds", float("nan")),
        "keyframes": summary["mapping"]["keyframes"] if summary["mapping"] else 0,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("sequences", nargs="*", type=Path, help="sequence folders [default: KITTI 06 of the data]")
    parser.add_argument("--frames", type=int, default=51)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--first-run", action="store_true", help="round 1 from an empty numba cache, then again")
    args = parser.parse_args()
    sequences = args.sequences or [data_dir() / DEFAULT_SEQUENCE]
    rows, stages = [], {}
    with tempfile.TemporaryDirectory() as scratch:
        scratch = Path(scratch)
        for sequence in sequences:
            for round_ in range(1, args.rounds + 1):
                yardstick = yardstick_ms(sequence, args.frames)
                cold = scratch / f"cache-{sequence.name}" if args.first_run and round_ == 1 else None
                out = scratch / f"{sequence.name}-{round_}"
                table, summary = timed_run(sequence, args.frames, out, cold)
                label = f"{sequence.name} round {round_}" + (" (first run)" if cold else "")
                rows.append(run_row(label, table, summary, yardstick))
                stages[label] = stage_means(table)
                if cold is not None:
                    table, summary = timed_run(sequence, args.frames, out, cold)
                    rows.append(run_row(f"{sequence.name} round {round_} (second run)", table, summary, yardstick))
                    first, second = rows[-2]["mean ms"], rows[-1]["mean ms"]
                    print(f"{sequence.name}: first run's mean over the second's {first / second:.2f}, "
                          f"kernels compiled in {rows[-2]['kernels s']:.1f} s before the first frame")
    pd.set_option("display.width", 200)
    print(pd.DataFrame(rows).to_string(index=False, float_format=lambda value: f"{value:.2f}"))
    print(f"ORB-SLAM2's tracking thread: mean {ORB_SLAM2_TRACKING['mean']}x, median "
          f"{ORB_SLAM2_TRACKING['median']}x the yardstick")
    print("\nmean ms per frame by stage (a stage that did not run counts 0; load and frontend ran ahead "
          "in the background, total holds only the wait for them):")
    print(pd.DataFrame(stages).T.to_string(float_format=lambda value: f"{value:.1f}"))
    print(f"median per-frame time over rounds: {np.median([row['median ms'] for row in rows]):.1f} ms")


if __name__ == "__main__":
    main()
