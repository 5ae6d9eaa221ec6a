"""Write a frame's results in the background while the next frame is computed.

Cache frame files are EXR files of 4-9 float channels (0.05-0.11 s to encode at 1080p; OpenEXR
encodes without holding the GIL). :class:`WriteBehind` runs each write in one background
thread, at most one at a time and in order: a write starts only once the previous one has
ended, and the previous one's error is raised by the next :meth:`~WriteBehind.submit` or by
:meth:`~WriteBehind.wait`, so a failure still stops the job, one frame later. What a write is
given must not be changed by the caller afterwards.
"""
from __future__ import annotations

from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any, Callable


class WriteBehind:
    """One background writer: ``submit(fn, *args)`` waits for the write in flight, then starts
    ``fn(*args)``; ``wait()`` waits for it (raising its error); ``close()`` waits and ends the thread."""

    def __init__(self) -> None:
        self._pool: ThreadPoolExecutor | None = None
        self._pending: Future | None = None
        self.submitted = 0
        """Writes started so far (for tests and benchmarks)."""

    def submit(self, fn: Callable[..., Any], *args: Any, **kwargs: Any) -> None:
        """Start ``fn(*args, **kwargs)`` once the write in flight has ended (its error is raised here)."""
        self.wait()
        if self._pool is None:
            self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="rvr-writebehind")
        self._pending = self._pool.submit(fn, *args, **kwargs)
        self.submitted += 1

    def wait(self) -> None:
        """Wait for the write in flight, if any; its error is raised here."""
        pending, self._pending = self._pending, None
        if pending is not None:
            pending.result()

    def close(self) -> None:
        """Wait for the write in flight (its error is raised) and end the thread."""
        try:
            self.wait()
        finally:
            if self._pool is not None:
                self._pool.shutdown(wait=True)
                self._pool = None

    def finish(self) -> BaseException | None:
        """:meth:`close`, returning the last write's error instead of raising it (a job closes
        its cache first, uncommitted, then raises it)."""
        try:
            self.close()
        except BaseException as ex:  # noqa: BLE001 - handed to the caller
            return ex
        return None
