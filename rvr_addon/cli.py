"""The ``rvr`` command line: ``rvr render INPUT --depth DEPTH ... -o OUT``, ``rvr render --demo``,
``rvr train --data DIR -o RUN_DIR``, ``rvr estimate INPUT -o CACHE``, ``rvr stabilize CACHE``,
``rvr eval-estimator --weights W --data HELDOUT -o REPORT``, ``rvr train-afnet --data DIR -o RUN_DIR``
and ``rvr batch CLIPS... -o OUT``."""
from __future__ import annotations

import argparse
import contextlib
import logging
import subprocess
import sys
from pathlib import Path
from typing import Any, Callable, Iterator

from . import __version__
from .errors import RvrError

log = logging.getLogger("rvr")

DEMO_DIR = Path("out/demo_scene")
DEMO_OUT = Path("out/demo_refocus.mp4")
DEMO_FRAMES = 48


class Interrupted(Exception):
    """Ctrl-C stopped a command that keeps its partial work: :func:`main` prints the message and
    returns 130 (raised by :func:`on_interrupt`)."""


@contextlib.contextmanager
def on_interrupt(command: str, message: Callable[[], str]) -> Iterator[None]:
    """Turn Ctrl-C inside the block into ``rvr COMMAND: message()`` on stderr and exit status 130.

    ``message`` is called after the interrupt, so it can say how far the job got.
    """
    try:
        yield
    except KeyboardInterrupt:
        raise Interrupted(f"rvr {command}: {message()}") from None


def set_torch_threads(threads: int | None) -> None:
    """``--threads N``: torch CPU threads (None: torch's choice). Raises RvrError below 1."""
    if threads is None:
        return
    if threads < 1:
        raise RvrError(f"--threads must be >= 1, got {threads}")
    import torch

    torch.set_num_threads(threads)


def add_run_args(p: argparse.ArgumentParser, iterations: int) -> None:
    """``-o RUN_DIR``, ``--iterations``, ``--resume``: the run folder of a resumable training run."""
    p.add_argument("-o", "--output", required=True, type=Path, metavar="RUN_DIR", help="run folder")
    p.add_argument("--iterations", type=int, default=iterations,
                   help=f"total iterations of the run (default {iterations})")
    p.add_argument("--resume", action="store_true", help="continue the run in RUN_DIR from its checkpoint")


def add_depth_method_args(p, note: str = "") -> None:
    """``--depth-method`` and ``--hfov`` (rvr estimate, rvr batch); ``note`` ends the first's help."""
    from .depth.methods import METHODS

    p.add_argument("--depth-method", choices=METHODS, default="auto",
                   help="where D comes from: auto (default: parallax where the camera translates, people layers "
                        "where there are people, the network elsewhere, fused), parallax, people, network (the "
                        "network alone) or external (--depth MAPS)" + note)
    p.add_argument("--hfov", type=float, metavar="DEG",
                   help="the camera's field of view in degrees across the frame's long side (the horizontal "
                        "one of a landscape clip, the vertical one of a portrait clip), for the geometric cues "
                        "(default: 66, a phone's main camera, refined from the clip where it moves)")


def add_run_control_args(p: argparse.ArgumentParser, checkpoint_every: int) -> None:
    """``--threads``, ``--checkpoint-every``, ``--seed`` of a training run."""
    p.add_argument("--threads", type=int, metavar="N",
                   help="torch CPU threads (default: torch's choice; 1 is much faster when other jobs share the cores)")
    p.add_argument("--checkpoint-every", type=int, default=checkpoint_every,
                   help="iterations between checkpoints and plots")
    p.add_argument("--seed", type=int, default=0, help="seed of the model init and the sample draws")


def run_training(command: str, trainer: Any, output: Path, quiet: bool) -> None:
    """``trainer.run()`` with a progress bar; Ctrl-C (checkpoint saved by the trainer) becomes the
    ``--resume`` hint and exit status 130."""
    with on_interrupt(command, lambda: f"interrupted at iteration {trainer.iteration}; checkpoint saved in "
                                       f"{output}; continue with the same command and --resume"):
        trainer.run(progress=not quiet)


