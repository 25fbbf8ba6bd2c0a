"""Bag-of-words place recognition, as ORB-SLAM2 does it: the rival of the paper's GGS.

Each new keyframe's ORB descriptors (the static ones: features labelled dynamic are left
out, as they are of the map) become a bag-of-words vector (`pld_slam.loop.vocabulary`),
scored against the earlier keyframes through an inverse index (`BowDatabase`). Candidate
selection follows ORB-SLAM2's ``KeyFrameDatabase::DetectLoopCandidates`` and
``LoopClosing::DetectLoop``:

1. The bar: the lowest score between the keyframe and its covisible neighbours.
2. Keyframes sharing words with it, except its covisible keyframes and the
   ``loop.exclude_recent_keyframes`` just before it (ORB-SLAM2 excludes only the
   covisible ones; we exclude the recent ones too, as GGS does, so that both detectors
   are asked the same question). Kept: those with at least ``loop.bow_common_words_ratio``
   (80 %) of the largest number of shared words, and a score at least the bar.
3. Each kept keyframe's group (itself and its ``loop.bow_group_neighbours`` (10) strongest
   covisible neighbours among the kept ones) accumulates their scores; the best-scored
   keyframe of every group whose accumulated score exceeds ``loop.bow_retain_ratio`` (75 %)
   of the best group's is a candidate.
4. Group consistency: a candidate's group (itself and its covisible neighbours) is
   consistent with a group of the previous keyframe's when they share a keyframe; a chain
   of ``loop.bow_consistency`` (3) such consecutive keyframes makes the candidate
   consistent. This is the detector's consistency test (`pld_slam.loop.detection`);
   the geometric check and the rest are shared with GGS, which verifies the first
   ``loop.candidates`` consistent candidates.
5. Consistency in the covisibility window (ORB-SLAM3's ``DetectCommonRegionsFromBoW``;
   ``loop.bow_covisible_check``): a candidate not (yet) consistent in time is verified as
   well, after the consistent ones, and accepted only when, besides every test of
   verification, the pose found for the keyframe also holds in ``loop.bow_consistency`` of
   its covisible keyframes (`pld_slam.loop.verify.covisible_support`). Group consistency
   alone needs four consecutive keyframes whose top-scored groups overlap; where a revisit
   is short, or the old place wins the scoring only when the camera is already there, it
   is over before the chain is, and the loop is missed; ORB-SLAM3 takes the evidence from
   the keyframes already in the map. The price is a geometric check of up to
   ``loop.candidates`` candidates at almost every keyframe (see
   docs/decisions/0022-bow-covisible-check.md).
"""

from dataclasses import dataclass

import numpy as np

from pld_slam.config import LoopConfig
from pld_slam.loop.detection import Detection
from pld_slam.loop.vocabulary import BowVector, Vocabulary, bow_score
from pld_slam.mapping.keyframe import KeyFrame
from pld_slam.mapping.map import Map


class BowDatabase:
    """An inverse index from words to the keyframes whose vectors hold them, with their weights.

    Each word's postings are two small arrays (keyframe ids, weights), grown by one entry
    per keyframe holding the word; a query gathers the postings of its words and sums per
    keyframe with `np.bincount` (keyframe ids are small integers), with no Python loop over
    postings.
    """

    def __init__(self) -> None:
        self._keyframes: dict[int, np.ndarray] = {}
        self._weights: dict[int, np.ndarray] = {}
        self._size = 0

    def add(self, keyframe_id: int, vector: BowVector) -> None:
        """Index a keyframe's vector."""
        empty = np.zeros(0)
        for word, weight in zip(vector.words.tolist(), vector.weights.tolist()):
            self._keyframes[word] = np.append(self._keyframes.get(word, empty.astype(np.int64)), keyframe_id)
            self._weights[word] = np.append(self._weights.get(word, empty), weight)
        self._size = max(self._size, keyframe_id + 1)

    def query(self, vector: BowVector) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Every indexed keyframe sharing a word with ``vector``: ids (N,) ascending, shared words (N,),
        and L1 scores (N,) (`pld_slam.loop.vocabulary.bow_score`: the sum of the smaller weights)."""
        present = [(word, weight) for word, weight in zip(vector.words.tolist(), vector.weights.tolist())
                   if word in self._keyframes]
        if not present:
            return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64), np.zeros(0)
        keyframes = np.concatenate([self._keyframes[word] for word, _ in present])
        weights = np.concatenate([self._weights[word] for word, _ in present])
        lengths = [len(self._keyframes[word]) for word, _ in present]
        query_weights = np.repeat([weight for _, weight in present], lengths)
        shared = np.bincount(keyframes, minlength=self._size)
        scores = np.bincount(keyframes, weights=np.minimum(weights, query_weights), minlength=self._size)
        ids = np.flatnonzero(shared)
        return ids, shared[ids], scores[ids]


@dataclass(frozen=True)
class _Group:
    """A candidate's group of keyframes and how many consecutive keyframes it has been consistent for."""

    keyframes: frozenset[int]
    consistency: int


