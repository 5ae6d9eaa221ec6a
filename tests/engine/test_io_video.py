"""Clip probing and frame streaming: videos (bundled ffmpeg) and image sequences (OpenCV)."""
from __future__ import annotations

import logging

import cv2
import numpy as np
import pytest

from rvr_addon.errors import InputError, VideoOpenError
from rvr_addon.io.video import ClipInfo, iter_frames, probe_clip


# ----------------------------------------------------------------------------- videos


def test_probe_video_with_audio(clip_av):
    info = probe_clip(clip_av)
    assert info == ClipInfo(clip_av, 64, 48, 24.0, 12, True, "video")


def test_probe_video_without_audio(clip_silent):
    info = probe_clip(clip_silent)
    assert (info.frame_count, info.has_audio, info.kind) == (12, False, "video")


def test_probe_fps_argument_overrides_video_rate(clip_silent):
    assert probe_clip(clip_silent, fps=30.0).fps == 30.0


def test_iter_frames_video_shape_dtype_count(clip_av):
    frames = list(iter_frames(clip_av))
    assert len(frames) == 12
    assert all(f.shape == (48, 64, 3) and f.dtype == np.uint8 for f in frames)
    assert frames[0].flags.writeable


@pytest.mark.parametrize(
    "start, stop, expected",
    [
        pytest.param(0, 3, [0, 1, 2], id="head"),
        pytest.param(5, 9, [5, 6, 7, 8], id="middle"),
        pytest.param(10, None, [10, 11], id="tail-to-end"),
        pytest.param(10, 50, [10, 11], id="stop-past-end"),
        pytest.param(4, 4, [], id="empty"),
    ],
)
def test_iter_frames_video_range_matches_full_decode(clip_silent, start, stop, expected):
    full = list(iter_frames(clip_silent))
    part = list(iter_frames(clip_silent, start, stop))
    assert len(part) == len(expected)
    for got, index in zip(part, expected):
        np.testing.assert_array_equal(got, full[index])


def test_iter_frames_early_stop_releases_decoder(clip_av):
    frames = iter_frames(clip_av)
    first = next(frames)
    frames.close()  # kills ffmpeg; must not hang
    assert first.shape == (48, 64, 3)


def test_bt709_clip_decodes_to_true_colour(clip_bt709_color):
    # OpenCV's VideoCapture ignores the colour-matrix tag (BT.601 always) and returns about
    # (187, 45, 32) here; decoding through ffmpeg honours BT.709.
    frame = next(iter_frames(clip_bt709_color))
    np.testing.assert_allclose(frame[24, 32].astype(int), [200, 60, 30], atol=3)


def test_rotated_clip_is_upright(clip_rotated, clip_silent):
    info = probe_clip(clip_rotated)
    assert (info.width, info.height) == (48, 64)
    rotated = next(iter_frames(clip_rotated))
    plain = next(iter_frames(clip_silent))
    np.testing.assert_array_equal(rotated, np.rot90(plain))


def test_trimmed_clip_counts_shown_frames(clip_trimmed):
    # 48 packets are stored, but the edit list shows only the last 36.
    info = probe_clip(clip_trimmed)
    assert info.frame_count == 36
    assert sum(1 for _ in iter_frames(clip_trimmed)) == 36


def test_resolution_change_in_video_raises(clip_resolution_change):
    with pytest.raises(InputError, match=r"res_change\.ts.*64x48 to 80x48.*frame 5"):
        list(iter_frames(clip_resolution_change))


def test_corrupt_video_raises(corrupt_clip):
    with pytest.raises(VideoOpenError, match=r"broken\.mp4.*re-export"):
        probe_clip(corrupt_clip)
    with pytest.raises(VideoOpenError, match=r"broken\.mp4"):
        list(iter_frames(corrupt_clip))


# ----------------------------------------------------------------------------- image sequences


def test_probe_image_directory(image_sequence):
    info = probe_clip(image_sequence)
    assert info == ClipInfo(image_sequence, 64, 48, 24.0, 12, False, "images")
    assert probe_clip(image_sequence, fps=12.5).fps == 12.5


@pytest.mark.parametrize(
    "spec",
    [
        pytest.param("{dir}", id="directory"),
        pytest.param("{dir}/frame*.png", id="glob"),
        pytest.param("{dir}/frame%d.png", id="printf"),
    ],
)
def test_image_sequence_round_trip_in_natural_order(image_sequence, image_frames, spec):
    frames = list(iter_frames(spec.format(dir=image_sequence)))
    assert len(frames) == 12
    for got, want in zip(frames, image_frames):
        np.testing.assert_array_equal(got, want)


def test_printf_pattern_with_padding(tmp_path, image_frames):
    for i in (7, 8, 9, 10):
        cv2.imwrite(str(tmp_path / f"f_{i:04d}.png"), image_frames[i][:, :, ::-1])
    cv2.imwrite(str(tmp_path / "f_12.png"), image_frames[0])  # not 4 digits: not part of f_%04d
    frames = list(iter_frames(tmp_path / "f_%04d.png", start=1, stop=3))
    np.testing.assert_array_equal(frames[0], image_frames[8])
    np.testing.assert_array_equal(frames[1], image_frames[9])
    assert probe_clip(tmp_path / "f_%04d.png").frame_count == 4


