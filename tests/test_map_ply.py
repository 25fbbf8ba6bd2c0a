"""map.ply: the map's points, line landmarks and keyframe centres, read back with plyfile."""

import numpy as np
import pytest
from plyfile import PlyData

from pld_slam.config import load_config
from pld_slam.datasets import open_sequence
from pld_slam.eval.run_summary import summarise_run
from pld_slam.io.map_ply import MapCloud, map_cloud, read_map_ply, write_map_ply
from pld_slam.io.run_output import KEYFRAMES_TUM, MAP_PLY, TIMING_PLOT
from pld_slam.io.trajectory import read_trajectory
from pld_slam.report.run_files import write_run_outputs
from pld_slam.synth import write_sequence
from pld_slam.system import System


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    folder = tmp_path_factory.mktemp("map_ply") / "static"
    write_sequence(folder, "static", 12, (320, 240), seed=0)
    sequence, config = open_sequence(folder), load_config()
    return sequence, config, System(sequence, config).run()


def test_a_cloud_survives_the_file_to_float32_precision(tmp_path):
    rng = np.random.default_rng(0)
    cloud = MapCloud(points_w=rng.normal(0, 20, (50, 3)), point_observers=rng.integers(1, 9, 50),
                     lines_w=rng.normal(0, 20, (7, 2, 3)), line_observers=rng.integers(1, 9, 7),
                     keyframe_centres_w=rng.normal(0, 20, (4, 3)))
    write_map_ply(tmp_path / "map.ply", cloud)
    back = read_map_ply(tmp_path / "map.ply")
    for name in ("points_w", "lines_w", "keyframe_centres_w"):
        np.testing.assert_allclose(getattr(back, name), getattr(cloud, name), rtol=1e-6, atol=1e-5)
    np.testing.assert_array_equal(back.point_observers, cloud.point_observers)
    np.testing.assert_array_equal(back.line_observers, cloud.line_observers)


def test_the_run_writes_the_map_with_the_counts_of_its_summary(run, tmp_path):
    sequence, config, result = run
    summary = summarise_run(sequence, result, config)
    written = write_run_outputs(tmp_path, result.trajectory(), summary, sequence.groundtruth, "map",
                                records=result.records, cloud=map_cloud(result.map),
                                keyframes=result.map.keyframe_trajectory())
    assert {tmp_path / MAP_PLY, tmp_path / KEYFRAMES_TUM, tmp_path / TIMING_PLOT} <= set(written)
    ply = PlyData.read(str(tmp_path / MAP_PLY))  # as a user's tool reads it
    landmarks = summary["mapping"]["landmarks"]
    assert landmarks["points"] > 0 and landmarks["lines"] > 0
    assert ply["vertex"].count == landmarks["points"] + 2 * landmarks["lines"]
    assert ply["edge"].count == landmarks["lines"]
    assert ply["camera"].count == summary["mapping"]["keyframes_alive"]
    edges = ply["edge"].data
    assert np.all(edges["vertex2"] == edges["vertex1"] + 1) and edges["vertex1"].min() == landmarks["points"]
    assert np.all(ply["vertex"].data["observers"] >= 1)


def test_keyframes_tum_holds_each_keyframe_at_the_pose_of_its_frame(run, tmp_path):
    sequence, config, result = run
    write_run_outputs(tmp_path, result.trajectory(), summarise_run(sequence, result, config), None, "kf",
                      keyframes=result.map.keyframe_trajectory())
    keyframes, frames = read_trajectory(tmp_path / KEYFRAMES_TUM, "tum"), result.trajectory()
    assert len(keyframes) == len(result.map.keyframes) >= 2
    at = np.searchsorted(frames.timestamps, keyframes.timestamps)
    np.testing.assert_allclose(frames.timestamps[at], keyframes.timestamps, atol=1e-6)
    np.testing.assert_allclose(frames.positions[at], keyframes.positions, atol=1e-6)
    centres = map_cloud(result.map).keyframe_centres_w  # map.ply's cameras: the same keyframes
    np.testing.assert_allclose(np.sort(centres, axis=0), np.sort(keyframes.positions, axis=0), atol=1e-6)
