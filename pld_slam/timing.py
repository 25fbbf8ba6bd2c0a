"""Wall-clock helpers: `ms_since`, and `StageClock`, the wall time of named stages lap by lap."""

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