def test_image_sequence_start_stop(image_sequence, image_frames):
    frames = list(iter_frames(image_sequence, start=9))
    assert len(frames) == 3
    np.testing.assert_array_equal(frames[0], image_frames[9])


@pytest.mark.parametrize(
    "stored, expected",
    [
        pytest.param(np.full((4, 6), 77, np.uint8), (77, 77, 77), id="gray8"),
        pytest.param(np.full((4, 6, 3), (65535, 257 * 10, 0), np.uint16), (0, 10, 255), id="bgr16"),
        pytest.param(np.dstack([np.full((4, 6, 3), (1, 2, 3), np.uint8), np.zeros((4, 6), np.uint8)]),
                     (3, 2, 1), id="bgra8-alpha-dropped"),
        pytest.param(np.full((4, 6), 32896, np.uint16), (128, 128, 128), id="gray16"),
    ],
)
def test_image_formats_become_rgb8(tmp_path, stored, expected):
    path = tmp_path / "one.png"
    assert cv2.imwrite(str(path), stored)
    info = probe_clip(path)
    assert (info.frame_count, info.width, info.height, info.kind) == (1, 6, 4, "images")
    frame = next(iter_frames(path))
    assert frame.dtype == np.uint8 and frame.shape == (4, 6, 3)
    assert tuple(frame[0, 0]) == expected


def test_exr_frames_are_srgb_encoded(tmp_path):
    from rvr_addon.io.exr import write_exr

    for i, value in enumerate((0.5, 0.0031308, 2.0)):
        write_exr(tmp_path / f"lin_{i}.exr", {c: np.full((4, 6), value, np.float32) for c in "RGB"})
    frames = list(iter_frames(tmp_path / "lin_%d.exr"))
    assert [int(f[0, 0, 0]) for f in frames] == [188, 10, 255]  # sRGB(0.5) = 0.7354; 2.0 is clipped


def test_image_size_mismatch_names_frame_and_file(image_sequence):
    cv2.imwrite(str(image_sequence / "frame4.png"), np.zeros((10, 10, 3), np.uint8))
    with pytest.raises(InputError, match=r"Frame 3 of '.*frame4\.png' is 10x10 .* 64x48"):
        list(iter_frames(image_sequence))


def test_corrupt_image_in_sequence(image_sequence):
    (image_sequence / "frame2.png").write_bytes(b"not a png")
    with pytest.raises(VideoOpenError, match=r"frame2\.png"):
        list(iter_frames(image_sequence))


# ----------------------------------------------------------------------------- bad paths


@pytest.mark.parametrize(
    "spec, message",
    [
        pytest.param("nowhere/clip.mp4", r"Input not found: '.*nowhere/clip\.mp4'", id="missing-file"),
        pytest.param("nowhere/*.png", r"No files match the pattern '.*nowhere/\*\.png'", id="glob-no-match"),
        pytest.param("nowhere/f_%04d.png", r"No files match the pattern '.*f_%04d\.png'", id="printf-no-match"),
    ],
)
def test_missing_inputs(tmp_path, spec, message):
    with pytest.raises(VideoOpenError, match=message):
        probe_clip(tmp_path / spec)


def test_empty_directory(tmp_path):
    (tmp_path / "notes.txt").write_text("no frames here")
    with pytest.raises(VideoOpenError, match=r"Folder '.*' contains no images"):
        probe_clip(tmp_path)


@pytest.mark.parametrize(
    "kwargs",
    [pytest.param({"start": -1}, id="negative-start"), pytest.param({"start": 5, "stop": 2}, id="stop-before-start")],
)
def test_bad_range(image_sequence, kwargs):
    with pytest.raises(InputError, match="seq"):
        list(iter_frames(image_sequence, **kwargs))


@pytest.mark.parametrize("fps", [pytest.param(0.0, id="zero"), pytest.param(float("nan"), id="nan")])
def test_bad_fps(image_sequence, fps):
    with pytest.raises(InputError, match="fps"):
        probe_clip(image_sequence, fps=fps)


def test_variable_frame_rate_warns(ffmpeg_run, tmp_path, caplog):
    path = tmp_path / "vfr.mp4"
    ffmpeg_run("-f", "lavfi", "-i", "testsrc2=size=64x48:rate=24", "-frames:v", "12",
               "-vf", "setpts='if(lt(N,6),N/24,0.25+(N-6)/8)/TB'", "-fps_mode", "vfr",
               "-c:v", "libx264", "-preset", "ultrafast", "-pix_fmt", "yuv420p", str(path))
    with caplog.at_level(logging.WARNING, logger="rvr_addon.io.video"):
        info = probe_clip(path)
    assert info.frame_count == 12
    assert sum(1 for _ in iter_frames(path)) == 12
    assert any("variable-frame-rate" in r.getMessage() and "vfr.mp4" in r.getMessage() for r in caplog.records)
