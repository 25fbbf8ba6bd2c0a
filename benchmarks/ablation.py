"""An ablation suite over the real extracts and synthetic sequences (the ablation issue's figures).

Generates ``--scenario`` sequences of ``--frames`` frames, one per ``--seeds`` (kept in
``--out``/sequences and reused), finds the real extracts through ``$PLD_SLAM_DATA``
(unless ``--no-real``), and runs ``pld-slam ablate`` on them all with ``--workers``: its
table and wall time are printed as the command prints them. A second invocation with the
same arguments reuses every finished cell (delete ``--out``/ablation to start afresh).

    python benchmarks/ablation.py [--suite table1] [--scenario dynamic] [--seeds 0 1 2]
                                  [--frames 300] [--workers 2] [--no-real] [--out DIR] [--set KEY=VALUE ...]

Paper figures: ``--suite table1`` (default: real extracts and three synthetic dynamic
sequences) and ``--suite lines --scenario lowtexture --no-real``.
"""

import argparse
import subprocess
import sys
from pathlib import Path

from extracts import existing_extracts

from pld_slam.report.regress import synthetic_sequence


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--suite", default="table1")
    parser.add_argument("--scenario", default="dynamic")
    parser.add_argument("--seeds", type=int, nargs="*", default=[0, 1, 2])
    parser.add_argument("--frames", type=int, default=300)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--no-real", action="store_true", help="leave out the real extracts")
    parser.add_argument("--out", type=Path, default=Path("/tmp/pld_slam_ablation"))
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    args = parser.parse_args()

    sequences = [] if args.no_real else existing_extracts()
    for seed in args.seeds:
        sequences.append(synthetic_sequence(args.out, args.scenario, seed, args.frames))
    command = [sys.executable, "-m", "pld_slam_cli", "ablate", *map(str, sequences), "--suite", args.suite,
               "--out", str(args.out / f"ablation-{args.suite}"), "--workers", str(args.workers)]
    for override in args.overrides:
        command += ["--set", override]
    print(" ".join(command), flush=True)
    sys.exit(subprocess.run(command).returncode)


if __name__ == "__main__":
    main()
