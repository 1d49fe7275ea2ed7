"""The one definition of object categories, task labels and object parts: the taxonomy.

Everything that names a category, a task or a part imports it from here:
the annotate stage, the render stage, the Parquet schemas, the training
package and the figures.

The taxonomy is data: ``osgd/contract/table1.toml``, shipped in the package,
holds the paper's Table I (Yang et al., "Task-oriented Grasping in Object
Stacking Scenes with CRF-based Semantic Model", IROS 2019) and the sources of
its figures. :func:`read_taxonomy` reads such a file into a :class:`Taxonomy`
and checks it, naming every mistake on a line of its own; the constants of
this module (``TASKS``, ``CATEGORIES``, ``PARTS``...) are those of Table I.
The order of the tasks matters: a detector's task logits and its CRF's
compatibility matrices are indexed by it (12 and 12 x 12 for Table I); so
does the order of the categories, the detector's classes.

A taxonomy file holds (units: metres, kg, kg/m^3):

- ``name``: a name for it;
- ``parts``: the part names of per-face part labels;
- ``tasks``: ``{name, requirement}`` tables in logit order; the first is
  ``"no task"`` and one is ``"hand over"`` (the label rules give them to any
  category, :mod:`osgd.grasps.labels`);
- ``[[categories]]``: ``name``; ``task``, the task it is the representative
  object of; the label rule of its grasps (``handle`` and ``working``, lists
  of parts; ``task_clearance`` and ``hand_over_clearance``, m, default 0.01;
  ``split``, in (0, 1], default 0.5: see :mod:`osgd.grasps.labels`); its
  physical properties (``length_range``, m; ``density``, kg/m^3;
  ``mass_range``, kg; ``lateral_friction``: :mod:`osgd.models.categories`);
  and, for a category without a rule of its own in :mod:`osgd.models.parts`,
  how users' meshes of it get their parts automatically: ``parts_rule =
  "elongated"`` with ``working_end`` one of :data:`WORKING_ENDS` (the handle
  and the working part along the tool's axis, the boundary where its
  cross-section changes), or none (parts from the sidecar only).

``extends = "table1"`` makes a file an extension of Table I: its ``parts``,
``tasks`` and ``categories`` follow Table I's, in that order, so that Table I's
tools keep their part, task and class indices. A pipeline names its taxonomy
with ``[pipeline] taxonomy``; the generator takes extensions of Table I
(:attr:`Taxonomy.extends_table1`), the detector any taxonomy.
"""

from __future__ import annotations

import functools
import hashlib
import json
import math
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from importlib import resources
from pathlib import Path
from typing import Any, Final

#: The packaged taxonomy of Table I.
TABLE1_FILE: Final[str] = "table1.toml"

#: The tasks every taxonomy has: the label of a grasp that serves no task, and handing the tool over.
NO_TASK: Final[str] = "no task"
HAND_OVER: Final[str] = "hand over"

#: Defaults of a category's label rule (see :mod:`osgd.grasps.labels`): clearances in metres, split a share.
RULE_DEFAULTS: Final[dict[str, float]] = {"task_clearance": 0.01, "hand_over_clearance": 0.01, "split": 0.5}

#: The automatic parts rule a category of a taxonomy may name (``parts_rule``; :mod:`osgd.models.parts`).
ELONGATED: Final[str] = "elongated"
#: Which end of an elongated tool works (``working_end``): the end of the larger or the smaller cross-section
#: (the outer fifth of the length at each end), or the half of the larger or the smaller volume.
WORKING_ENDS: Final[tuple[str, ...]] = ("wider", "narrower", "heavier", "lighter")
#: What ``extends`` may name.
EXTENDABLE: Final[tuple[str, ...]] = ("table1",)

_CATEGORY_FIELDS: Final[frozenset[str]] = frozenset(
    {"name", "task", "handle", "working", "length_range", "density", "mass_range", "lateral_friction",
     "parts_rule", "working_end", *RULE_DEFAULTS})


