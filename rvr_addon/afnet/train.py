"""``rvr train-afnet``: resumable training of AF-Net (paper section 5.3).

Loss per sample (weight 1; weak-label clips ``weak_weight``): ``w_map`` times the cross-entropy
between the focus-region target of each unit centre with a known region and the spatial
softmax of CNN-1's map (the paper supervises (x, y) with fixation maps; ours are boxes and
focus points, :mod:`.data`), plus ``w_nft`` times the binary cross-entropy between the
predicted NFT logit and the soft NFT label of the centre frame. Adam (lr 1e-3), batch 8,
gradient norm clipped at 5.

The run folder holds, as for the estimator (:mod:`rvr_addon.estimate.train`):

```
checkpoint.pt   model, Adam, iteration, numpy + torch RNG, wall time (atomic; every
                --checkpoint-every iterations, at the end and on Ctrl-C)
loss_log.csv    one row per iteration (LOG_FIELDS)
loss.png        the loss curves (refreshed with every checkpoint)
run.json        settings and the training-data summary of the latest start
afnet.pt        exported weights at the end: {"format", "header" (JSON text), "state_dict"},
                loaded with torch.load(weights_only=True)
afnet.json      the same header, for people
data_cache/     the prepared clips (.npz), reused on resume
```

``--init-from WEIGHTS`` starts a new run from exported AF-Net weights (their architecture; with
``--audio`` on weights without it, the audio input is added with zero weights, so the run starts
from exactly the old predictions: :func:`.model.grow_state_dict`).

``--resume`` continues exactly where the checkpoint stopped (same samples and result as an
uninterrupted run); rows of the log past the checkpoint are dropped.
"""
from __future__ import annotations

import csv
import json
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from .. import __version__
from ..errors import InputError, RvrError
from ..training_run import TrainingRun, previous_init_record, save_png, save_weights
from .data import Sample, TrainingSet, load_training_clips
from .model import AFNet, AFNetConfig, grow_state_dict

CHECKPOINT_FORMAT = "rvr-laaf-afnet-checkpoint/1"
WEIGHTS_FORMAT = "rvr-laaf-afnet/1"
LOG_FIELDS = ("iteration", "wall_s", "total", "map", "nft", "p_pos", "p_neg", "grad_norm", "weak_share", "rss_mb")
"""Columns of loss_log.csv: ``map`` and ``nft`` the two loss terms (weighted means over the
batch), ``p_pos``/``p_neg`` the mean predicted NFT probability on samples with label >= 0.5 /
< 0.5 (blank when the batch had none), ``weak_share`` the share of weak-label samples."""


@dataclass
class AFNetTrainSettings:
    """Everything ``rvr train-afnet`` takes (see ``rvr train-afnet --help``)."""

    run_dir: Path
    data: list[Path] = field(default_factory=list)
    annotations: list[Path] = field(default_factory=list)
    iterations: int = 10000
    lr: float = 1e-3
    batch: int = 8
    weak_weight: float = 0.3
    w_map: float = 1.0
    w_nft: float = 1.0
    pos_fraction: float = 0.5
    tolerance: float = 3.0
    checkpoint_every: int = 250
    grad_clip: float = 5.0
    seed: int = 0
    resume: bool = False
    model: AFNetConfig = field(default_factory=AFNetConfig)
    init_from: Path | None = None
    stride: int | None = None
    """Inference stride written into the weights (None: the model config's; a resumed run may change
    it: queries at inference only, training does not use it)."""
    threshold: float | None = None
    """NFT probability threshold written into the weights' header for inference (None: none, 0.5)."""
    depth_augment: float = 0.0
    """Share of samples whose disparity is replaced by estimate-like, region-flat or flat depth
    (:func:`.data.augment_disparity`; 0: the stored disparity only)."""


