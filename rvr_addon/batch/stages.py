"""The tasks a batch worker runs: one stage of one chunk (or one clip) each.

Every task calls the engine's own job on a frame range; none re-implements a stage:

=================  ==========================================================  =============
task               what it runs                                                reads/writes
=================  ==========================================================  =============
probe              ``probe_clip`` + source fingerprint; done marker check      the clip
estimate           ``EstimateJob`` on [a, b) (the whole clip for fused depth)   staging cache
merge_estimates    ``ClipCache.adopt`` of every estimate chunk                 clip cache
stabilize          ``StabilizeJob`` writing [a, b), reading [a - P, b + F)     staging cache
merge_stabilized   ``ClipCache.adopt`` of every stabilize chunk                clip cache
laaf_measure       ``laaf.analysis.measure_range`` on [a, b) (from a - 1 and    work/analysis_*
                   the last face detection before a)
autofocus          ``AutofocusJob`` over the whole clip on those measurements   work/focus.json
                   (frame-order state: tracks, tracking, pulls) + focus file
render             ``RenderJob`` on [a, b) to an image sequence                work/render_*
finalize           encode / assemble the outputs, done marker                  output folder
=================  ==========================================================  =============

Each returns a small dict (stage, frames, seconds, ...) that the client sums up. Failures are
raised as :class:`StageError` naming the clip, the stage, the frames and the cause.
"""
from __future__ import annotations

import json
import logging
import os
import shutil
import time
from pathlib import Path

from ..errors import InputError, RvrError
from ..io.paths import temp_sibling
from .chunks import stabilize_reads
from .settings import BatchSettings, ClipPlan

log = logging.getLogger(__name__)


class StageError(RvrError):
    """A stage of one clip failed; the message names the clip, the stage and the cause."""


def cpu_seconds() -> float:
    """CPU time (s, user + system) of this process and of its finished child processes
    (ffmpeg decoders/encoders). Per task it is robust to other load on the machine; with
    several task threads per worker the children of concurrent tasks mix in."""
    import resource

    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return time.process_time() + r.ru_utime + r.ru_stime


def _guard(stage: str, plan: ClipPlan, frames: tuple[int, int] | None, fn):
    """Run fn(), timing it (wall and CPU s); wrap failures in StageError naming the clip and
    the stage."""
    where = f"{stage}" + (f" (frames {frames[0]}..{frames[1] - 1})" if frames else "")
    t0, c0 = time.perf_counter(), cpu_seconds()
    try:
        result = fn()
    except StageError:
        raise
    except RvrError as ex:
        raise StageError(f"{plan.source}: {where}: {ex}") from None
    except Exception as ex:  # a bug: keep the type, log the traceback on the worker
        log.exception("%s: %s failed", plan.source, where)
        raise StageError(f"{plan.source}: {where}: {type(ex).__name__}: {ex} (see the worker log)") from None
    result = dict(result or {})
    result.update(stage=stage, seconds=time.perf_counter() - t0, cpu_seconds=cpu_seconds() - c0)
    return result


def staging_root(plan: ClipPlan) -> Path:
    """Where a clip's staging caches live: beside its cache (same filesystem, for renames)."""
    return plan.cache.parent / ".staging" / plan.cache.name


def depth_maps(plan: ClipPlan, settings: BatchSettings) -> Path | None:
    """The clip's external disparity maps (``depth_root/NAME``), or None."""
    return settings.depth_root / plan.name if settings.depth_root is not None else None


# ------------------------------------------------------------------------------ probe


def read_marker(path: Path) -> dict | None:
    """A done marker's content, None if absent or unreadable."""
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def probe(plan: ClipPlan, settings: BatchSettings, fingerprint: str) -> dict:
    """Describe the clip; ``skip`` is True when its done marker matches (same source, same
    settings, outputs present) and ``settings.force`` is off."""
    from ..estimate.cache import source_fingerprint
    from ..io.video import probe_clip

    def run():
        if not Path(plan.source).exists():
            raise InputError(f"clip '{plan.source}' not found; check the path (or the list file naming it)")
        clip = probe_clip(plan.source, fps=settings.fps)
        source_hash = source_fingerprint(plan.source)["hash"]
        depth = depth_maps(plan, settings)
        if depth is not None and not depth.exists():
            raise InputError(f"no depth maps for this clip: expected '{depth}' (a folder of per-frame maps named "
                             f"after the clip, under --depth-root {settings.depth_root})")
        probed = plan.probed(frames=clip.frame_count, fps=clip.fps, width=clip.width, height=clip.height,
                             has_audio=clip.has_audio, source_hash=source_hash)
        marker = read_marker(plan.marker_path(settings))
        skip = (not settings.force and marker is not None and marker.get("fingerprint") == fingerprint
                and marker.get("source_hash") == source_hash
                and all(p.exists() for p in probed.output_paths(settings)))
        return {"plan": probed, "skip": skip, "frames": clip.frame_count}

    return _guard("probe", plan, None, run)


