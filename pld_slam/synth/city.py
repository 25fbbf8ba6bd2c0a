"""The ``city`` scenario (issue 40): a drive as long as KITTI 00 through a grid of streets.

KITTI 00 is 4,541 frames (3.7 km) through a residential grid that passes many earlier
places again, some in the same direction and some in the opposite one: the sequence loop
closing is judged on. ``city`` is such a drive in the synthetic world.

- The grid (`GRID_NODES` crossings, `BLOCK` m apart both ways, `Grid`): every street
  between two neighbouring crossings is a segment, built once on a straight `Path` of its
  own with the street builders of `pld_slam.synth.scenarios` (`segment_street`): road,
  sidewalks and curbs between the crossings, and on both sides buildings, poles, crates
  and parked cars, each row from the segment's own random stream. The camera drives a
  street several times; its buildings are there once. Crossings stay open: the sidewalks
  and their curbs end where the crossing street's begin and each corner gets a square of
  sidewalk (`crossing_pavements`). A block's corner lots belong to its north-south
  streets; the buildings of an east-west street start `CORNER_LOT` m from the crossing,
  beyond the deepest corner building (`building_lots`). On the city's edge the outer rows
  of buildings run on past the crossings, so a street ending there looks at facades, not
  at the empty plain. Parked cars keep `NO_PARKING` m from the crossings, clear of the
  turning lanes.
- The route (`camera_route`): first once round a block and back past the start (a revisit
  in the same direction from frame 296 on), then round the block to the west and along
  the first block's south street the other way (a revisit in the opposite direction from
  frame 569 on, hence `scenarios.MIN_CITY_FRAMES` = 600), then a walk over the grid that
  takes the streets driven least so far (a seeded choice among equals) for as long as
  the request needs: it covers the grid, then drives it again, passing earlier places in
  both directions (seed 0, 4,541 frames: 5 runs of same-direction revisits and 3 of
  opposite ones, `revisit_pairs`). Vehicles keep to the right lane and turn in quarter
  circles of `TURN_RADIUS` inside the crossing (`lane_path`).
- The drive (`travel_times`): `CRUISE_SPEED` (10 m/s, 1 m per frame at 10 Hz, KITTI's
  speed), slowing to `TURN_SPEED` in the turns at `ACCELERATION`: 0.89 m per frame on
  average, 4.0 km in 4,541 frames (KITTI 00: 0.82 m, 3.7 km). The ride is the other
  street scenarios' (`scenarios.WOBBLE`), so the first frames do not depend on the seed.
- Traffic (`city_traffic`): cars on the camera's route around the time the camera is
  there: oncoming ones driving a stretch of it backwards in the other lane, and some going
  our way ahead of us, each arriving from and leaving into other streets. A car exists
  from where it cannot be seen (beyond the view distance, or behind the camera) until it
  cannot be seen again (`unseen`), and none comes near the camera or another car
  (`Trip.clear_of`), so a few are in view at a time and their number does not grow with
  the drive; the trips share a small pool of movers (`pooled_movers`).
- Render cost: a city has tens of thousands of quads; the scene draws only those within
  `VIEW_DISTANCE` of the camera (`pld_slam.synth.scene.QuadGrid`), so a frame costs about
  the same early and late in the drive.
"""

from collections import Counter
from dataclasses import dataclass

import numpy as np

from pld_slam.geometry.places import SAME_PLACE_DEG, same_place
from pld_slam.geometry.se3 import transform_points, viewpoint_change
from pld_slam.synth.scenarios import (
    CAMERA_HEIGHT,
    CAR_SIZE,
    CURB_HEIGHT,
    LANE,
    ROAD_LEFT,
    ROAD_RIGHT,
    SIDEWALK,
    STREET_ROWS,
    Palette,
    Path,
    building_row,
    camera_poses,
    crate_row,
    forward_of,
    ground_plane,
    make_scene,
    mover,
    parked_row,
    piecewise_path,
    pole_row,
    right_of,
    rng_for,
    street_ground,
    textured_palette,
)
from pld_slam.synth.scene import DOWN, UP, MovingObject, QuadGrid, Quads, Scene, box, floor, wall, yaw_pose

