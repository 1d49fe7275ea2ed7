"""Task labels of sampled grasps, from the parts the fingers touch and where along the tool they hold it.

The paper's Table I (``osgd.contract.taxonomy.TASK_REQUIREMENT``) states each task's
grasp requirement in words. For a model whose faces carry part labels the
requirement becomes one rule per category (:func:`default_rules` of a taxonomy; Table I's in
:data:`DEFAULT_RULES`):

- the category's **task** (hammer for a hammer, cut for a knife...) when
  every part the fingers touch is a ``handle`` part, no ``working`` part
  lies within ``task_clearance`` of the region between the finger pads
  ("avoid the blade", "away from the heavier end"), and the grasp centre
  lies behind ``split``: in the half of the tool at its handle end;
- **hand over** when every touched part is a ``working`` part and no
  ``handle`` part lies within ``hand_over_clearance`` ("leave the handle
  clear"), or when the grasp centre lies at or beyond ``split``, every
  touched part is known and not both kinds are touched: the receiver takes
  the tool by the end of its handle;
- **no task** otherwise: an unknown part (-1) touched, both kinds of part
  touched (where the handle meets the working part), or too close to the
  other kind.

The position along the tool is measured on its :class:`ToolAxis`, the
longest side of its oriented bounding box, from the handle end (0) to the
working end (1). ``split`` follows the paper authors' own annotations: on
their 75 models the pairs of each category's task lie in the half at the
handle end and the hand-over pairs in the half at the working end, handle
included (a hammer held by the shaft under its head, a fork by its neck;
paper Fig. 1: hand over "grasp its head or neck"), so the half agrees with
more of their pairs than the parts alone do (docs/models.md, "How well:
the authors' models"). ``split = 1`` labels by the parts alone.

A working part at the handle end, behind the centre of the handle parts (a
wrench's ring end, when the open jaws are at the other), is held like the
handle for the task: Table I asks the wrench task only to keep "away from
the jaws". The rules are checked in the order above. A pipeline config
replaces the rule of a category with ``[grasps.label_rules.<category>]``
(see ``docs/grasps.md``).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import trimesh
from pydantic import BaseModel, ConfigDict, Field, PrivateAttr

from osgd.contract.taxonomy import HAND_OVER, NO_TASK, RULE_DEFAULTS, TABLE1, UNKNOWN_PART, Taxonomy
from osgd.models.parts import principal_frame


class LabelRule(BaseModel):
    """How one category's grasps get their task label (see the module text).

    Its parts are names of a taxonomy's parts; the rule reads their indices, and its category's task, from
    the taxonomy it is bound to (:meth:`bound`; Table I unless bound to another).
    """

    model_config = ConfigDict(extra="forbid", frozen=True)
    _taxonomy: Taxonomy = PrivateAttr(default=TABLE1)

    handle: tuple[str, ...] = Field(
        description="parts held for the category's task; hand over must leave them clear"
    )
    working: tuple[str, ...] = Field(
        description="parts that do the work: the task leaves them free, hand over holds them; the first of "
        "them that a tool has marks its working end (tool_axis)"
    )
    task_clearance: float = Field(
        RULE_DEFAULTS["task_clearance"], ge=0.0,
        description="least distance, m, from the pads' region to a working part for the task label"
    )
    hand_over_clearance: float = Field(
        RULE_DEFAULTS["hand_over_clearance"], ge=0.0,
        description="least distance, m, from the pads' region to a handle part for hand over"
    )
    split: float = Field(
        RULE_DEFAULTS["split"], gt=0.0, le=1.0,
        description="where along the tool, as a share of its length from the handle end, the category's task "
        "(behind) gives way to hand over (at and beyond), as the paper authors annotated their models; 1: by "
        "the parts alone",
    )

    @property
    def taxonomy(self) -> Taxonomy:
        """The taxonomy the rule's parts and tasks are of."""
        return self._taxonomy

    def bound(self, taxonomy: Taxonomy) -> LabelRule:
        """The same rule on the parts and tasks of ``taxonomy``.

        Raises
        ------
        ValueError
            If the taxonomy has not some of its parts.
        """
        unknown = self.unknown_parts(taxonomy)
        if unknown:
            raise ValueError(f"unknown part(s) {unknown}; parts are {list(taxonomy.parts)}")
        rule = self.model_copy()
        rule._taxonomy = taxonomy
        return rule

    def unknown_parts(self, taxonomy: Taxonomy) -> list[str]:
        """The rule's parts that the taxonomy has not."""
        return [part for part in (*self.handle, *self.working) if part not in taxonomy.part_index]

    def part(self, name: str) -> int:
        """The index of a part."""
        return self._taxonomy.part_index[name]

    @property
    def handle_parts(self) -> frozenset[int]:
        """Part indices of :attr:`handle`."""
        return frozenset(self.part(part) for part in self.handle)

    @property
    def working_parts(self) -> frozenset[int]:
        """Part indices of :attr:`working`."""
        return frozenset(self.part(part) for part in self.working)

    @property
    def by_position(self) -> bool:
        """Whether the place along the tool counts (``split`` below 1)."""
        return self.split < 1.0


