"""Domain errors of the engine. Every message names the file or setting at fault and the fix."""
from __future__ import annotations


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
