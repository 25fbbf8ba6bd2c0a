"""What a place-recognition detector hands to verification: one `Detection` per loop candidate.

Both detectors (`pld_slam.loop.ggs_detector`, the paper's; `pld_slam.loop.bow_detector`,
the bag-of-words rival) pick a new keyframe's candidates and run their own consistency
test on them; everything after (geometric check, drift gate, ``lc_rat``, correction) is
shared by `pld_slam.loop.loop_closing`, so the two are compared on place recognition
alone.
"""

from dataclasses import dataclass
from typing import Protocol

from pld_slam.mapping.keyframe import KeyFrame


@dataclass(frozen=True)
class Detection:
    """A loop candidate of one keyframe and its detector's consistency test.

    Attributes
    ----------
    candidate : the candidate keyframe's id.
    score : the detector's similarity of the pair: a GGS distance (smaller is more similar)
        or a bag-of-words L1 score (larger is more similar).
    bar : the score the candidate had to reach (the same units).
    previous_distance, neighbour_distance : GGS stage 2 (`pld_slam.loop.verify.neighbourhood`);
        NaN for bag of words.
    consistency : bag of words, ORB-SLAM2's group consistency: consecutive keyframes whose
        candidates' groups overlap this one's; NaN for GGS.
    consistent : whether the candidate passed its detector's consistency test.
    """

    candidate: int
    score: float
    bar: float
    previous_distance: float
    neighbour_distance: float
    consistency: float
    consistent: bool


class LoopDetector(Protocol):
    """A place-recognition detector: the candidates of each new keyframe, in insertion order."""

    def detect(self, keyframe: KeyFrame) -> list[Detection]:
        """The keyframe's candidates, the most similar first; called once per keyframe, in order."""
        ...
