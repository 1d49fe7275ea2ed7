"""Progress as plain lines, for output that is not a terminal (a CI log, ``nohup``).

A terminal gets live progress bars (:mod:`rich`); a file would get nothing
from them until a stage ends. :class:`LineProgress` writes one line when a
stage starts, one every ``interval`` seconds while it runs (items done of
all, how they went, the rate and the time left) and one when it ends.
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from types import TracebackType

#: Seconds between two progress lines; ``OSGD_PROGRESS_INTERVAL`` overrides it.
DEFAULT_INTERVAL = 30.0


def progress_interval() -> float:
    """The interval from ``OSGD_PROGRESS_INTERVAL`` (seconds, > 0), else :data:`DEFAULT_INTERVAL`."""
    try:
        value = float(os.environ.get("OSGD_PROGRESS_INTERVAL", DEFAULT_INTERVAL))
    except ValueError:
        return DEFAULT_INTERVAL
    return value if value > 0 else DEFAULT_INTERVAL


def format_duration(seconds: float) -> str:
    """``"45s"``, ``"3m05s"`` or ``"1h02m"``."""
    seconds = max(0, round(seconds))
    if seconds < 60:
        return f"{seconds}s"
    if seconds < 3600:
        return f"{seconds // 60}m{seconds % 60:02d}s"
    return f"{seconds // 3600}h{seconds % 3600 // 60:02d}m"


@dataclass
class _StageProgress:
    name: str
    total: int
    started: float
    counts: dict[str, int] = field(default_factory=lambda: {"built": 0, "reused": 0, "failed": 0})

    @property
    def done(self) -> int:
        return sum(self.counts.values())

    def line(self, now: float, finished: bool = False) -> str:
        if not self.done and not finished:
            return f"{self.name}: {self.total} items"
        elapsed = now - self.started
        how = ", ".join(f"{count} {label}" for label, count in self.counts.items() if count) or "none yet"
        head = f"{self.name}: {self.done}/{self.total} items ({how})"
        if finished:
            return f"{head}, done in {format_duration(elapsed)}"
        rate = self.done / elapsed if elapsed > 0 else 0.0
        left = format_duration((self.total - self.done) / rate) if rate > 0 else "unknown"
        return f"{head}, {rate:.2f} items/s, time left {left}, elapsed {format_duration(elapsed)}"


class LineProgress:
    """Progress lines at a steady pace; a context manager that runs a timer thread.

    Parameters
    ----------
    write : callable(str)
        Writes one line.
    interval : float, optional
        Seconds between lines while a stage runs; default :func:`progress_interval`.
    clock : callable, optional
        Monotonic seconds (``time.monotonic``).
    """

    def __init__(
        self, write: Callable[[str], None], interval: float | None = None, clock: Callable[[], float] = time.monotonic
    ) -> None:
        self._write = write
        self._interval = progress_interval() if interval is None else interval
        self._clock = clock
        self._current: _StageProgress | None = None
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._tick, name="osgd-progress", daemon=True)

    def __enter__(self) -> LineProgress:
        self._thread.start()
        return self

    def __exit__(
        self, kind: type[BaseException] | None, error: BaseException | None, trace: TracebackType | None
    ) -> None:
        if error is None:  # a stage cut short by an error did not finish: no closing line
            self._finish_stage()
        self._stop.set()
        self._thread.join()

    def on_stage(self, name: str, total: int) -> None:
        """A stage starts with ``total`` items: ends the one before, writes a first line."""
        self._finish_stage()
        with self._lock:
            self._current = _StageProgress(name, total, self._clock())
            self._write(self._current.line(self._clock()))

    def on_item(self, name: str, item: str, status: str) -> None:
        """One item of the running stage is ``"built"``, ``"reused"`` or ``"failed"``."""
        with self._lock:
            if self._current is not None and self._current.name == name:
                self._current.counts[status] = self._current.counts.get(status, 0) + 1

    def _finish_stage(self) -> None:
        with self._lock:
            if self._current is not None:
                self._write(self._current.line(self._clock(), finished=True))
                self._current = None

    def _tick(self) -> None:
        while not self._stop.wait(self._interval):
            with self._lock:
                if self._current is not None:
                    self._write(self._current.line(self._clock()))
