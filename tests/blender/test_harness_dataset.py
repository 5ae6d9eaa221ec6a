"""`python -m sintel_eval generate` on tiny clips (64x36, 2-4 samples): the folder layout of
sintel_eval/DATASET.md, exact ground truth, lens records, training sidecars, events, and
resuming after an interruption."""
from __future__ import annotations

import json
import os
from pathlib import Path

import cv2
import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from rvr_addon.color import linear_to_srgb, srgb_to_linear  # noqa: E402
from rvr_addon.errors import InputError  # noqa: E402
from rvr_addon.io.exr import read_exr  # noqa: E402
from rvr_addon.io.track import load_track, resolve_track  # noqa: E402
from rvr_addon.io.video import probe_clip  # noqa: E402
from sintel_eval.dataset import GenerateConfig, frame_complete, generate  # noqa: E402

W, H, N = 64, 36, 6
CFG = GenerateConfig(seed=5, frames=N, width=W, height=H, script="enter", samples=2, dof_samples=4,
                     train_every=3, pull_frames=2)


@pytest.fixture(scope="module")
def clip(tmp_path_factory):
    out = tmp_path_factory.mktemp("harness") / "enter5"
    result = generate(out, CFG, progress=False)
    return out, result, json.loads((out / "manifest.json").read_text())


def _png(path: Path) -> np.ndarray:
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    assert img is not None, path
    return img[..., ::-1]


def _rgb(path: Path) -> np.ndarray:
    ch = read_exr(path)
    return np.dstack([ch[c] for c in "RGB"])


