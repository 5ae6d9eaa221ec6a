"""LAAF: NFT validation, the puller's timing and profiles, keyframes, the focus file round trip."""
from __future__ import annotations

import json
import logging

import numpy as np
import pytest

from rvr_addon.errors import InputError
from rvr_addon.io.track import load_track, resolve_track
from rvr_addon.laaf.keyframes import evaluate_keys, keyframes
from rvr_addon.laaf.nft import NFT, load_nfts, validate_nfts
from rvr_addon.laaf.puller import PROFILES, PullSettings, PullTarget, compose_track, pull_weight, schedule_pulls
from rvr_addon.laaf.timebase import frames_at


def nft(t, x=50.0, y=40.0, box=(40.0, 30.0, 20.0, 20.0), **kw):
    return NFT(x=x, y=y, t=t, box=box, **kw)


# ------------------------------------------------------------------------------------------ NFTs

def test_nfts_out_of_order_are_sorted_with_a_warning(caplog):
    with caplog.at_level(logging.WARNING):
        out = validate_nfts([nft(30), nft(5)], 40, 100, 80)
    assert [n.t for n in out] == [5, 30]
    assert "out of order" in caplog.text


@pytest.mark.parametrize("bad, message", [
    pytest.param(nft(40), "outside the clip", id="after-the-end"),
    pytest.param(nft(-1), "outside the clip", id="negative"),
    pytest.param(nft(3, box=(200.0, 200.0, 10.0, 10.0)), "entirely outside", id="box-outside"),
    pytest.param(nft(3, box=(10.0, 10.0, 0.0, 5.0)), "no area", id="empty-box"),
])
def test_bad_nfts_name_the_target_and_the_fix(bad, message):
    with pytest.raises(InputError, match=message):
        validate_nfts([bad], 40, 100, 80, where="NFTs of 'x.json'")


def test_two_nfts_on_one_frame_is_an_error():
    with pytest.raises(InputError, match="second NFT on frame 3"):
        validate_nfts([nft(3), nft(3)], 40, 100, 80)


def test_box_reaching_outside_is_clipped_and_point_moved_inside(caplog):
    with caplog.at_level(logging.WARNING):
        (out,) = validate_nfts([nft(3, x=-5.0, y=-5.0, box=(-10.0, -10.0, 30.0, 30.0))], 40, 100, 80)
    assert out.box == (0.0, 0.0, 20.0, 20.0)
    assert (out.x, out.y) == (10.0, 10.0)
    assert "clipped" in caplog.text


def test_load_nfts_json_forms_and_errors(tmp_path):
    good = tmp_path / "n.json"
    good.write_text(json.dumps({"nfts": [{"frame": 4, "x": 10, "y": 12}, {"t": 9, "box": [0, 0, 8, 8]}]}))
    a, b = load_nfts(good, 64, 48)
    assert a.t == 4 and a.box[2] > 0 and a.source == "manual"
    assert (b.x, b.y) == (4.0, 4.0)
    bad = tmp_path / "bad.json"
    bad.write_text('[{"t": 1}]')
    with pytest.raises(InputError, match=r"bad.json.*NFT #0.*'x' and 'y'"):
        load_nfts(bad)
    with pytest.raises(InputError, match="not found"):
        load_nfts(tmp_path / "missing.json")


# ------------------------------------------------------------------------------------------ puller

@pytest.mark.parametrize("profile", PROFILES)
def test_profiles_start_at_0_end_at_1_and_rise(profile):
    u = np.linspace(0, 1, 101)
    w = pull_weight(u, profile)
    assert w[0] == pytest.approx(0.0, abs=1e-12) and w[-1] == pytest.approx(1.0, abs=1e-12)
    assert np.all(np.diff(w) >= -1e-12)


@pytest.mark.parametrize("lead, pull", [(5, 10), (0, 10), (8, 4)])
@pytest.mark.parametrize("profile", PROFILES)
def test_pull_ends_exactly_lead_frames_before_the_nft(lead, pull, profile):
    n, t_nft = 60, 40
    a, b = np.full(n, 1.0), np.full(n, 4.0)
    s = PullSettings(pull_frames=pull, lead_frames=lead, profile=profile)
    track = compose_track([PullTarget(0, a), PullTarget(t_nft, b)], n, s)
    end, start = t_nft - lead, t_nft - lead - pull
    assert track.focus[end] == pytest.approx(4.0)  # arrived
    assert track.focus[end - 1] < 4.0 - 1e-6  # not before
    assert track.focus[start] == pytest.approx(1.0) and track.focus[start + 1] > 1.0 + 1e-6  # starts there
    assert np.all(track.focus[end:] == pytest.approx(4.0))
    assert track.pulls[0].start == start and track.pulls[0].end == end


@pytest.mark.parametrize("fps, pull, lead, hold", [(24, 10, 5, 12), (25, 10, 5, 12), (30, 12, 6, 14),
                                                   (50, 20, 10, 24), (60, 24, 12, 29), (None, 10, 5, 12)])
def test_the_default_pull_is_the_same_seconds_at_any_frame_rate(fps, pull, lead, hold):
    s = PullSettings().at_fps(fps)  # 0.4 s, 0.2 s, 0.48 s: DESIGN's 10, 5, 12 frames at 25 fps
    assert (s.pull_frames, s.lead_frames, s.hold_frames, s.min_pull_frames) == (pull, lead, hold, 2)
    n, t_nft = 120, 80
    track = compose_track([PullTarget(0, np.full(n, 1.0)), PullTarget(t_nft, np.full(n, 4.0))], n, fps=fps)
    assert (track.pulls[0].start, track.pulls[0].end) == (t_nft - lead - pull, t_nft - lead)


