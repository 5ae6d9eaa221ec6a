"""AF-Net's audio input (beyond the paper): a few numbers per video frame that say whether
someone speaks and in what voice.

The paper's AF-Net sees frames only, and on our conversation clips it missed every speaker
change (the mouths are a few pixels at 128x72). With ``AFNetConfig.audio = AUDIO_FEATURES``
the network also gets, for every clip frame ``k`` (the interval ``[k/fps, (k+1)/fps)``):

0. ``level``: RMS in dB relative to the clip's 99th-percentile frame RMS, mapped from
   [-50, 0] dB to [0, 1] (0 also for a clip without sound);
1. ``vad``: the share of WebRTC VAD's 30 ms frames that are voiced (:mod:`rvr_addon.laaf.audio`);
2.-4. ``bands``: the shares of the frame's energy in 80-300, 300-1,000 and 1,000-4,000 Hz (a
   voice's register: who is speaking, without knowing whom);
5. ``onset``: the rise of ``level`` from the previous frame, clipped to [0, 1].

Sound is decoded at 16 kHz mono (:func:`rvr_addon.laaf.audio.decode_audio`), once per clip:
32 kB per second, small next to the frames. A clip without an audio track gets zeros, as the
harness clips without speech were trained with (and, half of the time, a noise floor: see
:func:`noise_features`), so the network does not take silence for a cue of its own.
"""
from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

log = logging.getLogger(__name__)

AUDIO_FEATURES = 6
"""Numbers per video frame (module docstring)."""
LEVEL_RANGE_DB = 50.0
BANDS_HZ = ((80.0, 300.0), (300.0, 1000.0), (1000.0, 4000.0))


def frame_features(samples: np.ndarray, rate: int, fps: float, n_frames: int) -> np.ndarray:
    """(n_frames, AUDIO_FEATURES) float32 features (module docstring) of mono samples in [-1, 1]
    at ``rate`` Hz; frames past the end of the sound are zeros."""
    from ..laaf.audio import analyse_audio

    out = np.zeros((n_frames, AUDIO_FEATURES), np.float32)
    samples = np.asarray(samples, np.float32)
    if n_frames < 1 or samples.size < 16:
        return out
    track = analyse_audio(samples, fps, n_frames, rate=rate)
    rms = track.envelope.astype(np.float64)
    ref = float(np.percentile(rms, 99)) if n_frames else 0.0
    if ref <= 1e-6:  # digital silence
        return out
    db = 20.0 * np.log10(np.maximum(rms, 1e-9) / ref)
    level = np.clip((db + LEVEL_RANGE_DB) / LEVEL_RANGE_DB, 0.0, 1.0)
    out[:, 0] = level
    out[:, 1] = track.vad_fraction
    for k in range(n_frames):
        a, b = int(k / fps * rate), int((k + 1) / fps * rate)
        seg = samples[a:min(b, samples.size)]
        if seg.size < 32 or level[k] <= 0:
            continue
        spec = np.abs(np.fft.rfft(seg * np.hanning(seg.size))) ** 2
        freqs = np.fft.rfftfreq(seg.size, 1.0 / rate)
        bands = np.array([spec[(freqs >= lo) & (freqs < hi)].sum() for lo, hi in BANDS_HZ])
        total = bands.sum()
        if total > 0:
            out[k, 2:5] = bands / total
    out[1:, 5] = np.clip(level[1:] - level[:-1], 0.0, 1.0) * 2.0
    np.clip(out[:, 5], 0.0, 1.0, out=out[:, 5])
    return out


def clip_features(path: str | Path, fps: float, n_frames: int, start_frame: int = 0) -> np.ndarray | None:
    """Features of frames ``start_frame .. start_frame + n_frames - 1`` of a media file's sound;
    None when it has no audio track ffmpeg can decode (the caller uses zeros and says so)."""
    from ..laaf.audio import SAMPLE_RATE, NoAudio, decode_audio

    try:
        samples = decode_audio(path, start_s=start_frame / fps, duration_s=n_frames / fps)
    except NoAudio as ex:
        log.warning("AF-Net audio: %s; its audio input is silence", ex)
        return None
    return frame_features(samples, SAMPLE_RATE, fps, n_frames)


def noise_features(n_frames: int, fps: float, rng: np.random.Generator, rate: int = 16000) -> np.ndarray:
    """Features of a non-speech background: coloured noise with a slow random loudness and,
    sometimes, a few clicks or a hum (traffic, room tone, music-like steadiness), so that a
    network trained with it does not fire on sound that is not a voice starting."""
    n = int(np.ceil(n_frames / fps * rate)) + rate // 10
    spec = np.fft.rfft(rng.standard_normal(n))
    freqs = np.fft.rfftfreq(n, 1.0 / rate)
    spec *= np.maximum(freqs, 20.0) ** (-0.5 * rng.uniform(0.0, 2.0))  # white to brown
    noise = np.fft.irfft(spec, n)
    t = np.arange(n) / rate
    gain = 1.0 + 0.5 * np.sin(2 * np.pi * rng.uniform(0.05, 0.5) * t + rng.uniform(0, 6.3))
    sound = noise * gain
    if rng.random() < 0.3:
        sound += rng.uniform(0.2, 1.0) * np.std(sound) * np.sin(2 * np.pi * rng.choice([50.0, 60.0, 120.0]) * t)
    if rng.random() < 0.3:
        for _ in range(int(rng.integers(1, 5))):
            at = int(rng.integers(0, max(1, n - 400)))
            sound[at:at + 400] += rng.uniform(2, 6) * np.std(sound) * np.exp(-np.arange(min(400, n - at)) / 60.0)
    sound = (sound / (np.abs(sound).max() + 1e-9) * rng.uniform(0.01, 0.5)).astype(np.float32)
    return frame_features(sound, rate, fps, n_frames)


def window(features: np.ndarray | None, centre: int, half: int, width: int = AUDIO_FEATURES) -> np.ndarray:
    """(width, 2 half + 1) float32: the features of frames ``centre - half .. centre + half``
    (columns in time order), zeros outside the clip or without sound."""
    out = np.zeros((width, 2 * half + 1), np.float32)
    if features is None or len(features) == 0:
        return out
    n = len(features)
    lo, hi = centre - half, centre + half + 1
    a, b = max(lo, 0), min(hi, n)
    if a < b:
        out[:, a - lo:b - lo] = features[a:b].T
    return out