def batch_loss(model: AFNet, samples: list[Sample], w_map: float = 1.0, w_nft: float = 1.0
               ) -> tuple[torch.Tensor, dict[str, float]]:
    """The loss of the module docstring on a batch; returns (total, float parts for the log)."""
    x = torch.from_numpy(np.stack([s.x for s in samples]))
    audio = torch.from_numpy(np.stack([s.audio for s in samples])) if model.config.audio else None
    target = torch.from_numpy(np.stack([s.target for s in samples]))
    valid = torch.from_numpy(np.stack([s.valid for s in samples]))
    label = torch.tensor([s.label for s in samples], dtype=torch.float32)
    weight = torch.tensor([s.weight for s in samples], dtype=torch.float32)
    logits, maps = model(x, audio)
    logp = F.log_softmax(maps.flatten(2), dim=-1)
    ce = -(target.flatten(2) * logp).sum(-1)  # (B, s)
    vw = valid.float() * weight[:, None]
    map_loss = (ce * vw).sum() / vw.sum().clamp_min(1e-6)
    nft = F.binary_cross_entropy_with_logits(logits, label, reduction="none")
    nft_loss = (nft * weight).sum() / weight.sum().clamp_min(1e-6)
    total = w_map * map_loss + w_nft * nft_loss
    prob = torch.sigmoid(logits.detach())
    pos, neg = label >= 0.5, label < 0.5
    parts = {"total": float(total.detach()), "map": float(map_loss.detach()), "nft": float(nft_loss.detach()),
             "p_pos": float(prob[pos].mean()) if bool(pos.any()) else float("nan"),
             "p_neg": float(prob[neg].mean()) if bool(neg.any()) else float("nan"),
             "weak_share": float(np.mean([s.weight < 1.0 for s in samples]))}
    return total, parts


class AFNetTrainer(TrainingRun):
    """A resumable AF-Net training run: ``step()`` / ``progress`` / ``cancel()`` (module docstring)."""

    checkpoint_format = CHECKPOINT_FORMAT
    log_fields = LOG_FIELDS
    weights_name = "afnet.pt"
    bar_desc = "train-afnet"
    run_noun = "an AF-Net run"
    checkpoint_noun = "an AF-Net training checkpoint"
    blank_nonfinite = True  # p_pos / p_neg are NaN on a batch without such samples
    settings: AFNetTrainSettings

    def __init__(self, settings: AFNetTrainSettings, progress: bool = False) -> None:
        s = self.settings = settings
        if not s.data and not s.annotations:
            raise InputError("no AF-Net training data: pass --data DATASET (harness clips) and/or --annotations "
                             "FILE.json (editor exports or weak labels)")
        if s.iterations < 1 or s.batch < 1 or s.lr <= 0 or s.checkpoint_every < 1:
            raise InputError(f"need --iterations >= 1, --batch >= 1, --lr > 0, --checkpoint-every >= 1 "
                             f"(got {s.iterations}, {s.batch}, {s.lr}, {s.checkpoint_every})")
        if s.weak_weight < 0 or s.w_map < 0 or s.w_nft < 0:
            raise InputError(f"--weak-weight, --w-map and --w-nft must be >= 0 (got {s.weak_weight}, {s.w_map}, "
                             f"{s.w_nft})")
        if s.threshold is not None and not 0.0 < s.threshold < 1.0:
            raise InputError(f"--threshold must be between 0 and 1, got {s.threshold}")
        self._check_run_dir()
        checkpoint = self._load_checkpoint() if s.resume else None
        model_cfg = AFNetConfig.from_dict(json.loads(checkpoint["model_config"])) if checkpoint else s.model.check()
        start_state = None
        self.init_record: dict | None = None
        if checkpoint is None and s.init_from is not None:
            model_cfg, start_state, self.init_record = _initial_weights(Path(s.init_from), s.model.audio)
        elif checkpoint is not None:
            self.init_record = previous_init_record(self.run_dir / "run.json")
        if s.stride is not None:
            try:
                model_cfg = replace(model_cfg, stride=int(s.stride)).check()
            except ValueError as ex:
                raise InputError(f"--stride: {ex}") from None
        self.run_dir.mkdir(parents=True, exist_ok=True)
        clips, self.report = load_training_clips(model_cfg, s.data, s.annotations, self.run_dir / "data_cache",
                                                 progress=progress)
        self.data = TrainingSet(clips, model_cfg, pos_fraction=s.pos_fraction, weak_weight=s.weak_weight,
                                tolerance=s.tolerance, depth_augment=s.depth_augment)

        def build() -> AFNet:
            net = AFNet(model_cfg)
            if start_state is not None:
                full = net.state_dict()
                full.update(start_state)  # the audio branch keeps its fresh initialisation
                net.load_state_dict(full)
            return net

        self._start(build, checkpoint)

    def _plot_losses(self, out: Path) -> None:
        plot_losses(self.log_path, out)

    def _backward(self) -> tuple[dict[str, float], dict[str, str]]:
        s = self.settings
        samples = [self.data.draw(self.rng) for _ in range(s.batch)]
        total, parts = batch_loss(self.model, samples, s.w_map, s.w_nft)
        if not np.isfinite(parts["total"]):
            raise RvrError(f"the AF-Net loss became {parts['total']} at iteration {self.iteration + 1}; lower --lr "
                           "and --resume from the last checkpoint")
        total.backward()
        return parts, {}

    # -- export ---------------------------------------------------------------------------
    def _run_record(self) -> dict:
        s = self.settings
        return {"engine_version": __version__, "data": [str(p) for p in s.data],
                "annotations": [str(p) for p in s.annotations], "iterations": s.iterations, "lr": s.lr,
                "batch": s.batch, "weak_weight": s.weak_weight, "w_map": s.w_map, "w_nft": s.w_nft,
                "pos_fraction": s.pos_fraction, "tolerance_frames": s.tolerance, "seed": s.seed,
                "depth_augment": s.depth_augment,
                "model": self.model.config.to_dict(), "parameters": self.model.parameter_count(),
                "init_from": self.init_record, "training_data": self.report.to_dict()}

    def _export_weights(self, path: Path, training: dict) -> Path:
        return export_weights(self.model, path, self.iteration, self.wall_time, training, self.settings.threshold)


