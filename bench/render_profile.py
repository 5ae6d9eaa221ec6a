"""Where the fast renderer's time goes, per phase, on the bench scene and on a real depth map.

    .venv/bin/python bench/render_profile.py [--repeats N]

The frames of ``bench/render_bench.py`` at 1080p: its bench scene and the same picture with the depth
the shipped network estimates for it (focused on its median, largest radius 32 px). One thread
(``FastRenderer(threads=1)``, ``cv2.setNumThreads(1)``) and CPU time, so the shares hold on a loaded
machine; the best of ``--repeats`` renders. Each phase is timed by wrapping the module's function
that does it; the rest (compositing, the resolve, Python) is what the wrapped ones leave. Also the
work's size: layers, active layers per tile, rectangles and their pixels (cores and boxes).
Keys ``render.fast_profile.<scene>.<phase>_s``; the last line of stdout is the JSON.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from collections import defaultdict
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

import rvr_addon.render.fast as fast  # noqa: E402
from render_bench import MAX_RADIUS_1080P, MIN_LAYERS, bench_scene  # noqa: E402
from rvr_addon.render.model import plan_for_radius_map, signed_radius  # noqa: E402

PHASES = {  # key: (owner, attribute) of the function timed
    "normaliser": (fast, "matte_normaliser_cv"),
    "active_tiles": (fast.FastRenderer, "_active_layers"),
    "rectangles": (fast.FastRenderer, "_plan_tasks"),
    "sources_and_blur": (fast, "blur_task"),
    "blur": (fast, "blur_core_planes"),
    "fill": (fast, "fill_level1_cv"),
}
"""``blur`` (the blur proper, with a reduced rectangle's area averaging, done as its sources are
written) is part of ``sources_and_blur``; the rest of that, ``sources``, is each rectangle's matte and
premultiplied sources and a reduced rectangle's upsampling."""


def profile(renderer: fast.FastRenderer, rad: np.ndarray, disp: np.ndarray, focus: float, aperture: float,
            repeats: int) -> dict[str, float]:
    """CPU seconds per phase (the best of ``repeats`` renders) and the work's size, of one frame."""
    spent: dict[str, float] = defaultdict(float)
    originals = {k: getattr(owner, name) for k, (owner, name) in PHASES.items()}

    def timed(key, fn):
        def wrapper(*args, **kwargs):
            t = time.process_time()
            try:
                return fn(*args, **kwargs)
            finally:
                spent[key] += time.process_time() - t
        return wrapper

    best: tuple[float, dict[str, float]] | None = None
    try:
        for key, (owner, name) in PHASES.items():
            setattr(owner, name, timed(key, originals[key]))
        renderer.render_linear(rad, disp, focus, aperture)  # warm-up: kernels, spectra
        for _ in range(repeats):
            spent.clear()
            t = time.process_time()
            renderer.render_linear(rad, disp, focus, aperture)
            total = time.process_time() - t
            if best is None or total < best[0]:
                best = (total, dict(spent))
    finally:
        for key, (owner, name) in PHASES.items():
            setattr(owner, name, originals[key])
    total, parts = best
    out = {f"{k}_s": v for k, v in parts.items()}
    out["sources_s"] = out.pop("sources_and_blur_s") - out["blur_s"]
    out["compositing_and_rest_s"] = total - sum(v for k, v in out.items())
    out["total_cpu_s"] = total
    # the size of the work
    s = signed_radius(disp, np.float32(focus), np.float32(aperture))
    plan = plan_for_radius_map(s, max_step=renderer.max_step, min_layers=renderer.min_layers)
    j_lo, j_hi = int(plan.indices.min()), int(plan.indices.max())
    u = np.clip(s / np.float32(plan.step), j_lo, j_hi).astype(np.float32)
    active = renderer._active_layers(u, j_lo, j_hi)
    tasks, _ = renderer._plan_tasks(plan, active, u.shape)
    out["layers"] = len(plan)
    out["layers_per_tile"] = float(active.sum()) / (active.shape[1] * active.shape[2])
    out["rectangles"] = len(tasks)
    out["core_mpx"] = sum((t.core[1] - t.core[0]) * (t.core[3] - t.core[2]) for t in tasks) / 1e6
    out["box_mpx"] = sum((t.box[1] - t.box[0]) * (t.box[3] - t.box[2]) for t in tasks) / 1e6
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=3, help="renders per frame, the fastest counts (default 3)")
    args = ap.parse_args()
    cv2.setNumThreads(1)
    img, rad, disp = bench_scene(1920, 1080)
    frames = {"bench": (disp, 0.0, 1.0)}
    try:
        from rvr_addon.estimate.infer import Estimator, default_weights, load_estimator

        d_real, _ = Estimator(load_estimator(default_weights()))(img)
        f = float(np.median(d_real))
        frames["real_depth"] = (d_real, f, MAX_RADIUS_1080P / max(float(np.abs(d_real - f).max()), 1e-6))
    except Exception as ex:  # noqa: BLE001 - no weights: the real-depth keys are absent, said once
        print(f"real-depth profile skipped: {ex}", file=sys.stderr)
    res: dict[str, float] = {}
    for scene, (d, focus, aperture) in frames.items():
        got = profile(fast.FastRenderer(min_layers=MIN_LAYERS, threads=1), rad, d, focus, aperture, args.repeats)
        total = got["total_cpu_s"]
        print(f"{scene}: {total:.3f} s CPU, {got['layers']} layers, {got['layers_per_tile']:.1f} layers a tile, "
              f"{got['rectangles']} rectangles, cores {got['core_mpx']:.1f} Mpx, boxes {got['box_mpx']:.1f} Mpx",
              file=sys.stderr)
        for k, v in got.items():
            if k.endswith("_s") and k != "total_cpu_s":
                print(f"  {k[:-2]:24s} {v:.3f} s {100 * v / total:4.0f} %", file=sys.stderr)
        res.update({f"render.fast_profile.{scene}.{k}": v for k, v in got.items()})
    print(json.dumps({k: round(v, 5) for k, v in res.items()}))


if __name__ == "__main__":
    main()
