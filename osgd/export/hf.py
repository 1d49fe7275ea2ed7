"""A data dir's samples as a Hugging Face dataset folder that opens anywhere.

``osgd export --format hf OUT`` writes::

    OUT/README.md                          the dataset card: YAML header the Hub reads, then text
    OUT/osgd-manifest.json                 the manifest of the pipeline the samples came from
    OUT/data/train-00000-of-00002.parquet  the rows of each split, at most ROWS_PER_FILE per file
    OUT/data/test-00000-of-00001.parquet

``datasets.load_dataset(OUT)`` (or ``load_dataset("parquet", data_dir=OUT)``)
opens it with ``train`` and ``test`` splits (the card's ``configs`` name the
files of each split; the file names alone say it too). The columns are those
of the ``samples`` table (:data:`osgd.contract.schemas.SAMPLES`), but the
PNG columns (``depth``, ``depth_clean``, ``mask``) are ``{"bytes", "path"}``
structs that the Parquet files' ``huggingface`` metadata and the card declare
as the ``datasets`` ``Image`` feature: the same lossless PNG bytes, which a
viewer shows and ``datasets`` decodes (16-bit depth as a PIL image of mode
``I;16``: ``numpy.asarray(image)`` is uint16 millimetres). Each column's
description and units are in the Parquet field metadata (``description``),
in the ``huggingface`` metadata and in the card.

The store's ``.sha256`` side files stay beside its shards: they make a
shard's completeness and integrity checkable without a manifest
(:mod:`osgd.contract.shards`), so a reader outside osgd opens this export,
not the data dir.
"""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.parquet as pq

from osgd.contract.files import Location
from osgd.contract.samples import sample_shards, samples_vocabulary
from osgd.contract.schemas import SAMPLES, SCHEMA_VERSION
from osgd.contract.shards import ShardReader
from osgd.contract.taxonomy import vocabulary_json

#: The PNG columns written as ``datasets.Image`` features, and what decoding one gives.
IMAGE_COLUMNS: dict[str, str] = {
    "depth": "decodes to a PIL image of mode I;16: numpy.asarray(image) is uint16 millimetres",
    "depth_clean": "decodes to a PIL image of mode I;16: numpy.asarray(image) is uint16 millimetres",
    "mask": "decodes to a PIL image of mode L: numpy.asarray(image) is uint8",
}
#: The most rows in one Parquet file of the export.
ROWS_PER_FILE = 1000
#: The splits, in the order the card names them.
SPLITS = ("train", "test")
MANIFEST_FILE = "osgd-manifest.json"
_IMAGE = pa.struct([("bytes", pa.binary()), ("path", pa.string())])
_DTYPES = {
    pa.string(): "string", pa.large_string(): "large_string", pa.binary(): "binary", pa.bool_(): "bool",
    pa.int8(): "int8", pa.int16(): "int16", pa.int32(): "int32", pa.int64(): "int64",
    pa.float32(): "float32", pa.float64(): "float64",
}


def column_descriptions() -> dict[str, str]:
    """Each exported column's meaning and units (from the samples schema's ``doc`` metadata)."""
    descriptions = {}
    for field in SAMPLES:
        doc = (field.metadata or {}).get(b"doc", b"").decode()
        if field.name in IMAGE_COLUMNS:
            doc = f"{doc}; an Image feature that {IMAGE_COLUMNS[field.name]}"
        descriptions[field.name] = doc or {"scene_id": "the scene the sample was rendered from",
                                           "height": "image rows, px", "width": "image columns, px"}.get(
                                               field.name, field.name)
    return descriptions


def export_schema(vocabulary: Mapping[str, Sequence[str]] | None = None) -> pa.Schema:
    """The schema of the exported files: the samples table, PNG columns as Image structs, with descriptions;
    ``vocabulary``, the samples' (default: the schema's, Table I), in its metadata."""
    descriptions = column_descriptions()
    fields = [
        # An Image column is nullable, as datasets writes it: else it does not take the metadata's feature.
        pa.field(field.name, _IMAGE if field.name in IMAGE_COLUMNS else field.type,
                 nullable=field.nullable or field.name in IMAGE_COLUMNS,
                 metadata={"description": descriptions[field.name]})
        for field in SAMPLES
    ]
    info = {"features": {name: {"_type": "Image"} for name in IMAGE_COLUMNS},
            "description": "osgd samples; columns: " + "; ".join(f"{k}: {v}" for k, v in descriptions.items())}
    metadata = {b"huggingface": json.dumps({"info": info}).encode(),
                b"osgd.schema_version": str(SCHEMA_VERSION).encode()}
    recorded = (SAMPLES.metadata or {}).get(b"osgd.vocabulary") if vocabulary is None else vocabulary_json(vocabulary)
    if recorded:
        metadata[b"osgd.vocabulary"] = recorded
    return pa.schema(fields, metadata=metadata)


