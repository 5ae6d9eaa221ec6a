"""Training of the RGBD-HDR estimator through the differentiable renderer (paper section 4.1).

:class:`Trainer` is a stepwise job (``step()`` / ``progress`` / ``cancel()``, like
:class:`rvr_addon.pipeline.RenderJob`); ``rvr train`` runs it with a progress bar. One
iteration draws ``batch`` samples (paper: 1), predicts D and E, renders every target through
:func:`rvr_addon.render.torch_render.render_torch` and takes one Adam step (lr 1e-4, paper) on
the mean of eq. 7 over the batch (plus, on harness samples, ``w_sup`` times the supervised
ground-truth terms of :mod:`.losses`, ours; ``--supervised-weight 0`` is the paper's loss), its
gradient norm clipped at ``grad_clip`` (1.0; the log records the norm before clipping). Clipping is ours, not the paper's: the gradient through the
renderer is spiky (on the test scenes a median norm of 1-5 with single steps above 30).

The run folder holds:

```
checkpoint.pt     latest state: model, Adam, iteration, numpy + torch RNG, wall time
                  (atomic: written to a temp name, then renamed; every --checkpoint-every
                  iterations, at the end and on Ctrl-C)
loss_log.csv      one row per iteration (total, its terms, the supervised terms, D error vs the
                  ground truth, resident memory, the sample drawn; LOG_FIELDS)
loss.png          the loss curves (refreshed with every checkpoint)
run.json          settings and the training-data summary of the latest start
estimator.pt      exported weights at the end: {"format", "header" (JSON text), "state_dict"}
estimator.json    the same header, for people (architecture, data, iterations, wall time)
photos/           the user's bracketed photos, aligned and downscaled (reused on resume)
```

``--resume`` continues from ``checkpoint.pt`` exactly where it stopped (same samples, same
result as an uninterrupted run); rows of the log past the checkpoint are dropped.
"""
from __future__ import annotations

import csv
import json
import time
import logging
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np
import torch

from .. import __version__
from ..color import srgb_to_linear
from ..errors import InputError, RvrError
from ..render.aperture import ApertureSpec
from ..render.model import K_HDR, hdr_radiance
from ..training_run import TrainingRun, previous_init_record, save_png, save_weights
from ..training_run import deferred_interrupt  # noqa: F401 - re-exported: callers import it from here
from .data import Augment, SkipReport, TrainingSet, TrainSample, photo_sources, real_sources, training_sources
from .losses import (
    LossResult, LossWeights, VGG19Features, exponent_keep_loss, fit_scale_shift, load_vgg19, render_member,
    supervised_loss, to_display, total_loss,
)
from .unet import DISPARITY_PERCENT, EstimatorConfig, EstimatorNet, clip_gate, disparity_to_px, grow_state_dict

TRAIN_ONLY = {"all": None, "disparity-head": "grid_head."}
"""``--train-only`` choices: the prefix of the parameters that learn (None: all of them)."""
CHECKPOINT_FORMAT = "rvr-laaf-estimator-checkpoint/1"
WEIGHTS_FORMAT = "rvr-laaf-estimator/1"
log = logging.getLogger(__name__)
LOG_FIELDS = ("iteration", "wall_s", "total", "rend", "adjust", "smooth", "pix", "ssim", "grad", "vgg", "grad_norm",
              "kind", "sample", "sup", "sup_d", "sup_dgrad", "sup_e", "sup_e0", "sup_keep", "d_rms_px", "d_corr",
              "rss_mb")
"""Columns of loss_log.csv. ``sup*``: the supervised terms (blank for samples without ground
truth; ``sup_keep``: the HDR teacher term of real pictures); ``d_rms_px``: RMS of D - D_gt in px at the native width and ``d_corr`` their Pearson
correlation (monitoring only, no gradient; harness samples); ``rss_mb``: the process's resident
memory after the step (MiB; a leak shows as a rising column)."""


