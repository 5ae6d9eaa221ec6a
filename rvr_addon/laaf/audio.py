"""Audio for the speech detector: decode a clip's sound, voice activity, per-frame envelope.

Audio is decoded once per clip with the ffmpeg bundled with imageio-ffmpeg into mono 16-bit
PCM at 16 kHz (32 kB per second of clip, small next to the frames, which stream). Voice
activity comes from WebRTC's VAD (PyPI ``webrtcvad-wheels``) on 30 ms frames, aggressiveness
3, then per video frame: voiced if at least half of the 30 ms VAD frames overlapping it are
voiced and the frame's RMS is within ``gate_db`` (-30 dB) of the clip's 99th-percentile RMS
(WebRTC flags breaths and hiss in near silence); gaps shorter than ``bridge_s`` are closed and
bursts shorter than ``min_s`` dropped. Where ``webrtcvad`` cannot be imported, a pure-numpy
energy and speech-band detector (:func:`energy_vad`) stands in, with a warning.

**Voice characteristic** (for a change of speaker inside continuous speech, issue 23): per video
frame the mean cepstrum (:func:`cepstra`: log mel-band energies of 32 ms windows, 24 bands
100-4000 Hz, DCT coefficients 1-12, i.e. MFCC-like, numpy only) over its loud windows.
:meth:`AudioTrack.voice_change` compares the cepstra of the half second before a frame with
the half second after it (causal: the last two quarter-seconds up to the frame) by a
two-sample statistic per coefficient, mapped to 0..1: near 0 while one voice goes on, near 1
where another voice (pitch, timbre, room) takes over.
"""
from __future__ import annotations

import logging
import subprocess
from dataclasses import dataclass
from pathlib import Path

import numpy as np

log = logging.getLogger(__name__)

SAMPLE_RATE = 16000
VAD_FRAME_S = 0.03
ENVELOPE_MIN_S = 0.04
"""Shortest window (s) of a video frame's RMS envelope: a 25 fps frame. At 50 or 60 fps a frame's
own 17-20 ms of sound is a noisier envelope (its 1 s correlation with the speaker's mouth fell
from 0.5-0.6 to 0.35-0.45 on a 50 fps copy of GRID + restaurant), so the window stays 40 ms,
centred on the frame; at 25 fps and below it is the frame's own span, as before."""
VOICE_CHANGE_RANGE = (6.0, 16.0)
"""Mean squared t-statistic of the cepstra mapped to a voice change of 0 (one voice goes on:
4-6 on real speech, phonemes differ) .. 1 (another voice: 11-17 on the composite clips)."""


class NoAudio(Exception):
    """The clip has no (decodable) audio track; the message says which file."""


def decode_audio(path: str | Path, start_s: float = 0.0, duration_s: float | None = None,
                 rate: int = SAMPLE_RATE) -> np.ndarray:
    """Mono float32 samples in [-1, 1] at ``rate`` Hz of a media file from ``start_s`` (s).

    Raises NoAudio naming the file when it has no audio stream or ffmpeg cannot decode it.
    """
    from ..io.video import ffmpeg_exe

    cmd = [ffmpeg_exe(), "-hide_banner", "-nostdin", "-v", "error"]
    if start_s > 0:
        cmd += ["-ss", f"{start_s:.6f}"]
    cmd += ["-i", str(path), "-map", "0:a:0", "-vn", "-ac", "1", "-ar", str(rate)]
    if duration_s is not None:
        cmd += ["-t", f"{duration_s:.6f}"]
    cmd += ["-f", "s16le", "pipe:1"]
    run = subprocess.run(cmd, capture_output=True, check=False)
    if run.returncode != 0:
        msg = run.stderr.decode("utf-8", "replace").strip().splitlines()
        raise NoAudio(f"'{path}' has no audio track ffmpeg can decode ({msg[-1] if msg else 'no stream'})")
    samples = np.frombuffer(run.stdout, dtype="<i2").astype(np.float32) / 32768.0
    if samples.size == 0:
        raise NoAudio(f"'{path}' has an empty audio track")
    return samples


N_MELS, N_CEPS = 24, 12
MEL_BAND = (100.0, 4000.0)


