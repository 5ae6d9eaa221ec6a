"""Composite two-speaker clips from real talking heads, with exact turns (issue 23, real evaluation).

Two real talking heads are placed side by side (one panel each). Per *turn* one panel plays a
stretch of its own clip where that person speaks, and the composite's sound is that stretch's
own audio; the other panel keeps playing its own footage (mouth moving or not) *muted*. So who
speaks, when, and where is known exactly: the annotation (``rvr eval-focus --real`` format,
``rvr_addon/laaf/score_real.py``) is written from the same timeline. Between turns: silence
(or none: a change of speaker inside continuous speech). An ``offscreen`` segment plays a voice
from a clip that is not shown, over both (muted) panels: no face on screen utters it, so it must
pull no focus to a silent face (annotation key ``offscreen``).

A panel's idle footage plays its ``idle`` range back and forth (ping-pong: no jump in the
picture); a turn jumps the panel to its speech stretch (a small in-panel jump, like an edit).

Nothing from ../shared/data is copied into the repository: the clip and its annotation are
written under the folder given at run time.

Usage: python scripts/composite_speakers.py OUT_DIR [--kind grid_restaurant|interview_halves]
(writes OUT_DIR/<kind>.mp4, OUT_DIR/<kind>.json and OUT_DIR/<kind>_depth.npy: a disparity map
with one level per panel, so only the focus *decision* is judged).
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import wave
from dataclasses import dataclass
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

CLIPS = ROOT.parent / "shared" / "data" / "clips"
FPS = 25.0
RATE = 16000


@dataclass
class Panel:
    """One talking head: clip (under CLIPS), crop (x, y, w, h) in its native px, idle (s0, s1):
    the range played (ping-pong) while this person does not speak."""

    clip: str
    crop: tuple[int, int, int, int]
    idle: tuple[float, float]
    name: str


@dataclass
class Turn:
    """A stretch of sound: ``panel`` (index; None: off-screen, the voice of ``clip``), from
    ``start_s`` of the source for ``dur_s``; ``gap_s`` of silence before it."""

    panel: int | None
    start_s: float
    dur_s: float
    gap_s: float = 0.5
    clip: str | None = None


KINDS = {
    # GRID's woman (speech 0.7-2.4 s) left, the restaurant's man (speaks throughout, loud noise) right
    "grid_restaurant": dict(
        size=(480, 480),
        panels=[Panel("lipnet_grid_lwbsza.mpg", (36, 0, 288, 288), (0.0, 2.96), "grid woman"),
                Panel("visualvoice_noisy_restaurant.mp4", (100, 0, 720, 720), (0.0, 8.9), "restaurant man")],
        turns=[Turn(0, 0.66, 1.8, 0.6), Turn(1, 1.0, 2.5, 0.5), Turn(0, 0.66, 1.8, 0.4),
               Turn(1, 4.0, 2.0, 0.0),  # no pause: a change of speaker inside continuous speech
               Turn(None, 10.8, 2.0, 0.6, clip="visualvoice_interview.mp4"),  # off-screen voice
               Turn(0, 0.66, 1.8, 0.6), Turn(1, 6.0, 2.4, 0.5),
               Turn(0, 0.66, 1.8, 0.0),  # no pause
               Turn(1, 0.2, 2.0, 0.5)],
        tail_s=0.6),
    # the interview's two halves from *different* times: the presenter's own stretches (left) and
    # the guest's (right), the other half muted and from elsewhere in the clip
    "interview_halves": dict(
        size=(320, 480),
        panels=[Panel("visualvoice_interview.mp4", (160, 0, 480, 720), (8.5, 15.0), "presenter"),
                Panel("visualvoice_interview.mp4", (640, 0, 480, 720), (4.8, 7.0), "guest")],
        turns=[Turn(0, 4.84, 0.68, 0.6), Turn(1, 10.72, 1.6, 0.5), Turn(0, 6.16, 0.76, 0.4),
               Turn(1, 12.4, 1.4, 0.0), Turn(0, 16.2, 0.9, 0.5),
               Turn(None, 1.0, 1.6, 0.6, clip="visualvoice_noisy_restaurant.mp4"),
               Turn(1, 13.8, 1.2, 0.6), Turn(0, 4.84, 0.68, 0.5), Turn(1, 8.48, 0.6, 0.5)],
        tail_s=0.6),
}


def _frames(clip: Path) -> list[np.ndarray]:
    from rvr_addon.io.video import iter_frames

    return list(iter_frames(clip))


def _panel_image(frame: np.ndarray, crop, size) -> np.ndarray:
    import cv2

    x, y, w, h = crop
    return cv2.resize(frame[y:y + h, x:x + w], size, interpolation=cv2.INTER_AREA)


def _ping_pong(t: float, a: float, b: float) -> float:
    span = max(b - a, 1e-3)
    u = t % (2 * span)
    return a + (u if u < span else 2 * span - u)


def build(out_dir: str | Path, kind: str = "grid_restaurant", clips: Path = CLIPS) -> tuple[Path, Path, Path]:
    """Write OUT_DIR/<kind>.mp4 (video + the turns' audio), OUT_DIR/<kind>.json (annotation:
    fps, turns with their speaker's panel box in composite px, offscreen segments) and
    OUT_DIR/<kind>_depth.npy (disparity 1.0 on the left panel, 3.0 on the right); returns them."""
    import imageio_ffmpeg

    from rvr_addon.laaf.audio import decode_audio

    spec = KINDS[kind]
    pw, ph = spec["size"]
    panels: list[Panel] = spec["panels"]
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    sources = {p.clip: _frames(clips / p.clip) for p in panels}
    sound = {}
    for c in {p.clip for p in panels} | {t.clip for t in spec["turns"] if t.clip}:
        sound[c] = decode_audio(clips / c, rate=RATE)

    # timeline: per output frame, the source time of each panel; audio samples
    schedule: list[list[float]] = []  # per frame: source time per panel
    audio: list[np.ndarray] = []
    turns_json, offscreen = [], []
    clock = [p.idle[0] for p in panels]  # idle clocks (ping-pong phase)
    now = 0.0

    def advance(dur: float, speaking: int | None = None, src_start: float = 0.0) -> None:
        nonlocal now
        n0, n1 = int(round(now * FPS)), int(round((now + dur) * FPS))
        for k in range(n0, n1):
            dt = (k - n0) / FPS
            row = []
            for i, p in enumerate(panels):
                if i == speaking:
                    row.append(src_start + dt)
                else:
                    row.append(_ping_pong(clock[i] + dt, *p.idle))
            schedule.append(row)
        for i in range(len(panels)):
            if i != speaking:
                clock[i] += (n1 - n0) / FPS
        now = n1 / FPS

    def samples(clip: str, start: float, dur: float) -> np.ndarray:
        s = sound[clip]
        a = int(round(start * RATE))
        seg = s[a:a + int(round(dur * RATE))]
        return np.pad(seg, (0, int(round(dur * RATE)) - len(seg)))

    for turn in spec["turns"]:
        if turn.gap_s > 0:
            g0 = len(schedule)
            advance(turn.gap_s)
            audio.append(np.zeros((len(schedule) - g0) * RATE // int(FPS), np.float32))
        f0 = len(schedule)
        dur = round(turn.dur_s * FPS) / FPS
        if turn.panel is None:
            advance(dur)
            audio.append(samples(turn.clip, turn.start_s, (len(schedule) - f0) / FPS))
            offscreen.append({"start_s": round(f0 / FPS, 4), "end_s": round(len(schedule) / FPS, 4),
                              "voice": f"{turn.clip} {turn.start_s}-{turn.start_s + turn.dur_s} s"})
            continue
        p = panels[turn.panel]
        advance(dur, speaking=turn.panel, src_start=turn.start_s)
        audio.append(samples(p.clip, turn.start_s, (len(schedule) - f0) / FPS))
        turns_json.append({"start_s": round(f0 / FPS, 4), "end_s": round(len(schedule) / FPS, 4),
                           "box": [turn.panel * pw, 0, pw, ph], "speaker": p.name,
                           "source": f"{p.clip} {turn.start_s}-{turn.start_s + dur:.2f} s"})
    t0 = len(schedule)
    advance(spec.get("tail_s", 0.5))
    audio.append(np.zeros((len(schedule) - t0) * RATE // int(FPS), np.float32))

    name = kind
    video = out_dir / f"{name}.mp4"
    pcm = (np.clip(np.concatenate(audio), -1, 1) * 32767).astype("<i2")
    with tempfile.TemporaryDirectory() as tmp:
        wav = Path(tmp) / "a.wav"
        with wave.open(str(wav), "wb") as w:
            w.setnchannels(1)
            w.setsampwidth(2)
            w.setframerate(RATE)
            w.writeframes(pcm.tobytes())
        writer = imageio_ffmpeg.write_frames(str(video), (pw * len(panels), ph), fps=FPS, quality=8,
                                             macro_block_size=8, audio_path=str(wav), audio_codec="aac",
                                             output_params=["-shortest"], ffmpeg_log_level="error")
        writer.send(None)
        for row in schedule:
            tiles = []
            for i, p in enumerate(panels):
                frames = sources[p.clip]
                k = int(min(max(round(row[i] * FPS), 0), len(frames) - 1))
                tiles.append(_panel_image(frames[k], p.crop, (pw, ph)))
            writer.send(np.ascontiguousarray(np.hstack(tiles)))
        writer.close()
    ann = {"clip": video.name, "fps": FPS, "turns": turns_json, "offscreen": offscreen, "cuts": [],
           "panels": [{"box": [i * pw, 0, pw, ph], "name": p.name, "clip": p.clip} for i, p in enumerate(panels)],
           "how": "built by scripts/composite_speakers.py: per turn one panel plays its own speech with its own "
                  "audio, the other panel plays its own footage muted; offscreen: a voice from a clip not shown"}
    annotation = out_dir / f"{name}.json"
    annotation.write_text(json.dumps(ann, indent=1))
    depth = np.full((ph, pw * len(panels)), 1.0, np.float32)
    depth[:, pw:] = 3.0
    depth_path = out_dir / f"{name}_depth.npy"
    np.save(depth_path, depth)
    return video, annotation, depth_path


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("out", type=Path)
    ap.add_argument("--kind", choices=tuple(KINDS), default="grid_restaurant")
    args = ap.parse_args(argv)
    for p in build(args.out, args.kind):
        print(p)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
