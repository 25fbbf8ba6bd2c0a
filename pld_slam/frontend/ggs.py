"""Global gray similarity (GGS): a grey-histogram descriptor of the left image, and ``sim_v``.

The paper (section "GGS") greys the left image, makes a copy "scaled by 0.8", cuts both
into 3 x 4 cells and keeps a 256-bin grey histogram per cell: 24 histograms per frame.
Two frames are compared by

    sim_v = 1 / (M N) * sum_{i=1..12} min_{p, q in {0, 1}} || hist_a(p, i) - hist_b(q, i) ||

with ``p, q`` choosing the original (0) or the scaled copy (1). What it leaves open, and
what we do (the measurements: docs/decisions/0009-ggs-descriptor.md):

The scaled copy. Shrinking the whole image by 0.8 and cutting it into the same 3 x 4 grid
puts the same content into every cell: the histograms would only differ by resampling,
and the minimum over the copies would change nothing. The paper wants the copy to make
GGS "tolerant to the position of the image" (a revisit seen from a little before or after
the first pass). We therefore read it as a zoom: the copy is the central 0.8 x 0.8 of the
image (what the camera sees a few metres further along its optical axis, magnified by
1 / 0.8), cut into the same 3 x 4 grid. Histograms are normalised per cell, so the copy
needs no resampling: its cells are cells of the crop.

The norm. ``||.||`` is the L1 norm of the difference of two histograms, each normalised to
sum 1 over its cell (so that a cell of the original and a cell of the smaller copy are
comparable; the paper's ``1 / (M N)`` normalises by the image size for the same purpose).
We divide the sum over cells by the number of cells, so ``sim_v`` lies in [0, 2]:
**0 for identical images, larger for less similar ones** (it is a distance, despite its
name; "more similar" means smaller).

The minimum. The paper's equation takes it inside the sum, per cell: each cell may pick
its own pairing. We follow it (`ggs_distances`).

Light (``ggs.place_ranks``, not in the paper). A grey histogram moves with the exposure
and the light: across a change of sun and exposure the paper's GGS rarely finds the same
place. Histograms of the grey levels' *ranks* in the image do not move with any
monotonic change of the grey levels (exposure, gain, gamma): grey level ``g`` stands for
the ranks ``[F(g - 1), F(g))`` of the image's cumulative histogram ``F``, its pixels
spread evenly over them (`rank_histograms`), and the ranks are cut into ``bins`` equal
bins (``ranks=True``). A new sun direction, which brightens some surfaces and darkens
others, still moves them, but less. But ranks alone lose what brightness says. Place
recognition therefore compares both: its descriptor holds the grey cells and then as
many cells of ranks (`ggs_and_place_descriptors`), so that its ``sim_v`` is the mean of
the two distances. The keyframe rule keeps the paper's grey levels: it compares
consecutive frames, which share their light, and with ranks nearly every KITTI frame
became a keyframe. Histogram equalisation (``cv2.equalizeHist``) would not do: it maps
each grey level to one level, leaving a comb of empty bins that moves with any small
change of ``F``; spreading each level over its ranks avoids the comb. The zoomed copy is
ranked within itself, so that it matches the original of a frame taken closer
(docs/decisions/0009-ggs-descriptor.md).

Storage. A frame's GGS is one compact ``(2, cells, bins)`` uint8 array (6 KB at 3 x 4 x
256): each normalised histogram in units of ``1 / HISTOGRAM_QUANTA`` of its cell,
rounded, saturating at 255 (``255 / 400`` = 64 % of a cell in one grey level, more than
real cells hold). Rounding changes a distance by a small amount; `tests/test_ggs.py`
bounds it against the exact float value. It can push a distance past 2 where many bins
round the same way: a cell spread evenly over 112 grey levels stores 4 quanta per level
(448 in all), and two such images with disjoint grey levels are at 2.24. Histograms of
ranks are flat, about 1.6 quanta per bin, and round more. A keyframe keeps both
descriptors: 6 KB for the keyframe rule, 12 KB (grey and rank cells) for place
recognition.

Speed (targets: under 2 ms per KITTI frame, under 1 ms for a query against 1,000
keyframes; `benchmarks/ggs_speed.py` measures them). A descriptor is 24
``cv2.calcHist`` calls; `ggs_and_place_descriptors` makes both from the same counts. A
query reads every stored byte once, in a numba kernel that sums the four pairings of a
cell in one pass on 16-bit lanes (numpy cannot fuse the four pairings nor sum uint8
without widening). The distances are the same to the last bit: the per-cell sums are
exact integers either way, and the mean over cells is the same float64 operation.
`GgsDatabase` keeps the keyframes stacked, so that a query does not first copy them.
The kernel is compiled once per machine and cached in a user cache folder
(`pld_slam.jit`).
"""

