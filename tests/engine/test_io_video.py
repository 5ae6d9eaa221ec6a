"""Clip probing and frame streaming: videos (bundled ffmpeg) and image sequences (OpenCV)."""
from __future__ import annotations

import logging

import cv2
import numpy as np
import pytest

from rvr_addon.errors import InputError, VideoOpenError
from rvr_addon.io.video import ClipInfo, iter_frames, probe_clip
from vfr_synth import flash_clip, flash_frames


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


def test_a_variable_frame_rate_clip_is_said_and_counted_on_its_timeline(ffmpeg_run, tmp_path, caplog):
    path = tmp_path / "vfr.mp4"  # 6 frames at 24 fps, a quarter-second hold, then 6 at 8 fps
    ffmpeg_run("-f", "lavfi", "-i", "testsrc2=size=64x48:rate=24", "-frames:v", "12",
               "-vf", "setpts='if(lt(N,6),N/24,0.25+(N-6)/8)/TB'", "-fps_mode", "vfr",
               "-c:v", "libx264", "-preset", "ultrafast", "-pix_fmt", "yuv420p", str(path))
    with caplog.at_level(logging.INFO, logger="rvr_addon.io.video"):
        info = probe_clip(path)
    assert (info.fps, info.nominal_fps, info.decoded_frames) == (24.0, 24.0, 12)
    assert info.frame_count == 22  # the last frame, shown at 0.25 + 5/8 s, is frame 0.875 x 24 = 21
    assert sum(1 for _ in iter_frames(path)) == info.frame_count
    assert sum(1 for _ in iter_frames(path, decode_order=True)) == 12
    assert any("variable frame rate" in r.getMessage() and "vfr.mp4" in r.getMessage() for r in caplog.records)


def test_a_variable_frame_rate_clip_decodes_at_its_nominal_constant_rate(ffmpeg_run, tmp_path):
    """In decode order the flash at 2.5 s is frame 55 (20 frames were dropped before it): at the
    container's average rate that is 2.2 s, out of step with its sound; on the constant-rate
    timeline it is frame 75 = 2.5 s, also when read from frame 70 on (seeking)."""
    path = flash_clip(ffmpeg_run, tmp_path / "vfr.mp4")
    info = probe_clip(path)
    assert info.nominal_fps == info.fps == pytest.approx(30.0) and info.frame_count == 105
    assert info.decoded_frames == 85 and info.average_fps == pytest.approx(85 / 3.5)
    assert flash_frames(path)[:1] == [75]
    assert flash_frames(path, decode_order=True)[:1] == [55]
    assert flash_frames(path, start=70, stop=80)[0] == 5  # frames of that timeline
    given = probe_clip(path, fps=30.0)  # a rate the user gives relabels the timeline, it does not change its frames
    assert (given.fps, given.frame_count, given.nominal_fps) == (30.0, 105, 30.0)


@pytest.mark.parametrize("suffix", [".mp4", ".mkv"])
def test_the_timeline_shows_what_ffmpegs_fps_filter_shows(ffmpeg_run, ffmpeg, tmp_path, suffix):
    """Every frame of the timeline (distinct test-pattern frames, a slow start and a 0.4 s gap) is
    the one ffmpeg's ``fps`` filter places there, from the first frame and from a seek."""
    import subprocess

    path = tmp_path / f"vfr{suffix}"
    ffmpeg_run("-f", "lavfi", "-i", "testsrc2=size=96x64:rate=30:duration=3", "-vf",
               "setpts='if(lt(N,30),N/20,1.5+(N-30)/30+0.4*gte(N,60))/TB'", "-fps_mode", "vfr", "-g", "12",
               "-c:v", "libx264", "-preset", "ultrafast", "-pix_fmt", "yuv420p", str(path))
    info = probe_clip(path)
    assert info.nominal_fps == pytest.approx(30.0) and info.decoded_frames == 90
    raw = subprocess.run([ffmpeg, "-v", "error", "-i", str(path), "-vf", "fps=30", "-f", "rawvideo", "-pix_fmt",
                          "rgb24", "-"], capture_output=True, check=True).stdout
    want = np.frombuffer(raw, np.uint8).reshape(-1, 64, 96, 3)
    got = np.stack(list(iter_frames(path)))
    assert len(got) == len(want) == info.frame_count
    assert np.array_equal(got, want)
    assert np.array_equal(np.stack(list(iter_frames(path, start=41, stop=77))), want[41:77])


