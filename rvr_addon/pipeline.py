"""Render a clip: frames + disparity (+ HDR) + focus track -> shallow-DOF video / images.

:class:`RenderJob` is the one driver every front end uses: the CLI and ``execute()`` loop
``while job.step(): pass``; a Blender modal operator calls ``step()`` from a timer and
``cancel()`` on Esc. Outputs are written atomically: nothing half-written is left at an
output path, and an earlier result there survives a failure or a cancel.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator, Sequence

import numpy as np

from .color import image_to_linear, linear_to_srgb, to_uint8
from .errors import InputError
from .io.maps import open_map_sequence, share_exr_reads
from .io.paths import check_outputs, replace_folder
from .io.readahead import ReadAhead
from .io.track import FocusTrack, constant_track, load_track, resolve_track, warn_keys_beyond
from .io.video import ClipInfo, iter_frames, probe_clip
from .io.writer import STILL_SUFFIXES, ImageSequenceWriter, StillImageWriter, VideoWriter
from .render.aperture import ApertureSpec
from .render.device import make_renderer
from .render.fast import FastRenderer
from .render.model import K_HDR, hdr_radiance

log = logging.getLogger(__name__)

VIDEO_SUFFIXES = (".mp4", ".mov", ".mkv", ".m4v")


@dataclass
class RenderSettings:
    """Everything a render needs; paths are files, folders or frame patterns.

    focus: constant focus disparity, or None with no track = the median disparity of the
        centre of the first frame (a simple default until autofocus is chosen).
    aperture: constant aperture scale (>= 0; 0 = no synthetic blur) when there is no track.
    track / track_data: a focus track file, or one in memory (e.g. sampled from F-curves);
        either overrides focus and aperture.
    outputs: .mp4/.mov/.mkv files (H.264, source audio kept) and/or folders or patterns
        (``frame_%05d.png``; a ``.exr`` pattern writes linear HDR radiance), or one picture
        (``photo_refocused.jpg``, .png, .tif, .exr) when the render has one frame.
    scale: render at this fraction of the clip's size (a proxy, e.g. 0.5); blur radii scale
        with the width, so the picture matches the full-size render, only smaller.
    frames: the clip frame of each output frame, never decreasing (a slowed-down clip repeats
        frames, a sped-up one skips some), e.g. what a retimed strip shows on each scene frame;
        replaces start/stop. The track is then keyed by output frame (0 = the first), and a
        video output gets no audio (its timing no longer matches the clip's).
    output_fps: frame rate of a video output (frames/s; None = the clip's).
    device: where to render: "auto" (CUDA when torch sees a GPU, else the fast CPU renderer),
        "cpu" or "cuda" (:mod:`.render.device`).
    threads: blur threads of the CPU renderer (None: its default; a batch task passes its budget).
    """

    input: Path
    depth: Path
    outputs: list[Path]
    hdr: Path | None = None
    focus: float | None = None
    aperture: float = 1.0
    track: Path | None = None
    track_data: FocusTrack | None = None
    spec: ApertureSpec = field(default_factory=ApertureSpec)
    depth_scale: float = 1.0
    depth_offset: float = 0.0
    naive: bool = False
    start: int = 0
    stop: int | None = None
    fps: float | None = None
    keep_audio: bool = True
    max_step: float = 1.0
    min_layers: int = 1
    scale: float = 1.0
    frames: Sequence[int] | None = None
    output_fps: float | None = None
    device: str = "auto"
    threads: int | None = None


def exponent_from_radiance(image_srgb: np.ndarray, radiance: np.ndarray, clip_level: float = 0.999) -> np.ndarray:
    """HDR exponent E (H, W, 3) float32 with ``linear(image) * exp(K_HDR E) = radiance``.

    Only pixels clipped in the 8-bit image (linear >= clip_level) get E != 0: below the clip,
    the 8-bit value is the truth up to quantisation. Used for ground-truth HDR inputs.
    """
    lin = image_to_linear(image_srgb)
    ratio = np.maximum(radiance, 1e-6) / np.maximum(lin, 1e-6)
    e = np.log(np.maximum(ratio, 1.0)) / K_HDR
    return np.where(lin >= clip_level, e, 0.0).astype(np.float32)


def prepare_demo_inputs(directory: Path, pull_frames: int | None = None) -> None:
    """Add to a demo-scene folder the HDR exponents (``hdr_exponent/*.npy``, from the exact
    radiance in ``hdr/``) and a rack-focus track (``focus_track.json``: the subject, a pull to
    the background, a hold, and a pull back). Idempotent."""
    import json

    import cv2

    from .io.exr import read_exr

    meta = json.loads((directory / "meta.json").read_text())
    n = int(meta["frames"])
    out = directory / "hdr_exponent"
    if not out.is_dir() or len(list(out.glob("*.npy"))) < n:
        tmp = directory / ".hdr_exponent.tmp"
        tmp.mkdir(exist_ok=True)
        for png in sorted((directory / "frames").glob("*.png")):
            ch = read_exr(directory / "hdr" / (png.stem + ".exr"))
            radiance = np.dstack([ch["R"], ch["G"], ch["B"]])
            srgb = cv2.cvtColor(cv2.imread(str(png), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
            np.save(tmp / (png.stem + ".npy"), exponent_from_radiance(srgb, radiance))
        replace_folder(tmp, out)
    track = directory / "focus_track.json"
    if not track.is_file():
        near, far = float(meta["subject_disparity"]), float(meta["background_disparity"])
        pull = pull_frames or max(n // 5, 1)
        hold = max((n - 2 * pull) // 3, 0)
        keys = [(0, near), (hold, near), (hold + pull, far), (2 * hold + pull, far),
                (2 * hold + 2 * pull, near), (n - 1, near)]
        track.write_text(json.dumps({"keys": [{"frame": min(f, n - 1), "focus": v, "aperture": 1.0}
                                              for f, v in keys]}, indent=1))


def is_still_output(out: Path) -> bool:
    """Whether an output path is one picture (``photo_refocused.jpg``: an image type, no frame
    number field), as opposed to a video, a folder or a numbered sequence."""
    out = Path(out)
    return "%" not in out.name and out.suffix.lower() in STILL_SUFFIXES


def refuse_picture_of_many(out: Path, frames: int, option: str = "output") -> None:
    """InputError, before any work, when ``out`` is one picture (:func:`is_still_output`) but
    ``frames`` frames would go there; ``option`` names the setting (``-o``, ``--side-by-side``)."""
    if is_still_output(out) and frames != 1:
        p = Path(out)
        raise InputError(f"{option} {out}: a picture holds one frame, this range has {max(0, frames)}: give a video "
                         f"(.mp4), a numbered sequence ({p.stem}_%05d{p.suffix}), or one frame (--start N --stop N+1)")


def sequence_writer(out: Path, start: int = 1) -> ImageSequenceWriter:
    """Writer for an image-sequence output: a folder (PNG frames) or ``folder/name_%05d.ext``.

    The folder is replaced as a whole when the render completes, so it must be the render's
    own: a folder holding anything but frames of this pattern is refused (nothing is lost).
    """
    if "%" in out.name or out.suffix.lower() in STILL_SUFFIXES:
        directory, pattern = out.parent, out.name
        if "%" not in pattern:
            raise InputError(f"image output {out} needs a frame number field, e.g. {out.stem}_%05d{out.suffix}")
    else:
        directory, pattern = out, "frame_%05d.png"
    if directory.is_dir():
        import re

        rx = re.compile(re.sub(r"%0?(\d*)d", r"\\d+", re.escape(pattern).replace("\\%", "%")) + "$")
        foreign = [p.name for p in directory.iterdir() if not rx.match(p.name)]
        if foreign:
            raise InputError(f"output folder {directory} holds other files ({', '.join(sorted(foreign)[:3])}...); "
                             "image sequences replace their folder as a whole: choose a new or empty folder")
    return ImageSequenceWriter(directory, pattern=pattern, start=start)


def frame_list(frames: Sequence[int], clip: ClipInfo) -> np.ndarray:
    """``RenderSettings.frames`` checked: whole, non-decreasing clip frames inside the clip."""
    out = np.asarray(frames).reshape(-1)
    if out.size == 0 or np.any(out != np.round(out)):
        raise InputError(f"the frame list for {clip.path} must be a non-empty list of whole frame numbers")
    out = out.astype(np.int64)
    back = np.flatnonzero(np.diff(out) < 0)
    if back.size:
        raise InputError(f"the frame list for {clip.path} goes back from frame {out[back[0]]} to {out[back[0] + 1]}; "
                         "frames must never decrease (reversed playback is not supported)")
    if out[0] < 0 or out[-1] >= clip.frame_count:
        raise InputError(f"the frame list for {clip.path} asks for frames {out[0]}..{out[-1]} but the clip has "
                         f"{clip.frame_count} frames (0..{clip.frame_count - 1})")
    return out


def repeat_frames(frames: Iterator[np.ndarray], first: int, wanted: np.ndarray) -> Iterator[np.ndarray]:
    """The decoded frame of each clip frame in ``wanted`` (non-decreasing), reading ``frames``
    (which starts at clip frame ``first``) once; stops early when the clip ends."""
    current, index = None, first - 1
    for k in wanted:
        while index < k:
            current = next(frames, None)
            index += 1
            if current is None:
                return
        yield current


def center_focus(disparity: np.ndarray, fraction: float = 0.2) -> float:
    """Median disparity of the central box (``fraction`` of each side): a default focus."""
    h, w = disparity.shape
    dy, dx = max(int(h * fraction / 2), 1), max(int(w * fraction / 2), 1)
    return float(np.median(disparity[h // 2 - dy:h // 2 + dy, w // 2 - dx:w // 2 + dx]))


class RenderJob:
    """A cancellable, stepwise render of one clip (see module docstring)."""

    def __init__(self, settings: RenderSettings) -> None:
        self.settings = settings
        s = settings
        if not s.outputs:
            raise InputError("no output given: pass -o OUT.mp4 and/or -o FRAMES_DIR")
        if s.aperture is not None and (not np.isfinite(s.aperture) or s.aperture < 0):
            raise InputError(f"--aperture must be >= 0 (0 = no blur), got {s.aperture}")
        if s.focus is not None and not np.isfinite(s.focus):
            raise InputError(f"--focus must be a finite disparity, got {s.focus}")
        if not (0 < s.scale <= 4):
            raise InputError(f"--scale must be in (0, 4] (e.g. 0.5 for a half-size proxy), got {s.scale}")
        # --device cuda without a GPU is refused before any file is read
        self.renderer = make_renderer(s.device, spec=s.spec, naive=s.naive, max_step=s.max_step,
                                      min_layers=s.min_layers, threads=s.threads)
        check_outputs("render", [("output", out) for out in s.outputs],
                      [("input", s.input), ("depth", s.depth), ("HDR", s.hdr), ("track", s.track)])
        self.clip: ClipInfo = probe_clip(s.input, fps=s.fps)
        from .estimate.cache import check_cache_source

        for maps in {s.depth, s.hdr} - {None}:  # a cache of another clip is refused
            check_cache_source(maps, s.input, self.clip, command="render")
        self.frame_list = None if s.frames is None else frame_list(s.frames, self.clip)
        if self.frame_list is not None:
            start, stop = int(self.frame_list[0]), int(self.frame_list[-1]) + 1
        else:
            start, stop = s.start, self.clip.frame_count if s.stop is None else min(s.stop, self.clip.frame_count)
        if start < 0 or start >= stop:
            raise InputError(f"frame range {start}..{stop} is empty for {s.input} "
                             f"({self.clip.frame_count} frames)")
        self.start, self.stop = start, stop
        self.total = stop - start if self.frame_list is None else len(self.frame_list)
        for out in s.outputs:
            refuse_picture_of_many(out, self.total)
        self.depth = open_map_sequence(s.depth, kind="disparity", scale=s.depth_scale, offset=s.depth_offset)
        self.depth.place_on_timeline(self.clip)
        if len(self.depth) > 1 and len(self.depth) < stop:
            raise InputError(f"the depth sequence {s.depth} has {len(self.depth)} maps but the clip "
                             f"{s.input} needs {stop}: supply one map per frame (or a single map)")
        self.depth.warn_extra(self.clip.frame_count, s.input)
        self.hdr = open_map_sequence(s.hdr, kind="hdr") if s.hdr is not None else None
        if self.hdr is not None:
            self.hdr.place_on_timeline(self.clip)
        self._shared_reads = None
        self._maps: ReadAhead = ReadAhead(self._read_maps)
        if self.hdr is not None:
            self.hdr.warn_extra(self.clip.frame_count, s.input)
            if not self.depth.static and self.depth.stack is None and self.hdr.paths == self.depth.paths:
                self._shared_reads = share_exr_reads(self.depth, self.hdr)  # one cache: each frame file read once
        self.track: FocusTrack | None = s.track_data
        if self.track is None and s.track is not None:
            self.track = load_track(s.track)
            warn_keys_beyond(self.track, self.clip.frame_count if self.frame_list is None else self.total, s.input)
        self.done = 0
        self.text = f"rendering {self.total} frames of {self.clip.path.name}"
        self._frames: Iterator[np.ndarray] | None = None
        self._decoder = None  # the clip's frame generator (its ffmpeg child ends when it is closed)
        self._writers: list = []
        self._focus: np.ndarray | None = None
        self._aperture: np.ndarray | None = None
        self._finished = False

    @property
    def output_size(self) -> tuple[int, int]:
        """(width, height) of the rendered frames in px."""
        sc = self.settings.scale
        return max(int(round(self.clip.width * sc)), 1), max(int(round(self.clip.height * sc)), 1)

    @property
    def progress(self) -> float:
        """Fraction of frames rendered, 0..1."""
        return self.done / self.total if self.total else 1.0

    def _open(self) -> None:
        s = self.settings
        first_d = self.depth.get(self.start if len(self.depth) > 1 else 0, size=(self.clip.width, self.clip.height))
        size = self.output_size
        track_start = self.start if self.frame_list is None else 0  # a frame list keys the track by output frame
        if self.track is not None:
            self._focus, self._aperture = resolve_track(self.track, self.total, start=track_start)
        else:
            focus = center_focus(first_d) if s.focus is None else float(s.focus)
            if s.focus is None:
                log.warning("%s: no focus track and no --focus: focus stays on the centre of the first frame "
                            "(disparity %.2f) for the whole clip; `rvr autofocus` chooses the subjects and when to "
                            "pull (then --track FOCUS.json), `rvr refocus` does everything", s.input, focus)
            self._focus, self._aperture = resolve_track(constant_track(focus, s.aperture), self.total,
                                                        start=track_start)
        self._warn_cost(first_d)
        self._frames = self._decoder = iter_frames(s.input, start=self.start, stop=self.stop)
        if self.frame_list is not None:
            self._frames = repeat_frames(self._frames, self.start, self.frame_list)
        keep_audio = s.keep_audio and self.clip.has_audio and self.frame_list is None
        audio = s.input if keep_audio else None
        for out in s.outputs:
            out = Path(out)
            if out.suffix.lower() in VIDEO_SUFFIXES:
                w = VideoWriter(out, fps=s.output_fps or self.clip.fps, size=size, audio_from=audio,
                                audio_start=self.start / self.clip.fps)
            elif is_still_output(out):
                w = StillImageWriter(out)
            else:
                w = sequence_writer(out, start=self.start + 1 if self.frame_list is None else 1)
            self._writers.append(w)

    def _warn_cost(self, first_d: np.ndarray) -> None:
        """Log what a frame will cost and how to make it cheaper (:mod:`.render.cost`) when that is
        a lot: the work counted on the first frame's disparity at the largest aperture of the track."""
        from .render.cost import cost_warning

        if not isinstance(self.renderer, FastRenderer):  # the cost model is the CPU path's
            return
        finite = first_d[np.isfinite(first_d)]
        if not finite.size:
            return
        sc = self.settings.scale
        lo, hi = float(finite.min()), float(finite.max())
        focus, aperture = np.asarray(self._focus, np.float64), np.abs(np.asarray(self._aperture, np.float64))
        radius = float(np.max(aperture * np.maximum(np.abs(hi - focus), np.abs(lo - focus)))) * sc
        w, h = self.output_size
        disparity = first_d
        if (disparity.shape[1], disparity.shape[0]) != (w, h):
            import cv2

            disparity = cv2.resize(first_d, (w, h), interpolation=cv2.INTER_LINEAR)
        work = self.renderer.work_px(disparity * sc, float(focus[0]) * sc, float(aperture.max()))
        message = cost_warning(w, h, radius, self.total, max_step=self.renderer.max_step, scale=sc, work_px=work,
                               what=f"rendering {self.clip.path.name}")
        if message:
            log.warning("%s", message)

    def step(self) -> bool:
        """Render and write the next frame; returns False once everything is written."""
        if self._finished:
            return False
        try:
            if self._frames is None:
                self._open()
            frame = next(self._frames, None)
            if frame is None:
                if self.done < self.total:
                    raise InputError(f"{self.settings.input} ended after {self.done} of {self.total} frames")
                self._close()
                return False
            self._write(self._render(frame, self.done))
            self.done += 1
            if self.done == self.total:
                self._close()
                return False
            return True
        except BaseException:
            self.abort()
            raise

    def _clip_frame(self, k: int) -> int:
        """Clip frame index of the k-th frame rendered."""
        return self.start + k if self.frame_list is None else int(self.frame_list[k])

    def _read_maps(self, key: tuple[int, tuple[int, int]]) -> tuple[np.ndarray | None, np.ndarray]:
        """(HDR exponent (H, W, C) or None, disparity (H, W)) of clip frame t at size (w, h)."""
        t, native = key
        exponent = None
        if self.hdr is not None:
            exponent = self.hdr.get(t if len(self.hdr) > 1 else 0, size=native)
            if exponent.ndim == 2:
                exponent = exponent[..., None]
        return exponent, self.depth.get(t if len(self.depth) > 1 else 0, size=native)

    def _render(self, frame: np.ndarray, k: int) -> np.ndarray:
        native = (frame.shape[1], frame.shape[0])
        t = self._clip_frame(k)
        then = (self._clip_frame(k + 1), native) if k + 1 < self.total else None
        exponent, disparity = self._maps.get((t, native), then)  # the next frame's are read meanwhile
        radiance = hdr_radiance(image_to_linear(frame), exponent)
        sc = self.settings.scale
        if sc != 1.0:  # a proxy: resample in linear light, as a smaller sensor would see it
            import cv2

            interp = cv2.INTER_AREA if sc < 1 else cv2.INTER_LINEAR
            radiance = cv2.resize(radiance, self.output_size, interpolation=interp)
            disparity = cv2.resize(disparity, self.output_size, interpolation=cv2.INTER_LINEAR)
        # disparity is in px at the native width: radii scale with the rendered width
        return self.renderer.render_linear(radiance, disparity * sc, float(self._focus[k]) * sc,
                                           float(self._aperture[k]))

    def _write(self, linear: np.ndarray) -> None:
        srgb8 = None
        for w in self._writers:
            if getattr(w, "linear", False):  # an EXR sequence or picture: linear HDR radiance
                w.write(linear.astype(np.float32))
            else:
                if srgb8 is None:
                    srgb8 = to_uint8(linear_to_srgb(linear))
                w.write(srgb8)

    def _stop_inputs(self) -> None:
        """End the map read-ahead, drop kept channels, end the decoder's ffmpeg."""
        self._maps.close()
        if self._shared_reads is not None:
            self._shared_reads.clear()
        decoder, self._decoder = self._decoder, None
        if decoder is not None:
            decoder.close()

    def _close(self) -> None:
        self._stop_inputs()
        for w in self._writers:
            w.close()
        self._writers = []
        self._finished = True
        self.text = f"rendered {self.done} frames"

    def abort(self) -> None:
        """Stop and remove partial outputs (the writers end their ffmpeg and delete their temp
        files); earlier results at the output paths survive."""
        try:
            self._stop_inputs()
        except Exception:  # noqa: BLE001 - the writers must still be cleaned up
            log.exception("closing the decoder of %s failed", self.settings.input)
        for w in self._writers:
            try:
                w.abort()
            except Exception:  # noqa: BLE001 - cleanup must visit every writer
                log.exception("cleaning up %s failed", w)
        self._writers = []
        self._finished = True

    def cancel(self) -> None:
        """User cancel: same as abort, with a status text; after the end (or a failure) it does nothing."""
        if self._finished:
            return
        self.abort()
        self.text = f"cancelled after {self.done} of {self.total} frames"

    def run(self, progress: bool = True) -> None:
        """Run to the end, with a tqdm progress bar when ``progress``."""
        from tqdm import tqdm

        with tqdm(total=self.total, unit="frame", disable=not progress, desc="render") as bar:
            try:
                while self.step():
                    bar.update(1)
            except BaseException:  # Ctrl-C / SIGTERM between two steps too: no temp file, no ffmpeg left
                self.abort()
                raise
            bar.update(self.total - bar.n)
