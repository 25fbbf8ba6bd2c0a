"""Is a run's error in its solver or in its measurements? Bundle adjustment started at the truth.

Each sequence runs with the final global BA off; then every keyframe and landmark of its
map is bundle-adjusted to convergence (`pld_slam.optim.bundle_adjustment.TO_CONVERGENCE`,
first keyframe held fixed, residuals and outlier rounds as every BA of the map), twice,
each on its own copy of the map:

- ``from run``: from the run's own poses and landmarks (what the final global BA could
  reach with no limit on its iterations);
- ``from truth``: from the keyframes' ground-truth poses, every landmark re-made from one
  of its stereo observations at that keyframe's true pose
  (`pld_slam.eval.map_at_truth.move_map_to_truth`).

``from truth`` is the optimum of the map's own observations (feature positions, matches,
and which of them BA keeps) nearest the truth. When its ATE is no better than the run's,
the run is as accurate as its measurements allow, and only better measurements can
improve it; when it is clearly better, the incremental estimation (tracking, local BA
windows) or the solver loses accuracy. The table has the ATE (SE(3) alignment, every
frame through its reference keyframe) of the run and of both solves, the solves'
evaluations and final cost (robust-round inliers, whitened), and the end pose's rotation
error (x right: pitch, z forward: roll).

Sequences: the real extracts found in ``$PLD_SLAM_DATA`` (default ``../shared/data``)
whose ground truth has a pose per frame (all of them: the EuRoC loader gives each frame
its ground-truth pose), and the synthetic ``--scenarios`` for each of ``--seeds``.

    python benchmarks/ba_truth.py [--scenarios static loop] [--seeds 0 1 2] [--frames 300]
                                  [--no-real] [--out /tmp/pld_slam_ba_truth] [--set KEY=VALUE ...]
"""

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # before numpy loads OpenBLAS, as `pld-slam` runs (`pld_slam`)

import argparse
import copy
import dataclasses
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd
from extracts import real_sequences
from scipy.spatial.transform import Rotation

from pld_slam.config import Config
from pld_slam.datasets import StereoSequence, open_sequence
from pld_slam.eval.map_at_truth import move_map_to_truth
from pld_slam.eval.metrics import evaluate
from pld_slam.geometry.se3 import inverse
from pld_slam.mapping.map_ba import BaReport, MapBaOptions, adjust_keyframes
from pld_slam.run_config import load_run_config
from pld_slam.synth.scenarios import DEFAULT_FRAMES
from pld_slam.synth.writer import ensure_sequence
from pld_slam.system import RunResult, System

MAX_NFEV = 200
"""Evaluations allowed per round of a solve (robust, then plain). On the default set the solves
took 6-55 evaluations over both rounds, but static seed 0 from the truth took 193, and three
took more than 200 (static seed 2 from the run, loop seeds 0 and 1 from the truth): one of
their rounds stopped here, short of its tolerance."""


def adjusted_copy(result: RunResult, sequence: StereoSequence, config: Config, from_truth: bool
                  ) -> tuple[RunResult, BaReport | None]:
    """A copy of ``result`` with every keyframe and landmark of its map bundle-adjusted to convergence,
    from the run's estimate or (``from_truth``) from the map moved to the truth; and the BA's report."""
    world_map = copy.deepcopy(result.map)
    if from_truth:
        move_map_to_truth(world_map, sequence.groundtruth.poses)
    report = adjust_keyframes(world_map, sorted(world_map.keyframes), sequence.camera, MapBaOptions.of(config),
                              MAX_NFEV, to_convergence=True)
    return dataclasses.replace(result, map=world_map), report


def end_rotation_error_deg(sequence: StereoSequence, estimate: np.ndarray) -> np.ndarray:
    """Rotation error (3,) [deg] of the last of the ``estimate`` poses (N, 4, 4) ``T_w_c`` relative to the
    first, as a rotation vector in its camera."""
    truth = sequence.groundtruth.poses
    error = inverse(inverse(truth[0]) @ truth[-1]) @ inverse(estimate[0]) @ estimate[-1]
    return np.degrees(Rotation.from_matrix(error[:3, :3]).as_rotvec())


def truth_row(label: str, sequence: StereoSequence, overrides: tuple[str, ...]) -> dict:
    """One row of the table (module docstring), for ``sequence`` named ``label``."""
    config = load_run_config(sequence, overrides=("optimize.global_ba=false", *overrides)).config
    system = System(sequence, config)
    system.run()
    if system.result.map is None:
        raise SystemExit(f"{label}: the run made no map (mapping.enabled=false?); there is nothing to adjust")
    row = {"sequence": label, "keyframes": len(system.result.map.keyframes)}
    variants = {"run": (system.result, None)}
    for name, from_truth in (("from run", False), ("from truth", True)):
        variants[name] = adjusted_copy(system.result, sequence, config, from_truth)
    for name, (result, report) in variants.items():
        trajectory = result.trajectory()
        ate = evaluate(sequence.groundtruth, trajectory, by_index=True).ate_rmse_m
        row[f"ATE {name} [m]"] = ate
        if report is not None:
            row[f"nfev {name}"] = report.nfev
            row[f"cost {name}"] = report.final_cost
        pitch, _, roll = end_rotation_error_deg(sequence, trajectory.poses)
        row[f"end pitch/roll {name} [deg]"] = f"{pitch:+.3f}/{roll:+.3f}"
    return row


def sequences(args: argparse.Namespace) -> dict[str, StereoSequence]:
    """The real extracts with a true pose per frame (unless ``--no-real``) and the synthetic sequences asked
    for, by name."""
    real = [] if args.no_real else real_sequences()
    found = {s.name: s for s in real if s.groundtruth is not None and len(s.groundtruth.poses) == len(s)}
    for scenario in args.scenarios:
        for seed in args.seeds:
            frames = args.frames if scenario == "static" else DEFAULT_FRAMES[scenario]
            folder = args.out / f"{scenario}_{seed}"
            found[folder.name] = open_sequence(ensure_sequence(folder, scenario, frames, seed))
    return found


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenarios", nargs="*", default=["static", "loop"])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--frames", type=int, default=300, help="frames of a static sequence (others: their default)")
    parser.add_argument("--no-real", action="store_true", help="synthetic sequences only")
    parser.add_argument("--out", type=Path, default=Path(tempfile.gettempdir()) / "pld_slam_ba_truth")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    args = parser.parse_args()
    rows = [truth_row(label, sequence, tuple(args.overrides)) for label, sequence in sequences(args).items()]
    print("\nbundle adjustment to convergence, from the run and from the truth (global BA off in the run)")
    print(pd.DataFrame(rows).to_string(index=False, float_format=lambda x: f"{x:.4g}"))


if __name__ == "__main__":
    main()
