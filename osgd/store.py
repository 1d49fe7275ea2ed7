"""The content-addressed shard store.

A shard is one Parquet file holding the rows one work item of a stage
produced. It lives at ``<data-dir>/<table>/<key>.parquet`` where ``key`` is
:func:`shard_key`: a sha256 over the stage name, the stage version, the work
item's identity and payload (the canonical JSON of every parameter the item
reads, seed included) and the sorted keys of the shards it reads. The same
inputs, parameters and code version therefore always map to the same file.

Beside each shard, ``<key>.sha256`` records the sha256 of the shard's bytes,
its key and its row count. A shard counts as done only when both files exist,
the bytes hash to the recorded value and the key stored in the shard's own
metadata is the key of its file name (a shard copied over another, checksum
file and all, is caught); anything else is rebuilt, never consumed.

The data dir is a folder, or a prefix of an object store (``s3://...``,
:mod:`osgd.contract.files`; docs/scale-out.md). In a folder, writes are
atomic: bytes go to a temporary file in the same folder, are
fsynced, then ``os.replace``-d onto the final name, so no partial file ever
carries a final name. In an object store each file is one whole upload,
there are no locks (the driver hands out each item once) and no leftovers.
In a folder, a per-shard ``fcntl`` lock keeps two processes on the
same data dir from building the same shard twice; the atomic replace keeps
them from corrupting it even without the lock. Lock files are removed as
their lock is let go, and :meth:`ShardStore.clean_leftovers` removes the
temporary and lock files of killed processes.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import hashlib
import io
import json
import os
import tempfile
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.parquet as pq

from osgd.contract.files import ObjectFiles, is_uri
from osgd.contract.schemas import SCHEMA_VERSION, TABLES
from osgd.contract.shards import ShardReader, ShardRecord

#: Parquet writer settings; fixed so identical tables give identical bytes.
_PARQUET_OPTIONS: dict[str, Any] = {
    "compression": "zstd",
    "compression_level": 3,
    "use_dictionary": True,
    "write_statistics": True,
    "version": "2.6",
}


def canonical_json(value: Any) -> str:
    """JSON with sorted keys and no whitespace: equal values give equal text.

    Floats are written by Python's shortest round-trip repr, so a parameter
    read from TOML and one set in code hash the same.
    """
    return json.dumps(value, sort_keys=True, separators=(",", ":"), ensure_ascii=True, allow_nan=False)


def shard_key(
    stage: str,
    version: int,
    item_id: str,
    payload: Mapping[str, Any],
    input_keys: Sequence[str],
) -> str:
    """The content hash naming a shard.

    Parameters
    ----------
    stage : str
        Stage name.
    version : int
        The stage's code version; bump it when the stage's output changes.
    item_id : str
        Identity of the work item within the stage (e.g. a model name).
    payload : mapping
        Every parameter the item's build reads, JSON-serialisable.
    input_keys : sequence of str
        Keys of the shards the item reads; their order does not matter.

    Returns
    -------
    str
        64 hex characters.
    """
    document = {
        "stage": stage,
        "version": int(version),
        "item": item_id,
        "payload": payload,
        "inputs": sorted(input_keys),
    }
    return hashlib.sha256(canonical_json(document).encode("utf-8")).hexdigest()


def _umask() -> int:
    current = os.umask(0)
    os.umask(current)
    return current


#: The ending of the temporary files :func:`atomic_write_bytes` writes.
TEMPORARY_SUFFIX = ".tmp"


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` so that ``path`` is either absent, the old
    file, or the complete new file, whatever happens meanwhile.

    The bytes go to ``.<name>.<random>.tmp`` in the same folder, which is
    ``flock``-ed while it is written: :meth:`ShardStore.clean_leftovers`
    removes only the temporary files nobody holds (those of killed writers).
    The file gets the permissions an ordinary ``open`` would give it
    (0666 less the umask), not the 0600 of a temporary file.
    """
    path.parent.mkdir(parents=True, exist_ok=True)
    for _ in range(3):
        if _write_and_replace(path, data):
            break
    else:
        raise OSError(f"{path}: its temporary file was removed three times while being written")
    # Make the rename itself durable.
    directory = os.open(path.parent, os.O_RDONLY)
    try:
        os.fsync(directory)
    finally:
        os.close(directory)


def _write_and_replace(path: Path, data: bytes) -> bool:
    """One attempt of :func:`atomic_write_bytes`; False when a cleaner took the
    temporary file for a leftover in the instant before it was locked."""
    handle, temporary = tempfile.mkstemp(prefix=f".{path.name}.", suffix=TEMPORARY_SUFFIX, dir=path.parent)
    try:
        fcntl.flock(handle, fcntl.LOCK_EX)
        os.fchmod(handle, 0o666 & ~_umask())
        view = memoryview(data)
        while view:
            view = view[os.write(handle, view):]
        os.fsync(handle)
        os.replace(temporary, path)
        return True
    except FileNotFoundError:
        return False
    except OSError as error:  # a full disk: say which file could not be written
        with contextlib.suppress(FileNotFoundError):
            os.unlink(temporary)
        raise OSError(error.errno, error.strerror, str(path)) from error
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(temporary)
        raise
    finally:
        os.close(handle)


