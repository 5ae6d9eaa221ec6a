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
