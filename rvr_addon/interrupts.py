"""SIGTERM stops a command like Ctrl-C (SIGINT): one light module the ``rvr`` entry point uses.

``kill PID``, a cluster's scheduler or a container stop send SIGTERM. Python's default is to
die on the spot: no ``finally`` runs, so a render left its hidden ``*.tmp.mp4`` and an ffmpeg
encoder that went on finishing it. Within :func:`sigterm_as_interrupt` SIGTERM raises
:class:`Terminated`, a ``KeyboardInterrupt``, so every cleanup written for Ctrl-C runs (the
writers end their ffmpeg child and delete their temp files, caches flush, checkpoints are
saved); :func:`exit_status` then gives 143 (128 + SIGTERM) instead of Ctrl-C's 130. A second
SIGTERM while the first is being handled is ignored, so it cannot cut a cleanup short.
"""
from __future__ import annotations

import contextlib
import signal
import threading
from typing import Iterator

_state = {"terminated": False}


class Terminated(KeyboardInterrupt):
    """SIGTERM arrived; raised in the main thread like Ctrl-C's KeyboardInterrupt."""


def raise_terminated() -> None:
    """Record that SIGTERM arrived and raise :class:`Terminated` (for code that held the signal
    back, e.g. around a checkpoint write, and now acts on it)."""
    _state["terminated"] = True
    raise Terminated("terminated (SIGTERM)")


def _on_sigterm(signum, frame) -> None:
    if _state["terminated"]:
        return  # already stopping: let the cleanup finish
    raise_terminated()


def terminated() -> bool:
    """True once a SIGTERM arrived inside :func:`sigterm_as_interrupt` (since it was entered)."""
    return _state["terminated"]


def exit_status() -> int:
    """The exit status of a stopped command: 143 after SIGTERM, else 130 (Ctrl-C)."""
    return 128 + signal.SIGTERM if terminated() else 130


@contextlib.contextmanager
def sigterm_as_interrupt() -> Iterator[None]:
    """Within the block SIGTERM raises :class:`Terminated` (a KeyboardInterrupt). Main thread only
    (elsewhere signal handlers cannot be set: the block runs unchanged)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    _state["terminated"] = False
    previous = signal.signal(signal.SIGTERM, _on_sigterm)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)
