"""Speech detector H_aud: *who* is speaking (voice activity + audio-visual synchrony).

The paper used a deep audio-visual localiser (Owens & Efros 2018). Here, without learned
weights, the same cue explicitly: while the voice activity detector says someone speaks, the
speaker is the face whose *mouth motion* follows the *audio envelope*.

**Who speaks, by the mouth** (where ``mediapipe`` imports; ``mouth='auto'``): per face track and
frame, the face mesh's mouth opening (``people.mouth_opening``: inner-lip gap / mouth width, a
ratio of the face's own size) on a crop of the native frame around the track's box
(``mediapipe_face.MediaPipeFaces.mouths``; every ``mesh_every`` frames, in between held). At
voiced frame t a face's *evidence* is the Pearson correlation of its opening with the audio
envelope over a window of ``mouth_window_s`` (centred on t in look-ahead mode, ending at t in
causal mode, clipped to the voiced segment +-2 frames). A face is a candidate only if its mouth
moves (standard deviation of the opening in the window >= ``mouth_min_activity`` and >=
``mouth_rel_activity``, 0.3, of the most active mouth on screen: a listener's nearly closed
mouth, whose twitches can correlate by chance, does not compete with an articulating one; at 0.5
a speaker whose mouth opened half as much as a muted talker's, a small panel's presenter on the
interview-halves composite, was no candidate in either of his first and last turns).

The per-frame evidence is weak (a 1 s correlation of a real mouth with its voice is 0.2-0.6, a
muted talker's with someone else's voice reaches 0.3 by chance, 0.8 for half a second at the
end of the other person's sentence), so the decision integrates it over time: a hidden Markov
chain over, per face track k, "k speaks" (score: its correlation; a non-candidate -1) and "k
spoke last and holds the focus, nobody on screen speaks now" (off-screen speech, a voice-over,
a pause: ``none_score``), plus "no face established yet" at the start (and where every face
held has left the picture). A *change of face* (the first speaker included) is what costs (issue 23, focus that holds): going from speaking to holding or back is free, so a
voice the held face's mouth no longer explains does not hand the focus to whichever other
mouth happens to move with it. Inside continuous speech a change costs ``switch_cost`` (about
a second of clear evidence), times ``1 - voice_weight * change`` where ``change`` is the
voice-characteristic change at that frame (``AudioTrack.voice_change``: another voice taking
over makes it cheaper, the same voice going on keeps it dear); at a voice onset (silence and
the first ``onset_s`` of a voiced segment: turns change there) it costs ``pause_cost``. Either
is multiplied by up to ``2 ** voice_id_weight`` when the voice at that frame is not the voice
the new face was heard with before (:meth:`SpeechDetector._voice_factor`; the cepstra of its
committed speaking frames). Look-ahead mode decides frame t by the best path (Viterbi) ending
``smooth_s`` after t (a fixed-lag smoother: the evidence of the next second is used); causal
mode by the best path ending at t (:meth:`SpeechDetector.turn_start`: the first voiced frame of the
named face's turn on that path, which LAAF's look-ahead takes as the change of speaker's frame: the
onset frame's own decision had less of the evidence after it). Decisions become final ``commit_s`` after they are made: the
chain keeps only the decided state of those frames, so a change of face later pays its cost
from the decided past (without this, a face held through the other's whole turn could take it
back in hindsight as soon as its mouth correlated for half a second). The heat map is the
speaking face's box; nobody (silence, off-screen speech, a held face) is an empty map and the
combination keeps its focus, never moving it onto a silent face. Measured on the composite
clips and the interview (``rvr eval-focus --real``, docs/autofocus.md): on GRID + restaurant the
spurious focus changes went from 8.1 to 0 per minute.
**A per-track audio-video lag** (lip-sync offset; ``max_lag_s``, 0.2 s: split-screen feeds are
delayed each on its own, on the interview the guest's picture runs 4-5 frames ahead of his
sound): per face track, every voiced mouth window's correlation curve over the lags in
+-max_lag (each window normalised on its own) where some lag reaches ``lag_window_corr`` is
averaged; the curve's peak is the track's lag once ``lag_min_windows_s`` of such windows are in
and it beats no lag by ``lag_margin``, else 0 (``lag_mode='curve'``). A feed's delay is one
constant and piles up at one lag; a listener's chance correlations and repeating syllables
scatter and average out. Learnt so (2026-12-03): the guest -4 or -5 frames on the interview,
the interview-halves composite and the shot/reverse-shot composite, every other face 0; the
interview-halves composite's share on the speaker 0.65 -> 0.81 (docs/autofocus.md). The
mesh and the motion cues of the track are both read shifted by it. The earlier estimate
(``lag_mode='sums'``: one Pearson over the track's whole voiced history) chose wrong lags,
a listener's too (its mouth reaches a chance peak at the edge of the search).

The mesh-read faces' evidence averages the opening's correlation with the motion cues' below
(``motion_weight``): on the interview the mesh alone is right on 0.49 of the annotated voiced
frames, the motion cues alone 0.81, the average 0.74-0.85; on the GRID + restaurant composite
0.81, 0.79 and 0.85-0.89 (``scripts/composite_speakers.py``; 2026-12-02).

**Fallback, without a face mesh** (mediapipe missing, ``mouth='motion'``, or a face the mesh does
not find: a profile, a drawn face): the raw motion of the box's mouth region.
Per frame (analysis resolution): the previous frame is aligned to the current one by a
homography (sparse Lucas-Kanade features + RANSAC: camera motion removed), and the absolute
difference gives motion energy. For each face track of the face detector two mouth cues are
recorded: the motion energy of its mouth region (lower middle of the box) minus that of its
upper face (head motion), and the mouth's darkness (upper-face minus mouth intensity: an open
mouth shows its dark inside). At frame t a face's score is the best Pearson correlation (of
moving averages over MOTION_SMOOTH_S, 3 frames at 25 fps) of motion with the envelope or with its change, or of darkness with
the envelope, taken over a window of ``window_s``
(centred on t in look-ahead mode, ending at t in causal mode) clipped to the current voiced
segment (+-2 frames), so two turns are never mixed. The heat map is the speaking face's box
(a lone face while someone speaks is taken as the speaker if it correlates at all).

Frames without any face track (faces too small or stylised for the face detector, a head
turned away): the speaker is localised without faces by audio-visual synchrony
(``synchrony.SynchronyLocaliser``, Hershey & Movellan 2000): the block of the camera-motion
compensated frame difference whose energy correlates best with the change of the audio
envelope, over the same kind of window (widened by ``sync_margin`` frames of the silence
around the turn, which shows that the block was still while nobody spoke); it must reach
``sync_min_corr``. Not within ``sync_face_gap_s`` (1 s) after a frame of the same shot with a face:
there the face detector missed a face (on the shot/reverse-shot composite MediaPipe's full-range
model lost close-ups, and a 40 px block of the wall won the voice). The heat map is then a square of ``sync_box_frac`` of the frame width
around that block. A speaker whose mouth is hidden (behind a leaf, off screen) leaves no
synchrony and is not found: the preset keeps its focus. (An earlier grid-correlation attempt
failed on textured, moving backgrounds because it had no camera-motion compensation and
correlated with the envelope rather than its change.) No audio track: ``available`` is
False and the preset falls back.
"""
from __future__ import annotations

