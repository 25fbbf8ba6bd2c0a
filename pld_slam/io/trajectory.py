"""Read and write trajectories (`Trajectory`, poses ``T_w_c``) as KITTI, TUM and EuRoC files.

One pose per line; blank lines and lines starting with ``#`` are skipped in all formats.

- ``kitti``: 12 numbers, the top 3x4 of ``T_w_c`` row by row; no timestamps (frame
  ``i`` gets ``i`` seconds unless the caller passes the sequence's times).
- ``tum``: ``timestamp tx ty tz qx qy qz qw`` [s, m], whitespace-separated.
- ``euroc``: CSV ``timestamp [ns], p_x, p_y, p_z, q_w, q_x, q_y, q_z``; any further
  columns (the velocities and IMU biases of EuRoC ground truth) are ignored.

Every problem with a file raises `TrajectoryError` with one line that starts with
``<path>:<line>:`` (or ``<path>:`` when no single line is to blame).

Decisions:

- A quaternion whose norm is within `UNIT_TOLERANCE` of 1 is normalised (files written
  with 6 decimals are ~1e-6 off unit); a zero or clearly non-unit quaternion, usually a
  column-order mistake, is rejected.
- KITTI rotation matrices are kept exactly as read (the official ground truth is ~1e-7
  off SO(3), and evo keeps them as read too); a matrix further than `UNIT_TOLERANCE`
  from a rotation is rejected. Writing a quaternion (TUM, EuRoC) projects the rotation
  onto SO(3) (scipy ``Rotation.from_matrix``) and picks the sign with ``q_w >= 0``.
- Writing is deterministic: KITTI ``%.9e``; TUM ``%.9f`` timestamps and values; EuRoC
  integer nanoseconds (the nearest nanosecond to the float64 seconds) and ``%.9f``.
  float64 seconds since 1970 resolve ~0.2 us, so EuRoC nanoseconds survive a read and
  write to within that; a second round trip is exact.
"""

import codecs
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from pld_slam.errors import TrajectoryError
from pld_slam.geometry.se3 import make_pose
from pld_slam.trajectory import Trajectory

FORMATS = ("kitti", "tum", "euroc")

UNIT_TOLERANCE = 1e-2
"""Largest accepted deviation of a quaternion norm from 1, and of ``R^T R`` from I."""

_NS_PER_S = 1_000_000_000
TUM_HEADER = "# timestamp tx ty tz qx qy qz qw"
"""The ``#`` line heading every TUM file we write."""
_EUROC_HEADER = "#timestamp [ns],p_x [m],p_y [m],p_z [m],q_w [],q_x [],q_y [],q_z []"


def _error(path, line: int, problem: str) -> TrajectoryError:
    return TrajectoryError(f"{path}:{line}: {problem}")