def _mel_filters(n_fft: int, rate: int, n_mels: int = N_MELS, band=MEL_BAND) -> np.ndarray:
    """(n_mels, n_fft // 2 + 1) triangular mel filters over ``band`` Hz."""
    mel = lambda f: 2595.0 * np.log10(1.0 + f / 700.0)  # noqa: E731
    hz = lambda m: 700.0 * (10 ** (m / 2595.0) - 1.0)  # noqa: E731
    edges = hz(np.linspace(mel(band[0]), mel(band[1]), n_mels + 2))
    freqs = np.fft.rfftfreq(n_fft, 1.0 / rate)
    fb = np.zeros((n_mels, len(freqs)), np.float32)
    for i in range(n_mels):
        lo, mid, hi = edges[i], edges[i + 1], edges[i + 2]
        fb[i] = np.clip(np.minimum((freqs - lo) / (mid - lo), (hi - freqs) / (hi - mid)), 0.0, None)
    return fb


def cepstra(samples: np.ndarray, fps: float, n_frames: int, rate: int = SAMPLE_RATE) -> np.ndarray:
    """(n_frames, N_CEPS) float32: per video frame the mean MFCC-like cepstrum (coefficients
    1..N_CEPS, c0 = loudness left out) of the 32 ms windows (hop 10 ms) it covers whose energy is
    within 30 dB of the loudest; NaN where a frame has none (silence)."""
    n_fft, hop = 512, int(round(0.01 * rate))
    out = np.full((n_frames, N_CEPS), np.nan, np.float32)
    if len(samples) < n_fft:
        return out
    n_win = 1 + (len(samples) - n_fft) // hop
    idx = np.arange(n_fft)[None, :] + hop * np.arange(n_win)[:, None]
    power = np.abs(np.fft.rfft(samples[idx].astype(np.float32) * np.hanning(n_fft).astype(np.float32), axis=1)) ** 2
    bands = power @ _mel_filters(n_fft, rate).T
    energy = bands.sum(axis=1)
    loud = energy >= float(np.max(energy)) * 1e-3 if n_win else energy > 0
    logb = np.log(bands + 1e-10)
    k = np.arange(N_MELS)
    dct = np.cos(np.pi / N_MELS * (k[None, :] + 0.5) * np.arange(1, N_CEPS + 1)[:, None])
    ceps = logb @ dct.T
    centre = (np.arange(n_win) * hop + n_fft / 2) / rate
    frame = np.floor(centre * fps).astype(np.int64)
    for f in range(n_frames):
        sel = (frame == f) & loud
        if sel.any():
            out[f] = ceps[sel].mean(axis=0)
    return out


@dataclass
class AudioTrack:
    """Per video frame: voiced (bool), envelope (RMS, linear), vad_fraction (0..1) and, when
    the samples were analysed, the voice characteristic ``timbre`` ((n, N_CEPS) cepstra, NaN in
    silence; None: unknown, no voice changes are reported)."""

    voiced: np.ndarray
    envelope: np.ndarray
    vad_fraction: np.ndarray
    fps: float
    timbre: np.ndarray | None = None

    def voice_change(self, t: int, half: int, causal: bool = False) -> float:
        """0..1: how much the voice at frame t differs from the voice just before it (module
        docstring). Look-ahead: frames [t - half, t) against [t, t + half); causal: [t - half,
        t - half // 2) against [t - half // 2, t] (only the past). Voiced frames only; 0 with
        fewer than 3 voiced frames on a side or without ``timbre``."""
        if self.timbre is None:
            return 0.0
        n = len(self.voiced)
        if causal:
            q = max(half // 2, 2)
            a, b = range(max(t - 2 * q, 0), max(t - q, 0)), range(max(t - q, 0), min(t + 1, n))
        else:
            a, b = range(max(t - half, 0), t), range(t, min(t + half, n))
        xa = self.timbre[[k for k in a if self.voiced[k]]]
        xb = self.timbre[[k for k in b if self.voiced[k]]]
        xa, xb = xa[np.isfinite(xa).all(axis=1)], xb[np.isfinite(xb).all(axis=1)]
        if len(xa) < 3 or len(xb) < 3:
            return 0.0
        d = (xa.mean(0) - xb.mean(0)) ** 2 / (xa.var(0) / len(xa) + xb.var(0) / len(xb) + 1e-3)
        lo, hi = VOICE_CHANGE_RANGE
        return float(np.clip((float(d.mean()) - lo) / (hi - lo), 0.0, 1.0))

    def segments(self) -> list[tuple[int, int]]:
        """Voiced runs as (first frame, last frame) inclusive."""
        v = np.concatenate([[False], self.voiced, [False]]).astype(np.int8)
        d = np.diff(v)
        return list(zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1) - 1))