class BowDetector:
    """ORB-SLAM2's loop detector (module docstring): keeps the inverse index and the consistent groups."""

    def __init__(self, world_map: Map, vocabulary: Vocabulary, config: LoopConfig) -> None:
        self._map = world_map
        self._vocabulary = vocabulary
        self._config = config
        self.database = BowDatabase()
        self.vectors: dict[int, BowVector] = {}
        """Each keyframe's bag-of-words vector, by keyframe id."""
        self._groups: list[_Group] = []

    def vector_of(self, keyframe: KeyFrame) -> BowVector:
        """The bag-of-words vector of the keyframe's static keypoints."""
        descriptors = keyframe.features.keypoints.descriptors[~keyframe.point_dynamic]
        return self._vocabulary.bow_vector(descriptors)

    def detect(self, keyframe: KeyFrame) -> list[Detection]:
        """The keyframe's candidates with their group consistency, the best scored first; then index it."""
        vector = self.vector_of(keyframe)
        self.vectors[keyframe.id] = vector
        bar = self._bar(keyframe, vector)
        candidates, scores = self._scored_candidates(keyframe, vector, bar)
        consistency = self._update_groups(candidates)
        self.database.add(keyframe.id, vector)
        return [
            Detection(candidate=c, score=s, bar=bar, previous_distance=np.nan, neighbour_distance=np.nan,
                      consistency=float(n), consistent=n >= self._config.bow_consistency)
            for c, s, n in zip(candidates, scores, consistency)
        ]

    def _bar(self, keyframe: KeyFrame, vector: BowVector) -> float:
        """Step 1: the lowest score with a covisible neighbour (NaN without any)."""
        scores = [bow_score(vector, self.vectors[k]) for k in self._map.covisibility.neighbours(keyframe.id)
                  if k in self.vectors]
        return min(scores) if scores else float("nan")

    def _scored_candidates(self, keyframe: KeyFrame, vector: BowVector, bar: float) -> tuple[list[int], list[float]]:
        """Steps 2 and 3: the best keyframe of each retained group and its score, the best first."""
        if np.isnan(bar):
            return [], []
        ids, shared, scores = self.database.query(vector)
        joined = [*self._map.covisibility.shared(keyframe.id), keyframe.id]
        eligible = (np.isin(ids, list(self._map.keyframes)) & ~np.isin(ids, joined)
                    & (ids < keyframe.id - self._config.exclude_recent_keyframes))
        if not eligible.any():
            return [], []
        config = self._config
        kept = eligible & (shared >= config.bow_common_words_ratio * shared[eligible].max()) & (scores >= bar)
        score_of = dict(zip(ids[kept].tolist(), scores[kept].tolist()))
        best: dict[int, float] = {}
        accumulated: dict[int, float] = {}
        for candidate, score in score_of.items():
            group = [candidate, *(k for k in self._map.covisibility.neighbours(candidate, config.bow_group_neighbours)
                                  if k in score_of)]
            leader = max(group, key=lambda k: (score_of[k], -k))
            total = sum(score_of[k] for k in group)
            if total > accumulated.get(leader, -1.0):
                best[leader], accumulated[leader] = score_of[leader], total
        if not accumulated:
            return [], []
        retain = config.bow_retain_ratio * max(accumulated.values())
        leaders = sorted((k for k in accumulated if accumulated[k] > retain), key=lambda k: (-best[k], k))
        return leaders, [best[k] for k in leaders]

    def _update_groups(self, candidates: list[int]) -> list[int]:
        """Step 4: each candidate's consistency, and the groups carried to the next keyframe."""
        previous, self._groups = self._groups, []
        extended = [False] * len(previous)
        consistency = []
        for candidate in candidates:
            group = frozenset([candidate, *self._map.covisibility.neighbours(candidate)])
            best = 0
            linked = False
            for n, old in enumerate(previous):
                if group.isdisjoint(old.keyframes):
                    continue
                linked = True
                best = max(best, old.consistency + 1)
                if not extended[n]:
                    self._groups.append(_Group(group, old.consistency + 1))
                    extended[n] = True
            if not linked:
                self._groups.append(_Group(group, 0))
            consistency.append(best)
        return consistency