def estimate(plan: ClipPlan, settings: BatchSettings, weights: Path | None, a: int, b: int) -> dict:
    """D and E of frames [a, b) into the chunk's staging cache (``EstimateJob``)."""
    from ..estimate.infer import EstimateJob, EstimateSettings
    from .staging import seed_staging
    from .worker import worker_model

    def run():
        staging = staging_root(plan) / f"estimate_{a:06d}_{b:06d}"
        seed_staging(plan.cache, staging, a, b)
        job = EstimateJob(EstimateSettings(
            input=plan.source, output=staging, weights=weights, depth=depth_maps(plan, settings),
            depth_scale=settings.depth_scale, depth_offset=settings.depth_offset,
            depth_is_distance=settings.depth_is_distance, no_hdr=settings.no_hdr, start=a, stop=b, fps=settings.fps,
            depth_method=settings.depth_method, hfov_deg=settings.hfov_deg),
            model=None if settings.no_hdr else worker_model(weights))
        job.run(progress=False)
        return {"frames": b - a, "computed": job.computed, "reused": job.reused, "range": (a, b)}

    return _guard("estimate", plan, (a, b), run)


def merge_estimates(plan: ClipPlan, chunks: list[dict]) -> dict:
    """Adopt every estimate chunk's frames into the clip cache (its only writer)."""
    from .staging import adopt_estimates

    def run():
        moved = 0
        for c in chunks:
            a, b = c["range"]
            moved += adopt_estimates(plan.cache, staging_root(plan) / f"estimate_{a:06d}_{b:06d}")
        return {"frames": plan.frames, "moved": moved}

    return _guard("merge estimates", plan, None, run)


def stabilize(plan: ClipPlan, settings: BatchSettings, a: int, b: int, merged: dict) -> dict:
    """Stabilized D and E of frames [a, b) (``StabilizeJob`` over a staging cache holding
    [a - P, b + F)), equal to a pass over the whole clip."""
    from ..temporal.job import StabilizeJob, StabilizeSettings
    from .staging import seed_staging

    def run():
        lo, hi = stabilize_reads(a, b, plan.frames, settings.temporal)
        staging = staging_root(plan) / f"stabilize_{a:06d}_{b:06d}"
        seed_staging(plan.cache, staging, lo, hi)
        job = StabilizeJob(StabilizeSettings(cache=staging, input=plan.source, temporal=settings.temporal,
                                             start=a, stop=b))
        job.run(progress=False)
        return {"frames": b - a, "written": job.written, "reused": job.reused, "range": (a, b),
                "streamed": job.total}

    return _guard("stabilize", plan, (a, b), run)


def merge_stabilized(plan: ClipPlan, chunks: list[dict]) -> dict:
    """Adopt every stabilize chunk's frames [a, b) into the clip cache."""
    from ..estimate.cache import stabilized_complete
    from .staging import adopt_stabilized

    def run():
        moved = 0
        for c in chunks:
            a, b = c["range"]
            moved += adopt_stabilized(plan.cache, staging_root(plan) / f"stabilize_{a:06d}_{b:06d}", a, b)
        meta = json.loads((plan.cache / "meta.json").read_text())
        if not stabilized_complete(meta) or len(meta.get("frames") or {}) != plan.frames:
            raise RuntimeError(f"the cache '{plan.cache}' is incomplete after the merge "
                               f"({len(meta.get('frames') or {})} of {plan.frames} frames)")
        shutil.rmtree(staging_root(plan), ignore_errors=True)
        _remove_if_empty(staging_root(plan).parent)
        return {"frames": plan.frames, "moved": moved}

    return _guard("merge stabilized", plan, None, run)