def _as_export(table: pa.Table, schema: pa.Schema) -> pa.Table:
    """A samples table with each PNG column as ``{"bytes", "path"}`` (path: ``<sample_id>_<column>.png``)."""
    table = table.select(SAMPLES.names)
    ids = table["sample_id"].to_pylist()
    columns = []
    for name in SAMPLES.names:
        column = table[name].combine_chunks()
        if name in IMAGE_COLUMNS:
            paths = pa.array([f"{sample_id}_{name}.png" for sample_id in ids], pa.string())
            column = pa.StructArray.from_arrays([column.cast(pa.binary()), paths], fields=list(_IMAGE))
        columns.append(column)
    return pa.Table.from_arrays(columns, schema=schema)


class _SplitWriter:
    """Writes the rows of each split into numbered files of at most ``ROWS_PER_FILE`` rows."""

    def __init__(self, folder: Path, schema: pa.Schema, rows_per_file: int) -> None:
        self.folder, self.schema, self.rows_per_file = folder, schema, rows_per_file
        self.pending: dict[str, list[pa.Table]] = {}
        self.files: dict[str, list[Path]] = {}
        self.rows: dict[str, int] = {}

    def add(self, split: str, table: pa.Table) -> None:
        self.pending.setdefault(split, []).append(table)
        self.rows[split] = self.rows.get(split, 0) + table.num_rows
        while sum(part.num_rows for part in self.pending[split]) >= self.rows_per_file:
            rows = pa.concat_tables(self.pending[split])
            self.pending[split] = [rows.slice(self.rows_per_file)]
            self._write(split, rows.slice(0, self.rows_per_file))

    def _write(self, split: str, table: pa.Table) -> None:
        path = self.folder / f".{split}-{len(self.files.get(split, [])):05d}.partial"
        pq.write_table(table, path, compression="zstd")
        self.files.setdefault(split, []).append(path)

    def finish(self) -> dict[str, int]:
        """Write what is left and give each file its final name; the rows per split."""
        for split, parts in self.pending.items():
            rest = pa.concat_tables(parts)
            if rest.num_rows:
                self._write(split, rest)
        for split, paths in self.files.items():
            for index, path in enumerate(paths):
                os.replace(path, self.folder / f"{split}-{index:05d}-of-{len(paths):05d}.parquet")
        order = [split for split in SPLITS if split in self.rows] + sorted(set(self.rows) - set(SPLITS))
        return {split: self.rows[split] for split in order if self.rows[split]}


def _split_tables(paths: Sequence[Location], schema: pa.Schema) -> Iterator[tuple[str, pa.Table]]:
    """Per samples shard, its rows of each split, in the export schema."""
    for path in paths:
        table = _as_export(pq.read_table(path), schema)
        splits = table["split"].to_pylist()
        for split in sorted(set(splits)):
            keep = pa.array([value == split for value in splits])
            yield split, table.filter(keep)


def _source_manifest(store: ShardReader, pipeline: str | None) -> tuple[str | None, dict[str, Any] | None]:
    """The pipeline whose samples are exported, and its manifest (None, None when the data dir has none)."""
    names = [pipeline] if pipeline else store.files.names("manifests", ".json")
    for name in names:
        manifest = store.read_manifest(name)
        entries = (manifest or {}).get("stages", {}).get("samples", {}).get("shards", [])
        if manifest is not None and any(store.shard_exists("samples", entry["key"]) for entry in entries):
            return name, manifest
    return pipeline, None


def export_hf(store: ShardReader, out_dir: str | Path, pipeline: str | None = None,
              rows_per_file: int = ROWS_PER_FILE) -> str:
    """Write the verified samples of a data dir as a Hugging Face dataset folder (see the module's text).

    Parameters
    ----------
    store : ShardReader
    out_dir : path
        A new or empty folder.
    pipeline : str, optional
        Whose samples (the manifest's shards); default: the data dir's only pipeline with samples.

    Returns
    -------
    str
        What was written.

    Raises
    ------
    ValueError
        If ``out_dir`` is a file or a folder that is not empty.
    FileNotFoundError
        If the data dir holds no samples.
    """
    out = Path(out_dir)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise ValueError(f"{out}: {'not a folder' if not out.is_dir() else 'not empty'}; "
                         "give `osgd export --format hf` a new or empty folder")
    paths = sample_shards(store.root, pipeline)
    name, manifest = _source_manifest(store, pipeline)
    schema = export_schema(samples_vocabulary(paths))
    (out / "data").mkdir(parents=True, exist_ok=True)
    writer = _SplitWriter(out / "data", schema, rows_per_file)
    for split, table in _split_tables(paths, schema):
        writer.add(split, table)
    rows = writer.finish()
    manifest_text = json.dumps(manifest, sort_keys=True, indent=1) + "\n" if manifest is not None else ""
    if manifest_text:
        (out / MANIFEST_FILE).write_text(manifest_text)
    source = {"pipeline": name, "shards": len(paths),
              "manifest": MANIFEST_FILE if manifest_text else None,
              "manifest_sha256": hashlib.sha256(manifest_text.encode()).hexdigest() if manifest_text else None}
    (out / "README.md").write_text(dataset_card(rows, source, manifest))
    counts = ", ".join(f"{split} {count}" for split, count in rows.items())
    return (f"wrote {sum(rows.values())} samples ({counts}) to {out} as a Hugging Face dataset: "
            f"datasets.load_dataset({str(out)!r}); README.md is its card (fill in the licence before pushing)")


