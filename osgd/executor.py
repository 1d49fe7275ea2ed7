"""Executors: where the work items of a stage run.

An executor maps a picklable, module-level function over a list of tasks and
yields ``(index, outcome)`` pairs as tasks finish, in any order. An exception
raised by a task never escapes: it comes back as a :class:`TaskFailure` with
its traceback, so one failing item neither stops the others nor loses their
results. Three backends implement the one-method interface:
:class:`SerialExecutor`, :class:`ProcessPoolExecutor` (local worker processes)
and :class:`RayExecutor` (each task a Ray task on a Ray cluster; Ray is
imported only when that backend runs, and is an optional dependency:
``pip install 'osgd[ray]'``). docs/scale-out.md tells how to run on a cluster.
"""

from __future__ import annotations

import concurrent.futures
import functools
import hashlib
import logging
import multiprocessing
import os
import signal
import socket
import sys
import tempfile
import threading
import time
import traceback
from collections.abc import Callable, Generator, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

from osgd.errors import describe
from osgd.kernels import portable_settings

log = logging.getLogger(__name__)

#: The backends :func:`make_executor` knows.
BACKENDS = ("process", "ray")


@dataclass(frozen=True)
class TaskFailure:
    """A task that raised.

    Attributes
    ----------
    error : str
        One line: the file (when known) and the cause.
    traceback : str
        The formatted traceback, from the process that ran the task.
    file : str
        The file the error is about; empty when unknown (:func:`osgd.errors.describe`).
    cause : str
        What went wrong, one line, without the file.
    """

    error: str
    traceback: str
    file: str = ""
    cause: str = ""


def failure_of(error: BaseException) -> TaskFailure:
    """The :class:`TaskFailure` describing ``error``; call it inside the ``except`` block."""
    file, cause = describe(error)
    return TaskFailure(f"{file}: {cause}" if file else cause, traceback.format_exc(), file, cause)


def call_safely(function: Callable[[Any], Any], task: Any) -> Any:
    """Run ``function(task)``, turning any exception into a :class:`TaskFailure`."""
    try:
        return function(task)
    except Exception as error:
        return failure_of(error)


class Executor(Protocol):
    """The interface every backend implements."""

    def map_unordered(
        self, function: Callable[[Any], Any], tasks: Sequence[Any]
    ) -> Iterator[tuple[int, Any]]:
        """Yield ``(task index, result or TaskFailure)`` as tasks finish."""
        ...


class SerialExecutor:
    """Runs tasks one after another in this process, in order."""

    def map_unordered(
        self, function: Callable[[Any], Any], tasks: Sequence[Any]
    ) -> Iterator[tuple[int, Any]]:
        for index, task in enumerate(tasks):
            yield index, call_safely(function, task)


#: Seconds between two looks of a worker's watchdog at its parent.
WATCHDOG_INTERVAL = 1.0


def _set_parent_death_signal() -> bool:
    """Ask Linux to send this process SIGKILL when its parent dies (``prctl(PR_SET_PDEATHSIG)``); whether it could."""
    if not sys.platform.startswith("linux"):
        return False
    import ctypes  # noqa: PLC0415 (Linux only)

    try:
        libc = ctypes.CDLL(None, use_errno=True)
        return libc.prctl(1, int(signal.SIGKILL), 0, 0, 0) == 0  # PR_SET_PDEATHSIG = 1
    except (OSError, AttributeError):
        return False


def _watch_parent(parent: int, interval: float) -> None:
    """End this process as soon as its parent is no longer ``parent`` (it died: the process was re-parented)."""
    while True:
        if os.getppid() != parent:
            os._exit(1)
        time.sleep(interval)


def die_with_parent(parent: int, interval: float = WATCHDOG_INTERVAL) -> None:
    """A worker initializer: the worker ends when its parent dies, whatever kills the parent (SIGKILL, OOM).

    On Linux the kernel kills the worker at once (the parent-death signal);
    everywhere a daemon thread checks every ``interval`` seconds that the
    parent is still ``parent`` and ends the worker otherwise, which also
    covers a parent that died before the signal was set. A worker blocked
    on its task pipe therefore never outlives the main process, and neither
    does multiprocessing's resource tracker, which ends once no process
    holds its pipe.
    """
    _set_parent_death_signal()
    if os.getppid() != parent:
        os._exit(1)
    threading.Thread(target=_watch_parent, args=(parent, interval), name="osgd-parent-watchdog", daemon=True).start()


