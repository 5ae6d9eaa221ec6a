"""depth.fuse.DepthFuser on synthetic cues: people alone (metric inside, backdrop behind), no cue
(the network's D unchanged), parallax scaled by people, parallax alone (the clip's scale fixed at
its first frame with parallax and kept), the depth carried along the flow into a frame whose
parallax fails, DESIGN units, frame size, finiteness, tiny and 4K frames."""
from __future__ import annotations

import tracemalloc

import numpy as np
import pytest

from rvr_addon.depth.cues import CueMap, lens_constant
from rvr_addon.depth.fuse import DepthFuser, FusionSettings

W, H = 160, 96


def textured(h: int = H, w: int = W, seed: int = 0) -> np.ndarray:
    """A mid-grey textured backdrop (uint8 RGB)."""
    rng = np.random.default_rng(seed)
    return np.clip(90 + rng.normal(0, 12, (h, w, 3)), 0, 255).astype(np.uint8)


def person_cue(shape, boxes) -> CueMap:
    """A metric people cue: boxes (x0, y0, x1, y1, distance m); NaN elsewhere."""
    q = np.full(shape, np.nan, np.float32)
    c = np.zeros(shape, np.float32)
    for x0, y0, x1, y1, dist in boxes:
        q[y0:y1, x0:x1] = 1.0 / dist
        c[y0:y1, x0:x1] = 1.0
    return CueMap("people", q, c, metric=True, shift_free=True, info={"people": len(boxes)})


def with_people(frame: np.ndarray, boxes) -> np.ndarray:
    out = frame.copy()
    for i, (x0, y0, x1, y1, _) in enumerate(boxes):
        out[y0:y1, x0:x1] = (220, 180 - 60 * i, 150)  # a person stands out of the backdrop
    return out


def q_of(d: np.ndarray, fuser: DepthFuser) -> np.ndarray:
    """Back from D to the fused inverse depth: D = K (q_ref - q)."""
    return fuser.q_ref - d / fuser.K


def test_people_only_metric_inside_and_backdrop_behind():
    boxes = [(60, 20, 100, 96, 1.5)]
    frame = with_people(textured(), boxes)
    fuser = DepthFuser(W)
    net_d = np.zeros((H, W), np.float32)  # the network thinks everything is at one depth: the person too
    out = fuser(frame, net_d, [person_cue((H, W), boxes)])
    assert out.disparity.shape == (H, W) and out.confidence.shape == (H, W)
    assert np.isfinite(out.disparity).all() and out.cues == ["people", "network"]
    q = q_of(out.disparity, fuser)
    inside = q[30:90, 66:94]
    np.testing.assert_allclose(inside, 1 / 1.5, rtol=0.02)
    # around the person (a ring 4 px .. 3/4 of behind_reach of the frame width wide; the ceiling fades out
    # beyond): no nearer than behind_ratio x the person
    s = fuser.settings
    reach = int(0.75 * s.behind_reach * W)
    around = np.concatenate([q[20:, 60 - reach:56].ravel(), q[20:, 104:100 + reach].ravel(),
                             q[20 - reach:16, 60 - reach:100 + reach].ravel()])
    assert around.max() <= s.behind_ratio * (1 / 1.5) * 1.03
    assert fuser.used == {"frames": 1, "parallax": 0, "people": 1, "network_only": 0, "carried": 0}


def test_no_cue_leaves_the_network_d_unchanged():
    rng = np.random.default_rng(3)
    net_d = rng.normal(0, 3, (H, W)).astype(np.float32)
    fuser = DepthFuser(W)
    empty = CueMap("people", np.full((H, W), np.nan, np.float32), np.zeros((H, W), np.float32), metric=True)
    for cues in ([], [empty]):
        out = fuser(textured(), net_d, cues)
        np.testing.assert_array_equal(out.disparity, net_d)
        assert out.cues == ["network"] and not out.confidence.any()
    assert fuser.used["network_only"] == 2 and fuser._fit is None
    # once cues have fitted the network, a frame without cues keeps the clip's units (through that fit)
    fuser(with_people(textured(), [(60, 20, 100, 96, 1.5)]), net_d, [person_cue((H, W), [(60, 20, 100, 96, 1.5)])])
    a, b = fuser._fit
    out = fuser(textured(), net_d, [])
    np.testing.assert_allclose(out.disparity, fuser.K * (fuser.q_ref - (a * net_d + b)), rtol=1e-5, atol=1e-5)


