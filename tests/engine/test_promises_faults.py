"""Issue 22, beyond the list: kill each long command at seeded pseudo-random points (SIGINT,
SIGTERM, SIGKILL), re-run it, and check the promises: the re-run exits 0, its outputs equal an
uninterrupted run's (decoded video frames; cache EXR channels; focus JSON without its timings), no
temp file is left (``.*.tmp*``, ``*.rebuild-*``; the OS-lock files ``.CACHE.lock`` beside a cache
are documented in rvr_addon/io/lock.py and allowed), and the files that were there before (the
clip, the cache a render reads, an unrelated file) are byte-identical.

4 commands x 3 signals = 12 faults. Each command runs as ``python -m rvr_addon`` in a child
process; SIGINT and SIGKILL come after a seeded random delay within the command's measured
duration, SIGTERM once the first new file (an output, a cache frame, a hidden temp file) appears.
"""
from __future__ import annotations

import json
import os
import random
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from batch_synth import make_clip  # noqa: E402

REPO = Path(__file__).resolve().parents[2]
COUNTS = {"faults": 0, "killed_mid_run": 0, "files_lost": 0}
SIGNALS = [signal.SIGINT, signal.SIGTERM, signal.SIGKILL]


def _rvr(args: list[str], cwd: Path) -> subprocess.Popen:
    env = dict(os.environ, PYTHONPATH=str(REPO), OMP_NUM_THREADS="1")
    return subprocess.Popen([sys.executable, "-m", "rvr_addon", *args, "-q"], cwd=cwd, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _complete(args: list[str], cwd: Path) -> float:
    t = time.monotonic()
    p = _rvr(args, cwd)
    out, err = p.communicate(timeout=120)
    assert p.returncode == 0, f"rvr {' '.join(args)} exited {p.returncode}\n{err[-3000:]}"
    return time.monotonic() - t


def _snapshot(paths: list[Path]) -> dict[str, bytes]:
    files = []
    for p in paths:
        files += [p] if p.is_file() else sorted(q for q in p.rglob("*") if q.is_file())
    return {str(f): f.read_bytes() for f in files}


def _frames(video: Path) -> list[bytes]:
    import imageio_ffmpeg

    reader = imageio_ffmpeg.read_frames(str(video))
    next(reader)
    return [bytes(f) for f in reader]


def _channels(cache: Path) -> dict[str, dict[str, np.ndarray]]:
    from rvr_addon.io.exr import read_exr

    return {f.name: read_exr(f) for f in sorted(cache.glob("*.exr"))}


def _untimed(data):
    if isinstance(data, dict):
        return {k: _untimed(v) for k, v in data.items()
                if "second" not in k and not k.endswith("_s") and not k.startswith("s_per") and k not in ("created", "time", "date")}
    if isinstance(data, list):
        return [_untimed(v) for v in data]
    return data


def _equal_caches(a: Path, b: Path) -> None:
    ca, cb = _channels(a), _channels(b)
    assert ca.keys() == cb.keys() and ca, (sorted(ca), sorted(cb))
    for name in ca:
        assert ca[name].keys() == cb[name].keys(), name
        for ch in ca[name]:
            np.testing.assert_array_equal(ca[name][ch], cb[name][ch], err_msg=f"{name} {ch}")


def _leftovers(root: Path) -> list[Path]:
    return [p for p in root.rglob("*") if (p.name.startswith(".") and ".tmp" in p.name) or ".rebuild-" in p.name
            or p.name.endswith(".tmp")]


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    """The clip, an uninterrupted run of every command (the references) and their durations."""
    root = tmp_path_factory.mktemp("faults")
    clip = make_clip(root / "clip.mp4", seed=5, frames=12)
    ref = root / "ref"
    ref.mkdir()
    shutil.copy(clip, ref / "clip.mp4")
    dur = {"estimate": _complete(["estimate", "clip.mp4", "-o", "cache", "--depth-method", "network"], ref)}
    shutil.copytree(ref / "cache", ref / "cache_raw")
    dur["stabilize"] = _complete(["stabilize", "cache"], ref)
    dur["render"] = _complete(["render", "clip.mp4", "--depth", "cache", "--hdr", "cache", "--aperture", "2",
                               "-o", "out.mp4", "--no-audio"], ref)
    dur["refocus"] = _complete(["refocus", "clip.mp4", "--depth-method", "network", "--no-cuts", "-o", "ref.mp4",
                                "--cache", "rc"], ref)
    return root, clip, ref, dur


COMMANDS = {
    "estimate": (["estimate", "clip.mp4", "-o", "cache", "--depth-method", "network"], "cache"),
    "stabilize": (["stabilize", "cache"], "cache"),
    "render": (["render", "clip.mp4", "--depth", "cache", "--hdr", "cache", "--aperture", "2", "-o", "out.mp4",
                "--no-audio"], "out.mp4"),
    "refocus": (["refocus", "clip.mp4", "--depth-method", "network", "--no-cuts", "-o", "ref.mp4", "--cache", "rc"],
                "rc"),
}


def _setup(work: Path, command: str, clip: Path, ref: Path) -> list[Path]:
    """The folder before the command; returns the pre-existing paths that must not change."""
    work.mkdir()
    shutil.copy(clip, work / "clip.mp4")
    (work / "notes.txt").write_text("an unrelated file")
    keep = [work / "clip.mp4", work / "notes.txt"]
    if command == "stabilize":
        shutil.copytree(ref / "cache_raw", work / "cache")
    elif command == "render":
        shutil.copytree(ref / "cache", work / "cache")
        keep.append(work / "cache")
    return keep


def _new_file(work: Path, known: set[str]) -> bool:
    return any(q.is_file() and str(q) not in known and not q.name.endswith(".lock") for q in work.rglob("*"))


def _kill(p: subprocess.Popen, sig: int, delay: float, watch: Path | None) -> bool:
    """Send ``sig`` after ``delay`` s, or (``watch``: the work folder) once a new file (output, cache
    frame, hidden temp file) appears in it; True if it hit a running process."""
    known = {str(q) for q in watch.rglob("*")} if watch is not None else set()
    deadline = time.monotonic() + (30.0 if watch is not None else delay)
    while time.monotonic() < deadline and p.poll() is None:
        if watch is not None and _new_file(watch, known):
            break
        time.sleep(0.005)
    hit = p.poll() is None
    if hit:
        p.send_signal(sig)
    p.communicate(timeout=60)
    return hit


@pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")
@pytest.mark.parametrize("command", list(COMMANDS))
def test_killed_at_random_points_the_rerun_completes_and_equals_an_uninterrupted_run(world, command):
    root, clip, ref, dur = world
    rng = random.Random(f"rvr-faults-{command}")
    args, _output = COMMANDS[command]
    for sig in SIGNALS:
        work = root / f"{command}_{sig.name}"
        keep = _setup(work, command, clip, ref)
        before = _snapshot(keep)
        watch = work if sig == signal.SIGTERM else None
        delay = rng.uniform(0.15, 0.95) * dur[command]
        COUNTS["faults"] += 1
        proc = _rvr(args, work)
        COUNTS["killed_mid_run"] += _kill(proc, sig, delay, watch)
        _complete(args, work)  # the re-run completes
        after = _snapshot(keep)
        lost = [k for k in before if after.get(k) != before[k]]
        COUNTS["files_lost"] += len(lost)
        assert not lost, f"{command} killed by {sig.name}: pre-existing files changed or lost: {lost}"
        assert not _leftovers(work), f"{command} killed by {sig.name}: temp files left: {_leftovers(work)}"
        if command in ("estimate", "stabilize"):
            _equal_caches(work / "cache", ref / "cache" if command == "stabilize" else ref / "cache_raw")
        elif command == "render":
            assert _frames(work / "out.mp4") == _frames(ref / "out.mp4"), f"render after {sig.name} differs"
        else:
            assert _frames(work / "ref.mp4") == _frames(ref / "ref.mp4"), f"refocus after {sig.name} differs"
            focus = sorted(work.glob("*.json"))
            assert [f.name for f in focus] == [f.name for f in sorted(ref.glob("*.json"))]
            for f in focus:
                assert _untimed(json.loads(f.read_text())) == _untimed(json.loads((ref / f.name).read_text())), f


def test_zz_report_faults():
    print(f"\npromises fault test: {COUNTS['faults']} faults injected ({COUNTS['killed_mid_run']} hit a running "
          f"command), files lost: {COUNTS['files_lost']}")
    assert COUNTS["files_lost"] == 0


def test_a_writer_removes_the_temp_files_a_sigkilled_writer_left(world, tmp_path):
    """SIGKILL cannot clean up: the next writer (it holds the cache's lock) removes the hidden temp
    files of frames and meta.json; the frames and the lock file stay."""
    from rvr_addon.estimate.cache import ClipCache

    _, _, ref, _ = world
    cache = tmp_path / "cache"
    shutil.copytree(ref / "cache", cache)
    stale = [cache / ".frame_00001.exr.2d1a2372.exr", cache / "..frame_00002.exr.2d1a2372.exr.258ea074.tmp.exr",
             cache / ".meta.json.0a1b2c3d.json"]
    for p in stale:
        p.write_bytes(b"half a file")
    ClipCache.open_existing(cache).close()
    assert not any(p.exists() for p in stale) and (cache / "frame_00001.exr").is_file()
    assert _channels(cache).keys() == _channels(ref / "cache").keys()
