"""Local mapping: accuracy, robustness and speed with the map on and off (the figures of the mapping issue).

Sections (``--section``, all by default), each printing one table:

- ``accuracy``: every real extract found in ``$PLD_SLAM_DATA`` (default ``../shared/data``)
  and synthetic ``static``, ``dynamic`` and ``lowtexture`` sequences (``--frames`` frames,
  one per ``--seeds``), with mapping on and off (``lowtexture`` also with lines off): lost
  frames, keyframes, landmarks, ATE (SE(3) and Sim(3) alignment) and the estimate's path
  length over the ground truth's, RPE, median point / line inliers, where the front end ran
  ahead (process, thread, or - when not), mean ms per frame of
  each stage (local BA counted in the frame where it runs), median and mean ms per frame,
  median local BA ms, real-time factor. Then, per synthetic scenario, the mean ATE over
  seeds with mapping on and off and their ratio. That ratio moves with the seeds more than
  with most changes: static (300 frames) 0.58 over seeds 0-2 (0.059 / 0.102 m) and 0.42 over
  seeds 3-5 (0.069 / 0.163 m), 0.48 over all six; judge it over six seeds or more.
- ``robustness``: each real extract with every second frame dropped, and started at frames
  10 and 25 (`pld_slam.datasets.StereoSequence.subsequence`): lost and recovered frames, ATE.
- ``keyframes``: where the GGS rule puts keyframes: on the synthetic ``loop`` (straights
  and turns) and KITTI raw 0005 (a junction), keyframes per 10 frames among frames that
  turn (heading change above ``--turn-deg`` per frame, ground truth) and among the others,
  and among the fastest and the slowest third of the frames.
- ``growth``: one long synthetic ``loop`` sequence (``--growth-frames``): mean ms per frame
  over frames 100-200 and over the last 100, their ratio (flat cost as the map grows), and
  the peak memory of the run (its own process) and of its front-end process (`pld_slam.frame_extraction`).
- ``determinism``: each real extract run twice: whether the trajectory files are the same bytes.

Time only on an otherwise idle machine.

    python benchmarks/mapping.py [--section accuracy robustness keyframes growth determinism]
                                 [--frames 300] [--seeds 0 1 2] [--growth-frames 1000]
                                 [--out /tmp/pld_slam_mapping] [--set KEY=VALUE ...]
"""

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # before numpy loads OpenBLAS, as `pld-slam` runs (`pld_slam`)

import argparse
import multiprocessing
import resource
import tempfile
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
import pandas as pd
from extracts import real_sequences

from pld_slam.datasets import StereoSequence, open_sequence
from pld_slam.eval.run_summary import summarise_run
from pld_slam.io.trajectory import write_kitti
from pld_slam.run_config import load_run_config
from pld_slam.synth import write_sequence
from pld_slam.system import RunResult, System

SYNTHETIC_SCENARIOS = ("static", "dynamic", "lowtexture")
TRACKING_STAGES = ("matching", "filters", "pose", "dynamic", "local_map", "see_through")


def run(sequence: StereoSequence, overrides: tuple[str, ...]) -> tuple[RunResult, dict]:
    """Run the pipeline on ``sequence`` (its family config, then ``overrides``); the result and its summary."""
    run_config = load_run_config(sequence, overrides=overrides)
    system = System(sequence, run_config.config)
    system.run()
    return system.result, summarise_run(sequence, system.result, run_config.config, run_config.sources)


def mean_stage_ms(result: RunResult, stages: tuple[str, ...]) -> float:
    """Mean over all frames of the summed wall time [ms] of ``stages`` (0 in frames that did not run them)."""
    return float(np.mean([sum(r.stage_ms.get(stage, 0.0) for stage in stages) for r in result.records]))


def sim3_figures(summary: dict) -> dict:
    """The run summary's ATE after Sim(3) alignment and path ratio (None without ground truth, or
    where the truth hardly moves: `pld_slam.eval.metrics.scale_is_measurable`)."""
    return {"ATE sim3 [m]": summary["ate_sim3_rmse_m"], "path ratio": summary["path_ratio"]}


