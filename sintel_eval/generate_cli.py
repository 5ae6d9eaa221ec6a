"""The ``generate`` sub-command of ``python -m sintel_eval`` (one ground-truth clip).

    python -m sintel_eval generate --seed K [--frames N] [--size WxH] [--script NAME] [--samples S]
                                   [--dof-samples S] [--train-samples S] [--f-numbers L,M,S] [--train-every N]
                                   [--pull-frames N] [--style auto|procedural|photo]
                                   [--lighting auto|classic|day|dim|night] [--textures DIR]
                                   [--texture-cache DIR] [--tilt MIN,MAX] [--no-denoise] [--no-dof] [--force] [-q] -o DIR
"""
from __future__ import annotations

import argparse
import logging
import sys

from .cli_args import float_range, non_negative_int, positive_int, size_arg

DEFAULT_STYLE = "auto"  # photo when a texture source is found (sintel_eval/DATASET.md "Looks")


def _f_numbers(text: str) -> tuple[float, float, float]:
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{text}' is not a list of f-numbers: write LARGE,MID,SMALL, "
                                         "e.g. 1.0,2.8,8.0") from None
    if len(values) != 3:
        raise argparse.ArgumentTypeError(f"'{text}': give exactly three f-numbers LARGE,MID,SMALL, e.g. 1.0,2.8,8.0")
    return values  # type: ignore[return-value]


def add_parser(sub) -> argparse.ArgumentParser:
    """Register ``generate`` on the sub-parsers of the harness CLI."""
    gen = sub.add_parser("generate", help="generate one ground-truth clip (format: sintel_eval/DATASET.md)",
                         description="Generate a seeded animated scene with Cycles: the deep-DOF input (PNG + "
                                     "MP4 with audio), exact disparity and HDR, Cycles' own shallow DOF for a "
                                     "constant and a rack focus track, training aperture/focal triplets, events "
                                     "and a manifest (sintel_eval/DATASET.md). Re-running the same command "
                                     "resumes an interrupted run.")
    gen.add_argument("-o", "--out", required=True, metavar="DIR", help="clip folder (created if missing)")
    gen.add_argument("--seed", required=True, metavar="K", help="scene seed: a whole number (decimal or 0x-hex)")
    gen.add_argument("--frames", type=positive_int, default=48, metavar="N", help="number of frames (default 48)")
    gen.add_argument("--size", type=size_arg, default=(320, 180), metavar="WxH", help="resolution (default 320x180)")
    gen.add_argument("--script", default="random", metavar="NAME",
                     help="scene script: random, enter, start-moving or conversation (default random)")
    gen.add_argument("--samples", type=positive_int, default=16, metavar="S",
                     help="Cycles samples of the pinhole (input/GT) pass (default 16)")
    gen.add_argument("--dof-samples", type=positive_int, default=24, metavar="S",
                     help="Cycles samples of the depth-of-field passes (default 24)")
    gen.add_argument("--train-samples", type=positive_int, default=16, metavar="S",
                     help="Cycles samples of the mid/small apertures of the training triplets (default 16)")
    gen.add_argument("--f-numbers", type=_f_numbers, default=(1.0, 2.8, 8.0), metavar="L,M,S",
                     help="f-numbers: LARGE aperture of the focus tracks, then MID and SMALL of the aperture "
                          "triplets (default 1.0,2.8,8.0; aperture scale 1 = f/1.0)")
    gen.add_argument("--train-every", type=non_negative_int, default=4, metavar="N",
                     help="training pairs/triplets on frames 1, 1+N, ... (0 = none; default 4)")
    gen.add_argument("--pull-frames", type=positive_int, default=10, metavar="N", help="rack pull length (default 10)")
    gen.add_argument("--style", choices=("auto", "procedural", "photo"), default=DEFAULT_STYLE,
                     help="look of the scene: photo (photo textures cut from real images, people-like figures, "
                          "varied lighting), procedural (the original procedural materials and figures), or auto: "
                          "photo when a texture source is found, else procedural with a warning "
                          f"(default {DEFAULT_STYLE})")
    gen.add_argument("--lighting", choices=("auto", "classic", "day", "dim", "night"), default="auto",
                     help="lighting: day (bright interior), dim, night (dark, bright small emitters), classic (the "
                          "original dusk), or auto: classic for the procedural style, a seeded day/dim/night for "
                          "photo (default auto)")
    gen.add_argument("--textures", metavar="DIR", default=None,
                     help="folder of real images and clips to cut photo textures from (default $RVR_TEXTURES or "
                          "../shared/data beside the repository; scikit-image's sample photos are added when it "
                          "is installed)")
    gen.add_argument("--texture-cache", metavar="DIR", default=None,
                     help="where extracted clip frames and texture crops go (default $RVR_TEXTURE_CACHE or "
                          "~/.cache/rvr-laaf/textures)")
    gen.add_argument("--tilt", type=float_range, default=None, metavar="MIN,MAX",
                     help="range of the seeded camera tilt in degrees, positive = up (default 0.5,2.5: the "
                          "near subject's head in frame); e.g. -14,0 shows the floor receding, as in much real "
                          "footage (the estimator's training data); write --tilt=-14,0 (with =) for a negative MIN")
    gen.add_argument("--no-denoise", action="store_true", help="disable OpenImageDenoise")
    gen.add_argument("--no-dof", action="store_true",
                     help="render only the deep pass (input, GT disparity and HDR, events): no shallow-DOF focus "
                          "tracks and no training triplets (implies --train-every 0); for event clips such as "
                          "AF-Net's training data. `ablate` skips such clips (no DOF ground truth)")
    gen.add_argument("--force", action="store_true",
                     help="regenerate from scratch (removes only the harness' own files in DIR)")
    gen.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    return gen


