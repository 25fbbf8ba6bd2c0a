"""The synthetic world's cameras: KITTI's read back exactly, the default one unchanged, the
size conflict refused, and the camera carried by regression baselines and `ensure_sequence`."""

import json

import numpy as np
import pytest
from click.testing import CliRunner

from pld_slam.datasets import open_sequence
from pld_slam.errors import ConfigError, PldSlamError
from pld_slam.geometry.camera import StereoCamera
from pld_slam.report.regress import read_baseline, resolve_sequence
from pld_slam.synth import build_scenario, ensure_sequence, write_sequence
from pld_slam_cli.main import EXIT_USER_ERROR, cli

KITTI_FX, KITTI_CX, KITTI_CY, KITTI_BF = 718.856, 607.1928, 185.2157, 386.1448


def synth(*args):
    return CliRunner().invoke(cli, ["synth", *map(str, args)])


def test_the_kitti_camera_reads_back_as_kitti_odometry_00_02s(tmp_path):
    result = synth(tmp_path / "seq", "--scenario", "highway", "--camera", "kitti", "--frames", 2)
    assert result.exit_code == 0, result.output
    assert "1241x376" in result.output
    camera = open_sequence(tmp_path / "seq").camera
    assert (camera.width, camera.height) == (1241, 376)
    assert (camera.fx, camera.fy, camera.cx, camera.cy) == (KITTI_FX, KITTI_FX, KITTI_CX, KITTI_CY)
    assert camera.baseline == pytest.approx(KITTI_BF / KITTI_FX, rel=1e-12)
    assert camera.bf == pytest.approx(KITTI_BF, rel=1e-12)
    assert camera.disparity_offset == 0.0


@pytest.mark.parametrize("size", ["640x480", "1240x376"])
def test_a_size_other_than_kittis_with_the_kitti_camera_is_an_error_naming_both(tmp_path, size):
    result = synth(tmp_path / "seq", "--camera", "kitti", "--size", size, "--frames", 2)
    assert result.exit_code == EXIT_USER_ERROR
    assert f"image size {size} conflicts with camera 'kitti'" in result.output and "1241x376" in result.output
    assert not (tmp_path / "seq").exists()
    with pytest.raises(PldSlamError, match="conflicts with camera 'kitti'"):
        build_scenario("static", 2, (640, 480), camera="kitti")
    with pytest.raises(PldSlamError, match="unknown synthetic camera 'zed'"):
        build_scenario("static", 2, camera="zed")


def test_kittis_own_size_with_the_kitti_camera_is_no_conflict():
    assert build_scenario("static", 2, (1241, 376), camera="kitti").camera.size == (1241, 376)


def test_the_default_camera_is_todays_and_the_camera_changes_only_the_images(tmp_path):
    default = build_scenario("dynamic", 3, seed=2)
    assert default.camera == StereoCamera(fx=384.0, fy=384.0, cx=320.0, cy=240.0, baseline=0.5, width=640, height=480)
    kitti = build_scenario("dynamic", 3, seed=2, camera="kitti")
    np.testing.assert_array_equal(kitti.poses, default.poses)
    np.testing.assert_array_equal(kitti.scene.static.origin, default.scene.static.origin)
    implicit, explicit = tmp_path / "implicit", tmp_path / "explicit"
    write_sequence(implicit, "dynamic", 2, seed=2)
    write_sequence(explicit, "dynamic", 2, size=(640, 480), seed=2, camera="default")
    files = sorted(p.relative_to(implicit) for p in implicit.rglob("*") if p.is_file())
    assert len(files) == 10
    for name in files:
        assert (implicit / name).read_bytes() == (explicit / name).read_bytes(), name


def test_ensure_sequence_rewrites_a_folder_written_for_another_camera(tmp_path):
    ensure_sequence(tmp_path, "static", 2, seed=1)
    assert json.loads((tmp_path / "synth.json").read_text())["width"] == 640
    ensure_sequence(tmp_path, "static", 2, seed=1, camera="kitti")
    assert json.loads((tmp_path / "synth.json").read_text())["width"] == 1241
    written = (tmp_path / "image_0" / "000000.png").stat().st_mtime_ns
    ensure_sequence(tmp_path, "static", 2, seed=1, camera="kitti")  # already there: kept
    assert (tmp_path / "image_0" / "000000.png").stat().st_mtime_ns == written


def test_a_baseline_cell_may_ask_for_the_kitti_camera(tmp_path):
    folder, _ = resolve_sequence({"synthetic": "static", "seed": 0, "frames": 2, "camera": "kitti"}, tmp_path)
    assert folder.name == "static-seed0-2f-kitti"
    assert open_sequence(folder).camera.size == (1241, 376)
    folder, _ = resolve_sequence({"synthetic": "static", "seed": 0, "frames": 2}, tmp_path)
    assert folder.name == "static-seed0-2f" and open_sequence(folder).camera.size == (640, 480)
    path = tmp_path / "base.json"
    path.write_text(json.dumps({"cells": [{"name": "a", "sequence": {
        "synthetic": "static", "seed": 0, "frames": 2, "camera": "zed"}}]}))
    with pytest.raises(ConfigError, match="cell 1: a synthetic sequence's 'camera' must be one of default, kitti"):
        read_baseline(path)
