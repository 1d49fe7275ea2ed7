"""Learning curves: the losses and held-out metrics of training runs, per epoch, as a PNG.

``togcrf curves RUN_DIR... --out curves.png`` reads each run's
``metrics.csv`` (``togcrf.train``) and draws two panels: the total training
loss and the grasp task loss (left, log scale), and the validation mAP,
mAP-G and Acc-T top-1 (right, percent; only runs trained with
``--val-samples``). Each run is one colour, labelled with the last two parts of its run dir.
"""

from __future__ import annotations

import csv
import logging
import math
from pathlib import Path
from typing import Annotated

import typer

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


def draw_curves(run_dirs: list[Path], out: Path) -> Path:
    """Draw the learning curves of runs into a PNG; returns its path."""
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    figure, (losses, validation) = plt.subplots(1, 2, figsize=(11, 4.2))
    for index, run_dir in enumerate(run_dirs):
        curves = read_curves(run_dir)
        colour = f"C{index}"
        name = "/".join(Path(run_dir).parts[-2:])  # run dirs are often OUT/<model>: keep OUT
        epochs = [epoch + 1 for epoch in curves.get("epoch", [])]
        for column, style in LOSS_LINES.items():
            if column in curves:
                losses.plot(epochs, curves[column], style, color=colour, label=f"{name}: {column}")
        for column, style in VALIDATION_LINES.items():
            values = curves.get(column, [])
            if values and not all(math.isnan(value) for value in values):
                validation.plot(epochs, [100 * value for value in values], style, marker="o", markersize=3,
                                color=colour, label=f"{name}: {column[4:]}")
    losses.set(xlabel="epoch", ylabel="training loss (mean over the epoch)", yscale="log", title="losses")
    validation.set(xlabel="epoch", ylabel="percent", ylim=(0, 100), title="held-out validation slice")
    for axes in (losses, validation):
        axes.grid(alpha=0.3)
        if axes.get_legend_handles_labels()[0]:
            axes.legend(fontsize=7)
    figure.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(out, dpi=120)
    plt.close(figure)
    return out


def register(app: typer.Typer) -> None:
    """Add the ``curves`` command to the togcrf CLI."""

    def curves_command(
        runs: Annotated[list[Path], typer.Argument(help="Run dirs holding metrics.csv.")],
        out: Annotated[Path, typer.Option("--out", help="PNG to write.")] = Path("curves.png"),
    ) -> None:
        """Draw the losses and validation metrics per epoch of training runs as a PNG."""
        try:
            path = draw_curves(runs, out)
        except FileNotFoundError as error:
            typer.echo(f"error: {error}", err=True)
            raise typer.Exit(1) from error
        typer.echo(f"wrote {path}")

    app.command("curves")(curves_command)
