"""AF-Net's audio input (beyond the paper): the features, growing shipped weights, streaming,
and a network that finds a New Focus Target it can only hear."""
from __future__ import annotations

import json
import subprocess
import wave

import cv2
import numpy as np
import pytest
import torch

from afnet_synth import BOX_A, frames_of, one_thread, tiny_config  # noqa: F401 - one_thread: autouse fixture
from rvr_addon.afnet.annotations import AnnotatedClip, Annotation, write_annotations
from rvr_addon.afnet.audio_features import AUDIO_FEATURES, frame_features, noise_features, window
from rvr_addon.afnet.infer import AFNetStream, load_afnet, predict_clip
from rvr_addon.afnet.model import AFNet, decode_frames, encode_frame, grow_state_dict, unit_audio_of
from rvr_addon.afnet.train import AFNetTrainer, AFNetTrainSettings
from rvr_addon.errors import InputError
from rvr_addon.io.video import ffmpeg_exe

RATE = 16000
FPS = 24.0


def voice(n_frames: int, start: int | None, seconds: float = 0.6, f0: float = 140.0, seed: int = 0) -> np.ndarray:
    """Silence with a vowel-like sound (harmonics of f0, syllable-rate tremolo) from frame ``start``."""
    rng = np.random.default_rng(seed)
    out = (rng.standard_normal(int(n_frames / FPS * RATE)) * 1e-4).astype(np.float32)
    if start is None:
        return out
    a = int(start / FPS * RATE)
    t = np.arange(min(int(seconds * RATE), out.size - a)) / RATE
    tone = sum(np.sin(2 * np.pi * f0 * h * t) / h for h in range(1, 8))
    tone *= 0.5 + 0.5 * np.abs(np.sin(2 * np.pi * 4.0 * t))
    out[a:a + t.size] += (0.3 * tone / np.abs(tone).max()).astype(np.float32)
    return out


def test_features_of_silence_and_a_voice():
    n = 48
    f = frame_features(voice(n, 20), RATE, FPS, n)
    assert f.shape == (n, AUDIO_FEATURES) and f.dtype == np.float32
    assert np.all(f[:19, 0] < 0.05)  # the noise floor is > 50 dB down
    assert np.all(f[21:33, 0] > 0.5)  # the voice is loud
    assert f[20, 5] > 0.3 and np.all(f[22:, 5] < 0.5)  # the onset at its start only
    np.testing.assert_allclose(f[22:33, 2:5].sum(1), 1.0, atol=1e-5)  # band shares
    assert np.all(f[22:33, 2] + f[22:33, 3] > 0.8)  # a low voice: its energy below 1 kHz
    assert np.all(f[22:33, 1] > 0.5)  # WebRTC VAD calls it voiced
    assert not frame_features(np.zeros(RATE, np.float32), RATE, FPS, 24).any()  # digital silence
    assert not frame_features(np.zeros(4, np.float32), RATE, FPS, 24).any()


def test_noise_features_are_steady_and_reproducible():
    a = noise_features(48, FPS, np.random.default_rng(3))
    b = noise_features(48, FPS, np.random.default_rng(3))
    np.testing.assert_array_equal(a, b)
    assert a.shape == (48, AUDIO_FEATURES) and np.all(np.isfinite(a))
    assert a[:, 0].mean() > 0.5  # noise is normalised to its own loudness


def test_window_pads_with_silence():
    f = np.arange(10 * AUDIO_FEATURES, dtype=np.float32).reshape(10, AUDIO_FEATURES)
    w = window(f, 1, 3)
    assert w.shape == (AUDIO_FEATURES, 7)
    assert not w[:, :2].any()
    np.testing.assert_array_equal(w[:, 2:], f[0:5].T)
    np.testing.assert_array_equal(window(f, 9, 1)[:, :2], f[8:10].T)
    assert not window(f, 9, 1)[:, 2].any()
    assert not window(None, 0, 2).any()


