"""The eleven synthetic scenarios: a camera path, the street built along it, and its movers.

- ``static``: a street with gentle curves: buildings on both sides, parked cars, poles,
  crates; the camera drives in the right lane at 8 m/s (0.8 m per frame at 10 Hz) with a
  slight 6-DoF wobble (steering, pitch and roll bob, height bob, lateral sway).
- ``dynamic``: the same street (same seed, same scene) plus traffic: a truck 4-6 m ahead in
  our lane, oncoming cars, pedestrians on both sidewalks and cyclists crossing the street.
- ``loop``: a block of 96 m x 72 m (rectangle with 18 m corner radius) driven once
  clockwise, buildings inside the block and outside the road; frame i sits at arc length
  ``L * (i / (N - 1) mod 1)`` so the last pose is the first one, bit for bit.
- ``lowtexture``: the street's path with plain walls of uniform panels, pillars, door frames
  and a uniform road: edges are nearly the only structure.
- ``loop2``: ``loop``'s block driven twice (default 720 frames, 0.85 m apart as in
  ``loop``'s default; at least 600, 1 m apart); frame i sits at arc length
  ``L * (2 i / (N - 1) mod 1)``, so the last pose is the first one and frame ``i + N/2``
  is frame i half a frame (0.42 m at 720 frames) further on. The first lap is ``loop``'s
  world; on the second a loop detector must see the same place through two changes:

  * other parked cars: each slot's car is drawn again from another random stream (other
    slots taken, paint, place in the slot, direction). The cars are `Transient` static
    quads that exist for a span of frames, not movers, because they never move while
    they exist and the dynamic masks mark moving objects only. A slot's cars swap when
    the camera is 8 m past it on the first lap, behind it, so no car pops in or out in
    view (the tracker sees an ordinary static world); ahead of it the first lap sees the
    old cars, the second lap only new ones.
  * another light: `SECOND_SUN` (lower, from the other side, so the walls lit on the
    first lap are in the shade) and `SECOND_EXPOSURE` (0.7: all radiance, sky included,
    30 % darker) instead of `SUN` and 1. They blend smoothly over the last 30 m of the
    first lap, as light changes over time: an exposure jump between two frames would
    test the tracker rather than the loop closing. The renderer takes the light and
    exposure per frame (`Scene.light_at`, `Scene.exposure_at`).

  The ground truth is exact as in ``loop``; only what the camera sees changes.
- ``nearmiss``: a hard negative for loop detection: out along a straight street, round the
  block (two right turns of 18 m joined by 4 m) halfway through the drive, and back along
  the parallel street 40 m to the right until level with the start (default 300 frames at
  0.8 m, at least 150). No two frames more than 30 apart with headings within 90 degrees
  are within 22 m of each other, and the way back faces other facades (those of the
  return street, drawn further along the same random streams: alike, never the same), so
  a loop detector must accept nothing here. The 40 m between the lane centres leave
  26 m between the facades of the two rows of buildings inside the block, for buildings
  8-14 m deep.
- ``convoy``, ``crossing``, ``parked_then_moving``: the street of ``static`` with movers a
  robust solve follows (the dynamic-scenes issue): a bus alongside and a truck and a car
  ahead driving at our varying speed (`convoy_traffic`, 27-39 % of the image); the camera
  stopping at a junction every 19 s while a crowd of 60 crosses, most of it one way
  (`crossing_crowd`, 20-30 %); cars parked long enough to enter the map that pull out
  when we are 20 m behind (`parked_movers`). The masks mark an object at the frames it
  moves (`pld_slam.synth.scene.MovingObject.moves_at`): a parked car or a waiting
  pedestrian is part of the static scene until it sets off.
- ``highway``: a motorway with long gentle curves (radius never under 800 m) driven in the
  middle of three lanes at 20-25 m/s (2.0-2.5 m per frame at 10 Hz, the speed a sine of
  18-30 s), default 100 frames: a grass median with lamp posts and guard rails, sign
  gantries, noise barriers and sparse trees a few to tens of metres off the road,
  buildings and wooded hills 50-300 m away, open sky; cars and trucks overtake us in the
  lane to our left and oncoming traffic drives beyond the median (`HIGHWAY_FLOWS`). For
  the stereo scale error: most structure is far, as on a KITTI drive out of town, and
  what is near (carriageway, verges, rails) has texture without a period the tracker
  could mistake a 2.2 m step for (`RAIL_POST_SPACING`, `HIGHWAY_ROAD_TILE`). Made for the
  ``kitti`` camera (seeds 0-5, 100 frames: no tracking failure, Sim(3) scale
  0.9971-1.0002, estimated over true path length 0.9974-0.9997); at the default
  640 x 480 there are about a quarter fewer stereo points and the dynamic detectors
  flag static ones (seed 0: one tracking failure, scale 0.967; with the true masks
  0.998).
- ``city`` (issue 40, `pld_slam.synth.city`): a drive like KITTI 00's, on which loop
  closing is judged: as long (default 4,541 frames; 4.0 km at 10 m/s, slowing in the
  turns) through a grid of streets of 70 m blocks that passes earlier places both the
  same way and the other way. Unlike the others the world is not built along the path:
  each street of the grid is built once (by this module's builders, on a straight path of
  its own) and the camera drives the streets several times, turning inside the crossings;
  first round a block and past the start, then along a street the other way (so the
  fewest frames, 600, hold one revisit of each kind), then a walk over the grid. Oncoming
  cars and cars going our way drive the streets around the camera's route; only quads
  within 200 m of the camera are drawn (`pld_slam.synth.scene.QuadGrid`), so a frame
  costs the same early and late in the drive.

Conventions (see `pld_slam.synth.scene`): the world is the first left camera (x right,
y down, z forward), the ground is the plane ``y = CAMERA_HEIGHT``. Positions along a path
are ``(s, l)``: arc length ``s`` [m] and lateral offset ``l`` [m], positive to the right,
``l = 0`` on the camera's lane centre.

Chosen here (the issue leaves them open): fx = fy = 0.6 * width (80 degrees horizontal
field of view, close to KITTI's), cx = width / 2, cy = height / 2 with pixel centres at
integer coordinates, baseline 0.5 m, camera 1.6 m above the road, 10 Hz: the ``default``
camera (`CAMERAS`), 640 x 480 unless a size is given. The ``kitti`` camera is KITTI
odometry 00-02's rectified grey pair instead (`KITTI_CAMERA`: 1241 x 376, fx = fy =
718.856, baseline 0.537 m; 81 x 29 degrees, so as wide as the default and narrower
vertically: the streets' facades are cut at 2-4 storeys, as in KITTI's images). Its size
is fixed: a size other than its own is refused rather than silently ignored or scaled.
The camera changes only the images: a scenario and seed give the same scene and poses
with either. The movers' shares of the image quoted above are the default camera's;
KITTI's narrower view, centred on the traffic, roughly doubles them (frame 20, seed 0:
``dynamic`` 12 -> 25 %, ``convoy`` 38 -> 63 %).
"""

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np

from pld_slam.errors import PldSlamError
from pld_slam.geometry.camera import StereoCamera
from pld_slam.geometry.se3 import make_pose, so3_exp
from pld_slam.synth import textures as tx
from pld_slam.synth.render import SynthFrame, View, render_stereo_frame, render_stereo_views
from pld_slam.synth.scene import (
    DOWN,
    UP,
    BoxMaterials,
    FacadeMaterials,
    MovingObject,
    Quads,
    Scene,
    Transient,
    box,
    building,
    floor,
    gantry,
    plain_building,
    pole,
    tree,
    wall,
    yaw_pose,
)

SCENARIOS = ("static", "dynamic", "loop", "lowtexture", "loop2", "nearmiss", "convoy", "crossing",
             "parked_then_moving", "highway", "city")
"""Names accepted by `build_scenario`."""
DEFAULT_FRAMES = {"static": 100, "dynamic": 100, "loop": 360, "lowtexture": 100, "loop2": 720, "nearmiss": 300,
                  "convoy": 150, "crossing": 180, "parked_then_moving": 150, "highway": 100, "city": 4541}
MIN_LOOP_FRAMES = 300
MIN_CITY_FRAMES = 600
MIN_FRAMES = {
    # name: (fewest frames, what they are needed for): about 1 m per frame at most.
    "loop": (MIN_LOOP_FRAMES, "to drive around the block"),
    "loop2": (2 * MIN_LOOP_FRAMES, "to drive around the block twice"),
    "nearmiss": (150, "to drive out, round the block and back"),
    "city": (MIN_CITY_FRAMES, "to pass an earlier place the same way and one the other way"),
}

CAMERA_HEIGHT = 1.6
"""Height [m] of the cameras above the road; also the world y of the ground."""
BASELINE = 0.5
FOCAL_PER_WIDTH = 0.6
DEFAULT_SIZE = (640, 480)
"""Image size [px] of the ``default`` camera unless one is given."""
CAMERAS = ("default", "kitti")
"""Camera models accepted by `build_scenario`."""
KITTI_CAMERA = StereoCamera(fx=718.856, fy=718.856, cx=607.1928, cy=185.2157, baseline=386.1448 / 718.856,
                            width=1241, height=376)
"""KITTI odometry 00-02's rectified grey cameras: ``P0`` and ``P1`` of their ``calib.txt``
(``P1[0, 3] = -386.1448``, a 0.537 m baseline), 1241 x 376 images: 81 x 29 degrees."""
FRAME_RATE = 10.0
STREET_STEP = 0.8
"""Distance [m] driven per frame on the open street (8 m/s)."""
VIEW_AHEAD = 130.0
"""Street [m] built beyond the last camera position (what it can still see)."""
SUN = np.array([-0.45, -0.8, 0.4]) / np.linalg.norm([-0.45, -0.8, 0.4])
"""Direction towards the sun (world frame): up, to the left of and ahead of the start."""
SECOND_SUN = np.array([0.6, -0.5, -0.45]) / np.linalg.norm([0.6, -0.5, -0.45])
"""The sun on ``loop2``'s second lap: lower (34 instead of 53 degrees up), from the right
and behind: the walls lit on the first lap are in the shade."""
SECOND_EXPOSURE = 0.7
"""Exposure (factor on all radiance, sky included) on ``loop2``'s second lap."""
LIGHT_RAMP = 30.0
"""Distance [m] over which the light changes, at the end of ``loop2``'s first lap."""
PARKING_SWAP_MARGIN = 8.0
"""On ``loop2``, a parking slot's car changes once the camera is this far [m] past it on
the first lap (out of sight behind it)."""
SECOND_PARKING_TAG = 20
"""Random stream tag of the parked cars of ``loop2``'s second lap."""

