"""Checkpoints: what a training run saves, and how every command loads it.

``RUN_DIR/checkpoint.pt`` is a dict of tensors and plain values, loaded with
``torch.load(weights_only=True)`` (no pickled code runs):

- ``model``: the model's state dict, float32: what evaluation, prediction
  and the robot need. The optimiser, schedule and loss-scaler state that
  ``--resume`` also needs lie beside it in ``RUN_DIR/training-state.pt``
  (``togcrf.train``), so that a checkpoint to share or evaluate is no larger
  than its weights; older checkpoints that hold them inside still resume;
- ``config``: the resolved training options (``togcrf.config.TrainConfig``
  as a dict, the model options nested by group; flat model options of older
  checkpoints are migrated on loading, ``togcrf.model.options.stored_options``);
- ``epoch``: the last epoch trained (0-based); ``trained_seconds``,
  ``stopped_by_budget``: the time budget's state;
- ``data``: what the run trained on (data dir, pipeline, split, shard keys);
- ``vocabulary``: the categories and task labels the model's outputs are
  indexed by (those of the data it trained on: the heads and the CRF's
  matrices are sized by them), and ``schema_version``: the samples schema
  it read (:mod:`osgd.contract`). Checkpoints without them read as Table
  I's vocabulary.

A model refuses data labelled with another vocabulary
(:func:`check_vocabulary`).
"""

from __future__ import annotations

import logging
import os
import pickle
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import torch

from osgd.contract.schemas import SCHEMA_VERSION
from osgd.contract.taxonomy import VOCABULARY, vocabulary_difference
from togcrf.model import build_model, stored_options

logger = logging.getLogger(__name__)

#: The file name of a run dir's checkpoint.
CHECKPOINT_FILE = "checkpoint.pt"

#: Training config entries that older checkpoints lack, with the value those checkpoints were trained with.
CONFIG_ADDED_LATER = {"depth_reference": "table"}


def table1_vocabulary() -> dict[str, list[str]]:
    """Table I's vocabulary (:data:`osgd.contract.taxonomy.VOCABULARY`) as JSON lists: that of a checkpoint
    written before checkpoints recorded theirs."""
    return {field: list(names) for field, names in VOCABULARY.items()}


def one_line_of(error: BaseException) -> str:
    """What ``torch.load`` says of a file it could not read, in one line."""
    first = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
    if first.startswith("Weights only load failed"):
        return "it needs unpickling code or objects, which is never done; a togcrf file holds tensors"
    return first


def checkpoint_path(path: str | Path) -> Path:
    """``path`` itself, or ``path/checkpoint.pt`` when ``path`` is a run dir."""
    path = Path(path)
    return path / CHECKPOINT_FILE if path.is_dir() else path


def save_checkpoint(path: Path, state: Mapping[str, Any], vocabulary: Mapping[str, Sequence[str]]) -> None:
    """Write a checkpoint atomically (a crash leaves the previous one whole).

    Parameters
    ----------
    path : path
        The file to write.
    state : mapping
        ``model``, ``config``, ``epoch``, ``data``, ``trained_seconds``,
        ``stopped_by_budget``.
    vocabulary : mapping
        ``{"categories": [...], "tasks": [...]}`` of the data trained on.
    """
    document = {**state, "vocabulary": {field: list(names) for field, names in vocabulary.items()},
                "schema_version": SCHEMA_VERSION}
    temporary = path.with_suffix(path.suffix + ".tmp")
    torch.save(document, temporary)
    os.replace(temporary, path)


def read_checkpoint(path: str | Path, device: str | torch.device = "cpu") -> dict[str, Any]:
    """The checkpoint's dict, with ``vocabulary`` and ``CONFIG_ADDED_LATER`` filled in for old checkpoints.

    Raises
    ------
    FileNotFoundError
        No such file.
    ValueError
        Not a togcrf checkpoint (unreadable, or without ``model`` and ``config``).
    """
    path = checkpoint_path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no checkpoint")
    try:
        checkpoint = torch.load(path, map_location=device, weights_only=True)
    except (RuntimeError, ValueError, EOFError, OSError, pickle.UnpicklingError) as error:
        raise ValueError(f"{path}: not a readable togcrf checkpoint ({one_line_of(error)})") from error
    if not isinstance(checkpoint, dict) or "model" not in checkpoint or "config" not in checkpoint:
        raise ValueError(f"{path}: not a togcrf checkpoint (needs 'model' and 'config')")
    checkpoint["config"] = {**CONFIG_ADDED_LATER, **checkpoint["config"]}
    checkpoint.setdefault("vocabulary", table1_vocabulary())
    checkpoint.setdefault("schema_version", SCHEMA_VERSION)
    return checkpoint


def load_checkpoint(path: str | Path, device: str = "cpu") -> tuple[torch.nn.Module, dict[str, Any]]:
    """The model of a checkpoint (eval mode, on ``device``) and its training config.

    Parameters
    ----------
    path : path
        ``RUN_DIR/checkpoint.pt`` (or a run dir).
    device : str

    Returns
    -------
    model, config : torch.nn.Module, dict
        ``config`` is the stored training config plus ``"epoch"``, ``"data"``
        and ``"vocabulary"``.

    Raises
    ------
    FileNotFoundError, ValueError
        Missing file, or not a togcrf checkpoint.
    """
    checkpoint = read_checkpoint(path, device)
    config = dict(checkpoint["config"])
    try:
        model = build_model(config["model"], config["backbone"], stored_options(config.get("model_options")),
                            checkpoint["vocabulary"])
        model.load_state_dict(checkpoint["model"])
    except (ValueError, TypeError, RuntimeError, KeyError) as error:
        lines = [line.strip() for line in str(error).strip().splitlines() if line.strip()] or [type(error).__name__]
        summary = " ".join(lines[:2])  # load_state_dict says what differs on its second line
        summary = summary if len(summary) <= 300 else summary[:297] + "..."
        raise ValueError(f"{checkpoint_path(path)}: cannot build its model: {summary}") from error
    model.to(device).eval()
    config["epoch"] = checkpoint.get("epoch")
    config["data"] = checkpoint.get("data")
    config["vocabulary"] = checkpoint["vocabulary"]
    return model, config


def check_vocabulary(model_vocabulary: Mapping[str, Sequence[str]], data_vocabulary: Mapping[str, Sequence[str]],
                     model_source: str, data_source: str) -> None:
    """Refuse data labelled with another vocabulary than the model's.

    Parameters
    ----------
    model_vocabulary, data_vocabulary : mapping
        ``{"categories": [...], "tasks": [...]}``.
    model_source, data_source : str
        What each came from (a checkpoint path, a data dir), for the message.

    Raises
    ------
    ValueError
        Naming both sources and the first field that differs.
    """
    difference = vocabulary_difference(data_vocabulary, model_vocabulary)
    if difference is not None:
        raise ValueError(f"{data_source} is labelled with another vocabulary than {model_source}: {difference} "
                         "(the data's against the model's); use data built with the model's vocabulary, or train a "
                         "model on this data")
