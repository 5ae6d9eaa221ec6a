"""Video and image-sequence input: probe a clip, stream its frames as uint8 RGB.

A clip is either a video file FFmpeg decodes (mp4, mov, mkv, ...) or an image sequence given
as a folder (natural order: frame2 < frame10), a glob pattern ("shots/*.png") or a printf
pattern ("frames/f_%04d.png"). Videos are decoded by the ffmpeg bundled with imageio-ffmpeg
through a pipe, not by cv2.VideoCapture: it converts YUV with the matrix the file is tagged
with (OpenCV always uses BT.601, which shifts the colours of BT.709 HD video by ~13 levels)
and applies display rotation, so phone frames come out upright; an HDR clip (HLG, as iPhones
record by default, or PQ) is tone-mapped to the SDR BT.709 the engine works in (:data:`HDR_TO_SDR`).
Image files are read with OpenCV. Frames are streamed, never held as a whole clip.

A video range that does not start at frame 0 is positioned by seeking (``seek_point``): from
the demuxer's packet timestamps (listed without decoding, up to a little past the range:
``scan_packets``), ffmpeg is sent to the keyframe before the first wanted frame and keeps the
frames whose presentation time is at least half way between frame start-1 and frame start,
which are exactly frames start, start+1, ... of a decode from the beginning (frame k being the
packet with the k-th smallest presentation time; any frame rate, variable too). Where that
cannot be guaranteed (containers whose seeking is approximate, missing or repeated timestamps,
a stream that does not begin with a keyframe) it decodes from the beginning.

A variable-frame-rate video (phones: Android above all, iPhones in low light; its frames, by
their own presentation times, do not each fall on a frame of a timeline at the rate of its median
frame interval) is read on a constant-rate timeline at its nominal rate (:class:`FrameTimeline`),
frame k being the picture shown k / fps s in, as Blender's sequencer shows the clip and as its
sound runs: every command, ``rvr batch`` and the Blender tool count the same frames, and a
frame's sound is its own. Its decoded frames are seeked and decoded as above, then repeated or
skipped.
"""
from __future__ import annotations

import functools
import logging
import math
import os
import re
import stat
import subprocess
import tempfile
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path
from typing import Iterator

import numpy as np

from ..errors import InputError, VideoOpenError
from .paths import expand_sequence

log = logging.getLogger(__name__)

IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".exr", ".webp")
DEFAULT_SEQUENCE_FPS = 24.0
_SEQUENCE_HELP = (
    "give a video file, a folder of images, a glob such as 'shots/*.png' "
    "or a printf pattern such as 'frames/f_%04d.png'"
)


@dataclass(frozen=True)
class ClipInfo:
    """What a clip is: size in px (upright, after display rotation), frame rate in frames/s."""

    path: Path
    width: int
    height: int
    fps: float
    frame_count: int
    has_audio: bool
    kind: str  # "video" or "images"
    nominal_fps: float | None = None
    """A variable-frame-rate video's nominal rate (frames/s): it is read on a constant-rate timeline
    at this rate (:class:`FrameTimeline`; ``fps`` and ``frame_count`` are that timeline's). None for
    a constant-rate video or an image sequence."""
    average_fps: float | None = None
    """A variable-frame-rate video's average rate (its decoded frames over its duration), else None."""
    decoded_frames: int | None = None
    """A variable-frame-rate video's count of decoded frames (``frame_count`` counts its timeline), else None."""


HDR_TRANSFERS = {"arib-std-b67": "HLG", "smpte2084": "PQ (HDR10)"}
"""Transfer functions (as ffmpeg names them) of HDR video: a phone's HDR clip (iPhone: HLG)."""
HDR_TO_SDR = ("zscale=t=linear:npl=100,format=gbrpf32le,zscale=p=bt709,tonemap=tonemap=mobius:param=0.8:desat=0,"
              "zscale=t=bt709:m=gbr:r=full,format=gbrp")
"""The ffmpeg filters that bring an HDR frame to the SDR BT.709 the engine works in: to linear light
(SDR white at 100 nits), BT.2020 primaries to BT.709, Mobius tone mapping (linear up to 0.8 of SDR
white, about code 231, then a roll-off that keeps the highlights' gradation instead of clipping
them, hue kept), the BT.709 transfer, full-range RGB. An SDR clip converted to HLG and decoded this
way: 34.8 dB PSNR against itself on the restaurant clip, 45.9 dB on smooth gradients (decoded as if
it were SDR, as before: 18.8 / 13.4 dB, dark and at half the saturation; Mobius at its default 0.3:
33.9 / 26.4 dB, the bright half compressed)."""


# ----------------------------------------------------------------------------- helpers


@functools.lru_cache(maxsize=1)
def _ffmpeg_has_tonemap() -> bool:
    """Whether the bundled ffmpeg has the zscale and tonemap filters (HDR to SDR)."""
    try:
        out = subprocess.run([ffmpeg_exe(), "-hide_banner", "-filters"], capture_output=True, check=False)
    except OSError:  # pragma: no cover - the binary ships with imageio-ffmpeg
        return False
    names = {line.split()[1] for line in out.stdout.decode("utf-8", "replace").splitlines() if len(line.split()) > 2}
    return {"zscale", "tonemap"} <= names


