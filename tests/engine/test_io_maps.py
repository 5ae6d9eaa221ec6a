"""EXR read/write and per-frame disparity / HDR-exponent map sequences."""
from __future__ import annotations

import logging
import os

import cv2
import numpy as np
import pytest

from rvr_addon.errors import InputError, OutputError
from rvr_addon.io.exr import read_exr, read_exr_header, write_exr
from rvr_addon.io.maps import fill_nonfinite, open_map_sequence

H, W = 6, 8


def ramp(offset: float = 0.0) -> np.ndarray:
    """(6, 8) float32 with distinct non-round values."""
    return (np.arange(H * W, dtype=np.float32).reshape(H, W) * 0.37 - 5.1 + offset).astype(np.float32)


# ----------------------------------------------------------------------------- EXR


def test_exr_round_trip_float32_exact(tmp_path):
    channels = {"R": ramp(), "G": ramp(1), "B": ramp(2), "rvr.D": ramp(3) * 1e-3, "rvr.E": np.full((H, W), 1e9, np.float32)}
    write_exr(tmp_path / "a.exr", channels)
    back = read_exr(tmp_path / "a.exr")
    assert set(back) == set(channels)
    for name, array in channels.items():
        assert back[name].dtype == np.float32 and back[name].shape == (H, W)
        np.testing.assert_array_equal(back[name], array)


def test_exr_rle_is_lossless_and_unknown_compression_is_refused(tmp_path):
    import OpenEXR

    channels = {"D": ramp(), "E.R": np.random.default_rng(0).normal(size=(H, W)).astype(np.float32)}
    write_exr(tmp_path / "r.exr", dict(channels), compression="rle")
    assert OpenEXR.File(str(tmp_path / "r.exr")).header()["compression"] == OpenEXR.RLE_COMPRESSION
    back = read_exr(tmp_path / "r.exr")
    for name, array in channels.items():
        np.testing.assert_array_equal(back[name], array)
    with pytest.raises(ValueError, match="compression 'lzw'"):
        write_exr(tmp_path / "x.exr", channels, compression="lzw")
    assert not (tmp_path / "x.exr").exists()


def test_exr_half_round_trip(tmp_path):
    write_exr(tmp_path / "h.exr", {"Y": ramp()}, half=True)
    back = read_exr(tmp_path / "h.exr")["Y"]
    assert back.dtype == np.float32
    np.testing.assert_allclose(back, ramp(), rtol=1e-3, atol=1e-3)
    np.testing.assert_array_equal(back, ramp().astype(np.float16).astype(np.float32))


def test_exr_multipart_names(tmp_path):
    import OpenEXR

    parts = [OpenEXR.Part({}, {"Z": ramp()}, "left"), OpenEXR.Part({}, {"Z": ramp(1)}, "right")]
    OpenEXR.File(parts).write(str(tmp_path / "m.exr"))
    back = read_exr(tmp_path / "m.exr")
    assert sorted(back) == ["left.Z", "right.Z"]
    np.testing.assert_array_equal(back["right.Z"], ramp(1))


def test_exr_header_names_the_channels_and_size_as_read_does(tmp_path):
    """The header alone (the cache's check of a frame) gives read_exr's channel names and (w, h)."""
    import OpenEXR

    write_exr(tmp_path / "a.exr", {"D": ramp(), "E.R": ramp(1)})
    assert read_exr_header(tmp_path / "a.exr") == (["D", "E.R"], (W, H))
    parts = [OpenEXR.Part({}, {"Z": ramp()}, "left"), OpenEXR.Part({}, {"Z": ramp(1)}, "right")]
    OpenEXR.File(parts).write(str(tmp_path / "m.exr"))
    names, size = read_exr_header(tmp_path / "m.exr")
    assert sorted(names) == sorted(read_exr(tmp_path / "m.exr")) and size == (W, H)
    (tmp_path / "bad.exr").write_bytes(b"not an exr")
    with pytest.raises(InputError, match="bad.exr"):
        read_exr_header(tmp_path / "bad.exr")
    with pytest.raises(InputError, match="not found"):
        read_exr_header(tmp_path / "missing.exr")


