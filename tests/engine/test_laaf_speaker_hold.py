"""Focus that holds (issue 23): the speech detector's decision chain on constructed evidence.

The per-frame evidence (each face's voice-to-mouth correlation) is given directly, so what is
tested is the decision over time: a change of face costs (the held face keeps the focus while
nobody on screen explains the voice), the past is not re-decided in hindsight, a clear new
speaker at a voice onset is taken at the onset, and a change to a face whose known voice is
not the one heard is dearer.
"""
from __future__ import annotations

import numpy as np
import pytest

from rvr_addon.laaf.audio import N_CEPS, AudioTrack
from rvr_addon.laaf.detectors.base import AnalysisFrame
from rvr_addon.laaf.detectors.face import FaceDetector
from rvr_addon.laaf.detectors.speech import SpeechDetector

FPS = 25.0
BOXES = {"A": (40.0, 40.0, 30.0, 30.0), "B": (130.0, 40.0, 30.0, 30.0)}


class FixedFaces(FaceDetector):
    """Two known face tracks on every frame."""

    def __init__(self):
        pass

    def faces_at(self, t):
        return [(b, 1.0, tid) for tid, b in BOXES.items()]


def audio(n: int, voiced_runs, voices=None) -> AudioTrack:
    """An AudioTrack voiced on ``voiced_runs`` [(first, last)], flat envelope; ``voices``:
    [(first, last, mean)] cepstra around a mean per stretch (None: no cepstra)."""
    voiced = np.zeros(n, bool)
    for a, b in voiced_runs:
        voiced[a:b + 1] = True
    timbre = None
    if voices is not None:
        rng = np.random.default_rng(0)
        timbre = np.full((n, N_CEPS), np.nan, np.float32)
        for a, b, mu in voices:
            timbre[a:b + 1] = mu + rng.normal(0.0, 1.0, (b - a + 1, N_CEPS))
        timbre[~voiced] = np.nan
    return AudioTrack(voiced, voiced.astype(np.float32), voiced.astype(np.float32), FPS, timbre)


def decide_all(evidence: dict[str, np.ndarray], track: AudioTrack, causal: bool = False, upto: int | None = None):
    """Run the chain on per-frame evidence {track: scores} (instead of measured mouths) the way
    LAAF does (each frame decided once its look-ahead is in); returns (detector, decided track
    id or None per frame)."""
    n = len(track.voiced)
    det = SpeechDetector(FixedFaces(), FPS, n, audio=track, causal=causal, sync=False, mouth="motion")
    det._evidence = lambda t: {k: float(v[t]) for k, v in evidence.items()} if track.voiced[t] else {}
    frame = AnalysisFrame(0, np.zeros((120, 200, 3), np.uint8), np.zeros((120, 200), np.uint8), None, 1.0, FPS)
    decided: dict[int, str | None] = {}
    stop = n if upto is None else upto
    for t in range(stop):
        frame.t = t
        det.ingest(t, frame, (None, None, None))
        k = t - det.lookahead_frames
        if k >= 0:
            decided[k] = det.decide(k)[2]
    if upto is None:
        det.flush()
        for k in range(max(0, n - det.lookahead_frames), n):
            decided[k] = det.decide(k)[2]
    return det, decided


@pytest.mark.parametrize("causal", [False, True], ids=["lookahead", "causal"])
def test_a_muted_mouth_moving_with_the_end_of_the_others_sentence_does_not_take_the_focus(causal):
    """A speaks, then B (a short turn after a pause); at the end of B's sentence B's mouth no
    longer follows its voice and A's (muted) mouth correlates strongly by chance for half a
    second, the same voice going on. Cheaper than a change inside continuous speech, and
    cheaper than the hindsight path "A held through B's turn" would be: the focus stays on B."""
    n = 160
    a, b = np.zeros(n), np.zeros(n)
    a[10:60] = 0.5
    b[80:110] = 0.35
    a[110:122], b[110:122] = 0.7, -0.3  # the chance correlation at the end of B's sentence
    b[122:150] = 0.35
    _, decided = decide_all({"A": a, "B": b}, audio(n, [(10, 59), (80, 149)]), causal)
    assert all(decided[t] != "A" for t in range(80, n)), [t for t in range(80, n) if decided[t] == "A"]
    assert sum(decided[t] == "B" for t in range(85, 110)) >= 15  # causal: from the 12th frame of the turn
    assert sum(decided[t] == "A" for t in range(20, 60)) >= 35


