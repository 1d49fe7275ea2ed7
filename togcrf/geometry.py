"""Geometry of grasp rectangles and boxes on numpy arrays, in a sample's pixel frame.

A grasp rectangle is ``(x, y, h, w, theta)``: centre in pixels, ``h`` the
gripper opening along the closing direction, ``w`` the finger width across
it, ``theta`` the angle of the closing direction to the image x axis in
radians; a rectangle and the same one turned by 180 degrees are the same
grasp. A detected grasp matches a ground-truth grasp when the Jaccard index
of the two rotated rectangles is larger than ``GRASP_JACCARD_THRESHOLD``
(0.25) and their angle difference, modulo 180 degrees, is smaller than
``GRASP_ANGLE_TOLERANCE`` (30 degrees): the Cornell rectangle metric of the
paper (Section V-B), used by ``togcrf.metrics``, the prediction pictures and
the robot experiment. Boxes are ``x1, y1, x2, y2``.
"""

from __future__ import annotations

import numpy as np
import shapely

#: Jaccard index of grasp rectangles above which grasps match (paper V-B).
GRASP_JACCARD_THRESHOLD = 0.25
#: Angle difference below which grasps match, radians (30 degrees, paper V-B).
GRASP_ANGLE_TOLERANCE = np.deg2rad(30.0)


def rectangle_corners(rectangles: np.ndarray) -> np.ndarray:
    """Corners of grasp rectangles.

    Parameters
    ----------
    rectangles : (..., 5) array
        ``x, y, h, w, theta`` (pixels, radians).

    Returns
    -------
    (..., 4, 2) float64 array
        Corners in pixels, in order around the rectangle.
    """
    rectangles = np.asarray(rectangles, dtype=np.float64)
    centre = rectangles[..., None, 0:2]
    half_opening = rectangles[..., 2, None, None] / 2
    half_width = rectangles[..., 3, None, None] / 2
    theta = rectangles[..., 4]
    closing = np.stack([np.cos(theta), np.sin(theta)], axis=-1)[..., None, :]
    across = np.stack([-np.sin(theta), np.cos(theta)], axis=-1)[..., None, :]
    signs = np.array([[1, 1], [1, -1], [-1, -1], [-1, 1]], dtype=np.float64)
    return (centre + signs[:, 0:1] * half_opening * closing + signs[:, 1:2] * half_width * across)


def _polygons(rectangles: np.ndarray) -> np.ndarray:
    return shapely.polygons(rectangle_corners(rectangles).reshape(-1, 4, 2))


def rectangle_jaccard(first: np.ndarray, second: np.ndarray) -> np.ndarray:
    """Jaccard index (intersection over union) of every pair of rotated rectangles.

    Parameters
    ----------
    first : (P, 5) array
    second : (M, 5) array
        Grasp rectangles ``x, y, h, w, theta``.

    Returns
    -------
    (P, M) float64 array
        Exact polygon intersection over union; 0 where a rectangle is empty.
    """
    first = np.asarray(first, dtype=np.float64).reshape(-1, 5)
    second = np.asarray(second, dtype=np.float64).reshape(-1, 5)
    if len(first) == 0 or len(second) == 0:
        return np.zeros((len(first), len(second)))
    polygons_first = _polygons(first)[:, None]
    polygons_second = _polygons(second)[None, :]
    intersection = shapely.area(shapely.intersection(polygons_first, polygons_second))
    area_first = np.abs(first[:, 2] * first[:, 3])[:, None]
    area_second = np.abs(second[:, 2] * second[:, 3])[None, :]
    union = area_first + area_second - intersection
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(union > 0, intersection / union, 0.0)


def _paired_jaccard(first: np.ndarray, second: np.ndarray) -> np.ndarray:
    """Jaccard index of rectangle ``first[i]`` with ``second[i]``: (P, 5), (P, 5) -> (P,)."""
    intersection = shapely.area(shapely.intersection(_polygons(first), _polygons(second)))
    union = np.abs(first[:, 2] * first[:, 3]) + np.abs(second[:, 2] * second[:, 3]) - intersection
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(union > 0, intersection / union, 0.0)


