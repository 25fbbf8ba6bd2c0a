"""Procedural textures of the synthetic world, and the mip-mapped atlas the renderer samples.

A `Texture` is a tileable grey image (float32 grey levels 0..255) together with the size in
metres of the surface patch one tile covers. Columns run along a quad's edge ``a`` and rows
along its edge ``b``; for a wall that is left to right and top to bottom as seen from the
front, for a floor right and backwards as seen from above. Texel counts are powers of two
so that tiling is a bit mask.

The textures have structure, not noise, so that ORB and LSD get real work: mortar lines and
a shade per brick, window grids with frames and sills, lane markings, paving joints, planks,
car windows and wheels. A faint low-contrast grain stands for the material itself.
Everything random comes from the ``rng`` handed in, so a scenario's seed fixes every texel.
"""

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
import scipy.fft

N_MIP_LEVELS = 6
"""Levels per mip pyramid: level k has 2**-k of the texels per metre of level 0."""


@dataclass(frozen=True)
class Texture:
    """A tileable grey image and the patch of surface one tile covers.

    Attributes
    ----------
    texels : np.ndarray
        (H, W) float32 grey levels in [0, 255]; H and W are powers of two. Row 0, column 0
        sits at the quad origin; columns run along edge ``a``, rows along edge ``b``.
    size_m : tuple of float
        (width, height) [m] of one tile along ``a`` and ``b``.
    """

    texels: np.ndarray
    size_m: tuple[float, float]


# --- drawing primitives (texel units, row 0 at the top) ------------------------------------


def periodic_noise(rng: np.random.Generator, shape: tuple[int, int],
                   components: Sequence[tuple[float, float]]) -> np.ndarray:
    """Tileable smooth noise (H, W) float32 with zero mean.

    One white noise is low-passed in the Fourier domain by a sum of Gaussians, one per
    ``(sigma, std)`` component (``sigma`` in texels): the result is periodic over the tile by
    construction and each component contributes about ``std`` grey levels.
    """
    white = rng.standard_normal(shape, dtype=np.float32)
    freq_rows = np.fft.fftfreq(shape[0]).astype(np.float32)[:, None]
    freq_cols = np.fft.rfftfreq(shape[1]).astype(np.float32)[None, :]
    radius2 = freq_rows**2 + freq_cols**2
    gain = np.zeros_like(radius2)
    for sigma, std in components:
        lowpass = np.exp(np.float32(-2.0 * (np.pi * sigma) ** 2) * radius2)
        gain += std * lowpass / np.sqrt(np.mean(lowpass**2))
    return scipy.fft.irfft2(scipy.fft.rfft2(white) * gain, s=shape).astype(np.float32)


def grain(rng: np.random.Generator, shape: tuple[int, int], amplitude: float) -> np.ndarray:
    """Material grain (H, W): fine noise plus broad blotches, about ``amplitude`` grey levels."""
    return periodic_noise(rng, shape, ((0.8, 0.6 * amplitude), (max(shape) / 16.0, 0.8 * amplitude)))


def fill(texels: np.ndarray, box: tuple[float, float, float, float], value: float) -> None:
    """Set the texels of ``box = (col0, row0, col1, row1)`` (half-open, rounded) to ``value``."""
    c0, r0, c1, r1 = (int(round(x)) for x in box)
    texels[max(r0, 0) : max(r1, 0), max(c0, 0) : max(c1, 0)] = value


def shade(texels: np.ndarray, box: tuple[float, float, float, float], factor) -> None:
    """Multiply the texels of ``box = (col0, row0, col1, row1)`` by ``factor`` (scalar or array)."""
    c0, r0, c1, r1 = (int(round(x)) for x in box)
    texels[max(r0, 0) : max(r1, 0), max(c0, 0) : max(c1, 0)] *= factor


def outline(texels: np.ndarray, box: tuple[float, float, float, float], width: float,
            value: float) -> None:
    """Draw a frame of ``width`` texels inside ``box = (col0, row0, col1, row1)``."""
    c0, r0, c1, r1 = box
    fill(texels, (c0, r0, c1, r0 + width), value)
    fill(texels, (c0, r1 - width, c1, r1), value)
    fill(texels, (c0, r0, c0 + width, r1), value)
    fill(texels, (c1 - width, r0, c1, r1), value)


def disc(texels: np.ndarray, centre: tuple[float, float], radius: float, value: float) -> None:
    """Set the texels within ``radius`` of ``centre = (col, row)`` to ``value``."""
    col, row = centre
    r0, r1 = int(max(row - radius, 0)), int(min(row + radius + 1, texels.shape[0]))
    c0, c1 = int(max(col - radius, 0)), int(min(col + radius + 1, texels.shape[1]))
    rows = np.arange(r0, r1)[:, None]
    cols = np.arange(c0, c1)[None, :]
    inside = (rows - row) ** 2 + (cols - col) ** 2 <= radius**2
    texels[r0:r1, c0:c1][inside] = value


