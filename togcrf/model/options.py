"""The options of the models, grouped as the detector's parts: backbone, RPN, box head, grasp head, FCGN, CRF, loss.

Every option has a default; a checkpoint stores all of them (:func:`options_dict`), and
:func:`model_options` builds them from what a user or a checkpoint gives: nested groups
(``{"rpn": {"anchor_sizes": [27, 53, 107]}}``) or dotted names (``{"rpn.anchor_sizes": [27, 53, 107]}``,
as ``togcrf train --option rpn.anchor_sizes=[27,53,107]`` gives them). The defaults are torchvision's
detection defaults and the paper's (Section IV-B: 7 x 7 RoIs, 196 candidates, a 12 x 12 CRF); the CPU and
GPU recipes override some of them (``togcrf.config.PRESETS``).

Checkpoints written before the options were grouped store them flat (``fpn_channels``, ``grasp_channels``,
...); :func:`migrate_flat_options` maps those names onto the groups, and refuses with one line the options
that were removed from the code with a value that changes the model.
"""

from __future__ import annotations

import typing
from dataclasses import asdict, dataclass, field, fields
from typing import Any

from togcrf.anchors import DEFAULT_ANCHOR_SIZE
from togcrf.crf import DEFAULT_BANDWIDTH, DEFAULT_ITERATIONS
from togcrf.losses import DEFAULT_NEGATIVE_RATIO


@dataclass(frozen=True)
class BackboneOptions:
    """The ResNet and its feature pyramid (the ResNet's depth is the training option ``backbone``).

    Attributes
    ----------
    norm : {"group", "batch"}
        Normalisation layers of the ResNet, the FPN (with ``fpn_norm``) and the grasp head. GroupNorm by
        default: batch statistics of 2-4 depth images are noisy, and GroupNorm behaves the same in training
        and evaluation.
    fpn_channels : int
        Channels of every FPN map (torchvision: 256).
    fpn_min_stride : {4, 8}
        Finest FPN level, pixels of the network input: 4 pools RoIs from ResNet C2 up (torchvision's), 8
        from C3 up.
    fpn_max_stride : {16, 32}
        Coarsest ResNet stage the FPN takes: 32 keeps C5 (torchvision's); 16 stops the ResNet after C4.
        The "pool" level lies at twice this stride, and ``rpn.anchor_sizes`` has one size per level.
    fpn_norm : bool
        Normalise the FPN's lateral and output convolutions with ``norm`` (torchvision's FPN has none;
        trained from scratch, its maps then grow large and uncentred).
    """

    norm: str = "group"
    fpn_channels: int = 256
    fpn_min_stride: int = 4
    fpn_max_stride: int = 32
    fpn_norm: bool = True


@dataclass(frozen=True)
class RpnOptions:
    """torchvision's region proposal network.

    Attributes
    ----------
    anchor_sizes : tuple of int
        Anchor side per FPN level, the "pool" level included, pixels of the network input (three aspect
        ratios, 0.5, 1 and 2, at each).
    pre_nms_train, post_nms_train, pre_nms_test, post_nms_test : int
        Proposals kept per level before, and per image after, the NMS.
    nms_threshold : float
        NMS IoU (REFERENCE section 3: 0.7).
    """

    anchor_sizes: tuple[int, ...] = (16, 32, 64, 128, 256)
    pre_nms_train: int = 1000
    post_nms_train: int = 500
    pre_nms_test: int = 500
    post_nms_test: int = 300
    nms_threshold: float = 0.7


@dataclass(frozen=True)
class BoxHeadOptions:
    """The RCNN box branch: torchvision's two-layer MLP head and predictor on 7 x 7 RoIs.

    Attributes
    ----------
    batch_per_image : int
        RoIs sampled per image for its loss (a quarter of them foreground at most).
    size : int
        Width of its two fully connected layers (torchvision: 1024).
    score_threshold : float
        Detection score floor.
    nms_threshold : float
        Per-class NMS IoU: 0.5, torchvision's, not ROI-GD's 0.3 (REFERENCE section 3), so that two
        overlapping objects of one category in a pile can both be detected.
    detections_per_image : int
    """

    batch_per_image: int = 256
    size: int = 1024
    score_threshold: float = 0.05
    nms_threshold: float = 0.5
    detections_per_image: int = 50


