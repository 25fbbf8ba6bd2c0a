"""Map landmarks of one kind, points or lines, in id-indexed numpy columns.

A landmark's id is its row. Rows are never reused: a removed landmark keeps its row with
``alive`` False, so a keyframe's landmark ids stay meaningful (an id whose row is dead is
treated as no landmark). Columns grow by doubling, so adding K landmarks costs O(K)
amortised, and projecting the whole local map, or building a BA problem, is a handful of
vectorised operations on these columns.

Observations (which keyframe sees a landmark, as which of its features) are kept twice,
as in ORB-SLAM2: each keyframe holds the landmark id of each of its features
(`KeyFrame.point_ids`, ``-1`` for none), and each landmark a dict ``{keyframe id: feature
index}`` (`Landmarks.observers`). The map (`pld_slam.mapping.map`) changes both together.

Lines are 3D segments stored by their two endpoints, start ``P`` and end ``Q`` (6 numbers).
Minimal line parameterisations (Plücker coordinates with an orthonormal update, 4 dof)
describe an infinite line, but the paper's horizontal error measures the endpoints, and
every residual of `pld_slam.optim.line_reprojection` is written on them. Bundle
adjustment moves an endpoint only across its line unless a horizontal error measures it
(`pld_slam.optim.bundle_adjustment._held_directions`), so a line keeps the 4 dof of an
infinite line and its endpoints their places along it.
"""

from collections.abc import Iterable
from typing import ClassVar

import numpy as np

from pld_slam.frontend.descriptors import DESCRIPTOR_BYTES

_INITIAL_CAPACITY = 256
NEVER_MOVING = -(2**40)
"""``moving_frame`` of a landmark never seen moving: further back than any memory reaches."""


class _Column:
    """A class attribute that reads as the first ``len(landmarks)`` rows of one named column, read-only:
    the map writes through `Landmarks.writable`."""

    def __set_name__(self, owner: type, name: str) -> None:
        self._name = name

    def __get__(self, landmarks: "Landmarks", owner: type | None = None) -> np.ndarray:
        rows = landmarks._data[self._name][: landmarks._size]
        rows.flags.writeable = False
        return rows


class Landmarks:
    """Landmarks of one kind: a row per landmark ever created (module docstring).

    Columns (each an (N, ...) view, N = landmarks ever created):

    - ``geometry``: a point's world position (N, 3) or a line's world endpoints (N, 2, 3) [m];
    - ``descriptor``: (N, 32) uint8, the representative ORB / LBD descriptor (the
      observation whose median Hamming distance to the others is smallest, as ORB-SLAM2);
    - ``normal``: (N, 3) mean unit viewing direction from the observing cameras (world);
    - ``visible``, ``found``: (N,) frames in whose view the landmark was predicted, and in
      how many of them tracking matched it (the culling test of ORB-SLAM2);
    - ``dynamic_streak``: (N,) frames since tracking last found it among the static
      features in which it matched a feature labelled dynamic or lay under one
      (`pld_slam.localisation.local_map.missed_near_movers`); a find within
      ``mapping.dynamic_memory`` tracked frames of such a frame does not end the streak;
    - ``moving_frame``: (N,) rank, among the tracked frames, of the last frame that saw it
      moving (a large negative number before any);
    - ``missed_streak``: (N,) frames with the landmark in view in which tracking did not find
      it, since it last found it;
    - ``first_keyframe``: (N,) id of the keyframe that created it;
    - ``n_observers``: (N,) keyframes observing it;
    - ``alive``: (N,) bool.
    """

    geometry = _Column()
    descriptor = _Column()
    normal = _Column()
    visible = _Column()
    found = _Column()
    dynamic_streak = _Column()
    missed_streak = _Column()
    moving_frame = _Column()
    first_keyframe = _Column()
    n_observers = _Column()
    alive = _Column()

    GEOMETRY_SHAPE: ClassVar[tuple[int, ...]] = ()
    """Shape of one landmark's geometry: (3,) for points, (2, 3) for lines."""
    IDS_FIELD: ClassVar[str] = ""
    """The `KeyFrame` attribute holding the landmark id of each feature of this kind."""
    FEATURES_FIELD: ClassVar[str] = ""
    """The `StereoFeatures` attribute holding the features of this kind."""
    DYNAMIC_FIELD: ClassVar[str] = ""
    """The `KeyFrame` attribute marking the features of this kind labelled dynamic."""

    def __init__(self) -> None:
        self._size = 0
        self._data = {
            name: np.full((_INITIAL_CAPACITY, *shape), fill, dtype=dtype)
            for name, (shape, dtype, fill) in self._column_specs().items()
        }
        self.observers: list[dict[int, int]] = []
        """Per landmark, ``{keyframe id: index of the feature observing it}``."""

    @classmethod
    def _column_specs(cls) -> dict[str, tuple[tuple[int, ...], type, object]]:
        """Shape of one row, dtype and fill of every column."""
        return {
            "geometry": (cls.GEOMETRY_SHAPE, np.float64, np.nan),
            "descriptor": ((DESCRIPTOR_BYTES,), np.uint8, 0),
            "normal": ((3,), np.float64, 0.0),
            "visible": ((), np.int64, 0),
            "found": ((), np.int64, 0),
            "dynamic_streak": ((), np.int64, 0),
            "missed_streak": ((), np.int64, 0),
            "moving_frame": ((), np.int64, NEVER_MOVING),
            "first_keyframe": ((), np.int64, -1),
            "n_observers": ((), np.int64, 0),
            "alive": ((), np.bool_, False),
        }

    def __len__(self) -> int:
        """Landmarks ever created (alive or not)."""
        return self._size

    def writable(self, name: str) -> np.ndarray:
        """Column ``name``'s first ``len(self)`` rows, writable: for `pld_slam.mapping.map.Map`, the landmarks'
        only writer (a test holds every other module to the read-only columns)."""
        return self._data[name][: self._size]

    @property
    def n_alive(self) -> int:
        """Landmarks alive now."""
        return int(np.count_nonzero(self.alive))

    def add(self, geometry: np.ndarray, descriptor: np.ndarray, first_keyframe: int) -> np.ndarray:
        """Append K landmarks (alive, no observers yet); returns their ids (K,) int64.

        ``geometry`` (K, *GEOMETRY_SHAPE) world coordinates [m], ``descriptor`` (K, 32) uint8.
        """
        count = len(geometry)
        self._reserve(self._size + count)
        ids = np.arange(self._size, self._size + count)
        self._size += count
        self.writable("geometry")[ids] = geometry
        self.writable("descriptor")[ids] = descriptor
        self.writable("first_keyframe")[ids] = first_keyframe
        self.writable("alive")[ids] = True
        self.observers.extend({} for _ in range(count))
        return ids

    def centres(self, ids: np.ndarray) -> np.ndarray:
        """World centre (K, 3) of landmarks ``ids`` (K,): a point's position, a line's midpoint."""
        geometry = self.geometry[ids]
        return geometry if geometry.ndim == 2 else geometry.mean(axis=1)

    def live(self, ids: np.ndarray) -> np.ndarray:
        """Which of ``ids`` (K,) int64 (``-1`` for none) name a landmark alive now (K,) bool."""
        ids = np.asarray(ids)
        valid = (ids >= 0) & (ids < self._size)
        valid[valid] = self.alive[ids[valid]]
        return valid

    def live_ids(self, ids: np.ndarray) -> np.ndarray:
        """The distinct ids among ``ids`` (K,) int64 (``-1`` for none) that name a live landmark, ascending."""
        ids = np.asarray(ids)
        return np.unique(ids[self.live(ids)])

    def observed_by(self, keyframes: Iterable) -> np.ndarray:
        """The distinct live landmarks (ascending) that any of ``keyframes`` (`KeyFrame` objects) observes."""
        ids = [getattr(keyframe, self.IDS_FIELD) for keyframe in keyframes]
        return self.live_ids(np.concatenate(ids) if ids else np.zeros(0, dtype=np.int64))

    def _reserve(self, size: int) -> None:
        """Grow every column to hold at least ``size`` rows (doubling)."""
        capacity = len(self._data["alive"])
        if size <= capacity:
            return
        while capacity < size:
            capacity *= 2
        for name, (shape, dtype, fill) in self._column_specs().items():
            grown = np.full((capacity, *shape), fill, dtype=dtype)
            grown[: self._size] = self._data[name][: self._size]
            self._data[name] = grown