@dataclass
class TrainSettings:
    """Everything ``rvr train`` takes (see ``rvr train --help``)."""

    run_dir: Path
    data: list[Path] = field(default_factory=list)
    user_photos: list[Path] = field(default_factory=list)
    iterations: int = 20000
    lr: float = 1e-4
    batch: int = 1
    crop: int = 128
    scale_range: tuple[float, float] = (0.5, 1.0)
    whole_frame: float = 0.5
    """Share of samples that are whole frames shrunk to ~crop**2 px (:class:`.data.Augment`)."""
    gt_share: float = 0.5
    """Share of draws from ground-truth-only frames (kind ``gt``) when there are also rendered ones."""
    procedural_share: float = 0.5
    """Share of draws from procedural frames (``rvr procedural``) when there are other sources too."""
    degrade: float = 0.0
    """Probability that a ground-truth-only sample's input is degraded like phone footage."""
    expose: float = 0.0
    """Probability that a ground-truth-only sample gets another white balance and exposure."""
    inference_max_pixels: int | None = None
    """Written into the weights' header: the trunk size inference uses by default (None: full size)."""
    vgg19: Path | None = None
    weights: LossWeights = field(default_factory=LossWeights)
    checkpoint_every: int = 500
    grad_clip: float = 1.0
    seed: int = 0
    resume: bool = False
    photo_max_side: int = 1024
    align_motion: str = "homography"
    model: EstimatorConfig = field(default_factory=EstimatorConfig)
    ignore_prints: bool = False
    """Leave the harness's photo prints out of the disparity supervision (:mod:`.data`)."""
    real: list[Path] = field(default_factory=list)
    """Folders of real pictures with measured depth (:mod:`.real_data`; ``--real``)."""
    real_exclude: tuple[str, ...] = ()
    """Scenes of ``real`` left out (leave-scene-out validation; ``--real-exclude``)."""
    real_share: float = 0.5
    """Share of draws from real pictures when there are other sources too (``--real-share``)."""
    hdr_teacher: Path | None = None
    """Weights whose E real pictures keep (they have no HDR truth); None with ``real``: ``init_from``."""
    init_from: Path | None = None
    """A new run starts from these weights (estimator.pt or a checkpoint) instead of a random init;
    its architecture is theirs, with ``model.row_prior`` switched on if asked (zero-initialised)."""
    train_only: str = "all"
    """Which parameters learn: ``all``, or ``disparity-head`` (the grid head alone, the 1x1 conv from
    the 1/8 decoder level to the bilateral grid, plus its row-prior column): every layer E depends on
    stays frozen, so the HDR output is bit-identical to the starting weights' (``TRAIN_ONLY``)."""


def sample_loss(model: EstimatorNet, sample: TrainSample, weights: LossWeights,
                vgg: VGG19Features | None = None, spec: ApertureSpec | None = None,
                teacher: EstimatorNet | None = None) -> LossResult:
    """Eq. 7 for one drawn sample: predict, render the target(s) through our model, compare.

    The network's D_rel becomes px at the working resolution with the sample's frame width
    (L_smooth takes D as a fraction of that width, see :mod:`.losses`); the radiance is ``srgb_to_linear(I) * exp(50 E)`` (eq. 3); each target is rendered with
    its own ``alpha * D + beta`` and compared in display sRGB.
    """
    image = torch.from_numpy(sample.image).permute(2, 0, 1)[None]
    out = model(image)
    d_px = disparity_to_px(out.disparity_rel, sample.frame_width)
    if sample.kind == "gt":  # a ground-truth-only frame: the supervised terms alone (no render)
        return _supervised_only(model, out, sample, weights, image if teacher is not None else None, teacher)
    radiance = hdr_radiance(srgb_to_linear(image), out.exponent)
    target = torch.from_numpy(sample.target).permute(2, 0, 1)[None]
    rendered = to_display(render_member(radiance, d_px, sample.alpha, sample.beta, spec))
    adjusted = None
    if sample.adjusted is not None:
        third, alpha, beta = sample.adjusted
        adjusted = (to_display(render_member(radiance, d_px, alpha, beta, spec)),
                    torch.from_numpy(third).permute(2, 0, 1)[None])
    result = total_loss(rendered, target, d_px / sample.frame_width, image, adjusted, weights, vgg)
    if sample.gt_disparity is None and sample.gt_exponent is None:
        return result
    gt_d = gt_e = sat = None
    if sample.gt_disparity is not None:  # px at the working width -> D_rel (percent of it)
        gt_d = torch.from_numpy(sample.gt_disparity)[None, None] * (DISPARITY_PERCENT / sample.frame_width)
        result.parts.update(disparity_metrics(out.disparity_rel.detach(), gt_d, sample.frame_width,
                                              sample.native_width))
    if sample.gt_exponent is not None and sample.saturated is not None:
        gt_e = torch.from_numpy(sample.gt_exponent).permute(2, 0, 1)[None]
        sat = torch.from_numpy(sample.saturated)[None, None]
    if weights.supervised > 0:
        sup = supervised_loss(out.disparity_rel, gt_d, out.exponent, gt_e, sat, model.config.e_max, weights)
        total = result.total + weights.supervised * sup.total
        result.parts.update(sup.parts)
        result.parts["total"] = total.item()
        result = LossResult(total, result.parts)
    return result


