"""The synthetic scene: textured rectangles ("quads"), the objects built from them, movers.

Every surface is a planar rectangle: an ``origin`` corner and two orthogonal edge vectors
``a`` and ``b``. A quad is seen from one side only, the side from which ``a`` points right
and ``b`` points down (like an image), so its outward normal is ``b x a``; boxes are built
with their normals outwards, floors with theirs up. A surface point ``origin + x a/|a| +
y b/|b|`` (``x``, ``y`` in metres) shows texture coordinate ``(x, y) + tex_offset``.

Frames follow the camera convention (y down): the world is the first left camera, the
ground is the plane ``y = scenarios.CAMERA_HEIGHT``; an object frame has x right, y down, z forward
and its origin on the ground at the middle of the object's footprint (for a building: of
its facade's foot, with z pointing into the building). ``T_w_o`` places an object.

What changes over a sequence: movers (`MovingObject`, a pose per frame), transient static
quads (`Transient`, which exist for a span of frames: parked cars that differ between two
visits of a place) and the light (`Scene.light` and `Scene.exposure`, optionally per frame).

A scene may have a view distance (`Scene.view_index`, a `QuadGrid`): then a frame is drawn
from the quads within that distance of the camera only (`Scene.quads_near`), so a large
world (a city) costs per frame what the camera's surroundings cost. Without one (every
scenario but the city) all quads are drawn, as they always were.
"""

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from pld_slam.geometry.se3 import make_pose, so3_exp, transform_points
from pld_slam.synth.textures import TextureAtlas

DOWN = np.array([0.0, 1.0, 0.0])
"""Gravity direction in the world and object frames (y down)."""
UP = -DOWN

STATIC_OBJECT = 0
"""Object id of every quad that never moves; moving objects are numbered from 1."""


@dataclass(frozen=True)
class Quads:
    """A set of Q textured rectangles (structure of arrays).

    Attributes
    ----------
    origin : np.ndarray
        (Q, 3) corner where the texture starts [m].
    edge_a, edge_b : np.ndarray
        (Q, 3) orthogonal edges [m]: texture columns run along ``a``, rows along ``b``.
    material : np.ndarray
        (Q,) int32 index of the texture in the scene's atlas.
    albedo : np.ndarray
        (Q,) float32 factor on the texture (paint colour of a car, shade of a wall panel).
    tex_offset : np.ndarray
        (Q, 2) texture coordinate [m] at the origin along ``a`` and ``b``.
    object_id : np.ndarray
        (Q,) int32: `STATIC_OBJECT` or the id of the moving object the quad belongs to.
    """

    origin: np.ndarray
    edge_a: np.ndarray
    edge_b: np.ndarray
    material: np.ndarray
    albedo: np.ndarray
    tex_offset: np.ndarray
    object_id: np.ndarray

    def __len__(self) -> int:
        return len(self.material)

    def transformed(self, T_a_b: np.ndarray) -> "Quads":
        """The quads moved from frame b into frame a by the pose ``T_a_b`` (4, 4)."""
        R = T_a_b[:3, :3]
        return replace(
            self,
            origin=transform_points(T_a_b, self.origin),
            edge_a=self.edge_a @ R.T,
            edge_b=self.edge_b @ R.T,
        )

    def select(self, keep: np.ndarray) -> "Quads":
        """The quads where the mask or index array ``keep`` selects them, in order."""
        return Quads(*(getattr(self, name)[keep] for name in Quads.__dataclass_fields__))

    def with_object_id(self, object_id: int) -> "Quads":
        """The same quads, all belonging to object ``object_id``."""
        return replace(self, object_id=np.full(len(self), object_id, dtype=np.int32))

    def normals(self) -> np.ndarray:
        """Outward unit normals (Q, 3): ``b x a`` normalised (the visible side)."""
        n = np.cross(self.edge_b, self.edge_a)
        return n / np.linalg.norm(n, axis=1, keepdims=True)

    def corners(self) -> np.ndarray:
        """Corners (Q, 4, 3) in order origin, +a, +a+b, +b."""
        o, a, b = self.origin, self.edge_a, self.edge_b
        return np.stack([o, o + a, o + a + b, o + b], axis=1)

    @staticmethod
    def concat(parts: Sequence["Quads"]) -> "Quads":
        """All quads of ``parts`` in order, as one set."""
        return Quads(*(np.concatenate([getattr(p, name) for p in parts])
                       for name in Quads.__dataclass_fields__))