BLOCK = 70.0
"""Distance [m] between neighbouring crossings (street centrelines), both ways."""
GRID_NODES = (7, 7)
"""Crossings along x (east) and along z (north): 6 x 6 blocks, 420 m x 420 m."""
START_NODE = (3, 2)
"""The crossing the camera first drives towards (north): the route's first blocks, east
and west of the street it starts on, lie inside the city, not on its edge."""
START_BEFORE_NODE = 20.0
"""Distance [m] of the first camera position before `START_NODE`."""
TURN_RADIUS = 10.0
"""Radius [m] of a vehicle's lane in a turn: the right turn passes 1.7 m from the kerb's
corner."""
CRUISE_SPEED = 10.0
TURN_SPEED = 6.5
"""Speed [m/s] in a turn: 3.7 degrees of heading per frame (KITTI 00's turns: 3-5)."""
ACCELERATION = 3.0
"""Braking before and speeding up after a turn [m/s^2]."""
HALF_ROAD = 0.5 * (ROAD_RIGHT - ROAD_LEFT)
"""Half the road's width [m] (two lanes and two parking lanes)."""
HALF_STREET = HALF_ROAD + SIDEWALK
"""Distance [m] from a street's centreline to its building line."""
CORNER_LOT = 25.0
"""Distance [m] from a crossing where the buildings of an east-west street start: past
the deepest building of the crossing street (`HALF_STREET` + 1 m set back + 14 m)."""
NO_PARKING = 15.0
"""Distance [m] from a crossing within which nobody parks (the turning lanes)."""
VIEW_DISTANCE = 200.0
"""Nothing farther [m] from the camera is drawn (`pld_slam.synth.scene.QuadGrid`)."""
CAR_RADIUS = float(np.linalg.norm([0.5 * CAR_SIZE[0], CAR_SIZE[1], 0.5 * CAR_SIZE[2]]))
"""Distance [m] from a car's origin to its farthest corner (`MovingObject.radius`)."""
DEPOT = np.array([0.0, CAMERA_HEIGHT, -1.0e5])
"""Where a pooled car waits between trips: far beyond any view distance."""
ONCOMING_SHARE, FOLLOWING_SHARE = 0.7, 0.3
"""Chance per street of the camera's route of a car that meets us there, and of one that
drives ahead of us there."""
TRIP_AHEAD, TRIP_BEHIND, TRIP_BRANCH = 3, 2, 3
"""Streets of the camera's route a car shares ahead of and behind the one where it meets
us, and streets it drives before and after, elsewhere."""
CAMERA_CLEARANCE = (2.5, 8.0)
"""No car comes within this box (half width across, half length along [m]) of the camera."""
CAR_CLEARANCE = (2.2, 6.5)
"""No car comes within this box (half width, half length [m]) of another."""
OPPOSITE_PLACE_M = 5.0
"""Farthest [m] two cameras driving a street in opposite directions see the same place
from (`revisit_pairs`): the lanes' centres are `LANE` (3.5 m) apart, plus the sway."""

GridNode = tuple[int, int]


@dataclass(frozen=True)
class Grid:
    """The crossings of the city: ``nodes`` along x and z, `BLOCK` m apart, crossing
    ``(0, 0)`` at the world ground point ``origin`` (3,)."""

    nodes: tuple[int, int]
    origin: np.ndarray

    def point(self, node: GridNode) -> np.ndarray:
        """World ground point (3,) at the middle of crossing ``node``."""
        return self.origin + BLOCK * np.array([node[0], 0.0, node[1]])

    def contains(self, node: GridNode) -> bool:
        return 0 <= node[0] < self.nodes[0] and 0 <= node[1] < self.nodes[1]

    def segments(self) -> list[tuple[GridNode, GridNode]]:
        """Every street between two neighbouring crossings, from west to east or south to
        north: the east-west ones row by row, then the north-south ones column by column."""
        nx, nz = self.nodes
        along_x = [((i, j), (i + 1, j)) for j in range(nz) for i in range(nx - 1)]
        along_z = [((i, j), (i, j + 1)) for i in range(nx) for j in range(nz - 1)]
        return along_x + along_z