def _supervised_only(model: EstimatorNet, out, sample: TrainSample, weights: LossWeights,
                     image: torch.Tensor | None = None, teacher: EstimatorNet | None = None) -> LossResult:
    """Loss of a kind-``gt`` sample: ``w_sup`` times the supervised terms (see :mod:`.losses`).

    A sample without HDR ground truth (a real picture) gets no E terms; with a ``teacher`` (the
    frozen weights the run started from) and the sample's ``image``, its E is kept near the
    teacher's instead (:func:`.losses.exponent_keep_loss`, weight ``w_sup``)."""
    if weights.supervised <= 0:
        raise InputError(f"sample {sample.name} has ground truth only (a clip without training sidecars), which "
                         "needs --supervised-weight > 0; raise it or leave such clips out of --data")
    gt_d = torch.from_numpy(sample.gt_disparity)[None, None] * (DISPARITY_PERCENT / sample.frame_width)
    gt_e = sat = None
    if sample.gt_exponent is not None and sample.saturated is not None:
        gt_e = torch.from_numpy(sample.gt_exponent).permute(2, 0, 1)[None]
        sat = torch.from_numpy(sample.saturated)[None, None]
    sup = supervised_loss(out.disparity_rel, gt_d, out.exponent, gt_e, sat, model.config.e_max, weights,
                          scale_free=sample.disparity_invariant)
    parts = dict(sup.parts)
    total = sup.total
    if gt_e is None and teacher is not None and image is not None:
        with torch.no_grad():
            kept = teacher(image).exponent
        cfg = model.config
        keep = exponent_keep_loss(out.exponent, kept, clip_gate(image, cfg.gate_lo, cfg.gate_hi))
        total = total + keep
        parts["sup_keep"] = keep.item()
    parts.update(disparity_metrics(out.disparity_rel.detach(), gt_d, sample.frame_width, sample.native_width,
                                   fitted=sample.disparity_invariant))
    total = weights.supervised * total
    parts["total"] = total.item()
    return LossResult(total, parts)


def disparity_metrics(disparity_rel: torch.Tensor, gt_rel: torch.Tensor, frame_width: float,
                      native_width: float | None, fitted: bool = False) -> dict[str, float]:
    """Monitoring figures of a predicted D against the ground truth (no gradient).

    disparity_rel, gt_rel: (1, 1, H, W) D in percent of the frame width (gt NaN where unknown).
    Returns ``d_rms_px``: RMS of D - D_gt in px at ``native_width`` (DESIGN units; the working
    width when None; after the least-squares scale and shift if ``fitted``, for ground truth known
    only up to them), and ``d_corr``: their Pearson correlation (0 when either is flat).
    """
    mask = torch.isfinite(gt_rel)
    if not bool(mask.any()):
        return {}
    if fitted:
        s, t = fit_scale_shift(disparity_rel, torch.where(mask, gt_rel, torch.zeros_like(gt_rel)), mask)
        disparity_rel = s * disparity_rel + t
    p, g = disparity_rel[mask].double(), gt_rel[mask].double()
    width = float(native_width or frame_width)
    rms = float(((p - g) ** 2).mean().sqrt()) * width / DISPARITY_PERCENT
    pc, gc = p - p.mean(), g - g.mean()
    den = float((pc.pow(2).sum() * gc.pow(2).sum()).sqrt())
    return {"d_rms_px": rms, "d_corr": float((pc * gc).sum()) / den if den > 0 else 0.0}


