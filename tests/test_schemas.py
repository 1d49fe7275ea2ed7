"""The schemas module: codecs round-trip, docs in sync."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from osgd.contract.schemas import TABLES, schemas_markdown, vectors_from_arrow, vectors_to_arrow

DOCS = Path(__file__).resolve().parents[1] / "docs"


@given(arrays(np.float64, st.tuples(st.integers(0, 20), st.sampled_from([3, 4])),
              elements=st.floats(-1e6, 1e6, allow_nan=False)))
def test_vectors_round_trip(values: np.ndarray) -> None:
    width = values.shape[1]
    np.testing.assert_array_equal(vectors_from_arrow(vectors_to_arrow(values, width), width), values)


def test_docs_schemas_is_generated_from_the_code() -> None:
    assert (DOCS / "schemas.md").read_text() == schemas_markdown(), (
        "docs/schemas.md is out of date: run `python -m osgd.contract.schemas > docs/schemas.md`"
    )


def test_every_table_has_identity_columns_and_a_column_is_null_only_where_its_doc_says_when() -> None:
    assert set(TABLES) == {"models", "grasps", "checks", "scenes", "samples"}
    for name, schema in TABLES.items():
        assert any(field.name.endswith("_id") for field in schema), name
        for field in schema:
            doc = (field.metadata or {}).get(b"doc", b"").decode()
            assert not field.nullable or "null for" in doc, (name, field.name)
    assert [field.name for schema in TABLES.values() for field in schema if field.nullable] == ["shake_stable"]
