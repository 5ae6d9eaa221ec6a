"""Per-frame 2-D maps supplied by the user: disparity D or HDR exponent E.

Sources: one file (used for every frame), a folder, a glob or a printf pattern of EXR, PNG,
TIFF, NPY or NPZ files, or one NPY/NPZ stack of N maps, shape (N, H, W) (HDR: also
(N, H, W, 3)), read as frames 0..N-1 (a 3-D array whose last axis is 1, 3 or 4 is one map
with channels). A per-clip cache folder (``rvr estimate``) is read as recorded in its
meta.json: a frame whose file is not the one recorded is refused, and so is a cache that
another process is writing (:mod:`.lock`).

Values are `raw * scale + offset`, with 8/16-bit images first normalised to [0, 1].
Disparity values are in px of blur radius at aperture 1 at the clip's native width, whatever
the map's own resolution: resampling a map to the frame size does NOT rescale its values
(scale them with `scale=` if your maps were made at another width).
"""
from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from ..errors import InputError
from .paths import expand_sequence

log = logging.getLogger(__name__)

MAP_EXTENSIONS = (".exr", ".png", ".tif", ".tiff", ".npy", ".npz")
DISPARITY_CHANNELS = ("D", "disparity", "Z", "Y", "R", "V")
_KIND_NAMES = {"disparity": "depth", "hdr": "HDR exponent"}


# ----------------------------------------------------------------------------- decoding one file


def _find_channel(channels: dict[str, np.ndarray], name: str) -> np.ndarray | None:
    """Channel `name`, or the first whose suffix after a layer prefix is `name` ("rvr.D")."""
    if name in channels:
        return channels[name]
    for full, array in channels.items():
        if full.endswith("." + name):
            return array
    return None


class SharedExrReads:
    """The channels of the EXR file read last, for sequences whose maps live in the same files
    (a cache's D and E channels share one file per frame): each file is decoded once, not once
    per sequence. The first read of a file keeps its channels; the next read of the same,
    unchanged file (same inode, mtime and size) takes them and forgets them, so at most one
    file's channels are held; the first reader gets copies (:func:`_exr_map`), so no two
    callers share an array."""

    def __init__(self) -> None:
        self._key: tuple | None = None
        self._channels: dict[str, np.ndarray] | None = None
        self.decoded = 0
        """Files decoded so far (a reader's own count, for tests and benchmarks)."""

    def read(self, path: Path) -> tuple[dict[str, np.ndarray], bool]:
        """({name: (H, W) float32}, True when the channels were kept from an earlier read)."""
        from .exr import read_exr

        st = path.stat()
        key = (str(path), st.st_ino, st.st_mtime_ns, st.st_size)
        if key == self._key and self._channels is not None:
            channels, self._key, self._channels = self._channels, None, None
            return channels, True
        self._key, self._channels = None, None
        channels = read_exr(path)
        self.decoded += 1
        self._key, self._channels = key, channels
        return channels, False

    def clear(self) -> None:
        """Drop the kept channels (a job closing)."""
        self._key, self._channels = None, None


def share_exr_reads(*sequences: "MapSequence | None") -> SharedExrReads:
    """Let ``sequences`` (e.g. the depth and HDR maps of one cache) decode each EXR file once."""
    shared = SharedExrReads()
    for seq in sequences:
        if seq is not None:
            seq.shared = shared
    return shared


def _exr_map(path: Path, kind: str, prefix: str = "", shared: SharedExrReads | None = None) -> np.ndarray:
    from .exr import read_exr

    if shared is None:
        return _pick_exr_channels(path, read_exr(path), kind, prefix)
    channels, kept = shared.read(path)
    array = _pick_exr_channels(path, channels, kind, prefix)
    # the first reader gets its own copy of a kept channel, the last (kept) reader the array itself
    return array if kept or array.ndim == 3 else array.copy()