def rectangle(origin, edge_a, edge_b, material, albedo=1.0, tex_offset=(0.0, 0.0)) -> Quads:
    """Static quads from origin corners and edges, each (3,) or (n, 3) [m]; ``material``,
    ``albedo`` (scalars or (n,)) and ``tex_offset`` ((2,) or (n, 2)) broadcast."""
    origin = np.asarray(origin, dtype=np.float64).reshape(-1, 3)
    edge_a = np.broadcast_to(np.asarray(edge_a, dtype=np.float64).reshape(-1, 3), origin.shape)
    edge_b = np.broadcast_to(np.asarray(edge_b, dtype=np.float64).reshape(-1, 3), origin.shape)
    n = len(origin)
    return Quads(
        origin=origin,
        edge_a=np.array(edge_a),
        edge_b=np.array(edge_b),
        material=np.broadcast_to(np.asarray(material, dtype=np.int32), (n,)).copy(),
        albedo=np.broadcast_to(np.asarray(albedo, dtype=np.float32), (n,)).copy(),
        tex_offset=np.broadcast_to(np.asarray(tex_offset, dtype=np.float64).reshape(-1, 2), (n, 2)).copy(),
        object_id=np.full(n, STATIC_OBJECT, dtype=np.int32),
    )


def wall(bottom_centre, normal, width, height, material, albedo=1.0, tex_offset=(0.0, 0.0)) -> Quads:
    """Vertical quads ``width`` x ``height`` [m] standing on ``bottom_centre`` and facing the
    horizontal unit ``normal`` ((3,) or (n, 3); sizes scalar or (n,)); the texture starts
    at the top left corner as seen from the front."""
    normal = np.asarray(normal, dtype=np.float64)
    width = np.asarray(width, dtype=np.float64)[..., None]
    height = np.asarray(height, dtype=np.float64)[..., None]
    a_dir = np.cross(normal, DOWN)
    origin = np.asarray(bottom_centre) - 0.5 * width * a_dir + height * UP
    return rectangle(origin, width * a_dir, height * DOWN, material, albedo, tex_offset)


def floor(centre, forward, width, length, material, albedo=1.0, tex_offset=(0.0, 0.0)) -> Quads:
    """Horizontal quads facing up, ``width`` across and ``length`` [m] along the horizontal
    unit ``forward``, centred on ``centre`` ((3,) or (n, 3); sizes scalar or (n,)). Texture
    columns run to the right and rows backwards, from the front left corner."""
    forward = np.asarray(forward, dtype=np.float64)
    width = np.asarray(width, dtype=np.float64)[..., None]
    length = np.asarray(length, dtype=np.float64)[..., None]
    right = np.cross(DOWN, forward)
    origin = np.asarray(centre) - 0.5 * width * right + 0.5 * length * forward
    return rectangle(origin, width * right, -length * forward, material, albedo, tex_offset)


@dataclass(frozen=True)
class BoxMaterials:
    """Materials of a box's faces: ``side`` (normal +-x), ``end`` (+-z) and ``top``."""

    side: int
    end: int
    top: int


def box(width: float, height: float, length: float, materials: BoxMaterials,
        albedo: float = 1.0) -> Quads:
    """A closed box (5 quads, no bottom) in its object frame: ``width`` along x, ``height``
    up, ``length`` along z [m], standing on the origin. Each face's texture starts at its
    top left corner, so a texture of the face's size covers it exactly once."""
    x, z = np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0])
    return Quads.concat([
        wall(0.5 * width * x, x, length, height, materials.side, albedo),
        wall(-0.5 * width * x, -x, length, height, materials.side, albedo),
        wall(0.5 * length * z, z, width, height, materials.end, albedo),
        wall(-0.5 * length * z, -z, width, height, materials.end, albedo),
        floor(height * UP, z, width, length, materials.top, albedo),
    ])


