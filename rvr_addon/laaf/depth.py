"""Disparity for LAAF: a per-clip cache (``rvr estimate`` output, stabilised channel preferred)
or any depth source ``rvr render --depth`` accepts (``io.maps``), resampled to the analysis
size with values unchanged (DESIGN units of the native width).
"""
from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np

from ..errors import InputError

log = logging.getLogger(__name__)

# channel names a stabilised disparity may carry in a cache EXR (temporal stage), best first;
# "S.D" is what `rvr stabilize` writes (rvr_addon.estimate.cache.STABILIZED_CHANNELS)
STABILIZED_CHANNELS = ("S.D", "D_stab", "Ds", "D.stab", "D.stabilized", "stab.D", "stabilized.D", "Dstab")


def pick_disparity_channel(channels: dict[str, np.ndarray]) -> str:
    """Name of the disparity channel to use: a stabilised one if present, else ``D``.

    Raises InputError listing the channels when there is neither."""
    for name in STABILIZED_CHANNELS:
        if name in channels:
            return name
    for name in channels:
        if "stab" in name.lower() and (name.startswith("D") or name.endswith(".D")):
            return name
    if "D" in channels:
        return "D"
    raise InputError(f"cache EXR has channels {sorted(channels)} but no D; re-run `rvr estimate`")


def is_cache(path: Path) -> bool:
    """True if ``path`` is an ``rvr estimate`` cache folder (meta.json with an rvr-laaf-cache format)."""
    meta = Path(path) / "meta.json"
    if not meta.is_file():
        return False
    try:
        return str(json.loads(meta.read_text()).get("format", "")).startswith("rvr-laaf-cache/")
    except (OSError, ValueError, AttributeError):
        return False


class DisparitySource:
    """get(index, size) -> (h, w) float32 disparity of clip frame ``index`` (0-based) at ``size``.

    cache: an ``rvr estimate`` cache folder; depth: a file/folder/pattern for ``io.maps``
    (scale/offset applied). Exactly one must be given.
    """

    def __init__(self, cache: str | Path | None = None, depth: str | Path | None = None,
                 scale: float = 1.0, offset: float = 0.0) -> None:
        if (cache is None) == (depth is None):
            raise InputError("give exactly one disparity source: --cache CACHE or --depth DEPTH")
        self.channel = None
        if cache is not None:
            self.cache = Path(cache)
            if not self.cache.is_dir():
                raise InputError(f"cache folder '{self.cache}' not found; create it with `rvr estimate INPUT -o "
                                 f"{self.cache}` or pass --depth MAPS")
            if not is_cache(self.cache):
                raise InputError(f"'{self.cache}' has no rvr cache meta.json; create it with `rvr estimate` "
                                 "or pass the maps with --depth")
            self.maps = None
            self.label = f"cache '{self.cache}'"
            from ..estimate.cache import stabilized_complete

            meta = json.loads((self.cache / "meta.json").read_text())
            # the temporally stabilized channel when every frame has it (rvr stabilize), else raw D
            self.channel = "S.D" if stabilized_complete(meta) else None
        else:
            from ..io.maps import open_map_sequence

            self.cache = None
            self.maps = open_map_sequence(depth, kind="disparity", scale=scale, offset=offset)
            self.label = self.maps.label

    def check_length(self, n_frames: int, start: int = 0) -> None:
        """Raise InputError if maps for frames start..start+n_frames-1 are missing."""
        if self.maps is not None:
            self.maps.check_length(start + n_frames)
        else:
            from ..estimate.cache import frame_path

            for i in (start, start + n_frames - 1):
                if not frame_path(self.cache, i).is_file():
                    raise InputError(f"{self.label} lacks frame {i} ('{frame_path(self.cache, i).name}'); "
                                     "run `rvr estimate` over the whole clip first")

    def get(self, index: int, size: tuple[int, int]) -> np.ndarray:
        """Disparity of frame ``index`` resampled to size (w, h); values unchanged."""
        import cv2

        if self.maps is not None:
            d = self.maps.get(index if not self.maps.static else 0)
        else:
            from ..estimate.cache import frame_path
            from ..io.exr import read_exr

            path = frame_path(self.cache, index)
            if not path.is_file():
                raise InputError(f"{self.label} lacks frame {index} ('{path.name}'); run `rvr estimate` first")
            try:
                channels = read_exr(path)
            except InputError as ex:  # truncated or corrupt: the cache's own fix
                raise InputError(f"{ex} It belongs to the {self.label}: run `rvr estimate CLIP -o {self.cache}` again "
                                 "to recompute it.") from ex
            name = self.channel if self.channel in channels else pick_disparity_channel(channels)
            if self.channel is None:
                self.channel = name
                log.info("reading disparity channel %s of %s", name, self.label)
            d = channels[name]
            if not np.isfinite(d).all():
                from ..io.maps import fill_nonfinite

                d, _ = fill_nonfinite(d)
        if (d.shape[1], d.shape[0]) != tuple(size):
            d = cv2.resize(d, tuple(size), interpolation=cv2.INTER_AREA if d.shape[1] > size[0] else cv2.INTER_LINEAR)
        return np.ascontiguousarray(d, dtype=np.float32)
