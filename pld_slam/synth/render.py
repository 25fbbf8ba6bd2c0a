"""A vectorised ray caster for quads: z-buffered visibility, then deferred texturing.

For a camera at ``T_w_c`` each quad is moved into the camera frame (each the scene draws
from there: all of them unless it has a view distance, `Scene.quads_near`). Along the ray
``d = (x, y, 1)`` of the normalised pixel ``(x, y)``, a quad's plane is hit at inverse depth
``w = 1/z = (d . n) / (o . n)`` and its in-quad coordinates times ``w`` are
``sigma = d . a_hat - w (o . a_hat)`` and ``tau = d . b_hat - w (o . b_hat)``: all three are
affine in the pixel ``(u, v)``, so on the quad's screen box they are outer sums of a row and a
column vector. The quad covers the pixels where ``0 <= sigma <= |a| w``, ``0 <= tau <= |b| w``
and ``w <= 1 / NEAR``: five half-planes, which give each row's column span directly.

Pass 1 (per visible quad, on its screen box) keeps the largest ``w`` (the nearest surface)
and the quad index per pixel. Pass 2 (per covered pixel, all at once) recovers the texture
coordinates ``sigma / w`` and ``tau / w``, picks a mip level from the pixel's footprint on
the surface, samples the atlas and applies flat lighting by the frame's sun direction
(`Scene.light_at`). Sky pixels get a smooth gradient by elevation. The frame's exposure
(`Scene.exposure_at`) then scales everything. Finally the sensor: a Gaussian blur (sigma
0.7 px, hides aliasing) and Gaussian noise (sigma 1.5 grey levels, seeded per frame and eye).
"""

from dataclasses import dataclass

import cv2
import numpy as np

from pld_slam.geometry.camera import StereoCamera
from pld_slam.geometry.se3 import inverse, make_pose
from pld_slam.synth.scene import STATIC_OBJECT, Quads, Scene

NEAR = 0.1
"""Near clipping distance [m]."""
AMBIENT = 0.55
"""Share of a surface's brightness that does not depend on its angle to the sun."""
LOD_BIAS = 0.5
"""Added to the mip level (texels per pixel, log2): slightly soft rather than aliased."""
SKY_HORIZON, SKY_ZENITH = 225.0, 165.0
"""Sky grey level at the horizon and straight up."""
BLUR_SIGMA = 0.7
"""Sensor blur [px]."""
NOISE_SIGMA = 1.5
"""Sensor noise [grey levels]."""


@dataclass(frozen=True)
class View:
    """The buffers of one rendered image (H, W).

    Attributes
    ----------
    radiance : np.ndarray
        float32 grey levels before sensor blur and noise.
    inv_depth : np.ndarray
        float32 inverse depth ``1/z`` [1/m] of the visible surface; 0 on the sky.
    quad_id : np.ndarray
        int32 index of the visible quad in the rendered `Quads`; -1 on the sky.
    object_id : np.ndarray
        int32 object id of the visible quad; `STATIC_OBJECT` on static surfaces and sky.
    """

    radiance: np.ndarray
    inv_depth: np.ndarray
    quad_id: np.ndarray
    object_id: np.ndarray


@dataclass(frozen=True)
class SynthFrame:
    """One rendered stereo frame: ``left`` and ``right`` (H, W) uint8 and the left image's
    ``dynamic_mask`` (H, W) bool, True where the visible surface belongs to a moving object."""

    left: np.ndarray
    right: np.ndarray
    dynamic_mask: np.ndarray


@dataclass(frozen=True)
class ProjectedQuads:
    """Per-quad screen-space equations for one camera (Q quads; coefficient triples
    ``(c_u, c_v, c_1)`` evaluate as ``c_u u + c_v v + c_1`` at pixel ``(u, v)``).

    Attributes
    ----------
    inv_depth : np.ndarray
        (Q, 3) coefficients of ``w = 1/z``.
    tex_s, tex_t : np.ndarray
        (Q, 3) coefficients of ``w`` times the texture coordinate [m] along ``a`` and ``b``.
    half_planes : np.ndarray
        (Q, 5, 3) the quad covers a pixel where all five are >= 0.
    box : np.ndarray
        (Q, 4) int64 screen box ``(u0, v0, u1, v1)``, inclusive, clipped to the image.
    candidate : np.ndarray
        (Q,) bool: facing the camera with a non-empty screen box.
    log2_distance : np.ndarray
        (Q,) log2 of the distance [m] from the camera centre to the quad's plane.
    """

    inv_depth: np.ndarray
    tex_s: np.ndarray
    tex_t: np.ndarray
    half_planes: np.ndarray
    box: np.ndarray
    candidate: np.ndarray
    log2_distance: np.ndarray


