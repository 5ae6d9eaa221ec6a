"""Atomic MP4 and image-sequence writers."""
from __future__ import annotations

import os

import numpy as np
import pytest

from rvr_addon.errors import InputError, OutputError
from rvr_addon.io.exr import read_exr
from rvr_addon.io.video import iter_frames, probe_clip
from rvr_addon.io.writer import ImageSequenceWriter, VideoWriter


def frames(n: int, width: int = 64, height: int = 48) -> list[np.ndarray]:
    """Smooth gradient frames (compress well, survive H.264 within a few levels)."""
    y, x = np.mgrid[0:height, 0:width]
    return [np.dstack([(x * 4 + i * 8) % 256, (y * 5) % 256, np.full_like(x, 128)]).astype(np.uint8) for i in range(n)]


def write_video(path, n: int, size=(64, 48), **kwargs) -> None:
    with VideoWriter(path, 24.0, size, **kwargs) as writer:
        for frame in frames(n, *size):
            writer.write(frame)


class Boom(Exception):
    pass


# ----------------------------------------------------------------------------- VideoWriter


def test_video_round_trip(tmp_path):
    path = tmp_path / "out.mp4"
    write_video(path, 12)
    info = probe_clip(path)
    assert (info.width, info.height, info.fps, info.frame_count, info.has_audio) == (64, 48, 24.0, 12, False)
    decoded = list(iter_frames(path))
    err = np.abs(decoded[5].astype(int) - frames(12)[5]).mean()
    assert err < 3.0
    assert os.listdir(tmp_path) == ["out.mp4"]


def test_audio_is_muxed_from_source(tmp_path, clip_av, stream_info):
    path = tmp_path / "with_audio.mp4"
    write_video(path, 12, audio_from=clip_av)
    streams = stream_info(path)
    assert "Video: h264" in streams and "Audio: aac" in streams
    assert probe_clip(path).frame_count == 12


@pytest.mark.parametrize(
    "n_frames",
    [pytest.param(6, id="audio-longer-than-video"), pytest.param(30, id="audio-shorter-than-video")],
)
def test_audio_length_never_changes_frame_count(tmp_path, clip_av, clip_long_audio, n_frames):
    source = clip_long_audio if n_frames < 12 else clip_av
    path = tmp_path / "a.mp4"
    write_video(path, n_frames, audio_from=source)
    info = probe_clip(path)
    assert info.frame_count == n_frames and info.has_audio


def test_audio_start_offsets_into_source(tmp_path, clip_long_audio):
    path = tmp_path / "later.mp4"
    write_video(path, 6, audio_from=clip_long_audio, audio_start=1.0)
    info = probe_clip(path)
    assert info.has_audio and info.frame_count == 6


def test_silent_audio_source_is_fine(tmp_path, clip_silent, stream_info):
    path = tmp_path / "quiet.mp4"
    write_video(path, 4, audio_from=clip_silent)
    assert "Audio:" not in stream_info(path)
    assert probe_clip(path).frame_count == 4


def test_missing_audio_source_names_file(tmp_path):
    with pytest.raises(InputError, match=r"ghost\.mov"):
        VideoWriter(tmp_path / "x.mp4", 24, (64, 48), audio_from=tmp_path / "ghost.mov")


def test_odd_size_is_padded_to_even(tmp_path):
    path = tmp_path / "odd.mp4"
    write_video(path, 3, size=(63, 47))
    info = probe_clip(path)
    assert (info.width, info.height, info.frame_count) == (64, 48, 3)


def test_exception_inside_with_keeps_existing_file(tmp_path):
    path = tmp_path / "render.mp4"
    path.write_bytes(b"earlier render")
    with pytest.raises(Boom):
        with VideoWriter(path, 24, (64, 48)) as writer:
            for frame in frames(3):
                writer.write(frame)
            raise Boom()
    assert path.read_bytes() == b"earlier render"
    assert os.listdir(tmp_path) == ["render.mp4"]


