"""The accuracy table every default change is judged by: every real sequence and synthetic scenarios over seeds.

Runs ``pld-slam run`` on every real sequence found under ``$PLD_SLAM_DATA``
(`extracts.found_sequences`: each with ground truth; ``--no-real`` leaves them out) and on
synthetic ``--scenarios``, one per ``--seeds``, of ``--frames`` frames, and prints one row
per run: ATE RMSE (SE(3)), ATE after Sim(3), the Sim(3) scale and the path ratio (both the
estimate's size over the ground truth's: above 1 is too long), RPE per frame (translation,
rotation) and the frames where tracking was lost; then per scenario the mean over the seeds.
A header says what was measured: the git commit (and whether the tree had uncommitted
changes), the ``--set`` overrides, the variants, the synthetic arguments.

Each run is an ablation cell (`pld_slam.report.cells`): ``pld-slam run`` in its own child
process, ``--workers`` at once. ``--set KEY=VALUE`` applies to every run (the before/after
tables of a default change); ``--variant NAME:KEY=VALUE,KEY=VALUE`` (repeatable) runs every
sequence under each named config, its rows side by side (``--variant base:`` is the default
config). The runs always run afresh: a cell's key sees the config, not the code, and this
table is how a code change is judged. The synthetic sequences are rendered by
``pld-slam synth`` (``--synth-arg`` passes it more arguments, e.g. ``--synth-arg=--camera
--synth-arg=kitti``) into ``--out``/sequences, one folder per (scenario, seed, frames,
synth args), and reused by later invocations (delete them after a change to the
renderer); each run's files are kept in
``--out``/cells/SEQUENCE/VARIANT. Without ``--out`` all of it goes to a temporary folder.

    python benchmarks/accuracy.py [--set KEY=VALUE ...] [--variant NAME:KEY=VALUE,... ...]
                                  [--scenarios static,dynamic,lowtexture] [--seeds 0,1,2] [--frames 100]
                                  [--synth-arg ARG ...] [--real | --no-real] [--workers 2]
                                  [--out DIR] [--csv FILE]
"""

import argparse
import json
import re
import shutil
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import pandas as pd
from extracts import data_dir, found_sequences

from pld_slam.datasets import StereoSequence, open_sequence
from pld_slam.errors import PldSlamError
from pld_slam.report.cells import CellSpec, plan_cells
from pld_slam.report.runner import run_cells
from pld_slam.report.store import cell_dir, read_cell
from pld_slam.report.suite import Suite, Variant, check_overrides

REPO = Path(__file__).resolve().parents[1]

DEFAULT_VARIANT = "default"
"""The variant's name without ``--variant``: the defaults and ``--set``."""

METRICS = (
    ("ATE [m]", "ate_rmse_m", "{:.4f}"),
    ("ATE sim3 [m]", "ate_sim3_rmse_m", "{:.4f}"),
    ("sim3 scale", "sim3_scale", "{:.4f}"),
    ("path ratio", "path_ratio", "{:.4f}"),
    ("RPE [m]", "rpe_trans_rmse_m", "{:.4f}"),
    ("RPE [deg]", "rpe_rot_rmse_deg", "{:.3f}"),
    ("lost", "lost_frames", "{:.3g}"),
)
"""The table's columns of figures: header, key of a row, format."""


@dataclass(frozen=True)
class TableSequence:
    """A sequence of the table.

    Attributes
    ----------
    label : str
        Its rows' label: the sequence's name, or ``SCENARIO sSEED``.
    scenario : str or None
        The synthetic scenario, whose seeds have a mean row; None for a real sequence.
    sequence : StereoSequence
    """

    label: str
    scenario: str | None
    sequence: StereoSequence


def comma_list(text: str) -> list[str]:
    """``a,b,c`` as ``["a", "b", "c"]`` (blanks dropped)."""
    return [item.strip() for item in text.split(",") if item.strip()]


