"""The LAAF driver: frames -> detectors -> focus signal -> NFTs -> tracking -> focus track.

:class:`AutofocusJob` owns the stream (STYLE.md: one driver owns the window). Frames are read
as a generator and kept only in a bounded ring buffer at the analysis resolution (default 320
px wide) for as long as tracking may still need them (a few dozen frames); disparity is read
per frame. Decisions for output frame t may use frames up to ``t + window`` (look-ahead,
default 2 s); with ``causal`` the window is 0, which is what a camera's autofocus can do.

How the window enters: every NFT records ``known_at``, the first *output* frame at which the
system knew of it: the frame whose analysis revealed it (ingest time) minus the window. A pull
never starts before ``known_at`` (``puller.schedule_pulls``), so with a window of W frames the
pull to a target at t can be placed before t only if the target was visible by t + W; in causal
mode every pull starts after the evidence, i.e. late. The focus of frame t is final once frame
t + W has been analysed; ``AutofocusResult`` holds the whole (small) per-frame track.

The per-frame work (frames at the analysis size, disparity, the detectors' ``measure``) is done
by ``analysis.FrameAnalyser`` here, or comes measured already in chunks (``frames=``, from
``analysis.measure_range``; ``rvr batch``): the result is the same (``analysis`` docstring).

Shot cuts (issue 23): the shared detector (``temporal.cuts.CutDetector``) runs on every
analysis frame, or the user gives the cut list (``cuts``; ``detect_cuts`` False: none). At a
cut every track ends (targets, face tracks: ``FocusDetector.cut``), the new shot's subject
becomes a target on the cut frame itself (a hard change: ``PullTarget.at_cut``; look-ahead: a
subject picked up soon after the cut and tracked back to it replaces that target, except a
region no face holds replacing a target on a face; the clip's first focus, on frame 0, is replaced
the same way, so a subject found just after the start is the first focus, not a pull at the start),
the cut is found before its frame is
measured (its faces detected afresh, no pairwise cue across it), steps of the
focus signal next to a cut are the cut itself and make no NFT, and no pull crosses a cut
(``puller.schedule_pulls``). Focus that holds: the ``calm`` knob (:mod:`.calm`) raises the
step threshold, defers a step within the minimum hold of the previous target, takes a step
only if its new level persists, and puts a deadband on following a subject.

Changes of speaker (issue 23): the speech detector's decision chain has its own cost of a change
of face, so a step to a new speaker it names is not held back by the minimum hold; and in
look-ahead mode such a change is a target at the chain's *turn start* (``SpeechDetector.turn_start``:
the first voiced frame the new face speaks on the chain's best path, which uses the evidence after
it, typically the voice onset), proposed on the frame the chain first names the speaker instead of
after the step detector's delay (``_turn_step``), so the pull can land before the voice; the step
the step detector finds later to the same speaker is dropped.

Manual NFTs (``nfts``/``targets``) are tracked from their frame (forward to the next NFT,
backward over the pull before it); with a preset as well, automatic NFTs closer than
``pull_frames`` to a manual one are dropped (the user wins).
"""
from __future__ import annotations

import logging
import math
import time
from collections import deque
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Iterable

import numpy as np

from ..errors import InputError
from ..io.video import ClipInfo, iter_frames
from ..temporal.cuts import CutDetector
from .analysis import (FrameAnalyser, FrameMeasurement, build_detectors, check_frame_size, measured_names, open_clip,
                       shrink)
from .calm import DEFAULT_CALM, calm_settings, check_calm, deadband, persists
from .combine import (DEFAULT_PRESET, PRESETS, PRIMARY, Region, Step, StepDetector, intersect, majority_region,
                      region_level, region_min_area)
from .detectors.base import AnalysisFrame, DetectorOutput, FocusDetector
from .focus_reading import read_focus
from .keyframes import Key, keyframes
from .nft import NFT, Box, load_nfts, validate_nfts
from .puller import ComposedTrack, PullSettings, PullTarget, compose_track, shot_bounds
from .timebase import frames_at
from .tracking import SubjectTracker

log = logging.getLogger(__name__)

ONSET_BEFORE = 6
"""Preset 'learned': a turn starting this many frames (at 25 fps, :mod:`.timebase`) before an AF-Net NFT
still explains it."""


@dataclass
class AutofocusSettings:
    """Everything ``rvr autofocus`` needs.

    input: video or image sequence. cache / depth: the disparity source (one of them).
    preset: 'auto' (the default: reads the clip and picks, :mod:`.auto`), 'action',
    'conversation', 'faces', 'salient', 'learned' or None (manual NFTs only).
    targets / nfts: manual NFTs (JSON file or list, native px, 0-based frames).
    window_s: look-ahead in seconds (default 2.0); causal: window 0.
    pull: pull length, lead, profile, hold. aperture: aperture scale of the track (>= 0).
    analysis_width: px width the detectors and the tracker work at (frames are shrunk to it).
    min_step: smallest focus change (disparity units) that makes an NFT.
    min_area: smallest focus region, as a fraction of the frame (not for a speaking face:
        ``combine.region_min_area``).
    keyframe_tol: the keyframes reproduce the track within this (disparity units).
    afnet_weights: AF-Net weights for preset 'learned' (None: rvr_addon/afnet/weights/afnet.pt).
    afnet_threshold: NFT probability an AF-Net peak must reach (0..1; None: the weights' own, else 0.5).
    afnet_speaker: preset 'learned' on a clip with sound: an NFT near a voice onset takes its
    region from the speaker the speech detector localises (mouth motion or audio-visual
    synchrony) instead of AF-Net's map; False: always the map (the paper's AF-Net alone).
    cuts: the shot cuts (0-based clip frames of the first frame of each new shot) given by the
    user; None: detected (``detect_cuts``). detect_cuts: False and no ``cuts``: no cuts at all.
    calm: 0 (responsive, the paper) .. 1 (calm): hysteresis, minimum hold, cost of a change
    and follow deadband (:mod:`.calm`).
    face_every: the face detector runs every this many frames at 25 fps (the same seconds at the
    clip's rate, :mod:`.timebase`; boxes held in between).
    """

    input: Path
    cache: Path | None = None
    depth: Path | None = None
    depth_scale: float = 1.0
    depth_offset: float = 0.0
    preset: str | None = DEFAULT_PRESET
    targets: Path | None = None
    nfts: list[NFT] | None = None
    window_s: float = 2.0
    causal: bool = False
    pull: PullSettings = field(default_factory=PullSettings)
    aperture: float = 1.0
    analysis_width: int = 320
    min_step: float = 0.5
    min_area: float = 0.01
    start: int = 0
    stop: int | None = None
    fps: float | None = None
    face_backend: str = "auto"
    face_every: int = 6
    speech_window_s: float = 1.0
    keyframe_tol: float = 0.05
    afnet_weights: Path | None = None
    afnet_threshold: float | None = None
    afnet_speaker: bool = True
    cuts: list[int] | None = None
    detect_cuts: bool = True
    calm: float = DEFAULT_CALM