# -- the dataset card ---------------------------------------------------------------------------------------
def _scalar(value: Any) -> str:
    """A YAML scalar: JSON's strings, numbers, booleans and null are YAML too."""
    return json.dumps(value)


def _feature_lines(name: str | None, kind: pa.DataType, indent: str, image: bool = False) -> list[str]:
    """One entry of the card's ``dataset_info.features``, in the form ``datasets`` writes and reads."""
    head = f"{indent}- name: {name}" if name is not None else None
    inner = indent + "  "
    lines = [head] if head else []
    if image:
        return [*lines, f"{inner}dtype: image"]
    if kind in _DTYPES:
        return [*lines, f"{inner}dtype: {_DTYPES[kind]}"]
    if pa.types.is_struct(kind):
        lines.append(f"{inner}struct:")
        for child in kind:
            lines += _feature_lines(child.name, child.type, inner)
        return lines
    if pa.types.is_list(kind) or pa.types.is_fixed_size_list(kind):
        value = kind.value_type
        if value in _DTYPES:
            lines.append(f"{inner}list: {_DTYPES[value]}")
        else:
            lines.append(f"{inner}list:")
            for child in value:
                lines += _feature_lines(child.name, child.type, inner)
        if pa.types.is_fixed_size_list(kind):
            lines.append(f"{inner}length: {kind.list_size}")
        return lines
    raise ValueError(f"column {name}: no datasets feature for the Arrow type {kind}")


def card_header(rows: Mapping[str, int], source: Mapping[str, Any]) -> list[str]:
    """The YAML lines between the card's ``---`` markers."""
    splits = [split for split in SPLITS if rows.get(split)] + sorted(set(rows) - set(SPLITS))
    title = f"osgd samples ({source.get('pipeline') or 'data dir'})"
    lines = [
        "# Fill in before pushing: the licence you publish the data under, e.g. cc-by-4.0",
        "# (https://huggingface.co/docs/hub/repositories-licenses); `other` needs license_name and license_link.",
        "license: unknown",
        "license_name: null",
        "license_link: null",
        f"pretty_name: {_scalar(title)}",
        "task_categories:", "- object-detection",
        "tags:", "- robotics", "- grasping", "- depth", "- osgd",
        "configs:", "- config_name: default", "  data_files:",
    ]
    for split in splits:
        lines += [f"  - split: {split}", f"    path: data/{split}-*.parquet"]
    lines += ["dataset_info:", "  config_name: default", "  features:"]
    for field in SAMPLES:
        lines += _feature_lines(field.name, field.type, "  ", image=field.name in IMAGE_COLUMNS)
    lines.append("  splits:")
    for split in splits:
        lines += [f"  - name: {split}", f"    num_examples: {rows[split]}"]
    lines += ["osgd:", f"  schema_version: {SCHEMA_VERSION}"]
    lines += [f"  {key}: {_scalar(value)}" for key, value in source.items()]
    lines.append("  columns:")
    lines += [f"    {name}: {_scalar(text)}" for name, text in column_descriptions().items()]
    return lines


def dataset_card(rows: Mapping[str, int], source: Mapping[str, Any], manifest: Mapping[str, Any] | None) -> str:
    """The card ``README.md``: the YAML header, then how to load the data, its columns and where it came from."""
    header = card_header(rows, source)
    table = [f"| `{name}` | {text.replace('|', '/')} |" for name, text in column_descriptions().items()]
    params = (manifest or {}).get("stages", {}).get("samples", {}).get("params")
    body = [
        f"# osgd samples: {source.get('pipeline') or 'data dir'}", "",
        "Depth images of stacked objects with task-oriented grasp rectangles, rendered by the osgd generator.", "",
        "```python", "import datasets", "import numpy", "",
        'ds = datasets.load_dataset("path/to/this/folder")  # or the Hub repo id',
        'depth = numpy.asarray(ds["train"][0]["depth"])  # uint16, millimetres, 0 = no reading', "```", "",
        "## Splits", "", *[f"- `{split}`: {count} samples" for split, count in rows.items()], "",
        "## Columns", "", "Lengths in metres, angles in radians, pixel coordinates (x right, y down).", "",
        "| column | meaning |", "| --- | --- |", *table, "",
        "## Source", "",
        f"Pipeline `{source.get('pipeline')}` (seed {(manifest or {}).get('seed', 'unknown')}), "
        f"{source.get('shards')} samples shard(s); its manifest is `{MANIFEST_FILE}` "
        f"(sha256 {source.get('manifest_sha256')}), which lists every stage's parameters and shard checksums.",
    ]
    if params:
        body += ["", "Samples stage parameters:", "", "```json", json.dumps(params, sort_keys=True, indent=1), "```"]
    body += ["", "## Licence", "", "Not set: fill in `license` in the header above before publishing.", ""]
    return "---\n" + "\n".join(header) + "\n---\n\n" + "\n".join(body)
