"""The ablation report folder: summary.json, README.md, frames.csv, plots, comparison images
and videos. Called by :func:`.ablate.run_ablation` on a temp folder that is then moved into place.

    REPORT/summary.json           flat {dotted key: number} (DESIGN.md "Benchmarks and evaluation output")
    REPORT/README.md              tables (best value per column in bold), metric definitions, dataset
    REPORT/frames.csv             every per-frame figure of every run
    REPORT/plots/*.png            per-frame PSNR per variant; bar charts of every metric
    REPORT/compare/*.png          input | Cycles GT | each variant, with a zoom on the depth-edge band
    REPORT/videos/*.mp4           the same panels as H.264 videos, one per clip and track

summary.json keys: ``ablation.<variant>.<metric>`` (mean over every clip and track),
``ablation.<clip>.<variant>.<metric>`` (mean over the clip's tracks),
``ablation.<clip>.<track>.<variant>.<metric>`` (one run), ``ablation.<variant>.s_per_frame``,
run totals (``ablation.clips``, ``.clips_skipped``, ``.runs``, ``.frames``, ``.seconds``) and
the issue's checks as 1/0 (``ablation.check.*``). A figure with nothing to measure (NaN, e.g.
no highlight in a clip) is left out, so every value is a finite number.
"""
from __future__ import annotations

import csv
import json
import math
import re
from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np

from rvr_addon.color import to_uint8

from .metrics import display_srgb, edge_band, flat_regions
from .panels import comparison_image, crop_box, disparity_image, error_image, mask_image, video_frame
from .scoring import HIGHER_IS_BETTER, METRICS, aggregate

if TYPE_CHECKING:
    from .ablate import Ablation, RunResult
    from .reader import GTFrame

SUMMARY_METRICS: tuple[str, ...] = METRICS
HEADLINE_METRICS: tuple[str, ...] = ("psnr_srgb_db", "edge_band_psnr_srgb_db", "flicker", "bokeh_recall")
"""Metrics shown per clip and track in one table each (README.md)."""
"""Figures written to summary.json for every variant (see :mod:`.scoring`)."""

UNITS = {
    "psnr_srgb_db": "dB", "psnr_linear_db": "dB", "ssim_srgb": "", "ssim_linear": "",
    "edge_band_psnr_srgb_db": "dB", "edge_band_psnr_linear_db": "dB", "splotchiness_px": "px",
    "flicker": "sRGB", "flicker_exact": "sRGB", "flicker_exact_warped": "sRGB", "bokeh_recall": "",
}
TITLES = {
    "psnr_srgb_db": "PSNR sRGB", "psnr_linear_db": "PSNR linear", "ssim_srgb": "SSIM sRGB",
    "ssim_linear": "SSIM linear", "edge_band_psnr_srgb_db": "edge PSNR sRGB",
    "edge_band_psnr_linear_db": "edge PSNR linear", "splotchiness_px": "splotchiness",
    "flicker": "flicker", "flicker_exact": "flicker vs exact",
    "flicker_exact_warped": "warped flicker vs exact", "bokeh_recall": "bokeh recall",
}
FORMATS = {"psnr_srgb_db": ".2f", "psnr_linear_db": ".2f", "ssim_srgb": ".4f", "ssim_linear": ".4f",
           "edge_band_psnr_srgb_db": ".2f", "edge_band_psnr_linear_db": ".2f", "splotchiness_px": ".3f",
           "flicker": ".4f", "flicker_exact": ".4f", "flicker_exact_warped": ".4f",
           "bokeh_recall": ".3f"}