def pixel_functional(camera: StereoCamera, g: np.ndarray) -> np.ndarray:
    """Coefficients (Q, 3) in pixels ``(u, v, 1)`` of the functionals ``g . (x, y, 1)`` (Q, 3)
    of normalised coordinates ``x = (u - cx) / fx``, ``y = (v - cy) / fy``."""
    return g @ np.linalg.inv(camera.K)


def project_quads(quads_c: Quads, camera: StereoCamera) -> ProjectedQuads:
    """Screen-space equations of quads given in the camera frame (see `ProjectedQuads`)."""
    origin, a, b = quads_c.origin, quads_c.edge_a, quads_c.edge_b
    len_a = np.linalg.norm(a, axis=1)
    len_b = np.linalg.norm(b, axis=1)
    a_hat, b_hat = a / len_a[:, None], b / len_b[:, None]
    normal = quads_c.normals()
    distance = np.einsum("qi,qi->q", origin, normal)
    facing = distance < -1e-9
    safe = np.where(facing, distance, -1.0)
    inv_depth = pixel_functional(camera, normal / safe[:, None])
    sigma = pixel_functional(camera, a_hat) - np.einsum("qi,qi->q", origin, a_hat)[:, None] * inv_depth
    tau = pixel_functional(camera, b_hat) - np.einsum("qi,qi->q", origin, b_hat)[:, None] * inv_depth
    near = np.broadcast_to(np.array([0.0, 0.0, 1.0 / NEAR]), inv_depth.shape)
    half_planes = np.stack(
        [sigma, len_a[:, None] * inv_depth - sigma, tau, len_b[:, None] * inv_depth - tau, near - inv_depth],
        axis=1,
    )
    box, on_screen = screen_boxes(quads_c.corners(), camera)
    return ProjectedQuads(
        inv_depth=inv_depth,
        tex_s=sigma + quads_c.tex_offset[:, :1] * inv_depth,
        tex_t=tau + quads_c.tex_offset[:, 1:] * inv_depth,
        half_planes=half_planes,
        box=box,
        candidate=facing & on_screen,
        log2_distance=np.log2(np.abs(safe)),
    )


def screen_boxes(corners_c: np.ndarray, camera: StereoCamera) -> tuple[np.ndarray, np.ndarray]:
    """Integer pixel boxes (Q, 4) ``(u0, v0, u1, v1)`` of quads clipped at z = NEAR, and
    whether each box is non-empty on the image (Q,).

    ``corners_c`` (Q, 4, 3) are the corners in the camera frame, in order around each quad.
    The clipped polygon's vertices are the corners in front of the near plane plus the
    points where the edges cross it.
    """
    nxt = np.roll(corners_c, -1, axis=1)
    z0, z1 = corners_c[..., 2], nxt[..., 2]
    crosses = (z0 - NEAR) * (z1 - NEAR) < 0.0
    ratio = np.where(crosses, (NEAR - z0) / np.where(crosses, z1 - z0, 1.0), 0.0)
    crossing = corners_c + ratio[..., None] * (nxt - corners_c)
    points = np.concatenate([corners_c, crossing], axis=1)
    valid = np.concatenate([z0 >= NEAR, crosses], axis=1)
    z = np.where(valid, np.maximum(points[..., 2], NEAR), 1.0)
    u = camera.fx * points[..., 0] / z + camera.cx
    v = camera.fy * points[..., 1] / z + camera.cy
    u0 = np.ceil(np.where(valid, u, np.inf).min(axis=1))
    u1 = np.floor(np.where(valid, u, -np.inf).max(axis=1))
    v0 = np.ceil(np.where(valid, v, np.inf).min(axis=1))
    v1 = np.floor(np.where(valid, v, -np.inf).max(axis=1))
    box = np.stack([np.clip(u0, 0, camera.width - 1), np.clip(v0, 0, camera.height - 1),
                    np.clip(u1, 0, camera.width - 1), np.clip(v1, 0, camera.height - 1)], axis=1)
    on_screen = (valid.any(axis=1) & (u0 <= u1) & (v0 <= v1) & (u0 <= camera.width - 1) & (u1 >= 0)
                 & (v0 <= camera.height - 1) & (v1 >= 0))
    return np.where(on_screen[:, None], box, 0).astype(np.int64), on_screen


