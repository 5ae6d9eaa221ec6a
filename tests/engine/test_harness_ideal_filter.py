"""The ideal-filter bound (sintel_eval/ideal_filter.py, ablation row ``temporal_ideal_est``):
exact correspondences from depth and cameras, and the per-point mean of the estimates' errors."""
from __future__ import annotations

import numpy as np
import pytest

from harness_data import FAKE_F_PX, WALL_D, write_fake_clip
from rvr_addon.errors import InputError
from sintel_eval.ideal_filter import correspondence, ideal_estimates, ideal_stage
from sintel_eval.reader import ClipReader, GTFrame

F_PX = 100.0


def _camera_at(x_m: float) -> np.ndarray:
    """world_to_camera of a Blender camera at (x_m, 0, 0) looking along -Z (no rotation)."""
    m = np.eye(4)
    m[0, 3] = -x_m
    return m


def _frame(index: int, d: np.ndarray, depth: np.ndarray, w2c: np.ndarray | None) -> GTFrame:
    h, w = d.shape
    return GTFrame(frame=index + 1, index=index, input_srgb=np.full((h, w, 3), 100 + index, np.uint8),
                   exponent=np.zeros((h, w, 3), np.float32), radiance=np.zeros((h, w, 3), np.float32),
                   disparity=d.astype(np.float32), dof_linear=np.zeros((h, w, 3), np.float32), focus=0.0,
                   aperture=1.0, depth_m=depth.astype(np.float32), world_to_camera=w2c, f_px=F_PX)


def test_correspondence_of_a_sideways_camera_and_an_occluder():
    """A wall 2 m away seen by a camera moved 0.1 m to the right shifts f * 0.1 / 2 = 5 px to the
    left; where frame k has something nearer in front, frame k does not see the wall."""
    h, w = 20, 40
    wall = np.full((h, w), 2.0)
    maps, visible = correspondence(wall, _camera_at(0.0), _camera_at(0.1), F_PX, wall)
    cols = np.arange(w, dtype=np.float32)[None, :].repeat(h, 0)
    rows = np.arange(h, dtype=np.float32)[:, None].repeat(w, 1)
    np.testing.assert_allclose(maps[..., 0], cols - 5.0, atol=1e-4)
    np.testing.assert_allclose(maps[..., 1], rows, atol=1e-4)
    assert not visible[:, :5].any() and visible[:, 5:].all()  # the first 5 columns leave frame k
    occluded = wall.copy()
    occluded[5:10, 20:30] = 1.0  # a nearer object in frame k, over columns 20..29
    _, vis2 = correspondence(wall, _camera_at(0.0), _camera_at(0.1), F_PX, occluded)
    assert not vis2[5:10, 25:35].any() and vis2[5:10, 5:25].all() and vis2[10:, 5:].all()


def test_ideal_estimates_average_each_points_error_over_the_clip():
    """Still camera, still wall: per-frame errors c_k (and E errors) average to their mean in
    every frame; a frame without the error spread keeps the exact mean, E stays >= 0."""
    h, w = 12, 16
    d_gt = np.linspace(-2, 3, h * w, dtype=np.float32).reshape(h, w)
    depth = 1.0 / (0.5 - d_gt / 20.0)
    frames = [_frame(i, d_gt, depth, np.eye(4)) for i in range(4)]
    offsets = [0.4, -0.2, 1.0, 0.2]  # mean 0.35
    e_err = [0.02, 0.0, 0.06, 0.0]  # mean 0.02

    def estimates(fr: GTFrame):
        return fr.disparity + offsets[fr.index], fr.exponent + e_err[fr.index]

    out = ideal_estimates(frames, estimates)
    for d, e in out:
        np.testing.assert_allclose(d, d_gt + 0.35, atol=1e-5)
        np.testing.assert_allclose(e, 0.02, atol=1e-6)
    narrow = ideal_estimates(frames, estimates, half_window=1)  # frames 0 and 1 only for frame 0
    np.testing.assert_allclose(narrow[0][0], d_gt + 0.1, atol=1e-5)


def test_an_error_attached_to_the_scene_is_left_as_it_is():
    """A panning camera over a wall whose estimate is wrong by a pattern fixed on the wall: that
    error is steady, so the ideal filter returns the estimates unchanged where frames overlap."""
    h, w, z = 10, 60, 2.0
    depth = np.full((h, w), z)
    d_gt = np.full((h, w), 1.5, np.float32)
    xs = [0.0, 0.04, 0.08]  # 2 px of pan a frame at 2 m

    def wall_x(fr: GTFrame) -> np.ndarray:  # world X of every pixel centre of the frame
        return (np.arange(w) + 0.5 - w / 2) * z / F_PX + xs[fr.index]

    frames = [_frame(i, d_gt, depth, _camera_at(x)) for i, x in enumerate(xs)]

    def estimates(fr: GTFrame):
        return (fr.disparity + np.sin(wall_x(fr) * 9.0)[None, :]).astype(np.float32), fr.exponent

    out = ideal_estimates(frames, estimates)
    for fr, (d, _) in zip(frames, out):
        np.testing.assert_allclose(d[:, 8:-8], estimates(fr)[0][:, 8:-8], atol=1e-5)


def test_ideal_row_names_what_is_missing():
    h, w = 4, 6
    fr = _frame(0, np.zeros((h, w)), np.ones((h, w)), None)
    with pytest.raises(InputError, match="camera_per_frame.*regenerate"):
        ideal_estimates([fr], lambda f: (f.disparity, f.exponent))


def test_reader_gives_depth_and_camera_and_the_stage_runs_on_a_clip(tmp_path):
    """The harness reader passes Z and the per-frame camera; on the fake clip (a still camera)
    the stage's wall pixels get the mean of the per-frame errors, in every focus track."""
    clip = write_fake_clip(tmp_path / "clip", frames=3)
    reader = ClipReader(clip)
    frames = list(reader.iter_frames("constant"))
    assert frames[0].f_px == FAKE_F_PX and np.array_equal(frames[0].world_to_camera, np.eye(4))
    np.testing.assert_allclose(frames[0].depth_m[0, -1], 1.0 / (0.5 - WALL_D / 20.0), rtol=1e-6)
    offsets = {1: 0.3, 2: -0.6, 3: 0.9}
    stage = ideal_stage(lambda fr: (fr.disparity + offsets[fr.frame], fr.exponent))
    for track in reader.tracks:
        out = list(stage(reader.iter_frames(track)))
        assert [fr.frame for fr, _ in out] == [1, 2, 3]
        for _, inputs in out:
            np.testing.assert_allclose(inputs.disparity[-4:, -8:], WALL_D + 0.2, atol=1e-5)
