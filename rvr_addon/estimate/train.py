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

import contextlib
import csv
import json
import logging
import os
import signal
import threading
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch

from .. import __version__
from ..color import srgb_to_linear
from ..errors import InputError, RvrError
from ..io.paths import temp_sibling
from ..render.aperture import ApertureSpec
from ..render.model import K_HDR, hdr_radiance
from .data import Augment, SkipReport, TrainingSet, TrainSample, harness_sources, photo_sources
from .losses import (
    LossResult, LossWeights, VGG19Features, load_vgg19, render_member, supervised_loss, to_display, total_loss,
)
from .unet import DISPARITY_PERCENT, EstimatorConfig, EstimatorNet, disparity_to_px

log = logging.getLogger(__name__)

CHECKPOINT_FORMAT = "rvr-laaf-estimator-checkpoint/1"
WEIGHTS_FORMAT = "rvr-laaf-estimator/1"
LOG_FIELDS = ("iteration", "wall_s", "total", "rend", "adjust", "smooth", "pix", "ssim", "grad", "vgg", "grad_norm",
              "kind", "sample", "sup", "sup_d", "sup_dgrad", "sup_e", "sup_e0", "d_rms_px", "d_corr", "rss_mb")
"""Columns of loss_log.csv. ``sup*``: the supervised terms (blank for samples without ground
truth); ``d_rms_px``: RMS of D - D_gt in px at the native width and ``d_corr`` their Pearson
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
    vgg19: Path | None = None
    weights: LossWeights = field(default_factory=LossWeights)
    checkpoint_every: int = 500
    grad_clip: float = 1.0
    seed: int = 0
    resume: bool = False
    photo_max_side: int = 1024
    align_motion: str = "homography"
    model: EstimatorConfig = field(default_factory=EstimatorConfig)


@contextlib.contextmanager
def deferred_interrupt():
    """Hold back Ctrl-C (SIGINT) until the block is done, then raise KeyboardInterrupt.

    Wraps the optimizer update and the checkpoint write, so an interrupt never leaves some
    parameters updated and others not. Outside the main thread (where signal handlers cannot
    be set) it does nothing.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught: list[int] = []
    previous = signal.signal(signal.SIGINT, lambda signum, frame: caught.append(signum))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
    if caught:
        raise KeyboardInterrupt


def current_rss_mb() -> float:
    """Resident memory of this process in MiB (Linux /proc/self/statm; elsewhere the peak from
    ``resource.getrusage``; NaN when neither is available)."""
    try:
        with open("/proc/self/statm", "rb") as f:
            pages = int(f.read().split()[1])
        return pages * os.sysconf("SC_PAGE_SIZE") / 2**20
    except (OSError, ValueError, IndexError, AttributeError):
        pass
    try:
        import resource
        import sys

        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        return peak / 2**20 if sys.platform == "darwin" else peak / 2**10
    except (ImportError, OSError):
        return float("nan")


TRIM_EVERY = 50
"""Iterations between :func:`release_memory` calls."""
_libc: list = []


def release_memory() -> bool:
    """Hand freed heap memory back to the OS (glibc ``malloc_trim(0)``; False where unavailable).

    Training allocates tensors of ever-changing shapes (random crops and scales, a layer count
    that follows the predicted disparity range); glibc then keeps freed blocks in fragmented
    arenas and the resident size creeps up although nothing is referenced: ~20 MB per 100
    iterations in our 500-iteration runs, which over a 150k-iteration run is the order of the
    18 GB an earlier experiment reached. Trimming every ``TRIM_EVERY`` iterations costs ~1 ms.
    """
    if not _libc:
        try:
            import ctypes
            import ctypes.util

            name = ctypes.util.find_library("c")
            lib = ctypes.CDLL(name) if name else None
            _libc.append(lib if lib is not None and hasattr(lib, "malloc_trim") else None)
        except (OSError, AttributeError):
            _libc.append(None)
    lib = _libc[0]
    if lib is None:
        return False
    lib.malloc_trim(0)
    return True


def _atomic_torch_save(obj, path: Path) -> None:
    tmp = temp_sibling(path, ".pt")
    try:
        torch.save(obj, tmp)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def _atomic_text(path: Path, text: str) -> None:
    tmp = temp_sibling(path, ".tmp")
    tmp.write_text(text)
    os.replace(tmp, path)