def city_grid() -> Grid:
    """The grid placed so that the first camera position, `START_BEFORE_NODE` m before
    `START_NODE` in the right lane heading north (+z), is the world origin."""
    i, j = START_NODE
    origin = np.array([-0.5 * LANE - i * BLOCK, CAMERA_HEIGHT, START_BEFORE_NODE - j * BLOCK])
    return Grid(GRID_NODES, origin)


# --- routes -------------------------------------------------------------------------------------


def turns_from(step: GridNode) -> tuple[GridNode, GridNode, GridNode]:
    """The grid steps that follow ``step`` without a U-turn: straight on, right, left."""
    di, dj = step
    return (di, dj), (dj, -di), (-dj, di)


def segment_key(a: GridNode, b: GridNode) -> tuple[GridNode, GridNode]:
    """The street between crossings ``a`` and ``b`` whichever way it is driven."""
    return (a, b) if a < b else (b, a)


def extend_walk(grid: Grid, nodes: list[GridNode], count: int, rng: np.random.Generator,
                visits: Counter | None = None) -> list[GridNode]:
    """``nodes`` (at least two) followed by ``count`` more crossings, each a neighbour of
    the one before inside the grid, without U-turns. With ``visits`` (times each street was
    driven, `segment_key`; updated) the walk takes a street driven least, else any; among
    equals ``rng`` chooses."""
    nodes = list(nodes)
    for _ in range(count):
        here, last = nodes[-1], nodes[-2]
        options = [(here[0] + di, here[1] + dj) for di, dj in turns_from((here[0] - last[0], here[1] - last[1]))]
        options = [node for node in options if grid.contains(node)]
        if visits is not None:
            fewest = min(visits[segment_key(here, node)] for node in options)
            options = [node for node in options if visits[segment_key(here, node)] == fewest]
        nodes.append(options[int(rng.integers(len(options)))])
        if visits is not None:
            visits[segment_key(here, nodes[-1])] += 1
    return nodes


def camera_route(grid: Grid, seed: int, distance: float) -> list[GridNode]:
    """The crossings the camera drives through, at least ``distance`` [m] of streets: from
    `START_NODE`'s southern neighbour clockwise round the block to its east and on past
    the start (the same way), left round the block to its west and east along the first
    block's south street (the other way), then `extend_walk` over the streets driven least
    (seeded by ``seed``)."""
    i, j = START_NODE
    nodes = [(i, j - 1), (i, j), (i + 1, j), (i + 1, j - 1), (i, j - 1), (i, j),
             (i - 1, j), (i - 1, j - 1), (i, j - 1), (i + 1, j - 1)]
    visits = Counter(segment_key(a, b) for a, b in zip(nodes[:-1], nodes[1:]))
    more = max(0, int(np.ceil(distance / (BLOCK - 2.0 * TURN_RADIUS))) - len(nodes) + 1)
    return extend_walk(grid, nodes, more, rng_for(seed, 60), visits)


