"""An ablation cell's child process: ``python -m pld_slam.report.cell_run SEQUENCE RUN_DIR CONFIG [MAX_FRAMES]``.

It runs `pld_slam.report.run_files.run_and_write` on the sequence folder with the cell's
config file as its only ``--config``, the call ``pld-slam run`` makes, so a cell measures
what a user runs. SIGTERM stops it as Ctrl-C does (`pld_slam.errors.stop_on_sigterm`):
the run writes its files so far, the last line on stderr says how far it got, and the
exit code is `EXIT_STOPPED`; once the run has returned, a signal ends the process at once
(`pld_slam.errors.end_on_stop_signals`). Any other failure ends it as Python does, with the traceback
on stderr (its last line the error) and exit code 1; `pld_slam.report.cells` takes that
last line as the cell's reason.
"""

import signal
import sys
from pathlib import Path

from pld_slam.datasets import open_sequence
from pld_slam.errors import end_on_stop_signals, stop_on_sigterm
from pld_slam.report.run_files import run_and_write

EXIT_STOPPED = 1
"""The exit code of a cell's run stopped by SIGTERM (or Ctrl-C) once its files were written."""


def main(arguments: list[str]) -> int:
    """Run the cell given by ``arguments`` (module docstring); the process's exit code."""
    sequence_dir, run_dir, config_path, *max_frames = arguments
    signal.signal(signal.SIGTERM, stop_on_sigterm)
    try:
        try:
            run_and_write(open_sequence(Path(sequence_dir)), Path(run_dir), (Path(config_path),), (),
                          int(max_frames[0]) if max_frames else None)
        finally:
            end_on_stop_signals()  # the files are written: a signal now ends the process, as pld-slam's does
    except KeyboardInterrupt as interrupt:
        print(f"stopped {interrupt}", file=sys.stderr)
        return EXIT_STOPPED
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