def parse_variant(text: str) -> Variant:
    """``NAME:KEY=VALUE,KEY=VALUE`` as a `Variant`, checked against the config.

    A comma splits overrides only before ``KEY=``, so a list value (``[1,2]``) stays whole;
    ``NAME:`` alone is the default config.
    """
    name, colon, overrides = text.partition(":")
    if not colon or not name.strip():
        raise argparse.ArgumentTypeError(f"{text!r}: expected NAME:KEY=VALUE,KEY=VALUE (or NAME: for the defaults)")
    variant = Variant(name.strip(), tuple(o.strip() for o in re.split(r",(?=\s*[\w.]+=)", overrides) if o.strip()))
    try:
        check_overrides(variant.overrides, f"--variant {variant.name}")
    except PldSlamError as error:
        raise argparse.ArgumentTypeError(str(error)) from None
    return variant


def synthetic_folder(sequences_dir: Path, scenario: str, seed: int, frames: int, synth_args: list[str]) -> Path:
    """The cache folder of a rendered sequence: ``SCENARIO-seedS-Nf``, then the synth arguments spelt out."""
    spelt = "_".join(re.sub(r"[^\w.=-]+", "_", arg.lstrip("-")) for arg in synth_args)
    return sequences_dir / (f"{scenario}-seed{seed}-{frames}f" + (f"--{spelt}" if spelt else ""))


def render_synthetic(folder: Path, scenario: str, seed: int, frames: int, synth_args: list[str]) -> Path:
    """``folder``, rendered by ``pld-slam synth`` unless there already.

    It renders into a scratch folder renamed to ``folder`` when done, so an existing
    ``folder`` is a whole sequence however an earlier invocation ended.

    Raises
    ------
    PldSlamError
        When ``pld-slam synth`` fails (an unknown scenario or argument): its last error line.
    """
    if folder.is_dir():
        return folder
    scratch = folder.with_name(folder.name + ".rendering")
    shutil.rmtree(scratch, ignore_errors=True)
    command = [sys.executable, "-m", "pld_slam_cli", "synth", str(scratch), "--scenario", scenario,
               "--seed", str(seed), "--frames", str(frames), *synth_args]
    done = subprocess.run(command, capture_output=True, text=True)
    if done.returncode != 0:
        lines = [line for line in done.stderr.splitlines() if line.strip()] or [f"exit code {done.returncode}"]
        raise PldSlamError(f"pld-slam synth {' '.join(command[5:])}: {lines[-1]}")
    scratch.rename(folder)
    return folder


def synthetic_sequences(out: Path, scenarios: list[str], seeds: list[int], frames: int, synth_args: list[str],
                        workers: int) -> list[TableSequence]:
    """Every (scenario, seed) sequence, rendered into ``out/sequences`` by ``workers`` at once where not cached."""
    (out / "sequences").mkdir(parents=True, exist_ok=True)
    keys = [(scenario, seed) for scenario in scenarios for seed in seeds]
    folders = [synthetic_folder(out / "sequences", scenario, seed, frames, synth_args) for scenario, seed in keys]
    with ThreadPoolExecutor(max_workers=max(1, workers)) as pool:
        jobs = [pool.submit(render_synthetic, folder, scenario, seed, frames, synth_args)
                for folder, (scenario, seed) in zip(folders, keys, strict=True)]
        for job in jobs:
            job.result()
    return [TableSequence(f"{scenario} s{seed}", scenario, open_sequence(folder))
            for (scenario, seed), folder in zip(keys, folders, strict=True)]


def real_table_sequences() -> list[TableSequence]:
    """Every real sequence with ground truth under ``$PLD_SLAM_DATA`` (`extracts.found_sequences`)."""
    return [TableSequence(sequence.name, None, sequence) for _, sequence in found_sequences()]


def run_row(out: Path, spec: CellSpec, table_sequence: TableSequence) -> dict:
    """The table row of a finished cell: its status and the figures of its summary.json (None where absent)."""
    recorded = read_cell(out, spec) or {"status": "failed", "reason": "no result"}
    summary_path = cell_dir(out, spec) / "summary.json"
    summary = json.loads(summary_path.read_text()) if summary_path.is_file() else None
    row = {
        "sequence": table_sequence.label,
        "scenario": table_sequence.scenario,
        "variant": spec.variant,
        "status": recorded["status"],
        "reason": recorded.get("reason") or "",
        "frames": None if summary is None else summary["frames"],
        "lost_frames": None if summary is None else len(summary["tracking_failures"]),
        "seconds": recorded.get("seconds"),
    }
    row.update({key: None if summary is None else summary[key] for _, key, _ in METRICS if key != "lost_frames"})
    return row


