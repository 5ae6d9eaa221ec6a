"""The pure-numpy voice activity fallback (rvr_addon.laaf.audio.energy_vad): what the
Conversation preset uses where webrtcvad cannot be imported."""
from __future__ import annotations

import numpy as np

from rvr_addon.laaf import audio

RATE = audio.SAMPLE_RATE


def _voice(seconds: float, f0: float = 140.0) -> np.ndarray:
    """A voiced-speech stand-in: harmonics of f0 shaped by two formants (700 and 1,200 Hz)."""
    t = np.arange(int(seconds * RATE)) / RATE
    out = np.zeros_like(t)
    for k in range(1, 30):
        f = k * f0
        gain = np.exp(-((f - 700) / 250) ** 2) + 0.7 * np.exp(-((f - 1200) / 300) ** 2) + 0.02
        out += gain * np.sin(2 * np.pi * f * t + k)
    return (0.3 * out / np.abs(out).max()).astype(np.float32)


def test_energy_vad_flags_voice_not_hum_or_silence():
    hum = (0.3 * np.sin(2 * np.pi * 60 * np.arange(RATE) / RATE)).astype(np.float32)
    clip = np.concatenate([np.zeros(RATE, np.float32), _voice(1.0), hum])
    flags = audio.energy_vad(clip)
    n = len(flags) // 3
    assert flags[:n].mean() == 0.0
    assert flags[n:2 * n].mean() > 0.9
    assert flags[2 * n:].mean() < 0.1


def test_analyse_audio_without_webrtcvad_falls_back_with_a_warning(monkeypatch, caplog):
    monkeypatch.setattr(audio, "webrtc_available", lambda: False)
    clip = np.concatenate([np.zeros(RATE // 2, np.float32), _voice(1.0), np.zeros(RATE // 2, np.float32)])
    with caplog.at_level("WARNING", logger=audio.__name__):
        track = audio.analyse_audio(clip, 24.0, 48)
    assert "webrtcvad" in caplog.text
    assert track.segments() and all(10 <= a and b <= 38 for a, b in track.segments())
    assert track.voiced[14:34].all() and not track.voiced[:10].any()