@dataclass(frozen=True)
class GraspHeadOptions:
    """The grasp head of TOG and TOG-CRFs on each RoI (paper, Section IV-B): 3 ResBlocks, 196 candidates.

    Attributes
    ----------
    channels : int
        Channels of its ResBlocks.
    trunk_norm : bool
        A last normalisation on the ResBlocks' output (also FCGN's); their identity path is never
        normalised, so without it the features grow positive and large.
    anchor_size : float
        Side of the square grasp anchors, pixels of the network input (``togcrf.anchors``).
    rois_per_image : int
        Foreground RoIs per image that train the grasp head (ground-truth boxes and proposals of IoU >= 0.5
        with an object, each with that object's grasps).
    """

    channels: int = 256
    trunk_norm: bool = True
    anchor_size: float = DEFAULT_ANCHOR_SIZE
    rois_per_image: int = 16


@dataclass(frozen=True)
class FcgnOptions:
    """The grasp branch of FCGN + Task (``togcrf.fcgn``): the grasp head on one FPN map of the whole image.

    Attributes
    ----------
    level : int
        FPN level it runs on, an index into the FPN's strides (0: the ``backbone.fpn_min_stride`` map).
    channels : int
        Channels of its ResBlocks.
    blocks : int
        ResBlocks before the output convolutions.
    candidates_per_box : int
        Most stable candidates given to each detected box at inference.
    """

    level: int = 1
    channels: int = 128
    blocks: int = 1
    candidates_per_box: int = 196


@dataclass(frozen=True)
class CrfOptions:
    """The task CRF of TOG-CRFs (``togcrf.crf.MeanFieldCrf``).

    Attributes
    ----------
    iterations : int
        Mean-field iterations unrolled (paper: eq. 4 as an RNN).
    bandwidth : float
        Gaussian kernel bandwidth of ``k_G``, RoI units.
    """

    iterations: int = DEFAULT_ITERATIONS
    bandwidth: float = DEFAULT_BANDWIDTH


@dataclass(frozen=True)
class LossOptions:
    """Loss weights and the grasp losses' settings (``togcrf.losses``).

    Attributes
    ----------
    rpn, rcnn, stability, regression, task : float
        Weights of the RPN losses (objectness and box), the RCNN losses (class and box) and the three
        grasp losses.
    negative_ratio : int
        Hard negatives per positive grasp candidate (REFERENCE section 3: 3).
    ranking_weight : float
        Weight of the top-1 ranking term added to the stability loss (``togcrf.losses.top1_ranking_loss``;
        0: the paper's cross entropy alone).
    """

    rpn: float = 1.0
    rcnn: float = 1.0
    stability: float = 1.0
    regression: float = 1.0
    task: float = 1.0
    negative_ratio: int = DEFAULT_NEGATIVE_RATIO
    ranking_weight: float = 0.0


@dataclass(frozen=True)
class ModelOptions:
    """Every option of a model, one group per part of the detector."""

    backbone: BackboneOptions = field(default_factory=BackboneOptions)
    rpn: RpnOptions = field(default_factory=RpnOptions)
    box_head: BoxHeadOptions = field(default_factory=BoxHeadOptions)
    grasp_head: GraspHeadOptions = field(default_factory=GraspHeadOptions)
    fcgn: FcgnOptions = field(default_factory=FcgnOptions)
    crf: CrfOptions = field(default_factory=CrfOptions)
    loss: LossOptions = field(default_factory=LossOptions)


#: The option groups by name, in the order of :class:`ModelOptions`.
GROUPS: dict[str, type] = {group.name: group.default_factory for group in fields(ModelOptions)}