def default_rules(taxonomy: Taxonomy) -> dict[str, LabelRule]:
    """The rule of each category of a taxonomy, as its file states it, bound to it."""
    return {
        category.name: LabelRule(handle=category.handle, working=category.working,
                                 task_clearance=category.task_clearance,
                                 hand_over_clearance=category.hand_over_clearance, split=category.split).bound(taxonomy)
        for category in taxonomy.categories
    }


#: The default rule of each category of Table I (``osgd/contract/table1.toml`` gives the reasons for its
#: clearances).
DEFAULT_RULES: dict[str, LabelRule] = default_rules(TABLE1)


def rule_mistakes(overrides: Mapping[str, LabelRule], taxonomy: Taxonomy) -> list[str]:
    """What a config's per-category replacements name that the taxonomy has not: a category, a part."""
    mistakes = [f"label_rules.{category}: unknown category; categories are {list(taxonomy.category_names)}"
                for category in sorted(set(overrides) - set(taxonomy.category_names))]
    return mistakes + [f"label_rules.{category}: unknown part(s) {rule.unknown_parts(taxonomy)}; parts are "
                       f"{list(taxonomy.parts)}" for category, rule in sorted(overrides.items())
                       if rule.unknown_parts(taxonomy)]


def effective_rules(overrides: Mapping[str, LabelRule], taxonomy: Taxonomy = TABLE1) -> dict[str, LabelRule]:
    """The default rules of the taxonomy's categories with a config's per-category replacements, bound to it.

    Raises
    ------
    ValueError
        If an override names no category, or a part the taxonomy has not.
    """
    mistakes = rule_mistakes(overrides, taxonomy)
    if mistakes:
        raise ValueError("; ".join(mistakes))
    defaults = DEFAULT_RULES if taxonomy == TABLE1 else default_rules(taxonomy)
    return {category: overrides[category].bound(taxonomy) if category in overrides else defaults[category]
            for category in taxonomy.category_names}


@dataclass(frozen=True)
class ToolAxis:
    """A tool's long axis, from its handle end to its working end.

    Attributes
    ----------
    direction : (3,) float
        Unit vector, object frame, pointing from the handle end to the working end.
    start : float
        Coordinate of the handle end along ``direction``, m.
    length : float
        The tool's extent along ``direction``, m.
    """

    direction: np.ndarray
    start: float
    length: float

    def position(self, points: np.ndarray) -> np.ndarray:
        """(N,) share of the length from the handle end of (N, 3) object-frame points (0 to 1 on the tool)."""
        return (np.asarray(points, dtype=np.float64) @ self.direction - self.start) / self.length


