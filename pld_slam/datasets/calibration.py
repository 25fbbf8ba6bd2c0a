"""Calibration files as key -> value maps, and the rectified camera of two projection matrices.

Two on-disk forms are read into the same `Calibration`:

- KITTI text files (``calib.txt``, ``calib_*.txt``): one ``KEY: numbers`` entry per line,
  values kept as text until asked for, so non-numeric entries such as ``calib_time``
  cost nothing;
- YAML files (EuRoC ``sensor.yaml``, the generic ``calib.yaml``), including OpenCV's
  ``%YAML:1.0`` first line, which PyYAML rejects and we drop;
- JSON files (Argoverse's calibration and pose files).

Every problem is a one-line `DatasetError` naming the file and, where there is one, the
key: a missing file, a missing key, a value that is not numbers or has the wrong count, a
number that is not finite (``nan``, ``inf``: named by its entry, ``cx of P0``, or its
position, ``R[1, 2]``). The camera made of the numbers (`stereo_camera_from_projections`,
every layout's) must be plausible too (`check_intrinsics`: positive focal lengths, the
principal point inside the image; a right camera to the right of the left one).
"""

import json
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from pld_slam.errors import DatasetError, read_user_text
from pld_slam.geometry.camera import StereoCamera
from pld_slam.geometry.se3 import make_pose

_OPENCV_YAML_DIRECTIVE = "%YAML"

PINHOLE_ENTRIES = {(0, 0): "fx", (1, 1): "fy", (0, 2): "cx", (1, 2): "cy", (0, 3): "tx", (2, 3): "tz"}
"""The entries of a (3, 3) intrinsic or (3, 4) projection matrix a camera uses, by name
(``tx = -fx * baseline`` of a right projection; ``tz``, the camera's offset along the
optical axis, is 0 but in KITTI's colour cameras), for messages."""


ROTATION_TOLERANCE = 1e-3
"""Largest entry of ``R R^T - I`` accepted for a rotation matrix ``R`` of a calibration file."""


@dataclass(frozen=True)
class Calibration:
    """The entries of one calibration file; ``path`` is named in every error.

    Keys of nested YAML mappings are written with dots: ``left.K``, ``T_BS.data``.
    """

    path: Path
    entries: Mapping[str, Any]

    def error(self, key: str, problem: str) -> DatasetError:
        """A `DatasetError` saying ``problem`` about ``key`` of this file."""
        return DatasetError(f"{self.path}: {key!r} {problem}")

    def has(self, key: str) -> bool:
        """Whether the (dotted) ``key`` is present."""
        try:
            self.value(key)
        except DatasetError:
            return False
        return True

    def value(self, key: str) -> Any:
        """The raw value of the (dotted) ``key``; a missing key raises `DatasetError`."""
        node: Any = self.entries
        for part in key.split("."):
            if not isinstance(node, Mapping) or part not in node:
                raise DatasetError(f"{self.path}: missing key {key!r}")
            node = node[part]
        return node

    def array(
        self, key: str, shape: tuple[int, ...] | None = None, entries: Mapping[tuple[int, ...], str] | None = None
    ) -> np.ndarray:
        """The numbers of ``key`` as float64, reshaped (row-major) to ``shape``; all finite.

        Parameters
        ----------
        key : str
            Dotted key; its value is a whitespace-separated string (KITTI) or a number,
            list or nested list (YAML).
        shape : tuple of int or None
            Expected shape; None returns the numbers flat, of any count.
        entries : mapping of index to str, optional
            Names of entries (e.g. `PINHOLE_ENTRIES`), for the message on a number that is
            not finite; other entries are named by their index.
        """
        raw = self.value(key)
        try:
            numbers = np.asarray(raw.split() if isinstance(raw, str) else raw, dtype=np.float64)
        except (TypeError, ValueError):
            raise self.error(key, f"is not a list of numbers: {str(raw)[:60]!r}") from None
        numbers = numbers.reshape(-1)
        if shape is not None and numbers.size != int(np.prod(shape)):
            raise self.error(key, f"has {numbers.size} numbers, expected {int(np.prod(shape))}")
        numbers = numbers if shape is None else numbers.reshape(shape)
        self._check_finite(key, numbers, entries or {})
        return numbers

    def rotation(self, key: str) -> np.ndarray:
        """The (3, 3) rotation matrix of ``key``; a matrix that is not a rotation raises (`check_rotation`)."""
        R = self.array(key, (3, 3))
        check_rotation(self, key, R)
        return R

    def _check_finite(self, key: str, numbers: np.ndarray, entries: Mapping[tuple[int, ...], str]) -> None:
        """Raise `DatasetError` naming the first number of ``key`` that is not finite."""
        not_finite = np.argwhere(~np.isfinite(numbers))
        if not not_finite.size:
            return
        index = tuple(int(i) for i in not_finite[0])
        if index in entries:
            entry = f"{entries[index]} of {key}"
        else:
            entry = key if numbers.size == 1 else f"{key}[{', '.join(map(str, index))}]"
        raise DatasetError(f"{self.path}: {entry} is {numbers[index]:g}, not a finite number")