def wheels(texels: np.ndarray, axles: Sequence[float], radius: float, hub_ratio: float, hub_value: float) -> None:
    """Tyres of ``radius`` [texels] standing on the bottom edge of a vehicle flank, at ``axles``
    (fractions of the width), each with a hub of ``hub_ratio`` times the radius and grey ``hub_value``."""
    height, width = texels.shape
    for axle in axles:
        centre = (axle * width, height - radius)
        disc(texels, centre, radius, 30.0)
        disc(texels, centre, hub_ratio * radius, hub_value)


def vertical_gradient(rows: int, top: float, bottom: float) -> np.ndarray:
    """A column (rows, 1) going linearly from ``top`` to ``bottom`` grey levels."""
    return np.linspace(top, bottom, rows, dtype=np.float32)[:, None]


def brick_pattern(rng: np.random.Generator, shape: tuple[int, int], courses: int,
                  bricks_per_course: int, base: float, mortar: float) -> np.ndarray:
    """Stretcher-bond brickwork (H, W): a shade per brick, one-texel light mortar joints.

    ``courses`` and ``bricks_per_course`` tile the texture exactly (courses even).
    """
    height, width = shape
    brick_h = height / courses
    brick_w = width / bricks_per_course
    rows = np.arange(height, dtype=np.float32)[:, None]
    cols = np.arange(width, dtype=np.float32)[None, :]
    course = np.floor(rows / brick_h).astype(np.int64)
    shifted = cols + (course % 2) * (brick_w / 2.0)
    column = np.floor(shifted / brick_w).astype(np.int64) % bricks_per_course
    brick_shade = rng.normal(1.0, 0.12, size=(courses, bricks_per_course)).astype(np.float32)
    bricks = base * brick_shade[course, column]
    joints = ((rows % brick_h) < 1.0) | ((shifted % brick_w) < 1.0)
    return np.where(joints, np.float32(mortar), bricks).astype(np.float32)