def _initial_weights(path: Path, audio: int) -> tuple[AFNetConfig, dict, dict]:
    """(config, state dict, record for run.json) of a new run from the AF-Net weights in ``path``,
    grown by the audio input when ``audio`` is asked and the weights lack it."""
    from .infer import load_afnet

    model, header = load_afnet(path, backend="torch")  # the state dict: never the ONNX export beside it
    old = model.config
    new = replace(old, audio=old.audio or audio)
    record = {"path": str(path), "iterations": header.get("iterations"), "wall_time_s": header.get("wall_time_s"),
              "audio_added": new != old}
    return new, grow_state_dict(model.state_dict(), old, new), record


def export_weights(model: AFNet, path: Path, iterations: int, wall_time_s: float, training: dict,
                   threshold: float | None = None) -> Path:
    """Write ``{"format", "header" (JSON text), "state_dict"}`` atomically, and the header as .json.
    threshold: the NFT probability inference uses by default (header ``threshold``; None: 0.5)."""
    cfg = model.config
    header = {"format": WEIGHTS_FORMAT, "architecture": "AFNet", "config": cfg.to_dict(),
              "parameters": model.parameter_count(), "engine_version": __version__,
              "receptive_field_frames": cfg.span, "iterations": int(iterations),
              "wall_time_s": round(float(wall_time_s), 1), "training": training,
              "created": time.strftime("%Y-%m-%dT%H:%M:%S%z")}
    if threshold is not None:
        header["threshold"] = float(threshold)
    return save_weights(model, path, WEIGHTS_FORMAT, header)


def plot_losses(log_path: Path, out: Path) -> None:
    """loss_log.csv -> PNG (atomic): map and NFT losses (moving averages, log scale) and the
    mean NFT probability on positive and negative samples."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cols: dict[str, list[float]] = {k: [] for k in ("iteration", "total", "map", "nft", "p_pos", "p_neg")}
    with log_path.open(newline="") as f:
        for r in csv.DictReader(f):
            try:
                it = float(r["iteration"])
            except (KeyError, ValueError, TypeError):
                continue
            cols["iteration"].append(it)
            for k in list(cols)[1:]:
                try:
                    cols[k].append(float(r.get(k) or "nan"))
                except ValueError:
                    cols[k].append(float("nan"))
    if not cols["iteration"]:
        return
    x = np.asarray(cols["iteration"])
    win = max(1, len(x) // 50)

    def smooth(key: str) -> tuple[np.ndarray, np.ndarray]:
        y = np.asarray(cols[key])
        ok = np.isfinite(y)
        if not ok.any():
            return np.zeros(0), np.zeros(0)
        xs, ys = x[ok], y[ok]
        w = min(win, len(ys))
        return xs[w - 1:], np.convolve(ys, np.ones(w) / w, mode="valid")

    fig, (a1, a2) = plt.subplots(2, 1, figsize=(8, 6.5), dpi=100)
    for key, label in (("total", "total"), ("map", "focus-region map (cross-entropy)"), ("nft", "NFT (BCE)")):
        xs, ys = smooth(key)
        if len(ys):
            a1.plot(xs, ys, label=label, lw=1.2)
    a1.set_yscale("log")
    a1.set_xlabel("iteration")
    a1.set_ylabel(f"loss (moving average over {win})")
    a1.grid(True, which="both", alpha=0.3)
    a1.legend(fontsize=8)
    for key, label in (("p_pos", "mean P on NFT samples"), ("p_neg", "mean P on other samples")):
        xs, ys = smooth(key)
        if len(ys):
            a2.plot(xs, ys, label=label, lw=1.2)
    a2.set_ylim(0, 1)
    a2.set_xlabel("iteration")
    a2.set_ylabel("NFT probability")
    a2.grid(True, alpha=0.3)
    a2.legend(fontsize=8)
    save_png(fig, out)