def translation(x: float, y: float, z: float) -> np.ndarray:
    """Pose (4, 4) that shifts by ``(x, y, z)`` [m] without rotating."""
    return make_pose(np.eye(3), np.array([x, y, z]))


def yaw_pose(position, yaw: float) -> np.ndarray:
    """Pose ``T_w_o`` (4, 4) of an upright object at ``position`` (3,) turned by ``yaw``
    [rad] about the down axis (positive turns z towards x, i.e. to the right)."""
    return make_pose(so3_exp(np.array([0.0, yaw, 0.0])), np.asarray(position, dtype=np.float64))


# --- building blocks ------------------------------------------------------------------------


@dataclass(frozen=True)
class FacadeMaterials:
    """Materials of a building: ``upper`` storeys, ``ground`` floor (shops), ``side`` walls."""

    upper: int
    ground: int
    side: int


GROUND_FLOOR_HEIGHT = 4.0
"""Height [m] of a building's ground floor (the shopfront texture is 4 m tall)."""


def building(width: float, depth: float, height: float, materials: FacadeMaterials,
             tex_shift: float, albedo: float = 1.0) -> Quads:
    """A building in its object frame: the facade ``width`` [m] wide at z = 0 facing -z,
    the body ``depth`` deep along +z, ``height`` tall. The facade is a ground floor and
    the upper storeys, whose texture is shifted by ``tex_shift`` [m] along the street and
    whose storeys start at the top edge (so ``height - GROUND_FLOOR_HEIGHT`` should be a
    multiple of the storey height). Sides are plain walls; roof and back are never seen."""
    x, z = np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0])
    upper = height - GROUND_FLOOR_HEIGHT
    return Quads.concat([
        wall(GROUND_FLOOR_HEIGHT * UP, -z, width, upper, materials.upper, albedo, (tex_shift, 0.0)),
        wall(np.zeros(3), -z, width, GROUND_FLOOR_HEIGHT, materials.ground, albedo, (tex_shift, 0.0)),
        wall(0.5 * width * x + 0.5 * depth * z, x, depth, height, materials.side, albedo),
        wall(-0.5 * width * x + 0.5 * depth * z, -x, depth, height, materials.side, albedo),
    ])


def pole(height: float, arm_length: float, metal: int, sign_material: int | None) -> Quads:
    """A street-light pole in its object frame: a 14 cm square mast of ``height`` [m] at the
    origin, an arm of ``arm_length`` [m] at the top towards -x (the road), and optionally a
    0.6 m sign facing -z (oncoming traffic) at 2.3 m."""
    metal_box = BoxMaterials(metal, metal, metal)
    parts = [
        box(0.14, height, 0.14, metal_box),
        box(arm_length, 0.12, 0.12, metal_box).transformed(
            translation(-0.5 * arm_length, -height + 0.3, 0.0)),
        box(0.5, 0.12, 0.3, metal_box).transformed(translation(-arm_length, -height + 0.18, 0.0)),
    ]
    if sign_material is not None:
        plate = BoxMaterials(metal, sign_material, metal)
        parts.append(box(0.6, 0.6, 0.04, plate).transformed(translation(0.0, -2.3, -0.1)))
    return Quads.concat(parts)


def gantry(span: float, clearance: float, metal: int, signs: Sequence[tuple[float, float, int]]) -> Quads:
    """A sign gantry over a road in its object frame: two 0.5 m square legs at
    ``x = +-span / 2``, a truss 1 m tall and 0.8 m deep across from ``clearance + 0.7``
    [m] up, and sign plates 2.4 m tall, their bottom edge at ``clearance``, hung in front
    of it facing -z (oncoming traffic), one per ``(x [m], width [m], material)``."""
    metal_box = BoxMaterials(metal, metal, metal)
    truss = clearance + 0.7
    parts = [box(0.5, truss + 1.0, 0.5, metal_box).transformed(translation(x, 0.0, 0.0))
             for x in (-0.5 * span, 0.5 * span)]
    parts.append(box(span, 1.0, 0.8, metal_box).transformed(translation(0.0, -truss, 0.0)))
    for x, width, material in signs:
        plate = BoxMaterials(metal, material, metal)
        parts.append(box(width, 2.4, 0.1, plate).transformed(translation(x, -clearance, -0.5)))
    return Quads.concat(parts)


