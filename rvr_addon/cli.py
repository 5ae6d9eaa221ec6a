"""The ``rvr`` command line: ``rvr render INPUT --depth DEPTH ... -o OUT`` and ``rvr render --demo``."""
from __future__ import annotations

import argparse
import logging
import subprocess
import sys
from pathlib import Path

from . import __version__
from .errors import RvrError

log = logging.getLogger("rvr")

DEMO_DIR = Path("out/demo_scene")
DEMO_OUT = Path("out/demo_refocus.mp4")
DEMO_FRAMES = 48


def _aperture_spec(args: argparse.Namespace):
    from .render.aperture import ApertureSpec, load_kernel_image

    image = load_kernel_image(args.kernel_image) if args.shape == "image" else None
    if args.kernel_image and args.shape != "image":
        raise RvrError("--kernel-image needs --shape image")
    return ApertureSpec(shape=args.shape, blades=args.blades, rotation_deg=args.rotation,
                        squeeze=args.squeeze, kernel_image=image, cat_eye=args.cat_eye)


def add_render_parser(sub) -> None:
    p = sub.add_parser("render", help="render shallow depth of field for a clip",
                       description="Render a shallow-DOF video from frames + a disparity sequence "
                                   "(+ an HDR exponent sequence) and a focus track or constants.")
    p.add_argument("input", nargs="?", type=Path, help="video file, image folder, glob or frame pattern")
    p.add_argument("--demo", action="store_true",
                   help="render the built-in demo: a Cycles scene with exact depth and HDR (rendered once "
                        f"into {DEMO_DIR}), rack focus from the subject to the background and back")
    p.add_argument("--depth", type=Path, help="disparity sequence (EXR/PNG/NPY file, folder or pattern)")
    p.add_argument("--depth-scale", type=float, default=1.0, help="multiply depth values (to DESIGN units)")
    p.add_argument("--depth-offset", type=float, default=0.0, help="then add this")
    p.add_argument("--hdr", type=Path, help="HDR exponent E sequence (log space; radiance = I*exp(50E))")
    p.add_argument("--focus", type=float, help="constant focus disparity (default: median of the frame centre)")
    p.add_argument("--aperture", type=float, default=1.0, help="constant aperture scale (0 = no blur)")
    p.add_argument("--track", type=Path, help="focus track CSV/JSON: frame, focus, aperture (overrides constants)")
    p.add_argument("--shape", choices=("disk", "polygon", "anamorphic", "image"), default="disk")
    p.add_argument("--blades", type=int, default=6, help="polygon blades")
    p.add_argument("--rotation", type=float, default=0.0, help="polygon rotation in degrees")
    p.add_argument("--squeeze", type=float, default=2.0, help="anamorphic squeeze (bokeh height / width)")
    p.add_argument("--kernel-image", type=Path, help="aperture image for --shape image")
    p.add_argument("--cat-eye", type=float, default=0.0,
                   help="optical vignetting 0..1: bokeh turns into cat's eyes toward the frame edges")
    p.add_argument("--naive", action="store_true", help="sum layers without occlusion (ablation)")
    p.add_argument("--start", type=int, default=0, help="first frame (0-based)")
    p.add_argument("--stop", type=int, help="stop before this frame")
    p.add_argument("--fps", type=float, help="frame rate of an image-sequence input (default 24)")
    p.add_argument("--no-audio", action="store_true", help="do not copy the source audio")
    p.add_argument("--min-layers", type=int, default=1, help="use at least this many depth layers")
    p.add_argument("--scale", type=float, default=1.0, help="render at this fraction of the size (0.5 = half-size proxy)")
    p.add_argument("-o", "--output", action="append", type=Path, default=None,
                   help="output .mp4 or image folder (repeatable; a folder/frame_%%05d.exr pattern "
                        "writes linear EXR)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_render)


def ensure_demo_scene(directory: Path = DEMO_DIR) -> Path:
    """Render the demo scene with Cycles (in a child process) unless it is already there."""
    import json

    meta = directory / "meta.json"
    if meta.is_file() and json.loads(meta.read_text()).get("frames") == DEMO_FRAMES:
        return directory
    print(f"rendering the demo scene with Cycles into {directory} (once; about two minutes)", file=sys.stderr)
    cmd = [sys.executable, "-m", "sintel_eval", "demo", "-o", str(directory), "--frames", str(DEMO_FRAMES)]
    if subprocess.call(cmd) != 0:
        raise RvrError(f"rendering the demo scene failed ({' '.join(cmd)}); is bpy installed? run scripts/setup.sh")
    return directory


def demo_settings(args: argparse.Namespace):
    """Settings for the demo: ground-truth depth and HDR, rack focus subject -> background."""
    import json

    from .pipeline import RenderSettings, prepare_demo_inputs

    d = ensure_demo_scene()
    meta = json.loads((d / "meta.json").read_text())
    prepare_demo_inputs(d)
    outputs = args.output or [DEMO_OUT]
    return RenderSettings(input=d / "frames", depth=d / "disparity", hdr=d / "hdr_exponent",
                          track=d / "focus_track.json", outputs=outputs, spec=_aperture_spec(args),
                          naive=args.naive, fps=float(meta.get("fps", 24)), min_layers=args.min_layers,
                          scale=args.scale)


def cmd_render(args: argparse.Namespace) -> int:
    from .pipeline import RenderJob, RenderSettings

    if args.demo:
        settings = demo_settings(args)
    else:
        if args.input is None or args.depth is None:
            raise RvrError("rvr render needs INPUT and --depth DEPTH (or --demo); see rvr render --help")
        if not args.output:
            raise RvrError("no output: add -o OUT.mp4 (and/or -o FRAMES_DIR)")
        settings = RenderSettings(
            input=args.input, depth=args.depth, hdr=args.hdr, outputs=args.output, focus=args.focus,
            aperture=args.aperture, track=args.track, spec=_aperture_spec(args),
            depth_scale=args.depth_scale, depth_offset=args.depth_offset, naive=args.naive,
            start=args.start, stop=args.stop, fps=args.fps, keep_audio=not args.no_audio,
            min_layers=args.min_layers, scale=args.scale)
    job = RenderJob(settings)
    job.run(progress=not args.quiet)
    for out in settings.outputs:
        print(f"wrote {out}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="rvr", description="RVR-LAAF: refocusable video rendering.")
    parser.add_argument("--version", action="version", version=f"rvr {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    add_render_parser(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``rvr`` console script; returns the exit status."""
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except RvrError as ex:
        print(f"rvr: error: {ex}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("rvr: cancelled; partial outputs removed", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
