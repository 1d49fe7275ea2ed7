"""The samples' PNG encodings: time and size per sample, one setting for every image against today's.

Reads the first ``--samples`` samples of a built pipeline (its manifest in
the data dir), decodes their noisy depth, clean depth and mask, and encodes
each image kind with zlib level 3 and libpng's adaptive row filters (one
setting for every image) and with today's setting per kind
(:mod:`osgd.contract.encoding`), in this process, in turn, ``--repeats`` times;
prints the best time per sample and the mean size of each, and checks that
both decode to the same arrays.

    python benchmarks/bench_png.py --data-dir DATA --pipeline osgd [--samples 100] [--repeats 3]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import cv2
import numpy as np
import pyarrow.parquet as pq

from osgd.contract.encoding import CLEAN_DEPTH_PNG_PARAMS, DEPTH_PNG_PARAMS, MASK_PNG_PARAMS

#: The one setting of every image before (zlib level 3, libpng's adaptive row filters).
BEFORE = (cv2.IMWRITE_PNG_COMPRESSION, 3)
KINDS = {"depth": DEPTH_PNG_PARAMS, "depth_clean": CLEAN_DEPTH_PNG_PARAMS, "mask": MASK_PNG_PARAMS}


def read_images(data_dir: Path, pipeline: str, count: int) -> dict[str, list[np.ndarray]]:
    """The first ``count`` samples' images of the pipeline's manifest, decoded, by column."""
    manifest = json.loads((data_dir / "manifests" / f"{pipeline}.json").read_text())
    images: dict[str, list[np.ndarray]] = {kind: [] for kind in KINDS}
    for shard in manifest["stages"]["samples"]["shards"]:
        table = pq.read_table(data_dir / "samples" / f"{shard['key']}.parquet", columns=list(KINDS))
        for kind in KINDS:
            images[kind].extend(cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
                                for data in table[kind].to_pylist())
        if len(images["mask"]) >= count:
            break
    return {kind: arrays[:count] for kind, arrays in images.items()}


def encode_all(arrays: list[np.ndarray], params: tuple[int, ...]) -> tuple[float, list[bytes]]:
    """Seconds to encode every array once, and the encodings."""
    start = time.perf_counter()
    encoded = [cv2.imencode(".png", array, list(params))[1].tobytes() for array in arrays]
    return time.perf_counter() - start, encoded


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data-dir", type=Path, default=Path("data"))
    parser.add_argument("--pipeline", default="osgd", help="the manifest to read samples from")
    parser.add_argument("--samples", type=int, default=100)
    parser.add_argument("--repeats", type=int, default=3, help="best of this many passes")
    arguments = parser.parse_args()
    images = read_images(arguments.data_dir, arguments.pipeline, arguments.samples)
    count = len(images["mask"])
    height, width = images["mask"][0].shape
    print(f"{count} samples of {arguments.pipeline} ({height} x {width}), best of {arguments.repeats} passes:")
    print(f"  {'image':12s} {'before ms':>9s} {'KiB':>6s} {'today ms':>9s} {'KiB':>6s}")
    totals = np.zeros(2)
    for kind, params in KINDS.items():
        seconds, kibibytes = np.full(2, np.inf), np.zeros(2)
        for _ in range(arguments.repeats):
            for column, setting in enumerate((BEFORE, params)):
                elapsed, encoded = encode_all(images[kind], setting)
                seconds[column] = min(seconds[column], elapsed)
                kibibytes[column] = sum(map(len, encoded)) / count / 1024
                for array, data in zip(images[kind], encoded, strict=True):
                    if not np.array_equal(cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED), array):
                        raise SystemExit(f"{kind}: an encoding does not decode to its image")
        totals += seconds
        print(f"  {kind:12s} {1000 * seconds[0] / count:9.2f} {kibibytes[0]:6.1f} "
              f"{1000 * seconds[1] / count:9.2f} {kibibytes[1]:6.1f}")
    print(f"  {'per sample':12s} {1000 * totals[0] / count:9.2f} {'':6s} {1000 * totals[1] / count:9.2f}"
          f"   ({totals[0] / totals[1]:.2f}x)")


if __name__ == "__main__":
    main()
