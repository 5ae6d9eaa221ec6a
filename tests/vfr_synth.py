"""A variable-frame-rate clip with a flash and a beep at one moment (sound-picture sync tests)."""
from __future__ import annotations

from rvr_addon.io.video import iter_frames


def flash_clip(ffmpeg_run, path, seconds: float = 3.5, flash_s: float = 2.5, vfr: bool = True):
    """A 30 fps clip whose first 2 s keep only 2 frames in 3 (20 fps there: variable frame rate, as
    phones record in low light), with a white flash and a 1 kHz beep at ``flash_s`` for 0.1 s
    (``vfr`` False: every frame kept, a constant frame rate)."""
    keep = "select='gte(n,60)+lt(mod(n,3),2)'" if vfr else "null"
    box = f"drawbox=x=100:y=50:w=120:h=80:color=white:t=fill:enable='between(t,{flash_s},{flash_s + 0.1})'"
    ffmpeg_run("-f", "lavfi", "-i", f"color=c=0x303030:size=320x180:rate=30:duration={seconds},{box}",
               "-f", "lavfi", "-i", f"sine=frequency=1000:duration={seconds},volume=volume=0:"
               f"enable='not(between(t,{flash_s},{flash_s + 0.1}))'",
               "-vf", keep, "-fps_mode", "vfr", "-c:v", "libx264",
               "-preset", "ultrafast", "-pix_fmt", "yuv420p", "-c:a", "aac", "-shortest", str(path))
    return path


def flash_frames(path, **kw) -> list[int]:
    return [k for k, f in enumerate(iter_frames(path, **kw)) if f.mean() > 60]


def assert_in_sync(out, flash_s: float = 2.5, fps: float = 30.0, frames: int = 105) -> None:
    """``out`` (a render of :func:`flash_clip`) is at the constant ``fps`` with its sound, and its
    flash is at ``flash_s`` (within a frame) and on its beep (within 50 ms)."""
    import numpy as np
    import pytest

    from rvr_addon.io.video import probe_clip
    from rvr_addon.laaf.audio import SAMPLE_RATE, decode_audio

    info = probe_clip(out)
    assert info.fps == pytest.approx(fps) and info.has_audio and abs(info.frame_count - frames) <= 1
    seen = next(k for k, f in enumerate(iter_frames(out)) if f.mean() > 60) / info.fps
    sound = np.abs(decode_audio(out))
    beep_s = int(np.argmax(sound > 0.5 * sound.max())) / SAMPLE_RATE
    assert seen == pytest.approx(flash_s, abs=1.05 / fps) and abs(seen - beep_s) <= 0.05, (seen, beep_s)