def test_exr_write_is_atomic_and_leaves_no_temp(tmp_path):
    target = tmp_path / "keep.exr"
    write_exr(target, {"Y": ramp()})
    before = target.read_bytes()
    with pytest.raises(OutputError, match=r"keep\.exr"):
        write_exr(target, {"Y": ramp(), "Z": np.zeros((2, 2), np.float32)})
    assert target.read_bytes() == before
    assert os.listdir(tmp_path) == ["keep.exr"]


@pytest.mark.parametrize(
    "content, match",
    [pytest.param(None, r"not found.*nothere\.exr", id="missing"), pytest.param(b"garbage", r"nothere\.exr.*corrupt", id="corrupt")],
)
def test_exr_read_errors_name_file(tmp_path, content, match):
    path = tmp_path / "nothere.exr"
    if content is not None:
        path.write_bytes(content)
    with pytest.raises(InputError, match=match):
        read_exr(path)


# ----------------------------------------------------------------------------- map sequences


def write_exr_sequence(folder, n: int, name: str = "D") -> list[np.ndarray]:
    folder.mkdir(exist_ok=True)
    maps = [ramp(i) for i in range(n)]
    for i, m in enumerate(maps):
        write_exr(folder / f"d_{i + 1:04d}.exr", {name: m, "R": np.zeros_like(m)})
    return maps


@pytest.mark.parametrize(
    "spec",
    [pytest.param("{d}", id="directory"), pytest.param("{d}/*.exr", id="glob"), pytest.param("{d}/d_%04d.exr", id="printf")],
)
def test_exr_sequence_values(tmp_path, spec):
    maps = write_exr_sequence(tmp_path / "depth", 3)
    seq = open_map_sequence(spec.format(d=tmp_path / "depth"), scale=2.0, offset=-1.0)
    assert len(seq) == 3 and not seq.static
    for i in range(3):
        got = seq.get(i)
        assert got.dtype == np.float32 and got.shape == (H, W)
        np.testing.assert_allclose(got, maps[i] * 2.0 - 1.0, rtol=0, atol=1e-6)


@pytest.mark.parametrize(
    "channel",
    [pytest.param("D", id="D"), pytest.param("rvr.D", id="layer-prefix"), pytest.param("disparity", id="disparity"),
     pytest.param("depth.Z", id="Z")],
)
def test_disparity_channel_choice(tmp_path, channel):
    write_exr(tmp_path / "one.exr", {"G": np.zeros((H, W), np.float32), channel: ramp(), "Y": ramp(9)})
    np.testing.assert_array_equal(open_map_sequence(tmp_path / "one.exr").get(0), ramp())


def test_exr_without_known_channel_names_file(tmp_path):
    write_exr(tmp_path / "odd.exr", {"foo": ramp()})
    with pytest.raises(InputError, match=r"odd\.exr.*foo"):
        open_map_sequence(tmp_path / "odd.exr").get(0)


def test_single_file_serves_every_frame(tmp_path):
    np.save(tmp_path / "d.npy", ramp())
    seq = open_map_sequence(tmp_path / "d.npy", offset=1.0)
    assert seq.static and len(seq) == 1
    seq.check_length(500)
    np.testing.assert_array_equal(seq.get(0), ramp() + 1.0)
    out = seq.get(499)
    np.testing.assert_array_equal(out, ramp() + 1.0)
    out[:] = 0  # the cached map must not be modified through a returned array
    np.testing.assert_array_equal(seq.get(3), ramp() + 1.0)


@pytest.mark.parametrize(
    "dtype, stored, expected",
    [
        pytest.param(np.uint16, 32768, 32768 / 65535 * 10.0, id="png16"),
        pytest.param(np.uint16, 65535, 10.0, id="png16-max"),
        pytest.param(np.uint8, 51, 2.0, id="png8"),
    ],
)
def test_png_is_normalised_then_scaled(tmp_path, dtype, stored, expected):
    cv2.imwrite(str(tmp_path / "d.png"), np.full((H, W), stored, dtype))
    got = open_map_sequence(tmp_path / "d.png", scale=10.0).get(0)
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-5)


