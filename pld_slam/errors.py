"""The one exception family of pld-slam.

Every error a user can cause (a bad folder, a malformed file, an invalid config) is a
`PldSlamError` whose message is one line naming the file or key and the problem; the CLI
prints that line and exits with code 2. `read_user_text` reads a user's text file so:
bytes that are not UTF-8 or a file that cannot be read are such an error.

Stopping is the other family: Ctrl-C (`KeyboardInterrupt`) and SIGTERM (`Terminated`, raised
by `stop_on_sigterm`) stop a run, which still writes its files; `deferred_interrupts` holds
both while those files are written.
"""

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised by `stop_on_sigterm` (the handler of the ``pld-slam`` command and of an
    ablation cell's run): a run stops as on Ctrl-C (`KeyboardInterrupt`) and its summary says
    ``terminated``."""


def stop_on_sigterm(signum: int, frame) -> None:
    """A SIGTERM handler (``signal.signal(signal.SIGTERM, stop_on_sigterm)``): raise `Terminated`."""
    raise Terminated


def end_on_stop_signals() -> None:
    """Give Ctrl-C and SIGTERM their default action back: the process ends at once, killed by the signal.

    For a process whose work is done (its files written). Raised from a Python handler during the
    interpreter's shutdown instead, they print a traceback from whatever atexit callback or thread
    join is running and the process exits 0 (issue 43).
    """
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, signal.SIG_DFL)


@dataclass
class HeldInterrupt:
    """What `deferred_interrupts` held: the first Ctrl-C (`KeyboardInterrupt`) or SIGTERM (`Terminated`) that
    came during its block, or None."""

    interrupt: KeyboardInterrupt | None = None


@contextmanager
def deferred_interrupts() -> Iterator[HeldInterrupt]:
    """Hold Ctrl-C and SIGTERM while the block runs (a run's files being written): each is kept in the
    yielded `HeldInterrupt` instead of raised, and the handlers before the block are back after it.
    Outside the main thread (where Python cannot set handlers) it holds nothing."""
    held = HeldInterrupt()
    if threading.current_thread() is not threading.main_thread():
        yield held
        return

    def hold(signum: int, frame) -> None:
        if held.interrupt is None:
            held.interrupt = Terminated() if signum == signal.SIGTERM else KeyboardInterrupt()

    before = {signum: signal.signal(signum, hold) for signum in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield held
    finally:
        for signum, handler in before.items():
            signal.signal(signum, handler)


class PldSlamError(Exception):
    """Base of every error pld-slam raises on purpose."""


class DatasetError(PldSlamError):
    """A sequence folder, calibration, image or ground-truth file is missing or malformed."""


class TrajectoryError(PldSlamError):
    """A trajectory file cannot be read, or two trajectories cannot be compared."""


class TrackingError(PldSlamError):
    """A run tracked too few of its frames to be of use; the input is the likely cause (the message says which)."""


class ConfigError(PldSlamError):
    """A configuration file or override names an unknown key or has a bad value."""


class OutputError(PldSlamError):
    """An output folder or file cannot be created or written (the message says which and why)."""

    @classmethod
    def from_os_error(cls, path, error: OSError) -> "OutputError":
        """The one-line error of ``error``, naming the file it names, else ``path``."""
        return cls(f"{error.filename or path}: cannot write ({error.strerror or error})")


def read_user_text(path: Path, error: type[PldSlamError], what: str) -> str:
    """The text of the user's file ``path`` (UTF-8, a byte-order mark dropped); ``error`` naming it when
    it cannot be read (``cannot read WHAT (why)``) or is not UTF-8 text (the offset of the first bad byte)."""
    try:
        return Path(path).read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as decode:
        raise error(f"{path}: not a text file (byte {decode.start} is not UTF-8)") from None
    except OSError as os_error:
        raise error(f"{path}: cannot read {what} ({os_error.strerror or os_error})") from None