REANCHOR_FRAMES = 5
"""Frames (at 25 fps: 0.2 s, the same seconds at any rate) a target's readings must agree on a new
level, when they jumped from the level read within that long of the target's first frame, for the
target to take it (``_reanchor``): the first reading was a glitch of the depth map (on a wide shot
the far speaker's person layer missing for the frame the target was read at put him at the near
one's depth, and every later reading, 4 units away, was refused as a slip of the box: the focus
stayed on the wrong depth for his whole turn). A target tracked longer keeps refusing jumps."""


@dataclass
class TargetState:
    """A focus target being tracked: its NFT, per-frame level (NaN = unknown) and trackers."""

    nft: NFT
    level: np.ndarray
    box_analysis: Box
    tracker: SubjectTracker | None = None
    lost_from: int | None = None
    active: bool = True
    events: list[dict] = field(default_factory=list)
    boxes: dict[int, tuple[Box, bool]] = field(default_factory=dict)  # frame -> (analysis box, on subject)
    first_read: int = -1  # the frame its level was first read at
    jumped: list[tuple[int, float]] = field(default_factory=list)  # the latest run of consecutive rejected readings


@dataclass
class AutofocusResult:
    """focus, aperture: (n,) per frame (DESIGN units / scale); keys: linear keyframes;
    nfts: targets in frame order (the first is the initial focus); tracking: loss,
    re-initialisation and exit events; signal: per-frame raw and held focus level of the
    detector combination (NaN = empty); detectors: metrics; clip: ClipInfo; start: first frame.
    boxes: per NFT (same order), {frame: ((x, y, w, h) native px, on_subject)} for the frames
    its subject was tracked (forward and backward over its pull; frames relative to start).
    cuts: first frames of new shots (relative to start)."""

    focus: np.ndarray
    aperture: np.ndarray
    keys: list[Key]
    nfts: list[NFT]
    tracking: list[dict]
    signal: dict
    detectors: dict
    composed: ComposedTrack
    clip: ClipInfo
    start: int
    settings: dict
    seconds: float
    boxes: list[dict[int, tuple[Box, bool]]] = field(default_factory=list)
    cuts: list[int] = field(default_factory=list)


