"""The per-frame part of LAAF, measured apart from the whole-clip decisions (``rvr batch``).

Where LAAF's time goes (``AutofocusJob`` timings, 100 frames of a 720p interview, 320 px
analysis width, a loaded 2-core machine): conversation preset: detectors 3.4-3.7 s (face
detection, mouth motion, synchrony flow), tracking 1.8-2.3 s, decode 0.6-0.7 s, combination
0.4-0.5 s, disparity 0.2 s (an .npy; a 1080p cache EXR costs more); action preset on a
640x272 clip (80 frames): detectors 1.3 s, combination 1.3 s, tracking 2.1 s, decode 0.3 s.

What is a pure function of frame t and frame t - 1 is *measured* here and can run on chunks
of a clip in parallel: decoding and shrinking the frame to the analysis size, reading its
disparity, and each detector's ``measure`` (face detection on detection frames, saliency,
optical flow and camera motion, motion-compensated mouth and block energy; see
``detectors.base``). A chunk [a, b) therefore reads from :func:`analysis_start` (frame a - 1,
and the last face-detection frame before a, whose boxes the speech detector measures mouths
in). What carries state across frames stays in one task per clip, in frame order
(``AutofocusJob`` with ``frames=``): face-track association, the action detector's decaying
memory, the speech and synchrony windows, the combination (its K-means is seeded per frame,
but it reads the detectors' state), the step detector, KCF tracking of every target from its
NFT to the next (however far apart: no bounded overlap reproduces it), the pulls. Since both
paths run the same ``measure`` on the same arrays and the same ``ingest`` in the same order,
a chunked run gives the single run's focus track and keys exactly (``tests/engine/test_batch.py``).

Measurement files are data-only archives (``.npz`` of JSON + arrays, :mod:`..io.datafile`; a
header, then one :class:`FrameMeasurement` per frame), written to a temporary name and renamed.
Nothing in them is unpickled: a file planted in the work folder cannot run code, it is only
refused (and measured again by ``rvr batch``). About 0.4-0.7 MB per frame at 320x180.
"""
from __future__ import annotations

import logging
import os
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Iterable, Iterator

import numpy as np

from ..errors import InputError
from ..io.paths import temp_sibling
from ..io.readahead import ReadAhead
from ..io.video import ClipInfo, probe_clip
from ..temporal.cuts import CutDetector
from .combine import FALLBACKS, PRESETS
from .presets import AUTO
from .depth import DisparitySource
from .detectors.base import AnalysisFrame, FocusDetector
from .nft import Box
from .timebase import frames_at

if TYPE_CHECKING:
    from .lookahead import AutofocusSettings

log = logging.getLogger(__name__)

ANALYSIS_FORMAT = "rvr-laaf-analysis/2"
"""/2: data-only .npz archives (/1 were pickle streams, never read any more)."""


@dataclass
class FrameMeasurement:
    """One measured frame. t: 0-based index in the run. rgb: (h, w, 3) uint8 at the analysis
    size. disparity: (h, w) float32 (DESIGN units of the native width). features: what each
    measuring detector's ``measure`` returned. seconds: time spent (s) per part: ``decode``,
    ``depth`` and each detector name."""

    t: int
    rgb: np.ndarray
    disparity: np.ndarray | None
    features: dict[str, object]
    seconds: dict[str, float]


@dataclass
class ClipSetup:
    """A run's clip: frames [start, stop) of ``clip`` (n of them), at ``fps``; disparity source;
    analysis scale (analysis px / native px) and size (w, h) px."""

    clip: ClipInfo
    start: int
    stop: int
    fps: float
    depth: DisparitySource
    scale: float
    size: tuple[int, int]
    reads: "ReadAhead | None" = None  # the next frame's disparity, read in the background

    def _disparity(self, k: int) -> np.ndarray:
        return self.depth.get(self.start + k, self.size)

    def close(self) -> None:
        """End the background read of a disparity map (a run ending or cancelled)."""
        if self.reads is not None:
            self.reads.close()

    @property
    def n(self) -> int:
        return self.stop - self.start

    def frame(self, rgb: np.ndarray, k: int, with_depth: bool = True,
              ahead: bool = True) -> tuple[AnalysisFrame, dict[str, float]]:
        """(analysis frame k of the run, seconds spent: decode = shrinking, depth) from a native
        frame; with_depth False: no disparity (warm-up frames only need the image). ahead: frame
        k + 1's disparity is read in the background meanwhile (:meth:`close` ends that)."""
        t0 = time.perf_counter()
        small, gray = shrink(rgb, self.size)
        t1 = time.perf_counter()
        disp = None
        if with_depth:
            if self.reads is None:
                self.reads = ReadAhead(self._disparity)
            disp = self.reads.get(k, k + 1 if ahead and k + 1 < self.n else None)
        return AnalysisFrame(k, small, gray, disp, self.scale, self.fps, native=rgb), {"decode": t1 - t0,
                                                                           "depth": time.perf_counter() - t1}