def test_float_tiff(tmp_path):
    assert cv2.imwrite(str(tmp_path / "d.tif"), ramp())
    np.testing.assert_array_equal(open_map_sequence(tmp_path / "d.tif").get(0), ramp())


@pytest.mark.parametrize(
    "arrays, expected_offset",
    [
        pytest.param({"a": ramp(5), "disparity": ramp()}, 0.0, id="key-disparity"),
        pytest.param({"first": ramp(5), "other": ramp()}, 5.0, id="first-array"),
    ],
)
def test_npz(tmp_path, arrays, expected_offset):
    np.savez(tmp_path / "d.npz", **arrays)
    np.testing.assert_array_equal(open_map_sequence(tmp_path / "d.npz").get(0), ramp(expected_offset))


def test_hdr_maps_keep_three_channels(tmp_path):
    write_exr(tmp_path / "rgb.exr", {"R": ramp(), "G": ramp(1), "B": ramp(2)})
    got = open_map_sequence(tmp_path / "rgb.exr", kind="hdr").get(0)
    assert got.shape == (H, W, 3)
    np.testing.assert_array_equal(got[:, :, 2], ramp(2))
    write_exr(tmp_path / "e.exr", {"E": ramp(), "R": ramp(1), "G": ramp(1), "B": ramp(1)})
    np.testing.assert_array_equal(open_map_sequence(tmp_path / "e.exr", kind="hdr").get(0), ramp())
    write_exr(tmp_path / "e3.exr", {"rvr.E.R": ramp(), "rvr.E.G": ramp(1), "rvr.E.B": ramp(2), "Y": ramp(7)})
    got = open_map_sequence(tmp_path / "e3.exr", kind="hdr").get(0)
    np.testing.assert_array_equal(got[:, :, 1], ramp(1))
    np.save(tmp_path / "e.npy", np.dstack([ramp(), ramp(1), ramp(2)]))
    assert open_map_sequence(tmp_path / "e.npy", kind="hdr").get(0).shape == (H, W, 3)


def test_size_mismatch_resamples_with_one_warning(tmp_path, caplog):
    folder = tmp_path / "small"
    folder.mkdir()
    for i in range(3):
        np.save(folder / f"m{i}.npy", np.full((4, 5), 3.0 + i, np.float32))
    seq = open_map_sequence(folder)
    with caplog.at_level(logging.WARNING, logger="rvr_addon.io.maps"):
        maps = [seq.get(i, size=(10, 8)) for i in range(3)]
    assert all(m.shape == (8, 10) for m in maps)
    np.testing.assert_allclose(maps[2], 5.0)  # values are not rescaled by the resampling
    warnings = [r for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warnings) == 1
    assert "m0.npy" in warnings[0].getMessage() and "5x4" in warnings[0].getMessage()
    assert "10x8" in warnings[0].getMessage()


def test_nan_filled_with_nearest_finite_value(tmp_path, caplog):
    m = np.zeros((5, 7), np.float32)
    m[:, :3] = 1.0
    m[:, 4:] = 9.0
    m[2, 0] = np.nan  # nearest finite neighbours are all 1.0
    m[1, 6] = np.inf  # nearest finite neighbours are all 9.0
    m[:, 3] = np.nan  # a column between 1.0 and 9.0: nearest finite value is one of them
    np.save(tmp_path / "nan.npy", m)
    with caplog.at_level(logging.WARNING, logger="rvr_addon.io.maps"):
        got = open_map_sequence(tmp_path / "nan.npy").get(0)
    assert np.isfinite(got).all()
    assert got[2, 0] == 1.0 and got[1, 6] == 9.0
    assert set(np.unique(got[:, 3])) <= {1.0, 9.0}
    messages = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert len(messages) == 1 and "nan.npy" in messages[0] and " 7 " in messages[0]


