"""The keyframe rule (`pld_slam.keyframes`) on constructed GGS sequences."""

import dataclasses

import pytest

from pld_slam.config import KeyframesConfig
from pld_slam.keyframes import KeyframeEvidence, KeyframeReason, KeyframeSelector

CONFIG = KeyframesConfig()
WELL_TRACKED = dict(tracked_landmarks=500, reference_landmarks=500)


def keyframe_gaps(selector: KeyframeSelector, steps: list[float], **tracking) -> list[int]:
    """Frames between keyframes when the GGS to the last keyframe grows by ``steps[k]`` per frame
    in the k-th interval (the last step repeats), and the reason of each keyframe."""
    gaps = []
    since, ggs = 0, 0.0
    evidence = {**WELL_TRACKED, **tracking}
    while len(gaps) < len(steps):
        step = steps[len(gaps)]
        since, ggs = since + 1, ggs + step
        reason = selector.decide(KeyframeEvidence(frames_since_keyframe=since, ggs_distance=ggs, **evidence))
        if reason is not None:
            gaps.append((since, reason))
            since, ggs = 0, 0.0
    return gaps


def test_the_first_threshold_is_the_initial_steps_times_the_first_frame_change():
    selector = KeyframeSelector(CONFIG)
    # 0.1 per frame: the threshold 2 x 0.1 is passed at the third frame (0.3 > 0.2; 0.2 is not above it).
    assert keyframe_gaps(selector, [0.1]) == [(3, KeyframeReason.GGS)]


def test_a_steady_change_of_view_keeps_the_spacing():
    selector = KeyframeSelector(CONFIG)
    gaps = keyframe_gaps(selector, [0.1] * 6)
    assert [gap for gap, _ in gaps] == [3] * 6
    assert all(reason is KeyframeReason.GGS for _, reason in gaps)


def test_a_faster_change_of_view_brings_keyframes_closer_and_a_slower_one_spaces_them():
    # threshold 0.2, then 0.2 + 0.4 (0.3 - 0.1) = 0.28 (passed at once), or 0.2 + 0.4 (0.03 - 0.1) = 0.172
    faster = keyframe_gaps(KeyframeSelector(CONFIG), [0.1, 0.1, 0.3, 0.3])
    assert [gap for gap, _ in faster] == [3, 3, 1, 1]
    slower = keyframe_gaps(KeyframeSelector(CONFIG), [0.1, 0.1, 0.03, 0.03])
    assert [gap for gap, _ in slower] == [3, 3, 6, 6]


def test_the_threshold_follows_the_paper_formula_from_the_last_one():
    selector = KeyframeSelector(CONFIG)
    keyframe_gaps(selector, [0.1, 0.1])
    selector.decide(KeyframeEvidence(frames_since_keyframe=1, ggs_distance=0.15, **WELL_TRACKED))
    # GGS_th = GGS_pKF + 0.4 (GGS_pKF+1 - GGS_ppKF+1), GGS_pKF the threshold of the last keyframe (0.2)
    assert selector.threshold == pytest.approx(0.2 + 0.4 * (0.15 - 0.1))


def test_the_gain_scales_the_change_in_the_rate_of_change():
    selector = KeyframeSelector(dataclasses.replace(CONFIG, ggs_gain=0.0))
    keyframe_gaps(selector, [0.1, 0.1])
    selector.decide(KeyframeEvidence(frames_since_keyframe=1, ggs_distance=0.15, **WELL_TRACKED))
    assert selector.threshold == pytest.approx(0.2)


def test_a_keyframe_comes_at_the_latest_after_max_frames_between_and_keeps_the_threshold():
    selector = KeyframeSelector(dataclasses.replace(CONFIG, max_frames_between=4, ggs_gain=0.0))
    gaps = keyframe_gaps(selector, [0.1, 0.001, 0.001])
    assert gaps[1:] == [(4, KeyframeReason.MAX_FRAMES), (4, KeyframeReason.MAX_FRAMES)]
    selector.decide(KeyframeEvidence(frames_since_keyframe=1, ggs_distance=0.001, **WELL_TRACKED))
    assert selector.threshold == pytest.approx(0.2)  # an unchanging view does not lower it


def test_a_frame_tracking_under_the_safety_share_of_its_reference_landmarks_is_a_keyframe():
    selector = KeyframeSelector(CONFIG)
    evidence = dict(frames_since_keyframe=1, ggs_distance=0.01, reference_landmarks=400)
    assert selector.decide(KeyframeEvidence(tracked_landmarks=200, **evidence)) is None  # half: kept
    assert selector.decide(KeyframeEvidence(**{**evidence, "frames_since_keyframe": 2}, tracked_landmarks=199)) \
        is KeyframeReason.FEW_TRACKED


def test_a_safety_keyframe_before_the_threshold_lowers_the_next_threshold_to_its_ggs():
    selector = KeyframeSelector(CONFIG)
    keyframe_gaps(selector, [0.1, 0.1])  # threshold 0.2
    selector.decide(KeyframeEvidence(frames_since_keyframe=1, ggs_distance=0.1, **WELL_TRACKED))
    reason = selector.decide(KeyframeEvidence(frames_since_keyframe=2, ggs_distance=0.15, tracked_landmarks=10,
                                              reference_landmarks=500))
    assert reason is KeyframeReason.FEW_TRACKED
    selector.decide(KeyframeEvidence(frames_since_keyframe=1, ggs_distance=0.1, **WELL_TRACKED))
    assert selector.threshold == pytest.approx(0.15)  # its GGS (0.15), the rate unchanged


def test_the_tracked_ratio_policy_ignores_the_ggs_and_follows_the_tracked_landmarks():
    selector = KeyframeSelector(dataclasses.replace(CONFIG, policy="tracked_ratio", tracked_ratio=0.9))
    evidence = dict(ggs_distance=5.0, reference_landmarks=100)
    assert selector.decide(KeyframeEvidence(frames_since_keyframe=1, tracked_landmarks=90, **evidence)) is None
    assert selector.decide(KeyframeEvidence(frames_since_keyframe=2, tracked_landmarks=89, **evidence)) \
        is KeyframeReason.TRACKED_RATIO