def hdr_transfer(description: str) -> str | None:
    """The HDR transfer ("HLG", "PQ (HDR10)") of the first video stream in ffmpeg's description of
    an input, or None for SDR."""
    for line in description.splitlines():
        if re.search(r"Stream #\d+:\d+.*: Video:", line):
            return next((name for key, name in HDR_TRANSFERS.items() if key in line), None)
    return None


def _file_key(video: Path) -> tuple[str, int, int]:
    """(path, modification time, size) of a file: the key of what is read from it once (a replaced
    file is read again)."""
    st = Path(video).stat()
    return str(video), st.st_mtime_ns, st.st_size


def video_transfer(video: Path) -> str | None:
    """The HDR transfer of a video file ("HLG", "PQ (HDR10)"), None for SDR."""
    return hdr_transfer(_listing(*_file_key(video)).description)


def _hdr_filter(video: Path) -> str | None:
    """The filters that decode an HDR ``video`` to SDR (:data:`HDR_TO_SDR`), None for SDR or where
    this ffmpeg cannot tone map (then the frames come as coded, and a warning says so)."""
    transfer = video_transfer(video)
    if transfer is None:
        return None
    if not _ffmpeg_has_tonemap():
        log.warning("'%s' is HDR (%s), but this ffmpeg has no zscale/tonemap filter: its frames are read as if "
                    "SDR (dark, desaturated); convert it to SDR BT.709 first, or reinstall imageio-ffmpeg",
                    video, transfer)
        return None
    return HDR_TO_SDR


def ffmpeg_exe() -> str:
    """Path of the ffmpeg binary bundled with imageio-ffmpeg (made executable first: Blender's
    extension installer unpacks wheels without the execute bit)."""
    import imageio_ffmpeg

    restore_execute_bit(Path(imageio_ffmpeg.__file__).parent / "binaries")
    try:
        return imageio_ffmpeg.get_ffmpeg_exe()
    except RuntimeError as ex:
        raise InputError(f"no usable ffmpeg ({ex}); reinstall imageio-ffmpeg (or the extension), or set "
                         "IMAGEIO_FFMPEG_EXE to an ffmpeg executable") from ex


def restore_execute_bit(folder: Path) -> list[Path]:
    """Add the execute bits (as far as read is allowed) to the ``ffmpeg*`` files in ``folder``
    that lack them; returns the files changed. A read-only install is left as it is."""
    changed = []
    for exe in sorted(folder.glob("ffmpeg*")) if folder.is_dir() else []:
        mode = exe.stat().st_mode
        if not exe.is_file() or mode & stat.S_IXUSR:
            continue
        try:
            exe.chmod(mode | ((mode & 0o444) >> 2))  # r -> x for user, group, other
        except OSError:
            continue
        changed.append(exe)
    return changed


def _resolve(path: str | Path) -> tuple[str, Path, list[Path]]:
    """(kind, display path, files): kind "video" (files = [file]) or "images" (ordered frames)."""
    if isinstance(path, ClipInfo):
        path = path.path
    text = str(path)
    how, files = expand_sequence(text, IMAGE_EXTENSIONS)
    shown = Path(text)
    if how == "missing":
        raise VideoOpenError(f"Input not found: '{text}'. Check the path; {_SEQUENCE_HELP}.")
    if how == "file":
        kind = "images" if shown.suffix.lower() in IMAGE_EXTENSIONS else "video"
        return kind, shown, files
    if not files:
        if how == "directory":
            raise VideoOpenError(
                f"Folder '{text}' contains no images ({', '.join(IMAGE_EXTENSIONS)}). "
                "Put the frames there, or point to the video file itself."
            )
        raise VideoOpenError(f"No files match the pattern '{text}'. Check the folder and the file names; {_SEQUENCE_HELP}.")
    return "images", shown, files