def open_clip(s: "AutofocusSettings") -> ClipSetup:
    """Probe the clip, check the frame range and the disparity source (InputError naming them)."""
    clip = probe_clip(s.input, fps=s.fps)
    stop = clip.frame_count if s.stop is None else min(s.stop, clip.frame_count)
    if s.start < 0 or s.start >= stop:
        raise InputError(f"frame range {s.start}..{stop} is empty for {s.input} ({clip.frame_count} frames)")
    depth = DisparitySource(cache=s.cache, depth=s.depth, scale=s.depth_scale, offset=s.depth_offset)
    if depth.maps is not None:
        depth.maps.place_on_timeline(clip)
    depth.check_length(stop - s.start, s.start)
    scale = min(1.0, s.analysis_width / clip.width)
    size = (max(int(round(clip.width * scale)), 8), max(int(round(clip.height * scale)), 8))
    return ClipSetup(clip, s.start, stop, clip.fps, depth, scale, size)


@dataclass
class DetectorSet:
    """The detectors of a run. combo: the preset's detectors the combination intersects (after
    a fallback); preset_used: the preset they belong to; fallback_note: why it fell back."""

    detectors: dict[str, FocusDetector]
    combo: tuple[str, ...]
    preset_used: str | None
    fallback_note: str = ""
    auto: dict | None = None  # preset 'auto': {"chose", "why", "reading"}


def build_detectors(s: "AutofocusSettings", setup: ClipSetup, causal: bool, whole_clip: bool = True) -> DetectorSet:
    """The detectors of preset ``s.preset``. whole_clip False: for measuring chunks only, i.e.
    without what only the whole-clip task uses (the audio track, AF-Net)."""
    if s.preset is None:
        return DetectorSet({}, (), None)
    preset, auto, audio = s.preset, None, None
    if preset == AUTO:  # read the clip, pick a preset (the same for every chunk)
        from .auto import resolve

        preset, why, reading, audio = resolve(s, setup)
        auto = {"chose": preset, "why": why, "reading": reading}
        s = replace(s, preset=preset)
    names = list(PRESETS[s.preset])
    detectors: dict[str, FocusDetector] = {}
    if "afnet" in names and whole_clip:
        from .detectors.afnet import AFNetDetector

        clip = setup.clip
        media = clip.path if clip.kind == "video" and clip.has_audio else None
        detectors["afnet"] = AFNetDetector(s.afnet_weights, setup.n, setup.fps, s.afnet_threshold, media=media,
                                           start_frame=setup.start)
    from .detectors.action import ActionDetector
    from .detectors.face import FaceDetector
    from .detectors.saliency import SaliencyDetector
    from .detectors.speech import SpeechDetector

    face = None
    clip = setup.clip
    speaker = ("afnet" in names and s.afnet_speaker and clip.kind == "video" and clip.has_audio)
    if "face" in names or "speech" in names or speaker:
        face = FaceDetector(backend=s.face_backend, every=frames_at(s.face_every, setup.fps))  # frames at 25 fps
        detectors["face"] = face
    if "saliency" in names:
        detectors["saliency"] = SaliencyDetector()
    if "action" in names:
        detectors["action"] = ActionDetector()
    preset_used, note = s.preset, ""
    if "speech" in names or speaker:  # speaker: AF-Net's NFTs take the speaker's region (lookahead)
        media = clip.path if clip.kind == "video" and clip.has_audio and whole_clip else None
        speech = SpeechDetector(face, setup.fps, setup.n, media=media, audio=audio if media is not None else None,
                                start_frame=setup.start,
                                window_s=s.speech_window_s, causal=causal)
        if "speech" in names:
            detectors["speech"] = speech
            if whole_clip and media is None:
                speech.available = False
                speech.unavailable_reason = f"speech detector off: '{clip.path}' has no audio track"
                log.warning("%s; preset %s falls back to %s", speech.unavailable_reason, s.preset,
                            FALLBACKS.get(s.preset))
            if not speech.available:
                names.remove("speech")
                preset_used = FALLBACKS.get(s.preset, s.preset)
                note = f"{speech.unavailable_reason}; preset {s.preset} fell back to {preset_used}"
        elif speech.available or not whole_clip:
            detectors["speech"] = speech
        elif "face" not in names:
            del detectors["face"]  # the sound does not decode: AF-Net's maps only
    return DetectorSet(detectors, tuple(names), preset_used, note, auto)