def check_rotation(calibration: Calibration, key: str, R: np.ndarray) -> None:
    """Raise `DatasetError` naming ``key`` of ``calibration`` unless ``R`` (3, 3) is a rotation matrix
    (entries of ``R R^T - I`` within `ROTATION_TOLERANCE`, determinant positive)."""
    orthonormal = bool(np.all(np.abs(R) <= 1.0 + ROTATION_TOLERANCE)) and np.allclose(R @ R.T, np.eye(3),
                                                                                 atol=ROTATION_TOLERANCE)
    if not orthonormal or np.linalg.det(R) < 0.0:
        raise calibration.error(key, "is not a rotation matrix")


def _require_file(path: Path, what: str) -> None:
    """Raise `DatasetError` unless the calibration file ``path`` exists."""
    if not path.is_file():
        raise DatasetError(f"{path}: {what} not found")


def read_kitti_calibration(path: Path) -> Calibration:
    """Read a KITTI ``KEY: value`` text file; blank lines are skipped.

    A non-blank line without a colon raises `DatasetError` naming ``file:line``.
    """
    _require_file(path, "KITTI calibration file")
    entries = {}
    for line_number, line in enumerate(read_user_text(path, DatasetError, "calibration").splitlines(), start=1):
        if not line.strip():
            continue
        key, colon, value = line.partition(":")
        if not colon:
            raise DatasetError(f"{path}:{line_number}: expected 'KEY: values', got {line[:60]!r}")
        entries[key.strip()] = value.strip()
    return Calibration(path, entries)


def read_yaml_calibration(path: Path) -> Calibration:
    """Read a YAML calibration file (an OpenCV ``%YAML:1.0`` first line is dropped)."""
    _require_file(path, "YAML calibration file")
    text = read_user_text(path, DatasetError, "calibration")
    if text.startswith(_OPENCV_YAML_DIRECTIVE):
        text = text.partition("\n")[2]
    try:
        entries = yaml.safe_load(text)
    except yaml.YAMLError as error:
        problem = " ".join(str(error).split())
        raise DatasetError(f"{path}: not valid YAML ({problem})") from None
    if not isinstance(entries, Mapping):
        raise DatasetError(f"{path}: expected a YAML mapping of keys to values")
    return Calibration(path, entries)


def read_json_calibration(path: Path, what: str = "JSON calibration file") -> Calibration:
    """Read a JSON file whose top level is an object; ``what`` names the file in a not-found error."""
    _require_file(path, what)
    try:
        entries = json.loads(path.read_text())
    except (ValueError, UnicodeDecodeError) as error:
        raise DatasetError(f"{path}: not valid JSON ({error})") from None
    if not isinstance(entries, Mapping):
        raise DatasetError(f"{path}: expected a JSON object of keys to values")
    return Calibration(path, entries)


def check_intrinsics(K: np.ndarray, size: tuple[int, int], source: Path | str, key: str) -> None:
    """Raise `DatasetError` unless the pinhole intrinsics of ``K`` are plausible for ``size``.

    ``fx``, ``fy``, ``cx``, ``cy`` of ``K`` (a (3, 3) intrinsic or (3, 4) projection
    matrix) must be finite, its third row start ``0 0 1``, the focal lengths positive and
    the principal point inside the ``(width, height)`` [px] image. The message names ``source`` (the calibration) and
    the entry of ``key`` (``cx of P0``).
    """
    intrinsics = {"fx": float(K[0, 0]), "fy": float(K[1, 1]), "cx": float(K[0, 2]), "cy": float(K[1, 2])}
    _require_finite(source, key, intrinsics)
    if not np.allclose(K[2, :3], (0.0, 0.0, 1.0)):
        raise DatasetError(f"{source}: the third row of {key} starts {K[2, :3].tolist()}, expected [0, 0, 1]")
    for name in ("fx", "fy"):
        if not intrinsics[name] > 0.0:
            raise DatasetError(f"{source}: {name} of {key} is {intrinsics[name]:g}; a focal length must be positive")
    for name, side, extent in (("cx", "width", size[0]), ("cy", "height", size[1])):
        if not 0.0 <= intrinsics[name] <= extent:
            raise DatasetError(
                f"{source}: {name} of {key} is {intrinsics[name]:g}, outside the image (0 to its {side}, {extent} px)"
            )


