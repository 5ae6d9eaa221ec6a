"""``rvr autofocus`` and ``rvr eval-focus`` (registered by ``rvr_addon/cli.py``)."""
from __future__ import annotations

import argparse
from pathlib import Path

from ..cli import on_interrupt
from ..errors import RvrError


def add_pull_args(p: argparse.ArgumentParser) -> None:
    """``--pull-frames --lead-frames --profile --hold-frames`` (rvr autofocus, eval-focus, batch, refocus)."""
    from .presets import PROFILES

    p.add_argument("--pull-frames", type=int,
                   help="length of a focus pull in frames (default 0.4 s at the clip's frame rate: 10 at 25 fps, "
                        "12 at 30, 24 at 60)")
    p.add_argument("--lead-frames", type=int,
                   help="the pull lands this many frames before the NFT (default 0.2 s: 5 at 25 fps)")
    p.add_argument("--profile", choices=PROFILES, default="linear", help="pull profile (default linear, as the paper)")
    p.add_argument("--hold-frames", type=int,
                   help="after a subject is lost, hold its focus this long before releasing (default 0.48 s: 12 "
                        "at 25 fps)")


def add_afnet_args(p: argparse.ArgumentParser, region: bool = True) -> None:
    """``--afnet-weights --afnet-threshold`` (and ``--afnet-region`` when ``region``) of preset learned."""
    p.add_argument("--afnet-weights", type=Path, metavar="PATH",
                   help="AF-Net weights for --preset learned (rvr train-afnet's RUN/afnet.pt; default "
                        "rvr_addon/afnet/weights/afnet.pt)")
    p.add_argument("--afnet-threshold", type=float, default=None, metavar="P",
                   help="NFT probability an AF-Net peak must reach, 0..1 (default: the weights' own threshold, 0.5 "
                        "if they name none)")
    if not region:
        return
    p.add_argument("--afnet-region", choices=("speaker", "map"), default="speaker",
                   help="where an AF-Net NFT focuses: speaker (default: where someone speaks, the speaker the speech "
                        "detector localises; elsewhere AF-Net's map) or map (always AF-Net's map, the paper's)")


def add_calm_cuts_args(p: argparse.ArgumentParser) -> None:
    """``--calm 0..1`` and ``--cuts FILE|FRAMES`` / ``--no-cuts`` (rvr autofocus, rvr refocus)."""
    from .presets import DEFAULT_CALM

    p.add_argument("--calm", type=float, default=DEFAULT_CALM, metavar="0..1",
                   help=f"calm <-> responsive (default {DEFAULT_CALM}): 1 holds focus (minimum hold, hysteresis, "
                        "a cost for each change, a follow deadband), 0 pulls on every detected change (the paper)")
    cuts = p.add_mutually_exclusive_group()
    cuts.add_argument("--cuts", metavar="FILE|FRAMES",
                      help='the shot cuts, instead of detecting them: frames ("12,80": 0-based first frame of each '
                           "new shot) or a file (JSON list, {\"cuts\": [...]} e.g. a focus file, or text)")
    cuts.add_argument("--no-cuts", action="store_true", help="no shot cuts: do not detect any")


def calm_cuts_from_args(args: argparse.Namespace) -> list[int] | None:
    """Check ``--calm`` (RvrError outside 0..1) and return the ``--cuts`` list (None: detect them)."""
    if not 0.0 <= args.calm <= 1.0:
        raise RvrError(f"--calm {args.calm}: give a value from 0 (responsive) to 1 (calm)")
    if args.cuts is None:
        return None
    from ..temporal.cuts import parse_cuts

    try:
        return parse_cuts(args.cuts)
    except (ValueError, OSError) as ex:
        raise RvrError(f"--cuts: {ex}") from None


def check_afnet_args(args: argparse.Namespace) -> None:
    """RvrError naming ``--afnet-threshold`` when it is outside (0, 1)."""
    if args.afnet_threshold is not None and not 0.0 < args.afnet_threshold < 1.0:
        raise RvrError(f"--afnet-threshold must be between 0 and 1, got {args.afnet_threshold}")


def pull_settings(args: argparse.Namespace):
    """The :class:`~rvr_addon.laaf.puller.PullSettings` of the pull options (RvrError naming a bad one)."""
    from .puller import PullSettings

    s = PullSettings(pull_frames=args.pull_frames, lead_frames=args.lead_frames, profile=args.profile,
                     hold_frames=args.hold_frames)
    try:
        s.check()
    except ValueError as ex:
        raise RvrError(f"--{str(ex).split('=')[0].replace('_', '-')}: {ex}") from None
    return s