def spawned_pool(workers: int) -> concurrent.futures.ProcessPoolExecutor:
    """A pool of ``workers`` spawned processes that end when this process dies (:func:`die_with_parent`)."""
    return concurrent.futures.ProcessPoolExecutor(
        max_workers=workers, mp_context=multiprocessing.get_context("spawn"),
        initializer=die_with_parent, initargs=(os.getpid(),),
    )


#: The failure of a task that took its worker process down with it.
WORKER_DIED = "its worker process died while running it (a crash in a native library, or out of memory)"


def _marked_call(function: Callable[[Any], Any], task: Any, mark: Path) -> Any:
    """:func:`call_safely`, leaving ``mark`` behind first: the task started."""
    mark.touch()
    return call_safely(function, task)


class ProcessPoolExecutor:
    """Runs tasks in a pool of local worker processes.

    Workers are started with ``spawn``: physics and rendering libraries
    (pybullet, EGL) hold process-wide state that must not be inherited by
    ``fork``. Each worker is reused across tasks, so a stage can keep one
    physics client per worker. Workers end when the process that started
    them dies, however it dies (:func:`die_with_parent`): no orphans.

    A task that kills its worker (a segfault in native code, the kernel's
    out-of-memory killer) breaks the pool and every task still in it. The
    tasks that had not started run again in a new pool; those that had
    started run again one at a time, each alone in a pool of one worker,
    so that the one that kills its worker again comes back as a
    :class:`TaskFailure` (:data:`WORKER_DIED`) and the others finish.

    Parameters
    ----------
    workers : int
        Number of processes.
    """

    def __init__(self, workers: int) -> None:
        if workers < 1:
            raise ValueError(f"workers must be at least 1, got {workers}")
        self.workers = workers

    def map_unordered(
        self, function: Callable[[Any], Any], tasks: Sequence[Any]
    ) -> Iterator[tuple[int, Any]]:
        waiting = list(range(len(tasks)))
        with tempfile.TemporaryDirectory(prefix="osgd-tasks-") as folder:
            marks = Path(folder)
            while waiting:
                lost = yield from self._round(function, tasks, waiting, self.workers, marks)
                started = [index for index in lost if (marks / str(index)).exists()]
                waiting = [index for index in lost if index not in started]
                for index in started:
                    if (yield from self._round(function, tasks, [index], 1, marks)):
                        log.warning("task %d: %s", index, WORKER_DIED)
                        yield index, TaskFailure(WORKER_DIED, "", "", WORKER_DIED)

    def _round(
        self, function: Callable[[Any], Any], tasks: Sequence[Any], indices: list[int], workers: int, marks: Path
    ) -> Generator[tuple[int, Any], None, list[int]]:
        """Run ``tasks[indices]`` in one pool, yielding their outcomes; returns those lost when a worker died."""
        lost: list[int] = []
        with spawned_pool(min(workers, len(indices))) as pool:
            futures = {pool.submit(_marked_call, function, tasks[index], marks / str(index)): index
                       for index in indices}
            for future in concurrent.futures.as_completed(futures):
                index = futures[future]
                try:
                    yield index, future.result()
                except concurrent.futures.process.BrokenProcessPool:
                    lost.append(index)
                except Exception as error:  # the result did not pickle
                    yield index, failure_of(error)
        return sorted(lost)


class ExecutorError(RuntimeError):
    """An executor that cannot start (Ray missing, a cluster that does not answer); one line."""


#: Environment variables a worker reads before it imports anything: the
#: kernel pins of :mod:`osgd.kernels` and the hash seed.
_KERNEL_VARIABLES = tuple(portable_settings(frozenset({"avx2", "fma"}), "x86_64"))


#: Where an object-store data dir is (no secrets): they follow the driver to Ray's workers.
OBJECT_STORE_VARIABLES = ("AWS_ENDPOINT_URL", "AWS_REGION", "AWS_DEFAULT_REGION")