def main(args: argparse.Namespace) -> int:
    """Run ``generate``; returns the exit code (1 with a clear message on bad input)."""
    try:
        import bpy  # noqa: F401  (the harness renders with Blender as a Python module)
    except ImportError:
        print("error: bpy is not installed: run ./scripts/setup.sh (it installs bpy==5.0.1 into .venv)",
              file=sys.stderr)
        return 2
    from rvr_addon.errors import RvrError

    from .dataset import GenerateConfig, generate

    logging.basicConfig(level=logging.WARNING, format="warning: %(message)s")  # the style fallbacks warn
    try:
        cfg = GenerateConfig(seed=args.seed, frames=args.frames, width=args.size[0], height=args.size[1],
                             script=args.script, samples=args.samples, dof_samples=args.dof_samples,
                             train_samples=args.train_samples,
                             f_numbers=args.f_numbers, train_every=args.train_every, pull_frames=args.pull_frames,
                             denoise=not args.no_denoise, style=args.style, lighting=args.lighting,
                             textures=args.textures, texture_cache=args.texture_cache,
                             dof=not args.no_dof, **({"tilt_deg": args.tilt} if args.tilt else {})).validated()
        result = generate(args.out, cfg, force=args.force, progress=not args.quiet)
    except RvrError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("cancelled: re-run the same command to resume (complete frames are kept)", file=sys.stderr)
        return 130
    t = result.timings
    print(f"wrote {result.out}: {len(result.rendered)} frame(s) rendered, {len(result.kept)} kept from an earlier "
          f"run; {t['total_s']:.1f} s (deep {t['deep_s']:.1f} s / {t['deep_renders']} renders, "
          f"dof {t['dof_s']:.1f} s / {t['dof_renders']} renders, encode {t['encode_s']:.1f} s); look: "
          f"{result.look.get('style')} style, {result.look.get('lighting')} lighting, "
          f"{result.look.get('textures', 0)} photo texture(s)")
    return 0