def test_design_units_two_people():
    """D = K (q_ref - q) with K = lens_constant(width): two people at 1 m and 2 m differ by K / 2."""
    boxes = [(10, 10, 50, 90, 1.0), (100, 10, 140, 90, 2.0)]
    fuser = DepthFuser(W)
    out = fuser(with_people(textured(), boxes), np.zeros((H, W), np.float32), [person_cue((H, W), boxes)])
    K = lens_constant(W)
    assert fuser.K == pytest.approx(K)
    near, far = np.median(out.disparity[20:80, 20:40]), np.median(out.disparity[20:80, 110:130])
    assert far - near == pytest.approx(K * (1.0 - 0.5), rel=0.02)  # farther = larger D (behind focus)
    assert fuser.q_ref is not None and np.isfinite(fuser.q_ref)


def test_a_portrait_clip_spans_its_long_side():
    """The reference lens's sensor spans the frame's long side, so a 360x640 (portrait) clip gets
    the K of a 640x360 one: the same phone held upright blurs as much, in px, as held sideways."""
    from rvr_addon.depth.cues import blur_span, inverse_depth_to_disparity

    assert blur_span(360, 640) == blur_span(640, 360) == 640
    assert lens_constant(360, 640) == pytest.approx(lens_constant(640)) == pytest.approx(lens_constant(640, 360))
    assert lens_constant(360) == pytest.approx(lens_constant(640) * 360 / 640)
    assert DepthFuser(360, height=640).K == pytest.approx(lens_constant(640))
    assert DepthFuser(640, height=360).K == pytest.approx(DepthFuser(640).K)
    q = np.array([0.5, 1.0], np.float32)
    assert np.allclose(inverse_depth_to_disparity(q, 360, height=640), inverse_depth_to_disparity(q, 640))


def scene_q(h: int = H, w: int = W) -> np.ndarray:
    """True inverse depth (1/m): a backdrop at 4 m, a box at 2 m, a near box at 1 m."""
    q = np.full((h, w), 0.25, np.float32)
    q[20:80, 20:70] = 0.5
    q[30:90, 100:140] = 1.0
    return q


def scene_frame(q: np.ndarray) -> np.ndarray:
    frame = textured(*q.shape)
    frame[q == 0.5] = (40, 160, 60)
    frame[q == 1.0] = (220, 180, 150)
    return frame


def parallax_cue(q_rel: np.ndarray, mask: np.ndarray | None = None) -> CueMap:
    c = np.ones(q_rel.shape, np.float32) if mask is None else mask.astype(np.float32)
    return CueMap("parallax", np.where(c > 0, q_rel, np.nan).astype(np.float32), c, metric=False, shift_free=True)


def test_parallax_scale_is_fixed_by_people():
    q = scene_q()
    frame = scene_frame(q)
    fuser = DepthFuser(W)
    # parallax knows q up to a scale (here 5x); the person (the near box) is metric
    people = person_cue((H, W), [(100, 30, 140, 90, 1.0)])
    net_d = lens_constant(W) * (0.3 - q)  # a network that is right up to an affine map
    out = fuser(frame, net_d, [parallax_cue(5.0 * q), people])
    assert fuser.parallax_scale == pytest.approx(0.2, rel=1e-3)
    assert out.cues == ["parallax", "people", "network"] and fuser.used["parallax"] == 1
    fq = q_of(out.disparity, fuser)
    assert np.median(fq[30:70, 30:60]) == pytest.approx(0.5, rel=0.03)  # the 2 m box, metric now
    assert np.median(fq[5:15, 80:95]) == pytest.approx(0.25, rel=0.05)  # the backdrop at 4 m


