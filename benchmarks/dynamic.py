"""Dynamic scenes: the detectors against neither and against the true masks (the dynamic-scenes issue's figures).

For each sequence, runs the pipeline (mapping on, the family config) with neither detector,
the dynamic grid only, the dynamic LLG only, both, and, where the sequence has masks,
"masks": the labels taken from the ground-truth masks (``dynamic.from_masks``), the ATE a
perfect detector would reach. Prints per run ATE RMSE (and its ratio to "neither" and to
"masks"), the share of matched features marked dynamic, precision / recall of the dynamic
point and line labels against the masks, the median ms per frame of detection (the two
detectors and the static-world check), of the test of missed landmarks against the stereo
pair (`pld_slam.tracking.see_through`), and in all.

Sections (``--section``, all by default):

- ``scenes``: synthetic ``convoy`` and ``crossing`` (movers a robust solve follows: the
  figures to reach), ``dynamic`` (the easy case) and ``static`` (what the detectors cost
  where nothing moves), each on ``--seeds``; then per scenario over the seeds: mean ATE
  of each variant, its ratio to neither and to masks (of the means), and precision /
  recall pooled over every frame.
- ``real``: KITTI odometry 06 (static) and KITTI raw 0005 (dynamic), neither and both,
  when found through ``$PLD_SLAM_DATA``; the detection ms there is the cost per KITTI frame.
- ``parked``: synthetic ``parked_then_moving`` on ``--seeds`` with both detectors: the
  landmarks each parked car gave the map before it pulled out, and how many of them are
  still alive at the 5th keyframe after it started moving (figure: none), and of those the
  ones no keyframe since the start had in view (nothing could see them leave); also those
  made on it while it moved (features the detectors missed) that local mapping has had
  time to judge and still keeps. A landmark
  belongs to the object whose surface its creating feature lay on (the renderer's object
  ids at that keyframe's frame; `pld_slam.eval.mover_landmarks`).

    python benchmarks/dynamic.py [--section scenes real parked] [--seeds 0 1 2]
                                 [--variants neither grid llg both masks] [--out DIR]
                                 [--set tracking.reference_max_age=1 ...]
"""

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # before numpy loads OpenBLAS, as `pld-slam` runs (`pld_slam`)

import argparse
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd
from extracts import existing_extracts

from pld_slam.datasets import StereoSequence, open_sequence
from pld_slam.eval.dynamic_labels import MaskScores
from pld_slam.eval.mover_landmarks import GROUPS, MoverLandmarks
from pld_slam.eval.run_summary import summarise_run
from pld_slam.run_config import load_run_config
from pld_slam.synth.scenarios import DEFAULT_FRAMES, build_scenario
from pld_slam.synth.writer import ensure_sequence
from pld_slam.system import FrameRecord, System

VARIANTS = {
    "neither": ("dynamic.grid=false", "dynamic.llg=false"),
    "grid": ("dynamic.grid=true", "dynamic.llg=false"),
    "llg": ("dynamic.grid=false", "dynamic.llg=true"),
    "both": ("dynamic.grid=true", "dynamic.llg=true"),
    "masks": ("dynamic.from_masks=true",),
}
REAL = ("kitti_odometry/sequences/06", "kitti_raw/2011_09_26/2011_09_26_drive_0005_sync")
HARD_SCENES = ("convoy", "crossing")
KEYFRAMES_AFTER_START = 5


def run_variant(sequence: StereoSequence, overrides: tuple[str, ...]) -> dict:
    """Summary of one run (the sequence's family config) with the detectors switched by ``overrides``;
    the labels scored against the sequence's masks where it has them."""
    run_config = load_run_config(sequence, overrides=overrides)
    margin_px = run_config.config.dynamic.mask_margin_px
    scores = None if sequence.dynamic_mask_paths is None else MaskScores(sequence, margin_px)
    system = System(sequence, run_config.config, [] if scores is None else [scores])
    system.run()
    return summarise_run(sequence, system.result, run_config.config, run_config.sources, scores)


def label_count_columns(dynamic: dict) -> dict:
    """The run's label counts (summed over frames) for pooling over sequences: flagged,
    on moving objects, and both, for points and lines; the values are None without masks."""
    return {
        f"{kind} {count}": dynamic[kind][count]
        for kind in ("points", "lines")
        for count in ("flagged", "on_moving_objects", "flagged_on_them")
    }


def count_columns(table: pd.DataFrame) -> list[str]:
    """The label-count columns of ``table`` (`label_count_columns`)."""
    return [column for column in table.columns if column.startswith(("points ", "lines "))]


def rows_for(sequence: StereoSequence, variants: list[str], extra: tuple[str, ...]) -> list[dict]:
    """One row per variant on ``sequence`` ("masks" only where it has masks)."""
    rows = []
    for variant in variants:
        if variant == "masks" and sequence.dynamic_mask_paths is None:
            continue
        summary = run_variant(sequence, extra + VARIANTS[variant])
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
            "see-through ms": summary["timing_ms"]["see_through"]["median"],
            "total ms": summary["timing_ms"]["total"]["median"],
            **label_count_columns(dynamic),
        })
    by_variant = {row["variant"]: row["ATE [m]"] for row in rows}
    for row in rows:
        row["ATE / neither"] = row["ATE [m]"] / by_variant["neither"] if "neither" in by_variant else np.nan
        row["ATE / masks"] = row["ATE [m]"] / by_variant["masks"] if "masks" in by_variant else np.nan
    return rows