def _aperture_spec(args: argparse.Namespace):
    from .render.aperture import ApertureSpec, load_kernel_image

    image = load_kernel_image(args.kernel_image) if args.shape == "image" else None
    if args.kernel_image and args.shape != "image":
        raise RvrError("--kernel-image needs --shape image")
    return ApertureSpec(shape=args.shape, blades=args.blades, rotation_deg=args.rotation,
                        squeeze=args.squeeze, kernel_image=image, cat_eye=args.cat_eye)


def add_device_arg(p: argparse.ArgumentParser) -> None:
    """``--device auto|cpu|cuda``: where the renderer runs (:mod:`.render.device`)."""
    from .render import DEVICE_HELP, DEVICES

    p.add_argument("--device", choices=DEVICES, default="auto", help=DEVICE_HELP)


def add_render_parser(sub) -> None:
    p = sub.add_parser("render", help="render shallow depth of field for a clip",
                       description="Render a shallow-DOF video from frames + a disparity sequence "
                                   "(+ an HDR exponent sequence) and a focus track or constants.")
    p.add_argument("input", nargs="?", type=Path, help="video file, image folder, glob or frame pattern")
    p.add_argument("--demo-cg", "--demo", dest="demo", action="store_true",
                   help="render the built-in CG demo: a Cycles scene with exact depth and HDR (rendered once "
                        f"into {DEMO_DIR}), rack focus from the subject to the background and back (the real "
                        "demo is `rvr refocus --demo`)")
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
    add_device_arg(p)
    p.add_argument("-o", "--output", action="append", type=Path, default=None,
                   help="output .mp4 or image folder (repeatable; a folder/frame_%%05d.exr pattern "
                        "writes linear EXR; a one-frame render may write one picture: OUT.jpg/.png/.tif/.exr)")
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
                          scale=args.scale, device=args.device)


def cmd_render(args: argparse.Namespace) -> int:
    from .pipeline import RenderJob, RenderSettings

    if args.demo:
        settings = demo_settings(args)
    else:
        if args.input is None or args.depth is None:
            raise RvrError("rvr render needs INPUT and --depth DEPTH (or --demo-cg); to refocus a clip in one "
                           "command, use `rvr refocus CLIP -o OUT.mp4`; see rvr render --help")
        if not args.output:
            raise RvrError("no output: add -o OUT.mp4 (and/or -o FRAMES_DIR)")
        settings = RenderSettings(
            input=args.input, depth=args.depth, hdr=args.hdr, outputs=args.output, focus=args.focus,
            aperture=args.aperture, track=args.track, spec=_aperture_spec(args),
            depth_scale=args.depth_scale, depth_offset=args.depth_offset, naive=args.naive,
            start=args.start, stop=args.stop, fps=args.fps, keep_audio=not args.no_audio,
            min_layers=args.min_layers, scale=args.scale, device=args.device)
    job = RenderJob(settings)
    job.run(progress=not args.quiet)
    for out in settings.outputs:
        print(f"wrote {out}")
    return 0