def test_fill_nonfinite_per_channel():
    m = np.dstack([ramp(), ramp(1), ramp(2)])
    m[0, 0, 1] = np.nan
    filled, count = fill_nonfinite(m)
    assert count == 1
    assert filled[0, 0, 1] in (ramp(1)[0, 1], ramp(1)[1, 0], ramp(1)[1, 1])
    np.testing.assert_array_equal(filled[:, :, 0], ramp())


def test_all_nan_map_is_an_error(tmp_path):
    np.save(tmp_path / "void.npy", np.full((4, 4), np.nan, np.float32))
    with pytest.raises(InputError, match=r"void\.npy.*no finite value"):
        open_map_sequence(tmp_path / "void.npy").get(0)


def test_index_beyond_sequence(tmp_path):
    write_exr_sequence(tmp_path / "depth", 3)
    seq = open_map_sequence(tmp_path / "depth")
    with pytest.raises(InputError, match=r"depth sequence '.*depth' has 3 maps but frame 5 was requested"):
        seq.get(5)
    with pytest.raises(InputError, match=r"has 3 maps but the clip has 12 frames; supply one map per frame"):
        seq.check_length(12)
    seq.check_length(3)


@pytest.mark.parametrize(
    "make, spec, match",
    [
        pytest.param(None, "missing/*.exr", r"depth maps '.*missing/\*\.exr' were not found|holds no depth maps",
                     id="no-match"),
        pytest.param(None, "nothing.exr", r"depth maps '.*nothing\.exr' were not found", id="missing-file"),
        pytest.param("empty", "empty", r"Folder '.*empty' holds no depth maps", id="empty-dir"),
    ],
)
def test_open_errors_name_path(tmp_path, make, spec, match):
    if make:
        (tmp_path / make).mkdir()
    with pytest.raises(InputError, match=match):
        open_map_sequence(tmp_path / spec)


def test_corrupt_map_file_names_file(tmp_path):
    (tmp_path / "bad.png").write_bytes(b"nope")
    with pytest.raises(InputError, match=r"bad\.png"):
        open_map_sequence(tmp_path / "bad.png").get(0)


def test_unknown_kind():
    with pytest.raises(InputError, match="kind"):
        open_map_sequence("x.exr", kind="normals")


def test_shared_reads_decode_each_file_once_and_share_no_array(tmp_path):
    """The depth and HDR maps of one folder (a cache's D and E live in one file per frame):
    with share_exr_reads each file is decoded once, values are those of separate reads, and
    changing a returned array in place changes nothing read later."""
    from rvr_addon.io.maps import share_exr_reads

    folder = tmp_path / "maps"
    for i in range(3):
        write_exr(folder / f"f_{i:04d}.exr", {"D": ramp(i), "E.R": ramp(10 + i), "E.G": ramp(20 + i),
                                              "E.B": ramp(30 + i)})
    depth, hdr = open_map_sequence(folder), open_map_sequence(folder, kind="hdr")
    shared = share_exr_reads(depth, hdr)
    for i in range(3):
        d = depth.get(i)
        d += 100.0  # the caller's own array
        e = hdr.get(i)
        np.testing.assert_array_equal(e[:, :, 2], ramp(30 + i))
        np.testing.assert_array_equal(depth.get(i), ramp(i))  # kept channels were handed over once: read again
        e2 = hdr.get(i)  # the depth read kept them: the HDR map comes from memory, equal to a file read
        np.testing.assert_array_equal(e2, open_map_sequence(folder, kind="hdr").get(i))
    assert shared.decoded == 6  # 3 frames x (one read shared by D and E, one by the second D and E)
    # a rewritten file is read again, not taken from memory
    depth.get(0)
    write_exr(folder / "f_0000.exr", {"D": ramp(5), "E.R": ramp(5), "E.G": ramp(5), "E.B": ramp(5)})
    os.utime(folder / "f_0000.exr", ns=(1, 1))
    np.testing.assert_array_equal(hdr.get(0)[:, :, 0], ramp(5))
    shared.clear()
    np.testing.assert_array_equal(hdr.get(0)[:, :, 0], ramp(5))