def slab_pattern(rng: np.random.Generator, shape: tuple[int, int], slabs: tuple[int, int],
                 base: float, joint: float, joint_width: float, variation: float) -> np.ndarray:
    """A grid of slabs (H, W): ``slabs = (across, down)`` per tile, a shade per slab, dark joints."""
    height, width = shape
    slab_w, slab_h = width / slabs[0], height / slabs[1]
    rows = np.arange(height)[:, None]
    cols = np.arange(width)[None, :]
    slab_shade = rng.normal(1.0, variation, size=(slabs[1], slabs[0])).astype(np.float32)
    texels = base * slab_shade[(rows // slab_h).astype(np.int64), (cols // slab_w).astype(np.int64)]
    joints = ((rows % slab_h) < joint_width) | ((cols % slab_w) < joint_width)
    return np.where(joints, np.float32(joint), texels).astype(np.float32)


def window(texels: np.ndarray, rng: np.random.Generator, box: tuple[float, float, float, float],
           frame: float, frame_value: float) -> None:
    """A framed two-pane window in ``box = (col0, row0, col1, row1)``: dark glass with a sky
    reflection gradient, a mullion, a random curtain or blind, and a light sill below it."""
    c0, r0, c1, r1 = box
    glass = vertical_gradient(int(round(r1)) - int(round(r0)), rng.uniform(55, 95), rng.uniform(25, 50))
    fill(texels, box, 0.0)
    texels[int(round(r0)) : int(round(r1)), int(round(c0)) : int(round(c1))] += glass
    curtain = rng.uniform(0.0, 0.6)
    if rng.random() < 0.5:
        fill(texels, (c0, r0, c1, r0 + curtain * (r1 - r0)), rng.uniform(150, 220))
    else:
        slat = max(3.0, (r1 - r0) / 12.0)
        for row in np.arange(r0, r0 + curtain * (r1 - r0), slat):
            fill(texels, (c0, row, c1, row + slat / 2.0), rng.uniform(120, 170))
    outline(texels, box, frame, frame_value)
    mid = (c0 + c1) / 2.0
    fill(texels, (mid - frame / 2.0, r0, mid + frame / 2.0, r1), frame_value)
    fill(texels, (c0 - 2 * frame, r1, c1 + 2 * frame, r1 + 1.5 * frame), frame_value + 15.0)


# --- ground ---------------------------------------------------------------------------------


def asphalt_texels(rng: np.random.Generator, shape: tuple[int, int]) -> np.ndarray:
    """Asphalt (H, W): grey 95 with fine grain and faint blotches, and two darker repair
    patches with straight edges."""
    texels = 95.0 + periodic_noise(rng, shape, ((0.8, 4.0), (max(shape) / 16.0, 2.0)))
    for _ in range(2):
        w, h = rng.uniform(0.05, 0.15) * shape[1], rng.uniform(0.05, 0.15) * shape[0]
        c, r = rng.uniform(0, shape[1] - w), rng.uniform(0, shape[0] - h)
        shade(texels, (c, r, c + w, r + h), rng.uniform(0.85, 0.92))
    return texels


def sealed_cracks(texels: np.ndarray, rng: np.random.Generator, count: int,
                  per_m: tuple[float, float]) -> None:
    """Draw ``count`` cracks sealed with dark bitumen into ``texels`` (H, W) in place: each a
    random walk of 3-8 straight pieces of 20-60 cm, 2-3 cm wide; ``per_m`` = texels per
    metre across and along."""
    for _ in range(count):
        point = rng.uniform((0.0, 0.0), texels.shape[::-1])
        heading = rng.uniform(0.0, 2.0 * np.pi)
        points = [point]
        for _ in range(int(rng.integers(3, 9))):
            heading += rng.uniform(-0.8, 0.8)
            point = point + rng.uniform(0.2, 0.6) * np.array([np.cos(heading) * per_m[0], np.sin(heading) * per_m[1]])
            points.append(point)
        cv2.polylines(texels, [np.round(points).astype(np.int32)], False, float(rng.uniform(45.0, 60.0)),
                      thickness=int(rng.integers(2, 4)))


def asphalt(rng: np.random.Generator) -> Texture:
    """Plain asphalt without markings, 8 m x 8 m per tile (the open ground)."""
    return Texture(asphalt_texels(rng, (512, 512)), (8.0, 8.0))


def road(rng: np.random.Generator, width_m: float, dashed_at: Sequence[float],
         solid_at: Sequence[float], cracks: int = 0, length_m: float = 8.0) -> Texture:
    """A road across its whole width ``width_m`` and ``length_m`` along (8 m times a power
    of two), with lane markings.

    Columns run across the road from its left edge, rows along it. ``dashed_at`` and
    ``solid_at`` are the lateral positions [m from the left edge] of 12 cm lines: dashed
    ones 3 m painted, 5 m gap (one period per 8 m); solid ones 10 cm wide. A manhole
    cover sits in one lane. ``cracks`` sealed cracks (`sealed_cracks`) are drawn under
    the paint: a tile longer than the markings' period keeps the asphalt from repeating
    with them.
    """
    per_m_along = 512 / 8.0
    shape = (int(per_m_along * length_m), 512)
    texels = asphalt_texels(rng, shape)
    if cracks:
        sealed_cracks(texels, rng, cracks, (shape[1] / width_m, per_m_along))
    per_m_across = shape[1] / width_m
    paint = 215.0
    for lateral in dashed_at:
        c = lateral * per_m_across
        for start in np.arange(0.0, length_m, 8.0) * per_m_along:
            fill(texels, (c - 0.06 * per_m_across, start, c + 0.06 * per_m_across, start + 3.0 * per_m_along), paint)
    for lateral in solid_at:
        c = lateral * per_m_across
        fill(texels, (c - 0.05 * per_m_across, 0, c + 0.05 * per_m_across, shape[0]), paint)
    manhole = (rng.uniform(0.3, 0.7) * shape[1], 6.0 * per_m_along)
    disc(texels, manhole, 0.32 * per_m_along, 70.0)
    disc(texels, manhole, 0.26 * per_m_along, 105.0)
    return Texture(texels, (width_m, length_m))


def paving(rng: np.random.Generator) -> Texture:
    """Sidewalk paving: 50 cm slabs with a shade each and dark joints, 4 m x 4 m per tile."""
    shape = (512, 512)
    texels = slab_pattern(rng, shape, (8, 8), 160.0, 95.0, 2.0, 0.07)
    return Texture(texels + grain(rng, shape, 4.0), (4.0, 4.0))


def curb(rng: np.random.Generator) -> Texture:
    """Curb stones: 1 m granite blocks with joints, 4 m x 0.25 m per tile."""
    shape = (32, 512)
    texels = slab_pattern(rng, shape, (4, 1), 175.0, 110.0, 2.0, 0.06)
    return Texture(texels + grain(rng, shape, 5.0), (4.0, 0.25))


# --- buildings ------------------------------------------------------------------------------

FLOOR_HEIGHT = 3.0
"""Storey height [m] of every facade texture; a facade tile is 4 storeys by 4 bays of 3 m."""


def _window_grid(texels: np.ndarray, rng: np.random.Generator, frame_value: float,
                 size: tuple[float, float], sill: float) -> None:
    """Windows of ``size = (width, height)`` [m] centred in each 3 m bay of each storey."""
    per_m = texels.shape[1] / 12.0
    bay = FLOOR_HEIGHT * per_m
    win_w, win_h = size[0] * per_m, size[1] * per_m
    for storey in range(4):
        for column in range(4):
            c0 = column * bay + (bay - win_w) / 2.0
            r0 = storey * bay + (bay - sill * per_m - win_h)
            window(texels, rng, (c0, r0, c0 + win_w, r0 + win_h), 0.08 * per_m, frame_value)


def brick_facade(rng: np.random.Generator) -> Texture:
    """Upper storeys of a brick building: brickwork with a 4 x 4 grid of framed windows."""
    base = rng.uniform(95, 140)
    texels = brick_pattern(rng, (1024, 1024), 160, 48, base, base + rng.uniform(40, 70))
    texels += grain(rng, texels.shape, 3.0)
    _window_grid(texels, rng, rng.uniform(190, 230), (1.3, 1.7), 0.9)
    return Texture(texels, (12.0, 12.0))


def plaster_facade(rng: np.random.Generator) -> Texture:
    """Upper storeys of a plastered building: light render, a cornice band per storey, windows."""
    shape = (1024, 1024)
    per_m = shape[1] / 12.0
    texels = rng.uniform(165, 205) + grain(rng, shape, 4.0)
    band = rng.uniform(0.7, 0.85)
    for storey in range(4):
        top = storey * FLOOR_HEIGHT * per_m
        shade(texels, (0, top, shape[1], top + 0.25 * per_m), band)
    _window_grid(texels, rng, rng.uniform(225, 245), (1.2, 1.6), 0.8)
    return Texture(texels, (12.0, 12.0))


def panel_facade(rng: np.random.Generator) -> Texture:
    """Upper storeys of an office block: concrete panels with dark joints and wide windows."""
    shape = (1024, 1024)
    texels = slab_pattern(rng, shape, (8, 8), rng.uniform(130, 175), 70.0, 2.0, 0.05)
    texels += grain(rng, shape, 3.0)
    _window_grid(texels, rng, rng.uniform(90, 120), (2.2, 1.4), 1.0)
    return Texture(texels, (12.0, 12.0))


def shopfront(rng: np.random.Generator) -> Texture:
    """A ground floor 12 m x 4 m: sign band with lettering blocks, display windows, doors, plinth."""
    shape = (512, 1024)
    per_m_across, per_m_down = shape[1] / 12.0, shape[0] / 4.0
    texels = rng.uniform(120, 190) + grain(rng, shape, 4.0)
    sign_value = rng.choice([45.0, 225.0])
    fill(texels, (0, 0.25 * per_m_down, shape[1], 0.85 * per_m_down), sign_value)
    for shop in range(3):
        left = shop * 4.0 * per_m_across
        letters = rng.integers(4, 9)
        for k in range(letters):
            c = left + (0.6 + 0.35 * k) * per_m_across
            fill(texels, (c, 0.38 * per_m_down, c + 0.22 * per_m_across, 0.72 * per_m_down),
                 255.0 - sign_value + rng.uniform(-25, 25))
        door_at = rng.choice([0.3, 2.7])
        for start, width in ((door_at, 1.0), (1.55 if door_at < 1 else 0.3, 2.2)):
            box = (left + start * per_m_across, 1.2 * per_m_down,
                   left + (start + width) * per_m_across, 3.6 * per_m_down)
            window(texels, rng, box, 0.09 * per_m_across, rng.uniform(50, 90))
        handle = left + (door_at + 0.85) * per_m_across
        fill(texels, (handle, 2.3 * per_m_down, handle + 0.04 * per_m_across, 2.6 * per_m_down), 220.0)
    fill(texels, (0, 3.7 * per_m_down, shape[1], shape[0]), rng.uniform(70, 100))
    return Texture(texels, (12.0, 4.0))


# --- street furniture and vehicles ---------------------------------------------------------


def crate(rng: np.random.Generator) -> Texture:
    """A wooden crate side 1 m x 1 m: horizontal planks with grain and gaps, a frame of boards."""
    shape = (256, 256)
    texels = rng.uniform(140, 175) + periodic_noise(rng, shape, ((1.0, 6.0), (6.0, 3.0)))
    texels = texels * np.repeat(rng.normal(1.0, 0.08, size=(8, 1)), 32, axis=0).astype(np.float32)
    for row in range(0, 256, 32):
        fill(texels, (0, row, 256, row + 3), 55.0)
    outline(texels, (0, 0, 256, 256), 26, 120.0)
    outline(texels, (0, 0, 256, 256), 3, 60.0)
    return Texture(texels.astype(np.float32), (1.0, 1.0))


def car_side(rng: np.random.Generator, size_m: tuple[float, float]) -> Texture:
    """A car flank ``size_m = (length, height)``: body, two side windows under the roof line,
    door seams and handles, a trim line and two wheels. Body grey 200 (cars get their
    paint from the quad albedo)."""
    shape = (256, 512)
    length, height = size_m
    per_m_x, per_m_y = shape[1] / length, shape[0] / height
    texels = 200.0 + grain(rng, shape, 2.0)
    glass_top, glass_bottom = 0.1 * shape[0], 0.38 * shape[0]
    fill(texels, (0.22 * shape[1], glass_top, 0.8 * shape[1], glass_bottom), 45.0)
    fill(texels, (0.5 * shape[1] - 0.05 * per_m_x, glass_top, 0.5 * shape[1] + 0.05 * per_m_x, glass_bottom), 190.0)
    for seam in (0.25, 0.5, 0.75):
        c = seam * shape[1]
        fill(texels, (c, glass_bottom, c + 2, 0.8 * shape[0]), 70.0)
    for handle in (0.38, 0.63):
        c = handle * shape[1]
        fill(texels, (c, 0.45 * shape[0], c + 0.12 * per_m_x, 0.48 * shape[0]), 90.0)
    fill(texels, (0, 0.6 * shape[0], shape[1], 0.63 * shape[0]), 120.0)
    wheels(texels, (0.17, 0.83), 0.33 * per_m_y, 0.55, 150.0)
    return Texture(texels, size_m)


def truck_side(rng: np.random.Generator, size_m: tuple[float, float]) -> Texture:
    """A box truck flank ``size_m = (length, height)``: cab with a window at the front end,
    a cargo box with vertical ribs and a company band, three wheels."""
    shape = (256, 512)
    length, height = size_m
    per_m_x, per_m_y = shape[1] / length, shape[0] / height
    texels = 205.0 + grain(rng, shape, 2.0)
    cab = 0.25 * shape[1]
    fill(texels, (cab, 0, cab + 3, 0.85 * shape[0]), 80.0)
    fill(texels, (0.03 * shape[1], 0.3 * shape[0], 0.2 * shape[1], 0.5 * shape[0]), 45.0)
    for rib in np.arange(cab + 0.6 * per_m_x, shape[1], 0.6 * per_m_x):
        fill(texels, (rib, 0.02 * shape[0], rib + 3, 0.75 * shape[0]), 165.0)
    band = rng.uniform(60, 120)
    fill(texels, (cab + 0.4 * per_m_x, 0.25 * shape[0], shape[1] - 0.4 * per_m_x, 0.4 * shape[0]), band)
    fill(texels, (0, 0.75 * shape[0], shape[1], 0.78 * shape[0]), 60.0)
    wheels(texels, (0.12, 0.7, 0.85), 0.5 * per_m_y, 0.5, 140.0)
    return Texture(texels, size_m)


def bus_side(rng: np.random.Generator, size_m: tuple[float, float]) -> Texture:
    """A bus flank ``size_m = (length, height)``: a row of framed windows, an advertising
    panel of blotchy print under them, doors, a skirt line and two wheels. The windows and
    the print give a bus alongside as many corners and edges as a facade (`convoy`)."""
    shape = (512, 1024)
    length, height = size_m
    per_m_x, per_m_y = shape[1] / length, shape[0] / height
    texels = 210.0 + grain(rng, shape, 2.0)
    for left in np.arange(0.4 * per_m_x, shape[1] - 1.4 * per_m_x, 1.5 * per_m_x):
        window(texels, rng, (left, 0.12 * shape[0], left + 1.3 * per_m_x, 0.45 * shape[0]), 5.0, 70.0)
    panel = (1.0 * per_m_x, 0.52 * shape[0], shape[1] - 1.0 * per_m_x, 0.7 * shape[0])
    texels[int(panel[1]) : int(panel[3]), int(panel[0]) : int(panel[2])] += periodic_noise(
        rng, (int(panel[3]) - int(panel[1]), int(panel[2]) - int(panel[0])), ((4.0, 40.0), (12.0, 30.0)))
    outline(texels, panel, 4.0, 60.0)
    for door in (0.08, 0.55):
        outline(texels, (door * shape[1], 0.12 * shape[0], door * shape[1] + 1.1 * per_m_x, 0.9 * shape[0]),
                4.0, 50.0)
    fill(texels, (0, 0.9 * shape[0], shape[1], 0.93 * shape[0]), 60.0)
    wheels(texels, (0.2, 0.8), 0.45 * per_m_y, 0.5, 140.0)
    return Texture(np.clip(texels, 0.0, 255.0), size_m)


def car_end(rng: np.random.Generator, size_m: tuple[float, float]) -> Texture:
    """A car front or rear ``size_m = (width, height)``: window, two lamps, grille, plate, bumper."""
    shape = (256, 256)
    texels = 200.0 + grain(rng, shape, 2.0)
    fill(texels, (0.12 * shape[1], 0.08 * shape[0], 0.88 * shape[1], 0.38 * shape[0]), 50.0)
    for lamp in (0.06, 0.78):
        fill(texels, (lamp * shape[1], 0.5 * shape[0], (lamp + 0.16) * shape[1], 0.6 * shape[0]), 245.0)
    for slat in np.linspace(0.5, 0.62, 4):
        fill(texels, (0.3 * shape[1], slat * shape[0], 0.7 * shape[1], (slat + 0.015) * shape[0]), 60.0)
    fill(texels, (0.38 * shape[1], 0.7 * shape[0], 0.62 * shape[1], 0.78 * shape[0]), 235.0)
    fill(texels, (0.0, 0.82 * shape[0], shape[1], 0.9 * shape[0]), 70.0)
    return Texture(texels, size_m)


def truck_rear(rng: np.random.Generator, size_m: tuple[float, float]) -> Texture:
    """A box truck's rear ``size_m = (width, height)``: roll-up door of slats in a frame,
    lamps, plate, bumper (the front end shows the same)."""
    shape = (512, 256)
    width, height = size_m
    per_m_x, per_m_y = shape[1] / width, shape[0] / height
    texels = 190.0 + grain(rng, shape, 2.0)
    door = (0.12 * per_m_x, 0.1 * per_m_y, shape[1] - 0.12 * per_m_x, 2.6 * per_m_y)
    for slat in np.arange(door[1], door[3], 0.25 * per_m_y):
        fill(texels, (door[0], slat, door[2], slat + 2), 120.0)
    outline(texels, door, 0.08 * per_m_x, 90.0)
    fill(texels, (0.45 * shape[1], 2.2 * per_m_y, 0.55 * shape[1], 2.35 * per_m_y), 60.0)
    for lamp in (0.04, 0.84):
        fill(texels, (lamp * shape[1], 2.75 * per_m_y, (lamp + 0.12) * shape[1], 2.95 * per_m_y), 245.0)
    fill(texels, (0.38 * shape[1], 2.75 * per_m_y, 0.62 * shape[1], 2.95 * per_m_y), 235.0)
    fill(texels, (0, 3.05 * per_m_y, shape[1], 3.2 * per_m_y), 60.0)
    return Texture(texels, size_m)


def person(rng: np.random.Generator, width_m: float) -> Texture:
    """A pedestrian seen from the front or side (``width_m`` x 1.75 m): head, jacket, trousers."""
    shape = (512, 128)
    per_m = shape[0] / 1.75
    texels = np.full(shape, rng.uniform(40, 90), dtype=np.float32)
    fill(texels, (0.3 * shape[1], 0, 0.7 * shape[1], 0.24 * per_m), rng.uniform(150, 200))
    jacket = rng.uniform(80, 230)
    fill(texels, (0, 0.24 * per_m, shape[1], 0.95 * per_m), jacket)
    fill(texels, (0.48 * shape[1], 0.3 * per_m, 0.52 * shape[1], 0.9 * per_m), 255.0 - jacket)
    fill(texels, (0.45 * shape[1], 1.0 * per_m, 0.55 * shape[1], 1.7 * per_m), 200.0)
    fill(texels, (0, 1.68 * per_m, shape[1], shape[0]), 25.0)
    return Texture(texels + grain(rng, shape, 3.0), (width_m, 1.75))


def bicycle_side(rng: np.random.Generator) -> Texture:
    """A cyclist seen from the side, 1.7 m x 1.75 m: two wheels, frame, rider."""
    shape = (256, 256)
    per_m_x, per_m_y = shape[1] / 1.7, shape[0] / 1.75
    texels = np.full(shape, 185.0, dtype=np.float32)
    for axle in (0.35, 1.35):
        centre = (axle * per_m_x, shape[0] - 0.34 * per_m_y)
        disc(texels, centre, 0.33 * per_m_y, 30.0)
        disc(texels, centre, 0.28 * per_m_y, 170.0)
    fill(texels, (0.35 * per_m_x, 1.05 * per_m_y, 1.35 * per_m_x, 1.12 * per_m_y), 60.0)
    rider = rng.uniform(60, 120)
    fill(texels, (0.6 * per_m_x, 0.25 * per_m_y, 1.0 * per_m_x, 1.05 * per_m_y), rider)
    disc(texels, (0.8 * per_m_x, 0.14 * per_m_y), 0.11 * per_m_y, 210.0)
    return Texture(texels + grain(rng, shape, 3.0), (1.7, 1.75))


def metal(rng: np.random.Generator) -> Texture:
    """Painted metal for poles and arms, 0.25 m x 4 m per tile, with a band every 2 m."""
    shape = (512, 32)
    texels = rng.uniform(90, 130) + grain(rng, shape, 3.0)
    for band in (0, 256):
        shade(texels, (0, band, shape[1], band + 10), 0.6)
    return Texture(texels, (0.25, 4.0))


def sign(rng: np.random.Generator) -> Texture:
    """A road sign face 0.6 m x 0.6 m: a border, a field and a bar or disc symbol."""
    shape = (128, 128)
    field = rng.choice([40.0, 230.0])
    texels = np.full(shape, field, dtype=np.float32)
    outline(texels, (0, 0, 128, 128), 12, 255.0 - field)
    if rng.random() < 0.5:
        fill(texels, (30, 54, 98, 74), 255.0 - field)
    else:
        disc(texels, (64.0, 64.0), 30.0, 255.0 - field)
        disc(texels, (64.0, 64.0), 18.0, field)
    return Texture(texels + grain(rng, shape, 2.0), (0.6, 0.6))


# --- the highway ----------------------------------------------------------------------------


def grass(rng: np.random.Generator) -> Texture:
    """Rough grass of the verges and the median, 16 m x 16 m per tile: grey 105 with dark
    and light clumps of 5-30 cm (they stay visible at the grazing angles a verge is seen
    at), patches of about 1 m and broad blotches."""
    shape = (1024, 1024)
    texels = 105.0 + periodic_noise(rng, shape, ((1.5, 10.0), (5.0, 22.0), (16.0, 14.0), (64.0, 8.0)))
    return Texture(np.clip(texels, 0.0, 255.0), (16.0, 16.0))


def guard_rail(rng: np.random.Generator) -> Texture:
    """A W-beam guard rail 16 m x 0.35 m: four 4 m beams of galvanised steel, each of its
    own shade and with its own dirt, a light ridge along the top, middle and bottom and
    two dark grooves between, splice bolts at the start of each beam and post bolts 2 m
    apart. The beams differ so that the rail does not repeat every 4 m like its posts."""
    shape = (64, 2048)
    per_m = shape[1] / 16.0
    texels = rng.uniform(150, 175) * np.ones(shape, dtype=np.float32)
    texels *= 0.85 + 0.3 * np.abs(np.cos(np.linspace(0.0, 2.0 * np.pi, shape[0], dtype=np.float32)))[:, None]
    for beam in range(4):
        shade(texels, (4.0 * beam * per_m, 0, 4.0 * (beam + 1) * per_m, shape[0]), rng.uniform(0.8, 1.1))
    texels += periodic_noise(rng, shape, ((0.8, 2.0), (6.0, 12.0)))
    for row in (0.3, 0.7):
        fill(texels, (0, row * shape[0] - 2, shape[1], row * shape[0] + 2), 70.0)
    for start in np.arange(0.0, 16.0, 4.0):
        for col in (0.06, 0.14, 0.22, 0.30):
            for row in (0.3, 0.7):
                disc(texels, ((start + col) * per_m, row * shape[0]), 3.0, 45.0)
        for bolt in (1.0, 3.0):
            disc(texels, ((start + bolt) * per_m, 0.5 * shape[0]), 4.0, 45.0)
    return Texture(texels, (16.0, 0.35))


def noise_wall(rng: np.random.Generator) -> Texture:
    """A noise barrier 16 m x 4 m: 2 m x 1 m panels of horizontal ribs (a shade per panel, a
    dark groove every 25 cm) between steel posts about every 4 m (each placed on its own,
    so the barrier does not repeat every 4 m), on a concrete plinth 0.5 m tall, weathered
    in broad streaks."""
    shape = (512, 2048)
    per_m = shape[0] / 4.0
    texels = slab_pattern(rng, shape, (8, 4), rng.uniform(120, 160), 70.0, 3.0, 0.15)
    for row in np.arange(0.0, 3.5 * per_m, 0.25 * per_m):
        fill(texels, (0, row, shape[1], row + 3), 80.0)
    fill(texels, (0, 3.5 * per_m, shape[1], shape[0]), rng.uniform(165, 190))
    for post in np.arange(0.0, 16.0, 4.0) + rng.uniform(-0.4, 0.4, size=4):
        fill(texels, ((post - 0.1) * per_m, 0, (post + 0.1) * per_m, shape[0]), 60.0)
    texels += periodic_noise(rng, shape, ((1.0, 3.0), (24.0, 10.0)))
    return Texture(texels, (16.0, 4.0))


def foliage(rng: np.random.Generator) -> Texture:
    """A tree crown 4 m x 4 m: dark leaves with light clumps of 5-40 cm and shadows."""
    shape = (256, 256)
    texels = 85.0 + periodic_noise(rng, shape, ((1.2, 18.0), (4.0, 22.0), (12.0, 14.0)))
    return Texture(np.clip(texels, 0.0, 255.0), (4.0, 4.0))


def bark(rng: np.random.Generator) -> Texture:
    """A tree trunk 0.5 m x 2 m: dark vertical streaks (a shade per 2 cm column) and grain."""
    shape = (256, 64)
    streaks = np.repeat(rng.normal(1.0, 0.15, size=(1, 16)), 4, axis=1).astype(np.float32)
    return Texture(70.0 * streaks + grain(rng, shape, 4.0), (0.5, 2.0))


def hillside(rng: np.random.Generator) -> Texture:
    """A wooded hillside 64 m x 32 m: tree crowns of 0.5-2 m over lighter meadow and darker
    forest patches of tens of metres."""
    shape = (256, 512)
    texels = 110.0 + periodic_noise(rng, shape, ((0.8, 10.0), (2.0, 14.0), (24.0, 18.0)))
    return Texture(np.clip(texels, 0.0, 255.0), (64.0, 32.0))


def direction_sign(rng: np.random.Generator, size_m: tuple[float, float]) -> Texture:
    """A motorway direction sign ``size_m = (width, height)``: a dark field in a light border,
    two or three lines of destination lettering, a route number box and an arrow."""
    shape = (256, 512)
    per_m_x, per_m_y = shape[1] / size_m[0], shape[0] / size_m[1]
    field, ink = rng.uniform(50, 80), rng.uniform(215, 240)
    texels = np.full(shape, field, dtype=np.float32)
    outline(texels, (0, 0, shape[1], shape[0]), 0.08 * per_m_x, ink)
    for line in range(int(rng.integers(2, 4))):
        row = (0.3 + 0.5 * line) * per_m_y
        col = 0.35 * per_m_x
        for _ in range(int(rng.integers(5, 11))):
            width = rng.uniform(0.12, 0.22) * per_m_x
            fill(texels, (col, row, col + width, row + 0.3 * per_m_y), ink)
            col += width + 0.06 * per_m_x
    box = (shape[1] - 1.0 * per_m_x, 0.25 * per_m_y, shape[1] - 0.3 * per_m_x, 0.75 * per_m_y)
    fill(texels, box, ink)
    fill(texels, (box[0] + 0.15 * per_m_x, box[1] + 0.1 * per_m_y, box[2] - 0.15 * per_m_x, box[3] - 0.1 * per_m_y),
         field)
    shaft = shape[1] - 0.65 * per_m_x
    fill(texels, (shaft - 0.06 * per_m_x, 1.2 * per_m_y, shaft + 0.06 * per_m_x, 2.1 * per_m_y), ink)
    for step in range(6):
        half = (0.05 + 0.04 * step) * per_m_x
        row = (1.0 + 0.04 * step) * per_m_y
        fill(texels, (shaft - half, row, shaft + half, row + 0.04 * per_m_y), ink)
    return Texture(texels + grain(rng, shape, 2.0), size_m)


def flat() -> Texture:
    """A uniform surface (grey 200); its shade comes from the quad albedo (low-texture world)."""
    return Texture(np.full((4, 4), 200.0, dtype=np.float32), (1.0, 1.0))


# --- the atlas ------------------------------------------------------------------------------


def mip_pyramid(texels: np.ndarray, n_levels: int = N_MIP_LEVELS) -> list[np.ndarray]:
    """``n_levels`` images: level 0 is ``texels``, each next one the 2 x 2 box mean of the last
    (an axis already one texel long stays so). Box means keep the tiling seamless."""
    levels = [np.ascontiguousarray(texels, dtype=np.float32)]
    for _ in range(n_levels - 1):
        image = levels[-1]
        if image.shape[0] > 1:
            image = 0.5 * (image[0::2] + image[1::2])
        if image.shape[1] > 1:
            image = 0.5 * (image[:, 0::2] + image[:, 1::2])
        levels.append(image)
    return levels


ATLAS_WIDTH = 4096
"""Width [texels] of the packed atlas image."""
REMAP_COLUMNS = 1024
"""Samples are looked up as an image of this width (cv2.remap limits images to 32767 px)."""


def pack_shelves(shapes: Sequence[tuple[int, int]], width: int) -> tuple[np.ndarray, int]:
    """Top-left corners (n, 2) ``(col, row)`` of blocks ``shapes = (rows, cols)`` packed in
    shelves of a ``width`` wide image (tallest blocks first), and the image height."""
    order = sorted(range(len(shapes)), key=lambda k: (-shapes[k][0], k))
    corners = np.zeros((len(shapes), 2), dtype=np.int64)
    col = row = shelf = 0
    for k in order:
        rows, cols = shapes[k]
        if col + cols > width:
            col, row, shelf = 0, row + shelf, 0
        corners[k] = (col, row)
        col += cols
        shelf = max(shelf, rows)
    return corners, row + shelf


@dataclass(frozen=True)
class TextureAtlas:
    """Every material's mip pyramid packed into one uint8 image, with a lookup table.

    Each level is stored with a one-texel border copied from the opposite side, so that
    bilinear interpolation (``cv2.remap``) across a tile edge blends the right texels.

    Attributes
    ----------
    image : np.ndarray
        (AH, `ATLAS_WIDTH`) uint8 atlas.
    table : np.ndarray
        (M * L, 8) float32, row ``material * n_levels + level``: texels per metre along
        ``a`` and ``b``, width and height [texels], their inverses, and the atlas column and
        row of texel (0, 0).
    log2_density : np.ndarray
        (M,) float32 log2 of the geometric mean texels per metre at level 0.
    n_levels : int
    """

    image: np.ndarray
    table: np.ndarray
    log2_density: np.ndarray
    n_levels: int

    @classmethod
    def build(cls, textures: Sequence[Texture], n_levels: int = N_MIP_LEVELS) -> "TextureAtlas":
        """Pack ``textures`` (material ``m`` is ``textures[m]``) with ``n_levels`` mip levels each."""
        levels, rows = [], []
        for texture in textures:
            for image in mip_pyramid(texture.texels, n_levels):
                levels.append(np.pad(image, 1, mode="wrap"))
                height, width = image.shape
                rows.append([width / texture.size_m[0], height / texture.size_m[1],
                             width, height, 1.0 / width, 1.0 / height])
        corners, atlas_height = pack_shelves([level.shape for level in levels], ATLAS_WIDTH)
        atlas = np.zeros((atlas_height, ATLAS_WIDTH), dtype=np.uint8)
        for (col, row), level in zip(corners, levels):
            atlas[row : row + level.shape[0], col : col + level.shape[1]] = np.clip(np.rint(level), 0, 255)
        level0 = [t.texels.size / (t.size_m[0] * t.size_m[1]) for t in textures]
        return cls(
            image=atlas,
            table=np.column_stack([rows, corners + 1]).astype(np.float32),
            log2_density=(0.5 * np.log2(level0)).astype(np.float32),
            n_levels=n_levels,
        )

    def sample(self, key: np.ndarray, s: np.ndarray, t: np.ndarray) -> np.ndarray:
        """Bilinear, tiled samples (P,) float32 at surface coordinates (P,) float32 [m].

        ``key`` (P,) selects material and mip level; ``s`` runs along edge ``a`` and ``t``
        along edge ``b`` of the quad, in metres from the tile origin. Texel centres sit at
        half-integer texel coordinates.
        """
        info = self.table[key]
        col = s * info[:, 0] - 0.5
        row = t * info[:, 1] - 0.5
        col -= info[:, 2] * np.floor(col * info[:, 4])
        row -= info[:, 3] * np.floor(row * info[:, 5])
        col += info[:, 6]
        row += info[:, 7]
        n = len(key)
        shape = (-(-n // REMAP_COLUMNS), REMAP_COLUMNS)
        map_col = np.zeros(shape[0] * shape[1], dtype=np.float32)
        map_row = np.zeros_like(map_col)
        map_col[:n] = col
        map_row[:n] = row
        values = cv2.remap(self.image, map_col.reshape(shape), map_row.reshape(shape), cv2.INTER_LINEAR,
                           borderMode=cv2.BORDER_REPLICATE)
        return values.ravel()[:n].astype(np.float32)