def test_abort_and_empty_close_keep_existing_file(tmp_path):
    path = tmp_path / "render.mp4"
    path.write_bytes(b"earlier render")
    writer = VideoWriter(path, 24, (64, 48))
    writer.write(frames(1)[0])
    writer.abort()
    with pytest.raises(OutputError, match=r"No frames were written to '.*render\.mp4'"):
        with VideoWriter(path, 24, (64, 48)):
            pass
    assert path.read_bytes() == b"earlier render"
    assert os.listdir(tmp_path) == ["render.mp4"]


@pytest.mark.parametrize(
    "bad",
    [
        pytest.param(np.zeros((48, 64, 3), np.float32), id="float"),
        pytest.param(np.zeros((40, 64, 3), np.uint8), id="wrong-size"),
        pytest.param(np.zeros((48, 64), np.uint8), id="gray"),
    ],
)
def test_bad_frame_is_rejected_and_nothing_written(tmp_path, bad):
    path = tmp_path / "clip.mp4"
    with pytest.raises(InputError, match=r"Frame 1 for '.*clip\.mp4'"):
        with VideoWriter(path, 24, (64, 48)) as writer:
            writer.write(frames(1)[0])
            writer.write(bad)
    assert os.listdir(tmp_path) == []


@pytest.mark.parametrize(
    "kwargs, match",
    [
        pytest.param({"fps": 0.0}, "fps", id="fps"),
        pytest.param({"crf": 60}, "crf", id="crf"),
        pytest.param({"size": (0, 10)}, "size", id="size"),
        pytest.param({"audio_start": -1.0}, "audio_start", id="audio-start"),
    ],
)
def test_bad_settings(tmp_path, kwargs, match):
    args = {"fps": 24.0, "size": (64, 48)} | kwargs
    with pytest.raises(InputError, match=match):
        VideoWriter(tmp_path / "x.mp4", **args)


def test_ffmpeg_failure_is_output_error_with_stderr(tmp_path, monkeypatch):
    fake = tmp_path / "fake_ffmpeg.sh"
    fake.write_text("#!/bin/sh\ncat > /dev/null\necho 'x264 [error]: fake encoder failure' >&2\nexit 3\n")
    fake.chmod(0o755)
    monkeypatch.setattr("rvr_addon.io.writer.ffmpeg_exe", lambda: str(fake))
    path = tmp_path / "render.mp4"
    path.write_bytes(b"earlier render")
    writer = VideoWriter(path, 24, (64, 48))
    writer.write(frames(1)[0])
    with pytest.raises(OutputError, match=r"(?s)render\.mp4.*fake encoder failure"):
        writer.close()
    assert path.read_bytes() == b"earlier render"
    assert sorted(os.listdir(tmp_path)) == ["fake_ffmpeg.sh", "render.mp4"]


def test_rename_failure_is_output_error(tmp_path):
    target = tmp_path / "is_a_dir.mp4"
    target.mkdir()
    writer = VideoWriter(target, 24, (64, 48))
    writer.write(frames(1)[0])
    with pytest.raises(OutputError, match=r"is_a_dir\.mp4"):
        writer.close()
    assert target.is_dir() and os.listdir(tmp_path) == ["is_a_dir.mp4"]


# ----------------------------------------------------------------------------- ImageSequenceWriter


def test_png_sequence_round_trip(tmp_path, image_frames):
    out = tmp_path / "frames"
    with ImageSequenceWriter(out, start=1) as writer:
        for frame in image_frames:
            writer.write(frame)
    assert sorted(os.listdir(out))[:2] == ["frame_00001.png", "frame_00002.png"]
    back = list(iter_frames(out))
    assert len(back) == 12
    for got, want in zip(back, image_frames):
        np.testing.assert_array_equal(got, want)
    assert os.listdir(tmp_path) == ["frames"]


