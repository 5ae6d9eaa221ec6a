"""`python -m sintel_eval generate --no-dof` on a tiny clip (64x36, 2 samples): the deep pass only
(no dof/, no train/), a complete and resumable clip that AF-Net's data reader and `rvr
eval-focus` take, and that `ablate` skips, saying it has no DOF ground truth (issue 8)."""
from __future__ import annotations

import json
import shutil

import pytest

bpy = pytest.importorskip("bpy")

from harness_data import write_fake_clip  # noqa: E402
from rvr_addon.errors import InputError  # noqa: E402
from sintel_eval.ablate import run_ablation  # noqa: E402
from sintel_eval.dataset import GenerateConfig, frame_complete, generate  # noqa: E402
from sintel_eval.reader import ClipReader  # noqa: E402

N = 3
CFG = GenerateConfig(seed=5, frames=N, width=64, height=36, script="enter", samples=2, dof_samples=2, train_every=4,
                     dof=False)


@pytest.fixture(scope="module")
def clip(tmp_path_factory):
    out = tmp_path_factory.mktemp("nodof") / "ds" / "enter5"
    result = generate(out, CFG, progress=False)
    return out, result


def test_deep_pass_only_and_resumable(clip):
    out, result = clip
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["status"] == {"complete": True, "frames_done": N}
    assert manifest["config"]["dof"] is False and manifest["config"]["train_every"] == 0
    assert manifest["passes"]["dof"]["skipped"] is True and manifest["passes"]["dof"]["tracks"] == []
    assert result.timings["dof_renders"] == 0
    assert not (out / "dof").exists() and not (out / "train").exists()
    for k in range(1, N + 1):
        assert frame_complete(out, k, manifest["config_hash"])
        assert (out / "input" / f"frame_{k:05d}.png").is_file() and (out / "gt" / "disparity" / f"frame_{k:05d}.exr").is_file()
    assert (out / "input.mp4").is_file() and (out / "events.json").is_file()
    assert ClipReader(out).tracks == []
    # the hash of a clip with its DOF passes is unchanged by the new setting
    assert GenerateConfig(seed=5).validated().config_hash("x") == GenerateConfig(seed=5, dof=True).validated().config_hash("x")
    assert CFG.validated().config_hash("x") != GenerateConfig(**{**CFG.__dict__, "dof": True}).validated().config_hash("x")
    again = generate(out, CFG, progress=False)  # resume: every frame is kept
    assert again.rendered == [] and again.kept == list(range(1, N + 1))


def test_afnet_and_eval_focus_read_it(clip):
    from rvr_addon.afnet.data import load_harness_clip
    from rvr_addon.laaf.evaluate import harness_clips
    from afnet_synth import tiny_config

    out, _ = clip
    assert harness_clips(out.parent) == [out]
    data = load_harness_clip(out, tiny_config())
    assert data.n == N and data.frames.shape[1:] == (4, 24, 32)


def test_ablate_skips_it_saying_why(clip, tmp_path):
    out, _ = clip
    with pytest.raises(InputError, match="no DOF ground truth"):
        run_ablation(out.parent, tmp_path / "r1", variants=["ours_gt"], progress=False, compare_frames=1)
    mixed = tmp_path / "mixed"
    shutil.copytree(out, mixed / "enter5")
    write_fake_clip(mixed / "clipA")
    ab = run_ablation(mixed, tmp_path / "r2", variants=["ours_gt"], progress=False, compare_frames=1)
    assert [c["clip"] for c in ab.clips] == ["clipA"]
    assert [name for name, _ in ab.skipped] == ["enter5"] and "--no-dof" in ab.skipped[0][1]
