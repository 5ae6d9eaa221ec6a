"""``rvr stabilize CACHE``: the temporal filter over a per-clip cache, resumable.

Reads the raw D and E of every recorded frame of a cache written by ``rvr estimate``
(:class:`rvr_addon.estimate.cache.ClipCache`), the clip's frames for the optical flow (the
source recorded in ``meta.json``, or ``--input``), runs :class:`.filter.TemporalFilter` and
adds the stabilized channels S.D, S.E.R/G/B and S.C to each frame's EXR (the raw channels
stay). ``meta.json``'s ``stabilized`` record holds the filter settings and the frames done:

* a rerun with the same settings skips the frames done and resumes after the last one; the
  filter is warmed up on the P frames before it, so the result equals an uninterrupted run;
* a rerun with other settings (or ``--force``) recomputes every frame; when the cache is
  completely stabilized, that happens in a copy beside it (hard links,
  :meth:`~rvr_addon.estimate.cache.ClipCache.fork`) put in its place only once every frame is
  done, so a cancel leaves the earlier stabilized cache as it was (a rerun resumes the copy);
* re-estimating a raw frame drops the record (the cache does this).

Recorded frames that are not consecutive (estimated in several ranges) are filtered as
separate segments. The job exposes ``step()`` / ``progress`` / ``cancel()`` like the other
jobs, and :meth:`StabilizeJob.run` shows a tqdm bar.
"""
from __future__ import annotations

import json
import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator

import numpy as np

from .. import __version__
from ..errors import InputError
from ..io.readahead import ReadAhead
from ..io.writebehind import WriteBehind
from .filter import TemporalFilter, TemporalSettings

log = logging.getLogger(__name__)


@dataclass
class StabilizeSettings:
    """What ``rvr stabilize`` takes: the cache folder, the video for the flow (None = the
    source recorded in meta.json), the filter settings, and force (recompute every frame).

    start / stop: stabilize only the frames start..stop-1 (0-based clip indices; stop None =
    to the end). The window still reads the P frames before and the F frames after them from
    the cache, so the result equals a run over the whole clip (``rvr batch`` chunks a clip so).
    """

    cache: Path
    input: Path | None = None
    temporal: TemporalSettings = field(default_factory=TemporalSettings)
    force: bool = False
    start: int = 0
    stop: int | None = None


def segments(indices: list[int]) -> list[tuple[int, int]]:
    """Runs of consecutive indices as [start, stop) pairs: [0, 1, 2, 5, 6] -> [(0, 3), (5, 7)]."""
    out: list[tuple[int, int]] = []
    for i in indices:
        if out and i == out[-1][1]:
            out[-1] = (out[-1][0], i + 1)
        else:
            out.append((i, i + 1))
    return out


