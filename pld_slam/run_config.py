"""The configuration of a run: defaults, the dataset family's file, the user's files, ``--set``.

`load_run_config` builds the `Config` of a run on a sequence and records where it came
from, each layer laid over the one before:

1. the defaults (the dataclasses of `pld_slam.config`, equal to ``configs/default.yaml``);
2. the file of the sequence's dataset family (`dataset_family`), chosen from the detected
   layout: ``kitti.yaml`` for KITTI odometry and KITTI raw, ``euroc.yaml`` for EuRoC,
   ``argoverse.yaml`` for Argoverse, ``synthetic.yaml`` for a sequence written by
   ``pld-slam synth`` (KITTI odometry layout with a ``synth.json`` in its root), none for
   the generic layout and ROS bags (a bag says nothing of the camera it holds). The
   family files hold only what differs from the defaults; they ship with the package as
   `pld_slam.configs`;
3. the user's ``--config`` files, in order;
4. the ``--set section.key=value`` overrides, in order.

What the paper leaves open here: nothing. Choosing and layering files is this
implementation's plumbing; the values themselves are documented in `pld_slam.config`.
"""

from collections.abc import Sequence
from dataclasses import dataclass
from importlib.resources import as_file, files
from importlib.resources.abc import Traversable
from pathlib import Path

from pld_slam.config import Config, load_config
from pld_slam.datasets import StereoSequence
from pld_slam.errors import ConfigError
from pld_slam.synth.writer import METADATA as SYNTH_METADATA

FAMILY_FILES = {
    "kitti": "kitti.yaml",
    "euroc": "euroc.yaml",
    "argoverse": "argoverse.yaml",
    "synthetic": "synthetic.yaml",
    "generic": None,
}
"""Each dataset family and its packaged config file (None: the defaults as they are)."""

_LAYOUT_FAMILIES = {
    "kitti_odometry": "kitti",
    "kitti_raw": "kitti",
    "euroc": "euroc",
    "argoverse": "argoverse",
    "generic": "generic",
    "rosbag": "generic",
}


@dataclass(frozen=True)
class RunConfig:
    """The effective configuration of a run and the sources laid over each other to make it.

    Attributes
    ----------
    config : Config
        The effective configuration.
    sources : tuple of str
        The sources applied, in order: ``"defaults"``, ``"family: NAME.yaml"``, each
        ``--config`` path, each ``"--set section.key=value"``.
    """

    config: Config
    sources: tuple[str, ...]


def dataset_family(sequence: StereoSequence) -> str:
    """The dataset family of ``sequence``: ``kitti``, ``euroc``, ``argoverse``, ``synthetic`` or ``generic``.

    Parameters
    ----------
    sequence : StereoSequence
        An opened sequence; its ``layout`` decides, except that a KITTI odometry folder
        holding a ``synth.json`` (written by ``pld-slam synth``) is ``synthetic``.

    Returns
    -------
    str
        One of the keys of `FAMILY_FILES`.
    """
    if sequence.layout == "kitti_odometry" and (Path(sequence.root) / SYNTH_METADATA).is_file():
        return "synthetic"
    return _LAYOUT_FAMILIES.get(sequence.layout, "generic")


def family_config_name(family: str) -> str | None:
    """The packaged config file of dataset family ``family``, None for ``generic``.

    Raises
    ------
    ConfigError
        For an unknown family.
    """
    if family not in FAMILY_FILES:
        raise ConfigError(f"unknown dataset family {family!r} (known: {', '.join(FAMILY_FILES)})")
    return FAMILY_FILES[family]


def packaged_config(name: str) -> Traversable:
    """The config file ``name`` (e.g. ``kitti.yaml``) shipped in the package `pld_slam.configs`.

    Raises
    ------
    ConfigError
        When the package holds no such file.
    """
    path = files("pld_slam.configs") / name
    if not path.is_file():
        known = sorted(entry.name for entry in files("pld_slam.configs").iterdir() if entry.name.endswith(".yaml"))
        raise ConfigError(f"{name}: no such packaged config (known: {', '.join(known)})")
    return path


def load_run_config(
    sequence: StereoSequence, config_paths: Sequence[Path] = (), overrides: Sequence[str] = ()
) -> RunConfig:
    """The configuration of a run on ``sequence`` (layers in the module docstring).

    Parameters
    ----------
    sequence : StereoSequence
        The opened sequence; its `dataset_family` picks the family file.
    config_paths : sequence of Path
        The user's YAML files, laid over the family file in order.
    overrides : sequence of str
        ``section.key=value`` overrides, applied last, in order.

    Returns
    -------
    RunConfig
        The effective configuration and its sources.

    Raises
    ------
    ConfigError
        For an unreadable or invalid file or override, naming it and the key.
    """
    family = family_config_name(dataset_family(sequence))
    if family is None:
        config = load_config(config_paths, overrides)
        sources = ["defaults"]
    else:
        with as_file(packaged_config(family)) as family_path:  # a real file even from a zipped install
            config = load_config([family_path, *config_paths], overrides)
        sources = ["defaults", f"family: {family}"]
    sources += [str(path) for path in config_paths] + [f"--set {text}" for text in overrides]
    return RunConfig(config=config, sources=tuple(sources))
