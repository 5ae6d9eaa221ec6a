"""Atomic video and image-sequence output.

Nothing half-written is ever left at the destination: `VideoWriter` encodes into a hidden
temp file beside the target, `ImageSequenceWriter` into a hidden temp folder beside it, and
each is renamed onto the target only when closed successfully. On an exception inside the
`with` block (or `abort()`), the temp is deleted and an earlier result survives untouched.
"""
from __future__ import annotations

import logging
import os
import shutil
import subprocess
import tempfile
from abc import ABC, abstractmethod
from fractions import Fraction
from pathlib import Path

import numpy as np

from ..errors import InputError, OutputError, output_error
from .paths import temp_sibling
from .video import ffmpeg_exe, probe_clip

log = logging.getLogger(__name__)


def _tail(data: bytes, lines: int = 15) -> str:
    kept = [line for line in data.decode("utf-8", "replace").strip().splitlines() if line.strip()]
    return "\n".join(kept[-lines:]) or "(ffmpeg printed nothing)"


def _has_audio(source: str | Path) -> bool:
    """True if `source` is a video with an audio stream; InputError if it does not exist."""
    if not Path(source).exists():
        raise InputError(f"Audio source '{source}' not found; pass the original clip as audio_from, or None.")
    try:
        return probe_clip(source).has_audio
    except InputError as ex:
        log.warning("No audio taken from '%s' (%s); the video is written without sound.", source, ex)
        return False


class _AtomicWriter(ABC):
    """Context-manager life cycle shared by the writers: ``close()`` on success, ``abort()``
    on an exception or when dropped unclosed (no temp file or child process is left)."""

    _closed = True

    @abstractmethod
    def close(self) -> None:
        """Finish and move the result into place."""

    @abstractmethod
    def abort(self) -> None:
        """Drop everything written; an earlier result at the target survives."""

    def __del__(self) -> None:
        if not getattr(self, "_closed", True):
            try:
                self.abort()
            except Exception:  # pragma: no cover - interpreter shutdown
                pass

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()