def test_a_clear_new_speaker_after_a_pause_is_taken_at_the_voice_onset():
    n = 140
    a, b = np.zeros(n), np.zeros(n)
    a[10:60] = 0.5
    b[80:130] = 0.5
    _, decided = decide_all({"A": a, "B": b}, audio(n, [(10, 59), (80, 129)]))
    assert decided[80] == "B" and all(decided[t] == "B" for t in range(80, 125))
    _, late = decide_all({"A": a, "B": b}, audio(n, [(10, 59), (80, 129)]), causal=True)
    first = next(t for t in range(80, n) if late[t] == "B")
    assert 80 < first <= 95  # causal: known only after the evidence, still taken in the turn


def test_a_weak_voice_after_a_pause_leaves_the_focus_where_it_is():
    """Off-screen speech: a voice after a pause that the held face's still mouth does not utter
    and the other face's mouth follows only weakly (just above "nobody"): nobody on screen
    speaks, the focus holds (no frame goes to B)."""
    n = 140
    a, b = np.full(140, -1.0), np.zeros(n)
    a[10:60] = 0.5
    b[80:130] = 0.2
    _, decided = decide_all({"A": a, "B": b}, audio(n, [(10, 59), (80, 129)]))
    assert all(decided[t] != "B" for t in range(n))
    assert all(decided[t] is None for t in range(80, 130))


def test_a_change_to_a_face_whose_voice_is_not_the_one_heard_is_dearer():
    """A was heard with one voice; later another voice speaks: a change to A costs up to
    2 ** voice_id_weight more; B (not heard yet) costs the plain price."""
    n = 140
    mu1, mu2 = np.zeros(N_CEPS), np.full(N_CEPS, 3.0)
    a, b = np.zeros(n), np.zeros(n)
    a[10:60] = 0.5
    track = audio(n, [(10, 59), (80, 129)], voices=[(10, 59, mu1), (80, 129, mu2)])
    det, _ = decide_all({"A": a, "B": b}, track, upto=100)
    assert det._voices["A"][0] >= 25  # A's voice: its committed speaking frames
    assert det._voice_factor("A", 82) == pytest.approx(2.0 ** det.voice_id_weight)
    assert det._voice_factor("B", 82) == 1.0
    assert det._voice_factor("A", 30) == 1.0  # its own voice: the plain price, never cheaper


def test_the_turn_of_a_new_speaker_starts_at_the_voice_onset_the_chain_sees_in_hindsight():
    """B answers after a pause with moderate evidence (0.3 against "nobody"'s 0.15): the chain
    needs more than its smoother's half second of it, so the onset frame's own decision still
    holds A and B is named a few frames into the turn; ``turn_start`` of that frame, read from
    the best path with the evidence after the onset, is the onset itself (what lets LAAF's
    pull land before the voice, ``lookahead._turn_step``). Causal mode has no such hindsight
    beyond the frames decided."""
    n = 150
    a, b = np.zeros(n), np.zeros(n)
    a[10:60] = 0.5
    b[70:130] = 0.3
    track = audio(n, [(10, 59), (70, 129)])
    det = SpeechDetector(FixedFaces(), FPS, n, audio=track, sync=False, mouth="motion")
    det._evidence = lambda t: {"A": float(a[t]), "B": float(b[t])} if track.voiced[t] else {}
    frame = AnalysisFrame(0, np.zeros((120, 200, 3), np.uint8), np.zeros((120, 200), np.uint8), None, 1.0, FPS)
    named, starts = {}, {}
    for t in range(n):
        frame.t = t
        det.ingest(t, frame, (None, None, None))
        k = t - det.lookahead_frames
        if k >= 0:
            named[k] = det.decide(k)[2]
            starts[k] = det.turn_start(k)
    first = next(k for k in range(70, n) if named[k] == "B")
    assert 70 < first < 90  # the onset frame's own decision did not name B yet
    assert starts[first] == 70  # ... but the turn it names starts at the onset
    assert all(starts[k] == 70 for k in range(first, n - det.lookahead_frames))
    assert starts[30] == 10 and starts[65] is None  # A's turn from its onset; a pause names nobody