def test_a_constant_rate_clip_is_not_a_timeline(ffmpeg_run, tmp_path):
    """Frame times a little off their grid (a capture's jitter) and an interlaced MPEG stream
    whose nominal rate is its field rate are constant-rate clips, counted as decoded."""
    jitter = tmp_path / "jitter.mp4"
    ffmpeg_run("-f", "lavfi", "-i", "testsrc2=size=64x48:rate=30", "-frames:v", "40", "-vf",
               "setpts='(N/30+0.012*sin(N*1.7))/TB'", "-fps_mode", "vfr", "-c:v", "libx264", "-preset", "ultrafast",
               "-pix_fmt", "yuv420p", str(jitter))
    mpeg = tmp_path / "m1.mpg"
    ffmpeg_run("-f", "lavfi", "-i", "testsrc2=size=64x48:rate=25", "-frames:v", "20", "-c:v", "mpeg1video",
               "-f", "mpeg", str(mpeg))
    for path, n, fps in ((jitter, 40, 30.0), (mpeg, 20, 25.0)):
        info = probe_clip(path)
        assert (info.frame_count, info.fps, info.nominal_fps, info.decoded_frames) == (n, fps, None, None)


def test_1000_1001_rates_are_exact():
    from rvr_addon.io.video import exact_rate

    assert exact_rate(23.98) == pytest.approx(24000 / 1001, abs=1e-12)
    assert exact_rate(29.97) == pytest.approx(30000 / 1001, abs=1e-12)
    assert exact_rate(59.94) == pytest.approx(60000 / 1001, abs=1e-12)
    assert exact_rate(25.0) == 25.0 and exact_rate(30.0) == 30.0


def test_maps_of_the_decoded_frames_are_placed_on_the_timeline(ffmpeg_run, tmp_path):
    """An external depth array with one map per decoded frame of a variable-frame-rate clip (as a
    tool decoding it in order makes it): frame k reads the map of the decoded frame it shows."""
    from rvr_addon.io.maps import open_map_sequence
    from rvr_addon.io.video import video_timeline

    path = flash_clip(ffmpeg_run, tmp_path / "vfr.mp4")
    info = probe_clip(path)
    stack = np.arange(85, dtype=np.float32)[:, None, None] * np.ones((1, 4, 6), np.float32)
    np.save(tmp_path / "d.npy", stack)
    seq = open_map_sequence(tmp_path / "d.npy", kind="disparity")
    seq.place_on_timeline(info)
    assert len(seq) == 105
    decoded = video_timeline(path).decoded
    assert [float(seq.get(k)[0, 0]) for k in (0, 40, 75, 104)] == [float(decoded[k]) for k in (0, 40, 75, 104)]
    assert float(seq.get(75)[0, 0]) == 55.0  # the flash's map on the flash
    other = open_map_sequence(tmp_path / "d.npy", kind="disparity")
    other.place_on_timeline(probe_clip(flash_clip(ffmpeg_run, tmp_path / "cfr.mp4", vfr=False)))
    assert len(other) == 85  # a constant-rate clip: as it is


# ----------------------------------------------------------------------------- seeking


SEEK_FRAMES = 110  # keyframes at 0, 50, 100 (-g 50, no scene-cut keyframes)
_SPARSE_GOP = ["-c:v", "libx264", "-preset", "ultrafast", "-pix_fmt", "yuv420p", "-g", "50", "-keyint_min", "50",
               "-sc_threshold", "0", "-bf", "3", "-x264-params", "b-pyramid=normal"]