class VideoWriter(_AtomicWriter):
    """Encode uint8 RGB frames to an H.264 (libx264, yuv420p, +faststart) MP4 with the bundled ffmpeg.

    path: destination file (its folder is created). fps: frames/s. size: (width, height) in px
    of every frame; odd sizes are padded by one black row/column to even. audio_from: a clip
    whose first audio stream is re-encoded to AAC and muxed in, starting `audio_start` seconds
    into it; audio longer than the video is cut, shorter is padded with silence, so the video
    keeps exactly the frames written. crf: x264 quality (0 lossless .. 51 worst; 18 ~ visually
    lossless). Colours are converted with the BT.709 matrix and tagged BT.709.
    """

    def __init__(self, path: str | Path, fps: float, size: tuple[int, int], audio_from: str | Path | None = None,
                 crf: int = 18, audio_start: float = 0.0):
        self.path = Path(path)
        width, height = int(size[0]), int(size[1])
        if width <= 0 or height <= 0:
            raise InputError(f"Output size {size} for '{self.path}' is not valid; give (width, height) in px > 0.")
        if not (np.isfinite(fps) and fps > 0):
            raise InputError(f"Output frame rate fps={fps!r} for '{self.path}' is not valid; give a positive number.")
        if not 0 <= int(crf) <= 51:
            raise InputError(f"crf={crf} for '{self.path}' is out of range; use 0 (lossless) .. 51 (18 is a good default).")
        if not (np.isfinite(audio_start) and audio_start >= 0):
            raise InputError(f"audio_start={audio_start!r} s for '{self.path}' must be a number >= 0 (seconds into audio_from).")
        self.size = (width, height)
        self.fps = float(fps)
        self.frames_written = 0
        self._with_audio = audio_from is not None and _has_audio(audio_from)
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as ex:
            raise OutputError(f"Cannot create the folder of '{self.path}': {ex}. Choose a writable location.") from ex
        self._tmp = temp_sibling(self.path, ".tmp.mp4")
        self._log = tempfile.TemporaryFile()
        self._said: str | None = None
        cmd = self._command(audio_from, int(crf), float(audio_start))
        try:
            self._proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=self._log)
        except OSError as ex:
            self._log.close()
            raise OutputError(f"Cannot start ffmpeg to write '{self.path}': {ex}. Reinstall imageio-ffmpeg.") from ex
        self._closed = False

    def _command(self, audio_from: str | Path | None, crf: int, audio_start: float) -> list[str]:
        width, height = self.size
        rate = Fraction(self.fps).limit_denominator(1001)
        cmd = [ffmpeg_exe(), "-hide_banner", "-nostdin", "-v", "error", "-y",
               "-f", "rawvideo", "-pix_fmt", "rgb24", "-video_size", f"{width}x{height}",
               "-framerate", f"{rate.numerator}/{rate.denominator}", "-i", "pipe:0"]
        if self._with_audio:
            if audio_start > 0:
                cmd += ["-ss", f"{audio_start:.6f}"]
            cmd += ["-i", str(audio_from), "-map", "0:v:0", "-map", "1:a:0",
                    "-af", "apad", "-c:a", "aac", "-b:a", "192k", "-shortest"]
        filters = []
        if width % 2 or height % 2:
            filters.append("pad=ceil(iw/2)*2:ceil(ih/2)*2:0:0:black")
        filters.append("scale=out_color_matrix=bt709:out_range=tv,format=yuv420p,"
                       "setparams=colorspace=bt709:color_primaries=bt709:color_trc=bt709:range=tv")
        cmd += ["-vf", ",".join(filters), "-c:v", "libx264", "-preset", "medium", "-crf", str(crf),
                "-pix_fmt", "yuv420p", "-colorspace", "bt709", "-color_primaries", "bt709", "-color_trc", "bt709",
                "-color_range", "tv", "-movflags", "+faststart", "-f", "mp4", str(self._tmp)]
        return cmd

    def write(self, frame: np.ndarray) -> None:
        """Append one frame: (H, W, 3) uint8 RGB with (W, H) == size."""
        if self._closed:
            raise OutputError(f"VideoWriter for '{self.path}' is already closed; open a new one to write more frames.")
        frame = np.asarray(frame)
        width, height = self.size
        if frame.dtype != np.uint8 or frame.shape != (height, width, 3):
            raise InputError(
                f"Frame {self.frames_written} for '{self.path}' is {frame.dtype} {frame.shape}; expected uint8 "
                f"({height}, {width}, 3) RGB. Convert with rvr_addon.color.to_uint8 and keep one size."
            )
        try:
            self._proc.stdin.write(np.ascontiguousarray(frame).data)
        except (BrokenPipeError, OSError) as ex:
            self.abort()  # waits for ffmpeg, keeps what it said, removes the temp file
            raise OutputError(f"ffmpeg stopped after {self.frames_written} frames while writing '{self.path}'; "
                              f"nothing was saved (an earlier file there is kept). Check that the folder is "
                              f"writable and the disk has space, and that the audio source can be read "
                              f"(or render without audio). ffmpeg said:\n{self._stderr()}") from ex
        self.frames_written += 1

    def _stderr(self) -> str:
        """The tail of what ffmpeg printed (read once, before the log is closed; kept after)."""
        if self._said is None:
            try:
                self._log.seek(0)
                self._said = _tail(self._log.read())
            except (ValueError, OSError) as ex:  # the log is closed or unreadable
                return f"(ffmpeg's log could not be read: {ex})"
        return self._said

    def close(self) -> None:
        """Finish encoding and move the file onto `path`. Raises OutputError if ffmpeg failed."""
        if self._closed:
            return
        if self.frames_written == 0:
            self.abort()
            raise OutputError(f"No frames were written to '{self.path}'; nothing was saved (the old file is kept).")
        try:
            self._proc.stdin.close()
        except (BrokenPipeError, OSError):
            pass
        code = self._proc.wait()
        self._closed = True
        try:
            self._stderr()
            if code != 0:
                raise OutputError(
                    f"ffmpeg failed ({code}) writing '{self.path}'; nothing was saved. ffmpeg said:\n{self._stderr()}"
                )
            try:
                os.replace(self._tmp, self.path)
            except OSError as ex:
                raise OutputError(f"Cannot move the finished video onto '{self.path}': {ex}. Check permissions.") from ex
        finally:
            self._log.close()
            _unlink(self._tmp)

    def abort(self) -> None:
        """Stop ffmpeg and delete the temp file; the destination is left as it was."""
        if self._closed:
            return
        self._closed = True
        if self._proc.poll() is None:
            self._proc.kill()
        try:
            self._proc.stdin.close()
        except (BrokenPipeError, OSError):
            pass
        self._proc.wait()
        self._stderr()  # read before the log goes: a caller's message quotes it
        self._log.close()
        _unlink(self._tmp)