def lane_path(grid: Grid, nodes: list[GridNode], start: float = 0.0) -> tuple[Path, np.ndarray]:
    """The right lane (`LANE` / 2 right of the centreline) of a vehicle driving through the
    crossings ``nodes`` (K,), from the middle of the first to the middle of the last,
    turning in quarter circles of `TURN_RADIUS` (a right turn begins `TURN_RADIUS` +
    `LANE` / 2 before the crossing, a left one `TURN_RADIUS` - `LANE` / 2), with ``s = 0``
    at ``start`` [m] along the first street. Also the arc length (K - 1,) [m] of the middle
    of each street's straight part."""
    steps = np.diff(np.asarray(nodes, dtype=np.int64), axis=0)
    side = steps[:-1, 1] * steps[1:, 0] - steps[:-1, 0] * steps[1:, 1]  # +1 right, -1 left, 0 straight on
    trim = np.select([side > 0, side < 0], [TURN_RADIUS + 0.5 * LANE, TURN_RADIUS - 0.5 * LANE], 0.0)
    straight = BLOCK - np.concatenate([[0.0], trim]) - np.concatenate([trim, [0.0]])
    quarter = 0.5 * np.pi * TURN_RADIUS
    pieces = []
    for k, length in enumerate(straight):
        if k > 0 and side[k - 1] != 0:
            pieces.append((quarter, side[k - 1] / TURN_RADIUS))
        pieces.append((float(length), 0.0))
    begins = np.cumsum(straight) - straight + quarter * np.cumsum(np.concatenate([[0], side != 0]))
    middles = begins + 0.5 * straight - start
    if start > 0.0:
        pieces = [(start, 0.0), (pieces[0][0] - start, 0.0), *pieces[1:]]
    heading = float(np.arctan2(steps[0, 0], steps[0, 1]))
    origin = grid.point(nodes[0]) + start * forward_of(heading)[0] + 0.5 * LANE * right_of(heading)[0]
    return placed(piecewise_path(pieces, start_piece=int(start > 0.0)), origin, heading), middles


def placed(path: Path, origin: np.ndarray, heading: float) -> Path:
    """``path`` (``s = 0`` at the world origin, heading along z) moved so that ``s = 0`` is
    at the ground point ``origin`` (3,) heading ``heading`` [rad]."""
    moved = transform_points(yaw_pose(origin, heading), path.position - CAMERA_HEIGHT * DOWN)
    return Path(s=path.s, heading=path.heading + heading, curvature=path.curvature, position=moved)


def travel_times(path: Path, cruise: float) -> np.ndarray:
    """Time [s] (K,) at which a vehicle driving ``path`` reaches each sample (0 at the
    first): at ``cruise`` [m/s], slowing to `TURN_SPEED` in turns at `ACCELERATION`."""
    turning = path.s[path.curvature != 0.0]
    if len(turning) == 0:
        speed = np.full(len(path.s), cruise)
    else:
        after = np.clip(np.searchsorted(turning, path.s), 0, len(turning) - 1)
        before = np.clip(after - 1, 0, len(turning) - 1)
        gap = np.minimum(np.abs(path.s - turning[after]), np.abs(path.s - turning[before]))
        speed = np.minimum(cruise, np.sqrt(TURN_SPEED**2 + 2.0 * ACCELERATION * gap))
    return np.concatenate([[0.0], np.cumsum(np.diff(path.s) * 0.5 * (1.0 / speed[:-1] + 1.0 / speed[1:]))])


def arc_lengths_at(path: Path, clock: np.ndarray, times: np.ndarray) -> np.ndarray:
    """Arc lengths (N,) [m] on ``path`` at ``times`` (N,) [s] of a vehicle reaching its
    samples at ``clock`` (K,) [s] (`travel_times` plus an offset), clamped to the path."""
    return np.interp(times, clock, path.s)


# --- the static world -----------------------------------------------------------------------------


def building_lots(grid: Grid, a: GridNode, b: GridNode, side: int) -> tuple[float, float]:
    """Where [m along the street from ``a``] the buildings on side ``side`` (+1 right, -1
    left, looking from ``a`` to ``b``) of the street between crossings ``a`` and ``b``
    begin and end: at each crossing that a street leaves on that side, past the corner lot
    (`CORNER_LOT` along an east-west street, `HALF_STREET` along a north-south one, whose
    buildings take the corner); at one on the city's edge, from the crossing's middle on,
    so that the row runs on past the end of the street that meets it there."""
    out = (side * (b[1] - a[1]), side * (a[0] - b[0]))
    lot = CORNER_LOT if b[0] != a[0] else HALF_STREET
    begin, end = (lot if grid.contains((node[0] + out[0], node[1] + out[1])) else 0.0 for node in (a, b))
    return begin, BLOCK - end


