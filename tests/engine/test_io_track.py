"""Focus tracks: CSV/JSON loading, per-frame resolution, errors naming file and line."""
from __future__ import annotations

import json
import logging

import numpy as np
import pytest

from rvr_addon.errors import InputError
from rvr_addon.io.track import FocusTrack, constant_track, load_track, resolve_track


def write(tmp_path, name: str, text: str):
    path = tmp_path / name
    path.write_text(text)
    return path


def test_csv_sparse_keys_interpolate_and_hold(tmp_path, caplog):
    path = write(tmp_path, "focus.csv", "frame,focus,aperture\n2,1.0,0.5\n6,3.0,1.5\n")
    track = load_track(path)
    np.testing.assert_array_equal(track.frames, [2, 6])
    assert track.focus.dtype == np.float32 and track.aperture.dtype == np.float32
    with caplog.at_level(logging.WARNING, logger="rvr_addon.io.track"):
        focus, aperture = resolve_track(track, 9)
    np.testing.assert_allclose(focus, [1, 1, 1, 1.5, 2, 2.5, 3, 3, 3])
    np.testing.assert_allclose(aperture, [0.5, 0.5, 0.5, 0.75, 1.0, 1.25, 1.5, 1.5, 1.5])
    messages = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert len(messages) == 1 and "focus.csv" in messages[0] and "frame 6" in messages[0] and "frame 8" in messages[0]


def test_resolve_with_start_offset_and_no_warning_inside_track(tmp_path, caplog):
    track = FocusTrack(np.array([0, 10]), np.array([0.0, 10.0]), np.array([1.0, 1.0]))
    with caplog.at_level(logging.WARNING):
        focus, aperture = resolve_track(track, 4, start=5)
    np.testing.assert_allclose(focus, [5, 6, 7, 8])
    np.testing.assert_allclose(aperture, 1.0)
    assert not caplog.records


def test_csv_alias_default_aperture_comments_and_order(tmp_path):
    text = "# exported by hand\nFrame, Focus_Disparity\n\n10, -2.5\n0, 4\n"
    track = load_track(write(tmp_path, "f.csv", text))
    np.testing.assert_array_equal(track.frames, [0, 10])
    np.testing.assert_allclose(track.focus, [4.0, -2.5])
    np.testing.assert_allclose(track.aperture, [1.0, 1.0])


@pytest.mark.parametrize(
    "data",
    [
        pytest.param([{"frame": 0, "focus": 1.0, "aperture": 0.0}, {"frame": 4, "focus": 5.0}], id="list"),
        pytest.param({"keys": [{"frame": 4, "focus": 5.0}, {"frame": 0, "focus": 1.0, "aperture": 0}]}, id="keys"),
    ],
)
def test_json_tracks(tmp_path, data):
    track = load_track(write(tmp_path, "f.json", json.dumps(data)))
    focus, aperture = resolve_track(track, 5)
    np.testing.assert_allclose(focus, [1, 2, 3, 4, 5])
    np.testing.assert_allclose(aperture, [0.0, 0.25, 0.5, 0.75, 1.0])


def test_constant_track_never_warns(caplog):
    with caplog.at_level(logging.WARNING):
        focus, aperture = resolve_track(constant_track(2.5, 0.0), 100, start=40)
    assert focus.shape == (100,) and np.all(focus == 2.5) and np.all(aperture == 0.0)
    assert not caplog.records


@pytest.mark.parametrize(
    "text, match",
    [
        pytest.param("frame,focus\n0,1\n1,abc\n", r"f\.csv', line 3: focus 'abc' is not a number", id="not-a-number"),
        pytest.param("frame,focus,aperture\n0,1,1\n\n5,1,-0.5\n", r"f\.csv', line 4: aperture -0\.5", id="neg-aperture"),
        pytest.param("frame,focus\n0,nan\n", r"f\.csv', line 2: focus nan is not finite", id="nan-focus"),
        pytest.param("frame,focus\n1.5,2\n", r"f\.csv', line 2: frame '1\.5'", id="fractional-frame"),
        pytest.param("time,depth\n0,1\n", r"f\.csv', line 1: header .* lacks", id="bad-header"),
        pytest.param("frame,focus\n0\n", r"f\.csv', line 2: expected 2 columns", id="short-row"),
        pytest.param("frame,focus\n3,1\n3,2\n", r"f\.csv'.*frame 3 is keyed twice", id="duplicate"),
        pytest.param("frame,focus\n", r"f\.csv' has no keys", id="no-rows"),
        pytest.param("", r"f\.csv' is empty", id="empty"),
    ],
)
def test_csv_errors_name_file_and_line(tmp_path, text, match):
    with pytest.raises(InputError, match=match):
        load_track(write(tmp_path, "f.csv", text))


@pytest.mark.parametrize(
    "text, match",
    [
        pytest.param('[{"frame": 0, "focus": 1},\n {"frame": 1, "focus": }]', r"f\.json', line 2: invalid JSON", id="syntax"),
        pytest.param('[{"frame": 0}]', r"f\.json', key #0: .* needs 'frame' and 'focus'", id="no-focus"),
        pytest.param('[{"frame": 0, "focus": 1, "aperture": -1}]', r"f\.json', key #0: aperture -1", id="neg-aperture"),
        pytest.param('{"focus": 3}', r"f\.json'", id="not-a-list"),
    ],
)
def test_json_errors_name_file(tmp_path, text, match):
    with pytest.raises(InputError, match=match):
        load_track(write(tmp_path, "f.json", text))


def test_missing_and_unknown_files(tmp_path):
    with pytest.raises(InputError, match=r"nope\.csv' not found"):
        load_track(tmp_path / "nope.csv")
    with pytest.raises(InputError, match=r"f\.xml' has an unknown type"):
        load_track(write(tmp_path, "f.xml", "<focus/>"))


@pytest.mark.parametrize(
    "focus, aperture, match",
    [
        pytest.param([1.0, 2.0], [1.0, -0.1], r"my\.csv.*frame 4 has aperture -0\.1", id="negative-aperture"),
        pytest.param([1.0, np.inf], [1.0, 1.0], r"my\.csv.*frame 4 has a non-finite focus", id="inf-focus"),
        pytest.param([1.0, 2.0], [np.nan, 1.0], r"my\.csv.*frame 0 has a non-finite aperture", id="nan-aperture"),
    ],
)
def test_resolve_rejects_bad_values(focus, aperture, match):
    track = FocusTrack(np.array([0, 4]), np.array(focus), np.array(aperture), source="Focus track 'my.csv'")
    with pytest.raises(InputError, match=match):
        resolve_track(track, 5)


def test_track_shape_errors():
    with pytest.raises(InputError, match="one focus and one aperture"):
        FocusTrack(np.array([0, 1]), np.array([1.0]), np.array([1.0, 1.0]))
    with pytest.raises(InputError, match="no keys"):
        FocusTrack(np.array([], int), np.array([]), np.array([]))
