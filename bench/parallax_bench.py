"""Benchmark of the parallax depth cue (rvr_addon/depth/parallax.py) on real RGB-D video.

    .venv/bin/python bench/parallax_bench.py [--data ../shared/data] [--frames N] [--sheets DIR]

Per clip (hololens_office, tum_fr1_rpy_window) and intrinsics (``true``: the data set's K;
``guess``: the product's default, 66 deg FOV, centred) it prints the per-frame affine-invariant
error of the cue's inverse depth against 1/z (estimate.evaluate.affine_invariant_error: 0
perfect, 1 = a constant; scale and shift fitted per frame):

- ``trusted``: over GT pixels with confidence > 0.5, with ``coverage`` (share of the GT-valid
  pixels trusted) and ``parallax_frames`` (share of frames with a non-empty cue);
- ``filled``: over all GT-valid pixels after filling the cue's holes with the nearest known
  value (a frame without any cue counts as 1.0, a constant);
- ``ramp``: the same for the "nearer toward the bottom" vertical ramp (the trivial prior);
- ``clip``: one scale and shift fitted over the trusted pixels of the WHOLE clip (does the scale
  hold across frames?), and ``scale_spread``: the spread (std of log) over frames of the
  per-frame median of cue / GT on trusted pixels (0 = one scale for the clip);

- ``photometric_contradicted_median``: the median over frames of the share of trusted pixels the
  photometric check (a plane sweep, rvr_addon/depth/sweep.py) contradicted (0 without the check);
- ``focal_ratio``: the focal length the cue used (info ``focal_px``; with ``guess``, refined from
  the tracks) over the data set's;

for kivy_cityCC0 (no ground truth) the coverage, the frames with parallax and the median
signal to noise of its frames (:func:`self_consistency`); and the speed (s per frame of
ParallaxEstimator.maps, frames already decoded, focal refinement included; wall and CPU time)
at 640x360 and 1920x1080 input (``--speed-only``: that alone). The last stdout line is one flat
JSON object (DESIGN.md "Benchmarks").
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from rvr_addon.depth.parallax import ParallaxEstimator  # noqa: E402
from rvr_addon.depth.real_video import open_rgbd_clip  # noqa: E402
from rvr_addon.estimate.evaluate import affine_invariant_error, colour_map, vertical_ramp  # noqa: E402

CLIPS = {"hololens": "hololens_office", "tum": "tum_fr1_rpy_window"}


def fill_nearest(q: np.ndarray) -> np.ndarray | None:
    """NaN holes filled with the nearest known value (None when nothing is known)."""
    known = np.isfinite(q)
    if not known.any():
        return None
    if known.all():
        return q
    _, labels = cv2.distanceTransformWithLabels((~known).astype(np.uint8), cv2.DIST_L2, 5,
                                                labelType=cv2.DIST_LABEL_PIXEL)
    ys, xs = np.nonzero(known)
    lut = np.zeros(labels.max() + 1, np.float32)
    lut[labels[ys, xs]] = q[ys, xs]
    return lut[labels]


def sheet_row(rgb: np.ndarray, gt: np.ndarray | None, q: np.ndarray, conf: np.ndarray, width: int = 320) -> np.ndarray:
    """frame | GT inverse depth (or blank) | cue inverse depth (trusted, percentiles) | confidence."""
    ok = np.isfinite(q) & (conf > 0.5)
    lo, hi = (np.percentile(q[ok], [2, 98]) if ok.sum() > 10 else (0.0, 1.0))
    tiles = [rgb]
    if gt is not None:
        g = gt[np.isfinite(gt)]
        tiles.append(colour_map(gt, *np.percentile(g, [2, 98]), cv2.COLORMAP_TURBO) if g.size else np.zeros_like(rgb))
    else:
        tiles.append(np.zeros_like(rgb))
    tiles.append(colour_map(np.where(ok, q, np.nan), lo, hi, cv2.COLORMAP_TURBO))
    tiles.append(np.repeat((np.clip(conf, 0, 1) * 255).astype(np.uint8)[..., None], 3, 2))
    h = int(round(rgb.shape[0] * width / rgb.shape[1]))
    return np.concatenate([cv2.resize(t, (width, h), interpolation=cv2.INTER_AREA) for t in tiles], 1)


def evaluate_clip(root: Path, K: np.ndarray | None, frames: int | None, sheet_every: int = 0,
                  sheet_path: Path | None = None) -> dict[str, float]:
    clip = open_rgbd_clip(root)
    n = len(clip) if frames is None else min(frames, len(clip))
    est = ParallaxEstimator(K=K)
    trusted, filled, ramp, cover, ratios, nonempty = [], [], [], [], [], 0
    contradicted: list[float] = []
    focal = None
    pool_p, pool_g, rows = [], [], []
    t0 = time.perf_counter()
    for i, m in enumerate(est.maps(clip.rgb_frames(0, n))):
        f = clip.frame(i)
        gt = f.inverse_depth
        valid = np.isfinite(gt)
        tr = valid & (m.confidence > 0.5)
        nonempty += bool(m.info.get("parallax"))
        if m.info.get("photometric_contradicted") is not None:
            contradicted.append(float(m.info["photometric_contradicted"]))
        if focal is None and m.info.get("focal_px"):
            focal = float(m.info["focal_px"])
        cover.append(float(tr.sum() / max(valid.sum(), 1)))
        ramp.append(affine_invariant_error(vertical_ramp(*gt.shape), gt, valid))
        if tr.sum() >= 100:
            trusted.append(affine_invariant_error(m.inverse_depth, gt, tr))
            ratios.append(float(np.median(m.inverse_depth[tr] / gt[tr])))
            pool_p.append(m.inverse_depth[tr][::5])
            pool_g.append(gt[tr][::5])
        full = fill_nearest(np.where(m.confidence > 0.5, m.inverse_depth, np.nan))
        filled.append(1.0 if full is None else affine_invariant_error(full, gt, valid))
        if sheet_every and i % sheet_every == sheet_every // 2:
            rows.append(sheet_row(f.rgb, gt, m.inverse_depth, m.confidence))
        print(f"  {root.name} {i:3d} nb={m.info.get('neighbours')} trusted={trusted[-1] if tr.sum() >= 100 else float('nan'):.3f} "
              f"cov={cover[-1]:.2f} filled={filled[-1]:.3f} ramp={ramp[-1]:.3f}", file=sys.stderr)
    elapsed = time.perf_counter() - t0
    if rows and sheet_path is not None:
        sheet_path.parent.mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(sheet_path), np.concatenate(rows, 0)[..., ::-1])
    out = {
        "affine_error": float(np.mean(trusted)) if trusted else 1.0,
        "affine_error_median": float(np.median(trusted)) if trusted else 1.0,
        "coverage": float(np.mean(cover)),
        "parallax_frames": nonempty / max(n, 1),
        "filled_affine_error": float(np.mean(filled)),
        "ramp_affine_error": float(np.mean(ramp)),
        "clip_affine_error": (affine_invariant_error(np.concatenate(pool_p), np.concatenate(pool_g))
                              if pool_p else 1.0),
        "scale_spread": float(np.std(np.log(ratios))) if len(ratios) > 1 else 0.0,
        "photometric_contradicted_median": float(np.median(contradicted)) if contradicted else 0.0,
        "frames": float(n),
        "focal_ratio": (focal / float(clip.K[0, 0])) if focal else 0.0,
        "eval_s_per_frame": elapsed / max(n, 1),
    }
    return out


def self_consistency(path: Path, frames: int) -> dict[str, float]:
    """A clip without ground truth (kivy_cityCC0: distant buildings, a slow move): the share of
    trusted pixels and of frames with parallax, and the median of the frames' signal to noise
    (info ``snr``: depth structure over the disagreement of independent measurements)."""
    cap = cv2.VideoCapture(str(path))
    imgs = []
    while len(imgs) < frames:
        ok, bgr = cap.read()
        if not ok:
            break
        imgs.append(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB))
    cap.release()
    cover, snr, contradicted, nonempty = [], [], [], 0
    for m in ParallaxEstimator().maps(iter(imgs)):
        cover.append(float(np.mean(m.confidence > 0.5)))
        nonempty += bool(m.info.get("parallax"))
        if m.info.get("snr") is not None:
            snr.append(float(m.info["snr"]))
        if m.info.get("photometric_contradicted") is not None:
            contradicted.append(float(m.info["photometric_contradicted"]))
    n = max(len(imgs), 1)
    return {"coverage": float(np.mean(cover)) if cover else 0.0, "parallax_frames": nonempty / n,
            "snr_median": float(np.median(snr)) if snr else 0.0,
            "photometric_contradicted_median": float(np.median(contradicted)) if contradicted else 0.0,
            "frames": float(len(imgs))}


def speed(root: Path, size: tuple[int, int], frames: int) -> tuple[float, float]:
    """(wall, CPU) s per frame of ParallaxEstimator.maps on ``frames`` frames resized to ``size``
    (decoded first). The CPU time (this process, every thread) is what to compare on a shared
    machine, with ``--threads 1``."""
    clip = open_rgbd_clip(root)
    imgs = [cv2.resize(clip.frame(i).rgb, size, interpolation=cv2.INTER_LINEAR) for i in range(frames)]
    est = ParallaxEstimator()
    t0, c0 = time.perf_counter(), time.process_time()
    for _ in est.maps(iter(imgs)):
        pass
    return (time.perf_counter() - t0) / frames, (time.process_time() - c0) / frames


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", default=str(Path(__file__).resolve().parents[2] / "shared" / "data"))
    ap.add_argument("--frames", type=int, default=None, help="frames per clip (default all)")
    ap.add_argument("--speed-frames", type=int, default=24)
    ap.add_argument("--sheets", default=None, help="folder for contact sheets (frame | GT | cue | confidence)")
    ap.add_argument("--threads", type=int, default=1, help="cv2 threads (default 1: the other core is shared)")
    ap.add_argument("--speed-only", action="store_true", help="only the speed keys (no accuracy figures)")
    args = ap.parse_args()
    cv2.setNumThreads(args.threads)
    base = Path(args.data) / "real_video_depth"
    result: dict[str, float] = {}
    for key, folder in ({} if args.speed_only else CLIPS).items():
        root = base / folder
        if not root.is_dir():
            print(f"skip {key}: {root} missing", file=sys.stderr)
            continue
        K = open_rgbd_clip(root).K
        for kname, kk in (("true_k", K), ("guess_k", None)):
            sheet = Path(args.sheets) / f"{key}_{kname}.png" if args.sheets else None
            every = 12 if key == "hololens" else 6
            res = evaluate_clip(root, kk, args.frames, every if sheet else 0, sheet)
            prefix = f"estimate.parallax.{key}" if kname == "true_k" else f"estimate.parallax.{key}.guess_k"
            for name, v in res.items():
                result[f"{prefix}.{name}"] = round(float(v), 4)
            print(f"{key} {kname}: " + ", ".join(f"{k}={v:.3f}" for k, v in res.items()), file=sys.stderr)
    kivy = Path(args.data) / "clips" / "kivy_cityCC0.mpg"
    if kivy.is_file() and not args.speed_only:
        for name, v in self_consistency(kivy, 60).items():
            result[f"estimate.parallax.kivy.{name}"] = round(float(v), 4)
    holo = base / CLIPS["hololens"]
    if holo.is_dir():
        for name, size in (("360p", (640, 360)), ("1080p", (1920, 1080))):
            wall, cpu = speed(holo, size, args.speed_frames)
            result[f"estimate.parallax.{name}.s_per_frame"] = round(wall, 4)
            result[f"estimate.parallax.{name}.cpu_s_per_frame"] = round(cpu, 4)
    print(json.dumps(result))


if __name__ == "__main__":
    main()