def segment_street(grid: Grid, a: GridNode, b: GridNode, index: int, seed: int, palette: Palette) -> list[Quads]:
    """Static quads of street ``index`` (of `Grid.segments`) between crossings ``a`` and
    ``b``: `street_ground` between the crossing streets' building lines, and each of
    `STREET_ROWS` on both sides (buildings on their lots, `building_lots`; poles and crates
    along the sidewalks; parked cars `NO_PARKING` m clear of the crossings), row k on side
    ``side`` from the stream ``rng_for(seed, 61, index, k, side + 1)``."""
    path, _ = lane_path(grid, [a, b])
    clear = {pole_row: HALF_STREET, parked_row: NO_PARKING, crate_row: HALF_STREET}
    parts = street_ground(path, HALF_STREET, BLOCK - HALF_STREET, palette)
    for k, make_row in enumerate(STREET_ROWS):
        for side in (1, -1):
            begin, end = (building_lots(grid, a, b, side) if make_row is building_row
                          else (clear[make_row], BLOCK - clear[make_row]))
            parts += make_row(path, begin, end, side, rng_for(seed, 61, index, k, side + 1), palette)
    return parts


def crossing_pavements(grid: Grid, palette: Palette) -> Quads:
    """The sidewalks of every crossing, with curbs on their road sides: a square at each
    corner, where the sidewalks of the two streets meet, and one across the mouth of each
    street that would leave the crossing beyond the city's edge."""
    squares, curbs, curb_normals, mouths, mouth_directions = [], [], [], [], []
    near, middle = HALF_ROAD, HALF_ROAD + 0.5 * SIDEWALK
    for i in range(grid.nodes[0]):
        for j in range(grid.nodes[1]):
            centre = grid.point((i, j))
            for sx, sz in ((-1.0, -1.0), (-1.0, 1.0), (1.0, -1.0), (1.0, 1.0)):
                squares.append(centre + np.array([sx * middle, 0.0, sz * middle]))
                curbs += [centre + np.array([sx * near, 0.0, sz * middle]),
                          centre + np.array([sx * middle, 0.0, sz * near])]
                curb_normals += [[-sx, 0.0, 0.0], [0.0, 0.0, -sz]]
            for di, dj in ((1, 0), (0, 1), (-1, 0), (0, -1)):
                if not grid.contains((i + di, j + dj)):
                    mouths.append(centre)
                    mouth_directions.append([float(di), 0.0, float(dj)])
    mouths, mouth_directions = np.array(mouths), np.array(mouth_directions)
    lift = CURB_HEIGHT * UP
    return Quads.concat([
        floor(np.array(squares) + lift, np.array([0.0, 0.0, 1.0]), SIDEWALK, SIDEWALK, palette.sidewalk),
        wall(np.array(curbs), np.array(curb_normals), SIDEWALK, CURB_HEIGHT, palette.curb),
        floor(mouths + middle * mouth_directions + lift, mouth_directions, 2.0 * near, SIDEWALK, palette.sidewalk),
        wall(mouths + near * mouth_directions, -mouth_directions, 2.0 * near, CURB_HEIGHT, palette.curb),
    ])


def city_static(grid: Grid, seed: int, palette: Palette) -> Quads:
    """Every static quad of the city: the ground plane, every street (`segment_street`)
    and the sidewalks of every crossing (`crossing_pavements`)."""
    corners = np.array([grid.point((0, 0)), grid.point((grid.nodes[0] - 1, grid.nodes[1] - 1))])
    parts = [ground_plane(corners, palette)]
    for index, (a, b) in enumerate(grid.segments()):
        parts += segment_street(grid, a, b, index, seed, palette)
    parts.append(crossing_pavements(grid, palette))
    return Quads.concat(parts)