def add_autofocus_parser(sub) -> None:
    """``rvr autofocus INPUT (--cache CACHE | --depth DEPTH) --preset P -o focus.json``."""
    from .presets import DEFAULT_PRESET, PRESETS

    p = sub.add_parser("autofocus", help="look-ahead autofocus: decide where and when to focus (focus.json)",
                       description="Look-Ahead Autofocus (paper section 5): detectors (face, saliency, action, "
                                   "speech) -> New Focus Targets -> KCF tracking -> focus pulls. Writes a focus "
                                   "file that `rvr render --track` reads (per-frame track + linear keyframes).")
    p.add_argument("input", type=Path, help="video file, image folder, glob or frame pattern")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--cache", type=Path, help="per-clip cache of `rvr estimate` (stabilised D preferred)")
    src.add_argument("--depth", type=Path, help="disparity maps (anything `rvr render --depth` accepts)")
    p.add_argument("--depth-scale", type=float, default=1.0, help="with --depth: multiply the maps")
    p.add_argument("--depth-offset", type=float, default=0.0, help="with --depth: then add this")
    p.add_argument("--preset", choices=tuple(PRESETS), default=None,
                   help=f"AI-assist preset (default {DEFAULT_PRESET} unless only --targets are given): auto reads the "
                        "clip (speech? faces? motion?) and picks one of action={action,saliency}, "
                        "conversation={speech,face}, faces, salient; or learned: AF-Net predicts the NFTs of any "
                        "video (needs trained weights, --afnet-weights)")
    add_afnet_args(p)
    p.add_argument("--targets", type=Path, help="manual NFTs (JSON: [{t, x, y, box, source}], 0-based frames)")
    p.add_argument("--window", type=float, default=2.0, help="look-ahead window in seconds (default 2.0)")
    p.add_argument("--causal", action="store_true", help="no look-ahead (window 0): what a camera could do")
    add_pull_args(p)
    p.add_argument("--aperture", type=float, default=1.0, help="aperture scale of the track (default 1.0)")
    add_calm_cuts_args(p)
    p.add_argument("--min-step", type=float, default=0.5,
                   help="smallest focus change (disparity units) that makes an NFT (default 0.5)")
    p.add_argument("--analysis-width", type=int, default=320, help="detector/tracker width in px (default 320)")
    p.add_argument("--start", type=int, default=0, help="first frame (0-based)")
    p.add_argument("--stop", type=int, help="stop before this frame")
    p.add_argument("--fps", type=float, help="frame rate of an image-sequence input (default 24)")
    p.add_argument("-o", "--output", type=Path, required=True, help="focus file to write (.json)")
    p.add_argument("--plot", type=Path, help="also write a PNG plot of the focus track")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_autofocus)


def cmd_autofocus(args: argparse.Namespace) -> int:
    from .focusfile import write_focus_file
    from .lookahead import AutofocusJob, AutofocusSettings

    if args.output.suffix.lower() != ".json":
        raise RvrError(f"-o {args.output}: the focus file is JSON; give a name ending in .json")
    from ..estimate.cache import check_cache_source
    from ..io.lock import writer_active
    from ..io.paths import check_outputs

    check_outputs("autofocus", [("focus file", args.output), ("plot", args.plot)],
                  [("input", args.input), ("cache", args.cache), ("depth", args.depth), ("targets", args.targets)])
    if args.cache is not None:
        other = writer_active(args.cache)
        if other is not None:
            raise RvrError(f"the cache '{args.cache}' is being written by another process ({other}); wait until it "
                           "has finished, then run this command again")
    for maps in (args.cache, args.depth):  # a cache (also given as --depth) of another clip is refused
        if maps is not None:
            check_cache_source(maps, args.input, command="autofocus")
    check_afnet_args(args)
    cut_list = calm_cuts_from_args(args)
    from .presets import DEFAULT_PRESET

    preset = args.preset if args.preset is not None or args.targets is not None else DEFAULT_PRESET
    settings = AutofocusSettings(
        input=args.input, cache=args.cache, depth=args.depth, depth_scale=args.depth_scale,
        depth_offset=args.depth_offset, preset=preset, targets=args.targets, window_s=args.window,
        causal=args.causal, pull=pull_settings(args), aperture=args.aperture, analysis_width=args.analysis_width,
        min_step=args.min_step, start=args.start, stop=args.stop, fps=args.fps, afnet_weights=args.afnet_weights,
        afnet_threshold=args.afnet_threshold, afnet_speaker=args.afnet_region == "speaker", cuts=cut_list,
        detect_cuts=not args.no_cuts, calm=args.calm)
    job = AutofocusJob(settings)
    with on_interrupt("autofocus", lambda: "cancelled; nothing written"):
        result = job.run(progress=not args.quiet)
    write_focus_file(args.output, result)
    if args.plot:
        from ..errors import output_error

        try:
            plot_focus(args.plot, result)
        except OSError as ex:
            raise output_error(args.plot, ex, "write the plot") from ex
        print(f"wrote {args.plot}")
    nfts = ", ".join(f"{n.t + result.start}({n.source})" for n in result.nfts)
    note = f"; {result.settings['fallback']}" if result.settings.get("fallback") else ""
    auto = result.settings.get("auto")
    if auto:
        note += f"; preset auto chose {auto['chose']} ({auto['why']})"
    if result.cuts:
        note += f"; shot cuts at {', '.join(str(c + result.start) for c in result.cuts)}"
    print(f"wrote {args.output}: {len(result.focus)} frames, {len(result.keys)} keys, NFTs at {nfts}{note} "
          f"({len(result.focus) / max(result.seconds, 1e-9):.1f} frames/s)")
    return 0


