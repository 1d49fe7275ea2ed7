"""Task functions for the Ray tests, in a module Ray workers can import (tests/ is on their PYTHONPATH).

A task function must be importable where it runs: Ray pickles a
module-level function by reference, as the process pool does.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

#: The variables a worker must hold for the bytes a local worker builds.
PINNED = ("PYTHONHASHSEED", "OPENBLAS_NUM_THREADS", "NPY_DISABLE_CPU_FEATURES", "OPENBLAS_CORETYPE")


def worker_facts(task: int) -> dict[str, Any]:
    """Where a task ran: the worker's process id and node, and its kernel variables."""
    import ray  # noqa: PLC0415 (runs in a Ray worker)

    return {
        "task": task,
        "pid": os.getpid(),
        "node": ray.get_runtime_context().get_node_id(),
        "environment": {name: os.environ.get(name) for name in PINNED},
    }


def fail_on_odd(task: int) -> int:
    """Raise for odd tasks; the square of even ones."""
    if task % 2:
        raise ValueError(f"task {task} is odd")
    return task * task


def traced(trace: str, function: Callable[[Any], Any], task: Any, hold: tuple[str, str] | None = None) -> Any:
    """Append ``<node id> <shard key> <stage module>`` to the file ``trace`` as a build starts, then run it.

    ``hold`` = (node id, stage module, e.g. ``"osgd.checks"``): a build of that
    stage on that node stops after its line is written, as if it were a long
    one, until the node is killed (at most five minutes, then it goes on), so
    that a test can kill the node in the middle of it whatever the timing.
    """
    import ray  # noqa: PLC0415

    node = ray.get_runtime_context().get_node_id()
    module = getattr(task, "stage_ref", "-").split(":")[0]
    with Path(trace).open("a") as handle:
        handle.write(f"{node} {getattr(task, 'key', task)} {module}\n")
    if hold is not None and (node, module) == hold:
        time.sleep(300)
    return function(task)
