"""``osgd.models.rows``: models rows with numpy meshes, the same values as ``to_pylist``."""

from __future__ import annotations

import numpy as np
import pyarrow as pa
from helpers import fixture_models

from osgd.contract.schemas import MODELS
from osgd.models.rows import BODY_COLUMNS, model_rows


def _assert_same_row(fast: dict, slow: dict) -> None:
    assert set(fast) == set(BODY_COLUMNS)
    np.testing.assert_array_equal(fast["vertices"], np.asarray(slow["vertices"], dtype=np.float64))
    np.testing.assert_array_equal(fast["faces"], np.asarray(slow["faces"], dtype=np.int64))
    assert fast["vertices"].shape[1] == 3 and fast["faces"].dtype == np.int64
    assert len(fast["convex_parts"]) == len(slow["convex_parts"]) > 0
    for fast_part, slow_part in zip(fast["convex_parts"], slow["convex_parts"], strict=True):
        np.testing.assert_array_equal(fast_part["vertices"], np.asarray(slow_part["vertices"]))
        np.testing.assert_array_equal(fast_part["faces"], np.asarray(slow_part["faces"]))
    for column in ("model_id", "category", "mass", "center_of_mass", "inertia", "friction"):
        assert fast[column] == slow[column], column


def test_model_rows_match_to_pylist_also_for_slices_and_chunks() -> None:
    table = pa.Table.from_pylist(fixture_models(), schema=MODELS)
    chunked = pa.concat_tables([table.slice(0, 1), table.slice(1)])  # two chunks, the second a slice
    for source in (table, chunked, table.slice(1, 2)):
        slow = {row["model_id"]: row for row in source.to_pylist()}
        fast = model_rows(source)
        assert list(fast) == list(slow)
        for model_id, row in slow.items():
            _assert_same_row(fast[model_id], row)


def test_model_rows_keep_only_the_models_asked_for() -> None:
    rows = fixture_models()
    table = pa.Table.from_pylist(rows, schema=MODELS)
    wanted = {rows[2]["model_id"], rows[0]["model_id"]}
    fast = model_rows(table, wanted)
    assert set(fast) == wanted
    _assert_same_row(fast[rows[2]["model_id"]], rows[2])
