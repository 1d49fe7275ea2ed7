"""Learning curves: the losses and held-out metrics of training runs, per epoch, as a PNG.

``togcrf curves RUN_DIR... --out curves.png`` reads each run's
``metrics.csv`` (``togcrf.train``) and draws two panels: the total training
loss and the grasp task loss (left, log scale), and the validation mAP,
mAP-G and Acc-T top-1 (right, percent; only runs trained with
``--val-samples``). Each run is one colour, named once under the panels by the last two parts of its run
dir; each metric is one line style.
"""

from __future__ import annotations

import csv
import logging
import math
from pathlib import Path
from typing import Annotated, Any

import typer
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

log = logging.getLogger(__name__)

#: Loss columns drawn (left panel) and their line styles.
LOSS_LINES = {"loss": "-", "grasp_task": ":"}

#: Validation columns drawn (right panel) and their line styles.
VALIDATION_LINES = {"val_mAP": "-", "val_mAP-G": "--", "val_Acc-T top1": ":"}


def read_curves(run_dir: Path) -> dict[str, list[float]]:
    """The columns of a run's ``metrics.csv`` as lists of floats (empty cells as NaN).

    Raises
    ------
    FileNotFoundError
        If the run dir has no ``metrics.csv``.
    """
    path = Path(run_dir) / "metrics.csv"
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no metrics.csv (is {run_dir} a togcrf run dir?)")
    with path.open(newline="") as handle:
        rows = list(csv.DictReader(handle))
    columns: dict[str, list[float]] = {}
    for row in rows:
        for key, value in row.items():
            columns.setdefault(key, []).append(float(value) if value not in ("", None) else math.nan)
    return columns


def _add_legends(figure: Any, panels: dict[Any, dict[str, str]], run_colours: list[tuple[str, str]]) -> None:
    """Each panel's line styles in its own legend, and the runs' (name, colour) once under the panels."""
    run_handles = [Line2D([], [], color=colour, label=name) for name, colour in run_colours]

    for axes, lines in panels.items():
        axes.grid(alpha=0.3)
        if axes.lines:
            axes.legend(handles=[Line2D([], [], linestyle=style, color="0.3", label=column.removeprefix("val_"))
                                 for column, style in lines.items()], fontsize=8)
    columns = min(4, max(1, len(run_handles)))
    rows = math.ceil(len(run_handles) / columns)
    figure.legend(handles=run_handles, loc="lower center", ncol=columns, fontsize=8, frameon=False)
    figure.tight_layout(rect=(0, min(0.4, 0.05 * rows + 0.02), 1, 1))


def draw_curves(run_dirs: list[Path], out: Path) -> Path:
    """Draw the learning curves of runs into a PNG; returns its path.

    Each run is one colour (named once, in a legend under the panels); each metric is one line style
    (named in its panel's legend), so that the legends stay short however many runs are drawn.
    """
    figure = Figure(figsize=(11, 4.2))
    losses, validation = figure.subplots(1, 2)
    run_colours: list[tuple[str, str]] = []
    for index, run_dir in enumerate(run_dirs):
        curves = read_curves(run_dir)
        colour = f"C{index % 10}"
        name = "/".join(Path(run_dir).parts[-2:])  # run dirs are often OUT/<model>: keep OUT
        run_colours.append((name, colour))
        epochs = [epoch + 1 for epoch in curves.get("epoch", [])]
        for column, style in LOSS_LINES.items():
            if column in curves:
                losses.plot(epochs, curves[column], style, color=colour)
        for column, style in VALIDATION_LINES.items():
            values = curves.get(column, [])
            if values and not all(math.isnan(value) for value in values):
                validation.plot(epochs, [100 * value for value in values], style, marker="o", markersize=3,
                                color=colour)
    losses.set(xlabel="epoch", ylabel="training loss (mean over the epoch)", yscale="log", title="losses")
    validation.set(xlabel="epoch", ylabel="percent", ylim=(0, 100), title="held-out validation slice")
    _add_legends(figure, {losses: LOSS_LINES, validation: VALIDATION_LINES}, run_colours)
    out.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(out, dpi=120)
    return out


def register(app: typer.Typer) -> None:
    """Add the ``curves`` command to the togcrf CLI."""

    def curves_command(
        runs: Annotated[list[Path], typer.Argument(help="Run dirs holding metrics.csv.")],
        out: Annotated[Path, typer.Option("--out", help="PNG to write.")] = Path("curves.png"),
    ) -> None:
        """Draw the losses and validation metrics per epoch of training runs as a PNG."""
        path = draw_curves(runs, out)
        typer.echo(f"wrote {path}")

    app.command("curves")(curves_command)
