"""``pld-slam config``: print the configuration a run would use."""

from pathlib import Path

import click

from pld_slam.config import dump_config, load_config

config_files_option = click.option(
    "--config",
    "config_paths",
    multiple=True,
    type=click.Path(path_type=Path),
    help="YAML file laid over the defaults (repeatable, applied in order).",
)
set_option = click.option(
    "--set",
    "overrides",
    multiple=True,
    metavar="SECTION.KEY=VALUE",
    help="Override one parameter (repeatable), e.g. --set dynamic.grid=false.",
)


@click.command("config")
@config_files_option
@set_option
def config_command(config_paths: tuple[Path, ...], overrides: tuple[str, ...]) -> None:
    """Print the effective configuration as YAML (defaults, then files, then --set)."""
    click.echo(dump_config(load_config(config_paths, overrides)), nl=False)