# The street cross-section, as lateral offsets l [m].
LANE = 3.5
PARKING = 2.4
SIDEWALK = 3.0
CURB_HEIGHT = 0.15
ROAD_LEFT = -1.5 * LANE - PARKING
ROAD_RIGHT = 0.5 * LANE + PARKING
ONCOMING_LANE = -LANE
STRIP_MAX = 6.0
"""Longest ground strip [m]; shorter on curves so strips of a band stay within 15 cm."""

# Loop block: straights of LOOP_A and LOOP_B metres joined by quarter circles.
LOOP_A, LOOP_B, LOOP_RADIUS = 60.0, 36.0, 18.0
PATH_STEP = 0.25
NEARMISS_LINK = 4.0
"""Straight [m] between the two corners of ``nearmiss``'s turn: the way back runs
``2 * LOOP_RADIUS + NEARMISS_LINK`` = 40 m beside the way out."""
PATH_BEHIND = 30.0
"""Path [m] before the first camera position on the open streets."""


def rng_for(seed: int, *tags: int) -> np.random.Generator:
    """An independent random stream per purpose, so adding draws to one leaves the others."""
    return np.random.default_rng([seed, *tags])


# --- the path ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class Path:
    """A curve on the ground, sampled densely: the lane the camera drives along.

    Attributes
    ----------
    s : np.ndarray
        (K,) arc length [m], increasing; ``s = 0`` is the first camera's position.
    heading : np.ndarray
        (K,) yaw [rad] about the down axis (positive = turned right); 0 at ``s = 0``.
    curvature : np.ndarray
        (K,) ``d heading / d s`` [1/m] of the step starting at each sample.
    position : np.ndarray
        (K, 3) ground point in the world frame, ``(0, CAMERA_HEIGHT, 0)`` at ``s = 0``.
    """

    s: np.ndarray
    heading: np.ndarray
    curvature: np.ndarray
    position: np.ndarray

    @classmethod
    def integrate(cls, steps: np.ndarray, curvature: np.ndarray, origin: int) -> "Path":
        """The path of arc ``steps`` (K-1,) [m] of constant ``curvature`` (K-1,) [1/m], placed
        so that sample ``origin`` lies on the ground right under the world origin, heading
        along z. Each step is integrated exactly (a circular arc)."""
        turn = curvature * steps
        heading = np.concatenate([[0.0], np.cumsum(turn)])
        chord = steps * np.sinc(turn / (2.0 * np.pi))
        middle = heading[:-1] + 0.5 * turn
        xz = np.concatenate([[[0.0, 0.0]], np.cumsum(np.column_stack(
            [chord * np.sin(middle), chord * np.cos(middle)]), axis=0)])
        heading0 = heading[origin]
        xz = xz - xz[origin]
        cos0, sin0 = np.cos(heading0), np.sin(heading0)
        x = cos0 * xz[:, 0] - sin0 * xz[:, 1]
        z = sin0 * xz[:, 0] + cos0 * xz[:, 1]
        s = np.concatenate([[0.0], np.cumsum(steps)])
        return cls(
            s=s - s[origin],
            heading=heading - heading0,
            curvature=np.append(curvature, curvature[-1]),
            position=np.column_stack([x, np.full_like(x, CAMERA_HEIGHT), z]),
        )

    @property
    def length(self) -> float:
        """Arc length [m] from the first to the last sample."""
        return float(self.s[-1] - self.s[0])

    def heading_at(self, s) -> np.ndarray:
        """Heading [rad] at arc lengths ``s`` (scalar or (n,))."""
        return np.interp(s, self.s, self.heading)

    def curvature_at(self, s) -> np.ndarray:
        """Curvature [1/m] at arc lengths ``s`` (scalar or (n,))."""
        return self.curvature[np.clip(np.searchsorted(self.s, s, side="right") - 1, 0, len(self.s) - 1)]

    def ground_point(self, s, lateral) -> np.ndarray:
        """World points (n, 3) on the ground at ``(s, l)`` (scalars or (n,))."""
        s = np.atleast_1d(np.asarray(s, dtype=np.float64))
        centre = np.column_stack([np.interp(s, self.s, self.position[:, k]) for k in range(3)])
        return centre + np.asarray(lateral)[..., None] * right_of(self.heading_at(s))

    def pose(self, s: float, lateral: float, yaw: float = 0.0) -> np.ndarray:
        """``T_w_o`` (4, 4) of an upright object on the ground at ``(s, l)``, turned by
        ``yaw`` [rad] from the path's heading."""
        return yaw_pose(self.ground_point(s, lateral)[0], float(self.heading_at(s)) + yaw)


def right_of(heading) -> np.ndarray:
    """Horizontal unit vectors (n, 3) to the right of headings (n,) [rad]."""
    heading = np.atleast_1d(heading)
    return np.column_stack([np.cos(heading), np.zeros_like(heading), -np.sin(heading)])


def forward_of(heading) -> np.ndarray:
    """Horizontal unit vectors (n, 3) along headings (n,) [rad]."""
    heading = np.atleast_1d(heading)
    return np.column_stack([np.sin(heading), np.zeros_like(heading), np.cos(heading)])


def street_path(seed: int, s_start: float, s_end: float) -> Path:
    """A street with gentle curves from ``s_start`` to ``s_end`` [m]: wavelengths 140-320 m,
    radius never under 100 m, heading swings of roughly 10 degrees."""
    return winding_path(rng_for(seed, 1), s_start, s_end, (140.0, 320.0), (1.0 / 400.0, 1.0 / 200.0))


def highway_path(seed: int, s_start: float, s_end: float) -> Path:
    """A highway with gentle curves from ``s_start`` to ``s_end`` [m]: wavelengths 0.9-2 km,
    radius never under 800 m (0.6 m/s^2 sideways at 22 m/s), heading swings of up to 11
    degrees."""
    return winding_path(rng_for(seed, 30), s_start, s_end, (900.0, 2000.0), (1.0 / 3200.0, 1.0 / 1600.0))


def winding_path(rng: np.random.Generator, s_start: float, s_end: float, wavelengths: tuple[float, float],
                 curvatures: tuple[float, float]) -> Path:
    """A path from ``s_start`` to ``s_end`` [m] whose curvature is a sum of two sines, each
    of a wavelength [m] and an amplitude [1/m] drawn from ``rng`` within the ranges
    ``wavelengths`` and ``curvatures``, and a random phase."""
    wavelengths = rng.uniform(*wavelengths, size=2)
    amplitudes = rng.uniform(*curvatures, size=2)
    phases = rng.uniform(0.0, 2.0 * np.pi, size=2)
    first = int(np.floor(s_start / PATH_STEP))
    s = PATH_STEP * np.arange(first, int(np.ceil(s_end / PATH_STEP)) + 1)
    middle = s[:-1] + 0.5 * PATH_STEP
    curvature = sum(a * np.sin(2.0 * np.pi * middle / lam + p)
                    for a, lam, p in zip(amplitudes, wavelengths, phases))
    return Path.integrate(np.full(len(middle), PATH_STEP), curvature, origin=-first)


def piecewise_path(pieces: list[tuple[float, float]], start_piece: int = 0) -> Path:
    """The path of ``pieces`` ``(length [m], curvature [1/m])``, straights and circular
    arcs, each cut into equal steps of at most `PATH_STEP`; ``s = 0`` where piece
    ``start_piece`` begins."""
    steps, curvature = [], []
    for length, kappa in pieces:
        n = int(np.ceil(length / PATH_STEP))
        steps.append(np.full(n, length / n))
        curvature.append(np.full(n, kappa))
    origin = sum(len(piece) for piece in steps[:start_piece])
    return Path.integrate(np.concatenate(steps), np.concatenate(curvature), origin=origin)


def loop_path() -> Path:
    """The closed block: start halfway along a long side, four right turns of
    `LOOP_RADIUS`, back to the start with the same heading."""
    quarter = 0.5 * np.pi * LOOP_RADIUS
    pieces = [(0.5 * LOOP_A, 0.0), (quarter, 1.0 / LOOP_RADIUS), (LOOP_B, 0.0),
              (quarter, 1.0 / LOOP_RADIUS), (LOOP_A, 0.0), (quarter, 1.0 / LOOP_RADIUS),
              (LOOP_B, 0.0), (quarter, 1.0 / LOOP_RADIUS), (0.5 * LOOP_A, 0.0)]
    return piecewise_path(pieces)


def nearmiss_path(out_length: float, back_length: float) -> Path:
    """Out along a straight street for ``out_length`` [m], round the block with two right
    turns of `LOOP_RADIUS` joined by `NEARMISS_LINK` m, and back for ``back_length`` [m]
    on the parallel street 40 m to the right; `PATH_BEHIND` m before the start."""
    quarter = 0.5 * np.pi * LOOP_RADIUS
    pieces = [(PATH_BEHIND, 0.0), (out_length, 0.0), (quarter, 1.0 / LOOP_RADIUS),
              (NEARMISS_LINK, 0.0), (quarter, 1.0 / LOOP_RADIUS), (back_length, 0.0)]
    return piecewise_path(pieces, start_piece=1)


def nearmiss_turn_length() -> float:
    """Arc length [m] of ``nearmiss``'s turn round the block (both corners and the link)."""
    return np.pi * LOOP_RADIUS + NEARMISS_LINK


# --- the camera -------------------------------------------------------------------------------

WOBBLE = {
    # name: ((amplitude, wavelength [m]), ...): the chosen 6-DoF perturbation of the ride.
    "yaw": ((0.005, 37.0),),
    "pitch": ((0.007, 6.5), (0.004, 17.0)),
    "roll": ((0.005, 9.0),),
    "height": ((0.02, 5.0),),
    "sway": ((0.12, 45.0),),
}


HIGHWAY_RIDE = {
    # WOBBLE's perturbations on a highway: a smoother road driven faster, so longer
    # wavelengths (body pitch and bounce near 1 Hz at 22 m/s, lane keeping over 10 s).
    "yaw": ((0.003, 150.0),),
    "pitch": ((0.004, 28.0), (0.002, 65.0)),
    "roll": ((0.003, 45.0),),
    "height": ((0.015, 22.0),),
    "sway": ((0.25, 230.0),),
}


def wobble(name: str, s: np.ndarray, period: float, ride: dict = WOBBLE) -> np.ndarray:
    """The ``name`` perturbation of ``ride`` (`WOBBLE` or `HIGHWAY_RIDE`) at arc lengths
    ``s`` (N,): sines with a whole number of cycles per ``period`` [m] (so a closed loop
    repeats exactly) and zero at ``s = 0``."""
    total = np.zeros_like(s)
    for amplitude, wavelength in ride[name]:
        cycles = max(1, round(period / wavelength))
        total += amplitude * np.sin(2.0 * np.pi * cycles * s / period)
    return total


