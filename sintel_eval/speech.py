"""Speech track of the "conversation" script: espeak-ng voices, turn timing from the audio,
mouth opening from each speaker's envelope (no bpy).

Times are seconds from the start of the clip; frame k (1-based) shows the interval
``[(k - 1) / fps, k / fps)``. Audio is mono float32 in [-1, 1] at ``SAMPLE_RATE`` Hz.
"""
from __future__ import annotations

import os
import shutil
import subprocess
import tempfile
import wave
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from rvr_addon.errors import InputError, OutputError
from rvr_addon.io.paths import temp_sibling

SAMPLE_RATE = 22050  # espeak-ng's native rate
VOICES = ("en-us+m3", "en-gb+f3", "en-us+f4", "en-gb-scotland+m1")
PITCHES = (40, 60, 70, 35)
WORDS_PER_MINUTE = 185
LINES = (
    "Hey, over here.", "Did you see that?", "Look at the lights.", "Not yet.", "Wait for me.",
    "It is late.", "Sure, let's go.", "I think so.", "Right behind you.", "What a night.",
    "Hold on.", "Come and see.", "Where were you?", "Just in time.", "Listen.", "Over there.",
    "Really?", "Of course.", "Not now.", "Let's dance.",
)
HOP_S = 0.010  # envelope hop
VAD_THRESHOLD_DB = -32.0  # voiced: envelope above this, relative to the speaker's peak
VAD_BRIDGE_S = 0.25  # gaps shorter than this inside a turn (between words) are bridged
VAD_MIN_S = 0.06  # shorter voiced bursts are ignored
SHORTEST_REPLY_S = 0.6  # about the shortest line ("Listen.", "Not yet.") at WORDS_PER_MINUTE


class SpeechUnavailable(InputError):
    """espeak-ng is not installed."""


def espeak_path() -> str:
    """Path of the espeak-ng executable; raises SpeechUnavailable with the fix."""
    exe = shutil.which("espeak-ng")
    if exe is None:
        raise SpeechUnavailable(
            "espeak-ng is not installed, so the 'conversation' script cannot make its speech track: "
            "run scripts/setup.sh as root (it runs 'apt-get install -y espeak-ng'), or choose "
            "--script random|enter|start-moving")
    return exe


def synthesize(text: str, voice: str, pitch: int = 50, wpm: int = WORDS_PER_MINUTE) -> np.ndarray:
    """Speak ``text`` with espeak-ng; returns mono float32 samples at SAMPLE_RATE, silence trimmed."""
    exe = espeak_path()
    with tempfile.TemporaryDirectory(prefix="rvr_speech_") as tmp:
        wav = Path(tmp) / "line.wav"
        cmd = [exe, "-v", voice, "-s", str(int(wpm)), "-p", str(int(pitch)), "-w", str(wav), text]
        done = subprocess.run(cmd, capture_output=True, text=True)
        if done.returncode != 0 or not wav.is_file():
            raise OutputError(f"espeak-ng failed for voice '{voice}' ({' '.join(cmd)}): {done.stderr.strip()}; "
                              "check that the voice exists ('espeak-ng --voices=en')")
        samples, rate = read_wav(wav)
    if rate != SAMPLE_RATE:
        raise OutputError(f"espeak-ng wrote {rate} Hz audio, expected {SAMPLE_RATE} Hz")
    segments = voice_activity(samples, rate)
    if not segments:
        raise OutputError(f"espeak-ng produced silence for '{text}' with voice '{voice}'")
    a, b = int(segments[0][0] * rate), int(segments[-1][1] * rate)
    return samples[a:b].copy()