def test_grown_weights_predict_exactly_what_the_old_network_did():
    old_cfg = tiny_config()
    torch.manual_seed(0)
    old = AFNet(old_cfg).eval()
    new_cfg = tiny_config(audio=AUDIO_FEATURES)
    new = AFNet(new_cfg)
    full = new.state_dict()
    full.update(grow_state_dict(old.state_dict(), old_cfg, new_cfg))
    new.load_state_dict(full)
    new.eval()
    x = torch.randn(2, old_cfg.frames_seen, old_cfg.channels, old_cfg.height, old_cfg.width)
    audio = torch.rand(2, AUDIO_FEATURES, new_cfg.span)
    with torch.no_grad():
        lo, mo = old(x)
        ln, mn = new(x, audio)
    torch.testing.assert_close(ln, lo, atol=1e-6, rtol=0)
    torch.testing.assert_close(mn, mo, atol=1e-6, rtol=0)
    with pytest.raises(ValueError, match="only switching the audio input on"):
        grow_state_dict(old.state_dict(), old_cfg, tiny_config(audio=AUDIO_FEATURES, f_t=5))


def test_unit_audio_takes_the_columns_of_each_units_frames():
    cfg = tiny_config(audio=2)
    audio = torch.arange(cfg.span, dtype=torch.float32).repeat(1, 2, 1)  # column index as value
    audio[:, 1] += 100
    units = unit_audio_of(audio, cfg)
    assert units.shape == (cfg.s, cfg.f_t, 2)
    cols = torch.as_tensor(cfg.offsets + cfg.half_span, dtype=torch.float32).reshape(cfg.s, cfg.f_t)
    torch.testing.assert_close(units[..., 0], cols)
    torch.testing.assert_close(units[..., 1], cols + 100)


def test_stream_with_audio_equals_the_network_on_the_padded_window():
    cfg = tiny_config(audio=AUDIO_FEATURES)
    torch.manual_seed(2)
    model = AFNet(cfg).eval()
    n = 23
    frames, maps, _ = frames_of(n, 9, 1)
    codes = [encode_frame(f, d, cfg) for f, d in zip(frames, maps)]
    feats = np.random.default_rng(0).random((n, AUDIO_FEATURES)).astype(np.float32)
    stream = AFNetStream(model, n, audio=feats)
    for c in codes:
        stream.push(c)
    stream.finish()
    for q in (0, 8, 22):
        idx = np.clip(q + cfg.offsets, 0, n - 1)
        x = decode_frames(np.stack([codes[i] for i in idx])[None], cfg)
        a = torch.from_numpy(window(feats, q, cfg.half_span))[None]
        with torch.no_grad():
            logit, _ = model(x, a)
        assert stream.probs[q] == pytest.approx(float(torch.sigmoid(logit)[0]), abs=1e-5)
    silent = predict_clip(model, frames, maps)
    assert any(abs(silent.probs[q] - stream.probs[q]) > 1e-6 for q in stream.probs)  # the sound matters
    with pytest.raises(InputError, match="audio numbers"):
        AFNetStream(model, n, audio=feats[:5])


def _write_talking_clip(folder, n: int, start: int | None, seed: int) -> AnnotatedClip:
    """A still frame (square A) whose sound starts at ``start``: that frame is the NFT, onto A."""
    folder.mkdir(parents=True, exist_ok=True)
    frames, _, _ = frames_of(n, None, seed)
    for k, f in enumerate(frames):
        cv2.imwrite(str(folder / f"f_{k:04d}.png"), f[..., ::-1])
    pcm = (np.clip(voice(n + 6, start, seed=seed), -1, 1) * 32767).astype("<i2")  # sound outlasts the frames
    with wave.open(str(folder / "sound.wav"), "wb") as w:
        w.setnchannels(1)
        w.setsampwidth(2)
        w.setframerate(RATE)
        w.writeframes(pcm.tobytes())
    mp4 = folder / "clip.mp4"
    subprocess.run([ffmpeg_exe(), "-v", "error", "-y", "-framerate", str(FPS), "-i", str(folder / "f_%04d.png"),
                    "-i", str(folder / "sound.wav"), "-c:v", "libx264", "-pix_fmt", "yuv420p", "-crf", "12",
                    "-c:a", "aac", "-b:a", "128k", "-frames:v", str(n), str(mp4)], check=True)
    recs = [Annotation(k, BOX_A, "manual" if k == start else "tracked", nft=(k == start)) for k in range(n)]
    return AnnotatedClip(mp4, recs, fps=FPS)