DEFINITIONS = """\
| metric | unit | what it measures (better) |
|---|---|---|
| PSNR sRGB | dB | 10 log10(1 / MSE) of the display sRGB encodings in [0, 1], MSE pooled over all frames of the run (higher) |
| PSNR linear | dB | the same on linear radiance clipped to the display range [0, 1], peak 1: errors in bright regions weigh more than in sRGB; energy above white is measured by bokeh recall instead (higher) |
| SSIM sRGB / linear | - | Wang et al. 2004, 11x11 Gaussian window (sigma 1.5), K1 0.01, K2 0.03, per RGB channel, mean over frames (higher) |
| edge PSNR sRGB / linear | dB | PSNR restricted to a band of {band} px around ground-truth depth discontinuities (neighbouring blur radii differ by > {jump} px): the edge artifacts of section 6.3 (higher) |
| splotchiness | px | standard deviation, within each frame, of the blur-size error a\\|D_used - f\\| - a\\|D_gt - f\\| inside flat ground-truth regions (blur-radius gradient < {grad} px/px, eroded {erode} px); 0 for every variant rendered from ground-truth disparity (lower) |
| flicker | sRGB | mean over consecutive frames of \\|(out_t - out_t-1) - (gt_t - gt_t-1)\\| in sRGB [0, 1]: frame-to-frame change beyond the ground truth's (lower) |
| flicker vs exact | sRGB | the same with, instead of Cycles' image, our renderer's output from the exact (ground-truth) disparity and HDR (the `ours_gt` row, which scores 0): the flicker the variant's inputs add, the part a temporal filter of D and E can remove; empty when `ours_gt` was not run (lower) |
| warped flicker vs exact | sRGB | motion-compensated: mean of \\|e_t - warp(e_t-1)\\| with e = out - (the `ours_gt` output), e_t-1 warped onto frame t along the input's optical flow (Farneback, full resolution; not the filter's DIS flow), over forward-backward-consistent pixels. "flicker vs exact" also counts an error that only moves with the scene (a wrong but steady blur on a panning wall changes every pixel); this counts errors that change along the motion. Not zero for a wrong but steady depth either: a defocused moving scene is not a rigid warp of its error image (parallax, occlusion edges), so compare rows with each other (lower) |
| bokeh recall | - | over the ground truth's defocused highlights (linear radiance > {hl} and blur radius >= {defocus} px), sum min(ours, gt) / sum gt: the share of the bokeh energy found (higher) |

Figures of a clip are means over its focus tracks; the overall figures are means over every clip and track.
"""


def _key(name: str) -> str:
    """A name usable as one part of a dotted summary key."""
    return re.sub(r"[^A-Za-z0-9_-]+", "_", str(name))


def _finite(value: float) -> bool:
    return isinstance(value, (int, float)) and math.isfinite(value)


def _runs(ab: "Ablation", *, clip: str | None = None, track: str | None = None,
          variant: str | None = None) -> list["RunResult"]:
    return [r for r in ab.runs if (clip is None or r.clip == clip) and (track is None or r.track == track)
            and (variant is None or r.variant == variant)]


def scopes(ab: "Ablation") -> list[tuple[str, list[str], dict[str, dict[str, float]]]]:
    """(title, key prefix parts, {variant: figures}) for the overall scope, each clip, each run."""
    names = [v.name for v in ab.variants]
    out = [("All clips and tracks", [], {v: aggregate([r.metrics for r in _runs(ab, variant=v)]) for v in names})]
    for clip in dict.fromkeys(r.clip for r in ab.runs):
        out.append((f"Clip {clip} (mean over tracks)", [clip],
                    {v: aggregate([r.metrics for r in _runs(ab, clip=clip, variant=v)]) for v in names}))
        for track in dict.fromkeys(r.track for r in _runs(ab, clip=clip)):
            out.append((f"Clip {clip}, track {track}", [clip, track],
                        {v: _runs(ab, clip=clip, track=track, variant=v)[0].metrics for v in names
                         if _runs(ab, clip=clip, track=track, variant=v)}))
    return out