def envelope(samples: np.ndarray, rate: int = SAMPLE_RATE, hop_s: float = HOP_S) -> np.ndarray:
    """RMS envelope, one value per ``hop_s`` seconds (window = 2 hops, centred)."""
    hop = max(int(round(hop_s * rate)), 1)
    n = int(np.ceil(len(samples) / hop))
    padded = np.zeros(n * hop + hop, dtype=np.float64)
    padded[hop // 2:hop // 2 + len(samples)] = samples
    sq = padded ** 2
    frames = sq[: n * hop].reshape(n, hop).mean(axis=1)
    nxt = sq[hop: hop + n * hop].reshape(n, hop).mean(axis=1)
    return np.sqrt(0.5 * (frames + nxt)).astype(np.float32)


def voice_activity(samples: np.ndarray, rate: int = SAMPLE_RATE, threshold_db: float = VAD_THRESHOLD_DB,
                   bridge_s: float = VAD_BRIDGE_S, min_s: float = VAD_MIN_S, reference: float | None = None
                   ) -> list[tuple[float, float]]:
    """Voiced segments [(start_s, end_s)] from the waveform envelope.

    A hop is voiced when its RMS exceeds ``threshold_db`` relative to ``reference`` (default:
    the envelope's peak); gaps shorter than ``bridge_s`` are bridged, bursts shorter than
    ``min_s`` dropped.
    """
    env = envelope(samples, rate)
    peak = float(env.max()) if reference is None else float(reference)
    if peak <= 0:
        return []
    voiced = env > peak * 10.0 ** (threshold_db / 20.0)
    segments: list[list[float]] = []
    for i in np.flatnonzero(voiced):
        t0, t1 = i * HOP_S, (i + 1) * HOP_S
        if segments and t0 - segments[-1][1] < bridge_s:
            segments[-1][1] = t1
        else:
            segments.append([t0, t1])
    duration = len(samples) / rate
    return [(max(a, 0.0), min(b, duration)) for a, b in segments if b - a >= min_s]


def read_wav(path: Path) -> tuple[np.ndarray, int]:
    """16-bit PCM WAV -> (mono float32 samples in [-1, 1], rate)."""
    try:
        with wave.open(str(path), "rb") as w:
            rate, channels, width = w.getframerate(), w.getnchannels(), w.getsampwidth()
            data = w.readframes(w.getnframes())
    except (OSError, wave.Error, EOFError) as exc:
        raise InputError(f"cannot read WAV '{path}': {exc}; re-generate the clip (--force)") from exc
    if width != 2:
        raise InputError(f"WAV '{path}' has {8 * width}-bit samples; expected 16-bit PCM")
    x = np.frombuffer(data, dtype="<i2").astype(np.float32) / 32768.0
    return x.reshape(-1, channels).mean(axis=1), rate


def write_wav(path: Path, samples: np.ndarray, rate: int = SAMPLE_RATE) -> None:
    """Mono float samples -> 16-bit PCM WAV, written atomically."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = temp_sibling(path, ".tmp.wav")
    pcm = (np.clip(samples, -1.0, 1.0) * 32767.0).round().astype("<i2")
    try:
        with wave.open(str(tmp), "wb") as w:
            w.setnchannels(1)
            w.setsampwidth(2)
            w.setframerate(rate)
            w.writeframes(pcm.tobytes())
        os.replace(tmp, path)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise OutputError(f"cannot write '{path}': {exc}; check free disk space and write permission") from exc


@dataclass
class Turn:
    """One speaker's turn, measured from that speaker's track: seconds and the first frame."""

    speaker: str
    start_s: float
    end_s: float
    text: str
    start_frame: int
    end_frame: int


@dataclass
class Conversation:
    """The speech of a clip. tracks: speaker -> float32 samples on the clip timeline (mono,
    SAMPLE_RATE); mix: their sum, peak-normalised; turns in time order; mouth: speaker ->
    (frames,) opening in [0, 1] per frame; voices: speaker -> espeak-ng voice."""

    speakers: list[str]
    tracks: dict[str, np.ndarray]
    mix: np.ndarray
    turns: list[Turn]
    mouth: dict[str, np.ndarray]
    voices: dict[str, str]
    lines: list[dict] = field(default_factory=list)

    def write(self, folder: Path) -> dict[str, Path]:
        """Write ``speech.wav`` and ``<speaker>.wav`` into ``folder``; returns their paths."""
        paths = {"speech": Path(folder) / "speech.wav"}
        write_wav(paths["speech"], self.mix)
        for name in self.speakers:
            paths[name] = Path(folder) / f"{name}.wav"
            write_wav(paths[name], self.tracks[name])
        return paths


def plan_conversation(speakers: list[str], frames: int, fps: float, rng: np.random.Generator) -> Conversation:
    """Alternating turns of espeak-ng lines that fit in the clip, one voice per speaker.

    Turns follow a random order without a speaker talking twice in a row; each line is
    synthesised, placed after a short pause, and the turn times are then measured back from
    each speaker's own track with :func:`voice_activity` (so they are timed from the audio).
    Raises InputError when the clip is too short for two turns.
    """
    if len(speakers) < 2:
        raise InputError("a conversation needs at least two speakers")
    duration = frames / float(fps)
    n_total = int(round(duration * SAMPLE_RATE))
    voices = {s: VOICES[i % len(VOICES)] for i, s in enumerate(speakers)}
    pitch = {s: PITCHES[i % len(PITCHES)] for i, s in enumerate(speakers)}
    tracks = {s: np.zeros(n_total, dtype=np.float32) for s in speakers}
    order = list(rng.permutation(len(LINES)))
    t = float(rng.uniform(0.08, 0.25))
    last: str | None = None
    lines: list[dict] = []
    cache: dict[tuple[str, str], np.ndarray] = {}
    while order:
        choices = [s for s in speakers if s != last]
        speaker = choices[int(rng.integers(len(choices)))]
        room = duration - t - 0.04
        placed = False
        for k, idx in enumerate(order):  # the first line (in seeded order) that still fits
            text = LINES[idx]
            key = (speaker, text)
            if key not in cache:
                cache[key] = synthesize(text, voices[speaker], pitch[speaker])
            audio = cache[key]
            # the first line must leave room for a pause and a short answer (two turns at least)
            reserve = 0.4 + SHORTEST_REPLY_S if not lines else 0.0
            if len(audio) / SAMPLE_RATE + reserve <= room:
                a = int(round(t * SAMPLE_RATE))
                tracks[speaker][a:a + len(audio)] += audio[: n_total - a]
                lines.append({"speaker": speaker, "text": text, "placed_s": t})
                t += len(audio) / SAMPLE_RATE + float(rng.uniform(0.18, 0.4))
                order.pop(k)
                placed = True
                break
            if k >= 5 and len(lines) >= 2:  # later slots try a few lines, not all
                break
        if not placed:
            break
        last = speaker
    if len(lines) < 2:
        need = int(np.ceil(2.0 * fps))
        raise InputError(f"--frames {frames} is too short for a conversation at {fps:g} fps: two spoken "
                         f"turns need about {need} frames; use --frames {need} or more")

    peak = max(float(np.abs(tr).max()) for tr in tracks.values())
    gain = 0.9 / peak if peak > 0 else 1.0
    tracks = {s: tr * gain for s, tr in tracks.items()}
    mix = np.clip(sum(tracks.values()), -1.0, 1.0).astype(np.float32)

    turns: list[Turn] = []
    for speaker in speakers:
        for a, b in voice_activity(tracks[speaker], SAMPLE_RATE, reference=float(envelope(tracks[speaker]).max())):
            turns.append(Turn(speaker, a, b, "", int(np.floor(a * fps)) + 1, min(int(np.floor(b * fps)) + 1, frames)))
    turns.sort(key=lambda tr: tr.start_s)
    for turn in turns:  # attach the text of the line placed nearest to the measured start
        best = min(lines, key=lambda ln: abs(ln["placed_s"] - turn.start_s) + (ln["speaker"] != turn.speaker) * 99)
        turn.text = best["text"]
    mouth = {s: mouth_opening(tracks[s], frames, fps) for s in speakers}
    return Conversation(list(speakers), tracks, mix, turns, mouth, voices, lines)


def mouth_opening(track: np.ndarray, frames: int, fps: float, rate: int = SAMPLE_RATE) -> np.ndarray:
    """Per-frame mouth opening in [0, 1] from a speaker's envelope: the RMS over each frame's
    interval, relative to the 90th percentile of the speaker's voiced frames; 0 when silent."""
    out = np.zeros(frames, dtype=np.float32)
    rms = np.zeros(frames, dtype=np.float64)
    for k in range(frames):
        a, b = int(k / fps * rate), int((k + 1) / fps * rate)
        seg = track[a:b]
        rms[k] = float(np.sqrt(np.mean(seg.astype(np.float64) ** 2))) if len(seg) else 0.0
    peak = float(rms.max())
    if peak <= 0:
        return out
    voiced = rms > peak * 10.0 ** (VAD_THRESHOLD_DB / 20.0)
    if not voiced.any():
        return out
    ref = float(np.percentile(rms[voiced], 90))
    out[voiced] = np.clip(rms[voiced] / ref, 0.0, 1.0)
    return out
