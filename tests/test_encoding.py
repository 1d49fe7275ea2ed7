"""The samples' PNG encodings: lossless, deterministic, and written with the settings they name."""

from __future__ import annotations

import json
import struct
import zlib
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
import pyarrow.parquet as pq
import pytest

from osgd.contract.encoding import (
    CLEAN_DEPTH_PNG_PARAMS,
    DEPTH_PNG_PARAMS,
    MASK_PNG_PARAMS,
    decode_depth,
    decode_mask,
    encode_depth,
    encode_mask,
)

ROOT = Path(__file__).resolve().parents[1]

#: PNG's per-row filter types (PNG specification, section 9.2).
FILTER_NONE, FILTER_UP = 0, 2


def png_rows(data: bytes) -> tuple[int, int, list[bytes]]:
    """Width, bytes per pixel and the filtered rows (filter byte first) of a greyscale PNG."""
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    position, idat, header = 8, b"", b""
    while position < len(data):
        (length,) = struct.unpack(">I", data[position:position + 4])
        kind, body = data[position + 4:position + 8], data[position + 8:position + 8 + length]
        header = body if kind == b"IHDR" else header
        idat += body if kind == b"IDAT" else b""
        position += 12 + length
    width, height, bit_depth, colour_type = struct.unpack(">IIBB", header[:10])
    assert colour_type == 0, "greyscale"
    pixel = bit_depth // 8
    raw = zlib.decompress(idat)
    stride = 1 + width * pixel
    assert len(raw) == height * stride
    return width, pixel, [raw[row * stride:(row + 1) * stride] for row in range(height)]


def noisy_depth(seed: int = 0, shape: tuple[int, int] = (48, 64)) -> np.ndarray:
    """A table at 0.6 m with a raised block and sensor-like noise, and a few holes, metres."""
    rng = np.random.default_rng(seed)
    depth = 0.6 + rng.normal(0.0, 0.002, shape)
    depth[10:30, 20:40] -= 0.03
    depth[rng.random(shape) < 0.02] = 0.0
    return depth


def test_depth_round_trips_to_the_millimetre_with_both_settings() -> None:
    depth = noisy_depth()
    depth[0, 0], depth[0, 1], depth[0, 2] = np.nan, -1.0, 65.535
    expected = np.where(np.isfinite(depth) & (depth > 0), np.rint(np.nan_to_num(depth) * 1000.0), 0.0) / 1000.0
    for params in (DEPTH_PNG_PARAMS, CLEAN_DEPTH_PNG_PARAMS):
        decoded = decode_depth(encode_depth(depth, params))
        assert decoded.dtype == np.float32 and decoded.shape == depth.shape
        np.testing.assert_array_equal(decoded, expected.astype(np.float32))


def test_mask_round_trips_exactly() -> None:
    mask = np.zeros((40, 50), dtype=np.int64)
    mask[5:20, 5:30], mask[18:35, 25:45], mask[39, 49] = 1, 2, 255
    np.testing.assert_array_equal(decode_mask(encode_mask(mask)), mask.astype(np.uint8))
    with pytest.raises(ValueError, match=r"0\.\.255"):
        encode_mask(mask + 1)


def test_the_same_image_gives_the_same_bytes() -> None:
    assert encode_depth(noisy_depth(3)) == encode_depth(noisy_depth(3))
    assert encode_depth(noisy_depth(3)) != encode_depth(noisy_depth(4))


@pytest.mark.parametrize(("encode", "row_filter", "pixel"), [
    (lambda: encode_depth(noisy_depth()), FILTER_UP, 2),
    (lambda: encode_depth(noisy_depth(), CLEAN_DEPTH_PNG_PARAMS), FILTER_NONE, 2),
    (lambda: encode_mask((noisy_depth() < 0.59).astype(np.uint8)), FILTER_NONE, 1),
])
def test_each_image_kind_is_written_with_its_row_filter(encode: Callable[[], bytes], row_filter: int,
                                                        pixel: int) -> None:
    """The writer applies the settings (an OpenCV without the row-filter key would pick filters per row)."""
    width, bytes_per_pixel, rows = png_rows(encode())
    assert (width, bytes_per_pixel) == (64, pixel)
    assert {row[0] for row in rows} == {row_filter}


@pytest.mark.parametrize(("params", "image"), [
    (DEPTH_PNG_PARAMS, lambda: np.rint(noisy_depth() * 1000).astype(np.uint16)),
    (MASK_PNG_PARAMS, lambda: (noisy_depth() < 0.59).astype(np.uint8)),
])
def test_the_zlib_strategy_takes_effect(params: tuple[int, ...], image: Callable[[], np.ndarray]) -> None:
    """OpenCV resets the strategy when it reads the compression level, so the level must come first."""
    assert params.index(cv2.IMWRITE_PNG_COMPRESSION) < params.index(cv2.IMWRITE_PNG_STRATEGY)
    strategy = params.index(cv2.IMWRITE_PNG_STRATEGY)
    without = params[:strategy] + params[strategy + 2:]
    with_strategy, without_strategy = (cv2.imencode(".png", image(), list(setting))[1].tobytes()
                                       for setting in (params, without))
    assert with_strategy != without_strategy


def test_the_committed_golden_samples_carry_each_kind_s_row_filter() -> None:
    """The samples stage writes each column with its kind's settings (the golden record, rebuilt by the stage)."""
    manifest = json.loads((ROOT / "data" / "manifests" / "golden.json").read_text())
    expected = {"depth": FILTER_UP, "depth_clean": FILTER_NONE, "mask": FILTER_NONE}
    shards = manifest["stages"]["samples"]["shards"]
    assert shards
    for shard in shards:
        table = pq.read_table(ROOT / "data" / "golden" / "samples" / f"{shard['key']}.parquet", columns=list(expected))
        for column, row_filter in expected.items():
            for data in table[column].to_pylist():
                assert {row[0] for row in png_rows(data)[2]} == {row_filter}, column
