"""Shared fixtures: tiny synthetic clips made with the ffmpeg bundled in imageio-ffmpeg.

Clips are 64x48, a dozen frames, built once per session (a few hundred ms in all).
"""
from __future__ import annotations

import subprocess
from pathlib import Path

import numpy as np
import pytest

CLIP_W, CLIP_H, CLIP_FRAMES, CLIP_FPS = 64, 48, 12, 24


@pytest.fixture(scope="session")
def ffmpeg() -> str:
    """Path of the bundled ffmpeg binary."""
    import imageio_ffmpeg

    return imageio_ffmpeg.get_ffmpeg_exe()


def run_ffmpeg(ffmpeg: str, *args: str) -> None:
    """Run ffmpeg quietly; fail the test with its stderr if it fails."""
    cmd = [ffmpeg, "-hide_banner", "-nostdin", "-v", "error", "-y", *args]
    done = subprocess.run(cmd, capture_output=True, text=True)
    assert done.returncode == 0, f"ffmpeg failed: {' '.join(cmd)}\n{done.stderr}"


@pytest.fixture(scope="session")
def ffmpeg_run(ffmpeg):
    """Callable running the bundled ffmpeg with the given arguments (asserts success)."""
    return lambda *args: run_ffmpeg(ffmpeg, *args)


@pytest.fixture(scope="session")
def stream_info(ffmpeg):
    """Callable returning ffmpeg's 'Stream #' lines for a file (contain 'Video:' / 'Audio:')."""
    return lambda path: stream_kinds(ffmpeg, path)


def stream_kinds(ffmpeg: str, path: Path) -> str:
    """ffmpeg's description of the streams of `path` (contains 'Video:' / 'Audio:')."""
    done = subprocess.run([ffmpeg, "-hide_banner", "-i", str(path)], capture_output=True, text=True)
    return "\n".join(line for line in done.stderr.splitlines() if "Stream #" in line)


@pytest.fixture(scope="session")
def clip_dir(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("clips")


def _testsrc(size: tuple[int, int] = (CLIP_W, CLIP_H), fps: int = CLIP_FPS) -> list[str]:
    return ["-f", "lavfi", "-i", f"testsrc2=size={size[0]}x{size[1]}:rate={fps}"]


def _frames(n: int = CLIP_FRAMES) -> list[str]:
    return ["-frames:v", str(n)]


_H264 = ["-c:v", "libx264", "-preset", "ultrafast", "-pix_fmt", "yuv420p"]


@pytest.fixture(scope="session")
def clip_av(ffmpeg, clip_dir) -> Path:
    """64x48, 12 frames at 24 fps, H.264 + AAC sine audio (0.5 s)."""
    path = clip_dir / "av.mp4"
    run_ffmpeg(ffmpeg, *_testsrc(), "-f", "lavfi", "-i", "sine=frequency=440:sample_rate=48000:duration=0.5",
               *_frames(), *_H264, "-c:a", "aac", "-shortest", str(path))
    return path


@pytest.fixture(scope="session")
def clip_silent(ffmpeg, clip_dir) -> Path:
    """64x48, 12 frames at 24 fps, no audio stream."""
    path = clip_dir / "silent.mp4"
    run_ffmpeg(ffmpeg, *_testsrc(), *_frames(), *_H264, str(path))
    return path


@pytest.fixture(scope="session")
def clip_long_audio(ffmpeg, clip_dir) -> Path:
    """48 frames (2 s) of video with 2 s of audio: an audio source longer than a short render."""
    path = clip_dir / "long_audio.mp4"
    run_ffmpeg(ffmpeg, *_testsrc(), "-f", "lavfi", "-i", "sine=frequency=220:sample_rate=48000:duration=2",
               *_frames(48), *_H264, "-c:a", "aac", str(path))
    return path


@pytest.fixture(scope="session")
def clip_rotated(ffmpeg, clip_dir, clip_silent) -> Path:
    """The silent clip's bitstream with a 90 degree display-rotation tag (as phones write)."""
    path = clip_dir / "rotated.mp4"
    run_ffmpeg(ffmpeg, "-display_rotation", "90", "-i", str(clip_silent), "-c", "copy", str(path))
    return path


@pytest.fixture(scope="session")
def clip_trimmed(ffmpeg, clip_dir) -> Path:
    """48 frames, one keyframe, trimmed by stream copy at 0.5 s: an MP4 edit list hides 12 frames."""
    full = clip_dir / "one_gop.mp4"
    run_ffmpeg(ffmpeg, *_testsrc(), *_frames(48), *_H264, "-g", "1000", str(full))
    path = clip_dir / "trimmed.mp4"
    run_ffmpeg(ffmpeg, "-ss", "0.5", "-i", str(full), "-c", "copy", str(path))
    return path


@pytest.fixture(scope="session")
def clip_bt709_color(ffmpeg, clip_dir) -> Path:
    """3 frames of solid sRGB (200, 60, 30), encoded with the BT.709 matrix and tagged BT.709."""
    path = clip_dir / "bt709.mp4"
    run_ffmpeg(ffmpeg, "-f", "lavfi", "-i", f"color=c=0xC83C1E:s={CLIP_W}x{CLIP_H}:r={CLIP_FPS},format=rgb24", "-frames:v", "3",
               "-vf", "scale=out_color_matrix=bt709:out_range=tv,format=yuv420p,"
               "setparams=colorspace=bt709:color_primaries=bt709:color_trc=bt709:range=tv",
               "-c:v", "libx264", "-crf", "0", str(path))
    return path


@pytest.fixture(scope="session")
def clip_resolution_change(ffmpeg, clip_dir) -> Path:
    """MPEG-TS whose first 5 frames are 64x48 and next 5 are 80x48 (concatenated streams)."""
    parts = []
    for i, width in enumerate((64, 80)):
        part = clip_dir / f"part{i}.ts"
        run_ffmpeg(ffmpeg, *_testsrc(size=(width, 48)), *_frames(5), *_H264, str(part))
        parts.append(part.read_bytes())
    path = clip_dir / "res_change.ts"
    path.write_bytes(b"".join(parts))
    return path


@pytest.fixture(scope="session")
def corrupt_clip(clip_dir) -> Path:
    """A file named .mp4 holding random bytes."""
    path = clip_dir / "broken.mp4"
    path.write_bytes(np.random.default_rng(0).integers(0, 256, 4096, dtype=np.uint8).tobytes())
    return path


@pytest.fixture
def image_frames() -> list[np.ndarray]:
    """12 random (48, 64, 3) uint8 RGB frames."""
    rng = np.random.default_rng(1)
    return [rng.integers(0, 256, (CLIP_H, CLIP_W, 3), dtype=np.uint8) for _ in range(CLIP_FRAMES)]


@pytest.fixture
def image_sequence(tmp_path, image_frames) -> Path:
    """Folder of PNGs frame1.png .. frame12.png (unpadded: natural order differs from text order)."""
    import cv2

    folder = tmp_path / "seq"
    folder.mkdir()
    for i, frame in enumerate(image_frames, start=1):
        assert cv2.imwrite(str(folder / f"frame{i}.png"), frame[:, :, ::-1])
    return folder
