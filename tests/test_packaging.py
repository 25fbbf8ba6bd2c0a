"""pyproject.toml installs every package of the library and the CLI under its own name."""

import tomllib
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[1]


def _pyproject() -> dict:
    return tomllib.loads((REPO_ROOT / "pyproject.toml").read_text())


def test_every_library_package_is_installed():
    listed = set(_pyproject()["tool"]["setuptools"]["packages"])
    on_disk = {
        ".".join(init.parent.relative_to(REPO_ROOT).parts)
        for init in (REPO_ROOT / "pld_slam").rglob("__init__.py")
    }
    assert on_disk <= listed, f"packages missing from pyproject.toml: {sorted(on_disk - listed)}"


def test_cli_installs_as_pld_slam_cli_not_cli():
    tool = _pyproject()["tool"]["setuptools"]
    assert tool["package-dir"]["pld_slam_cli"] == "cli"
    assert "cli" not in tool["packages"]
    assert _pyproject()["project"]["scripts"]["pld-slam"].startswith("pld_slam_cli.")


def test_config_files_install_as_package_data():
    tool = _pyproject()["tool"]["setuptools"]
    assert tool["package-dir"]["pld_slam.configs"] == "configs"
    assert "pld_slam.configs" in tool["packages"]
    assert tool["package-data"]["pld_slam.configs"] == ["*.yaml", "ablations/*.yaml"]