class StabilizeJob:
    """Stabilize a cache in place (see the module docstring)."""

    def __init__(self, settings: StabilizeSettings) -> None:
        from ..estimate.cache import ClipCache, check_cache_source
        from ..io.paths import check_outputs
        from ..io.video import probe_clip

        self.settings = s = settings
        check_outputs("stabilize", [("cache", s.cache)], [("video", s.input)])
        self.cache = ClipCache.open_existing(s.cache)
        recorded = self.cache.info.get("source") or {}
        source = s.input if s.input is not None else recorded.get("path")
        if source is None:
            raise InputError(f"the cache '{s.cache}' does not record its source video; pass --input VIDEO "
                             "(the clip it was estimated from)")
        self.source = Path(source)
        if not self.source.exists() and s.input is None:
            raise InputError(f"the cache's source '{self.source}' (recorded in {Path(s.cache) / 'meta.json'}) was not "
                             "found; pass --input VIDEO with the clip the cache was estimated from")
        self.clip = probe_clip(self.source)
        self.resolution = tuple(int(v) for v in self.cache.key["resolution"])
        indices = self.cache.frame_indices()
        if indices[-1] >= self.clip.frame_count:
            raise InputError(f"the cache '{s.cache}' holds frames up to {indices[-1]} but '{self.source}' has only "
                             f"{self.clip.frame_count} frames; pass --input with the clip the cache was estimated from")
        check_cache_source(s.cache, self.source, self.clip, command="stabilize")  # another clip's flow: refused
        if (self.clip.width, self.clip.height) != self.resolution:
            log.info("'%s' is %dx%d, the cache %dx%d: flows are computed on the frames and resampled to the cache",
                     self.source, self.clip.width, self.clip.height, *self.resolution)
        record = {**s.temporal.to_dict(), "engine_version": __version__}
        old = self.cache.stabilized
        if self.cache.stabilized_complete() and (s.force or old["settings"] != json.loads(json.dumps(record))):
            # a complete stabilized cache stays as it is until the new one is complete
            self.cache = self.cache.fork({"stabilized": record, "force": s.force},
                                         "stabilized with " + ("--force" if s.force else "other settings"))
        if s.force:
            self.cache.stabilized = None
        self.cache.begin_stabilized(record)
        stop = indices[-1] + 1 if s.stop is None else s.stop
        if s.start < 0 or stop <= s.start:
            raise InputError(f"stabilize range {s.start}..{stop} is empty; give 0 <= start < stop")
        self.todo = {i for i in indices if s.start <= i < stop and not self.cache.has_stabilized(i)}
        self.plan: list[tuple[int, int]] = []  # (stream start, stop) per segment with work
        for a, b in segments(indices):
            missing = [i for i in range(a, b) if i in self.todo]
            if missing:  # P frames of warm-up before, F frames of future after
                self.plan.append((max(a, missing[0] - s.temporal.past), min(b, missing[-1] + 1 + s.temporal.future)))
        self.total = sum(b - a for a, b in self.plan)
        self.done = 0
        self.written = 0
        self.reused = len(indices) - len(self.todo)
        self.text = f"stabilizing {len(self.todo)} of {len(indices)} frames of {self.source.name}"
        self._stream: Iterator[tuple[int, np.ndarray]] | None = None
        self._filter: TemporalFilter | None = None
        self._held: dict[int, dict[str, np.ndarray]] = {}  # channels read, until their frame is written
        self._streamed = {i for a, b in self.plan for i in range(a, b)}
        self._reads = ReadAhead(self._read_valid)  # the next frame's file is read while this one is filtered
        self._writes = WriteBehind()
        self._finished = not self.plan
        if self._finished:
            self.cache.commit()
            self.cache.close()
            self.text = f"all {len(indices)} frames already stabilized with these settings (--force recomputes)"

    @property
    def progress(self) -> float:
        """Fraction of the frames to stream (warm-up included) done, 0..1."""
        return self.done / self.total if self.total else 1.0

    def _frames(self) -> Iterator[tuple[int, np.ndarray]]:
        from ..io.video import iter_frames

        for a, b in self.plan:
            for k, frame in enumerate(iter_frames(self.source, start=a, stop=b)):
                yield a + k, frame
            yield -1, np.empty(0)  # end of a segment

    def _read_valid(self, index: int) -> dict[str, np.ndarray] | None:
        return self.cache.read_valid(index, self.resolution)

    def _raw(self, index: int) -> tuple[np.ndarray, np.ndarray]:
        from ..estimate.cache import frame_path, split_channels

        raw = self._reads.get(index, index + 1 if index + 1 in self._streamed else None)
        if raw is None:
            raise InputError(f"frame {index} of the cache ('{frame_path(self.cache.folder, index)}') is missing, "
                             "truncated or corrupt; run `rvr estimate` with the same settings again to recompute it, "
                             "then `rvr stabilize` again")
        if index in self.todo:  # written back with its stabilized channels (no second read)
            self._held[index] = raw
        return split_channels(raw)

    def step(self) -> bool:
        """Stream the next frame through the filter and store what it returns; False at the end."""
        if self._finished:
            return False
        if self._stream is None:
            self._stream = self._frames()
            self._filter = TemporalFilter(self.settings.temporal)
        item = next(self._stream, None)
        if item is None:
            self._close()
            return False
        index, frame = item
        if index < 0:
            outputs = self._filter.finish()
        else:
            d, e = self._raw(index)
            outputs = self._filter.push(index, frame, d, e)
            self.done += 1
        for t, d_s, e_s, conf in outputs:
            if t in self.todo:  # written while the next frame is filtered (a write's error stops the next step)
                self._writes.submit(self._store, t, d_s, e_s, conf, self._held.pop(t, None))
                self.todo.discard(t)
        return True

    def _store(self, t: int, d_s: np.ndarray, e_s: np.ndarray, conf: np.ndarray,
               existing: dict[str, np.ndarray] | None) -> None:
        self.cache.write_stabilized(t, d_s, e_s, conf, existing=existing)
        self.written += 1

    def _close(self) -> None:
        failed = self._writes.finish()  # the last frame's write; a failed one keeps the cache uncommitted
        if self._stream is not None:
            self._stream.close()
        self._reads.close()
        self._held.clear()
        self.cache.flush()
        if not self.todo and failed is None:
            self.cache.commit()  # a fork beside the cache (other settings) replaces it only now
        self.cache.close()
        self._finished = True
        cuts = len(self._filter.cuts) if self._filter is not None else 0
        self.text = (f"stabilized {self.written} frames, kept {self.reused} already stabilized"
                     + (f"; the window restarted {cuts} time(s) (scene cuts / size changes, see the log)" if cuts else ""))
        if failed is not None:
            raise failed

    def cancel(self) -> None:
        """Stop; frames stored so far stay valid (meta.json is flushed). After the end it does nothing."""
        if self._finished:
            return
        self._close()
        self.text = f"cancelled after {self.written} stabilized frames"

    def run(self, progress: bool = True) -> None:
        """Run to the end with a tqdm bar; Ctrl-C keeps what is stored, then re-raises."""
        from tqdm import tqdm

        with tqdm(total=self.total, unit="frame", desc="stabilize", disable=not progress) as bar:
            try:
                while self.step():
                    bar.update(self.done - bar.n)
                bar.update(self.total - bar.n)
            except BaseException:
                self.cancel()
                raise
