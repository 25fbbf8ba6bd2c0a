"""Loop closures scored against ground truth: precision of candidates and loops, recall of revisits.

A pair of keyframes shows the same place when their true camera centres are within 3 m
and their optical axes within 30 deg (`pld_slam.geometry.places.same_place`, the issue's
definition). What it leaves open, and what we do:

- Precision: the share of closed loops whose two keyframes show the same place; the same
  for every candidate the detector proposed (place recognition before verification).
- Recall. Once a loop is closed, the keyframes that follow are joined to the old map and
  are no longer asked to find it again (ORB-SLAM2 behaves the same), so a recall per
  keyframe would count a perfectly closed loop as a handful of misses. We count revisits
  instead: a *revisit* is a run of consecutive queried keyframes each of which shows the
  same place as some keyframe queried more than ``exclude_recent`` keyframe ids before it;
  a revisit is found when one of its keyframes closed a true loop. Recall is found
  revisits over revisits. Keyframes culled later still count as places seen.
- Keyframes without a ground-truth pose within 10 ms take no part.
"""

from dataclasses import dataclass

import numpy as np

from pld_slam.geometry.places import same_place
from pld_slam.trajectory import Trajectory

_MAX_TIME_DIFF_S = 0.01


@dataclass(frozen=True)
class LoopTruth:
    """Loop closing against ground truth (module docstring); precisions and recall None where undefined."""

    candidates: int
    true_candidates: int
    loops: int
    true_loops: int
    revisits: int
    found_revisits: int

    @property
    def candidate_precision(self) -> float | None:
        return self.true_candidates / self.candidates if self.candidates else None

    @property
    def precision(self) -> float | None:
        return self.true_loops / self.loops if self.loops else None

    @property
    def recall(self) -> float | None:
        return self.found_revisits / self.revisits if self.revisits else None

    def as_dict(self) -> dict:
        return {
            "candidates": self.candidates, "true_candidates": self.true_candidates,
            "candidate_precision": self.candidate_precision, "loops": self.loops, "true_loops": self.true_loops,
            "precision": self.precision, "revisits": self.revisits, "found_revisits": self.found_revisits,
            "recall": self.recall,
        }


def true_poses_at(groundtruth: Trajectory, timestamps: np.ndarray) -> np.ndarray:
    """Ground-truth ``T_w_c`` (K, 4, 4) at ``timestamps`` (K,): the nearest pose within 10 ms, NaN otherwise."""
    right = np.clip(np.searchsorted(groundtruth.timestamps, timestamps), 1, max(len(groundtruth) - 1, 1))
    left = right - 1
    nearer = np.where(
        np.abs(groundtruth.timestamps[right] - timestamps) < np.abs(groundtruth.timestamps[left] - timestamps),
        right, left,
    )
    poses = groundtruth.poses[nearer].copy()
    poses[np.abs(groundtruth.timestamps[nearer] - timestamps) > _MAX_TIME_DIFF_S] = np.nan
    return poses


def score_loops(
    groundtruth: Trajectory,
    query_ids: np.ndarray,
    query_times: np.ndarray,
    candidate_pairs: np.ndarray,
    loop_pairs: np.ndarray,
    exclude_recent: int,
) -> LoopTruth:
    """Score a run's loop closing against ``groundtruth``.

    Parameters
    ----------
    query_ids, query_times : (Q,) every keyframe looked up for a loop, in order: id and timestamp [s].
    candidate_pairs, loop_pairs : (C, 2), (L, 2) int keyframe ids (query, candidate) of the
        candidates proposed and of the loops closed.
    exclude_recent : ``loop.exclude_recent_keyframes``.
    """
    poses = true_poses_at(groundtruth, np.asarray(query_times, dtype=np.float64))
    row = {int(k): n for n, k in enumerate(query_ids)}

    def true_pairs(pairs: np.ndarray) -> int:
        pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
        known = np.array([a in row and b in row for a, b in pairs.tolist()], dtype=bool)
        rows = np.array([[row[a], row[b]] for a, b in pairs[known].tolist()], dtype=np.int64).reshape(-1, 2)
        return int(same_place(poses[rows[:, 0]], poses[rows[:, 1]]).sum())

    revisit = revisiting(np.asarray(query_ids), poses, exclude_recent)
    found = np.zeros(len(query_ids), dtype=bool)
    for a, b in np.asarray(loop_pairs, dtype=np.int64).reshape(-1, 2).tolist():
        if a in row and b in row and same_place(poses[row[a]], poses[row[b]]):
            found[row[a]] = True
    events = np.cumsum(revisit & ~np.concatenate([[False], revisit[:-1]]))
    return LoopTruth(
        candidates=len(np.asarray(candidate_pairs).reshape(-1, 2)), true_candidates=true_pairs(candidate_pairs),
        loops=len(np.asarray(loop_pairs).reshape(-1, 2)), true_loops=true_pairs(loop_pairs),
        revisits=int(events[-1]) if len(events) else 0,
        found_revisits=len(np.unique(events[revisit & found])),
    )


def revisiting(query_ids: np.ndarray, poses: np.ndarray, exclude_recent: int) -> np.ndarray:
    """(Q,) bool: each queried keyframe shows the same place as one queried more than
    ``exclude_recent`` ids before it. ``poses`` (Q, 4, 4) true ``T_w_c``."""
    same = same_place(poses[:, None], poses[None, :])
    earlier = query_ids[None, :] < query_ids[:, None] - exclude_recent
    return (same & earlier).any(axis=1)

