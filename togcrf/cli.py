"""The ``togcrf`` command line: train, evaluate, predict, figures, the table, the robot experiment.

Each command lives in the module of its topic, which registers it here through a ``register(app)``
function, so this file stays a table of contents. A user error (a bad option, a missing or foreign
file, a non-finite loss) ends the command with one line ``error: ...`` and exit status 1; ``--debug``
shows the traceback instead. An interrupt exits 130; a run dir keeps its last epoch's checkpoint
(``--resume`` continues it).
"""

from __future__ import annotations

import functools
import logging
import sys
from collections.abc import Callable
from typing import NoReturn

import typer

from osgd.contract.process_exit import run_then_exit
from osgd.contract.shards import ShardError
from togcrf import compare, curves, evaluate, figures, predict, reproduce, train
from togcrf.robot import cli as robot_cli

app = typer.Typer(
    help="Train and evaluate the TOG / TOG-CRFs task-oriented grasp detectors on osgd samples.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)

#: Modules that add commands, in the order they appear in --help.
COMMAND_MODULES = (train, curves, evaluate, compare, predict, figures, reproduce, robot_cli)

#: Errors that a user's input causes: one line without ``--debug``.
USER_ERRORS = (ValueError, FileNotFoundError, FileExistsError, IsADirectoryError, NotADirectoryError,
               PermissionError, FloatingPointError, KeyError, ShardError)


class _Settings:
    """The global options of the invocation."""

    debug = False


@app.callback()
def main(
    log_level: str = typer.Option("warning", help="debug, info, warning or error."),
    debug: bool = typer.Option(False, "--debug", help="Show the traceback of an error instead of one line."),
) -> None:
    _Settings.debug = debug
    logging.basicConfig(level=getattr(logging, log_level.upper(), logging.WARNING),
                        format="%(levelname)s %(name)s: %(message)s")


def one_line(error: BaseException) -> str:
    """An error's message as one line (the first line of a multi-line message; KeyError's quotes dropped)."""
    text = str(error.args[0]) if isinstance(error, KeyError) and error.args else str(error)
    lines = [line.strip() for line in text.strip().splitlines() if line.strip()]
    return lines[0] if lines else type(error).__name__


def one_line_errors(command: Callable) -> Callable:
    """``command`` with its user errors (``USER_ERRORS``) as one line and exit 1, unless ``--debug``."""
    @functools.wraps(command)
    def wrapped(*args, **kwargs):
        try:
            return command(*args, **kwargs)
        except USER_ERRORS as error:
            if _Settings.debug:
                raise
            typer.echo(f"error: {one_line(error)} (--debug shows the traceback)", err=True)
            raise typer.Exit(1) from error

    return wrapped


def _register_commands() -> None:
    for module in COMMAND_MODULES:
        module.register(app)
    for group in [app, *(info.typer_instance for info in app.registered_groups)]:
        for info in group.registered_commands:
            info.callback = one_line_errors(info.callback)


_register_commands()


def run_app() -> None:
    """The CLI; an interrupt exits 130."""
    try:
        app()
    except KeyboardInterrupt:
        typer.echo("interrupted", err=True)
        sys.exit(130)


def run() -> NoReturn:
    """Console-script entry point; the process ends without the native libraries' teardown
    (:func:`osgd.contract.process_exit.run_then_exit`)."""
    run_then_exit(run_app)
