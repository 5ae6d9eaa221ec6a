"""depth.refine.ClipRefiner: a frame without geometry takes the geometry of the frames after it
(where the scene moved to), frames whose own geometry agrees keep it, nothing crosses a cut, the
people cue is not shared between frames, the lag (items out = items in, in order), tiny frames,
full-size D keeps its own edges; and the shared cut detector's confirmation (fast motion is not
a cut, a real cut still is)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rvr_addon.depth.fuse import FusedDepth, FusionSettings
from rvr_addon.depth.refine import ClipRefiner, carry_step
from rvr_addon.temporal.cuts import CutDetector

W, H = 160, 96


def textured(h: int = H, w: int = W, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.clip(90 + rng.normal(0, 25, (h, w, 3)), 0, 255).astype(np.uint8)


def scene(h: int = H, w: int = W, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(frame, true D): a textured backdrop at D 10 with a near box (D -10) of another colour."""
    frame = textured(h, w, seed)
    d = np.full((h, w), 10.0, np.float32)
    d[30:70, 60:100] = -10.0
    frame[30:70, 60:100] = np.clip(frame[30:70, 60:100].astype(int) + (100, -40, 40), 0, 255).astype(np.uint8)
    return frame, d


def item(frame, d, conf, cues=("parallax", "network")):
    c = np.full(d.shape, conf, np.float32) if np.isscalar(conf) else conf
    return frame, d, np.zeros((*d.shape, 3), np.float32), FusedDepth(d, c, list(cues))


def run(refiner: ClipRefiner, items) -> list:
    out = []
    for it in items:
        out += list(refiner.push(it))
    return out + list(refiner.finish())


def test_a_frame_without_geometry_takes_the_geometry_of_the_frames_after_it():
    """Frame 0 has no geometry (confidence 0, a flat D: the clip's first frame); frames 1..5 are
    the scene moved 3 px right each, with their true D at confidence 1: frame 0's box comes out
    near where it is in frame 0 and the backdrop far; frames 1..5 keep their D."""
    frame, d = scene()
    frames = [np.roll(frame, 3 * k, axis=1) for k in range(6)]
    truth = [np.roll(d, 3 * k, axis=1) for k in range(6)]
    items = [item(frames[0], np.zeros((H, W), np.float32), 0.0)]
    items += [item(frames[k], truth[k], 1.0) for k in range(1, 6)]
    refiner = ClipRefiner(FusionSettings(refine_lag=4))
    out = run(refiner, items)
    assert len(out) == 6 and all(o[0] is f for o, f in zip(out, frames))  # in order, the same frames
    d0 = out[0][1]
    assert np.median(d0[35:65, 65:95]) < -8.0  # the box, near
    assert np.median(d0[5:25, 20:50]) > 8.0  # the backdrop, far
    assert out[0][3].info.get("refined") is True
    for k in range(1, 6):  # their own D, where they agree with the neighbours (inside the box, the backdrop)
        np.testing.assert_allclose(out[k][1][35:65, 65 + 3 * k:95 + 3 * k], -10.0, atol=0.5)
        np.testing.assert_allclose(out[k][1][5:25, 20:50], 10.0, atol=0.5)
    assert refiner.refined >= 1