def add_train_parser(sub) -> None:
    from .estimate.loss_weights import LossWeights

    p = sub.add_parser("train", help="train the RGBD-HDR estimator (disparity + HDR from one frame)",
                       description="Train the RGBD-HDR estimator through the differentiable renderer (paper "
                                   "section 4.1) on harness clips, procedural scenes and/or your own "
                                   "aperture-bracketed photos. "
                                   "Resumable (--resume), with a progress bar, loss_log.csv and loss.png in the "
                                   "run folder; writes RUN_DIR/estimator.pt at the end.")
    p.add_argument("--data", action="append", type=Path, default=[], metavar="DIR",
                   help="a folder of harness clips (`python -m sintel_eval generate`) and/or procedural datasets "
                        "(`rvr procedural`) (repeatable)")
    p.add_argument("--real", action="append", type=Path, default=[], metavar="DIR",
                   help="real pictures with measured depth (a real_depth folder: Middlebury, Kinect; D supervised up "
                        "to scale and shift, E kept near the --init-from weights' own) (repeatable)")
    p.add_argument("--real-exclude", action="append", default=[], metavar="SCENE",
                   help="leave this scene of --real out (e.g. middlebury2006/Aloe or Aloe; repeatable): "
                        "leave-scene-out validation")
    p.add_argument("--real-share", type=float, default=0.5, metavar="P",
                   help="share of draws from --real pictures when there are other sources too (default 0.5)")
    p.add_argument("--hdr-teacher", type=Path, metavar="WEIGHTS",
                   help="weights whose HDR output E the real pictures keep (default: --init-from)")
    p.add_argument("--user-photos", action="append", type=Path, default=[], metavar="DIR",
                   help="folder of bracketed photos: NAME_small.jpg + NAME_large.jpg [+ NAME_medium.jpg] "
                        "[+ NAME.json], or one sub-folder per shot (repeatable)")
    add_run_args(p, iterations=20000)
    p.add_argument("--lr", type=float, default=1e-4, help="Adam learning rate (paper: 1e-4)")
    p.add_argument("--batch", type=int, default=1, help="samples per step (paper: 1)")
    p.add_argument("--crop", type=int, default=128, help="training crop side in px (default 128)")
    p.add_argument("--min-scale", type=float, default=0.5, help="smallest random resize factor (default 0.5)")
    p.add_argument("--whole-frame", type=float, default=0.5, metavar="P",
                   help="share of samples that are whole frames shrunk to about crop^2 px instead of crops, as the "
                        "paper trained and as inference sees them (default 0.5)")
    p.add_argument("--gt-share", type=float, default=0.5, metavar="P",
                   help="share of draws from ground-truth-only harness frames (clips generated with --no-dof: "
                        "the supervised terms alone) when there are also frames with shallow-DOF images "
                        "(default 0.5)")
    p.add_argument("--procedural-share", type=float, default=0.5, metavar="P",
                   help="share of draws from procedural frames (folders written by `rvr procedural`, D supervised "
                        "up to scale and shift) when --data also holds harness clips or --user-photos are given "
                        "(default 0.5)")
    p.add_argument("--degrade", type=float, default=0.0, metavar="P",
                   help="share of ground-truth-only samples (harness --no-dof clips, procedural frames) whose input "
                        "is degraded like phone footage (blur, sensor noise, JPEG) while the targets stay exact "
                        "(default 0)")
    p.add_argument("--expose", type=float, default=0.0, metavar="P",
                   help="share of ground-truth-only samples given another white balance and a brighter exposure "
                        "(0-1 stop; the input is clipped again, the HDR target follows) (default 0)")
    p.add_argument("--inference-max-pixels", type=int, metavar="P",
                   help="record in the weights that inference runs the network's trunk on frames shrunk to at "
                        "most P pixels (the scale it was trained at; D is sliced and E gated at full size); "
                        "default: full size")
    p.add_argument("--vgg19", type=Path, metavar="PATH",
                   help="local VGG-19 state dict (torchvision layout) for the paper's perceptual loss")
    p.add_argument("--init-from", type=Path, metavar="WEIGHTS",
                   help="start a new run from these estimator weights (estimator.pt or a checkpoint.pt) instead "
                        "of a random init; their architecture is kept")
    p.add_argument("--row-prior", action="store_true",
                   help="give the disparity head the row coordinate (lets the network learn that the floor is "
                        "nearer toward the bottom of the frame); with --init-from it is added, zero-initialised, "
                        "to weights without it")
    p.add_argument("--train-only", choices=("all", "disparity-head"), default="all",
                   help="which parameters learn: all (default), or the disparity head alone (the 1x1 conv to the "
                        "bilateral grid and its row column): the HDR output E stays bit-identical to --init-from's")
    p.add_argument("--ignore-prints", action="store_true",
                   help="no disparity supervision on the harness's photo prints (billboards, poster panels: "
                        "photographs of real scenes on flat boards), which teach that a photographed scene is flat")
    p.add_argument("--grad-clip", type=float, default=1.0, metavar="N",
                   help="clip the gradient's norm at N before each Adam step (default 1.0; a small N makes every "
                        "step the same size, which fits the few real pictures of --real faster)")
    p.add_argument("--w-smooth", type=float, default=10.0, help="smoothness weight w1 (paper: 10)")
    sup = LossWeights()
    p.add_argument("--supervised-weight", type=float, default=sup.supervised, metavar="W",
                   help="weight of the supervised ground-truth terms on harness frames (ours, not the paper's; "
                        f"photos have none); 0 = the paper's loss alone (default {sup.supervised:g})")
    p.add_argument("--w-disparity", type=float, default=sup.sup_disparity,
                   help=f"within them: L1 of D in %% of the frame width (default {sup.sup_disparity:g})")
    p.add_argument("--w-disparity-grad", type=float, default=sup.sup_disparity_grad,
                   help=f"multi-scale gradient matching of D (default {sup.sup_disparity_grad:g})")
    p.add_argument("--w-exponent", type=float, default=sup.sup_exponent,
                   help=f"L1 of 50 E on saturated pixels (default {sup.sup_exponent:g})")
    p.add_argument("--w-exponent-zero", type=float, default=sup.sup_exponent_zero,
                   help=f"pull of E toward 0 on unsaturated pixels (default {sup.sup_exponent_zero:g})")
    p.add_argument("--disparity-invariant", action="store_true",
                   help="supervise D only up to a per-sample least-squares scale and shift (MiDaS-style)")
    add_run_control_args(p, checkpoint_every=500)
    p.add_argument("--photo-max-side", type=int, default=1024, help="bracketed photos are downscaled to this")
    p.add_argument("--align", choices=("homography", "affine", "euclidean", "translation"), default="homography",
                   help="ECC motion model for bracketed photos (default homography)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_train)


def cmd_train(args: argparse.Namespace) -> int:
    from .estimate.losses import LossWeights
    from .estimate.train import Trainer, TrainSettings
    from .estimate.unet import EstimatorConfig

    if not 0 < args.min_scale <= 1:
        raise RvrError(f"--min-scale must be in (0, 1], got {args.min_scale}")
    if not args.grad_clip > 0:
        raise RvrError(f"--grad-clip must be > 0, got {args.grad_clip}")
    sup = (args.supervised_weight, args.w_disparity, args.w_disparity_grad, args.w_exponent, args.w_exponent_zero)
    if min(sup) < 0:
        raise RvrError(f"--supervised-weight and the --w-* weights must be >= 0, got {sup}")
    set_torch_threads(args.threads)
    weights = LossWeights(smooth=args.w_smooth, supervised=args.supervised_weight, sup_disparity=args.w_disparity,
                          sup_disparity_grad=args.w_disparity_grad, sup_exponent=args.w_exponent,
                          sup_exponent_zero=args.w_exponent_zero, disparity_invariant=args.disparity_invariant)
    settings = TrainSettings(
        run_dir=args.output, data=args.data, user_photos=args.user_photos, iterations=args.iterations,
        lr=args.lr, batch=args.batch, crop=args.crop, scale_range=(args.min_scale, 1.0), vgg19=args.vgg19,
        whole_frame=args.whole_frame, weights=weights, checkpoint_every=args.checkpoint_every, seed=args.seed,
        resume=args.resume, photo_max_side=args.photo_max_side, align_motion=args.align, gt_share=args.gt_share,
        procedural_share=args.procedural_share, degrade=args.degrade, expose=args.expose,
        inference_max_pixels=args.inference_max_pixels, init_from=args.init_from, ignore_prints=args.ignore_prints,
        model=EstimatorConfig(row_prior=args.row_prior), real=args.real, real_exclude=tuple(args.real_exclude),
        real_share=args.real_share, hdr_teacher=args.hdr_teacher, grad_clip=args.grad_clip,
        train_only=args.train_only)
    trainer = Trainer(settings, progress=not args.quiet)
    print(f"training on {trainer.data.summary()}; {trainer.report.summary()}", file=sys.stderr)
    run_training("train", trainer, args.output, args.quiet)
    if trainer.report.total:
        print(f"rvr train: {trainer.report.summary()} (see the warnings above)", file=sys.stderr)
    print(f"wrote {args.output / 'estimator.pt'} ({trainer.iteration} iterations, {trainer.wall_time:.0f} s)")
    return 0


def add_procedural_parser(sub) -> None:
    p = sub.add_parser("procedural", help="write procedural training scenes for the estimator (rooms, streets, "
                                          "close-ups)",
                       description="Ray-cast random rooms, streets and close-ups textured with pieces of real "
                                   "photographs "
                                   "and write them as a training dataset for `rvr train --data DIR`: input PNG, "
                                   "ground-truth disparity and HDR per frame (under 1 s a frame on one core). "
                                   "Resumable: frames already written are kept; a larger --frames extends it.")
    p.add_argument("-o", "--output", required=True, type=Path, metavar="DIR", help="dataset folder")
    p.add_argument("--frames", type=int, default=2000, help="number of frames (default 2000)")
    p.add_argument("--seed", type=int, default=1, help="dataset seed: frame i is drawn from (seed, i) (default 1)")
    p.add_argument("--generator", type=int, default=None, metavar="VERSION",
                   help="generator version (default: the latest; 2 = rooms and streets only, as the shipped "
                        "weights' older dataset)")
    p.add_argument("--textures", action="append", type=Path, default=[], metavar="DIR",
                   help="folder of photographs (png/jpg, recursively) to cut material textures from (repeatable); "
                        "scikit-image's sample photographs are always added (never the Motorcycle pair)")
    p.add_argument("--workers", type=int, default=1, metavar="N",
                   help="render in N processes (one per core; the frames are the same) (default 1)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_procedural)


def cmd_procedural(args: argparse.Namespace) -> int:
    from .estimate.procedural import GENERATOR_VERSION, TexturePool, texture_paths, write_dataset

    if args.frames < 1 or args.workers < 1:
        raise RvrError(f"--frames and --workers must be at least 1, got {args.frames} and {args.workers}")
    pool = TexturePool.from_paths(texture_paths(args.textures))
    if not pool.images:
        print("rvr procedural: no photographs found (install scikit-image or pass --textures DIR); "
              "using procedural textures only", file=sys.stderr)
    made = write_dataset(args.output, args.frames, args.seed, pool, progress=not args.quiet,
                         version=args.generator or GENERATOR_VERSION, workers=args.workers)
    print(f"wrote {made} frames to {args.output} ({args.frames} in all, {len(pool.images)} photographs)")
    return 0


def _depth_point(text: str):
    from .estimate.infer import parse_point

    try:
        return parse_point(text)
    except RvrError as ex:
        raise argparse.ArgumentTypeError(str(ex)) from None


def add_estimate_parser(sub) -> None:
    p = sub.add_parser("estimate", help="estimate disparity D and HDR E per frame into a cache folder",
                       description="Estimate D (disparity, DESIGN units) and E (HDR exponent) for every frame "
                                   "and write the per-clip cache (one EXR per frame + meta.json). Resumable: "
                                   "frames already cached for the same model and source are kept.")
    p.add_argument("input", type=Path, help="video file, image folder, glob or frame pattern")
    p.add_argument("-o", "--output", required=True, type=Path, metavar="CACHE", help="cache folder")
    p.add_argument("--weights", type=Path, help="estimator weights (RUN_DIR/estimator.pt from rvr train)")
    p.add_argument("--depth", type=Path, help="external depth/disparity maps (EXR/PNG/NPY file, folder or pattern) "
                                              "used for D instead of the network")
    p.add_argument("--depth-scale", type=float, default=1.0, help="D = scale * map + offset")
    p.add_argument("--depth-offset", type=float, default=0.0, help="D = scale * map + offset")
    p.add_argument("--depth-points", type=_depth_point, nargs=2, metavar="X,Y,D",
                   help="fit scale and offset so that pixel (X, Y) of the first frame gets disparity D (two points)")
    p.add_argument("--depth-is-distance", action="store_true",
                   help="the maps hold distance (larger = farther): use 1/map before the affine")
    p.add_argument("--no-hdr", action="store_true", help="with --depth: E = 0 (no network needed)")
    add_depth_method_args(p)
    p.add_argument("--start", type=int, default=0, help="first frame (0-based)")
    p.add_argument("--stop", type=int, help="stop before this frame")
    p.add_argument("--fps", type=float, help="frame rate of an image-sequence input (default 24)")
    p.add_argument("--max-pixels", type=int, metavar="P",
                   help="run the network's trunk on copies shrunk to at most P pixels (D sliced and E gated at "
                        "full size); default: the size the weights were trained for")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_estimate)


def cmd_estimate(args: argparse.Namespace) -> int:
    from .estimate.infer import EstimateJob, EstimateSettings

    if args.max_pixels is not None and args.max_pixels < 1:
        raise RvrError(f"--max-pixels {args.max_pixels}: give a positive number of pixels, e.g. 230400 (640x360)")
    job = EstimateJob(EstimateSettings(
        input=args.input, output=args.output, weights=args.weights, depth=args.depth, depth_scale=args.depth_scale,
        depth_offset=args.depth_offset, depth_points=list(args.depth_points or []),
        depth_is_distance=args.depth_is_distance, no_hdr=args.no_hdr, start=args.start, stop=args.stop,
        fps=args.fps, max_pixels=args.max_pixels, depth_method=args.depth_method, hfov_deg=args.hfov))
    print(job.plan.summary())
    with on_interrupt("estimate", lambda: f"stopped after {job.done} of {job.total} frames; {job.kept()}; run the "
                                          "same command again to continue"):
        job.run(progress=not args.quiet)
    print(f"wrote {args.output} ({job.text})")
    return 0


def add_eval_estimator_parser(sub) -> None:
    p = sub.add_parser("eval-estimator", help="score estimator weights against ground truth (harness, Middlebury)",
                       description="Run estimator weights on held-out harness clips (GT disparity and HDR) and/or "
                                   "the Middlebury 2014 motorcycle view shipped with scikit-image, and write a report "
                                   "folder: summary.json (estimate.* keys), README.md and comparison PNGs.")
    p.add_argument("--weights", type=Path, help="estimator weights (RUN_DIR/estimator.pt; default: the shipped ones)")
    p.add_argument("--data", action="append", type=Path, default=[], metavar="DIR",
                   help="held-out harness dataset (clips NOT used for training; repeatable)")
    p.add_argument("--motorcycle", action="store_true", help="also score the Middlebury 2014 motorcycle view")
    p.add_argument("--real", nargs=2, action="append", type=Path, default=[], metavar=("IMAGE", "DISPARITY"),
                   help="also score a real picture against its ground truth: a disparity or inverse-depth map "
                        "(EXR/PNG/NPY/NPZ, <= 0 = unknown) of that view; keys estimate.real.<image stem>.* "
                        "(repeatable)")
    p.add_argument("-o", "--output", required=True, type=Path, metavar="REPORT", help="report folder")
    p.add_argument("--max-frames", type=int, metavar="N", help="at most N frames per clip")
    p.add_argument("--every", type=int, default=1, metavar="K", help="every K-th frame of a clip (default 1)")
    p.add_argument("--compare-frames", type=int, default=3, metavar="K", help="comparison PNGs (default 3)")
    p.add_argument("--max-pixels", type=int, metavar="P",
                   help="run the network on copies shrunk to at most P pixels (D sliced, E gated at full size); "
                        "to match the resolution it was trained at")
    p.add_argument("--real-set", type=Path, metavar="DIR",
                   help="score every real picture with measured depth under DIR (../shared/data/real_depth: "
                        "Middlebury 2006/2001-3, Kinect); keys estimate.real.<set>.*")
    p.add_argument("--depth-method", choices=("network", "auto", "people"), default="network",
                   help="depth of single pictures (--real-set, --real, --motorcycle, --aperture): network (the "
                        "estimator alone, default) or auto/people (people + network, rvr_addon.depth)")
    p.add_argument("--weights-per-scene", type=Path, metavar="JSON",
                   help="with --real-set: JSON {scene: weights file} (leave-scene-out fold models; other scenes "
                        "use --weights)")
    p.add_argument("--real-video", action="append", type=Path, default=[], metavar="DIR",
                   help="score the depth system on a real RGB-D clip with poses (HoloLens / TUM layout, "
                        "../shared/data/real_video_depth/...); keys estimate.video.<clip>.<method>.* (repeatable)")
    p.add_argument("--depth-methods", default="auto,network", metavar="M,M",
                   help="with --real-video: depth methods as in rvr estimate --depth-method (default auto,network); "
                        "M+centred / M+causal: M's D after rvr stabilize with that window (what rvr refocus renders)")
    p.add_argument("--video-frames", type=int, metavar="N", help="with --real-video: at most N frames a clip")
    p.add_argument("--hfov", type=float, metavar="DEG",
                   help="field of view for the geometric cues, as rvr estimate --hfov (default: its default)")
    p.add_argument("--aperture", type=Path, metavar="DIR",
                   help="fit our renderer to real wide-aperture photos (../shared/data/real_depth/aperture: "
                        "<scene>/input.jpg + 1_8.jpg or target.jpg) beside a Gaussian blur; keys estimate.aperture.*")
    p.add_argument("--aperture-size", type=int, default=512, metavar="PX",
                   help="with --aperture: long side the photos are shrunk to (default 512)")
    p.add_argument("--force", action="store_true", help="replace an existing report folder")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_eval_estimator)


