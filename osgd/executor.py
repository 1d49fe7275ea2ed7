"""Executors: where the work items of a stage run.

An executor maps a picklable, module-level function over a list of tasks and
yields ``(index, outcome)`` pairs as tasks finish, in any order. An exception
raised by a task never escapes: it comes back as a :class:`TaskFailure` with
its traceback, so one failing item neither stops the others nor loses their
results. A distributed backend (Ray, Dask, a batch queue) implements the same
one-method interface.
"""

from __future__ import annotations

import concurrent.futures
import multiprocessing
import os
import traceback
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

from osgd.errors import describe


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


class ProcessPoolExecutor:
    """Runs tasks in a pool of local worker processes.

    Workers are started with ``spawn``: physics and rendering libraries
    (pybullet, EGL) hold process-wide state that must not be inherited by
    ``fork``. Each worker is reused across tasks, so a stage can keep one
    physics client per worker.

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
        if not tasks:
            return
        context = multiprocessing.get_context("spawn")
        with concurrent.futures.ProcessPoolExecutor(
            max_workers=min(self.workers, len(tasks)), mp_context=context
        ) as pool:
            futures = {pool.submit(call_safely, function, task): index for index, task in enumerate(tasks)}
            for future in concurrent.futures.as_completed(futures):
                index = futures[future]
                try:
                    yield index, future.result()
                except Exception as error:  # the worker died, or the result did not pickle
                    yield index, failure_of(error)


def make_executor(workers: int | None) -> Executor:
    """Serial for one worker, a process pool otherwise.

    Parameters
    ----------
    workers : int or None
        None means one worker per core.
    """
    count = (os.cpu_count() or 1) if workers is None else workers
    if count <= 1:
        return SerialExecutor()
    return ProcessPoolExecutor(count)
