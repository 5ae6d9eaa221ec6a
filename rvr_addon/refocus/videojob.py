"""The shape the refocus stages that write one video share: frames in, one H.264 MP4 out, step by
step (Job protocol), the file appearing only when complete (:class:`~rvr_addon.io.writer.VideoWriter`)."""
from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Any, Iterator

import numpy as np

from ..io.writer import VideoWriter


class VideoWriteJob(ABC):
    """Base of a job writing ``total`` frames: subclasses give :meth:`open` (the items and the
    writer) and :meth:`frame` (one item -> one uint8 RGB frame); ``what`` names the output in
    the cancel text."""

    what = "video"

    def __init__(self, total: int, text: str) -> None:
        self.total = total
        self.done = 0
        self.text = text
        self._items: Iterator[Any] | None = None
        self._writer: VideoWriter | None = None
        self._finished = False

    @property
    def progress(self) -> float:
        """Fraction of frames written, 0..1."""
        return self.done / self.total if self.total else 1.0

    @abstractmethod
    def open(self) -> tuple[Iterator[Any], VideoWriter]:
        """(the items to write, in order; the writer of the output)."""

    @abstractmethod
    def frame(self, item: Any) -> np.ndarray:
        """The (H, W, 3) uint8 RGB frame written for ``item``."""

    def ended_early(self) -> None:
        """Called when the items end before ``total``: raise to refuse a short output (default: keep it)."""

    def step(self) -> bool:
        """Write the next frame; False once the video is complete."""
        if self._finished:
            return False
        try:
            if self._items is None:
                self._items, self._writer = self.open()
            item = next(self._items, None)
            if item is None:
                self.ended_early()
            else:
                self._writer.write(np.ascontiguousarray(self.frame(item)))
                self.done += 1
            if item is None or self.done == self.total:
                self._writer.close()
                self._writer = None
                self._finished = True
                return False
            return True
        except BaseException:
            self.cancel()
            raise

    def cancel(self) -> None:
        """Stop; no partial file is left at the output path. Idempotent; after the end it changes
        nothing."""
        if self._finished:
            return
        if self._writer is not None:
            self._writer.abort()
            self._writer = None
        self._finished = True
        self.text = f"cancelled after {self.done} of {self.total} frames; no {self.what} written"
