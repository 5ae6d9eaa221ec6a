"""RGBD-HDR estimator speed on this machine: per-frame inference at 640x360 and 1920x1080.

    .venv/bin/python bench/estimate_bench.py [--repeats 7] [--no-job]

Times :class:`rvr_addon.estimate.infer.Estimator` on a real picture (a Sintel frame from
../shared/data, resized; random texture if it is missing): uint8 frame in, D and E as numpy
arrays out, everything in between included (conversion, padding, U-Net, bilateral slicing,
E gating). It uses the shipped weights (rvr_addon/estimate/weights/estimator.pt) and so the
trunk size they ask for (``inference_max_pixels``: frames above it run the network on a shrunk
copy, D sliced and E gated at full size), or ``--weights W``; without any, a freshly initialised
network at full size (speed does not depend on the weights' values). ``s_per_frame`` is the median
of the repeats (the machine is shared: the minimum is reported too). Unless ``--no-job``, it
also times ``rvr estimate`` end to end at 360p (PNG decode + inference + EXR write to the
cache) over 8 frames (``--depth-method network``: the network's own path).

The whole depth system (``rvr estimate --depth-method auto``, the default) on REAL clips resized to
640x360 and 1920x1080 (``--frames`` frames each; skipped with a message when the clips are absent):

* ``estimate.<size>.s_per_frame``: the whole auto estimate per frame (plan probe, decode, every cue,
  fusion, EXR writes) on ../shared/data/clips/visualvoice_interview.mp4 (a still camera, two people:
  auto picks people + network; the printed line and ``estimate.auto.<size>.cues_*`` say which);
  ``estimate.<size>.min_s_per_frame`` stays the network core's minimum (as before);
* ``estimate.network.<size>.s_per_frame``: the same clip, ``--depth-method network`` (whole job);
  ``estimate.network_core.<size>.s_per_frame``: the estimator call alone (what
  ``estimate.<size>.s_per_frame`` measured before the depth system);
* per cue, timed inside the stream (the calls of DepthStream's parts): ``estimate.people.<size>``,
  ``estimate.fuse.<size>`` (interview), ``estimate.parallax.<size>`` (kivy_cityCC0.mpg, a moving
  camera, where auto adds parallax; its whole auto run is ``estimate.auto_moving.<size>``). With
  the parallax cue on, the network and the people cue run on DepthStream's worker thread while the
  parallax cue works, so on the moving clip the parts overlap and add up to more than the total.
  ``estimate.refine_moving.<size>``: the moving clip's refinement with the frames after it
  (:mod:`rvr_addon.depth.refine`: its flows and carries).

The last line of stdout is the JSON of DESIGN.md's keys.
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

PICTURE = ROOT.parent / "shared" / "data" / "sintel_frames" / "frame_0016.png"
CLIPS = ROOT.parent / "shared" / "data" / "clips"
STILL_CLIP = CLIPS / "visualvoice_interview.mp4"
MOVING_CLIP = CLIPS / "kivy_cityCC0.mpg"
SIZES = {"360p": (640, 360), "1080p": (1920, 1080)}


def picture(width: int, height: int) -> np.ndarray:
    """(H, W, 3) uint8 RGB test frame with a few clipped highlights."""
    if PICTURE.is_file():
        img = cv2.cvtColor(cv2.imread(str(PICTURE)), cv2.COLOR_BGR2RGB)
    else:
        img = (np.random.default_rng(0).random((54, 96, 3)) * 255).astype(np.uint8)
    img = cv2.resize(img, (width, height), interpolation=cv2.INTER_AREA)
    rng = np.random.default_rng(1)
    for _ in range(20):
        x, y = int(rng.integers(0, width - 4)), int(rng.integers(0, height // 2))
        img[y:y + 3, x:x + 3] = 255
    return img


def time_calls(fn, repeats: int) -> list[float]:
    fn()  # warm-up (allocator, oneDNN kernels)
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return times


def clip_frames(src: Path, folder: Path, size: tuple[int, int], n: int, start: int) -> Path:
    """Frames start..start+n-1 of a real clip, resized to ``size``, as a PNG sequence (lossless)."""
    from rvr_addon.io.video import iter_frames

    folder.mkdir(parents=True, exist_ok=True)
    for i, f in enumerate(iter_frames(src, start, start + n)):
        f = cv2.resize(f, size, interpolation=cv2.INTER_AREA if size[0] < f.shape[1] else cv2.INTER_CUBIC)
        cv2.imwrite(str(folder / f"f{i:04d}.png"), cv2.cvtColor(f, cv2.COLOR_RGB2BGR))
    return folder


class _Timed:
    """Wraps a callable part of DepthStream (people detector, fuser): times its calls, delegates the rest."""

    def __init__(self, part, acc: dict, key: str) -> None:
        self.__dict__.update(_part=part, _acc=acc, _key=key)

    def __call__(self, *a, **k):
        t = time.perf_counter()
        try:
            return self._part(*a, **k)
        finally:
            self._acc[self._key] = self._acc.get(self._key, 0.0) + time.perf_counter() - t

    def __getattr__(self, name):
        return getattr(self._part, name)


def timed_auto_job(frames: Path, cache: Path, weights: Path, method: str = "auto") -> tuple[dict, object]:
    """Run ``rvr estimate --depth-method METHOD`` on a frame folder, timing the stream's parts.
    Returns ({"total", "plan", "network", "people", "fuse", "parallax", "decode"} seconds, the job)."""
    from rvr_addon.estimate.infer import EstimateJob, EstimateSettings

    acc: dict[str, float] = {}
    t0 = time.perf_counter()
    job = EstimateJob(EstimateSettings(input=frames, output=cache, weights=weights, depth_method=method))
    acc["plan"] = time.perf_counter() - t0  # the auto probe (tracks on the first frames) + weights load
    stream = job.stream
    if stream is not None:
        stream.network = _Timed(stream.network, acc, "network")
        if stream.people is not None:
            stream.people = _Timed(stream.people, acc, "people")
        stream.fuser = _Timed(stream.fuser, acc, "fuse")
        if stream.parallax is not None:
            original = stream._parallax_maps

            def timed_maps(frames_in, queue):
                decode = [0.0]

                def timed_frames():
                    it = iter(frames_in)
                    while True:
                        t = time.perf_counter()
                        f = next(it, None)
                        decode[0] += time.perf_counter() - t
                        if f is None:
                            return
                        yield f

                gen = original(timed_frames(), queue)
                while True:
                    t, d0 = time.perf_counter(), decode[0]
                    cue = next(gen, None)
                    acc["parallax"] = acc.get("parallax", 0.0) + (time.perf_counter() - t) - (decode[0] - d0)
                    if cue is None:
                        return
                    yield cue

            stream._parallax_maps = timed_maps
            from rvr_addon.depth import system as depth_system_mod

            class TimedRefiner(depth_system_mod.ClipRefiner):
                """The refinement's share (depth.refine: flows, carries), timed per call."""

                def push(self, item):
                    t = time.perf_counter()
                    out = list(super().push(item))
                    acc["refine"] = acc.get("refine", 0.0) + time.perf_counter() - t
                    yield from out

                def finish(self):
                    t = time.perf_counter()
                    out = list(super().finish())
                    acc["refine"] = acc.get("refine", 0.0) + time.perf_counter() - t
                    yield from out

            depth_system_mod.ClipRefiner = TimedRefiner  # the stream makes its refiner when it starts
    elif job.estimator is not None:
        job.estimator = _Timed(job.estimator, acc, "network")
    try:
        job.run(progress=False)
    finally:
        from rvr_addon.depth import refine, system as depth_system_mod

        depth_system_mod.ClipRefiner = refine.ClipRefiner
    acc["total"] = time.perf_counter() - t0
    return acc, job


