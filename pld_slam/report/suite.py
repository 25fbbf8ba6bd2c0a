"""Ablation suites: named variants, each a config overlay, read from YAML.

A suite file::

    description: dynamic grid and dynamic LLG, each on or off
    variants:
      without: {dynamic.grid: false, dynamic.llg: false}
      grid: {dynamic.grid: true, dynamic.llg: false}

Each variant maps ``section.key`` (the keys of ``--set``) to a value. The built-in
suites (`BUILTIN_SUITES`) ship with the package under ``pld_slam.configs/ablations``;
any other name is read as a path. `load_suite` checks every variant against the
configuration before anything runs: an unknown key or a bad value is a `ConfigError`
naming the file and the variant.
"""

import json
from collections.abc import Mapping
from dataclasses import dataclass
from importlib.resources import files
from pathlib import Path

from pld_slam.config import Config, apply_mapping, parse_override, parse_yaml
from pld_slam.errors import ConfigError, read_user_text

BUILTIN_SUITES = ("table1", "lines", "keyframes", "loop")
"""The suites shipped as ``pld_slam.configs/ablations/NAME.yaml``."""


@dataclass(frozen=True)
class Variant:
    """One column of an ablation table.

    Attributes
    ----------
    name : str
        The variant's name, as the table's column header.
    overrides : tuple of str
        ``section.key=value`` overrides (the ``--set`` syntax; values as JSON, which
        YAML reads back unchanged), applied in order.
    """

    name: str
    overrides: tuple[str, ...]


@dataclass(frozen=True)
class Suite:
    """A named list of variants.

    Attributes
    ----------
    name : str
        The built-in name, or the file's stem.
    description : str
        One line saying what the suite compares.
    variants : tuple of Variant
        In the file's order (the order of the table's columns).
    """

    name: str
    description: str
    variants: tuple[Variant, ...]


def suite_source(name_or_path: str) -> tuple[str, str, str]:
    """The suite's name, its YAML text and where it comes from (a path, or "built-in suite NAME").

    Raises
    ------
    ConfigError
        When ``name_or_path`` is neither a built-in suite nor a readable file.
    """
    if name_or_path in BUILTIN_SUITES:
        text = (files("pld_slam.configs") / "ablations" / f"{name_or_path}.yaml").read_text()
        return name_or_path, text, f"built-in suite {name_or_path}"
    path = Path(name_or_path)
    if not path.is_file():
        raise ConfigError(
            f"{name_or_path}: no such suite (built-in: {', '.join(BUILTIN_SUITES)}; or a YAML file)"
        )
    return path.stem, read_user_text(path, ConfigError, "suite"), str(path)


def load_suite(name_or_path: str) -> Suite:
    """The suite ``name_or_path`` (a built-in name or a YAML file), every variant checked.

    Raises
    ------
    ConfigError
        For a missing file, bad YAML, no variants, or a variant naming an unknown key or
        an invalid value; the message names the file and the variant.
    """
    name, text, where = suite_source(name_or_path)
    data = parse_yaml(text, where)
    if not isinstance(data, Mapping) or not isinstance(data.get("variants"), Mapping) or not data["variants"]:
        raise ConfigError(f"{where}: a suite needs a 'variants' mapping of names to config overlays")
    unknown = set(data) - {"description", "variants"}
    if unknown:
        raise ConfigError(
            f"{where}: unknown top-level key(s) {', '.join(sorted(unknown))} (known: description, variants)"
        )
    variants = tuple(_variant(where, str(key), overlay) for key, overlay in data["variants"].items())
    return Suite(name=name, description=str(data.get("description", "")), variants=variants)


def _variant(where: str, name: str, overlay) -> Variant:
    """A `Variant` from one entry of a suite's ``variants``, checked against `Config`."""
    if overlay is None:
        overlay = {}
    if not isinstance(overlay, Mapping):
        raise ConfigError(f"{where}: variant {name}: expected a mapping of section.key to value")
    overrides = tuple(f"{key}={json.dumps(value)}" for key, value in overlay.items())
    check_overrides(overrides, f"{where}: variant {name}")
    return Variant(name=name, overrides=overrides)


def check_overrides(overrides: tuple[str, ...], where: str) -> None:
    """Raise `ConfigError` prefixed by ``where`` when an override names no key or a bad value."""
    config = Config()
    for text in overrides:
        try:
            config = apply_mapping(config, parse_override(text), f"--set {text}")
        except ConfigError as error:
            raise ConfigError(f"{where}: {error}") from None