def checks(ab: "Ablation") -> dict[str, bool]:
    """The issue's targets, where the variants involved ran: ours beats Blender's Defocus (sRGB
    PSNR) on every clip and track; occlusion-aware beats naive in the edge band on every one."""
    out: dict[str, bool] = {}
    pairs = {"ours_beats_blender_defocus_psnr_srgb": ("ours_gt", "blender_defocus", "psnr_srgb_db"),
             "ours_beats_naive_edge_band_psnr_srgb": ("ours_gt", "naive_gt", "edge_band_psnr_srgb_db")}
    for name, (a, b, metric) in pairs.items():
        verdicts = []
        for clip, track in dict.fromkeys((r.clip, r.track) for r in ab.runs):
            ra, rb = _runs(ab, clip=clip, track=track, variant=a), _runs(ab, clip=clip, track=track, variant=b)
            if ra and rb and _finite(ra[0].metrics[metric]) and _finite(rb[0].metrics[metric]):
                verdicts.append(ra[0].metrics[metric] > rb[0].metrics[metric])
        if verdicts:
            out[name] = all(verdicts)
    return out


def summary(ab: "Ablation") -> dict[str, float]:
    """The flat summary.json mapping (finite numbers only)."""
    out: dict[str, float] = {}
    for _, parts, table in scopes(ab):
        for variant, figures in table.items():
            for metric in SUMMARY_METRICS:
                value = figures.get(metric, float("nan"))
                if _finite(value):
                    out[".".join(["ablation", *map(_key, parts), _key(variant), metric])] = float(value)
    for v in ab.variants:
        runs = _runs(ab, variant=v.name)
        frames = sum(len(r.frames) for r in runs)
        if frames:
            out[f"ablation.{_key(v.name)}.s_per_frame"] = sum(r.seconds for r in runs) / frames
    out["ablation.clips"] = float(len(ab.clips))
    out["ablation.clips_skipped"] = float(len(ab.skipped))
    out["ablation.runs"] = float(len(ab.runs))
    out["ablation.frames"] = float(sum(len(r.frames) for r in _runs(ab, variant=ab.variants[0].name)))
    out["ablation.seconds"] = float(ab.seconds)
    for name, ok in checks(ab).items():
        out[f"ablation.check.{name}"] = 1.0 if ok else 0.0
    return out


# ----------------------------------------------------------------------------------------
# Markdown


def _fmt(metric: str, value: float) -> str:
    return format(value, FORMATS.get(metric, ".4g")) if _finite(value) else "–"


