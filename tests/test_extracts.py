"""benchmarks/extracts.py: every sequence under the data folder is found, and each one left out says why."""

import importlib.util
import shutil

import pytest
from conftest import REPO_ROOT

from pld_slam.synth import write_sequence


def benchmark_module(name: str):
    """``benchmarks/NAME.py`` loaded as a module (the benchmarks are scripts, not a package)."""
    spec = importlib.util.spec_from_file_location(name, REPO_ROOT / "benchmarks" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


extracts = benchmark_module("extracts")


@pytest.fixture(scope="module")
def data_root(tmp_path_factory):
    """A data folder: one good KITTI odometry sequence, copies without ground truth and with a
    98 s gap, KITTI raw and EuRoC folders that do not open, and folders of no sequence."""
    root = tmp_path_factory.mktemp("data")
    sequences = root / "kitti_odometry" / "sequences"
    write_sequence(sequences / "00", "static", 4, (320, 240), seed=0)
    shutil.copytree(sequences / "00", sequences / "01")
    (sequences / "01" / "poses.txt").unlink()
    shutil.copytree(sequences / "00", sequences / "02")
    times = (sequences / "02" / "times.txt").read_text().split()
    (sequences / "02" / "times.txt").write_text("\n".join([*times[:-1], "98.5"]) + "\n")
    (sequences / "03" / "velodyne").mkdir(parents=True)
    (root / "kitti_raw" / "2011_09_26" / "2011_09_26_drive_0001_sync" / "image_00").mkdir(parents=True)
    (root / "euroc" / "V1_02" / "mav0").mkdir(parents=True)
    (root / "notes").mkdir()
    (root / "notes" / "README.md").write_text("not a sequence")
    return root


def test_every_sequence_folder_is_listed_and_only_those_with_ground_truth_and_consecutive_frames_kept(
        data_root, capsys):
    sequences = data_root / "kitti_odometry" / "sequences"
    raw = data_root / "kitti_raw" / "2011_09_26" / "2011_09_26_drive_0001_sync"
    assert extracts.sequence_folders(data_root) == [
        data_root / "euroc" / "V1_02", sequences / "00", sequences / "01", sequences / "02", raw,
    ]
    found = extracts.found_sequences(data_root)
    assert [folder for folder, _ in found] == [sequences / "00"]
    assert found[0][1].groundtruth is not None
    skipped = {line.split(": ", 1)[0]: line.split(": ", 1)[1] for line in capsys.readouterr().out.splitlines()}
    assert skipped[f"skipped {sequences / '01'}"] == "no ground truth"
    assert skipped[f"skipped {sequences / '02'}"].startswith("frames up to 98.3 s apart")
    assert skipped[f"skipped {raw}"].startswith("cannot be opened")
    assert skipped[f"skipped {data_root / 'euroc' / 'V1_02'}"].startswith("cannot be opened")
    assert len(skipped) == 4


def test_named_extracts_are_taken_as_named_and_none_means_every_sequence_found(data_root, monkeypatch, capsys):
    monkeypatch.setenv("PLD_SLAM_DATA", str(data_root))
    named = extracts.existing_extracts(("kitti_odometry/sequences/01", "kitti_odometry/sequences/99"))
    assert named == [data_root / "kitti_odometry" / "sequences" / "01"]  # no ground truth: taken as named
    assert "sequences/99: not found" in capsys.readouterr().out
    assert [s.name for s in extracts.real_sequences()] == ["synth_static"]
    assert extracts.existing_extracts() == [data_root / "kitti_odometry" / "sequences" / "00"]