def _pick_exr_channels(path: Path, channels: dict[str, np.ndarray], kind: str, prefix: str) -> np.ndarray:
    """The ``kind`` map among an EXR file's channels (a stack of E.R/G/B is a new array)."""
    if prefix:  # a cache's stabilized channels (S.D, S.E.R/G/B): exact names, no fallback
        names = (prefix + "D",) if kind == "disparity" else tuple(prefix + c for c in ("E.R", "E.G", "E.B"))
        if all(n in channels for n in names):
            return channels[names[0]] if len(names) == 1 else np.stack([channels[n] for n in names], axis=2)
        raise InputError(f"EXR map '{path}' lacks the stabilized channel(s) {', '.join(names)} that its cache's "
                         "meta.json records; run `rvr stabilize` on the cache again.")
    if kind == "disparity":
        for name in DISPARITY_CHANNELS:
            found = _find_channel(channels, name)
            if found is not None:
                return found
        wanted = ", ".join(DISPARITY_CHANNELS)
    else:
        for group in (("E",), ("E.R", "E.G", "E.B"), ("R", "G", "B"), ("Y",)):
            found = [_find_channel(channels, name) for name in group]
            if all(f is not None for f in found):
                return found[0] if len(found) == 1 else np.stack(found, axis=2)
        wanted = "E, E.R/E.G/E.B, R/G/B or Y"
    raise InputError(
        f"EXR map '{path}' has channels {sorted(channels)} but none of {wanted}; "
        f"rename the {_KIND_NAMES[kind]} channel to one of these."
    )


def _image_map(path: Path, kind: str) -> np.ndarray:
    import cv2

    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None or image.size == 0:
        raise InputError(f"Cannot read map '{path}': the file is corrupt or not an image OpenCV reads; re-export it.")
    if image.dtype == np.uint8:
        image = image.astype(np.float32) / 255.0
    elif image.dtype == np.uint16:
        image = image.astype(np.float32) / 65535.0
    else:
        image = image.astype(np.float32)
    if image.ndim == 3:
        if image.shape[2] >= 3:
            image = image[:, :, 2::-1]  # BGR(A) -> RGB, alpha dropped
        else:
            image = image[:, :, 0]
    if image.ndim == 3 and kind == "disparity":
        image = image[:, :, 0]  # R channel of a colour image
    return image


def _numpy_array(path: Path, kind: str, mmap: bool = False) -> np.ndarray:
    """The array of an NPY file (memory-mapped when ``mmap``) or the map array of an NPZ file."""
    try:
        loaded = np.load(path, allow_pickle=False, mmap_mode="r" if mmap and path.suffix.lower() == ".npy" else None)
    except Exception as ex:
        raise InputError(f"Cannot read map '{path}': {ex}. Save it with numpy.save / numpy.savez.") from ex
    if isinstance(loaded, np.lib.npyio.NpzFile):
        with loaded:
            if not loaded.files:
                raise InputError(f"NPZ map '{path}' holds no arrays; save the map with numpy.savez(path, disparity=D).")
            key = "disparity" if kind == "disparity" else "E"
            return loaded[key] if key in loaded.files else loaded[loaded.files[0]]
    return loaded


def stack_length(shape: tuple[int, ...], kind: str) -> int | None:
    """N for an array of N maps ((N, H, W), or (N, H, W, C)), None for one map ((H, W), or
    (H, W, C) with C in 1, 3, 4: channels of one picture)."""
    if len(shape) == 4:
        return int(shape[0])
    if len(shape) == 3 and shape[2] not in (1, 3, 4):
        return int(shape[0])
    return None


def _numpy_map(path: Path, kind: str, array: np.ndarray | None = None) -> np.ndarray:
    array = np.asarray(_numpy_array(path, kind) if array is None else array)
    if array.ndim == 3 and array.shape[2] == 1:
        array = array[:, :, 0]
    if array.ndim == 3 and kind == "disparity":
        array = array[:, :, 0]
    return array.astype(np.float32)


