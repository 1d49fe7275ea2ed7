"""The one definition of the depth camera.

Camera frame
------------
OpenCV convention, right-handed: ``x`` to the right of the image, ``y`` down
the image, ``z`` forward along the optical axis. A point ``(X, Y, Z)`` in the
camera frame (metres, ``Z > 0``) projects to pixel
``(u, v) = (fx X / Z + cx, fy Y / Z + cy)``; pixel ``(0, 0)`` is the centre of
the top-left pixel.

The default intrinsics are close to the Kinect v2 depth camera the paper used
on its robot (512 x 424 pixels, about 70.6 x 60 degrees field of view, range
0.5-4.5 m; REFERENCE section 6).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class CameraIntrinsics:
    """Pinhole intrinsics; sizes in pixels, focal lengths in pixels.

    Attributes
    ----------
    width, height : int
        Image size.
    fx, fy : float
        Focal lengths.
    cx, cy : float
        Principal point.
    near, far : float
        Depth range of the sensor, metres.
    """

    width: int = 512
    height: int = 424
    fx: float = 365.5
    fy: float = 365.5
    cx: float = 255.5
    cy: float = 211.5
    near: float = 0.5
    far: float = 4.5

    def matrix(self) -> np.ndarray:
        """The 3 x 3 intrinsic matrix ``K``, float64."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def as_array(self) -> np.ndarray:
        """``(fx, fy, cx, cy)`` as a (4,) float64 array, the form stored in shards."""
        return np.array([self.fx, self.fy, self.cx, self.cy], dtype=np.float64)

    def cropped(self, left: float, top: float, side: float, size: int) -> CameraIntrinsics:
        """The intrinsics of a square window of this image resized to ``size`` px.

        Parameters
        ----------
        left, top : float
            Window corner in pixel-edge coordinates (0 is the image's left /
            top border; pixel ``i`` spans ``[i, i + 1)``). The window may
            reach past the image: the result is a virtual camera.
        side : float
            Window side, px of this image.
        size : int
            Side of the output image, px.

        Returns
        -------
        CameraIntrinsics
            ``size`` x ``size``, same depth range; a point projecting to
            ``(u, v)`` here projects to ``((u + 0.5 - left) s - 0.5, ...)``
            with ``s = size / side``.
        """
        if side <= 0 or size < 1:
            raise ValueError(f"crop side {side} px and size {size} px must be positive")
        scale = size / side
        return CameraIntrinsics(
            width=size, height=size, fx=self.fx * scale, fy=self.fy * scale,
            cx=(self.cx + 0.5 - left) * scale - 0.5, cy=(self.cy + 0.5 - top) * scale - 0.5,
            near=self.near, far=self.far,
        )

    def project(self, points_camera: np.ndarray) -> np.ndarray:
        """Project camera-frame points to pixels.

        Parameters
        ----------
        points_camera : (N, 3) float
            Points in the camera frame, metres, ``Z > 0``.

        Returns
        -------
        (N, 2) float64
            Pixel coordinates ``(u, v)``.
        """
        points = np.asarray(points_camera, dtype=np.float64).reshape(-1, 3)
        z = points[:, 2]
        u = self.fx * points[:, 0] / z + self.cx
        v = self.fy * points[:, 1] / z + self.cy
        return np.stack([u, v], axis=1)


#: The default depth camera, close to a Kinect v2.
KINECT_V2 = CameraIntrinsics()
