"""Keyframe selection: the paper's GGS rule, ORB-SLAM2's tracked-ratio rule, and safety rules.

The paper (section "Local map update") inserts a keyframe when "the GGS of the current
frame exceeds"

    GGS_th = GGS_pKF + 0.4 * (GGS_pKF+1 - GGS_ppKF+1)

with ``GGS_pKF`` "the GGS of the previous keyframe", ``GGS_pKF+1`` that of the frame after
it and ``GGS_ppKF+1`` that of the frame after the keyframe before. It leaves open what
"the GGS of a frame" is and how the rule starts. We decide:

- The GGS of a frame is ``sim_v`` between the frame and the last keyframe
  (`pld_slam.frontend.ggs`: 0 for identical images, growing as the view changes). It
  grows with the distance travelled and the angle turned since the keyframe, so a
  threshold on it spaces keyframes by appearance change: denser in turns and fast motion.
- ``GGS_pKF+1`` and ``GGS_ppKF+1`` are the GGS of the first frame after each of the last
  two keyframes: the one-frame change at each. Their difference raises the threshold
  when the view changes faster than before (and lowers it when slower) by 0.4 of it.
- ``GGS_pKF`` is the threshold the previous keyframe was selected under, not the value it
  reached. Read as the value reached, the rule ratchets: a keyframe's value overshoots
  the threshold by up to one frame's change, the next threshold starts from there, and
  keyframe gaps grow until the frame cap below decides alone. With the threshold, the
  rule telescopes to ``GGS_th = th_0 + 0.4 (GGS_pKF+1 - GGS_KF1+1)``: it keeps the
  spacing of the first keyframes and adapts it to the rate of change, denser in turns
  (docs/decisions/0016-keyframe-selection.md).
- A keyframe inserted because the frame tracks too few landmarks (``min_tracked_ratio``,
  below) sets ``GGS_pKF`` to its own GGS when that is lower than the threshold: the
  tracking needed a keyframe sooner, so the spacing shrinks. One inserted by the frame
  cap (``max_frames_between``) keeps the threshold: there the view hardly changed, and
  lowering the threshold to the GGS of an unchanging view would make image noise insert
  keyframes.
- Start: the first threshold is ``ggs_initial_steps`` (2) times the GGS of the frame
  after the first keyframe (one frame's change of view); the rule adapts it from the
  second keyframe on. The telescoped rule keeps the spacing of the start, so this sets
  the density of keyframes: 3 spaced them too far for local BA on the synthetic street
  (docs/decisions/0016-keyframe-selection.md).

Safety rules, which the paper does not state, apply under either policy:

- ``max_frames_between``: a keyframe at the latest after this many frames (ORB-SLAM2: one
  second of frames), so the local map keeps up when the GGS hardly changes.
- ``min_tracked_ratio``: a keyframe when the frame tracks fewer map landmarks than this
  share (50 %) of those its reference keyframe holds. Local BA can only correct
  keyframes through the landmarks they share: at ORB-SLAM2's 25 % (its emergency rule;
  its main stereo rule asks for 75 %), keyframes shared too few for local BA to keep well
  tracked poses where they were (docs/decisions/0016-keyframe-selection.md).

ORB-SLAM2's third stereo rule (a keyframe when fewer than 100 near map points are
tracked while 70 near stereo points have none) is left out: our map tracking finds about
a quarter of the near points a frame later, so it fired at every frame, and a keyframe
per frame bought no accuracy over the rules above at three times the mapping cost
(docs/decisions/0016-keyframe-selection.md).

``policy: tracked_ratio`` replaces the GGS rule by ORB-SLAM2's: a keyframe whenever the
frame tracks fewer than ``tracked_ratio`` (90 %) of its reference keyframe's landmarks.
The landmarks a reference keyframe holds are those it observes that at least two
keyframes see (ORB-SLAM2 counts its points seen by a few keyframes, leaving out the new
ones that may yet be culled).
"""