def _read_raw(path: Path, kind: str, prefix: str = "", layer: np.ndarray | None = None,
              shared: SharedExrReads | None = None) -> np.ndarray:
    suffix = path.suffix.lower()
    if layer is not None:  # one map of an (N, H, W) stack
        array = _numpy_map(path, kind, layer)
    elif suffix == ".exr":
        array = _exr_map(path, kind, prefix, shared)
    elif suffix in (".npy", ".npz"):
        array = _numpy_map(path, kind)
    else:
        array = _image_map(path, kind)
    array = np.asarray(array, dtype=np.float32)
    good = array.ndim == 2 or (array.ndim == 3 and array.shape[2] == 3 and kind == "hdr")
    if not good or min(array.shape[:2]) == 0:
        want = "(H, W)" if kind == "disparity" else "(H, W) or (H, W, 3)"
        raise InputError(f"Map '{path}' has shape {array.shape}; a {_KIND_NAMES[kind]} map must be {want}.")
    return array


def read_map(path: Path, kind: str = "disparity") -> np.ndarray:
    """One map file (EXR / PNG and other images / NPY / NPZ) as float32 (H, W) (``kind`` "hdr":
    or (H, W, 3)); 8/16-bit images scaled to [0, 1]. Raises InputError naming the file."""
    if not Path(path).is_file():
        raise InputError(f"map '{path}' not found; check the path")
    return _read_raw(Path(path), kind)


def fill_nonfinite(array: np.ndarray) -> tuple[np.ndarray, int]:
    """Replace NaN/inf by the nearest finite value, per channel. Returns (filled, count replaced).

    array: (H, W) or (H, W, C) float32. A channel with no finite value is returned unchanged
    (the caller reports it).
    """
    import cv2

    bad = ~np.isfinite(array)
    count = int(bad.sum())
    if count == 0:
        return array, 0
    out = array.copy()
    planes = [out] if out.ndim == 2 else [out[:, :, c] for c in range(out.shape[2])]
    masks = [bad] if bad.ndim == 2 else [bad[:, :, c] for c in range(bad.shape[2])]
    for plane, mask in zip(planes, masks):
        if not mask.any() or mask.all():
            continue
        _, labels = cv2.distanceTransformWithLabels(
            mask.astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE, labelType=cv2.DIST_LABEL_PIXEL
        )
        good = ~mask
        lut = np.zeros(int(labels.max()) + 1, dtype=np.int64)
        lut[labels[good]] = np.flatnonzero(good)
        plane[mask] = plane.reshape(-1)[lut[labels[mask]]]
    return out, count


# ----------------------------------------------------------------------------- the sequence