def tree(trunk_height: float, crown_width: float, crown_height: float, bark: int, foliage: int) -> Quads:
    """A tree in its object frame: a trunk 0.35 m square and ``trunk_height`` [m] tall
    under a square crown ``crown_width`` wide and ``crown_height`` tall (boxes, so it
    looks the same from every side)."""
    trunk = box(0.35, trunk_height + 0.3, 0.35, BoxMaterials(bark, bark, bark))
    crown = box(crown_width, crown_height, crown_width, BoxMaterials(foliage, foliage, foliage))
    return Quads.concat([trunk, crown.transformed(translation(0.0, -trunk_height, 0.0))])


STOREY_BAND_SPACING = 3.0
"""Height [m] between the flat bands that mark the storeys of a plain building."""


def plain_building(width: float, depth: float, height: float, flat: int,
                   panel_shades: np.ndarray, door_at: Sequence[float], door_shade: float,
                   band_shade: float) -> Quads:
    """A low-texture building in its object frame (facade at z = 0 facing -z): a wall of
    uniform panels of ``panel_shades`` (K,) albedos side by side, a skirting band, a band of
    ``band_shade`` at every storey, a pillar between neighbouring panels, and framed doors
    centred at ``door_at`` [m from the facade centre]. Everything uses the ``flat``
    material; edges carry all the structure."""
    x, z = np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0])
    plain = BoxMaterials(flat, flat, flat)
    panel_w = width / len(panel_shades)
    parts = []
    for k, panel_shade in enumerate(panel_shades):
        centre = -0.5 * width + (k + 0.5) * panel_w
        parts.append(wall(centre * x, -z, panel_w, height, flat, float(panel_shade)))
        if k > 0:
            parts.append(box(0.4, height, 0.3, plain, 0.8).transformed(
                translation(centre - 0.5 * panel_w, 0.0, -0.15)))
    parts.append(box(width, 0.4, 0.06, plain, 0.45).transformed(translation(0.0, 0.0, -0.03)))
    for storey in np.arange(STOREY_BAND_SPACING, height, STOREY_BAND_SPACING):
        parts.append(wall(np.array([0.0, -(storey - 0.1), -0.02]), -z, width, 0.2, flat, band_shade))
    for centre in door_at:
        parts.append(wall(np.array([centre, 0.0, -0.02]), -z, 1.2, 2.3, flat, door_shade))
        for jamb in (-0.68, 0.68):
            parts.append(box(0.16, 2.45, 0.08, plain, 0.95).transformed(translation(centre + jamb, 0.0, -0.04)))
        parts.append(box(1.52, 0.16, 0.08, plain, 0.95).transformed(translation(centre, -2.3, -0.04)))
    side_shade = 0.9 * float(panel_shades[0])
    parts.append(wall(0.5 * width * x + 0.5 * depth * z, x, depth, height, flat, side_shade))
    parts.append(wall(-0.5 * width * x + 0.5 * depth * z, -x, depth, height, flat, side_shade))
    return Quads.concat(parts)


# --- moving objects and the scene ------------------------------------------------------------


