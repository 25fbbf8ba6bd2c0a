"""The layer order of ARCHITECTURE.md, enforced: the import-linter contracts of pyproject.toml
(``[tool.importlinter]``) hold, and the library never starts the CLI package.

A module importing from a layer above its own breaks the first test, which prints
``lint-imports``' report naming the import and its line.
"""

from pathlib import Path

from importlinter.cli import lint_imports

ROOT = Path(__file__).resolve().parents[1]


def test_every_import_linter_contract_is_kept():
    assert lint_imports(config_filename=str(ROOT / "pyproject.toml"), no_cache=True, no_logo=True) == 0


def test_no_library_module_names_the_cli_package():
    """The CLI depends on the library, never the other way: not by an import (the contracts) nor by
    starting ``python -m pld_slam_cli`` in a child process."""
    naming = [path.relative_to(ROOT) for path in sorted((ROOT / "pld_slam").rglob("*.py"))
              if "pld_slam_cli" in path.read_text()]
    assert naming == []