# --- traffic ------------------------------------------------------------------------------------


def upright_poses(points: np.ndarray, headings: np.ndarray) -> np.ndarray:
    """``T_w_o`` (n, 4, 4) of upright objects at ground ``points`` (n, 3) turned by
    ``headings`` (n,) [rad] about the down axis (`yaw_pose` for many at once)."""
    cos, sin = np.cos(headings), np.sin(headings)
    poses = np.zeros((len(points), 4, 4))
    poses[:, 0, 0], poses[:, 0, 2], poses[:, 2, 0], poses[:, 2, 2] = cos, sin, -sin, cos
    poses[:, 1, 1] = poses[:, 3, 3] = 1.0
    poses[:, :3, 3] = points
    return poses


def relative_positions(T_w_a: np.ndarray, T_w_b: np.ndarray) -> np.ndarray:
    """Positions (n, 3) of the origins of poses ``T_w_b`` (n, 4, 4) in frames ``T_w_a`` (n, 4, 4)."""
    return np.einsum("nji,nj->ni", T_w_a[:, :3, :3], T_w_b[:, :3, 3] - T_w_a[:, :3, 3])


def within(offsets: np.ndarray, half_box: tuple[float, float]) -> bool:
    """Whether any of ``offsets`` (n, 3) lies inside the box of half width ``half_box[0]``
    (x) and half length ``half_box[1]`` (z) [m]."""
    return bool(((np.abs(offsets[:, 0]) < half_box[0]) & (np.abs(offsets[:, 2]) < half_box[1])).any())


@dataclass(frozen=True)
class Trip:
    """A car's poses ``poses`` (n, 4, 4) at frames ``first .. first + n - 1``."""

    first: int
    poses: np.ndarray

    @property
    def end(self) -> int:
        return self.first + len(self.poses)

    def clear_of(self, camera: np.ndarray, others: list["Trip"]) -> bool:
        """Whether the car keeps `CAMERA_CLEARANCE` from the camera at ``camera`` (N, 4, 4)
        and `CAR_CLEARANCE` from the cars of ``others`` at the frames they share."""
        if within(relative_positions(camera[self.first:self.end], self.poses), CAMERA_CLEARANCE):
            return False
        for other in others:
            first, end = max(self.first, other.first), min(self.end, other.end)
            if first < end and within(relative_positions(self.poses[first - self.first:end - self.first],
                                                         other.poses[first - other.first:end - other.first]),
                                      CAR_CLEARANCE):
                return False
        return True


def unseen(points: np.ndarray, camera: np.ndarray) -> np.ndarray:
    """(N,) bool: whether a car at the ground ``points`` (N, 3) is out of both images of the
    cameras ``camera`` (N, 4, 4) (left camera poses), whatever the camera model: not drawn
    (farther than `VIEW_DISTANCE` plus `CAR_RADIUS`, see `Scene.quads_near`) or wholly behind
    the cameras (both have the left camera's image plane)."""
    offset = points - camera[:, :3, 3]
    far = np.linalg.norm(offset[:, [0, 2]], axis=1) > VIEW_DISTANCE + CAR_RADIUS
    return far | (np.einsum("ni,ni->n", offset, camera[:, :3, 2]) < -CAR_RADIUS)


def trip_in_view(path: Path, clock: np.ndarray, camera: np.ndarray, times: np.ndarray, meeting: int) -> Trip | None:
    """The frames around frame ``meeting`` at which a car driving ``path`` on ``clock``
    (K,) [s] may be seen from the cameras ``camera`` (N, 4, 4) at ``times`` (N,) [s], from
    the frame before to the frame after (where it is `unseen`, so it may appear and vanish
    there); None if it cannot be seen at the meeting, or if it could be where its path
    begins or ends within the drive."""
    on_path = (times >= clock[0]) & (times <= clock[-1])
    s = arc_lengths_at(path, clock, times)
    points = path.ground_point(s, 0.0)
    seen = on_path & ~unseen(points, camera)
    if not seen[meeting]:
        return None
    hidden = np.flatnonzero(~seen)
    before, after = hidden[hidden < meeting], hidden[hidden > meeting]
    first = int(before[-1]) if len(before) else 0
    end = int(after[0]) + 1 if len(after) else len(times)
    if not on_path[first:end].all():
        return None
    return Trip(first, upright_poses(points[first:end], path.heading_at(s[first:end])))


