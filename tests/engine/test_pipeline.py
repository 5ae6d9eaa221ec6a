"""End to end: clip + depth (+ HDR) + focus -> MP4 / image sequence, through RenderJob and the CLI."""
from __future__ import annotations

import json
import logging

import cv2
import numpy as np
import pytest

from rvr_addon.cli import main as rvr_main
from rvr_addon.errors import InputError, VideoOpenError
from rvr_addon.io.video import iter_frames
from rvr_addon.pipeline import RenderJob, RenderSettings, exponent_from_radiance
from rvr_addon.render.fast import FastRenderer
from rvr_addon.color import image_to_linear, srgb_to_linear, linear_to_srgb, to_float01

CLIP_W, CLIP_H, CLIP_FRAMES = 64, 48, 12  # the size of tests/conftest.py's clips


@pytest.fixture
def depth_dir(tmp_path):
    """One .npy disparity map per clip frame: a left-right ramp from -2 to +6 px."""
    d = tmp_path / "depth"
    d.mkdir()
    ramp = np.tile(np.linspace(-2, 6, CLIP_W, dtype=np.float32), (CLIP_H, 1))
    for i in range(CLIP_FRAMES):
        np.save(d / f"d_{i:04d}.npy", ramp + 0.1 * i)
    return d


@pytest.fixture
def frames_dir(tmp_path):
    """A PNG sequence (lossless, so outputs can be checked against the renderer exactly)."""
    d = tmp_path / "frames"
    d.mkdir()
    rng = np.random.default_rng(0)
    for i in range(CLIP_FRAMES):
        cv2.imwrite(str(d / f"f_{i:04d}.png"), (rng.random((CLIP_H, CLIP_W, 3)) * 255).astype(np.uint8))
    return d


def test_video_in_mp4_out_keeps_audio_and_frame_count(clip_av, depth_dir, tmp_path, stream_info):
    out = tmp_path / "out" / "refocus.mp4"
    job = RenderJob(RenderSettings(input=clip_av, depth=depth_dir, outputs=[out], focus=0.0, aperture=1.5))
    job.run(progress=False)
    assert job.progress == 1.0
    assert out.is_file()
    kinds = stream_info(out)
    assert "Audio:" in kinds and "Video: h264" in kinds
    frames = list(iter_frames(out))
    assert len(frames) == CLIP_FRAMES and frames[0].shape == (CLIP_H, CLIP_W, 3)


def test_png_sequence_output_equals_the_renderer(frames_dir, depth_dir, tmp_path):
    out = tmp_path / "render"
    track = tmp_path / "track.csv"
    track.write_text("frame,focus,aperture\n0,0.0,1.0\n11,4.0,2.0\n")
    RenderJob(RenderSettings(input=frames_dir, depth=depth_dir, outputs=[out], track=track)).run(progress=False)
    written = sorted(out.glob("*.png"))
    assert len(written) == CLIP_FRAMES
    k = 5  # focus and aperture interpolate linearly between the keys
    src = cv2.cvtColor(cv2.imread(str(sorted(frames_dir.glob("*.png"))[k])), cv2.COLOR_BGR2RGB)
    disp = np.load(sorted(depth_dir.glob("*.npy"))[k])
    expected = FastRenderer().render_linear(srgb_to_linear(to_float01(src)), disp, 4.0 * k / 11, 1.0 + k / 11)
    got = cv2.cvtColor(cv2.imread(str(written[k])), cv2.COLOR_BGR2RGB)
    assert np.abs(got.astype(int) - (linear_to_srgb(expected) * 255 + 0.5).astype(int)).max() <= 1


def test_exr_output_is_linear_hdr(frames_dir, depth_dir, tmp_path):
    from rvr_addon.io.exr import read_exr

    hdr = tmp_path / "hdr"
    hdr.mkdir()
    e = np.zeros((CLIP_H, CLIP_W), np.float32)
    e[10:14, 10:14] = 0.05  # radiance x e^2.5 = 12x
    np.save(hdr / "e.npy", e)  # one map for every frame
    out = tmp_path / "exr" / "f_%04d.exr"
    RenderJob(RenderSettings(input=frames_dir, depth=depth_dir, hdr=hdr / "e.npy", outputs=[out],
                             focus=-2.0, aperture=0.0)).run(progress=False)
    ch = read_exr(tmp_path / "exr" / "f_0001.exr")
    src = srgb_to_linear(to_float01(cv2.cvtColor(cv2.imread(str(sorted(frames_dir.glob("*.png"))[0])), cv2.COLOR_BGR2RGB)))
    assert ch["R"][12, 12] == pytest.approx(src[12, 12, 0] * np.exp(2.5), rel=1e-5)


