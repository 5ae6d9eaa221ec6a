"""Issue 22.5: every command's write path ends in a clear message (naming the file and the fix),
exit status 2, no traceback, and the earlier result kept: a read-only output folder (as root,
where chmod restricts nothing, an output path under a regular file), a full disk (simulated at
the write call), an ffmpeg that dies mid-stream (was ``ValueError: seek of closed file``), a
truncated source with audio."""
from __future__ import annotations

import errno
import json
import os
import subprocess
from pathlib import Path

import cv2
import numpy as np
import pytest

from rvr_addon.cli import main
from rvr_addon.errors import OutputError, output_error
from rvr_addon.io.video import ffmpeg_exe
from rvr_addon.io.writer import VideoWriter

W, H, N = 40, 30, 6
ROOT = os.geteuid() == 0


@pytest.fixture
def clip(tmp_path):
    folder = tmp_path / "clip"
    folder.mkdir()
    rng = np.random.default_rng(0)
    for i in range(N):
        cv2.imwrite(str(folder / f"f{i:03d}.png"), (rng.random((H, W, 3)) * 255).astype(np.uint8))
    return folder


@pytest.fixture
def maps(tmp_path):
    folder = tmp_path / "maps"
    folder.mkdir()
    for i in range(N):
        np.save(folder / f"d_{i:04d}.npy", np.tile(np.linspace(-3, 3, W, dtype=np.float32), (H, 1)))
    return folder


@pytest.fixture
def unwritable(tmp_path):
    """A folder nothing can be written in: chmod 555, or (as root, where chmod restricts nothing)
    a regular file standing where the folder should be."""
    if ROOT:
        blocker = tmp_path / "not_a_folder"
        blocker.write_text("a file")
        yield blocker
        return
    folder = tmp_path / "readonly"
    folder.mkdir()
    folder.chmod(0o555)
    yield folder
    folder.chmod(0o755)


def _leftovers(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.rglob(".*")) if folder.is_dir() else []


def _fails_cleanly(capsys, argv: list[str], *named: str) -> str:
    rc = main(argv)  # an exception escaping main() (a traceback) fails the test
    err = capsys.readouterr().err
    assert rc == 2, err
    assert "rvr: error:" in err and "Traceback" not in err
    for name in named:
        assert name in err, err
    return err


def test_output_error_says_why_and_how_to_fix():
    assert "disk is full" in str(output_error("/a/b.json", OSError(errno.ENOSPC, "No space left on device")))
    assert "not writable" in str(output_error("/a/b.json", PermissionError(errno.EACCES, "Permission denied")))
    assert "'/a/b.json'" in str(output_error("/a/b.json", OSError(errno.EIO, "I/O error")))


@pytest.mark.parametrize("kind", ["mp4", "frames"])
def test_render_into_an_unwritable_folder(clip, maps, unwritable, capsys, kind):
    out = unwritable / ("r.mp4" if kind == "mp4" else "frames")
    _fails_cleanly(capsys, ["render", str(clip), "--depth", str(maps), "--focus", "0", "-o", str(out), "-q"], str(out))


def test_autofocus_into_an_unwritable_folder_and_onto_a_full_disk(clip, maps, unwritable, capsys, monkeypatch,
                                                                   tmp_path):
    out = unwritable / "focus.json"
    argv = ["autofocus", str(clip), "--depth", str(maps), "--preset", "salient", "-q", "-o"]
    _fails_cleanly(capsys, argv + [str(out)], str(out), "focus file")
    earlier = tmp_path / "focus.json"
    earlier.write_text("an earlier focus file")
    real = Path.write_text

    def full(self, *a, **kw):
        if self.name.startswith(".focus.json"):
            raise OSError(errno.ENOSPC, "No space left on device", str(self))
        return real(self, *a, **kw)

    monkeypatch.setattr(Path, "write_text", full)
    _fails_cleanly(capsys, argv + [str(earlier)], str(earlier), "disk is full")
    assert earlier.read_text() == "an earlier focus file" and not _leftovers(tmp_path)


def test_estimate_into_an_unwritable_folder(clip, maps, unwritable, capsys):
    out = unwritable / "cache"
    _fails_cleanly(capsys, ["estimate", str(clip), "--depth", str(maps), "-o", str(out), "-q"], str(out))


class _FullDiskEXR:
    """Stands in for OpenEXR.File: writing raises ENOSPC, as a full disk does."""

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False

    def write(self, name):
        raise OSError(errno.ENOSPC, "No space left on device", name)


