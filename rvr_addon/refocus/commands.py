"""``rvr refocus CLIP -o OUT.mp4`` and ``rvr refocus --demo`` (registered by ``rvr_addon/cli.py``)."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..errors import RvrError

SHAPES = ("disk", "polygon", "anamorphic")
F_STOP_REFERENCE = 2.0
"""The f-number of aperture scale 1 (the reference lens, 50 mm f/2): ``--f-stop N`` is aperture 2/N."""


def parse_point(text: str) -> tuple[float, float]:
    """``"X,Y"`` -> (x, y) floats (px of the clip); argparse type."""
    try:
        x, y = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: give X,Y in px of the clip, e.g. 640,300") from None
    if x < 0 or y < 0:
        raise argparse.ArgumentTypeError(f"{text!r}: X and Y are px from the top-left corner, >= 0")
    return x, y


def add_parser(sub) -> None:
    """Register ``rvr refocus``."""
    from ..depth.methods import METHODS
    from ..laaf.presets import DEFAULT_PRESET, PRESETS
    from . import DEFAULT_MAX_SIZE

    p = sub.add_parser("refocus", help="one command: a clip in, a refocused video out (estimate, stabilize, "
                                       "autofocus, render)",
                       description="Refocus a clip: depth from the clip itself (parallax, people, the network), "
                                   "stabilized over time, look-ahead autofocus on its subjects (or a subject you "
                                   "pin), rendered with a real lens's shallow depth of field. Re-running the same "
                                   "command reuses the finished work (Ctrl-C is safe).")
    p.add_argument("input", nargs="?", type=Path, help="the clip: a video file (any FFmpeg reads) or an image folder")
    p.add_argument("-o", "--output", type=Path,
                   help="the refocused video (.mp4; a photo: .jpg/.png/.tif/.exr); default CLIP_refocused.mp4 beside "
                        "the clip, a photo's PHOTO_refocused.jpg (--demo: out/demo/bikes_refocused.mp4)")
    p.add_argument("--demo", action="store_true",
                   help="refocus the built-in real demo clip (a 10 s street montage) into out/demo/: the video, a "
                        "before | after video and a contact sheet")
    p.add_argument("--preset", choices=tuple(PRESETS), default=None,
                   help=f"what the autofocus looks for (default {DEFAULT_PRESET}: it reads the clip and picks): "
                        "conversation (who speaks), faces, action (moving subjects), salient, learned (AF-Net)")
    focus = p.add_mutually_exclusive_group()
    focus.add_argument("--focus-on", type=parse_point, metavar="X,Y",
                       help="pin focus on the subject at X,Y (px of the clip, first frame) and follow it, instead "
                            "of autofocus")
    focus.add_argument("--track", type=Path, metavar="FOCUS.json",
                       help="render with this focus file instead of autofocus: the OUT.focus.json of an earlier run "
                            "with the same clip options, edited (frames and units of that run)")
    lens = p.add_mutually_exclusive_group()
    lens.add_argument("--aperture", type=float, help="blur strength: aperture scale (1 = a 50 mm f/2 lens wide open, "
                                                     "the default; 2 = twice the blur; 0 = none)")
    lens.add_argument("--f-stop", type=float, metavar="N", help="blur strength as an f-number of the reference 50 mm "
                                                                "lens (1.4 = strong, 2 = default, 4 = mild)")
    p.add_argument("--shape", choices=SHAPES, default="disk", help="bokeh shape (default disk)")
    p.add_argument("--blades", type=int, default=6, help="blades of --shape polygon (default 6)")
    p.add_argument("--start", type=int, default=0, help="first frame (0-based)")
    span = p.add_mutually_exclusive_group()
    span.add_argument("--stop", type=int, help="stop before this frame")
    span.add_argument("--duration", type=float, metavar="S", help="refocus this many seconds from --start")
    p.add_argument("--max-size", type=int, default=DEFAULT_MAX_SIZE, metavar="PX",
                   help=f"work at a long side of at most PX (default {DEFAULT_MAX_SIZE}; 0 = the clip's size)")
    p.add_argument("--side-by-side", nargs="?", const="", type=str, metavar="OUT.mp4",
                   help="also write a before | after video (default name OUT_side_by_side.mp4; a photo's: a picture)")
    p.add_argument("--preview", nargs="?", const="", type=str, metavar="SHEET.png",
                   help="also write a contact sheet: frames with their depth and what is in focus "
                        "(default name OUT_sheet.png)")
    p.add_argument("--cache", type=Path, metavar="DIR",
                   help="the clip's work folder (default OUT_DIR/rvr_cache/CLIP-HASH); kept for re-runs")
    p.add_argument("--depth-method", choices=METHODS[:-1], default="auto",
                   help="where depth comes from (default auto: parallax where the camera moves, people, the network)")
    p.add_argument("--hfov", type=float, metavar="DEG", help="the camera's field of view across the frame's long side (default 66)")
    p.add_argument("--window", type=float, default=2.0, help="look-ahead window of the autofocus in s (default 2)")
    p.add_argument("--causal", action="store_true",
                   help="no look-ahead (what a camera could do live): the autofocus and the temporal filter see no later frame")
    from ..laaf.commands import add_calm_cuts_args, add_pull_args

    add_calm_cuts_args(p)  # frames of --cuts are frames of the clip, whatever --start says
    add_pull_args(p)
    p.add_argument("--no-stabilize", action="store_true", help="skip the temporal filter of the depth")
    p.add_argument("--weights", type=Path, help="estimator weights (default: the shipped ones)")
    p.add_argument("--fps", type=float, help="frame rate of an image-sequence input (default 24)")
    from ..render import DEVICE_HELP, DEVICES

    p.add_argument("--device", choices=DEVICES, default="auto", help=DEVICE_HELP)
    p.add_argument("-q", "--quiet", action="store_true", help="no progress display")
    p.set_defaults(func=cmd_refocus)


def settings_from_args(args: argparse.Namespace):
    """The :class:`~rvr_addon.refocus.job.RefocusSettings` of the command line."""
    from ..render.aperture import ApertureSpec
    from .demo import DEMO_OUT_DIR, demo_clip
    from .job import RefocusSettings, default_output, derived_path

    if args.demo:
        if args.input is not None:
            raise RvrError("give either a CLIP or --demo, not both")
        args.input = demo_clip()
        if args.output is None:
            args.output = DEMO_OUT_DIR / "bikes_refocused.mp4"
        if args.side_by_side is None:
            args.side_by_side = ""
        if args.preview is None:
            args.preview = ""
    if args.input is None:
        raise RvrError("rvr refocus needs a CLIP (or --demo); e.g. rvr refocus phone.mp4 -o phone_refocused.mp4")
    output = args.output or default_output(args.input)
    if args.f_stop is not None:
        if not args.f_stop > 0:
            raise RvrError(f"--f-stop {args.f_stop}: give a positive f-number, e.g. 2 or 2.8")
        aperture = F_STOP_REFERENCE / args.f_stop
    else:
        aperture = 1.0 if args.aperture is None else args.aperture
    if aperture < 0:
        raise RvrError(f"--aperture {aperture}: give a blur strength >= 0 (0 = none)")
    if args.duration is not None and not args.duration > 0:
        raise RvrError(f"--duration {args.duration}: give a positive number of seconds")
    from ..pipeline import is_still_output

    beside = "_side_by_side" + (output.suffix if is_still_output(output) else ".mp4")  # a photo's is a picture
    side = None if args.side_by_side is None else Path(args.side_by_side or derived_path(output, beside))
    sheet = None if args.preview is None else Path(args.preview or derived_path(output, "_sheet.png"))
    preset = args.preset  # None: the default preset, unless a subject is pinned (refocus_job decides)
    from ..laaf.commands import calm_cuts_from_args, pull_settings

    cut_list = calm_cuts_from_args(args)
    pull = pull_settings(args)
    return RefocusSettings(
        input=args.input, output=output, cache=args.cache, preset=preset, focus_on=args.focus_on, aperture=aperture,
        spec=ApertureSpec(shape=args.shape, blades=args.blades), start=args.start, stop=args.stop,
        duration_s=args.duration, max_size=args.max_size or None, side_by_side=side, preview=sheet,
        depth_method=args.depth_method, hfov_deg=args.hfov, window_s=args.window, causal=args.causal, weights=args.weights, fps=args.fps,
        stabilize=not args.no_stabilize, calm=args.calm, cuts=cut_list, detect_cuts=not args.no_cuts,
        track=args.track, device=args.device, pull=pull)


def run_with_progress(chain, quiet: bool) -> None:
    """Step ``chain`` to the end with one progress display: stage, its frame, the whole run's
    ETA (log lines are printed above the bar, not through it)."""
    from tqdm import tqdm
    from tqdm.contrib.logging import logging_redirect_tqdm

    fmt = "{desc} {percentage:3.0f}%|{bar}| [{elapsed}<{remaining}] {postfix}"
    with logging_redirect_tqdm(), tqdm(total=1000, disable=quiet, bar_format=fmt, file=sys.stderr) as bar:
        while chain.step():
            stage, job = chain.stage, chain.job
            if stage is not None and job is not None:
                bar.set_description_str(f"{stage.name:<14}", refresh=False)
                bar.set_postfix_str(chain.frame_text(), refresh=False)
            bar.update(int(chain.progress * 1000) - bar.n)
        bar.update(1000 - bar.n)


def cmd_refocus(args: argparse.Namespace) -> int:
    from ..cli import Interrupted
    from .demo import DEMO_CREDIT
    from .job import refocus_job

    settings = settings_from_args(args)
    chain, run = refocus_job(settings)
    print(f"refocusing {settings.input} ({run.frames} frames at {run.size[0]}x{run.size[1]}) -> {settings.output}; "
          f"work folder {run.work}", file=sys.stderr)
    try:
        run_with_progress(chain, args.quiet)
    except KeyboardInterrupt:
        where = chain.stage.name if chain.stage is not None else "the last stage"
        job = chain.job
        frame = f" ({chain.frame_text()})" if job is not None else ""
        chain.cancel()
        raise Interrupted(f"rvr refocus: interrupted during {where}{frame}; finished work is kept in {run.work}: "
                          "run the same command again to continue") from None
    except BaseException:
        chain.cancel()
        raise
    for note in run.notes:
        print(note)
    seconds = ", ".join(f"{k} {v:.1f} s" for k, v in chain.seconds.items() if k not in chain.skipped)
    print(f"time: {seconds}" + (f" (reused: {', '.join(chain.skipped)})" if chain.skipped else ""))
    for out in run.outputs:
        print(f"kept {out} (unchanged)" if out in run.kept else f"wrote {out}")
    if args.demo:
        print(DEMO_CREDIT)
    return 0