def _close_gaps(flags: np.ndarray, max_gap: int, min_run: int) -> np.ndarray:
    out = flags.copy()
    n = len(out)
    idx = np.flatnonzero(out)
    if idx.size:
        for a, b in zip(idx[:-1], idx[1:]):
            if 1 < b - a <= max_gap + 1:
                out[a:b] = True
    v = np.concatenate([[False], out, [False]]).astype(np.int8)
    d = np.diff(v)
    for s, e in zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1)):
        if e - s < min_run:
            out[s:e] = False
    return out[:n]


def energy_vad(samples: np.ndarray, rate: int = SAMPLE_RATE, hop: int | None = None,
               band: tuple[float, float] = (300.0, 3400.0), share: float = 0.5, gate_db: float = -35.0) -> np.ndarray:
    """Voice activity per 30 ms frame without WebRTC (pure numpy; the fallback where ``webrtcvad``
    is not importable): a frame is voiced when its energy is within ``gate_db`` of the clip's
    95th-percentile frame and at least ``share`` of it lies in the speech ``band`` (Hz), which
    rejects hum and hiss. Coarser than WebRTC's model; :func:`analyse_audio`'s loudness gate and
    gap closing apply on top. Returns (n_frames,) bool."""
    hop = hop or int(round(VAD_FRAME_S * rate))
    n = len(samples) // hop
    if n == 0:
        return np.zeros(0, bool)
    frames = samples[:n * hop].reshape(n, hop).astype(np.float32) * np.hanning(hop).astype(np.float32)
    power = np.abs(np.fft.rfft(frames, axis=1)) ** 2
    freqs = np.fft.rfftfreq(hop, 1.0 / rate)
    total = power.sum(axis=1) + 1e-12
    in_band = power[:, (freqs >= band[0]) & (freqs <= band[1])].sum(axis=1) / total
    loud = total >= float(np.percentile(total, 95)) * 10 ** (gate_db / 10)
    return (in_band >= share) & loud


def webrtc_available() -> bool:
    """Whether WebRTC's VAD (``webrtcvad``, PyPI ``webrtcvad-wheels``) can be imported."""
    import importlib.util

    return importlib.util.find_spec("webrtcvad") is not None


def analyse_audio(samples: np.ndarray, fps: float, n_frames: int, rate: int = SAMPLE_RATE,
                  aggressiveness: int = 3, bridge_s: float = 0.05, min_s: float = 0.08,
                  gate_db: float = -30.0) -> AudioTrack:
    """Voice activity and envelope per video frame (frame k covers [k/fps, (k+1)/fps) s; its
    envelope, the RMS, is taken over at least :data:`ENVELOPE_MIN_S` centred on the frame).
    Without ``webrtcvad`` the voice activity comes from :func:`energy_vad`, with a warning."""
    hop = int(round(VAD_FRAME_S * rate))
    pcm = (np.clip(samples, -1, 1) * 32767).astype("<i2")
    n_vad = len(pcm) // hop
    if webrtc_available():
        import webrtcvad

        vad = webrtcvad.Vad(int(aggressiveness))
        flags = np.zeros(n_vad, bool)
        for i in range(n_vad):
            flags[i] = vad.is_speech(pcm[i * hop:(i + 1) * hop].tobytes(), rate)
    else:
        log.warning("voice activity from the energy fallback: webrtcvad is not installed (pip install "
                    "webrtcvad-wheels==2.0.14.post1; the Blender extension bundles it for linux-x64)")
        flags = energy_vad(samples, rate, hop)
    frac = np.zeros(n_frames, np.float32)
    env = np.zeros(n_frames, np.float32)
    for k in range(n_frames):
        a, b = k / fps, (k + 1) / fps
        i0, i1 = int(np.floor(a / VAD_FRAME_S)), int(np.ceil(b / VAD_FRAME_S))
        sel = flags[i0:min(i1, n_vad)]
        frac[k] = float(sel.mean()) if sel.size else 0.0
        c, half = (a + b) / 2, max((b - a) / 2, ENVELOPE_MIN_S / 2)  # at least 40 ms at any frame rate
        s0, s1 = max(int(round((c - half) * rate)), 0), int(round((c + half) * rate))
        seg = samples[s0:min(s1, len(samples))]
        env[k] = float(np.sqrt(np.mean(seg * seg))) if seg.size else 0.0
    loud = env >= float(np.percentile(env, 99)) * 10 ** (gate_db / 20) if n_frames else env > 0
    voiced = _close_gaps((frac >= 0.5) & loud, int(round(bridge_s * fps)), max(1, int(round(min_s * fps))))
    return AudioTrack(voiced, env, frac, fps, cepstra(samples, fps, n_frames, rate))
