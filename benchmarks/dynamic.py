"""Dynamic-feature detection: the four variants of the paper's Table I side by side.

For each sequence, runs the pipeline with neither detector, the dynamic grid only, the
dynamic LLG only, and both, and prints ATE RMSE (and its ratio to "neither"), the share of
matched features marked dynamic, precision / recall of the dynamic point and line labels
against the moving-object masks (synthetic sequences), and the median ms per frame the
detection costs. Sequences: synthetic ``dynamic`` (several seeds) and ``static``, and the
real KITTI raw 0005 (dynamic) and KITTI odometry 06 (static) extracts when found.

    python benchmarks/dynamic.py [--seeds 0 1 2] [--frames 100] [--out /tmp/pld_slam_dynamic]
"""

import argparse
import os
import tempfile
from pathlib import Path

import pandas as pd

from pld_slam.config import load_config
from pld_slam.datasets import open_sequence
from pld_slam.eval.run_summary import summarise_run
from pld_slam.synth import write_sequence
from pld_slam.system import System

REPO = Path(__file__).resolve().parents[1]
CONFIGS = REPO / "configs"
VARIANTS = {"neither": (False, False), "grid": (True, False), "llg": (False, True), "both": (True, True)}
REAL = {
    "kitti_raw/2011_09_26/2011_09_26_drive_0005_sync": "kitti.yaml",
    "kitti_odometry/sequences/06": "kitti.yaml",
}


def run_variant(folder: Path, family: str, grid: bool, llg: bool) -> dict:
    """Summary of one run with the two detectors switched as given."""
    sequence = open_sequence(folder)
    overrides = (f"dynamic.grid={str(grid).lower()}", f"dynamic.llg={str(llg).lower()}")
    config = load_config([CONFIGS / "default.yaml", CONFIGS / family], overrides)
    system = System(sequence, config)
    system.run()
    return summarise_run(sequence, system.result, config)


def rows_for(folder: Path, family: str) -> list[dict]:
    """One row per variant on the sequence in ``folder``."""
    rows = []
    for variant, (grid, llg) in VARIANTS.items():
        summary = run_variant(folder, family, grid, llg)
        dynamic = summary["dynamic"]
        rows.append({
            "sequence": summary["sequence"],
            "variant": variant,
            "ATE [m]": summary["ate_rmse_m"],
            "marked %": 100.0 * (dynamic["marked_fraction"] or 0.0),
            "pt P": dynamic["points"]["precision"],
            "pt R": dynamic["points"]["recall"],
            "line P": dynamic["lines"]["precision"],
            "line R": dynamic["lines"]["recall"],
            "dyn ms": summary["timing_ms"]["dynamic"]["median"],
            "total ms": summary["timing_ms"]["total"]["median"],
        })
    neither = rows[0]["ATE [m]"]
    for row in rows:
        row["ATE / neither"] = row["ATE [m]"] / neither
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--frames", type=int, default=100)
    parser.add_argument("--out", type=Path, default=Path(tempfile.gettempdir()) / "pld_slam_dynamic")
    args = parser.parse_args()
    rows = []
    for scenario, seeds in (("dynamic", args.seeds), ("static", args.seeds[:1])):
        for seed in seeds:
            folder = args.out / f"{scenario}_{seed}"
            write_sequence(folder, scenario, n_frames=args.frames, seed=seed)
            rows += [dict(row, sequence=f"synth_{scenario}_{seed}") for row in rows_for(folder, "synthetic.yaml")]
    data_dir = Path(os.environ.get("PLD_SLAM_DATA", REPO.parent / "shared" / "data"))
    for relative, family in REAL.items():
        if (data_dir / relative).is_dir():
            rows += rows_for(data_dir / relative, family)
        else:
            print(f"skipped {data_dir / relative}: not found (set PLD_SLAM_DATA)")
    table = pd.DataFrame(rows)
    print(table.to_string(index=False, float_format=lambda x: f"{x:.3f}"))


if __name__ == "__main__":
    main()