class MapSequence:
    """Random access to per-frame maps, values as float32 `raw * scale + offset`.

    `static` is True when one file serves every frame (then any index is valid and `len` is 1).
    """

    def __init__(self, source: str, paths: list[Path], kind: str, scale: float, offset: float, static: bool):
        self.source = source
        self.paths = paths
        self.kind = kind
        self.scale = float(scale)
        self.offset = float(offset)
        self.static = static
        self.prefix = ""  # "S." reads a cache's stabilized channels (see open_map_sequence)
        self.stack: np.ndarray | None = None  # an (N, H, W) NPY/NPZ stack (memory-mapped NPY)
        self.cache: dict | None = None
        """A cache folder's record: {"folder", "fix" (the rvr estimate command), "files": {path:
        (recorded sizes, (st_ino, st_mtime_ns) when opened, or None if the size was already wrong)}}."""
        self._warned_size = False
        self._warned_nonfinite = False
        self._static_cache: tuple[tuple[int, int] | None, np.ndarray] | None = None
        self.shared: SharedExrReads | None = None
        """EXR reads shared with another sequence of the same files (:func:`share_exr_reads`)."""
        self.rows: np.ndarray | None = None
        """Per frame, the layer of ``stack`` it reads, when not its own index (:meth:`place_on_timeline`)."""

    def __len__(self) -> int:
        return len(self.paths)

    def __repr__(self) -> str:
        return f"MapSequence({self.source!r}, kind={self.kind!r}, maps={len(self)}, static={self.static})"

    @property
    def label(self) -> str:
        """Human name of the sequence for messages ("the depth sequence 'maps/*.exr'")."""
        return f"the {_KIND_NAMES[self.kind]} sequence '{self.source}'"

    def check_length(self, n_frames: int) -> None:
        """Raise InputError unless the sequence has a map for each of `n_frames` frames."""
        if not self.static and len(self) < n_frames:
            raise InputError(
                f"{self.label} has {len(self)} maps but the clip has {n_frames} frames; supply one map per frame."
            )

    def warn_extra(self, clip_frames: int, clip: str | Path) -> None:
        """Log a warning naming both counts when there are more maps than ``clip`` has frames
        (maps of another, longer clip, or a folder holding more than this clip's maps)."""
        if not self.static and len(self) > 1 and len(self) > clip_frames:
            log.warning("%s has %d maps but the clip '%s' has %d frames; maps %d..%d are not used. Check that the maps "
                        "belong to this clip.", self.label, len(self), clip, clip_frames, clip_frames, len(self) - 1)

    def place_on_timeline(self, clip) -> None:
        """Maps of a variable-frame-rate clip's decoded frames, one each (as a tool that decodes it
        in order makes them), placed on the constant-rate timeline the clip is read on
        (``io.video.video_timeline``, ``ClipInfo.decoded_frames``): frame k gets the map of the
        decoded frame it shows. Other sequences (one map, a cache, a map per timeline frame) are
        left as they are."""
        if (self.static or self.cache is not None or clip.decoded_frames is None or len(self) != clip.decoded_frames
                or clip.decoded_frames == clip.frame_count):
            return
        from .video import video_timeline

        timeline = video_timeline(clip.path)
        if timeline is None:
            return
        self.paths = [self.paths[j] for j in timeline.decoded]
        if self.stack is not None:
            self.rows = timeline.decoded
        log.info("%s: %d maps, one per decoded frame of the variable-frame-rate clip '%s', placed on the %d frames it "
                 "is read as (a constant %.4g fps)", self.label, clip.decoded_frames, clip.path, clip.frame_count,
                 clip.nominal_fps)

    def path_for(self, index: int) -> Path:
        """File that holds frame `index` (0-based); InputError when out of range."""
        if self.static:
            return self.paths[0]
        if index < 0 or index >= len(self):
            raise InputError(
                f"{self.label} has {len(self)} maps but frame {index} was requested (frames count from 0); "
                "supply one map per frame of the clip."
            )
        path = self.paths[index]
        if not path.is_file():
            fix = self.cache["fix"] if self.cache else "rvr estimate CLIP -o CACHE"
            raise InputError(f"{self.label} lacks frame {index} ('{path.name}'); run `{fix}` over the frames you "
                             "render")
        return path

    def get(self, index: int, size: tuple[int, int] | None = None) -> np.ndarray:
        """Map of frame `index` as float32 (H, W) (disparity; hdr maps may be (H, W, 3)).

        size: (width, height) of the frame; a map of another size is resampled (bilinear) and
        one warning is logged per sequence. Values are not rescaled by the resampling.
        """
        path = self.path_for(index)
        if self.static and self._static_cache is not None and self._static_cache[0] == size:
            return self._static_cache[1].copy()
        array = self._load(path, size, index)
        if self.static:
            self._static_cache = (size, array)
            return array.copy()
        return array

    def _read_cache_frame(self, path: Path) -> np.ndarray:
        """A cache frame, checked against the meta.json read when the sequence was opened."""
        folder, fix = self.cache["folder"], self.cache["fix"]
        expected = self.cache["files"].get(path)
        if expected is None:
            raise InputError(f"'{path}' is not recorded in '{folder / 'meta.json'}' (its estimate was not finished); "
                             f"run `{fix}` again to compute it")
        try:
            st = path.stat()
        except OSError as ex:
            raise InputError(f"cache frame '{path}' cannot be read ({ex}); run `{fix}` again to recompute it") from ex
        if expected[1] is not None and (st.st_ino, st.st_mtime_ns) != expected[1]:
            raise InputError(f"cache frame '{path}' was rewritten while it was being read (another process writes "
                             f"the cache '{folder}'); run this command again once it has finished")
        if st.st_size not in expected[0]:
            raise InputError(f"cache frame '{path}' is truncated or incomplete ({st.st_size} bytes; meta.json records "
                             f"{expected[0][0]}); run `{fix}` again to recompute it")
        try:
            return _read_raw(path, self.kind, self.prefix, shared=self.shared)
        except InputError as ex:
            raise InputError(f"{ex} It belongs to the cache '{folder}': run `{fix}` again to recompute it.") from ex

    def _load(self, path: Path, size: tuple[int, int] | None, index: int = 0) -> np.ndarray:
        import cv2

        if self.cache is not None:
            array = self._read_cache_frame(path)
        elif self.stack is not None:
            array = _read_raw(path, self.kind, layer=np.asarray(self.stack[index if self.rows is None else
                                                                            int(self.rows[index])]))
        else:
            array = _read_raw(path, self.kind, self.prefix, shared=self.shared)
        finite = np.isfinite(array)
        if not finite.all():
            if not finite.reshape(array.shape[0], array.shape[1], -1).any(axis=(0, 1)).all():
                raise InputError(
                    f"Map '{path}' has no finite value (all NaN or infinite); re-export it or remove it from "
                    f"{self.label}."
                )
            array, count = fill_nonfinite(array)
            level = logging.DEBUG if self._warned_nonfinite else logging.WARNING
            log.log(level, "Map '%s' has %d NaN/infinite values; they were replaced by the nearest finite value.",
                    path, count)
            self._warned_nonfinite = True
        if size is not None:
            width, height = int(size[0]), int(size[1])
            if (array.shape[1], array.shape[0]) != (width, height):
                level = logging.DEBUG if self._warned_size else logging.WARNING
                log.log(level, "Map '%s' is %dx%d but the frame is %dx%d; resampling it (values are not rescaled).",
                        path, array.shape[1], array.shape[0], width, height)
                self._warned_size = True
                array = cv2.resize(array, (width, height), interpolation=cv2.INTER_LINEAR)
        if self.scale != 1.0 or self.offset != 0.0:
            array = array * np.float32(self.scale) + np.float32(self.offset)
        return np.ascontiguousarray(array, dtype=np.float32)


