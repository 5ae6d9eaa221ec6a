"""The editor's tool end to end, headless, through the Sequencer operators (bpy module).

    .venv/bin/python bench/vse_bench.py [--seconds 10] [--clip PATH] [--weights W] [--preset action]

Input: the first ``--seconds`` (default 10) of ``../shared/data/clips/visualvoice_interview.mp4``
(25 fps, two faces, speech) resized to 640x360 with its audio (ffmpeg); without ../shared/data a
synthetic testsrc2 clip with a tone. The extension is registered from this repository (as the
tests do), a .blend is saved in a temporary folder, and:

* ``vse.analyze_s``: import the clip as a movie strip and run **Analyze** (estimator on every
  frame + temporal stabilization into the cache). With no trained weights (``--weights`` or
  the shipped file) an untrained network of the same architecture is timed instead
  (``vse.analyze.untrained_weights`` = 1: the same cost, a meaningless disparity).
* ``vse.import_to_render_s``: after analysis, in a fresh file: import the clip, **Analyze**
  again (the cache is reused: ``vse.analyze_reuse_s``), **Auto Focus** (``--preset``,
  2 s look-ahead: ``vse.autofocus_s``), **Render** to H.264 with sound (``vse.render_s``).

The last stdout line is DESIGN.md's flat JSON. The issue's bar: import_to_render under 120 s.
"""
from __future__ import annotations

import argparse
import importlib
import json
import sys
import tempfile
import time
from pathlib import Path

from laaf_bench import make_clip  # bench/ is sys.path[0] when run as a script

ROOT = Path(__file__).resolve().parents[1]
CLIP = ROOT.parent / "shared" / "data" / "clips" / "visualvoice_interview.mp4"


def load_addon(tmp: Path):
    """This repository imported as the package ``rvr_laaf`` (as Blender imports the extension)."""
    link = tmp / "addon_path" / "rvr_laaf"
    link.parent.mkdir()
    link.symlink_to(ROOT, target_is_directory=True)
    sys.path.insert(0, str(link.parent))
    return importlib.import_module("rvr_laaf")


def fresh_file(bpy, blend: Path, clip: Path):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    scene = bpy.context.scene
    scene.render.fps = 25
    editor = scene.sequence_editor_create()
    strip = editor.strips.new_movie("Clip", str(clip), channel=2, frame_start=1)
    editor.active_strip = strip
    scene.frame_end = strip.frame_final_end - 1
    return strip


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--clip", type=Path, default=CLIP)
    ap.add_argument("--weights", type=Path, help="estimator weights (default: the shipped file, else untrained)")
    ap.add_argument("--preset", default="action", choices=("action", "conversation", "faces", "salient"))
    args = ap.parse_args()

    import bpy

    out: dict[str, float] = {}
    with tempfile.TemporaryDirectory() as tmp_text:
        tmp = Path(tmp_text)
        addon = load_addon(tmp)
        addon.register()
        prefs = addon.operators.prefs
        infer = importlib.import_module("rvr_laaf.rvr_addon.estimate.infer")
        weights = args.weights or (infer.SHIPPED_WEIGHTS if infer.SHIPPED_WEIGHTS.is_file() else None)
        out["vse.analyze.untrained_weights"] = float(weights is None)
        if weights is None:
            import torch

            train = importlib.import_module("rvr_laaf.rvr_addon.estimate.train")
            unet = importlib.import_module("rvr_laaf.rvr_addon.estimate.unet")
            torch.manual_seed(0)
            weights = train.export_weights(unet.EstimatorNet(), tmp / "untrained.pt", iterations=0, wall_time_s=0.0,
                                           training={"note": "bench timing only"})
            print("no trained weights: timing an untrained network of the same architecture", file=sys.stderr)
        clip = make_clip(args.clip, tmp / "clip360.mp4", seconds=args.seconds)
        cache_dir = tmp / "cache"
        with prefs.override(weights_path=str(weights), cache_dir=str(cache_dir)):
            strip = fresh_file(bpy, tmp / "analyze.blend", clip)
            frames = strip.frame_final_duration
            t0 = time.perf_counter()
            assert bpy.ops.rvr.analyze("EXEC_DEFAULT") == {"FINISHED"}
            out["vse.analyze_s"] = time.perf_counter() - t0
            print(f"analyze: {frames} frames in {out['vse.analyze_s']:.1f} s", file=sys.stderr)

            t_import = time.perf_counter()
            strip = fresh_file(bpy, tmp / "edit.blend", clip)
            t0 = time.perf_counter()
            assert bpy.ops.rvr.analyze("EXEC_DEFAULT") == {"FINISHED"}
            out["vse.analyze_reuse_s"] = time.perf_counter() - t0
            t0 = time.perf_counter()
            assert bpy.ops.rvr.auto_focus("EXEC_DEFAULT", preset=args.preset, lookahead_s=2.0) == {"FINISHED"}
            out["vse.autofocus_s"] = time.perf_counter() - t0
            t0 = time.perf_counter()
            strip.rvr.output_dir = str(tmp / "renders")
            assert bpy.ops.rvr.render_strip("EXEC_DEFAULT") == {"FINISHED"}
            out["vse.render_s"] = time.perf_counter() - t0
            out["vse.import_to_render_s"] = time.perf_counter() - t_import
        out["vse.frames"] = float(frames)
        addon.unregister()
    for key, value in out.items():
        print(f"{key:32s} {value:10.2f}", file=sys.stderr)
    print(json.dumps({k: round(v, 3) for k, v in out.items()}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