# ------------------------------------------------------------------------------ autofocus, render


def focus_work_path(plan: ClipPlan) -> Path:
    """The focus file while the clip is in progress."""
    return plan.work / "focus.json"


def analysis_path(plan: ClipPlan, a: int, b: int) -> Path:
    """The LAAF measurements of frames [a, b) (deleted once the focus file is written)."""
    return plan.work / f"analysis_{a:06d}_{b:06d}.npz"


def autofocus_settings(plan: ClipPlan, settings: BatchSettings):
    """The ``AutofocusSettings`` of the clip: what the measure chunks and the autofocus task share."""
    from ..laaf.lookahead import AutofocusSettings

    return AutofocusSettings(input=plan.source, cache=plan.cache, preset=settings.preset, window_s=settings.window_s,
                             causal=settings.causal, pull=settings.pull, aperture=settings.aperture, fps=settings.fps,
                             afnet_weights=settings.afnet_weights, afnet_threshold=settings.afnet_threshold,
                             afnet_speaker=settings.afnet_speaker, calm=settings.calm,
                             detect_cuts=settings.detect_cuts)


def laaf_measure(plan: ClipPlan, settings: BatchSettings, a: int, b: int, merged: dict) -> dict:
    """The per-frame part of LAAF on frames [a, b) (detectors, frames at the analysis size,
    disparity) into work/analysis_*.npz (data only, never unpickled); kept when complete from an
    earlier run, measured again when the file there is not a complete one (logged)."""
    from ..laaf.analysis import measure_range, read_header, write_measurements

    def run():
        path = analysis_path(plan, a, b)
        header = read_header(path)
        if focus_work_path(plan).is_file() or (header is not None and tuple(header["range"]) == (a, b)):
            return {"frames": b - a, "reused": True, "range": (a, b)}
        written = write_measurements(path, {"range": (a, b)}, measure_range(autofocus_settings(plan, settings), a, b))
        return {"frames": written, "reused": False, "range": (a, b)}

    return _guard("laaf measure", plan, (a, b), run)


def autofocus(plan: ClipPlan, settings: BatchSettings, measured: list[dict]) -> dict:
    """LAAF over the whole clip (``AutofocusJob`` fed the measure chunks, in order) ->
    work/focus.json (kept across re-runs); then the measurement files are deleted."""
    from ..laaf.analysis import read_measurements
    from ..laaf.focusfile import write_focus_file
    from ..laaf.lookahead import AutofocusJob

    def run():
        path = focus_work_path(plan)
        files = [analysis_path(plan, *c["range"]) for c in measured]
        if not path.is_file():  # else written atomically by an earlier run with the same settings
            job = AutofocusJob(autofocus_settings(plan, settings), frames=read_measurements(files))
            result = job.run(progress=False)
            write_focus_file(path, result)
        for f in files:
            f.unlink(missing_ok=True)
        return {"frames": plan.frames}

    return _guard("autofocus", plan, None, run)


def render_dir(plan: ClipPlan, a: int, b: int) -> Path:
    """Folder of the rendered frames of chunk [a, b) (frame_NNNNN = clip index + 1)."""
    return plan.work / f"render_{a:06d}_{b:06d}"


def _suffix(settings: BatchSettings) -> str:
    return ".exr" if settings.format == "exr" else ".png"


def render(plan: ClipPlan, settings: BatchSettings, a: int, b: int, focus: dict) -> dict:
    """Render frames [a, b) (``RenderJob``: stabilized D and E of the cache, the LAAF track)
    into an image sequence in the work folder (skipped when it is complete already)."""
    from ..pipeline import RenderJob, RenderSettings
    from .worker import worker_task_threads

    def run():
        out = render_dir(plan, a, b)
        if out.is_dir() and len(list(out.glob("frame_*" + _suffix(settings)))) == b - a:
            return {"frames": b - a, "reused": True}  # the writer swaps a folder in only when complete
        job = RenderJob(RenderSettings(
            input=plan.source, depth=plan.cache, hdr=plan.cache, outputs=[out / f"frame_%05d{_suffix(settings)}"],
            track=focus_work_path(plan), start=a, stop=b, fps=settings.fps, keep_audio=False, scale=settings.scale,
            threads=worker_task_threads()))  # the renderer's blur pool keeps to --task-threads too
        job.run(progress=False)
        return {"frames": b - a, "reused": False}

    return _guard("render", plan, (a, b), run)


