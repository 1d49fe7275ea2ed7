"""The read side of the shard store: find, verify and read finished shards.

A shard is one Parquet file, ``<data_dir>/<table>/<key>.parquet``, with a
checksum file beside it, ``<key>.sha256``, recording the sha256 of its
bytes, its key and its row count; a pipeline's manifest,
``<data_dir>/manifests/<pipeline>.json``, lists the shards of each stage.
The generator writes them (:class:`osgd.store.ShardStore`, which adds
writing, locks and manifests to :class:`ShardReader`); a reader of the data
needs only this module, which imports nothing but pyarrow.
"""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.parquet as pq

from osgd.contract.files import Location, data_files
from osgd.contract.schemas import TABLES


class ShardError(RuntimeError):
    """A shard is missing, unreadable, fails its checksum or holds another key."""


@dataclass(frozen=True)
class ShardRecord:
    """What the store knows of one finished shard.

    Attributes
    ----------
    table : str
    key : str
    item_id : str
    rows : int
    sha256 : str
        sha256 of the Parquet file's bytes.
    """

    table: str
    key: str
    item_id: str
    rows: int
    sha256: str

    def as_dict(self) -> dict[str, Any]:
        return {"item": self.item_id, "key": self.key, "rows": self.rows, "sha256": self.sha256}


def file_sha256(path: Path) -> str:
    """sha256 of a file's bytes, hex."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def stored_key(path: Path | pa.BufferReader, name: str | None = None) -> str:
    """The key a shard file holds in its metadata (``osgd.key``); empty when it has none.

    Parameters
    ----------
    path : path or pyarrow.BufferReader
        The file, or its bytes.
    name : str, optional
        What to call it in an error (default: ``path``).

    Raises
    ------
    ShardError
        If the file is not readable Parquet.
    """
    try:
        metadata = pq.read_schema(path).metadata or {}
    except (OSError, pa.ArrowException) as error:
        raise ShardError(f"{name or path}: unreadable Parquet ({error})") from error
    return metadata.get(b"osgd.key", b"").decode("utf-8", "replace")


class ShardReader:
    """Finished shards of every table under one data dir, read-only.

    Parameters
    ----------
    root : path
        The data dir.
    """

    def __init__(self, root: str | os.PathLike[str]) -> None:
        self.files = data_files(root)
        #: The data dir: a :class:`~pathlib.Path`, or an :class:`~osgd.contract.files.ObjectUri` for an object store.
        self.root: Location = self.files.root

    # -- paths -------------------------------------------------------------
    def shard_path(self, table: str, key: str) -> Location:
        """``<root>/<table>/<key>.parquet``."""
        return self.files.location(f"{table}/{key}.parquet")

    def checksum_path(self, table: str, key: str) -> Location:
        """``<root>/<table>/<key>.sha256``: the recorded checksum and row count."""
        return self.files.location(f"{table}/{key}.sha256")

    def manifest_path(self, pipeline: str) -> Location:
        """``<root>/manifests/<pipeline>.json``."""
        return self.files.location(f"manifests/{pipeline}.json")

    def shard_exists(self, table: str, key: str) -> bool:
        """Whether a shard's Parquet file exists (complete or not)."""
        return self.files.exists(f"{table}/{key}.parquet")

    def _content(self, table: str, key: str) -> tuple[str, Path | bytes]:
        """The sha256 of a shard's bytes, and the file (in a folder) or its bytes (in an object store)."""
        if not self.files.remote:
            path = self.shard_path(table, key)
            return file_sha256(path), path
        data = self.files.read_bytes(f"{table}/{key}.parquet")
        return hashlib.sha256(data).hexdigest(), data

    # -- reading and verifying ---------------------------------------------
    def verify(self, table: str, key: str, expected_sha256: str | None = None) -> ShardRecord:
        """Check that a shard is complete and intact (see :meth:`_verified`).

        Raises
        ------
        ShardError
            Naming the file and what is wrong with it.
        """
        return self._verified(table, key, expected_sha256)[0]

    def _verified(self, table: str, key: str, expected_sha256: str | None = None
                  ) -> tuple[ShardRecord, Path | pa.BufferReader]:
        """Check that a shard is complete and intact.

        Parameters
        ----------
        expected_sha256 : str, optional
            The checksum a manifest recorded; when given it must agree too.

        Raises
        ------
        ShardError
            Naming the file and what is wrong with it.
        """
        path = self.shard_path(table, key)
        checksum_path = self.checksum_path(table, key)
        if not self.shard_exists(table, key):
            raise ShardError(f"{path}: missing")
        try:
            record = json.loads(self.files.read_bytes(f"{table}/{key}.sha256"))
            recorded, rows, item_id = str(record["sha256"]), int(record["rows"]), str(record["item"])
        except FileNotFoundError as error:
            raise ShardError(f"{path}: no checksum file (the write was interrupted)") from error
        except (ValueError, KeyError, TypeError) as error:
            raise ShardError(f"{checksum_path}: unreadable checksum file ({error})") from error
        recorded_key = str(record.get("key", key))
        if recorded_key != key:
            raise ShardError(f"{checksum_path}: the checksum file of shard {recorded_key[:12]}, not of {key[:12]}")
        try:
            actual, content = self._content(table, key)
        except FileNotFoundError as error:
            raise ShardError(f"{path}: missing") from error
        if actual != recorded:
            raise ShardError(f"{path}: checksum {actual[:12]} disagrees with recorded {recorded[:12]}")
        if expected_sha256 is not None and actual != expected_sha256:
            raise ShardError(f"{path}: checksum {actual[:12]} disagrees with the manifest's {expected_sha256[:12]}")
        source = content if isinstance(content, Path) else pa.BufferReader(content)
        stored = stored_key(source, str(path))
        if stored != key:
            raise ShardError(f"{path}: holds the shard of key {stored[:12] or '(none)'}, not of its file name")
        return ShardRecord(table, key, item_id, rows, actual), source

    def is_done(self, table: str, key: str, expected_sha256: str | None = None) -> bool:
        """Whether :meth:`verify` passes."""
        try:
            self.verify(table, key, expected_sha256)
        except ShardError:
            return False
        return True

    def read(self, table: str, key: str, columns: Sequence[str] | None = None) -> pa.Table:
        """Read one shard (after verifying it).

        Raises
        ------
        ShardError
            If the shard is missing, incomplete or corrupt.
        """
        _, source = self._verified(table, key)  # read once: an object store's bytes serve both
        path = self.shard_path(table, key)
        try:
            return pq.read_table(source, columns=list(columns) if columns else None)
        except (OSError, pa.ArrowException) as error:
            raise ShardError(f"{path}: unreadable Parquet ({error})") from error

    def read_many(self, table: str, keys: Sequence[str], columns: Sequence[str] | None = None) -> pa.Table:
        """Concatenate several shards of one table, in the given order."""
        parts = [self.read(table, key, columns) for key in keys]
        if not parts:
            schema = TABLES[table]
            if columns:
                schema = pa.schema([schema.field(name) for name in columns])
            return schema.empty_table()
        return pa.concat_tables(parts)

    def keys_on_disk(self, table: str) -> list[str]:
        """Keys of every shard file present for ``table``, sorted."""
        return self.files.names(table, ".parquet")

    # -- manifests ---------------------------------------------------------
    def read_manifest(self, pipeline: str) -> dict[str, Any] | None:
        """The pipeline's manifest, or None when there is none or it is unreadable."""
        try:
            return json.loads(self.files.read_bytes(f"manifests/{pipeline}.json"))
        except (FileNotFoundError, ValueError):
            return None
