"""``pld-slam config``: print the configuration a run would use."""

from pathlib import Path

import click

from pld_slam.config import dump_config, load_config
from pld_slam.datasets import open_sequence
from pld_slam.run_config import load_run_config

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
@click.option("--sequence", "sequence_dir", type=click.Path(exists=True, path_type=Path), default=None,
              help="Print the config of a run on this sequence folder or bag (its dataset family included).")
def config_command(config_paths: tuple[Path, ...], overrides: tuple[str, ...], sequence_dir: Path | None) -> None:
    """Print the effective configuration as YAML (defaults, then files, then --set).

    With --sequence, the dataset family's file of that folder comes right after the
    defaults, as in `pld-slam run`, and a first comment line lists the sources.
    """
    if sequence_dir is None:
        click.echo(dump_config(load_config(config_paths, overrides)), nl=False)
        return
    run_config = load_run_config(open_sequence(sequence_dir), config_paths, overrides)
    click.echo(f"# sources: {', '.join(run_config.sources)}\n{dump_config(run_config.config)}", nl=False)