import cv2
import numpy as np

from pld_slam.config import GgsConfig
from pld_slam.jit import kernel

GREY_LEVELS = 256
"""Grey levels of a uint8 image: the resolution of `_level_counts`."""

HISTOGRAM_QUANTA = 400
"""A stored histogram bin counts in 1 / 400 of its cell (uint8, saturating at 255)."""

ORIGINAL, ZOOMED = 0, 1
"""Index of the original image and of its zoomed copy in a GGS descriptor's first axis."""


def ggs_descriptor(image: np.ndarray, config: GgsConfig, ranks: bool = False) -> np.ndarray:
    """The GGS of a grey image (H, W) uint8: (2, rows * cols, bins) uint8 (module docstring).

    `ggs_histograms`, quantised for storage (`quantise_histograms`).
    """
    return quantise_histograms(ggs_histograms(image, config, ranks))


def ggs_and_place_descriptors(image: np.ndarray, config: GgsConfig) -> tuple[np.ndarray, np.ndarray]:
    """The GGS (2, C, B) uint8 of a grey image (H, W) uint8 that the keyframe rule compares, and the one
    place recognition compares: with ``config.place_ranks`` its cells followed by as many cells
    of ranks (2, 2 C, B), whose ``sim_v`` is the mean of the two kinds' (module docstring,
    "Light"); else the same array. Both come from one count of the cells' grey levels."""
    counts = _level_counts(image, config)
    grey = quantise_histograms(grey_histograms(counts, config.bins))
    if not config.place_ranks:
        return grey, grey
    return grey, np.concatenate([grey, quantise_histograms(_parts_rank_histograms(counts, config.bins))], axis=1)


def ggs_histograms(image: np.ndarray, config: GgsConfig, ranks: bool = False) -> np.ndarray:
    """The exact histograms behind the GGS of a grey image (H, W) uint8: (2, rows * cols, bins) float64.

    ``[ORIGINAL]`` holds the cell histograms of the image, ``[ZOOMED]`` those of its
    central ``config.scale`` crop; cells are numbered row by row, each sums to 1. With
    ``ranks`` they are histograms of the grey levels' ranks, in the image or in the crop
    (module docstring, "Light").
    """
    counts = _level_counts(image, config)
    return _parts_rank_histograms(counts, config.bins) if ranks else grey_histograms(counts, config.bins)


def _level_counts(image: np.ndarray, config: GgsConfig) -> np.ndarray:
    """Pixels (2, rows * cols, 256) float64 of each grey level in each cell of a grey image (H, W) uint8
    (``[ORIGINAL]``) and of its central ``config.scale`` crop (``[ZOOMED]``).

    The cells split the rows and the columns as evenly as integer pixels allow, so the
    cells of each part add up to the whole part.
    """
    height, width = image.shape
    crop_h, crop_w = round(config.scale * height), round(config.scale * width)
    top, left = (height - crop_h) // 2, (width - crop_w) // 2
    zoomed = image[top : top + crop_h, left : left + crop_w]
    return np.stack([_cell_level_counts(part, config) for part in (image, zoomed)])


def _cell_level_counts(image: np.ndarray, config: GgsConfig) -> np.ndarray:
    """Pixels (rows * cols, 256) of each grey level in each cell of ``image`` (H, W) uint8 (`_level_counts`)."""
    height, width = image.shape
    row_edges = np.linspace(0, height, config.grid_rows + 1).round().astype(int)
    col_edges = np.linspace(0, width, config.grid_cols + 1).round().astype(int)
    counts = np.empty((config.grid_rows * config.grid_cols, GREY_LEVELS))
    for r in range(config.grid_rows):
        for c in range(config.grid_cols):
            cell = image[row_edges[r] : row_edges[r + 1], col_edges[c] : col_edges[c + 1]]
            counts[r * config.grid_cols + c] = cv2.calcHist([cell], [0], None, [GREY_LEVELS], [0, 256]).ravel()
    return counts


def grey_histograms(counts: np.ndarray, bins: int) -> np.ndarray:
    """Grey histograms (..., C, bins) of cells from their grey-level counts (..., C, 256), each summing to 1.

    Bin ``k`` holds the levels ``g`` with ``floor(g bins / 256) = k``, as ``cv2.calcHist``
    with ``bins`` bins over ``[0, 256)`` counts them (the sums are of whole numbers: exact).
    """
    level_bin = np.arange(GREY_LEVELS) * bins // GREY_LEVELS
    return _shares(counts @ (level_bin[:, None] == np.arange(bins)[None, :]).astype(np.float64))