def _to_rgb8(image: np.ndarray, source: Path) -> np.ndarray:
    """Any OpenCV-decoded image (BGR/BGRA/gray, 8/16-bit/float) -> (H, W, 3) uint8 RGB.

    16-bit is rounded to 8-bit; floats are taken as display values in [0, 1] and clipped;
    alpha is dropped (not composited).
    """
    if image.ndim == 2:
        image = image[:, :, None]
    channels = image.shape[2]
    if channels >= 3:
        image = image[:, :, 2::-1]  # BGR(A) -> RGB
    else:
        image = np.repeat(image[:, :, :1], 3, axis=2)
    if image.dtype == np.uint8:
        return np.ascontiguousarray(image)
    if image.dtype == np.uint16:
        return ((image.astype(np.uint32) + 128) // 257).astype(np.uint8)
    if np.issubdtype(image.dtype, np.floating):
        from ..color import to_uint8

        return to_uint8(np.nan_to_num(image.astype(np.float32), nan=0.0))
    raise VideoOpenError(f"Image '{source}' has pixel type {image.dtype}, which is not supported; save it as 8- or 16-bit PNG.")


def _read_exr_rgb8(path: Path) -> np.ndarray:
    """Linear EXR frame -> sRGB-encoded (H, W, 3) uint8 (channels R,G,B or Y)."""
    from ..color import linear_to_srgb, to_uint8
    from .exr import read_exr

    try:
        channels = read_exr(path)
    except InputError as ex:
        raise VideoOpenError(str(ex)) from ex
    if all(c in channels for c in ("R", "G", "B")):
        rgb = np.stack([channels["R"], channels["G"], channels["B"]], axis=2)
    elif "Y" in channels:
        rgb = np.repeat(channels["Y"][:, :, None], 3, axis=2)
    else:
        raise VideoOpenError(
            f"EXR frame '{path}' has channels {sorted(channels)} but no R,G,B or Y; export the frames as RGB EXR."
        )
    return to_uint8(linear_to_srgb(np.nan_to_num(rgb, nan=0.0)))


def read_image_rgb8(path: Path) -> np.ndarray:
    """Read one image file as (H, W, 3) uint8 RGB; raise VideoOpenError naming it if unreadable."""
    import cv2

    if path.suffix.lower() == ".exr":
        return _read_exr_rgb8(path)
    # JPEGs through IMREAD_COLOR so their EXIF orientation is applied (IMREAD_UNCHANGED ignores it).
    flags = cv2.IMREAD_COLOR if path.suffix.lower() in (".jpg", ".jpeg") else cv2.IMREAD_UNCHANGED
    image = cv2.imread(str(path), flags)
    if image is None or image.size == 0:
        raise VideoOpenError(
            f"Cannot read image '{path}': the file is missing, corrupt or not an image format OpenCV reads. "
            "Re-export the frame (PNG is safest) or remove it from the sequence."
        )
    return _to_rgb8(image, path)


# ----------------------------------------------------------------------------- video via ffmpeg

_STREAM_FPS = re.compile(r"([\d.]+)(k?) fps, ([\d.]+)(k?) tbr")
_PACKET_FLAGS = re.compile(r"F=0x([0-9a-fA-F]+)")
_SIZE_CHANGE = re.compile(
    r"filter context - w: (\d+) h: (\d+).*?incoming frame - w: (\d+) h: (\d+).*?pts_time: ([-\d.]+|NOPTS)"
)
_DISCARD_FLAG = 0x4  # AV_PKT_FLAG_DISCARD: packet kept only for decoding, e.g. cut away by an MP4 edit list


def _tail(text: str, lines: int = 12) -> str:
    kept = [line for line in text.strip().splitlines() if line.strip()]
    return "\n".join(kept[-lines:])


@dataclass(frozen=True)
class _Listing:
    """What :func:`_scan_with_ffmpeg` read: the shown frames' count, whether there is audio,
    ffmpeg's description of the input, the shown frames' presentation times in time-base units
    (sorted; None when a packet has none) and the time base (s per unit; None if not given)."""

    count: int
    has_audio: bool
    description: str
    shown_pts: np.ndarray | None
    time_base: Fraction | None


@functools.lru_cache(maxsize=16)
def _listing(path: str, mtime_ns: int, size: int) -> _Listing:
    """:func:`_scan_with_ffmpeg` of a file version (:func:`_file_key`)."""
    return _scan_with_ffmpeg(Path(path))


def _scan_with_ffmpeg(path: Path) -> _Listing:
    """Count the shown frames of the first video stream without decoding, and look for audio.

    Lists packets by stream copy (framecrc) and skips packets flagged discard, which MP4 edit
    lists (trimmed clips) keep only for decoding; the count then equals the decoded frames.
    """
    cmd = [ffmpeg_exe(), "-hide_banner", "-nostdin", "-i", str(path), "-map", "0:V:0", "-c", "copy",
           "-f", "framecrc", "-"]
    try:
        run = subprocess.run(cmd, capture_output=True, check=False)
    except OSError as ex:  # pragma: no cover - the binary ships with imageio-ffmpeg
        raise VideoOpenError(f"Cannot run ffmpeg to read '{path}': {ex}. Reinstall the imageio-ffmpeg package.") from ex
    stderr = run.stderr.decode("utf-8", "replace")
    description = stderr.split("Stream mapping:")[0].split("Output #0")[0]
    if run.returncode != 0:
        if "matches no streams" in stderr:
            raise VideoOpenError(f"'{path}' has no video stream; choose a video file or an image sequence.")
        raise VideoOpenError(
            f"Cannot open video '{path}': FFmpeg could not read it. The file may be corrupt, incomplete or not a "
            f"video; re-export it (H.264 MP4 is safest).\nffmpeg said:\n{_tail(stderr)}"
        )
    has_audio = re.search(r"Stream #\d+:\d+.*: Audio:", description) is not None
    count = packets = 0
    header: list[str] = []
    shown: list[int] | None = []
    for line in run.stdout.decode("ascii", "replace").splitlines():
        if not line or line.startswith("#"):
            header.append(line + "\n")
            continue
        packets += 1
        packet = parse_packet(line)
        if packet is not None and not packet.discard:
            count += 1
            if shown is not None and packet.pts is not None:
                shown.append(packet.pts)
            else:
                shown = None
    tb = _time_base(header)
    span = float((max(shown) - min(shown)) * tb) if shown and tb is not None else None
    _warn_if_truncated(path, count, packets, "partial file" in stderr, span)
    return _Listing(count, has_audio, description, np.sort(np.asarray(shown, dtype=np.int64)) if shown is not None
                    else None, tb)


def _warn_if_truncated(path: Path, count: int, packets: int, partial: bool, span_s: float | None = None) -> None:
    """Warn, naming the file and both counts, when the container declares more frames than its
    data holds (a copy or download cut short; a ``+faststart`` MP4 keeps its full index). A
    container that declares its duration times its rate (Matroska) is not truncated when its
    frames' own times (``span_s`` from the first to the last) span that count: a variable frame rate."""
    import cv2

    cap = cv2.VideoCapture(str(path), cv2.CAP_FFMPEG)
    try:
        declared = float(cap.get(cv2.CAP_PROP_FRAME_COUNT)) if cap.isOpened() else 0.0
        rate = float(cap.get(cv2.CAP_PROP_FPS)) if cap.isOpened() else 0.0
    finally:
        cap.release()
    declared = int(declared) if np.isfinite(declared) and declared > 0 else 0
    spanned = int(round(span_s * rate)) + 1 if span_s is not None and np.isfinite(rate) and rate > 0 else 0
    if partial or declared > max(packets, spanned):
        said = f"its container declares {declared} frames but" if declared > packets else "ffmpeg reports a partial file;"
        log.warning("'%s' is truncated or damaged: %s only %d can be read; the clip is used as %d frames. Re-copy or "
                    "re-export the file to get the whole clip.", path, said, count, count)


def _container_fps(path: Path) -> float:
    """Average frame rate as OpenCV's FFmpeg backend reports it (0.0 when unknown)."""
    import cv2

    cap = cv2.VideoCapture(str(path), cv2.CAP_FFMPEG)
    try:
        fps = float(cap.get(cv2.CAP_PROP_FPS)) if cap.isOpened() else 0.0
    finally:
        cap.release()
    return fps if np.isfinite(fps) and fps > 0 else 0.0


def stream_rates(description: str) -> tuple[float, float] | None:
    """(average, nominal) frames/s of the first video stream as ffmpeg's description of the input
    prints them ("25.71 fps, 30 tbr"), None where it does not."""
    match = _STREAM_FPS.search(description)
    if not match:
        return None
    average = float(match.group(1)) * (1000 if match.group(2) else 1)
    nominal = float(match.group(3)) * (1000 if match.group(4) else 1)
    return (average, nominal) if average > 0 and nominal > 0 else None


NTSC_RATES = tuple(Fraction(1000 * n, 1001) for n in (24, 30, 48, 60, 120, 240))
"""The 1000/1001 rates, which ffmpeg prints rounded ("23.98", "29.97"): :func:`exact_rate`."""


def exact_rate(rate: float) -> float:
    """A frame rate as printed, made exact where it is a 1000/1001 rate (23.98 is 24000/1001: at
    23.98 the timeline of a long clip would slip a frame every ~4 minutes)."""
    near = min(NTSC_RATES, key=lambda r: abs(float(r) - rate))
    return float(near) if abs(float(near) - rate) < 0.006 else float(rate)


def _nominal_rate(description: str, median_rate: float) -> float:
    """The rate a variable-frame-rate clip's timeline runs at: the stream's nominal rate (ffmpeg's
    tbr, as Blender takes it) where it is one a camera records at, else the rate of its median
    frame interval; made exact."""
    rates = stream_rates(description)
    return exact_rate(rates[1]) if rates is not None and 1.0 <= rates[1] <= 240.0 else median_rate


@dataclass(frozen=True)
class FrameTimeline:
    """How a variable-frame-rate video is read: on a constant-rate timeline at its nominal rate
    ``fps``, frame k being the picture shown k / fps s after its first one. ``decoded[k]`` is that
    picture's index among the decoded frames (in presentation order, as a plain decode gives them):
    a frame held longer is repeated, one shown for less than a frame time may be skipped. Frame k
    is the last decoded frame whose time, in frames of the timeline, rounds to k or less (ffmpeg's
    ``fps`` filter places frames so, and Blender's sequencer shows a movie strip so)."""

    fps: float
    average_fps: float
    decoded: np.ndarray
    decoded_count: int

    @property
    def frame_count(self) -> int:
        return int(len(self.decoded))


def timeline_of(shown_pts: "np.ndarray | list[int]", time_base: Fraction | float, fps: float) -> np.ndarray:
    """``FrameTimeline.decoded`` of frames shown at ``shown_pts`` (time-base units, any order) on a
    timeline of ``fps`` frames a second from the first of them: per timeline frame, the index of
    the decoded frame shown then (int64)."""
    shown = np.sort(np.asarray(shown_pts, dtype=np.int64))
    seconds = (shown - shown[0]) * float(time_base)
    slot = np.floor(seconds * fps + 0.5).astype(np.int64)
    return np.searchsorted(slot, np.arange(int(slot[-1]) + 1), side="right") - 1


def _is_identity(decoded: np.ndarray) -> bool:
    return bool(np.array_equal(decoded, np.arange(len(decoded))))


@functools.lru_cache(maxsize=16)
def _timeline(path: str, mtime_ns: int, size: int) -> FrameTimeline | None:
    listing = _listing(path, mtime_ns, size)
    pts = listing.shown_pts
    if pts is None or listing.time_base is None or len(pts) < 2 or len(np.unique(pts)) != len(pts):
        rates = stream_rates(listing.description)
        # (a nominal rate twice the average is an interlaced stream's field rate, not a variable frame rate)
        if rates is not None and min(abs(rates[1] - rates[0]), abs(rates[1] - 2 * rates[0])) > 0.02 * rates[1]:
            log.warning("'%s' looks variable-frame-rate (average %.4g fps, nominal %.4g fps) but its frames' times are "
                        "missing or repeated, so its frames are read in decode order and the sound may drift against "
                        "them; convert it first (ffmpeg -i IN -fps_mode cfr -r %.4g OUT.mp4)", path, *rates, rates[1])
        return None
    seconds = (pts - pts[0]) * float(listing.time_base)
    median = float(np.median(np.diff(seconds)))
    if median <= 0:
        return None
    median_rate = exact_rate(1.0 / median)
    if _is_identity(timeline_of(pts, listing.time_base, median_rate)):
        return None  # every frame at its own time at the rate of its median interval: a constant frame rate
    nominal = _nominal_rate(listing.description, median_rate)
    decoded = timeline_of(pts, listing.time_base, nominal)
    if _is_identity(decoded):  # (a nominal rate other than the median one that still fits every frame)
        return None
    average = listing.count / (float(seconds[-1]) + 1.0 / nominal)
    log.info("'%s' has a variable frame rate (average %.4g fps, nominal %.4g fps): it is read at a constant %.4g fps, "
             "each of its %d frames at its time (%d frames), so sound and picture stay in sync",
             path, average, nominal, nominal, listing.count, len(decoded))
    return FrameTimeline(nominal, average, decoded, listing.count)


def video_timeline(video: Path) -> FrameTimeline | None:
    """The constant-rate timeline a variable-frame-rate video is read on (:class:`FrameTimeline`),
    None for a constant-rate video (or one whose frame times are missing: decode order)."""
    return _timeline(*_file_key(video))


def _read_exact(stream, count: int) -> bytearray | None:
    """Read exactly `count` bytes (None at a clean end of stream)."""
    buf = bytearray(count)
    view = memoryview(buf)
    got = 0
    while got < count:
        n = stream.readinto(view[got:])
        if not n:
            return None if got == 0 else buf[:got]
        got += n
    return buf


def _read_ppm(stream, video: Path) -> np.ndarray | None:
    """Next binary PPM frame (as ffmpeg's ppm encoder writes it) -> (H, W, 3) uint8, None at the end."""
    magic = stream.readline()
    if not magic:
        return None
    dims = stream.readline().split()
    maxval = stream.readline().strip()
    if magic.strip() != b"P6" or len(dims) != 2 or maxval != b"255":
        raise VideoOpenError(f"Unexpected data while decoding '{video}'; the ffmpeg output was not a PPM stream.")
    width, height = int(dims[0]), int(dims[1])
    data = _read_exact(stream, width * height * 3)
    if data is None or len(data) != width * height * 3:
        return None
    return np.frombuffer(data, dtype=np.uint8).reshape(height, width, 3)


class _LogWatch:
    """Scan ffmpeg's log file incrementally for a mid-stream resolution change."""

    def __init__(self, log_file):
        self.file = log_file
        self.pos = 0
        self.partial = b""

    def size_change(self) -> tuple[str, str, float | None] | None:
        """(old size, new size, time in s) once ffmpeg has logged a resolution change, else None."""
        end = os.fstat(self.file.fileno()).st_size
        if end == self.pos:
            return None
        # pread, not seek + read: the file offset is shared with ffmpeg, which is still writing
        chunk = self.partial + os.pread(self.file.fileno(), end - self.pos, self.pos)
        self.pos = end
        lines, _, self.partial = chunk.rpartition(b"\n")
        for match in _SIZE_CHANGE.finditer(lines.decode("utf-8", "replace")):
            old, new = (match.group(1), match.group(2)), (match.group(3), match.group(4))
            if old != new:
                t = None if match.group(5) == "NOPTS" else float(match.group(5))
                return f"{old[0]}x{old[1]}", f"{new[0]}x{new[1]}", t
        return None


# ----------------------------------------------------------------------------- seeking

# Demuxers whose backward seek lands exactly on an indexed keyframe at or before the target
# (MP4/MOV: the sample table, by decode time; Matroska: the cues, by presentation time).
# Others (MPEG-TS/PS, AVI, FLV, raw streams) seek approximately: they decode from the start.
SEEKABLE_FORMATS = ("mov,mp4,m4a,3gp,3g2,mj2", "matroska,webm")
_INPUT_FORMAT = re.compile(r"Input #0, (\S+), from")
_TIME_BASE = re.compile(r"^#tb 0: (\d+)/(\d+)", re.MULTILINE)
_KEY_FLAG = 0x1  # AV_PKT_FLAG_KEY: a random access point (framecrc omits F= when it is the only flag)
_NOPTS = -(2**63)
REORDER_FRAMES = 16  # most packets decoded before a packet and shown after it (H.264/HEVC limit)
FFMPEG_SEEK_BACKOFF = Fraction(3, 23)  # s: ffmpeg's -ss lands this much earlier on streams with B-frames


@dataclass(frozen=True)
class Packet:
    """One packet of the video stream as the demuxer gives it: dts, pts in stream time-base
    units (None = unknown), keyframe, discard (decoded but never shown: MP4 edit lists)."""

    dts: int | None
    pts: int | None
    key: bool
    discard: bool


@dataclass(frozen=True)
class PacketScan:
    """The first video stream's packets in decode order; container: ffmpeg's input format
    name (e.g. 'mov,mp4,m4a,3gp,3g2,mj2'); time_base: s per timestamp unit; complete: False
    when the listing stopped early (a prefix of the stream, see :func:`scan_packets`)."""

    container: str
    time_base: Fraction
    packets: list[Packet]
    complete: bool = True


def _timestamp(text: str) -> int | None:
    value = int(text)
    return None if value == _NOPTS else value


def parse_packet(line: str) -> Packet | None:
    """One packet line of ffmpeg's framecrc listing (None for a header line); F= omitted means key."""
    if not line.strip() or line.startswith("#"):
        return None
    fields = [f.strip() for f in line.split(",")]
    flags = _PACKET_FLAGS.search(line)
    bits = int(flags.group(1), 16) if flags else _KEY_FLAG
    return Packet(_timestamp(fields[1]), _timestamp(fields[2]), bool(bits & _KEY_FLAG), bool(bits & _DISCARD_FLAG))


def _time_base(header: list[str]) -> Fraction | None:
    tb = _TIME_BASE.search("".join(header))
    return Fraction(int(tb.group(1)), int(tb.group(2))) if tb else None


def _container(log_file) -> str | None:
    """ffmpeg's input format name from its log so far (pread: the file offset is ffmpeg's too)."""
    fd = log_file.fileno()
    found = _INPUT_FORMAT.search(os.pread(fd, os.fstat(fd).st_size, 0).decode("utf-8", "replace"))
    return found.group(1) if found else None


def scan_packets(video: Path, start: int | None = None) -> PacketScan | None:
    """The demuxer's own timestamps (``-copyts``: not shifted to start at 0) and flags of the
    first video stream's packets, listed by stream copy without decoding (~0.1 ms a packet);
    None when ffmpeg cannot list them (the decoder will then say why). start: stop once the
    packets read decide :func:`seek_point` for that frame (``complete`` False), so positioning
    a chunk lists the file up to the chunk, not to its end."""
    cmd = [ffmpeg_exe(), "-hide_banner", "-nostdin", "-copyts", "-i", str(video), "-map", "0:V:0", "-c", "copy",
           "-f", "framecrc", "-"]
    packets: list[Packet] = []
    header: list[str] = []
    check = None if start is None else start + 2 * REORDER_FRAMES
    stopped = False
    with tempfile.TemporaryFile() as log_file:
        try:
            proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=log_file)
        except OSError:  # pragma: no cover - the binary ships with imageio-ffmpeg
            return None
        try:
            for raw in proc.stdout:
                packet = parse_packet(raw.decode("ascii", "replace"))
                if packet is None:
                    header.append(raw.decode("ascii", "replace"))
                    continue
                packets.append(packet)
                if check is not None and len(packets) >= check:
                    check += 16
                    container, tb = _container(log_file), _time_base(header)
                    if container is None or tb is None:
                        break
                    if prefix_decides(PacketScan(container, tb, packets, False), start):
                        stopped = True
                        break
        finally:
            if proc.poll() is None:
                proc.kill()
            proc.stdout.close()
            code = proc.wait()
        container = _container(log_file)
    tb = _time_base(header)
    if container is None or tb is None or (code != 0 and not stopped):
        return None
    return PacketScan(container, tb, packets, not stopped)


