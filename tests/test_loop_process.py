"""`LoopClosing.process`: which candidates it verifies, in what order, and what it records of each
(`pld_slam.loop.loop_closing`). The detector, the geometric check and the covisible keyframes' check
are replaced by scripted answers, and the correction by a record of its calls: those are tested on
their own (`test_loop_detection.py`, `test_loop_correction.py`)."""

import dataclasses

import numpy as np
import pytest
from map_fixtures import CAMERA, camera_at, empty_features, make_keyframe

from pld_slam.config import Config
from pld_slam.loop import loop_closing
from pld_slam.loop.detection import Detection
from pld_slam.loop.loop_closing import LoopClosing
from pld_slam.loop.verify import GeometricCheck
from pld_slam.mapping.map import Map

CURRENT = 11
"""The query keyframe; keyframes 0..CURRENT stand 5 cm apart along x, so every check below is a
plausible drift and joins keyframes at the same place."""


def config_for(detector: str, candidates: int = 3) -> Config:
    loop = dataclasses.replace(Config().loop, detector=detector, candidates=candidates)
    return dataclasses.replace(Config(), loop=loop)


def detection(candidate: int, consistent: bool) -> Detection:
    return Detection(candidate=candidate, score=0.1, bar=0.05, previous_distance=np.nan,
                     neighbour_distance=np.nan, consistency=np.nan, consistent=consistent)


def passing_check(candidate: int) -> GeometricCheck:
    """A check that places the query keyframe 2 cm from ``candidate``, with every match an inlier."""
    return GeometricCheck(T_c_w=camera_at([0.05 * candidate + 0.02, 0.0, 0.0]), matches=100, inliers=100,
                          tracking=None, local_map=None)


@pytest.fixture
def scripted(monkeypatch):
    """Build a `LoopClosing` whose detector returns ``detections``, whose geometric check returns
    ``checks[candidate]`` (None: the check failed) and whose covisible keyframes confirm ``support``;
    returns it and the candidate ids checked and closed, in call order."""

    def build(config: Config, detections: list[Detection], checks: dict[int, GeometricCheck | None],
              support: int = 0):
        calls = {"checked": [], "closed": []}

        class Detector:
            def detect(self, keyframe):
                return detections

        def geometric_check(world_map, keyframe, candidate, *args):
            calls["checked"].append(candidate.id)
            return checks[candidate.id]

        def close(self, keyframe, candidate, check):
            calls["closed"].append(candidate.id)
            return "closed"

        monkeypatch.setattr(loop_closing, "make_detector", lambda world_map, config: Detector())
        monkeypatch.setattr(loop_closing, "geometric_check", geometric_check)
        monkeypatch.setattr(loop_closing, "covisible_support", lambda *args: support)
        monkeypatch.setattr(LoopClosing, "_close", close)
        world_map = Map(covisibility_min_shared=1)
        for k in range(CURRENT + 1):
            world_map.add_keyframe(make_keyframe(k, empty_features(), camera_at([0.05 * k, 0.0, 0.0])))
        closing = LoopClosing(world_map, CAMERA, config)
        return closing, closing.process(world_map.keyframes[CURRENT]), calls

    return build


def reasons(closing: LoopClosing) -> dict[int, str]:
    return {record.candidate: record.reason for record in closing.candidates}


def test_bag_of_words_verifies_the_consistent_candidates_first_then_asks_the_covisible_keyframes(scripted):
    closing, closed, calls = scripted(
        config_for("bow"), [detection(1, consistent=False), detection(0, consistent=True)],
        {0: None, 1: passing_check(1)}, support=3,
    )
    assert calls["checked"] == [0, 1]  # the consistent one first, though the detector listed it second
    assert calls["closed"] == [1] and closed == "closed"
    assert reasons(closing) == {0: "pnp", 1: "accepted"}
    assert {record.candidate: record.covisible for record in closing.candidates}[1] == 3


def test_a_candidate_the_covisible_keyframes_do_not_confirm_is_recorded_and_not_closed(scripted):
    closing, closed, calls = scripted(config_for("bow"), [detection(1, consistent=False)], {1: passing_check(1)},
                                      support=2)
    assert calls["checked"] == [1] and calls["closed"] == [] and closed is None
    assert reasons(closing) == {1: "covisible"}


def test_a_consistent_candidate_needs_no_covisible_keyframe(scripted):
    closing, closed, calls = scripted(config_for("bow"), [detection(0, consistent=True)], {0: passing_check(0)},
                                      support=0)
    assert calls["closed"] == [0] and reasons(closing) == {0: "accepted"}
    assert np.isnan(closing.candidates[0].covisible)


def test_ggs_never_verifies_a_candidate_that_failed_its_consistency_test(scripted):
    closing, closed, calls = scripted(
        config_for("ggs"), [detection(1, consistent=False), detection(0, consistent=True)],
        {0: None, 1: passing_check(1)}, support=3,
    )
    assert calls["checked"] == [0] and calls["closed"] == [] and closed is None
    assert reasons(closing) == {1: "consistency", 0: "pnp"}


def test_no_more_than_loop_candidates_are_verified_per_keyframe(scripted):
    closing, closed, calls = scripted(
        config_for("bow", candidates=1), [detection(1, consistent=False), detection(0, consistent=True)],
        {0: None, 1: passing_check(1)}, support=3,
    )
    assert calls["checked"] == [0] and calls["closed"] == []
    assert reasons(closing) == {0: "pnp", 1: "not verified"}