@dataclass(frozen=True)
class CategorySpec:
    """One category of a taxonomy: its task, the label rule of its grasps, its physical properties.

    Attributes
    ----------
    name, task : str
    handle, working : tuple of str
        Parts held for the task / left clear for it (:class:`osgd.grasps.labels.LabelRule`).
    task_clearance, hand_over_clearance : float
        Metres.
    split : float
        Share of the length from the handle end where the task gives way to hand over.
    length_range : (float, float)
        Real longest extent, metres.
    density : float
        kg/m^3.
    mass_range : (float, float)
        kg.
    lateral_friction : float
    parts_rule : str
        ``"elongated"`` (:data:`ELONGATED`) or ``""``: how a user's mesh of a category without a rule of its
        own gets automatic parts (none: from its sidecar only).
    working_end : str
        One of :data:`WORKING_ENDS` for an elongated category, else ``""``.
    """

    name: str
    task: str
    handle: tuple[str, ...]
    working: tuple[str, ...]
    task_clearance: float
    hand_over_clearance: float
    split: float
    length_range: tuple[float, float]
    density: float
    mass_range: tuple[float, float]
    lateral_friction: float
    parts_rule: str = ""
    working_end: str = ""


@dataclass(frozen=True)
class Taxonomy:
    """Categories, tasks and parts, in their order (see the module text)."""

    name: str
    parts: tuple[str, ...]
    tasks: tuple[str, ...]
    requirements: tuple[str, ...]
    categories: tuple[CategorySpec, ...]

    @property
    def category_names(self) -> tuple[str, ...]:
        """The categories' names, in order."""
        return tuple(category.name for category in self.categories)

    def category(self, name: str) -> CategorySpec:
        """The category called ``name``.

        Raises
        ------
        ValueError
            If the taxonomy has none of that name.
        """
        found = self._categories.get(name)
        if found is None:
            raise ValueError(f"unknown category {name!r}; expected one of {list(self.category_names)}")
        return found

    @functools.cached_property
    def _categories(self) -> dict[str, CategorySpec]:
        return {category.name: category for category in self.categories}

    @functools.cached_property
    def part_index(self) -> dict[str, int]:
        """Part index by name: the values of per-face part labels."""
        return {name: index for index, name in enumerate(self.parts)}

    @property
    def vocabulary(self) -> dict[str, tuple[str, ...]]:
        """The detector's classes and task logits, in order (:data:`VOCABULARY` for Table I)."""
        return {"categories": self.category_names, "tasks": self.tasks}

    @property
    def extends_table1(self) -> bool:
        """Whether Table I's parts, tasks and categories come first, in order, and unchanged."""
        return (self.parts[: len(TABLE1.parts)] == TABLE1.parts and self.tasks[: len(TABLE1.tasks)] == TABLE1.tasks
                and self.categories[: len(TABLE1.categories)] == TABLE1.categories)

    def document(self) -> dict[str, Any]:
        """The taxonomy as a TOML-like document that :func:`parse_taxonomy` reads back to an equal taxonomy."""
        categories = []
        for category in self.categories:
            entry = {key: list(value) if isinstance(value, tuple) else value for key, value in asdict(category).items()}
            categories.append({key: value for key, value in entry.items() if value != ""})
        return {"name": self.name, "parts": list(self.parts),
                "tasks": [{"name": task, "requirement": requirement}
                          for task, requirement in zip(self.tasks, self.requirements, strict=True)],
                "categories": categories}

    @property
    def digest(self) -> str:
        """SHA-256 of :meth:`document` as compact, key-sorted JSON: what the taxonomy's shards depend on."""
        text = json.dumps(self.document(), sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(text.encode("utf-8")).hexdigest()


class TaxonomyError(ValueError):
    """A taxonomy file with mistakes; the message has one line per mistake, each naming the file."""


def _names(entries: Any, where: str, mistakes: list[str], tables: bool) -> list[str]:
    """The names of a list of strings (``tables`` False) or of tables with a ``name``, noting a missing list, an
    entry of the wrong kind, a missing name or a duplicate."""
    if not isinstance(entries, list) or not entries:
        mistakes.append(f"{where}: expected a non-empty list")
        return []
    names = []
    for index, entry in enumerate(entries):
        name = entry.get("name") if tables and isinstance(entry, dict) else entry
        if tables and not isinstance(entry, dict):
            mistakes.append(f"{where}[{index}]: expected a table, got {entry!r}")
        elif not isinstance(name, str) or not name.strip():
            mistakes.append(f"{where}[{index}]: expected a name (a non-empty string), got {name!r}")
        elif name in names:
            mistakes.append(f"{where}: {name!r} is named twice")
        else:
            names.append(name)
    return names


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def _number_range(value: Any, where: str, mistakes: list[str]) -> tuple[float, float]:
    if (not isinstance(value, list) or len(value) != 2 or not all(_is_number(v) for v in value)
            or not 0 < value[0] <= value[1]):
        mistakes.append(f"{where}: expected [low, high], finite numbers with 0 < low <= high, got {value!r}")
        return (0.0, 0.0)
    return (float(value[0]), float(value[1]))


def _positive(value: Any, where: str, mistakes: list[str], allow_zero: bool = False) -> float:
    if not _is_number(value) or value < 0 or (value == 0 and not allow_zero):
        mistakes.append(f"{where}: expected a finite number {'>= 0' if allow_zero else '> 0'}, got {value!r}")
        return 0.0
    return float(value)


def _task_requirements(entries: Any, mistakes: list[str]) -> tuple[str, ...]:
    """Each task table's ``requirement``, noting unknown keys and a requirement that is not text."""
    requirements = []
    for index, entry in enumerate(entries if isinstance(entries, list) else []):
        if not isinstance(entry, dict):
            continue
        for key in sorted(set(entry) - {"name", "requirement"}):
            mistakes.append(f"tasks[{index}]: unknown key {key!r}; allowed: name, requirement")
        requirement = entry.get("requirement")
        if not isinstance(requirement, str) or not requirement.strip():
            mistakes.append(f"tasks[{index}].requirement: expected the task's grasp requirement as text, "
                            f"got {requirement!r}")
        requirements.append(str(requirement))
    return tuple(requirements)


def _part_list(value: Any, where: str, parts: Sequence[str], mistakes: list[str]) -> tuple[str, ...]:
    if not isinstance(value, list) or not value or not all(isinstance(part, str) for part in value):
        mistakes.append(f"{where}: expected a non-empty list of parts")
        return ()
    for part in value:
        if part not in parts:
            mistakes.append(f"{where}: unknown part {part!r}; parts are {list(parts)}")
    return tuple(value)


def _category(entry: dict[str, Any], where: str, parts: Sequence[str], tasks: Sequence[str],
              mistakes: list[str]) -> CategorySpec:
    """One ``[[categories]]`` table, noting each mistake."""
    for key in sorted(set(entry) - _CATEGORY_FIELDS):
        mistakes.append(f"{where}: unknown key {key!r}; allowed: {sorted(_CATEGORY_FIELDS)}")
    task = entry.get("task")
    if task not in tasks or task in (NO_TASK, HAND_OVER):
        mistakes.append(f"{where}: task {task!r} is not a task of the taxonomy (other than {NO_TASK!r} and "
                        f"{HAND_OVER!r})")
    handle = _part_list(entry.get("handle"), f"{where}.handle", parts, mistakes)
    working = _part_list(entry.get("working"), f"{where}.working", parts, mistakes)
    for part in sorted(set(handle) & set(working)):
        mistakes.append(f"{where}: part {part!r} is both a handle and a working part")
    rule = {key: _positive(entry.get(key, default), f"{where}.{key}", mistakes, allow_zero=key != "split")
            for key, default in RULE_DEFAULTS.items()}
    if rule["split"] > 1:
        mistakes.append(f"{where}.split: expected a share in (0, 1], got {rule['split']!r}")
    return CategorySpec(
        name=str(entry.get("name")), task=str(task), handle=handle, working=working, **rule,
        length_range=_number_range(entry.get("length_range"), f"{where}.length_range", mistakes),
        density=_positive(entry.get("density"), f"{where}.density", mistakes),
        mass_range=_number_range(entry.get("mass_range"), f"{where}.mass_range", mistakes),
        lateral_friction=_positive(entry.get("lateral_friction"), f"{where}.lateral_friction", mistakes),
        **_parts_rule(entry, where, mistakes))


def _parts_rule(entry: Mapping[str, Any], where: str, mistakes: list[str]) -> dict[str, str]:
    """``parts_rule`` and ``working_end`` of a category table, noting a rule or an end that is not known."""
    rule, end = entry.get("parts_rule", ""), entry.get("working_end", "")
    if rule not in ("", ELONGATED):
        mistakes.append(f"{where}.parts_rule: expected {ELONGATED!r} (or no parts_rule: parts from the sidecar "
                        f"only), got {rule!r}")
    if rule == ELONGATED and end not in WORKING_ENDS:
        mistakes.append(f"{where}.working_end: an elongated category names its working end, one of "
                        f"{list(WORKING_ENDS)}; got {end!r}")
    if rule != ELONGATED and end != "":
        mistakes.append(f"{where}.working_end: only a category with parts_rule = {ELONGATED!r} has one")
    return {"parts_rule": str(rule), "working_end": str(end)}


def _extended(document: Mapping[str, Any], mistakes: list[str]) -> dict[str, Any]:
    """The document with the taxonomy it ``extends`` put first (Table I's parts, tasks and categories)."""
    base_name = document.get("extends")
    document = {key: value for key, value in document.items() if key != "extends"}
    if base_name is None:
        return document
    if base_name not in EXTENDABLE:
        mistakes.append(f"extends: expected one of {list(EXTENDABLE)}, got {base_name!r}")
        return document
    base = _table1_document()
    for key in ("parts", "tasks", "categories"):
        added = document.get(key, [])
        if not isinstance(added, list):
            mistakes.append(f"{key}: expected a list, got {added!r}")
            added = []
        document[key] = [*base[key], *added]
    return document


def parse_taxonomy(document: Mapping[str, Any], source: str) -> Taxonomy:
    """A taxonomy from its parsed TOML.

    Raises
    ------
    TaxonomyError
        Naming ``source`` and every mistake, a line each: an unknown key or part, a duplicate name, a
        category without a task or rule, a task that no category serves, a value out of its range.
    """
    mistakes: list[str] = []
    for key in sorted(set(document) - {"name", "extends", "parts", "tasks", "categories"}):
        mistakes.append(f"unknown key {key!r}; allowed: categories, extends, name, parts, tasks")
    document = _extended(document, mistakes)
    name = document.get("name", Path(source).stem)
    if not isinstance(name, str) or not name.strip():
        mistakes.append(f"name: expected a non-empty string, got {name!r}")
    parts = _names(document.get("parts"), "parts", mistakes, tables=False)
    tasks = _names(document.get("tasks"), "tasks", mistakes, tables=True)
    requirements = _task_requirements(document.get("tasks"), mistakes)
    if tasks and tasks[0] != NO_TASK:
        mistakes.append(f"tasks: the first task must be {NO_TASK!r}, got {tasks[0]!r}")
    if tasks and HAND_OVER not in tasks:
        mistakes.append(f"tasks: {HAND_OVER!r} is missing")
    entries = document.get("categories")
    _names(entries, "categories", mistakes, tables=True)
    categories = [_category(entry, f"categories[{entry.get('name', index)!r}]", parts, tasks, mistakes)
                  for index, entry in enumerate(entries if isinstance(entries, list) else [])
                  if isinstance(entry, dict)]
    served = {category.task for category in categories}
    for task in tasks:
        if task not in (NO_TASK, HAND_OVER) and task not in served:
            mistakes.append(f"tasks: {task!r} has no rule: no category names it as its task")
    if mistakes:
        raise TaxonomyError("\n".join(f"{source}: {mistake}" for mistake in mistakes))
    return Taxonomy(name=str(name), parts=tuple(parts), tasks=tuple(tasks),
                    requirements=requirements, categories=tuple(categories))


def read_taxonomy(path: str | Path) -> Taxonomy:
    """The taxonomy of a TOML file.

    Raises
    ------
    FileNotFoundError
        If there is no such file.
    TaxonomyError
        If it is not TOML, or has mistakes (:func:`parse_taxonomy`).
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such taxonomy file")
    try:
        document = tomllib.loads(path.read_text(encoding="utf-8"))
    except UnicodeDecodeError as error:
        raise TaxonomyError(f"{path}: not UTF-8 text ({error.reason} at byte {error.start}); a taxonomy is TOML") \
            from error
    except tomllib.TOMLDecodeError as error:
        raise TaxonomyError(f"{path}: not TOML ({error})") from error
    return parse_taxonomy(document, str(path))


def _table1_document() -> dict[str, Any]:
    text = resources.files(__package__).joinpath(TABLE1_FILE).read_text(encoding="utf-8")
    return tomllib.loads(text)


def _table1() -> Taxonomy:
    return parse_taxonomy(_table1_document(), f"osgd/contract/{TABLE1_FILE}")


#: Table I of the paper: the taxonomy of every built-in stage and model.
TABLE1: Final[Taxonomy] = _table1()

#: The 12 task labels in the order of Table I (11 tasks plus "no task").
TASKS: Final[tuple[str, ...]] = TABLE1.tasks

#: Task index by name, for encoding labels as integers.
TASK_INDEX: Final[dict[str, int]] = {name: index for index, name in enumerate(TASKS)}

#: The 10 object categories, in the order of Table I's representative objects.
CATEGORIES: Final[tuple[str, ...]] = TABLE1.category_names

#: Category index by name; the detector's class label is this index + 1
#: (0 is the background class).
CATEGORY_INDEX: Final[dict[str, int]] = {name: index for index, name in enumerate(CATEGORIES)}

#: The task each category is the representative object of (Table I).
CATEGORY_TASK: Final[dict[str, str]] = {category.name: category.task for category in TABLE1.categories}

#: The grasp requirement of each task, verbatim from Table I.
TASK_REQUIREMENT: Final[dict[str, str]] = dict(zip(TABLE1.tasks, TABLE1.requirements, strict=True))

def task_file_stem(task: str) -> str:
    """The file name stem of a task in the original OSGD annotation layout (``<name>/annotations/<stem>.npy``)
    and in its text format: spaces as underscores (``hand over`` -> ``hand_over``)."""
    return task.replace(" ", "_")


#: :func:`task_file_stem` of each task of Table I.
TASK_FILE_STEM: Final[dict[str, str]] = {task: task_file_stem(task) for task in TASKS}

#: Object part names used for per-face part labels. Index -1 means unknown.
PARTS: Final[tuple[str, ...]] = TABLE1.parts

#: Part index by name.
PART_INDEX: Final[dict[str, int]] = {name: index for index, name in enumerate(PARTS)}

#: The label of a face whose part is not known.
UNKNOWN_PART: Final[int] = -1


def task_from_file_stem(stem: str, tasks: Sequence[str] = TASKS) -> str:
    """Return the task named by an OSGD annotation file stem.

    Parameters
    ----------
    stem : str
        File name without extension, e.g. ``"hand_over"``.
    tasks : sequence of str
        The tasks it may name (default Table I's).

    Raises
    ------
    ValueError
        If the stem names none of them.
    """
    for task in tasks:
        if task_file_stem(task) == stem:
            return task
    raise ValueError(
        f"annotation file stem {stem!r} names no task; expected one of "
        f"{sorted(task_file_stem(task) for task in tasks)}"
    )


#: The vocabulary a detector's outputs are indexed by: the category classes and the task logits, in
#: order. Samples shards record it (``osgd.vocabulary`` in their Parquet metadata) and so do
#: checkpoints, so that a model never reads data labelled with another vocabulary.
VOCABULARY: Final[dict[str, tuple[str, ...]]] = {"categories": CATEGORIES, "tasks": TASKS}


def vocabulary_json(vocabulary: Mapping[str, Sequence[str]]) -> bytes:
    """A vocabulary as Parquet metadata records it (``osgd.vocabulary``): compact JSON."""
    return json.dumps({field: list(names) for field, names in vocabulary.items()}, separators=(",", ":")).encode()


def vocabulary_difference(recorded: Mapping[str, Sequence[str]], expected: Mapping[str, Sequence[str]]) -> str | None:
    """One line saying how two vocabularies differ, or None when they agree.

    Parameters
    ----------
    recorded, expected : mapping
        ``{"categories": [...], "tasks": [...]}`` as in :data:`VOCABULARY`.
    """
    for field in ("categories", "tasks"):
        first, second = list(recorded.get(field, ())), list(expected.get(field, ()))
        if first != second:
            return f"{field} {first} against {second}"
    return None


#: matplotlib's ``tab20`` colours, (r, g, b) floats in [0, 1], written out so that the contract imports no
#: matplotlib: the pairs of a dark and a light shade of ten hues.
TAB20: Final[tuple[tuple[float, float, float], ...]] = (
    (0.12156862745098039, 0.4666666666666667, 0.7058823529411765),  # tab20[0]
    (0.6823529411764706, 0.7803921568627451, 0.9098039215686274),  # tab20[1]
    (1.0, 0.4980392156862745, 0.054901960784313725),  # tab20[2]
    (1.0, 0.7333333333333333, 0.47058823529411764),  # tab20[3]
    (0.17254901960784313, 0.6274509803921569, 0.17254901960784313),  # tab20[4]
    (0.596078431372549, 0.8745098039215686, 0.5411764705882353),  # tab20[5]
    (0.8392156862745098, 0.15294117647058825, 0.1568627450980392),  # tab20[6]
    (1.0, 0.596078431372549, 0.5882352941176471),  # tab20[7]
    (0.5803921568627451, 0.403921568627451, 0.7411764705882353),  # tab20[8]
    (0.7725490196078432, 0.6901960784313725, 0.8352941176470589),  # tab20[9]
    (0.5490196078431373, 0.33725490196078434, 0.29411764705882354),  # tab20[10]
    (0.7686274509803922, 0.611764705882353, 0.5803921568627451),  # tab20[11]
    (0.8901960784313725, 0.4666666666666667, 0.7607843137254902),  # tab20[12]
    (0.9686274509803922, 0.7137254901960784, 0.8235294117647058),  # tab20[13]
    (0.4980392156862745, 0.4980392156862745, 0.4980392156862745),  # tab20[14]
    (0.7803921568627451, 0.7803921568627451, 0.7803921568627451),  # tab20[15]
    (0.7372549019607844, 0.7411764705882353, 0.13333333333333333),  # tab20[16]
    (0.8588235294117647, 0.8588235294117647, 0.5529411764705883),  # tab20[17]
    (0.09019607843137255, 0.7450980392156863, 0.8117647058823529),  # tab20[18]
    (0.6196078431372549, 0.8549019607843137, 0.8980392156862745),  # tab20[19]
)


def task_palette(tasks: Sequence[str]) -> dict[str, tuple[float, float, float]]:
    """One colour per task, for any number of tasks: task ``i`` (in the vocabulary's order) takes ``tab20``
    entry ``(2 * i) % 20 + (i // 10) % 2``, the dark shades of the ten hues, then the light ones; colours repeat
    from the 21st task on."""
    return {task: TAB20[(2 * index) % 20 + (index // 10) % 2] for index, task in enumerate(tasks)}


#: One colour per task of Table I: the one palette of every picture that colours by task.
TASK_COLOURS: Final[dict[str, tuple[float, float, float]]] = task_palette(TASKS)


@functools.lru_cache(maxsize=8)
def _parsed_document(text: str) -> Taxonomy:
    return parse_taxonomy(json.loads(text), "the pipeline's taxonomy")


def taxonomy_of_document(document: Mapping[str, Any] | None) -> Taxonomy:
    """The taxonomy of a :meth:`Taxonomy.document` (parsed once per process), Table I for None."""
    if document is None:
        return TABLE1
    return _parsed_document(json.dumps(document, sort_keys=True))