def camera_poses(path: Path, s: np.ndarray, period: float, ride: dict = WOBBLE) -> np.ndarray:
    """Left-camera poses ``T_w_c`` (N, 4, 4) at arc lengths ``s`` (N,): on the lane centre,
    `CAMERA_HEIGHT` above the road, plus the perturbations of ``ride`` (`wobble`);
    identity at ``s = 0``."""
    heading = path.heading_at(s)
    yaw = heading + wobble("yaw", s, period, ride)
    pitch, roll = wobble("pitch", s, period, ride), wobble("roll", s, period, ride)
    centre = path.ground_point(s, wobble("sway", s, period, ride))
    height = CAMERA_HEIGHT + wobble("height", s, period, ride)
    poses = np.empty((len(s), 4, 4))
    for i in range(len(s)):
        R = (so3_exp(np.array([0.0, yaw[i], 0.0])) @ so3_exp(np.array([pitch[i], 0.0, 0.0]))
             @ so3_exp(np.array([0.0, 0.0, roll[i]])))
        poses[i] = make_pose(R, centre[i] + height[i] * UP)
    return poses


def make_camera(model: str, size: tuple[int, int] | None) -> StereoCamera:
    """The rectified stereo camera ``model`` (one of `CAMERAS`, see the module doc):
    ``default`` for images of ``size = (width, height)`` [px] (None: `DEFAULT_SIZE`),
    ``kitti`` = `KITTI_CAMERA`, whose size is fixed (``size`` None or its own).

    Raises
    ------
    PldSlamError
        For an unknown model, a size that is not two positive integers, or a size other
        than KITTI's with ``kitti``.
    """
    if model not in CAMERAS:
        raise PldSlamError(f"unknown synthetic camera {model!r}; choose one of {', '.join(CAMERAS)}")
    if size is not None and (len(size) != 2 or any(int(v) != v or v <= 0 for v in size)):
        raise PldSlamError(f"image size must be two positive integers (width, height), got {tuple(size)}")
    if model == "kitti":
        if size is not None and tuple(size) != KITTI_CAMERA.size:
            raise PldSlamError(
                f"image size {size[0]}x{size[1]} conflicts with camera 'kitti', whose images are "
                f"{KITTI_CAMERA.width}x{KITTI_CAMERA.height}: give the size or the kitti camera, not both")
        return KITTI_CAMERA
    width, height = (int(v) for v in (DEFAULT_SIZE if size is None else size))
    focal = FOCAL_PER_WIDTH * width
    return StereoCamera(fx=focal, fy=focal, cx=width / 2.0, cy=height / 2.0,
                        baseline=BASELINE, width=width, height=height)


# --- materials ------------------------------------------------------------------------------


@dataclass(frozen=True)
class Palette:
    """The look of a world: its textures and which material each kind of surface uses."""

    textures: tuple[tx.Texture, ...]
    ground: int
    road: int
    sidewalk: int
    curb: int
    facades: tuple[FacadeMaterials, ...]
    metal: int
    signs: tuple[int, ...]
    car: BoxMaterials
    truck: BoxMaterials
    pedestrian: BoxMaterials
    cyclist: BoxMaterials
    crate: BoxMaterials
    plain: bool


CAR_SIZE = (1.8, 1.5, 4.4)
TRUCK_SIZE = (2.5, 3.4, 7.0)
PEDESTRIAN_SIZE = (0.5, 1.75, 0.35)
CYCLIST_SIZE = (0.5, 1.75, 1.7)


def textured_palette(seed: int) -> Palette:
    """Materials of the textured street (static, dynamic and loop scenarios)."""
    rng = rng_for(seed, 2)
    textures: list[tx.Texture] = []

    def add(texture: tx.Texture) -> int:
        textures.append(texture)
        return len(textures) - 1

    road_width = ROAD_RIGHT - ROAD_LEFT
    ground = add(tx.asphalt(rng))
    road = add(tx.road(rng, road_width, dashed_at=[-0.5 * LANE - ROAD_LEFT],
                       solid_at=[PARKING, road_width - PARKING]))
    sidewalk, curb_material = add(tx.paving(rng)), add(tx.curb(rng))
    facades = []
    for make_upper in (tx.brick_facade, tx.plaster_facade, tx.panel_facade) * 2:
        upper = add(make_upper(rng))
        facades.append(FacadeMaterials(upper=upper, ground=add(tx.shopfront(rng)), side=upper))
    metal = add(tx.metal(rng))
    signs = tuple(add(tx.sign(rng)) for _ in range(3))
    roof = add(tx.flat())
    car = BoxMaterials(side=add(tx.car_side(rng, (CAR_SIZE[2], CAR_SIZE[1]))),
                       end=add(tx.car_end(rng, CAR_SIZE[:2])), top=roof)
    truck = BoxMaterials(side=add(tx.truck_side(rng, (TRUCK_SIZE[2], TRUCK_SIZE[1]))),
                         end=add(tx.truck_rear(rng, TRUCK_SIZE[:2])), top=roof)
    pedestrian = BoxMaterials(side=add(tx.person(rng, PEDESTRIAN_SIZE[2])),
                              end=add(tx.person(rng, PEDESTRIAN_SIZE[0])), top=roof)
    cyclist = BoxMaterials(side=add(tx.bicycle_side(rng)), end=pedestrian.end, top=roof)
    crate_material = add(tx.crate(rng))
    return Palette(tuple(textures), ground, road, sidewalk, curb_material, tuple(facades), metal,
                   signs, car, truck, pedestrian, cyclist,
                   BoxMaterials(crate_material, crate_material, crate_material), plain=False)


def plain_palette() -> Palette:
    """Materials of the low-texture world: one uniform texture; shades come from albedos."""
    flat = BoxMaterials(0, 0, 0)
    return Palette((tx.flat(),), 0, 0, 0, 0, (FacadeMaterials(0, 0, 0),), 0, (), flat, flat, flat,
                   flat, flat, plain=True)


# --- the street -------------------------------------------------------------------------------


def strip_edges(path: Path, s_start: float, s_end: float) -> np.ndarray:
    """Arc lengths (n+1,) cutting ``[s_start, s_end]`` into ground strips: `STRIP_MAX` long
    on straights, shorter on curves (adjacent strips 4 m from the path then part by at
    most 15 cm)."""
    edges = [s_start]
    while edges[-1] < s_end:
        kappa = abs(float(path.curvature_at(edges[-1])))
        edges.append(min(edges[-1] + min(STRIP_MAX, 0.15 / (4.0 * kappa + 1e-9)), s_end))
    return np.array(edges)


@dataclass(frozen=True)
class Strips:
    """Ground strips of one band ``[l_in, l_out]``: centres (n, 3) on the band's middle
    line, forward directions (n, 3), lengths (n,) along that line and the arc length along
    it (n,) at each strip's front and back [m]."""

    centre: np.ndarray
    forward: np.ndarray
    length: np.ndarray
    arc_front: np.ndarray
    arc_back: np.ndarray


def band_strips(path: Path, edges: np.ndarray, lateral: float, half_width: float = 0.0) -> Strips:
    """Strips between arc lengths ``edges`` (n+1,) along the line at offset ``lateral`` of a
    band ``2 * half_width`` [m] wide.

    A strip keeps the path's heading at its middle; its length is scaled by
    ``1 - curvature * lateral`` (shorter inside a bend) and grown by the wedge a bend opens
    at the band's outer edge, so neighbours overlap slightly instead of leaving a gap. The
    arc length along the offset line is ``s - lateral * heading(s)``, which keeps textures
    continuous across strips.
    """
    middle = 0.5 * (edges[:-1] + edges[1:])
    heading = path.heading_at(middle)
    arc = edges - lateral * path.heading_at(edges)
    return Strips(
        centre=path.ground_point(middle, np.full(len(middle), lateral)),
        forward=forward_of(heading),
        length=np.diff(arc) + np.abs(path.curvature_at(middle) * np.diff(edges)) * half_width,
        arc_front=arc[1:],
        arc_back=arc[:-1],
    )


def ground_band(path: Path, edges: np.ndarray, l_in: float, l_out: float, lift: float,
                material: int, albedo: float, across_offset: float) -> Quads:
    """Floor strips of the band ``l_in < l_out`` [m], ``lift`` [m] above the road; texture
    columns start ``across_offset`` [m] in, rows run backwards along the band."""
    strips = band_strips(path, edges, 0.5 * (l_in + l_out), 0.5 * (l_out - l_in))
    offsets = np.column_stack([np.full(len(strips.length), across_offset), -strips.arc_front])
    return floor(strips.centre + lift * UP, strips.forward, l_out - l_in, strips.length,
                 material, albedo, offsets)


def wall_band(path: Path, edges: np.ndarray, lateral: float, facing_right: bool, height: float,
              material: int, albedo: float, lift: float = 0.0) -> Quads:
    """Vertical strips between arc lengths ``edges`` (n+1,) at offset ``lateral`` facing the
    road (right or left), from ``lift`` to ``lift + height`` [m] above it: curbs, guard
    rails, noise walls. The texture runs continuously along the band."""
    strips = band_strips(path, edges, lateral)
    right = np.cross(DOWN, strips.forward)
    normal = right if facing_right else -right
    along = strips.arc_back if facing_right else -strips.arc_front
    return wall(strips.centre + lift * UP, normal, strips.length, height, material, albedo,
                np.column_stack([along, np.zeros_like(along)]))


def street_ground(path: Path, s_start: float, s_end: float, palette: Palette) -> list[Quads]:
    """Road (two bands, split on the camera lane centre), sidewalks and curbs."""
    edges = strip_edges(path, s_start, s_end)
    road_albedo, side_albedo, curb_albedo = (0.45, 0.75, 0.9) if palette.plain else (1.0, 1.0, 1.0)
    parts = [
        ground_band(path, edges, ROAD_LEFT, 0.0, 0.0, palette.road, road_albedo, 0.0),
        ground_band(path, edges, 0.0, ROAD_RIGHT, 0.0, palette.road, road_albedo, -ROAD_LEFT),
        ground_band(path, edges, ROAD_RIGHT, ROAD_RIGHT + SIDEWALK, CURB_HEIGHT, palette.sidewalk,
                    side_albedo, 0.0),
        ground_band(path, edges, ROAD_LEFT - SIDEWALK, ROAD_LEFT, CURB_HEIGHT, palette.sidewalk,
                    side_albedo, 0.0),
        wall_band(path, edges, ROAD_RIGHT, False, CURB_HEIGHT, palette.curb, curb_albedo),
        wall_band(path, edges, ROAD_LEFT, True, CURB_HEIGHT, palette.curb, curb_albedo),
    ]
    if palette.plain:
        centre_line = -0.5 * LANE
        parts.append(ground_band(path, edges, centre_line - 0.08, centre_line + 0.08, 0.005,
                                 palette.road, 0.95, 0.0))
    return parts