def test_nothing_crosses_a_cut_and_people_are_not_shared():
    """Frames 0-1 (no geometry) are followed by a cut to another scene with geometry: they keep
    their D. A frame whose confidence comes from the people cue alone lends nothing either."""
    a, _ = scene(seed=1)
    b, db = scene(seed=2)
    b = np.ascontiguousarray(b[:, ::-1] // 2 + 100)  # another shot: mirrored, darker, shifted
    flat = np.zeros((H, W), np.float32)
    items = [item(a, flat, 0.0), item(a, flat, 0.0), item(b, db, 1.0), item(b, db, 1.0)]
    out = run(ClipRefiner(FusionSettings(refine_lag=4)), items)
    np.testing.assert_array_equal(out[0][1], flat)
    np.testing.assert_array_equal(out[1][1], flat)
    frame, d = scene()
    people = [item(frame, flat, 0.0), item(frame, d, 1.0, cues=("people", "network"))]
    out = run(ClipRefiner(FusionSettings(refine_lag=4)), people)
    np.testing.assert_array_equal(out[0][1], flat)


def test_lag_zero_and_agreeing_frames_change_nothing():
    frame, d = scene()
    items = [item(frame, d, 1.0) for _ in range(3)]
    out = run(ClipRefiner(FusionSettings(refine_lag=0)), items)
    assert [o is i for o, i in zip(out, items)] == [True] * 3
    refiner = ClipRefiner(FusionSettings(refine_lag=2))
    pushed = [list(refiner.push(it)) for it in items]
    assert [len(p) for p in pushed] == [0, 0, 1]  # held back two frames
    rest = list(refiner.finish())
    for o in pushed[2] + rest:
        np.testing.assert_allclose(o[1], d, atol=1e-4)  # the same D everywhere: the same D out


def test_the_fusers_flow_luma_is_reused_and_a_wrong_sized_one_is_not(monkeypatch):
    """The refiner takes the frame's luma at the flow size from FusedDepth.flow_gray (the fuser's
    carry computed it) instead of converting the frame again; one of another size is recomputed;
    with lag 0 there is no cut detector (nothing is held)."""
    import rvr_addon.temporal.flow as flow

    frame = textured(288, 480)
    d = np.zeros((288, 480), np.float32)
    size = flow.flow_size(480, 288, FusionSettings().carry_flow_side)  # (320, 192); the cut detector's is smaller
    calls = []
    real = flow.to_flow_gray
    monkeypatch.setattr(flow, "to_flow_gray", lambda f, sz: (calls.append(sz) if tuple(sz) == size else None)
                        or real(f, sz))
    given = real(frame, size)
    refiner = ClipRefiner(FusionSettings(refine_lag=2))
    ok = item(frame, d, 1.0)
    ok[3].flow_gray = given
    held = refiner._hold(ok)
    assert held.gray is given and calls == []
    bad = item(frame, d, 1.0)
    bad[3].flow_gray = given[:-1]
    assert refiner._hold(bad).gray.shape == given.shape and calls == [size]
    assert ClipRefiner(FusionSettings(refine_lag=0))._cuts is None


@pytest.mark.parametrize("h,w", [(1, 1), (2, 3), (1, 700)])
def test_tiny_and_thin_frames(h, w):
    rng = np.random.default_rng(0)
    items = [item(rng.integers(0, 255, (h, w, 3), dtype=np.uint8), rng.normal(0, 5, (h, w)).astype(np.float32),
                  float(k % 2)) for k in range(4)]
    out = run(ClipRefiner(FusionSettings(refine_lag=2)), items)
    assert len(out) == 4 and all(o[1].shape == (h, w) and np.isfinite(o[1]).all() for o in out)


def test_full_size_d_keeps_its_own_edges():
    """At 1280x720 (twice the analysis size) the refinement adds a smooth difference: an edge of
    D one pixel wide stays as sharp as it was."""
    frame, d = scene(720, 1280)
    d[:, 641:] += 4.0  # a sharp step at full resolution
    items = [item(frame, np.zeros((720, 1280), np.float32), 0.0), item(frame, d, 1.0)]
    out = run(ClipRefiner(FusionSettings(refine_lag=4)), items)
    d0 = out[0][1]
    assert d0.shape == (720, 1280)
    assert abs(np.median(d0[5:25, 600:630]) - 10.0) < 1.0 and abs(np.median(d0[5:25, 660:690]) - 14.0) < 1.0


def test_carry_step_weights():
    """own confidence 0: the carried value; carried confidence 0 (outside the neighbour): own."""
    own = np.zeros((4, 4), np.float32)
    other = np.full((4, 4), 2.0, np.float32)
    luma = np.full((4, 4), 100.0, np.float32)
    maps = np.dstack(np.meshgrid(np.arange(4, dtype=np.float32), np.arange(4, dtype=np.float32)))
    d, c = carry_step(own, np.zeros_like(own), luma, other, np.ones_like(own), luma, maps, 24.0, 0.9)
    np.testing.assert_allclose(d, 2.0)
    np.testing.assert_allclose(c, 0.9)
    d, c = carry_step(own, np.ones_like(own), luma, other, np.ones_like(own), luma, maps + 10.0, 24.0, 0.9)
    np.testing.assert_array_equal(d, own)


def test_the_cut_detector_confirms_a_candidate_with_the_better_flow(monkeypatch):
    """A pair the fast flow fails is decided by the confirming flow's answer; with confirm None,
    or when the fast flow passes, the first answer stands."""
    import rvr_addon.temporal.cuts as cuts

    answers = {"ultrafast": 0.9, "medium": 0.2}
    calls = []

    def fake_checks(flow, *args):
        calls.append(flow.preset)
        return cuts.LinkChecks(None, None, None, None, answers[flow.preset])

    monkeypatch.setattr(cuts, "link_checks", fake_checks)
    a, b = textured(seed=1), textured(seed=2)  # different enough to skip the quiet shortcut
    det = CutDetector()
    assert [det.push(f) for f in (a, b)] == [False, False] and det.fail[-1] == 0.2
    assert calls == ["ultrafast", "medium"]
    answers["medium"] = 0.95
    assert det.push(a) is True and det.cuts == [2]
    fast_only = CutDetector(confirm=None)
    assert [fast_only.push(f) for f in (a, b)] == [False, True]
    answers["ultrafast"] = 0.3
    calls.clear()
    assert CutDetector().push(a) is False and not calls  # one frame: nothing to compare


HOLOLENS = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "real_video_depth" / "hololens_office"


@pytest.mark.skipif(not HOLOLENS.is_dir(), reason="../shared/data/real_video_depth/hololens_office is not here")
def test_a_head_mounted_walk_has_almost_no_cuts():
    """The HoloLens office walk (120 frames, one shot, fast head turns): the fast flow alone calls
    28 of its pairs cuts; confirmed by the better flow, 2 (measured 2026-12-07)."""
    from rvr_addon.depth.real_video import open_rgbd_clip

    clip = open_rgbd_clip(HOLOLENS)
    det, fast_only = CutDetector(), CutDetector(confirm=None)
    for frame in clip.rgb_frames(0, len(clip)):
        det.push(frame)
        fast_only.push(frame)
    assert len(fast_only.cuts) >= 20
    assert len(det.cuts) <= 3
