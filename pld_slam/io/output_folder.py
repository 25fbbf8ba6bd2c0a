"""The one check of an output path before a command works: `create_output_folder`.

Every command that writes files (``run``, ``demo``, ``eval --plot`` and ``--save-results``,
``places``, ``vocabulary build``, ``ablate``, ``regress``) calls it on its output folder (or
a file's folder) before its work, so that an output path under a
file, or in a folder it cannot write, costs a one-line error at once rather than the
work done before the first file is written.
"""

import errno
import os
from pathlib import Path

from pld_slam.errors import OutputError


def create_output_folder(folder: Path) -> None:
    """Create ``folder`` and its parents if needed and check that files can be written in it; `OutputError`
    naming it when either fails (under a file, without write permission, on a read-only disk)."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise OutputError.from_os_error(folder, error) from None
    if not os.access(folder, os.W_OK | os.X_OK):
        raise OutputError.from_os_error(folder, PermissionError(errno.EACCES, os.strerror(errno.EACCES)))