def _shown_and_key(packets: list[Packet], start: int, bound: int | None) -> tuple[list[int], int | None]:
    """(pts of the shown packets up to ``bound`` (None: all), sorted; decode index of the
    keyframe to seek to for frame start, None if there is none or too few frames)."""
    shown = sorted(p.pts for p in packets if not p.discard and (bound is None or p.pts <= bound))
    if start >= len(shown):
        return shown, None
    first = shown[start]
    needed = min(i for i, p in enumerate(packets) if not p.discard and p.pts >= first)
    keys = [i for i in range(needed + 1) if packets[i].key and packets[i].pts <= first]
    return shown, keys[-1] if keys else None


def prefix_decides(scan: PacketScan, start: int) -> bool:
    """True when the packets listed decide frames start - 1 and start, the keyframe to seek to
    and the keyframe after it (always for a complete listing). In a conforming stream at most
    REORDER_FRAMES packets decoded before any packet are shown after it (the H.264/HEVC reorder
    limit, which decoders rely on to output frames in order), so every later packet is shown
    after all listed packets but the REORDER_FRAMES shown last."""
    packets = scan.packets
    if scan.complete or any(p.pts is None for p in packets):
        return True  # seek_point decides (or refuses) on what is there
    if len(packets) <= REORDER_FRAMES:
        return False
    bound = sorted(p.pts for p in packets)[-REORDER_FRAMES - 1]
    shown, j = _shown_and_key(packets, start, bound)
    if start >= len(shown):
        return False
    return j is None or any(p.key for p in packets[j + 1:])


