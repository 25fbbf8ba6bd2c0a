"""The paper's two frame-to-frame mismatch filters: grid_cval for points, LLG for lines.

The tracker matches descriptors between the previous and the current frame and passes
the matched positions here; `point_grid_filter` and `line_llg_filter` each return a
boolean keep-mask over the matches (whether to call them is the tracker's choice,
``filters.point_grid`` and ``filters.line_llg``). `local_line_groups` is public: the
dynamic-LLG detector groups lines the same way. What each reading of the paper removes
and loses, on labelled matches of KITTI 06 and EuRoC, is in
docs/decisions/0007-mismatch-filters.md; the mismatches the point rule leaves are out of
reach of any rule local to a cell (lone matches, cells where mismatches are the
majority), and the robust pose solver deals with them.

Point filter: decisions
-----------------------
- Grid. The paper says "64x48 grids", the numbers of ORB-SLAM2's grid (64 columns by 48
  rows); on a KITTI image those are 19 x 8 px cells, mostly too sparse to judge. We read
  it as cells of 64 x 48 px (``point_grid_cell_width``, ``point_grid_cell_height``)
  (docs/decisions/0007-mismatch-filters.md).
- Cells are taken in the previous image and each cell's matches are compared in both
  images, so ``g_l`` and ``g_r`` average over the same matches (the paper's
  "corresponding grids").
- Coordinates. ``g_k = 1/n sum_i p_k x p_i`` over the n matches of the cell is
  ``(p_k - o) x (m - o)``, m the cell centroid and o the origin of the coordinates (the
  match's own term is zero). The origin must be fixed: relative to the centroid, g is
  identically zero. With one fixed origin in both images, the change of g of a match
  moved by its cell's mean flow f plus its own deviation e_k is
  ``(p_k - m) x f + e_k x (m' - o)``: the first term grows with the flow (up to 60 px
  on KITTI, over a 64 px cell) and rejects correct matches of a plainly translating
  cell. We take the previous image's coordinates from the image origin, as the paper,
  and the current image's from the image origin moved by the cell's mean flow, which
  discounts the cell's common motion (the paper's premise: correct matches keep their
  relations to their neighbours). The change is then exactly ``(f_k - f) x m``: the
  deviation of the match's flow from its cell's mean flow, across the direction of the
  cell's centroid seen from the image origin, times ``|m|``; divided by ``|m|`` it is a
  deviation in pixels, zero under any translation. Like the paper's quantity it is
  blind to deviations along that direction. (The other origins measured:
  docs/decisions/0007-mismatch-filters.md.)
- Threshold. The paper rejects ``|g_l - g_r| > alpha (g_lm - g_rm)``, but the cell mean
  of the changes is near zero (the flow term averages out over the cell), so this
  rejects most correct matches. We compare each deviation's distance to the cell's
  median with alpha (1.5) times the cell's mean distance to the median, and reject only
  when it also exceeds ``point_grid_min_deviation_px`` (3 px), so that a noise-level deviation
  never rejects (the floors measured: docs/decisions/0007-mismatch-filters.md).
- Cells with fewer than ``point_grid_min_cell_matches`` (3) matches are kept whole: with two the
  median sits halfway and cannot tell which one is wrong (with alpha >= 1 the rule
  already rejects neither). The robust pose solver deals with what is left.

Line filter: decisions
----------------------
- LLG. A line's circular domain has its midpoint as centre and its length as diameter;
  two lines are linked when their domains overlap (midpoint distance below the sum of
  the radii), and the LLGs are the connected components of the links (transitive: the
  paper draws LLGs as disjoint groups, and the dynamic-LLG detector needs groups).
  Judging each line among its direct neighbours only measured slightly worse.
- Groups are formed in the previous image, so each match belongs to one group, as for
  the point cells (groups overlapping in both images, or formed in the current image,
  measured the same).
- Change of a match: the angle between the two segment directions modulo pi (LSD
  orients a segment by its gradient), in [0, pi/2], and the distance between the
  midpoints [px], as the paper.
- Threshold. A match is an outlier when its angle change or its midpoint shift exceeds
  ``line_llg_factor`` (2) times the mean over the *other* lines of its LLG. The paper's
  mean includes the judged line, which leaves a group of two unable to reject anything
  (``x > 2 (x + y) / 2`` never holds) and lets a gross mismatch raise its own
  threshold. A lone line is compared with the mean over all other matches of the image,
  as the paper says. Floors: an angle change below ``line_llg_min_angle_change_deg`` (5 deg,
  above the correct matches' spread) or a midpoint shift below
  ``line_llg_min_midpoint_shift_px`` (20 px; LSD's endpoints slide along the line) never
  rejects. The correct matches still lost mostly fail by their shift, in large LLGs
  whose lines lie at different depths and move differently
  (docs/decisions/0007-mismatch-filters.md).
"""

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components

