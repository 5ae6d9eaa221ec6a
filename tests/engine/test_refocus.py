"""rvr refocus: the one command from a clip to a refocused video (estimate -> stabilize ->
autofocus -> render, + before | after video and contact sheet), its re-use of finished work,
resume after Ctrl-C, pinned focus, the working copy (resize / range) and refused outputs.

Clips are 64x36, 12 frames (tests/batch_synth.py); depth from the shipped network alone
(``--depth-method network``) keeps them fast and deterministic."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from batch_synth import N, make_clip
from rvr_addon.cli import build_parser, main
from rvr_addon.io.video import iter_frames, probe_clip
from rvr_addon.refocus.chain import JobChain, Stage
from rvr_addon.refocus.commands import settings_from_args
from rvr_addon.refocus.proxy import proxy_size

FAST = ["--depth-method", "network", "-q"]


@pytest.fixture(scope="module")
def clip(tmp_path_factory) -> Path:
    return make_clip(tmp_path_factory.mktemp("refocus") / "clip.mp4", seed=3)


@pytest.fixture(scope="module")
def reference(clip, tmp_path_factory):
    """One complete run with every output; returns its folder."""
    out = tmp_path_factory.mktemp("ref")
    assert main(["refocus", str(clip), "-o", str(out / "r.mp4"), "--preview", "--side-by-side", *FAST]) == 0
    return out


def frames_of(path: Path) -> np.ndarray:
    return np.stack(list(iter_frames(path)))


def test_one_command_writes_the_video_its_focus_file_a_sheet_and_a_before_after(clip, reference):
    info = probe_clip(reference / "r.mp4")
    assert (info.width, info.height, info.frame_count) == (64, 36, N)
    doc = json.loads((reference / "r.focus.json").read_text())
    assert len(doc["per_frame"]["focus"]) == N and doc["settings"].get("preset_used")
    assert all(np.isfinite(v) for v in doc["per_frame"]["focus"])
    sbs = probe_clip(reference / "r_side_by_side.mp4")
    assert (sbs.width, sbs.frame_count) == (2 * 64 + 4, N)
    import cv2

    sheet = cv2.imread(str(reference / "r_sheet.png"))
    assert sheet is not None and sheet.shape[1] == 1500 and sheet.shape[0] > 100
    work = list((reference / "rvr_cache").iterdir())
    assert len(work) == 1 and work[0].name.startswith("clip-")
    assert (work[0] / "cache" / "meta.json").is_file() and list(work[0].glob("focus-*.json"))
    meta = json.loads((work[0] / "cache" / "meta.json").read_text())
    assert meta["stabilized"]["settings"]["window"] == "centred"  # a recorded clip has its future


def test_causal_means_no_later_frame_for_the_temporal_filter_either(clip, tmp_path):
    assert main(["refocus", str(clip), "-o", str(tmp_path / "c.mp4"), "--causal", *FAST]) == 0
    meta = json.loads(next((tmp_path / "rvr_cache").glob("*/cache/meta.json")).read_text())
    assert meta["stabilized"]["settings"]["window"] == "causal"


def test_a_second_run_reuses_the_depth_and_the_focus_decision(clip, reference, capsys):
    before = frames_of(reference / "r.mp4")
    assert main(["refocus", str(clip), "-o", str(reference / "r.mp4"), *FAST]) == 0
    printed = capsys.readouterr().out
    assert "reused" in printed and "autofocus" in printed.split("reused")[-1]
    np.testing.assert_array_equal(frames_of(reference / "r.mp4"), before)


def _reused(printed: str) -> list[str]:
    """The stages the ``time:`` line of a refocus run says were reused."""
    line = next(t for t in printed.splitlines() if t.startswith("time:"))
    return line.split("(reused: ")[1].rstrip(")").split(", ") if "(reused: " in line else []


def test_the_same_render_again_is_reused_and_a_change_renders_anew(clip, tmp_path, capsys):
    """Adding --preview (or --side-by-side) to a finished run makes only the sheet: the render is
    the same (same depth, focus file and render settings) and its file is as it was written. Another
    aperture, or an output touched since, renders again."""
    out = tmp_path / "s.mp4"
    args = ["refocus", str(clip), "-o", str(out), *FAST[:-1]]
    assert main(args) == 0
    first, frames = out.stat().st_mtime_ns, frames_of(out)
    capsys.readouterr()
    assert main([*args, "--preview"]) == 0
    printed = capsys.readouterr().out
    assert "render" in _reused(printed) and f"kept {out} (unchanged)" in printed and "render: reused" in printed
    assert out.stat().st_mtime_ns == first and (tmp_path / "s_sheet.png").is_file()
    assert main([*args, "--f-stop", "1.4"]) == 0  # another aperture: rendered again
    assert "render" not in _reused(capsys.readouterr().out) and not np.array_equal(frames_of(out), frames)
    assert main(args) == 0  # back to the first aperture: its record no longer matches the file
    assert "render" not in _reused(capsys.readouterr().out)
    np.testing.assert_array_equal(frames_of(out), frames)
    out.write_bytes(out.read_bytes())  # touched by someone else: rendered again
    assert main(args) == 0 and "render" not in _reused(capsys.readouterr().out)


def test_ctrl_c_keeps_the_work_and_the_same_command_continues(clip, reference, tmp_path, monkeypatch, capsys):
    from rvr_addon.pipeline import RenderJob

    original = RenderJob.step
    calls = {"n": 0}

    def interrupted(self):
        calls["n"] += 1
        if calls["n"] == 5:
            raise KeyboardInterrupt
        return original(self)

    monkeypatch.setattr(RenderJob, "step", interrupted)
    out = tmp_path / "r.mp4"
    assert main(["refocus", str(clip), "-o", str(out), *FAST]) == 130
    err = capsys.readouterr().err
    assert "interrupted during render" in err and "run the same command again" in err
    assert not out.exists() and not [p for p in tmp_path.iterdir() if p.name.startswith(".r.mp4")]
    monkeypatch.setattr(RenderJob, "step", original)
    assert main(["refocus", str(clip), "-o", str(out), *FAST]) == 0
    assert "estimate" not in capsys.readouterr().out.split("reused")[0].split("time:")[-1]
    np.testing.assert_array_equal(frames_of(out), frames_of(reference / "r.mp4"))


def test_focus_on_pins_the_subject_at_that_point(clip, tmp_path):
    out = tmp_path / "pinned.mp4"
    assert main(["refocus", str(clip), "-o", str(out), "--focus-on", "17,18", "--cache", str(tmp_path / "w"),
                 *FAST]) == 0
    doc = json.loads((tmp_path / "pinned.focus.json").read_text())
    first = doc["nfts"][0]
    assert first["source"] == "manual" and first["t"] == 0 and (first["x"], first["y"]) == (17.0, 18.0)
    assert doc["settings"].get("preset") is None
    assert (tmp_path / "w" / "cache" / "meta.json").is_file()


def test_max_size_and_a_range_make_a_working_copy_of_that_size_and_length(clip, tmp_path):
    out = tmp_path / "small.mp4"
    assert main(["refocus", str(clip), "-o", str(out), "--max-size", "32", "--start", "2", "--duration", "0.25",
                 *FAST]) == 0
    info = probe_clip(out)
    assert (info.width, info.height, info.frame_count) == (32, 18, 6)  # 0.25 s at 24 fps
    doc = json.loads((tmp_path / "small.focus.json").read_text())
    assert doc["clip"]["width"] == 32


def test_an_output_that_is_the_input_is_refused_before_anything_runs(clip, tmp_path, capsys):
    data = clip.read_bytes()
    assert main(["refocus", str(clip), "-o", str(clip.parent / ".." / clip.parent.name / clip.name), *FAST]) == 2
    assert "same file or folder as the clip" in capsys.readouterr().err
    assert clip.read_bytes() == data
    assert main(["refocus", str(clip), "-o", str(tmp_path / "x.mov.txt"), *FAST]) == 2
    same = str(tmp_path / "a.mp4")
    assert main(["refocus", str(clip), "-o", same, "--side-by-side", same, *FAST]) == 2
    assert "give each its own name" in capsys.readouterr().err


def test_f_stop_is_an_aperture_relative_to_the_f2_reference_lens(clip):
    args = build_parser().parse_args(["refocus", str(clip), "--f-stop", "1"])
    assert settings_from_args(args).aperture == pytest.approx(2.0)
    args = build_parser().parse_args(["refocus", str(clip), "--f-stop", "4"])
    s = settings_from_args(args)
    assert s.aperture == pytest.approx(0.5) and s.output == clip.with_name("clip_refocused.mp4")
    args = build_parser().parse_args(["refocus", str(clip), "--aperture", "0"])
    assert settings_from_args(args).aperture == 0.0


def test_proxy_size_keeps_the_aspect_and_even_sides():
    assert proxy_size(1920, 1080, 1280) == (1280, 720)
    assert proxy_size(1080, 1920, 1280) == (720, 1280)
    assert proxy_size(640, 360, 1280) == (640, 360)
    assert proxy_size(1919, 1079, None) == (1919, 1079)
    assert proxy_size(101, 3, 50) == (50, 2)


class _Job:
    def __init__(self, n):
        self.n, self.done, self.total, self.cancelled = n, 0, n, False

    @property
    def progress(self):
        return self.done / self.n

    def step(self):
        self.done += 1
        return self.done < self.n

    def cancel(self):
        self.cancelled = True


def test_job_chain_runs_stages_in_turn_weights_progress_and_cancels_the_running_one():
    jobs, finished = [], []

    def make(n):
        def build():
            jobs.append(_Job(n))
            return jobs[-1]
        return build

    chain = JobChain([Stage("a", 1.0, make(2), finished.append), Stage("skip", 5.0, lambda: None),
                      Stage("b", 3.0, make(4))])
    seen = [chain.progress]
    while chain.step():
        seen.append(chain.progress)
    assert seen == sorted(seen) and chain.progress == 1.0
    assert finished == [jobs[0]] and chain.skipped == ["skip"] and len(jobs) == 2
    chain = JobChain([Stage("a", 1.0, make(3)), Stage("b", 1.0, make(3))])
    chain.step()
    assert chain.frame_text() == "frame 1/3"
    chain.cancel()
    assert jobs[-1].cancelled and not chain.step() and "cancelled during a" in chain.text


def test_cuts_and_calm_reach_the_autofocus_in_frames_of_the_working_copy(clip, tmp_path):
    out = tmp_path / "c.mp4"
    assert main(["refocus", str(clip), "-o", str(out), "--start", "2", "--cuts", "5,9,40", "--calm", "0.2",
                 *FAST]) == 0
    doc = json.loads((tmp_path / "c.focus.json").read_text())
    assert doc["cuts"] == [3, 7] and doc["settings"]["cuts_source"] == "given"  # 40 is beyond the clip
    assert doc["settings"]["calm"]["calm"] == 0.2
    assert main(["refocus", str(clip), "-o", str(out), "--calm", "2", *FAST]) == 2


def test_an_edited_focus_file_renders_again_without_autofocus(clip, reference, tmp_path, capsys):
    doc = json.loads((reference / "r.focus.json").read_text())
    doc["per_frame"]["focus"] = [5.0] * N  # the user's own decision
    edited = tmp_path / "edited.focus.json"
    edited.write_text(json.dumps(doc))
    out = tmp_path / "e.mp4"
    assert main(["refocus", str(clip), "-o", str(out), "--track", str(edited), "--cache",
                 str(next((reference / "rvr_cache").iterdir())), *FAST]) == 0
    assert "no autofocus" in capsys.readouterr().out
    assert json.loads((tmp_path / "e.focus.json").read_text())["per_frame"]["focus"] == [5.0] * N
    assert not np.array_equal(frames_of(out), frames_of(reference / "r.mp4"))
    assert main(["refocus", str(clip), "-o", str(out), "--track", str(tmp_path / "none.json"), *FAST]) == 2


def test_the_render_decodes_each_cache_frame_once(clip, reference, tmp_path, monkeypatch):
    """The cache's D and E live in one EXR per frame: the render reads each of them once
    (the first frame twice: the job opens on it), not once for D and once for E."""
    from collections import Counter

    import rvr_addon.io.exr as exr

    reads: Counter = Counter()
    real = exr.read_exr

    def counting(path):
        reads[Path(path).name] += 1
        return real(path)

    monkeypatch.setattr(exr, "read_exr", counting)
    out = tmp_path / "again.mp4"
    assert main(["refocus", str(clip), "-o", str(out), "--track", str(reference / "r.focus.json"), "--cache",
                 str(next((reference / "rvr_cache").iterdir())), *FAST]) == 0
    frames = sorted(n for n in reads if n.startswith("frame_"))
    assert len(frames) == N
    assert sum(reads[n] for n in frames) <= N + 1, reads
    np.testing.assert_array_equal(frames_of(out), frames_of(reference / "r.mp4"))


def test_a_label_fits_a_narrow_portrait_column():
    """A caption wider than its picture (a portrait clip's column on the contact sheet) is shrunk,
    then wrapped, so no text runs into the next column; a wide picture keeps one line."""
    from rvr_addon.refocus.sidebyside import label

    text = "frame 120 (4.8 s), focus D=-3.21 (face)"
    for h, w in ((720, 404), (240, 60), (30, 20), (360, 640)):
        out = label(np.full((h, w, 3), 80, np.uint8), text)
        assert out.shape == (h, w, 3)
        if w >= 60:  # the text ends before the right edge: nothing cut off
            assert np.flatnonzero((out > 200).all(axis=2).any(axis=0)).max() < w - 2
    wide = label(np.full((360, 640, 3), 80, np.uint8), text)
    rows = np.flatnonzero((wide == 0).all(axis=2).any(axis=1))
    narrow = label(np.full((720, 120, 3), 80, np.uint8), text)
    rows_n = np.flatnonzero((narrow == 0).all(axis=2).any(axis=1))
    assert rows_n.max() > rows.max()  # wrapped into more than one line
    assert (narrow[: rows_n.max() + 1] == 255).any()


def test_a_photo_is_refocused_into_a_picture_of_its_own_type(clip, tmp_path, capsys):
    """``rvr refocus photo.png`` writes ``photo_refocused.png`` (not a one-frame video); a photo
    larger than --max-size gets a lossless PNG working copy; a picture output of a multi-frame clip
    is refused before any work (an earlier picture there survives), one frame of it is accepted."""
    import cv2

    frame = next(iter(iter_frames(clip)))
    photo = tmp_path / "photo.png"
    cv2.imwrite(str(photo), cv2.cvtColor(cv2.resize(frame, (128, 72)), cv2.COLOR_RGB2BGR))
    assert main(["refocus", str(photo), "--max-size", "96", "--side-by-side", *FAST]) == 0
    out = cv2.imread(str(tmp_path / "photo_refocused.png"))
    assert out is not None and out.shape == (54, 96, 3)
    assert cv2.imread(str(tmp_path / "photo_refocused_side_by_side.png")).shape == (54, 2 * 96 + 4, 3)
    assert (tmp_path / "photo_refocused.focus.json").is_file()
    assert not list(tmp_path.glob("photo_refocused*.mp4"))
    work = next((tmp_path / "rvr_cache").iterdir())
    assert [p.name for p in work.glob("picture_*.png")] == ["picture_96x54.png"]
    before = (tmp_path / "photo_refocused.png").read_bytes()
    capsys.readouterr()
    assert main(["refocus", str(clip), "-o", str(tmp_path / "photo_refocused.png"), *FAST]) != 0
    err = capsys.readouterr().err
    assert "a picture holds one frame" in err and "--start" in err
    assert (tmp_path / "photo_refocused.png").read_bytes() == before  # nothing overwritten
    assert [p.name for p in (tmp_path / "rvr_cache").iterdir()] == [work.name]  # refused before any work
    assert main(["refocus", str(clip), "--start", "2", "--stop", "3", "-o", str(tmp_path / "f2.jpg"), *FAST]) == 0
    assert cv2.imread(str(tmp_path / "f2.jpg")).shape == (36, 64, 3)


def test_still_image_writer_is_atomic_and_holds_one_frame(tmp_path):
    from rvr_addon.errors import InputError, OutputError
    from rvr_addon.io.exr import read_exr
    from rvr_addon.io.writer import StillImageWriter

    target = tmp_path / "p.jpg"
    target.write_bytes(b"earlier")
    w = StillImageWriter(target)
    w.write(np.full((4, 6, 3), 200, np.uint8))
    assert target.read_bytes() == b"earlier"  # not before close
    with pytest.raises(InputError, match="single picture"):
        w.write(np.full((4, 6, 3), 200, np.uint8))
    w.abort()
    assert target.read_bytes() == b"earlier" and [p.name for p in tmp_path.iterdir()] == ["p.jpg"]
    with StillImageWriter(target) as w:
        w.write(np.full((4, 6, 3), 200, np.uint8))
    import cv2

    assert cv2.imread(str(target)).shape == (4, 6, 3)
    with StillImageWriter(tmp_path / "h.exr") as w:
        assert w.linear
        w.write(np.full((4, 6, 3), 7.5, np.float32))
    assert float(read_exr(tmp_path / "h.exr")["R"].max()) == pytest.approx(7.5)
    with pytest.raises(InputError, match="uint8"):
        StillImageWriter(tmp_path / "q.png").write(np.zeros((4, 6, 3), np.float32))
    with pytest.raises(OutputError, match="No picture"):
        StillImageWriter(tmp_path / "e.png").close()
    with pytest.raises(InputError, match="picture is written as"):
        StillImageWriter(tmp_path / "e.gif")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["h.exr", "p.jpg"]


def test_a_new_decision_logic_makes_the_focus_decision_again(tmp_path, monkeypatch):
    """rvr refocus reuses a focus file by its depth and settings; a change of LAAF's decision
    (DECISION_VERSION) must not reuse one made by the old logic (nor may rvr batch's markers)."""
    from rvr_addon.batch.settings import BatchSettings
    from rvr_addon.laaf import presets
    from rvr_addon.refocus.job import focus_key

    (tmp_path / "meta.json").write_text("{}")
    settings = {"preset": "auto", "window_s": 2.0}
    before = focus_key(tmp_path, settings), BatchSettings(output=tmp_path).fingerprint("w")
    assert before == (focus_key(tmp_path, settings), BatchSettings(output=tmp_path).fingerprint("w"))
    monkeypatch.setattr(presets, "DECISION_VERSION", presets.DECISION_VERSION + 1)
    after = focus_key(tmp_path, settings), BatchSettings(output=tmp_path).fingerprint("w")
    assert after[0] != before[0] and after[1] != before[1]


def test_refocus_takes_the_pull_options_and_they_name_the_focus_decision(tmp_path):
    args = build_parser().parse_args(["refocus", "clip.mp4", "--pull-frames", "6", "--profile", "ease_in_out_sine"])
    s = settings_from_args(args)
    assert (s.pull.pull_frames, s.pull.lead_frames, s.pull.profile) == (6, None, "ease_in_out_sine")
    assert settings_from_args(build_parser().parse_args(["refocus", "clip.mp4"])).pull.at_fps(60).pull_frames == 24
    with pytest.raises(Exception, match="pull-frames"):
        settings_from_args(build_parser().parse_args(["refocus", "clip.mp4", "--pull-frames", "0"]))


def test_a_variable_frame_rate_clip_keeps_sound_and_picture_in_sync(ffmpeg_run, tmp_path, capsys):
    """A phone's variable-frame-rate clip is read at its nominal constant rate, each frame at its
    time (no working copy needed at its own size), so the refocused video's flash is where its beep
    is (in decode order at the average rate it came 0.3 s early)."""
    from vfr_synth import assert_in_sync, flash_clip

    clip = flash_clip(ffmpeg_run, tmp_path / "vfr.mp4")
    out = tmp_path / "out.mp4"
    assert main(["refocus", str(clip), "-o", str(out), "--max-size", "0", "--depth-method", "network", "-q"]) == 0
    assert "variable frame rate" in capsys.readouterr().out
    assert_in_sync(out)


def test_rvr_render_of_a_variable_frame_rate_clip_keeps_sound_and_picture_in_sync(ffmpeg_run, tmp_path):
    """``rvr render`` alone (not only ``rvr refocus``) reads the clip's constant-rate timeline, and
    depth maps with one map per decoded frame are placed on it: the flash keeps its beep, and the
    maps that put the flash far out of focus blur the frames that show it."""
    from vfr_synth import assert_in_sync, flash_clip

    clip = flash_clip(ffmpeg_run, tmp_path / "vfr.mp4")
    maps = np.zeros((85, 180, 320), np.float32)
    maps[55:59] = 8.0  # decoded frames 55-58 are the flash: strongly blurred, the rest sharp
    np.save(tmp_path / "d.npy", maps)
    out = tmp_path / "out.mp4"
    assert main(["render", str(clip), "--depth", str(tmp_path / "d.npy"), "--focus", "0", "--aperture", "1",
                 "-o", str(out), "-q"]) == 0
    assert_in_sync(out)
    frames = list(iter_frames(out))
    flash = next(k for k, f in enumerate(frames) if f.mean() > 60)
    row = frames[flash][90, 60:140, 0].astype(float)  # across the flash box's left edge at x = 100
    assert np.abs(np.diff(row)).max() < 60  # blurred: its decoded frame's map (without placing: sharp)
