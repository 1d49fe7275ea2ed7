"""A data dir in an object store (``s3://``), against a real local S3 server.

The server is moto's (``moto[server]``, in the ``dev`` extra): a separate
thread speaking the S3 protocol on a local port, reached through pyarrow's
S3 file system exactly as a bucket on AWS or a MinIO server would be
(``AWS_ENDPOINT_URL``). The tests skip, saying so, where moto is absent.
"""

from __future__ import annotations

import importlib.util
import json
import logging
import os
import re
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from osgd.contract.files import FolderFiles, ObjectFiles, ObjectUri, data_files, is_uri
from osgd.contract.samples import iter_samples
from osgd.contract.shards import ShardError
from osgd.executor import ray_runtime_env
from osgd.store import DataDirError, ShardStore, check_data_dir

ROOT = Path(__file__).resolve().parents[1]
GOLDEN = ROOT / "pipelines" / "golden.toml"
COMMITTED = ROOT / "data" / "manifests" / "golden.json"
BUCKET = "osgd-test"
needs_moto = pytest.mark.skipif(
    importlib.util.find_spec("moto") is None,
    reason="moto is not installed; `pip install 'moto[server]'` (in the dev extra) runs the object-store tests",
)
pytestmark = needs_moto


@pytest.fixture(scope="module")
def s3_server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """A local S3 server with one bucket; the AWS variables point this process and its children at it."""
    from moto.server import ThreadedMotoServer  # noqa: PLC0415

    logging.getLogger("werkzeug").setLevel(logging.WARNING)  # one line per request otherwise
    server = ThreadedMotoServer(ip_address="127.0.0.1", port=0, verbose=False)
    server.start()
    host, port = server.get_host_and_port()
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("AWS_ENDPOINT_URL", f"http://{host}:{port}")
        patch.setenv("AWS_ACCESS_KEY_ID", "test")
        patch.setenv("AWS_SECRET_ACCESS_KEY", "test")
        patch.setenv("AWS_DEFAULT_REGION", "us-east-1")
        patch.setenv("OSGD_CACHE_DIR", str(tmp_path_factory.mktemp("osgd-cache")))
        ObjectFiles(f"s3://{BUCKET}?allow_bucket_creation=true").filesystem.create_dir(BUCKET)
        yield f"s3://{BUCKET}"
    server.stop()


def _osgd(*arguments: str, cwd: Path) -> subprocess.CompletedProcess:
    """``python -m osgd ARGUMENTS`` as `osgd` runs (hash seed 0), in ``cwd``."""
    return subprocess.run([sys.executable, "-m", "osgd", *arguments], capture_output=True, text=True, cwd=cwd,
                          env={**os.environ, "PYTHONHASHSEED": "0"}, check=False)


def _keys_and_rows(manifest: dict) -> dict[str, list[tuple[str, int]]]:
    """What a manifest records that does not depend on the processor: each stage's shard keys and row counts."""
    return {name: [(shard["key"], shard["rows"]) for shard in stage["shards"]]
            for name, stage in manifest["stages"].items()}


@pytest.fixture(scope="module")
def golden_in_s3(s3_server: str, tmp_path_factory: pytest.TempPathFactory) -> tuple[str, subprocess.CompletedProcess]:
    """The golden pipeline built by two worker processes into the object store: its URI and the run."""
    uri = f"{s3_server}/golden"
    cwd = tmp_path_factory.mktemp("cwd")
    result = _osgd("--data-dir", uri, "--workers", "2", "run", str(GOLDEN), cwd=cwd)
    assert result.returncode == 0, result.stdout + result.stderr
    assert not any(cwd.iterdir()), "a URI data dir must not become a local folder"
    return uri, result


def test_names_tell_a_uri_from_a_path() -> None:
    assert is_uri("s3://bucket/osgd") and not is_uri("data") and not is_uri(Path("/shared/osgd-data"))
    assert isinstance(data_files("data"), FolderFiles)
    assert ObjectUri("s3://bucket/osgd/") / "models" / "a.parquet" == "s3://bucket/osgd/models/a.parquet"


def test_object_files_write_read_list_and_delete(s3_server: str) -> None:
    files = ObjectFiles(f"{s3_server}/files")
    assert files.names("samples", ".parquet") == [] and not files.exists("samples/a.parquet")
    files.write_bytes("samples/b.parquet", b"bb")
    files.write_bytes("samples/a.parquet", b"a")
    files.write_bytes("samples/a.sha256", b"{}")
    files.write_bytes("samples/deeper/c.parquet", b"c")
    assert files.names("samples", ".parquet") == ["a", "b"]
    assert files.read_bytes("samples/b.parquet") == b"bb"
    files.delete("samples/b.parquet")
    files.delete("samples/b.parquet")  # a second delete is no error
    assert not files.exists("samples/b.parquet")
    with pytest.raises(FileNotFoundError):
        files.read_bytes("samples/b.parquet")