def paired_grasp_match(detected: np.ndarray, ground_truth: np.ndarray) -> np.ndarray:
    """Whether grasp ``detected[i]`` matches ``ground_truth[i]``, by the rule of :func:`grasp_match_matrix`.

    Parameters
    ----------
    detected, ground_truth : (P, 5) array

    Returns
    -------
    (P,) bool array
    """
    detected = np.asarray(detected, dtype=np.float64).reshape(-1, 5)
    ground_truth = np.asarray(ground_truth, dtype=np.float64).reshape(-1, 5)
    angles_close = angle_difference(detected[:, 4], ground_truth[:, 4]) < GRASP_ANGLE_TOLERANCE
    return angles_close & (_paired_jaccard(detected, ground_truth) > GRASP_JACCARD_THRESHOLD)


def angle_difference(first: np.ndarray, second: np.ndarray) -> np.ndarray:
    """Smallest difference of grasp angles, modulo 180 degrees.

    Parameters
    ----------
    first, second : array-like, broadcastable
        Angles in radians.

    Returns
    -------
    float64 array in [0, pi/2]
        Radians.
    """
    difference = np.abs(np.asarray(first, dtype=np.float64) - np.asarray(second, dtype=np.float64)) % np.pi
    return np.minimum(difference, np.pi - difference)


def grasp_match_matrix(detected: np.ndarray, ground_truth: np.ndarray) -> np.ndarray:
    """Which detected grasps match which ground-truth grasps.

    Parameters
    ----------
    detected : (P, 5) array
    ground_truth : (M, 5) array

    Returns
    -------
    (P, M) bool array
        Jaccard > :data:`GRASP_JACCARD_THRESHOLD` and angle difference
        (mod 180 degrees) < :data:`GRASP_ANGLE_TOLERANCE`.
    """
    detected = np.asarray(detected, dtype=np.float64).reshape(-1, 5)
    ground_truth = np.asarray(ground_truth, dtype=np.float64).reshape(-1, 5)
    angles_close = angle_difference(detected[:, None, 4], ground_truth[None, :, 4]) < GRASP_ANGLE_TOLERANCE
    # Only pairs close in angle and in position need the (costly) polygon intersection.
    reach = (np.hypot(detected[:, 2], detected[:, 3])[:, None] + np.hypot(ground_truth[:, 2], ground_truth[:, 3])) / 2
    centre_distance = np.linalg.norm(detected[:, None, :2] - ground_truth[None, :, :2], axis=-1)
    rows, columns = np.nonzero(angles_close & (centre_distance < reach))
    matches = np.zeros(angles_close.shape, dtype=bool)
    if len(rows):
        matches[rows, columns] = paired_grasp_match(detected[rows], ground_truth[columns])
    return matches


def box_iou(first: np.ndarray, second: np.ndarray, *, plus_one: bool = False) -> np.ndarray:
    """IoU of axis-aligned boxes ``x1, y1, x2, y2``.

    Parameters
    ----------
    first : (P, 4) array
    second : (M, 4) array
    plus_one : bool
        False (ours): continuous boxes, width ``x2 - x1``. True (the lab's
        and VOC's code): inclusive pixel boxes, width ``x2 - x1 + 1``.

    Returns
    -------
    (P, M) float64 array
    """
    first = np.asarray(first, dtype=np.float64).reshape(-1, 4)
    second = np.asarray(second, dtype=np.float64).reshape(-1, 4)
    pad = 1.0 if plus_one else 0.0
    top_left = np.maximum(first[:, None, :2], second[None, :, :2])
    bottom_right = np.minimum(first[:, None, 2:], second[None, :, 2:])
    intersection = np.prod(np.clip(bottom_right - top_left + pad, 0, None), axis=-1)
    area_first = np.prod(np.clip(first[:, 2:] - first[:, :2] + pad, 0, None), axis=-1)
    area_second = np.prod(np.clip(second[:, 2:] - second[:, :2] + pad, 0, None), axis=-1)
    union = area_first[:, None] + area_second[None, :] - intersection
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(union > 0, intersection / union, 0.0)
