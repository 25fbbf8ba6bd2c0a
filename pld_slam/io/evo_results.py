"""evo's result files: the zip ``evo_res`` reads (``evo.tools.file_interface.save_res_file``)."""

from pathlib import Path

from evo.core.result import Result
from evo.tools import file_interface

from pld_slam.errors import OutputError


def write_evo_result(path: Path, result: Result) -> None:
    """Write ``result`` as evo's zip at ``path`` (replacing a file there); `OutputError` naming it if it cannot."""
    try:
        file_interface.save_res_file(path, result, confirm_overwrite=False)
    except OSError as error:
        raise OutputError.from_os_error(path, error) from None