import enum
from dataclasses import dataclass

import numpy as np

from pld_slam.config import KeyframesConfig


class KeyframeReason(enum.Enum):
    """Why a frame became a keyframe."""

    FIRST = "first"
    """The first tracked frame: the map starts from it."""
    GGS = "ggs"
    """Its GGS exceeded the GGS threshold (paper)."""
    TRACKED_RATIO = "tracked_ratio"
    """It tracked fewer than ``tracked_ratio`` of its reference keyframe's landmarks (ORB-SLAM2)."""
    MAX_FRAMES = "max_frames"
    """``max_frames_between`` frames passed since the last keyframe (safety)."""
    FEW_TRACKED = "few_tracked"
    """It tracked fewer than ``min_tracked_ratio`` of its reference keyframe's landmarks (safety)."""


@dataclass(frozen=True)
class KeyframeEvidence:
    """What a tracked frame offers the keyframe decision.

    Attributes
    ----------
    frames_since_keyframe : frames since the last keyframe (1 for the frame right after it).
    ggs_distance : ``sim_v`` between the frame and the last keyframe (0 = identical).
    tracked_landmarks : map landmarks (points + lines) the frame tracked as inliers.
    reference_landmarks : landmarks of its reference keyframe seen by at least two keyframes.
    """

    frames_since_keyframe: int
    ggs_distance: float
    tracked_landmarks: int
    reference_landmarks: int


class KeyframeSelector:
    """Decides, frame by frame, which tracked frames become keyframes (module docstring).

    Call `decide` once per tracked frame, in order; a frame it names a keyframe is taken
    to be inserted. The first frame of a run is a keyframe without asking (`FIRST`).
    """

    def __init__(self, config: KeyframesConfig) -> None:
        self._config = config
        self._threshold = np.inf
        """GGS_th for the next keyframe (inf until the GGS rule has its inputs)."""
        self._base: float | None = None
        """GGS_pKF: the threshold the last keyframe was selected under (lower for a FEW_TRACKED one)."""
        self._first_steps: list[float] = []
        """GGS of the first frame after each of the last two keyframes (GGS_ppKF+1, GGS_pKF+1)."""

    @property
    def threshold(self) -> float:
        """The GGS threshold for the next keyframe (inf while the GGS rule cannot apply yet)."""
        return self._threshold

    def decide(self, evidence: KeyframeEvidence) -> KeyframeReason | None:
        """The reason the frame becomes a keyframe, or None; updates the rule's state."""
        if evidence.frames_since_keyframe == 1:
            self._record_first_step(evidence.ggs_distance)
        reason = self._reason(evidence)
        if reason is KeyframeReason.FEW_TRACKED:
            self._base = min(self._threshold, evidence.ggs_distance)
        elif reason is not None:
            self._base = self._threshold
        if reason is not None:
            self._threshold = np.inf
        return reason

    def _reason(self, evidence: KeyframeEvidence) -> KeyframeReason | None:
        config = self._config
        if evidence.frames_since_keyframe >= config.max_frames_between:
            return KeyframeReason.MAX_FRAMES
        if evidence.tracked_landmarks < config.min_tracked_ratio * evidence.reference_landmarks:
            return KeyframeReason.FEW_TRACKED
        if config.policy == "tracked_ratio":
            if evidence.tracked_landmarks < config.tracked_ratio * evidence.reference_landmarks:
                return KeyframeReason.TRACKED_RATIO
        elif evidence.ggs_distance > self._threshold:
            return KeyframeReason.GGS
        return None

    def _record_first_step(self, ggs_distance: float) -> None:
        """Keep the GGS of the frame after the last keyframe and set GGS_th (module docstring)."""
        self._first_steps = [*self._first_steps[-1:], ggs_distance]
        if self._base is None:
            self._base = self._config.ggs_initial_steps * ggs_distance
        change = self._first_steps[-1] - self._first_steps[0]
        self._threshold = self._base + self._config.ggs_gain * change
