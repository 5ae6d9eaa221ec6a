"""Harness speed: generate a 48-frame 320x180 ground-truth clip with all its passes.

    .venv/bin/python bench/harness_bench.py [--script enter] [--seed 7] [--keep DIR] [--quick]
                                            [--convergence] [--style procedural|photo]
                                            [--lighting auto|classic|day|dim|night]

Runs ``sintel_eval.dataset.generate`` (what ``python -m sintel_eval generate`` runs) into a
fresh folder and prints, as the LAST stdout line, one JSON object (DESIGN.md "Benchmarks"):

    harness.clip48_320x180_s                     the whole clip, build to videos
    harness.clip48_320x180.{build,deep,dof,encode}_s   per stage
    harness.clip48_320x180.{deep,dof}_s_per_render     one Cycles render of each kind
    harness.clip48_320x180.s_per_frame

``--convergence`` adds the Monte-Carlo quality of the chosen settings on one frame:
``harness.dof{N}spp_psnr_vs_1024spp_db`` and ``harness.deep{N}spp_psnr_vs_1024spp_db`` (sRGB PSNR
of the denoised render against an un-denoised 1024-sample one). ``--quick`` runs 8 frames at
160x90 (a smoke test; its keys say so). ``--style photo`` times the photo style (textures from
$RVR_TEXTURES or ../shared/data): its keys read ``harness.photo.clip48_320x180...``.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def _convergence(script: str, seed: int, samples: int, dof_samples: int, width: int, height: int) -> dict:
    import numpy as np

    from rvr_addon.color import linear_to_srgb
    from sintel_eval.bpy_util import bpy, reset_blender
    from sintel_eval.camera_math import Lens
    from sintel_eval.passes import LensSetting, PassRenderer, configure_cycles
    from sintel_eval.scene_builder import apply_frame, build_scene, subject_frame
    from sintel_eval.scene_plan import FOCAL_MM, SENSOR_WIDTH_MM
    from sintel_eval.scripts_events import make_plan

    reset_blender()
    scene = bpy.context.scene
    configure_cycles(scene, width, height, seed, True, 24)
    plan = make_plan(seed, script, 48, 24)
    built = build_scene(plan, width, height)
    apply_frame(built, plan, 24)
    s_f = subject_frame(built, plan.main, Lens(FOCAL_MM, SENSOR_WIDTH_MM, width, 1.0, 3.0), width, height).depth_m
    r = PassRenderer(scene, built.camera, samples, dof_samples, built.radiance_cap)

    def psnr(a, b) -> float:
        return float(10 * np.log10(1.0 / np.mean((linear_to_srgb(a) - linear_to_srgb(b)) ** 2)))

    try:
        lens = LensSetting(s_f, 1.0)
        dof, deep = r.render_dof(lens), r.render_deep()["rgb"]
        scene.cycles.use_denoising = False
        ref_dof = r.render_dof(lens, 1024)
        r.samples_deep = 1024
        ref_deep = r.render_deep()["rgb"]
    finally:
        r.close()
    return {f"harness.dof{dof_samples}spp_psnr_vs_1024spp_db": psnr(dof, ref_dof),
            f"harness.deep{samples}spp_psnr_vs_1024spp_db": psnr(deep, ref_deep)}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--script", default="enter", help="scene script (default enter)")
    parser.add_argument("--seed", type=int, default=7)
    parser.add_argument("--keep", metavar="DIR", help="write the clip here instead of a temporary folder")
    parser.add_argument("--quick", action="store_true", help="8 frames at 160x90 (smoke test)")
    parser.add_argument("--convergence", action="store_true", help="also measure Monte-Carlo convergence")
    parser.add_argument("--style", choices=("procedural", "photo"), default="procedural",
                        help="scene look (default procedural: the DESIGN.md key)")
    parser.add_argument("--lighting", default="auto", help="lighting of the photo style (default auto)")
    args = parser.parse_args()

    from sintel_eval.dataset import GenerateConfig, generate

    frames, (w, h) = (8, (160, 90)) if args.quick else (48, (320, 180))
    cfg = GenerateConfig(seed=args.seed, frames=frames, width=w, height=h, script=args.script, style=args.style,
                         lighting=args.lighting).validated()
    key = f"harness.clip{frames}_{w}x{h}"
    if args.style != "procedural":
        key = f"harness.{args.style}.clip{frames}_{w}x{h}"
    load = os.getloadavg()[0]
    print(f"{key}: script {cfg.script}, seed {cfg.seed}, samples deep {cfg.samples} / dof {cfg.dof_samples} / "
          f"train {cfg.train_samples}, train every {cfg.train_every}, style {cfg.style}, lighting {cfg.lighting}; "
          f"load average at start {load:.2f} "
          f"on {os.cpu_count()} CPUs", file=sys.stderr)
    with tempfile.TemporaryDirectory(prefix="rvr_harness_bench_") as tmp:
        out = Path(args.keep) if args.keep else Path(tmp) / "clip"
        t0 = time.perf_counter()
        result = generate(out, cfg, force=True, progress=True)
        total = time.perf_counter() - t0
    t = result.timings
    figures = {
        f"{key}_s": total,
        f"{key}.build_s": t["build_s"],
        f"{key}.deep_s": t["deep_s"],
        f"{key}.dof_s": t["dof_s"],
        f"{key}.encode_s": t["encode_s"],
        f"{key}.deep_s_per_render": t["deep_s"] / max(t["deep_renders"], 1),
        f"{key}.dof_s_per_render": t["dof_s"] / max(t["dof_renders"], 1),
        f"{key}.s_per_frame": total / frames,
    }
    print(f"look {result.look}; {t['deep_renders']} pinhole + {t['dof_renders']} DOF renders; load average at end "
          f"{os.getloadavg()[0]:.2f}", file=sys.stderr)
    if args.convergence:
        figures.update(_convergence(cfg.script, cfg.seed, cfg.samples, cfg.dof_samples, w, h))
    print(json.dumps(figures))
    return 0


if __name__ == "__main__":
    sys.exit(main())
