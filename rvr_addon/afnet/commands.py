"""``rvr train-afnet`` (registered by ``rvr_addon/cli.py``)."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..cli import add_run_args, add_run_control_args, run_training, set_torch_threads
from ..errors import RvrError


def add_parser(sub) -> None:
    """Register ``rvr train-afnet`` on the ``rvr`` sub-parsers."""
    from .config import AFNetConfig

    d = AFNetConfig()
    p = sub.add_parser("train-afnet", help="train AF-Net (learned look-ahead focus for any video)",
                       description="Train AF-Net (paper section 5.3) on harness clips (`python -m sintel_eval "
                                   "generate --no-dof`: exact focus regions and NFTs) and/or focus annotation files "
                                   "(editor exports; weak labels from the AI-assist detectors, at a lower loss "
                                   "weight). Resumable (--resume), with a progress bar, loss_log.csv and loss.png in "
                                   "the run folder; writes RUN_DIR/afnet.pt (+ afnet.json) at the end. Use it with "
                                   "`rvr autofocus --preset learned --afnet-weights RUN_DIR/afnet.pt`.")
    p.add_argument("--data", action="append", type=Path, default=[], metavar="DIR",
                   help="harness dataset: a folder of clips written by `python -m sintel_eval generate` (repeatable)")
    p.add_argument("--annotations", action="append", type=Path, default=[], metavar="FILE",
                   help="focus annotation file (rvr-laaf-focus-annotations/1: editor exports and weak labels; "
                        "see rvr_addon/afnet/annotations.py; repeatable)")
    add_run_args(p, iterations=10000)
    p.add_argument("--lr", type=float, default=1e-3, help="Adam learning rate (default 1e-3)")
    p.add_argument("--batch", type=int, default=8, help="queries per step (default 8)")
    p.add_argument("--weak-weight", type=float, default=0.3, metavar="W",
                   help="loss weight of weak-label clips (detectors alone; default 0.3)")
    p.add_argument("--w-map", type=float, default=1.0, help="weight of the focus-region loss (default 1)")
    p.add_argument("--w-nft", type=float, default=1.0, help="weight of the NFT-probability loss (default 1)")
    p.add_argument("--pos-fraction", type=float, default=0.5,
                   help="share of queries centred near an NFT (default 0.5)")
    p.add_argument("--tolerance", type=float, default=3.0, metavar="FRAMES",
                   help="NFT label window: label exp(-dt^2 / 2 tol^2) (default 3 frames)")
    p.add_argument("--depth-augment", type=float, default=0.0, metavar="P",
                   help="share of queries whose disparity is replaced by estimate-like (blurred, distorted, noisy), "
                        "region-flat (2-3 levels) or flat depth, so the network works on every kind of depth it "
                        "meets at inference (default 0: the training clips' exact disparity only)")
    p.add_argument("--size", default=f"{d.width}x{d.height}", metavar="WxH",
                   help=f"network input size, multiples of 8 (default {d.width}x{d.height})")
    p.add_argument("--gray", action="store_true", help="gray instead of RGB input")
    p.add_argument("--no-disparity", action="store_true", help="no disparity input channel")
    p.add_argument("--f-t", type=int, default=d.f_t, help=f"sampled frames per temporal unit, odd (default {d.f_t})")
    p.add_argument("--units", type=int, default=d.s, help=f"temporal units s, odd (default {d.s})")
    p.add_argument("--sample-step", type=int, default=d.sample_step,
                   help=f"clip frames between sampled frames (default {d.sample_step}, as the paper)")
    p.add_argument("--stride", type=int, default=None,
                   help=f"clip frames between queries at inference, written into the weights (default {d.stride}, "
                        "as the paper; training does not use it, so a --resume may change it)")
    p.add_argument("--threshold", type=float, default=None, metavar="P",
                   help="NFT probability that `--preset learned` uses by default with these weights (written into "
                        "their header; default: none, i.e. 0.5)")
    p.add_argument("--audio", action="store_true",
                   help="give the network the clip's sound too (beyond the paper: voice activity, level, onsets and "
                        "voice register per frame; see rvr_addon/afnet/audio_features.py)")
    p.add_argument("--init-from", type=Path, metavar="WEIGHTS",
                   help="start a new run from these AF-Net weights (an afnet.pt); their architecture is kept, "
                        "with --audio the audio input is added with zero weights")
    add_run_control_args(p, checkpoint_every=250)
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_train_afnet)


def cmd_train_afnet(args: argparse.Namespace) -> int:
    from .audio_features import AUDIO_FEATURES
    from .model import AFNetConfig
    from .train import AFNetTrainer, AFNetTrainSettings

    try:
        w, h = (int(v) for v in args.size.lower().split("x"))
        config = AFNetConfig(width=w, height=h, rgb=not args.gray, disparity=not args.no_disparity, f_t=args.f_t,
                             s=args.units, sample_step=args.sample_step,
                             audio=AUDIO_FEATURES if args.audio else 0).check()  # --stride: via the settings
    except ValueError as ex:
        raise RvrError(f"--size/--f-t/--units/--sample-step: {ex}") from None
    set_torch_threads(args.threads)
    if not 0.0 <= args.depth_augment <= 1.0:
        raise RvrError(f"--depth-augment must be in [0, 1] (got {args.depth_augment})")
    if not 0.0 <= args.pos_fraction <= 1.0 or args.tolerance <= 0:
        raise RvrError(f"--pos-fraction must be in [0, 1] and --tolerance > 0 (got {args.pos_fraction}, "
                       f"{args.tolerance})")
    settings = AFNetTrainSettings(
        run_dir=args.output, data=list(args.data), annotations=list(args.annotations), iterations=args.iterations,
        lr=args.lr, batch=args.batch, weak_weight=args.weak_weight, w_map=args.w_map, w_nft=args.w_nft,
        pos_fraction=args.pos_fraction, tolerance=args.tolerance, checkpoint_every=args.checkpoint_every,
        seed=args.seed, resume=args.resume, model=config, init_from=args.init_from, stride=args.stride,
        threshold=args.threshold, depth_augment=args.depth_augment)
    trainer = AFNetTrainer(settings, progress=not args.quiet)
    print(f"training AF-Net ({trainer.model.parameter_count()} parameters, receptive field "
          f"{trainer.model.config.span} frames) on {trainer.report.summary()}", file=sys.stderr)
    run_training("train-afnet", trainer, args.output, args.quiet)
    print(f"wrote {args.output / 'afnet.pt'} ({trainer.iteration} iterations, {trainer.wall_time:.0f} s)")
    return 0
