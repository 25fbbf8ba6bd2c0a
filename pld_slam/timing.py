"""`StageClock`: the wall time of named stages, lap by lap."""

import time


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
