"""The default preset ``auto`` (issue 23): it reads the clip (speech, faces, motion), picks a
preset, logs why and writes the choice into the focus file; it is the one default of every
command."""
from __future__ import annotations

import json
import logging
from pathlib import Path

import pytest

from laaf_synth import entering_square, write_clip
from rvr_addon.cli import main as rvr_main
from rvr_addon.laaf import presets
from rvr_addon.laaf.auto import ClipReading, choose_preset
from rvr_addon.laaf.lookahead import AutofocusJob, AutofocusSettings

CLIPS = Path(__file__).resolve().parents[3] / "shared" / "data" / "clips"


def _reading(**kw) -> ClipReading:
    base = dict(has_audio=False, voiced_share=0.0, voiced_s=0.0, face_share=0.0, max_faces=0, face_area=0.0,
                motion_share=0.0, probed=[0])
    return ClipReading(**{**base, **kw})


def test_rules():
    talk = dict(has_audio=True, voiced_share=0.8, voiced_s=5.0)
    assert choose_preset(_reading(**talk, face_share=1.0, face_area=0.05))[0] == "conversation"
    assert choose_preset(_reading(face_share=1.0, face_area=0.1))[0] == "faces"
    # an off-screen voice over a faceless scene is not followed
    assert choose_preset(_reading(**talk, motion_share=0.1))[0] == "action"
    assert choose_preset(_reading(face_share=0.5, face_area=0.005, motion_share=0.1))[0] == "action"
    assert choose_preset(_reading())[0] == "salient"
    assert "speech" in choose_preset(_reading(**talk, face_share=1.0))[1]


def test_one_default_everywhere():
    assert presets.DEFAULT_PRESET == presets.AUTO == "auto" and "auto" in presets.PRESETS
    assert AutofocusSettings(input=Path("x")).preset == presets.DEFAULT_PRESET
    import argparse

    from rvr_addon.batch.commands import add_parser

    p = argparse.ArgumentParser()
    sub = p.add_subparsers()
    add_parser(sub)
    args = p.parse_args(["batch", "in.mp4", "-o", "out"])
    assert args.preset == presets.DEFAULT_PRESET


def test_auto_on_a_moving_square_picks_action_and_says_so(tmp_path, caplog):
    frames, maps, _ = entering_square(n=40, enter=10)
    fdir, ddir = write_clip(tmp_path, frames, maps)
    out = tmp_path / "focus.json"
    with caplog.at_level(logging.INFO, logger="rvr_addon.laaf.auto"):
        assert rvr_main(["autofocus", str(fdir), "--depth", str(ddir), "--fps", "24", "-o", str(out), "-q"]) == 0
    doc = json.loads(out.read_text())
    assert doc["settings"]["preset"] == "auto"
    auto = doc["settings"]["auto"]
    assert auto["chose"] == doc["settings"]["preset_used"] == "action"
    assert auto["reading"]["motion"] and not auto["reading"]["speech"] and auto["why"]
    assert any("chose action" in r.getMessage() for r in caplog.records)


@pytest.mark.skipif(not (CLIPS / "lipnet_grid_lwbsza.mpg").is_file(), reason="needs ../shared/data/clips")
def test_auto_on_a_real_talking_head_picks_conversation(tmp_path):
    import numpy as np

    d = tmp_path / "d.npy"
    np.save(d, np.full((288, 360), 1.0, np.float32))
    r = AutofocusJob(AutofocusSettings(input=CLIPS / "lipnet_grid_lwbsza.mpg", depth=d)).run(progress=False)
    assert r.settings["preset"] == "auto" and r.settings["preset_used"] == "conversation"
    assert r.settings["auto"]["reading"]["speech"] and r.settings["auto"]["reading"]["faces"]


def test_auto_reads_the_same_motion_at_twice_the_frame_rate(tmp_path):
    """The probe measures motion between frames 1/25 s apart: the same square at the same px a
    second, recorded at 24 or 48 fps, reads alike (frame to frame at 48 fps it moves half as far)."""
    readings = {}
    for fps, speed, n in ((24, 3.0, 40), (48, 1.5, 80)):
        frames, maps, _ = entering_square(n=n, enter=n // 4, speed=speed)
        fdir, ddir = write_clip(tmp_path / str(fps), frames, maps)
        out = tmp_path / f"focus{fps}.json"
        assert rvr_main(["autofocus", str(fdir), "--depth", str(ddir), "--fps", str(fps), "-o", str(out), "-q"]) == 0
        readings[fps] = json.loads(out.read_text())["settings"]["auto"]
    assert readings[24]["chose"] == readings[48]["chose"] == "action"
    m24, m48 = (readings[f]["reading"]["motion_share"] for f in (24, 48))
    assert m48 == pytest.approx(m24, rel=0.25), (m24, m48)
