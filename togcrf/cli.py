"""The ``togcrf`` command line: train, evaluate, predict, figures.

Each command lives in the module of its topic, which registers it here
through a ``register(app)`` function, so this file stays a table of contents.
"""

from __future__ import annotations

import logging
from typing import NoReturn

import typer

from osgd.contract.process_exit import run_then_exit
from togcrf import curves, evaluate, figures, predict, reproduce, train
from togcrf.robot import cli as robot_cli

app = typer.Typer(
    help="Train and evaluate the TOG / TOG-CRFs task-oriented grasp detectors on osgd samples.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)

#: Modules that add commands, in the order they appear in --help.
COMMAND_MODULES = (train, curves, evaluate, predict, figures, reproduce, robot_cli)


@app.callback()
def main(
    log_level: str = typer.Option("warning", help="debug, info, warning or error."),
) -> None:
    logging.basicConfig(level=getattr(logging, log_level.upper(), logging.WARNING),
                        format="%(levelname)s %(name)s: %(message)s")


for _module in COMMAND_MODULES:
    _module.register(app)


def run() -> NoReturn:
    """Console-script entry point; the process ends without the native libraries' teardown
    (:func:`osgd.contract.process_exit.run_then_exit`)."""
    run_then_exit(app)