def _same_file(handle: int, path: Path) -> bool:
    """Whether ``path`` still names the file open as ``handle``."""
    try:
        named = os.stat(path)
    except FileNotFoundError:
        return False
    opened = os.fstat(handle)
    return (named.st_ino, named.st_dev) == (opened.st_ino, opened.st_dev)


def _acquire(path: Path, wait: bool) -> int | None:
    """An open, ``flock``-ed descriptor of the lock file ``path``; None when busy and not waiting.

    A holder removes the lock file before letting go, so a waiter may wake up
    holding a file that no longer has a name: it then locks the new one.
    """
    while True:
        handle = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
        try:
            fcntl.flock(handle, fcntl.LOCK_EX if wait else fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(handle)
            return None
        except BaseException:
            os.close(handle)
            raise
        if _same_file(handle, path):
            return handle
        os.close(handle)


def _remove_if_unheld(path: Path) -> bool:
    """Remove a lock or temporary file that no process holds; whether it was removed."""
    try:
        handle = os.open(path, os.O_RDONLY)
    except FileNotFoundError:
        return False
    try:
        fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        if not _same_file(handle, path):
            return False
        path.unlink()
        return True
    except (BlockingIOError, FileNotFoundError):
        return False
    finally:
        os.close(handle)


#: Metadata a table may set for itself over its schema's: the vocabulary of samples labelled with a
#: pipeline's own taxonomy (``osgd.contract.schemas.samples_schema``).
TABLE_OWN_METADATA = frozenset({b"osgd.vocabulary"})


def table_to_parquet_bytes(table: pa.Table, table_name: str, key: str) -> bytes:
    """Serialise ``table`` with the osgd metadata; deterministic bytes.

    Raises
    ------
    ValueError
        If the table does not match the schema of ``table_name``.
    """
    schema = TABLES[table_name]
    own = {name: value for name, value in (table.schema.metadata or {}).items() if name in TABLE_OWN_METADATA}
    if not table.schema.equals(schema, check_metadata=False):
        try:
            table = table.select(schema.names).cast(schema)
        except (KeyError, pa.ArrowInvalid, pa.ArrowNotImplementedError, ValueError) as error:
            raise ValueError(
                f"rows for table {table_name!r} do not match its schema: {error}\n"
                f"got: {table.schema}\nwant: {schema}"
            ) from error
    metadata = {**(schema.metadata or {}), **own}
    metadata.update(
        {
            b"osgd.schema_version": str(SCHEMA_VERSION).encode(),
            b"osgd.table": table_name.encode(),
            b"osgd.key": key.encode(),
        }
    )
    table = table.replace_schema_metadata(metadata)
    buffer = io.BytesIO()
    pq.write_table(table, buffer, **_PARQUET_OPTIONS)
    return buffer.getvalue()


class DataDirError(RuntimeError):
    """The data dir cannot be used (a file, not writable, full); one line saying what to do."""


def check_data_dir(root: str | os.PathLike[str], writable: bool) -> None:
    """Check that ``root`` can serve as a data dir, before anything is read or written.

    Parameters
    ----------
    root : path or URI
    writable : bool
        Also create it if needed and write a probe file in it.

    Raises
    ------
    DataDirError
        Naming the folder, the problem and what to do.
    """
    if is_uri(root):
        _check_object_store(str(root), writable)
        return
    root = Path(root)
    for folder in (root, *root.parents):
        if folder.exists() and not folder.is_dir():
            what = "is a file" if folder == root else f"lies under {folder}, which is a file"
            raise DataDirError(f"data dir {root} {what}, not a folder; give --data-dir a folder path")
    if not writable:
        return
    try:
        root.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=root) as probe:
            probe.write(b"osgd")
            probe.flush()
            os.fsync(probe.fileno())
    except OSError as error:
        raise DataDirError(
            f"data dir {root} is not writable ({error.strerror or error}); "
            + _remedy(error)
        ) from error


#: The object a writable check puts into an object-store data dir, and removes.
_PROBE = ".osgd-probe"


def _check_object_store(uri: str, writable: bool) -> None:
    """:func:`check_data_dir` for an object-store URI: it can be opened (and written, when asked)."""
    try:
        files = ObjectFiles(uri)
        if writable:
            files.write_bytes(_PROBE, b"osgd")
            files.delete(_PROBE)
        else:
            files.names("manifests", ".json")
    except (ValueError, OSError) as error:
        first_line = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
        raise DataDirError(
            f"data dir {uri} cannot be {'written' if writable else 'read'} ({first_line}); check the bucket, "
            "the credentials and the endpoint (AWS_ENDPOINT_URL, AWS_ACCESS_KEY_ID, AWS_SECRET_ACCESS_KEY)"
        ) from error


