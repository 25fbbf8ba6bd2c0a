"""The ``pld-slam`` command group and its error policy.

A `PldSlamError` (bad folder, malformed file, invalid config) reaches the user as one line
``error: ...`` on stderr and exit code 2. Any other exception is a bug: one line asking
for ``--verbose`` and exit code 1. Ctrl-C prints ``interrupted`` (with what a run wrote
and where, `pld_slam.report.run_files.RunInterrupted`) and exits with 130. ``--verbose`` prints
the traceback before that line and changes nothing else, the exit code included.

SIGTERM (``kill``, a batch scheduler's time limit, a container stopping) stops a command
the way Ctrl-C does, so that a run still writes what it has: the handler
(`pld_slam.errors.stop_on_sigterm`) raises `pld_slam.errors.Terminated` (a
`KeyboardInterrupt`); the line and ``summary.json``'s ``stop_reason`` say ``terminated``,
and the exit code is 143 (128 + 15, what a shell reports for a process ended by SIGTERM).
Without it SIGTERM ends the process at once and a run leaves only its partial trajectory
file. It also reaches a process whose SIGINT is ignored (started in the background by a
shell or ``nohup``), so it is how `pld_slam.report.cells` stops a cell at its time limit
(the cell's run, `pld_slam.report.cell_run`, has the same handler).

Once the command has returned or raised (a run's files are written by then), Ctrl-C and
SIGTERM get their default action back (`_command_over`): the process ends at once, killed
by the signal, as it would late in the interpreter's shutdown anyway. Raised from a Python handler there,
they printed a traceback from whatever atexit callback or thread join was running
(``Exception ignored in atexit callback``) and exited 0, or ``Aborted!`` and 1 from click
(issue 43). This holds for the console script (`main`), not for a command invoked in process.

The commands are imported when one is invoked, not with this module: their imports
(OpenCV, numba, evo, matplotlib) take seconds, and a Ctrl-C during them would otherwise
escape as a Python traceback before the error policy above is in place.
"""

import importlib
import signal
import sys
import traceback

import click

from pld_slam import __version__
from pld_slam.errors import PldSlamError, Terminated, end_on_stop_signals, stop_on_sigterm

EXIT_USER_ERROR = 2
EXIT_BUG = 1
EXIT_INTERRUPTED = 130
EXIT_TERMINATED = 128 + signal.SIGTERM

_COMMANDS = {
    "run": "pld_slam_cli.run:run_command",
    "demo": "pld_slam_cli.demo:demo_command",
    "synth": "pld_slam_cli.synth:synth_command",
    "eval": "pld_slam_cli.evaluate:eval_command",
    "config": "pld_slam_cli.config:config_command",
    "places": "pld_slam_cli.places:places_command",
    "vocabulary": "pld_slam_cli.vocabulary:vocabulary_command",
    "ablate": "pld_slam_cli.ablate:ablate_command",
    "regress": "pld_slam_cli.regress:regress_command",
}
"""Each command's name and where it is defined (``module:attribute``), imported on use."""


class _ReportingGroup(click.Group):
    """A click group of lazily imported commands that reports errors as one line (see module docstring)."""

    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted(_COMMANDS)

    def get_command(self, ctx: click.Context, name: str) -> click.Command | None:
        if name not in _COMMANDS:
            return None
        module, attribute = _COMMANDS[name].split(":")
        return getattr(importlib.import_module(module), attribute)

    def invoke(self, ctx: click.Context):
        try:
            try:
                return super().invoke(ctx)
            finally:
                _command_over(ctx.obj)  # before any line is reported: a signal now ends the process
        except PldSlamError as error:
            _report(ctx, f"error: {error}", EXIT_USER_ERROR)
        except KeyboardInterrupt as interrupt:
            terminated = isinstance(interrupt, Terminated) or isinstance(interrupt.__cause__, Terminated)
            stopped, code = ("terminated", EXIT_TERMINATED) if terminated else ("interrupted", EXIT_INTERRUPTED)
            _report(ctx, " ".join(filter(None, (stopped, str(interrupt)))), code)
        except (click.exceptions.Exit, click.ClickException, click.Abort):
            raise
        except Exception as error:  # a bug: keep the one-line promise, point at --verbose
            _report(ctx, f"internal error: {type(error).__name__}: {error} (run with --verbose for the traceback)",
                    EXIT_BUG)


_SIGNALS_DEFAULT_WHEN_OVER = "signals_default_when_over"
"""The key of ``ctx.obj`` with which `main` asks for `_command_over`'s signal dispositions."""


def _command_over(obj) -> None:
    """The command has ended: Ctrl-C and SIGTERM get their default action back (module docstring),
    when the console script asked for it in the context's ``obj`` (`main`); a command invoked in
    process keeps its caller's."""
    if isinstance(obj, dict) and obj.get(_SIGNALS_DEFAULT_WHEN_OVER):
        end_on_stop_signals()


def _report(ctx: click.Context, line: str, exit_code: int) -> None:
    """Print ``line`` on stderr (after the traceback of the exception being handled with ``--verbose``) and exit."""
    if ctx.obj and ctx.obj.get("verbose"):
        traceback.print_exc(file=sys.stderr)
    click.echo(line, err=True)
    ctx.exit(exit_code)


@click.group(cls=_ReportingGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.option("--verbose", is_flag=True, help="Show the full traceback of errors.")
@click.version_option(__version__, prog_name="pld-slam")
@click.pass_context
def cli(ctx: click.Context, verbose: bool) -> None:
    """PLD-SLAM: stereo point-line SLAM for dynamic scenes."""
    ctx.ensure_object(dict)["verbose"] = verbose


def main() -> None:
    """Console-script entry point: SIGTERM stops a command as Ctrl-C does; once it has ended, both end the
    process at once (module docstring)."""
    signal.signal(signal.SIGTERM, stop_on_sigterm)
    obj = {_SIGNALS_DEFAULT_WHEN_OVER: True}
    try:
        sys.exit(cli(prog_name="pld-slam", obj=obj))
    finally:  # --help, --version and usage errors end before a command is invoked
        _command_over(obj)