def _shares(counts: np.ndarray) -> np.ndarray:
    """Counts (..., K) divided by their sum over the last axis (at least 1), as float64.

    The division is made in float32, as the GGS has always been computed (``cv2.calcHist``
    counts in float32): in float64, 0.1 % of the stored bytes would round the other way.
    """
    total = np.maximum(counts.sum(axis=-1, keepdims=True), 1.0)
    return (counts.astype(np.float32) / total.astype(np.float32)).astype(np.float64)


def _parts_rank_histograms(counts: np.ndarray, bins: int) -> np.ndarray:
    """`rank_histograms` (2, C, bins) of the cells of both parts from their grey-level counts (2, C, 256)
    (`_level_counts`: the cells of a part add up to it)."""
    return np.stack([rank_histograms(_shares(part), part.sum(axis=0), bins) for part in counts])


def rank_histograms(histograms: np.ndarray, part_counts: np.ndarray, bins: int) -> np.ndarray:
    """Histograms (C, bins) of the grey levels' ranks in an image (or crop), of cells whose grey
    histograms (C, 256) are given (each a share of its cell); ``part_counts`` (256,) are the
    pixels of each grey level in the whole image.

    Grey level ``g`` holds the ranks ``[F(g - 1), F(g))`` of the image, ``F`` its cumulative
    grey histogram normalised to 1, and its pixels are spread evenly over them (module
    docstring, "Light"): a cell's cumulative histogram over ranks is then its cumulative
    grey histogram interpolated linearly at the grey level where ``F`` reaches the rank. It
    is read at the ``bins + 1`` edges of ``bins`` equal bins of ``[0, 1]`` and differenced.
    Where ``F`` is flat (a grey level the image lacks) the cell's cumulative histogram is
    flat too, so the interpolation is exact. (The same as multiplying by the (256, bins)
    matrix of each level's interval's overlap with each bin, to 1e-16, in a quarter of the
    time: 0.2 against 0.9 ms per KITTI image.)
    """
    cumulative = np.concatenate([[0.0], np.cumsum(part_counts)]) / max(float(part_counts.sum()), 1.0)
    cell_cumulative = np.concatenate([np.zeros((len(histograms), 1)), np.cumsum(histograms, axis=1)], axis=1)
    edges = np.linspace(0.0, 1.0, bins + 1)
    level = np.clip(np.searchsorted(cumulative, edges, side="right") - 1, 0, GREY_LEVELS - 1)
    width = cumulative[level + 1] - cumulative[level]
    share = np.divide(edges - cumulative[level], width, out=np.zeros_like(edges), where=width > 0.0)
    at_edges = cell_cumulative[:, level] + share * (cell_cumulative[:, level + 1] - cell_cumulative[:, level])
    return np.diff(at_edges, axis=1)


def quantise_histograms(histograms: np.ndarray) -> np.ndarray:
    """Normalised histograms (..., bins) as uint8 in units of ``1 / HISTOGRAM_QUANTA``, saturating at 255."""
    return np.minimum(np.rint(histograms * HISTOGRAM_QUANTA), 255).astype(np.uint8)


def ggs_distances(query: np.ndarray, database: np.ndarray) -> np.ndarray:
    """``sim_v`` (N,) between one GGS (2, C, B) and N others (N, 2, C, B), all uint8.

    For each cell, the L1 distance of the normalised histograms under the best of the
    four pairings (original or zoomed copy on either side); the mean over cells.
    0 for identical images, at most 2 up to rounding (module docstring). A C-contiguous
    uint8 ``database`` is read in place; anything else is first copied into one.
    """
    query = np.ascontiguousarray(query, dtype=np.uint8)
    database = np.ascontiguousarray(database, dtype=np.uint8).reshape((-1,) + query.shape)
    return _best_pairing_cell_l1(query, database).mean(axis=1) / HISTOGRAM_QUANTA


def ggs_distance(a: np.ndarray, b: np.ndarray) -> float:
    """``sim_v`` between two GGS descriptors (2, C, B) uint8 (`ggs_distances`)."""
    return float(ggs_distances(a, b[None])[0])