def test_pull_frames_a_user_gives_stay_frames_at_any_frame_rate():
    s = PullSettings(pull_frames=7, lead_frames=0, hold_frames=3).at_fps(60)
    assert (s.pull_frames, s.lead_frames, s.hold_frames, s.min_pull_frames) == (7, 0, 3, 2)
    assert PullSettings(pull_frames=1).at_fps(60).min_pull_frames == 1
    assert frames_at(10, 24) == frames_at(10, 25) == 10 and frames_at(10, 60) == 24 and frames_at(0.2, 25) == 1
    assert frames_at(2, 12, 0) == 1 and frames_at(3, float("nan")) == 3
    with pytest.raises(ValueError, match="pull_frames=0"):
        PullSettings(pull_frames=0).check()


def test_late_knowledge_starts_the_pull_late_with_full_length():
    n = 60
    s = PullSettings(pull_frames=10, lead_frames=5)
    (p,) = schedule_pulls([PullTarget(0, np.zeros(n)), PullTarget(30, np.ones(n), known_at=33)], s)
    assert (p.start, p.end) == (33, 43) and "late" in p.note


def test_crowded_targets_compress_the_second_pull():
    n = 60
    s = PullSettings(pull_frames=10, lead_frames=5)
    p1, p2 = schedule_pulls([PullTarget(0, np.zeros(n)), PullTarget(20, np.ones(n)), PullTarget(24, np.ones(n) * 2)], s)
    assert p1.end == 15 and p2.start == 15 and p2.end == 19 and "crowded" in p2.note


def test_lost_target_is_held_then_released_to_the_next():
    n = 80
    s = PullSettings(pull_frames=10, lead_frames=5, hold_frames=6)
    level0 = np.full(n, 1.0)
    level0[20:] = np.nan  # subject left at frame 20: its focus is held
    track = compose_track([PullTarget(0, level0, lost_from=20), PullTarget(60, np.full(n, 3.0))], n, s)
    assert np.all(track.focus[20:26] == pytest.approx(1.0))  # held for hold_frames
    assert track.pulls[0].start == 26 and track.focus[36] == pytest.approx(3.0)  # released early


def test_aperture_is_pulled_with_the_focus():
    n = 40
    track = compose_track([PullTarget(0, np.zeros(n)), PullTarget(30, np.ones(n), aperture=0.5)], n,
                          PullSettings(), aperture=1.0)
    assert track.aperture[0] == 1.0 and track.aperture[25] == pytest.approx(0.5) and 0.5 < track.aperture[20] < 1.0


# ------------------------------------------------------------------------------------------ keyframes

def _tracks():
    rng = np.random.default_rng(4)
    n = 200
    walk = np.cumsum(rng.normal(0, 0.03, n))
    comp = compose_track([PullTarget(0, walk), PullTarget(90, 3 + walk), PullTarget(150, -1 + 0.5 * walk)], n,
                         PullSettings(profile="ease_in_out_sine"))
    return [np.sin(np.linspace(0, 6, n)) * 2, walk, comp.focus, np.zeros(1), np.full(5, 2.0)]


@pytest.mark.parametrize("i", range(5))
def test_keyframes_reproduce_the_track_within_tolerance(i):
    focus = _tracks()[i]
    aperture = np.linspace(1.0, 0.6, len(focus))
    keys = keyframes(focus, aperture, tol=0.05)
    f, a = evaluate_keys(keys, len(focus))
    assert np.max(np.abs(f - focus)) <= 0.05 and np.max(np.abs(a - aperture)) <= 0.005
    assert keys[0].frame == 0 and keys[-1].frame == len(focus) - 1
    assert len(keys) <= max(2, len(focus) // 2) or len(focus) < 4


def test_flat_track_needs_two_keys():
    keys = keyframes(np.full(100, 1.5))
    assert [k.frame for k in keys] == [0, 99]


# ------------------------------------------------------------------------------------------ focus file

def test_focus_file_is_read_by_rvr_render_exactly_and_by_keys(tmp_path):
    focus = _tracks()[2].astype(np.float32)
    aperture = np.ones_like(focus)
    keys = keyframes(focus, aperture)
    doc = {"format": "rvr-laaf-focus/1", "interpolation": "LINEAR",
           "keys": [{"frame": k.frame, "focus": k.focus, "aperture": k.aperture} for k in keys],
           "per_frame": {"start": 0, "focus": focus.tolist(), "aperture": aperture.tolist()}}
    path = tmp_path / "focus.json"
    path.write_text(json.dumps(doc))
    f, a = resolve_track(load_track(path), len(focus))
    np.testing.assert_allclose(f, focus, atol=1e-6)
    del doc["per_frame"]
    path.write_text(json.dumps(doc))
    f, _ = resolve_track(load_track(path), len(focus))
    assert np.max(np.abs(f - focus)) <= 0.05
    doc["interpolation"] = "BEZIER"
    path.write_text(json.dumps(doc))
    with pytest.raises(InputError, match="interpolation"):
        load_track(path)