def _require_finite(source: Path | str, key: str, values: Mapping[str, float]) -> None:
    """Raise `DatasetError` naming the first of the named ``values`` of ``key`` that is not finite."""
    for name, value in values.items():
        if not np.isfinite(value):
            raise DatasetError(f"{source}: {name} of {key} is {value:g}, not a finite number")


def stereo_camera_from_projections(
    P_left: np.ndarray,
    P_right: np.ndarray,
    width: int,
    height: int,
    source: Path | str,
    keys: tuple[str, str] = ("the left P", "the right P"),
) -> StereoCamera:
    """The rectified `StereoCamera` of the two (3, 4) projection matrices of a rectified pair.

    Each matrix is ``K [I | t]``: it projects points of a reference camera's rectified
    frame, ``t`` being where that camera's origin lies in this camera's frame [m].
    Intrinsics come from ``P_left``; the baseline [m] is the distance along x between the
    two cameras, ``t_left[0] - t_right[0]``, with ``t[0] = (P[0, 3] - cx * P[2, 3]) / fx``.
    Where the left camera is the reference (KITTI's grey pair, ``cv2.stereoRectify``),
    ``P[2, 3] = 0`` and this is ``(P_left[0, 3] - P_right[0, 3]) / fx``
    (``P_right[0, 3] = -fx * b``). KITTI's colour cameras are not the reference and sit
    a few mm apart along the optical axis (``P2[2, 3]`` 6.2 mm, ``P3[2, 3]`` 3.3 mm on
    odometry 04); ``(P2[0, 3] - P3[0, 3]) / fx`` would count ``cx`` times those 2.9 mm as
    baseline, 0.5379 m instead of 0.5354. Projecting points 3 to 40 m away, spread over
    the image, through that calibration's ``P2`` and ``P3``: the x distance gives their
    depths 0.01 % short on average, the ``tx`` difference 0.45 % too far (KITTI raw
    2011_09_26: 0.53271 against 0.53273 m, the cameras 0.2 mm apart along the axis).
    Where the two matrices have different principal points, their difference
    ``P_left[0, 2] - P_right[0, 2]`` is the camera's ``disparity_offset``.

    Every layout makes its camera here, so the checks are made once: the intrinsics
    (`check_intrinsics`), the ``tx`` and ``tz`` of both and the right ``cx`` finite, and a
    positive baseline (one that is not, the right camera not to the right, means swapped
    images or a sign error in the calibration). Each raises `DatasetError` naming
    ``source``, the calibration file, and ``keys``, what the two matrices are called there.
    """
    check_intrinsics(P_left, (width, height), source, keys[0])
    _require_finite(source, keys[0], {"tx": float(P_left[0, 3]), "tz": float(P_left[2, 3])})
    _require_finite(
        source, keys[1], {"tx": float(P_right[0, 3]), "cx": float(P_right[0, 2]), "tz": float(P_right[2, 3])}
    )
    fx = float(P_left[0, 0])
    baseline = _x_offset(P_left, fx) - _x_offset(P_right, fx)
    if not baseline > 0.0:
        raise DatasetError(
            f"{source}: the right camera is not to the right of the left one "
            f"(baseline {baseline:.4g} m); are left and right swapped?"
        )
    return StereoCamera(
        fx=fx,
        fy=float(P_left[1, 1]),
        cx=float(P_left[0, 2]),
        cy=float(P_left[1, 2]),
        baseline=baseline,
        width=int(width),
        height=int(height),
        disparity_offset=float(P_left[0, 2] - P_right[0, 2]),
    )


def _x_offset(P: np.ndarray, fx: float) -> float:
    """``t[0]`` [m] of a (3, 4) projection ``P = K [I | t]`` without skew, of focal length ``fx`` [px]."""
    return float(P[0, 3] - P[0, 2] * P[2, 3]) / fx


def camera_from_reference(P: np.ndarray) -> np.ndarray:
    """(4, 4) ``T_c_ref`` of the rectified camera whose (3, 4) projection ``P = K [I | t]``
    maps points of the reference camera's rectified frame: ``[I | K^-1 P[:, 3]]``.

    Rectified cameras share the reference's orientation, so the pose is a translation
    (the identity for the reference itself, ``P = K [I | 0]``). KITTI's colour left camera
    (``P2``: ``t`` = (0.061, -0.001, 0.006) m on sequence 04) sits 6 cm to the left of the
    grey one (cam0, the frame of the ground truth): its centre, ``-t`` in cam0, has x < 0.
    ``K`` = ``P[:, :3]`` must be invertible (`check_intrinsics` passed).
    """
    return make_pose(np.eye(3), np.linalg.solve(P[:, :3], P[:, 3]))