class GgsDatabase:
    """The GGS descriptors of keyframes by id, stacked in one array for `distances`.

    Stacking N descriptors for every query costs more than the query (``np.stack`` of
    1,000: 0.7 ms); here each keyframe is copied once, into a buffer whose capacity
    doubles. Rows keep insertion order (`remove` shifts the later ones up), as
    ``Map.keyframes`` does, so equal distances rank as on a stack of its descriptors.
    """

    def __init__(self) -> None:
        self._buffer: np.ndarray | None = None
        """(capacity, 2, C, B) uint8, shaped by the first descriptor added."""
        self._buffer_ids = np.empty(0, dtype=np.int64)
        self._size = 0

    def __len__(self) -> int:
        return self._size

    @property
    def ids(self) -> np.ndarray:
        """Keyframe ids (N,) int64 in insertion order: the rows of `descriptors` and `distances`."""
        return self._buffer_ids[: self._size]

    @property
    def descriptors(self) -> np.ndarray:
        """The stacked descriptors (N, 2, C, B) uint8: a C-contiguous view, which `add` and `remove` change.

        (0,) before the first `add`.
        """
        return np.empty(0, dtype=np.uint8) if self._buffer is None else self._buffer[: self._size]

    def add(self, keyframe_id: int, descriptor: np.ndarray) -> None:
        """Append the GGS (2, C, B) uint8 of a keyframe whose id is not in the database yet."""
        if self._buffer is None:
            self._buffer = np.empty((0, *descriptor.shape), dtype=np.uint8)
        if self._size == len(self._buffer):
            self._grow(max(16, 2 * self._size))
        self._buffer[self._size] = descriptor
        self._buffer_ids[self._size] = keyframe_id
        self._size += 1

    def remove(self, keyframe_id: int) -> None:
        """Drop a keyframe's descriptor (KeyError when absent); the later rows move up by one."""
        rows = np.flatnonzero(self.ids == keyframe_id)
        if len(rows) == 0:
            raise KeyError(keyframe_id)
        row = int(rows[0])
        self._buffer[row : self._size - 1] = self._buffer[row + 1 : self._size]
        self._buffer_ids[row : self._size - 1] = self._buffer_ids[row + 1 : self._size]
        self._size -= 1

    def distances(self, query: np.ndarray) -> np.ndarray:
        """``sim_v`` (N,) between ``query`` (2, C, B) uint8 and every keyframe, in the order of `ids`."""
        return ggs_distances(query, self.descriptors)

    def _grow(self, capacity: int) -> None:
        """Move the rows into buffers of ``capacity`` rows."""
        buffer = np.empty((capacity,) + self._buffer.shape[1:], dtype=np.uint8)
        buffer[: self._size] = self.descriptors
        buffer_ids = np.empty(capacity, dtype=np.int64)
        buffer_ids[: self._size] = self.ids
        self._buffer, self._buffer_ids = buffer, buffer_ids


@kernel
def _best_pairing_cell_l1(query: np.ndarray, database: np.ndarray) -> np.ndarray:
    """Per cell, the least L1 distance over the four pairings: (N, C) uint16.

    ``query`` (2, C, B) and ``database`` (N, 2, C, B) uint8, C-contiguous. One pass over
    a stored cell's two histograms sums the four pairings at once. Every sum is exact:
    ``|a - b|`` is ``max - min`` in uint8 (it cannot wrap) and a sum of B <= 256 of them
    is at most 65280 < 2 ** 16, so it is kept in uint16, which lets the loop run on
    16-bit vector lanes (numba's default int64 sums take 2.6 times as long). ``s_pq`` sums
    the query's half ``p`` against the stored half ``q``.
    """
    n, _, cells, bins = database.shape
    best = np.empty((n, cells), dtype=np.uint16)
    for i in range(n):
        for c in range(cells):
            q0, q1 = query[ORIGINAL, c], query[ZOOMED, c]
            d0, d1 = database[i, ORIGINAL, c], database[i, ZOOMED, c]
            s00 = s01 = s10 = s11 = np.uint16(0)
            for b in range(bins):
                s00 = np.uint16(s00 + _absolute_difference(q0[b], d0[b]))
                s01 = np.uint16(s01 + _absolute_difference(q0[b], d1[b]))
                s10 = np.uint16(s10 + _absolute_difference(q1[b], d0[b]))
                s11 = np.uint16(s11 + _absolute_difference(q1[b], d1[b]))
            best[i, c] = min(s00, s01, s10, s11)
    return best


@kernel
def _absolute_difference(a: np.uint8, b: np.uint8) -> np.uint8:
    """``|a - b|`` of two uint8, in uint8."""
    return np.uint8(max(a, b) - min(a, b))