def metric_table(table: dict[str, dict[str, float]], labels: dict[str, str] | None = None) -> str:
    """Markdown table: one row per variant, one column per metric, the best of a column in bold
    (ties on the shown digits are all bold)."""
    labels = labels or {}
    head = "| variant | " + " | ".join(f"{TITLES[m]}{f' ({UNITS[m]})' if UNITS[m] else ''}" for m in METRICS) + " |"
    lines = [head, "|---|" + "---:|" * len(METRICS)]
    best: dict[str, str] = {}
    for m in METRICS:
        shown = [(float(_fmt(m, f[m])), _fmt(m, f[m])) for f in table.values() if _finite(f.get(m, float("nan")))]
        if shown:
            best[m] = (max if HIGHER_IS_BETTER[m] else min)(shown)[1]
    for variant, figures in table.items():
        cells = []
        for m in METRICS:
            text = _fmt(m, figures.get(m, float("nan")))
            cells.append(f"**{text}**" if best.get(m) == text and text != "–" else text)
        lines.append(f"| {labels.get(variant, variant)} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def run_table(ab: "Ablation", metric: str) -> str:
    """Markdown table of one metric: a row per clip and track, a column per variant, the best
    of each row in bold."""
    names = [v.name for v in ab.variants]
    lines = ["| clip / track | " + " | ".join(names) + " |", "|---|" + "---:|" * len(names)]
    for clip, track in dict.fromkeys((r.clip, r.track) for r in ab.runs):
        texts = [_fmt(metric, r[0].metrics[metric]) if (r := _runs(ab, clip=clip, track=track, variant=n)) else "–"
                 for n in names]
        shown = [float(t) for t in texts if t != "–"]
        best = (max if HIGHER_IS_BETTER[metric] else min)(shown) if shown else None
        cells = [f"**{t}**" if t != "–" and float(t) == best else t for t in texts]
        lines.append(f"| {clip} / {track} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def headline_table(ab: "Ablation") -> str:
    """The overall table (Markdown), also printed by the CLI."""
    return metric_table(scopes(ab)[0][2])


def _num(value) -> str:
    return format(value, ".4g") if isinstance(value, (int, float)) else str(value)


def _dataset_table(ab: "Ablation") -> str:
    lines = ["| clip | seed | script | size | frames | fps | f-number ref | K (px m) | tracks | complete |",
             "|---|---:|---|---|---:|---:|---:|---:|---|---|"]
    for c in ab.clips:
        lines.append(f"| {c['clip']} | {c['seed']} | {c['script']} | {c['size']} | {c['frames']} | {c['fps']:g} | "
                     f"{c['f_number_ref']} | {_num(c['K_px'])} | {', '.join(c['tracks'])} | {c['complete']} |")
    return "\n".join(lines)


def write_readme(ab: "Ablation", folder: Path, plots: list[Path], images: list[Path], videos: list[Path]) -> Path:
    """README.md of the report (tables, definitions, dataset, checks, figures)."""
    s = ab.settings
    rel = lambda p: p.relative_to(folder).as_posix()  # noqa: E731
    n_frames = sum(len(r.frames) for r in _runs(ab, variant=ab.variants[0].name))
    md = [f"# Artifact ablation against Cycles ground truth\n",
          f"Dataset `{ab.dataset}`: {len(ab.clips)} clip(s), {n_frames} scored frames per variant (frames x "
          f"focus tracks{f'; the first {ab.max_frames} frames of each clip' if ab.max_frames else ''}); "
          f"{len(ab.runs)} runs rendered and scored in {ab.seconds:.1f} s. Paper section 6.3; issue 3.\n",
          "## Variants\n", "| name | what |", "|---|---|"]
    md += [f"| `{v.name}` | {v.description} |" for v in ab.variants]
    if ab.unavailable:
        md += ["", "Not run here: " + "; ".join(f"`{n}` ({why})" for n, why in ab.unavailable) + "."]
    verdicts = checks(ab)
    if verdicts:
        md += ["", "## Checks (issue 3)\n"]
        md += [f"- {name.replace('_', ' ')}: **{'yes' if ok else 'NO'}** (every clip and track)"
               for name, ok in verdicts.items()]
    labels = {v.name: v.name for v in ab.variants}
    (title, _, overall), *per_clip = scopes(ab)
    md += ["", f"## {title}\n", metric_table(overall, labels)]
    md += ["", "## Per clip and track, one metric at a time\n"]
    for metric in HEADLINE_METRICS:
        md += [f"### {TITLES[metric]}{f' ({UNITS[metric]})' if UNITS[metric] else ''}\n", run_table(ab, metric), ""]
    md += ["## Every metric per clip and per track"]
    for title, _, table in per_clip:
        md += ["", f"### {title}\n", metric_table(table, labels)]
    md += ["", "## Metrics\n", DEFINITIONS.format(band=s.edge_band_px, jump=s.edge_threshold_px,
                                                   grad=s.flat_gradient_px, erode=s.flat_erode_px,
                                                   hl=s.highlight_threshold, defocus=s.min_defocus_px)]
    md += ["Values are finite or shown as – (nothing to measure, e.g. no highlight in a clip); "
           "identical images score 100 dB. `frames.csv` has every per-frame figure.\n"]
    md += ["## Dataset\n", _dataset_table(ab)]
    if ab.skipped:
        md += ["", "## Skipped clips\n"] + [f"- `{name}`: {why}" for name, why in ab.skipped]
    md += ["", "## Plots\n"] + [f"![{p.stem}]({rel(p)})" for p in plots]
    md += ["", "## Comparisons\n",
           "Columns: the deep-DOF input, Cycles' ground truth, then each variant (its sRGB PSNR on that frame in "
           "the label). Middle row: the outlined window enlarged, placed where the depth-edge band is densest. "
           "Bottom row: the ground-truth blur radius (turbo colour map), the metric masks (edge band red, flat "
           "regions grey), then each variant's absolute sRGB error against the ground truth, times 4.\n"]
    md += [f"![{p.stem}]({rel(p)})" for p in images]
    md += ["", "## Videos\n"] + [f"- [{p.name}]({rel(p)})" for p in videos]
    path = folder / "README.md"
    path.write_text("\n".join(md) + "\n")
    return path


# ----------------------------------------------------------------------------------------
# Tables, plots, images, videos


def write_frames_csv(ab: "Ablation", folder: Path) -> Path:
    """frames.csv: clip, track, variant and every per-frame figure."""
    path = folder / "frames.csv"
    rows = [{"clip": r.clip, "track": r.track, "variant": r.variant, **f} for r in ab.runs for f in r.frames]
    with path.open("w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    return path


def write_plots(ab: "Ablation", folder: Path) -> list[Path]:
    """Per-frame PSNR (whole frame and edge band) per variant for each clip and track, and bar
    charts of every overall metric. Returns the PNG paths."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import MaxNLocator

    out_dir = folder / "plots"
    out_dir.mkdir()
    paths = []
    overall = scopes(ab)[0][2]
    names = [v.name for v in ab.variants]
    rows = -(-len(METRICS) // 3)
    fig, axes = plt.subplots(rows, 3, figsize=(13, 3 * rows), constrained_layout=True)
    for ax, metric in zip(axes.flat, METRICS):
        vals = [overall[n].get(metric, float("nan")) for n in names]
        ax.bar(range(len(names)), [v if _finite(v) else 0.0 for v in vals], color=[f"C{i}" for i in range(len(names))])
        ax.set_xticks(range(len(names)), names, rotation=25, ha="right", fontsize=8)
        arrow = "higher is better" if HIGHER_IS_BETTER[metric] else "lower is better"
        ax.set_title(f"{TITLES[metric]}{f' ({UNITS[metric]})' if UNITS[metric] else ''} - {arrow}", fontsize=9)
        for i, v in enumerate(vals):
            ax.annotate(_fmt(metric, v), (i, v if _finite(v) else 0.0), ha="center", va="bottom", fontsize=7)
    fig.suptitle("Ablation: mean over all clips and tracks")
    paths.append(out_dir / "metrics_bars.png")
    fig.savefig(paths[-1], dpi=90)
    plt.close(fig)

    for clip, track in dict.fromkeys((r.clip, r.track) for r in ab.runs):
        fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(9, 6), sharex=True, constrained_layout=True)
        for i, name in enumerate(names):
            for run in _runs(ab, clip=clip, track=track, variant=name):
                x = [f["frame"] for f in run.frames]
                ax1.plot(x, [f["psnr_srgb_db"] for f in run.frames], color=f"C{i}", label=name, marker=".")
                ax2.plot(x, [f["edge_band_psnr_srgb_db"] for f in run.frames], color=f"C{i}", label=name, marker=".")
        ax1.set_ylabel("PSNR sRGB (dB)")
        ax2.set_ylabel("edge-band PSNR sRGB (dB)")
        ax2.set_xlabel("frame")
        ax2.xaxis.set_major_locator(MaxNLocator(integer=True))
        ax1.legend(fontsize=8)
        ax1.grid(alpha=0.3)
        ax2.grid(alpha=0.3)
        fig.suptitle(f"{clip} / {track}: per-frame PSNR against Cycles")
        paths.append(out_dir / f"{_key(clip)}__{_key(track)}_psnr.png")
        fig.savefig(paths[-1], dpi=90)
        plt.close(fig)
    return paths


def _read_png(path: Path) -> np.ndarray:
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        raise FileNotFoundError(f"scratch frame '{path}' is missing")
    return img[:, :, ::-1]


def _panels(ab: "Ablation", clip: str, track: str, frame: int) -> tuple[list[tuple[str, np.ndarray]], "GTFrame"]:
    """(label, image) of the input, the ground truth and every variant on one frame; a variant's
    label carries its sRGB PSNR on that frame."""
    reader = ab.readers[clip]
    gt = reader.read(track, frame)
    panels = [("input (deep DOF)", gt.input_srgb), ("GT Cycles DOF", to_uint8(display_srgb(gt.dof_linear)))]
    for v in ab.variants:
        run = _runs(ab, clip=clip, track=track, variant=v.name)
        if run:
            score = next((f["psnr_srgb_db"] for f in run[0].frames if f["frame"] == frame), float("nan"))
            panels.append((f"{v.label} {score:.1f} dB", _read_png(run[0].outputs / f"frame_{frame:05d}.png")))
    return panels, gt


def write_comparisons(ab: "Ablation", folder: Path, frames_per_run: int = 3) -> list[Path]:
    """Side-by-side comparison PNGs on ``frames_per_run`` evenly spaced frames of each clip and
    track, with a zoom on the densest part of the depth-edge band."""
    out_dir = folder / "compare"
    out_dir.mkdir()
    paths = []
    for clip, track in dict.fromkeys((r.clip, r.track) for r in ab.runs):
        numbers = [int(f["frame"]) for f in _runs(ab, clip=clip, track=track)[0].frames]
        picks = sorted({numbers[int(round(i))] for i in np.linspace(0, len(numbers) - 1, max(frames_per_run, 1))})
        for frame in picks:
            panels, gt = _panels(ab, clip, track, frame)
            s = ab.settings
            band = edge_band(gt.disparity, s.edge_band_px, aperture=gt.aperture, threshold_px=s.edge_threshold_px)
            flat = flat_regions(gt.disparity, aperture=gt.aperture, gradient_px=s.flat_gradient_px,
                                erode_px=s.flat_erode_px)
            reference = panels[1][1]
            bottom = [disparity_image(gt.disparity, gt.focus, gt.aperture), mask_image(band, flat)]
            bottom += [error_image(img, reference) for _, img in panels[2:]]
            image = comparison_image(panels, crop_box(band), bottom)
            path = out_dir / f"{_key(clip)}__{_key(track)}__frame_{frame:05d}.png"
            cv2.imwrite(str(path), image[:, :, ::-1])
            paths.append(path)
    return paths


def write_videos(ab: "Ablation", folder: Path) -> list[Path]:
    """One H.264 MP4 per clip and track: labelled panels (input, GT, variants), frame by frame."""
    from rvr_addon.io.writer import VideoWriter

    out_dir = folder / "videos"
    out_dir.mkdir()
    paths = []
    for clip, track in dict.fromkeys((r.clip, r.track) for r in ab.runs):
        numbers = [int(f["frame"]) for f in _runs(ab, clip=clip, track=track)[0].frames]
        path = out_dir / f"{_key(clip)}__{_key(track)}.mp4"
        writer = None
        try:
            for frame in numbers:
                panels, gt = _panels(ab, clip, track, frame)
                image = video_frame(panels, cols=3, caption=f"{clip} / {track}  frame {frame}  "
                                                            f"focus {gt.focus:.2f} px  aperture {gt.aperture:.2f}")
                if writer is None:
                    writer = VideoWriter(path, ab.readers[clip].fps, (image.shape[1], image.shape[0]))
                writer.write(image)
            if writer is not None:
                writer.close()
        except BaseException:
            if writer is not None:
                writer.abort()
            raise
        paths.append(path)
    return paths


def write_report(ab: "Ablation", folder: Path, *, compare_frames: int = 3, progress: bool = True) -> None:
    """Write every part of the report into ``folder`` (which exists and is empty but for scratch)."""
    (folder / "summary.json").write_text(json.dumps(summary(ab), indent=1, sort_keys=True) + "\n")
    write_frames_csv(ab, folder)
    plots = write_plots(ab, folder)
    images = write_comparisons(ab, folder, compare_frames)
    videos = write_videos(ab, folder)
    write_readme(ab, folder, plots, images, videos)