class PointLandmarks(Landmarks):
    """Map points. Extra column ``max_distance`` (N,): ORB-SLAM2's scale-invariance range.

    A point observed at ORB octave ``o`` from distance ``d`` is predicted to be found at
    octave 0 up to ``max_distance = d * scale_factor**o`` and at the top octave down to
    ``max_distance / scale_factor**(n_levels - 1)``; `predicted_octaves` gives the octave at
    any distance, which sizes its search window.
    """

    max_distance = _Column()
    GEOMETRY_SHAPE = (3,)
    IDS_FIELD = "point_ids"
    FEATURES_FIELD = "keypoints"
    DYNAMIC_FIELD = "point_dynamic"

    @classmethod
    def _column_specs(cls) -> dict[str, tuple[tuple[int, ...], type, object]]:
        return {**super()._column_specs(), "max_distance": ((), np.float64, np.inf)}


class LineLandmarks(Landmarks):
    """Map lines: 3D segments by their world endpoints (N, 2, 3), start then end (module docstring)."""

    GEOMETRY_SHAPE = (2, 3)
    IDS_FIELD = "line_ids"
    FEATURES_FIELD = "lines"
    DYNAMIC_FIELD = "line_dynamic"


_OCTAVE_ROUNDING = 1e-9
"""Taken off a log ratio before rounding it up, so that a point at the distance it was seen
from is predicted at the octave it was seen at (``log(1.2**2) / log(1.2)`` is 2.0000000000000004)."""


def predicted_octaves(
    max_distance: np.ndarray, distance: np.ndarray, scale_factor: float, n_levels: int
) -> np.ndarray:
    """ORB octave (K,) int64 at which points of ``max_distance`` (K,) are expected at ``distance`` (K,) [m].

    ORB-SLAM2's ``PredictScale``: ``ceil(log(max_distance / distance) / log(scale_factor))``
    clipped to ``[0, n_levels - 1]``.
    """
    ratio = np.maximum(max_distance / np.maximum(distance, 1e-9), 1e-9)
    octave = np.ceil(np.log(ratio) / np.log(scale_factor) - _OCTAVE_ROUNDING)
    return np.clip(octave, 0, n_levels - 1).astype(np.int64)