@pytest.fixture(scope="module")
def seek_clips(ffmpeg_run, tmp_path_factory) -> dict:
    """H.264 with B-frames and sparse keyframes in several containers and timings (64x48)."""
    root = tmp_path_factory.mktemp("seek")
    src = ["-f", "lavfi", "-i", "testsrc2=size=64x48:rate=24", "-frames:v", str(SEEK_FRAMES)]
    clips = {}
    for name, extra in {"mp4": [], "mkv": [], "ts": []}.items():
        clips[name] = root / f"sparse.{name}"
        ffmpeg_run(*src, *_SPARSE_GOP, *extra, str(clips[name]))
    clips["ntsc"] = root / "ntsc.mp4"  # 29.97 fps: time base 1/30000, 1001 units per frame
    ffmpeg_run("-f", "lavfi", "-i", "testsrc2=size=64x48:rate=30000/1001", "-frames:v", str(SEEK_FRAMES),
               *_SPARSE_GOP, str(clips["ntsc"]))
    clips["vfr"] = root / "vfr.mp4"  # 24 fps for 40 frames, then 8 fps
    ffmpeg_run(*src, "-vf", "setpts='if(lt(N,40),N/24,40/24+(N-40)/8)/TB'", "-fps_mode", "vfr",
               *_SPARSE_GOP, str(clips["vfr"]))
    clips["open_gop"] = root / "open_gop.mp4"  # non-IDR keyframes: leading B-frames reference the GOP before
    ffmpeg_run(*src, *_SPARSE_GOP[:-1], "b-pyramid=normal:open-gop=1", str(clips["open_gop"]))
    return clips


SEEK_STARTS = [1, 2, 49, 50, 51, 77, 99, 100, 101, SEEK_FRAMES - 1]


@pytest.mark.parametrize("name", ["mp4", "mkv", "ntsc", "vfr", "open_gop"])
def test_iter_frames_seeks_and_yields_exactly_the_frames_of_a_full_decode(seek_clips, name):
    from rvr_addon.io.video import _video_command, scan_packets, seek_point

    path = seek_clips[name]
    scan = scan_packets(path)
    full = list(iter_frames(path, decode_order=True))  # (the vfr clip's timeline: the test above)
    assert len(full) == SEEK_FRAMES == (probe_clip(path).decoded_frames or probe_clip(path).frame_count)
    shown = sorted(p.pts for p in scan.packets)
    # the keyframes (display index) the starts are about: on them, just before and just after
    keys = [i for i, p in enumerate(scan.packets) if p.key]
    assert [shown.index(scan.packets[i].pts) for i in keys] == [0, 50, 100]
    leading = [p for p in scan.packets[keys[1]:] if p.pts < scan.packets[keys[1]].pts]
    assert bool(leading) == (name == "open_gop")  # frames shown before the keyframe but decoded after it
    assert any(p.pts != p.dts for p in scan.packets)  # B-frames: decode order differs from display order
    for k in SEEK_STARTS:
        prefix = scan_packets(path, start=k)  # what iter_frames lists: up to the chunk, not the whole file
        assert seek_point(prefix, k) == seek_point(scan, k) is not None and "-ss" in _video_command(path, k, None), k
        if k < 50:  # decided by the keyframe at 50: the listing stops before the end of the file
            assert not prefix.complete and len(prefix.packets) < SEEK_FRAMES, k
        part = list(iter_frames(path, start=k, decode_order=True))
        assert len(part) == SEEK_FRAMES - k, k
        for i, (got, want) in enumerate(zip(part, full[k:])):
            np.testing.assert_array_equal(got, want, err_msg=f"{name}: frame {k + i} decoded from start={k}")
    window = list(iter_frames(path, start=51, stop=54, decode_order=True))
    assert len(window) == 3 and all(np.array_equal(g, w) for g, w in zip(window, full[51:54]))


def test_seeking_honours_edit_lists_and_rotation(clip_trimmed, clip_rotated):
    from rvr_addon.io.video import _video_command

    for path, start in ((clip_trimmed, 13), (clip_rotated, 5)):
        full = list(iter_frames(path))
        assert "-ss" in _video_command(path, start, None)
        part = list(iter_frames(path, start=start))
        assert len(part) == len(full) - start
        assert all(np.array_equal(g, w) for g, w in zip(part, full[start:]))