from pld_slam.config import FiltersConfig
from pld_slam.geometry.segments import segment_directions, segment_midpoints, unoriented_angle_differences


def cross_2d(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """z component (N,) of the cross products of 2D vectors ``a`` and ``b`` (N, 2)."""
    return a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]


def group_means(values: np.ndarray, groups: np.ndarray) -> np.ndarray:
    """Mean (G, ...) of ``values`` (N, ...) over each group; ``groups`` (N,) are labels 0..G-1, none empty."""
    sums = np.zeros((groups.max(initial=-1) + 1,) + values.shape[1:])
    np.add.at(sums, groups, values)
    counts = np.bincount(groups)
    return sums / counts.reshape((-1,) + (1,) * (values.ndim - 1))


def group_medians(values: np.ndarray, groups: np.ndarray) -> np.ndarray:
    """Median (G,) of ``values`` (N,) over each group; ``groups`` (N,) are labels 0..G-1, none empty."""
    ordered = values[np.lexsort((values, groups))]
    counts = np.bincount(groups)
    starts = np.cumsum(counts) - counts
    return 0.5 * (ordered[starts + (counts - 1) // 2] + ordered[starts + counts // 2])


def outlying(values: np.ndarray, references: np.ndarray, factor: float, floor: float) -> np.ndarray:
    """Whether each value (N,) exceeds both ``factor`` times its reference (N,) and ``floor``."""
    return (values > factor * references) & (values > floor)


# --- points ------------------------------------------------------------------------------


def cell_coordinates(uv: np.ndarray, cell_width: float, cell_height: float) -> np.ndarray:
    """Grid cell (column, row) (N, 2) int of pixels ``uv`` (N, 2); cells of ``cell_width`` x
    ``cell_height`` [px], the first one at the image origin."""
    return np.floor(uv / np.array([cell_width, cell_height])).astype(np.int64)


def grid_cells(uv: np.ndarray, cell_width: float, cell_height: float) -> np.ndarray:
    """Grid cell (N,) of pixels ``uv`` (N, 2), as labels 0..C-1 of the C occupied cells (`cell_coordinates`)."""
    cell = cell_coordinates(uv, cell_width, cell_height)
    return np.unique(cell, axis=0, return_inverse=True)[1].reshape(-1)


def grid_cval(uv: np.ndarray, cells: np.ndarray, origin: np.ndarray) -> np.ndarray:
    """The paper's grid_cval (N,) [px^2] of each match in its cell, coordinates from ``origin``.

    ``g_k = 1/n sum_i (p_k - o) x (p_i - o)`` over the n matches ``p_i`` of k's cell,
    which is ``(p_k - o) x (m - o)`` with m the cell's centroid.

    Parameters
    ----------
    uv : (N, 2)
        Matched pixels in one image.
    cells : (N,)
        Cell label of each match (0..C-1).
    origin : (2,) or (N, 2)
        Origin o of the coordinates [px], per match or shared.
    """
    centroids = group_means(uv, cells)[cells]
    return cross_2d(uv - origin, centroids - origin)


def grid_cval_deviations(uv_prev: np.ndarray, uv_curr: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """The change of grid_cval (N,) of each match between the images, as a deviation [px].

    The previous image's coordinates are taken from the image origin, the current
    image's from the image origin moved by the cell's mean flow. The difference
    ``g_curr - g_prev`` is then ``(f_k - f_cell) x m_prev``, f the flows and m_prev the
    cell's centroid in the previous image; divided by ``|m_prev|`` (at least 1 px) it is
    the component [px] of the match's flow deviation across the cell's direction.

    Parameters
    ----------
    uv_prev, uv_curr : (N, 2)
        Matched pixels in the previous and the current image.
    cells : (N,)
        Cell label of each match in the previous image (0..C-1).
    """
    centroids_prev = group_means(uv_prev, cells)
    cell_flows = group_means(uv_curr, cells) - centroids_prev
    g_prev = grid_cval(uv_prev, cells, np.zeros(2))
    g_curr = grid_cval(uv_curr, cells, cell_flows[cells])
    return (g_curr - g_prev) / np.maximum(np.linalg.norm(centroids_prev[cells], axis=1), 1.0)


def point_grid_filter(uv_prev: np.ndarray, uv_curr: np.ndarray, config: FiltersConfig) -> np.ndarray:
    """Keep-mask (N,) bool of frame-to-frame point matches by the grid_cval filter.

    A match is an outlier when its cell (in the previous image, ``point_grid_cell_width``
    x ``point_grid_cell_height`` px) holds at least ``point_grid_min_cell_matches`` matches and
    its grid_cval deviation differs from the cell's median by more than
    ``point_grid_alpha`` times the cell's mean absolute difference from that median and
    by more than ``point_grid_min_deviation_px``.

    Parameters
    ----------
    uv_prev, uv_curr : (N, 2)
        Pixels (u, v) of each match in the previous and the current left image.
    config : FiltersConfig
        The cell size, ``point_grid_alpha`` and the two ``point_grid_min_*`` bounds.
    """
    if len(uv_prev) == 0:
        return np.ones(0, dtype=bool)
    cells = grid_cells(uv_prev, config.point_grid_cell_width, config.point_grid_cell_height)
    deviations = grid_cval_deviations(uv_prev, uv_curr, cells)
    distances = np.abs(deviations - group_medians(deviations, cells)[cells])
    mean_distances = group_means(distances, cells)[cells]
    judged = np.bincount(cells)[cells] >= config.point_grid_min_cell_matches
    return ~(judged & outlying(distances, mean_distances, config.point_grid_alpha, config.point_grid_min_deviation_px))


# --- lines -------------------------------------------------------------------------------


def local_line_groups(endpoints: np.ndarray) -> np.ndarray:
    """Local line group (LLG) label (M,) int of each segment ``(u_s, v_s, u_e, v_e)`` (M, 4) [px].

    A segment's circular domain is centred at its midpoint with its length as diameter;
    segments whose domains overlap (midpoint distance < sum of the radii) are linked, and
    the LLGs are the connected components of these links, labelled 0..G-1. A segment
    overlapping no other forms an LLG of its own.
    """
    return connected_components(csr_matrix(overlapping_domains(endpoints)), directed=False)[1]


def overlapping_domains(endpoints: np.ndarray) -> np.ndarray:
    """(M, M) bool: whether the circular domains of segments (M, 4) overlap (a segment overlaps itself).

    A domain is centred at the segment's midpoint with its length as diameter; two overlap
    when their midpoint distance is below the sum of the radii.
    """
    midpoints = segment_midpoints(endpoints)
    radii = 0.5 * np.linalg.norm(endpoints[:, 2:] - endpoints[:, :2], axis=1)
    distances = np.linalg.norm(midpoints[:, None] - midpoints[None], axis=2)
    return distances < radii[:, None] + radii[None]


def angle_changes(endpoints_prev: np.ndarray, endpoints_curr: np.ndarray) -> np.ndarray:
    """Direction change (M,) [rad, 0..pi/2] of matched segments (M, 4), modulo pi."""
    return unoriented_angle_differences(segment_directions(endpoints_curr), segment_directions(endpoints_prev))


def midpoint_shifts(endpoints_prev: np.ndarray, endpoints_curr: np.ndarray) -> np.ndarray:
    """Distance (M,) [px] between the midpoints of matched segments (M, 4)."""
    return np.linalg.norm(segment_midpoints(endpoints_curr) - segment_midpoints(endpoints_prev), axis=1)


def other_members_means(values: np.ndarray, groups: np.ndarray) -> np.ndarray:
    """Mean (M,) of ``values`` (M,) over the other members of each one's group.

    A lone member (group of one) gets the mean over all other values of the image.
    Needs M >= 2.
    """
    counts = np.bincount(groups)[groups]
    group_sums = np.bincount(groups, weights=values)[groups]
    in_group = (group_sums - values) / np.maximum(counts - 1, 1)
    image_wide = (values.sum() - values) / (len(values) - 1)
    return np.where(counts > 1, in_group, image_wide)


def line_llg_filter(endpoints_prev: np.ndarray, endpoints_curr: np.ndarray, config: FiltersConfig) -> np.ndarray:
    """Keep-mask (M,) bool of frame-to-frame line matches by the LLG filter.

    LLGs are formed in the previous image (`local_line_groups`). A match is an outlier
    when its angle change exceeds ``line_llg_factor`` times the mean over the other
    lines of its LLG and ``line_llg_min_angle_change_deg``, or its midpoint shift exceeds
    ``line_llg_factor`` times that mean and ``line_llg_min_midpoint_shift_px``. A lone line is
    compared with the means over all other matches. Fewer than two matches are kept.

    Parameters
    ----------
    endpoints_prev, endpoints_curr : (M, 4)
        Segments ``(u_s, v_s, u_e, v_e)`` [px] of each match in the previous and the
        current left image.
    config : FiltersConfig
        ``line_llg_factor`` and the two ``line_llg_min_*`` floors.
    """
    if len(endpoints_prev) < 2:
        return np.ones(len(endpoints_prev), dtype=bool)
    groups = local_line_groups(endpoints_prev)
    angles = angle_changes(endpoints_prev, endpoints_curr)
    shifts = midpoint_shifts(endpoints_prev, endpoints_curr)
    factor = config.line_llg_factor
    min_angle = np.deg2rad(config.line_llg_min_angle_change_deg)
    turned = outlying(angles, other_members_means(angles, groups), factor, min_angle)
    moved = outlying(shifts, other_members_means(shifts, groups), factor, config.line_llg_min_midpoint_shift_px)
    return ~(turned | moved)
