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

Kind ``shot_reverse_shot`` (cuts, issue 23) is edited instead: full-frame *shots*, one person
each (GRID's woman, the restaurant's man, the interview's presenter and guest, cropped so that the
heads alternate left / right like a shot-reverse-shot), joined by hard cuts. Per shot a list of
*parts* says what its picture plays (a source stretch, or a ping-pong of an idle range) and what
is heard: the shown person's own voice in sync (a turn), nothing, or another clip's voice (the
previous shot's person going on over this shot: an L-cut; the next shot's person starting before
the cut: a J-cut), which is off-screen speech. The annotation adds ``cuts`` (first frame of each
new shot) and ``shots`` (first frame, the shown person's head box); the depth is one map per
frame (an (N, H, W) stack at a reduced size): the shown person's head and torso at that person's
own disparity, the rest at a background level.

Usage: python scripts/composite_speakers.py OUT_DIR [--kind grid_restaurant|interview_halves|shot_reverse_shot]
(writes OUT_DIR/<kind>.mp4, OUT_DIR/<kind>.json and OUT_DIR/<kind>_depth.npy: a disparity map
with one level per panel, or per shot, so only the focus *decision* is judged).
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


@dataclass
class Person:
    """One person of an edited kind: clip (under CLIPS), crop (x, y, w, h) in its native px
    (the shot's frame, resized to the output size), head (x, y, w, h): the head in the clip's
    native px (the turn box; clipped to the crop), disparity: that person's level."""

    clip: str
    crop: tuple[int, int, int, int]
    head: tuple[int, int, int, int]
    disparity: float
    name: str


@dataclass
class Part:
    """A stretch of a shot, ``dur_s`` long. video: the source time it starts at (played
    forward), a range (a, b) played ping-pong from a towards b, or None (the previous part's
    clock goes on). voice: None (silence), "own" (the shown person, in sync with the picture:
    a turn) or (clip, start_s): a voice of another clip, not the shown person's (off-screen)."""

    dur_s: float
    video: float | tuple[float, float] | None
    voice: str | tuple[str, float] | None = None


@dataclass
class Shot:
    """A shot: ``person`` (index into the kind's persons) and its parts; a hard cut before it
    (except the first)."""

    person: int
    parts: list[Part]


_W = Person("lipnet_grid_lwbsza.mpg", (100, 40, 260, 208), (50, 40, 215, 248), 3.0, "grid woman")
_M = Person("visualvoice_noisy_restaurant.mp4", (60, 0, 560, 448), (330, 20, 210, 260), 2.0, "restaurant man")
_P = Person("visualvoice_interview.mp4", (250, 40, 380, 304), (295, 60, 210, 290), 3.6, "presenter")
_G = Person("visualvoice_interview.mp4", (660, 60, 350, 280), (795, 60, 215, 290), 1.4, "guest")
_REST = "visualvoice_noisy_restaurant.mp4"

SHOT_KINDS = {
    # W left / M right / P left / G right; background disparity 0.5, each person at its own level
    "shot_reverse_shot": dict(
        size=(400, 320), background=0.5,
        persons=[_W, _M, _P, _G],
        shots=[
            Shot(0, [Part(0.4, 0.26), Part(1.8, 0.66, "own")]),                    # she speaks
            Shot(1, [Part(2.5, 1.0, "own")]),                                       # cut: he speaks at once
            # L-cut: his voice goes on over her silent face (she ping-pongs her still first 0.64 s),
            # then she answers in the same shot
            Shot(0, [Part(2.56, (0.64, 0.0), (_REST, 3.5)), Part(1.8, 0.66, "own"), Part(0.4, 2.46)]),
            Shot(2, [Part(0.68, 4.84, "own"), Part(0.64, 5.52), Part(0.76, 6.16, "own")]),  # cut: he speaks
            Shot(3, [Part(0.44, 6.3)]),                                              # an 11-frame reaction insert:
            Shot(2, [Part(0.3, 15.9), Part(0.9, 16.2, "own"), Part(0.3, 17.1)]),     # two cuts 0.44 s apart
            # cut: the guest speaks at once; then a J-cut: the restaurant man's voice starts over the
            # guest's muted face (his mouth still moves: his own speech, muted) before the cut to him.
            # (The guest's 14.4-16.2 s are left out: his hand sweeping past the close-up fails the cut
            # detector's flow checks on 60-72% of the pixels, a false cut.)
            Shot(3, [Part(2.0, 10.72, "own"), Part(0.48, 12.72), Part(1.1, None, (_REST, 5.0))]),
            Shot(1, [Part(2.3, 6.1, "own"), Part(0.4, 8.4)]),                      # his voice goes on: he is seen
        ]),
}


def _box_in_shot(person: Person, size: tuple[int, int]) -> list[int]:
    """The person's head box in output px of a shot (clipped to the frame)."""
    cx, cy, cw, ch = person.crop
    sx, sy = size[0] / cw, size[1] / ch
    x, y, w, h = person.head
    x0, y0 = max((x - cx) * sx, 0.0), max((y - cy) * sy, 0.0)
    x1, y1 = min((x + w - cx) * sx, size[0]), min((y + h - cy) * sy, size[1])
    return [int(round(x0)), int(round(y0)), int(round(x1 - x0)), int(round(y1 - y0))]


def _part_clock(video, prev, dt: float) -> float:
    """Source time at dt s into a part (``Part.video``; prev: the previous part's clock and its length)."""
    if video is None:
        fn, offset = prev
        return fn(offset + dt)
    if isinstance(video, tuple):
        a, b = video
        span = max(abs(b - a), 1e-3)
        u = dt % (2 * span)
        tri = u if u < span else 2 * span - u
        return a + tri if b >= a else a - tri
    return float(video) + dt


def build_shots(out_dir: str | Path, kind: str = "shot_reverse_shot", clips: Path = CLIPS,
                depth_size: tuple[int, int] = (100, 80)) -> tuple[Path, Path, Path]:
    """Write an edited kind (``SHOT_KINDS``): OUT_DIR/<kind>.mp4 (video + sound), OUT_DIR/<kind>.json
    (fps, turns with the speaker's head box in output px, offscreen segments, cuts: first frame of
    each new shot, shots: first frame + head box + name) and OUT_DIR/<kind>_depth.npy ((N, h, w)
    float32 at ``depth_size`` (w, h) px, one map per frame: the shown person's head and torso at the
    person's disparity, the rest at the background's); returns the three paths."""

    from rvr_addon.laaf.audio import decode_audio

    spec = SHOT_KINDS[kind]
    size = spec["size"]
    persons: list[Person] = spec["persons"]
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    sources = {c: _frames(clips / c) for c in {p.clip for p in persons}}
    voices = {p.clip for p in persons} | {pt.voice[0] for s in spec["shots"] for pt in s.parts
                                          if isinstance(pt.voice, tuple)}
    sound = {c: decode_audio(clips / c, rate=RATE) for c in voices}
    per_frame = RATE // int(FPS)

    def samples(clip: str, start: float, n_frames: int) -> np.ndarray:
        a = int(round(start * RATE))
        seg = sound[clip][a:a + n_frames * per_frame]
        return np.pad(seg, (0, n_frames * per_frame - len(seg))).astype(np.float32)

    rows: list[tuple[int, int]] = []  # per output frame: (person, source frame)
    audio: list[np.ndarray] = []
    turns_json, offscreen, cuts, shots_json = [], [], [], []
    for si, shot in enumerate(spec["shots"]):
        person = persons[shot.person]
        box = _box_in_shot(person, size)
        first = len(rows)
        if si:
            cuts.append(first)
        shots_json.append({"first": first, "person": person.name, "box": box})
        prev = None
        for part in shot.parts:
            n = int(round(part.dur_s * FPS))
            f0 = len(rows)
            clock = [_part_clock(part.video, prev, k / FPS) for k in range(n)]
            rows += [(shot.person, int(round(t * FPS))) for t in clock]
            if part.video is None:
                prev = (prev[0], prev[1] + n / FPS)
            else:
                prev = ((lambda v: (lambda dt: _part_clock(v, None, dt)))(part.video), n / FPS)
            span = {"start_s": round(f0 / FPS, 4), "end_s": round(len(rows) / FPS, 4)}
            if part.voice is None:
                audio.append(np.zeros(n * per_frame, np.float32))
            elif part.voice == "own":
                if not isinstance(part.video, (int, float)):
                    raise ValueError(f"shot {si}: an 'own' voice needs a forward-played video start, got {part.video}")
                audio.append(samples(person.clip, float(part.video), n))
                turns_json.append({**span, "box": box, "speaker": person.name,
                                   "source": f"{person.clip} {part.video}-{part.video + n / FPS:.2f} s"})
            else:
                clip, t0 = part.voice
                audio.append(samples(clip, t0, n))
                offscreen.append({**span, "voice": f"{clip} {t0}-{t0 + n / FPS:.2f} s",
                                  "over": person.name})

    video = out_dir / f"{kind}.mp4"
    dw, dh = depth_size
    depth = np.full((len(rows), dh, dw), float(spec["background"]), np.float32)

    def shot_frames():
        for k, (pi, src) in enumerate(rows):
            person = persons[pi]
            frames = sources[person.clip]
            yield _panel_image(frames[min(max(src, 0), len(frames) - 1)], person.crop, size)
            # head and torso (the head box widened by a third and down to the bottom of the frame)
            x, y, w, h = _box_in_shot(person, size)
            x0, x1 = max(x - w / 6, 0), min(x + w * 7 / 6, size[0])
            depth[k, int(round(y * dh / size[1])):, int(round(x0 * dw / size[0])):int(round(x1 * dw / size[0]))] = \
                person.disparity

    _write_video(video, size, audio, shot_frames())
    ann = {"clip": video.name, "fps": FPS, "turns": turns_json, "offscreen": offscreen, "cuts": cuts,
           "shots": shots_json,
           "persons": [{"name": p.name, "clip": p.clip, "disparity": p.disparity} for p in persons],
           "how": "built by scripts/composite_speakers.py: full-frame shots of one person each, joined by hard cuts; "
                  "a turn: the shown person's own voice in sync; offscreen: another clip's voice over the shown "
                  "(silent) person (L-cut / J-cut)"}
    annotation = out_dir / f"{kind}.json"
    annotation.write_text(json.dumps(ann, indent=1))
    depth_path = out_dir / f"{kind}_depth.npy"
    np.save(depth_path, depth)
    return video, annotation, depth_path


def _write_video(video: Path, size: tuple[int, int], audio: list[np.ndarray], frames) -> None:
    """Write ``frames`` ((h, w, 3) uint8 RGB, ``size`` = (w, h)) at FPS with the mono ``audio``
    chunks (float in [-1, 1] at RATE) as an H.264 + AAC MP4."""
    import imageio_ffmpeg

    pcm = (np.clip(np.concatenate(audio), -1, 1) * 32767).astype("<i2")
    with tempfile.TemporaryDirectory() as tmp:
        wav = Path(tmp) / "a.wav"
        with wave.open(str(wav), "wb") as w:
            w.setnchannels(1)
            w.setsampwidth(2)
            w.setframerate(RATE)
            w.writeframes(pcm.tobytes())
        writer = imageio_ffmpeg.write_frames(str(video), size, fps=FPS, quality=8, macro_block_size=8,
                                             audio_path=str(wav), audio_codec="aac", output_params=["-shortest"],
                                             ffmpeg_log_level="error")
        writer.send(None)
        for frame in frames:
            writer.send(np.ascontiguousarray(frame))
        writer.close()


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
    OUT_DIR/<kind>_depth.npy (disparity 1.0 on the left panel, 3.0 on the right); returns them. An edited kind (``SHOT_KINDS``) is written by :func:`build_shots`."""
    if kind in SHOT_KINDS:
        return build_shots(out_dir, kind, clips)

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
    def panel_frames():
        for row in schedule:
            tiles = []
            for i, p in enumerate(panels):
                frames = sources[p.clip]
                k = int(min(max(round(row[i] * FPS), 0), len(frames) - 1))
                tiles.append(_panel_image(frames[k], p.crop, (pw, ph)))
            yield np.hstack(tiles)

    _write_video(video, (pw * len(panels), ph), audio, panel_frames())
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
    ap.add_argument("--kind", choices=tuple(KINDS) + tuple(SHOT_KINDS), default="grid_restaurant")
    args = ap.parse_args(argv)
    for p in build(args.out, args.kind):
        print(p)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