def cmd_eval_estimator(args: argparse.Namespace) -> int:
    import json

    from .estimate.evaluate import EvalSettings, evaluate

    if (args.max_frames is not None and args.max_frames < 1) or args.every < 1 or args.compare_frames < 0 \
            or (args.max_pixels is not None and args.max_pixels < 1):
        raise RvrError("--max-frames, --every and --max-pixels must be >= 1, --compare-frames >= 0")
    if (args.video_frames is not None and args.video_frames < 2) or args.aperture_size < 32:
        raise RvrError("--video-frames must be >= 2 and --aperture-size >= 32")
    methods = [m.strip() for m in args.depth_methods.split(",") if m.strip()]
    summary = evaluate(EvalSettings(output=args.output, weights=args.weights, data=list(args.data),
                                    motorcycle=args.motorcycle, max_frames=args.max_frames, every=args.every,
                                    compare_frames=args.compare_frames, force=args.force,
                                    max_pixels=args.max_pixels, real=[tuple(p) for p in args.real],
                                    real_set=args.real_set, depth_method=args.depth_method,
                                    weights_per_scene=args.weights_per_scene, real_video=list(args.real_video),
                                    depth_methods=methods, video_frames=args.video_frames, hfov_deg=args.hfov,
                                    aperture=args.aperture, aperture_size=args.aperture_size),
                       progress=not args.quiet)
    print(json.dumps(summary, indent=1, sort_keys=True))
    print(f"wrote {args.output}")
    return 0