def sample_loss(model: EstimatorNet, sample: TrainSample, weights: LossWeights,
                vgg: VGG19Features | None = None, spec: ApertureSpec | None = None) -> LossResult:
    """Eq. 7 for one drawn sample: predict, render the target(s) through our model, compare.

    The network's D_rel becomes px at the working resolution with the sample's frame width
    (L_smooth takes D as a fraction of that width, see :mod:`.losses`); the radiance is ``srgb_to_linear(I) * exp(50 E)`` (eq. 3); each target is rendered with
    its own ``alpha * D + beta`` and compared in display sRGB.
    """
    image = torch.from_numpy(sample.image).permute(2, 0, 1)[None]
    out = model(image)
    d_px = disparity_to_px(out.disparity_rel, sample.frame_width)
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


def disparity_metrics(disparity_rel: torch.Tensor, gt_rel: torch.Tensor, frame_width: float,
                      native_width: float | None) -> dict[str, float]:
    """Monitoring figures of a predicted D against the ground truth (no gradient).

    disparity_rel, gt_rel: (1, 1, H, W) D in percent of the frame width (gt NaN where unknown).
    Returns ``d_rms_px``: RMS of D - D_gt in px at ``native_width`` (DESIGN units; the working
    width when None), and ``d_corr``: their Pearson correlation (0 when either is flat).
    """
    mask = torch.isfinite(gt_rel)
    if not bool(mask.any()):
        return {}
    p, g = disparity_rel[mask].double(), gt_rel[mask].double()
    width = float(native_width or frame_width)
    rms = float(((p - g) ** 2).mean().sqrt()) * width / DISPARITY_PERCENT
    pc, gc = p - p.mean(), g - g.mean()
    den = float((pc.pow(2).sum() * gc.pow(2).sum()).sqrt())
    return {"d_rms_px": rms, "d_corr": float((pc * gc).sum()) / den if den > 0 else 0.0}


