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
  on the synthetic loop (360 frames) keyframe gaps grew from 5 to 20-30 frames until the
  frame cap below decided alone; on KITTI raw 0005 one gap reached 29 frames. With the
  threshold, the rule telescopes to ``GGS_th = th_0 + 0.4 (GGS_pKF+1 - GGS_KF1+1)``: it
  keeps the spacing of the first keyframes and adapts it to the rate of change
  (simulated on the synthetic loop: a keyframe every 3.7 frames in the turns, every 7.2
  on the straights; KITTI raw 0005, turning at a junction: 3.0 against 5.0).
- A keyframe inserted by a safety rule (below) sets ``GGS_pKF`` to its own GGS when that
  is lower than the threshold: the tracking needed a keyframe sooner, so the spacing
  shrinks.
- Start: the threshold needs two keyframes and the frame after each; until then only
  the safety rules insert keyframes.

Safety rules, which the paper does not state, apply under either policy:

- ``max_frames_between``: a keyframe at the latest after this many frames (ORB-SLAM2: one
  second of frames), so the local map keeps up when the GGS hardly changes.
- ``min_tracked_ratio``: a keyframe when the frame tracks fewer map landmarks than this
  share (25 %, ORB-SLAM2's stereo emergency rule) of those its reference keyframe holds.
- Close points (ORB-SLAM2's stereo ``bNeedToInsertClose``): a keyframe when the frame
  tracks fewer than ``min_tracked_close`` (100) map points nearer than
  ``close_depth_baselines`` (40 baselines) while more than ``min_new_close`` (70) of its
  stereo points that near have no map point yet. Near points fix the translation; they
  also change appearance fastest and are found again least (on the synthetic street, a
  point nearer than 10 m was matched in 21 % of the frames that should see it, against
  40 % beyond 30 m), so without this rule the map kept the far points only and a
  frame's translation rested on them.

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
    CLOSE_POINTS = "close_points"
    """It tracked too few near map points and could create many (safety, ORB-SLAM2's stereo rule)."""


@dataclass(frozen=True)
class KeyframeEvidence:
    """What a tracked frame offers the keyframe decision.

    Attributes
    ----------
    frames_since_keyframe : frames since the last keyframe (1 for the frame right after it).
    ggs_distance : ``sim_v`` between the frame and the last keyframe (0 = identical).
    tracked_landmarks : map landmarks (points + lines) the frame tracked as inliers.
    reference_landmarks : landmarks of its reference keyframe seen by at least two keyframes.
    tracked_close, untracked_close : the frame's stereo points nearer than
        ``close_depth_baselines`` that tracked a map point, and that did not.
    """

    frames_since_keyframe: int
    ggs_distance: float
    tracked_landmarks: int
    reference_landmarks: int
    tracked_close: int = 0
    untracked_close: int = 0


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
        """GGS_pKF: the threshold the last keyframe was selected under, or its own GGS."""
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
        if reason is not None:
            self._base = min(self._threshold, evidence.ggs_distance)
            self._threshold = np.inf
        return reason

    def _reason(self, evidence: KeyframeEvidence) -> KeyframeReason | None:
        config = self._config
        if evidence.frames_since_keyframe >= config.max_frames_between:
            return KeyframeReason.MAX_FRAMES
        if evidence.tracked_landmarks < config.min_tracked_ratio * evidence.reference_landmarks:
            return KeyframeReason.FEW_TRACKED
        if evidence.tracked_close < config.min_tracked_close and evidence.untracked_close > config.min_new_close:
            return KeyframeReason.CLOSE_POINTS
        if config.policy == "tracked_ratio":
            if evidence.tracked_landmarks < config.tracked_ratio * evidence.reference_landmarks:
                return KeyframeReason.TRACKED_RATIO
        elif evidence.ggs_distance > self._threshold:
            return KeyframeReason.GGS
        return None

    def _record_first_step(self, ggs_distance: float) -> None:
        """Keep the GGS of the frame after the last keyframe and, with two of them, set GGS_th."""
        self._first_steps = [*self._first_steps[-1:], ggs_distance]
        if len(self._first_steps) == 2 and self._base is not None:
            previous, latest = self._first_steps
            self._threshold = self._base + self._config.ggs_gain * (latest - previous)
