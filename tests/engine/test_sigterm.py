"""Issue 22.9: SIGTERM during ``rvr render`` (kill, a scheduler) is handled like Ctrl-C: the
ffmpeg encoder child is ended, the hidden ``*.tmp.mp4`` is removed, an earlier render survives,
and the command exits 143 with a message. It used to die on the spot, leaving both behind."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from rvr_addon.interrupts import Terminated, exit_status, sigterm_as_interrupt, terminated

W, H, N = 320, 240, 240


def _children(pid: int) -> list[int]:
    """Process ids whose parent is ``pid`` (Linux /proc)."""
    out = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
            out.append(int(stat.parent.name))
    return out


def _cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().decode(errors="replace")
    except OSError:
        return ""


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


def test_sigterm_raises_terminated_once_and_gives_143():
    with sigterm_as_interrupt():
        with pytest.raises(Terminated):
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(1)
        assert terminated() and exit_status() == 143
        os.kill(os.getpid(), signal.SIGTERM)  # a second one while stopping is ignored
        time.sleep(0.05)
    with sigterm_as_interrupt():
        assert not terminated() and exit_status() == 130


def test_a_sigterm_held_back_by_a_training_step_is_still_a_sigterm():
    from rvr_addon.training_run import deferred_interrupt, terminate_as_interrupt

    with sigterm_as_interrupt(), terminate_as_interrupt():
        done = []
        with pytest.raises(Terminated):
            with deferred_interrupt():
                os.kill(os.getpid(), signal.SIGTERM)
                done.append("update")
        assert done == ["update"] and exit_status() == 143


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs Linux /proc to find the ffmpeg child")
@pytest.mark.parametrize("source", ["png_frames", "mp4"])
def test_sigterm_during_a_render_ends_ffmpeg_and_removes_the_temp_file(tmp_path, source):
    if source == "mp4":  # decoded by an ffmpeg child too
        from rvr_addon.io.video import ffmpeg_exe

        clip = tmp_path / "clip.mp4"
        subprocess.run([ffmpeg_exe(), "-v", "error", "-y", "-f", "lavfi", "-i",
                        f"testsrc2=size={W}x{H}:rate=24:duration={N / 24}", "-pix_fmt", "yuv420p", "-c:v", "libx264",
                        "-preset", "ultrafast", str(clip)], check=True)
    else:
        clip = tmp_path / "clip"
        clip.mkdir()
        rng = np.random.default_rng(0)
        frame = (rng.random((H, W, 3)) * 255).astype(np.uint8)
        for i in range(N):
            cv2.imwrite(str(clip / f"f{i:04d}.png"), np.roll(frame, i, axis=1))
    depth = tmp_path / "d.npy"
    np.save(depth, np.tile(np.linspace(-8, 8, W, dtype=np.float32), (H, 1)))
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    out = out_dir / "render.mp4"
    out.write_bytes(b"an earlier render")
    proc = subprocess.Popen([sys.executable, "-m", "rvr_addon", "render", str(clip), "--depth", str(depth),
                             "--focus", "0", "--aperture", "2", "-o", str(out), "-q"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=Path(__file__).resolve().parents[2])
    try:
        deadline = time.monotonic() + 120
        tmp = []
        while time.monotonic() < deadline and proc.poll() is None:  # wait until it writes the temp video
            tmp = [p for p in out_dir.iterdir() if p.name.endswith(".tmp.mp4")]
            if tmp and tmp[0].stat().st_size > 0:
                break
            time.sleep(0.05)
        assert proc.poll() is None and tmp, ("the render ended before it wrote", proc.communicate())
        encoders = [c for c in _children(proc.pid) if "ffmpeg" in _cmdline(c)]  # ffmpeg children
        assert len(encoders) >= (2 if source == "mp4" else 1), encoders  # the encoder (and the decoder)
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    err = err.decode()
    assert proc.returncode == 143, err
    assert "terminated (SIGTERM)" in err and "Traceback" not in err
    assert [p.name for p in out_dir.iterdir()] == ["render.mp4"]  # no hidden temp file
    assert out.read_bytes() == b"an earlier render"
    time.sleep(0.2)
    assert not [pid for pid in encoders if _alive(pid)]  # the ffmpeg child is gone, not orphaned