# ------------------------------------------------------------------------------ finalize


def _remove_if_empty(folder: Path) -> None:
    try:
        folder.rmdir()
    except OSError:
        pass  # not empty (other clips in progress) or gone


def _write_json(path: Path, data: dict) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = temp_sibling(path, ".json")
    try:
        tmp.write_text(json.dumps(data, indent=1, default=str))
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def _chunk_frames(plan: ClipPlan, settings: BatchSettings, ranges: list[tuple[int, int]]) -> list[Path]:
    files = []
    for a, b in ranges:
        got = sorted(render_dir(plan, a, b).glob("frame_*" + _suffix(settings)))
        if len(got) != b - a:
            raise RuntimeError(f"render chunk {a}..{b - 1} of '{plan.source}' holds {len(got)} of {b - a} frames")
        files += got
    return files


def _encode(plan: ClipPlan, settings: BatchSettings, files: list[Path]) -> None:
    import cv2

    from ..io.writer import VideoWriter

    first = cv2.imread(str(files[0]), cv2.IMREAD_COLOR)
    size = (first.shape[1], first.shape[0])
    audio = plan.source if plan.has_audio else None
    with VideoWriter(plan.video_path(settings), fps=plan.fps, size=size, audio_from=audio) as writer:
        for f in files:
            frame = cv2.imread(str(f), cv2.IMREAD_COLOR)
            if frame is None:
                raise RuntimeError(f"cannot read the rendered frame '{f}'")
            writer.write(cv2.cvtColor(frame, cv2.COLOR_BGR2RGB))


def _assemble(plan: ClipPlan, settings: BatchSettings, files: list[Path]) -> None:
    """Hard-link the chunks' frames into one folder, swapped in place of the output folder."""
    from .staging import _link

    final = plan.frames_path(settings)
    final.parent.mkdir(parents=True, exist_ok=True)
    tmp = temp_sibling(final, ".tmp")
    tmp.mkdir()
    try:
        for f in files:
            _link(f, tmp / f.name)
        old = None
        if final.exists():
            old = temp_sibling(final, ".old")
            os.replace(final, old)
        os.replace(tmp, final)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def finalize(plan: ClipPlan, settings: BatchSettings, fingerprint: str, ranges: list[tuple[int, int]],
             results: list[dict]) -> dict:
    """Write the clip's outputs (video or frame folder, focus file), then its done marker;
    remove its work folder. Returns the clip's summary (frames, per-stage seconds)."""

    def run():
        files = _chunk_frames(plan, settings, ranges)
        if len(files) != plan.frames:
            raise RuntimeError(f"{len(files)} rendered frames for a clip of {plan.frames}")
        if settings.format == "mp4":
            _encode(plan, settings, files)
        else:
            _assemble(plan, settings, files)
        focus = plan.focus_path(settings)
        tmp = temp_sibling(focus, ".json")
        try:
            shutil.copyfile(focus_work_path(plan), tmp)
            os.replace(tmp, focus)
        finally:
            tmp.unlink(missing_ok=True)
        seconds: dict[str, float] = {}
        cpu: dict[str, float] = {}
        for r in results:
            seconds[r["stage"]] = seconds.get(r["stage"], 0.0) + float(r["seconds"])
            cpu[r["stage"]] = cpu.get(r["stage"], 0.0) + float(r["cpu_seconds"])
        summary = {"source": str(plan.source), "source_hash": plan.source_hash, "fingerprint": fingerprint,
                   "frames": plan.frames, "fps": plan.fps, "size": [plan.width, plan.height],
                   "outputs": [str(p) for p in plan.output_paths(settings)], "cache": str(plan.cache),
                   "task_seconds": {k: round(v, 4) for k, v in seconds.items()},
                   "task_cpu_seconds": {k: round(v, 4) for k, v in cpu.items()},
                   "finished": time.strftime("%Y-%m-%dT%H:%M:%S%z")}
        _write_json(plan.marker_path(settings), summary)
        shutil.rmtree(plan.work, ignore_errors=True)
        _remove_if_empty(plan.work.parent)
        if not settings.keep_cache:
            shutil.rmtree(plan.cache, ignore_errors=True)
        return summary

    return _guard("finalize", plan, None, run)
