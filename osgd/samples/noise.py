"""Depth sensor noise: the paper's gaussian, or a richer sensor model.

``gaussian`` (the paper, section IV-A: "zero-mean gaussian noise")
    ``depth + N(0, sigma)`` on every pixel with a reading.

``sensor`` (our choice, after REFERENCE section 6)
    The gaussian above, plus

    - correlated noise: a zero-mean gaussian field drawn on a grid
      ``correlated_cell`` pixels coarse and upsampled bilinearly (as Dex-Net
      and the original OSGD generator do: smooth, low-frequency error);
    - depth-dependent spread: sigma grows with the square of the distance
      beyond 0.5 m (``sigma * (1 + growth * (z - 0.5)^2)``), as the Kinect
      axial noise does;
    - edge noise: where the 3 x 3 depth range exceeds ``edge_threshold``
      (object borders), a fraction ``edge_hole_fraction`` of the pixels are
      lost (0, no reading) and the rest are jittered by ``edge_sigma``, the
      flying pixels of time-of-flight cameras;
    - random holes: a fraction ``hole_fraction`` of all pixels read 0.

Pixels without a reading (0) stay 0. Every draw comes from the generator
passed in, in a fixed order, so the same seed gives the same noise.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

#: Noise models :func:`add_noise` knows.
NOISE_MODELS: tuple[str, ...] = ("none", "gaussian", "sensor")


@dataclass(frozen=True)
class NoiseModel:
    """Parameters of the depth noise; lengths in metres.

    Attributes
    ----------
    model : {"none", "gaussian", "sensor"}
    sigma : float
        Standard deviation of the per-pixel gaussian at 0.5 m.
    correlated_sigma : float
        Standard deviation of the correlated field (``sensor`` only).
    correlated_cell : int
        Pixels per cell of the coarse grid the correlated field is drawn on.
    growth : float
        Relative growth of ``sigma`` per square metre beyond 0.5 m.
    edge_threshold : float
        3 x 3 depth range that marks an edge pixel.
    edge_hole_fraction : float
        Fraction of edge pixels that lose their reading.
    edge_sigma : float
        Extra gaussian jitter on the other edge pixels.
    hole_fraction : float
        Fraction of all pixels that lose their reading.
    """

    model: str = "gaussian"
    sigma: float = 0.002
    correlated_sigma: float = 0.002
    correlated_cell: int = 16
    growth: float = 1.0
    edge_threshold: float = 0.01
    edge_hole_fraction: float = 0.3
    edge_sigma: float = 0.005
    hole_fraction: float = 0.002

    def __post_init__(self) -> None:
        if self.model not in NOISE_MODELS:
            raise ValueError(f"unknown noise model {self.model!r}; choose one of {list(NOISE_MODELS)}")
        if self.correlated_cell < 1:
            raise ValueError("correlated_cell must be at least 1 pixel")


def edge_pixels(depth: np.ndarray, threshold: float) -> np.ndarray:
    """Pixels whose 3 x 3 neighbourhood spans more than ``threshold`` metres.

    Parameters
    ----------
    depth : (H, W) float
        Metres.

    Returns
    -------
    (H, W) bool
    """
    kernel = np.ones((3, 3), dtype=np.uint8)
    depth32 = depth.astype(np.float32)
    return (cv2.dilate(depth32, kernel) - cv2.erode(depth32, kernel)) > threshold


def add_noise(depth: np.ndarray, rng: np.random.Generator, noise: NoiseModel) -> np.ndarray:
    """A noisy copy of a clean depth map.

    Parameters
    ----------
    depth : (H, W) float
        Clean depth, metres, 0 = no reading.
    rng : numpy.random.Generator
    noise : NoiseModel

    Returns
    -------
    (H, W) float64
        Noisy depth, metres, 0 = no reading; never negative.
    """
    clean = np.asarray(depth, dtype=np.float64)
    valid = clean > 0
    if noise.model == "none":
        return clean.copy()
    height, width = clean.shape
    if noise.model == "gaussian":
        noisy = clean + rng.normal(0.0, noise.sigma, size=clean.shape)
        return np.where(valid, np.maximum(noisy, 0.0), 0.0)

    spread = noise.sigma * (1.0 + noise.growth * np.square(np.maximum(clean - 0.5, 0.0)))
    noisy = clean + rng.normal(0.0, 1.0, size=clean.shape) * spread
    coarse_shape = (height // noise.correlated_cell + 2, width // noise.correlated_cell + 2)
    coarse = rng.normal(0.0, noise.correlated_sigma, size=coarse_shape).astype(np.float32)
    noisy += cv2.resize(coarse, (width, height), interpolation=cv2.INTER_LINEAR)
    edges = edge_pixels(clean, noise.edge_threshold)
    edge_draw = rng.random(size=clean.shape)
    edge_jitter = rng.normal(0.0, noise.edge_sigma, size=clean.shape)
    noisy = np.where(edges, noisy + edge_jitter, noisy)
    holes = (edges & (edge_draw < noise.edge_hole_fraction)) | (rng.random(size=clean.shape) < noise.hole_fraction)
    return np.where(valid & ~holes, np.maximum(noisy, 0.0), 0.0)
