"""Where a data dir's files live: a local folder, or a prefix of an object store.

A data dir is named by a path (``data``, ``/shared/osgd-data``) or by a URI
that :func:`pyarrow.fs.FileSystem.from_uri` understands (``s3://bucket/osgd``;
credentials, region and endpoint come from the usual AWS variables, e.g.
``AWS_ENDPOINT_URL`` for a MinIO or other S3-compatible server). The shard
store reads and writes through one of two classes with the same methods:

- :class:`FolderFiles`: a POSIX folder, local or shared (NFS);
- :class:`ObjectFiles`: an object store, through pyarrow's file systems. An
  object is written whole by one upload, so a partial file never carries a
  final name, but there is no rename and no lock (``docs/scale-out.md``).

Files are named relative to the data dir with ``/`` (``"samples/<key>.parquet"``).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Union

import pyarrow.fs as pafs


def is_uri(root: str | os.PathLike[str]) -> bool:
    """Whether a data dir name is a URI (``scheme://...``) rather than a path."""
    return "://" in str(root)


class ObjectUri(str):
    """A URI that joins like a path: ``ObjectUri("s3://b/osgd") / "models"`` is ``s3://b/osgd/models``."""

    def __truediv__(self, part: str | os.PathLike[str]) -> ObjectUri:
        return ObjectUri(f"{self.rstrip('/')}/{os.fspath(part)}")


#: What a data dir's files are named by: a path for a folder, a URI for an object store.
Location = Union[Path, ObjectUri]  # noqa: UP007 (used at run time)


class FolderFiles:
    """The files of a data dir that is a folder.

    Parameters
    ----------
    root : path
    """

    remote = False

    def __init__(self, root: str | os.PathLike[str]) -> None:
        self.root = Path(root)

    def location(self, relative: str) -> Path:
        """The path of a file or folder, for pyarrow, ``open`` and messages."""
        return self.root / relative

    def exists(self, relative: str) -> bool:
        return self.location(relative).exists()

    def read_bytes(self, relative: str) -> bytes:
        """The file's bytes. Raises FileNotFoundError when there is none."""
        return self.location(relative).read_bytes()

    def names(self, folder: str, suffix: str) -> list[str]:
        """Names (without ``suffix``) of the files directly in ``folder`` ending in ``suffix``, sorted."""
        path = self.location(folder)
        if not path.is_dir():
            return []
        return sorted(item.name[: -len(suffix)] for item in path.glob(f"*{suffix}"))

    def delete(self, relative: str) -> None:
        """Remove a file if it exists."""
        self.location(relative).unlink(missing_ok=True)


class ObjectFiles:
    """The files of a data dir that is a prefix of an object store.

    Parameters
    ----------
    uri : str
        ``scheme://bucket/prefix``; anything :func:`pyarrow.fs.FileSystem.from_uri` accepts.

    Raises
    ------
    ValueError
        When pyarrow knows no file system for the URI (one line naming it).
    """

    remote = True

    def __init__(self, uri: str) -> None:
        uri = str(uri).rstrip("/")
        try:
            self.filesystem, self.base = pafs.FileSystem.from_uri(uri)
        except (ValueError, OSError) as error:  # pyarrow's ArrowInvalid is a ValueError
            raise ValueError(f"data dir {uri}: pyarrow cannot open it ({error})") from error
        self.root = ObjectUri(uri.split("?", 1)[0])

    def _path(self, relative: str) -> str:
        return f"{self.base.rstrip('/')}/{relative}" if relative else self.base

    def location(self, relative: str) -> ObjectUri:
        """The URI of a file or folder, for pyarrow's readers and messages."""
        return self.root / relative if relative else self.root

    def exists(self, relative: str) -> bool:
        return self.filesystem.get_file_info(self._path(relative)).type != pafs.FileType.NotFound

    def read_bytes(self, relative: str) -> bytes:
        """The object's bytes. Raises FileNotFoundError when there is none."""
        try:
            with self.filesystem.open_input_stream(self._path(relative)) as stream:
                return stream.read()
        except FileNotFoundError:
            raise
        except OSError as error:
            if not self.exists(relative):
                raise FileNotFoundError(str(self.location(relative))) from error
            raise

    def names(self, folder: str, suffix: str) -> list[str]:
        """Names (without ``suffix``) of the objects directly under ``folder`` ending in ``suffix``, sorted."""
        selector = pafs.FileSelector(self._path(folder), allow_not_found=True, recursive=False)
        return sorted(info.base_name[: -len(suffix)] for info in self.filesystem.get_file_info(selector)
                      if info.type == pafs.FileType.File and info.base_name.endswith(suffix))

    def write_bytes(self, relative: str, data: bytes) -> None:
        """Upload one object whole; readers see the old object or the new one, never a part."""
        with self.filesystem.open_output_stream(self._path(relative)) as stream:
            stream.write(data)

    def delete(self, relative: str) -> None:
        """Remove an object if it exists."""
        try:
            self.filesystem.delete_file(self._path(relative))
        except FileNotFoundError:
            pass


#: Either kind of data dir files.
DataFiles = Union[FolderFiles, ObjectFiles]  # noqa: UP007


def data_files(root: str | os.PathLike[str]) -> DataFiles:
    """The files of the data dir ``root``: :class:`ObjectFiles` for a URI, else :class:`FolderFiles`."""
    return ObjectFiles(str(root)) if is_uri(root) else FolderFiles(root)
