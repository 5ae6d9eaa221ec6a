"""``rvr batch CLIPS... -o OUT`` (wired in :mod:`rvr_addon.cli`)."""
from __future__ import annotations

import argparse
import logging
from pathlib import Path

from ..cli import add_depth_method_args, on_interrupt
from ..errors import RvrError


def add_parser(sub) -> argparse.ArgumentParser:
    """Add the ``batch`` sub-command to the ``rvr`` sub-parsers."""
    from ..laaf.commands import add_afnet_args, add_pull_args
    from ..laaf.presets import DEFAULT_PRESET, PRESETS
    from ..temporal.settings import TemporalSettings
    from . import FORMATS

    d = TemporalSettings()
    p = sub.add_parser("batch", help="refocus many clips on a Dask cluster (analyze -> autofocus -> render)",
                       description="Run analyze (estimate + stabilize), look-ahead autofocus and render for many clips "
                                   "as one Dask task graph: an embedded local cluster by default, an existing one with "
                                   "--scheduler. Long clips are split into chunks (--chunk-frames) whose results equal "
                                   "one pass. Per clip NAME: OUT/NAME.mp4 (or OUT/NAME_frames/) and OUT/NAME.focus.json; "
                                   "caches in OUT/rvr_cache. A clip that fails is reported and the others go on; "
                                   "running the same command again skips finished clips and resumes the others. "
                                   "Exit status 1 when a clip failed.")
    p.add_argument("clips", nargs="+", type=Path, metavar="CLIP",
                   help="video files, image-sequence folders, folders of clips, or list files (.txt, one clip a line)")
    p.add_argument("-o", "--output", required=True, type=Path, metavar="OUT", help="output folder")
    p.add_argument("--cache-root", type=Path, metavar="DIR", help="per-clip caches (default OUT/rvr_cache)")
    p.add_argument("--format", choices=FORMATS, default="mp4",
                   help="mp4 (H.264 + the source audio), png (8-bit sRGB frames) or exr (linear HDR frames)")
    g = p.add_argument_group("analyze")
    g.add_argument("--weights", type=Path, help="estimator weights (default: the ones shipped with rvr)")
    g.add_argument("--depth-root", type=Path, metavar="DIR",
                   help="external disparity maps instead of the network's D: DIR/NAME holds clip NAME's maps")
    g.add_argument("--depth-scale", type=float, default=1.0, help="D = scale * map + offset")
    g.add_argument("--depth-offset", type=float, default=0.0, help="D = scale * map + offset")
    g.add_argument("--depth-is-distance", action="store_true", help="the maps hold distance: 1/map before the affine")
    g.add_argument("--no-hdr", action="store_true", help="with --depth-root: E = 0 (no network needed)")
    add_depth_method_args(g, ". Fused depth keeps clip-wide state, so a clip's estimate is then one task (not "
                             "chunked); network and external are chunked")
    g.add_argument("--temporal-window", choices=("causal", "centred"), default=d.window,
                   help="temporal filter window (rvr stabilize --window; default %(default)s)")
    g.add_argument("-M", "--temporal-frames", dest="m", type=int, default=d.m, metavar="M",
                   help="temporal filter: neighbouring frames in the window (default %(default)s)")
    g = p.add_argument_group("autofocus")
    g.add_argument("--preset", choices=tuple(PRESETS), default=DEFAULT_PRESET,
                   help="LAAF AI-assist preset (default %(default)s: reads the clip and picks; conversation without "
                        "audio falls back to faces), or learned (AF-Net)")
    add_afnet_args(g)
    g.add_argument("--look-ahead", type=float, default=2.0, metavar="S", help="look-ahead window in seconds (default 2)")
    g.add_argument("--causal", action="store_true", help="no look-ahead (what a camera could do)")
    add_pull_args(g)
    g.add_argument("--aperture", type=float, default=1.0, help="aperture scale of the focus track (default 1)")
    from ..laaf.presets import DEFAULT_CALM

    g.add_argument("--calm", type=float, default=DEFAULT_CALM, metavar="0..1",
                   help=f"calm <-> responsive focus (default {DEFAULT_CALM}; rvr autofocus --calm)")
    g.add_argument("--no-cuts", action="store_true", help="detect no shot cuts (each clip is one shot)")
    g = p.add_argument_group("render")
    g.add_argument("--scale", type=float, default=1.0, help="render at this fraction of the size (a proxy)")
    g.add_argument("--fps", type=float, help="frame rate of image-sequence inputs (default 24)")
    g = p.add_argument_group("cluster")
    g.add_argument("--scheduler", metavar="tcp://HOST:PORT",
                   help="an existing Dask cluster (its workers must see the same paths); default: a local cluster")
    g.add_argument("--workers", type=int, help="local worker processes (default: one per CPU core)")
    g.add_argument("--threads-per-worker", type=int, default=1, help="tasks each local worker runs at once (default 1)")
    g.add_argument("--task-threads", type=int, default=1, help="torch/OpenCV threads per task (default 1)")
    g.add_argument("--chunk-frames", type=int, default=240,
                   help="frames per task; longer clips are split (default 240; 0 = whole clips)")
    g.add_argument("--retries", type=int, default=0, help="retries of a task that raised (dead workers: always)")
    g.add_argument("--no-dashboard", action="store_true", help="do not serve Dask's dashboard")
    p.add_argument("--drop-cache", action="store_true",
                   help="delete each clip's cache once its outputs are written (caches are large: tens of MB per "
                        "1080p frame); default: keep them for editing in Blender")
    p.add_argument("--force", action="store_true", help="redo clips already finished (caches are still reused)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_batch)
    return p


def cmd_batch(args: argparse.Namespace) -> int:
    """Run ``rvr batch``; prints the summary table; exit status 1 if any clip failed."""
    from ..laaf.commands import check_afnet_args, pull_settings
    from ..temporal.filter import TemporalSettings
    from .graph import ClusterSettings, run_batch
    from .inputs import collect_clips
    from .settings import BatchSettings

    check_afnet_args(args)
    if not 0.0 <= args.calm <= 1.0:
        raise RvrError(f"--calm {args.calm}: give a value from 0 (responsive) to 1 (calm)")
    settings = BatchSettings(
        output=args.output, cache_root=args.cache_root, weights=args.weights, depth_root=args.depth_root,
        depth_scale=args.depth_scale, depth_offset=args.depth_offset, depth_is_distance=args.depth_is_distance,
        no_hdr=args.no_hdr, temporal=TemporalSettings(window=args.temporal_window, m=args.m), preset=args.preset,
        window_s=args.look_ahead, causal=args.causal, pull=pull_settings(args), aperture=args.aperture, scale=args.scale,
        format=args.format, chunk_frames=args.chunk_frames, fps=args.fps, force=args.force, retries=args.retries,
        keep_cache=not args.drop_cache, afnet_weights=args.afnet_weights, afnet_threshold=args.afnet_threshold,
        afnet_speaker=args.afnet_region == "speaker", depth_method=args.depth_method, hfov_deg=args.hfov,
        calm=args.calm, detect_cuts=not args.no_cuts)
    cluster = ClusterSettings(scheduler=args.scheduler, workers=args.workers,
                              threads_per_worker=args.threads_per_worker, task_threads=args.task_threads,
                              dashboard=not args.no_dashboard)
    clips = collect_clips(args.clips)
    # the scheduler of a local cluster runs in this process: keep its INFO chatter off the terminal
    import distributed  # noqa: F401 - configures its loggers on import; then quieten them

    logging.getLogger("distributed").setLevel(logging.WARNING)
    with on_interrupt("batch", lambda: "cancelled; finished clips and cached frames are kept; run the same command "
                                       "again to continue"):
        report = run_batch(clips, settings, cluster, progress=not args.quiet)
    print(report.table())
    return 1 if report.count("failed") else 0
