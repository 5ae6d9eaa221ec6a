"""Read the next frame's maps while the current frame is being worked on.

The per-frame stages read their inputs in order (cache EXR files of 9 float channels take
0.04-0.08 s each at 1080p; OpenEXR decodes without holding the GIL). :class:`ReadAhead`
calls the stage's own read function for the *next* index in one background thread, so the
read overlaps the stage's computation on the other core. Values, and errors, are those of the
read itself: an error of a read ahead is raised when (and only if) its index is asked for.
"""
from __future__ import annotations

from concurrent.futures import Future, ThreadPoolExecutor
from typing import Callable, Generic, TypeVar

K = TypeVar("K")
V = TypeVar("V")


class ReadAhead(Generic[K, V]):
    """``get(key, then)`` returns ``read(key)`` (read ahead when the previous call named this
    key as ``then``) and starts ``read(then)`` in the background. One read at a time runs, in
    the background thread once any has been started there, so ``read`` need not be
    thread-safe against itself; the caller must not use what ``read`` uses meanwhile."""

    def __init__(self, read: Callable[[K], V]) -> None:
        self._read = read
        self._pool: ThreadPoolExecutor | None = None
        self._pending: tuple[K, Future] | None = None
        self.ahead = 0
        """How many values came from a read ahead (for tests and benchmarks)."""

    def get(self, key: K, then: K | None = None) -> V:
        """``read(key)``; with ``then``, ``read(then)`` starts in the background."""
        pending, self._pending = self._pending, None
        if pending is not None and pending[0] == key:
            value = pending[1].result()  # its exception, if any, is raised here
            self.ahead += 1
        else:
            if pending is not None:  # not the key asked for: wait, so reads never overlap
                pending[1].exception()
            value = self._read(key)
        if then is not None:
            if self._pool is None:
                self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="rvr-readahead")
            self._pending = (then, self._pool.submit(self._read, then))
        return value

    def close(self) -> None:
        """Wait for a read still running, drop its value; later gets read in the caller's thread."""
        pending, self._pending = self._pending, None
        if pending is not None:
            pending[1].exception()
        if self._pool is not None:
            self._pool.shutdown(wait=True)
            self._pool = None
