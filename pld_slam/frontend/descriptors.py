"""Binary descriptors (ORB, LBD: 32 bytes each): Hamming distances and best-match selection.

Shared by the stereo point and line matchers, and usable by frame-to-frame matching:
both build candidate pairs from geometry first, then pick, per query, the candidate with
the smallest Hamming distance under an absolute threshold and Lowe's ratio test.
Popcounts use ``np.bitwise_count`` (numpy >= 2.0) on the descriptors viewed as four
uint64 words: 1.6 ms for 80,000 pairs, twice as fast as a 16-bit lookup table.
"""

from dataclasses import dataclass

import numpy as np

DESCRIPTOR_BYTES = 32
"""Length of an ORB or binary LBD descriptor [bytes] (256 bits)."""

MAX_DISTANCE = 8 * DESCRIPTOR_BYTES
"""Largest Hamming distance between two descriptors [bits]."""


def hamming_distances(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise Hamming distances (K,) int64 between descriptors ``a`` and ``b`` (K, 32) uint8."""
    xor = a.view(np.uint64) ^ b.view(np.uint64)
    return np.bitwise_count(xor).sum(axis=1, dtype=np.int64)


@dataclass(frozen=True)
class CandidateMatches:
    """Descriptor matches picked from candidate pairs, one per query that passed.

    Attributes
    ----------
    query, train : (K,) int64
        Indices of the matched query and train features.
    distance : (K,) int64
        Hamming distance of each match.
    """

    query: np.ndarray
    train: np.ndarray
    distance: np.ndarray


def best_matches(
    query: np.ndarray,
    train: np.ndarray,
    distance: np.ndarray,
    position: np.ndarray,
    max_distance: int,
    ratio: float,
) -> CandidateMatches:
    """The best candidate of each query, kept if it is close enough and unambiguous.

    Parameters
    ----------
    query, train : (P,) int64
        Candidate pairs (query index, train index), indices >= 0, in any order.
    distance : (P,) int64
        Hamming distance of each pair.
    position : (P,) or (P, D) float64
        Where each candidate lies (e.g. its right-image column, or its pixel), in units of
        the smallest gap between two distinct features. A candidate is a rival of the best
        only when it lies more than 1 unit (Euclidean) away from it, so that the same
        feature found twice (at two pyramid levels, say) does not make a match ambiguous.
    max_distance : int
        A best candidate farther than this is no match.
    ratio : float
        Lowe's ratio test: keep the best only when ``best < ratio * second best``, where
        the second best is the closest rival. A query with no rival passes.

    Returns
    -------
    CandidateMatches
        At most one match per query, sorted by query index; ties in distance go to the
        pair listed first, so the result is deterministic.
    """
    order = np.argsort(query * (MAX_DISTANCE + 1) + distance, kind="stable")
    query, train, distance, position = query[order], train[order], distance[order], position[order]
    first = np.flatnonzero(np.diff(query, prepend=-1))
    group_size = np.diff(np.r_[first, query.size])
    gap = position - np.repeat(position[first], group_size, axis=0)
    squared = gap**2 if gap.ndim == 1 else np.einsum("pd,pd->p", gap, gap)
    is_rival = squared > 1.0
    no_rival = np.iinfo(np.int64).max
    second = np.minimum.reduceat(np.where(is_rival, distance, no_rival), first) if first.size else first
    best = distance[first]
    keep = (best <= max_distance) & (best < ratio * second)
    kept = first[keep]
    return CandidateMatches(query[kept], train[kept], distance[kept])


def unique_train(matches: CandidateMatches) -> CandidateMatches:
    """``matches`` with each train feature used once, by its closest query.

    Ties in distance go to the match listed first (the lowest query for the output of
    `best_matches`); the result keeps the order of ``matches``.
    """
    order = np.argsort(matches.train * (MAX_DISTANCE + 1) + matches.distance, kind="stable")
    first = np.sort(order[np.flatnonzero(np.diff(matches.train[order], prepend=-1))])
    return CandidateMatches(matches.query[first], matches.train[first], matches.distance[first])