def run_table(out: Path, sequences: list[TableSequence], variants: list[Variant], overrides: list[str],
              workers: int) -> pd.DataFrame:
    """Every sequence under every variant, run afresh as ablation cells in ``out``; one row per run.

    Progress (each run as it finishes) goes to stderr, so that stdout holds the table only.
    """
    suite = Suite("accuracy", "", tuple(variants))
    cells = plan_cells([s.sequence for s in sequences], suite, overrides)
    shutil.rmtree(out / "cells", ignore_errors=True)
    finished = []

    def progress(row: dict) -> None:
        finished.append(row)
        note = f": {row['reason']}" if row["reason"] else ""
        print(f"[{len(finished)}/{len(cells)}] {row['sequence']} / {row['variant']}: {row['status']}{note} "
              f"({row['seconds']:.0f} s)", file=sys.stderr, flush=True)

    run_cells(out, cells, workers=workers, on_done=progress)
    owners = [s for s in sequences for _ in variants]  # plan_cells: sequence by sequence, variants within
    return pd.DataFrame([run_row(out, spec, owner) for spec, owner in zip(cells, owners, strict=True)])


def scenario_means(runs: pd.DataFrame) -> pd.DataFrame:
    """Per synthetic scenario and variant, the mean of every figure over the seeds that gave one.

    ``reason`` says how many seeds gave an ATE when not all did.
    """
    synthetic = runs[runs["scenario"].notna()]
    columns = [key for _, key, _ in METRICS]
    rows = []
    for (scenario, variant), group in synthetic.groupby(["scenario", "variant"], sort=False):
        measured = int(group["ate_rmse_m"].notna().sum())
        rows.append({
            "sequence": f"{scenario} mean", "scenario": scenario, "variant": variant,
            "status": "mean", "reason": "" if measured == len(group) else f"{measured} of {len(group)} seeds",
            **group[columns].astype(float).mean().to_dict(),
        })
    return pd.DataFrame(rows)


def cell_text(value, fmt: str) -> str:
    """A figure as the table prints it: ``-`` for none."""
    return "-" if value is None or pd.isna(value) else fmt.format(value)


def format_table(runs: pd.DataFrame, means: pd.DataFrame, show_variant: bool) -> str:
    """One line per run, a rule, then one per scenario mean; a note where a run stopped or failed."""
    labels = ["sequence", *(["variant"] if show_variant else []), *(header for header, _, _ in METRICS), "note"]

    def note(row) -> str:
        if row["status"] in ("ok", "mean"):
            return row["reason"]
        return f"{row['status']}: {row['reason']}" if row["reason"] else row["status"]

    def cells(row) -> list[str]:
        return [row["sequence"], *([row["variant"]] if show_variant else []),
                *(cell_text(row[key], fmt) for _, key, fmt in METRICS), note(row)]

    body = [cells(row) for _, row in runs.iterrows()]
    summary = [cells(row) for _, row in means.iterrows()]
    widths = [max(len(line[i]) for line in [labels, *body, *summary]) for i in range(len(labels))]
    figures = range(len(labels) - len(METRICS) - 1, len(labels) - 1)

    def line(texts: list[str]) -> str:
        return "  ".join(text.rjust(w) if i in figures else text.ljust(w)
                         for i, (text, w) in enumerate(zip(texts, widths, strict=True))).rstrip()

    rule = "-" * len(line(labels))
    return "\n".join([line(labels), *map(line, body), *([rule, *map(line, summary)] if summary else [])])


def git_state() -> str:
    """The commit checked out (short hash), and how many files differ from it."""
    def git(*args: str) -> str:
        return subprocess.run(["git", "-C", str(REPO), *args], capture_output=True, text=True).stdout.strip()

    commit = git("rev-parse", "--short", "HEAD") or "unknown"
    changed = len(git("status", "--porcelain").splitlines())
    return commit + (f" + uncommitted changes in {changed} files" if changed else " (clean)")