class Trainer:
    """A resumable training run (see the module docstring)."""

    def __init__(self, settings: TrainSettings, progress: bool = False) -> None:
        s = self.settings = settings
        if not s.data and not s.user_photos:
            raise InputError("no training data: pass --data DATASET (harness clips) and/or --user-photos DIR")
        if not 0.0 <= s.whole_frame <= 1.0:
            raise InputError(f"whole_frame (--whole-frame) is a probability in [0, 1], got {s.whole_frame}")
        if s.iterations < 1 or s.batch < 1 or s.crop < 8 or s.lr <= 0 or s.checkpoint_every < 1:
            raise InputError(f"need iterations >= 1, batch >= 1, crop >= 8, lr > 0, checkpoint_every >= 1 "
                             f"(got {s.iterations}, {s.batch}, {s.crop}, {s.lr}, {s.checkpoint_every})")
        self.run_dir = Path(s.run_dir)
        self.checkpoint_path = self.run_dir / "checkpoint.pt"
        self.log_path = self.run_dir / "loss_log.csv"
        if self.checkpoint_path.exists() and not s.resume:
            raise InputError(f"'{self.run_dir}' already holds a training run (checkpoint.pt): pass --resume to "
                             "continue it, or choose a new -o folder")
        if s.resume and not self.checkpoint_path.exists():
            raise InputError(f"--resume: '{self.checkpoint_path}' does not exist; start the run without --resume")
        self.run_dir.mkdir(parents=True, exist_ok=True)
        self.report = SkipReport()
        sources = []
        for root in s.data:
            sources += harness_sources(root, self.report)
        for folder in s.user_photos:
            sources += photo_sources(folder, self.run_dir / "photos", self.report, max_side=s.photo_max_side,
                                     motion=s.align_motion, progress=progress)
        self.data = TrainingSet(sources, Augment(crop=s.crop, scale_range=s.scale_range, whole_frame=s.whole_frame), self.report)
        self.vgg = load_vgg19(s.vgg19) if s.vgg19 is not None else None
        self.iteration = 0
        self.wall_before = 0.0
        model_cfg = s.model
        checkpoint = self._load_checkpoint() if s.resume else None
        if checkpoint is not None:
            model_cfg = EstimatorConfig.from_dict(json.loads(checkpoint["model_config"]))
        torch.manual_seed(s.seed)
        self.rng = np.random.default_rng(s.seed)
        self.model = EstimatorNet(model_cfg)
        self.optimizer = torch.optim.Adam(self.model.parameters(), lr=s.lr)
        if checkpoint is not None:
            self._restore(checkpoint)
        self._started = time.perf_counter()
        self._cancelled = False
        self.last: dict[str, float] = {}
        self._log_file = None
        self._open_log()
        _atomic_text(self.run_dir / "run.json", json.dumps(self._run_record(), indent=1))

    # -- checkpoints ----------------------------------------------------------------------
    def _load_checkpoint(self) -> dict:
        try:
            ck = torch.load(self.checkpoint_path, map_location="cpu", weights_only=True)
        except Exception as ex:
            raise InputError(f"checkpoint '{self.checkpoint_path}' cannot be read ({type(ex).__name__}: {ex}); it is "
                             "corrupt. Delete it to start over (or restore a copy).") from ex
        if not isinstance(ck, dict) or ck.get("format") != CHECKPOINT_FORMAT:
            raise InputError(f"'{self.checkpoint_path}' is not an estimator training checkpoint ({CHECKPOINT_FORMAT})")
        return ck

    def _restore(self, ck: dict) -> None:
        self.model.load_state_dict(ck["model"])
        self.optimizer.load_state_dict(ck["optimizer"])
        for group in self.optimizer.param_groups:
            group["lr"] = self.settings.lr
        self.iteration = int(ck["iteration"])
        self.wall_before = float(ck["wall_time_s"])
        self.rng.bit_generator.state = json.loads(ck["numpy_rng"])
        torch.set_rng_state(ck["torch_rng"])
        log.info("resumed %s at iteration %d", self.checkpoint_path, self.iteration)

    def save_checkpoint(self) -> None:
        """Write checkpoint.pt atomically (model, Adam, iteration, RNG, wall time)."""
        _atomic_torch_save({
            "format": CHECKPOINT_FORMAT, "iteration": self.iteration, "wall_time_s": self.wall_time,
            "model_config": json.dumps(self.model.config.to_dict()), "model": self.model.state_dict(),
            "optimizer": self.optimizer.state_dict(), "numpy_rng": json.dumps(self.rng.bit_generator.state),
            "torch_rng": torch.get_rng_state(),
        }, self.checkpoint_path)
        if self._log_file is not None:
            self._log_file.flush()

    @property
    def wall_time(self) -> float:
        """Training seconds over all sessions of this run."""
        return self.wall_before + (time.perf_counter() - self._started)

    # -- log and plots --------------------------------------------------------------------
    def _open_log(self) -> None:
        rows = []
        if self.log_path.exists() and self.settings.resume:
            with self.log_path.open(newline="") as f:
                rows = [r for r in csv.DictReader(f) if r.get("iteration", "").isdigit()
                        and int(r["iteration"]) <= self.iteration]
        tmp = temp_sibling(self.log_path, ".csv")
        with tmp.open("w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=LOG_FIELDS)
            w.writeheader()
            w.writerows({k: r.get(k, "") for k in LOG_FIELDS} for r in rows)
        os.replace(tmp, self.log_path)
        self._log_file = self.log_path.open("a", newline="")
        self._log = csv.DictWriter(self._log_file, fieldnames=LOG_FIELDS)

    def plot(self) -> None:
        """Write loss.png: total and terms per iteration (moving average over 1% of the run).

        Skipped with one warning when matplotlib is not installed (the CSV log has it all).
        """
        if self._log_file is not None:
            self._log_file.flush()
        try:
            plot_losses(self.log_path, self.run_dir / "loss.png")
        except ImportError as ex:
            if not getattr(self, "_warned_plot", False):
                log.warning("no loss plot (%s); install matplotlib for loss.png, the numbers are in %s",
                            ex, self.log_path)
                self._warned_plot = True

    # -- the job --------------------------------------------------------------------------
    @property
    def progress(self) -> float:
        """Fraction of the iterations done, 0..1."""
        return min(self.iteration / self.settings.iterations, 1.0)

    @property
    def done(self) -> bool:
        return self.iteration >= self.settings.iterations or self._cancelled

    def step(self) -> bool:
        """One optimisation step; False once the run has reached its iteration count."""
        if self.done:
            return False
        s = self.settings
        self.model.train()
        self.optimizer.zero_grad(set_to_none=True)
        sums: dict[str, float] = {}
        counts: dict[str, int] = {}
        kinds, names = [], []
        for _ in range(s.batch):
            sample = self.data.draw(self.rng)
            res = sample_loss(self.model, sample, s.weights, self.vgg)
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
        with deferred_interrupt():  # the update, its count and its log row happen together or not at all
            norm = torch.nn.utils.clip_grad_norm_(self.model.parameters(), s.grad_clip)
            parts_sum["grad_norm"] = float(norm)
            self.optimizer.step()
            if (self.iteration + 1) % TRIM_EVERY == 0:
                release_memory()
            parts_sum["rss_mb"] = current_rss_mb()
            self.iteration += 1
            self.last = parts_sum
            row = {k: "" for k in LOG_FIELDS}
            row.update({k: f"{v:.6g}" for k, v in parts_sum.items() if k in LOG_FIELDS})
            row.update(iteration=self.iteration, wall_s=f"{self.wall_time:.2f}", kind="+".join(kinds),
                       sample="+".join(names))
            self._log.writerow(row)
            if self.iteration % s.checkpoint_every == 0:
                self.save_checkpoint()
        if self.iteration % s.checkpoint_every == 0:
            self.plot()
        if self.iteration >= s.iterations:
            self.finish()
            return False
        return True

    def finish(self) -> None:
        """Final checkpoint, plot and exported weights."""
        self.save_checkpoint()
        self.plot()
        self.export(self.run_dir / "estimator.pt")
        self.close()

    def cancel(self) -> None:
        """Stop (Ctrl-C, Esc): save a checkpoint so ``--resume`` continues from here."""
        self._cancelled = True
        self.save_checkpoint()
        self.plot()
        self.close()

    def close(self) -> None:
        if self._log_file is not None:
            self._log_file.close()
            self._log_file = None

    def run(self, progress: bool = True) -> None:
        """Run to the end with a tqdm bar; on Ctrl-C save a checkpoint, then re-raise."""
        from tqdm import tqdm

        s = self.settings
        bar = tqdm(total=s.iterations, initial=self.iteration, unit="it", desc="train", disable=not progress)
        try:
            while self.step():
                bar.update(1)
                if self.iteration % 10 == 0:
                    bar.set_postfix(loss=f"{self.last.get('total', 0):.4f}", refresh=False)
            bar.update(s.iterations - bar.n)
        except KeyboardInterrupt:
            self.cancel()
            raise
        except BaseException:
            self.close()
            raise
        finally:
            bar.close()

    # -- export ---------------------------------------------------------------------------
    def _run_record(self) -> dict:
        s = self.settings
        return {
            "engine_version": __version__,
            "data": [str(p) for p in s.data], "user_photos": [str(p) for p in s.user_photos],
            "iterations": s.iterations, "lr": s.lr, "batch": s.batch, "crop": s.crop,
            "scale_range": list(s.scale_range), "whole_frame": s.whole_frame, "seed": s.seed, "vgg19": str(s.vgg19) if s.vgg19 else None,
            "loss_weights": asdict(s.weights), "model": self.model.config.to_dict(),
            "parameters": self.model.parameter_count(), "training_data": self.data.summary(),
            "skipped": self.report.summary(),
        }

    def export(self, path: Path) -> Path:
        """Write the shippable weights file (state dict + JSON header) and a .json copy of the header."""
        training = {k: v for k, v in self._run_record().items() if k not in ("model", "parameters", "engine_version")}
        return export_weights(self.model, path, iterations=self.iteration, wall_time_s=self.wall_time,
                              training=training)


def export_weights(model: EstimatorNet, path: Path, iterations: int, wall_time_s: float, training: dict) -> Path:
    """Write ``{"format", "header" (JSON text), "state_dict"}`` atomically, and the header as .json.

    The header records the architecture hyper-parameters, the parameter count, the engine
    version, the iterations, the wall time and the training data summary (``training``).
    """
    path = Path(path)
    header = {
        "format": WEIGHTS_FORMAT, "architecture": "EstimatorNet", "config": model.config.to_dict(),
        "parameters": model.parameter_count(), "engine_version": __version__,
        "iterations": int(iterations), "wall_time_s": round(float(wall_time_s), 1),
        "disparity_unit": f"percent of the frame width (D_px = D_rel * width / {DISPARITY_PERCENT:g})",
        "k_hdr": K_HDR, "training": training, "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }
    state = {k: v.detach().clone() for k, v in model.state_dict().items()}
    path.parent.mkdir(parents=True, exist_ok=True)
    _atomic_torch_save({"format": WEIGHTS_FORMAT, "header": json.dumps(header), "state_dict": state}, path)
    _atomic_text(path.with_suffix(".json"), json.dumps(header, indent=1))
    return path


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
    fig.tight_layout()
    tmp = temp_sibling(out, ".png")
    fig.savefig(tmp, format="png")
    plt.close(fig)
    os.replace(tmp, out)
