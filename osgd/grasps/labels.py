"""Task labels of sampled grasps, from the parts the fingers touch.

The paper's Table I (``osgd.contract.taxonomy.TASK_REQUIREMENT``) states each task's
grasp requirement in words. For a model whose faces carry part labels the
requirement becomes one rule per category, all in :data:`DEFAULT_RULES`:

- the category's **task** (hammer for a hammer, cut for a knife...) when
  every part the fingers touch is a ``handle`` part and no ``working`` part
  lies within ``task_clearance`` of the region between the finger pads
  ("avoid the blade", "away from the heavier end");
- **hand over** when every touched part is a ``working`` part and no
  ``handle`` part lies within ``hand_over_clearance`` ("leave the handle
  clear");
- **no task** otherwise: both kinds of part touched, an unknown part (-1)
  or a part the rule does not name touched, or too close to the other kind.

The rules are checked in that order, so a grasp that meets both (impossible
when the clearances are positive) gets the category's task. A pipeline config
replaces the rule of a category with ``[grasps.label_rules.<category>]``
(see ``docs/grasps.md``).
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator

from osgd.contract.taxonomy import CATEGORIES, CATEGORY_TASK, PART_INDEX, PARTS


class LabelRule(BaseModel):
    """How one category's grasps get their task label (see the module text)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    handle: tuple[str, ...] = Field(
        description="parts held for the category's task; hand over must leave them clear"
    )
    working: tuple[str, ...] = Field(
        description="parts that do the work: the task leaves them free, hand over holds them"
    )
    task_clearance: float = Field(
        0.01, ge=0.0, description="least distance, m, from the pads' region to a working part for the task label"
    )
    hand_over_clearance: float = Field(
        0.01, ge=0.0, description="least distance, m, from the pads' region to a handle part for hand over"
    )

    @field_validator("handle", "working")
    @classmethod
    def _known_parts(cls, parts: tuple[str, ...]) -> tuple[str, ...]:
        unknown = [part for part in parts if part not in PART_INDEX]
        if unknown:
            raise ValueError(f"unknown part(s) {unknown}; parts are {list(PARTS)}")
        return parts


#: The default rule of each category, following Table I. Clearances: 1 cm
#: keeps a pad off the working part when the grasp slips a little in the
#: check stage; the hammer's 3 cm is "away from the heavier end" and the
#: pen's 2 cm "not close to the tip". ``neck`` (spoon, fork, spatula,
#: toothbrush) is held with the handle: "avoid the bowl / tines / blade /
#: bristles" allows it.
DEFAULT_RULES: dict[str, LabelRule] = {
    #                 held for the task            held for hand over
    "knife": LabelRule(handle=("handle",), working=("blade", "tip")),
    "screwdriver": LabelRule(handle=("handle",), working=("shaft", "tip")),
    "spoon": LabelRule(handle=("handle", "neck"), working=("bowl",)),
    "fork": LabelRule(handle=("handle", "neck"), working=("tines",)),
    "wrench": LabelRule(handle=("handle",), working=("jaws", "head")),
    "hammer": LabelRule(handle=("handle",), working=("head",), task_clearance=0.03),
    "pen": LabelRule(handle=("handle", "shaft"), working=("tip",), task_clearance=0.02),
    "toothbrush": LabelRule(handle=("handle", "neck"), working=("head", "bristles")),
    "spatula": LabelRule(handle=("handle", "neck"), working=("blade",)),
    "pliers": LabelRule(handle=("handle",), working=("jaws", "head")),
}

assert set(DEFAULT_RULES) == set(CATEGORIES), "every category needs a label rule"


def effective_rules(overrides: Mapping[str, LabelRule]) -> dict[str, LabelRule]:
    """The default rules with a config's per-category replacements.

    Raises
    ------
    ValueError
        If an override names no category.
    """
    unknown = sorted(set(overrides) - set(CATEGORIES))
    if unknown:
        raise ValueError(f"label_rules name unknown categor(ies) {unknown}; categories are {list(CATEGORIES)}")
    return {category: overrides.get(category, DEFAULT_RULES[category]) for category in CATEGORIES}


def label_grasp(
    category: str,
    rule: LabelRule,
    touched_parts: np.ndarray,
    part_distances: Mapping[int, float],
) -> str:
    """The task label of one grasp.

    Parameters
    ----------
    category : str
        One of ``taxonomy.CATEGORIES``.
    rule : LabelRule
        The category's rule.
    touched_parts : (K,) int array
        Part indices (``taxonomy.PARTS``, -1 unknown) of the surface between
        the finger pads.
    part_distances : mapping of part index to float
        Least distance, m, from the pads' region to each part near the grasp;
        a part that is absent is farther than any clearance.

    Returns
    -------
    str
        One of ``taxonomy.TASKS``.
    """
    touched = {int(part) for part in np.unique(touched_parts)}
    if not touched:
        return "no task"
    handle = {PART_INDEX[part] for part in rule.handle}
    working = {PART_INDEX[part] for part in rule.working}

    def clear_of(parts: set[int], clearance: float) -> bool:
        return all(part_distances.get(part, np.inf) >= clearance for part in parts)

    if touched <= handle and clear_of(working, rule.task_clearance):
        return CATEGORY_TASK[category]
    if touched <= working and clear_of(handle, rule.hand_over_clearance):
        return "hand over"
    return "no task"