def open_map_sequence(path: str | Path, kind: str = "disparity", scale: float = 1.0, offset: float = 0.0) -> MapSequence:
    """Open per-frame maps of `kind` "disparity" or "hdr" (files are read lazily by `get`).

    Raises InputError naming the path when nothing is found or a setting is invalid.
    """
    if kind not in _KIND_NAMES:
        raise InputError(f"Map kind {kind!r} is not known; use 'disparity' or 'hdr'.")
    if not (np.isfinite(scale) and np.isfinite(offset)):
        raise InputError(f"Map scale={scale!r} / offset={offset!r} for '{path}' must be finite numbers.")
    text = str(path)
    how, files = expand_sequence(text, MAP_EXTENSIONS)
    name = _KIND_NAMES[kind]
    if how == "missing":
        raise InputError(
            f"The {name} maps '{text}' were not found. Give a file, a folder, a glob such as 'depth/*.exr' "
            "or a printf pattern such as 'depth/d_%04d.exr'."
        )
    if not files:
        where = "Folder" if how == "directory" else "Pattern"
        raise InputError(
            f"{where} '{text}' holds no {name} maps ({', '.join(MAP_EXTENSIONS)}); check the path and file names."
        )
    unsupported = [p for p in files if p.suffix.lower() not in MAP_EXTENSIONS]
    if unsupported:
        raise InputError(
            f"'{unsupported[0]}' is not a supported map format; use one of {', '.join(MAP_EXTENSIONS)}."
        )
    if how == "file" and files[0].suffix.lower() in (".npy", ".npz"):
        stack = _numpy_array(files[0], kind, mmap=True)
        n = stack_length(stack.shape, kind)
        if n is not None:
            if n == 0:
                raise InputError(f"the {name} stack '{text}' has shape {stack.shape}: no maps; save one map per frame, "
                                 "shape (N, H, W)")
            seq = MapSequence(text, [files[0]] * n, kind, scale, offset, static=False)
            seq.stack = stack
            log.info("%s: an array of %d maps of %dx%d (one per frame)", text, n, stack.shape[2], stack.shape[1])
            return seq
    seq = MapSequence(text, files, kind, scale, offset, static=(how == "file"))
    if how == "directory":
        _use_cache_channels(seq, Path(text))
    return seq


