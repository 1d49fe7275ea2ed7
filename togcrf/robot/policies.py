"""Who picks the grasp: a trained checkpoint, the oracle, or a random pixel.

Every policy sees the trial (task, named category) and the observation, and
returns one :class:`Choice`: a rectangle ``(x, y, h, w, theta)`` in the
depth image's pixels, or none with the reason.

- :class:`ModelPolicy`: the paper's rule, :func:`togcrf.predict.best_grasp_for_task`:
  the candidate with the largest P(task | stable) over all detected objects
  (score >= ``min_score``), only among those of the named category for "no
  task" and "hand over", only among candidates with P(stable) >=
  ``min_stability`` when any is.
- :class:`OraclePolicy`: a ground-truth rectangle of the right task from the
  render stage's own annotations of this image (of the named category for
  "no task" and "hand over"): with the pile's ground truth, the first, from
  the 3-D grasp that comes most nearly straight down (the executed grasp is
  top-down), then the highest, whose top-down grasp the gripper can reach
  without touching any tool on the way down (the pile collision test of the
  render stage, :func:`osgd.simulation.pile_collider`); the first of all when none can.
- :class:`RandomPolicy`: a pixel drawn uniformly among those with a depth
  reading (table and tools), a closing angle uniform in [-pi/2, pi/2) and
  an opening uniform in [1 cm, the gripper's maximum].
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from scipy.spatial.transform import Rotation

from togcrf.checkpoint import load_checkpoint
from togcrf.predict import best_grasp_for_task, keep_confident, predict_depth
from togcrf.robot.observation import Observation
from togcrf.robot.pile import clear_grasps, task_grasps
from togcrf.robot.protocol import Trial, trial_rng
from togcrf.tta import check_view_count, views_label

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Choice:
    """The grasp a policy picked.

    Attributes
    ----------
    rectangle : (5,) float64 or None
        ``x, y, h, w, theta`` in pixels and radians; None when the policy found none.
    category : str
        The category the policy believes the object is ("" when it has no belief).
    task_probability : float
        P(task | stable) of the candidate (NaN for the oracle and random policies).
    stability : float
        P(stable) (NaN likewise).
    detections : int
        Objects the policy detected (-1 when it detects nothing by design).
    reason : str
        Why there is no rectangle ("" when there is one).
    """

    rectangle: np.ndarray | None
    category: str = ""
    task_probability: float = float("nan")
    stability: float = float("nan")
    detections: int = -1
    reason: str = ""


class Policy(Protocol):
    """What every policy offers."""

    name: str
    checkpoint: str

    def choose(self, trial: Trial, observation: Observation) -> Choice:
        """Pick a grasp for a trial."""
        ...


@dataclass
class OraclePolicy:
    """A ground-truth rectangle of the right task (see the module text).

    Attributes
    ----------
    world : World
        For the models' collision shapes and the gripper.
    params : RobotParams
        How a rectangle is lifted to a top-down grasp.
    tolerance : float
        Penetration the clearance test allows, m.
    """

    world: Any
    params: Any
    tolerance: float = 0.001
    name: str = "oracle"
    checkpoint: str = ""

    def choose(self, trial: Trial, observation: Observation) -> Choice:
        """The first ground-truth grasp of the task (of the named category) whose top-down grasp is clear."""
        grasps = task_grasps(observation, trial)
        if not grasps:
            return Choice(None, reason="no ground-truth rectangle of the task in the image")
        rotation = observation.pose.rotation
        approaches = np.array([rotation @ Rotation.from_quat(grasp["quaternion"]).as_matrix()[:, 2]
                               for grasp in grasps])
        heights = np.array([(rotation @ np.asarray(grasp["position"]) + observation.pose.position)[2]
                            for grasp in grasps])
        # Most nearly straight down first (rounded, so that near-ties go to the highest grasp).
        ranked = [grasps[int(index)] for index in np.lexsort((-heights, np.round(approaches[:, 2], 2)))]
        clear = clear_grasps(self.world, observation, ranked, self.params, self.tolerance)
        best = ranked[clear.index(True)] if any(clear) else ranked[0]
        categories = {obj["object_index"]: obj["category"] for obj in observation.sample["objects"]}
        return Choice(np.asarray(best["rectangle"], dtype=np.float64), str(categories[best["object_index"]]))


@dataclass
class RandomPolicy:
    """A random rectangle on a random pixel with a depth reading (see the module text)."""

    seed: int
    finger_width: float
    max_opening: float
    name: str = "random"
    checkpoint: str = ""

    def choose(self, trial: Trial, observation: Observation) -> Choice:
        """Draw a pixel, an angle and an opening from the trial's own generator."""
        rng = trial_rng(self.seed, trial.task_index, trial.repeat, 1)
        rows, columns = np.nonzero(observation.depth > 0)
        if not len(rows):
            return Choice(None, reason="no depth reading in the image")
        pick = int(rng.integers(len(rows)))
        depth = float(observation.depth[rows[pick], columns[pick]])
        focal = (observation.intrinsics.fx + observation.intrinsics.fy) / 2
        opening = rng.uniform(0.01, self.max_opening)
        theta = rng.uniform(-np.pi / 2, np.pi / 2)
        rectangle = np.array([columns[pick], rows[pick], opening * focal / depth, self.finger_width * focal / depth,
                              theta], dtype=np.float64)
        return Choice(rectangle)


@dataclass
class ModelPolicy:
    """A trained checkpoint, choosing as the paper's robot does (see the module text)."""

    name: str
    checkpoint: str
    model: Any
    image_size: int | None
    min_score: float = 0.5
    min_stability: float = 0.5
    device: str = "cpu"
    depth_reference: str = "table"
    #: Test-time views averaged per image (:mod:`togcrf.tta`); 1: the image as given.
    views: int = 1
    last_detections: Any = field(default=None, repr=False)

    def choose(self, trial: Trial, observation: Observation) -> Choice:
        """Detect, then :func:`togcrf.predict.best_grasp_for_task`."""
        detections = keep_confident(predict_depth(self.model, observation.depth, self.image_size, self.device,
                                                  self.depth_reference, self.views),
                                    self.min_score)
        self.last_detections = detections
        count = len(detections.scores)
        try:
            best = best_grasp_for_task(detections, trial.task, trial.category, self.min_stability,
                                       self.model.vocabulary)
        except ValueError as error:
            return Choice(None, detections=count, reason=str(error))
        return Choice(np.asarray(best["rectangle"], dtype=np.float64), best["category"],
                      best["task_probability"], best["stability"], count)


def model_policy(checkpoint: Path, name: str | None = None, *, min_score: float = 0.5, min_stability: float = 0.5,
                 device: str = "cpu", views: int = 1) -> ModelPolicy:
    """A :class:`ModelPolicy` for a checkpoint (named after its model and run folder, and its test-time views
    when more than one, unless ``name``).

    Raises
    ------
    FileNotFoundError, ValueError
        Not a togcrf checkpoint, or views not in ``togcrf.tta.VIEW_COUNTS``.
    """
    check_view_count(views)
    model, config = load_checkpoint(checkpoint, device=device)
    checkpoint = Path(checkpoint)
    run = checkpoint.parent if checkpoint.suffix == ".pt" else checkpoint
    label = name or f"{config.get('model', 'model')}:{run.parent.name}{views_label(views)}"
    return ModelPolicy(label, str(checkpoint), model, config.get("image_size"), min_score, min_stability, device,
                       config["depth_reference"], views)

