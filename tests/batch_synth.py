"""Helpers of the rvr batch tests: tiny clips, untrained weights, and a worker plugin that
kills its own worker process in the middle of a chunk (importable by the spawned workers)."""
from __future__ import annotations

import os
import signal
import subprocess
import threading
import time
from pathlib import Path

import cv2
import numpy as np
from distributed import WorkerPlugin

W, H, N = 64, 36, 12


def make_clip(path: Path, seed: int = 0, frames: int = N, width: int = W, height: int = H) -> Path:
    """An H.264 MP4 (no audio): a blurred noise background panning left, a white box moving right."""
    import imageio_ffmpeg

    path.parent.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    base = cv2.GaussianBlur((rng.random((height, width * 2, 3)) * 200).astype(np.uint8), (5, 5), 0)
    data = []
    for i in range(frames):
        f = base[:, i:i + width].copy()
        cv2.rectangle(f, (10 + i, 10), (24 + i, 26), (255, 255, 255), -1)
        data.append(f.tobytes())
    cmd = [imageio_ffmpeg.get_ffmpeg_exe(), "-v", "error", "-y", "-f", "rawvideo", "-pix_fmt", "rgb24", "-s",
           f"{width}x{height}", "-r", "24", "-i", "-", "-c:v", "libx264", "-pix_fmt", "yuv420p", "-crf", "12", str(path)]
    subprocess.run(cmd, input=b"".join(data), check=True, capture_output=True)
    return path


def make_depth(folder: Path, frames: int = N, width: int = W, height: int = H) -> Path:
    """One .npy disparity map per frame: a ramp -2..6 px, the box region near (-1 px)."""
    folder.mkdir(parents=True, exist_ok=True)
    ramp = np.tile(np.linspace(-2, 6, width, dtype=np.float32), (height, 1))
    for i in range(frames):
        d = ramp.copy()
        d[10:27, 10 + i:25 + i] = -1.0
        np.save(folder / f"d_{i:04d}.npy", d)
    return folder


def untrained_weights(path: Path, seed: int = 0) -> Path:
    """An untrained estimator exported like `rvr train` does (the batch does not care what it learnt)."""
    import torch

    from rvr_addon.estimate.train import export_weights
    from rvr_addon.estimate.unet import EstimatorNet

    torch.manual_seed(seed)
    return export_weights(EstimatorNet(), path, iterations=0, wall_time_s=0.0, training={"note": "test only"})


class KillOnce(WorkerPlugin):
    """Kill this worker's process (SIGKILL, as the OOM killer would) once in the whole test:
    when a task whose key starts with ``prefix`` runs and its staging folder under
    ``watch`` has received its first frame file, i.e. in the middle of the chunk. ``flag``
    records the kill (pid, key), so the restarted worker does not kill again."""

    name = "test-kill-once"

    def __init__(self, flag: Path, prefix: str, watch: Path, pattern: str) -> None:
        self.flag, self.prefix, self.watch, self.pattern = Path(flag), prefix, Path(watch), pattern

    def transition(self, key, start, finish, **kwargs) -> None:
        if finish != "executing" or not str(key).startswith(self.prefix) or self.flag.exists():
            return
        threading.Thread(target=self._kill_when_started, args=(str(key),), daemon=True).start()

    def _kill_when_started(self, key: str) -> None:
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline:
            if any(self.watch.glob(self.pattern)):
                break
            time.sleep(0.002)
        if self.flag.exists():
            return
        self.flag.write_text(f"{os.getpid()} {key}")
        os.kill(os.getpid(), signal.SIGKILL)


def make_talking_clip(folder: Path, frames: int = 40, turns=((4, 17, 0), (22, 36, 1)),
                      pan: float = 1.0) -> tuple[Path, Path, object]:
    """Two textured heads whose mouths open with their own turns (``laaf_synth.talking_blobs``),
    as an H.264 MP4 with an audio track (a quiet tone: its voice activity is given to the test
    separately), one disparity ramp for all frames; pan: the camera's px/frame (0: still heads
    where ``fake_faces`` puts their boxes, for clips longer than 40 frames); returns (clip, depth map, AudioTrack)."""
    import imageio_ffmpeg

    from laaf_synth import talking_blobs
    from rvr_addon.laaf.audio import AudioTrack

    fps = 25.0
    rgb, env, voiced, _ = talking_blobs(n=frames, turns=turns, fps=fps, pan=pan)
    h, w = rgb[0].shape[:2]
    folder.mkdir(parents=True, exist_ok=True)
    clip = folder / "talk.mp4"
    cmd = [imageio_ffmpeg.get_ffmpeg_exe(), "-v", "error", "-y", "-f", "rawvideo", "-pix_fmt", "rgb24", "-s",
           f"{w}x{h}", "-r", str(fps), "-i", "-", "-f", "lavfi", "-i", "sine=frequency=300:sample_rate=16000",
           "-c:v", "libx264", "-pix_fmt", "yuv420p", "-crf", "12", "-g", "12", "-c:a", "aac", "-shortest", str(clip)]
    subprocess.run(cmd, input=b"".join(f.tobytes() for f in rgb), check=True, capture_output=True)
    depth = folder / "depth.npy"
    np.save(depth, np.tile(np.linspace(-2, 6, w, dtype=np.float32), (h, 1)))
    return clip, depth, AudioTrack(voiced, env.astype(np.float32), voiced.astype(np.float32), fps)


def fake_faces(self, gray: np.ndarray) -> list[tuple[float, float, float, float]]:
    """Stand-in for FaceBackend.detect on drawn heads (not dlib's business): the two head boxes
    of ``make_talking_clip``, shifted by a deterministic function of the frame, so boxes and
    face tracks change over the clip."""
    h, w = gray.shape
    shift = float(gray[h // 2, :8].mean() % 5)
    boxes = [(w * 0.28 - 15 + shift, h / 2 - 18, 30.0, 36.0), (w * 0.72 - 15 - shift, h / 2 - 18, 30.0, 36.0 + shift)]
    return boxes[: 1 + int(gray[0, 0]) % 2 + (shift > 1)]


def laaf_outcome(result) -> dict:
    """Everything an AutofocusResult decides (not its timings)."""
    return {"keys": [(k.frame, k.focus, k.aperture) for k in result.keys], "focus": result.focus.tolist(),
            "aperture": result.aperture.tolist(), "nfts": result.nfts, "tracking": result.tracking,
            "raw": np.nan_to_num(result.signal["raw"], nan=-99).tolist(),
            "held": np.nan_to_num(result.signal["held"], nan=-99).tolist(), "boxes": result.boxes,
            "detectors": {n: {k: v for k, v in m.items() if not k.startswith("s_per")}
                          for n, m in result.detectors.items()}}


def chunked_laaf(settings, folder: Path, n: int, chunk: int):
    """LAAF measured in chunks (files written and read back), decided in one AutofocusJob."""
    from rvr_addon.batch.chunks import chunk_ranges
    from rvr_addon.laaf.analysis import measure_range, read_measurements, write_measurements
    from rvr_addon.laaf.lookahead import AutofocusJob

    files = []
    for a, b in chunk_ranges(n, chunk):
        files.append(folder / f"analysis_{a:06d}.npz")
        assert write_measurements(files[-1], {"range": (a, b)}, measure_range(settings, a, b)) == b - a
    return AutofocusJob(settings, frames=read_measurements(files)).run(progress=False)
