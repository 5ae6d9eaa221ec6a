"""rvr batch throughput: frames per second for 1 and 2 local worker processes.

    .venv/bin/python bench/batch_bench.py [--clips 4] [--frames 48] [--size 640x360] [--chunk-frames 24]
                                          [--workers 1 2] [--weights W] [--quick] [--cores-only]

Input: ``--clips`` clips of ``--frames`` frames at ``--size``, cut from consecutive stretches
of ``../shared/data/clips/visualvoice_interview.mp4`` (a TV interview: faces, speech; 25 fps)
with their audio; without ../shared/data, ffmpeg's testsrc2 pattern with a tone. Weights:
``--weights``, else the shipped estimator (``rvr_addon/estimate/weights/estimator.pt``: its header
runs the trunk at 320x180 and slices D at full size, which is what a batch costs); without it
an untrained network of the same architecture at full size (``batch.untrained_weights`` = 1). For each worker count a
fresh LocalCluster (processes, 1 thread each, torch/OpenCV 1 thread per task) runs the whole
batch (estimate, stabilize, autofocus with the conversation preset, render, MP4 encode) into
a fresh output folder, so nothing is reused. ``batch.workersN.fps`` = frames of all clips /
wall time from the first task to the last result (cluster start-up excluded, reported as
``batch.workersN.startup_s``). ``batch.task.<stage>.<size>.s_per_frame`` (wall) and
``.cpu_s_per_frame`` (CPU of the worker process and its ffmpeg children: robust to other load
on the machine) are the summed task times per frame of the 1-worker run (one core per task):
the per-frame costs a cluster plan scales up (docs/batch.md), stages ``estimate``, ``merge_estimates``, ``stabilize``,
``merge_stabilized``, ``laaf_measure`` (LAAF's per-frame part, chunked), ``autofocus`` (its whole-clip part: one task
per clip), ``render``, ``finalize`` (encode), and ``batch.task.total.<size>.(cpu_)s_per_frame`` their sum;
``batch.cache.<size>.mb_per_frame`` the per-clip cache on disk (raw + stabilized channels);
``batch.laaf.<size>.measure_mb_per_frame`` the LAAF measurement files (kept until the clip's autofocus task ends);
``batch.io.list_cpu_s_per_packet``, ``batch.io.list_cpu_s_per_call`` (listing packets without decoding, on
``--clip``) and ``batch.io.<size>.decode_cpu_s_per_frame`` (the first clip) what positioning a chunk costs.
``--cores-only``: no cluster; ``batch.cores.<stage>.<size>.per_task``, the cores one task of each stage
uses (CPU of the process and its ffmpeg children over that of the task's thread: robust to other
load, unlike ``batch.speedup_2_vs_1`` on a shared machine). Tables go to stderr; the last stdout
line is DESIGN.md's flat JSON.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

CLIP = ROOT.parent / "shared" / "data" / "clips" / "visualvoice_interview.mp4"


def make_clips(src: Path, n: int, frames: int, size: tuple[int, int], folder: Path) -> list[Path]:
    """n H.264 + AAC clips of ``frames`` frames each at ``size`` (consecutive stretches of src)."""
    import imageio_ffmpeg

    ff = imageio_ffmpeg.get_ffmpeg_exe()
    folder.mkdir(parents=True, exist_ok=True)
    w, h = size
    clips = []
    for i in range(n):
        out = folder / f"clip{i:02d}.mp4"
        if src.is_file():
            inputs = ["-ss", f"{i * frames / 25.0:.3f}", "-i", str(src)]
        else:
            inputs = ["-f", "lavfi", "-i", f"testsrc2=size={w}x{h}:rate=25", "-f", "lavfi",
                      "-i", f"sine=frequency={300 + 50 * i}"]
        cmd = [ff, "-hide_banner", "-v", "error", "-y", *inputs, "-frames:v", str(frames),
               "-vf", f"scale={w}:{h},setsar=1", "-r", "25", "-c:v", "libx264", "-preset", "veryfast", "-crf", "18",
               "-pix_fmt", "yuv420p", "-c:a", "aac", "-shortest", str(out)]
        subprocess.run(cmd, check=True)
        clips.append(out)
    return clips


def io_costs(clip: Path, long_clip: Path, label: str) -> dict[str, float]:
    """What positioning a chunk costs (CPU s of this process and its ffmpeg): listing packets
    without decoding (``io.video.scan_packets``) per call and per packet (a line through a short
    and a full listing of ``long_clip``), and decoding ``clip`` per frame."""
    from rvr_addon.batch.stages import cpu_seconds
    from rvr_addon.io.video import iter_frames, scan_packets

    c0 = cpu_seconds()
    short = len(scan_packets(long_clip, start=1).packets)
    c1 = cpu_seconds()
    full = len(scan_packets(long_clip).packets)
    c2 = cpu_seconds()
    frames = sum(1 for _ in iter_frames(clip))
    c3 = cpu_seconds()
    per_packet = max(c2 - c1 - (c1 - c0), 0.0) / max(full - short, 1)
    return {"batch.io.list_cpu_s_per_packet": round(per_packet, 8),
            "batch.io.list_cpu_s_per_call": round(max(c1 - c0 - short * per_packet, 0.0), 5),
            f"batch.io.{label}.decode_cpu_s_per_frame": round((c3 - c2) / max(frames, 1), 5)}


def measure_mb_per_frame(clip: Path, cache: Path, folder: Path, preset: str | None) -> float:
    """MB per frame of the LAAF measurement file of a clip (its cache gives the disparity)."""
    from rvr_addon.io.video import probe_clip
    from rvr_addon.laaf.analysis import measure_range, write_measurements
    from rvr_addon.laaf.lookahead import AutofocusSettings

    n = probe_clip(clip).frame_count
    path = folder / "measure.npz"  # data only (io.datafile), as rvr batch names it
    settings = AutofocusSettings(input=clip, cache=cache, preset=preset)
    write_measurements(path, {"range": (0, n)}, measure_range(settings, 0, n))
    return path.stat().st_size / 2**20 / n


def cores_per_task(clip: Path, folder: Path, label: str, threads: int = 1) -> dict[str, float]:
    """How many cores one task of each stage would use on an idle machine, measured so that other
    load does not change it: the stage's job runs in this process with torch/OpenCV at ``threads``
    (``--task-threads``), and ``batch.cores.<stage>.<size>.per_task`` = CPU of the process and its
    ffmpeg children / CPU of the calling thread (the task's critical path when it never waits).
    ``render`` renders with the blur pool at ``threads`` as the batch does now, ``render_pool_default``
    with the renderer's own default (up to 4 threads; what batch tasks did before); the MP4 encode
    (ffmpeg's libx264 threads) is ``render_mp4``."""
    import resource
    import time

    import cv2
    import torch

    from rvr_addon.cli import main as rvr
    from rvr_addon.pipeline import RenderJob, RenderSettings

    torch.set_num_threads(threads)
    cv2.setNumThreads(threads)

    def clock() -> tuple[float, float]:
        r = resource.getrusage(resource.RUSAGE_CHILDREN)
        return time.thread_time(), time.process_time() + r.ru_utime + r.ru_stime

    cache, track = folder / "cores_cache", folder / "cores_focus.json"

    def render(out: str, pool: int | None) -> None:
        RenderJob(RenderSettings(input=clip, depth=cache, hdr=cache, track=track, outputs=[folder / out],
                                 device="cpu", threads=pool)).run(progress=False)

    steps = [("estimate", lambda: rvr(["estimate", str(clip), "-o", str(cache), "-q"])),
             ("stabilize", lambda: rvr(["stabilize", str(cache), "-q"])),
             ("autofocus", lambda: rvr(["autofocus", str(clip), "--cache", str(cache), "-o", str(track), "-q"])),
             ("render", lambda: render("r1/frame_%05d.exr", threads)),
             ("render_pool_default", lambda: render("r2/frame_%05d.exr", None)),
             ("render_mp4", lambda: render("r3.mp4", threads))]
    out = {}
    for stage, fn in steps:
        t0, c0 = clock()
        fn()
        t1, c1 = clock()
        out[f"batch.cores.{stage}.{label}.per_task"] = round((c1 - c0) / max(t1 - t0, 1e-9), 3)
    return out


def size_label(size: tuple[int, int]) -> str:
    return f"{size[1]}p" if size[1] in (360, 720, 1080, 2160) else f"{size[0]}x{size[1]}"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--clips", type=int, default=4)
    ap.add_argument("--frames", type=int, default=48, help="frames per clip")
    ap.add_argument("--size", default="640x360", help="WxH of the clips (default 640x360)")
    ap.add_argument("--chunk-frames", type=int, default=24)
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--weights", type=Path, help="estimator weights (default: the shipped file, else untrained)")
    ap.add_argument("--clip", type=Path, default=CLIP, help="source video the clips are cut from")
    ap.add_argument("--quick", action="store_true", help="2 clips of 12 frames at 160x90 (checks the plumbing)")
    ap.add_argument("--cores-only", action="store_true",
                    help="only batch.cores.*: cores one task of each stage uses (robust to other load), no cluster")
    args = ap.parse_args()
    if args.quick:
        args.clips, args.frames, args.size, args.chunk_frames = 2, 12, "160x90", 6
    size = tuple(int(v) for v in args.size.lower().split("x"))

    import logging

    from distributed import Client, LocalCluster

    from rvr_addon.batch.graph import run_batch
    from rvr_addon.batch.settings import BatchSettings

    logging.getLogger("distributed").setLevel(logging.WARNING)
    out: dict[str, float] = {}
    label = size_label(size)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        clips = make_clips(args.clip, args.clips, args.frames, size, tmp / "clips")
        if args.cores_only:
            out.update(cores_per_task(clips[0], tmp, label))
            print(json.dumps(out))
            return 0
        weights = args.weights
        from rvr_addon.estimate.infer import SHIPPED_WEIGHTS

        if weights is None and SHIPPED_WEIGHTS.is_file():
            weights = SHIPPED_WEIGHTS
        out["batch.untrained_weights"] = float(weights is None)
        if weights is None:
            import torch

            from rvr_addon.estimate.train import export_weights
            from rvr_addon.estimate.unet import EstimatorNet

            torch.manual_seed(0)
            weights = export_weights(EstimatorNet(), tmp / "untrained.pt", iterations=0, wall_time_s=0.0,
                                     training={"note": "benchmark only: untrained, same cost as trained"})
        for n in args.workers:
            import time

            t0 = time.perf_counter()
            with LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=":0") as cluster, \
                    Client(cluster) as client:
                startup = time.perf_counter() - t0
                settings = BatchSettings(output=tmp / f"out{n}", weights=weights, chunk_frames=args.chunk_frames)
                report = run_batch(clips, settings, client=client, progress=False)
            print(f"--- {n} worker(s), {len(clips)} clips x {args.frames} frames at {args.size}\n{report.table()}",
                  file=sys.stderr)
            if report.count("failed"):
                print("batch_bench: clips failed (see the table)", file=sys.stderr)
                return 1
            out[f"batch.workers{n}.fps"] = round(report.fps, 4)
            out[f"batch.workers{n}.startup_s"] = round(startup, 2)
            out[f"batch.workers{n}.wall_s"] = round(report.wall_s, 2)
            if n == min(args.workers):
                cache_bytes = sum(f.stat().st_size for f in settings.caches.rglob("frame_*.exr"))
                out[f"batch.cache.{label}.mb_per_frame"] = round(cache_bytes / 2**20 / report.frames_done, 3)
                cpu = report.stage_seconds_per_frame(cpu=True)
                wall = report.stage_seconds_per_frame()
                for stage, s in wall.items():
                    key = f"batch.task.{stage.replace(' ', '_')}.{label}"
                    out[f"{key}.s_per_frame"] = round(s, 5)
                    out[f"{key}.cpu_s_per_frame"] = round(cpu.get(stage, 0.0), 5)
                out[f"batch.task.total.{label}.s_per_frame"] = round(sum(wall.values()), 5)
                out[f"batch.task.total.{label}.cpu_s_per_frame"] = round(sum(cpu.values()), 5)
                cache = next(settings.caches.glob(f"{clips[0].stem}-*"))
                out[f"batch.laaf.{label}.measure_mb_per_frame"] = round(
                    measure_mb_per_frame(clips[0], cache, tmp, settings.preset), 4)
                out.update(io_costs(clips[0], args.clip if args.clip.is_file() else clips[0], label))
        if "batch.workers1.fps" in out and "batch.workers2.fps" in out:
            out["batch.speedup_2_vs_1"] = round(out["batch.workers2.fps"] / max(out["batch.workers1.fps"], 1e-9), 3)
        out[f"batch.{label}.frames"] = args.clips * args.frames
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
