"""One OS file lock per output folder (a per-clip cache), so two processes never write it at once.

The lock file sits next to the folder (``PARENT/.NAME.lock``), so it outlives a folder that is
swapped for a rebuilt one. A writer takes it exclusively (:func:`acquire`; a second writer is
refused with a message naming the folder and the process that holds it); a reader asks
:func:`writer_active` and refuses to read a folder another process is writing. POSIX uses
``fcntl.flock``; Windows ``msvcrt.locking`` on a byte far past the text (the lock is then
exclusive for readers too, so :func:`writer_active` only probes it). Within one process the
lock is re-entrant: Blender's Analyze runs the estimate and the stabilization on one cache.
The OS drops the lock when the process dies, so a killed run never leaves a stale lock.
"""
from __future__ import annotations

import json
import logging
import os
import socket
import sys
import time
import weakref
from pathlib import Path

from ..errors import InputError, OutputError

log = logging.getLogger(__name__)

_WIN_OFFSET = 1 << 30  # msvcrt locks bytes: lock one far past the text so readers can read it
_HELD: "weakref.WeakValueDictionary[str, FolderLock]" = weakref.WeakValueDictionary()


def lock_path(folder: str | Path) -> Path:
    """The lock file of ``folder``: ``PARENT/.NAME.lock``."""
    folder = Path(os.path.realpath(folder))
    return folder.parent / f".{folder.name}.lock"


def _try_lock(fh, exclusive: bool) -> bool:
    """Take the OS lock without waiting; False when another process holds a conflicting one."""
    try:
        import fcntl
    except ImportError:  # Windows
        try:
            import msvcrt
        except ImportError:  # pragma: no cover - neither API: no locking
            return True
        fh.seek(_WIN_OFFSET)
        try:
            msvcrt.locking(fh.fileno(), msvcrt.LK_NBLCK, 1)
        except OSError:
            return False
        return True
    try:
        fcntl.flock(fh.fileno(), (fcntl.LOCK_EX if exclusive else fcntl.LOCK_SH) | fcntl.LOCK_NB)
    except BlockingIOError:
        return False
    except OSError as ex:  # a filesystem without locks (some network mounts): go on unlocked
        log.warning("cannot lock '%s' (%s); concurrent runs on it are not detected", fh.name, ex)
    return True


def _unlock(fh) -> None:
    try:
        import fcntl
    except ImportError:
        try:
            import msvcrt
        except ImportError:  # pragma: no cover
            return
        fh.seek(_WIN_OFFSET)
        try:
            msvcrt.locking(fh.fileno(), msvcrt.LK_UNLCK, 1)
        except OSError:  # pragma: no cover
            pass
        return
    fcntl.flock(fh.fileno(), fcntl.LOCK_UN)


def holder(path: Path) -> str:
    """What a lock file says about the process holding it ("pid 123 on host: rvr estimate ...")."""
    try:
        info = json.loads(path.read_text() or "{}")
    except (OSError, ValueError):
        info = {}
    if not isinstance(info, dict) or "pid" not in info:
        return "another process"
    return f"pid {info['pid']} on {info.get('host', '?')} since {info.get('since', '?')}: {info.get('command', '?')}"


class FolderLock:
    """A held exclusive lock (see the module docstring); released by :meth:`release` or when the
    last reference goes."""

    def __init__(self, key: str, path: Path, fh) -> None:
        self.key, self.path, self._fh = key, path, fh

    def release(self) -> None:
        """Give the lock back (idempotent); the holders sharing it in this process lose it too."""
        fh, self._fh = self._fh, None
        if fh is None:
            return
        try:
            fh.seek(0)
            fh.truncate()
            fh.flush()
            _unlock(fh)
        except (OSError, ValueError):  # pragma: no cover - closing releases it anyway (ValueError: the
            pass                       # garbage collector closed the file first, at a lock left unreleased)
        finally:
            fh.close()
            if _HELD.get(self.key) is self:
                del _HELD[self.key]

    def __del__(self) -> None:
        self.release()


def acquire(folder: str | Path, what: str = "the folder") -> FolderLock:
    """Lock ``folder`` for writing. Re-entrant in one process (the same lock is returned).

    Raises InputError naming the folder and the process holding the lock when another process
    writes it; OutputError when the lock file cannot be created (a read-only location).
    """
    key = os.path.realpath(folder)
    held = _HELD.get(key)
    if held is not None and held._fh is not None:
        return held
    path = lock_path(folder)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fh = open(path, "a+", encoding="utf-8")
    except OSError as ex:
        raise OutputError(f"cannot create the lock file '{path}' for {what} '{folder}': {ex}; choose a writable "
                          "location") from ex
    if not _try_lock(fh, exclusive=True):
        fh.close()
        raise InputError(f"{what} '{folder}' is being written by another process ({holder(path)}); wait until it "
                         "has finished (or stop it), or write to another folder")
    fh.seek(0)
    fh.truncate()
    fh.write(json.dumps({"pid": os.getpid(), "host": socket.gethostname(),
                         "since": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "command": " ".join(sys.argv)[:500]}))
    fh.flush()
    lock = FolderLock(key, path, fh)
    _HELD[key] = lock
    return lock


def writer_active(folder: str | Path) -> str | None:
    """Who writes ``folder`` in another process (:func:`holder`'s text), or None when nobody does
    (or this process does: its own jobs take turns)."""
    key = os.path.realpath(folder)
    held = _HELD.get(key)
    if held is not None and held._fh is not None:
        return None
    path = lock_path(folder)
    if not path.is_file():
        return None
    try:
        fh = open(path, "rb")
    except OSError:
        return None
    try:
        if _try_lock(fh, exclusive=False):
            _unlock(fh)
            return None
        return holder(path)
    finally:
        fh.close()