class RvrArgumentParser(argparse.ArgumentParser):
    """The ``rvr`` parser: an option no sub-command knows (``rvr render --aperturee 2``) is reported by
    that sub-command's parser, with its usage and the closest option it has ("did you mean
    --aperture?"), instead of the top-level usage that plain argparse prints."""

    def parse_args(self, args=None, namespace=None):
        ns, extras = self.parse_known_args(args, namespace)
        if extras:
            parser = self._subcommand_parser(ns) or self
            parser.error(unrecognized_message(parser, extras))
        return ns

    def _subcommand_parser(self, ns: argparse.Namespace) -> argparse.ArgumentParser | None:
        for action in self._actions:
            if isinstance(action, argparse._SubParsersAction):
                return action.choices.get(getattr(ns, action.dest, None) or "")
        return None


def unrecognized_message(parser: argparse.ArgumentParser, extras: list[str]) -> str:
    """``unrecognized arguments: --aperturee; did you mean --aperture?`` (difflib over ``parser``'s
    option strings; no suggestion when nothing is close)."""
    import difflib

    options = [o for action in parser._actions for o in action.option_strings]
    hints = []
    for arg in extras:
        if not arg.startswith("-") or arg == "-":
            continue
        flag = arg.split("=", 1)[0]
        close = difflib.get_close_matches(flag, options, n=1)
        if close:
            hints.append((flag, close[0]))
    text = f"unrecognized arguments: {' '.join(extras)}"
    if len(hints) == 1:
        text += f"; did you mean {hints[0][1]}?"
    elif hints:
        text += "; did you mean " + ", ".join(f"{match} (for {flag})" for flag, match in hints) + "?"
    return text