def plot_focus(path: Path, result) -> None:
    """PNG of a focus track: focus disparity per frame, the raw detector level, the NFTs."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    t = np.arange(len(result.focus)) + result.start
    fig, ax = plt.subplots(figsize=(8, 3))
    ax.plot(t, result.signal["raw"], ".", color="0.6", ms=3, label="detector level (raw)")
    ax.plot(t, result.focus, "C0-", label="focus track")
    ax.plot([k.frame + result.start for k in result.keys], [k.focus for k in result.keys], "C1o", ms=3,
            label="keyframes")
    for n in result.nfts:
        ax.axvline(n.t + result.start, color="C2", ls=":", lw=1)
        ax.text(n.t + result.start, ax.get_ylim()[1], n.source, fontsize=7, rotation=90, va="top")
    ax.set_xlabel("frame")
    ax.set_ylabel("focus disparity")
    ax.set_title(f"{Path(result.clip.path).name}: {result.settings.get('preset_used') or 'manual'}"
                 f"{' (causal)' if result.settings.get('causal') else ''}", fontsize=9)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def add_eval_focus_parser(sub) -> None:
    """``rvr eval-focus DATASET -o REPORT [--presets ...]``."""
    from .presets import EVAL_PRESETS

    p = sub.add_parser("eval-focus", help="evaluate LAAF on harness clips (mean |dt|, mean |dd|)",
                       description="Run look-ahead and causal LAAF per preset on each harness clip (ground-truth "
                                   "disparity) and compare with the ground-truth NFTs (paper section 6.2): "
                                   "summary.json, report.md and focus plots in REPORT.")
    p.add_argument("dataset", type=Path, nargs="?", help="folder of harness clips (or one clip); not with --real")
    p.add_argument("-o", "--output", type=Path, required=True, metavar="REPORT", help="report folder")
    p.add_argument("--presets", nargs="+", choices=EVAL_PRESETS, default=["action", "conversation"],
                   help="presets to evaluate on the same clips (default action conversation; add learned for AF-Net, "
                        "learned-map for AF-Net with every region from its own map)")
    add_afnet_args(p, region=False)
    p.add_argument("--window", type=float, default=2.0, help="look-ahead window in seconds (default 2.0)")
    add_pull_args(p)
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    add_eval_real_args(p)
    p.set_defaults(func=cmd_eval_focus)


def add_eval_real_args(p: argparse.ArgumentParser) -> None:
    """``--real CLIP --annotations ANN.json (--cache C | --depth D) [--preset P ...] [--causal-too]``."""
    from .presets import DEFAULT_PRESET, PRESETS

    g = p.add_argument_group("real clips", "score `rvr autofocus` on a real clip against a hand annotation "
                             "(rvr_addon/laaf/score_real.py): lead/lag per speaker turn, share of speaking time "
                             "on the speaker, spurious focus changes per minute, pulls across cuts")
    g.add_argument("--real", type=Path, metavar="CLIP", help="a real clip to score (instead of DATASET)")
    g.add_argument("--annotations", type=Path, metavar="ANN.json",
                   help='with --real: {"fps", "turns": [{start_s, end_s, box}], "cuts"} (or stretches + sides)')
    g.add_argument("--preset", nargs="+", choices=tuple(PRESETS), default=None, metavar="P",
                   help=f"with --real: presets to run (default {DEFAULT_PRESET})")
    g.add_argument("--cache", type=Path, help="with --real: the clip's `rvr estimate` cache (its depth)")
    g.add_argument("--depth", type=Path, help="with --real: disparity maps of the clip")
    g.add_argument("--causal-too", action="store_true", help="with --real: also run causal (no look-ahead)")


def cmd_eval_focus(args: argparse.Namespace) -> int:
    from .evaluate import evaluate

    check_afnet_args(args)
    if args.real is not None:
        return cmd_eval_focus_real(args)
    for opt in ("annotations", "preset", "cache", "depth"):
        if getattr(args, opt) is not None:
            raise RvrError(f"--{opt} belongs to --real CLIP; give --real or leave it out")
    if args.dataset is None:
        raise RvrError("eval-focus: give a DATASET of harness clips, or --real CLIP --annotations ANN.json")
    summary = evaluate(args.dataset, args.output, args.presets, pull_settings(args), args.window, progress=not args.quiet,
                       afnet_weights=args.afnet_weights, afnet_threshold=args.afnet_threshold)
    for p in args.presets:
        g = summary.get
        print(f"{p}: look-ahead mean|dt| {g(f'focus.{p}.mean_dt_frames')} frames, mean|dd| {g(f'focus.{p}.mean_dd')}; "
              f"causal mean|dt| {g(f'focus.{p}.causal.mean_dt_frames')}, mean|dd| {g(f'focus.{p}.causal.mean_dd')}")
    print(f"wrote {args.output / 'summary.json'}, {args.output / 'report.md'}")
    return 0


def cmd_eval_focus_real(args: argparse.Namespace) -> int:
    """``rvr eval-focus --real CLIP --annotations ANN.json (--cache | --depth) ...``."""
    from .presets import DEFAULT_PRESET
    from .score_real import evaluate_real, load_annotation

    if args.dataset is not None:
        raise RvrError(f"eval-focus: give either DATASET ({args.dataset}) or --real {args.real}, not both")
    if args.annotations is None:
        raise RvrError("eval-focus --real: give --annotations ANN.json (the speaker turns of the clip)")
    if (args.cache is None) == (args.depth is None):
        raise RvrError("eval-focus --real: give the clip's depth, either --cache CACHE (of `rvr estimate`) or "
                       "--depth MAPS (one of them); a flat depth map would make every focus pull a no-op")
    try:
        load_annotation(args.annotations)
    except (OSError, ValueError, KeyError, TypeError) as ex:
        raise RvrError(f"--annotations {args.annotations}: {ex}") from None
    from ..estimate.cache import check_cache_source

    for maps in (args.cache, args.depth):
        if maps is not None:
            check_cache_source(maps, args.real, command="eval-focus")
    presets = args.preset or [DEFAULT_PRESET]
    with on_interrupt("eval-focus", lambda: "cancelled"):
        summary = evaluate_real(args.real, args.annotations, args.output, presets, cache=args.cache,
                                depth=args.depth, causal_too=args.causal_too, window_s=args.window,
                                pull=pull_settings(args), progress=not args.quiet,
                                afnet_weights=args.afnet_weights, afnet_threshold=args.afnet_threshold)
    name = args.real.stem
    for p in presets:
        for suffix, label in (("", "look-ahead"), (".causal", "causal")):
            k = f"focus.real.{name}.{p}{suffix}"
            if f"{k}.speaking_share" not in summary:
                continue
            g = summary.get
            chose = f" (auto chose {g(k + '.auto_chose')})" if g(k + ".auto_chose") else ""
            print(f"{p} {label}{chose}: speaking share {g(k + '.speaking_share')}, turns led "
                  f"{g(k + '.turns_led')}/{g(k + '.turns_changed')}, lead mean {g(k + '.lead_frames_mean')} frames, "
                  f"spurious {g(k + '.spurious_per_min')}/min, pulls across cuts {g(k + '.pulls_across_cuts')}"
                  + (f", off-screen speech: {g(k + '.offscreen_changes')} changes, moved "
                     f"{g(k + '.offscreen_moved_share')}" if g(k + ".offscreen_changes") is not None else "")
                  + (f", cuts on the new shot's subject at once {g(k + '.cuts_on_subject')}/"
                     f"{g(k + '.cuts_annotated')} (largest lag {g(k + '.cut_lag_frames_max')} frames)"
                     if g(k + ".cuts_on_subject") is not None else ""))
    print(f"wrote {args.output / 'summary.json'}, {args.output / 'details.json'}")
    return 0


def add_parsers(sub) -> None:
    """Register the LAAF commands on the ``rvr`` sub-parsers."""
    add_autofocus_parser(sub)
    add_eval_focus_parser(sub)
