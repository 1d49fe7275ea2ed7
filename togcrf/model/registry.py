"""The registry of the models of Table II: their names, row names, grasp branches and CRF terms.

``MODELS`` is the only list of model names; training, evaluation, the table and the CLI take theirs
from here.
"""

from __future__ import annotations

from dataclasses import dataclass

#: Grasp branches of the detector: "roi" (TOG: candidates in each RoI of the RCNN) and "image"
#: (FCGN + Task: candidates over the whole image's feature map, ``togcrf.fcgn``).
GRASP_BRANCHES = ("roi", "image")


@dataclass(frozen=True)
class ModelSpec:
    """One model of Table II.

    Attributes
    ----------
    paper_name : str
        Its row name in Table II.
    grasp_branch : {"roi", "image"}
        Its grasp branch (``GRASP_BRANCHES``).
    crf_terms : (bool, bool) or None
        ``(use_omega, use_mu)`` of its task CRF; None: no CRF.
    """

    paper_name: str
    grasp_branch: str
    crf_terms: tuple[bool, bool] | None = None


#: The models by name, in the row order of Table II.
MODELS: dict[str, ModelSpec] = {
    "fcgn-task": ModelSpec("FCGN + Task", "image"),
    "tog": ModelSpec("TOG", "roi"),
    "tog-crfs-omega": ModelSpec("TOG-CRFs omega", "roi", (True, False)),
    "tog-crfs-mu": ModelSpec("TOG-CRFs mu", "roi", (False, True)),
    "tog-crfs": ModelSpec("TOG-CRFs", "roi", (True, True)),
}

#: Model names, in the order of Table II.
MODEL_NAMES = tuple(MODELS)

#: Row names of Table II, by model name.
PAPER_NAMES = {name: spec.paper_name for name, spec in MODELS.items()}