def test_containers_without_exact_seeking_decode_from_the_start(seek_clips):
    from rvr_addon.io.video import _video_command, scan_packets, seek_point

    path = seek_clips["ts"]  # MPEG-TS seeks by approximate bisection: never trusted
    assert scan_packets(path).container == "mpegts" and seek_point(scan_packets(path), 51) is None
    assert "-ss" not in _video_command(path, 51, None)
    full = list(iter_frames(path))
    part = list(iter_frames(path, start=51, stop=60))
    assert len(part) == 9 and all(np.array_equal(g, w) for g, w in zip(part, full[51:60]))


def _scan(packets: list[tuple[int, int, bool]], container: str = "mov,mp4,m4a,3gp,3g2,mj2"):
    from fractions import Fraction

    from rvr_addon.io.video import Packet, PacketScan

    return PacketScan(container, Fraction(1, 100), [Packet(d, p, k, False) for d, p, k in packets])


def test_seek_point_refuses_what_it_cannot_guarantee():
    from rvr_addon.io.video import seek_point

    # decode order I0 P3 B1 B2 I6(open GOP) B4 B5 P7: frames 4 and 5 are leading pictures of I6
    gop = [(0, 0, True), (10, 30, False), (20, 10, False), (30, 20, False), (40, 60, True), (50, 40, False),
           (60, 50, False), (70, 70, False)]
    target, threshold = seek_point(_scan(gop), 4)
    assert target < 0.40 and threshold == pytest.approx(0.35)  # lands on I0, not on I6 (after frame 4 in decode order)
    target, threshold = seek_point(_scan(gop), 6)
    assert 0.40 <= target < 0.60 and threshold == pytest.approx(0.55)  # I6 or earlier, never the key after it
    assert seek_point(_scan(gop), 8) is None  # past the end
    assert seek_point(_scan(gop, container="mpegts"), 4) is None
    assert seek_point(_scan([(0, 0, False)] + gop[1:]), 4) is None  # does not start with a keyframe
    assert seek_point(_scan(gop[:2] + [(20, 30, False)] + gop[3:]), 4) is None  # a repeated pts
    assert seek_point(_scan(gop[:2] + [(20, None, False)] + gop[3:]), 4) is None  # a missing pts


def test_a_listing_prefix_decides_only_what_later_packets_cannot_change():
    from dataclasses import replace

    from rvr_addon.io.video import prefix_decides, seek_point

    # I0 P100 B1 .. B99 I101 P102 (decode order; legal with one reorder frame): B99, listed 98
    # packets after P100, is shown before it. A prefix must not take P100 for frame 2.
    full = _scan([(0, 0, True), (1, 100, False)] + [(1 + i, i, False) for i in range(1, 100)]
                 + [(101, 101, True), (102, 102, False)])
    decided = {}
    for length in range(1, len(full.packets)):
        prefix = replace(full, packets=full.packets[:length], complete=False)
        for start in (1, 5, 60, 99, 100):
            if prefix_decides(prefix, start):
                decided.setdefault(start, length)
                assert seek_point(prefix, start) == seek_point(full, start), (length, start)
    assert decided == {1: 102, 5: 102, 60: 102}  # the keyframe after I0 decides the seek target
    assert seek_point(full, 100)[0] < 0.2 <= 1.01 <= seek_point(full, 101)[0]  # P100 follows I0 in decode order


def test_bundled_ffmpeg_gets_its_execute_bit_back(tmp_path):
    """Blender's extension installer unpacks wheels without the execute bit (imageio-ffmpeg's
    binary then counts as missing); ffmpeg_exe() restores it."""
    import stat

    from rvr_addon.io.video import restore_execute_bit

    exe = tmp_path / "ffmpeg-linux-x86_64-v7.0.2"
    exe.write_bytes(b"#!/bin/sh\n")
    exe.chmod(0o644)
    other = tmp_path / "README.md"
    other.write_text("x")
    other.chmod(0o644)
    assert restore_execute_bit(tmp_path) == [exe]
    assert stat.S_IMODE(exe.stat().st_mode) == 0o755 and stat.S_IMODE(other.stat().st_mode) == 0o644
    assert restore_execute_bit(tmp_path) == []  # already executable: untouched
    assert restore_execute_bit(tmp_path / "missing") == []


