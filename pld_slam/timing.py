"""Wall-clock and memory readings: `ms_since`, `StageClock` (the wall time of named stages lap
by lap), `resident_mb` and `process_resident_mb`."""

import os
import resource
import sys
import time


def ms_since(start: float) -> float:
    """Milliseconds since ``start``, a `time.perf_counter` reading."""
    return 1e3 * (time.perf_counter() - start)


class StageClock:
    """Wall time between laps [ms], by stage name (a stage lapped twice keeps the later time)."""

    def __init__(self) -> None:
        self.laps: dict[str, float] = {}
        self._last = time.perf_counter()

    def lap(self, stage: str) -> None:
        """Close the stage that ran since the last lap (or since the clock started)."""
        now = time.perf_counter()
        self.laps[stage] = 1e3 * (now - self._last)
        self._last = now


def process_resident_mb(pid: int | str) -> float:
    """Resident memory of process ``pid`` (or ``"self"``) now [MiB], from Linux's ``/proc/PID/statm``;
    `OSError` where there is none (no such process, no ``/proc``)."""
    with open(f"/proc/{pid}/statm") as statm:
        return int(statm.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


def resident_mb() -> float:
    """This process's resident memory now [MiB]; where ``/proc`` is missing (macOS), its peak so far."""
    try:
        return process_resident_mb("self")
    except OSError:
        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        return peak / 2**20 if sys.platform == "darwin" else peak / 2**10