def seek_point(scan: PacketScan, start: int) -> tuple[float, float] | None:
    """(seek target s, threshold s) for decoding frames start, start+1, ... of a clip by seeking.

    Frame k of a decode from the beginning is the shown packet with the k-th smallest pts.
    ffmpeg is sent to the keyframe j at or before (in decode order) every packet of frame start
    or later, whose pts is at most frame start's (so the frames wanted follow a random access
    point in decode and in display order); the target is j's index timestamp, so the backward
    seek lands on j or an earlier keyframe (landing earlier costs decode time, never frames).
    Frames with t >= threshold (half way between frames start-1 and start) are kept.
    None when exactness cannot be guaranteed: a container outside SEEKABLE_FORMATS, a missing
    or repeated timestamp, a stream whose first packet is not a keyframe, start out of range,
    a listing that stopped before deciding (:func:`prefix_decides`).
    """
    packets = scan.packets
    if scan.container not in SEEKABLE_FORMATS or not packets or not packets[0].key or start < 1:
        return None
    if any(p.pts is None or p.dts is None for p in packets) or not prefix_decides(scan, start):
        return None
    shown, j = _shown_and_key(packets, start, None)
    if len(set(shown)) != len(shown) or j is None:
        return None
    threshold = Fraction(shown[start - 1] + shown[start], 2) * scan.time_base
    later = [p for p in packets[j + 1:] if p.key]
    if not later and not scan.complete:
        return None
    return _seek_target(packets[j], later[0] if later else None, scan.time_base), float(threshold)


