"""Refit the estimator's disparity head alone on real pictures with measured depth (E untouched).

``python -m rvr_addon.estimate.head_fit --real ../shared/data/real_depth -o OUT [--cv 5]``

The disparity D of :class:`.unet.EstimatorNet` is the bilateral grid ``grid_head`` (a 1x1
convolution of the 1/8 decoder level, plus the row coordinate with ``--row-prior``) sliced by the
frame's luma; E comes from the 1/4 level, which the grid head does not feed. With every other
layer frozen, E is bit-identical to the starting weights' (HDR cannot regress) and the trunk's
features of a picture are fixed: they are computed once per picture, exactly as inference computes
them (the frame shrunk to the weights' ``inference_max_pixels`` by :class:`.infer.Estimator`'s
resampling, the grid sliced by the full-size luma), so a fit takes seconds and the leave-scene-out
figures are the ones ``rvr eval-estimator`` gives (``--cv``; the exported weights are re-scored
with it anyway).

Loss per picture: the supervised D terms of ``rvr train --real`` (L1 + 0.5 x multi-scale gradient
matching after a positive median/MAD scale and a shift, :func:`.losses.supervised_loss`), either in
the picture's own unit (stereo px: a picture weighs by its depth contrast) or ``--normalise``d
(each picture's target divided by its mean absolute deviation: every picture weighs alike, like
the figure), plus ``--w-l2`` x a pull of the head's weights towards the starting ones.
Augmentation: horizontal flips and trunk sizes ``--scales`` x the inference size.

``--procedural DIR`` (a dataset of ``rvr procedural``, repeatable) mixes ray-cast rooms, streets and
close-ups with exact disparity into the fit: a ``--procedural-share`` of each batch's pictures,
their targets brought to the real pictures' median spread, so the head is not fitted to the real
set's tabletop layouts alone.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from .unet import DISPARITY_PERCENT, bound_disparity


@dataclass
class PictureFeatures:
    """One view prepared for the head: the grid head's input, the full-size guide luma and truth."""

    name: str
    scene: str
    feats: torch.Tensor  # (1, C, hg, wg) input of grid_head
    guide: torch.Tensor  # (1, 1, H, W) luma of the full-size frame
    extent: tuple[float, float]
    target: torch.Tensor  # (1, 1, H, W) D_rel-like target (-scale q * 100 / W), NaN unknown
    q: np.ndarray  # (H, W) inverse depth (for the figure), NaN unknown
    train_guide: torch.Tensor | None = None  # the guide and target at the trunk's size, for the fit
    train_target: torch.Tensor | None = None


def _features(net, rgb: np.ndarray, max_pixels: int
              ) -> tuple[torch.Tensor, torch.Tensor, tuple[float, float], tuple[int, int]]:
    """(grid-head input, full-size luma, extent, (w, h) of the trunk's input) of a frame, as
    :class:`.infer.Estimator` runs it."""
    import cv2

    from ..color import image_to_linear, linear_to_srgb, to_float01
    from .bilateral import luma

    h, w = rgb.shape[:2]
    full = torch.from_numpy(np.ascontiguousarray(to_float01(rgb))).permute(2, 0, 1)[None]
    small = full
    if h * w > max_pixels:
        s = (max_pixels / (h * w)) ** 0.5
        size = (max(int(w * s), 1), max(int(h * s), 1))
        shrunk = linear_to_srgb(cv2.resize(image_to_linear(rgb), size, interpolation=cv2.INTER_AREA))
        small = torch.from_numpy(np.ascontiguousarray(shrunk, dtype=np.float32)).permute(2, 0, 1)[None]
    got: list[torch.Tensor] = []
    hook = net.grid_head.register_forward_hook(lambda _m, inp, _out: got.append(inp[0].detach()))
    try:
        with torch.inference_mode():
            _grid, _e, (hp, wp) = net.trunk(small)
    finally:
        hook.remove()
    sh, sw = small.shape[-2:]
    return got[0].clone(), luma(full).clone(), (sh / hp, sw / wp), (sw, sh)


def _variant(net, name: str, scene: str, img: np.ndarray, target: np.ndarray, q: np.ndarray,
             max_pixels: int) -> PictureFeatures:
    """One prepared view: the trunk's features of ``img`` at ``max_pixels``, the full-size
    ``target`` (D_rel-like, larger = farther) and its copy at the trunk's size, ``q`` for the figure."""
    from .data import resize_disparity

    feats, guide, extent, size = _features(net, img, max_pixels)
    small_guide = F.interpolate(guide, size=(size[1], size[0]), mode="area")
    small_tgt = torch.from_numpy(np.ascontiguousarray(resize_disparity(target, size)))[None, None]
    return PictureFeatures(name, scene, feats, guide, extent, torch.from_numpy(target)[None, None], q,
                           small_guide, small_tgt)