class Trainer(TrainingRun):
    """A resumable training run (see the module docstring)."""

    checkpoint_format = CHECKPOINT_FORMAT
    log_fields = LOG_FIELDS
    weights_name = "estimator.pt"
    bar_desc = "train"
    run_noun = "a training run"
    checkpoint_noun = "an estimator training checkpoint"
    settings: TrainSettings

    def __init__(self, settings: TrainSettings, progress: bool = False) -> None:
        s = self.settings = settings
        if not s.data and not s.user_photos and not s.real:
            raise InputError("no training data: pass --data DATASET (harness clips), --real DIR (real pictures with "
                             "measured depth, e.g. ../shared/data/real_depth) and/or --user-photos DIR")
        if not 0.0 <= s.real_share <= 1.0:
            raise InputError(f"real_share (--real-share) is a probability in [0, 1], got {s.real_share}")
        if not 0.0 <= s.whole_frame <= 1.0:
            raise InputError(f"whole_frame (--whole-frame) is a probability in [0, 1], got {s.whole_frame}")
        if not 0.0 <= s.gt_share <= 1.0:
            raise InputError(f"gt_share (--gt-share) is a probability in [0, 1], got {s.gt_share}")
        for flag, value in (("degrade", s.degrade), ("expose", s.expose)):
            if not 0.0 <= value <= 1.0:
                raise InputError(f"{flag} (--{flag}) is a probability in [0, 1], got {value}")
        if not 0.0 <= s.procedural_share <= 1.0:
            raise InputError(f"procedural_share (--procedural-share) is a probability in [0, 1], got "
                             f"{s.procedural_share}")
        if s.inference_max_pixels is not None and s.inference_max_pixels < 1:
            raise InputError(f"--inference-max-pixels {s.inference_max_pixels}: give a positive number of pixels")
        if s.iterations < 1 or s.batch < 1 or s.crop < 8 or s.lr <= 0 or s.checkpoint_every < 1:
            raise InputError(f"need iterations >= 1, batch >= 1, crop >= 8, lr > 0, checkpoint_every >= 1 "
                             f"(got {s.iterations}, {s.batch}, {s.crop}, {s.lr}, {s.checkpoint_every})")
        self._check_run_dir()
        self.run_dir.mkdir(parents=True, exist_ok=True)
        self.report = SkipReport()
        sources = []
        for root in s.data:
            sources += training_sources(root, self.report, ignore_prints=s.ignore_prints)
        for root in s.real:
            sources += real_sources(root, self.report, s.real_exclude)
        for folder in s.user_photos:
            sources += photo_sources(folder, self.run_dir / "photos", self.report, max_side=s.photo_max_side,
                                     motion=s.align_motion, progress=progress)
        self.data = TrainingSet(sources, Augment(crop=s.crop, scale_range=s.scale_range, whole_frame=s.whole_frame,
                                                 gt_share=s.gt_share, procedural_share=s.procedural_share,
                                                 degrade=s.degrade, expose=s.expose, real_share=s.real_share),
                                self.report)
        self.vgg = load_vgg19(s.vgg19) if s.vgg19 is not None else None
        model_cfg = s.model
        checkpoint = self._load_checkpoint() if s.resume else None
        start_state = None
        self.init_record: dict | None = None
        if checkpoint is not None:
            model_cfg = EstimatorConfig.from_dict(json.loads(checkpoint["model_config"]))
            self.init_record = previous_init_record(self.run_dir / "run.json")
        elif s.init_from is not None:
            model_cfg, start_state, self.init_record = initial_weights(Path(s.init_from), s.model.row_prior)

        def build() -> EstimatorNet:
            net = EstimatorNet(model_cfg)
            if start_state is not None:
                net.load_state_dict(start_state)
            return net

        self._start(build, checkpoint)
        if s.train_only not in TRAIN_ONLY:
            raise InputError(f"train_only (--train-only) is one of {', '.join(TRAIN_ONLY)}, got {s.train_only!r}")
        frozen = TRAIN_ONLY[s.train_only]
        if frozen is not None:  # Adam skips parameters that never get a gradient
            for name, p in self.model.named_parameters():
                p.requires_grad_(name.startswith(frozen))
        # the HDR teacher only matters when E can move
        self.teacher = self._load_teacher() if frozen is None else None

    def _load_teacher(self) -> EstimatorNet | None:
        """The frozen net whose E real pictures keep (``hdr_teacher``, else ``init_from``)."""
        s = self.settings
        path = s.hdr_teacher if s.hdr_teacher is not None else (s.init_from if s.real else None)
        if path is None or not s.real:
            return None
        from .infer import load_estimator

        net = load_estimator(path).net
        net.eval()
        for p in net.parameters():
            p.requires_grad_(False)
        return net

    def _plot_losses(self, out: Path) -> None:
        plot_losses(self.log_path, out)

    def _backward(self) -> tuple[dict[str, float], dict[str, str]]:
        s = self.settings
        sums: dict[str, float] = {}
        counts: dict[str, int] = {}
        kinds, names = [], []
        for _ in range(s.batch):
            sample = self.data.draw(self.rng)
            res = sample_loss(self.model, sample, s.weights, self.vgg, teacher=self.teacher)
            (res.total / s.batch).backward()
            for k, v in res.parts.items():  # floats only: no tensor (and no graph) outlives the step
                sums[k] = sums.get(k, 0.0) + float(v)
                counts[k] = counts.get(k, 0) + 1
            kinds.append(sample.kind)
            names.append(sample.name)
            del res, sample
        # a term is averaged over the samples that have it (photos have no supervised terms)
        parts_sum = {k: v / counts[k] for k, v in sums.items()}
        if not np.isfinite(parts_sum.get("total", np.nan)):
            raise RvrError(f"the training loss became {parts_sum.get('total')} at iteration {self.iteration + 1} "
                           f"(sample {names}); lower --lr and --resume from the last checkpoint")
        return parts_sum, {"kind": "+".join(kinds), "sample": "+".join(names)}

    # -- export ---------------------------------------------------------------------------
    def _run_record(self) -> dict:
        s = self.settings
        return {
            "engine_version": __version__,
            "data": [str(p) for p in s.data], "user_photos": [str(p) for p in s.user_photos],
            "iterations": s.iterations, "lr": s.lr, "batch": s.batch, "crop": s.crop, "grad_clip": s.grad_clip,
            "scale_range": list(s.scale_range), "whole_frame": s.whole_frame, "gt_share": s.gt_share,
            "procedural_share": s.procedural_share, "degrade": s.degrade, "expose": s.expose, "seed": s.seed,
            "ignore_prints": s.ignore_prints, "real": [str(p) for p in s.real],
            "real_exclude": list(s.real_exclude), "real_share": s.real_share, "train_only": s.train_only,
            "hdr_teacher": str(s.hdr_teacher) if s.hdr_teacher else (str(s.init_from) if s.real and s.init_from else None),
            "vgg19": str(s.vgg19) if s.vgg19 else None,
            "loss_weights": asdict(s.weights), "model": self.model.config.to_dict(),
            "parameters": self.model.parameter_count(), "training_data": self.data.summary(),
            "skipped": self.report.summary(), "init_from": self.init_record,
        }

    def _export_weights(self, path: Path, training: dict) -> Path:
        return export_weights(self.model, path, iterations=self.iteration, wall_time_s=self.wall_time,
                              training=training, inference_max_pixels=self.settings.inference_max_pixels)