def ground_plane(points: np.ndarray, palette: Palette) -> Quads:
    """One large floor 2 cm under the road, 400 m beyond the ground ``points`` (n, 3) all round."""
    low, high = points.min(axis=0), points.max(axis=0)
    centre = 0.5 * (low + high) + 0.02 * DOWN
    size = high - low + 800.0
    return floor(centre, np.array([0.0, 0.0, 1.0]), size[0], size[2], palette.ground,
                 0.55 if palette.plain else 1.0)


def building_row(path: Path, s_start: float, s_end: float, side: int, rng: np.random.Generator,
                 palette: Palette) -> list[Quads]:
    """Buildings along one side (``side`` +1 right, -1 left) between two arc lengths: 9-24 m
    wide (whole bays), 7-19 m tall, set back 0-1 m from the sidewalk, gaps of 0-5 m."""
    edge = ROAD_RIGHT + SIDEWALK if side > 0 else ROAD_LEFT - SIDEWALK
    parts = []
    s = s_start + rng.uniform(0.0, 3.0)
    while True:
        lateral = edge + side * rng.uniform(0.0, 1.0)
        width = 3.0 * rng.integers(3, 9)
        height = tx.FLOOR_HEIGHT * rng.integers(1, 6) + 4.0
        depth = rng.uniform(8.0, 14.0)
        kappa = float(path.curvature_at(s))
        if abs(kappa) > 1.0 / 50.0:
            width = 9.0
        span = width / max(1.0 - kappa * lateral, 0.2)
        if s + span > s_end:
            return parts
        T_w_o = path.pose(s + 0.5 * span, lateral, side * 0.5 * np.pi)
        parts.append(make_building(palette, rng, width, depth, height).transformed(T_w_o))
        s += span + (0.0 if rng.random() < 0.4 else rng.uniform(1.5, 5.0))


def make_building(palette: Palette, rng: np.random.Generator, width: float, depth: float,
                  height: float) -> Quads:
    """One building in its object frame, textured or plain after the palette."""
    if palette.plain:
        panels = rng.uniform(0.5, 1.0, size=int(rng.integers(2, 5)))
        doors = rng.uniform(-0.4, 0.4, size=int(rng.integers(0, 3))) * width
        return plain_building(width, depth, height, 0, panels, doors, rng.uniform(0.3, 0.6),
                              rng.uniform(0.4, 1.0))
    facade = palette.facades[int(rng.integers(len(palette.facades)))]
    return building(width, depth, height, facade, tex_shift=3.0 * rng.integers(0, 4))


def pole_row(path: Path, s_start: float, s_end: float, side: int, rng: np.random.Generator,
             palette: Palette) -> list[Quads]:
    """Street-light poles near the curb every 14-24 m, arms over the road, some with signs."""
    lateral = ROAD_RIGHT + 0.45 if side > 0 else ROAD_LEFT - 0.45
    parts = []
    s = s_start + rng.uniform(2.0, 10.0)
    while s < s_end:
        signed = palette.signs and rng.random() < 0.4
        sign_material = palette.signs[int(rng.integers(len(palette.signs)))] if signed else None
        quads = pole(rng.uniform(4.5, 6.5), rng.uniform(1.0, 1.8), palette.metal, sign_material)
        lift = CURB_HEIGHT * UP
        T_w_o = path.pose(s, lateral, 0.0 if side > 0 else np.pi)
        T_w_o[:3, 3] += lift
        parts.append(quads.transformed(T_w_o))
        s += rng.uniform(14.0, 24.0)
    return parts


def parked_slots(path: Path, s_start: float, s_end: float, side: int, rng: np.random.Generator,
                 palette: Palette) -> list[tuple[float, Quads]]:
    """Parked cars in the parking lane, one 6.5 m slot in two taken, random paint, up to
    0.8 m off the slot's middle, 30 % facing the other way: the arc length [m] of each
    taken slot's middle and its car."""
    lateral = ROAD_RIGHT - 0.5 * PARKING if side > 0 else ROAD_LEFT + 0.5 * PARKING
    slots = []
    for s in np.arange(s_start + 3.0, s_end, 6.5):
        taken, turned, paint, shift = rng.random(), rng.random(), rng.uniform(0.3, 1.1), rng.uniform(-0.8, 0.8)
        if taken < 0.5:
            yaw = np.pi if (turned < 0.3) != (side < 0) else 0.0
            car = box(*CAR_SIZE, palette.car, float(paint))
            slots.append((float(s), car.transformed(path.pose(s + shift, lateral, yaw))))
    return slots


def parked_row(path: Path, s_start: float, s_end: float, side: int, rng: np.random.Generator,
               palette: Palette) -> list[Quads]:
    """The parked cars of `parked_slots`."""
    return [car for _, car in parked_slots(path, s_start, s_end, side, rng, palette)]


def crate_row(path: Path, s_start: float, s_end: float, side: int, rng: np.random.Generator,
              palette: Palette) -> list[Quads]:
    """Crates (1 m cubes, sometimes two stacked) on the sidewalk every 15-40 m."""
    lateral = ROAD_RIGHT + SIDEWALK - 0.7 if side > 0 else ROAD_LEFT - SIDEWALK + 0.7
    parts = []
    s = s_start + rng.uniform(5.0, 20.0)
    while s < s_end:
        stack = int(rng.integers(1, 3))
        yaw = rng.uniform(-0.3, 0.3)
        for level in range(stack):
            T_w_o = path.pose(s, lateral, yaw)
            T_w_o[:3, 3] += (CURB_HEIGHT + level) * UP
            parts.append(box(1.0, 1.0, 1.0, palette.crate, float(rng.uniform(0.8, 1.1))).transformed(T_w_o))
        s += rng.uniform(15.0, 40.0)
    return parts


STREET_ROWS: tuple[Callable, ...] = (building_row, pole_row, parked_row, crate_row)
"""The rows of objects along a street; row k on side ``side`` draws from the random stream
``rng_for(seed, 10 + k, side + 1)``."""


def row_rng(seed: int, make_row: Callable, side: int) -> np.random.Generator:
    """The random stream of row ``make_row`` (one of `STREET_ROWS`) on side ``side``."""
    return rng_for(seed, 10 + STREET_ROWS.index(make_row), side + 1)


def street(path: Path, s_start: float, s_end: float, seed: int, palette: Palette,
           parked: bool = True) -> Quads:
    """All static quads of a street between two arc lengths, including the ground plane,
    without the parked cars if not ``parked``. Each row of objects draws from its own
    random stream."""
    parts = [ground_plane(path.position, palette), *street_ground(path, s_start, s_end, palette)]
    for make_row in STREET_ROWS:
        if make_row is parked_row and not parked:
            continue
        for side in (1, -1):
            parts += make_row(path, s_start, s_end, side, row_rng(seed, make_row, side), palette)
    return Quads.concat(parts)


# --- what changes between the laps of loop2 -----------------------------------------------------


def parked_visits(path: Path, driven: np.ndarray, seed: int, palette: Palette) -> Transient:
    """The parked cars of ``loop2`` around the closed ``path``, at frames that have driven
    ``driven`` (N,) [m] in all (0 to two laps).

    On the first visit of each slot they are those of ``loop``; then each slot's car is
    drawn again from another random stream (`SECOND_PARKING_TAG`): other slots taken,
    other paint, place in the slot and direction. A slot's cars swap at the first frame
    `PARKING_SWAP_MARGIN` past it on the first lap, when it is behind the camera, so no
    car appears or vanishes in view; the first lap sees the cars ahead of it as they were,
    the second lap sees only the new ones.
    """
    quads, first, end = [], [], []
    for visit, tag in enumerate((10 + STREET_ROWS.index(parked_row), SECOND_PARKING_TAG)):
        for side in (1, -1):
            for s, car in parked_slots(path, 0.0, path.length, side, rng_for(seed, tag, side + 1), palette):
                swap = int(np.searchsorted(driven, s + PARKING_SWAP_MARGIN))
                quads.append(car)
                first.append(np.full(len(car), 0 if visit == 0 else swap))
                end.append(np.full(len(car), swap if visit == 0 else len(driven)))
    return Transient(Quads.concat(quads), np.concatenate(first), np.concatenate(end))


def lap_light(driven: np.ndarray, lap_length: float) -> tuple[np.ndarray, np.ndarray]:
    """The sun direction (N, 3) and exposure (N,) of ``loop2`` at frames that have driven
    ``driven`` (N,) [m] around a lap of ``lap_length`` [m]: `SUN` and 1 on the first lap,
    `SECOND_SUN` and `SECOND_EXPOSURE` on the second, blended smoothly over the last
    `LIGHT_RAMP` m of the first lap (a change of light between two frames would test
    the tracker, not the loop closing)."""
    x = np.clip((driven - (lap_length - LIGHT_RAMP)) / LIGHT_RAMP, 0.0, 1.0)
    blend = (x * x * (3.0 - 2.0 * x))[:, None]
    light = (1.0 - blend) * SUN + blend * SECOND_SUN
    exposure = 1.0 + (SECOND_EXPOSURE - 1.0) * blend[:, 0]
    return light / np.linalg.norm(light, axis=1, keepdims=True), exposure


# --- movers ------------------------------------------------------------------------------------


