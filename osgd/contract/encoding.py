"""Lossless image encodings of the ``samples`` table.

- depth: 16-bit PNG of millimetres (uint16), 0 = no reading; resolution 1 mm,
  range up to 65.535 m;
- instance mask: 8-bit PNG, 0 = background, ``object_index + 1`` elsewhere.

PNG through OpenCV is lossless and deterministic for the same array and
encoder settings, so shards stay byte-identical across runs. The settings
are chosen per image kind for speed at about the same size
(``benchmarks/bench_png.py``): any PNG decoder reads the same arrays.
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np

#: Noisy depth: rows predicted from the row above, entropy-coded only (LZ77
#: finds no repeats in sensor noise): faster than zlib level 3 with adaptive
#: filters, at the same size.
DEPTH_PNG_PARAMS = (cv2.IMWRITE_PNG_COMPRESSION, 1, cv2.IMWRITE_PNG_STRATEGY, cv2.IMWRITE_PNG_STRATEGY_HUFFMAN_ONLY,
                    cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_UP)
#: Clean depth (flat table, smooth objects): zlib level 3 without row filters.
CLEAN_DEPTH_PNG_PARAMS = (cv2.IMWRITE_PNG_COMPRESSION, 3, cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_NONE)
#: Instance masks (long runs of one value): run-length matching, no row filters.
MASK_PNG_PARAMS = (cv2.IMWRITE_PNG_COMPRESSION, 3, cv2.IMWRITE_PNG_STRATEGY, cv2.IMWRITE_PNG_STRATEGY_RLE,
                   cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_NONE)


def encode_depth(depth_m: np.ndarray, params: Sequence[int] = DEPTH_PNG_PARAMS) -> bytes:
    """Encode a depth map as a 16-bit PNG of millimetres.

    Parameters
    ----------
    depth_m : (H, W) float
        Depth in metres; non-finite or non-positive values mean no reading.
    params : sequence of int
        OpenCV's PNG writer settings: :data:`DEPTH_PNG_PARAMS` for noisy
        depth, :data:`CLEAN_DEPTH_PNG_PARAMS` for noiseless.

    Returns
    -------
    bytes
    """
    depth = np.asarray(depth_m, dtype=np.float64)
    millimetres = np.where(np.isfinite(depth) & (depth > 0), np.rint(depth * 1000.0), 0.0)
    ok, data = cv2.imencode(".png", np.clip(millimetres, 0, 65535).astype(np.uint16), list(params))
    if not ok:
        raise ValueError("OpenCV could not encode the depth map as PNG")
    return data.tobytes()


def decode_depth(data: bytes) -> np.ndarray:
    """Decode :func:`encode_depth` bytes.

    Returns
    -------
    (H, W) float32
        Depth in metres, 0 where there is no reading.
    """
    image = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
    if image is None or image.dtype != np.uint16 or image.ndim != 2:
        raise ValueError("not a single-channel 16-bit PNG depth map")
    return image.astype(np.float32) / 1000.0


def encode_mask(mask: np.ndarray) -> bytes:
    """Encode an instance mask (H, W) of integers 0..255 as an 8-bit PNG."""
    mask = np.asarray(mask)
    if mask.size and (mask.min() < 0 or mask.max() > 255):
        raise ValueError("instance mask values must lie in 0..255 (at most 255 objects)")
    ok, data = cv2.imencode(".png", mask.astype(np.uint8), list(MASK_PNG_PARAMS))
    if not ok:
        raise ValueError("OpenCV could not encode the mask as PNG")
    return data.tobytes()


def decode_mask(data: bytes) -> np.ndarray:
    """Decode :func:`encode_mask` bytes to an (H, W) uint8 array."""
    image = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
    if image is None or image.dtype != np.uint8 or image.ndim != 2:
        raise ValueError("not a single-channel 8-bit PNG mask")
    return image