@dataclass(frozen=True)
class MovingObject:
    """A rigid object that moves: its quads in its own frame and its pose at every frame.

    Attributes
    ----------
    quads : Quads
        Quads in the object frame, all with this object's id (>= 1).
    poses : np.ndarray
        (N, 4, 4) ``T_w_o`` at each frame of the sequence.
    """

    quads: Quads
    poses: np.ndarray

    @property
    def object_id(self) -> int:
        """The id stamped on the object's quads."""
        return int(self.quads.object_id[0])

    def radius(self) -> float:
        """Distance [m] from the object's origin to its farthest corner."""
        return float(np.linalg.norm(self.quads.corners(), axis=2).max())

    def moves_at(self, frame: int) -> bool:
        """Whether the object moves at ``frame``: its pose there differs from the frame
        before's (frame 0: from frame 1's). A parked car that has not pulled out yet, or a
        pedestrian waiting at the kerb, does not: the dynamic masks leave it out until it
        moves, as the map should take it in until then."""
        other = frame - 1 if frame > 0 else min(1, len(self.poses) - 1)
        return not np.allclose(self.poses[frame], self.poses[other], rtol=0.0, atol=1e-9)


@dataclass(frozen=True)
class Transient:
    """Static quads that exist for a span of frames only: a parked car that is gone when
    the camera comes back, another one that was not there before.

    They never move while they exist, so they keep `STATIC_OBJECT` (they are not in the
    dynamic masks, which mark moving objects).

    Attributes
    ----------
    quads : Quads
        (Q) quads in the world frame, object id `STATIC_OBJECT`.
    first, end : np.ndarray
        (Q,) int64: each quad exists at frames ``first <= frame < end``.
    """

    quads: Quads
    first: np.ndarray
    end: np.ndarray

    def at(self, frame: int) -> Quads:
        """The quads that exist at ``frame``."""
        return self.quads.select((self.first <= frame) & (frame < self.end))


def ground_boxes(quads: Quads) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper corners (Q, 2) of each quad's box on the ground plane, as ``(x, z)`` [m]."""
    xz = quads.corners()[:, :, [0, 2]]
    return xz.min(axis=1), xz.max(axis=1)


@dataclass(frozen=True)
class QuadGrid:
    """Static quads binned by where they lie on the ground, to find those near a point fast.

    The ground ``(x, z)`` is cut into square cells; a quad is listed in every cell its box on
    the ground (`ground_boxes`) overlaps. `near` looks at the cells around a point only, so
    its cost depends on how much stands near the point, not on the size of the world.

    Attributes
    ----------
    view_distance : float
        Reach [m] of `near`: a quad is near when its ground box comes this close.
    cell : float
        Side [m] of a cell.
    low : np.ndarray
        (2,) ``(x, z)`` [m] of the lower corner of cell ``(0, 0)``.
    shape : tuple of int
        Cells along x and along z.
    start : np.ndarray
        (C + 1,) int64 where each cell's entries begin in ``quad`` (cells row by row: index
        ``iz * shape[0] + ix``).
    quad : np.ndarray
        (E,) int64 index of the quad of each entry, cell by cell, ascending within a cell.
    box_low, box_high : np.ndarray
        (Q, 2) each quad's box on the ground, ``(x, z)`` [m].
    """

    view_distance: float
    cell: float
    low: np.ndarray
    shape: tuple[int, int]
    start: np.ndarray
    quad: np.ndarray
    box_low: np.ndarray
    box_high: np.ndarray

    @classmethod
    def build(cls, quads: Quads, view_distance: float, cell: float = 50.0) -> "QuadGrid":
        """The grid of ``quads`` (world frame) for `near` within ``view_distance`` [m]."""
        box_low, box_high = ground_boxes(quads)
        low = box_low.min(axis=0)
        first = np.floor((box_low - low) / cell).astype(np.int64)
        last = np.floor((box_high - low) / cell).astype(np.int64)
        shape = tuple(int(n) for n in last.max(axis=0) + 1)
        spans = last - first + 1
        counts = spans[:, 0] * spans[:, 1]
        quad = np.repeat(np.arange(len(quads)), counts)
        entry = np.arange(len(quad)) - np.repeat(np.cumsum(counts) - counts, counts)
        ix = first[quad, 0] + entry % spans[quad, 0]
        iz = first[quad, 1] + entry // spans[quad, 0]
        cell_of = iz * shape[0] + ix
        order = np.argsort(cell_of, kind="stable")
        start = np.searchsorted(cell_of[order], np.arange(shape[0] * shape[1] + 1))
        return cls(view_distance, cell, low, shape, start, quad[order], box_low, box_high)

    def near(self, centre: np.ndarray) -> np.ndarray:
        """Indices (ascending) of the quads whose ground box comes within `view_distance`
        of the world point ``centre`` (3,), measured on the ground (x and z)."""
        point = np.asarray(centre, dtype=np.float64)[[0, 2]]
        first = np.maximum(np.floor((point - self.view_distance - self.low) / self.cell).astype(np.int64), 0)
        last = np.minimum(np.floor((point + self.view_distance - self.low) / self.cell).astype(np.int64),
                          np.array(self.shape) - 1)
        if (first > last).any():
            return np.zeros(0, dtype=np.int64)
        rows = [self.quad[self.start[iz * self.shape[0] + first[0]]:self.start[iz * self.shape[0] + last[0] + 1]]
                for iz in range(first[1], last[1] + 1)]
        candidates = np.unique(np.concatenate(rows))
        gap = np.maximum(np.maximum(self.box_low[candidates] - point, point - self.box_high[candidates]), 0.0)
        return candidates[np.einsum("qi,qi->q", gap, gap) <= self.view_distance ** 2]


