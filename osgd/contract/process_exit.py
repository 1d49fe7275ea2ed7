"""Ending a command-line process without the native libraries' teardown.

After a command has done its work, CPython's finalisation frees the modules
and the C runtime then runs the native libraries' static destructors. Arrow's
thread pools and pyarrow's S3 file system (the AWS SDK's threads) can be torn
down there while one of their threads is still alive; a ``std::thread``
destroyed in that state calls ``std::terminate``, and a run that wrote every
shard and printed its summary exits with SIGABRT and "terminate called
without an active exception" (apache/arrow issues 34314 and 41087). It is
rare and depends on thread timing, not on the data. At libc's ``exit()``,
after the interpreter's finalisation and before the static destructors,
Arrow's thread-pool workers (``std::thread``) can still be waiting for work.

:func:`exit_process` runs the clean-up that a normal exit runs in Python (the
threads that still work are waited for, then the ``atexit`` handlers: the
log's flush, pyarrow's S3 finalisation, Ray's shutdown, the worker pools'),
flushes stdout and stderr, and ends the process with :func:`os._exit`, which
skips only the native teardown. Every file osgd writes is closed (and renamed
into place) before a command returns, so nothing written is lost.

Entry points call it; library code never does.
"""

from __future__ import annotations

import atexit
import contextlib
import gc
import os
import sys
import threading
from collections.abc import Callable
from typing import NoReturn


def exit_status(code: object) -> int:
    """The process status ``sys.exit(code)`` gives: None 0, an int itself, anything else (a message) 1."""
    if code is None:
        return 0
    return code if isinstance(code, int) else 1


def exit_process(code: object = 0) -> NoReturn:
    """End the process with ``code`` as :func:`sys.exit` would, without the native teardown.

    Parameters
    ----------
    code : object
        What :class:`SystemExit` carries: None (status 0), an int (the
        status), or a message (printed to stderr; status 1).
    """
    status = exit_status(code)
    if code is not None and not isinstance(code, int):
        with contextlib.suppress(OSError, ValueError):
            print(code, file=sys.stderr)
    main = threading.main_thread()
    for thread in threading.enumerate():
        if thread is not main and not thread.daemon:
            thread.join()
    gc.collect()  # native objects held only by cycles go while their libraries still run
    atexit._run_exitfuncs()  # what Python's own finalisation calls (no public name)
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(OSError, ValueError, AttributeError):
            stream.flush()
    os._exit(status)


def run_then_exit(command: Callable[[], object]) -> NoReturn:
    """Run a console command (a Click app ends in :class:`SystemExit`), then :func:`exit_process` with its status.

    Any other exception propagates, with its traceback, through Python's own exit.
    """
    try:
        command()
    except SystemExit as end:
        exit_process(end.code)
    exit_process(0)
