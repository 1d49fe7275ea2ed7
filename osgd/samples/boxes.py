"""Object boxes and visible fractions from an instance mask.

A box is the tight box of an object's visible pixels: ``(x1, y1, x2, y2)``
are the smallest and largest column and row of those pixels (pixel
centres, as in :mod:`osgd.camera`; the box spans ``x2 - x1 + 1`` pixels
across), the convention of the original OSGD generator (REFERENCE
section 2).

The visible fraction is the object's visible pixels over the pixels it
would cover alone in front of the camera: its silhouette, found by casting
one ray per pixel centre at the object alone (embree, exact), over the
object's whole projection, also the part outside the image, so an object
cut by the image border counts as partly hidden. :class:`SilhouetteCounter`
builds each mesh's embree scene once per worker and turns the rays into the
mesh's frame.
"""

from __future__ import annotations

import numpy as np

from osgd.camera import CameraIntrinsics
from osgd.raycast import EMBREE_SCENES_KEPT, EmbreeScenes
from osgd.samples.renderer import RenderObject, cast_object
from osgd.samples.viewpoint import CameraPose


def visible_boxes(mask: np.ndarray, count: int) -> tuple[np.ndarray, np.ndarray]:
    """Tight boxes of each object's visible pixels.

    Parameters
    ----------
    mask : (H, W) int
        0 background, ``i + 1`` for object ``i``.
    count : int
        Number of objects.

    Returns
    -------
    boxes : (count, 4) float64
        ``x1, y1, x2, y2`` pixels; zeros for an object with no visible pixel.
    pixels : (count,) int64
        Visible pixels per object.
    """
    boxes = np.zeros((count, 4))
    pixels = np.bincount(np.asarray(mask).reshape(-1), minlength=count + 1)[1 : count + 1].astype(np.int64)
    for index in np.nonzero(pixels)[0]:
        rows, columns = np.nonzero(mask == index + 1)
        boxes[index] = [columns.min(), rows.min(), columns.max(), rows.max()]
    return boxes, pixels


class SilhouetteCounter:
    """Counts the pixels an object would cover alone, one embree scene per mesh, reused.

    For the renderers that do not count them in their own pass (egl, tiny;
    the embree renderer's :attr:`Rendering.silhouettes` come from the same
    casts). The rays are turned into the mesh's frame and cast at its scene
    in :class:`osgd.raycast.EmbreeScenes`, built once per mesh.

    Parameters
    ----------
    capacity : int
        Scenes kept, least recently used dropped first.
    """

    def __init__(self, capacity: int = EMBREE_SCENES_KEPT) -> None:
        self.scenes = EmbreeScenes(capacity)

    def count(self, obj: RenderObject, intrinsics: CameraIntrinsics, pose: CameraPose) -> int:
        """Pixel centres whose ray hits the object when it is alone.

        Counts pixels of the unbounded image plane (the projection of the
        object may extend past the image).

        Parameters
        ----------
        obj : RenderObject
        intrinsics : CameraIntrinsics
        pose : CameraPose

        Returns
        -------
        int
            0 if any part of the object is behind the camera's image plane (no
            finite projection) or nothing is hit.
        """
        hits = cast_object(self.scenes, obj, intrinsics, pose)
        return 0 if hits is None else int(np.count_nonzero(hits.hit))