def _unlink(path: Path) -> None:
    try:
        path.unlink()
    except FileNotFoundError:
        pass
    except OSError as ex:  # pragma: no cover - e.g. a locked file on Windows
        log.warning("Could not remove temp file '%s': %s", path, ex)


JPEG_QUALITY = 95
"""JPEG quality of picture outputs (OpenCV's default is 95 too; said here so it is not implicit)."""


def encode_picture(target: Path, frame: np.ndarray, suffix: str) -> bool:
    """Write ``frame`` to ``target`` as the type ``suffix`` says: ".exr" float linear RGB as float32
    R, G, B; else (H, W, 3) RGB bytes (or uint16) through OpenCV. False when OpenCV could not write;
    OSError as raised."""
    if suffix == ".exr":
        from .exr import write_exr

        write_exr(target, {c: frame[:, :, i].astype(np.float32, copy=False) for i, c in enumerate("RGB")})
        return True
    import cv2

    params = [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY] if suffix in (".jpg", ".jpeg") else []
    return bool(cv2.imwrite(str(target), np.ascontiguousarray(frame[:, :, ::-1]), params))


class _PictureWriter(_AtomicWriter):
    """A writer of picture files; ``suffix`` (lower case) picks their type."""

    suffix = ".png"

    @property
    def linear(self) -> bool:
        """True when the pictures take linear float RGB (EXR), not display sRGB bytes."""
        return self.suffix == ".exr"


class ImageSequenceWriter(_PictureWriter):
    """Write numbered frames into `directory`, replacing it atomically on success.

    pattern: printf file name ("frame_%05d.png"); the suffix picks the format. PNG/JPG/TIF take
    (H, W, 3) uint8 RGB (PNG/TIF also uint16); ".exr" takes (H, W, 3) float linear RGB written as
    float32 R, G, B. Numbering starts at `start`. Frames go to a hidden temp folder beside
    `directory`; `close()` swaps it in (an existing folder is moved aside and deleted only
    after the new one is in place); an exception inside `with`, or `abort()`, deletes the temp.
    """

    def __init__(self, directory: str | Path, pattern: str = "frame_%05d.png", start: int = 1):
        self.directory = Path(directory)
        try:
            pattern % 1
        except (TypeError, ValueError) as ex:
            raise InputError(f"File pattern {pattern!r} needs one integer field such as %05d.") from ex
        if "/" in pattern or "\\" in pattern:
            raise InputError(f"File pattern {pattern!r} must be a file name only; put folders in `directory`.")
        self.pattern = pattern
        self.start = int(start)
        self.suffix = Path(pattern % 0).suffix.lower()
        if self.suffix not in (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".exr"):
            raise InputError(f"File pattern {pattern!r} has an unsupported type; use .png, .jpg, .tif or .exr.")
        if self.directory.exists() and not self.directory.is_dir():
            raise OutputError(f"'{self.directory}' is a file, not a folder; choose another output folder.")
        try:
            self.directory.parent.mkdir(parents=True, exist_ok=True)
            self._tmp = temp_sibling(self.directory, ".tmp")
            self._tmp.mkdir()
        except OSError as ex:
            raise OutputError(f"Cannot create a folder beside '{self.directory}': {ex}. Choose a writable location.") from ex
        self.frames_written = 0
        self._shape: tuple[int, ...] | None = None
        self._closed = False

    def write(self, frame: np.ndarray) -> Path:
        """Write the next frame; returns the final path it will have after close()."""
        if self._closed:
            raise OutputError(f"The writer for '{self.directory}' is already closed; open a new one.")
        frame = np.asarray(frame)
        name = self.pattern % (self.start + self.frames_written)
        self._check(frame, name)
        target = self._tmp / name
        try:
            if not encode_picture(target, frame, self.suffix):
                raise OutputError(f"Cannot write frame '{self.directory / name}'; check free disk space and that "
                                  "the folder is writable (nothing was saved, an earlier folder there is kept).")
        except OSError as ex:
            raise output_error(self.directory / name, ex, "write frame") from ex
        self.frames_written += 1
        return self.directory / name

    def _check(self, frame: np.ndarray, name: str) -> None:
        if self.suffix == ".exr":
            good = np.issubdtype(frame.dtype, np.floating)
            want = "float linear RGB"
        else:
            allowed = (np.uint8, np.uint16) if self.suffix in (".png", ".tif", ".tiff") else (np.uint8,)
            good = frame.dtype in allowed
            want = "uint8 RGB" if len(allowed) == 1 else "uint8 or uint16 RGB"
        if not good or frame.ndim != 3 or frame.shape[2] != 3:
            raise InputError(f"Frame '{name}' for '{self.directory}' is {frame.dtype} {frame.shape}; expected (H, W, 3) {want}.")
        if self._shape is None:
            self._shape = frame.shape
        elif frame.shape != self._shape:
            raise InputError(
                f"Frame '{name}' for '{self.directory}' is {frame.shape[1]}x{frame.shape[0]} but the first frame was "
                f"{self._shape[1]}x{self._shape[0]}; keep one size per sequence."
            )

    def close(self) -> None:
        """Swap the finished folder in place of `directory`."""
        if self._closed:
            return
        if self.frames_written == 0:
            self.abort()
            raise OutputError(f"No frames were written to '{self.directory}'; nothing was saved (the old folder is kept).")
        self._closed = True
        old = None
        try:
            if self.directory.exists():
                old = temp_sibling(self.directory, ".old")
                os.replace(self.directory, old)
            os.replace(self._tmp, self.directory)
        except OSError as ex:
            if old is not None and not self.directory.exists():
                os.replace(old, self.directory)  # put the earlier result back
                old = None
            shutil.rmtree(self._tmp, ignore_errors=True)
            raise OutputError(f"Cannot move the finished frames into '{self.directory}': {ex}. Check permissions.") from ex
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)

    def abort(self) -> None:
        """Delete the temp folder; `directory` is left as it was."""
        if self._closed:
            return
        self._closed = True
        shutil.rmtree(self._tmp, ignore_errors=True)


