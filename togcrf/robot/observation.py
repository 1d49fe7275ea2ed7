"""What the robot sees of a pile: the pile at rest and its depth image (:class:`Observation`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from osgd.simulation import CameraIntrinsics, CameraPose


@dataclass(frozen=True)
class Observation:
    """A pile at rest and its depth image.

    Attributes
    ----------
    scene : dict
        A ``scenes`` row: ``scene_id``, ``scene_index``, ``seed``, ``objects``
        (``model_id``, ``category``, mesh-frame ``position`` and
        ``quaternion`` in the world).
    depth : (H, W) float32
        Noisy depth, m, 0 = no reading (what the robot sees).
    mask : (H, W) uint8
        ``object_index + 1`` on each object's visible pixels.
    intrinsics : CameraIntrinsics
    pose : CameraPose
    sample : dict
        The ``samples`` row: ``objects`` (boxes) and ``grasps`` (the
        ground-truth rectangles with their tasks and camera-frame poses).
    """

    scene: dict[str, Any]
    depth: np.ndarray
    mask: np.ndarray
    intrinsics: CameraIntrinsics
    pose: CameraPose
    sample: dict[str, Any]

    def object_at(self, x: float, y: float) -> int:
        """The scene object index seen at a pixel, -1 for the table or outside the image."""
        row, column = round(y), round(x)
        height, width = self.mask.shape
        if not (0 <= row < height and 0 <= column < width):
            return -1
        return int(self.mask[row, column]) - 1

    @property
    def categories(self) -> list[str]:
        """The category of every object of the pile, in scene order."""
        return [str(obj["category"]) for obj in self.scene["objects"]]
