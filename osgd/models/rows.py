"""``models`` rows as numpy arrays, for the stages that load meshes into physics or a renderer.

``Table.to_pylist()`` turns every vertex of every mesh and convex part into
Python floats, which is slow for the authors' models (up to ~50k vertices
each). :func:`model_rows` reads the
same rows with the mesh columns as numpy arrays, straight from the Arrow
buffers, and leaves out the columns those stages never read.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterable, Iterator
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from osgd.contract.shards import ShardError
from osgd.store import ShardStore

#: The ``models`` columns a physics body or a rendering needs (``osgd.physics.create_object_body``,
#: ``osgd.samples.renderer.RenderObject``).
BODY_COLUMNS = ("model_id", "category", "vertices", "faces", "convex_parts", "decomposition", "mass", "center_of_mass",
                "inertia", "friction")

#: The columns of ``BODY_COLUMNS`` that :func:`model_rows` turns into arrays; the rest stay Python values.
ARRAY_COLUMNS = ("vertices", "faces", "convex_parts")


def nested_rows(array: pa.Array, width: int, dtype: type) -> list[np.ndarray]:
    """Each row of a ``list<list<number>[width]>`` array as an ``(n, width)`` array.

    Parameters
    ----------
    array : pyarrow ListArray (or ChunkedArray) of fixed-size lists
    width : int
        Numbers per inner list (3 for vertices and faces).
    dtype : numpy type

    Returns
    -------
    list of (n_i, width) arrays
        Views of one array per call: rows share its memory.
    """
    if isinstance(array, pa.ChunkedArray):
        array = array.combine_chunks()
    offsets = array.offsets.to_numpy()
    inner = array.values  # the whole child: the offsets index into it even when ``array`` is a slice
    if isinstance(inner, pa.FixedSizeListArray):
        inner = inner.flatten()
    values = inner.to_numpy(zero_copy_only=False).astype(dtype, copy=False)
    if len(values) % width:
        raise ValueError(f"{len(values)} numbers do not make rows of {width}")
    values = values.reshape(-1, width)
    return [values[start:stop] for start, stop in itertools.pairwise(offsets)]


def _convex_parts(column: pa.ChunkedArray) -> list[list[dict[str, np.ndarray]]]:
    """``convex_parts`` of each row: a list of ``{"vertices": (V, 3) float64, "faces": (F, 3) int64}``."""
    parts = column.combine_chunks()
    offsets = parts.offsets.to_numpy()
    structs = parts.values
    vertices = nested_rows(structs.field("vertices"), 3, np.float64)
    faces = nested_rows(structs.field("faces"), 3, np.int64)
    start = structs.offset  # field() ignores a sliced struct's offset
    return [
        [{"vertices": vertices[start + index], "faces": faces[start + index]} for index in range(low, high)]
        for low, high in itertools.pairwise(offsets)
    ]


def model_rows(table: pa.Table, model_ids: Iterable[str] | None = None) -> dict[str, dict[str, Any]]:
    """The rows of a ``models`` table by model id, mesh columns as numpy arrays.

    Parameters
    ----------
    table : pyarrow.Table
        ``models`` rows with at least :data:`BODY_COLUMNS`.
    model_ids : iterable of str, optional
        Keep only these models.

    Returns
    -------
    dict of model id to dict
        ``vertices`` (V, 3) float64, ``faces`` (F, 3) int64, ``convex_parts``
        (list of dicts of ``vertices`` and ``faces`` arrays), ``mass``,
        ``center_of_mass`` (3,), ``inertia`` (9,), ``friction`` (3,), plus
        ``model_id``, ``category`` and ``decomposition`` (which names the
        convex parts, :func:`osgd.physics.create_object_body`). The other
        columns are left out.
    """
    table = table.select(list(BODY_COLUMNS))
    if model_ids is not None:
        wanted = pa.array(sorted(set(model_ids)), type=pa.string())
        table = table.filter(pc.is_in(table["model_id"], value_set=wanted))
    scalars = table.select([column for column in BODY_COLUMNS if column not in ARRAY_COLUMNS]).to_pylist()
    vertices = nested_rows(table["vertices"], 3, np.float64)
    faces = nested_rows(table["faces"], 3, np.int64)
    convex_parts = _convex_parts(table["convex_parts"])
    rows = {}
    for index, row in enumerate(scalars):
        row.update(vertices=vertices[index], faces=faces[index], convex_parts=convex_parts[index])
        rows[row["model_id"]] = row
    return rows


def model_tables(store: ShardStore, columns: list[str] | None = None) -> Iterator[tuple[str, pa.Table]]:
    """(key, table) of every verified, non-empty shard of the ``models`` table; shards failing their checks
    are passed over."""
    for key in store.keys_on_disk("models"):
        try:
            table = store.read("models", key, columns=columns)
        except ShardError:
            continue
        if table.num_rows:
            yield key, table


def find_model(store: ShardStore, model: str) -> pa.Table:
    """The ``models`` row whose ``model_id`` or ``name`` (``osgd/hammer_001``, ``user/drill``) is ``model``.

    Returns
    -------
    pa.Table
        One row, every column.

    Raises
    ------
    KeyError
        No verified shard holds it; the message names a few of the models there.
    """
    names: list[str] = []
    for key, index in model_tables(store, ["model_id", "name"]):
        rows = zip(index.column("model_id").to_pylist(), index.column("name").to_pylist(), strict=True)
        for row, identity_and_name in enumerate(rows):
            if model in identity_and_name:
                return store.read("models", key).slice(row, 1)
        names += index.column("name").to_pylist()
    listed = ", ".join(sorted(names)[:5]) + (", ..." if len(names) > 5 else "")
    there = f" (models there: {listed})" if names else ""
    raise KeyError(f"no model with id or name {model!r} in {store.root / 'models'}{there}")