def track_poses(path: Path, s: np.ndarray, lateral: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """``T_w_o`` (N, 4, 4) of an upright object at ``(s, l)`` (N,) turned ``yaw`` (N,) from
    the path heading."""
    return np.stack([path.pose(float(si), float(li), float(yi)) for si, li, yi in zip(s, lateral, yaw)])


def waypoint_track(times: np.ndarray, waypoints: np.ndarray) -> tuple[np.ndarray, ...]:
    """Position ``(s, l)`` and heading (N,) each at ``times`` (N,) [s] of an object moving
    straight between ``waypoints`` (K, 3) = ``(time, s, l)``; it faces along its motion."""
    s = np.interp(times, waypoints[:, 0], waypoints[:, 1])
    lateral = np.interp(times, waypoints[:, 0], waypoints[:, 2])
    legs = np.arctan2(np.diff(waypoints[:, 2]), np.diff(waypoints[:, 1]))
    leg = np.clip(np.searchsorted(waypoints[:, 0], times) - 1, 0, len(legs) - 1)
    return s, lateral, legs[leg]


def mover(object_id: int, quads: Quads, poses: np.ndarray) -> MovingObject:
    """A moving object with its id stamped on its quads."""
    return MovingObject(quads=quads.with_object_id(object_id), poses=poses)


def traffic(path: Path, camera_s: np.ndarray, times: np.ndarray, s_end: float, seed: int,
            palette: Palette) -> tuple[MovingObject, ...]:
    """The movers of the dynamic scenario (chosen so they cover 10-40 % of the left image):

    - a truck 4.2-5.8 m ahead in our lane (its gap breathing over 8 s);
    - oncoming cars at 7 m/s, 25-45 m apart;
    - pedestrians walking both ways on both sidewalks at 1.2-1.6 m/s, 8-16 m apart;
    - a cyclist crossing the street every ~45 m while still 25-55 m ahead of us, riding
      along the sidewalks (4 m/s) before and after.
    """
    rng = rng_for(seed, 3)
    movers: list[MovingObject] = []
    gap = 5.0 + 0.8 * np.sin(2.0 * np.pi * times / 8.0)
    truck_s = camera_s + gap + 0.5 * TRUCK_SIZE[2]
    zeros = np.zeros_like(times)
    movers.append(mover(1, box(*TRUCK_SIZE, palette.truck, 0.9),
                        track_poses(path, truck_s, zeros, zeros)))
    s = 15.0
    while s < s_end + 60.0:
        car = box(*CAR_SIZE, palette.car, float(rng.uniform(0.3, 1.1)))
        movers.append(mover(len(movers) + 1, car,
                            track_poses(path, s - 7.0 * times, zeros + ONCOMING_LANE, zeros + np.pi)))
        s += rng.uniform(25.0, 45.0)
    for side in (1, -1):
        lanes = (ROAD_RIGHT + 0.8, ROAD_RIGHT + 2.2) if side > 0 else (ROAD_LEFT - 2.2, ROAD_LEFT - 0.8)
        s = rng.uniform(0.0, 8.0)
        while s < s_end:
            speed = rng.uniform(1.2, 1.6) * rng.choice([-1.0, 1.0])
            walker = box(*PEDESTRIAN_SIZE, palette.pedestrian, float(rng.uniform(0.7, 1.1)))
            lateral = zeros + rng.uniform(*lanes)
            yaw = zeros + (0.0 if speed > 0 else np.pi)
            movers.append(mover(len(movers) + 1, walker, track_poses(path, s + speed * times, lateral, yaw)))
            s += rng.uniform(8.0, 16.0)
    far_side, near_side = ROAD_LEFT - 1.5, ROAD_RIGHT + 1.5
    for crossing in np.arange(35.0, s_end, 45.0):
        start = (crossing - 55.0) / (STREET_STEP * FRAME_RATE)
        waypoints = np.array([
            [start - 100.0, crossing - 400.0, far_side],
            [start, crossing, far_side],
            [start + 4.0, crossing, near_side],
            [start + 104.0, crossing + 400.0, near_side],
        ])
        s, lateral, yaw = waypoint_track(times, waypoints)
        movers.append(mover(len(movers) + 1, box(*CYCLIST_SIZE, palette.cyclist),
                            track_poses(path, s, lateral, yaw)))
    return tuple(movers)


# --- movers a robust solve alone cannot reject (the dynamic-scenes issue) ----------------------

BUS_SIZE = (2.55, 3.2, 12.0)
CONVOY_SPEED = (8.0, 1.5, 11.0)
"""The camera's speed in ``convoy``: mean [m/s], swing [m/s] and period [s] of a sine."""
CROSSING_CYCLE = ((2.0, 5.0), (2.5, 0.0), (9.0, 0.0), (2.5, 5.0), (3.0, 5.0))
"""The camera's speed in ``crossing``, one junction per cycle: phases of (duration [s],
speed at its end [m/s]), the speed changing linearly over each: cruise at 5 m/s, brake
to a stop, wait 9 s (until the crowd has cleared our lane), pull away, cruise. 19 s per
junction."""
PULL_OUT_DISTANCE = 20.0
"""In ``parked_then_moving``, a parked car pulls out when the camera is this far [m] behind it."""


def arc_lengths(times: np.ndarray, speed: Callable[[np.ndarray], np.ndarray]) -> np.ndarray:
    """Distance driven (N,) [m] at ``times`` (N,) [s] from ``times[0]`` at ``speed(t)`` [m/s],
    integrated on a 1 ms grid (trapezoids)."""
    grid = np.arange(times[0], times[-1] + 1e-3, 1e-3)
    step = 0.5 * (speed(grid[1:]) + speed(grid[:-1])) * np.diff(grid)
    return np.interp(times, grid, np.concatenate([[0.0], np.cumsum(step)]))


def convoy_speed(t: np.ndarray) -> np.ndarray:
    """The camera's speed [m/s] at times ``t`` [s] in ``convoy`` (`CONVOY_SPEED`)."""
    mean, swing, period = CONVOY_SPEED
    return mean + swing * np.sin(2.0 * np.pi * t / period)


def crossing_speed(t: np.ndarray) -> np.ndarray:
    """The camera's speed [m/s] at times ``t`` [s] in ``crossing`` (`CROSSING_CYCLE`, repeated)."""
    durations = np.array([d for d, _ in CROSSING_CYCLE])
    ends = np.array([v for _, v in CROSSING_CYCLE])
    knots = np.concatenate([[0.0], np.cumsum(durations)])
    speeds = np.concatenate([[ends[-1]], ends])
    return np.interp(np.asarray(t) % knots[-1], knots, speeds)


def crossing_stops(times: np.ndarray) -> np.ndarray:
    """Times [s] within ``times`` at which ``crossing``'s camera comes to a stop."""
    durations = [d for d, _ in CROSSING_CYCLE]
    first, cycle = sum(durations[:2]), sum(durations)
    return np.arange(first, times[-1], cycle)


def with_textures(palette: Palette, textures: Sequence[tx.Texture]) -> tuple[Palette, int]:
    """``palette`` with ``textures`` appended, and the material of the first of them; the
    palette's own materials (and their random draws) stay as they are."""
    return replace(palette, textures=(*palette.textures, *textures)), len(palette.textures)


def with_box_materials(palette: Palette, side: tx.Texture, end: tx.Texture) -> tuple[Palette, BoxMaterials]:
    """``palette`` with two more textures, and the materials of a box using them."""
    palette, first = with_textures(palette, (side, end))
    return palette, BoxMaterials(side=first, end=first + 1, top=palette.car.top)


def convoy_traffic(path: Path, camera_s: np.ndarray, times: np.ndarray, seed: int,
                   palette: Palette, bus: BoxMaterials) -> tuple[MovingObject, ...]:
    """The movers of ``convoy``, all driving our way at about our speed:

    - a bus in the lane to our left, its middle 1 m behind to 8 m ahead of the camera (a sine of
      16-20 s): alongside and just ahead it fills the left half of the image;
    - a queue ahead in our lane: a truck whose middle is 8.5-11.5 m ahead, a car 2.5 m
      behind its tail, the gap breathing over 6-9 s.

    Together they cover 27-39 % of a frame (seeds 0-2, every 5th frame at 320x240), for the
    whole sequence.

    To a robust solve their features say "the camera stands still": a coherent group
    beside the static scene's, as large or larger.
    """
    rng = rng_for(seed, 4)
    zeros = np.zeros_like(times)

    def breathing(mean: float, swing: float, periods: tuple[float, float]) -> np.ndarray:
        period, phase = rng.uniform(*periods), rng.uniform(0.0, 2.0 * np.pi)
        return mean + swing * np.sin(2.0 * np.pi * times / period + phase)

    lead = breathing(3.5, 4.5, (16.0, 20.0))
    movers = [mover(1, box(*BUS_SIZE, bus, 0.95), track_poses(path, camera_s + lead, zeros - LANE, zeros))]
    gap = breathing(10.0, 1.5, (6.0, 9.0))
    truck = box(*TRUCK_SIZE, palette.truck, 0.9)
    movers.append(mover(2, truck, track_poses(path, camera_s + gap, zeros, zeros)))
    car = box(*CAR_SIZE, palette.car, float(rng.uniform(0.3, 1.1)))
    gap = gap + 0.5 * TRUCK_SIZE[2] + 2.5 + 0.5 * CAR_SIZE[2]
    movers.append(mover(3, car, track_poses(path, camera_s + gap, zeros, zeros)))
    return tuple(movers)


def walk_across(times: np.ndarray, start: float, s: float, l_from: float, l_to: float,
                speed: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Position ``(s, l)`` and heading (N,) at ``times`` (N,) [s] of someone waiting at
    ``(s, l_from)`` who crosses to ``l_to`` at ``speed`` [m/s] from time ``start``, facing
    the way across throughout."""
    lateral = l_from + np.sign(l_to - l_from) * np.clip(speed * (times - start), 0.0, abs(l_to - l_from))
    yaw = np.full_like(times, 0.5 * np.pi * np.sign(l_to - l_from))
    return np.full_like(times, s), lateral, yaw


CROWD = 60
"""Pedestrians crossing at each of ``crossing``'s junctions (and 3 cyclists)."""


def crossing_crowd(path: Path, camera_s: np.ndarray, times: np.ndarray, seed: int,
                   palette: Palette) -> tuple[MovingObject, ...]:
    """The movers of ``crossing``: at each stop of the camera, `CROWD` pedestrians and 3
    cyclists cross the street 4-8 m in front of it, 80 % of them from right to left,
    setting off together within 2.5 s of the stop (the lights changed). They wait at the
    kerb before, so they are part of the static scene until they set off.
    """
    rng = rng_for(seed, 5)
    right, left = ROAD_RIGHT + 0.8, ROAD_LEFT - 0.8
    movers: list[MovingObject] = []
    for stop in crossing_stops(times):
        s_stop = float(np.interp(stop, times, camera_s))
        for walker in range(CROWD + 3):
            cyclist = walker >= CROWD
            l_from, l_to = (right, left) if rng.random() < 0.8 else (left, right)
            start = stop + rng.uniform(-1.0, 1.5)
            speed = rng.uniform(3.5, 4.5) if cyclist else rng.uniform(1.1, 1.6)
            s, lateral, yaw = walk_across(times, start, s_stop + rng.uniform(4.0, 8.0),
                                          l_from + rng.uniform(-0.6, 0.6), l_to, speed)
            size, look = (CYCLIST_SIZE, palette.cyclist) if cyclist else (PEDESTRIAN_SIZE, palette.pedestrian)
            body = box(*size, look, float(rng.uniform(0.7, 1.1)))
            movers.append(mover(len(movers) + 1, body, track_poses(path, s, lateral, yaw)))
    return tuple(movers)


def pull_out_track(times: np.ndarray, start: float, s_parked: float, l_parked: float,
                   l_lane: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Position ``(s, l)`` and heading (N,) of a car parked at ``(s_parked, l_parked)`` that
    pulls out at time ``start`` [s]: it accelerates at 4 m/s^2 up to 12 m/s (faster than the
    camera, which it lets come no closer than 12 m) while easing over to the lane at
    ``l_lane`` within 3 s, then drives on."""
    elapsed = np.clip(times - start, 0.0, None)
    top_speed, acceleration = 12.0, 4.0
    ramp = top_speed / acceleration
    s = s_parked + np.where(elapsed < ramp, 0.5 * acceleration * elapsed**2,
                            0.5 * top_speed * ramp + top_speed * (elapsed - ramp))
    blend = 0.5 - 0.5 * np.cos(np.pi * np.clip(elapsed / 3.0, 0.0, 1.0))
    lateral = l_parked + (l_lane - l_parked) * blend
    speed = np.minimum(acceleration * elapsed, top_speed)
    drift = (l_lane - l_parked) * 0.5 * np.pi / 3.0 * np.sin(np.pi * np.clip(elapsed / 3.0, 0.0, 1.0))
    yaw = np.where(elapsed > 0.0, np.arctan2(drift, np.maximum(speed, 1e-6)), 0.0)
    return s, lateral, yaw


def parked_movers(path: Path, camera_s: np.ndarray, times: np.ndarray, seed: int,
                  palette: Palette) -> tuple[tuple[MovingObject, ...], list[float]]:
    """The movers of ``parked_then_moving``: a car parked every 40 m from 35 m on,
    alternately in the right and the left parking lane, that pulls out into the nearest
    lane of our direction (`pull_out_track`) when the camera is `PULL_OUT_DISTANCE` behind
    it. Also the arc lengths [m] where they park (the static parked cars keep clear)."""
    rng = rng_for(seed, 6)
    movers: list[MovingObject] = []
    spots = []
    for n, s_parked in enumerate(np.arange(35.0, camera_s[-1] + 20.0, 40.0)):
        side = 1 if n % 2 == 0 else -1
        l_parked = ROAD_RIGHT - 0.5 * PARKING if side > 0 else ROAD_LEFT + 0.5 * PARKING
        l_lane = 0.0 if side > 0 else -LANE
        start = float(np.interp(s_parked - PULL_OUT_DISTANCE, camera_s, times, right=np.inf))
        s, lateral, yaw = pull_out_track(times, start, float(s_parked), l_parked, l_lane)
        car = box(*CAR_SIZE, palette.car, float(rng.uniform(0.3, 1.1)))
        movers.append(mover(len(movers) + 1, car, track_poses(path, s, lateral, yaw)))
        spots.append((float(s_parked), side))
    return tuple(movers), spots


def parked_cars_clear_of(path: Path, s_start: float, s_end: float, seed: int, palette: Palette,
                         spots: list[tuple[float, int]]) -> list[Quads]:
    """The street's parked cars (`parked_slots`, both sides) but those within 7 m of ``spots``
    (arc length, side) where a mover parks."""
    cars = []
    for side in (1, -1):
        taken = [s for s, spot_side in spots if spot_side == side]
        for s, car in parked_slots(path, s_start, s_end, side, row_rng(seed, parked_row, side), palette):
            if all(abs(s - other) > 7.0 for other in taken):
                cars.append(car)
    return cars


# --- the highway -------------------------------------------------------------------------------

HIGHWAY_LANE = 3.75
CARRIAGEWAY_LEFT = -1.5 * HIGHWAY_LANE - 1.0
"""Left edge [m] of our carriageway: three lanes (ours the middle one) and a 1 m inner shoulder."""
CARRIAGEWAY_RIGHT = 1.5 * HIGHWAY_LANE + 3.0
"""Right edge [m] of our carriageway: a 3 m hard shoulder."""
ONCOMING_RIGHT = CARRIAGEWAY_LEFT - 4.0
"""Right edge [m] of the oncoming carriageway (ours mirrored), beyond a 4 m grass median."""
ONCOMING_LEFT = ONCOMING_RIGHT - (CARRIAGEWAY_RIGHT - CARRIAGEWAY_LEFT)
ONCOMING_LANES = ONCOMING_RIGHT - 1.0 - HIGHWAY_LANE * np.array([0.5, 1.5, 2.5])
"""Centres [m] of the oncoming lanes, fast lane first."""
GUARD_RAILS = ((CARRIAGEWAY_LEFT - 0.8, True), (CARRIAGEWAY_RIGHT + 0.8, False), (ONCOMING_LEFT - 0.8, True))
"""Lateral offset [m] of each guard rail and whether it faces right (the road on its right):
in the median facing us, beyond our hard shoulder, beyond the oncoming hard shoulder."""
RAIL_BEAM = (0.4, 0.35)
"""Height of a guard rail beam's lower edge above the road and the beam's height [m]."""
RAIL_POST_SPACING = (3.6, 4.4)
"""Range of the gap [m] between neighbouring guard rail posts: about 4 m, but no period.
With posts (and rail and barrier textures) repeating every 4 m, a step of 2.45 m and one
of -1.55 m fitted them alike, and seed 2 drove backwards at -1.56 m per frame from its
first frame on (the tracker starts without a velocity)."""
GANTRY_LEGS = (CARRIAGEWAY_LEFT - 1.4, CARRIAGEWAY_RIGHT + 1.4)
"""Lateral offsets [m] of a sign gantry's legs, behind the guard rails."""
GANTRY_SIGN = (3.4, 2.4)
"""Width and height [m] of a sign over a lane."""
NOISE_WALL = (CARRIAGEWAY_RIGHT + 4.0, 4.0)
"""Lateral offset and height [m] of the noise barriers on the right."""
HIGHWAY_ROAD_TILE = 32.0
"""Length [m] of the carriageways' texture: four periods of the lane markings, so the
asphalt does not repeat with them."""
HIGHWAY_CRACKS = 160
"""Sealed cracks per tile of carriageway (`textures.sealed_cracks`), as on a worn motorway:
the asphalt's grain gives FAST little right ahead of the camera (with them, about 86
instead of 56 corners within 30 m per KITTI image, seed 0). Most near corners come from
the rough verges (`textures.grass`: about 300). Measured on seeds 0-3 (100 frames, the
detectors): Sim(3) scale 0.9971-0.9992 with them, 0.9969-0.9997 without: no consistent
change."""
HIGHWAY_SPEED = (22.5, 2.2, (18.0, 30.0))
"""The camera's speed in ``highway``: mean [m/s], swing [m/s] and the range of the period [s]
of a sine: 20.3-24.7 m/s, 2.03-2.47 m per frame at 10 Hz."""
HIGHWAY_VIEW_AHEAD = 400.0
"""Highway [m] built beyond the last camera position: guard rails and gantries stay visible
for hundreds of metres, and the far scenery at up to 300 m to the side comes into view
from 350 m behind it."""
HIGHWAY_BEHIND = 60.0
"""Highway [m] built before the first camera position (overtaking traffic comes from there)."""
TRAFFIC_REACH = 35.0
"""Fastest traffic [m/s]: the path reaches as far as traffic drives over the sequence."""
HIGHWAY_RIDE_PERIOD = 460.0
"""Period [m] of which `HIGHWAY_RIDE`'s wavelengths are whole fractions."""
HIGHWAY_FLOWS = (
    # lateral offset [m], speed range [m/s] (negative: oncoming), gap range [m], share of trucks
    (-HIGHWAY_LANE, (28.0, 33.0), (35.0, 90.0), 0.3),  # overtaking us in the lane to our left
    (ONCOMING_LANES[0], (-33.0, -27.0), (40.0, 110.0), 0.2),
    (ONCOMING_LANES[1], (-28.0, -24.0), (50.0, 130.0), 0.4),
    (ONCOMING_LANES[2], (-24.0, -20.0), (60.0, 160.0), 0.7),
)
"""The highway's traffic, one lane each. The lane to our right stays empty: a truck we
overtake there fills 30-40 % of the image for 2 s from 4-13 m ahead, and the tracker
followed it (0.3 of the true step for 17 frames: Sim(3) scale 0.93 and 0.84 in two seeds
of five with the detectors, 0.996 and 0.989 with the true masks), which would hide the
scale error this scenario is for; ``convoy`` tests movers alongside."""


@dataclass(frozen=True)
class HighwayMaterials:
    """The highway's own materials, beside its `Palette` (`highway_palette`): the two
    carriageways (each with its lane markings), guard rail beams, noise barriers, tree
    crowns and trunks, hillsides and the gantries' signs."""

    carriageway: int
    oncoming: int
    guard_rail: int
    noise_wall: int
    foliage: int
    bark: int
    hillside: int
    gantry_signs: tuple[int, ...]


def lane_markings(left_edge: float, lane_edges: np.ndarray) -> dict[str, list[float]]:
    """`textures.road`'s markings of a carriageway whose left edge is at ``left_edge`` [m]
    and whose three lanes are bounded by ``lane_edges`` (4,) [m]: solid lines on the outer
    two, dashed ones on the inner two, in metres from the left edge."""
    edges = sorted(float(edge - left_edge) for edge in lane_edges)
    return {"dashed_at": edges[1:-1], "solid_at": [edges[0], edges[-1]]}


def highway_palette(seed: int) -> tuple[Palette, HighwayMaterials]:
    """The street's materials (facades for the distant buildings, metal, cars and trucks)
    with the highway's appended, drawn from their own random stream; the open ground
    (``Palette.ground``, under the verges and the median) is grass."""
    rng = rng_for(seed, 32)
    width = CARRIAGEWAY_RIGHT - CARRIAGEWAY_LEFT
    ours = lane_markings(CARRIAGEWAY_LEFT, CARRIAGEWAY_LEFT + 1.0 + HIGHWAY_LANE * np.arange(4))
    theirs = lane_markings(ONCOMING_LEFT, ONCOMING_RIGHT - 1.0 - HIGHWAY_LANE * np.arange(4))
    carriageways = [tx.road(rng, width, **markings, cracks=HIGHWAY_CRACKS, length_m=HIGHWAY_ROAD_TILE)
                    for markings in (ours, theirs)]
    textures = [tx.grass(rng), *carriageways, tx.guard_rail(rng),
                tx.noise_wall(rng), tx.foliage(rng), tx.bark(rng), tx.hillside(rng),
                *(tx.direction_sign(rng, GANTRY_SIGN) for _ in range(3))]
    palette, first = with_textures(textured_palette(seed), textures)
    look = HighwayMaterials(carriageway=first + 1, oncoming=first + 2, guard_rail=first + 3,
                            noise_wall=first + 4, foliage=first + 5, bark=first + 6, hillside=first + 7,
                            gantry_signs=(first + 8, first + 9, first + 10))
    return replace(palette, ground=first), look


def highway_speed(seed: int) -> Callable[[np.ndarray], np.ndarray]:
    """The camera's speed [m/s] at times [s] in ``highway``: a sine about `HIGHWAY_SPEED`'s
    mean, its period and phase drawn from ``seed``."""
    rng = rng_for(seed, 31)
    mean, swing, periods = HIGHWAY_SPEED
    period, phase = rng.uniform(*periods), rng.uniform(0.0, 2.0 * np.pi)

    def speed(t: np.ndarray) -> np.ndarray:
        return mean + swing * np.sin(2.0 * np.pi * t / period + phase)

    return speed


def guard_rail(path: Path, edges: np.ndarray, lateral: float, facing_right: bool, rng: np.random.Generator,
               palette: Palette, look: HighwayMaterials) -> list[Quads]:
    """A W-beam guard rail at offset ``lateral`` [m] facing the road (right or left) along
    strips ``edges`` (n+1,): the beam (`RAIL_BEAM`) on 12 cm posts set 10 cm behind it,
    with gaps drawn from ``rng`` within `RAIL_POST_SPACING`."""
    bottom, height = RAIL_BEAM
    beam = wall_band(path, edges, lateral, facing_right, height, look.guard_rail, 1.0, lift=bottom)
    gaps = rng.uniform(*RAIL_POST_SPACING, size=int((edges[-1] - edges[0]) / RAIL_POST_SPACING[0]) + 1)
    s = edges[0] + np.cumsum(gaps)
    s = s[s < edges[-1]]
    facing = 1.0 if facing_right else -1.0
    normal = facing * right_of(path.heading_at(s))
    posts = wall(path.ground_point(s, lateral - 0.1 * facing), normal, 0.12, bottom + height, palette.metal, 0.9)
    return [beam, posts]


def median_lamps(path: Path, s_start: float, s_end: float, rng: np.random.Generator,
                 palette: Palette) -> list[Quads]:
    """Lamp posts in the middle of the median every 45-55 m: 10-11 m masts with a 2.5-3 m
    arm over our carriageway (`pole`)."""
    lateral = 0.5 * (CARRIAGEWAY_LEFT + ONCOMING_RIGHT)
    parts = []
    s = s_start + rng.uniform(0.0, 50.0)
    while s < s_end:
        lamp = pole(rng.uniform(10.0, 11.0), rng.uniform(2.5, 3.0), palette.metal, None)
        parts.append(lamp.transformed(path.pose(s, lateral, np.pi)))
        s += rng.uniform(45.0, 55.0)
    return parts


def gantries(path: Path, s_end: float, rng: np.random.Generator, palette: Palette,
             look: HighwayMaterials) -> list[Quads]:
    """Sign gantries over our carriageway, the first 60-140 m ahead of the start, then every
    250-450 m: legs at `GANTRY_LEGS`, a sign 5.2-5.6 m above the road over each lane in
    four of five."""
    left, right = GANTRY_LEGS
    centre = 0.5 * (left + right)
    parts = []
    s = rng.uniform(60.0, 140.0)
    while s < s_end:
        signs = []
        for lane in (-1.0, 0.0, 1.0):
            if rng.random() < 0.8:
                material = look.gantry_signs[int(rng.integers(len(look.gantry_signs)))]
                signs.append((lane * HIGHWAY_LANE - centre, GANTRY_SIGN[0], material))
        frame = gantry(right - left, rng.uniform(5.2, 5.6), palette.metal, signs)
        parts.append(frame.transformed(path.pose(s, centre)))
        s += rng.uniform(250.0, 450.0)
    return parts


def noise_walls(path: Path, s_start: float, s_end: float, rng: np.random.Generator,
                look: HighwayMaterials) -> list[Quads]:
    """Noise barriers on the right (`NOISE_WALL`): sections of 80-250 m with gaps of
    60-200 m between them."""
    lateral, height = NOISE_WALL
    parts = []
    s = s_start + rng.uniform(0.0, 150.0)
    while s < s_end:
        length = rng.uniform(80.0, 250.0)
        edges = strip_edges(path, s, min(s + length, s_end))
        parts.append(wall_band(path, edges, lateral, False, height, look.noise_wall, 1.0))
        s += length + rng.uniform(60.0, 200.0)
    return parts


def roadside_trees(path: Path, s_start: float, s_end: float, side: int, rng: np.random.Generator,
                   look: HighwayMaterials) -> list[Quads]:
    """Sparse trees along one side (``side`` +1 right, -1 left) every 10-40 m: 14-45 m to
    the right of our lane, or 30-70 m to its left (beyond the oncoming carriageway);
    trunks 1.5-3 m tall, crowns 3-6 m wide and tall."""
    near, far = (14.0, 45.0) if side > 0 else (30.0, 70.0)
    parts = []
    s = s_start + rng.uniform(0.0, 20.0)
    while s < s_end:
        crown = rng.uniform(3.0, 6.0)
        quads = tree(rng.uniform(1.5, 3.0), crown, rng.uniform(3.0, 6.0), look.bark, look.foliage)
        parts.append(quads.transformed(path.pose(s, side * rng.uniform(near, far), rng.uniform(0.0, 0.5 * np.pi))))
        s += rng.uniform(10.0, 40.0)
    return parts


def hill(rng: np.random.Generator, width: float, height: float, material: int) -> Quads:
    """A wooded hill in its object frame, facing -z: three walls, each narrower, taller and
    15 m further back than the one before, up to ``height`` [m] (a stepped skyline). Each
    wall's texture is placed by its position, so the tiers show one continuous hillside."""
    parts = []
    for tier in range(3):
        tier_width, tier_height = width * (1.0 - 0.3 * tier), height * (0.5 + 0.25 * tier)
        x = rng.uniform(-0.15, 0.15) * width
        parts.append(wall(np.array([x, 0.0, 15.0 * tier]), np.array([0.0, 0.0, -1.0]), tier_width, tier_height,
                          material, 1.0, (x - 0.5 * tier_width, -tier_height)))
    return Quads.concat(parts)


def far_scenery(path: Path, s_start: float, s_end: float, side: int, rng: np.random.Generator,
                palette: Palette, look: HighwayMaterials) -> list[Quads]:
    """Distant structure along one side (``side`` +1 right, -1 left), facing the road, every
    40-120 m: a building (15-60 m wide, 7-28 m tall, 50-300 m off the road) or a wooded
    hill (`hill`: 80-200 m wide, 15-40 m tall, 120-300 m off), one each in two."""
    parts = []
    s = s_start + rng.uniform(0.0, 60.0)
    while s < s_end:
        if rng.random() < 0.5:
            lateral = rng.uniform(50.0, 300.0)
            width, height = 3.0 * rng.integers(5, 21), tx.FLOOR_HEIGHT * rng.integers(1, 9) + 4.0
            quads = make_building(palette, rng, width, rng.uniform(12.0, 30.0), height)
        else:
            lateral = rng.uniform(120.0, 300.0)
            quads = hill(rng, rng.uniform(80.0, 200.0), rng.uniform(15.0, 40.0), look.hillside)
        parts.append(quads.transformed(path.pose(s, side * lateral, side * 0.5 * np.pi)))
        s += rng.uniform(40.0, 120.0)
    return parts


def highway(path: Path, s_start: float, s_end: float, seed: int, palette: Palette,
            look: HighwayMaterials) -> Quads:
    """All static quads of the highway between two arc lengths: the ground plane (grass),
    both carriageways (ours in two bands split on the camera lane centre, as the street's
    road), the `GUARD_RAILS`, and the lamps, gantries, noise barriers, trees and far
    scenery, each from its own random stream."""
    edges = strip_edges(path, s_start, s_end)
    parts = [
        ground_plane(path.position, palette),
        ground_band(path, edges, CARRIAGEWAY_LEFT, 0.0, 0.0, look.carriageway, 1.0, 0.0),
        ground_band(path, edges, 0.0, CARRIAGEWAY_RIGHT, 0.0, look.carriageway, 1.0, -CARRIAGEWAY_LEFT),
        ground_band(path, edges, ONCOMING_LEFT, ONCOMING_RIGHT, 0.0, look.oncoming, 1.0, 0.0),
    ]
    for k, (lateral, facing_right) in enumerate(GUARD_RAILS):
        parts += guard_rail(path, edges, lateral, facing_right, rng_for(seed, 45, k), palette, look)
    parts += median_lamps(path, s_start, s_end, rng_for(seed, 40), palette)
    parts += gantries(path, s_end, rng_for(seed, 41), palette, look)
    parts += noise_walls(path, s_start, s_end, rng_for(seed, 42), look)
    for side in (1, -1):
        parts += roadside_trees(path, s_start, s_end, side, rng_for(seed, 43, side + 1), look)
        parts += far_scenery(path, s_start, s_end, side, rng_for(seed, 44, side + 1), palette, look)
    return Quads.concat(parts)


def lane_traffic(path: Path, camera_s: np.ndarray, times: np.ndarray, flow: tuple, rng: np.random.Generator,
                 palette: Palette, first_id: int) -> list[MovingObject]:
    """The vehicles of one ``flow`` of `HIGHWAY_FLOWS` at ``times`` (N,) [s], the camera at
    arc lengths ``camera_s`` (N,) [m]: all at one speed drawn from the flow's range (so
    none catches up with another), spaced by gaps drawn from its range over the stretch
    from which they come within 30 m behind to `HIGHWAY_VIEW_AHEAD` ahead of the camera
    at some frame; trucks in the flow's share, cars otherwise; ids from ``first_id``."""
    lateral, speeds, gaps, truck_share = flow
    speed = rng.uniform(*speeds)
    start_behind_camera = camera_s - speed * times
    low = float(start_behind_camera.min()) - 30.0
    high = float(start_behind_camera.max()) + HIGHWAY_VIEW_AHEAD
    lanes, yaw = np.full_like(times, lateral), np.full_like(times, 0.0 if speed > 0.0 else np.pi)
    movers = []
    s = low + rng.uniform(0.0, gaps[1])
    while s < high:
        truck, paint = rng.random() < truck_share, float(rng.uniform(0.3, 1.1))
        body = box(*TRUCK_SIZE, palette.truck, 0.9) if truck else box(*CAR_SIZE, palette.car, paint)
        movers.append(mover(first_id + len(movers), body, track_poses(path, s + speed * times, lanes, yaw)))
        s += rng.uniform(*gaps)
    return movers


def highway_traffic(path: Path, camera_s: np.ndarray, times: np.ndarray, seed: int,
                    palette: Palette) -> tuple[MovingObject, ...]:
    """The movers of ``highway``: every flow of `HIGHWAY_FLOWS` (`lane_traffic`): cars and
    trucks overtaking us on the left and oncoming traffic in three lanes beyond the median."""
    rng = rng_for(seed, 33)
    movers: list[MovingObject] = []
    for flow in HIGHWAY_FLOWS:
        movers += lane_traffic(path, camera_s, times, flow, rng, palette, len(movers) + 1)
    return tuple(movers)


def highway_world(times: np.ndarray, seed: int) -> tuple[np.ndarray, Scene]:
    """Camera poses and scene of ``highway``: a gently curving motorway (`highway_path`)
    driven in the middle of three lanes at 20-25 m/s (`highway_speed`), with the ride of
    `HIGHWAY_RIDE`, its roadside (`highway`) and its traffic (`highway_traffic`)."""
    s = arc_lengths(times, highway_speed(seed))
    s_end = s[-1] + HIGHWAY_VIEW_AHEAD
    reach = TRAFFIC_REACH * float(times[-1])
    path = highway_path(seed, -HIGHWAY_BEHIND - reach, s_end + reach)
    palette, look = highway_palette(seed)
    static = highway(path, -HIGHWAY_BEHIND, s_end, seed, palette, look)
    movers = highway_traffic(path, s, times, seed, palette)
    return camera_poses(path, s, HIGHWAY_RIDE_PERIOD, HIGHWAY_RIDE), make_scene(static, palette, moving=movers)


# --- scenarios ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class Scenario:
    """A synthetic stereo sequence held in memory; frames are rendered on demand.

    Attributes
    ----------
    name : str
        One of `SCENARIOS`.
    seed : int
        Seed of the scene, textures, movers and sensor noise.
    camera : StereoCamera
        The rectified stereo camera.
    poses : np.ndarray
        (N, 4, 4) ground-truth ``T_w_c`` of the left camera; ``poses[0]`` is the identity.
    timestamps : np.ndarray
        (N,) frame times [s] at `FRAME_RATE`.
    scene : Scene
        The quads, movers, textures and light.
    """

    name: str
    seed: int
    camera: StereoCamera
    poses: np.ndarray
    timestamps: np.ndarray
    scene: Scene

    @property
    def n_frames(self) -> int:
        return len(self.poses)

    def render_frame(self, index: int) -> SynthFrame:
        """Left and right uint8 images and the left dynamic mask of frame ``index``."""
        return render_stereo_frame(self.scene, self.camera, self.poses[index], index, self.seed)

    def render_views(self, index: int) -> tuple[View, View]:
        """Noise-free left and right views (with depth and id buffers) of frame ``index``."""
        return render_stereo_views(self.scene, self.camera, self.poses[index], index)


def check_request(name: str, n_frames: int | None) -> int:
    """The frame count to render, or a `PldSlamError` naming what is wrong with the request."""
    if name not in SCENARIOS:
        raise PldSlamError(f"unknown synthetic scenario {name!r}; choose one of {', '.join(SCENARIOS)}")
    frames = DEFAULT_FRAMES[name] if n_frames is None else n_frames
    if frames < 1:
        raise PldSlamError(f"scenario {name!r} needs at least 1 frame, got {frames}")
    fewest, purpose = MIN_FRAMES.get(name, (1, ""))
    if frames < fewest:
        raise PldSlamError(f"scenario {name!r} needs at least {fewest} frames {purpose}, got {frames}")
    return int(frames)


def lap_arc_lengths(path: Path, frames: int, laps: int) -> tuple[np.ndarray, np.ndarray]:
    """Arc lengths (N,) of ``frames`` camera positions spread evenly over ``laps`` laps of
    the closed ``path``, and the distance driven (N,) [m] at each. Frame i sits at
    ``L * (laps * i / (N - 1) mod 1)``: the last pose is the first one, bit for bit."""
    fraction = laps * np.arange(frames) / (frames - 1)
    return path.length * (fraction % 1.0), path.length * fraction


def make_scene(static: Quads, palette: Palette, **changes) -> Scene:
    """The scene of ``static`` quads with ``palette``'s textures; by default no movers and
    the light `SUN`, or else as given in ``changes`` (`Scene` fields)."""
    fields = {"moving": (), "light": SUN, **changes}
    return Scene(static=static, atlas=tx.TextureAtlas.build(palette.textures), **fields)


def loop_world(frames: int, seed: int) -> tuple[np.ndarray, Scene]:
    """Camera poses and scene of ``loop``: once round the block."""
    path = loop_path()
    s, _ = lap_arc_lengths(path, frames, laps=1)
    palette = textured_palette(seed)
    static = street(path, 0.0, path.length, seed, palette)
    return camera_poses(path, s, period=path.length), make_scene(static, palette)


def two_lap_world(frames: int, seed: int) -> tuple[np.ndarray, Scene]:
    """Camera poses and scene of ``loop2``: twice round ``loop``'s block, with other parked
    cars (`parked_visits`) and another light (`lap_light`) on the second lap."""
    path = loop_path()
    s, driven = lap_arc_lengths(path, frames, laps=2)
    palette = textured_palette(seed)
    static = street(path, 0.0, path.length, seed, palette, parked=False)
    light, exposure = lap_light(driven, path.length)
    scene = make_scene(static, palette, light=light, exposure=exposure,
                       transient=parked_visits(path, driven, seed, palette))
    return camera_poses(path, s, period=path.length), scene


def nearmiss_world(frames: int, seed: int) -> tuple[np.ndarray, Scene]:
    """Camera poses and scene of ``nearmiss``: out along a street, round the block halfway
    through the drive, and back along the parallel street."""
    s = STREET_STEP * np.arange(frames)
    s_end = s[-1] + VIEW_AHEAD
    leg = 0.5 * (s[-1] - nearmiss_turn_length())
    path = nearmiss_path(leg, s_end + 10.0 - leg - nearmiss_turn_length())
    palette = textured_palette(seed)
    static = street(path, -25.0, s_end, seed, palette)
    return camera_poses(path, s, period=120.0), make_scene(static, palette)


def convoy_world(times: np.ndarray, seed: int) -> tuple[np.ndarray, Scene]:
    """Camera poses and scene of ``convoy``: the street of ``static`` driven at a varying
    speed (`CONVOY_SPEED`) with a bus and a queue of cars going our way (`convoy_traffic`)."""
    s = arc_lengths(times, convoy_speed)
    s_end = s[-1] + VIEW_AHEAD
    path = street_path(seed, -PATH_BEHIND, s_end + 10.0)
    palette = textured_palette(seed)
    rng = rng_for(seed, 7)
    palette, bus = with_box_materials(palette, tx.bus_side(rng, (BUS_SIZE[2], BUS_SIZE[1])),
                                      tx.truck_rear(rng, BUS_SIZE[:2]))
    static = street(path, -25.0, s_end, seed, palette)
    movers = convoy_traffic(path, s, times, seed, palette, bus)
    return camera_poses(path, s, period=120.0), make_scene(static, palette, moving=movers)


def crossing_world(times: np.ndarray, seed: int) -> tuple[np.ndarray, Scene]:
    """Camera poses and scene of ``crossing``: the street of ``static``, the camera stopping
    at a junction every 19 s (`CROSSING_CYCLE`) while a crowd crosses (`crossing_crowd`)."""
    s = arc_lengths(times, crossing_speed)
    s_end = s[-1] + VIEW_AHEAD
    path = street_path(seed, -PATH_BEHIND, s_end + 10.0)
    palette = textured_palette(seed)
    static = street(path, -25.0, s_end, seed, palette)
    movers = crossing_crowd(path, s, times, seed, palette)
    return camera_poses(path, s, period=120.0), make_scene(static, palette, moving=movers)


def parked_then_moving_world(times: np.ndarray, seed: int) -> tuple[np.ndarray, Scene]:
    """Camera poses and scene of ``parked_then_moving``: the street of ``static`` at 8 m/s,
    with cars that stay parked long enough to enter the map, then drive off (`parked_movers`)."""
    s = STREET_STEP * np.arange(len(times))
    s_end = s[-1] + VIEW_AHEAD
    path = street_path(seed, -PATH_BEHIND, s_end + 10.0)
    palette = textured_palette(seed)
    movers, spots = parked_movers(path, s, times, seed, palette)
    static = Quads.concat([street(path, -25.0, s_end, seed, palette, parked=False),
                           *parked_cars_clear_of(path, -25.0, s_end, seed, palette, spots)])
    return camera_poses(path, s, period=120.0), make_scene(static, palette, moving=movers)


TRAFFIC_WORLDS: dict[str, Callable[[np.ndarray, int], tuple[np.ndarray, Scene]]] = {
    "convoy": convoy_world,
    "crossing": crossing_world,
    "parked_then_moving": parked_then_moving_world,
}
"""The scenarios of movers a robust solve follows, each built from the frame times and the seed."""


def street_world(name: str, times: np.ndarray, seed: int) -> tuple[np.ndarray, Scene]:
    """Camera poses and scene of ``static``, ``dynamic`` or ``lowtexture`` at frame
    ``times`` (N,) [s]: along a gently curved street."""
    s = STREET_STEP * np.arange(len(times))
    s_end = s[-1] + VIEW_AHEAD
    path = street_path(seed, -PATH_BEHIND, s_end + 10.0)
    palette = plain_palette() if name == "lowtexture" else textured_palette(seed)
    static = street(path, -25.0, s_end, seed, palette)
    movers = traffic(path, s, times, s_end, seed, palette) if name == "dynamic" else ()
    return camera_poses(path, s, period=120.0), make_scene(static, palette, moving=movers)


def build_scenario(name: str, n_frames: int | None = None, size: tuple[int, int] | None = None,
                   seed: int = 0, camera: str = "default") -> Scenario:
    """Build scenario ``name`` (one of `SCENARIOS`) with ``n_frames`` frames (default per
    `DEFAULT_FRAMES`) seen by the stereo ``camera`` (one of `CAMERAS`) from ``seed``.

    ``size = (width, height)`` [px] is the ``default`` camera's image size (None:
    `DEFAULT_SIZE`); the ``kitti`` camera's is fixed (see `make_camera`). The camera
    changes only the images: the scene and poses are the same for both.

    Raises
    ------
    PldSlamError
        For an unknown name or camera, a non-positive size or one that conflicts with the
        camera, or fewer frames than `MIN_FRAMES` asks (``loop``: `MIN_LOOP_FRAMES`).
    """
    frames = check_request(name, n_frames)
    rig = make_camera(camera, size)
    times = np.arange(frames) / FRAME_RATE
    if name == "loop":
        poses, scene = loop_world(frames, seed)
    elif name == "loop2":
        poses, scene = two_lap_world(frames, seed)
    elif name == "nearmiss":
        poses, scene = nearmiss_world(frames, seed)
    elif name == "highway":
        poses, scene = highway_world(times, seed)
    elif name == "city":
        from pld_slam.synth.city import city_world  # the city is built of this module's streets

        poses, scene = city_world(times, seed)
    elif name in TRAFFIC_WORLDS:
        poses, scene = TRAFFIC_WORLDS[name](times, seed)
    else:
        poses, scene = street_world(name, times, seed)
    return Scenario(name=name, seed=seed, camera=rig, poses=poses, timestamps=times, scene=scene)