def row_spans(half_planes: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per row, the column interval ``[lo, hi]`` (R,) where all of that row's half-planes
    (R, K, 3) are >= 0 on row ``rows`` (R,) (empty where lo > hi)."""
    slope = half_planes[..., 0]
    offset = half_planes[..., 1] * rows[:, None] + half_planes[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        bound = -offset / slope
    unbounded = np.where((slope == 0.0) & (offset < 0.0), np.inf, -np.inf)
    lo = np.where(slope > 0.0, bound, unbounded).max(axis=1)
    hi = np.where(slope < 0.0, bound, np.inf).min(axis=1)
    return lo, hi


@dataclass(frozen=True)
class Spans:
    """The pixels each candidate quad covers, as column spans of the rows of its screen box.

    Rows of all quads are concatenated: quad k owns rows ``first[k] .. last[k]`` (indices into
    the row arrays; ``first > last`` if it covers nothing).

    Attributes
    ----------
    quad : np.ndarray
        (C,) index of each candidate quad.
    row : np.ndarray
        (R,) image row of each span.
    lo, hi : np.ndarray
        (R,) float32 first and last covered column (pixel centres ``lo <= u <= hi``).
    row_inv_depth : np.ndarray
        (R,) float32 the row's part ``c_v v + c_1`` of the quad's inverse depth.
    first, last : np.ndarray
        (C,) first and last covered row of each quad in the row arrays.
    col_lo, col_hi : np.ndarray
        (C,) leftmost and rightmost covered column of each quad.
    """

    quad: np.ndarray
    row: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    row_inv_depth: np.ndarray
    first: np.ndarray
    last: np.ndarray
    col_lo: np.ndarray
    col_hi: np.ndarray


def quad_spans(projected: ProjectedQuads) -> Spans:
    """Column spans of every row of every candidate's screen box, all at once."""
    quad = np.flatnonzero(projected.candidate)
    box = projected.box[quad]
    heights = box[:, 3] - box[:, 1] + 1
    starts = np.cumsum(heights) - heights
    owner = np.repeat(np.arange(len(quad)), heights)
    index = np.arange(int(heights.sum()))
    row = (index - starts[owner] + box[owner, 1]).astype(np.float64)
    lo, hi = row_spans(projected.half_planes[quad][owner], row)
    lo = np.maximum(lo, box[owner, 0])
    hi = np.minimum(hi, box[owner, 2])
    filled = np.ceil(lo) <= np.floor(hi)
    coef = projected.inv_depth[quad][owner]
    return Spans(
        quad=quad,
        row=row.astype(np.int64),
        lo=lo.astype(np.float32),
        hi=hi.astype(np.float32),
        row_inv_depth=(coef[:, 1] * row + coef[:, 2]).astype(np.float32),
        first=np.minimum.reduceat(np.where(filled, index, len(index)), starts),
        last=np.maximum.reduceat(np.where(filled, index, -1), starts),
        col_lo=np.minimum.reduceat(np.where(filled, np.ceil(lo), np.inf), starts),
        col_hi=np.maximum.reduceat(np.where(filled, np.floor(hi), -np.inf), starts),
    )


def rasterise(projected: ProjectedQuads, camera: StereoCamera) -> tuple[np.ndarray, np.ndarray]:
    """Z-buffer pass: inverse depth (H, W) float32 (0 = sky) and quad index (H, W) int32
    (-1 = sky) of the nearest surface at each pixel centre."""
    shape = (camera.height, camera.width)
    inv_depth = np.zeros(shape, dtype=np.float32)
    quad_id = np.full(shape, -1, dtype=np.int32)
    if not projected.candidate.any():
        return inv_depth, quad_id
    spans = quad_spans(projected)
    cols_all = np.arange(camera.width, dtype=np.float32)
    col_coef = projected.inv_depth[:, 0].astype(np.float32)
    for k in np.flatnonzero(spans.first <= spans.last):
        r0, r1 = spans.first[k], spans.last[k] + 1
        v0, v1 = spans.row[r0], spans.row[r1 - 1] + 1
        u0, u1 = int(spans.col_lo[k]), int(spans.col_hi[k]) + 1
        q = spans.quad[k]
        cols = cols_all[u0:u1]
        w = (col_coef[q] * cols)[None, :] + spans.row_inv_depth[r0:r1, None]
        covered = (cols >= spans.lo[r0:r1, None]) & (cols <= spans.hi[r0:r1, None])
        depth_view = inv_depth[v0:v1, u0:u1]
        covered &= w > depth_view
        np.copyto(depth_view, w, where=covered)
        np.copyto(quad_id[v0:v1, u0:u1], q, where=covered)
    return inv_depth, quad_id


def quad_brightness(quads: Quads, light: np.ndarray) -> np.ndarray:
    """Flat Lambert shading (Q,) float32: albedo times ``AMBIENT + (1 - AMBIENT) cos`` of the
    angle between the outward normal and the direction to the sun ``light`` (3,)."""
    lambert = np.clip(quads.normals() @ light, 0.0, None)
    return (quads.albedo * (AMBIENT + (1.0 - AMBIENT) * lambert)).astype(np.float32)


def sky(camera: StereoCamera, R_w_c: np.ndarray) -> np.ndarray:
    """Sky radiance (H, W) float32: a smooth gradient with the sine of the ray's elevation
    above the world horizon (world y is down), from `SKY_HORIZON` to `SKY_ZENITH`."""
    up_c = -R_w_c[1, :]
    x = (np.arange(camera.width, dtype=np.float32) - camera.cx) / camera.fx
    y = (np.arange(camera.height, dtype=np.float32) - camera.cy) / camera.fy
    up = (up_c[0] * x)[None, :] + (up_c[1] * y + up_c[2])[:, None]
    norm = np.sqrt((x * x)[None, :] + (y * y + 1.0)[:, None])
    elevation = np.clip(up / norm, 0.0, 1.0)
    return (SKY_HORIZON + (SKY_ZENITH - SKY_HORIZON) * elevation).astype(np.float32)


def shading_table(projected: ProjectedQuads, quads: Quads, scene: Scene,
                  camera: StereoCamera, light: np.ndarray) -> np.ndarray:
    """Per-quad shading constants (Q, 9) float32: texture coordinate coefficients along
    ``a`` (3) and ``b`` (3), mip level offset, ``material * n_levels`` and brightness under
    the sun direction ``light`` (3,).

    The mip level is log2 of the texels per pixel: a pixel's footprint on a plane at
    distance ``h`` has area ``z^2 / (fx^2 |d . n|) = 1 / (fx^2 w^3 h)``, so the level is
    ``offset - 1.5 log2 w`` with the offset below (plus `LOD_BIAS`).
    """
    atlas = scene.atlas
    lod_offset = (atlas.log2_density[quads.material] - np.log2(camera.fx)
                  - 0.5 * projected.log2_distance + LOD_BIAS)
    return np.column_stack([
        projected.tex_s,
        projected.tex_t,
        lod_offset,
        quads.material * atlas.n_levels,
        quad_brightness(quads, light),
    ]).astype(np.float32)


def shade_pixels(projected: ProjectedQuads, quads: Quads, scene: Scene, camera: StereoCamera,
                 inv_depth: np.ndarray, quad_id: np.ndarray, radiance: np.ndarray,
                 light: np.ndarray) -> None:
    """Deferred texturing: write the texture value lit by the sun direction ``light`` (3,)
    of every covered pixel into ``radiance`` (H, W) float32, in place."""
    atlas = scene.atlas
    pixels = np.flatnonzero(quad_id.ravel() >= 0)
    per_pixel = shading_table(projected, quads, scene, camera, light)[quad_id.ravel()[pixels]]
    v, u = np.divmod(pixels, camera.width)
    u = u.astype(np.float32)
    v = v.astype(np.float32)
    w = inv_depth.ravel()[pixels]
    z = 1.0 / w
    s = (per_pixel[:, 0] * u + per_pixel[:, 1] * v + per_pixel[:, 2]) * z
    t = (per_pixel[:, 3] * u + per_pixel[:, 4] * v + per_pixel[:, 5]) * z
    level = np.rint(per_pixel[:, 6] - 1.5 * np.log2(w))
    np.clip(level, 0, atlas.n_levels - 1, out=level)
    key = (per_pixel[:, 7] + level).astype(np.intp)
    radiance.ravel()[pixels] = atlas.sample(key, s, t) * per_pixel[:, 8]


def render_view(scene: Scene, quads: Quads, camera: StereoCamera, T_w_c: np.ndarray,
                frame: int = 0) -> View:
    """Render world-frame ``quads`` of ``scene`` seen from a camera at ``T_w_c`` (4, 4),
    under the light and exposure of ``frame``."""
    quads_c = quads.transformed(inverse(T_w_c))
    projected = project_quads(quads_c, camera)
    inv_depth, quad_id = rasterise(projected, camera)
    radiance = sky(camera, T_w_c[:3, :3])
    shade_pixels(projected, quads, scene, camera, inv_depth, quad_id, radiance, scene.light_at(frame))
    exposure = scene.exposure_at(frame)
    if exposure != 1.0:
        radiance *= np.float32(exposure)
    object_id = np.where(quad_id >= 0, quads.object_id[quad_id], STATIC_OBJECT).astype(np.int32)
    return View(radiance=radiance, inv_depth=inv_depth, quad_id=quad_id, object_id=object_id)


def sensor_image(radiance: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """The uint8 image (H, W) a camera records of ``radiance`` (H, W) float32: Gaussian blur
    of `BLUR_SIGMA` px, then Gaussian noise of `NOISE_SIGMA` grey levels from ``rng``."""
    blurred = cv2.GaussianBlur(radiance, (0, 0), BLUR_SIGMA)
    blurred += NOISE_SIGMA * rng.standard_normal(blurred.shape, dtype=np.float32)
    return np.clip(np.rint(blurred), 0, 255).astype(np.uint8)


def right_camera_pose(T_w_c: np.ndarray, camera: StereoCamera) -> np.ndarray:
    """``T_w_r`` (4, 4) of the right camera: ``(+baseline, 0, 0)`` in the left camera frame."""
    return T_w_c @ make_pose(np.eye(3), np.array([camera.baseline, 0.0, 0.0]))


def render_stereo_views(scene: Scene, camera: StereoCamera, T_w_c: np.ndarray,
                        frame: int) -> tuple[View, View]:
    """Noise-free left and right views of ``frame`` for the left camera at ``T_w_c``: both
    draw the quads the scene keeps near the left camera (`Scene.quads_near`)."""
    quads = scene.quads_near(frame, T_w_c[:3, 3])
    left = render_view(scene, quads, camera, T_w_c, frame)
    right = render_view(scene, quads, camera, right_camera_pose(T_w_c, camera), frame)
    return left, right


def render_stereo_frame(scene: Scene, camera: StereoCamera, T_w_c: np.ndarray, frame: int,
                        seed: int) -> SynthFrame:
    """The stereo pair and left dynamic mask of ``frame``; the sensor noise of each eye is
    drawn from ``default_rng((seed, frame, eye))``, so a frame renders the same every time."""
    left, right = render_stereo_views(scene, camera, T_w_c, frame)
    return SynthFrame(
        left=sensor_image(left.radiance, np.random.default_rng((seed, frame, 0))),
        right=sensor_image(right.radiance, np.random.default_rng((seed, frame, 1))),
        dynamic_mask=np.isin(left.object_id, scene.moving_ids_at(frame)),
    )