def initial_weights(path: Path, row_prior: bool) -> tuple[EstimatorConfig, dict, dict]:
    """(config, state dict, record for run.json) of a new run started from the weights in ``path``
    (``--init-from``), grown by the row prior when ``row_prior`` is asked and the weights lack it."""
    from .infer import load_estimator

    loaded = load_estimator(path)
    old = loaded.net.config
    new = replace(old, row_prior=old.row_prior or row_prior)
    record = {"path": str(path), "sha256_16": loaded.model_hash, "iterations": loaded.header.get("iterations"),
              "wall_time_s": loaded.header.get("wall_time_s"), "row_prior_added": new != old}
    log.info("starting from the weights in %s (%s iterations)%s", path, record["iterations"],
             ", row prior added" if new != old else "")
    return new, grow_state_dict(loaded.net.state_dict(), old, new), record


def export_weights(model: EstimatorNet, path: Path, iterations: int, wall_time_s: float, training: dict,
                   inference_max_pixels: int | None = None) -> Path:
    """Write ``{"format", "header" (JSON text), "state_dict"}`` atomically, and the header as .json.

    The header records the architecture hyper-parameters, the parameter count, the engine
    version, the iterations, the wall time and the training data summary (``training``), and
    ``inference_max_pixels`` when given (:func:`.infer.preferred_max_pixels`).
    """
    header = {
        "format": WEIGHTS_FORMAT, "architecture": "EstimatorNet", "config": model.config.to_dict(),
        "parameters": model.parameter_count(), "engine_version": __version__,
        "iterations": int(iterations), "wall_time_s": round(float(wall_time_s), 1),
        "disparity_unit": f"percent of the frame width (D_px = D_rel * width / {DISPARITY_PERCENT:g})",
        "k_hdr": K_HDR, "training": training, "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }
    if inference_max_pixels is not None:
        header["inference_max_pixels"] = int(inference_max_pixels)
    return save_weights(model, path, WEIGHTS_FORMAT, header)


def plot_losses(log_path: Path, out: Path) -> None:
    """Plot loss_log.csv to a PNG, atomically: the losses (total, L_rend, L_adjust_rend, L_smooth
    and, when logged, the supervised L_sup, L_D, L_E) as moving averages on a log scale, and,
    when the run had ground truth, a second panel with the disparity RMS (px) and correlation."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    keys = ("total", "rend", "adjust", "smooth", "sup", "sup_d", "sup_e", "d_rms_px", "d_corr")
    rows: list[dict[str, float]] = []
    with log_path.open(newline="") as f:
        for r in csv.DictReader(f):
            try:
                row = {k: float(r[k]) for k in ("iteration", "total", "rend", "adjust", "smooth")}
            except (KeyError, ValueError, TypeError):
                continue
            for k in keys[4:]:
                try:
                    row[k] = float(r.get(k) or "nan")
                except ValueError:
                    row[k] = float("nan")
            rows.append(row)
    if not rows:
        return
    win = max(1, len(rows) // 100)

    def curve(key: str) -> tuple[np.ndarray, np.ndarray]:
        # L_adjust_rend exists only on triplet iterations, the supervised terms and the disparity
        # figures only on samples with ground truth: average each over the rows that have it
        pts = [(r["iteration"], r[key]) for r in rows if np.isfinite(r[key]) and (key != "adjust" or r[key] > 0)]
        if not pts:
            return np.zeros(0), np.zeros(0)
        x, y = np.asarray(pts).T
        w = min(win, len(y))
        return x[w - 1:], np.convolve(y, np.ones(w) / w, mode="valid")

    has_gt = any(np.isfinite(r["d_rms_px"]) for r in rows)
    fig, axes = plt.subplots(2 if has_gt else 1, 1, figsize=(8, 7.5 if has_gt else 4.5), dpi=100, squeeze=False)
    ax = axes[0, 0]
    for key, label in (("total", "total"), ("rend", "L_rend"), ("adjust", "L_adjust_rend (triplets)"),
                       ("smooth", "L_smooth"), ("sup", "L_sup (supervised, ours)"), ("sup_d", "L_D"),
                       ("sup_e", "L_E")):
        x, y = curve(key)
        if len(y) and np.any(y > 0):
            ax.plot(x, y, label=label, lw=1.2)
    ax.set_yscale("log")
    ax.set_xlabel("iteration")
    ax.set_ylabel(f"loss (moving average over {win})")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    if has_gt:
        ax2 = axes[1, 0]
        x, y = curve("d_rms_px")
        ax2.plot(x, y, color="C3", lw=1.2, label="D RMS error (px, native width)")
        ax2.set_xlabel("iteration")
        ax2.set_ylabel("D RMS error, px", color="C3")
        ax2.grid(True, alpha=0.3)
        twin = ax2.twinx()
        x, y = curve("d_corr")
        twin.plot(x, y, color="C0", lw=1.2, label="corr(D, D_gt)")
        twin.set_ylabel("correlation with ground truth", color="C0")
        twin.set_ylim(-1, 1)
    save_png(fig, out)

