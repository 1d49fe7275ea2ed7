"""The paper's figure 5: heat maps of the learned CRF matrices omega and mu.

``togcrf figures CHECKPOINT --out DIR`` writes ``omega.png`` and ``mu.png``
(each T x T for the model's T tasks, 12 for Table I, task labels in the
model's order on both axes, darker = higher as in the paper), ``figure5.png``
with both side by side, and ``crf.json`` with the values. The stored parameters are drawn (``model.crf.omega`` and
``model.crf.mu``), not the scaled matrices of equation 4: the scale is one
positive constant per matrix (see ``togcrf.crf``), so the picture is the same
up to the colour bar. A variant without one of the terms (TOG-CRFs omega or
mu) gets only the other map; a model without a CRF is an error.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from pathlib import Path
from typing import Annotated

import numpy as np
import torch
import typer
from matplotlib.figure import Figure

from togcrf.checkpoint import load_checkpoint
from togcrf.evaluate import write_json

log = logging.getLogger(__name__)


def crf_matrices(model: torch.nn.Module) -> dict[str, np.ndarray]:
    """The learned ``omega`` and ``mu`` of a model's CRF, those it has.

    Returns
    -------
    dict of str to (T, T) float64 array
        T: the model's task labels.

    Raises
    ------
    ValueError
        If the model has no CRF or the CRF has neither matrix.
    """
    crf = getattr(model, "crf", None)
    if crf is None:
        raise ValueError(f"{type(model).__name__} has no CRF (figure 5 needs a TOG-CRFs model)")
    matrices = {}
    for name in ("omega", "mu"):
        value = getattr(crf, name, None)
        if value is not None:
            matrices[name] = value.detach().to("cpu", torch.float64).numpy()
    if not matrices:
        raise ValueError("the model's CRF has neither omega nor mu")
    return matrices


def _draw_heat_map(axes: object, matrix: np.ndarray, title: str, tasks: Sequence[str]) -> object:
    image = axes.imshow(matrix, cmap="Blues")
    axes.set_xticks(range(len(tasks)), tasks, rotation=60, ha="right", fontsize=8)
    axes.set_yticks(range(len(tasks)), tasks, fontsize=8)
    axes.set_xlabel("task label $x_j$")
    axes.set_ylabel("task label $x_i$")
    axes.set_title(title)
    return image


def draw_crf_figures(matrices: dict[str, np.ndarray], out_dir: Path, tasks: Sequence[str]) -> list[Path]:
    """Write one heat map per matrix and a side-by-side figure 5, axes labelled with ``tasks`` (the model's
    vocabulary, in logit order); returns the paths."""
    out_dir.mkdir(parents=True, exist_ok=True)
    titles = {"omega": r"$\omega(x_i, x_j)$: task compatibility", "mu": r"$\mu(x_i, x_j)$: task region continuity"}
    written = []
    for name, matrix in matrices.items():
        figure = Figure(figsize=(6, 5.4), dpi=110)
        axes = figure.subplots()
        image = _draw_heat_map(axes, matrix, titles[name], tasks)
        figure.colorbar(image, ax=axes, fraction=0.046)
        figure.tight_layout()
        path = out_dir / f"{name}.png"
        figure.savefig(path)
        written.append(path)
    figure = Figure(figsize=(6 * len(matrices), 5.4), dpi=110)
    all_axes = figure.subplots(1, len(matrices), squeeze=False)
    for axes, (name, matrix) in zip(all_axes[0], matrices.items(), strict=True):
        image = _draw_heat_map(axes, matrix, titles[name], tasks)
        figure.colorbar(image, ax=axes, fraction=0.046)
    figure.tight_layout()
    path = out_dir / "figure5.png"
    figure.savefig(path)
    written.append(path)
    return written


def figures_command(
    checkpoint: Annotated[Path, typer.Argument(help="A TOG-CRFs checkpoint.pt.")],
    out: Annotated[Path, typer.Option("--out", help="Folder for omega.png, mu.png, figure5.png, crf.json.")],
) -> None:
    """Draw the learned CRF matrices omega and mu as heat maps (the paper's figure 5)."""

    if not Path(checkpoint).is_file():
        raise FileNotFoundError(f"{checkpoint}: no such checkpoint")
    model, config = load_checkpoint(checkpoint, device="cpu")
    matrices = crf_matrices(model)
    tasks = config["vocabulary"]["tasks"]
    written = draw_crf_figures(matrices, out, tasks)
    write_json(out / "crf.json", {"model": config.get("model"), "checkpoint": str(checkpoint), "tasks": list(tasks),
                                  **{name: matrix.tolist() for name, matrix in matrices.items()}})
    typer.echo("written: " + ", ".join(str(path) for path in [*written, out / "crf.json"]))


def register(app: typer.Typer) -> None:
    """Add ``figures`` to the ``togcrf`` command line."""
    app.command("figures")(figures_command)
