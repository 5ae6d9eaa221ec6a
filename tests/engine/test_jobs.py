"""Issue 22.3: every job has one interface (``rvr_addon.jobs.Job``: step, cancel, progress, text),
and a cancel at any point (before the first step, in the middle, after the end) stops it
cleanly, is idempotent, and leaves what the user had (an earlier render, the cache) as it was.

The Blender modal runner's side (status reset to IDLE whatever happens) is in
tests/blender/test_job_cancel.py."""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from rvr_addon.jobs import JOB_MEMBERS, Job, check_job, missing_members, stop_job

W, H, N = 40, 30, 6
POINTS = ["before_first_step", "mid_way", "after_the_end"]


def _png_clip(folder: Path) -> Path:
    folder.mkdir(parents=True)
    rng = np.random.default_rng(0)
    for i in range(N):
        cv2.imwrite(str(folder / f"f{i:03d}.png"), (rng.random((H, W, 3)) * 255).astype(np.uint8))
    return folder


def _maps(folder: Path) -> Path:
    folder.mkdir(parents=True)
    for i in range(N):
        d = np.tile(np.linspace(-4.0, 4.0, W, dtype=np.float32), (H, 1)) + 0.1 * i
        np.save(folder / f"d_{i:04d}.npy", d)
    return folder


def _snapshot(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    root = tmp_path_factory.mktemp("jobs")
    return _png_clip(root / "clip"), _maps(root / "maps")


def _estimate(tmp_path, inputs):
    from rvr_addon.estimate.infer import EstimateJob, EstimateSettings

    clip, maps = inputs
    return EstimateJob(EstimateSettings(input=clip, output=tmp_path / "cache", depth=maps, no_hdr=True))


def _stabilize(tmp_path, inputs):
    from rvr_addon.temporal.job import StabilizeJob, StabilizeSettings

    _estimate(tmp_path, inputs).run(progress=False)
    return StabilizeJob(StabilizeSettings(cache=tmp_path / "cache", input=inputs[0]))


def _render(tmp_path, inputs):
    from rvr_addon.pipeline import RenderJob, RenderSettings

    out = tmp_path / "out" / "render.mp4"
    out.parent.mkdir()
    out.write_bytes(b"an earlier render")
    return RenderJob(RenderSettings(input=inputs[0], depth=inputs[1], outputs=[out, tmp_path / "out" / "frames"],
                                    focus=0.0, aperture=1.0))


def _autofocus(tmp_path, inputs):
    from rvr_addon.laaf.lookahead import AutofocusJob, AutofocusSettings
    from rvr_addon.laaf.nft import NFT

    nfts = [NFT(10.0, 15.0, 0, (5.0, 10.0, 10.0, 10.0)), NFT(30.0, 15.0, 3, (25.0, 10.0, 10.0, 10.0))]
    return AutofocusJob(AutofocusSettings(input=inputs[0], depth=inputs[1], preset=None, nfts=nfts))


def _training(tmp_path, inputs):
    from estimate_synth import make_clip
    from rvr_addon.estimate.train import Trainer, TrainSettings

    make_clip(tmp_path / "data" / "clip0", seed=5, frames=2)
    return Trainer(TrainSettings(run_dir=tmp_path / "run", data=[tmp_path / "data"], iterations=4, lr=1e-3, crop=32,
                                 checkpoint_every=2))


def _refocus(tmp_path, inputs):
    from rvr_addon.refocus.job import RefocusSettings, refocus_job

    chain, _run = refocus_job(RefocusSettings(input=inputs[0], output=tmp_path / "refocused" / "r.mp4",
                                              depth_method="network", max_size=None))
    return chain


def _working_copy(tmp_path, inputs):
    from rvr_addon.refocus.proxy import ProxyJob

    return ProxyJob(inputs[0], tmp_path / "copy" / "clip.mp4", max_size=20)


def _before_after(tmp_path, inputs):
    from rvr_addon.refocus.sidebyside import SideBySideJob

    return SideBySideJob(inputs[0], inputs[0], tmp_path / "sbs" / "sbs.mp4")


JOBS = {"estimate": _estimate, "stabilize": _stabilize, "render": _render, "autofocus": _autofocus,
        "training": _training, "refocus": _refocus, "working_copy": _working_copy, "before_after": _before_after}


def test_the_protocol_names_what_a_job_lacks():
    class NotAJob:
        def step(self) -> bool:
            return False

    assert missing_members(NotAJob()) == ["cancel", "progress", "text"]
    with pytest.raises(TypeError, match="lacks cancel, progress, text"):
        check_job(NotAJob())
    assert set(JOB_MEMBERS) == {"step", "cancel", "progress", "text"}


@pytest.mark.parametrize("point", POINTS)
@pytest.mark.parametrize("kind", list(JOBS))
def test_every_job_cancels_cleanly_at_every_point(kind, point, tmp_path, inputs):
    job = JOBS[kind](tmp_path, inputs)
    assert isinstance(job, Job) and check_job(job) is job, missing_members(job)
    before = _snapshot(tmp_path / "out") if kind == "render" else None
    finished_text = None
    if point == "mid_way":
        assert job.step() and job.step()
        assert 0.0 < job.progress < 1.0
    elif point == "after_the_end":
        while job.step():
            pass
        assert job.progress == pytest.approx(1.0)
        finished_text = job.text
    job.cancel()
    job.cancel()  # idempotent
    assert job.step() is False  # a cancelled (or finished) job does nothing more
    assert isinstance(job.text, str) and 0.0 <= job.progress <= 1.0
    if finished_text is not None:
        assert job.text == finished_text  # cancel after the end changes nothing
    else:
        assert "cancel" in job.text
    if kind == "render":
        out = tmp_path / "out"
        if point == "after_the_end":
            assert (out / "render.mp4").read_bytes() != b"an earlier render"  # the finished render is kept
            assert len(list((out / "frames").glob("frame_*.png"))) == N
        else:
            assert _snapshot(out) == before  # the earlier render survives, nothing partial is left
        assert not [p for p in out.iterdir() if p.name.startswith(".")]  # no temp file, no temp folder
    if kind == "autofocus":
        assert (job.result is not None) == (point == "after_the_end")
    for kind_, out in (("refocus", "refocused/r.mp4"), ("working_copy", "copy/clip.mp4"), ("before_after", "sbs/sbs.mp4")):
        if kind == kind_:  # the video exists only when complete; nothing partial or hidden is left
            assert (tmp_path / out).is_file() == (point == "after_the_end")
            folder = (tmp_path / out).parent
            assert not folder.exists() or not [p for p in folder.iterdir() if p.name.startswith(".")]
    if kind == "training" and point != "before_first_step":
        assert (tmp_path / "run" / "checkpoint.pt").is_file()


def test_stop_job_prefers_abort_after_a_failed_step():
    calls = []

    class Both:
        text, progress = "", 0.0

        def step(self):
            return False

        def cancel(self):
            calls.append("cancel")

        def abort(self):
            calls.append("abort")

    stop_job(Both(), failed=True)
    stop_job(Both())
    assert calls == ["abort", "cancel"]
