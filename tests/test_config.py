"""Configuration: paper defaults, YAML layering, overrides, and errors that name the key."""

import dataclasses
from pathlib import Path

import pytest

from pld_slam.config import ORDERED_KEYS, Config, dump_config, load_config
from pld_slam.errors import ConfigError

CONFIGS = Path(__file__).resolve().parents[1] / "configs"


def test_defaults_are_the_papers_values():
    config = Config()
    assert (config.filters.point_grid_cell_width, config.filters.point_grid_cell_height) == (64, 48)
    assert config.filters.point_grid_alpha == 1.5
    assert config.filters.line_llg_factor == 2.0
    assert (config.ggs.scale, config.ggs.grid_rows, config.ggs.grid_cols, config.ggs.bins) == (0.8, 3, 4, 256)
    assert config.keyframes.ggs_gain == 0.4
    assert config.mapping.covisibility_min_shared == 20
    assert (config.loop.lc_rat_alpha, config.loop.lc_rat_threshold, config.loop.pose_graph_min_shared_ratio) == (
        0.001, 0.2, 0.2)
    assert config.loop.detector == "ggs"


def test_default_yaml_lists_every_parameter_at_its_default():
    assert load_config([CONFIGS / "default.yaml"]) == Config()
    text = (CONFIGS / "default.yaml").read_text()
    for section in dataclasses.fields(Config):
        for spec in dataclasses.fields(getattr(Config(), section.name)):
            assert f"  {spec.name}:" in text, f"{section.name}.{spec.name} missing from default.yaml"


@pytest.mark.parametrize("name", ["kitti.yaml", "euroc.yaml", "argoverse.yaml", "synthetic.yaml"])
def test_dataset_family_files_load(name):
    config = load_config([CONFIGS / "default.yaml", CONFIGS / name])
    assert config != Config()


def test_files_then_overrides_apply_in_order(tmp_path):
    first = tmp_path / "a.yaml"
    first.write_text("dynamic:\n  grid: false\npoints:\n  n_features: 800\n")
    second = tmp_path / "b.yaml"
    second.write_text("points:\n  n_features: 900\n")
    config = load_config([first, second], ["points.n_features=1000", "loop.detector=bow"])
    assert config.dynamic.grid is False
    assert config.points.n_features == 1000
    assert config.loop.detector == "bow"


def test_int_is_accepted_for_a_float_and_stored_as_float():
    config = load_config(overrides=["filters.point_grid_alpha=2"])
    assert config.filters.point_grid_alpha == 2.0
    assert isinstance(config.filters.point_grid_alpha, float)


def test_dump_reads_back_to_the_same_config(tmp_path):
    config = load_config(overrides=["lines.horizontal_error=false", "ggs.scale=0.5"])
    path = tmp_path / "dumped.yaml"
    path.write_text(dump_config(config))
    assert load_config([path]) == config


@pytest.mark.parametrize(
    "override, message",
    [
        ("points.n_features=abc", "points.n_features must be an integer"),
        ("points.n_features=true", "points.n_features must be an integer"),
        ("points.n_features=0", "points.n_features = 0 is outside"),
        ("lines.enabled=1", "lines.enabled must be true or false"),
        ("loop.detector=netvlad", "loop.detector must be one of ggs, bow"),
        ("ggs.scale=1.5", "ggs.scale = 1.5 is outside"),
        ("filters.point_grid_alpha=.nan", "filters.point_grid_alpha must be a finite number, got float nan"),
        ("filters.point_grid_alpha=.inf", "filters.point_grid_alpha must be a finite number, got float inf"),
        ("filters.point_grid_alpha=-.inf", "filters.point_grid_alpha must be a finite number, got float -inf"),
        ("points.n_features=1000000000000", r"points.n_features = 1000000000000 is outside \[1, 100000\]"),
        ("points.nope=3", "unknown key points.nope"),
        ("nosection.key=3", "unknown section nosection"),
        ("points.n_features", "expected section.key=value"),
        ("n_features=3", "expected section.key=value"),
    ],
)
def test_bad_overrides_name_the_key(override, message):
    with pytest.raises(ConfigError, match=message) as raised:
        load_config(overrides=[override])
    assert f"--set {override}" in str(raised.value)


def config_fields(kind: type) -> list[str]:
    """``section.key`` of every config field of type ``kind``."""
    return [f"{section.name}.{key.name}" for section in dataclasses.fields(Config)
            for key in dataclasses.fields(section.default_factory()) if key.type in (kind, kind.__name__)]


@pytest.mark.parametrize("value", [".nan", ".inf", "-.inf"])
def test_no_number_field_takes_a_value_that_is_not_finite(value):
    for key in config_fields(float):
        with pytest.raises(ConfigError, match=f"{key} must be a finite number"):
            load_config(overrides=[f"{key}={value}"])


def test_no_integer_field_takes_a_value_beyond_a_32_bit_integer():
    for key in config_fields(int):
        with pytest.raises(ConfigError, match=rf"{key} = 2147483648 is outside \[.*, \d+\]"):
            load_config(overrides=[f"{key}=2147483648"])


def test_bad_file_errors_name_the_file(tmp_path):
    unknown = tmp_path / "unknown.yaml"
    unknown.write_text("filters:\n  point_grid_alpfa: 1.5\n")
    with pytest.raises(ConfigError, match=r"unknown\.yaml: unknown key filters\.point_grid_alpfa"):
        load_config([unknown])
    broken = tmp_path / "broken.yaml"
    broken.write_text("filters:\n  point_grid: [unclosed\n")
    with pytest.raises(ConfigError, match=r"broken\.yaml:\d+: not valid YAML"):
        load_config([broken])
    not_sections = tmp_path / "list.yaml"
    not_sections.write_text("- a\n- b\n")
    with pytest.raises(ConfigError, match="list.yaml: expected a mapping of sections"):
        load_config([not_sections])
    flat = tmp_path / "flat.yaml"
    flat.write_text("points: 3\n")
    with pytest.raises(ConfigError, match="flat.yaml: section points must be a mapping"):
        load_config([flat])
    with pytest.raises(ConfigError, match="missing.yaml: cannot read config"):
        load_config([tmp_path / "missing.yaml"])


def test_empty_file_changes_nothing(tmp_path):
    empty = tmp_path / "empty.yaml"
    empty.write_text("# nothing here\n")
    assert load_config([empty]) == Config()


def test_a_number_written_without_a_dot_is_a_number(tmp_path):
    """PyYAML (YAML 1.1) reads ``1e-6`` as text; a float key takes it as the number it spells."""
    assert load_config(overrides=["tracking.pose_cost_tolerance=1e-6"]).tracking.pose_cost_tolerance == 1e-6
    path = tmp_path / "tolerance.yaml"
    path.write_text("mapping:\n  ba_cost_tolerance: 2e-4\n")
    assert load_config([path]).mapping.ba_cost_tolerance == 2e-4
    with pytest.raises(ConfigError, match="must be a number, got str 'fast'"):
        load_config(overrides=["tracking.pose_cost_tolerance=fast"])


@pytest.mark.parametrize("lower, upper", ORDERED_KEYS)
def test_keys_out_of_order_are_an_error_naming_both(lower, upper):
    """Each pair of `ORDERED_KEYS` holds at the defaults, and the first set above the second is refused."""
    config = load_config()
    section, key = upper.split(".")
    high = getattr(getattr(config, section), key)
    above = high + 1 if isinstance(high, int) else high * 2.0
    with pytest.raises(ConfigError, match=f"{lower} = .* exceeds {upper} = "):
        load_config(overrides=[f"{lower}={above}", f"{upper}={high}"])