def header(args: argparse.Namespace, variants: list[Variant]) -> str:
    """What the table measured: commit, overrides, variants, synthetic sequences, real data."""
    def overrides_text(overrides) -> str:
        return " ".join(f"--set {o}" for o in overrides) or "none"

    lines = [f"# pld-slam accuracy  commit {git_state()}", f"# overrides: {overrides_text(args.overrides)}"]
    if args.variants:
        lines.append("# variants: " + "; ".join(f"{v.name}: {overrides_text(v.overrides)}" for v in variants))
    if args.scenarios:
        lines.append(f"# synthetic: {','.join(args.scenarios)}, seeds {','.join(map(str, args.seeds))}, "
                     f"{args.frames} frames, synth args: {' '.join(args.synth_args) or 'none'}")
    lines.append(f"# real: {'every sequence with ground truth under ' + str(data_dir()) if args.real else 'none'}")
    return "\n".join(lines)


def parse_args() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                        help="a config override for every run (repeatable)")
    parser.add_argument("--variant", dest="variants", action="append", default=[], type=parse_variant,
                        metavar="NAME:KEY=VALUE,...", help="a named config to compare (repeatable)")
    parser.add_argument("--scenarios", type=comma_list, default=["static", "dynamic", "lowtexture"],
                        help="synthetic scenarios, separated by commas (none: '')")
    parser.add_argument("--seeds", type=lambda text: [int(seed) for seed in comma_list(text)], default=[0, 1, 2])
    parser.add_argument("--frames", type=int, default=100, help="frames of each synthetic sequence")
    parser.add_argument("--synth-arg", dest="synth_args", action="append", default=[], metavar="ARG",
                        help="one more argument to pld-slam synth (repeatable; --synth-arg=--camera)")
    parser.add_argument("--real", action=argparse.BooleanOptionalAction, default=True,
                        help="run the real sequences under $PLD_SLAM_DATA")
    parser.add_argument("--workers", type=int, default=2, help="runs at once, each in a child process")
    parser.add_argument("--out", type=Path, default=None, help="keep the sequences and runs here")
    parser.add_argument("--csv", type=Path, default=None, help="also write every row, full precision, here")
    args = parser.parse_args()
    try:
        check_overrides(tuple(args.overrides), "every run")
    except PldSlamError as error:
        parser.error(str(error))
    names = [variant.name for variant in args.variants]
    if len(set(names)) < len(names):
        parser.error(f"--variant names must differ: {', '.join(names)}")
    return args


def measure(args: argparse.Namespace, out: Path) -> str:
    """Render, run and tabulate in ``out``; the printed table with its header and wall time."""
    start = time.perf_counter()
    variants = args.variants or [Variant(DEFAULT_VARIANT, ())]
    sequences = real_table_sequences() if args.real else []
    sequences += synthetic_sequences(out, args.scenarios, args.seeds, args.frames, args.synth_args, args.workers)
    if not sequences:
        raise PldSlamError("no sequence to run: no real sequence found and no --scenarios")
    runs = run_table(out, sequences, variants, args.overrides, args.workers)
    means = scenario_means(runs)
    if args.csv is not None:
        overrides = {variant.name: " ".join([*args.overrides, *variant.overrides]) for variant in variants}
        table = pd.concat([runs, means])
        table.assign(overrides=table["variant"].map(overrides), commit=git_state()).to_csv(args.csv, index=False)
    return "\n".join([header(args, variants), format_table(runs, means, show_variant=len(variants) > 1),
                      f"{len(runs)} runs, {args.workers} at once; wall time {time.perf_counter() - start:.0f} s"])


def main() -> None:
    args = parse_args()
    try:
        if args.out is not None:
            print(measure(args, args.out))
            return
        with tempfile.TemporaryDirectory(prefix="pld-slam-accuracy-") as scratch:
            print(measure(args, Path(scratch)))
    except PldSlamError as error:
        sys.exit(f"error: {error}")


if __name__ == "__main__":
    main()