def depth_system(result: dict, weights: Path, tmp: Path, n_frames: int) -> None:
    """The whole auto estimate and its parts on the real clips (keys in the module docstring)."""
    if not STILL_CLIP.is_file():
        print(f"skipping the depth-system timings: {STILL_CLIP} is absent (the shared real clips)", file=sys.stderr)
        return
    try:  # the one-off import of mediapipe (TF Lite) is a process's, not a clip's: keep it out of the figures
        import mediapipe  # noqa: F401
    except ImportError:
        print("mediapipe is not installed: auto runs without the people cue", file=sys.stderr)
    for name, size in SIZES.items():
        n = n_frames if name == "360p" else max(3, n_frames * 2 // 3)
        still = clip_frames(STILL_CLIP, tmp / f"still_{name}", size, n, start=100)
        t, job = timed_auto_job(still, tmp / f"c_still_{name}", weights)
        per = t["total"] / job.total
        result[f"estimate.{name}.s_per_frame"] = round(per, 4)
        result[f"estimate.auto.{name}.s_per_frame"] = round(per, 4)
        for cue in ("parallax", "people", "network"):
            result[f"estimate.auto.{name}.cues_{cue}"] = float(cue in job.plan.cues)
        result[f"estimate.auto.{name}.plan_s"] = round(t["plan"], 4)
        result[f"estimate.auto.{name}.after_plan_s_per_frame"] = round((t["total"] - t["plan"]) / job.total, 4)
        for part in ("people", "fuse"):
            if part in t:
                result[f"estimate.{part}.{name}.s_per_frame"] = round(t[part] / job.total, 4)
        result[f"estimate.auto.{name}.network_call_s_per_frame"] = round(t.get("network", 0.0) / job.total, 4)
        print(f"{name} auto on {STILL_CLIP.name} ({n} frames): {per:.3f} s/frame, {job.plan.summary()}; in the "
              f"stream per frame: network {t.get('network', 0) / job.total:.3f}, people {t.get('people', 0) / job.total:.3f}, "
              f"fuse {t.get('fuse', 0) / job.total:.3f}; plan (probe + weights) {t['plan']:.2f} s once", file=sys.stderr)
        tn, jn = timed_auto_job(still, tmp / f"c_net_{name}", weights, method="network")
        result[f"estimate.network.{name}.s_per_frame"] = round(tn["total"] / jn.total, 4)
        print(f"{name} network only: {tn['total'] / jn.total:.3f} s/frame", file=sys.stderr)
        if MOVING_CLIP.is_file():
            moving = clip_frames(MOVING_CLIP, tmp / f"moving_{name}", size, n, start=0)
            tm, jm = timed_auto_job(moving, tmp / f"c_moving_{name}", weights)
            result[f"estimate.auto_moving.{name}.s_per_frame"] = round(tm["total"] / jm.total, 4)
            result[f"estimate.auto_moving.{name}.cues_parallax"] = float("parallax" in jm.plan.cues)
            if "parallax" not in jm.plan.cues:  # auto's probe said no: time the cue forced (--depth-method parallax)
                print(f"{name}: auto left parallax out on {MOVING_CLIP.name} ({jm.plan.reasons.get('parallax')}); "
                      "timing --depth-method parallax", file=sys.stderr)
                tm, jm = timed_auto_job(moving, tmp / f"c_moving_par_{name}", weights, method="parallax")
                result[f"estimate.parallax_forced.{name}.s_per_frame"] = round(tm["total"] / jm.total, 4)
            if "parallax" in tm:
                result[f"estimate.parallax.{name}.s_per_frame"] = round(tm["parallax"] / jm.total, 4)
            result[f"estimate.fuse_moving.{name}.s_per_frame"] = round(tm.get("fuse", 0.0) / jm.total, 4)
            result[f"estimate.refine_moving.{name}.s_per_frame"] = round(tm.get("refine", 0.0) / jm.total, 4)
            print(f"{name} auto on {MOVING_CLIP.name} ({n} frames): {tm['total'] / jm.total:.3f} s/frame, "
                  f"{jm.plan.summary()}; per frame: parallax {tm.get('parallax', 0) / jm.total:.3f}, network "
                  f"{tm.get('network', 0) / jm.total:.3f}, people {tm.get('people', 0) / jm.total:.3f}, fuse "
                  f"{tm.get('fuse', 0) / jm.total:.3f}, refine {tm.get('refine', 0) / jm.total:.3f}", file=sys.stderr)
        else:
            print(f"no parallax timing: {MOVING_CLIP} is absent", file=sys.stderr)


def onnx_time(result: dict[str, float], weights: Path, repeats: int) -> None:
    """``estimate.onnx.<size>.s_per_frame``: the same frames through the ONNX export on onnxruntime
    (what the Blender extension runs; ``estimate.<size>`` is torch), when the export matches."""
    import importlib.util

    from rvr_addon import onnxrun
    from rvr_addon.estimate.infer import Estimator, load_estimator

    if importlib.util.find_spec("onnxruntime") is None or not onnxrun.matching_onnx(weights, weights.with_suffix(".onnx")):
        print("no onnxruntime or no matching .onnx export: estimate.onnx.* skipped", file=sys.stderr)
        return
    est = Estimator(load_estimator(weights, backend="onnx"))
    result["estimate.onnx.threads"] = float(onnxrun.threads())
    for name, (w, h) in SIZES.items():
        frame = picture(w, h)
        times = time_calls(lambda: est(frame), repeats)
        result[f"estimate.onnx.{name}.s_per_frame"] = round(statistics.median(times), 4)
        print(f"onnx {name} {w}x{h}: median {statistics.median(times):.3f} s, min {min(times):.3f} s", file=sys.stderr)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--no-job", action="store_true", help="skip the end-to-end rvr estimate timing")
    parser.add_argument("--weights", type=Path, help="estimator weights (default: the shipped ones)")
    parser.add_argument("--frames", type=int, default=10,
                        help="frames of each real clip for the depth-system timings at 360p (2/3 of it at 1080p)")
    parser.add_argument("--no-depth-system", action="store_true", help="skip the rvr estimate --depth-method auto timings")
    parser.add_argument("--threads", type=int, help="torch and OpenCV threads (default: their choice)")
    args = parser.parse_args()

    import torch

    if args.threads:
        torch.set_num_threads(args.threads)
        cv2.setNumThreads(args.threads)

    from rvr_addon.estimate.infer import SHIPPED_WEIGHTS, EstimateJob, EstimateSettings, Estimator, load_estimator
    from rvr_addon.estimate.train import export_weights
    from rvr_addon.estimate.unet import EstimatorNet

    result: dict[str, float] = {}
    with tempfile.TemporaryDirectory() as tmp:
        weights = args.weights or (SHIPPED_WEIGHTS if SHIPPED_WEIGHTS.is_file() else None)
        if weights is None:
            torch.manual_seed(0)
            weights = export_weights(EstimatorNet(), Path(tmp) / "untrained.pt", iterations=0, wall_time_s=0.0,
                                     training={"note": "benchmark only: untrained"})
        model = load_estimator(weights)
        net = model.net
        est = Estimator(model)
        print(f"weights {weights}: trunk at most {est.max_pixels} px", file=sys.stderr)
        result["estimate.trunk_max_pixels"] = float(est.max_pixels)
        result["estimate.model.parameters"] = float(net.parameter_count())
        result["estimate.model.weights_mb"] = round(weights.stat().st_size / 1e6, 2)
        result["estimate.threads"] = float(torch.get_num_threads())
        for name, (w, h) in SIZES.items():
            frame = picture(w, h)
            times = time_calls(lambda: est(frame), args.repeats)
            result[f"estimate.{name}.s_per_frame"] = round(statistics.median(times), 4)  # replaced by auto below
            result[f"estimate.network_core.{name}.s_per_frame"] = round(statistics.median(times), 4)
            result[f"estimate.{name}.min_s_per_frame"] = round(min(times), 4)
            print(f"{name} {w}x{h}: median {statistics.median(times):.3f} s, min {min(times):.3f} s "
                  f"over {len(times)}", file=sys.stderr)
        onnx_time(result, Path(weights), args.repeats)
        if not args.no_job:
            frames = Path(tmp) / "frames"
            frames.mkdir()
            for i in range(8):
                cv2.imwrite(str(frames / f"f{i:03d}.png"), cv2.cvtColor(np.roll(picture(640, 360), 4 * i, axis=1),
                                                                       cv2.COLOR_RGB2BGR))
            t = time.perf_counter()
            job = EstimateJob(EstimateSettings(input=frames, output=Path(tmp) / "cache", weights=weights,
                                               depth_method="network"))
            job.run(progress=False)
            per = (time.perf_counter() - t) / job.total
            result["estimate.job.360p.s_per_frame"] = round(per, 4)
            print(f"rvr estimate --depth-method network end to end at 360p: {per:.3f} s/frame", file=sys.stderr)
        if not args.no_depth_system:
            depth_system(result, Path(weights), Path(tmp), args.frames)
    print(json.dumps(result))


if __name__ == "__main__":
    main()
