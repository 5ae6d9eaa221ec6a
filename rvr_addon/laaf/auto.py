"""The default preset ``auto``: read the clip, then pick the detectors that fit it (issue 23).

:func:`read_clip` looks at what a clip holds, cheaply and deterministically (the same answer
for every chunk of ``rvr batch``): **speech** (the voice activity of its sound over the run:
share of voiced frames), **faces** (the face detector on ``PROBE_FRAMES`` frames spread over
the run: share with a face, the most faces at once) and **motion** (share of pixels that
change by more than ``MOTION_LEVEL`` grey levels between consecutive frames at the same
places). :func:`choose_preset` turns the reading into a preset and says why:

- speech and faces on screen: ``conversation`` (speech + face: focus on who speaks);
- faces, no speech (or speech with no face on screen: an off-screen voice is not followed):
  ``faces``, unless there is much motion and no face is large, then ``action``;
- no faces, motion: ``action`` (action + saliency);
- neither: ``salient``.

The choice and the reading are logged and written to the focus file (``settings.auto``).
"""
from __future__ import annotations

import logging
from collections import OrderedDict
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from .presets import AUTO
from .timebase import frames_at

if TYPE_CHECKING:  # pragma: no cover
    from .analysis import ClipSetup
    from .audio import AudioTrack

log = logging.getLogger(__name__)

PROBE_WINDOWS = 3
"""Short runs of frames decoded for the reading (start, middle, end of the run)."""
PROBE_RUN = 6
"""Consecutive frames per probe window at 25 fps (:mod:`.timebase`: the same seconds at any rate; motion is
measured between frames 1/25 s apart, faces on PROBE_FACES of them)."""
PROBE_FACES = 2
"""Frames per window the face detector looks at."""
MOTION_LEVEL = 20
"""Grey levels (0..255) a pixel must change by between consecutive frames to count as moving."""
SPEECH_SHARE, SPEECH_MIN_S = 0.15, 0.5
"""Speech is present when at least this share of the frames is voiced and at least this long (s)."""
FACE_SHARE = 0.3
"""Faces are present when at least this share of the probed frames shows one."""
MOTION_SHARE = 0.025
"""Motion is present when at least this share of the pixels moves (median over the probed pairs)."""
BIG_FACE = 0.04
"""A face covering this share of the frame is a subject in its own right (motion does not override it)."""

_READINGS: "OrderedDict[tuple, ClipReading]" = OrderedDict()
"""read_clip's memo (a look-ahead and a causal run of one clip probe it once), the last READINGS_KEPT
readings: a long Blender session does not keep every clip's."""
READINGS_KEPT = 8


@dataclass
class ClipReading:
    """What a clip holds: has_audio, voiced_share (0..1 of the run's frames), voiced_s (s),
    face_share (0..1 of the probed frames), max_faces, face_area (largest face, share of the
    frame), motion_share (0..1 of the pixels), probed (frame indices of the run)."""

    has_audio: bool
    voiced_share: float
    voiced_s: float
    face_share: float
    max_faces: int
    face_area: float
    motion_share: float
    probed: list[int]

    @property
    def speech(self) -> bool:
        return self.has_audio and self.voiced_share >= SPEECH_SHARE and self.voiced_s >= SPEECH_MIN_S

    @property
    def faces(self) -> bool:
        return self.face_share >= FACE_SHARE

    @property
    def motion(self) -> bool:
        return self.motion_share >= MOTION_SHARE

    def to_json(self) -> dict:
        d = {k: (round(v, 4) if isinstance(v, float) else v) for k, v in asdict(self).items()}
        d.update(speech=self.speech, faces=self.faces, motion=self.motion)
        return d


def choose_preset(r: ClipReading) -> tuple[str, str]:
    """(preset, why) for a reading (module docstring)."""
    facts = (f"speech on {r.voiced_share:.0%} of the frames" if r.has_audio else "no sound") + \
        f", a face on {r.face_share:.0%} of the probed frames, {r.motion_share:.1%} of the pixels moving"
    if r.speech and r.faces:
        return "conversation", f"{facts}: someone speaks on screen, focus follows who speaks"
    if r.faces:
        if r.motion and r.face_area < BIG_FACE:
            return "action", f"{facts}: small faces in a moving scene, focus follows the action"
        extra = " (the voice has no face on screen: not followed)" if r.speech else ""
        return "faces", f"{facts}: faces without speech{extra}, focus on the faces"
    if r.motion:
        return "action", f"{facts}: no face, motion: focus follows the action"
    return "salient", f"{facts}: no face, little motion: focus on what stands out"