def option_names() -> list[str]:
    """Every option's dotted name (``group.option``)."""
    return [f"{group}.{option.name}" for group, kind in GROUPS.items() for option in fields(kind)]


def _dotted(values: dict[str, Any]) -> dict[str, Any]:
    """Nested groups and dotted names, as one dict of dotted names."""
    flat: dict[str, Any] = {}
    for name, value in values.items():
        if name in GROUPS and isinstance(value, dict):
            flat |= {f"{name}.{option}": option_value for option, option_value in value.items()}
        else:
            flat[name] = value
    return flat


def model_options(values: dict[str, Any] | ModelOptions | None = None) -> ModelOptions:
    """Options from nested groups or dotted names (the defaults for what is not given).

    Raises
    ------
    ValueError
        Unknown names, listed with the known ones.
    """
    if isinstance(values, ModelOptions):
        return values
    flat = _dotted(values or {})
    known = option_names()
    unknown = sorted(set(flat) - set(known))
    if unknown:
        raise ValueError(f"unknown model option{'s' if len(unknown) > 1 else ''} {', '.join(unknown)}; "
                         f"known: {', '.join(known)}")
    groups = {}
    hints = {group: typing.get_type_hints(kind) for group, kind in GROUPS.items()}
    for group, kind in GROUPS.items():
        given = {name.split(".", 1)[1]: value for name, value in flat.items() if name.startswith(f"{group}.")}
        groups[group] = kind(**{name: _checked(f"{group}.{name}", value, hints[group][name])
                                 for name, value in given.items()})
    return ModelOptions(**groups)


def _checked(name: str, value: Any, kind: Any) -> Any:
    """``value`` if it is of the option's type (an int where a float is asked is taken); else a ValueError."""
    if kind is bool:
        ok = isinstance(value, bool)
        expected = "true or false"
    elif kind is int:
        ok = isinstance(value, int) and not isinstance(value, bool)
        expected = "a whole number"
    elif kind is float:
        ok = isinstance(value, int | float) and not isinstance(value, bool)
        expected = "a number"
    elif kind is str:
        ok = isinstance(value, str)
        expected = "a string"
    else:  # tuple[int, ...]
        ok = isinstance(value, list | tuple) and all(isinstance(item, int) and not isinstance(item, bool)
                                                     for item in value)
        expected = "a list of whole numbers, e.g. [27,53,107]"
    if not ok:
        raise ValueError(f"model option {name}={value!r}: expected {expected}")
    return float(value) if kind is float else tuple(value) if isinstance(value, list) else value


def dotted_options(options: ModelOptions) -> dict[str, Any]:
    """Options as dotted names with JSON values (``{"rpn.anchor_sizes": [16, 32, 64, 128, 256], ...}``)."""
    return _dotted(options_dict(options))


def with_options(options: ModelOptions, values: dict[str, Any]) -> ModelOptions:
    """``options`` with the dotted or nested ``values`` changed."""
    merged = dotted_options(options) | _dotted(values)
    return model_options(merged)


def options_dict(options: ModelOptions) -> dict[str, dict[str, Any]]:
    """Options as nested JSON values (tuples as lists), as checkpoints and config.json store them."""
    values = asdict(options)
    values["rpn"]["anchor_sizes"] = list(values["rpn"]["anchor_sizes"])
    return values