def test_an_nft_only_the_sound_shows_is_learned_with_audio(tmp_path):
    """Every frame of every clip is the same still image; the NFT is where a voice starts.
    Trained with the audio input, AF-Net finds it on a clip it never saw, from the sound alone."""
    n = 40
    starts = [10, 14, 18, 22, 26, 12, 20, None]
    clips = [_write_talking_clip(tmp_path / f"c{i}", n, s, seed=0) for i, s in enumerate(starts)]
    ann = write_annotations(tmp_path / "annotations.json", clips)
    cfg = tiny_config(audio=AUDIO_FEATURES, disparity=False)
    run = tmp_path / "run"
    trainer = AFNetTrainer(AFNetTrainSettings(run_dir=run, annotations=[ann], iterations=150, lr=3e-3, batch=8,
                                              checkpoint_every=150, model=cfg))
    trainer.run(progress=False)
    model, header = load_afnet(run / "afnet.pt")
    assert header["config"]["audio"] == AUDIO_FEATURES
    held_out = _write_talking_clip(tmp_path / "held", n, 16, seed=0)
    from rvr_addon.afnet.audio_features import clip_features

    feats = clip_features(held_out.clip, FPS, n)
    assert feats is not None and feats[16:26, 0].min() > 0.5
    frames, _, _ = frames_of(n, None, 0)
    pred = predict_clip(model, frames, None, threshold=0.5, min_gap=12, audio=feats)
    assert [p.t for p in pred.peaks] and abs(pred.peaks[0].t - 16) <= 2, pred.probs
    quiet = predict_clip(model, frames, None, threshold=0.5, min_gap=12, audio=np.zeros_like(feats))
    assert not quiet.peaks, quiet.probs  # no sound, nothing to see: no NFT


def test_init_from_adds_audio_to_weights_without_it(tmp_path):
    from afnet_synth import write_annotated_dataset

    ann = write_annotated_dataset(tmp_path / "data", [8, None], n=24)
    first = tmp_path / "first"
    AFNetTrainer(AFNetTrainSettings(run_dir=first, annotations=[ann], iterations=2, checkpoint_every=2,
                                    model=tiny_config())).run(progress=False)
    second = tmp_path / "second"
    t = AFNetTrainer(AFNetTrainSettings(run_dir=second, annotations=[ann], iterations=1, checkpoint_every=1,
                                        model=tiny_config(audio=AUDIO_FEATURES), init_from=first / "afnet.pt"))
    assert t.model.config.audio == AUDIO_FEATURES
    record = json.loads((second / "run.json").read_text())["init_from"]
    assert record["audio_added"] is True and record["iterations"] == 2
    with pytest.raises(InputError, match="--init-from starts a new run"):
        AFNetTrainer(AFNetTrainSettings(run_dir=second, annotations=[ann], iterations=2, resume=True,
                                        model=tiny_config(), init_from=first / "afnet.pt"))


def test_inference_stride_and_threshold_travel_with_the_weights(tmp_path):
    """--stride and --threshold are written into the weights (a --resume may change them: they
    are inference settings) and the learned preset's detector uses them unless told otherwise."""
    from afnet_synth import write_annotated_dataset
    from rvr_addon.laaf.detectors.afnet import AFNetDetector

    ann = write_annotated_dataset(tmp_path / "data", [8, None], n=24)
    run = tmp_path / "run"
    AFNetTrainer(AFNetTrainSettings(run_dir=run, annotations=[ann], iterations=2, checkpoint_every=2,
                                    model=tiny_config())).run(progress=False)
    _, header = load_afnet(run / "afnet.pt")
    assert "threshold" not in header and header["config"]["stride"] == tiny_config().stride
    assert AFNetDetector(run / "afnet.pt", 30, 24.0).threshold == 0.5
    AFNetTrainer(AFNetTrainSettings(run_dir=run, annotations=[ann], iterations=2, resume=True, stride=1,
                                    threshold=0.3, model=tiny_config())).run(progress=False)
    model, header = load_afnet(run / "afnet.pt")
    assert header["threshold"] == 0.3 and model.config.stride == 1
    det = AFNetDetector(run / "afnet.pt", 30, 24.0)
    assert det.threshold == 0.3 and det.stream.queries == list(range(30))
    assert AFNetDetector(run / "afnet.pt", 30, 24.0, threshold=0.7).threshold == 0.7
    with pytest.raises(InputError, match="--threshold must be between 0 and 1"):
        AFNetTrainer(AFNetTrainSettings(run_dir=tmp_path / "bad", annotations=[ann], iterations=1, threshold=1.5,
                                        model=tiny_config()))
