"""Evaluation of trained estimator weights against ground truth (``rvr eval-estimator``).

```
rvr eval-estimator --weights W.pt --data HELDOUT_DATASET [--motorcycle] -o REPORT
                   [--max-frames N] [--every K] [--compare-frames K] [--force]
                   [--real-set DIR [--weights-per-scene JSON]] [--depth-method network|auto|people]
                   [--real-video DIR [--depth-methods auto,network] [--video-frames N]] [--hfov DEG]
                   [--aperture DIR [--aperture-size PX]]
```

Real material (``--real-set``, ``--real-video``, ``--aperture``: real pictures with measured
depth, real RGB-D video with poses, real aperture photos) is scored by :mod:`.evaluate_real`
(its docstring defines those keys); ``--depth-method`` also sets what ``--real`` and
``--motorcycle`` run (default ``network``, the figures below).

**Harness clips** (``--data``, sintel_eval/DATASET.md; use clips the weights were *not* trained
on): every complete frame (or every K-th, at most N per clip) of every clip is run through the
network at its native size, and compared with ``gt/disparity`` and ``gt/hdr``:

* ``estimate.disparity_rms_px``: per frame, the RMS of ``s D + t - D_gt`` after the
  least-squares scale s and shift t of that frame (DESIGN units: px of blur radius at aperture 1
  at the native width), averaged over the frames. Scale and shift are fitted because focus and
  aperture set them at render time anyway; the un-fitted figure is
  ``estimate.disparity_rms_px_absolute`` (the network is trained in DESIGN units, so this one
  matters too) and the fitted scale is ``estimate.disparity_fit_scale`` (1 = right scale).
* ``estimate.disparity_rms_px_baseline``: the same for a trivial prior, a vertical ramp
  ("nearer toward the bottom of the frame": the row index), fitted by the same scale and shift;
  ``estimate.disparity_rms_px_constant``: for a constant (the RMS about the frame's mean, i.e.
  the standard deviation of D_gt).
* ``estimate.disparity_corr``: Pearson correlation of D and D_gt, averaged over the frames.
* ``estimate.hdr_log_mse_saturated``: mean over the saturated input pixels (brightest channel
  >= 254/255) and their 3 channels of ``(ln L - ln L_gt)^2``, ``L = srgb_to_linear(I) exp(50 E)``
  our radiance, ``L_gt`` the true one (both floored at 1e-3), pooled over all frames;
  ``..._no_recovery`` is the same with E = 0 (the clipped input as is).

**Middlebury 2014 motorcycle** (``--motorcycle``; the left view and its disparity shipped with
scikit-image, ``skimage.data.stereo_motorcycle()``, 741 x 500): ``estimate.motorcycle.
affine_invariant_error`` is the RMS of ``s D + t - d_gt`` after the least-squares scale and shift
over the valid pixels (finite, > 0; 93% of the frame) **divided by the standard deviation of
d_gt** over those pixels: 0 is perfect, 1 is what the best constant achieves (it equals
``sqrt(1 - r^2)``, r the correlation). A negative s is allowed (stereo disparity grows toward
the camera, ours away from the focal plane). ``estimate.motorcycle.baseline_error``: the same
for the vertical ramp.

REPORT holds ``summary.json`` (flat keys above, numbers only), ``README.md`` (the table, the
settings, how to read it) and ``compare_*.png`` (input | GT D | ours D as predicted, in the
GT's colour range | ours D after the scale+shift fit). The folder is written under a temp name
and renamed at the end; an existing REPORT is replaced only with ``--force`` and only if it is
an earlier report.
"""
from __future__ import annotations

import json
import logging
import math
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator

import numpy as np

from ..errors import InputError, OutputError
from ..io.paths import replace_folder, temp_sibling

log = logging.getLogger(__name__)

LOG_FLOOR = 1e-3
"""Radiance floor before the logarithm of the HDR error."""
SATURATED = 254.0 / 255.0


# ------------------------------------------------------------------------------ metrics


def _valid(pred: np.ndarray, gt: np.ndarray, mask: np.ndarray | None) -> np.ndarray:
    ok = np.isfinite(pred) & np.isfinite(gt)
    return ok if mask is None else ok & mask.astype(bool)