#: Flat option names of checkpoints written before the options were grouped, by their dotted name now.
FLAT_NAMES = {
    "norm": "backbone.norm", "fpn_channels": "backbone.fpn_channels", "fpn_min_stride": "backbone.fpn_min_stride",
    "fpn_max_stride": "backbone.fpn_max_stride", "fpn_norm": "backbone.fpn_norm",
    "grasp_trunk_norm": "grasp_head.trunk_norm", "rpn_anchor_sizes": "rpn.anchor_sizes",
    "rpn_pre_nms_train": "rpn.pre_nms_train", "rpn_post_nms_train": "rpn.post_nms_train",
    "rpn_pre_nms_test": "rpn.pre_nms_test", "rpn_post_nms_test": "rpn.post_nms_test",
    "rpn_nms_threshold": "rpn.nms_threshold", "box_batch_per_image": "box_head.batch_per_image",
    "box_head_size": "box_head.size", "box_score_threshold": "box_head.score_threshold",
    "box_nms_threshold": "box_head.nms_threshold", "detections_per_image": "box_head.detections_per_image",
    "grasp_anchor_size": "grasp_head.anchor_size", "grasp_ranking_weight": "loss.ranking_weight",
    "grasp_rois_per_image": "grasp_head.rois_per_image", "grasp_channels": "grasp_head.channels",
    "crf_iterations": "crf.iterations", "crf_bandwidth": "crf.bandwidth", "negative_ratio": "loss.negative_ratio",
    "weight_rpn": "loss.rpn", "weight_rcnn": "loss.rcnn", "weight_stability": "loss.stability",
    "weight_regression": "loss.regression", "weight_task": "loss.task", "fcgn_level": "fcgn.level",
    "fcgn_channels": "fcgn.channels", "fcgn_blocks": "fcgn.blocks",
    "fcgn_candidates_per_box": "fcgn.candidates_per_box",
}

#: Flat options that were removed from the code, with the value under which a model had none of them: those that
#: gave the model other layers or outputs (a checkpoint that used one cannot be built) ...
REMOVED_LAYER_OPTIONS = {
    "grasp_object_map": False, "grasp_confidence": False, "grasp_stability_per_category": False,
    "grasp_fine_map": False, "grasp_grid": 7, "grasp_context_cells": 0,
}
#: ... and those that changed only its training targets or losses (its model loads; its training cannot go on).
REMOVED_TRAINING_OPTIONS = {
    "grasp_positive_radius": 0.0, "grasp_ignore_radius": None, "grasp_regression_radius": 0.0,
    "grasp_ranking_matches": False, "grasp_confidence_trains_features": False, "weight_object_map": 1.0,
    "weight_confidence": 1.0,
}
REMOVED_FLAT_OPTIONS = REMOVED_LAYER_OPTIONS | REMOVED_TRAINING_OPTIONS


def is_flat(values: dict[str, Any]) -> bool:
    """Whether stored options are in the flat form of checkpoints from before the groups."""
    return any(name in FLAT_NAMES or name in REMOVED_FLAT_OPTIONS for name in values)


def migrate_flat_options(values: dict[str, Any], training: bool = False) -> dict[str, Any]:
    """Flat stored options as dotted names; the removed options must hold their neutral value (those that
    changed only training, when the options are to train on: ``training``).

    Raises
    ------
    ValueError
        A removed option with another value, or an unknown name.
    """
    removed = REMOVED_FLAT_OPTIONS if training else REMOVED_LAYER_OPTIONS
    changed = {name: value for name, value in values.items() if name in removed and value != removed[name]}
    if changed:
        listed = ", ".join(f"{name}={value!r}" for name, value in sorted(changed.items()))
        what = "was trained with" if training else "uses"
        raise ValueError(f"its model {what} options this code no longer has ({listed}); "
                         f"{'train' if training else 'evaluate'} it at the commit that trained it")
    unknown = sorted(set(values) - set(FLAT_NAMES) - set(REMOVED_FLAT_OPTIONS))
    if unknown:
        raise ValueError(f"unknown stored model options {', '.join(unknown)}")
    return {FLAT_NAMES[name]: value for name, value in values.items() if name in FLAT_NAMES}


def stored_options(values: dict[str, Any] | None, training: bool = False) -> ModelOptions:
    """The options a checkpoint or config.json stores, in either form (flat ones migrated; ``training``: to
    resume its training, which refuses also the removed options that changed only training)."""
    values = values or {}
    return model_options(migrate_flat_options(values, training) if is_flat(values) else values)