def analysis_start(a: int, face_every: int | None) -> int:
    """First frame a chunk starting at frame a must read: the frame before (pairwise detectors)
    and, with face detection every ``face_every`` frames, the last detection frame <= a."""
    if a <= 0:
        return 0
    first = a - 1
    if face_every:
        first = min(first, a - a % face_every)
    return max(first, 0)


def measured_names(detectors: dict[str, FocusDetector], speech: bool) -> list[str]:
    """Detectors whose ``measure`` runs, face first (speech measures in its boxes): every
    available measuring detector; speech when ``speech`` (a chunk knows only whether the clip
    has an audio track; whether its audio decodes, and so whether speech is available, is known
    to the whole-clip task)."""
    names = [n for n, d in detectors.items() if d.measures and (d.available or (n == "speech" and speech))]
    return sorted(names, key=lambda n: n != "face")


class FrameAnalyser:
    """Measure the frames of a run in order: keeps the previous frame and the face boxes of the
    last face detection, which the next frames' measurements use."""

    def __init__(self, detectors: dict[str, FocusDetector], names: list[str]) -> None:
        self.detectors = {n: detectors[n] for n in names}
        self.prev: AnalysisFrame | None = None
        self.faces: list[Box] = []

    def measure(self, frame: AnalysisFrame, warm_up: bool = False,
                cut: bool = False) -> tuple[dict[str, object], dict[str, float]]:
        """(features, seconds per detector) of ``frame``, the frame after the last one measured.
        warm_up: a frame before a chunk, measured only for what the chunk needs (face boxes).
        cut: the frame starts a new shot: its faces are detected afresh (the previous shot's
        boxes are not held over the cut, as ``FaceDetector.cut`` wants) and nothing is measured
        against the previous frame (a pairwise cue across a cut is the cut itself)."""
        features: dict[str, object] = {}
        seconds: dict[str, float] = {}
        prev = self.prev if self.prev is not None and self.prev.t == frame.t - 1 and not cut else None
        try:
            for name, det in self.detectors.items():
                if warm_up and name != "face":
                    continue
                t0 = time.perf_counter()
                if cut and name == "face" and hasattr(det, "detect"):
                    features[name] = det.detect(frame)
                else:
                    features[name] = det.measure(frame, prev, self.faces)
                seconds[name] = time.perf_counter() - t0
                if name == "face" and features[name] is not None:
                    self.faces = list(features[name])
        finally:
            frame.native = None  # measured: the buffers keep the analysis size only
        self.prev = frame
        return features, seconds