def car_trip(grid: Grid, nodes: list[GridNode], segment: int, meet_time: float, cruise: float,
             camera: np.ndarray, times: np.ndarray) -> Trip | None:
    """The trip of a car through crossings ``nodes`` at ``cruise`` [m/s] that is at the
    middle of its street ``segment`` at ``meet_time`` [s] (`trip_in_view`)."""
    path, middles = lane_path(grid, nodes)
    clock = travel_times(path, cruise)
    clock = clock + meet_time - np.interp(middles[segment], path.s, clock)
    meeting = int(np.clip(np.searchsorted(times, meet_time), 0, len(times) - 1))
    return trip_in_view(path, clock, camera, times, meeting)


def oncoming_nodes(grid: Grid, route: list[GridNode], m: int, rng: np.random.Generator) -> tuple[list, int]:
    """Crossings of a car that drives the camera's ``route`` backwards from `TRIP_AHEAD`
    streets past street ``m`` to `TRIP_BEHIND` before it, coming from and going on to
    `TRIP_BRANCH` random streets; and the index of street ``m`` (driven backwards) in it."""
    high, low = min(m + 1 + TRIP_AHEAD, len(route) - 1), max(m - TRIP_BEHIND, 0)
    shared = route[low:high + 1]
    coming = extend_walk(grid, shared, TRIP_BRANCH, rng)[::-1]
    return extend_walk(grid, coming, TRIP_BRANCH, rng), TRIP_BRANCH + high - (m + 1)


def following_nodes(grid: Grid, route: list[GridNode], m: int, rng: np.random.Generator) -> tuple[list, int]:
    """Crossings of a car that drives the camera's ``route`` from street ``m`` on for
    `TRIP_AHEAD` more, coming from and going on to `TRIP_BRANCH` random streets; and the
    index of street ``m`` in it."""
    shared = route[m:min(m + 2 + TRIP_AHEAD, len(route))]
    coming = extend_walk(grid, shared[::-1], TRIP_BRANCH, rng)[::-1]
    return extend_walk(grid, coming, TRIP_BRANCH, rng), TRIP_BRANCH


def city_traffic(grid: Grid, route: list[GridNode], middles: np.ndarray, camera: np.ndarray,
                 camera_s: np.ndarray, times: np.ndarray, seed: int, palette: Palette) -> tuple[MovingObject, ...]:
    """The cars of ``city``: for each street of the camera's ``route`` whose middle (arc
    length ``middles``, (K - 1,) [m]) the camera passes during the drive (arc lengths
    ``camera_s`` (N,) at ``times`` (N,) [s], poses ``camera`` (N, 4, 4)), with chance
    `ONCOMING_SHARE` a car meeting us there in the other lane at 8.5-11 m/s
    (`oncoming_nodes`) and with chance `FOLLOWING_SHARE` one 3-6 s ahead of us in our lane
    at 10-12 m/s, never slower than us (`following_nodes`). A trip that would come close
    to the camera or to another car, or that cannot appear and vanish out of view (beyond
    the view distance or behind the camera), is dropped (`Trip.clear_of`, `trip_in_view`).
    The trips share a pool of movers, each waiting at `DEPOT` between its trips
    (`pooled_movers`)."""
    rng = rng_for(seed, 62)
    passed = np.interp(middles, camera_s, times, left=np.nan, right=np.nan)
    trips: list[Trip] = []
    for m in np.flatnonzero(np.isfinite(passed)):
        for share, make_nodes, cruise, lead in ((ONCOMING_SHARE, oncoming_nodes, (8.5, 11.0), (0.0, 0.0)),
                                                (FOLLOWING_SHARE, following_nodes, (10.0, 12.0), (3.0, 6.0))):
            if rng.random() >= share:
                continue
            nodes, segment = make_nodes(grid, route, int(m), rng)
            trip = car_trip(grid, nodes, segment, float(passed[m]) - rng.uniform(*lead), rng.uniform(*cruise),
                            camera, times)
            if trip is not None and trip.clear_of(camera, trips):
                trips.append(trip)
    return pooled_movers(trips, len(times), rng, palette)