def fit_scale_shift(pred: np.ndarray, gt: np.ndarray, mask: np.ndarray | None = None) -> tuple[float, float]:
    """Least-squares (s, t) minimising sum over valid pixels of (s pred + t - gt)^2.

    Valid = finite in both (and ``mask``). A flat prediction gets s = 0, t = mean(gt).
    Raises ValueError when no pixel is valid.
    """
    ok = _valid(pred, gt, mask)
    if not ok.any():
        raise ValueError("no valid pixel to fit a scale and shift on")
    p, g = pred[ok].astype(np.float64), gt[ok].astype(np.float64)
    pc = p - p.mean()
    var = float(pc @ pc)
    if var <= 1e-12 * max(float(p @ p), 1e-30):
        return 0.0, float(g.mean())
    s = float(pc @ (g - g.mean())) / var
    return s, float(g.mean() - s * p.mean())


def affine_rms(pred: np.ndarray, gt: np.ndarray, mask: np.ndarray | None = None) -> float:
    """RMS of s pred + t - gt over the valid pixels after the least-squares (s, t) (gt's unit)."""
    s, t = fit_scale_shift(pred, gt, mask)
    ok = _valid(pred, gt, mask)
    r = s * pred[ok].astype(np.float64) + t - gt[ok].astype(np.float64)
    return float(np.sqrt(np.mean(r * r)))


def affine_invariant_error(pred: np.ndarray, gt: np.ndarray, mask: np.ndarray | None = None) -> float:
    """:func:`affine_rms` divided by the standard deviation of gt over the same pixels.

    0 = perfect up to scale and shift; 1 = no better than a constant (= sqrt(1 - r^2)).
    A constant gt (std 0) gives 0 for a perfect fit, else inf.
    """
    ok = _valid(pred, gt, mask)
    rms = affine_rms(pred, gt, mask)
    std = float(np.std(gt[ok].astype(np.float64)))
    if std == 0.0:
        return 0.0 if rms == 0.0 else math.inf
    return rms / std


