"""Which tools and piles are held out for test: the ``split`` group of the scenes stage (``[scenes.split]``).

Two rules (``docs/scenes.md``, "Splits by tool"):

- ``by = "scene"`` (the default): every pile draws from every model, and the
  samples stage puts a scene in the test split when the sha256 of its scene
  id, as a fraction of 2^64, is below ``samples.test_fraction``
  (:func:`unit_hash`).
- ``by = "model"``: each model is a train or a test model
  (:func:`model_sides`), each pile is a test pile when :func:`unit_hash` of
  its scene id is below ``scene_fraction``, and it is drawn from the models
  of its own side only, so no pile mixes the two. A sample is in the test
  split when every object of its scene is a test model
  (:func:`scene_split`).

The rule acts where piles are drawn because a pile of independently drawn
tools is seldom all of one side: with a fifth of the tools held out, a pile
of 3-6 tools is all test once in about 400 piles, and three in five mix
both.
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Iterable, Mapping, Sequence
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

#: The two sides of a split, the values of the ``samples.split`` column.
SIDES: tuple[str, str] = ("train", "test")


class SplitParams(BaseModel):
    """How the dataset is split into train and test (``[scenes.split]``); fractions in [0, 1]."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    by: Literal["scene", "model"] = Field(
        "scene",
        description="'scene': piles draw from every model and samples.test_fraction of the scenes (by scene-id "
        "hash) are test; 'model': tools are held out, each pile draws from the train or the test tools only, "
        "and a sample is test when its pile's tools are",
    )
    model_fraction: float = Field(
        0.2, ge=0.0, le=1.0,
        description="by='model': share of the models held out for test, by model-id hash (per category with "
        "per_category)",
    )
    per_category: bool = Field(
        True,
        description="by='model': hold out ceil(model_fraction x n) of the n models of each category (those of "
        "lowest model-id hash), at most n - 1, so every category of two or more models has held-out and "
        "training tools; false: a model is test when its model-id hash is below model_fraction",
    )
    test_models: tuple[str, ...] = Field(
        (),
        description="by='model': model ids or names (e.g. procedural/hammer_03) held out besides those the "
        "fraction picks; each must name a model of the models table",
    )
    scene_fraction: float = Field(
        0.1, ge=0.0, le=1.0,
        description="by='model': share of the piles drawn from the test models, by scene-id hash (the same hash "
        "as samples.test_fraction, so the same scenes are test at the same fraction)",
    )

    @field_validator("test_models")
    @classmethod
    def _sorted_names(cls, value: tuple[str, ...]) -> tuple[str, ...]:
        return tuple(sorted(set(value)))

    @model_validator(mode="after")
    def _consistent(self) -> SplitParams:
        if self.by == "scene":
            changed = [name for name, info in type(self).model_fields.items()
                       if name != "by" and getattr(self, name) != info.default]
            if changed:
                raise ValueError(f"by = 'scene' splits by scene id (samples.test_fraction) and uses none of "
                                 f"{', '.join(changed)}; set by = 'model' or leave them out")
        elif self.model_fraction == 0 and not self.test_models:
            raise ValueError("by = 'model' holds out no model: set model_fraction above 0 or list test_models")
        return self


def unit_hash(text: str) -> float:
    """The first 8 bytes of ``sha256(text)`` (UTF-8) as a fraction of 2^64, in [0, 1)."""
    return int.from_bytes(hashlib.sha256(text.encode("utf-8")).digest()[:8], "big") / 2.0**64


def pile_side(scene_id: str, split: SplitParams) -> str:
    """``"test"`` when :func:`unit_hash` of the scene id is below ``split.scene_fraction``, else ``"train"``."""
    return "test" if unit_hash(scene_id) < split.scene_fraction else "train"


def model_sides(rows: Iterable[Mapping[str, Any]], split: SplitParams) -> dict[str, str]:
    """``"train"`` or ``"test"`` for every model, by the rule of ``split`` (``by = "model"``).

    Parameters
    ----------
    rows : iterable of mapping
        ``models`` rows with at least ``model_id``, ``name`` and ``category``.
    split : SplitParams

    Returns
    -------
    dict of model id to side

    Raises
    ------
    ValueError
        If an entry of ``split.test_models`` names no model of ``rows``.
    """
    rows = list(rows)
    test: set[str] = set()
    if split.per_category:
        by_category: dict[str, list[str]] = {}
        for row in rows:
            by_category.setdefault(str(row["category"]), []).append(str(row["model_id"]))
        for model_ids in by_category.values():
            ordered = sorted(set(model_ids), key=lambda model_id: (unit_hash(model_id), model_id))
            count = min(len(ordered) - 1, math.ceil(split.model_fraction * len(ordered) - 1e-9))
            test.update(ordered[:max(count, 0)])
    else:
        test.update(str(row["model_id"]) for row in rows if unit_hash(str(row["model_id"])) < split.model_fraction)
    named = {str(row["model_id"]): str(row["model_id"]) for row in rows}
    named.update({str(row["name"]): str(row["model_id"]) for row in rows})
    unknown = [entry for entry in split.test_models if entry not in named]
    if unknown:
        raise ValueError(f"[scenes.split] test_models = {list(unknown)}: no model of the models table has that id "
                         f"or name ({len(rows)} models, e.g. {sorted(named)[:3]})")
    test.update(named[entry] for entry in split.test_models)
    return {str(row["model_id"]): "test" if str(row["model_id"]) in test else "train" for row in rows}


def scene_split(model_ids: Sequence[str], sides: Mapping[str, str]) -> str:
    """The split of a scene's samples under ``by = "model"``: ``"train"`` only when every model is a train model.

    A scene drawn by the scenes stage holds models of one side; one that mixes
    both (or holds no object) is ``"test"``, so no test model is ever trained on.
    """
    return "train" if model_ids and all(sides[model_id] == "train" for model_id in model_ids) else "test"