def test_exponent_from_radiance_recovers_clipped_highlights():
    radiance = np.array([[[0.2, 0.5, 30.0]]], np.float32)
    img = (linear_to_srgb(radiance) * 255 + 0.5).astype(np.uint8)
    e = exponent_from_radiance(img, radiance)
    assert e[0, 0, 0] == 0 and e[0, 0, 1] == 0
    assert srgb_to_linear(to_float01(img))[0, 0, 2] * np.exp(50 * e[0, 0, 2]) == pytest.approx(30.0, rel=1e-5)


def test_short_track_holds_its_last_value_with_a_warning(frames_dir, depth_dir, tmp_path, caplog):
    track = tmp_path / "t.json"
    track.write_text(json.dumps([{"frame": 0, "focus": 0.0}, {"frame": 3, "focus": 2.0}]))
    job = RenderJob(RenderSettings(input=frames_dir, depth=depth_dir, outputs=[tmp_path / "o"], track=track))
    with caplog.at_level(logging.WARNING):
        job.run(progress=False)
    assert job._focus[-1] == 2.0 and job._focus[1] == pytest.approx(2.0 / 3)
    assert any("t.json" in r.getMessage() for r in caplog.records)


def test_depth_of_another_size_is_resampled_with_a_warning(frames_dir, tmp_path, caplog):
    d = tmp_path / "small.npy"
    np.save(d, np.zeros((CLIP_H // 2, CLIP_W // 2), np.float32))
    with caplog.at_level(logging.WARNING):
        RenderJob(RenderSettings(input=frames_dir, depth=d, outputs=[tmp_path / "o"], focus=0.0)).run(progress=False)
    assert len(list((tmp_path / "o").glob("*.png"))) == CLIP_FRAMES
    assert any("small.npy" in r.getMessage() for r in caplog.records)


def test_nan_in_depth_is_filled(frames_dir, tmp_path):
    d = np.tile(np.linspace(0, 4, CLIP_W, dtype=np.float32), (CLIP_H, 1))
    d[5:9, 5:9] = np.nan
    np.save(tmp_path / "d.npy", d)
    RenderJob(RenderSettings(input=frames_dir, depth=tmp_path / "d.npy", outputs=[tmp_path / "o"], focus=0.0)).run(progress=False)
    img = cv2.imread(str(sorted((tmp_path / "o").glob("*.png"))[0]))
    assert img is not None and np.isfinite(img).all()


@pytest.mark.parametrize("case", ["missing-input", "missing-depth", "short-depth", "negative-aperture", "bad-hdr"])
def test_failures_leave_no_output_and_keep_an_earlier_one(case, frames_dir, depth_dir, tmp_path):
    out = tmp_path / "final.mp4"
    out.write_bytes(b"earlier render")
    kwargs = dict(input=frames_dir, depth=depth_dir, outputs=[out], focus=0.0)
    if case == "missing-input":
        kwargs["input"] = tmp_path / "nope.mp4"
    elif case == "missing-depth":
        kwargs["depth"] = tmp_path / "nodepth"
    elif case == "short-depth":
        for p in sorted(depth_dir.glob("*.npy"))[6:]:
            p.unlink()
    elif case == "negative-aperture":
        kwargs["aperture"] = -1.0
    elif case == "bad-hdr":
        (tmp_path / "hdr.npy").write_bytes(b"garbage")
        kwargs["hdr"] = tmp_path / "hdr.npy"
    with pytest.raises((InputError, VideoOpenError)) as ex:
        RenderJob(RenderSettings(**kwargs)).run(progress=False)
    assert any(name in str(ex.value) for name in ("nope.mp4", "nodepth", "depth", "aperture", "hdr.npy"))
    assert out.read_bytes() == b"earlier render"
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []  # no temp left


def test_cancel_midway_removes_partial_output(frames_dir, depth_dir, tmp_path):
    out = tmp_path / "o.mp4"
    job = RenderJob(RenderSettings(input=frames_dir, depth=depth_dir, outputs=[out, tmp_path / "seq"], focus=0.0))
    assert job.step() and job.step()
    job.cancel()
    assert not job.step()
    assert not out.exists() and not (tmp_path / "seq").exists()
    assert "cancelled" in job.text
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []


def test_refuses_to_replace_a_folder_of_other_files(frames_dir, depth_dir, tmp_path):
    keep = tmp_path / "mine"
    keep.mkdir()
    (keep / "notes.txt").write_text("precious")
    with pytest.raises(InputError, match="notes.txt"):
        RenderJob(RenderSettings(input=frames_dir, depth=depth_dir, outputs=[keep], focus=0.0)).run(progress=False)
    assert (keep / "notes.txt").read_text() == "precious"


def test_cli_render_with_shape_and_errors(frames_dir, depth_dir, tmp_path, capsys):
    out = tmp_path / "cli.mp4"
    code = rvr_main(["render", str(frames_dir), "--depth", str(depth_dir), "--focus", "1", "--aperture", "2",
                     "--shape", "polygon", "--blades", "5", "--cat-eye", "0.5", "-q", "-o", str(out)])
    assert code == 0 and out.is_file()
    assert rvr_main(["render", str(frames_dir), "--depth", str(tmp_path / "none"), "-q", "-o", str(out)]) == 2
    assert "none" in capsys.readouterr().err
    assert rvr_main(["render", str(frames_dir), "--depth", str(depth_dir), "--shape", "image",
                     "--kernel-image", str(tmp_path / "k.png"), "-q", "-o", str(out)]) == 2
    assert "k.png" in capsys.readouterr().err


def test_half_size_proxy_matches_a_downscaled_full_render(frames_dir, tmp_path):
    """Blur radii scale with the width: the proxy looks like the full render, only smaller."""
    big = np.zeros((CLIP_H, CLIP_W), np.float32)
    big[:, CLIP_W // 2:] = 8.0  # right half far behind the focus: 8 px blur at full size
    np.save(tmp_path / "d.npy", big)
    full, half = tmp_path / "full", tmp_path / "half"
    for out, scale in ((full, 1.0), (half, 0.5)):
        RenderJob(RenderSettings(input=frames_dir, depth=tmp_path / "d.npy", outputs=[out], focus=0.0,
                                 stop=1, scale=scale)).run(progress=False)
    a = cv2.imread(str(sorted(full.glob("*.png"))[0])).astype(np.float32)
    b = cv2.imread(str(sorted(half.glob("*.png"))[0])).astype(np.float32)
    assert b.shape == (CLIP_H // 2, CLIP_W // 2, 3)
    down = cv2.resize(a, (CLIP_W // 2, CLIP_H // 2), interpolation=cv2.INTER_AREA)
    blurred = (slice(4, -4), slice(CLIP_W // 4 + 4, -4))  # well inside the blurred half
    assert np.abs(down[blurred] - b[blurred]).mean() < 4.0  # code values
    with pytest.raises(InputError, match="scale"):
        RenderJob(RenderSettings(input=frames_dir, depth=tmp_path / "d.npy", outputs=[full], scale=0.0))


def test_frame_list_renders_one_output_frame_per_entry(clip_av, frames_dir, depth_dir, tmp_path, stream_info):
    """``frames``: repeated and skipped clip frames (a retimed strip), the track keyed by output
    frame; each output frame equals a one-frame render of its clip frame at its focus."""
    from rvr_addon.io.track import FocusTrack

    frames = [2, 2, 3, 5, 5, 9]
    track = FocusTrack(np.array([0, 5]), np.array([0.0, 5.0]), np.array([1.0, 1.0]))
    out = tmp_path / "list"
    RenderJob(RenderSettings(input=frames_dir, depth=depth_dir, outputs=[out], track_data=track,
                             frames=frames)).run(progress=False)
    written = sorted(out.glob("*.png"))
    assert len(written) == len(frames)
    for n in (0, 1, 4):
        single = tmp_path / f"single_{n}"
        RenderJob(RenderSettings(input=frames_dir, depth=depth_dir, outputs=[single], focus=float(n),
                                 aperture=1.0, start=frames[n], stop=frames[n] + 1)).run(progress=False)
        np.testing.assert_array_equal(cv2.imread(str(written[n])), cv2.imread(str(next(single.glob("*.png")))))
    video = tmp_path / "list.mp4"
    RenderJob(RenderSettings(input=clip_av, depth=depth_dir, outputs=[video], focus=0.0, frames=frames,
                             output_fps=25.0)).run(progress=False)
    assert len(list(iter_frames(video))) == len(frames) and "Audio:" not in stream_info(video)
    from rvr_addon.io.video import probe_clip

    assert probe_clip(video).fps == pytest.approx(25.0)
    with pytest.raises(InputError, match="never decrease"):
        RenderJob(RenderSettings(input=frames_dir, depth=depth_dir, outputs=[out], frames=[3, 2]))
    with pytest.raises(InputError, match="has 12 frames"):
        RenderJob(RenderSettings(input=frames_dir, depth=depth_dir, outputs=[out], frames=[0, CLIP_FRAMES]))


@pytest.mark.parametrize("shape", [(5, 7), (5, 7, 3), (5, 7, 4), (2, 5, 7, 3), (1, 1, 3)])
def test_image_to_linear_by_table_equals_the_formula_bit_for_bit(shape):
    img = np.random.default_rng(1).integers(0, 256, shape, dtype=np.uint8)
    img.flat[:2] = (0, 255)
    got = image_to_linear(img)
    assert got.dtype == np.float32 and got.shape == img.shape
    np.testing.assert_array_equal(got, srgb_to_linear(to_float01(img)))
    u16 = (img.astype(np.uint16) * 257)
    np.testing.assert_array_equal(image_to_linear(u16), srgb_to_linear(to_float01(u16)))
    f = to_float01(img)
    np.testing.assert_array_equal(image_to_linear(f), srgb_to_linear(f))