def pearson(pred: np.ndarray, gt: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Pearson correlation over the valid pixels (0 when either side is flat)."""
    ok = _valid(pred, gt, mask)
    p, g = pred[ok].astype(np.float64), gt[ok].astype(np.float64)
    p, g = p - p.mean(), g - g.mean()
    den = math.sqrt(float(p @ p) * float(g @ g))
    return float(p @ g) / den if den > 0 else 0.0


def vertical_ramp(height: int, width: int) -> np.ndarray:
    """The trivial depth prior: (H, W) float32 row index / (H - 1), 0 at the top, 1 at the bottom
    ("nearer toward the bottom"; its sign and scale come from the fit)."""
    col = np.arange(height, dtype=np.float32) / max(height - 1, 1)
    return np.repeat(col[:, None], width, axis=1)


def saturated_mask(srgb: np.ndarray) -> np.ndarray:
    """(H, W) bool: the brightest channel of an sRGB image (uint8 or float in [0, 1]) is >= 254/255."""
    x = srgb.astype(np.float32) / 255.0 if srgb.dtype == np.uint8 else srgb.astype(np.float32)
    return x.max(axis=-1) >= SATURATED - 1e-6


def log_radiance_sq_error(pred: np.ndarray, gt: np.ndarray, mask: np.ndarray) -> tuple[float, int]:
    """(sum, count) of (ln max(pred, 1e-3) - ln max(gt, 1e-3))^2 over the masked pixels' channels.

    pred, gt: (H, W, 3) linear radiance; mask: (H, W) bool. Sums pool over frames.
    """
    m = mask.astype(bool)
    if not m.any():
        return 0.0, 0
    d = np.log(np.maximum(pred[m], LOG_FLOOR).astype(np.float64)) - np.log(np.maximum(gt[m], LOG_FLOOR).astype(np.float64))
    return float(np.sum(d * d)), int(d.size)


# ------------------------------------------------------------------------------ data


@dataclass
class EvalFrame:
    """One evaluation frame: uint8 RGB input, GT disparity (DESIGN units, NaN unknown), GT
    radiance (None when the frame has none)."""

    name: str
    image: np.ndarray
    disparity: np.ndarray
    radiance: np.ndarray | None


def harness_frames(root: str | Path, max_frames: int | None = None, every: int = 1,
                   skipped: list[str] | None = None) -> Iterator[EvalFrame]:
    """Stream the complete frames of every harness clip under ``root`` (every ``every``-th, at most
    ``max_frames`` per clip). Incomplete or unreadable frames are skipped, their reasons appended
    to ``skipped``. Raises InputError when ``root`` holds no clip."""
    from ..io.video import read_image_rgb8
    from .data import find_harness_clips, frame_complete, read_gt_disparity, read_gt_radiance

    clips = find_harness_clips(root)
    if not clips:
        raise InputError(f"'{root}' holds no harness clip (no manifest.json of format 'rvr-laaf-harness/...'); "
                         "generate held-out clips with `python -m sintel_eval generate --seed K -o DIR/clipK`.")
    skipped = skipped if skipped is not None else []
    for clip in clips:
        manifest = json.loads((clip / "manifest.json").read_text())
        n = int((manifest.get("config") or {}).get("frames") or 0)
        used = 0
        for frame in range(1, n + 1, max(every, 1)):
            if max_frames is not None and used >= max_frames:
                break
            why = frame_complete(clip, frame, manifest.get("config_hash"))
            stem = f"frame_{frame:05d}"
            if why is None:
                try:
                    image = read_image_rgb8(clip / "input" / f"{stem}.png")
                    size = (image.shape[1], image.shape[0])
                    d = read_gt_disparity(clip / "gt" / "disparity" / f"{stem}.exr", size)
                    hdr_path = clip / "gt" / "hdr" / f"{stem}.exr"
                    rad = read_gt_radiance(hdr_path, size) if hdr_path.is_file() else None
                except (InputError, OSError, ValueError) as ex:
                    why = str(ex)
            if why is not None:
                skipped.append(f"{clip.name}/{stem}: {why}")
                log.warning("skipping %s/%s: %s", clip.name, stem, why)
                continue
            used += 1
            yield EvalFrame(f"{clip.name}/{stem}", image, d, rad)


def real_pair(image: Path, disparity: Path) -> tuple[str, np.ndarray, np.ndarray]:
    """(name, image (H, W, 3) uint8 RGB, ground truth (H, W) float32, NaN where invalid) of a real
    picture and its disparity (any affine of inverse depth: stereo disparity, a depth sensor's
    1/Z) as EXR/PNG/NPY/NPZ. Values <= 0 or non-finite are invalid (Middlebury's 0 = unknown).
    The name is the image's stem. Raises InputError naming the file."""
    from ..io.maps import read_map
    from ..io.video import read_image_rgb8

    try:
        rgb = read_image_rgb8(image)
    except Exception as ex:
        raise InputError(f"--real image {image}: {ex}") from ex
    gt = read_map(Path(disparity), "disparity")
    if gt.shape != rgb.shape[:2]:
        raise InputError(f"--real disparity {disparity} is {gt.shape[1]}x{gt.shape[0]} but the image {image} is "
                         f"{rgb.shape[1]}x{rgb.shape[0]}; give the map of that very view")
    gt = np.where(np.isfinite(gt) & (gt > 0), gt, np.nan).astype(np.float32)
    if np.isfinite(gt).sum() < 2:
        raise InputError(f"--real disparity {disparity} has no valid pixel (all <= 0 or not finite)")
    name = "".join(c if c.isalnum() or c in "-_" else "_" for c in Path(image).stem)
    return name, rgb, gt


def motorcycle() -> tuple[np.ndarray, np.ndarray]:
    """(left view (500, 741, 3) uint8 RGB, disparity (500, 741) float32 with NaN where invalid)
    of Middlebury 2014 'Motorcycle' as shipped in scikit-image (``skimage.data.stereo_motorcycle``).

    Invalid pixels (inf, NaN or <= 0 in motorcycle_disp.npz) become NaN.
    """
    try:
        from skimage import data as skdata
    except ImportError as ex:
        raise InputError("--motorcycle needs scikit-image (the Middlebury motorcycle pair ships with it): "
                         "run scripts/setup.sh (requirements.txt pins scikit-image)") from ex
    left, _right, disp = skdata.stereo_motorcycle()
    disp = np.asarray(disp, dtype=np.float32)
    disp = np.where(np.isfinite(disp) & (disp > 0), disp, np.nan).astype(np.float32)
    return np.ascontiguousarray(left[..., :3], dtype=np.uint8), disp


# ------------------------------------------------------------------------------ pictures


def colour_map(d: np.ndarray, lo: float, hi: float, colormap: int | None = None) -> np.ndarray:
    """(H, W, 3) uint8 RGB picture of a map over [lo, hi] (OpenCV colormap, viridis by default);
    non-finite pixels black."""
    import cv2

    u = np.clip((np.nan_to_num(d, nan=lo) - lo) / max(hi - lo, 1e-9), 0, 1)
    cmap = cv2.COLORMAP_VIRIDIS if colormap is None else colormap
    rgb = cv2.applyColorMap((u * 255).astype(np.uint8), cmap)[..., ::-1]
    rgb = rgb.copy()
    rgb[~np.isfinite(d)] = 0
    return rgb


def comparison_image(image: np.ndarray, gt: np.ndarray, pred: np.ndarray, path: Path,
                     show_raw: bool = True) -> None:
    """Write input | GT D | ours D (as predicted, GT colour range) | ours D (scale+shift fitted)
    side by side as a PNG (viridis over the GT's 2-98th percentiles; black = no GT)."""
    import cv2

    ok = np.isfinite(gt)
    lo, hi = (np.percentile(gt[ok], [2, 98]) if ok.any() else (0.0, 1.0))
    s, t = fit_scale_shift(pred, gt)
    panels = [("input", image), ("GT D", colour_map(gt, lo, hi))]
    if show_raw:
        panels.append(("ours D", colour_map(pred, lo, hi)))
    panels.append((f"ours D fitted (x{s:.2g})", colour_map(s * pred + t, lo, hi)))
    h = image.shape[0]
    scale = max(1, int(round(160 / h))) if h < 160 else 1
    tiles = []
    for label, tile in panels:
        tile = np.ascontiguousarray(tile, dtype=np.uint8)
        if scale > 1:
            tile = cv2.resize(tile, (tile.shape[1] * scale, tile.shape[0] * scale), interpolation=cv2.INTER_NEAREST)
        tile = tile.copy()
        cv2.putText(tile, label, (4, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 3, cv2.LINE_AA)
        cv2.putText(tile, label, (4, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (255, 255, 255), 1, cv2.LINE_AA)
        tiles.append(tile)
    gap = np.full((tiles[0].shape[0], 4, 3), 255, np.uint8)
    row = np.concatenate([x for t in tiles for x in (t, gap)][:-1], axis=1)
    if not cv2.imwrite(str(path), row[..., ::-1]):
        raise OutputError(f"cannot write '{path}'; check free space and permissions")


# ------------------------------------------------------------------------------ the run


@dataclass
class EvalSettings:
    """What ``rvr eval-estimator`` takes (weights None = the shipped weights)."""

    output: Path
    weights: Path | None = None
    data: list[Path] = field(default_factory=list)
    motorcycle: bool = False
    max_frames: int | None = None
    every: int = 1
    compare_frames: int = 3
    force: bool = False
    max_pixels: int | None = None
    """Run the network's trunk on a copy shrunk to at most this many pixels (D is still sliced
    and E gated at full resolution; ``rvr estimate``'s default when None)."""
    real: list[tuple[Path, Path]] = field(default_factory=list)
    """Real pictures with ground truth: (image, disparity or inverse-depth map) pairs."""
    real_set: Path | None = None
    """A real_depth folder: every picture of real_data.find_real_pictures (evaluate_real)."""
    depth_method: str = "network"
    """Single pictures (--real-set, --real, --motorcycle, --aperture): network | auto | people."""
    weights_per_scene: Path | None = None
    """JSON {scene: weights file} for --real-set (leave-scene-out fold models)."""
    real_video: list[Path] = field(default_factory=list)
    """Real RGB-D clips with poses (HoloLens / TUM layout)."""
    depth_methods: list[str] = field(default_factory=lambda: ["auto", "network"])
    """--real-video: the depth methods run on each clip."""
    video_frames: int | None = None
    """--real-video: at most this many frames of a clip (None: all)."""
    hfov_deg: float | None = None
    """The geometric cues' field of view (rvr estimate --hfov; None: its default)."""
    aperture: Path | None = None
    """A folder of real aperture pairs (vabd_*/input + 1_8, ebb_*/input + target)."""
    aperture_size: int = 512
    """--aperture: long side (px) both photos are shrunk to."""


def _check_target(report: Path, force: bool) -> None:
    if not report.exists():
        return
    if not report.is_dir():
        raise OutputError(f"report path '{report}' is a file; choose another -o folder")
    if not force:
        raise OutputError(f"report folder '{report}' already exists; pass --force to replace it or choose another -o")
    if any(report.iterdir()) and not (report / "summary.json").is_file():
        raise OutputError(f"refusing to replace '{report}' with --force: it is not empty and holds no summary.json")


def _mean(values: list[float]) -> float:
    return float(np.mean(values)) if values else float("nan")


def evaluate(settings: EvalSettings, progress: bool = False) -> dict[str, float]:
    """Run the evaluation and write the report folder; returns the summary (flat keys).

    Raises InputError (no weights / unreadable weights / no data / no usable frame) naming the
    file and the fix, OutputError when the report folder may not be written.
    """
    from tqdm import tqdm

    from .infer import Estimator, default_weights, load_estimator

    s = settings
    if not s.data and not s.motorcycle and not s.real and s.real_set is None and not s.real_video \
            and s.aperture is None:
        raise InputError("nothing to evaluate: pass --data HELDOUT_DATASET (harness clips), --motorcycle, "
                         "--real IMAGE DISPARITY, --real-set DIR, --real-video DIR and/or --aperture DIR")
    pairs = [real_pair(Path(i), Path(d)) for i, d in s.real]  # bad files fail before any work
    seen: dict[str, int] = {}
    for k, (name, rgb, gt) in enumerate(pairs):  # two pictures of the same stem: name_2, name_3, ...
        seen[name] = seen.get(name, 0) + 1
        if seen[name] > 1:
            pairs[k] = (f"{name}_{seen[name]}", rgb, gt)
    report = Path(s.output)
    _check_target(report, s.force)
    model = load_estimator(s.weights if s.weights is not None else default_weights())
    est = Estimator(model, max_pixels=s.max_pixels)
    from .evaluate_real import picture_depth

    depth = picture_depth(s.depth_method, est, s.hfov_deg)  # single pictures (network: est itself)
    extra_md: list[str] = []
    summary: dict[str, float] = {}
    rows: list[dict] = []
    skipped: list[str] = []
    report.parent.mkdir(parents=True, exist_ok=True)
    tmp = temp_sibling(report, ".partial")
    tmp.mkdir()
    t_start = time.perf_counter()
    try:
        if s.data:
            rms, rms_base, rms_const, rms_abs, corr, scales = [], [], [], [], [], []
            sq_ours = sq_none = 0.0
            n_sat = 0
            seconds = 0.0
            picked = 0
            frames = [f for root in s.data for f in harness_frames(root, s.max_frames, s.every, skipped)]
            if not frames:
                raise InputError("no complete harness frame to evaluate under " + ", ".join(map(str, s.data))
                                 + (f" ({len(skipped)} skipped: {skipped[0]})" if skipped else ""))
            stride = max(1, len(frames) // max(s.compare_frames, 1))
            for i, fr in enumerate(tqdm(frames, desc="eval", unit="frame", disable=not progress)):
                t0 = time.perf_counter()
                d, e = est(fr.image)
                seconds += time.perf_counter() - t0
                gt = fr.disparity
                ok = np.isfinite(gt)
                if ok.sum() < 2:
                    skipped.append(f"{fr.name}: no valid ground-truth disparity")
                    continue
                fs, _ = fit_scale_shift(d, gt)
                row = {"frame": fr.name, "rms_px": affine_rms(d, gt),
                       "rms_baseline_px": affine_rms(vertical_ramp(*gt.shape), gt),
                       "rms_constant_px": float(np.std(gt[ok])),
                       "rms_absolute_px": float(np.sqrt(np.mean((d[ok] - gt[ok]) ** 2))),
                       "corr": pearson(d, gt), "fit_scale": fs}
                rms.append(row["rms_px"])
                rms_base.append(row["rms_baseline_px"])
                rms_const.append(row["rms_constant_px"])
                rms_abs.append(row["rms_absolute_px"])
                corr.append(row["corr"])
                scales.append(fs)
                if fr.radiance is not None:
                    from ..color import image_to_linear

                    sat = saturated_mask(fr.image)
                    lin = image_to_linear(fr.image).astype(np.float32)
                    a, n = log_radiance_sq_error(lin * np.exp(50.0 * e), fr.radiance, sat)
                    b, _ = log_radiance_sq_error(lin, fr.radiance, sat)
                    sq_ours, sq_none, n_sat = sq_ours + a, sq_none + b, n_sat + n
                    row["saturated_px"] = int(sat.sum())
                rows.append(row)
                if i % stride == 0 and picked < s.compare_frames:
                    comparison_image(fr.image, gt, d, tmp / f"compare_{fr.name.replace('/', '_')}.png")
                    picked += 1
            if not rows:
                raise InputError("no evaluable harness frame (every frame lacked valid ground truth)")
            summary.update({
                "estimate.disparity_rms_px": _mean(rms), "estimate.disparity_rms_px_baseline": _mean(rms_base),
                "estimate.disparity_rms_px_constant": _mean(rms_const),
                "estimate.disparity_rms_px_absolute": _mean(rms_abs), "estimate.disparity_corr": _mean(corr),
                "estimate.disparity_fit_scale": float(np.median(scales)),
                "estimate.frames": len(rows), "estimate.clips": len({r["frame"].split("/")[0] for r in rows}),
                "estimate.frames_skipped": len(skipped), "estimate.s_per_frame": seconds / len(rows),
                "estimate.saturated_values": n_sat,
            })
            if n_sat:
                summary["estimate.hdr_log_mse_saturated"] = sq_ours / n_sat
                summary["estimate.hdr_log_mse_saturated_no_recovery"] = sq_none / n_sat
        if s.motorcycle:
            left, disp = motorcycle()
            d, _ = depth(left)
            valid = np.isfinite(disp)
            summary["estimate.motorcycle.affine_invariant_error"] = affine_invariant_error(d, disp, valid)
            summary["estimate.motorcycle.baseline_error"] = affine_invariant_error(vertical_ramp(*disp.shape), disp,
                                                                                  valid)
            summary["estimate.motorcycle.corr"] = pearson(d, disp, valid)
            summary["estimate.motorcycle.valid_fraction"] = float(valid.mean())
            comparison_image(left, disp, d, tmp / "compare_motorcycle.png", show_raw=False)
        for name, rgb, gt in pairs:
            d, _ = depth(rgb)
            valid = np.isfinite(gt)
            key = f"estimate.real.{name}"
            summary[f"{key}.affine_invariant_error"] = affine_invariant_error(d, gt, valid)
            summary[f"{key}.baseline_error"] = affine_invariant_error(vertical_ramp(*gt.shape), gt, valid)
            summary[f"{key}.corr"] = pearson(d, gt, valid)
            summary[f"{key}.valid_fraction"] = float(valid.mean())
            comparison_image(rgb, gt, d, tmp / f"compare_real_{name}.png", show_raw=False)
        extra_md += _evaluate_real_material(s, est, depth, summary, tmp, progress)
        summary["estimate.eval_s"] = time.perf_counter() - t_start
        _write_report(tmp, summary, rows, skipped, model, s, extra_md, [p[0] for p in pairs])
        replace_folder(tmp, report)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return summary


def _evaluate_real_material(s: EvalSettings, est, depth, summary: dict, folder: Path, progress: bool) -> list[str]:
    """--real-set, --real-video and --aperture (:mod:`.evaluate_real`): keys into ``summary``,
    pictures into ``folder``; returns the README sections."""
    from . import evaluate_real as er

    md: list[str] = []
    if s.real_set is not None:
        weights_map = er.load_weights_map(s.weights_per_scene) if s.weights_per_scene is not None else None
        networks = er.SceneNetworks(est, str(est.model.path), weights_map, s.max_pixels)
        keys, rows, lines = er.evaluate_real_set(s.real_set, networks, s.depth_method, s.hfov_deg, folder, progress)
        summary.update(keys)
        (folder / "real_views.json").write_text(json.dumps(rows, indent=1))
        md += lines
    for clip in s.real_video:
        keys, lines = er.evaluate_video_clip(clip, list(s.depth_methods), est, s.hfov_deg, s.video_frames, folder,
                                             progress=progress)
        summary.update(keys)
        md += lines
    if s.aperture is not None:
        keys, lines = er.evaluate_aperture(s.aperture, depth, s.aperture_size, folder, progress)
        summary.update(keys)
        md += lines
    return md


def _fmt(v: float | None, digits: int = 3) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "n/a"
    return f"{v:.{digits}g}"


def _write_report(folder: Path, summary: dict, rows: list[dict], skipped: list[str], model, s: EvalSettings,
                  extra_md: list[str] | None = None, real_names: list[str] | None = None) -> None:
    g = summary.get
    (folder / "summary.json").write_text(json.dumps(summary, indent=1, sort_keys=True))
    (folder / "frames.json").write_text(json.dumps({"frames": rows, "skipped": skipped}, indent=1))
    hdr = model.header
    md = ["# Estimator evaluation", "",
          f"Weights: `{model.path}` (sha256 {model.model_hash}, {hdr.get('iterations', '?')} iterations, "
          f"config {json.dumps(hdr.get('config'))}).", ""]
    if s.max_pixels is not None:
        md += [f"The network's trunk ran on copies shrunk to at most {s.max_pixels} pixels (--max-pixels).", ""]
    if s.data:
        md += [f"Held-out harness data: {', '.join(f'`{p}`' for p in s.data)}: {g('estimate.frames', 0)} frames of "
               f"{g('estimate.clips', 0)} clip(s), {len(skipped)} skipped.", "",
               "| disparity (px at the native width, per frame, mean) | ours | vertical ramp | constant |",
               "|---|---|---|---|",
               f"| RMS after least-squares scale + shift | {_fmt(g('estimate.disparity_rms_px'))} | "
               f"{_fmt(g('estimate.disparity_rms_px_baseline'))} | {_fmt(g('estimate.disparity_rms_px_constant'))} |",
               f"| RMS as predicted (DESIGN units, no fit) | {_fmt(g('estimate.disparity_rms_px_absolute'))} | | |",
               f"| correlation with GT | {_fmt(g('estimate.disparity_corr'))} | | |",
               f"| fitted scale (median; 1 = right scale) | {_fmt(g('estimate.disparity_fit_scale'))} | | |", ""]
        if "estimate.hdr_log_mse_saturated" in summary:
            md += ["| HDR on saturated input pixels (brightest channel >= 254) | ours | E = 0 (no recovery) |",
                   "|---|---|---|",
                   f"| MSE of ln radiance ({g('estimate.saturated_values')} pixel-channels) | "
                   f"{_fmt(g('estimate.hdr_log_mse_saturated'))} | "
                   f"{_fmt(g('estimate.hdr_log_mse_saturated_no_recovery'))} |", ""]
        else:
            md += ["No saturated input pixel in the evaluated frames: no HDR figure.", ""]
    if s.motorcycle:
        md += ["Middlebury 2014 *Motorcycle* (left view, scikit-image's copy, 741x500; "
               f"{100 * g('estimate.motorcycle.valid_fraction', 0):.0f}% valid GT pixels):", "",
               "| affine-invariant error (RMS after scale + shift / std of GT disparity; 1 = a constant) | value |",
               "|---|---|",
               f"| ours | {_fmt(g('estimate.motorcycle.affine_invariant_error'))} |",
               f"| vertical ramp (nearer toward the bottom) | {_fmt(g('estimate.motorcycle.baseline_error'))} |", ""]
    for name in sorted(real_names if real_names is not None else
                       {k.split(".")[2] for k in summary if k.startswith("estimate.real.")}):
        key = f"estimate.real.{name}"
        md += [f"Real picture `{name}` ({100 * g(key + '.valid_fraction', 0):.0f}% valid GT pixels):", "",
               "| affine-invariant error (1 = a constant) | value |", "|---|---|",
               f"| ours | {_fmt(g(key + '.affine_invariant_error'))} |",
               f"| vertical ramp (nearer toward the bottom) | {_fmt(g(key + '.baseline_error'))} |", ""]
    md += list(extra_md or [])
    if s.depth_method != "network":
        md += [f"Single pictures (--real, --motorcycle, --real-set, --aperture) ran depth method `{s.depth_method}`.", ""]
    md += ["Pictures: `compare_*.png` = input | GT D | ours D as predicted (GT colour range) | ours D after the "
           "least-squares scale + shift (viridis over GT's 2-98th percentiles; black = no GT).", "",
           "How to read it: the disparity figures are fitted per frame because focus and aperture rescale and "
           "shift D at render time; a model that beats the ramp has learnt depth from image content. "
           "Definitions: `rvr_addon/estimate/evaluate.py`.", ""]
    if skipped:
        md += ["Skipped:", ""] + [f"- {x}" for x in skipped[:50]] + [""]
    (folder / "README.md").write_text("\n".join(md))
