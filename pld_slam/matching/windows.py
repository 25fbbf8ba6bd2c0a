"""The window search of every matcher: candidate pairs of predicted and observed pixels within a radius.

`pairs_within` runs a numba kernel over square cells. Called by frame-to-frame matching
(`pld_slam.matching.frames`), the projection search of map landmarks
(`pld_slam.matching.projection`) and tracking's judgement of the landmarks missed near
movers (`pld_slam.localisation.local_map.missed_near_movers`).
"""

import numpy as np

from pld_slam.jit import kernel

_MAX_CELLS = 1_000_000
"""`pairs_within` widens its cells so that the observed pixels' extent holds at most this many
(8 MB of cell starts), whatever the pixels' spread; an image, or a fusion's 11 keyframes
side by side, holds fewer at the median radius."""


def pairs_within(predicted: np.ndarray, usable: np.ndarray, observed: np.ndarray, radius: np.ndarray):
    """Candidate pairs ``(query, train)`` (P,) with ``|observed[train] - predicted[query]| <= radius[query]``.

    ``predicted`` (Q, 2) and ``observed`` (K, 2) pixels, ``usable`` (Q,) bool, ``radius`` (Q,)
    [px]. Pairs come out sorted by query, then by observed column (ties by index). The
    observed pixels are put in square cells as wide as the median radius, and each usable
    query tests those of the cells its circle reaches (`_pairs_in_cells`). It replaced a
    numpy search of the observed pixels sorted by column, whose windows ran the whole
    image high, the largest cost of matching the local map and of local mapping's fusion;
    the pairs and their order are the same (see docs/decisions/0023-matching-search-cost.md).
    """
    queries = np.flatnonzero(usable)
    if len(queries) == 0 or len(observed) == 0:
        no_pairs = np.zeros(0, dtype=np.int64)
        return no_pairs, no_pairs
    extent = np.ptp(observed, axis=0) + 1.0
    cell = max(float(np.median(radius[queries])), 1.0, float(np.sqrt(extent[0] * extent[1] / _MAX_CELLS)))
    return _pairs_in_cells(
        np.ascontiguousarray(predicted, dtype=np.float64), queries, np.ascontiguousarray(observed, dtype=np.float64),
        np.ascontiguousarray(radius, dtype=np.float64), cell,
    )


@kernel
def _pairs_in_cells(predicted, queries, observed, radius, cell):
    """`pairs_within` for the ``queries`` (Q',) int64, with observed pixels in square cells ``cell`` px wide."""
    n_observed = observed.shape[0]
    u0, v0 = observed[:, 0].min(), observed[:, 1].min()
    n_columns = int((observed[:, 0].max() - u0) // cell) + 1
    n_rows = int((observed[:, 1].max() - v0) // cell) + 1
    cell_of = np.empty(n_observed, dtype=np.int64)
    first_in_cell = np.zeros(n_rows * n_columns + 1, dtype=np.int64)
    for k in range(n_observed):
        cell_of[k] = int((observed[k, 1] - v0) // cell) * n_columns + int((observed[k, 0] - u0) // cell)
        first_in_cell[cell_of[k] + 1] += 1
    first_in_cell = np.cumsum(first_in_cell)
    members = np.empty(n_observed, dtype=np.int64)
    filled = first_in_cell[:-1].copy()
    for k in range(n_observed):
        members[filled[cell_of[k]]] = k
        filled[cell_of[k]] += 1
    capacity = max(16, 4 * len(queries))
    query_out = np.empty(capacity, dtype=np.int64)
    train_out = np.empty(capacity, dtype=np.int64)
    n_pairs = 0
    for query in queries:
        u, v, r = predicted[query, 0], predicted[query, 1], radius[query]
        first_column, last_column = max(int((u - r - u0) // cell), 0), min(int((u + r - u0) // cell), n_columns - 1)
        first_row, last_row = max(int((v - r - v0) // cell), 0), min(int((v + r - v0) // cell), n_rows - 1)
        start = n_pairs
        for row in range(first_row, last_row + 1):
            for column in range(first_column, last_column + 1):
                c = row * n_columns + column
                for m in range(first_in_cell[c], first_in_cell[c + 1]):
                    k = members[m]
                    du, dv = observed[k, 0] - u, observed[k, 1] - v
                    if du * du + dv * dv <= r * r:
                        if n_pairs == capacity:
                            capacity *= 2
                            query_out = _grown(query_out, capacity)
                            train_out = _grown(train_out, capacity)
                        query_out[n_pairs] = query
                        train_out[n_pairs] = k
                        n_pairs += 1
        for i in range(start + 1, n_pairs):  # insertion sort of the query's pairs by (column, index)
            k = train_out[i]
            j = i - 1
            while j >= start and (observed[train_out[j], 0] > observed[k, 0]
                                  or (observed[train_out[j], 0] == observed[k, 0] and train_out[j] > k)):
                train_out[j + 1] = train_out[j]
                j -= 1
            train_out[j + 1] = k
    return query_out[:n_pairs].copy(), train_out[:n_pairs].copy()


@kernel
def _grown(values, capacity):
    """``values`` (n,) copied into a new array of ``capacity`` (> n) entries."""
    grown = np.empty(capacity, dtype=values.dtype)
    grown[: len(values)] = values
    return grown
