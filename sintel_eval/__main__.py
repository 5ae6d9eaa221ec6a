"""Command line of the ground-truth harness.

    python -m sintel_eval demo -o DIR [--frames N] [--size WxH] [--samples S] [--seed K]
    python -m sintel_eval generate --seed K -o DIR [--frames N] [--size WxH] [--script NAME] [--force]
    python -m sintel_eval ablate DATASET -o REPORT [--variants A,B] [--force] [--max-frames N]
"""
from __future__ import annotations

import argparse
import sys
import time

from .cli_args import positive_int, size_arg


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m sintel_eval",
                                     description="RVR-LAAF ground-truth harness (Cycles scenes via bpy).")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    demo = sub.add_parser("demo", help="render the procedural shallow-DOF demo scene with ground truth",
                          description="Render the procedural demo scene: 8-bit sRGB frames, linear HDR "
                                      "EXRs, disparity (DESIGN units) and meta.json.")
    demo.add_argument("-o", "--out", required=True, metavar="DIR", help="output folder (created if missing)")
    demo.add_argument("--frames", type=positive_int, default=24, metavar="N", help="number of frames (default 24)")
    demo.add_argument("--size", type=size_arg, default=(384, 216), metavar="WxH", help="resolution (default 384x216)")
    demo.add_argument("--samples", type=positive_int, default=16, metavar="S", help="Cycles samples (default 16)")
    demo.add_argument("--seed", type=int, default=0, metavar="K", help="scene seed (default 0)")
    demo.add_argument("--no-denoise", action="store_true", help="disable OpenImageDenoise")
    demo.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    from .ablate import add_parser as add_ablate_parser  # `ablate` (sintel_eval/ablate.py)

    add_ablate_parser(sub)
    from .generate_cli import add_parser as add_generate_parser  # `generate` (sintel_eval/generate_cli.py)

    add_generate_parser(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.command == "ablate":  # bpy is needed only by its Blender Defocus variant
        from .ablate import main as ablate_main

        return ablate_main(args)
    if args.command == "generate":
        from .generate_cli import main as generate_main

        return generate_main(args)
    try:
        import bpy  # noqa: F401  (the harness renders with Blender as a Python module)
    except ImportError:
        print("error: bpy is not installed: run ./scripts/setup.sh (it installs bpy==5.0.1 into .venv)",
              file=sys.stderr)
        return 2

    from rvr_addon.errors import RvrError

    from .demo_scene import render_demo_scene

    if args.command == "demo":
        t0 = time.perf_counter()
        try:
            out = render_demo_scene(args.out, frames=args.frames, size=args.size, samples=args.samples,
                                    seed=args.seed, progress=not args.quiet, denoise=not args.no_denoise)
        except RvrError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 1
        except KeyboardInterrupt:
            print("cancelled", file=sys.stderr)
            return 130
        print(f"wrote {args.frames} frames to {out} in {time.perf_counter() - t0:.1f} s")
        return 0
    return 2  # pragma: no cover - argparse enforces the sub-command


if __name__ == "__main__":
    sys.exit(main())