import logging
import time

import numpy as np

from ..audio import VOICE_CHANGE_RANGE, AudioTrack, NoAudio, analyse_audio, decode_audio
from ..nft import Box
from ..timebase import REFERENCE_FPS, frames_at, reference_frames_per_frame
from .base import AnalysisFrame, DetectorOutput, FocusDetector, boxes_heat
from .face import FaceDetector
from .mediapipe_face import MediaPipeFaces, mediapipe_importable
from .synchrony import SynchronyLocaliser

MOUTH_MODES = ("auto", "mesh", "motion")
NOBODY = ""  # the decision chain's "no face established yet" (track ids are never empty)
NOBODY_STATE = (NOBODY, False)

log = logging.getLogger(__name__)


def _pearson(x: np.ndarray, y: np.ndarray) -> float:
    x = x - x.mean()
    y = y - y.mean()
    den = float(np.sqrt((x * x).sum() * (y * y).sum()))
    return float((x * y).sum() / den) if den > 1e-12 else 0.0


MOTION_SMOOTH_S = 0.12
"""Span (s) of the moving average of the motion cues and the envelope before they are correlated:
3 frames at 25 fps (as before), 5 at 30 fps, 7 at 50-60 fps (:func:`motion_smooth_frames`)."""


def motion_smooth_frames(fps: float) -> int:
    """The odd number of frames (>= 3) :data:`MOTION_SMOOTH_S` spans at ``fps``."""
    return max(3, int(round(MOTION_SMOOTH_S * float(fps))) | 1) if fps and fps > 0 else 3


def _smooth(x: np.ndarray, width: int = 3) -> np.ndarray:
    """Moving average over ``width`` frames (mouth motion is a derivative; smoothing aligns it
    with the envelope)."""
    if len(x) < width:
        return x
    return np.convolve(x, np.ones(width) / width, mode="same")


def align_previous(prev: np.ndarray, cur: np.ndarray) -> np.ndarray:
    """``prev`` warped onto ``cur`` by a homography from LK-tracked corners (RANSAC); unwarped
    when too few features. (h, w) uint8 in, float32 out."""
    import cv2

    pts = cv2.goodFeaturesToTrack(prev, 150, 0.01, 6)
    if pts is not None and len(pts) >= 8:
        nxt, st, _ = cv2.calcOpticalFlowPyrLK(prev, cur, pts, None, winSize=(15, 15), maxLevel=2)
        good = st.reshape(-1) == 1
        if good.sum() >= 8:
            H, _ = cv2.findHomography(pts[good], nxt[good], cv2.RANSAC, 1.0)
            if H is not None:
                return cv2.warpPerspective(prev, H, (cur.shape[1], cur.shape[0]), flags=cv2.INTER_LINEAR,
                                           borderMode=cv2.BORDER_REPLICATE).astype(np.float32)
    return prev.astype(np.float32)


def mouth_box(face: Box) -> Box:
    """The mouth region of a face box: x 25-75%, y 62-97% of the box."""
    x, y, w, h = face
    return (x + 0.25 * w, y + 0.62 * h, 0.5 * w, 0.35 * h)


def upper_box(face: Box) -> Box:
    """The upper face (eyes, forehead): x 20-80%, y 15-50% of the box."""
    x, y, w, h = face
    return (x + 0.2 * w, y + 0.15 * h, 0.6 * w, 0.35 * h)


def _mean_in(img: np.ndarray, box: Box) -> float:
    h, w = img.shape
    x0, y0 = int(max(box[0], 0)), int(max(box[1], 0))
    x1, y1 = int(min(np.ceil(box[0] + box[2]), w)), int(min(np.ceil(box[1] + box[3]), h))
    return float(img[y0:y1, x0:x1].mean()) if x1 > x0 and y1 > y0 else float("nan")


def _mouth_cues(diff: np.ndarray, gray: np.ndarray, face: Box) -> tuple[float, float] | None:
    """(mouth motion minus upper-face motion, clipped at 0; upper-face minus mouth intensity) of
    one face box, from the motion-compensated frame difference ``diff`` and the grey frame; None
    where a region falls outside the frame."""
    m = _mean_in(diff, mouth_box(face)) - _mean_in(diff, upper_box(face))
    cur = gray.astype(np.float32)
    dark = _mean_in(cur, upper_box(face)) - _mean_in(cur, mouth_box(face))
    return (max(m, 0.0), dark) if np.isfinite(m) and np.isfinite(dark) else None


COST_REFERENCE_FPS = REFERENCE_FPS
"""Frame rate at which ``switch_cost`` and ``pause_cost`` count frames of evidence (the rate of the
clips they were set on): a 50 fps clip pays twice as many frames, so a change takes the same
seconds of evidence at any frame rate (before, a 50 fps copy of GRID + restaurant followed the
listener's mouth in the last half second of the other's sentences: share of speaking time on the
speaker 0.77 against 0.93 at 25 fps; 0.86 with this and :data:`..audio.ENVELOPE_MIN_S`)."""