class AutofocusJob:
    """Stepwise LAAF over one clip: ``while job.step(): pass``, then ``job.result``."""

    def __init__(self, settings: AutofocusSettings, frames: Iterable[FrameMeasurement] | None = None) -> None:
        """frames: the run's frames measured already (``analysis.measure_range`` on chunks, in
        order), instead of decoding and measuring them here; the result is the same."""
        s = self.settings = settings
        s.pull.check()
        if s.preset is None and s.targets is None and s.nfts is None:
            raise InputError("rvr autofocus needs --preset or --targets NFTS.json (or both)")
        if s.preset is not None and s.preset not in PRESETS:
            raise InputError(f"--preset {s.preset!r} is not known; use one of {', '.join(PRESETS)}")
        if not (np.isfinite(s.aperture) and s.aperture >= 0):
            raise InputError(f"--aperture must be >= 0 (0 = no blur), got {s.aperture}")
        if s.window_s < 0:
            raise InputError(f"--window {s.window_s} must be >= 0 seconds (0 = causal)")
        try:
            check_calm(s.calm)
        except ValueError as ex:
            raise InputError(f"--calm: {ex}") from None
        self.setup = open_clip(s)
        self.clip = self.setup.clip
        self.start, self.stop = self.setup.start, self.setup.stop
        self.n = self.setup.n
        self.fps = self.setup.fps
        self.depth = self.setup.depth
        self.scale, self.size = self.setup.scale, self.setup.size
        self.window = 0 if s.causal else int(round(s.window_s * self.fps))
        self.pull = s.pull.at_fps(self.fps)  # the pull's defaults in frames of this clip (timebase)
        self.causal = s.causal or self.window == 0
        manual = list(s.nfts or [])
        if s.targets is not None:
            manual += load_nfts(s.targets, self.clip.width, self.clip.height)
        manual = [replace(n, t=n.t - self.start, known_at=0) for n in manual] if self.start else manual
        self.manual = validate_nfts(manual, self.n, self.clip.width, self.clip.height,
                                    where=f"NFTs of '{s.targets}'" if s.targets else "NFTs") if manual else []
        built = build_detectors(s, self.setup, self.causal)
        self.detectors: dict[str, FocusDetector] = built.detectors
        self._combo: tuple[str, ...] = built.combo
        self.preset_used: str | None = built.preset_used
        self.fallback_note = built.fallback_note
        self.auto = built.auto
        speech = self.detectors.get("speech")
        measured = measured_names(self.detectors, speech is not None and speech.available)
        self.analyser = FrameAnalyser(self.detectors, measured)
        self._measured_frames = frames
        self.learned = self.detectors.get("afnet")  # preset 'learned': AF-Net proposes the NFTs itself
        self.detector_lag = max([d.lookahead_frames for n, d in self.detectors.items()
                                 if n in self._combo] or [0])
        # the step detector's windows: frames at 25 fps, the same seconds at the clip's rate (timebase)
        self.step_detector = StepDetector(min_step=s.min_step, r=frames_at(3, self.fps),
                                          min_gap=max(frames_at(4, self.fps), self.pull.pull_frames // 2),
                                          causal=self.causal, min_support=frames_at(2, self.fps),
                                          filter_radius=frames_at(2, self.fps))
        # look-ahead: the persistence of a new level is checked in frames the window still sees before
        # the pull must start; causal: not at all (waiting for it would make every pull later still)
        spare = (0 if self.causal else
                 self.window - self.detector_lag - self.step_detector.delay - self.pull.lead_frames
                 - self.pull.pull_frames)
        self.calm = calm_settings(s.calm, self.fps, s.aperture, max_persist=spare)
        self.step_detector.min_step = s.min_step * self.calm.step_factor  # hysteresis
        keep = (self.detector_lag + self.step_detector.delay + 3 + self.pull.lead_frames + self.pull.pull_frames + 4
                + self.calm.persist_frames)
        self._pending: list = []  # (Step, frame its decision is due): steps waiting for persistence / the hold
        if s.cuts is not None:
            self.cuts_source = "given"
            self.cuts = sorted({int(c) - self.start for c in s.cuts if self.start < int(c) < self.stop})
        else:
            self.cuts_source = "detected" if s.detect_cuts else "off"
            self.cuts = []
        self._cutset = set(self.cuts)
        self.cut_detector = CutDetector() if s.cuts is None and s.detect_cuts else None
        self.cut_guard = self.step_detector.r + self.step_detector.filter_radius + 1
        self.buffer: deque[AnalysisFrame] = deque(maxlen=keep)
        self.targets: list[TargetState] = []
        # a tracked subject's reading may move this much per frame (disparity units); more is
        # the box slipping onto another surface: ignored, the level is held (but see _reanchor)
        self.max_jump = max(0.5, s.min_step)
        self.reanchor_frames = max(2, frames_at(REANCHOR_FRAMES, self.fps))
        self.regions: dict[int, Region | None] = {}
        self.raw = np.full(self.n, np.nan, np.float32)
        self.held = np.full(self.n, np.nan, np.float32)
        self._frames = None
        self._k = 0
        self._measured = 0
        self._finished = False
        self.result: AutofocusResult | None = None
        self._t0 = time.perf_counter()
        self._timings = {"decode_s": 0.0, "depth_s": 0.0, "detect_s": 0.0, "combine_s": 0.0, "track_s": 0.0}
        self.text = f"autofocus on {self.n} frames of {self.clip.path.name}"

    # -- stream -----------------------------------------------------------------------------
    @property
    def progress(self) -> float:
        """Fraction of frames analysed, 0..1."""
        return self._k / self.n if self.n else 1.0

    def _analyse(self, item, k: int) -> tuple[AnalysisFrame, dict[str, object], dict[str, float]]:
        """(analysis frame k, detector measurements, seconds per part): measured here from a
        decoded frame, or taken from a FrameMeasurement (``frames=``)."""
        if isinstance(item, FrameMeasurement):
            if item.t != k or (item.rgb.shape[1], item.rgb.shape[0]) != tuple(self.size):
                raise InputError(f"the LAAF measurements of {self.settings.input} give frame {item.t} at "
                                 f"{item.rgb.shape[1]}x{item.rgb.shape[0]} px where frame {k} at {self.size[0]}x"
                                 f"{self.size[1]} px was due; measure the chunks with these settings, in order")
            small, gray = shrink(item.rgb, self.size)
            af = AnalysisFrame(k, small, gray, item.disparity, self.scale, self.fps)
            self._find_cut(af, k)  # the chunk was measured knowing its cuts (analysis.measure_range)
            return af, item.features, item.seconds
        check_frame_size(item, self.clip, k, self.settings.input)
        af, seconds = self.setup.frame(item, k)
        features, det_seconds = self.analyser.measure(af, cut=self._find_cut(af, k))
        return af, features, {**seconds, **det_seconds}

    def _find_cut(self, af: AnalysisFrame, k: int) -> bool:
        """True when frame k starts a new shot: a given cut, or one the cut detector finds
        (recorded in ``cuts``). Run before frame k is measured: a cut frame's faces are
        detected afresh and no pairwise cue is measured across it."""
        if self.cut_detector is not None:
            t0 = time.perf_counter()
            if self.cut_detector.push(af.rgb) and k > 0:
                log.info("autofocus: shot cut at frame %d (%.0f%% of the pixels fail the flow checks): tracks and "
                         "targets restart", k + self.start, 100 * self.cut_detector.fail[-1])
                self.cuts.append(k)
                self._cutset.add(k)
            self._timings["cuts_s"] = self._timings.get("cuts_s", 0.0) + time.perf_counter() - t0
        return k in self._cutset

    def _ingest(self, k: int, af: AnalysisFrame, features: dict[str, object], seconds: dict[str, float]) -> None:
        """Every available detector takes frame k and its measurement, in frame order."""
        t0 = time.perf_counter()
        for name, det in self.detectors.items():
            if not det.available:
                continue
            if det.measures:
                if name not in features:
                    raise InputError(f"the LAAF measurements of frame {k} of {self.settings.input} lack detector "
                                     f"{name}; measure the chunks with the settings of this run")
                det.add_seconds(seconds.get(name, 0.0))
            det.ingest(k, af, features.get(name))
        measured = sum(seconds.get(name, 0.0) for name in self.detectors)
        self._timings["detect_s"] += time.perf_counter() - t0 + measured
        self._timings["decode_s"] += seconds.get("decode", 0.0)
        self._timings["depth_s"] += seconds.get("depth", 0.0)

    def _frame(self, k: int) -> AnalysisFrame | None:
        for f in self.buffer:
            if f.t == k:
                return f
        return None

    def step(self) -> bool:
        """Analyse the next frame; returns False once the whole clip is done (result ready)."""
        if self._finished:
            return False
        if self._frames is None:
            if self._measured_frames is not None:
                self._frames = iter(self._measured_frames)
            else:
                self._frames = iter_frames(self.settings.input, start=self.start, stop=self.stop)
        t0 = time.perf_counter()
        item = next(self._frames, None) if self._k < self.n else None
        self._timings["decode_s"] += time.perf_counter() - t0
        if item is None:
            if self._k < self.n:
                raise InputError(f"{self.settings.input} ended after {self._k} of {self.n} frames")
            self._finish()
            return False
        k = self._k
        af, features, seconds = self._analyse(item, k)
        if k in self._cutset:
            for det in self.detectors.values():
                det.cut(k)
        self.buffer.append(af)
        self._ingest(k, af, features, seconds)
        while self._measured <= k - self.detector_lag:
            self._measure(self._measured, ingest=k)
            self._measured += 1
        for nft in self.manual:
            if nft.t == k:
                self._add_target(nft, self._to_analysis(nft.box), k, ingest=k)
        self._track(af)
        self._k += 1
        return True

    def _finish(self) -> None:
        self.setup.close()
        for det in self.detectors.values():
            det.flush()
        last = self._k - 1
        while self._measured <= last:
            self._measure(self._measured, ingest=last)
            self._measured += 1
        if self.learned is not None:
            self.step_detector.finish()
            for cand in self.learned.take_nfts():
                self._commit_learned(cand, ingest=last)
        elif self._combo:
            for st in self.step_detector.finish():
                self._propose(st)
            self._resolve(last, ingest=last, final=True)
        self._finished = True
        self.result = self._compose()

    # -- measurement ------------------------------------------------------------------------
    def _measure(self, m: int, ingest: int) -> None:
        if not self._combo:
            return
        af = self._frame(m)
        if af is None:  # pragma: no cover - the buffer is sized for the lag
            raise RuntimeError(f"frame {m} left the analysis buffer too early")
        t0 = time.perf_counter()
        outputs: dict[str, DetectorOutput] = {n: self.detectors[n].output(m) for n in self._combo}
        mask, used = intersect(outputs, PRIMARY.get(self.preset_used or ""), self.settings.min_area)
        region = majority_region(mask, region_min_area(used, self.settings.min_area)) if mask is not None else None
        if region is not None:
            region.detectors = used
        level = region_level(af.disparity, region) if region is not None else float("nan")
        self.regions[m] = region
        for old in [k for k in self.regions if k < m - self.buffer.maxlen]:
            del self.regions[old]
        self.raw[m] = level
        new_shot = m == 0 or m in self._cutset
        if new_shot and not any(t.nft.t == m for t in self.targets):
            self._initial_target(af, region, level, ingest, t=m)
            if not math.isfinite(level):
                mine = [tg for tg in self.targets if tg.nft.t == m]
                level = float(mine[0].level[m]) if mine else level
        self._timings["combine_s"] += time.perf_counter() - t0
        turn = self._turn_step(m, region, level) if self.learned is None else None
        steps = self.step_detector.push(level)
        if self.learned is not None:
            for cand in self.learned.take_nfts():
                if not self._near_cut(cand[0]):
                    self._commit_learned(cand, ingest)
        else:
            if turn is not None:
                self._propose(turn)
            for st in steps:
                self._propose(st)
            self._resolve(m, ingest)
        self.held[m] = self.step_detector.held[m]

    # -- cuts and calm ------------------------------------------------------------------------
    def _near_cut(self, e: int) -> bool:
        """A step at frame e within ``cut_guard`` frames of a cut is the cut itself."""
        return any(abs(e - c) <= self.cut_guard for c in self.cuts)

    def _last_target_t(self, e: int) -> int | None:
        """Frame of the latest pulled-to target at or before e on e's shot (None if none; the
        shot's first target, set on its first frame, starts no hold)."""
        first, _ = shot_bounds(e, self.cuts)
        ts = [tg.nft.t for tg in self.targets if first < tg.nft.t <= e]
        return max(ts) if ts else None

    def _step_speaker(self, st) -> str | None:
        """The face track a step goes to when it is the speaking face the speech detector's chain
        names (its ``speaker``, or on a speech region of frames e..e+3), else None."""
        if st.speaker is not None:
            return st.speaker
        speech = self.detectors.get("speech")
        if speech is None or not speech.available:
            return None
        for k in range(st.frame, st.frame + 4):
            region = self.regions.get(k)
            if region is not None and "speech" in region.detectors:
                tid = speech.decide(k)[2]
                if tid is not None:
                    return tid
        return None

    def _latest_subject(self, e: int) -> str | None:
        """The subject (face track id or None) of the latest target at or before frame e on e's shot."""
        first, _ = shot_bounds(e, self.cuts)
        before = [tg for tg in self.targets if first <= tg.nft.t <= e]
        return max(before, key=lambda tg: tg.nft.t).nft.subject if before else None

    def _speaker_turn(self, st) -> bool:
        """Whether a step is a change of speaker made by the speech detector's decision chain (to
        a face that is not the subject of the shot's latest target). The chain's own cost of a
        change of face (about a second of clear evidence inside speech, less at a voice onset) is
        its hysteresis, so the minimum hold is not added on top: it would defer the answer to a
        turn shorter than the hold (0.8 s turns on the interview-halves composite) past its start."""
        tid = self._step_speaker(st)
        return tid is not None and tid != self._latest_subject(st.frame)

    def _turn_step(self, m: int, region: Region | None, level: float) -> Step | None:
        """Look-ahead: a change of speaker the speech detector's chain makes at frame m, as a step at
        the chain's turn start (``SpeechDetector.turn_start``: the first frame the new face speaks
        on the chain's best path, with the evidence after it; the decision of that frame itself had
        less of it and held the previous face), proposed as soon as frame m is measured instead of
        after the step detector's delay; the region is frame m's. None when frame m's region is not
        a new speaker's (the latest target's subject), its level is within the step threshold of
        the held level, or in causal mode (the chain has no hindsight there)."""
        speech = self.detectors.get("speech")
        if (self.causal or region is None or "speech" not in region.detectors or not math.isfinite(level)
                or speech is None or not speech.available):
            return None
        tid = speech.decide(m)[2]
        if tid is None or tid == self._latest_subject(m):
            return None
        held = self.step_detector.held[-1] if self.step_detector.held else float("nan")
        if not math.isfinite(held) or abs(level - held) < self.step_detector.min_step:
            return None
        onset = speech.turn_start(m)
        if onset is None:
            return None
        first, _ = shot_bounds(m, self.cuts)
        floor = max([first] + [tg.nft.t + 1 for tg in self.targets if first <= tg.nft.t <= m])
        return Step(min(max(onset, floor), m), held, level, speaker=tid, region_frame=m)

    def _propose(self, st) -> None:
        """A step of the focus signal: dropped next to a cut, else decided once its
        persistence window (calm) and the minimum hold after the previous target are seen."""
        e = st.frame
        if self._near_cut(e):
            log.debug("step at frame %d is a shot cut; the cut's own target covers it", e)
            return
        p = self.pull
        due = (e if st.region_frame is None else max(e, st.region_frame)) + self.calm.persist_frames
        last = self._last_target_t(e)
        if last is not None and self.calm.hold_frames and e - p.lead_frames - p.pull_frames < last + self.calm.hold_frames \
                and not self._speaker_turn(st):
            due = max(due, last + self.calm.hold_frames + p.lead_frames + p.pull_frames)
        self._pending.append((st, due))

    def _resolve(self, m: int, ingest: int, final: bool = False) -> None:
        """Decide the pending steps due by frame m (all of them when final)."""
        if not self._pending:
            return
        keep = []
        for st, due in self._pending:
            if due > m and not final:
                keep.append((st, due))
                continue
            self._decide(st, min(due, m), ingest)
        self._pending = keep

    def _decide(self, st, due: int, ingest: int) -> None:
        e = st.frame
        _, nxt = shot_bounds(e, self.cuts)
        if nxt is not None and nxt <= due:
            log.debug("step at frame %d: a cut follows at frame %d before it is decided; dropped", e, nxt)
            return
        tol = max(0.5 * abs(st.after - st.before), 0.3)
        seen = e if st.region_frame is None else max(e, st.region_frame)  # a turn step: measured from its region's frame
        if self.calm.persist_frames and not persists(self.raw[seen:min(seen + self.calm.persist_frames, due + 1)],
                                                     st.after, tol):
            log.debug("step at frame %d: its new level %.2f does not persist; held", e, st.after)
            return
        first, _ = shot_bounds(e, self.cuts)
        if any(e <= tg.nft.t and first <= tg.nft.t for tg in self.targets):
            log.debug("step at frame %d: focus moved on since; dropped", e)
            return
        if self._withdraw_taken_back(st, ingest):
            return
        speaker = self._step_speaker(st)
        if speaker is not None and speaker == self._latest_subject(e):
            log.debug("step at frame %d: focus is on its speaker (%s) already; dropped", e, speaker)
            return
        search = None if st.region_frame is None else range(st.region_frame, st.region_frame + 1)
        p = self.pull
        # the shot's first target: a cut's, or the clip's initial focus (frame 0 is a shot's start too),
        # replaced by the subject found just after; a motion or saliency subject may be corrected again
        # within the hold, a speaker's (a turn that happened) is final: the next speaker is a pull
        cut_tg = next((tg for tg in self.targets if tg.nft.t == first
                       and (tg.nft.detail.get("cut") or tg.nft.detail.get("start"))
                       and not (tg.nft.source == "speech" and "subject_from_frame" in tg.nft.detail)), None)
        # the shot's first target is a guess (the largest face, a voice's region, saliency): a subject
        # found within the look-ahead may replace it, not only within the minimum hold
        if (cut_tg is not None and not self.causal and self.calm.hold_frames
                and e - p.lead_frames - p.pull_frames < first + max(self.calm.hold_frames, self.window)
                and not any(first < tg.nft.t for tg in self.targets)):
            # look-ahead, soon after a cut: if this subject is already there on the cut frame (tracked
            # back to it), it is the shot's subject: focus on it on the cut itself
            if self._commit(st, ingest, search=search, at_cut=cut_tg):
                return
        last = self._last_target_t(e)
        if last is not None and self.calm.hold_frames and e - p.lead_frames - p.pull_frames < last + self.calm.hold_frames \
                and not self._speaker_turn(st):
            t_new = last + self.calm.hold_frames + p.lead_frames + p.pull_frames
            if t_new >= self.n:
                return
            seen = self.raw[max(t_new - 3, 0):t_new + 1]
            seen = seen[np.isfinite(seen)]
            if seen.size == 0 or abs(float(np.median(seen)) - st.after) > tol:
                log.debug("step at frame %d (minimum hold until %d): the scene no longer asks for it", e, t_new)
                return
            self._commit(Step(t_new, st.before, st.after), ingest, search=range(max(t_new - 4, 0), t_new + 1))
            return
        self._commit(st, ingest, search=search)

    def _withdraw_taken_back(self, st, ingest: int) -> bool:
        """A change of speaker back to the face the focus was on before the latest target, within a
        pull of that target's frame: the speech chain took back the change it made there (its
        decision for those frames was not final yet; on the interview made small, a pull to the
        presenter at frame 380 was followed by one back to the guest at 381). Instead of pulling
        there and straight back, that target is withdrawn and the one before resumes (its subject
        tracked on from where it stopped). True when so."""
        if self.causal or not self._speaker_turn(st):
            return False
        first, _ = shot_bounds(st.frame, self.cuts)
        shot = sorted((tg for tg in self.targets if first <= tg.nft.t <= st.frame), key=lambda tg: tg.nft.t)
        if len(shot) < 2:
            return False
        latest, before = shot[-1], shot[-2]
        if (latest.nft.source != "speech" or latest.nft.detail.get("cut") or latest.nft.detail.get("start")
                or st.frame - latest.nft.t > self.pull.pull_frames or self._step_speaker(st) != before.nft.subject
                or before.tracker is None):
            return False
        self.targets.remove(latest)
        before.active = True
        self._track_forward(before, before.tracker.state.frame + 1, ingest)
        before.events.append({"frame": latest.nft.t, "status": "resumed", "score": 0.0, "direction": "forward"})
        log.debug("step at frame %d: the change of speaker at frame %d was taken back; that target is withdrawn",
                  st.frame, latest.nft.t)
        return True

    def _initial_target(self, af: AnalysisFrame, region: Region | None, level: float, ingest: int,
                        t: int = 0) -> None:
        """The focus before the first NFT of a shot (frame t: 0 or a cut): the preset's region on
        frame t, else the largest face, else the salient majority region (see
        combine.INITIAL_CHAIN). At a cut the NFT is a hard change on the cut frame."""
        if any(n.t == t for n in self.manual):
            return
        source = self._source(region.detectors) if region is not None else None
        if region is None:
            from .detectors.face import FaceDetector
            from .detectors.saliency import SaliencyDetector

            face = self.detectors.get("face")
            boxes = face.faces_at(t) if isinstance(face, FaceDetector) else []
            if not boxes:
                try:
                    boxes = [(b, 1.0, None) for b in FaceDetector(backend=self.settings.face_backend).detect(af)]
                except RuntimeError:
                    boxes = []
            if boxes:
                box = max((b for b, _, _ in boxes), key=lambda b: b[2] * b[3])
                mask = np.zeros(af.gray.shape, bool)
                x, y, w, h = (int(round(v)) for v in box)
                mask[max(y, 0):y + h, max(x, 0):x + w] = True
                region = Region(box[0] + box[2] / 2, box[1] + box[3] / 2, box, mask, float(mask.mean()), ("face",))
                source = "face"
            else:
                sal = self.detectors.get("saliency") or SaliencyDetector()
                heat = sal.compute(af.rgb) if isinstance(sal, SaliencyDetector) else None
                region = majority_region(heat >= 0.5, self.settings.min_area) if heat is not None else None
                source = "saliency"
        if region is None:  # nothing anywhere: the centre of the frame
            h, w = af.gray.shape
            box = (w * 0.4, h * 0.4, w * 0.2, h * 0.2)
            mask = np.zeros((h, w), bool)
            mask[int(h * 0.4):int(h * 0.6), int(w * 0.4):int(w * 0.6)] = True
            region = Region(w / 2, h / 2, box, mask, 0.04, ())
            source = "initial"
        nft = self._nft_from_region(region, t, source, known_at=max(t - 1, 0), subject=None)
        speech = self.detectors.get("speech")
        on_face = "face" in region.detectors or (speech is not None and speech.available
                                                 and "speech" in region.detectors and speech.decide(t)[2] is not None)
        if t > 0:
            nft = replace(nft, pull_frames=1, lead_frames=0, detail={"cut": True, "on_face": bool(on_face)})
        else:  # the clip's first focus: look-ahead may still replace it by the subject found just after
            nft = replace(nft, detail={"start": True, "on_face": bool(on_face)})
        self._add_target(nft, region.box, t, ingest, mask=region.mask)

    def _source(self, used: tuple[str, ...]) -> str:
        for name in ("afnet", "speech", "action", "face", "saliency"):
            if name in used:
                return name
        return "initial"

    def _to_analysis(self, box: Box) -> Box:
        return tuple(v * self.scale for v in box)

    def _nft_from_region(self, region: Region, t: int, source: str, known_at: int, subject) -> NFT:
        s = self.scale
        box = tuple(v / s for v in region.box)
        return NFT(region.x / s, region.y / s, t, box, source, known_at=known_at, subject=subject)

    def _commit(self, step, ingest: int, search: range | None = None, at_cut: TargetState | None = None) -> bool:
        """Make the NFT of a step (its region: the first of frames ``search``, default e..e+3,
        whose level is near the step's new level); True if it was made. at_cut: the target of
        the cut that starts the step's shot, replaced by this subject on the cut frame (a hard
        change there) only if the subject is tracked back to the cut frame and, where that
        target is on a face, the subject is on a face too (a speaker's face; not a region only
        audio-visual synchrony or motion found); else nothing is made."""
        e = step.frame
        region = None
        first, nxt = shot_bounds(e, self.cuts)
        for k in (search if search is not None else range(e, min(e + 4, self._measured))):
            if k < first or (nxt is not None and k >= nxt):
                continue  # a region of another shot
            r, f = self.regions.get(k), self._frame(k)
            if r is None or f is None:  # no region, or its frame has left the buffer (a region outlives it)
                continue
            if abs(region_level(f.disparity, r) - step.after) < max(0.5, 0.5 * abs(step.after - step.before)):
                region, e_region = r, k
                break
        if region is None:
            log.debug("step at frame %d has no region near its new level; skipped", e)
            return False
        known_at = max(0, ingest - self.window)
        if any(abs(n.t - e) < self.pull.pull_frames for n in self.manual):
            return False
        outputs_tid = None
        speech = self.detectors.get("speech")
        if speech is not None and speech.available and "speech" in region.detectors:
            outputs_tid = speech.decide(e_region)[2]
        if at_cut is not None and at_cut.nft.detail.get("on_face") and outputs_tid is None \
                and "face" not in region.detectors:
            log.debug("step at frame %d: no face holds its region, and the cut at frame %d found a face: the face "
                      "stays the shot's subject", e, at_cut.nft.t)
            return False
        nft = self._nft_from_region(region, e, self._source(region.detectors), known_at, outputs_tid)
        nft = NFT(nft.x, nft.y, nft.t, nft.box, nft.source, nft.known_at,
                  confidence=float(min(1.0, abs(step.after - step.before) / (2 * self.settings.min_step))),
                  subject=outputs_tid, detail={"level_before": round(step.before, 4), "level_after": round(step.after, 4)})
        if at_cut is not None:
            c = at_cut.nft.t
            nft = replace(nft, t=c, known_at=max(c - 1, 0), pull_frames=at_cut.nft.pull_frames,
                          lead_frames=at_cut.nft.lead_frames,
                          detail={**nft.detail, "cut" if c > 0 else "start": True, "subject_from_frame": int(e)})
        hold_back = ((at_cut.nft.t, outputs_tid) if at_cut is not None and outputs_tid is not None
                     and self._face_track_covers(outputs_tid, at_cut.nft.t, e_region) else None)
        tg = self._add_target(nft, region.box, e_region, ingest, mask=region.mask, hold_back=hold_back)
        if at_cut is not None:
            if not np.isfinite(tg.level[at_cut.nft.t]):  # not there yet on the cut frame
                self.targets.remove(tg)
                return False
            self.targets.remove(at_cut)
            log.debug("the subject of the shot from frame %d is the one of frame %d: focus on it from the shot's "
                      "first frame", at_cut.nft.t, e)
        return True

    def _commit_learned(self, cand, ingest: int) -> None:
        """An NFT proposed by AF-Net: (frame t, frame q of its region, probability, region)."""
        t, q, p, region = cand
        if t >= self.n or any(n.t == t for n in self.manual) or any(tg.nft.t == t for tg in self.targets):
            return
        if any(abs(n.t - t) < self.pull.pull_frames for n in self.manual):
            return  # the user wins
        source, subject, detail = "afnet", None, {"p": round(float(p), 4)}
        spoken = self._speaker_region(t)
        if spoken is not None:
            q, region, subject, corr, turn = spoken
            source = "afnet_speech"
            detail.update(speech_corr=round(corr, 4), voice_turn=list(turn))
        t_box = min(max(q, self.buffer[0].t), self.buffer[-1].t)  # the region's frame, kept in the buffer
        known_at = max(0, ingest - self.window)
        nft = self._nft_from_region(region, t, source, known_at, subject)
        nft = replace(nft, confidence=round(float(p), 4), detail={**detail, "region_frame": int(q)})
        self._add_target(nft, region.box, t_box, ingest, mask=region.mask)

    def _speaker_region(self, t: int) -> tuple[int, Region, str | None, float, tuple[int, int]] | None:
        """(frame, region, face track id, correlation, the turn's (first, last) frame) of the
        speaker at an AF-Net NFT at t, or None.

        Preset 'learned' with a speech detector (``afnet_speaker``, a clip with sound), when a
        voiced segment (a turn) starts within ``ONSET_BEFORE`` frames before t .. REGION_LAG_FRAMES
        after it: of that turn's frames from t to t + REGION_LAG_FRAMES still in the buffer, the
        speaker the speech detector localises with the highest correlation. An NFT far from any
        voice onset (someone enters while another talks on) keeps AF-Net's map. AF-Net knows
        *when* the speaker changes, but seeing every 5th frame at 128 x 72 px it often cannot
        tell *whose* mouth moves."""
        from ..afnet.infer import REGION_LAG_FRAMES

        speech = self.detectors.get("speech")
        if speech is None or not speech.available or not self.buffer:
            return None
        before, lag = frames_at(ONSET_BEFORE, self.fps), frames_at(REGION_LAG_FRAMES, self.fps)  # frames at 25 fps
        turns = [(a, b) for a, b in speech.audio.segments() if t - before <= a <= t + lag]
        if not turns:
            return None
        a, b = turns[0]
        best = None
        for k in range(max(t, a, self.buffer[0].t), min(t + lag, b, self.buffer[-1].t) + 1):
            box, corr, tid = speech.decide(k)
            if box is not None and (best is None or corr > best[1]):
                best = (k, corr, box, tid)
        if best is None:
            return None
        k, corr, box, tid = best
        h, w = self._frame(k).gray.shape
        x, y, bw, bh = box
        mask = np.zeros((h, w), bool)
        mask[max(int(round(y)), 0):int(round(y + bh)), max(int(round(x)), 0):int(round(x + bw))] = True
        region = Region(x + bw / 2, y + bh / 2, box, mask, float(mask.mean()), ("afnet", "speech"))
        return k, region, tid, float(corr), (int(a), int(b))

    # -- targets and tracking -----------------------------------------------------------------
    def _read(self, af: AnalysisFrame, box: Box, mask=None, prior: float | None = None) -> float:
        return read_focus(af.disparity, box, mask, prior=prior).value

    def _face_box(self, tid: str, k: int) -> Box | None:
        """Face track ``tid``'s box on frame k (analysis px; the face detector's kept boxes), or None."""
        face = self.detectors.get("face")
        faces_at = getattr(face, "faces_at", None)
        return next((b for b, _, i in faces_at(k) if i == tid), None) if faces_at is not None else None

    def _face_track_covers(self, tid: str, a: int, b: int) -> bool:
        """Whether face track ``tid`` is on every frame a..b."""
        return all(self._face_box(tid, k) is not None for k in range(a, b + 1))

    def _add_target(self, nft: NFT, box: Box, t_box: int, ingest: int, mask=None,
                    hold_back: tuple[int, str] | None = None) -> TargetState:
        """Start tracking a new target from frame t_box (analysis box), backwards over its pull
        and forwards up to the newest frame in the buffer; returns its state. hold_back: (a
        shot's first frame; the subject's face track, on every frame since): where tracking back stops
        before it (the buffer's oldest frame reached, the tracker lost, a reading that jumps), the last
        level read is held back to it in the face track's boxes (a talking head keeps its distance; the
        face track says the subject is there; the frames themselves may no longer be in memory)."""
        t0 = time.perf_counter()
        tg = TargetState(nft, np.full(self.n, np.nan, np.float32), box, first_read=t_box)
        af = self._frame(t_box)
        tg.tracker = SubjectTracker()
        tg.tracker.start(af.rgb, box, t_box)
        tg.boxes[t_box] = (tuple(box), True)
        tg.level[t_box] = self._read(af, box, mask)
        # backwards over the frames the pull to this target may use
        p = self.pull
        back = SubjectTracker()
        back.start(af.rgb, box, t_box)
        first, _ = shot_bounds(nft.t, self.cuts)
        for k in range(t_box - 1, max(nft.t - p.lead_frames - p.pull_frames - 2, first, 0) - 1, -1):
            f = self._frame(k)
            state = back.update(f.rgb, k) if f is not None else None
            value = None
            if state is not None and state.ok:
                tg.boxes[k] = (state.box, True)
                value = self._read(f, state.box, prior=float(tg.level[k + 1]))
            if value is not None and abs(value - float(tg.level[k + 1])) > self.max_jump:
                tg.events.append({"frame": k, "status": "depth_jump", "score": round(value, 3), "direction": "backward"})
                value = None  # e.g. a subject not yet in frame: the box sees what is behind it
            if value is None:  # tracking back stops here: the frame has left the buffer, the tracker lost it, a jump
                if hold_back is not None and hold_back[0] <= k and np.isfinite(tg.level[k + 1]):
                    # the speaker's face track is on every frame since the shot's start: its level holds
                    tg.level[hold_back[0]:k + 1] = tg.level[k + 1]
                    for j in range(hold_back[0], k + 1):
                        tg.boxes[j] = (tuple(self._face_box(hold_back[1], j)), True)
                    tg.events.append({"frame": k, "status": "held_back", "score": round(float(tg.level[k + 1]), 3),
                                      "direction": "backward"})
                break
            tg.level[k] = value
        for ev in back.events:
            tg.events.append({"frame": ev.frame, "status": ev.status, "score": round(ev.score, 3),
                              "direction": "backward"})
        # retire the previous target (its level no longer matters after this NFT)
        for other in self.targets:
            if other.active and other.nft.t < nft.t:
                other.active = False
        self.targets.append(tg)
        self.targets.sort(key=lambda x: x.nft.t)
        self._track_forward(tg, t_box + 1, ingest)
        self._timings["track_s"] += time.perf_counter() - t0
        return tg

    def _track_forward(self, tg: TargetState, start: int, ingest: int) -> None:
        """Track ``tg``'s subject over frames start..ingest of the buffer, up to the end of its shot
        (no box is carried over a cut: there the target ends)."""
        _, nxt = shot_bounds(tg.nft.t, self.cuts)
        for k in range(start, ingest + 1):
            if nxt is not None and k >= nxt:
                tg.active = False
                tg.events.append({"frame": nxt, "status": "cut", "score": 0.0, "direction": "forward"})
                break
            f = self._frame(k)
            if f is not None:
                self._update_target(tg, f)

    def _reanchor(self, tg: TargetState) -> None:
        """Take a young target's new level when its readings have jumped away from the first ones
        and agree among themselves for ``reanchor_frames`` frames in a row (:data:`REANCHOR_FRAMES`):
        the level it jumped from was the odd one. In look-ahead mode the run and the frames since its
        first reading take the new level too (the pull lands on it); causal mode cannot change the
        past: from the frame it decides on."""
        run = tg.jumped[-self.reanchor_frames:]
        if len(run) < self.reanchor_frames or run[0][0] - tg.first_read > self.reanchor_frames:
            return
        values = np.array([v for _, v in run])
        level = float(np.median(values))
        if np.abs(values - level).max() > self.max_jump:
            return
        for k, v in run if not self.causal else run[-1:]:  # causal: from the frame it decides on
            tg.level[k] = v
        if not self.causal:
            before = np.isfinite(tg.level[:run[0][0]])
            tg.level[:run[0][0]][before] = level
        tg.events.append({"frame": run[0][0], "status": "reanchor", "score": round(level, 3), "direction": "forward"})
        tg.jumped.clear()

    def _update_target(self, tg: TargetState, af: AnalysisFrame) -> None:
        state = tg.tracker.update(af.rgb, af.t)
        tg.boxes[af.t] = (state.box, state.ok)
        if state.ok:
            known = tg.level[:af.t]
            prior = known[np.isfinite(known)][-1] if np.isfinite(known).any() else None
            value = self._read(af, state.box, prior=prior)
            if prior is not None and abs(value - prior) > self.max_jump:
                tg.events.append({"frame": af.t, "status": "depth_jump", "score": round(value, 3),
                                  "direction": "forward"})
                if tg.jumped and tg.jumped[-1][0] != af.t - 1:
                    tg.jumped.clear()
                tg.jumped.append((af.t, value))
                self._reanchor(tg)
            else:
                tg.level[af.t] = value
                tg.jumped.clear()
        if state.status != "tracked":
            tg.events.append({"frame": af.t, "status": state.status, "score": round(state.score, 3),
                              "direction": "forward"})
        if tg.lost_from is None and tg.tracker.frames_lost >= self.pull.hold_frames:
            tg.lost_from = af.t - tg.tracker.frames_lost + 1
            log.info("target of frame %d lost from frame %d (%s): holding its focus, then releasing",
                     tg.nft.t, tg.lost_from, state.status)

    def _track(self, af: AnalysisFrame) -> None:
        t0 = time.perf_counter()
        if af.t in self._cutset:
            for tg in self.targets:
                if tg.active and tg.nft.t < af.t:
                    tg.active = False
                    tg.events.append({"frame": af.t, "status": "cut", "score": 0.0, "direction": "forward"})
        for tg in self.targets:
            if tg.active and tg.tracker is not None and tg.tracker.state.frame < af.t:
                self._update_target(tg, af)
        self._timings["track_s"] += time.perf_counter() - t0

    # -- result ---------------------------------------------------------------------------------
    def _compose(self) -> AutofocusResult:
        s = self.settings
        if not self.targets:
            raise InputError(f"no focus target in {s.input}: nothing was found by preset {s.preset}; give NFTs "
                             "with --targets")
        pts = []
        for tg in self.targets:
            level = deadband(tg.level, self.calm.deadband)
            if not np.isfinite(level).any():
                level[tg.nft.t] = float(np.nanmedian(self.held)) if np.isfinite(self.held).any() else 0.0
            pts.append(PullTarget(tg.nft.t, level, known_at=tg.nft.known_at, lost_from=tg.lost_from,
                                  aperture=tg.nft.aperture, pull_frames=tg.nft.pull_frames,
                                  lead_frames=tg.nft.lead_frames, at_cut=bool(tg.nft.detail.get("cut"))))
        composed = compose_track(pts, self.n, self.pull, aperture=s.aperture, cuts=self.cuts)
        keys = keyframes(composed.focus, composed.aperture, tol=s.keyframe_tol)
        tracking = []
        for i, tg in enumerate(self.targets):
            for ev in tg.events:
                tracking.append({"target": i, **ev})
        metrics = {n: d.metrics() for n, d in self.detectors.items()}
        fallback = self.fallback_note
        if "face" in self._combo and not self.detectors["face"].metrics()["frames_with_faces"]:
            sync = int(metrics.get("speech", {}).get("synchrony_frames", 0)) if "speech" in self._combo else 0
            if sync:
                fallback = fallback or (f"no face was found; the {s.preset} preset used the speech detector's "
                                        f"audio-visual synchrony alone ({sync} frames)")
                log.warning("no face was found in %s; the %s preset fell back to the speech detector's audio-visual "
                            "synchrony map alone (speaker localised on %d frames)", s.input, s.preset, sync)
            else:
                log.warning("no face was found in %s; the %s preset had nothing to intersect with faces",
                            s.input, s.preset)
        seconds = time.perf_counter() - self._t0
        settings = {"preset": s.preset, "preset_used": self.preset_used if self._combo else None,
                    "fallback": fallback or None, "window_s": 0.0 if self.causal else s.window_s,
                    "window_frames": self.window, "causal": self.causal, "pull_frames": self.pull.pull_frames,
                    "lead_frames": self.pull.lead_frames, "profile": self.pull.profile,
                    "hold_frames": self.pull.hold_frames,
                    "aperture": s.aperture, "analysis_width": self.size[0], "min_step": s.min_step,
                    "disparity": self.depth.label + (f" (channel {self.depth.channel})" if self.depth.channel else ""),
                    "auto": self.auto,
                    "cuts": [c + self.start for c in self.cuts], "cuts_source": self.cuts_source,
                    "calm": {"calm": self.calm.calm, "step_factor": round(self.calm.step_factor, 3),
                             "min_step_effective": round(s.min_step * self.calm.step_factor, 4),
                             "hold_frames": self.calm.hold_frames, "persist_frames": self.calm.persist_frames,
                             "deadband": round(self.calm.deadband, 4)},
                    "timings_s": {k: round(v, 3) for k, v in self._timings.items()}}
        inv = 1.0 / self.scale
        boxes = [{k: (tuple(float(v) * inv for v in b), ok) for k, (b, ok) in sorted(t.boxes.items())}
                 for t in self.targets]
        return AutofocusResult(composed.focus, composed.aperture, keys, [t.nft for t in self.targets], tracking,
                               {"raw": self.raw, "held": self.held}, metrics, composed, self.clip, self.start,
                               settings, seconds, boxes, list(self.cuts))

    def cancel(self) -> None:
        """Stop (Esc, Ctrl-C; any time, idempotent): the decoder is closed and no result is made.
        The job writes nothing itself, so nothing changes; after the end the result stays."""
        frames, self._frames = self._frames, None
        close = getattr(frames, "close", None)
        if close is not None:
            close()
        self.setup.close()
        if not self._finished:
            self._finished = True
            self.text = f"cancelled after {self._k} of {self.n} frames"

    def run(self, progress: bool = True) -> AutofocusResult:
        """Run to the end (tqdm progress bar when ``progress``); returns the result."""
        from tqdm import tqdm

        with tqdm(total=self.n, unit="frame", disable=not progress, desc="autofocus") as bar:
            while self.step():
                bar.update(1)
            bar.update(self.n - bar.n)
        assert self.result is not None
        return self.result