def _use_cache_channels(seq: MapSequence, folder: Path) -> None:
    """A per-clip cache folder (``rvr estimate``): read its stabilized channels when every
    frame has them (``rvr stabilize``), else the raw per-frame ones; log which."""
    import json

    meta_path = folder / "meta.json"
    if not meta_path.is_file():
        return
    try:
        meta = json.loads(meta_path.read_text())
    except (OSError, ValueError):
        return
    if not isinstance(meta, dict) or not str(meta.get("format", "")).startswith("rvr-laaf-cache/"):
        return
    from ..estimate.cache import _FRAME_RE, FRAME_NAME, stabilized_complete
    from .lock import writer_active

    source = (meta.get("source") or {}).get("path") if isinstance(meta.get("source"), dict) else None
    fix = f"rvr estimate {source or 'CLIP'} -o {folder}"
    other = writer_active(folder)
    if other is not None:
        raise InputError(f"the cache '{folder}' is being written by another process ({other}); wait until it has "
                         "finished, then run this command again")
    frames = meta.get("frames") if isinstance(meta.get("frames"), dict) else {}
    pending = ((meta.get("stabilized") or {}).get("pending") or {}) if isinstance(meta.get("stabilized"), dict) else {}
    files: dict[Path, tuple] = {}
    for number, size in frames.items():
        path = folder / FRAME_NAME.format(int(number))
        sizes = tuple(int(v) for v in (size, pending.get(str(number))) if v is not None)
        try:
            st = path.stat()
            files[path] = (sizes, (st.st_ino, st.st_mtime_ns) if st.st_size in sizes else None)
        except OSError:
            pass  # missing: path_for says so
    seq.cache = {"folder": folder, "fix": fix, "files": files}

    # a cache may hold a part of its clip (frames 40..80 of a trimmed strip): index i is the
    # file of clip frame i (frame_NNNNN.exr = i + 1), never the i-th file present
    numbers = [int(m.group(1)) for p in seq.paths if (m := _FRAME_RE.match(p.name))]
    if numbers:
        seq.paths = [folder / FRAME_NAME.format(i) for i in range(1, max(numbers) + 1)]
    name = _KIND_NAMES[seq.kind]
    if stabilized_complete(meta):
        seq.prefix = "S."
        settings = (meta.get("stabilized") or {}).get("settings") or {}
        log.info("%s: using the temporally stabilized %s channels (%s; rvr stabilize, window %s)", folder, name,
                 "S.D" if seq.kind == "disparity" else "S.E.R/G/B", settings.get("window", "?"))
    else:
        log.info("%s: using the per-frame %s channels (%s); run `rvr stabilize %s` for temporally stable ones",
                 folder, name, "D" if seq.kind == "disparity" else "E.R/G/B", folder)