def pooled(rows: pd.DataFrame) -> pd.DataFrame:
    """Per variant over a scenario's seeds: mean ATE, its ratio to the mean ATE of neither and
    of masks, and precision / recall of the labels pooled over all their frames."""
    means = rows.groupby("variant", sort=False)["ATE [m]"].mean()
    table = {}
    for variant, group in rows.groupby("variant", sort=False):
        counts = group[count_columns(group)].sum()
        table[variant] = {
            "mean ATE [m]": means[variant],
            "/ neither": means[variant] / means["neither"] if "neither" in means else np.nan,
            "/ masks": means[variant] / means["masks"] if "masks" in means else np.nan,
            **{
                f"{short} {measure}": counts[f"{kind} flagged_on_them"] / counts[f"{kind} {total}"]
                if counts[f"{kind} {total}"] else float("nan")
                for kind, short in (("points", "pt"), ("lines", "line"))
                for measure, total in (("P", "flagged"), ("R", "on_moving_objects"))
            },
            "marked %": group["marked %"].mean(),
        }
    return pd.DataFrame(table).T


def print_table(table: pd.DataFrame) -> None:
    print(table.to_string(float_format=lambda x: f"{x:.3f}"), flush=True)


def scenes(out: Path, seeds: list[int], variants: list[str], extra: tuple[str, ...]) -> None:
    """The ``scenes`` section (module docstring)."""
    rows = []
    for scenario in (*HARD_SCENES, "dynamic", "static"):
        for seed in seeds:
            folder = ensure_sequence(out / f"{scenario}_{seed}", scenario, DEFAULT_FRAMES[scenario], seed)
            sequence_rows = rows_for(open_sequence(folder), variants, extra)
            rows += [dict(row, scenario=scenario, sequence=f"synth_{scenario}_{seed}") for row in sequence_rows]
            table = pd.DataFrame(sequence_rows)
            print_table(table.drop(columns=count_columns(table)).set_index(["sequence", "variant"]))
    table = pd.DataFrame(rows)
    print("\nevery run:")
    print_table(table.drop(columns=[*count_columns(table), "scenario"]).set_index(["sequence", "variant"]))
    for scenario, group in table.groupby("scenario", sort=False):
        print(f"\n{scenario}, seeds {' '.join(map(str, seeds))}: "
              "means over seeds, labels pooled over all frames")
        print_table(pooled(group))


def real(variants: list[str], extra: tuple[str, ...]) -> None:
    """The ``real`` section (module docstring)."""
    rows = []
    for folder in existing_extracts(REAL):
        rows += rows_for(open_sequence(folder), [v for v in variants if v in ("neither", "both")], extra)
    if rows:
        table = pd.DataFrame(rows)
        print("\nreal extracts:")
        print_table(table.drop(columns=count_columns(table)).set_index(["sequence", "variant"]))


def parked_run(folder: Path, seed: int, extra: tuple[str, ...]) -> list[dict]:
    """One ``parked_then_moving`` run with both detectors: a row per car that pulled out (module docstring)."""
    sequence = open_sequence(folder)
    size = (sequence.camera.width, sequence.camera.height)
    config = load_run_config(sequence, overrides=extra + VARIANTS["both"]).config
    watch = MoverLandmarks(build_scenario("parked_then_moving", len(sequence), size, seed), KEYFRAMES_AFTER_START,
                           config.mapping.min_observation_age)
    system: System

    def on_record(record: FrameRecord) -> None:
        if record.keyframe is not None:
            watch.on_keyframe(system.local_mapping.map, record.reference_keyframe)

    system = System(sequence, config, record_observer=on_record)
    system.run()
    return [{"seed": seed} | row for row in watch.rows()]


def parked(out: Path, seeds: list[int], extra: tuple[str, ...]) -> None:
    """The ``parked`` section (module docstring)."""
    rows = []
    for seed in seeds:
        folder = ensure_sequence(out / f"parked_then_moving_{seed}", "parked_then_moving",
                                 DEFAULT_FRAMES["parked_then_moving"], seed)
        rows += parked_run(folder, seed, extra)
    table = pd.DataFrame(rows)
    print(f"\nparked_then_moving, both detectors: landmarks on each car that pulled out, and those alive "
          f"{KEYFRAMES_AFTER_START} keyframes after it started (NaN: the run ended first)")
    print(table.to_string(index=False), flush=True)
    print(f"landmarks made on the cars that pulled out: {int(table[['points made', 'lines made']].to_numpy().sum())}")
    for group in GROUPS:
        alive = int(np.nansum(table.filter(like=f"made {group}, alive").to_numpy(dtype=float)))
        print(f"made {group}, alive at KF+{KEYFRAMES_AFTER_START}: {alive}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--section", nargs="+", choices=("scenes", "real", "parked"),
                        default=["scenes", "real", "parked"])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--variants", nargs="+", choices=tuple(VARIANTS), default=list(VARIANTS))
    parser.add_argument("--out", type=Path, default=Path(tempfile.gettempdir()) / "pld_slam_dynamic")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    args = parser.parse_args()
    extra = tuple(args.overrides)
    if "scenes" in args.section:
        scenes(args.out, args.seeds, args.variants, extra)
    if "real" in args.section:
        real(args.variants, extra)
    if "parked" in args.section:
        parked(args.out, args.seeds, extra)


if __name__ == "__main__":
    main()
