"""Accuracy and speed of tracking: one table over the real extracts and synthetic sequences.

Runs the pipeline (as ``pld-slam run``) on every real extract found in ``$PLD_SLAM_DATA``
(default ``../shared/data``) and on synthetic ``static`` and ``lowtexture`` sequences
(lines on and off), and prints: sequence, variant, frames, failures, ATE RMSE, RPE
(1 frame), median ms per frame of each stage, real-time factor.

    python benchmarks/tracking.py [--frames-synthetic 100] [--out /tmp/pld_slam_bench]
"""

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # before numpy loads OpenBLAS, as `pld-slam` runs (`pld_slam`)

import argparse
import tempfile
from pathlib import Path

import pandas as pd
from extracts import existing_extracts

from pld_slam.datasets import open_sequence
from pld_slam.eval.run_summary import summarise_run
from pld_slam.run_config import load_run_config
from pld_slam.synth import write_sequence
from pld_slam.system import System

STAGE_COLUMNS = ("frontend", "matching", "filters", "pose", "dynamic", "total")


def run_row(folder: Path, variant: str, overrides: tuple[str, ...] = ()) -> dict:
    """One table row: run the pipeline on ``folder`` (its family's config, then ``overrides``) and summarise it."""
    sequence = open_sequence(folder)
    run_config = load_run_config(sequence, overrides=overrides)
    system = System(sequence, run_config.config)
    system.run()
    summary = summarise_run(sequence, system.result, run_config.config, run_config.sources)
    row = {
        "sequence": sequence.name,
        "variant": variant,
        "frames": summary["frames"],
        "failures": len(summary["tracking_failures"]),
        "ATE [m]": summary["ate_rmse_m"],
        "RPE t [m]": summary["rpe_trans_rmse_m"],
        "RPE R [deg]": summary["rpe_rot_rmse_deg"],
    }
    for stage in STAGE_COLUMNS:
        row[f"{stage} ms"] = summary["timing_ms"][stage]["median"]
    row["RTF"] = summary["real_time_factor"]
    return row


def real_rows() -> list[dict]:
    """Rows for the real extracts found (missing ones are reported and skipped)."""
    return [run_row(folder, "default") for folder in existing_extracts()]


def synthetic_rows(out: Path, n_frames: int) -> list[dict]:
    """Rows for synthetic static and lowtexture sequences, lines on and off."""
    rows = []
    for scenario in ("static", "lowtexture"):
        folder = out / scenario
        write_sequence(folder, scenario, n_frames=n_frames, seed=0)
        for lines in ("true", "false"):
            rows.append(run_row(folder, f"lines={lines}", (f"lines.enabled={lines}",)))
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames-synthetic", type=int, default=100)
    parser.add_argument("--out", type=Path, default=Path(tempfile.gettempdir()) / "pld_slam_bench")
    args = parser.parse_args()
    rows = real_rows() + synthetic_rows(args.out, args.frames_synthetic)
    table = pd.DataFrame(rows).round({"ATE [m]": 4, "RPE t [m]": 4, "RPE R [deg]": 4, "RTF": 2})
    table = table.round({f"{stage} ms": 1 for stage in STAGE_COLUMNS})
    print(table.to_string(index=False))


if __name__ == "__main__":
    main()