def ray_runtime_env(extra: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """The Ray runtime environment under which a Ray worker builds the bytes a local worker builds.

    Each worker process pins its own processor's kernels before it imports
    numpy (``worker_process_setup_hook``: :func:`osgd.kernels.pin_kernels`,
    what the ``osgd`` entry point does), so a node of another processor
    family pins what suits it. The variables that must follow the driver
    travel as ``env_vars``: ``PYTHONHASHSEED`` (``0`` unless set), a kernel
    variable the user set to something else than the pin,
    ``OSGD_NATIVE_SIMD``, and where an object store is the data dir, the
    variables that say where it is (:data:`OBJECT_STORE_VARIABLES`; the
    credentials stay with each node: its own variables, profile or role).

    Parameters
    ----------
    extra : mapping, optional
        More runtime environment fields; its ``env_vars`` are added to these.

    Returns
    -------
    dict
        For ``ray.init(runtime_env=...)``; pass it when a program calls
        ``ray.init`` itself before running stages on a :class:`RayExecutor`.
    """
    pinned = portable_settings()
    variables = {"PYTHONHASHSEED": os.environ.get("PYTHONHASHSEED", "0")}
    for name in (*_KERNEL_VARIABLES, "OSGD_NATIVE_SIMD", *OBJECT_STORE_VARIABLES):
        value = os.environ.get(name)
        if value is not None and value != pinned.get(name):
            variables[name] = value
    extra = dict(extra or {})
    variables.update(extra.pop("env_vars", {}))
    return {**extra, "env_vars": variables, "worker_process_setup_hook": "osgd.kernels.pin_kernels"}


@functools.cache
def code_fingerprint() -> str:
    """sha256 over the Python sources of the osgd package this process runs (relative paths and bytes)."""
    root = Path(__file__).resolve().parent
    digest = hashlib.sha256()
    for path in sorted(root.rglob("*.py")):
        digest.update(f"{path.relative_to(root).as_posix()}\0".encode())
        digest.update(hashlib.sha256(path.read_bytes()).digest())
    return digest.hexdigest()


def call_checked(fingerprint: str, function: Callable[[Any], Any], task: Any) -> Any:
    """:func:`call_safely`, on a worker that runs the driver's osgd (``fingerprint``); else a :class:`TaskFailure`.

    A node with another osgd would write other bytes under the same shard
    keys (keys name the stage version, not every line of code).
    """
    mine = code_fingerprint()
    if mine != fingerprint:
        cause = (f"the worker on {socket.gethostname()} runs another osgd than the driver (code fingerprint "
                 f"{mine[:12]}, the driver's {fingerprint[:12]}); install the same osgd on every node")
        return TaskFailure(cause, "", "", cause)
    return call_safely(function, task)


def _import_ray() -> Any:
    """The ``ray`` module, or :class:`ExecutorError` saying how to install it."""
    try:
        import ray  # noqa: PLC0415 (optional dependency, imported only when used)
    except ImportError as error:
        raise ExecutorError(
            "the Ray executor needs Ray, which is not installed: pip install 'osgd[ray]' "
            "(or pip install 'ray[default]')"
        ) from error
    return ray


class RayExecutor:
    """Runs each task as a Ray task, on a Ray cluster or a Ray instance started here.

    Every task asks for one CPU. Ray reuses a worker process for many tasks
    of the same job, so what a stage keeps per process (a physics client, an
    EGL context, caches) is kept per Ray worker, as in the process pool. A
    task whose worker or node dies is retried ``max_retries`` times on
    another worker; one that fails for good comes back as a
    :class:`TaskFailure`, as does an exception the task raised. At most
    ``workers`` tasks (default: twice the cluster's CPUs) are in flight at a
    time, so a stage of 100,000 items holds a bounded queue.

    Every node must run the same osgd (a task on a worker whose osgd
    sources differ from the driver's fails, see :func:`call_checked`) and
    reach the data dir at the same absolute path: a shared POSIX folder
    such as an NFS mount (docs/scale-out.md).

    Parameters
    ----------
    address : str, optional
        ``ray.init``'s address: ``"auto"`` (the cluster this node belongs
        to), ``"HOST:PORT"`` (the head's GCS) or ``"ray://HOST:10001"``
        (Ray client). None: ``RAY_ADDRESS`` when set, else a Ray instance
        on this machine with ``workers`` CPUs, shut down by :meth:`close`.
    workers : int, optional
        The most tasks in flight at once; also the CPUs of a local instance.
    max_retries : int
        Retries of a task whose worker process or node died.
    runtime_env : mapping, optional
        More of Ray's runtime environment (see :func:`ray_runtime_env`).
    """

    def __init__(
        self,
        address: str | None = None,
        workers: int | None = None,
        *,
        max_retries: int = 3,
        runtime_env: Mapping[str, Any] | None = None,
    ) -> None:
        if workers is not None and workers < 1:
            raise ValueError(f"workers must be at least 1, got {workers}")
        self.address = address or None
        self.workers = workers
        self.max_retries = max_retries
        self.runtime_env = dict(runtime_env or {})
        self._started = False
        self._remote: Any = None

    def connect(self) -> Any:
        """Join the cluster (or start a local instance) unless Ray already runs here; the ``ray`` module.

        Raises
        ------
        ExecutorError
            When Ray is not installed or the cluster cannot be reached.
        """
        ray = _import_ray()
        if not ray.is_initialized():
            self._init(ray)
        if self._remote is None:
            self._remote = ray.remote(call_checked).options(
                num_cpus=1, max_retries=self.max_retries, retry_exceptions=False
            )
        return ray

    def _init(self, ray: Any) -> None:
        _check_reachable(self.address or os.environ.get("RAY_ADDRESS") or "")
        local = self.address is None and not os.environ.get("RAY_ADDRESS")
        # "local": a new instance even where `ray start` left a cluster's address on this machine.
        options: dict[str, Any] = {"num_cpus": self.workers, "include_dashboard": False} if local else {}
        try:
            ray.init(address="local" if local else self.address, runtime_env=ray_runtime_env(self.runtime_env),
                     logging_level=logging.WARNING, **options)
        except Exception as error:  # Ray raises ConnectionError, RuntimeError, ValueError...
            where = self.address or os.environ.get("RAY_ADDRESS") or "a local instance"
            hint = "" if local or os.environ.get("RAY_AUTH_MODE") else (
                "; a cluster with token authentication (recent Ray turns it on by default) needs RAY_AUTH_MODE=token "
                "here too, and its token in ~/.ray/auth_token or RAY_AUTH_TOKEN"
            )
            raise ExecutorError(f"cannot start Ray ({where}): {describe(error)[1]}{hint}") from error
        self._started = True
        log.info("Ray: %s CPUs on %d node(s)", ray.cluster_resources().get("CPU", 0), len(ray.nodes()))

    def close(self) -> None:
        """Shut down the Ray instance this executor started, or leave the cluster it joined (which runs on)."""
        if self._started:
            _import_ray().shutdown()
            self._started = False
            self._remote = None

    def window(self) -> int:
        """How many tasks are kept in flight."""
        if self.workers is not None:
            return self.workers
        cpus = int(self.connect().cluster_resources().get("CPU", 1))
        return max(1, 2 * cpus)

    def map_unordered(
        self, function: Callable[[Any], Any], tasks: Sequence[Any]
    ) -> Iterator[tuple[int, Any]]:
        if not tasks:
            return
        ray = self.connect()
        window, fingerprint = self.window(), code_fingerprint()
        pending: dict[Any, int] = {}
        submitted = 0
        try:
            while pending or submitted < len(tasks):
                while submitted < len(tasks) and len(pending) < window:
                    pending[self._remote.remote(fingerprint, function, tasks[submitted])] = submitted
                    submitted += 1
                ready, _ = ray.wait(list(pending), num_returns=1)
                for reference in ready:
                    yield pending.pop(reference), _result(ray, reference)
        finally:
            for reference in pending:  # the caller stopped early (an interrupt): stop the rest
                ray.cancel(reference)


def _check_reachable(address: str, timeout: float = 10.0) -> None:
    """Raise :class:`ExecutorError` at once when a ``HOST:PORT`` (or ``ray://HOST:PORT``) does not answer.

    Ray itself retries an unreachable cluster for minutes; ``"auto"``,
    ``"local"`` and an empty address are left to Ray.
    """
    host, _, port = address.removeprefix("ray://").rpartition(":")
    if not host or not port.isdigit():
        return
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=timeout).close()
    except OSError as error:
        raise ExecutorError(
            f"cannot reach the Ray cluster at {address}: {error.strerror or error}; "
            "is the head node up (`ray start --head`) and the address its GCS address (port 6379 by default)?"
        ) from error


def _result(ray: Any, reference: Any) -> Any:
    """A finished task's result, or the :class:`TaskFailure` of a task Ray could not run to the end."""
    try:
        return ray.get(reference)
    except Exception as error:  # its worker or node died after every retry, or it was cancelled
        return failure_of(error)


def make_executor(workers: int | None, backend: str = "process", address: str | None = None) -> Executor:
    """The executor for a backend.

    Parameters
    ----------
    workers : int or None
        ``"process"``: worker processes, None meaning one per core (one runs
        serially). ``"ray"``: the most tasks in flight (:class:`RayExecutor`).
    backend : str
        ``"process"`` or ``"ray"``.
    address : str, optional
        The Ray cluster's address (``"ray"`` only).
    """
    if backend == "ray":
        return RayExecutor(address, workers)
    if backend != "process":
        raise ValueError(f"unknown executor {backend!r}; use one of {', '.join(BACKENDS)}")
    count = (os.cpu_count() or 1) if workers is None else workers
    if count <= 1:
        return SerialExecutor()
    return ProcessPoolExecutor(count)
