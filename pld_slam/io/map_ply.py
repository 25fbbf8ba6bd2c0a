"""The map as a PLY file: points, line landmarks as edges, keyframe camera centres.

``map.ply`` (binary little-endian, written with `plyfile`) holds three elements, in the
world frame of the run's trajectory (the first camera):

- ``vertex``: ``x, y, z`` (float32 [m]) and ``observers`` (int32: keyframes that see the
  landmark): the map points first, then the two endpoints of each line landmark, start
  then end;
- ``edge``: ``vertex1, vertex2`` (int32), one per line landmark, its two endpoint vertices;
- ``camera``: ``x, y, z`` (float32 [m]), the centre of each keyframe alive at the end, in
  keyframe order.

MeshLab and CloudCompare show the vertices and edges (and skip the ``camera`` element),
Open3D's ``read_point_cloud`` the vertices; `read_map_ply` reads all of it back.
"""

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from plyfile import PlyData, PlyElement

from pld_slam.mapping.map import Map


@dataclass(frozen=True)
class MapCloud:
    """A map's landmarks and keyframe centres as arrays (world frame).

    Attributes
    ----------
    points_w : (N, 3) map points [m].
    point_observers : (N,) keyframes observing each point.
    lines_w : (L, 2, 3) line landmarks' endpoints, start then end [m].
    line_observers : (L,) keyframes observing each line.
    keyframe_centres_w : (K, 3) keyframe camera centres [m].
    """

    points_w: np.ndarray
    point_observers: np.ndarray
    lines_w: np.ndarray
    line_observers: np.ndarray
    keyframe_centres_w: np.ndarray


def map_cloud(world_map: Map) -> MapCloud:
    """The landmarks alive in ``world_map`` and the centres of its keyframes, in keyframe id order."""
    points, lines = world_map.points, world_map.lines
    centres = [world_map.keyframes[key].T_w_c[:3, 3] for key in sorted(world_map.keyframes)]
    return MapCloud(
        points_w=points.geometry[points.alive],
        point_observers=points.n_observers[points.alive],
        lines_w=lines.geometry[lines.alive],
        line_observers=lines.n_observers[lines.alive],
        keyframe_centres_w=np.array(centres).reshape(-1, 3),
    )


def write_map_ply(path: Path, cloud: MapCloud) -> None:
    """Write ``cloud`` to ``path`` as the PLY file of the module docstring (OSErrors to the caller)."""
    n_points, n_lines = len(cloud.points_w), len(cloud.lines_w)
    vertices = np.concatenate([cloud.points_w, cloud.lines_w.reshape(-1, 3)])
    observers = np.concatenate([cloud.point_observers, np.repeat(cloud.line_observers, 2)])
    vertex = np.empty(len(vertices), dtype=[("x", "f4"), ("y", "f4"), ("z", "f4"), ("observers", "i4")])
    vertex["x"], vertex["y"], vertex["z"] = vertices.T
    vertex["observers"] = observers
    edge = np.empty(n_lines, dtype=[("vertex1", "i4"), ("vertex2", "i4")])
    edge["vertex1"] = n_points + 2 * np.arange(n_lines)
    edge["vertex2"] = edge["vertex1"] + 1
    camera = np.empty(len(cloud.keyframe_centres_w), dtype=[("x", "f4"), ("y", "f4"), ("z", "f4")])
    camera["x"], camera["y"], camera["z"] = cloud.keyframe_centres_w.T
    elements = [PlyElement.describe(data, name) for data, name in ((vertex, "vertex"), (edge, "edge"),
                                                                   (camera, "camera"))]
    PlyData(elements, text=False, byte_order="<").write(str(path))


def read_map_ply(path: Path) -> MapCloud:
    """The `MapCloud` of a ``map.ply`` that `write_map_ply` wrote (float32 coordinates)."""
    ply = PlyData.read(str(path))
    vertex, edge, camera = ply["vertex"].data, ply["edge"].data, ply["camera"].data
    xyz = np.column_stack([vertex["x"], vertex["y"], vertex["z"]]).astype(np.float64)
    n_points = len(xyz) - 2 * len(edge)
    return MapCloud(
        points_w=xyz[:n_points],
        point_observers=vertex["observers"][:n_points].astype(np.int64),
        lines_w=np.stack([xyz[edge["vertex1"]], xyz[edge["vertex2"]]], axis=1),
        line_observers=vertex["observers"][edge["vertex1"]].astype(np.int64),
        keyframe_centres_w=np.column_stack([camera["x"], camera["y"], camera["z"]]).astype(np.float64),
    )