class SpeechDetector(FocusDetector):
    """H_aud (module docstring).

    media: the clip file whose audio is decoded (a video), or None (no audio). audio: an
    AudioTrack given directly (tests), overriding media. faces: the FaceDetector whose tracks
    are scored (shared with H_face). causal: trailing window, no look-ahead.
    min_corr: correlation (of moving averages over MOTION_SMOOTH_S) at which the motion cues of a face the
    mesh does not read score like ``none_score`` (below: less than nobody).
    mouth: 'auto' (face mesh where mediapipe imports, else motion), 'mesh' (required), 'motion'.
    mouth_window_s, mouth_min_activity, mouth_rel_activity (0: off), max_lag_s (0: no lag), lag_mode
    ('curve' or 'sums'), lag_window_corr, lag_margin, lag_min_windows_s (seconds): the face-mesh
    evidence and the per-track lag (module docstring); none_score, switch_cost, voice_weight,
    smooth_s, pause_cost (cost units: a frame of evidence 1 is worth 1), onset_s, commit_s
    (seconds), voice_id_weight: the decision over time (module docstring). mesh_every: read the mouths with the face mesh on every n-th frame (held in
    between: the mesh is the costly part). The motion cues (faces the mesh does not read) score
    their correlation less ``min_corr`` plus ``none_score``; a lone such face, its correlation
    plus ``none_score`` when positive.
    sync: localise without faces by audio-visual synchrony on frames with no face track.
    sync_min_corr: smoothed block correlation the synchrony peak must reach (0..1).
    sync_margin: frames of silence around the voiced segment the synchrony window may use;
    seg_margin: frames around a voiced segment the mouth windows may reach (both frames at 25 fps,
    :mod:`..timebase`: the same seconds at the clip's rate).
    sync_box_frac: side of the speaker's square, as a fraction of the frame width.
    sync_face_gap_s: synchrony is not used within this many seconds after a frame with a face of
    the same shot (the face detector missed a face there: no background block speaks for it).
    """

    name = "speech"

    def __init__(self, faces: FaceDetector, fps: float, n_frames: int, media=None, audio: AudioTrack | None = None,
                 start_frame: int = 0, window_s: float = 1.0, causal: bool = False, min_corr: float = 0.25,
                 sync: bool = True, sync_min_corr: float = 0.3, sync_margin: int = 4, sync_box_frac: float = 0.1,
                 mouth: str = "auto", mouth_window_s: float = 1.0, mouth_min_activity: float = 0.02,
                 max_lag_s: float = 0.2, mouth_rel_activity: float = 0.3, none_score: float = 0.15,
                 switch_cost: float = 8.0, voice_weight: float = 0.7, smooth_s: float = 0.5, pause_cost: float = 2.5,
                 onset_s: float = 0.2, commit_s: float = 0.5, voice_id_weight: float = 1.0,
                 mesh_every: int = 1, motion_weight: float = 0.5, seg_margin: int = 2,
                 sync_face_gap_s: float = 1.0, lag_mode: str = "curve", lag_window_corr: float = 0.4,
                 lag_margin: float = 0.1, lag_min_windows_s: float = 1.0) -> None:
        if mouth not in MOUTH_MODES:
            raise ValueError(f"speech detector: mouth={mouth!r} is not one of {', '.join(MOUTH_MODES)}")
        self.faces = faces
        self.fps = fps
        self.causal = causal
        self.min_corr = min_corr
        self.radius = max(2, int(round(window_s * fps / 2)))
        self.mouth_radius = max(2, int(round(mouth_window_s * fps / 2)))
        self.mouth_min_activity = mouth_min_activity
        self.mouth_rel_activity = mouth_rel_activity
        self.max_lag = max(0, int(round(max_lag_s * fps)))
        if lag_mode not in ("curve", "sums"):
            raise ValueError(f"speech detector: lag_mode={lag_mode!r} is not 'curve' or 'sums'")
        self.lag_mode = lag_mode
        self.lag_window_corr = float(lag_window_corr)
        self.lag_margin = float(lag_margin)
        self.lag_min_windows_s = float(lag_min_windows_s)
        self.none_score = float(none_score)
        # the costs are frames of evidence at COST_REFERENCE_FPS: the same seconds at any frame rate
        per_frame = 1.0 / reference_frames_per_frame(fps)
        self.switch_cost = float(switch_cost) * per_frame
        self.pause_cost = float(pause_cost) * per_frame
        self.onset_frames = max(1, int(round(onset_s * fps)))
        # a correlation needs more frames than a voice onset's: over 3 frames any two mouths reach
        # +-0.9 (causal mode's trailing window at an onset), a tie decided by the order of the faces
        self.min_window = max(3, self.onset_frames + 1)
        self.commit_lag = max(0, int(round(commit_s * fps)))
        self.voice_id_weight = float(voice_id_weight)
        self.voice_weight = float(voice_weight)
        self.smooth = 0 if causal else max(0, int(round(smooth_s * fps)))
        self.mesh_every = max(1, int(mesh_every))
        self.motion_weight = float(motion_weight)
        self.seg_margin = frames_at(max(0, int(seg_margin)), fps, 0)  # frames at 25 fps (timebase)
        self.sync_margin = frames_at(max(0, int(sync_margin)), fps, 0)
        self.mesh = MediaPipeFaces(detect=False) if mouth == "mesh" or (mouth == "auto" and mediapipe_importable()) \
            else None
        self._mesh_required = mouth == "mesh"
        # a frame's evidence needs its window's future; its decision the smoother's too
        self.lookahead_frames = 0 if causal else max(self.radius + (self.sync_margin if sync else 0),
                                                     self.mouth_radius + self.max_lag + self.smooth,
                                                     self.seg_margin + self.max_lag + self.smooth)
        self.sync_min_corr = sync_min_corr
        self.sync_box_frac = sync_box_frac
        self.sync_face_gap = max(0, int(round(sync_face_gap_s * fps)))
        self.synchrony = SynchronyLocaliser(keep_frames=8 * self.radius + 4 * self.sync_margin + 8) if sync else None
        self.audio = audio
        if self.audio is None:
            try:
                if media is None:
                    raise NoAudio("no media file was given")
                samples = decode_audio(media, start_s=start_frame / fps, duration_s=n_frames / fps)
                self.audio = analyse_audio(samples, fps, n_frames)
            except NoAudio as ex:
                self.available = False
                self.unavailable_reason = f"speech detector off: {ex}"
                if media is not None:
                    log.warning("%s; the preset falls back to the other detectors", self.unavailable_reason)
        self._prev: AnalysisFrame | None = None  # the frame before (process only)
        self._mouth: dict[str, dict[int, float]] = {}
        self._open: dict[str, dict[int, float]] = {}  # track -> frame -> face-mesh mouth opening
        self._lag_sums: dict[str, np.ndarray] = {}  # track -> (lags, 6): n, sx, sy, sxx, syy, sxy
        self._lag_curves: dict[str, list] = {}  # track -> [windows, sum of their correlation curves]
        self._mesh_decided: set[int] = set()
        # the decision chain: per scored frame, state (a track id, NOBODY) -> (score of the best
        # path ending in it, relative to the best; the state at the frame before on that path)
        self._chain: dict[int, dict[tuple[str, bool], tuple[float, tuple[str, bool]]]] = {}
        self._scored = -1  # last frame whose evidence is in the chain
        self._emit: dict[int, tuple[dict[tuple[str, bool], float], float, frozenset[str], dict[str, float]]] = {}
        self._voices: dict[str, list] = {}  # track -> [n, sum, sum of squares] of its committed speaking frames' cepstra
        self._committed = -1  # last frame whose decision is final (the chain keeps its state only)
        self._flushed = False
        self._shape: tuple[int, int] = (0, 0)
        self._last = -1
        self._decisions: dict[int, tuple[Box | None, float, str | None]] = {}
        self._seconds = 0.0
        self._speaker_frames = 0
        self._sync_frames = 0

    # -- ingest -----------------------------------------------------------------------------
    measures = True

    def measure(self, frame: AnalysisFrame, prev: AnalysisFrame | None, faces: list[Box]) -> tuple | None:
        """(mouth cues, block energy) of ``frame`` against ``prev``: mouth cues are, per box of
        ``faces`` (in order), (mouth motion minus upper-face motion clipped at 0, upper-face minus
        mouth intensity) or None where a region is empty, or None at the first frame; block
        energy is the synchrony localiser's (None without it or at the first frame)."""
        cur = frame.gray
        mouths = None
        if prev is not None and prev.gray.shape == cur.shape:
            diff = np.abs(cur.astype(np.float32) - align_previous(prev.gray, cur))
            mouths = [_mouth_cues(diff, cur, box) for box in faces]
        energy = None
        if self.synchrony is not None:
            energy = self.synchrony.measure(prev.gray if prev is not None else None, cur, frame.disparity)
        return mouths, energy, self._openings(frame, faces)

    def _openings(self, frame: AnalysisFrame, faces: list[Box]) -> list[float | None] | None:
        """The face mesh's mouth opening per box of ``faces`` (on the native frame when the frame
        carries it), None per face the mesh does not find; None without a mesh."""
        if self.mesh is None or not faces or frame.t % self.mesh_every:
            return None
        image, scale = (frame.native, frame.scale) if frame.native is not None else (frame.rgb, 1.0)
        try:
            return self.mesh.mouths(image, faces, scale)
        except Exception as exc:  # PeopleModelError: mediapipe does not load here
            if self._mesh_required:
                raise
            log.warning("speech detector: no face mesh (%s); who speaks comes from mouth motion", exc)
            self.mesh = None
            return None

    def process(self, t: int, frame: AnalysisFrame) -> None:
        if not self.available:
            return
        start = time.perf_counter()
        measured = self.measure(frame, self._prev, [b for b, _, _ in self.faces.faces_at(t)])
        self._seconds += time.perf_counter() - start
        self.ingest(t, frame, measured)

    def ingest(self, t: int, frame: AnalysisFrame, measured: tuple | None) -> None:
        """Record the mouth cues under the face tracks of frame t (``faces.faces_at(t)``, the
        boxes they were measured in) and the block energy."""
        if not self.available:
            return
        mouths, energy = measured[:2]
        openings = measured[2] if len(measured) > 2 else None
        self._shape = frame.gray.shape
        faces = self.faces.faces_at(t) if mouths is not None or openings is not None else []
        for readings in (mouths, openings):
            if readings is not None and len(faces) != len(readings):
                raise RuntimeError(f"speech detector: {len(readings)} mouth readings for the {len(faces)} faces of "
                                   f"frame {t}; the frame was measured with other face boxes")
        if mouths is not None:
            for (_, _, tid), cues in zip(faces, mouths):
                if tid is not None and cues is not None:
                    self._mouth.setdefault(tid, {})[t] = cues
        if openings is not None:
            for (_, _, tid), value in zip(faces, openings):
                if tid is not None and value is not None:
                    self._open.setdefault(tid, {})[t] = float(value)
        elif self.mesh is not None and self.mesh_every > 1 and t % self.mesh_every:
            for _, _, tid in self.faces.faces_at(t):  # between mesh frames: the last reading holds
                series = self._open.get(tid) if tid is not None else None
                if series and t - 1 in series:
                    series[t] = series[t - 1]
        self._add_lag_pairs(t)
        self._add_lag_window(t)
        if self.synchrony is not None:
            self.synchrony.add(t, frame.gray.shape, energy)
        self._prev = frame
        self._last = t
        # a frame's evidence is complete once its window's last frame is in
        self._advance(t - (0 if self.causal else self.mouth_radius + self.max_lag))
        keep = 4 * self.radius + 4
        for series in self._mouth.values():
            for k in [k for k in series if k < t - keep]:
                del series[k]
        keep = 4 * (self.mouth_radius + self.max_lag) + 4
        for series in self._open.values():
            for k in [k for k in series if k < t - keep]:
                del series[k]

    def _add_lag_window(self, t: int) -> None:
        """Per face track, the correlation curve of the mouth window centred on frame k = t -
        max_lag - mouth_radius (all its shifted openings are in once frame t is; causal mode: the
        window ending at t - max_lag), clipped to its voiced segment +- ``seg_margin``: Pearson of
        the opening shifted by each lag in +-max_lag with the envelope. A window where some lag
        reaches ``lag_window_corr`` (the mouth follows the voice there) is added to the track's
        mean curve (:meth:`track_lag`)."""
        if self.lag_mode != "curve" or self.max_lag <= 0:
            return
        a = self.audio
        k = t - self.max_lag - (0 if self.causal else self.mouth_radius)
        if a is None or k < 1 or k >= len(a.voiced) or not a.voiced[k]:
            return
        s, e = k, k
        while s > 0 and a.voiced[s - 1]:
            s -= 1
        while e + 1 < len(a.voiced) and a.voiced[e + 1] and e + 1 <= k + self.mouth_radius:
            e += 1
        if self.causal:
            lo, hi = max(k - 2 * self.mouth_radius, s - self.seg_margin, 1), k
        else:
            lo, hi = max(k - self.mouth_radius, s - self.seg_margin, 1), min(k + self.mouth_radius, e + self.seg_margin)
        frames = np.arange(lo, min(hi, len(a.envelope) - 1) + 1)
        if len(frames) < self.mouth_radius:  # a short segment: too few syllables to tell lags apart
            return
        env = a.envelope[frames].astype(np.float64)
        env = env - env.mean()
        lags = range(-self.max_lag, self.max_lag + 1)
        first, last = int(frames[0]) - self.max_lag, int(frames[-1]) + self.max_lag
        n = len(frames)
        for tid, series in self._open.items():
            if first not in series or last not in series:
                continue
            row = np.array([series.get(f, np.nan) for f in range(first, last + 1)])
            if not np.isfinite(row).all():
                continue
            shifted = np.lib.stride_tricks.sliding_window_view(row, n)  # (lags, frames): lag -max_lag first
            x = shifted - shifted.mean(axis=1, keepdims=True)
            den = np.sqrt((x * x).sum(axis=1) * (env * env).sum())
            curve = np.where(den > 1e-12, (x @ env) / np.maximum(den, 1e-12), 0.0)  # Pearson per lag
            if curve.max() >= self.lag_window_corr:
                acc = self._lag_curves.setdefault(tid, [0, np.zeros(len(lags))])
                acc[0] += 1
                acc[1] += curve

    def _add_lag_pairs(self, t: int) -> None:
        """Add to each track's lag sums the pairs (opening at k + lag, envelope at k) of voiced
        frame k = t - max_lag, for every lag in +-max_lag (all known once frame t is in; the
        envelope is read at k <= t only, so causal mode stays causal)."""
        a, k = self.audio, t - self.max_lag
        if self.lag_mode != "sums" or a is None or k < 0 or k >= len(a.voiced) or not a.voiced[k]:
            return
        y = float(a.envelope[k])
        lags = range(-self.max_lag, self.max_lag + 1)
        for tid, series in self._open.items():
            sums = self._lag_sums.setdefault(tid, np.zeros((len(lags), 6)))
            for i, lag in enumerate(lags):
                x = series.get(k + lag)
                if x is not None:
                    sums[i] += (1.0, x, y, x * x, y * y, x * y)

    def track_lag(self, tid: str) -> int:
        """The audio-video lag (frames) of face track ``tid``, in +-max_lag (the opening at frame
        k + lag goes with the sound at k). ``lag_mode`` 'curve': the peak of the track's mean
        correlation curve over its windows where the mouth follows the voice (:meth:`_add_lag_window`:
        each window normalised on its own, so the curve is the feed's lip-sync; a chance
        correlation of a listener's mouth, or a syllable repeating, has no consistent lag and
        averages out), once there are ``lag_min_windows_s`` seconds of such windows and the peak
        beats no lag by ``lag_margin``; else 0. 'sums': the one whose opening, shifted by it,
        correlates best with the envelope over the track's voiced history (0 until it has two seconds of voiced frames)."""
        if self.lag_mode == "curve":
            acc = self._lag_curves.get(tid)
            if acc is None or acc[0] < self.lag_min_windows_s * self.fps:
                return 0
            curve = acc[1] / acc[0]
            i = int(np.argmax(curve))
            return i - self.max_lag if curve[i] - curve[self.max_lag] >= self.lag_margin else 0
        sums = self._lag_sums.get(tid)
        if sums is None or sums[self.max_lag, 0] < 2.0 * self.fps:
            return 0
        n, sx, sy, sxx, syy, sxy = sums.T
        n = np.maximum(n, 1.0)
        cov = sxy / n - sx * sy / (n * n)
        den = np.sqrt(np.maximum(sxx / n - (sx / n) ** 2, 0.0) * np.maximum(syy / n - (sy / n) ** 2, 0.0))
        r = np.where(den > 1e-12, cov / np.maximum(den, 1e-12), -1.0)
        return int(np.argmax(r)) - self.max_lag

    # -- decide -----------------------------------------------------------------------------
    def _window(self, t: int, margin: int = 2, radius: int | None = None) -> tuple[int, int] | None:
        """Frames (first, last) of the decision window of voiced frame t (module docstring) of
        ``radius`` frames each side (default: ``window_s``), clipped to its voiced segment +-
        ``margin`` frames; None if t is silent."""
        radius = self.radius if radius is None else radius
        a = self.audio
        if a is None or t >= len(a.voiced) or not a.voiced[t]:
            return None
        s = t
        while s > 0 and a.voiced[s - 1]:
            s -= 1
        e = t
        while e + 1 < len(a.voiced) and a.voiced[e + 1]:
            e += 1
        if self.causal:
            lo, hi = max(t - 2 * radius, s - margin), t
        else:
            lo, hi = max(t - radius, s - margin), min(t + radius, e + margin)
        lo, hi = max(lo, 1), min(hi, self._last)
        return (lo, hi) if hi - lo + 1 >= self.min_window else None

    def flush(self) -> None:
        """End of the clip: the last frames' evidence is taken with the windows they have."""
        self._flushed = True
        self._advance(self._last)

    def _evidence(self, t: int) -> dict[str, float]:
        """Per face track on frame t, its score as the speaker (module docstring); {} when t
        is silent or no face is on it."""
        win = self._window(t, margin=self.seg_margin) if self.available else None
        if win is None:
            return {}
        lo, hi = win
        frames = list(range(lo, hi + 1))
        env = self.audio.envelope[frames].astype(np.float64)
        faces = self.faces.faces_at(t) if self.faces is not None else []
        mwin = self._window(t, margin=self.seg_margin, radius=self.mouth_radius)
        meshed, motion = {}, {}
        for _, _, tid in faces:
            if tid is None:
                continue
            by_mesh = self._mouth_score(tid, mwin) if mwin is not None else None
            r = self._motion_score(tid, frames, env)
            if by_mesh is not None:
                if r is not None and self.motion_weight > 0:
                    by_mesh = ((1.0 - self.motion_weight) * by_mesh[0] + self.motion_weight * r, by_mesh[1])
                meshed[tid] = by_mesh
            elif r is not None:
                motion[tid] = r
        top = max((a for _, a in meshed.values()), default=0.0)
        out = {}
        for tid, (r, act) in meshed.items():
            candidate = act >= self.mouth_min_activity and (self.mouth_rel_activity <= 0 or
                                                             act >= self.mouth_rel_activity * top)
            out[tid] = r if candidate else -1.0
        for tid, r in motion.items():
            lone = len(faces) == 1 and r > 0
            out[tid] = (r + self.none_score) if lone else (r - self.min_corr + self.none_score)
        return out

    def _change_cost(self, t: int, voiced: bool) -> float:
        """Cost of moving the chain from one face (or holding it) to another at frame t: in
        silence and in the first ``onset_frames`` of a voiced segment (a voice onset: turns
        change there) ``pause_cost``; later inside continuous speech ``switch_cost`` times
        ``1 - voice_weight * change`` (the voice change at t, 0..1)."""
        v = self.audio.voiced
        if not voiced:
            return self.pause_cost
        s = t
        while s > 0 and s > t - self.onset_frames and v[s - 1]:
            s -= 1
        if t - s < self.onset_frames and not (s > 0 and v[s - 1]):
            return self.pause_cost
        if self.switch_cost <= 0:
            return 0.0
        change = self.audio.voice_change(t, self.mouth_radius, self.causal) if self.voice_weight > 0 else 0.0
        return self.switch_cost * (1.0 - self.voice_weight * change)

    def _add_voice(self, tid: str, t: int) -> None:
        """Add frame t's cepstrum (``AudioTrack.timbre``) to the voice of face track ``tid``
        (a frame the chain committed to "tid speaks"; silent or unanalysed frames add nothing)."""
        tb = self.audio.timbre
        if tb is None or t >= len(tb) or not self.audio.voiced[t] or not np.isfinite(tb[t]).all():
            return
        x = tb[t].astype(np.float64)
        acc = self._voices.setdefault(tid, [0, np.zeros_like(x), np.zeros_like(x)])
        acc[0] += 1
        acc[1] += x
        acc[2] += x * x

    def _voice_factor(self, tid: str, t: int) -> float:
        """Multiplier (1 .. ``2 ** voice_id_weight``) of the cost of a change to face ``tid`` at
        frame t: ``2 ** (voice_id_weight * max(2 m - 1, 0))``, where m (0..1) is how much the
        voice at t (the cepstra of the half ``mouth_window_s`` after t; causal: up to t) differs from the
        voice ``tid`` was heard with (its committed speaking frames), by the two-sample
        statistic of ``AudioTrack.voice_change`` on the same scale. Another voice than the
        face's own (m > 0.5) makes the change dearer; a similar one is no evidence (on the
        composites different voices often score similar, so it never makes a change cheaper).
        1.0 where unknown: the face not heard yet (fewer than that many frames), fewer
        than 3 voiced frames at t, no cepstra."""
        acc = self._voices.get(tid)
        tb = self.audio.timbre
        half = self.mouth_radius
        if self.voice_id_weight <= 0 or tb is None or acc is None or acc[0] < half:
            return 1.0
        n = len(self.audio.voiced)
        span = range(max(t - half + 1, 0), t + 1) if self.causal else range(t, min(t + half, n))
        xs = tb[[k for k in span if self.audio.voiced[k]]]
        xs = xs[np.isfinite(xs).all(axis=1)]
        if len(xs) < 3:
            return 1.0
        m = min(acc[0], len(xs))  # the profile weighed as a segment of the same length (same scale as voice_change)
        mu = acc[1] / acc[0]
        var = np.maximum(acc[2] / acc[0] - mu * mu, 0.0)
        d = (xs.mean(0) - mu) ** 2 / (xs.var(0) / len(xs) + var / m + 1e-3)
        lo, hi = VOICE_CHANGE_RANGE
        mismatch = float(np.clip((float(d.mean()) - lo) / (hi - lo), 0.0, 1.0))
        return float(2.0 ** (self.voice_id_weight * max(2.0 * mismatch - 1.0, 0.0)))

    def _advance(self, upto: int) -> None:
        """Extend the decision chain (Viterbi forward pass) to frame ``upto``: each frame's
        scores and change cost are computed once (``_emit``), then :meth:`_forward`."""
        if not self.available or self.audio is None:
            return
        upto = min(upto, self._last)
        n_audio = len(self.audio.voiced)
        while self._scored < upto:
            t = self._scored + 1
            self._scored = t
            voiced = t < n_audio and bool(self.audio.voiced[t])
            scores = self._evidence(t) if voiced else {}
            hold = self.none_score if voiced else 0.0
            states: dict[tuple[str, bool], float] = {NOBODY_STATE: hold}
            on_screen = frozenset(tid for _, _, tid in (self.faces.faces_at(t) if self.faces is not None else [])
                                  if tid is not None)
            for tid in sorted(on_screen):  # a fixed order: the chain's ties do not follow string hashing
                states[(tid, True)] = scores.get(tid, -1.0) if voiced else 0.0
                states[(tid, False)] = hold
            factors = {tid: self._voice_factor(tid, t) for tid in on_screen} if voiced else {}
            self._emit[t] = (states, self._change_cost(t, voiced), on_screen, factors)
            self._forward(t)
            for k in [k for k in self._chain if k < t - 12 * self.mouth_radius - 2 * self.smooth - 8]:
                del self._chain[k]
                self._emit.pop(k, None)

    def _forward(self, t: int) -> None:
        """chain[t] from chain[t - 1] and frame t's scores (:meth:`_advance`).

        States (module docstring): NOBODY (no face established yet) and, per face track k on
        the frame, (k, True) "k speaks" (score: its evidence) and (k, False) "k spoke last and
        holds the focus; nobody on screen speaks now" (score ``none_score``). Moving between the
        two states of one face is free, so is leaving a face no longer on screen (into NOBODY
        too); NOBODY is not entered from a face on screen (it stays held); every other move, a
        change of face (from NOBODY too: the first speaker), costs :meth:`_change_cost` times the new face's
        :meth:`_voice_factor`."""
        states, cost, on_screen, factors = self._emit[t]
        prev = self._chain.get(t - 1)
        if not prev:
            self._chain[t] = {state: (e, state) for state, e in states.items()}
            return
        # the best previous state per face, and the best one a move from is free (a face gone)
        per_face: dict[str, tuple[float, tuple[str, bool]]] = {}
        free: tuple[float, tuple[str, bool]] | None = None
        for st, (v, _) in prev.items():
            if st[0] not in per_face or v > per_face[st[0]][0]:
                per_face[st[0]] = (v, st)
            if st[0] != NOBODY and st[0] not in on_screen and (free is None or v > free[0]):
                free = (v, st)
        chain: dict[tuple[str, bool], tuple[float, tuple[str, bool]]] = {}
        for state, e in states.items():
            own = per_face.get(state[0])
            best = own if own is not None else (-np.inf, state)
            if free is not None and free[0] > best[0]:
                best = free
            move = cost * factors.get(state[0], 1.0) if state[0] != NOBODY else np.inf  # a face stays held
            for face, (v, st) in per_face.items():
                if face != state[0] and v - move > best[0]:
                    best = (v - move, st)
            chain[state] = (best[0] + e, best[1])
        top = max(v[0] for v in chain.values())
        self._chain[t] = {k: (v[0] - top, v[1]) for k, v in chain.items()}

    def _speaker_at(self, t: int) -> str | None:
        """The face track the chain says speaks at frame t (None: nobody on screen speaks, or
        not known yet). Decisions become final ``commit_s`` later: the frames up to t minus that
        lag are committed to the best path's states, so a later change of face pays its cost
        from there and the past is not re-decided (a face held through a turn cannot take it
        back in hindsight)."""
        end = t if self.causal else min(t + self.smooth, self._scored)
        if end < t or any(k not in self._chain for k in range(t, end + 1)):
            return None
        state = max(self._chain[end], key=lambda k: self._chain[end][k][0])
        c = t - self.commit_lag
        lo = max(min(t, self._committed + 1), 0) if c > self._committed else t  # back to the last final frame
        path = {end: state}
        for k in range(end, lo, -1):
            if k - 1 not in self._chain:
                lo = k
                break
            path[k - 1] = self._chain[k][path[k]][1]
        if c > self._committed and c >= lo:
            for f in range(max(lo, self._committed + 1), c + 1):
                self._chain[f] = {path[f]: (0.0, self._chain[f][path[f]][1])}
                if path[f][1] and path[f][0] != NOBODY:
                    self._add_voice(path[f][0], f)
            self._committed = c
            for f in range(c + 1, self._scored + 1):
                self._forward(f)
        state = path[t]
        return state[0] if state[1] and state[0] != NOBODY else None

    def turn_start(self, t: int) -> int | None:
        """The first frame (<= t) of the turn the chain gives the face that speaks at frame t
        (:meth:`decide`): back along the best path from the newest frame decision t saw (t +
        ``smooth_s``; causal: t), over the frames on which that face speaks or holds, the earliest
        voiced one on which it speaks. Inside the look-ahead this is the change of face as the chain places
        it with the evidence after the onset too (typically the voice onset), where the decision of
        the onset frame itself, made with less of that evidence, still held the previous face.
        None where t's decision names nobody, or the path has left the face by its newest frame."""
        tid = self.decide(t)[2]
        if tid is None:
            return None
        end = t if self.causal else min(t + self.smooth, self._scored)
        if end not in self._chain:
            return t
        state = max(self._chain[end], key=lambda k: self._chain[end][k][0])
        if state[0] != tid:
            return None
        start, k, voiced = t, end, self.audio.voiced
        while k - 1 in self._chain and state in self._chain[k]:
            prev = self._chain[k][state][1]
            if prev[0] != tid or prev not in self._chain[k - 1]:
                break
            k, state = k - 1, prev
            if state[1] and k < len(voiced) and voiced[k]:
                start = k
        return start

    def decide(self, t: int) -> tuple[Box | None, float, str | None]:
        """(speaker's face box in analysis px or None, its evidence at t, face track id)."""
        if t in self._decisions:
            return self._decisions[t]
        result: tuple[Box | None, float, str | None] = (None, 0.0, None)
        win = self._window(t) if self.available else None
        if win is not None:
            faces = self.faces.faces_at(t) if self.faces is not None else []
            if not faces and self.synchrony is not None and not (
                    self.faces is not None and self.faces.seen_before(t, self.sync_face_gap)):  # a missed face
                result = self._decide_by_synchrony(t)
            if self._flushed or self.causal:
                self._advance(t if self.causal else t + self.smooth)
            tid = self._speaker_at(t)
            if tid is not None:
                box = next(b for b, _, i in faces if i == tid)
                r = self._evidence(t).get(tid, 0.0)
                result = (box, r, tid)
                if tid in self._open and t in self._open[tid]:
                    self._mesh_decided.add(t)
        self._decisions[t] = result
        if len(self._decisions) > 8 * self.radius + 8:
            for k in sorted(self._decisions)[: len(self._decisions) // 2]:
                del self._decisions[k]
        return result

    def _motion_score(self, tid: str | None, frames: list[int], env: np.ndarray) -> float | None:
        """The motion cues' correlation of a track over ``frames`` (``env``: their envelope; the
        cues shifted by the track's lag, :meth:`track_lag`):
        the best of mouth motion with the envelope or its change and darkness with the
        envelope (moving averages over :data:`MOTION_SMOOTH_S`); None with fewer than 3 readings."""
        series = self._mouth.get(tid, {})
        lag = self.track_lag(tid) if tid is not None else 0  # the same feed: the mesh's lag
        ks = [i for i, k in enumerate(frames) if k + lag in series]
        if len(ks) < 3:
            return None
        feats = np.array([series[frames[i] + lag] for i in ks])
        # motion ~ |d opening/dt| follows the envelope's changes; darkness ~ opening follows it
        d_env = np.abs(np.diff(env, prepend=env[0]))
        w = motion_smooth_frames(self.fps)
        return max(_pearson(_smooth(feats[:, 0], w), _smooth(env[ks], w)),
                   _pearson(_smooth(feats[:, 0], w), _smooth(d_env[ks], w)),
                   _pearson(_smooth(feats[:, 1], w), _smooth(env[ks], w)))

    def _mouth_score(self, tid: str | None, win: tuple[int, int]) -> tuple[float, float] | None:
        """(correlation of the track's mouth opening, shifted by its lag, with the envelope over
        the frames of ``win``; standard deviation of that opening), or None when the face mesh
        read the mouth on fewer than 60% of those frames (then the motion cues decide)."""
        series = self._open.get(tid) if tid is not None else None
        if not series:
            return None
        lag = self.track_lag(tid)
        frames = [k for k in range(win[0], win[1] + 1) if 0 <= k < len(self.audio.envelope)]
        ks = [k for k in frames if k + lag in series]
        if len(ks) < max(5, 0.6 * len(frames)):
            return None
        opening = np.array([series[k + lag] for k in ks])
        return _pearson(opening, self.audio.envelope[ks].astype(np.float64)), float(opening.std())

    def _sync_window(self, t: int) -> tuple[int, int] | None:
        """Frames (first, last) of the synchrony window of voiced frame t: its whole voiced
        segment +- ``sync_margin`` frames of silence, at most 2 * radius + 1 + 2 * sync_margin
        frames long (centred on t when longer); causal: ending at t. None if t is silent."""
        seg = self._window(t, margin=0)
        a = self.audio
        if seg is None or a is None:
            return None
        s, e = t, t
        while s > 0 and a.voiced[s - 1]:
            s -= 1
        while e + 1 < len(a.voiced) and a.voiced[e + 1]:
            e += 1
        lo, hi = s - self.sync_margin, e + self.sync_margin
        cap = 2 * self.radius + 2 * self.sync_margin
        if self.causal:
            lo, hi = max(lo, t - cap), t
        elif hi - lo > cap:
            lo = min(max(lo, t - cap // 2), hi - cap)
            hi = lo + cap
        lo, hi = max(lo, 1), min(hi, self._last)
        return (lo, hi) if hi - lo + 1 >= 6 else None

    def _decide_by_synchrony(self, t: int) -> tuple[Box | None, float, str | None]:
        """(square around the synchrony peak or None, peak correlation, None) for voiced t."""
        win = self._sync_window(t)
        if win is None:
            return None, 0.0, None
        frames = list(range(win[0], win[1] + 1))
        env = self.audio.envelope.astype(np.float64)
        feature = np.abs(env[frames] - env[[max(k - 1, 0) for k in frames]])
        corr, _ = self.synchrony.correlate(frames, feature)
        if corr is None:
            return None, 0.0, None
        value, x, y = self.synchrony.peak(corr)
        if value < self.sync_min_corr:
            return None, value, None
        h, w = self.synchrony.shape
        side = self.sync_box_frac * w
        x0, y0 = min(max(x - side / 2, 0.0), max(w - side, 0.0)), min(max(y - side / 2, 0.0), max(h - side, 0.0))
        return (x0, y0, min(side, w), min(side, h)), value, None

    def output(self, t: int) -> DetectorOutput:
        if not self.available:
            return DetectorOutput(None, available=False)
        box, corr, tid = self.decide(t)
        if box is None:
            return DetectorOutput(None)
        self._speaker_frames += 1
        if tid is None:
            self._sync_frames += 1
        boxes = [(box, 1.0, tid)]
        return DetectorOutput(boxes_heat(self._shape, boxes), boxes)

    def metrics(self) -> dict:
        m = {"available": self.available, "s_per_frame": self._seconds / max(self._last + 1, 1),
             "speaker_frames": self._speaker_frames, "synchrony_frames": self._sync_frames,
             "mouth": "mesh" if self.mesh is not None else "motion", "mesh_frames": len(self._mesh_decided),
             "track_lags_frames": {tid: self.track_lag(tid)
                                   for tid in sorted(set(self._lag_sums) | set(self._lag_curves))},
             "track_lag_curves": {tid: [round(float(v), 3) for v in acc[1] / max(acc[0], 1)] + [int(acc[0])]
                                  for tid, acc in sorted(self._lag_curves.items())}}
        if self.audio is not None:
            m["voiced_frames"] = int(self.audio.voiced.sum())
            m["voiced_segments"] = [[int(a), int(b)] for a, b in self.audio.segments()]
        if not self.available:
            m["reason"] = self.unavailable_reason
        return m