def shrink(rgb: np.ndarray, size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """(rgb, gray) of a frame at the analysis size (w, h): INTER_AREA, as the detectors see it."""
    import cv2

    small = rgb if (rgb.shape[1], rgb.shape[0]) == tuple(size) else cv2.resize(rgb, size, interpolation=cv2.INTER_AREA)
    return small, cv2.cvtColor(small, cv2.COLOR_RGB2GRAY)


# ------------------------------------------------------------------------------ chunks


def measure_range(s: "AutofocusSettings", a: int, b: int) -> Iterator[FrameMeasurement]:
    """Frames a..b-1 of the run ``s`` describes (0-based from ``s.start``), measured as
    ``AutofocusJob`` measures them, one at a time; reads from :func:`analysis_start`. Raises
    InputError naming the clip when the range is out of the clip or the clip ends early."""
    from ..io.video import iter_frames

    setup = open_clip(s)
    if not 0 <= a < b <= setup.n:
        raise InputError(f"analysis chunk {a}..{b - 1} is outside the {setup.n} frames of the run on {s.input}")
    causal = s.causal or int(round(s.window_s * setup.fps)) == 0
    dets = build_detectors(s, setup, causal, whole_clip=False).detectors
    clip = setup.clip
    names = measured_names(dets, speech=clip.kind == "video" and clip.has_audio)
    analyser = FrameAnalyser(dets, names)
    lo = analysis_start(a, dets["face"].every if "face" in names else None)
    # the shot cuts, as the run finds them (AutofocusJob: given, or detected on the analysis frames;
    # the detector is pairwise, so from lo on it says what the whole run's says)
    given = {int(c) - setup.start for c in s.cuts} if s.cuts is not None else None
    cut_detector = CutDetector() if given is None and s.detect_cuts else None
    frames = iter_frames(s.input, start=setup.start + lo, stop=setup.start + b)
    try:
        for k in range(lo, b):
            t0 = time.perf_counter()
            rgb = next(frames, None)
            read = time.perf_counter() - t0
            if rgb is None:
                raise InputError(f"{s.input} ended after {k} of {setup.n} frames while measuring frames {a}..{b - 1}")
            check_frame_size(rgb, clip, k, s.input)
            af, seconds = setup.frame(rgb, k, with_depth=k >= a, ahead=k + 1 < b)
            cut = k > 0 and (k in given if given is not None else
                             cut_detector is not None and cut_detector.push(af.rgb))
            features, det_seconds = analyser.measure(af, warm_up=k < a, cut=cut)
            if k >= a:
                seconds["decode"] += read
                yield FrameMeasurement(k, af.rgb, af.disparity, features, {**seconds, **det_seconds})
    finally:
        frames.close()
        setup.close()


def check_frame_size(rgb: np.ndarray, clip: ClipInfo, k: int, source) -> None:
    """InputError when frame k is not the clip's size."""
    if (rgb.shape[1], rgb.shape[0]) != (clip.width, clip.height):
        raise InputError(f"frame {k} of {source} has another size than the first frame")


# ------------------------------------------------------------------------------ files


def write_measurements(path: Path, header: dict, frames: Iterable[FrameMeasurement]) -> int:
    """Stream ``frames`` into a measurement file (a data-only archive under a temp name, renamed
    when complete); returns how many were written."""
    from ..io.datafile import DataWriter

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = temp_sibling(path, ".tmp")
    count = 0
    try:
        with DataWriter(tmp) as out:
            for m in frames:
                out.put(f"f{count}", {"t": int(m.t), "rgb": m.rgb, "disparity": m.disparity,
                                      "features": m.features, "seconds": m.seconds})
                count += 1
            out.put("header", {"format": ANALYSIS_FORMAT, **header, "frames": count})
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return count


def _open(path: Path):
    """(reader, header) of a measurement file; DataFileError when it is not a complete one."""
    from ..io.datafile import DataFileError, DataReader

    reader = DataReader(path, what=f"LAAF measurement file ({ANALYSIS_FORMAT})")
    try:
        header = reader.get("header")
        ok = (isinstance(header, dict) and header.get("format") == ANALYSIS_FORMAT
              and isinstance(header.get("range"), (list, tuple)) and len(header["range"]) == 2
              and header.get("frames") == header["range"][1] - header["range"][0])
        if not ok:
            raise DataFileError(f"'{path}' is not a LAAF measurement file ({ANALYSIS_FORMAT}): its header is "
                                f"{str(header)[:120]}")
    except BaseException:
        reader.close()
        raise
    return reader, header


def read_header(path: Path) -> dict | None:
    """The header of a complete measurement file, None if it is missing or not one (logged when
    a file is there but is not one: e.g. planted, truncated, or of an older format)."""
    from ..io.datafile import DataFileError

    path = Path(path)
    if not path.is_file():
        return None
    try:
        reader, header = _open(path)
    except DataFileError as ex:
        log.warning("%s; it is not used (rvr batch measures these frames again)", ex)
        return None
    reader.close()
    return header


def read_measurements(paths: Iterable[Path]) -> Iterator[FrameMeasurement]:
    """The frames of measurement files, file after file (one frame in memory at a time).
    Raises InputError naming a file that is not a complete measurement file."""
    from ..io.datafile import DataFileError

    for path in paths:
        try:
            reader, header = _open(Path(path))
        except DataFileError as ex:
            raise InputError(f"{ex}; delete it and re-run (rvr batch measures missing chunks again)") from None
        a, b = (int(v) for v in header["range"])
        with reader:
            for k, t in enumerate(range(a, b)):
                try:
                    item = reader.get(f"f{k}")
                    m = FrameMeasurement(int(item["t"]), item["rgb"], item["disparity"], item["features"],
                                         item["seconds"])
                    if not isinstance(m.rgb, np.ndarray) or not isinstance(m.features, dict):
                        raise TypeError("rgb is not an array or features not a mapping")
                except DataFileError as ex:
                    raise InputError(f"LAAF measurement file '{path}' has no complete frame {t} of {a}..{b - 1} "
                                     f"({ex}); delete it and re-run the analysis") from None
                except (KeyError, TypeError, ValueError) as ex:
                    raise InputError(f"LAAF measurement file '{path}': frame {t} is not a measurement ({ex}); "
                                     "delete it and re-run the analysis") from None
                yield m