def prepare(net, pictures, max_pixels: int, scales: tuple[float, ...] = (1.0,), flips: bool = True,
            progress: bool = False) -> dict[str, list[PictureFeatures]]:
    """{picture name: [its variants]}; the first variant is the unflipped one at the inference size."""
    from .real_data import disparity_scale, read_image, read_inverse_depth

    out: dict[str, list[PictureFeatures]] = {}
    for i, pic in enumerate(pictures):
        rgb, q = read_image(pic), read_inverse_depth(pic)
        scale = disparity_scale(pic)
        variants = []
        for s in scales:
            for flip in ((False, True) if flips else (False,)):
                img = np.ascontiguousarray(rgb[:, ::-1]) if flip else rgb
                qq = np.ascontiguousarray(q[:, ::-1]) if flip else q
                t = (-scale * qq * DISPARITY_PERCENT / qq.shape[1]).astype(np.float32)
                variants.append(_variant(net, pic.name, pic.scene, img, t, qq, max(1, int(max_pixels * s * s))))
        out[pic.name] = variants
        if progress:
            print(f"\rfeatures {i + 1}/{len(pictures)}", end="", file=sys.stderr)
    if progress:
        print(file=sys.stderr)
    return out


def prepare_procedural(net, folders: list[Path], max_pixels: int, flips: bool = True, limit: int = 0,
                       progress: bool = False) -> dict[str, list[PictureFeatures]]:
    """{frame name: [its variants]} of ``rvr procedural`` datasets, as :func:`prepare` does for the
    real pictures; the target is the frame's exact D (DESIGN px at its width: larger = farther, the
    orientation of the real pictures' targets). limit: at most this many frames in all (0: every one)."""
    import cv2

    from .data import SkipReport, procedural_sources, read_gt_disparity

    report = SkipReport()
    sources = [src for folder in folders for src in procedural_sources(Path(folder), report)]
    if limit > 0:
        sources = sources[:limit]
    out: dict[str, list[PictureFeatures]] = {}
    for i, src in enumerate(sources):
        rgb = cv2.cvtColor(cv2.imread(str(src.input), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
        d = read_gt_disparity(src.gt_disparity)
        variants = []
        for flip in ((False, True) if flips else (False,)):
            img = np.ascontiguousarray(rgb[:, ::-1]) if flip else rgb
            t = np.ascontiguousarray(d[:, ::-1] if flip else d, dtype=np.float32)
            variants.append(_variant(net, src.name, "procedural", img, t, -t, max_pixels))
        out[src.name] = variants
        if progress:
            print(f"\rprocedural features {i + 1}/{len(sources)}", end="", file=sys.stderr)
    if progress:
        print(file=sys.stderr)
    return out


def head_disparity(weight: torch.Tensor, bias: torch.Tensor, f: PictureFeatures, cfg,
                   small: bool = False) -> torch.Tensor:
    """D_rel (1, 1, H, W) of a prepared picture with these grid-head parameters (as the net does;
    ``small``: sliced by the guide at the trunk's size, for the fit)."""
    from .bilateral import bilateral_slice

    grid = F.conv2d(f.feats, weight, bias) * cfg.head_gain
    guide = f.train_guide if small and f.train_guide is not None else f.guide
    return bilateral_slice(bound_disparity(grid, cfg.max_disparity), guide, channels=1, extent=f.extent)


def picture_error(weight, bias, f: PictureFeatures, cfg) -> float:
    """The figure of ``rvr eval-estimator --real-set``: affine-invariant error of D against q."""
    from .evaluate import affine_invariant_error

    with torch.no_grad():
        d = head_disparity(weight, bias, f, cfg)[0, 0].numpy()
    return affine_invariant_error(d, f.q, np.isfinite(f.q))


def ramp_error(f: PictureFeatures) -> float:
    from .evaluate import affine_invariant_error, vertical_ramp

    return affine_invariant_error(vertical_ramp(*f.q.shape), f.q, np.isfinite(f.q))


@dataclass
class FitSettings:
    iterations: int = 600
    lr: float = 1e-3
    batch: int = 4
    normalise: bool = False
    w_l2: float = 0.0
    w_grad: float = 0.5
    seed: int = 0
    procedural_share: float = 0.0


def _spread(t: torch.Tensor) -> float:
    """Mean absolute deviation from the median of a target's known values."""
    v = t[torch.isfinite(t)]
    return float((v - v.median()).abs().mean().clamp(min=1e-6)) if v.numel() else 1.0


def fit_head(net, train: list[list[PictureFeatures]], fs: FitSettings,
             procedural: list[list[PictureFeatures]] | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """Adam on the grid head's weight and bias over the prepared training pictures; with
    ``procedural`` frames, each batch draws ``fs.procedural_share`` of its pictures from them, their
    targets brought to the real pictures' median spread (or to 1 with ``fs.normalise``)."""
    from .losses import LossWeights, supervised_loss

    cfg = net.config
    w0 = net.grid_head.weight.detach().clone()
    b0 = net.grid_head.bias.detach().clone()
    weight, bias = w0.clone().requires_grad_(True), b0.clone().requires_grad_(True)
    opt = torch.optim.Adam([weight, bias], lr=fs.lr)
    lw = LossWeights(sup_disparity=1.0, sup_disparity_grad=fs.w_grad)
    rng = np.random.default_rng(fs.seed)
    norms = {v[0].name: _spread(v[0].train_target) if fs.normalise else 1.0 for v in train}
    procedural = procedural or []
    if procedural:
        real_spread = 1.0 if fs.normalise else float(np.median([_spread(v[0].train_target) for v in train]))
        norms.update({v[0].name: _spread(v[0].train_target) / real_spread for v in procedural})
    for _ in range(fs.iterations):
        opt.zero_grad(set_to_none=True)
        total = weight.new_zeros(())
        for _ in range(fs.batch):
            pool = procedural if procedural and fs.procedural_share > 0 and rng.random() < fs.procedural_share else train
            variants = pool[int(rng.integers(len(pool)))]
            f = variants[int(rng.integers(len(variants)))]
            d = head_disparity(weight, bias, f, cfg, small=True)
            sup = supervised_loss(d, f.train_target / norms[f.name], d.new_zeros((1, 3) + d.shape[-2:]), None, None,
                                  cfg.e_max, lw, scale_free=True)
            total = total + sup.total / fs.batch
        if fs.w_l2 > 0:
            total = total + fs.w_l2 * (((weight - w0) ** 2).sum() + ((bias - b0) ** 2).sum())
        total.backward()
        opt.step()
    return weight.detach(), bias.detach()


def _load(weights: Path, row_prior: bool):
    from .train import initial_weights
    from .unet import EstimatorNet

    cfg, state, record = initial_weights(weights, row_prior)
    net = EstimatorNet(cfg)
    net.load_state_dict(state)
    net.eval()
    return net, record


def main(argv: list[str] | None = None) -> int:
    from .infer import load_estimator, preferred_max_pixels
    from .real_data import find_real_pictures, scene_folds
    ap = argparse.ArgumentParser(prog="python -m rvr_addon.estimate.head_fit", description=__doc__.split("\n\n")[0])
    ap.add_argument("--real", type=Path, required=True)
    ap.add_argument("--init-from", type=Path, default=Path(__file__).parent / "weights" / "estimator.pt")
    ap.add_argument("-o", "--output", type=Path, required=True)
    ap.add_argument("--cv", type=int, default=0, help="leave-scene-out folds to score (0: none)")
    ap.add_argument("--folds", default=None, help="only these folds, e.g. 0,1,2")
    ap.add_argument("--no-all", action="store_true", help="do not fit and export the all-scenes model")
    ap.add_argument("--export-folds", action="store_true",
                    help="with --cv: also write OUT/fold<k>/estimator.pt and OUT/weights_per_scene.json, for "
                         "rvr eval-estimator --real-set DIR --weights-per-scene OUT/weights_per_scene.json")
    ap.add_argument("--row-prior", action="store_true")
    ap.add_argument("--iterations", type=int, default=600)
    ap.add_argument("--lr", type=float, default=1e-3)
    ap.add_argument("--batch", type=int, default=4)
    ap.add_argument("--normalise", action="store_true")
    ap.add_argument("--w-l2", type=float, default=0.0)
    ap.add_argument("--w-grad", type=float, default=0.5)
    ap.add_argument("--scales", default="1.0")
    ap.add_argument("--no-flips", action="store_true")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--procedural", type=Path, action="append", default=[],
                    help="an `rvr procedural` dataset to mix into the fit (repeatable)")
    ap.add_argument("--procedural-share", type=float, default=0.3,
                    help="share of each batch drawn from --procedural frames (default 0.3)")
    ap.add_argument("--procedural-limit", type=int, default=0, help="at most this many procedural frames (0: all)")
    a = ap.parse_args(argv)
    torch.set_num_threads(a.threads)
    t0 = time.perf_counter()
    net, record = _load(a.init_from, a.row_prior)
    start = load_estimator(a.init_from)
    max_pixels = preferred_max_pixels(start)
    start_wall_s = float(start.header.get("wall_time_s") or 0.0)
    pictures = find_real_pictures(a.real)
    scales = tuple(float(s) for s in a.scales.split(","))
    prepared = prepare(net, pictures, max_pixels, scales, not a.no_flips, progress=True)
    fs = FitSettings(a.iterations, a.lr, a.batch, a.normalise, a.w_l2, a.w_grad, a.seed,
                     a.procedural_share if a.procedural else 0.0)
    procedural = list(prepare_procedural(net, a.procedural, max_pixels, not a.no_flips, a.procedural_limit,
                                         progress=True).values()) if a.procedural else None
    a.output.mkdir(parents=True, exist_ok=True)
    cfg = net.config
    result: dict = {"settings": _settings(a),
                    "max_pixels": max_pixels}
    if a.cv:
        folds = scene_folds(pictures, a.cv)
        chosen = range(len(folds)) if a.folds is None else [int(k) for k in a.folds.split(",")]
        rows: list[dict] = []
        per_scene: dict[str, str] = {}
        for k in chosen:
            held = set(folds[k])
            train = [v for n, v in prepared.items() if v[0].scene not in held]
            weight, bias = fit_head(net, train, fs, procedural)
            if a.export_folds:
                _export(net, weight, bias, a.output / f"fold{k}" / "estimator.pt", record, a, t0, len(train),
                        max_pixels, start_wall_s)
                per_scene.update({s: str(a.output / f"fold{k}" / "estimator.pt") for s in held})
            for n, v in prepared.items():
                if v[0].scene in held:
                    rows.append({"name": n, "scene": v[0].scene, "fold": k,
                                 "affine_error": picture_error(weight, bias, v[0], cfg),
                                 "before": picture_error(net.grid_head.weight, net.grid_head.bias, v[0], cfg),
                                 "ramp_error": ramp_error(v[0])})
            print(f"fold {k}: {_summary([r for r in rows if r['fold'] == k])}", file=sys.stderr)
        if a.export_folds:
            (a.output / "weights_per_scene.json").write_text(json.dumps(per_scene, indent=1))
        result["cv_rows"] = rows
        result["cv"] = _summary(rows)
        result["cv_per_fold"] = {k: _summary([r for r in rows if r["fold"] == k]) for k in chosen}
        print(f"leave-scene-out: {result['cv']}", file=sys.stderr)
    if not a.no_all:
        weight, bias = fit_head(net, list(prepared.values()), fs, procedural)
        _export(net, weight, bias, a.output / "estimator.pt", record, a, t0, len(pictures), max_pixels, start_wall_s)
    result["wall_s"] = time.perf_counter() - t0
    (a.output / "head_fit.json").write_text(json.dumps(result, indent=1))
    return 0


def _export(net, weight, bias, path: Path, record: dict, a, t0: float, n_pictures: int, max_pixels: int,
            start_wall_s: float) -> None:
    """Write the net with this grid head (a copy: ``net`` keeps the starting head); its wall time is
    the starting weights' ``start_wall_s`` plus this run's so far."""
    import copy

    from .train import export_weights

    out = copy.deepcopy(net)
    with torch.no_grad():
        out.grid_head.weight.copy_(weight)
        out.grid_head.bias.copy_(bias)
    training = {"head_fit": _settings(a), "init_from": record, "real_pictures": n_pictures,
                "note": "grid_head refitted on real pictures; every other layer (and so E) unchanged"}
    export_weights(out, path, iterations=(record.get("iterations") or 0),
                   wall_time_s=start_wall_s + time.perf_counter() - t0, training=training,
                   inference_max_pixels=max_pixels)


def _settings(a: argparse.Namespace) -> dict:
    """The command line's settings as JSON values (paths as strings)."""
    def plain(v):
        if isinstance(v, Path):
            return str(v)
        return [plain(x) for x in v] if isinstance(v, list) else v

    return {k: plain(v) for k, v in vars(a).items()}


def _summary(rows: list[dict]) -> dict:
    mid = [r for r in rows if r["name"].startswith("middlebury")]
    if not mid:
        return {}
    return {"views": len(mid), "affine_error": float(np.mean([r["affine_error"] for r in mid])),
            "before": float(np.mean([r["before"] for r in mid])),
            "ramp_error": float(np.mean([r["ramp_error"] for r in mid])),
            "better_than_ramp_share": float(np.mean([r["affine_error"] < r["ramp_error"] for r in mid]))}


if __name__ == "__main__":
    raise SystemExit(main())