def accuracy_row(sequence: StereoSequence, variant: str, overrides: tuple[str, ...]) -> dict:
    """One row of the accuracy table."""
    result, summary = run(sequence, overrides)
    mapping = summary["mapping"] or {}
    features = summary["features_median"]
    with_map = bool(mapping)
    total = summary["timing_ms"]["total"]
    landmarks = mapping.get("landmarks", {})
    return {
        "sequence": sequence.name,
        "variant": variant,
        "frames": summary["frames"],
        "lost": len(summary["tracking_failures"]),
        "keyframes": mapping.get("keyframes"),
        "points": landmarks.get("points"),
        "lines": landmarks.get("lines"),
        "ATE [m]": summary["ate_rmse_m"],
        **sim3_figures(summary),
        "RPE t [m]": summary["rpe_trans_rmse_m"],
        "RPE R [deg]": summary["rpe_rot_rmse_deg"],
        "pt inl": features["map_point_inliers"] if with_map else features["point_inliers"],
        "line inl": features["map_line_inliers"] if with_map else features["line_inliers"],
        "front in": summary["frontend_worker"] or "-",
        "front ms": mean_stage_ms(result, ("load", "frontend")),
        "track ms": mean_stage_ms(result, TRACKING_STAGES),
        "map ms": mean_stage_ms(result, ("mapping",)),
        "total med": total["median"],
        "total mean": total["mean"],
        "BA med": mapping.get("local_ba", {}).get("ms_median"),
        "RTF": summary["real_time_factor"],
    }


def accuracy_rows(out: Path, frames: int, seeds: list[int], overrides: tuple[str, ...]) -> list[dict]:
    rows = []
    for sequence in real_sequences():
        for variant, switch in (("map", "mapping.enabled=true"), ("no map", "mapping.enabled=false")):
            rows.append(accuracy_row(sequence, variant, (switch, *overrides)))
    for scenario in SYNTHETIC_SCENARIOS:
        for seed in seeds:
            folder = out / f"{scenario}_{seed}"
            write_sequence(folder, scenario, n_frames=frames, seed=seed)
            sequence = open_sequence(folder)
            variants = [("map", ("mapping.enabled=true",)), ("no map", ("mapping.enabled=false",))]
            if scenario == "lowtexture":
                variants.append(("map, no lines", ("mapping.enabled=true", "lines.enabled=false")))
            for variant, switches in variants:
                rows.append(accuracy_row(sequence, variant, (*switches, *overrides)) | {"scenario": scenario})
    return rows


def synthetic_ratios(rows: list[dict]) -> pd.DataFrame:
    """Per synthetic scenario and variant, the mean ATE over seeds, and each variant's over the run without a map."""
    table = pd.DataFrame([row for row in rows if row.get("scenario")])
    if table.empty:
        return table
    means = table.groupby(["scenario", "variant"])["ATE [m]"].mean().unstack("variant")
    for variant in means.columns:
        means[f"{variant} / no map"] = means[variant] / means["no map"]
    return means


def robustness_rows(overrides: tuple[str, ...]) -> list[dict]:
    """Each real extract with every second frame dropped, and started at frames 10 and 25."""
    rows = []
    for sequence in real_sequences():
        for start, step in ((0, 2), (10, 1), (25, 1)):
            if start >= len(sequence) - 2:
                continue
            part = sequence.subsequence(start, step)
            _, summary = run(part, overrides)
            rows.append({
                "sequence": part.name,
                "frames": summary["frames"],
                "lost": len(summary["tracking_failures"]),
                "recovered": len(summary["recovered_frames"]),
                "ATE [m]": summary["ate_rmse_m"],
                "RPE t [m]": summary["rpe_trans_rmse_m"],
            })
    return rows


def keyframe_density_row(sequence: StereoSequence, turn_deg: float, overrides: tuple[str, ...]) -> dict:
    """Keyframes per 10 frames in turns and on straights, in fast and slow motion (ground-truth motion)."""
    result, summary = run(sequence, overrides)
    poses = sequence.groundtruth.poses[: len(result.records)]
    turn = np.einsum("nji,njk->nik", poses[:-1, :3, :3], poses[1:, :3, :3])  # R_{k-1}^T R_k
    rotation = np.degrees(np.arccos(np.clip((np.trace(turn, axis1=1, axis2=2) - 1) / 2, -1, 1)))
    speed = np.linalg.norm(poses[1:, :3, 3] - poses[:-1, :3, 3], axis=1)
    is_keyframe = np.array([r.keyframe is not None for r in result.records[1:]])
    turning = rotation > turn_deg
    slow, fast = speed <= np.quantile(speed, 1 / 3), speed >= np.quantile(speed, 2 / 3)

    def per_10(frames: np.ndarray) -> float | None:
        return 10.0 * is_keyframe[frames].mean() if frames.any() else None

    return {
        "sequence": sequence.name,
        "frames": len(result.records),
        "keyframes": summary["mapping"]["keyframes"],
        "turning frames": int(turning.sum()),
        "KF/10 turning": per_10(turning),
        "KF/10 straight": per_10(~turning),
        "KF/10 fastest third": per_10(fast),
        "KF/10 slowest third": per_10(slow),
        "ATE [m]": summary["ate_rmse_m"],
    }


