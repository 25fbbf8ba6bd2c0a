"""How well the disparity-offset self-calibration finds an offset it is given: rigs calibrated wrong on purpose.

Renders synthetic drives (``pld-slam synth``: an exact rig, true offset 0), then copies
each (images linked, not copied) with a calibration file that is off: the right camera's
principal point in ``P1`` moved by DELTA px, so the file's disparity offset is wrong by
DELTA and the self-calibration (`pld_slam.stereo_calibration`) should read DELTA. The
copies have no ``synth.json``: they read as KITTI odometry sequences and get the KITTI
family's settings (a prior spread of 0.15 px, no test), as a KITTI rig of unknown offset
does. Each copy is measured whole and cut to its first ``--cut`` frames (a short or fast
drive has few anchors). Printed per copy: the estimate and its deviation against DELTA,
what was applied, the pairs and anchors' frame gap, why it was not used; with ``--run``,
also the run's Sim(3) scale and path ratio (1 when the offset was found and nothing else
is wrong).

The truth is the offset put in, not a ground truth of a real rig: this measures the
estimator itself, which the real extracts cannot (KITTI 04's ground-truth motion asks for
-0.14 to +0.03 px depending on the frame gap, `benchmarks/stereo_depth.py`).

    python benchmarks/calibration_offset.py [--scenario highway] [--seeds 0,1,2] [--deltas -0.12,0,0.12]
                                            [--frames 100] [--cut 26] [--camera kitti] [--set KEY=VALUE ...]
                                            [--run] [--out DIR]

``--set`` applies to the estimate and the runs alike (a before/after table of a calibration key).
"""

import argparse
import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd
from speed import cli_run

from pld_slam.datasets import open_sequence
from pld_slam.run_config import load_run_config
from pld_slam.stereo_calibration import estimate_disparity_offset
from pld_slam.synth.writer import ensure_sequence


def miscalibrated_copy(source: Path, target: Path, delta: float, n_frames: int) -> Path:
    """A KITTI odometry sequence ``target`` (``.../sequences/NN``) of the first ``n_frames`` frames of
    ``source``, images linked, ``P1``'s principal point column moved by ``delta`` [px], its ground
    truth in ``.../poses/NN.txt``; a copy an earlier call left there is replaced."""
    shutil.rmtree(target, ignore_errors=True)
    for camera in ("image_0", "image_1"):
        (target / camera).mkdir(parents=True)
        for index in range(n_frames):
            (target / camera / f"{index:06d}.png").symlink_to(source / camera / f"{index:06d}.png")
    rows = []
    for line in (source / "calib.txt").read_text().splitlines():
        if line.startswith("P1:"):
            values = [float(value) for value in line.split()[1:]]
            values[2] += delta
            line = "P1: " + " ".join(f"{value:.12e}" for value in values)
        rows.append(line)
    (target / "calib.txt").write_text("\n".join(rows) + "\n")
    (target / "times.txt").write_text("\n".join((source / "times.txt").read_text().split()[:n_frames]) + "\n")
    poses = target.parents[1] / "poses"
    poses.mkdir(exist_ok=True)
    rows = [line for line in (source / "poses.txt").read_text().splitlines() if line.strip()][:n_frames]
    (poses / f"{target.name}.txt").write_text("\n".join(rows) + "\n")
    return target


def measure(folder: Path, delta: float, overrides: list[str], run_out: Path | None) -> dict:
    """The self-calibration's outcome on one miscalibrated copy (and its run's scale with ``run_out``)."""
    sequence = open_sequence(folder)
    estimate = estimate_disparity_offset(sequence, load_run_config(sequence, overrides=overrides).config)
    row = {
        "frames": len(sequence), "offset in [px]": delta, "estimate [px]": estimate.estimate_px,
        "sigma [px]": estimate.sigma_px, "applied [px]": estimate.offset_px,
        "error [px]": estimate.offset_px - delta, "pairs": estimate.pairs, "gap": estimate.frame_gap,
        "not used because": estimate.reason or "-",
    }
    if run_out is not None:
        _, summary = cli_run(folder, run_out, *(argument for override in overrides for argument in ("--set", override)))
        row["sim3 scale"], row["path ratio"] = summary["sim3_scale"], summary["path_ratio"]
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="highway")
    parser.add_argument("--seeds", default="0,1,2")
    parser.add_argument("--deltas", default="-0.12,0,0.12", help="offsets put into the calibration [px]")
    parser.add_argument("--frames", type=int, default=100)
    parser.add_argument("--cut", type=int, default=26, help="also measure the first this many frames (0: not)")
    parser.add_argument("--camera", default="kitti")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                        help="a configuration override for the estimate and the runs (repeatable)")
    parser.add_argument("--run", action="store_true", help="also run pld-slam on each copy: Sim(3) scale")
    parser.add_argument("--out", type=Path, default=None,
                        help="rendered drives and copies (default: a temporary folder)")
    args = parser.parse_args()
    out = args.out or Path(tempfile.mkdtemp(prefix="pld-slam-offset-"))
    seeds = [int(seed) for seed in args.seeds.split(",")]
    deltas = [float(delta) for delta in args.deltas.split(",")]
    lengths = [args.frames] + ([args.cut] if 0 < args.cut < args.frames else [])
    rows = []
    for seed in seeds:
        rendered = ensure_sequence(out / "rendered" / f"{args.scenario}-seed{seed}-{args.frames}-{args.camera}",
                                   args.scenario, args.frames, seed, args.camera)
        for d, delta in enumerate(deltas):
            for c, length in enumerate(lengths):
                name = f"{seed}{d}{c}"
                copy = miscalibrated_copy(rendered, out / "kitti_odometry" / "sequences" / name, delta, length)
                run_out = out / "runs" / name if args.run else None
                rows.append({"seed": seed, **measure(copy, delta, args.overrides, run_out)})
                print(f"seed {seed}, offset {delta:+.3f} px, {length} frames: done", file=sys.stderr, flush=True)
    table = pd.DataFrame(rows)
    print(f"# {args.scenario}, {args.camera} camera, self-calibration with the KITTI family's settings"
          f"{', --set ' + ' '.join(args.overrides) if args.overrides else ''}; files in {out}")
    with pd.option_context("display.width", 200, "display.max_columns", 20, "display.max_colwidth", 60):
        print(table.to_string(index=False, float_format=lambda value: f"{value:+.4f}"))
        found = table[table["not used because"] == "-"]
        print(f"\nused {len(found)} of {len(table)}; error of the applied offset over those: mean "
              f"{found['error [px]'].mean():+.4f} px, RMS {np.sqrt((found['error [px]'] ** 2).mean()):.4f} px")


if __name__ == "__main__":
    main()