def _seek_target(key: Packet, next_key: Packet | None, time_base: Fraction) -> float:
    """-ss value (s, whole microseconds, as ffmpeg reads it) whose backward seek lands on ``key``
    or earlier, never on ``next_key``. The index time of a keyframe is its dts (MP4) or pts
    (Matroska): min of the two bounds both. ffmpeg itself seeks FFMPEG_SEEK_BACKOFF earlier
    when the stream has B-frames; the target adds that back as far as the next keyframe allows
    (ffmpeg rounds the target to the nearest time-base unit: half a unit of margin)."""
    us = 1_000_000
    low = math.ceil(Fraction(min(key.dts, key.pts)) * time_base * us)
    target = low + math.ceil(FFMPEG_SEEK_BACKOFF * us)
    if next_key is not None:
        high = math.floor((Fraction(min(next_key.dts, next_key.pts)) - Fraction(1, 2)) * time_base * us) - 1
        target = max(low, min(target, high))
    return target / us


def _video_command(video: Path, start: int, stop: int | None) -> list[str]:
    """The ffmpeg command decoding frames start..stop-1 (in decode order) into a PPM pipe
    (seeking when exact)."""
    head = [ffmpeg_exe(), "-hide_banner", "-nostdin", "-v", "warning", "-reinit_filter", "0"]
    tail = ["-map", "0:V:0", "-fps_mode", "passthrough", "-an", "-sn", "-dn"]
    point = None
    if start > 0:
        scan = scan_packets(video, start)
        point = seek_point(scan, start) if scan is not None else None
        if point is None:
            log.debug("'%s': no exact seek point for frame %d; decoding from the first frame", video, start)
    filters = []
    if point is not None:
        target, threshold = point
        cmd = head + ["-seek_timestamp", "1", "-ss", f"{target:.6f}", "-noaccurate_seek", "-copyts",
                      "-i", str(video), *tail]
        filters.append(f"select=gte(t\\,{threshold:.9f})")
    else:
        cmd = head + ["-i", str(video), *tail]
        if start > 0:
            filters.append(f"select=gte(n\\,{start})")
    hdr = _hdr_filter(video)
    if hdr is not None:
        filters.append(hdr)
    if filters:
        cmd += ["-vf", ",".join(filters)]
    if stop is not None:
        cmd += ["-frames:v", str(stop - start)]
    return cmd + ["-f", "image2pipe", "-c:v", "ppm", "-pix_fmt", "rgb24", "pipe:1"]