def _hlg_pair(tmp_path):
    """The same 6 frames (smooth colour blobs, 160x90, seeded) as an SDR BT.709 H.264 clip and as an
    HLG (BT.2020, 10-bit HEVC) clip made from it, as a phone records HDR; skips where this ffmpeg
    cannot make them."""
    import subprocess

    from rvr_addon.io.video import ffmpeg_exe
    from rvr_addon.io.writer import VideoWriter

    rng = np.random.default_rng(11)
    base = cv2.resize(rng.uniform(20, 235, (6, 10, 3)).astype(np.float32), (160, 90), interpolation=cv2.INTER_CUBIC)
    sdr, hlg = tmp_path / "sdr.mp4", tmp_path / "hlg.mp4"
    with VideoWriter(sdr, fps=10, size=(160, 90), crf=0) as w:
        for k in range(6):
            w.write(np.clip(np.roll(base, 4 * k, axis=1), 0, 255).astype(np.uint8))
    tags = "setparams=color_primaries=bt709:color_trc=bt709:colorspace=bt709:range=tv"
    to_hlg = (f"{tags},zscale=t=linear:npl=100:p=bt2020:m=gbr,format=gbrpf32le,"
              "zscale=t=arib-std-b67:m=bt2020nc:r=tv,format=yuv420p10le")
    out = subprocess.run([ffmpeg_exe(), "-y", "-hide_banner", "-v", "error", "-i", str(sdr), "-vf", to_hlg,
                          "-c:v", "libx265", "-x265-params", "log-level=error:lossless=1", "-color_primaries", "bt2020",
                          "-color_trc", "arib-std-b67", "-colorspace", "bt2020nc", str(hlg)], capture_output=True)
    if out.returncode != 0:
        pytest.skip(f"this ffmpeg cannot make the HLG test clip: {out.stderr.decode()[-200:]}")
    return sdr, hlg


def test_an_hdr_phone_clip_is_tone_mapped_to_the_sdr_the_engine_works_in(tmp_path, caplog, monkeypatch):
    """An HLG clip (an iPhone's HDR video) decoded as if it were SDR comes out dark and at about
    half the saturation; decoded through the HDR-to-SDR filters it matches the SDR clip of the same
    frames. Seeking into it gives the same frames; the probe says it is HDR."""
    from rvr_addon.io import video as V

    sdr, hlg = _hlg_pair(tmp_path)
    assert V.video_transfer(hlg) == "HLG" and V.video_transfer(sdr) is None
    ref = np.stack(list(iter_frames(sdr))).astype(np.float64)
    with caplog.at_level(logging.INFO, logger="rvr_addon.io.video"):
        info = probe_clip(hlg)
    assert (info.width, info.height, info.frame_count) == (160, 90, 6)
    assert "HDR (HLG)" in caplog.text and "tone-mapped" in caplog.text
    mapped = np.stack(list(iter_frames(hlg))).astype(np.float64)
    np.testing.assert_array_equal(np.stack(list(iter_frames(hlg, 2, 5))), mapped[2:5].astype(np.uint8))

    def psnr(a):
        return 10 * np.log10(255.0 ** 2 / np.mean((a - ref) ** 2))

    monkeypatch.setattr(V, "_hdr_filter", lambda video: None)  # what the decoder did before
    raw = np.stack(list(iter_frames(hlg))).astype(np.float64)
    assert psnr(mapped) > 30.0 and psnr(raw) < 20.0, (psnr(mapped), psnr(raw))  # 32.6 / 14.7 dB here
    assert abs(mapped.mean() - ref.mean()) < 3.0 < 10.0 < abs(raw.mean() - ref.mean())


def test_hdr_transfer_reads_the_first_video_stream():
    from rvr_addon.io.video import hdr_transfer

    line = "  Stream #0:0[0x1](und): Video: hevc (Main 10), yuv420p10le(tv, bt2020nc/bt2020/{}), 1920x1080"
    assert hdr_transfer(line.format("arib-std-b67")) == "HLG"
    assert hdr_transfer(line.format("smpte2084")) == "PQ (HDR10)"
    assert hdr_transfer(line.format("bt709")) is None
    assert hdr_transfer("  Stream #0:1: Audio: aac, arib-std-b67") is None
