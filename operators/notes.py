"""Warnings the engine logs during a job, shown in Blender's UI: a missing optional piece (no
webrtcvad: energy voice activity; no MediaPipe: no people cue; no torch: the ONNX networks)
degrades with a WARNING report naming the fix, never a traceback, and is not only in the console.

:func:`start` (when a job is prepared) empties the collector and hooks it on the engine's logger
(``<extension>.rvr_addon``); :func:`report` (when the job's result is applied) reports each
distinct warning once through the operator and empties it again. No bpy import: the operator
passes its ``report``.
"""
from __future__ import annotations

import logging
from typing import Callable

MAX_NOTES = 8
"""At most this many distinct warnings are reported after one job."""


class _Collector(logging.Handler):
    """Keeps the distinct WARNING-or-worse messages logged since the last :func:`start`."""

    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.messages: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        try:
            text = record.getMessage()
        except Exception:  # noqa: BLE001 - a bad format string must not break the job
            return
        if text not in self.messages and len(self.messages) < MAX_NOTES:
            self.messages.append(text)


_COLLECTOR = _Collector()


def _engine_logger() -> logging.Logger:
    return logging.getLogger(__name__.rsplit(".", 2)[0] + ".rvr_addon")


def start() -> None:
    """Forget earlier warnings and collect the engine's from now on."""
    logger = _engine_logger()
    if _COLLECTOR not in logger.handlers:
        logger.addHandler(_COLLECTOR)
    _COLLECTOR.messages.clear()


def take() -> list[str]:
    """The warnings collected since :func:`start`, emptied."""
    out = list(_COLLECTOR.messages)
    _COLLECTOR.messages.clear()
    return out


def report(reporter: Callable[[set, str], None]) -> list[str]:
    """Report each collected warning once as a WARNING (``reporter`` is an operator's ``report``)."""
    notes = take()
    for text in notes:
        reporter({"WARNING"}, text)
    return notes


def stop() -> None:
    """Unhook the collector (the add-on's unregister)."""
    logger = _engine_logger()
    if _COLLECTOR in logger.handlers:
        logger.removeHandler(_COLLECTOR)
    _COLLECTOR.messages.clear()
