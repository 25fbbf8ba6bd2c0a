"""Dynamic-feature detection: the four variants of the paper's Table I side by side.

For each sequence, runs the pipeline with neither detector, the dynamic grid only, the
dynamic LLG only, and both, and prints ATE RMSE (and its ratio to "neither"), the share of
matched features marked dynamic, precision / recall of the dynamic point and line labels
against the moving-object masks (synthetic sequences), and the median ms per frame the
detection costs. Sequences with masks get a fifth row, "masks": the labels taken from the
ground-truth masks (``dynamic.from_masks``), the ATE a perfect detector would reach.
Sequences: synthetic ``dynamic`` (several seeds) and ``static``, and the real KITTI raw
0005 (dynamic) and KITTI odometry 06 (static) extracts when found.

    python benchmarks/dynamic.py [--seeds 0 1 2] [--frames 100] [--out /tmp/pld_slam_dynamic]
                                 [--set tracking.reference_max_age=1 ...]

``--set`` overrides the configuration of every run, e.g. frame-to-frame tracking
(``tracking.reference_max_age=1``), where movers hurt the pose more.
"""

import argparse
import os
import tempfile
from pathlib import Path

import pandas as pd

from pld_slam.datasets import StereoSequence, open_sequence
from pld_slam.eval.run_summary import summarise_run
from pld_slam.run_config import load_run_config
from pld_slam.synth import write_sequence
from pld_slam.system import System

REPO = Path(__file__).resolve().parents[1]
VARIANTS = {
    "neither": ("dynamic.grid=false", "dynamic.llg=false"),
    "grid": ("dynamic.grid=true", "dynamic.llg=false"),
    "llg": ("dynamic.grid=false", "dynamic.llg=true"),
    "both": ("dynamic.grid=true", "dynamic.llg=true"),
    "masks": ("dynamic.from_masks=true",),
}
REAL = (
    "kitti_raw/2011_09_26/2011_09_26_drive_0005_sync",
    "kitti_odometry/sequences/06",
)


def run_variant(sequence: StereoSequence, overrides: tuple[str, ...]) -> dict:
    """Summary of one run (the sequence's family config) with the detectors switched by ``overrides``."""
    run_config = load_run_config(sequence, overrides=overrides)
    system = System(sequence, run_config.config)
    system.run()
    return summarise_run(sequence, system.result, run_config.config, run_config.sources)


def label_count_columns(dynamic: dict) -> dict:
    """The run's label counts (summed over frames) for pooling over sequences: flagged,
    on moving objects, and both, for points and lines; None without masks."""
    return {
        f"{kind} {count}": dynamic[kind][count]
        for kind in ("points", "lines")
        for count in ("flagged", "on_moving_objects", "flagged_on_them")
    }


def count_columns(table: pd.DataFrame) -> list[str]:
    """The label-count columns of ``table`` (`label_count_columns`)."""
    return [column for column in table.columns if column.startswith(("points ", "lines "))]


def pooled(rows: pd.DataFrame) -> pd.DataFrame:
    """Per variant over the synthetic dynamic sequences: ATE / neither (mean, min, max) and
    precision / recall of the labels pooled over all their frames."""
    table = {}
    for variant, group in rows.groupby("variant", sort=False):
        counts = group[count_columns(group)].sum()
        table[variant] = {
            "ATE / neither mean": group["ATE / neither"].mean(),
            "min": group["ATE / neither"].min(),
            "max": group["ATE / neither"].max(),
            **{
                f"{short} {measure}": counts[f"{kind} flagged_on_them"] / counts[f"{kind} {total}"]
                if counts[f"{kind} {total}"] else float("nan")
                for kind, short in (("points", "pt"), ("lines", "line"))
                for measure, total in (("P", "flagged"), ("R", "on_moving_objects"))
            },
        }
    return pd.DataFrame(table).T


def rows_for(folder: Path, extra: tuple[str, ...]) -> list[dict]:
    """One row per variant on the sequence in ``folder`` ("masks" only where it has masks)."""
    sequence = open_sequence(folder)
    rows = []
    for variant, overrides in VARIANTS.items():
        if variant == "masks" and sequence.dynamic_mask_paths is None:
            continue
        summary = run_variant(sequence, extra + overrides)
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
            **label_count_columns(dynamic),
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
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    args = parser.parse_args()
    extra = tuple(args.overrides)
    rows = []
    for scenario, seeds in (("dynamic", args.seeds), ("static", args.seeds[:1])):
        for seed in seeds:
            folder = args.out / f"{scenario}_{seed}"
            write_sequence(folder, scenario, n_frames=args.frames, seed=seed)
            synthetic_rows = rows_for(folder, extra)
            rows += [dict(row, sequence=f"synth_{scenario}_{seed}") for row in synthetic_rows]
    data_dir = Path(os.environ.get("PLD_SLAM_DATA", REPO.parent / "shared" / "data"))
    for relative in REAL:
        if (data_dir / relative).is_dir():
            rows += rows_for(data_dir / relative, extra)
        else:
            print(f"skipped {data_dir / relative}: not found (set PLD_SLAM_DATA)")
    table = pd.DataFrame(rows)
    print(table.drop(columns=count_columns(table)).to_string(index=False, float_format=lambda x: f"{x:.3f}"))
    dynamic = table[table["sequence"].str.startswith("synth_dynamic")]
    print(f"\nsynthetic dynamic, seeds {' '.join(map(str, args.seeds))} pooled:")
    print(pooled(dynamic).to_string(float_format=lambda x: f"{x:.3f}"))


if __name__ == "__main__":
    main()
