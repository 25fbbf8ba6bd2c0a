"""Global gray similarity (GGS): a grey-histogram descriptor of the left image, and ``sim_v``.

The paper (section "GGS") greys the left image, makes a copy "scaled by 0.8", cuts both
into 3 x 4 cells and keeps a 256-bin grey histogram per cell: 24 histograms per frame.
Two frames are compared by

    sim_v = 1 / (M N) * sum_{i=1..12} min_{p, q in {0, 1}} || hist_a(p, i) - hist_b(q, i) ||

with ``p, q`` choosing the original (0) or the scaled copy (1). What it leaves open, and
what we do:

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

Storage. A frame's GGS is one compact ``(2, cells, bins)`` uint8 array (6 KB at 3 x 4 x
256): each normalised histogram in units of ``1 / HISTOGRAM_QUANTA`` of its cell,
rounded, saturating at 255 (``255 / 400`` = 64 % of a cell in one grey level; on the
real extracts, 99 % of the cells have no bin above 57 %). Rounding changes a distance by
a small zero-mean amount; `tests/test_ggs.py` bounds it against the exact float value.
"""

import cv2
import numpy as np

from pld_slam.config import GgsConfig

HISTOGRAM_QUANTA = 400
"""A stored histogram bin counts in 1 / 400 of its cell (uint8, saturating at 255)."""

ORIGINAL, ZOOMED = 0, 1
"""Index of the original image and of its zoomed copy in a GGS descriptor's first axis."""


def ggs_descriptor(image: np.ndarray, config: GgsConfig) -> np.ndarray:
    """The GGS of a grey image (H, W) uint8: (2, rows * cols, bins) uint8 (module docstring).

    ``[ORIGINAL]`` holds the cell histograms of the image, ``[ZOOMED]`` those of its
    central ``config.scale`` crop; cells are numbered row by row.
    """
    height, width = image.shape
    crop_h, crop_w = round(config.scale * height), round(config.scale * width)
    top, left = (height - crop_h) // 2, (width - crop_w) // 2
    zoomed = image[top : top + crop_h, left : left + crop_w]
    histograms = np.stack([cell_histograms(part, config) for part in (image, zoomed)])
    return quantise_histograms(histograms)


def cell_histograms(image: np.ndarray, config: GgsConfig) -> np.ndarray:
    """Grey histograms (rows * cols, bins) float64 of the cells of ``image`` (H, W) uint8, each summing to 1.

    The cells split the rows and the columns as evenly as integer pixels allow.
    """
    height, width = image.shape
    row_edges = np.linspace(0, height, config.grid_rows + 1).round().astype(int)
    col_edges = np.linspace(0, width, config.grid_cols + 1).round().astype(int)
    histograms = np.empty((config.grid_rows * config.grid_cols, config.bins))
    for r in range(config.grid_rows):
        for c in range(config.grid_cols):
            cell = image[row_edges[r] : row_edges[r + 1], col_edges[c] : col_edges[c + 1]]
            counts = cv2.calcHist([cell], [0], None, [config.bins], [0, 256]).ravel()
            histograms[r * config.grid_cols + c] = counts / max(cell.size, 1)
    return histograms


def quantise_histograms(histograms: np.ndarray) -> np.ndarray:
    """Normalised histograms (..., bins) as uint8 in units of ``1 / HISTOGRAM_QUANTA``, saturating at 255."""
    return np.minimum(np.rint(histograms * HISTOGRAM_QUANTA), 255).astype(np.uint8)


def ggs_distances(query: np.ndarray, database: np.ndarray) -> np.ndarray:
    """``sim_v`` (N,) between one GGS (2, C, B) and N others (N, 2, C, B), all uint8.

    For each cell, the L1 distance of the normalised histograms under the best of the
    four pairings (original or zoomed copy on either side); the mean over cells.
    0 for identical images, at most 2 (module docstring).
    """
    database = np.asarray(database).reshape((-1,) + query.shape)
    per_pairing = np.stack(
        [_cell_l1(query[p], database[:, q]) for p in (ORIGINAL, ZOOMED) for q in (ORIGINAL, ZOOMED)]
    )
    return per_pairing.min(axis=0).mean(axis=1) / HISTOGRAM_QUANTA


def ggs_distance(a: np.ndarray, b: np.ndarray) -> float:
    """``sim_v`` between two GGS descriptors (2, C, B) uint8 (`ggs_distances`)."""
    return float(ggs_distances(a, b[None])[0])


def _cell_l1(query_cells: np.ndarray, database_cells: np.ndarray) -> np.ndarray:
    """L1 distances (N, C) between query cells (C, B) and each of N descriptors' cells (N, C, B), uint8 in."""
    difference = np.abs(database_cells.astype(np.int16) - query_cells.astype(np.int16))
    return difference.sum(axis=2, dtype=np.int32)