def test_the_golden_pipeline_in_an_object_store_is_the_records_dataset(golden_in_s3: tuple) -> None:
    uri, _ = golden_in_s3
    store = ShardStore(uri)
    manifest = store.read_manifest("golden")
    assert manifest is not None, f"no manifest in {uri}"
    assert _keys_and_rows(manifest) == _keys_and_rows(json.loads(COMMITTED.read_text()))
    for stage in manifest["stages"].values():
        for shard in stage["shards"]:
            store.verify(stage["table"], shard["key"], shard["sha256"])
        assert store.keys_on_disk(stage["table"]) == sorted(shard["key"] for shard in stage["shards"])
    samples = list(iter_samples(uri, pipeline="golden"))
    assert len(samples) == sum(shard["rows"] for shard in manifest["stages"]["samples"]["shards"]) > 0
    assert all(sample.depth.size > 0 for sample in samples)


def test_a_second_run_on_an_object_store_reuses_every_shard(golden_in_s3: tuple, tmp_path: Path) -> None:
    uri, _ = golden_in_s3
    result = _osgd("--data-dir", uri, "--workers", "2", "run", str(GOLDEN), cwd=tmp_path)
    assert result.returncode == 0, result.stdout + result.stderr
    reused = re.findall(r"^(\w+): (\d+)/\2 items \(\2 reused\), done in", result.stderr, re.MULTILINE)
    assert [stage for stage, _ in reused] == ["models", "grasps", "checks", "scenes", "samples"], result.stderr


def test_status_pictures_and_the_training_dataset_read_an_object_store(golden_in_s3: tuple, tmp_path: Path) -> None:
    from togcrf.data import SamplesDataset  # noqa: PLC0415

    uri, _ = golden_in_s3
    status = _osgd("--data-dir", uri, "status", "--config", str(GOLDEN), cwd=tmp_path)
    assert status.returncode == 0, status.stdout + status.stderr
    assert re.search(r"samples\W+2\W+0\W+0\W+0\W+0\W", status.stdout), status.stdout
    assert "golden in s3://osgd-test/golden" in status.stdout
    manifest = ShardStore(uri).read_manifest("golden")
    dataset = SamplesDataset(uri, pipeline="golden", split=None)
    assert len(dataset) == sum(shard["rows"] for shard in manifest["stages"]["samples"]["shards"])
    sample_id = dataset.read_sample(0).sample_id
    picture = tmp_path / "sample.png"
    shown = _osgd("--data-dir", uri, "show", "sample", sample_id, "--out", str(picture), cwd=tmp_path)
    assert shown.returncode == 0, shown.stdout + shown.stderr
    assert picture.read_bytes().startswith(b"\x89PNG")


def test_a_shard_cut_short_or_without_its_checksum_in_the_object_store_is_rebuilt(
    golden_in_s3: tuple, tmp_path: Path
) -> None:
    uri, _ = golden_in_s3
    store = ShardStore(uri)
    before = store.read_manifest("golden")
    samples, scenes = before["stages"]["samples"]["shards"][0], before["stages"]["scenes"]["shards"][0]
    data = store.files.read_bytes(f"samples/{samples['key']}.parquet")
    store.files.write_bytes(f"samples/{samples['key']}.parquet", data[: len(data) // 2])
    store.files.delete(f"scenes/{scenes['key']}.sha256")
    with pytest.raises(ShardError, match="checksum"):
        store.verify("samples", samples["key"])
    result = _osgd("--data-dir", uri, "--workers", "2", "run", str(GOLDEN), cwd=tmp_path)
    assert result.returncode == 0, result.stdout + result.stderr
    after = store.read_manifest("golden")
    assert _keys_and_rows(after) == _keys_and_rows(before)
    store.verify("samples", samples["key"], samples["sha256"])  # the same bytes again
    store.verify("scenes", scenes["key"], scenes["sha256"])


def test_an_object_store_has_no_locks_or_leftovers_and_caches_on_this_machine(s3_server: str) -> None:
    store = ShardStore(f"{s3_server}/locks")
    with store.lock("models", "k", wait=False) as first, store.lock("models", "k", wait=False) as second:
        assert first and second  # the driver owns the claims: each item is handed out once
    assert store.clean_leftovers() == (0, 0)
    cache = store.local_folder("cache/decompositions")
    assert cache.is_relative_to(Path(os.environ["OSGD_CACHE_DIR"]))
    assert cache != ShardStore(f"{s3_server}/other").local_folder("cache/decompositions")


def test_a_bucket_that_does_not_exist_is_one_line_naming_it(s3_server: str, tmp_path: Path) -> None:
    with pytest.raises(DataDirError, match=r"data dir s3://no-such-bucket/osgd cannot be written .*AWS_ENDPOINT_URL"):
        check_data_dir("s3://no-such-bucket/osgd", writable=True)
    result = _osgd("--data-dir", "s3://no-such-bucket/osgd", "run", str(GOLDEN), cwd=tmp_path)
    assert result.returncode == 2
    lines = [line for line in (result.stdout + result.stderr).splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: data dir s3://no-such-bucket/osgd cannot be written")


def test_rays_workers_are_told_where_the_object_store_is_but_not_its_secrets(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setenv("AWS_ENDPOINT_URL", "http://minio.cluster:9000")
    monkeypatch.setenv("AWS_SECRET_ACCESS_KEY", "secret")
    variables = ray_runtime_env()["env_vars"]
    assert variables["AWS_ENDPOINT_URL"] == "http://minio.cluster:9000"
    assert "AWS_SECRET_ACCESS_KEY" not in variables
