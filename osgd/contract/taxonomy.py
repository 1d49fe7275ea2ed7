"""The one definition of object categories, task labels and object parts.

Everything that names a category, a task or a part imports it from here:
the annotate stage, the render stage, the Parquet schemas, the training
package and the figures.

The task labels and their order are those of Table I of the paper (Yang et
al., "Task-oriented Grasping in Object Stacking Scenes with CRF-based
Semantic Model", IROS 2019); the order matters because the network's 12 task
logits and the CRF's 12 x 12 compatibility matrices are indexed by it.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Final

#: The 12 task labels in the order of Table I (11 tasks plus "no task").
TASKS: Final[tuple[str, ...]] = (
    "no task",
    "cut",
    "screw",
    "ladle",
    "fork",
    "wrench",
    "hammer",
    "write",
    "brush",
    "shovel",
    "pinch",
    "hand over",
)

#: Task index by name, for encoding labels as integers.
TASK_INDEX: Final[dict[str, int]] = {name: index for index, name in enumerate(TASKS)}

#: The 10 object categories, in the order of Table I's representative objects.
CATEGORIES: Final[tuple[str, ...]] = (
    "knife",
    "screwdriver",
    "spoon",
    "fork",
    "wrench",
    "hammer",
    "pen",
    "toothbrush",
    "spatula",
    "pliers",
)

#: Category index by name; the detector's class label is this index + 1
#: (0 is the background class).
CATEGORY_INDEX: Final[dict[str, int]] = {name: index for index, name in enumerate(CATEGORIES)}

#: The task each category is the representative object of (Table I).
CATEGORY_TASK: Final[dict[str, str]] = {
    "knife": "cut",
    "screwdriver": "screw",
    "spoon": "ladle",
    "fork": "fork",
    "wrench": "wrench",
    "hammer": "hammer",
    "pen": "write",
    "toothbrush": "brush",
    "spatula": "shovel",
    "pliers": "pinch",
}

#: The grasp requirement of each task, verbatim from Table I.
TASK_REQUIREMENT: Final[dict[str, str]] = {
    "no task": "cannot finish any task",
    "cut": "avoid the blade",
    "screw": "avoid the shaft",
    "ladle": "avoid the bowl",
    "fork": "avoid the tines",
    "wrench": "away from the jaws",
    "hammer": "away from the heavier end",
    "write": "not close to the tip",
    "brush": "avoid the parts with bristles",
    "shovel": "avoid the blade",
    "pinch": "avoid the jaws",
    "hand over": "leave the handle clear",
}

#: The file name stem of each task in the original OSGD annotation layout
#: (``<name>/annotations/<stem>.npy``).
TASK_FILE_STEM: Final[dict[str, str]] = {task: task.replace(" ", "_") for task in TASKS}

#: Object part names used for per-face part labels. Index -1 means unknown.
PARTS: Final[tuple[str, ...]] = (
    "handle",
    "blade",
    "shaft",
    "tip",
    "bowl",
    "tines",
    "head",
    "neck",
    "jaws",
    "bristles",
)

#: Part index by name.
PART_INDEX: Final[dict[str, int]] = {name: index for index, name in enumerate(PARTS)}

#: The label of a face whose part is not known.
UNKNOWN_PART: Final[int] = -1


def task_from_file_stem(stem: str) -> str:
    """Return the task named by an OSGD annotation file stem.

    Parameters
    ----------
    stem : str
        File name without extension, e.g. ``"hand_over"``.

    Raises
    ------
    ValueError
        If the stem names no task of Table I.
    """
    for task, task_stem in TASK_FILE_STEM.items():
        if task_stem == stem:
            return task
    raise ValueError(
        f"annotation file stem {stem!r} names no task; expected one of "
        f"{sorted(TASK_FILE_STEM.values())}"
    )


#: The vocabulary a detector's outputs are indexed by: the category classes and the task logits, in
#: order. Samples shards record it (``osgd.vocabulary`` in their Parquet metadata) and so do
#: checkpoints, so that a model never reads data labelled with another vocabulary.
VOCABULARY: Final[dict[str, tuple[str, ...]]] = {"categories": CATEGORIES, "tasks": TASKS}


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


#: One colour per task, (r, g, b) floats in [0, 1]: the one palette of every picture that colours by
#: task. They are matplotlib's ``tab20`` entries, written out so that the contract imports no
#: matplotlib: task ``i`` (Table I order) takes entry ``(2 * i) % 20 + (i >= 10)``, the dark shade of
#: the first ten pairs, then the light shade of the first two.
TASK_COLOURS: Final[dict[str, tuple[float, float, float]]] = {
    "no task": (0.12156862745098039, 0.4666666666666667, 0.7058823529411765),  # tab20[0]
    "cut": (1.0, 0.4980392156862745, 0.054901960784313725),  # tab20[2]
    "screw": (0.17254901960784313, 0.6274509803921569, 0.17254901960784313),  # tab20[4]
    "ladle": (0.8392156862745098, 0.15294117647058825, 0.1568627450980392),  # tab20[6]
    "fork": (0.5803921568627451, 0.403921568627451, 0.7411764705882353),  # tab20[8]
    "wrench": (0.5490196078431373, 0.33725490196078434, 0.29411764705882354),  # tab20[10]
    "hammer": (0.8901960784313725, 0.4666666666666667, 0.7607843137254902),  # tab20[12]
    "write": (0.4980392156862745, 0.4980392156862745, 0.4980392156862745),  # tab20[14]
    "brush": (0.7372549019607844, 0.7411764705882353, 0.13333333333333333),  # tab20[16]
    "shovel": (0.09019607843137255, 0.7450980392156863, 0.8117647058823529),  # tab20[18]
    "pinch": (0.6823529411764706, 0.7803921568627451, 0.9098039215686274),  # tab20[1]
    "hand over": (1.0, 0.7333333333333333, 0.47058823529411764),  # tab20[3]
}