def test_png16_sequence(tmp_path):
    frame = (np.arange(48 * 64 * 3).reshape(48, 64, 3) * 7 % 65536).astype(np.uint16)
    with ImageSequenceWriter(tmp_path / "f16", pattern="f_%03d.png", start=0) as writer:
        writer.write(frame)
    import cv2

    back = cv2.imread(str(tmp_path / "f16" / "f_000.png"), cv2.IMREAD_UNCHANGED)[:, :, ::-1]
    np.testing.assert_array_equal(back, frame)


def test_exr_sequence_float_exact(tmp_path):
    rng = np.random.default_rng(3)
    linear = [rng.random((6, 8, 3), dtype=np.float32) * 40.0 for _ in range(2)]
    with ImageSequenceWriter(tmp_path / "lin", pattern="lin_%04d.exr", start=7) as writer:
        for frame in linear:
            writer.write(frame)
    channels = read_exr(tmp_path / "lin" / "lin_0008.exr")
    np.testing.assert_array_equal(np.dstack([channels["R"], channels["G"], channels["B"]]), linear[1])


def test_sequence_replaces_existing_folder(tmp_path, image_frames):
    out = tmp_path / "frames"
    out.mkdir()
    for i in range(5):
        (out / f"old_{i}.png").write_bytes(b"old")
    with ImageSequenceWriter(out) as writer:
        for frame in image_frames[:3]:
            writer.write(frame)
    assert sorted(os.listdir(out)) == ["frame_00001.png", "frame_00002.png", "frame_00003.png"]
    assert os.listdir(tmp_path) == ["frames"]


def test_sequence_exception_keeps_existing_folder(tmp_path, image_frames):
    out = tmp_path / "frames"
    out.mkdir()
    (out / "frame_00001.png").write_bytes(b"earlier result")
    with pytest.raises(Boom):
        with ImageSequenceWriter(out) as writer:
            writer.write(image_frames[0])
            writer.write(image_frames[1])
            raise Boom()
    assert os.listdir(out) == ["frame_00001.png"]
    assert (out / "frame_00001.png").read_bytes() == b"earlier result"
    assert os.listdir(tmp_path) == ["frames"]


@pytest.mark.parametrize(
    "pattern, frame, match",
    [
        pytest.param("frame_%05d.png", np.zeros((4, 4, 3), np.float32), "uint8", id="float-to-png"),
        pytest.param("frame_%05d.exr", np.zeros((4, 4, 3), np.uint8), "float", id="uint8-to-exr"),
        pytest.param("frame_%05d.jpg", np.zeros((4, 4), np.uint8), r"\(H, W, 3\)", id="gray"),
    ],
)
def test_sequence_rejects_bad_frames(tmp_path, pattern, frame, match):
    with pytest.raises(InputError, match=match):
        with ImageSequenceWriter(tmp_path / "out", pattern=pattern) as writer:
            writer.write(frame)
    assert os.listdir(tmp_path) == []


def test_sequence_size_change_rejected(tmp_path):
    with pytest.raises(InputError, match=r"frame_00002\.png.*8x4.*4x4"):
        with ImageSequenceWriter(tmp_path / "out") as writer:
            writer.write(np.zeros((4, 4, 3), np.uint8))
            writer.write(np.zeros((4, 8, 3), np.uint8))


@pytest.mark.parametrize(
    "pattern",
    [pytest.param("frame.png", id="no-number"), pytest.param("sub/f_%04d.png", id="folder"),
     pytest.param("f_%04d.gif", id="format")],
)
def test_bad_patterns(tmp_path, pattern):
    with pytest.raises(InputError, match="pattern"):
        ImageSequenceWriter(tmp_path / "out", pattern=pattern)


def test_dropped_writers_leave_nothing_behind(tmp_path, image_frames):
    import gc

    video = VideoWriter(tmp_path / "v.mp4", 24, (64, 48))
    video.write(frames(1)[0])
    sequence = ImageSequenceWriter(tmp_path / "seq")
    sequence.write(image_frames[0])
    del video, sequence
    gc.collect()
    assert os.listdir(tmp_path) == []
