"""The ``pld-slam`` command group and its error policy.

A `PldSlamError` (bad folder, malformed file, invalid config) reaches the user as one line
``error: ...`` on stderr and exit code 2. Any other exception is a bug: one line asking
for ``--verbose`` and exit code 1. ``--verbose`` re-raises so the traceback shows.
"""

import sys

import click

from pld_slam import __version__
from pld_slam.errors import PldSlamError
from pld_slam_cli.ablate import ablate_command
from pld_slam_cli.config import config_command
from pld_slam_cli.demo import demo_command
from pld_slam_cli.evaluate import eval_command
from pld_slam_cli.places import places_command
from pld_slam_cli.regress import regress_command
from pld_slam_cli.run import run_command
from pld_slam_cli.synth import synth_command
from pld_slam_cli.vocabulary import vocabulary_command

EXIT_USER_ERROR = 2
EXIT_BUG = 1
EXIT_INTERRUPTED = 130


class _ReportingGroup(click.Group):
    """A click group that reports library errors as one line (see module docstring)."""

    def invoke(self, ctx: click.Context):
        try:
            return super().invoke(ctx)
        except PldSlamError as error:
            if ctx.obj and ctx.obj.get("verbose"):
                raise
            click.echo(f"error: {error}", err=True)
            ctx.exit(EXIT_USER_ERROR)
        except KeyboardInterrupt:
            click.echo("interrupted", err=True)
            ctx.exit(EXIT_INTERRUPTED)
        except (click.exceptions.Exit, click.ClickException, click.Abort):
            raise
        except Exception as error:  # a bug: keep the one-line promise, point at --verbose
            if ctx.obj and ctx.obj.get("verbose"):
                raise
            click.echo(
                f"internal error: {type(error).__name__}: {error} (run with --verbose for the traceback)",
                err=True,
            )
            ctx.exit(EXIT_BUG)


@click.group(cls=_ReportingGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.option("--verbose", is_flag=True, help="Show the full traceback of errors.")
@click.version_option(__version__, prog_name="pld-slam")
@click.pass_context
def cli(ctx: click.Context, verbose: bool) -> None:
    """PLD-SLAM: stereo point-line SLAM for dynamic scenes."""
    ctx.ensure_object(dict)["verbose"] = verbose


cli.add_command(run_command)
cli.add_command(demo_command)
cli.add_command(synth_command)
cli.add_command(eval_command)
cli.add_command(config_command)
cli.add_command(places_command)
cli.add_command(vocabulary_command)
cli.add_command(ablate_command)
cli.add_command(regress_command)


def main() -> None:
    """Console-script entry point."""
    sys.exit(cli(prog_name="pld-slam"))
