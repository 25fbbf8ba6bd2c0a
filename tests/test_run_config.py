"""The configuration of a run: the dataset family from the layout, its packaged file, the layering."""

import json

import pytest
import yaml
from click.testing import CliRunner
from conftest import require
from test_datasets import make_generic, rectified_calibration

from pld_slam.config import Config, apply_mapping
from pld_slam.datasets import open_sequence
from pld_slam.errors import ConfigError
from pld_slam.run_config import FAMILY_FILES, dataset_family, family_config_name, load_run_config, packaged_config
from pld_slam.synth import write_sequence
from pld_slam_cli.main import cli


def family_value(name: str, section: str, key: str):
    """``section.key`` as written in the packaged family file ``name``."""
    return yaml.safe_load(packaged_config(name).read_text())[section][key]


@pytest.fixture(scope="module")
def synthetic_folder(tmp_path_factory):
    """A 3-frame sequence written by `write_sequence` (KITTI odometry layout plus synth.json)."""
    folder = tmp_path_factory.mktemp("synth") / "seq"
    write_sequence(folder, "static", n_frames=3, size=(160, 120), seed=0)
    return folder


@pytest.mark.parametrize(
    "extract, layout, family",
    [
        ("kitti_odometry/sequences/06", "kitti_odometry", "kitti"),
        ("kitti_raw/2011_09_26/2011_09_26_drive_0005_sync", "kitti_raw", "kitti"),
        ("euroc/V1_01_easy_static", "euroc", "euroc"),
    ],
)
def test_real_layouts_map_to_their_family(data_dir, extract, layout, family):
    sequence = open_sequence(require(data_dir / extract))
    assert sequence.layout == layout
    assert dataset_family(sequence) == family


def test_a_synth_sequence_is_synthetic_though_in_the_kitti_layout(synthetic_folder):
    sequence = open_sequence(synthetic_folder)
    assert sequence.layout == "kitti_odometry"
    assert dataset_family(sequence) == "synthetic"


def test_a_generic_folder_gets_the_defaults_only(tmp_path):
    sequence = open_sequence(make_generic(tmp_path, rectified_calibration()))
    assert dataset_family(sequence) == "generic"
    assert family_config_name("generic") is None
    run_config = load_run_config(sequence)
    assert run_config.config == Config()
    assert run_config.sources == ("defaults",)


def test_the_family_file_is_laid_over_the_defaults(synthetic_folder):
    run_config = load_run_config(open_sequence(synthetic_folder))
    n_features = family_value("synthetic.yaml", "points", "n_features")
    assert n_features != Config().points.n_features
    assert run_config.config.points.n_features == n_features
    assert run_config.sources == ("defaults", "family: synthetic.yaml")


def test_user_files_then_set_beat_the_family_file(synthetic_folder, tmp_path):
    mine = tmp_path / "mine.yaml"
    mine.write_text("points:\n  n_features: 555\n")
    sequence = open_sequence(synthetic_folder)
    assert load_run_config(sequence, [mine]).config.points.n_features == 555
    run_config = load_run_config(sequence, [mine], ["points.n_features=777"])
    assert run_config.config.points.n_features == 777
    assert run_config.sources == ("defaults", "family: synthetic.yaml", str(mine), "--set points.n_features=777")


@pytest.mark.parametrize("family", [family for family, name in FAMILY_FILES.items() if name is not None])
def test_every_packaged_family_file_loads_and_changes_something(family):
    name = family_config_name(family)
    config = apply_mapping(Config(), yaml.safe_load(packaged_config(name).read_text()), name)
    assert config != Config()


def test_packaged_defaults_equal_the_dataclass_defaults_and_unknown_names_are_errors():
    assert apply_mapping(Config(), yaml.safe_load(packaged_config("default.yaml").read_text()), "d") == Config()
    with pytest.raises(ConfigError, match="kitti.yaml"):
        packaged_config("kiti.yaml")
    with pytest.raises(ConfigError, match="unknown dataset family"):
        family_config_name("tum")


def test_run_writes_the_config_sources_into_the_summary(synthetic_folder, tmp_path):
    out = tmp_path / "run"
    result = CliRunner().invoke(cli, ["run", str(synthetic_folder), "--out", str(out), "--set", "lines.enabled=false"])
    assert result.exit_code == 0, result.output
    summary = json.loads((out / "summary.json").read_text())
    assert summary["config_sources"] == ["defaults", "family: synthetic.yaml", "--set lines.enabled=false"]
    assert summary["config"]["points"]["n_features"] == family_value("synthetic.yaml", "points", "n_features")


def test_config_with_a_sequence_prints_the_family_value(synthetic_folder):
    result = CliRunner().invoke(cli, ["config", "--sequence", str(synthetic_folder)])
    assert result.exit_code == 0, result.output
    assert result.output.startswith("# sources: defaults, family: synthetic.yaml\n")
    n_features = yaml.safe_load(result.output)["points"]["n_features"]
    assert n_features == family_value("synthetic.yaml", "points", "n_features")
    without = yaml.safe_load(CliRunner().invoke(cli, ["config"]).output)
    assert without["points"]["n_features"] == Config().points.n_features