def read_clip(s, setup: "ClipSetup", audio: "AudioTrack | None" = None) -> tuple[ClipReading, "AudioTrack | None"]:
    """The reading of the run ``setup`` (frames start..stop of its clip) with the face backend
    of settings ``s``; also the run's AudioTrack (None without sound) for the speech detector.
    Cached per clip (path, modification time and size), range and analysis size."""
    from ..io.video import iter_frames
    from .analysis import shrink
    from .detectors.base import AnalysisFrame
    from .detectors.face import FaceDetector

    clip = setup.clip
    try:
        st = Path(clip.path).stat()
        stamp = (st.st_mtime_ns, st.st_size)
    except OSError:
        stamp = None
    key = (str(clip.path), stamp, setup.start, setup.stop, setup.fps, tuple(setup.size), s.face_backend)
    if audio is None and clip.kind == "video" and clip.has_audio:
        audio = _audio(clip.path, setup)
    if key in _READINGS:
        _READINGS.move_to_end(key)
        return _READINGS[key], audio
    n = setup.n
    voiced = audio.voiced[:n] if audio is not None else np.zeros(0, bool)
    # the windows and the motion between frames 1/25 s apart: the same seconds at any frame rate
    run, gap = frames_at(PROBE_RUN, setup.fps), frames_at(1, setup.fps)
    starts = sorted({int(v) for v in np.linspace(0, max(n - run, 0), PROBE_WINDOWS)})
    try:
        face = FaceDetector(backend=s.face_backend)
    except RuntimeError:
        face = None
    probed, with_face, max_faces, area, motion = [], 0, 0, 0.0, []
    for a in starts:
        b = min(a + run, n)
        prev: list[np.ndarray] = []
        for j, rgb in enumerate(iter_frames(s.input, start=setup.start + a, stop=setup.start + b)):
            small, gray = shrink(rgb, setup.size)
            if len(prev) >= gap:
                motion.append(float(np.mean(np.abs(gray.astype(np.int16) - prev[-gap]) > MOTION_LEVEL)))
            prev = (prev + [gray.astype(np.int16)])[-gap:]
            if face is not None and j % max(run // PROBE_FACES, 1) == 0:
                boxes = face.detect(AnalysisFrame(a + j, small, gray, None, setup.scale, setup.fps, native=rgb))
                probed.append(a + j)
                if boxes:
                    with_face += 1
                    max_faces = max(max_faces, len(boxes))
                    area = max(area, max(bw * bh for _, _, bw, bh in boxes) / float(gray.size))
    reading = ClipReading(audio is not None, float(voiced.mean()) if voiced.size else 0.0,
                          float(voiced.sum()) / setup.fps, with_face / max(len(probed), 1), max_faces, area,
                          float(np.median(motion)) if motion else 0.0, probed)
    _READINGS[key] = reading
    while len(_READINGS) > READINGS_KEPT:
        _READINGS.popitem(last=False)
    return reading, audio


def _audio(path, setup: "ClipSetup") -> "AudioTrack | None":
    from .audio import NoAudio, analyse_audio, decode_audio

    try:
        samples = decode_audio(path, start_s=setup.start / setup.fps, duration_s=setup.n / setup.fps)
    except NoAudio:
        return None
    return analyse_audio(samples, setup.fps, setup.n)


def resolve(s, setup: "ClipSetup") -> tuple[str, str, dict, "AudioTrack | None"]:
    """For preset ``auto``: (preset chosen, why, the reading as JSON, the run's AudioTrack or
    None); logged at INFO."""
    reading, audio = read_clip(s, setup)
    preset, why = choose_preset(reading)
    log.info("preset %s chose %s: %s", AUTO, preset, why)
    return preset, why, reading.to_json(), audio
