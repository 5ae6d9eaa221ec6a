"""``rvr stabilize CACHE [--input VIDEO] [--window causal|centred] ...`` (wired in :mod:`rvr_addon.cli`)."""
from __future__ import annotations

import argparse
from pathlib import Path

from ..cli import on_interrupt


def add_parser(sub) -> argparse.ArgumentParser:
    """Add the ``stabilize`` sub-command to the ``rvr`` sub-parsers."""
    from .settings import FLOW_PRESETS, TemporalSettings

    d = TemporalSettings()
    p = sub.add_parser("stabilize", help="temporally stabilize the D and E of an estimation cache (paper 4.2)",
                       description="Occlusion-aware, outlier-robust temporal filter of the disparity D and HDR "
                                   "exponent E in a cache written by `rvr estimate` (paper section 4.2; DIS optical "
                                   "flow instead of FlowNet 2.0). Adds channels S.D, S.E.R/G/B and S.C (confidence) "
                                   "to each frame's EXR and keeps the raw ones; `rvr render --depth CACHE --hdr "
                                   "CACHE` then uses the stabilized channels. Resumable: run the same command again "
                                   "after an interruption; other settings recompute every frame.")
    p.add_argument("cache", type=Path, metavar="CACHE", help="cache folder written by `rvr estimate ... -o CACHE`")
    p.add_argument("--input", type=Path, metavar="VIDEO",
                   help="the clip for the optical flow (default: the source recorded in CACHE/meta.json)")
    p.add_argument("--window", choices=("causal", "centred"), default=d.window,
                   help="centred: M/2 past and M/2 future frames (recorded video; lag-free, shorter flow chains); "
                        "causal: the current and M past frames (the paper's; what a camera could do live). "
                        "Default %(default)s")
    p.add_argument("-M", "--frames", dest="m", type=int, default=d.m, metavar="M",
                   help="neighbouring frames in the window (paper: 6; default %(default)s)")
    p.add_argument("--delta", type=float, default=d.delta_px, metavar="PX",
                   help="forward-backward consistency threshold in px at the flow resolution (default %(default)s)")
    p.add_argument("--photometric-tol", type=float, default=d.photometric_tol, metavar="T",
                   help="a warped pixel whose colour differs by more than T (fraction of full scale, 5x5 mean) is "
                        "treated as occluded (default %(default)s)")
    p.add_argument("--outlier-scale", type=float, default=d.outlier_scale_d, metavar="S",
                   help="scale of the D outlier weight exp(-median/s), as a fraction of the frame width "
                        "(default %(default)s)")
    p.add_argument("--outlier-scale-e", type=float, default=d.outlier_scale_e, metavar="S",
                   help="the same for E, in E units (default %(default)s)")
    p.add_argument("--flow-preset", choices=FLOW_PRESETS, default=d.flow_preset,
                   help="OpenCV DIS preset (default %(default)s)")
    p.add_argument("--flow-size", type=int, default=d.flow_max_side, metavar="PX",
                   help="longer side of the resolution the flow runs at (default %(default)s px)")
    p.add_argument("--cut-fraction", type=float, default=d.cut_fraction, metavar="F",
                   help="a frame pair where more than F of the pixels fail the flow checks is a scene cut: the "
                        "window restarts (default %(default)s)")
    p.add_argument("--force", action="store_true", help="recompute frames already stabilized")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_stabilize)
    return p


def cmd_stabilize(args: argparse.Namespace) -> int:
    """Run ``rvr stabilize``; returns the exit status (errors are RvrError, handled by the CLI)."""
    from .filter import TemporalSettings
    from .job import StabilizeJob, StabilizeSettings

    settings = TemporalSettings(window=args.window, m=args.m, delta_px=args.delta,
                                photometric_tol=args.photometric_tol, outlier_scale_d=args.outlier_scale,
                                outlier_scale_e=args.outlier_scale_e, flow_preset=args.flow_preset,
                                flow_max_side=args.flow_size, cut_fraction=args.cut_fraction)
    job = StabilizeJob(StabilizeSettings(cache=args.cache, input=args.input, temporal=settings, force=args.force))
    with on_interrupt("stabilize", lambda: f"stopped; {job.written} frames stored in {job.cache.folder}"
                                           + (f" (the cache '{args.cache}' is unchanged until they are complete)"
                                              if job.cache.rebuilding else "")
                                           + "; run the same command again to continue"):
        job.run(progress=not args.quiet)
    print(f"stabilized {args.cache} ({job.text})")
    return 0
