"""The golden pipeline rebuilds to the committed record.

``data/manifests/golden.json`` records the key, row count and sha256 of every
shard of ``pipelines/golden.toml``, and ``data/golden/<table>/<key>.parquet``
holds the shards themselves (under 1 MB). A rebuild must give the same keys,
parameters and row counts, and each shard either the same bytes or, where the
processor rounds differently from the one that recorded them, the same
content: identical ids, labels, flags and encodings, floats within 1e-6
(absolute and relative), depth images within 1 mm on all but 0.1 % of their
pixels. Anything else is drift: if it is intended, ``make golden-update``
rewrites the record, and ``git diff`` shows it.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from osgd.samples.encoding import decode_depth, decode_mask

ROOT = Path(__file__).resolve().parents[1]
COMMITTED = ROOT / "data" / "manifests" / "golden.json"
GOLDEN_SHARDS = ROOT / "data" / "golden"

#: Float columns: |a - b| <= ABSOLUTE + RELATIVE * |b|.
ABSOLUTE, RELATIVE = 1e-6, 1e-6
#: Image columns: the share of pixels that may differ (beyond 1 mm for depth).
IMAGE_PIXEL_SHARE = 1e-3
DEPTH_COLUMNS = ("depth", "depth_clean")
MASK_COLUMNS = ("mask",)


def _same_image(column: str, expected: bytes, actual: bytes) -> str | None:
    if column in DEPTH_COLUMNS:
        a, b = decode_depth(expected), decode_depth(actual)
        tolerance = 0.0011  # metres: one millimetre step of the 16-bit PNG
    else:
        a, b = decode_mask(expected), decode_mask(actual)
        tolerance = 0
    if a.shape != b.shape:
        return f"image shape {a.shape} != {b.shape}"
    share = float(np.mean(np.abs(a.astype(np.float64) - b.astype(np.float64)) > tolerance))
    return None if share <= IMAGE_PIXEL_SHARE else f"{share:.2%} of the pixels differ"


def _same_value(expected: object, actual: object) -> bool:
    if isinstance(expected, float) and isinstance(actual, float):
        if math.isnan(expected) or math.isnan(actual):
            return math.isnan(expected) and math.isnan(actual)
        return abs(expected - actual) <= ABSOLUTE + RELATIVE * abs(expected)
    if isinstance(expected, dict) and isinstance(actual, dict):
        return expected.keys() == actual.keys() and all(_same_value(expected[k], actual[k]) for k in expected)
    if isinstance(expected, list) and isinstance(actual, list):
        return len(expected) == len(actual) and all(map(_same_value, expected, actual))
    return expected == actual


def content_differences(expected_path: Path, actual_path: Path) -> list[str]:
    """What differs between two shards beyond the rounding of another processor."""
    expected, actual = pq.read_table(expected_path), pq.read_table(actual_path)
    if expected.schema != actual.schema:
        return [f"schema differs: {expected.schema} != {actual.schema}"]
    if expected.num_rows != actual.num_rows:
        return [f"{actual.num_rows} rows, expected {expected.num_rows}"]
    differences = []
    for name in expected.column_names:
        for row, (a, b) in enumerate(zip(expected[name].to_pylist(), actual[name].to_pylist(), strict=True)):
            if name in DEPTH_COLUMNS + MASK_COLUMNS:
                problem = _same_image(name, a, b)
            else:
                problem = None if _same_value(a, b) else f"{str(b)[:120]} != expected {str(a)[:120]}"
            if problem:
                differences.append(f"column {name!r}, row {row}: {problem}")
    return differences


def test_golden_pipeline_reproduces_the_committed_record(tmp_path: Path) -> None:
    environment = {**os.environ, "PYTHONHASHSEED": "0"}
    result = subprocess.run(
        [sys.executable, "-m", "osgd", "--data-dir", str(tmp_path), "--workers", "2", "run",
         str(ROOT / "pipelines" / "golden.toml")],
        capture_output=True, text=True, env=environment, check=False,
    )
    assert result.returncode == 0, result.stdout + result.stderr
    built = json.loads((tmp_path / "manifests" / "golden.json").read_text())
    committed = json.loads(COMMITTED.read_text())
    assert built.keys() == committed.keys()
    assert built["stages"].keys() == committed["stages"].keys()
    rounded_differently = []
    for stage, entry in committed["stages"].items():
        got = built["stages"][stage]
        assert got["params"] == entry["params"], f"{stage}: parameters differ from the committed run"
        layout = [(shard["item"], shard["key"], shard["rows"]) for shard in got["shards"]]
        expected_layout = [(shard["item"], shard["key"], shard["rows"]) for shard in entry["shards"]]
        assert layout == expected_layout, (
            f"{stage}: shard keys or row counts differ from data/manifests/golden.json; if the change is "
            f"intended, run `make golden-update` and commit data/manifests/golden.json and data/golden/"
        )
        table = stage  # every stage writes the table of its name
        for shard, expected in zip(got["shards"], entry["shards"], strict=True):
            if shard["sha256"] == expected["sha256"]:
                continue
            reference = GOLDEN_SHARDS / table / f"{expected['key']}.parquet"
            assert reference.is_file(), f"{reference} is missing: run `make golden-update`"
            assert hashlib.sha256(reference.read_bytes()).hexdigest() == expected["sha256"], (
                f"{reference} does not match data/manifests/golden.json"
            )
            differences = content_differences(reference, tmp_path / table / f"{shard['key']}.parquet")
            assert not differences, f"{stage} {shard['item']}:\n" + "\n".join(differences[:10])
            rounded_differently.append(f"{stage}/{shard['item']}")
    if rounded_differently:
        # Same content within rounding, other bytes: reported, not a failure.
        print("same content, other bytes (this processor rounds differently):", ", ".join(rounded_differently))


def test_content_comparison_catches_a_changed_value(tmp_path: Path) -> None:
    """The fallback comparison is not blind: a changed grasp width is drift."""
    committed = json.loads(COMMITTED.read_text())
    shard = committed["stages"]["grasps"]["shards"][0]
    reference = GOLDEN_SHARDS / "grasps" / f"{shard['key']}.parquet"
    if not reference.is_file():
        pytest.skip(f"{reference} is missing: run `make golden-update`")
    table = pq.read_table(reference)
    assert content_differences(reference, reference) == []
    widths = table["width"].to_numpy()
    for change, expect_drift in ((1e-9, False), (1e-4, True)):
        changed = table.set_column(table.schema.get_field_index("width"), "width",
                                   [widths + change]).cast(table.schema)
        path = tmp_path / f"changed-{change}.parquet"
        pq.write_table(changed, path)
        assert bool(content_differences(reference, path)) is expect_drift
