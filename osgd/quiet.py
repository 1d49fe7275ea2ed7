"""Keeping what C libraries print off the command line's output.

pybullet prints "pybullet build time: ..." to stderr when it is imported, in
the main process and in every worker, and its EGL plugin prints its GL set-up
when it loads, renders and unloads. The CLI's progress bars and summaries are
what a user reads, so osgd imports pybullet through :func:`import_pybullet`
(by way of :func:`osgd.physics.pybullet_module`, on first use: never when a
module is imported) and wraps the plugin's calls in :func:`native_output_hidden`.
"""

from __future__ import annotations

import contextlib
import ctypes
import importlib
import os
import sys
from collections.abc import Iterator
from types import ModuleType


@contextlib.contextmanager
def native_output_hidden(descriptors: tuple[int, ...] = (1,)) -> Iterator[None]:
    """Send what is written to these file descriptors to /dev/null for a while.

    Parameters
    ----------
    descriptors : tuple of int
        1 for stdout, 2 for stderr. Python's own ``sys.stdout`` and
        ``sys.stderr`` are flushed first, so nothing of theirs is lost.
    """
    sys.stdout.flush()
    sys.stderr.flush()
    saved = [os.dup(descriptor) for descriptor in descriptors]
    try:
        with open(os.devnull, "wb") as devnull:
            for descriptor in descriptors:
                os.dup2(devnull.fileno(), descriptor)
        yield
    finally:
        # C's stdio buffers what it prints when the output is a pipe or a file:
        # flush it while it still goes to /dev/null.
        _flush_c_stdio()
        for descriptor, copy in zip(descriptors, saved, strict=True):
            os.dup2(copy, descriptor)
            os.close(copy)


def _flush_c_stdio() -> None:
    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL(None).fflush(None)


def import_pybullet() -> ModuleType:
    """The pybullet module, imported without its build-time banner."""
    if "pybullet" not in sys.modules:
        with native_output_hidden((1, 2)):  # the banner goes to stderr
            importlib.import_module("pybullet")
    return sys.modules["pybullet"]