STILL_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".exr")
"""Picture types :class:`StillImageWriter` writes (EXR: linear HDR radiance, float32 RGB)."""


class StillImageWriter(_PictureWriter):
    """Write one picture (a refocused photo) to ``path``, atomically: into a hidden temp file beside
    it, renamed onto ``path`` by ``close()``; ``abort()`` deletes the temp and an earlier picture at
    ``path`` survives. PNG/JPG/TIF take (H, W, 3) uint8 RGB, ``.exr`` float linear RGB. A second
    frame is refused: a picture holds one."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.suffix = self.path.suffix.lower()
        if self.suffix not in STILL_SUFFIXES:
            raise InputError(f"'{self.path}': a picture is written as {', '.join(STILL_SUFFIXES)}; rename it")
        if self.path.is_dir():
            raise OutputError(f"'{self.path}' is a folder; give a file name for the picture")
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as ex:
            raise output_error(self.path, ex, "create the folder of") from ex
        self._tmp = temp_sibling(self.path, self.suffix)
        self.frames_written = 0
        self._closed = False

    def write(self, frame: np.ndarray) -> Path:
        """Write the picture (to the temp file until ``close()``); returns its final path."""
        if self._closed:
            raise OutputError(f"The writer for '{self.path}' is already closed; open a new one.")
        if self.frames_written:
            raise InputError(f"'{self.path}' is a single picture, but the render has more than one frame: give a "
                             f"video (.mp4) or a numbered sequence ({self.path.stem}_%05d{self.path.suffix})")
        frame = np.asarray(frame)
        want_float = self.linear
        ok_type = np.issubdtype(frame.dtype, np.floating) if want_float else frame.dtype == np.uint8
        if not ok_type or frame.ndim != 3 or frame.shape[2] != 3:
            kind = "float linear RGB" if want_float else "uint8 RGB"
            raise InputError(f"the picture for '{self.path}' is {frame.dtype} {frame.shape}; expected (H, W, 3) {kind}")
        try:
            if not encode_picture(self._tmp, frame, self.suffix):
                raise OutputError(f"Cannot write the picture '{self.path}'; check free disk space and that the "
                                  "folder is writable (an earlier picture there is kept).")
        except OSError as ex:
            raise output_error(self.path, ex, "write") from ex
        self.frames_written = 1
        return self.path

    def close(self) -> None:
        """Move the finished picture onto ``path`` (replacing an earlier one only now)."""
        if self._closed:
            return
        if not self.frames_written:
            self.abort()
            raise OutputError(f"No picture was rendered for '{self.path}'; nothing was saved (an earlier one is kept).")
        self._closed = True
        try:
            os.replace(self._tmp, self.path)
        except OSError as ex:
            self._tmp.unlink(missing_ok=True)
            raise output_error(self.path, ex, "move the finished picture onto") from ex

    def abort(self) -> None:
        """Delete the temp file; ``path`` is left as it was."""
        if self._closed:
            return
        self._closed = True
        self._tmp.unlink(missing_ok=True)