def pooled_movers(trips: list[Trip], frames: int, rng: np.random.Generator,
                  palette: Palette) -> tuple[MovingObject, ...]:
    """Movers (cars of paint drawn from ``rng``) that drive ``trips`` over ``frames``
    frames: each trip goes to the first mover free by its first frame (a new one if none
    is), which waits at `DEPOT` when it has no trip."""
    poses: list[np.ndarray] = []
    free_from: list[int] = []
    for trip in sorted(trips, key=lambda trip: trip.first):
        slot = next((k for k, end in enumerate(free_from) if end <= trip.first), len(poses))
        if slot == len(poses):
            poses.append(np.broadcast_to(yaw_pose(DEPOT, 0.0), (frames, 4, 4)).copy())
            free_from.append(0)
        poses[slot][trip.first:trip.end] = trip.poses
        free_from[slot] = trip.end
    return tuple(mover(k + 1, box(*CAR_SIZE, palette.car, float(rng.uniform(0.3, 1.1))), slot_poses)
                 for k, slot_poses in enumerate(poses))


# --- the scenario ---------------------------------------------------------------------------------


def city_world(times: np.ndarray, seed: int) -> tuple[np.ndarray, Scene]:
    """Camera poses (N, 4, 4) and scene of ``city`` at frame ``times`` (N,) [s] from ``seed``."""
    grid = city_grid()
    route = camera_route(grid, seed, CRUISE_SPEED * float(times[-1] - times[0]) + BLOCK)
    path, middles = lane_path(grid, route, BLOCK - START_BEFORE_NODE)
    clock = travel_times(path, CRUISE_SPEED)
    s = arc_lengths_at(path, clock, times - times[0] + np.interp(0.0, path.s, clock))
    poses = camera_poses(path, s, period=120.0)
    palette = textured_palette(seed)
    static = city_static(grid, seed, palette)
    movers = city_traffic(grid, route, middles, poses, s, times, seed, palette)
    return poses, make_scene(static, palette, moving=movers, view_index=QuadGrid.build(static, VIEW_DISTANCE))


def revisit_pairs(poses: np.ndarray, min_gap: int, opposite: bool) -> np.ndarray:
    """Pairs (R, 2) ``(earlier, later)`` of camera poses ``poses`` (N, 4, 4) at least
    ``min_gap`` frames apart that see the same place: as the loop truth defines it
    (`pld_slam.geometry.places.same_place`: within 3 m, optical axes within 30 degrees),
    or if ``opposite`` from the other direction (within `OPPOSITE_PLACE_M`, axes within 30
    degrees of opposite). One pair per later frame that revisits: its nearest such
    earlier frame."""
    pairs = []
    for later in range(min_gap, len(poses)):
        earlier = poses[:later - min_gap + 1]
        distance, angle = viewpoint_change(earlier, poses[later])
        if opposite:
            alike = (distance <= OPPOSITE_PLACE_M) & (angle >= 180.0 - SAME_PLACE_DEG)
        else:
            alike = same_place(earlier, poses[later])
        if alike.any():
            pairs.append((int(np.flatnonzero(alike)[np.argmin(distance[alike])]), later))
    return np.array(pairs, dtype=np.int64).reshape(-1, 2)
