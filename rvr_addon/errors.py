"""Domain errors of the engine. Every message names the file or setting at fault and the fix."""
from __future__ import annotations

import errno
import os


class RvrError(Exception):
    """Base class of every error the engine raises on purpose (bad input, cancel, ...)."""


class InputError(RvrError, ValueError):
    """A file or setting given by the user is missing, unreadable or inconsistent."""


class VideoOpenError(InputError):
    """A video file or image sequence cannot be opened or decoded."""


class OutputError(RvrError):
    """An output cannot be written (no encoder, no permission, disk full)."""


class Cancelled(RvrError):
    """The user cancelled a job; partial outputs were removed."""


def output_error(path, ex: OSError, what: str = "write") -> OutputError:
    """An :class:`OutputError` for ``ex`` raised while trying to ``what`` ``path``: names the file,
    says why in words and how to fix it (full disk, no permission, a file where a folder should
    be). Use as ``raise output_error(path, ex) from ex``."""
    code = getattr(ex, "errno", None)
    reason = getattr(ex, "strerror", None) or str(ex)
    if code in (errno.ENOSPC, getattr(errno, "EDQUOT", -1)):
        fix = "the disk is full: free some space or choose an output on another disk"
    elif code in (errno.EACCES, errno.EPERM, errno.EROFS):
        fix = "the location is not writable: choose a writable output folder or fix its permissions"
    elif code in (errno.ENOTDIR, errno.EEXIST) and not _is_dir(getattr(ex, "filename", None)):
        fix = "a part of the path is a file, not a folder: choose another output location"
    else:
        fix = "check the output location (free space, permissions) or choose another one"
    return OutputError(f"cannot {what} '{path}': {reason}; {fix} (an earlier result there is kept)")


def _is_dir(name) -> bool:
    """True when ``name`` is an existing folder."""
    return bool(name) and os.path.isdir(name)
