"""``blender -b -c rvr analyze|autofocus|render --blend FILE ...``: the VSE operators headless.

Registered by the extension's ``__init__`` through ``bpy.utils.register_cli_command("rvr")``.
A command with ``--blend`` (and ``analyze``, which only exists here) opens the .blend, makes
the strip active (``--strip NAME``, default: the active strip), runs the same operator the
panel runs (``EXEC_DEFAULT``: blocking), and saves the file (``--no-save`` to leave it). Any
other ``rvr`` command goes to the engine's command line (``rvr render INPUT --depth ...``).

Exit status: 0 done, 1 the operator reported an error (printed, naming the file and the fix),
2 bad arguments.
"""
from __future__ import annotations

import argparse
import sys
from contextlib import contextmanager
from pathlib import Path

import bpy

from ..rvr_addon.laaf.presets import DEFAULT_PRESET
from . import compat, prefs

COMMANDS = ("analyze", "autofocus", "render")


def wants_blender(argv: list[str]) -> bool:
    """True when ``argv`` is a strip command for this module (else the engine's CLI runs it)."""
    return bool(argv) and argv[0] in COMMANDS and (argv[0] == "analyze" or "--blend" in argv)


def _target(text: str) -> tuple[int, float, float, float, float]:
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"--target {text!r}: give FRAME,X,Y or FRAME,X,Y,W,H (numbers)") from None
    if len(values) not in (3, 5):
        raise argparse.ArgumentTypeError(f"--target {text!r}: give FRAME,X,Y or FRAME,X,Y,W,H")
    frame, x, y, *wh = values
    w, h = wh or (0.0, 0.0)
    return int(frame), x, y, w, h


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="blender -b -c rvr", description="RVR-LAAF on a strip of a .blend file")
    sub = parser.add_subparsers(dest="command", required=True)

    def common(p):
        p.add_argument("--blend", type=Path, required=True, help="the .blend file (saved after the command)")
        p.add_argument("--strip", help="strip name (default: the file's active strip)")
        p.add_argument("--no-save", action="store_true", help="do not save the .blend file afterwards")
        p.add_argument("--cache-dir", help="cache location (default: the preferences', //rvr_cache/)")
        p.add_argument("--threads", type=int, help="CPU threads (default: the preferences')")

    p = sub.add_parser("analyze", help="estimate + stabilize the strip into its cache")
    common(p)
    p.add_argument("--weights", type=Path, help="estimator weights (default: the preferences', else shipped)")
    p.add_argument("--depth", type=Path, help="disparity maps for the strip (depth from elsewhere)")

    p = sub.add_parser("autofocus", help="add targets, then Auto Focus with a preset (or only Track)")
    common(p)
    p.add_argument("--preset", choices=("auto", "action", "conversation", "faces", "salient", "none"),
                   default=DEFAULT_PRESET,
                   help="detector preset; auto reads the clip and picks; none = only track the strip's targets "
                        "(default %(default)s)")
    p.add_argument("--window", type=float, help="look-ahead in seconds (default: the strip's)")
    p.add_argument("--target", type=_target, action="append", default=[], metavar="FRAME,X,Y[,W,H]",
                   help="add a manual focus target first (scene frame, clip px); repeatable")
    p.add_argument("--pull-frames", type=int, help="default pull length in frames (0: 0.4 s at the clip's frame rate)")
    p.add_argument("--lead-frames", type=int, help="default lead in frames (-1: 0.2 s at the clip's frame rate)")

    p = sub.add_parser("render", help="render the strip with its focus F-curves; adds the result strip")
    common(p)
    p.add_argument("--format", choices=("movie", "images"), help="movie (default) or image sequence")
    p.add_argument("--size", choices=("1.0", "0.5", "0.25"), help="full size or a proxy")
    p.add_argument("--output", help="output folder (default: the strip's, //rvr_renders/)")
    return parser


@contextmanager
def _preferences(args):
    over = {k: v for k, v in (("cache_dir", args.cache_dir), ("threads", args.threads),
                              ("weights_path", str(args.weights) if getattr(args, "weights", None) else None))
            if v is not None}
    with prefs.override(**over):
        yield


def _open(args):
    if not args.blend.is_file():
        raise RuntimeError(f"the .blend file '{args.blend}' was not found; give the path of a saved file")
    bpy.ops.wm.open_mainfile(filepath=str(args.blend))
    scene = compat.sequencer_scene(bpy.context)
    editor = scene.sequence_editor
    if editor is None:
        raise RuntimeError(f"'{args.blend}' has no strips (scene '{scene.name}'); add the clip in the Sequencer")
    if args.strip:
        strip = compat.strip_collection_all(editor).get(args.strip)
        if strip is None:
            names = ", ".join(s.name for s in compat.strip_collection_all(editor))
            raise RuntimeError(f"no strip '{args.strip}' in '{args.blend}' (strips: {names})")
        editor.active_strip = strip
    elif editor.active_strip is None:
        raise RuntimeError(f"'{args.blend}' has no active strip; pass --strip NAME")
    return scene, editor.active_strip


def run(argv: list[str]) -> int:
    """Run one strip command; returns the exit status."""
    try:
        args = build_parser().parse_args(argv)
    except SystemExit as ex:
        return ex.code if isinstance(ex.code, int) else 2
    try:
        with _preferences(args):
            scene, strip = _open(args)
            if args.command == "analyze":
                if args.depth:
                    strip.rvr.depth_path = str(args.depth.resolve())
                bpy.ops.rvr.analyze("EXEC_DEFAULT")
            elif args.command == "autofocus":
                for name in ("pull_frames", "lead_frames"):
                    if getattr(args, name) is not None:
                        setattr(strip.rvr, name, getattr(args, name))
                for frame, x, y, w, h in args.target:
                    bpy.ops.rvr.add_focus_target(frame=frame, x=x, y=y, w=w, h=h)
                if args.preset == "none":
                    bpy.ops.rvr.track_targets("EXEC_DEFAULT")
                else:
                    window = -1.0 if args.window is None else args.window
                    bpy.ops.rvr.auto_focus("EXEC_DEFAULT", preset=args.preset, lookahead_s=window)
            else:
                if args.format:
                    strip.rvr.render_format = args.format.upper()
                if args.size:
                    strip.rvr.render_size = args.size
                if args.output:
                    strip.rvr.output_dir = args.output
                bpy.ops.rvr.render_strip("EXEC_DEFAULT")
            if not args.no_save:
                bpy.ops.wm.save_mainfile()
    except RuntimeError as ex:  # an operator's ERROR report, or _open's
        print(f"rvr {args.command}: {str(ex).strip()}", file=sys.stderr)
        return 1
    return 0