def tool_axis(mesh: trimesh.Trimesh, face_parts: np.ndarray, rule: LabelRule) -> ToolAxis | None:
    """The tool's axis: the longest side of its oriented box, pointing from its handle parts to its working part.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        Object frame, m; F faces.
    face_parts : (F,) int
        Part index per face (the rule's taxonomy), -1 unknown.
    rule : LabelRule
        Names the handle and working parts.

    Returns
    -------
    ToolAxis or None
        None when the mesh has no handle part or no working part, or their
        area centres do not differ along the axis (no end to tell). The
        working end is that of the first of ``rule.working`` the mesh has.
    """
    areas = np.asarray(mesh.area_faces, dtype=np.float64)
    centres = np.asarray(mesh.triangles_center, dtype=np.float64)
    handle = np.isin(face_parts, list(rule.handle_parts))
    # the working end is that of the rule's first working part the tool has: a wrench's open jaws, however
    # large its ring end (the paper authors' wrench_003, whose ring outweighs its jaws)
    working = next((kind for kind in (face_parts == rule.part(part) for part in rule.working)
                    if areas[kind].sum() > 0), None)
    if working is None or areas[handle].sum() <= 0:
        return None
    handle_centre, working_centre = (
        np.average(centres[kind], axis=0, weights=areas[kind]) for kind in (handle, working)
    )
    along = principal_frame(mesh).axes[0]
    towards_work = float((working_centre - handle_centre) @ along)
    if abs(towards_work) < 1e-9:
        return None
    direction = along if towards_work > 0 else -along
    coordinates = np.asarray(mesh.vertices, dtype=np.float64) @ direction
    low = float(coordinates.min())
    return ToolAxis(direction, low, float(coordinates.max()) - low)


def holding_parts(parts: np.ndarray, points: np.ndarray, axis: ToolAxis | None, rule: LabelRule) -> np.ndarray:
    """The parts as the task label sees them: a working part behind the handle's centre counts as the handle.

    Parameters
    ----------
    parts : (P,) int
        Part index of each surface sample.
    points : (P, 3) float
        The samples, object frame, m.
    axis : ToolAxis or None
        The tool's axis; None (or a rule with ``split = 1``) returns ``parts`` as they are.
    rule : LabelRule

    Returns
    -------
    (P,) int
        ``parts`` with each working part at the handle end (a wrench's ring
        end) replaced by the rule's first handle part.
    """
    if axis is None or not rule.by_position:
        return parts
    position = axis.position(points)
    handle = np.isin(parts, list(rule.handle_parts))
    working = np.isin(parts, list(rule.working_parts))
    if not handle.any():
        return parts
    behind = working & (position < float(np.median(position[handle])))
    return np.where(behind, rule.part(rule.handle[0]), parts)


def label_grasp(
    category: str,
    rule: LabelRule,
    touched_parts: np.ndarray,
    part_distances: Mapping[int, float],
    position: float | None = None,
) -> str:
    """The task label of one grasp.

    Parameters
    ----------
    category : str
        A category of the rule's taxonomy.
    rule : LabelRule
        The category's rule.
    touched_parts : (K,) int array
        Part indices (the rule's taxonomy, -1 unknown) of the surface between
        the finger pads (:func:`holding_parts`).
    part_distances : mapping of part index to float
        Least distance, m, from the pads' region to each part near the grasp;
        a part that is absent is farther than any clearance.
    position : float, optional
        The grasp centre's share of the tool's length from its handle end
        (:meth:`ToolAxis.position`); None when the tool has no axis, and the
        parts alone decide.

    Returns
    -------
    str
        A task of the rule's taxonomy.
    """
    touched = {int(part) for part in np.unique(touched_parts)}
    if not touched:
        return NO_TASK
    handle, working = rule.handle_parts, rule.working_parts
    beyond_split = rule.by_position and position is not None and position >= rule.split

    def clear_of(parts: set[int], clearance: float) -> bool:
        return all(part_distances.get(part, np.inf) >= clearance for part in parts)

    if not beyond_split and touched <= handle and clear_of(working, rule.task_clearance):
        return rule.taxonomy.category(category).task
    if touched <= working and clear_of(handle, rule.hand_over_clearance):
        return HAND_OVER
    if beyond_split and UNKNOWN_PART not in touched and not (touched & handle and touched & working):
        return HAND_OVER
    return NO_TASK