def keyframe_density_rows(out: Path, n_frames: int, turn_deg: float,
                          overrides: tuple[str, ...]) -> list[dict]:
    folder = out / f"loop_{n_frames}"
    write_sequence(folder, "loop", n_frames=n_frames, seed=0)
    sequences = [open_sequence(folder)]
    sequences += real_sequences(("kitti_raw/2011_09_26/2011_09_26_drive_0005_sync",))
    return [keyframe_density_row(sequence, turn_deg, overrides) for sequence in sequences]


def growth_row(folder: Path, overrides: tuple[str, ...]) -> dict:
    """Cost per frame early and late in a long run (run in its own process for its peak memory)."""
    sequence = open_sequence(folder)
    result, summary = run(sequence, overrides)
    total = np.array([r.stage_ms["total"] for r in result.records])
    early, late = total[100:200].mean(), total[-100:].mean()
    return {
        "sequence": sequence.name,
        "frames": len(total),
        "keyframes": summary["mapping"]["keyframes"],
        "landmarks": summary["mapping"]["landmarks"]["points"] + summary["mapping"]["landmarks"]["lines"],
        "ms 100-200": early,
        "ms last 100": late,
        "late / early": late / early,
        "ATE [m]": summary["ate_rmse_m"],
        "peak MB": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
        "front-end process peak MB": resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024.0 or None,
    }


def growth_rows(out: Path, n_frames: int, overrides: tuple[str, ...]) -> list[dict]:
    folder = out / f"loop_{n_frames}"
    write_sequence(folder, "loop", n_frames=n_frames, seed=0)
    with ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context("spawn")) as pool:
        return [pool.submit(growth_row, folder, overrides).result()]


def determinism_rows(out: Path, overrides: tuple[str, ...]) -> list[dict]:
    """Each real extract run twice: are the KITTI trajectory files the same bytes?"""
    rows = []
    for sequence in real_sequences():
        files = []
        for attempt in range(2):
            result, _ = run(sequence, overrides)
            path = out / f"{sequence.name}_{attempt}.kitti.txt"
            write_kitti(path, result.trajectory())
            files.append(path.read_bytes())
        rows.append({"sequence": sequence.name, "same bytes": files[0] == files[1]})
    return rows


def show(title: str, rows: list[dict] | pd.DataFrame) -> None:
    table = rows if isinstance(rows, pd.DataFrame) else pd.DataFrame(rows)
    print(f"\n{title}")
    print(table.to_string(index=isinstance(rows, pd.DataFrame), float_format=lambda x: f"{x:.4g}"))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sections = ["accuracy", "robustness", "keyframes", "growth", "determinism"]
    parser.add_argument("--section", nargs="+", default=sections, choices=sections)
    parser.add_argument("--frames", type=int, default=300, help="frames of each synthetic sequence")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--growth-frames", type=int, default=1000)
    parser.add_argument("--loop-frames", type=int, default=360, help="frames of the synthetic loop of 'keyframes'")
    parser.add_argument("--turn-deg", type=float, default=0.5, help="heading change per frame of a turning frame")
    parser.add_argument("--out", type=Path, default=Path(tempfile.gettempdir()) / "pld_slam_mapping")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    overrides = tuple(args.overrides)
    if "accuracy" in args.section:
        rows = accuracy_rows(args.out, args.frames, args.seeds, overrides)
        show("accuracy and speed, mapping on and off (ms: mean per frame unless 'med')",
             [{k: v for k, v in row.items() if k != "scenario"} for row in rows])
        show("synthetic: mean ATE [m] over seeds, and over the run without a map", synthetic_ratios(rows))
    if "robustness" in args.section:
        show("every second frame dropped, and late starts (mapping on)", robustness_rows(overrides))
    if "keyframes" in args.section:
        show("keyframes per 10 frames: turns and straights, fast and slow motion",
             keyframe_density_rows(args.out, args.loop_frames, args.turn_deg, overrides))
    if "growth" in args.section:
        show("cost as the map grows", growth_rows(args.out, args.growth_frames, overrides))
    if "determinism" in args.section:
        show("same input, same bytes", determinism_rows(args.out, overrides))


if __name__ == "__main__":
    main()