def test_estimate_and_stabilize_onto_a_full_disk_or_a_read_only_cache(clip, maps, tmp_path, capsys, monkeypatch):
    import OpenEXR

    cache = tmp_path / "cache"
    assert main(["estimate", str(clip), "--depth", str(maps), "-o", str(cache), "-q"]) == 0
    before = {p.name: p.read_bytes() for p in cache.iterdir() if p.is_file()}
    if ROOT:
        real = OpenEXR.File
        monkeypatch.setattr(OpenEXR, "File", lambda *a, **kw: _FullDiskEXR() if isinstance(a[0], dict) else real(*a, **kw))
    else:
        cache.chmod(0o555)
    try:
        err = _fails_cleanly(capsys, ["stabilize", str(cache), "-q"], str(cache))
        assert "disk space" in err or "writ" in err
        if ROOT:
            _fails_cleanly(capsys, ["estimate", str(clip), "--depth", str(maps), "-o", str(tmp_path / "c2"), "-q"],
                           str(tmp_path / "c2"))
    finally:
        cache.chmod(0o755)
    after = {p.name: p.read_bytes() for p in cache.iterdir() if p.is_file() and not p.name.startswith(".")}
    assert after.keys() == before.keys()
    assert {k: v for k, v in after.items() if k != "meta.json"} == {k: v for k, v in before.items() if k != "meta.json"}
    assert json.loads(after["meta.json"])["frames"] == json.loads(before["meta.json"])["frames"]  # frames still valid


def test_ffmpeg_dying_mid_stream_is_an_output_error_naming_the_file(tmp_path):
    """Was ``ValueError: seek of closed file``: abort() closed ffmpeg's log before it was read."""
    out = tmp_path / "out" / "r.mp4"
    out.parent.mkdir()
    out.write_bytes(b"an earlier render")
    w = VideoWriter(out, fps=24, size=(64, 48))
    w.write(np.zeros((48, 64, 3), np.uint8))
    w._proc.kill()
    w._proc.wait()
    with pytest.raises(OutputError, match="ffmpeg stopped after .* frames while writing '.*r.mp4'.*kept"):
        for _ in range(200):  # the pipe's buffer takes a few frames before it breaks
            w.write(np.zeros((48, 64, 3), np.uint8))
    assert out.read_bytes() == b"an earlier render" and _leftovers(out.parent) == []
    w.abort()  # idempotent


def test_output_folder_becoming_unwritable_mid_stream(tmp_path):
    out = tmp_path / "out" / "r.mp4"
    out.parent.mkdir()
    w = VideoWriter(out, fps=24, size=(64, 48))
    if ROOT:  # ffmpeg opens its output once frames arrive: make the folder a file before that
        out.parent.rename(tmp_path / "moved")
        out.parent.write_text("a file")
    else:
        out.parent.chmod(0o555)
    try:
        with pytest.raises(OutputError, match="r.mp4") as info:
            for _ in range(200):
                w.write(np.zeros((48, 64, 3), np.uint8))
            w.close()
        assert "Traceback" not in str(info.value)
    finally:
        if not ROOT:
            out.parent.chmod(0o755)


def test_a_truncated_source_with_audio_renders_or_fails_cleanly(tmp_path, maps, capsys):
    src = tmp_path / "av.mp4"
    subprocess.run([ffmpeg_exe(), "-v", "error", "-y", "-f", "lavfi", "-i", f"testsrc2=size={W}x{H}:rate=24:duration=2",
                    "-f", "lavfi", "-i", "sine=frequency=440:sample_rate=48000:duration=2", "-c:v", "libx264",
                    "-pix_fmt", "yuv420p", "-c:a", "aac", "-shortest", "-movflags", "+faststart", str(src)], check=True)
    depth = tmp_path / "d.npy"
    np.save(depth, np.tile(np.linspace(-3, 3, W, dtype=np.float32), (H, 1)))
    data = src.read_bytes()
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    for i, frac in enumerate((0.3, 0.6, 0.9)):
        cut = tmp_path / f"cut{i}.mp4"
        cut.write_bytes(data[: int(len(data) * frac)])
        out = out_dir / f"r{i}.mp4"
        rc = main(["render", str(cut), "--depth", str(depth), "--focus", "0", "-o", str(out), "-q"])
        err = capsys.readouterr().err
        assert rc in (0, 2) and "Traceback" not in err, err
        assert out.is_file() == (rc == 0)
        if rc == 2:
            assert str(cut) in err or str(out) in err
    assert _leftovers(out_dir) == []


def test_a_stray_os_error_in_any_command_is_a_message_not_a_traceback(clip, maps, tmp_path, capsys, monkeypatch):
    """The safety net in main(): a write path without its own message still ends in exit 2."""
    from rvr_addon.pipeline import RenderJob

    target = tmp_path / "out" / "r.mp4"

    def full(self, progress=True):
        raise OSError(errno.ENOSPC, "No space left on device", str(target))

    monkeypatch.setattr(RenderJob, "run", full)
    _fails_cleanly(capsys, ["render", str(clip), "--depth", str(maps), "--focus", "0", "-o", str(target), "-q"],
                   str(target), "No space left on device", "free space")