def test_parallax_alone_scale_set_once_and_kept():
    q = scene_q()
    frame = scene_frame(q)
    fuser = DepthFuser(W)
    K = lens_constant(W)
    # frame 0: no parallax yet (the network alone); frame 1: the first parallax; frame 2: parallax
    # seeing only the near boxes (its median is nearer) and a network off by a shift
    net0 = K * (0.3 - q)
    first = fuser(frame, net0, [])
    np.testing.assert_array_equal(first.disparity, net0)
    assert fuser.parallax_scale is None
    out1 = fuser(frame, net0, [parallax_cue(7.0 * q)])
    scale = fuser.parallax_scale
    s = fuser.settings
    # set so that the median trusted pixel is default_distance_m away
    assert scale * 7.0 * np.median(q) == pytest.approx(1.0 / s.default_distance_m, rel=1e-3)
    mask = np.zeros((H, W), bool)
    mask[20:90, 20:140] = True
    out2 = fuser(frame, net0, [parallax_cue(7.0 * q, mask)])
    assert fuser.parallax_scale == scale  # kept
    for y, x in ((50, 45), (60, 120)):  # the same scene points, the same D
        assert out2.disparity[y, x] == pytest.approx(out1.disparity[y, x], abs=0.02 * K * 0.5)
    # frame 2's parallax misses the border: there the depth of frame 1 is carried along the flow
    assert fuser.used == {"frames": 3, "parallax": 2, "people": 0, "network_only": 1, "carried": 1}


