"""Every samples row of two builds' manifests: the same decoded images and the same other columns.

    python same_decoded.py BEFORE_DIR BEFORE_MANIFEST AFTER_DIR AFTER_MANIFEST
"""

import json
import sys
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq

from osgd.contract.encoding import decode_depth, decode_mask

DECODERS = {"depth": decode_depth, "depth_clean": decode_depth, "mask": decode_mask}


def shards(data_dir: Path, manifest: Path) -> list[tuple[str, Path]]:
    """(item, shard path) of the manifest's samples stage."""
    entries = json.loads(manifest.read_text())["stages"]["samples"]["shards"]
    return [(entry["item"], data_dir / "samples" / f"{entry['key']}.parquet") for entry in entries]


def main() -> None:
    before_dir, before_manifest, after_dir, after_manifest = map(Path, sys.argv[1:5])
    before, after = shards(before_dir, before_manifest), shards(after_dir, after_manifest)
    assert [item for item, _ in before] == [item for item, _ in after]
    rows = images = bytes_before = bytes_after = 0
    for (item, path_before), (_, path_after) in zip(before, after, strict=True):
        table_before, table_after = pq.read_table(path_before), pq.read_table(path_after)
        assert table_before.schema.names == table_after.schema.names, item
        for name in table_before.schema.names:
            column_before, column_after = table_before[name].to_pylist(), table_after[name].to_pylist()
            if name not in DECODERS:
                assert column_before == column_after, (item, name)
                continue
            for old, new in zip(column_before, column_after, strict=True):
                assert np.array_equal(DECODERS[name](old), DECODERS[name](new)), (item, name)
                bytes_before, bytes_after, images = bytes_before + len(old), bytes_after + len(new), images + 1
        rows += table_before.num_rows
    print(f"{len(before)} shards, {rows} samples: every column equal, {images} PNG images decode to the same arrays;"
          f" PNG bytes {bytes_before / 2**20:.1f} MiB before, {bytes_after / 2**20:.1f} MiB after")


if __name__ == "__main__":
    main()