def test_layout_markers_and_videos(clip, stream_info):
    out, result, manifest = clip
    assert result.rendered == list(range(1, N + 1)) and result.kept == []
    assert manifest["format"] == "rvr-laaf-harness/1" and manifest["status"] == {"complete": True, "frames_done": N}
    h = manifest["config_hash"]
    for k in range(1, N + 1):
        name = f"frame_{k:05d}"
        assert frame_complete(out, k, h)
        for rel in (f"input/{name}.png", f"gt/hdr/{name}.exr", f"gt/disparity/{name}.exr", f"gt/exponent/{name}.exr",
                    f"dof/constant/{name}.png", f"dof/constant/{name}.exr", f"dof/constant/{name}.json",
                    f"dof/rack/{name}.png", f"dof/rack/{name}.exr", f"dof/rack/{name}.json", f"done/{name}.json"):
            assert (out / rel).is_file(), rel
    assert sorted(p.name for p in (out / "train").glob("*.json")) == ["frame_00001.json", "frame_00004.json"]
    assert (out / "train" / "frame_00004_f2.8.png").is_file() and (out / "train" / "frame_00004_focusB.exr").is_file()
    assert not [p for p in out.rglob(".*")], "temporary files left behind"
    info = probe_clip(out / "input.mp4")
    assert (info.width, info.height, info.frame_count) == (W, H, N) and not info.has_audio
    assert "Video:" in stream_info(out / "dof" / "rack.mp4")
    # The rvr CLI reads the track files as they are.
    focus, aperture = resolve_track(load_track(out / "dof" / "rack" / "rvr_track.json"), N)
    recs = [json.loads((out / "dof" / "rack" / f"frame_{k:05d}.json").read_text()) for k in range(1, N + 1)]
    np.testing.assert_allclose(focus, [r["focus_disparity"] for r in recs], rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(aperture, [r["aperture_scale"] for r in recs], rtol=1e-6)


def test_input_is_the_clipped_srgb_of_the_hdr_and_the_exponent_restores_it(clip):
    out, _, manifest = clip
    for k in (1, N):
        radiance = _rgb(out / "gt" / "hdr" / f"frame_{k:05d}.exr")
        png = _png(out / "input" / f"frame_{k:05d}.png")
        assert np.abs(png.astype(np.float64) - np.round(255.0 * linear_to_srgb(radiance))).max() <= 1.0
        e = np.dstack([read_exr(out / "gt" / "exponent" / f"frame_{k:05d}.exr")[f"E.{c}"] for c in "RGB"])
        clipped = e > 0
        assert clipped.any() and radiance.max() > 3.0  # emitters far above display white (sub-pixel here)
        restored = srgb_to_linear(png.astype(np.float32) / 255.0) * np.exp(50.0 * e)
        np.testing.assert_allclose(restored[clipped], radiance[clipped], rtol=1e-3)
        assert radiance.max() <= max(manifest["scene"]["radiance_cap"]) * (1 + 1e-6)


def test_disparity_is_exact_from_z_and_ids_are_named(clip):
    out, _, manifest = clip
    cam = manifest["camera"]
    for k in (1, N):
        ch = read_exr(out / "gt" / "disparity" / f"frame_{k:05d}.exr")
        z = ch["Z"].astype(np.float64)
        assert np.isfinite(z).all() and z.min() > 0.5 and z.max() < 40.0  # no pixel sees the empty world
        expected = cam["K_px"] * (1.0 / cam["s_ref_m"] - 1.0 / z)
        np.testing.assert_allclose(ch["D"], expected, rtol=1e-6, atol=1e-5)
        ids = {str(int(v)) for v in np.unique(np.round(ch["ID"]))}
        assert ids <= set(manifest["object_ids"]), ids
    # The main subject's focus point is the reference depth on frame 1: D = 0 there.
    main = manifest["scene"]["main"]
    assert manifest["subjects"][main]["per_frame"][0]["disparity"] == pytest.approx(0.0, abs=1e-9)


def test_lens_records_follow_cycles_thin_lens(clip):
    out, _, manifest = clip
    cam = manifest["camera"]
    main = manifest["scene"]["main"]
    rack = manifest["focus_tracks"]["rack"]
    weights = []
    for k in range(1, N + 1):
        for track in ("constant", "rack"):
            rec = json.loads((out / "dof" / track / f"frame_{k:05d}.json").read_text())
            assert rec["frame"] == k and rec["index"] == k - 1 and rec["track"] == track
            assert rec["aperture_scale"] == pytest.approx(cam["f_number_ref"] / rec["f_number"], rel=1e-12)
            assert rec["focus_disparity"] == pytest.approx(
                cam["K_px"] * (1.0 / cam["s_ref_m"] - 1.0 / rec["focus_distance_m"]), rel=1e-9, abs=1e-9)
            assert rec["K_N_px"] == pytest.approx(rec["aperture_scale"] * cam["K_px"], rel=1e-12)
        const = json.loads((out / "dof" / "constant" / f"frame_{k:05d}.json").read_text())
        assert const["focus_disparity"] == pytest.approx(manifest["subjects"][main]["per_frame"][k - 1]["disparity"])
        weights.append(json.loads((out / "dof" / "rack" / f"frame_{k:05d}.json").read_text())["rack_weight"])
    assert weights[0] == 0.0 and weights[-1] == 1.0 and np.all(np.diff(weights) >= 0)
    assert rack["from"] != rack["to"]


def test_training_sidecar_scale_and_shift(clip):
    out, _, _ = clip
    side = json.loads((out / "train" / "frame_00004.json").read_text())
    m = side["members"]
    for role in ("large", "mid", "small", "focusB"):
        assert (out / m[role]["png"]).is_file() and (out / m[role]["exr"]).is_file()
        assert m[role]["alpha"] == m[role]["aperture_scale"]
        assert m[role]["beta"] == pytest.approx(-m[role]["aperture_scale"] * m[role]["focus_disparity"])
    assert m["large"]["f_number"] < m["mid"]["f_number"] < m["small"]["f_number"]
    assert m["large"]["focus_disparity"] == m["mid"]["focus_disparity"] == m["small"]["focus_disparity"]
    assert m["focusB"]["f_number"] == m["large"]["f_number"]
    assert m["focusB"]["focus_disparity"] != m["large"]["focus_disparity"]
    d = np.linspace(-3.0, 6.0, 50)
    for rel in side["relations"]:
        a, b = m[rel["from"]], m[rel["to"]]
        r_from = a["aperture_scale"] * (d - a["focus_disparity"])
        r_to = b["aperture_scale"] * (d - b["focus_disparity"])
        np.testing.assert_allclose(rel["alpha"] * r_from + rel["beta"], r_to, atol=1e-9)
    assert side["focal_triplet"] == ["input", "large", "focusB"]


def test_enter_event_box_contains_the_subject(clip):
    """The enter event of the walking subject: its face enters on that frame (not before), its
    box holds the projected focus point and every pixel Cycles' object-index pass gives it."""
    out, _, manifest = clip
    events = json.loads((out / "events.json").read_text())
    assert events == manifest["events"]
    enter = [e for e in events if e["type"] == "enter"]
    assert len(enter) == 1 and enter[0]["subject"] == manifest["scene"]["second"]
    e = enter[0]
    per_frame = manifest["subjects"][e["subject"]]["per_frame"]
    assert e["frame"] > 1 and not per_frame[e["frame"] - 2]["face_in_frame"] and per_frame[e["frame"] - 1]["face_in_frame"]
    x, y, w, h = e["box"]
    px, py = e["point"]
    assert x <= px <= x + w and y <= py <= y + h and w > 0 and h > 0
    assert e["disparity"] == pytest.approx(per_frame[e["frame"] - 1]["disparity"])
    index = manifest["subjects"][e["subject"]]["index"]
    for k in range(1, N + 1):
        ids = read_exr(out / "gt" / "disparity" / f"frame_{k:05d}.exr")["ID"]
        rows, cols = np.nonzero(np.round(ids) == index)
        x, y, w, h = per_frame[k - 1]["box"]
        if len(rows):
            assert cols.min() >= np.floor(x) - 1 and cols.max() + 1 <= np.ceil(x + w) + 1, k
            assert rows.min() >= np.floor(y) - 1 and rows.max() + 1 <= np.ceil(y + h) + 1, k


def test_resume_renders_only_the_damaged_frames(clip):
    out, _, manifest = clip
    before = _png(out / "input" / "frame_00003.png")
    (out / "dof" / "rack" / "frame_00003.png").unlink()  # a lost file
    (out / "done" / "frame_00005.json").unlink()  # an interrupted frame: marker never written
    with open(out / "gt" / "hdr" / "frame_00002.exr", "r+b") as f:  # a truncated file
        f.truncate(100)
    result = generate(out, CFG, progress=False)
    assert result.rendered == [2, 3, 5] and result.kept == [1, 4, 6]
    assert all(frame_complete(out, k, manifest["config_hash"]) for k in range(1, N + 1))
    after = _png(out / "input" / "frame_00003.png")
    assert np.abs(after.astype(int) - before.astype(int)).max() <= 1  # the same seeded render
    assert len(json.loads((out / "manifest.json").read_text())["runs"]) == 2


def test_interrupted_run_never_leaves_a_complete_looking_frame(tmp_path, monkeypatch):
    from sintel_eval import passes

    cfg = GenerateConfig(seed=2, frames=3, width=W, height=H, script="start-moving", samples=1, dof_samples=1,
                         train_every=0)
    real = passes.PassRenderer.render_dof

    def flaky(self, lens, samples=None):
        if bpy.context.scene.frame_current == 2:  # Ctrl-C after frame 2's input and GT are written
            raise KeyboardInterrupt
        return real(self, lens, samples)

    monkeypatch.setattr(passes.PassRenderer, "render_dof", flaky)
    with pytest.raises(KeyboardInterrupt):
        generate(tmp_path / "clip", cfg, progress=False)
    h = json.loads((tmp_path / "clip" / "manifest.json").read_text())["config_hash"]
    assert frame_complete(tmp_path / "clip", 1, h) and not frame_complete(tmp_path / "clip", 2, h)
    assert not (tmp_path / "clip" / "done" / "frame_00002.json").exists()
    monkeypatch.setattr(passes.PassRenderer, "render_dof", real)
    result = generate(tmp_path / "clip", cfg, progress=False)
    assert result.rendered == [2, 3] and result.kept == [1]
    assert not [p for p in (tmp_path / "clip").rglob(".*")]


def test_other_settings_in_the_same_folder_need_force(tmp_path):
    out = tmp_path / "clip"
    cfg = GenerateConfig(seed=3, frames=2, width=W, height=H, script="random", samples=1, dof_samples=1,
                         train_every=0)
    generate(out, cfg, progress=False)
    (out / "notes.txt").write_text("mine")
    with pytest.raises(InputError, match=r"seed: 3 -> 4.*--force"):
        generate(out, GenerateConfig(**{**cfg.__dict__, "seed": 4}), progress=False)
    result = generate(out, GenerateConfig(**{**cfg.__dict__, "seed": 4}), force=True, progress=False)
    assert result.rendered == [1, 2]
    assert json.loads((out / "manifest.json").read_text())["config"]["seed"] == 4
    assert (out / "notes.txt").read_text() == "mine"  # --force removes only the harness' own entries
    (tmp_path / "file").write_text("x")
    with pytest.raises(InputError, match="is a file"):
        generate(tmp_path / "file", cfg, progress=False)


def test_cli_errors_are_clear(capsys, tmp_path):
    from sintel_eval.__main__ import main

    assert main(["generate", "--seed", "seven", "-o", str(tmp_path / "x"), "-q"]) == 1
    assert "--seed 'seven' is not a seed" in capsys.readouterr().err
    assert main(["generate", "--seed", "7", "--script", "chase", "-o", str(tmp_path / "x"), "-q"]) == 1
    assert "--script 'chase'" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["generate", "--seed", "7", "--size", "big", "-o", str(tmp_path / "x")])
    assert "WxH" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()
    assert os.environ.get("PYTEST_CURRENT_TEST")


def test_cli_generates_and_resumes(capsys, tmp_path):
    from sintel_eval.__main__ import main

    args = ["generate", "--seed", "0x9", "--frames", "2", "--size", "32x18", "--samples", "1", "--dof-samples", "1",
            "--train-samples", "1", "--script", "start-moving", "-q", "-o", str(tmp_path / "c")]
    assert main(args) == 0
    assert "2 frame(s) rendered, 0 kept" in capsys.readouterr().out
    assert main(args) == 0
    assert "0 frame(s) rendered, 2 kept" in capsys.readouterr().out
    manifest = json.loads((tmp_path / "c" / "manifest.json").read_text())
    assert manifest["config"]["seed"] == 9 and manifest["status"]["complete"]