@contextmanager
def _reading(path) -> Iterator[None]:
    """Turn the errors of reading the file ``path`` (UTF-8) into a `TrajectoryError` naming it."""
    try:
        yield
    except FileNotFoundError:
        raise TrajectoryError(f"{path}: no such file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise TrajectoryError(f"{path}: cannot read the file ({exc})") from None


def _numbered_data_lines(lines: Iterable[str]) -> Iterator[tuple[int, str]]:
    """(line number, stripped text) of each of ``lines`` that is neither blank nor a ``#`` comment."""
    for number, line in enumerate(lines, start=1):
        if line.strip() and not line.lstrip().startswith("#"):
            yield number, line.strip()


def _no_poses(path) -> TrajectoryError:
    return TrajectoryError(f"{path}: no poses (empty file)")


def _data_lines(path) -> list[tuple[int, str]]:
    """(line number, stripped text) of each line that is neither blank nor a ``#`` comment."""
    with _reading(path):
        text = Path(path).read_text(encoding="utf-8-sig")
    lines = list(_numbered_data_lines(text.splitlines()))
    if not lines:
        raise _no_poses(path)
    return lines


def _first_data_line(path) -> tuple[int, str]:
    """The first of `_data_lines`, the file read only up to it.

    The bytes are decoded one line at a time and each line split as ``str.splitlines``
    splits the whole text, so the line numbers are those of `_data_lines`. Bytes that are
    not UTF-8 before that line are reported as `_data_lines` reports them.
    """
    with _reading(path), Path(path).open("rb") as file:
        try:
            for number_and_line in _numbered_data_lines(_decoded_lines(file)):
                return number_and_line
        except UnicodeDecodeError:
            pass
        else:
            raise _no_poses(path)
    return _data_lines(path)[0]


def _decoded_lines(file) -> Iterator[str]:
    """The lines of the binary ``file``'s UTF-8 text (a byte-order mark dropped) as ``str.splitlines``
    gives them, decoded one line at a time."""
    decoder = codecs.getincrementaldecoder("utf-8-sig")()
    for raw in file:
        yield from decoder.decode(raw).splitlines()
    yield from decoder.decode(b"", final=True).splitlines()


def _split_rows(
    path, separator: str | None, n_columns: int, extra_columns: bool = False
) -> tuple[np.ndarray, list[list[str]]]:
    """Line numbers (M,) and the first ``n_columns`` fields of each data line.

    ``separator`` None splits on whitespace. With ``extra_columns`` a row may have more
    fields than ``n_columns`` (they are dropped), never fewer.
    """
    line_numbers, rows = [], []
    for number, line in _data_lines(path):
        fields = [field.strip() for field in line.split(separator)]
        if len(fields) < n_columns or (len(fields) > n_columns and not extra_columns):
            expected = f"at least {n_columns}" if extra_columns else str(n_columns)
            raise _error(path, number, f"expected {expected} numbers, got {len(fields)}")
        line_numbers.append(number)
        rows.append(fields[:n_columns])
    return np.array(line_numbers), rows


def _parse_floats(path, line_numbers: np.ndarray, rows: list[list[str]]) -> np.ndarray:
    """The fields as a finite float64 table (M, n_columns)."""
    values = np.empty((len(rows), len(rows[0])))
    for i, (number, fields) in enumerate(zip(line_numbers, rows)):
        for j, field in enumerate(fields):
            try:
                values[i, j] = float(field)
            except ValueError:
                raise _error(path, number, f"not a number: {field!r}") from None
            if not np.isfinite(values[i, j]):
                raise _error(path, number, f"not a finite number: {field!r}")
    return values


def _parse_nanoseconds(path, line_numbers: np.ndarray, fields: list[str]) -> np.ndarray:
    """Integer nanosecond timestamps (M,) int64."""
    stamps = np.empty(len(fields), dtype=np.int64)
    for i, (number, field) in enumerate(zip(line_numbers, fields)):
        try:
            stamps[i] = int(field)
        except (ValueError, OverflowError):
            problem = f"timestamp must be integer nanoseconds: {field!r}"
            raise _error(path, number, problem) from None
    return stamps


def _ns_to_seconds(ns: np.ndarray) -> np.ndarray:
    """Nanoseconds (M,) int64 to seconds (M,) float64, within half a float64 step.

    Whole seconds are split off first: the ns count itself (~1.4e18) does not fit a
    float64 exactly.
    """
    return (ns // _NS_PER_S).astype(np.float64) + (ns % _NS_PER_S) / 1e9


def _seconds_to_ns(seconds: np.ndarray) -> list[int]:
    """Nearest integer nanosecond of each float64 time (M,) [s]."""
    whole = np.floor(seconds)
    return [int(s) * _NS_PER_S + int(round(f * 1e9)) for s, f in zip(whole, seconds - whole)]


def _check_increasing(path, line_numbers: np.ndarray, timestamps: np.ndarray) -> None:
    bad = np.flatnonzero(np.diff(timestamps) <= 0.0)
    if bad.size:
        i = bad[0] + 1
        raise _error(
            path,
            line_numbers[i],
            f"timestamp {timestamps[i]:.9f} is not after the previous one "
            f"({timestamps[i - 1]:.9f}); timestamps must increase",
        )


def rotations_from_quaternions(q_xyzw: np.ndarray, error: Callable[[int, str], Exception]) -> np.ndarray:
    """Rotation matrices (M, 3, 3) of near-unit quaternions (M, 4) in (x, y, z, w) order.

    The first quaternion whose norm is off 1 by more than `UNIT_TOLERANCE` raises
    ``error(index, problem)``, so that each reader names its own file, line or message.
    """
    norms = np.linalg.norm(q_xyzw, axis=1)
    bad = np.flatnonzero(np.abs(norms - 1.0) > UNIT_TOLERANCE)
    if bad.size:
        raise error(bad[0], f"quaternion norm is {norms[bad[0]]:.6g}, not 1 (zero or not unit)")
    return Rotation.from_quat(q_xyzw / norms[:, None]).as_matrix()


def _rotations_from_quaternions(
    path, line_numbers: np.ndarray, q_xyzw: np.ndarray
) -> np.ndarray:
    """`rotations_from_quaternions` of a file's rows, a bad one named by ``file:line``."""
    return rotations_from_quaternions(q_xyzw, lambda i, problem: _error(path, line_numbers[i], problem))


def _check_rotations(path, line_numbers: np.ndarray, R: np.ndarray) -> None:
    """Reject any matrix of ``R`` (M, 3, 3) that is not a rotation to `UNIT_TOLERANCE`."""
    orthogonality = np.abs(np.swapaxes(R, 1, 2) @ R - np.eye(3)).max(axis=(1, 2))
    determinant = np.linalg.det(R)
    not_rotation = (orthogonality > UNIT_TOLERANCE) | (np.abs(determinant - 1.0) > UNIT_TOLERANCE)
    bad = np.flatnonzero(not_rotation)
    if bad.size:
        i = bad[0]
        raise _error(
            path,
            line_numbers[i],
            f"not a rotation matrix (max |R^T R - I| = {orthogonality[i]:.3g}, "
            f"det = {determinant[i]:.6g})",
        )


def _stack_poses(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Poses (M, 4, 4) from rotations (M, 3, 3) and translations (M, 3)."""
    return np.array([make_pose(R_i, t_i) for R_i, t_i in zip(R, t)])


def _quaternions_xyzw(poses: np.ndarray) -> np.ndarray:
    """Unit quaternions (N, 4) (x, y, z, w), ``w >= 0``, of the nearest rotations of ``poses``."""
    return Rotation.from_matrix(poses[:, :3, :3]).as_quat(canonical=True)


def read_kitti(path, timestamps: np.ndarray | None = None) -> Trajectory:
    """Read a KITTI pose file (12 numbers a line: the top 3x4 of ``T_w_c``, row-major).

    Parameters
    ----------
    path : str or Path
    timestamps : (N,) array [s] or None
        Times of the N poses (e.g. the sequence's ``times.txt``); default ``0, 1, ..., N-1``.
    """
    line_numbers, rows = _split_rows(path, None, 12)
    matrices = _parse_floats(path, line_numbers, rows).reshape(-1, 3, 4)
    _check_rotations(path, line_numbers, matrices[:, :, :3])
    poses = _stack_poses(matrices[:, :, :3], matrices[:, :, 3])
    if timestamps is None:
        timestamps = np.arange(len(poses), dtype=np.float64)
    elif len(timestamps) != len(poses):
        raise TrajectoryError(f"{path}: {len(poses)} poses but {len(timestamps)} timestamps given")
    return Trajectory(np.asarray(timestamps, dtype=np.float64), poses)


def read_tum(path) -> Trajectory:
    """Read a TUM file: ``timestamp tx ty tz qx qy qz qw`` a line [s, m]."""
    line_numbers, rows = _split_rows(path, None, 8)
    values = _parse_floats(path, line_numbers, rows)
    _check_increasing(path, line_numbers, values[:, 0])
    R = _rotations_from_quaternions(path, line_numbers, values[:, 4:8])
    return Trajectory(values[:, 0], _stack_poses(R, values[:, 1:4]))


def read_euroc(path) -> Trajectory:
    """Read a EuRoC CSV: ``timestamp [ns], p_x, p_y, p_z, q_w, q_x, q_y, q_z[, ignored...]``."""
    line_numbers, rows = _split_rows(path, ",", 8, extra_columns=True)
    timestamps = _ns_to_seconds(_parse_nanoseconds(path, line_numbers, [row[0] for row in rows]))
    _check_increasing(path, line_numbers, timestamps)
    values = _parse_floats(path, line_numbers, [row[1:] for row in rows])
    R = _rotations_from_quaternions(path, line_numbers, np.roll(values[:, 3:7], -1, axis=1))
    return Trajectory(timestamps, _stack_poses(R, values[:, 0:3]))


def _write_lines(path, traj: Trajectory, lines: list[str]) -> None:
    if len(traj) == 0:
        raise TrajectoryError(f"{path}: cannot write an empty trajectory")
    try:
        Path(path).write_text("\n".join(lines) + "\n")
    except OSError as exc:
        raise TrajectoryError(f"{path}: cannot write the file ({exc.strerror})") from None


def write_kitti(path, traj: Trajectory) -> None:
    """Write the top 3x4 of each ``T_w_c`` as 12 ``%.9e`` numbers a line (no timestamps)."""
    rows = traj.poses[:, :3, :].reshape(-1, 12)
    _write_lines(path, traj, [" ".join(f"{v:.9e}" for v in row) for row in rows])


def tum_rows(traj: Trajectory) -> list[str]:
    """The TUM rows of ``traj``: ``timestamp tx ty tz qx qy qz qw``, all ``%.9f``, no newline."""
    values = np.column_stack([traj.timestamps, traj.positions, _quaternions_xyzw(traj.poses)])
    return [" ".join(f"{v:.9f}" for v in row) for row in values]


def write_tum(path, traj: Trajectory) -> None:
    """Write `tum_rows` under the `TUM_HEADER` line."""
    _write_lines(path, traj, [TUM_HEADER, *tum_rows(traj)])


def write_euroc(path, traj: Trajectory) -> None:
    """Write ``timestamp [ns],p_x,p_y,p_z,q_w,q_x,q_y,q_z`` a line under a ``#`` header."""
    q_wxyz = np.roll(_quaternions_xyzw(traj.poses), 1, axis=1)
    values = np.column_stack([traj.positions, q_wxyz])
    lines = [
        f"{ns}," + ",".join(f"{v:.9f}" for v in row)
        for ns, row in zip(_seconds_to_ns(traj.timestamps), values)
    ]
    _write_lines(path, traj, [_EUROC_HEADER, *lines])


_WRITERS: dict[str, Callable[..., None]] = {
    "kitti": write_kitti,
    "tum": write_tum,
    "euroc": write_euroc,
}


def detect_format(path) -> str:
    """The format of a trajectory file from its first data line (the file is read up to it only).

    Comma-separated with 8 or more columns is ``euroc``; 8 whitespace-separated columns
    ``tum``; 12 ``kitti``. Anything else raises `TrajectoryError` naming the file.
    """
    number, line = _first_data_line(path)
    if "," in line:
        n_columns = len(line.split(","))
        if n_columns >= 8:
            return "euroc"
        kind = "comma-separated"
    else:
        n_columns = len(line.split())
        if n_columns in (8, 12):
            return "tum" if n_columns == 8 else "kitti"
        kind = "whitespace-separated"
    raise _error(
        path,
        number,
        f"cannot tell the trajectory format from {n_columns} {kind} columns "
        "(TUM: 8, KITTI: 12, EuRoC: 8 or more comma-separated)",
    )


EUROC_BODY_COLUMN = "p_RS_R_x"
"""The header name of the first position column of EuRoC's ``state_groundtruth_estimate0/data.csv``:
the position of the body (R: the IMU, S: the sensor frame) in the world."""


def is_euroc_body_groundtruth(path) -> bool:
    """Whether the file's first line is the header of EuRoC's body-frame ground truth (`EUROC_BODY_COLUMN`).

    That file reads as an ``euroc`` trajectory, but of the IMU, not of a camera: compared
    with a camera trajectory it differs by the camera-IMU lever arm and rotation, which
    no SE(3) alignment of the whole trajectory removes. A file that cannot be read is not
    one (reading it reports why).
    """
    try:
        with Path(path).open(encoding="utf-8-sig") as file:
            header = file.readline()
    except (OSError, UnicodeDecodeError):
        return False
    return header.startswith("#") and EUROC_BODY_COLUMN in header


def _check_format(fmt: str, path) -> None:
    if fmt not in FORMATS:
        raise TrajectoryError(
            f"{path}: unknown trajectory format {fmt!r}; expected one of {FORMATS}"
        )


def read_trajectory(path, fmt: str = "auto", timestamps: np.ndarray | None = None) -> Trajectory:
    """Read a trajectory file in format ``fmt`` (one of `FORMATS`, or ``auto`` to detect it).

    ``timestamps`` (N,) [s] are only for KITTI files, which carry none.
    """
    detected = fmt == "auto"
    if detected:
        fmt = detect_format(path)
    _check_format(fmt, path)
    if fmt == "kitti":
        return read_kitti(path, timestamps)
    if timestamps is not None:
        raise TrajectoryError(f"{path}: timestamps can only be given for a KITTI file, not {fmt}")
    if fmt == "tum":
        return read_tum(path)
    try:
        return read_euroc(path)
    except TrajectoryError as error:
        if not detected:
            raise
        raise TrajectoryError(f"{error} (read as EuRoC, for its comma-separated columns; a TUM file separates "
                              "them by spaces)") from None


def write_trajectory(path, traj: Trajectory, fmt: str) -> None:
    """Write ``traj`` to ``path`` in format ``fmt`` (one of `FORMATS`)."""
    _check_format(fmt, path)
    _WRITERS[fmt](path, traj)
