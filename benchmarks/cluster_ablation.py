"""`pld-slam ablate` on a Dask cluster of two worker processes (issue 40): each cell bounded
in memory, a line per cell, and a worker killed mid-cell costing that cell's work only.

Renders the synthetic city at ``--frames`` frames for seeds 0 and 1 (kept in
``--out``/sequences and reused), starts a `distributed.LocalCluster` of two single-threaded
worker processes and runs ``pld-slam ablate --scheduler ADDRESS --max-memory-mb N`` on the
two sequences under two variants (the default config, and no loop closing), afresh into
``--out``/ablation (``ablation-killed`` with ``--kill-a-worker``). Ablate's own output
comes as it prints it (a line per cell, then the table). With ``--kill-a-worker``, one
worker process running a cell gets SIGKILL ``--kill-after`` seconds in; the script shows
which of its cell's processes are still running two seconds later (none: a cell's run
dies with its worker), and the scheduler gives the cell to another worker.

Then, per cell, its status, wall time, kernel compilation time (summary.json) and the
run's peak resident memory (frames.csv's rss_mb: the run's main process, without its
front end), and the whole's wall time.

    python benchmarks/cluster_ablation.py [--out DIR] [--frames 600] [--max-memory-mb 1500]
                                          [--kill-a-worker] [--kill-after 20]
"""

import argparse
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
from distributed import Client, LocalCluster

from pld_slam.report.cells import process_tree
from pld_slam.report.regress import synthetic_sequence
from pld_slam.report.store import cell_folder, read_ablation, recorded_rows

SUITE = """description: the default config against no loop closing
variants:
  default: {}
  no-loop: {loop.detector: none}
"""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=Path, default=Path("/tmp/pld_slam_cluster"))
    parser.add_argument("--frames", type=int, default=600)
    parser.add_argument("--max-memory-mb", type=int, default=1500,
                        help="per cell; a 600-frame city run peaks at about 0.8 GiB with its front end")
    parser.add_argument("--kill-a-worker", action="store_true", help="SIGKILL one worker process mid-cell")
    parser.add_argument("--kill-after", type=float, default=20.0, help="seconds into the ablation")
    args = parser.parse_args()

    sequences = [synthetic_sequence(args.out, "city", seed, args.frames) for seed in (0, 1)]
    ablation = args.out / ("ablation-killed" if args.kill_a_worker else "ablation")
    shutil.rmtree(ablation, ignore_errors=True)
    suite = args.out / "cluster_suite.yaml"
    suite.write_text(SUITE)
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster, \
            Client(cluster) as client:
        command = [sys.executable, "-m", "pld_slam_cli", "ablate", *map(str, sequences), "--suite", str(suite),
                   "--out", str(ablation), "--scheduler", cluster.scheduler_address,
                   "--max-memory-mb", str(args.max_memory_mb)]
        print(" ".join(command), flush=True)
        start = time.perf_counter()
        ablate = subprocess.Popen(command)
        if args.kill_a_worker:
            time.sleep(args.kill_after)
            kill_a_worker(client)
        returncode = ablate.wait()
        seconds = time.perf_counter() - start
    print_cells(ablation)
    print(f"ablate exited with {returncode}; the whole took {seconds:.1f} s")
    sys.exit(returncode)


def kill_a_worker(client: Client) -> None:
    """SIGKILL a worker process that runs a cell; print its cell's processes and which still run 2 s later."""
    for worker_pid in client.run(os.getpid).values():
        cell_processes = process_tree(worker_pid)[1:]
        if cell_processes:
            break
    else:
        print("no worker runs a cell: none killed", flush=True)
        return
    os.kill(worker_pid, signal.SIGKILL)
    print(f"killed worker process {worker_pid}, running {command_line(cell_processes[0])} "
          f"(processes {', '.join(map(str, cell_processes))})", flush=True)
    time.sleep(2.0)
    left = [pid for pid in cell_processes if running(pid)]
    print(f"2 s later, of its cell's processes still running: {left or 'none'}", flush=True)


def command_line(pid: int) -> str:
    """Process ``pid``'s command line, its arguments separated by spaces."""
    return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode().strip()


def running(pid: int) -> bool:
    """Whether process ``pid`` runs (a zombie, dead but not yet reaped, does not)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rpartition(")")[2].split()[0] != "Z"
    except FileNotFoundError:
        return False


def print_cells(ablation: Path) -> None:
    """Every recorded cell of ``ablation`` (out of how many it has): status, time, kernel
    compilation, peak resident memory."""
    rows = []
    for row in recorded_rows(ablation):
        folder = cell_folder(ablation, row["sequence"], row["variant"])
        frames = folder / "frames.csv"
        summary = folder / "summary.json"
        rows.append({
            "sequence": row["sequence"], "variant": row["variant"], "status": row["status"],
            "reason": row["reason"] or "", "seconds": round(row["seconds"], 1),
            "kernels_s": round(json.loads(summary.read_text())["kernels_seconds"], 2) if summary.is_file() else None,
            "peak_rss_mb": round(pd.read_csv(frames)["rss_mb"].max()) if frames.is_file() else None,
        })
    planned = read_ablation(ablation)
    print(f"\n{len(rows)} of {len(planned['sequences']) * len(planned['variants'])} cells recorded in {ablation}:")
    print(pd.DataFrame(rows).to_string(index=False))


if __name__ == "__main__":
    main()