def _iter_timeline(video: Path, timeline: FrameTimeline, start: int, stop: int | None) -> Iterator[np.ndarray]:
    """Frames start..stop-1 of a variable-frame-rate video's constant-rate timeline: the decoded
    frames they show (:class:`FrameTimeline`), a frame shown on several timeline frames repeated
    (as a copy: a caller may change a frame it was given)."""
    stop = timeline.frame_count if stop is None else min(stop, timeline.frame_count)
    if start >= stop:
        return
    wanted = timeline.decoded[start:stop]
    k = 0
    for index, frame in enumerate(_iter_video(video, int(wanted[0]), int(wanted[-1]) + 1), start=int(wanted[0])):
        first = True
        while k < len(wanted) and wanted[k] == index:
            yield frame if first else frame.copy()
            first = False
            k += 1


def _iter_video(video: Path, start: int, stop: int | None) -> Iterator[np.ndarray]:
    """Decode with the bundled ffmpeg into a PPM pipe (frames in decode order).

    ffmpeg (unlike OpenCV's capture, which always assumes BT.601) converts with the colour
    matrix the file is tagged with (BT.709 for HD phone video) and applies display rotation.
    `-reinit_filter 0` makes a mid-stream resolution change show up in its log instead of
    being scaled away silently; it is then reported as an InputError. A range from start > 0
    seeks where that is exact (module docstring), else decodes from the first frame.
    """
    cmd = _video_command(video, start, stop)
    with tempfile.TemporaryFile() as log_file:
        proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=log_file)
        watch = _LogWatch(log_file)
        try:
            index, want = start, None
            while True:
                frame = _read_ppm(proc.stdout, video)
                if frame is None:
                    proc.wait()  # flush the whole log before the last scan
                change = watch.size_change()
                if change is not None:
                    old, new, t = change
                    fps = _container_fps(video) or DEFAULT_SEQUENCE_FPS
                    at = f"frame {round(t * fps)} (t={t:.3f} s)" if t is not None else f"after frame {index - 1}"
                    raise InputError(
                        f"Video '{video}' changes resolution from {old} to {new} at {at}; a clip must keep one "
                        "resolution. Re-export it at a fixed size (e.g. ffmpeg -vf scale=W:H) or split it."
                    )
                if frame is None:
                    break
                if want is None:
                    want = frame.shape
                elif frame.shape != want:
                    raise _size_error(index, video, frame.shape, want)
                yield frame
                index += 1
            proc.stdout.close()
            if proc.wait() != 0:
                log_file.seek(0)
                raise VideoOpenError(
                    f"Decoding '{video}' failed after {index - start} frames (from frame {start}); the file may be corrupt or truncated. "
                    f"Re-export or re-copy it.\nffmpeg said:\n{_tail(log_file.read().decode('utf-8', 'replace'))}"
                )
        finally:
            if proc.poll() is None:
                proc.kill()
            proc.wait()
            if proc.stdout is not None:
                proc.stdout.close()