def _remedy(error: OSError) -> str:
    """What a person can do about an ``OSError`` met while writing the data dir."""
    if error.errno == errno.ENOSPC:
        return "free some space there or give --data-dir a folder on a disk with room"
    if error.errno == errno.EROFS:
        return "the file system is read-only: give --data-dir a writable folder"
    return "give --data-dir a folder you can write to, or fix the folder's permissions"


def write_problem(error: OSError) -> str:
    """One line for an ``OSError`` met while writing shards or manifests: what failed and what to do."""
    where = f"{error.filename}: " if error.filename else ""
    return f"cannot write {where}{error.strerror or error}; {_remedy(error)}"


class ShardStore(ShardReader):
    """Shards of every table under one data dir: :class:`ShardReader` and the writing side.

    Parameters
    ----------
    root : path
        The data dir; created when first written.
    """

    # -- writing -----------------------------------------------------------
    def write(self, table_name: str, key: str, item_id: str, table: pa.Table) -> ShardRecord:
        """Write one shard atomically and record its checksum.

        The Parquet file is replaced first and its checksum second, so a
        crash between the two leaves a shard without a checksum, which
        :meth:`verify` treats as missing.
        """
        data = table_to_parquet_bytes(table, table_name, key)
        digest = hashlib.sha256(data).hexdigest()
        self.write_file(f"{table_name}/{key}.parquet", data)
        record = {"item": item_id, "key": key, "rows": table.num_rows, "sha256": digest}
        self.write_file(f"{table_name}/{key}.sha256", (canonical_json(record) + "\n").encode())
        return ShardRecord(table_name, key, item_id, table.num_rows, digest)

    def write_file(self, relative: str, data: bytes) -> None:
        """Write one file of the data dir whole: atomically in a folder, as one upload in an object store.

        Parameters
        ----------
        relative : str
            ``/``-separated, relative to the data dir (``"samples/<key>.notes.json"``).
        """
        if self.files.remote:
            self.files.write_bytes(relative, data)
        else:
            atomic_write_bytes(self.files.location(relative), data)

    def local_folder(self, relative: str) -> Path:
        """A folder on this machine for a cache the data dir keeps (``cache/decompositions``).

        In a folder data dir it is ``<root>/<relative>``. An object store
        cannot hold files that libraries open by name, so there it is
        ``$OSGD_CACHE_DIR`` (default ``~/.cache/osgd``) ``/<hash of the URI>/<relative>``
        on each machine. The caches are keyed by their content, so either place
        gives the same results.
        """
        if not self.files.remote:
            return self.files.location(relative)
        base = Path(os.environ.get("OSGD_CACHE_DIR") or Path.home() / ".cache" / "osgd")
        return base / hashlib.sha256(str(self.root).encode()).hexdigest()[:16] / relative

    @contextlib.contextmanager
    def lock(self, table: str, key: str, wait: bool = True) -> Iterator[bool]:
        """Hold an exclusive lock on one shard for as long as the block runs.

        ``flock`` locks work between processes of one machine and, on NFSv4
        and most cluster file systems, between machines sharing the folder.
        The lock file (``<table>/.locks/<key>.lock``) is removed as the lock
        is let go, so lock files do not pile up.

        Parameters
        ----------
        wait : bool
            Wait for another holder to let go; with False the block runs at
            once and receives False when someone else holds the lock.

        Yields
        ------
        bool
            Whether this process holds the lock.
        """
        if self.files.remote:
            # No locks in an object store: the driver hands out each item once (docs/scale-out.md).
            yield True
            return
        lock_dir = self.root / table / ".locks"
        lock_dir.mkdir(parents=True, exist_ok=True)
        path = lock_dir / f"{key}.lock"
        handle = _acquire(path, wait)
        if handle is None:
            yield False
            return
        try:
            yield True
        finally:
            # Unlinked while still held: a waiter that wakes up on this file sees it has no name.
            with contextlib.suppress(FileNotFoundError):
                path.unlink()
            os.close(handle)

    def clean_leftovers(self) -> tuple[int, int]:
        """Remove what killed processes left behind: temporary files and lock files.

        Only files no live process holds are removed, so this is safe while
        other runs use the data dir.

        Returns
        -------
        temporaries, locks : int
            How many of each were removed.
        """
        if self.files.remote or not self.root.is_dir():
            # An object store has no temporary files: an unfinished upload never becomes an object.
            return 0, 0
        pattern = f".*{TEMPORARY_SUFFIX}"
        temporaries = [*self.root.glob(pattern), *self.root.glob(f"*/{pattern}"), *self.root.glob(f"*/*/{pattern}")]
        removed = sum(_remove_if_unheld(path) for path in temporaries)
        locks = sum(_remove_if_unheld(path) for path in self.root.glob("*/.locks/*.lock"))
        return removed, locks

    # -- manifests ---------------------------------------------------------
    def write_manifest(self, pipeline: str, manifest: Mapping[str, Any]) -> Path:
        """Write a manifest atomically; the text is canonical and stable."""
        text = json.dumps(manifest, sort_keys=True, indent=1, ensure_ascii=True) + "\n"
        self.write_file(f"manifests/{pipeline}.json", text.encode("utf-8"))
        return self.manifest_path(pipeline)
