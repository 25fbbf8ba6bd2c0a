"""Whether a process still runs, for the tests that kill a parent and check its child dies with it (Linux)."""

import time
from pathlib import Path


def running(pid: int) -> bool:
    """Whether process ``pid`` exists and is not a zombie waiting to be reaped (one reaped between
    opening its stat file and reading it raises ProcessLookupError: seen in a fresh virtual environment)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except (FileNotFoundError, ProcessLookupError):
        return False
    return stat.rsplit(")", 1)[1].split()[0] != "Z"


def ends_within(pid: int, seconds: float) -> bool:
    """Whether process ``pid`` stops `running` within ``seconds``, polling every 50 ms."""
    deadline = time.monotonic() + seconds
    while running(pid) and time.monotonic() < deadline:
        time.sleep(0.05)
    return not running(pid)