def build_parser() -> argparse.ArgumentParser:
    parser = RvrArgumentParser(prog="rvr", description="RVR-LAAF: refocusable video rendering.")
    parser.add_argument("--version", action="version", version=f"rvr {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    from .refocus.commands import add_parser as add_refocus_parser

    add_refocus_parser(sub)  # rvr refocus: the whole pipeline, listed first
    add_render_parser(sub)
    add_train_parser(sub)
    add_procedural_parser(sub)
    add_estimate_parser(sub)
    add_eval_estimator_parser(sub)
    from .laaf.commands import add_parsers as add_laaf_parsers

    add_laaf_parsers(sub)  # rvr autofocus, rvr eval-focus
    from .afnet.commands import add_parser as add_train_afnet_parser

    add_train_afnet_parser(sub)  # rvr train-afnet
    from .temporal.commands import add_parser as add_stabilize_parser

    add_stabilize_parser(sub)  # rvr stabilize
    from .batch.commands import add_parser as add_batch_parser

    add_batch_parser(sub)  # rvr batch
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``rvr`` console script; returns the exit status."""
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    args = build_parser().parse_args(argv)
    from .interrupts import exit_status, sigterm_as_interrupt, terminated

    with sigterm_as_interrupt():  # SIGTERM cleans up like Ctrl-C (temp files, ffmpeg children); exit 143
        try:
            return args.func(args)
        except RvrError as ex:
            print(f"rvr: error: {ex}", file=sys.stderr)
            return 2
        except Interrupted as ex:
            print(f"{ex}{' (SIGTERM)' if terminated() else ''}", file=sys.stderr)
            return exit_status()
        except KeyboardInterrupt:
            how = "terminated (SIGTERM)" if terminated() else "cancelled"
            print(f"rvr: {how}; partial outputs removed", file=sys.stderr)
            return exit_status()
        except OSError as ex:  # a write path without its own message (disk full, read-only): no traceback
            log.debug("rvr %s failed", getattr(args, "command", ""), exc_info=True)
            name = f" '{ex.filename}'" if getattr(ex, "filename", None) else ""
            print(f"rvr: error:{name} {ex.strerror or ex}; check that the output location is writable and has free "
                  "space (or choose another one); earlier results are kept", file=sys.stderr)
            return 2


if __name__ == "__main__":
    sys.exit(main())