def test_the_fit_memory_smooths_the_network_fit():
    q = scene_q()
    frame = scene_frame(q)
    K = lens_constant(W)
    mask = np.zeros((H, W), bool)
    mask[:, :W // 2] = True  # parallax on the left half only: the right half is the fitted network
    fits = {}
    for memory in (0.0, 0.8):
        fuser = DepthFuser(W, FusionSettings(fit_memory=memory))
        fuser(frame, K * (0.3 - q), [parallax_cue(q, mask)])
        fuser(frame, 2.0 * K * (0.3 - q), [parallax_cue(q, mask)])  # the network's scale jumps
        fits[memory] = fuser._fit[0]
        scale = fuser.parallax_scale
    a_now = -scale / (2.0 * K)  # slope of q (1/m) per D of frame 1 alone: q = scale (0.3 - D / 2K)
    assert fits[0.0] == pytest.approx(a_now, rel=0.05)
    assert abs(fits[0.8] - a_now) > 0.5 * abs(a_now)  # remembered: mostly frame 0's slope


@pytest.mark.parametrize("h, w", [(1, 1), (2, 3), (1, 700)])
def test_tiny_and_thin_frames(h, w):
    fuser = DepthFuser(w)
    frame = np.full((h, w, 3), 128, np.uint8)
    q = np.full((h, w), 0.5, np.float32)
    cues = [CueMap("people", q, np.ones((h, w), np.float32), metric=True), parallax_cue(q)]
    for frame_cues in (cues, cues, []):  # the second and third frames carry the first's depth along the flow
        out = fuser(frame, np.zeros((h, w), np.float32), frame_cues)
        assert out.disparity.shape == out.confidence.shape == (h, w)
        assert np.isfinite(out.disparity).all() and np.isfinite(out.confidence).all()


def test_4k_frame_full_size_finite_and_memory_bounded():
    h, w = 2160, 3840
    frame = np.full((h, w, 3), 100, np.uint8)
    frame[600:2100, 1500:2400] = (220, 180, 150)
    people = person_cue((h, w), [(1500, 600, 2400, 2100, 2.0)])
    net_d = np.tile(np.linspace(-5, 5, w, dtype=np.float32), (h, 1))
    fuser = DepthFuser(w)
    tracemalloc.start()
    try:
        out = fuser(frame, net_d, [people])
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert out.disparity.shape == (h, w) and out.disparity.dtype == np.float32
    assert np.isfinite(out.disparity).all()
    plane = h * w * 4  # one full-size float32 map (33 MB)
    assert peak < 12 * plane, f"peak {peak / 1e6:.0f} MB"  # a few full-size planes, not per-layer copies


def test_what_the_network_puts_clearly_in_front_of_a_person_stays_in_front():
    """A person in the background (2 m) behind a desk the network puts far nearer: the ceiling
    around the person must not push the desk behind the person; the backdrop the network puts at
    the person's depth is still pushed behind (front_ratio 0: everything is capped, as before)."""
    boxes = [(60, 10, 100, 50, 2.0)]
    frame = with_people(textured(), boxes)
    net_d = np.zeros((H, W), np.float32)
    K = lens_constant(W)
    net_d[60:, :] = -K * 1.0  # the desk: 1 1/m nearer than the rest by the network (lens slope)
    outs = {}
    for ratio in (1.5, 0.0):
        fuser = DepthFuser(W, FusionSettings(front_ratio=ratio))
        outs[ratio] = q_of(fuser(frame, net_d, [person_cue((H, W), boxes)]).disparity, fuser)
    desk = (slice(70, 96), slice(50, 110))
    backdrop = (slice(10, 50), slice(40, 56))
    q_person = 1 / 2.0
    assert np.median(outs[1.5][desk]) > 2.0 * q_person  # measured 1.5: the network says 1 1/m nearer
    assert np.median(outs[0.0][desk]) < 1.2 * q_person  # measured 0.4: capped at 0.8 x the person
    for ratio in (1.5, 0.0):
        assert np.percentile(outs[ratio][backdrop], 90) <= 0.8 * q_person * 1.03


def test_a_frame_whose_parallax_fails_keeps_the_depth_carried_along_the_flow():
    """Frame 0 has parallax; frames 1.. are the same scene moved 4 px right each, with no cue and a
    flat network: the near box stays near, where it moved to (not the network's flat D), until the
    chain ends carry_frames frames after the parallax; with carry_weight 0 the frame is the network's."""
    q = scene_q()
    frame = scene_frame(q)
    K = lens_constant(W)
    flat = np.zeros((H, W), np.float32)
    outs = {}
    for weight in (1.0, 0.0):
        fuser = DepthFuser(W, FusionSettings(carry_weight=weight, carry_frames=3))
        first = fuser(frame, flat, [parallax_cue(q)])
        outs[weight] = [fuser(np.roll(frame, 4 * k, axis=1), flat, []) for k in (1, 2, 3, 4)]
        if weight == 0.0:
            assert [o.cues for o in outs[weight]] == [["network"]] * 4
            np.testing.assert_array_equal(outs[weight][0].disparity, fuser.K * (fuser.q_ref - (
                fuser._fit[0] * flat + fuser._fit[1])))
            assert fuser.used["carried"] == 0
            continue
        assert [o.cues for o in outs[weight]] == [["carried", "network"]] * 3 + [["network"]]
        assert fuser.used == {"frames": 5, "parallax": 1, "people": 0, "network_only": 1, "carried": 3}
        step = np.median(first.disparity[5:15, 80:95]) - np.median(first.disparity[40:80, 110:130])
        assert step > 0.3 * K  # the near box is in front of the backdrop in frame 0
        for k, out in enumerate(outs[weight][:3], start=1):
            box = out.disparity[40:80, 110 + 4 * k:130 + 4 * k]  # where the box moved to
            back = out.disparity[5:15, 80 + 4 * k:95 + 4 * k]
            assert np.median(back) - np.median(box) > 0.8 * step, k
        assert np.ptp(outs[weight][3].disparity) < 1e-3 * K  # the chain has ended: the flat network


def test_a_still_camera_carries_nothing():
    """People alone (no parallax): no depth is carried; a frame without cues is the network's."""
    boxes = [(60, 20, 100, 96, 1.5)]
    frame = with_people(textured(), boxes)
    fuser = DepthFuser(W)
    net_d = np.zeros((H, W), np.float32)
    fuser(frame, net_d, [person_cue((H, W), boxes)])
    assert fuser._carry is None
    assert fuser(frame, net_d, []).cues == ["network"] and fuser.used["carried"] == 0