@dataclass(frozen=True)
class Scene:
    """Everything the renderer needs: static quads, movers, textures, the light.

    Attributes
    ----------
    static : Quads
        Quads fixed in the world frame (object id `STATIC_OBJECT`).
    moving : tuple of MovingObject
        Objects whose pose changes per frame.
    atlas : TextureAtlas
        Textures indexed by ``Quads.material``.
    light : np.ndarray
        (3,) unit vector in the world frame pointing towards the sun, or (N, 3) one per
        frame.
    exposure : np.ndarray or None
        (N,) factor on all radiance (surfaces and sky) at each frame: the daylight level;
        None for 1 throughout.
    transient : Transient or None
        Static quads that exist for some frames only; None for none.
    view_index : QuadGrid or None
        The static quads binned for `quads_near`, with the view distance beyond which
        nothing is drawn; None to draw everything at every frame.
    """

    static: Quads
    moving: tuple[MovingObject, ...]
    atlas: TextureAtlas
    light: np.ndarray
    exposure: np.ndarray | None = None
    transient: Transient | None = None
    view_index: QuadGrid | None = None

    def quads_at(self, frame: int) -> Quads:
        """All quads in the world frame at ``frame``: the static ones, the transient ones
        that exist then, then each mover's."""
        present = [] if self.transient is None else [self.transient.at(frame)]
        movers = [obj.quads.transformed(obj.poses[frame]) for obj in self.moving]
        return Quads.concat([self.static, *present, *movers])

    def quads_near(self, frame: int, centre: np.ndarray) -> Quads:
        """The quads of `quads_at` that a camera at the world point ``centre`` (3,) draws:
        all of them without a `view_index`; else the static ones the index finds within
        its view distance (on the ground), the transient ones that exist then, and the
        movers whose bounding circle comes that close, in that order."""
        if self.view_index is None:
            return self.quads_at(frame)
        reach = self.view_index.view_distance
        ground = np.asarray(centre, dtype=np.float64)[[0, 2]]
        present = [] if self.transient is None else [self.transient.at(frame)]
        movers = [obj.quads.transformed(obj.poses[frame]) for obj in self.moving
                  if np.linalg.norm(obj.poses[frame][[0, 2], 3] - ground) <= reach + obj.radius()]
        return Quads.concat([self.static.select(self.view_index.near(centre)), *present, *movers])

    def moving_ids_at(self, frame: int) -> np.ndarray:
        """Object ids (M,) of the movers that move at ``frame`` (`MovingObject.moves_at`)."""
        return np.array([obj.object_id for obj in self.moving if obj.moves_at(frame)], dtype=np.int32)

    def light_at(self, frame: int) -> np.ndarray:
        """(3,) unit vector towards the sun at ``frame``."""
        return self.light if self.light.ndim == 1 else self.light[frame]

    def exposure_at(self, frame: int) -> float:
        """The factor on all radiance at ``frame``."""
        return 1.0 if self.exposure is None else float(self.exposure[frame])
