"""``pld-slam run --rerun FILE.rrd``: the recording read back with rerun's own reader, its features by class,
and the one-line error without the optional rerun SDK."""

import sys
from collections import defaultdict
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner
from map_fixtures import add_landmarks, camera_at, insert_observer

from pld_slam.config import load_config
from pld_slam.datasets import open_sequence
from pld_slam.mapping.map import Map
from pld_slam.report.rerun_recording import CLASS_COLOURS, feature_classes, open_recording
from pld_slam.synth import write_sequence
from pld_slam.system import RunResult, System
from pld_slam_cli.main import EXIT_USER_ERROR, cli

N_FRAMES = 6
PER_FRAME = {"/world/camera", "/world/camera/image", "/world/trajectory",
             *(f"/world/camera/image/{name}" for name in CLASS_COLOURS)}
PER_KEYFRAME = {"/world/map/points", "/world/map/lines", "/world/map/keyframes"}
STATIC = {"/world", "/world/camera/image", "/world/groundtruth"}


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    """A short synthetic street with movers (ground truth, masks), as the CLI tests use."""
    out = tmp_path_factory.mktemp("rerun") / "seq"
    write_sequence(out, "dynamic", N_FRAMES, (320, 240), seed=3)
    return out


def recorded_frames(path) -> tuple[dict[str, set[int]], set[str]]:
    """The frames each entity of the recording at ``path`` was logged at, and the entities logged static."""
    from rerun.chunk import RrdReader

    frames, static = defaultdict(set), set()
    for chunk in RrdReader(path).stream():
        if chunk.is_static:
            static.add(chunk.entity_path)
        elif "frame" in chunk.timeline_names:
            frames[chunk.entity_path].update(chunk.to_record_batch().column("frame").to_pylist())
    return frames, static


def test_a_run_recorded_for_rerun_has_each_frame_and_the_map_at_each_keyframe(folder, tmp_path):
    pytest.importorskip("rerun", reason='the rerun SDK is optional (pip install "pld-slam[viz]")')
    recording = tmp_path / "views" / "run.rrd"  # its folder is created
    result = CliRunner().invoke(cli, ["run", str(folder), "--out", str(tmp_path / "run"), "--rerun", str(recording)])
    assert result.exit_code == 0, result.output
    frames, static = recorded_frames(recording)
    assert set(frames) == PER_FRAME | PER_KEYFRAME  # a closed loop would add /world/map/loops
    assert static >= STATIC
    table = pd.read_csv(tmp_path / "run" / "frames.csv")
    for entity in PER_FRAME:
        assert frames[entity] == set(range(N_FRAMES)), entity
    keyframes = set(table["index"][table["keyframe"].notna()])
    assert len(keyframes) >= 2
    for entity in PER_KEYFRAME:
        assert frames[entity] == keyframes, entity


def test_a_closed_loop_is_recorded_as_an_edge_between_its_keyframes_centres(folder, tmp_path):
    pytest.importorskip("rerun", reason='the rerun SDK is optional (pip install "pld-slam[viz]")')
    from rerun.chunk import RrdReader

    world_map = Map(covisibility_min_shared=20)
    points, _ = add_landmarks(world_map, 3)
    keyframes = [insert_observer(world_map, points, T_c_w=camera_at([i, 0.0, 2.0 * i])) for i in range(4)]
    result = RunResult(map=world_map, loop_closing=SimpleNamespace(loops=[]))
    with open_recording(tmp_path / "loop.rrd", open_sequence(folder)) as recording:
        recording.keyframe(keyframes[2], result)  # no loop yet
        result.loop_closing.loops.append(SimpleNamespace(keyframe=3, candidate=0))
        recording.keyframe(keyframes[3], result)
    chunks = [chunk for chunk in RrdReader(tmp_path / "loop.rrd").stream() if chunk.entity_path == "/world/map/loops"]
    assert len(chunks) == 1
    batch = chunks[0].to_record_batch()
    assert batch.column("frame").to_pylist() == [keyframes[3].frame_index]
    [strips] = batch.column("LineStrips3D:strips").to_pylist()
    np.testing.assert_allclose(strips, [[[3.0, 0.0, 6.0], [0.0, 0.0, 0.0]]])


def test_the_features_of_a_frame_are_static_dynamic_or_outliers_once_each(folder):
    """The classes part the tracker's labelled features; the outliers are exactly the matches the pose rejected."""
    sequence = open_sequence(folder)
    seen = []

    def check(frame, features, tracked):
        classes = feature_classes(features, tracked)
        points = sum(len(uv) for uv, _ in classes.values())
        lines = sum(len(segments) for _, segments in classes.values())
        labels = tracked.dynamic
        assert (points, lines) == ((0, 0) if labels is None else (len(labels.point_uv), len(labels.line_segments)))
        assert len(classes["outlier"][0]) == np.count_nonzero(tracked.point_rejected)
        assert len(classes["outlier"][1]) == np.count_nonzero(tracked.line_rejected)
        assert len(classes["dynamic"][0]) == (0 if labels is None else np.count_nonzero(labels.point_dynamic))
        seen.append((len(classes["dynamic"][0]), len(classes["outlier"][0])))

    System(sequence, load_config(), [check]).run()
    assert len(seen) == N_FRAMES
    dynamic, outliers = np.array(seen).sum(axis=0)
    assert dynamic > 0 and outliers > 0  # the movers are labelled, and the pose rejected some matches


def test_without_the_rerun_sdk_the_run_stops_before_the_first_frame_saying_what_to_install(
    folder, tmp_path, monkeypatch
):
    monkeypatch.setitem(sys.modules, "rerun", None)  # import rerun raises ImportError
    result = CliRunner().invoke(cli, ["run", str(folder), "--out", str(tmp_path / "run"),
                                      "--rerun", str(tmp_path / "run.rrd")])
    assert result.exit_code == EXIT_USER_ERROR
    assert result.output.strip().splitlines()[-1] == 'error: --rerun needs the rerun SDK: pip install "pld-slam[viz]"'
    assert not (tmp_path / "run").exists() and not (tmp_path / "run.rrd").exists()