# ----------------------------------------------------------------------------- public API


def _check_fps(fps: float | None) -> float | None:
    if fps is None:
        return None
    if not np.isfinite(fps) or fps <= 0:
        raise InputError(f"Frame rate fps={fps!r} is not valid; give a positive number of frames per second, e.g. 24.")
    return float(fps)


def probe_clip(path: str | Path, fps: float | None = None) -> ClipInfo:
    """Describe a clip, decoding only its first frame.

    fps: frames/s of an image sequence (default 24.0); for a video it overrides the container
    rate (a mislabelled clip; it does not change which frames are read). width/height are those
    of the decoded (upright) frames. frame_count of a video counts the frames of its first video
    stream from the packet list (exact, unlike container metadata, and honouring MP4 edit
    lists); of a variable-frame-rate video, the frames of its constant-rate timeline
    (:func:`video_timeline`). Raises VideoOpenError naming the path and the fix.
    """
    fps = _check_fps(fps)
    kind, shown, files = _resolve(path)
    if kind == "images":
        first = read_image_rgb8(files[0])
        return ClipInfo(shown, int(first.shape[1]), int(first.shape[0]), fps or DEFAULT_SEQUENCE_FPS,
                        len(files), False, "images")
    video = files[0]
    listing = _listing(*_file_key(video))
    count, has_audio, description = listing.count, listing.has_audio, listing.description
    frames = _iter_video(video, 0, 1)
    try:
        first = next(frames, None)
    finally:
        frames.close()
    if first is None or count <= 0:
        raise VideoOpenError(f"Video '{video}' has no decodable frames; the file may be truncated. Re-export or re-copy it.")
    timeline = video_timeline(video)
    nominal = average = None
    if timeline is not None:
        count, nominal, average = timeline.frame_count, timeline.fps, timeline.average_fps
    if fps is None:
        fps = nominal or _container_fps(video)
        if not fps:
            fps = DEFAULT_SEQUENCE_FPS
            log.warning("'%s' has no frame rate; assuming %.4g fps. Pass fps= to set it.", video, fps)
    transfer = hdr_transfer(description)
    if transfer is not None and _ffmpeg_has_tonemap():
        log.info("'%s' is HDR (%s): its frames are tone-mapped to SDR BT.709, which the engine and the refocused "
                 "video use", video, transfer)
    return ClipInfo(video, int(first.shape[1]), int(first.shape[0]), fps, count, has_audio, "video", nominal,
                    average, timeline.decoded_count if timeline is not None else None)


def _check_range(path: str | Path, start: int, stop: int | None) -> None:
    if start < 0:
        raise InputError(f"start={start} for '{path}' is negative; frames are counted from 0.")
    if stop is not None and stop < start:
        raise InputError(f"stop={stop} is before start={start} for '{path}'; give stop >= start (or None for the end).")


def _size_error(index: int, source: Path, got: tuple, want: tuple) -> InputError:
    return InputError(
        f"Frame {index} of '{source}' is {got[1]}x{got[0]} but the clip's first frame is {want[1]}x{want[0]}; "
        "a clip must keep one resolution. Re-export it at a fixed size (e.g. ffmpeg -vf scale=W:H)."
    )


def iter_frames(path: str | Path, start: int = 0, stop: int | None = None,
                decode_order: bool = False) -> Iterator[np.ndarray]:
    """Yield frames start..stop-1 (stop None = to the end) as (H, W, 3) uint8 RGB.

    A variable-frame-rate video's frames are those of its constant-rate timeline
    (:func:`video_timeline`: frame k is the picture shown k / nominal fps s in, so its sound stays in
    sync), as ``probe_clip`` counts them; ``decode_order`` True gives its decoded frames instead.

    Streams one decoded frame at a time. Videos are positioned by seeking to the keyframe
    before ``start`` where the packet timestamps make that exact (MP4/MOV, Matroska; any frame
    rate, variable too), else by decoding forward from the first frame (module docstring). Raises
    VideoOpenError when the clip cannot be opened, InputError when a frame's size differs from
    the first frame's.
    """
    _check_range(path, start, stop)
    kind, shown, files = _resolve(path)
    if stop is not None and stop == start:
        return
    if kind == "images":
        yield from _iter_images(files, start, stop)
    else:
        timeline = None if decode_order else video_timeline(files[0])
        if timeline is not None:
            yield from _iter_timeline(files[0], timeline, start, stop)
        else:
            yield from _iter_video(files[0], start, stop)


def _iter_images(files: list[Path], start: int, stop: int | None) -> Iterator[np.ndarray]:
    end = len(files) if stop is None else min(stop, len(files))
    if start >= end:
        return
    want = read_image_rgb8(files[0]).shape if start > 0 else None
    for index in range(start, end):
        frame = read_image_rgb8(files[index])
        if want is None:
            want = frame.shape
        elif frame.shape != want:
            raise _size_error(index, files[index], frame.shape, want)
        yield frame
