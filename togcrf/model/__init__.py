"""The models of Table II: TOG, TOG-CRFs (paper, Section IV-B/C, Fig. 3), its CRF ablations and FCGN + Task.

One module per part: ``registry`` (the model names), ``options`` (every option, grouped by part),
``backbone`` (ResNet + FPN), ``grasp_head`` (the ResBlocks and the candidates' outputs), ``targets``
(the grasp branch's training targets) and ``detector`` (:class:`GraspDetector`, which holds them all).
:func:`build_model` builds a model by name.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from togcrf.model.backbone import BACKBONES
from togcrf.model.detector import GraspDetector, batch_images
from togcrf.model.grasp_head import stable_probability
from togcrf.model.options import ModelOptions, model_options, options_dict, stored_options
from togcrf.model.registry import MODEL_NAMES, MODELS, PAPER_NAMES


def build_model(name: str, backbone: str = "resnet18", options: ModelOptions | dict[str, Any] | None = None,
                vocabulary: Mapping[str, Sequence[str]] | None = None) -> GraspDetector:
    """A model of Table II by name (``MODELS``).

    Parameters
    ----------
    name : str
        One of ``MODEL_NAMES``.
    backbone : str
        One of ``BACKBONES``.
    options : ModelOptions, or nested or dotted option values (``togcrf.model.options.model_options``)
    vocabulary : mapping, optional
        The categories and tasks its outputs are indexed by (default Table I's; ``GraspDetector``).

    Raises
    ------
    ValueError
        Unknown name, backbone or option.
    """
    if name not in MODELS:
        raise ValueError(f"unknown model {name!r}; expected one of {', '.join(MODEL_NAMES)}")
    spec = MODELS[name]
    return GraspDetector(backbone, spec.crf_terms, model_options(options), spec.grasp_branch, vocabulary)


__all__ = ["BACKBONES", "MODELS", "MODEL_NAMES", "PAPER_NAMES", "GraspDetector", "ModelOptions", "batch_images",
           "build_model", "model_options", "options_dict", "stable_probability", "stored_options"]
