"""Analyze: RGBD-HDR estimate + temporal stabilization of the active strip into its cache.

:func:`plan_analyze` reads the strip (the clip frames it shows, its Disparity maps if any,
the preferences: cache location, weights, threads) into an engine
:class:`~rvr_addon.estimate.infer.EstimateSettings`; :class:`AnalyzeJob` runs the engine's
``EstimateJob`` and then its ``StabilizeJob`` on the same cache, as one job with one
progress. Both skip what the cache already holds for the same model, source and settings, so
re-running Analyze on an analysed strip only checks the cache. Cancelling keeps every frame
finished so far (the cache's meta.json is flushed) and changes nothing in the scene; only a
complete run records the cache on the strip (``strip.rvr.cache_path``). When the strip's
settings changed since its cache was made, the new cache is built (estimated and stabilized)
beside the old one and swapped in only at the end, so Esc leaves the strip on its intact old
cache; the job holds the cache's lock from start to end (another Blender or ``rvr`` process
writing the same cache is refused, naming it).

Where D comes from: the strip's Depth setting (``strip.rvr.depth_method``: Auto fuses parallax,
people and the network, see ``rvr_addon.depth.system``; Parallax, People, Network) with its
Field of view (across the long side), replaced by the strip's Disparity maps when they are set ("depth from
elsewhere"; E still from the network, or 0 without weights). No weights and no maps: an error
naming the missing weights file and the two fixes. Without MediaPipe, Auto leaves the people cue
out and says so (the report and the panel's depth line); People then is an error naming the fix.
After Analyze the panel shows which cues spoke (:func:`depth_line`, from the cache's meta.json).
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import bpy

from . import compat, notes, prefs
from .jobrun import JobOperator
from .ops_render import poll_clip_strip
from .source import StripSource, abspath, cache_folder, resolve_source
from ..rvr_addon.errors import InputError

log = logging.getLogger(__name__)

ESTIMATE_SHARE = 0.7
"""Share of the progress bar for the estimate (the rest is the stabilization)."""


@dataclass
class AnalyzePlan:
    """What Analyze runs and where it records the result."""

    source: StripSource
    cache: Path
    cache_text: str  # what is stored in strip.rvr.cache_path (// relative when the file is saved)
    weights: Path | None
    depth: Path | None
    stabilize: bool = True
    depth_method: str = "auto"
    hfov_deg: float | None = None


def _relative(path: Path) -> str:
    if bpy.data.filepath:
        try:
            return bpy.path.relpath(str(path))
        except ValueError:  # another drive
            pass
    return str(path)


def plan_analyze(scene, strip, preferences=None) -> AnalyzePlan:
    """Read the strip and preferences into an AnalyzePlan; InputError for bad input."""
    preferences = preferences or prefs.get()
    source = resolve_source(scene, strip)
    depth = abspath(strip.rvr.depth_path, "disparity path", strip) if strip.rvr.depth_path else None
    try:
        weights = prefs.weights_file(preferences)
    except InputError:
        if depth is None or preferences.weights_path:
            raise
        weights = None  # depth from elsewhere, no HDR recovery until weights exist
    from ..rvr_addon.estimate.infer import estimator_unavailable

    reason = estimator_unavailable(weights) if weights is not None else ""
    if reason:
        if depth is None:
            raise InputError(f"Analyze cannot run the estimator network: {reason}; or set the strip's Disparity maps "
                             "(depth from elsewhere)")
        log.warning("strip '%s' is analysed with its disparity maps and without HDR recovery: %s", strip.name, reason)
        weights = None
    method = str(getattr(strip.rvr, "depth_method", "AUTO")).lower()
    if depth is not None and method != "auto":
        raise InputError(f"strip '{strip.name}' has Disparity maps and its Depth is set to {method.title()}: the maps "
                         "are the depth; clear the Disparity maps, or set Depth to Auto")
    hfov = float(getattr(strip.rvr, "hfov_deg", 0.0)) or None
    folder = cache_folder(source, preferences.cache_dir)
    return AnalyzePlan(source, folder, _relative(folder), weights, depth, depth_method=method, hfov_deg=hfov)


_DEPTH_LINES: dict[str, tuple[float, str]] = {}


def depth_line(cache: Path | str) -> str:
    """One line on the depth a cache holds, from its meta.json (``depth_plan`` and ``depth_cues``),
    e.g. ``Depth (auto): parallax 40/48, people 48/48, network`` or ``Depth (auto): network;
    people off: ...``. "" for a cache without a plan (older caches, unreadable files). Cached by
    the file's mtime: panels call it on every redraw."""
    import json

    path = Path(cache) / "meta.json"
    try:
        mtime = path.stat().st_mtime
    except OSError:
        return ""
    hit = _DEPTH_LINES.get(str(path))
    if hit is not None and hit[0] == mtime:
        return hit[1]
    try:
        meta = json.loads(path.read_text())
        plan = meta.get("depth_plan") or {}
        cues = list(plan.get("cues") or [])
        used = ((meta.get("depth_cues") or {}).get("used")) or {}
        reasons = plan.get("reasons") or {}
    except (OSError, ValueError, AttributeError, TypeError):
        return ""
    if not cues:
        return ""
    n = used.get("frames")
    parts = [f"{c} {used.get(c, 0)}/{n}" if n and c not in ("network", "external") else c for c in cues]
    for extra in ("carried", "refined"):  # the moving camera's depth carried along the flow / refined with later frames
        if n and used.get(extra):
            parts.insert(len(parts) - 1 if parts and parts[-1] in ("network", "external") else len(parts),
                         f"{extra} {used[extra]}/{n}")
    line = f"Depth ({plan.get('method', '?')}): " + ", ".join(parts)
    off = [f"{k} {str(v).split(';')[0]}" for k, v in reasons.items() if str(v).startswith("off")]
    notes = (meta.get("depth_cues") or {}).get("notes") or []
    if off or notes:
        line += "; " + "; ".join(off + [str(x) for x in notes])
    _DEPTH_LINES[str(path)] = (mtime, line)
    return line


class AnalyzeJob:
    """Estimate, then stabilize, one strip's clip frames into its cache (``step()`` /
    ``progress`` / ``text`` / ``cancel()`` like every engine job)."""

    def __init__(self, plan: AnalyzePlan) -> None:
        from ..rvr_addon.estimate.infer import EstimateJob, EstimateSettings
        from ..rvr_addon.io import lock as folder_lock

        self.plan = plan
        span = plan.source.span
        self._lock = folder_lock.acquire(plan.cache, "the cache")  # held across estimate, stabilize and the swap
        self.estimate = EstimateJob(EstimateSettings(
            input=plan.source.path, output=plan.cache, weights=plan.weights, depth=plan.depth,
            no_hdr=plan.weights is None, start=span.clip_start, stop=span.clip_stop, fps=plan.source.fps,
            depth_method=plan.depth_method, hfov_deg=plan.hfov_deg, defer_commit=True))
        self.stabilize = None
        self.phase = "estimate"
        self.text = self.estimate.text
        self.cancelled = False

    @property
    def progress(self) -> float:
        if self.phase == "estimate":
            return ESTIMATE_SHARE * self.estimate.progress
        if self.stabilize is None:
            return 1.0
        return ESTIMATE_SHARE + (1 - ESTIMATE_SHARE) * self.stabilize.progress

    def step(self) -> bool:
        if self.phase == "estimate":
            if self.estimate.step():
                self.text = f"estimating frame {self.estimate.done}/{self.estimate.total}"
                return True
            if not self.plan.stabilize:
                self._commit()
                return False
            from ..rvr_addon.temporal.job import StabilizeJob, StabilizeSettings

            self.phase = "stabilize"  # where the estimate wrote: the cache, or the new one beside it
            self.stabilize = StabilizeJob(StabilizeSettings(cache=self.estimate.cache.folder,
                                                            input=self.plan.source.path))
            self.text = self.stabilize.text
            return True
        if self.phase == "stabilize":
            if self.stabilize.step():
                self.text = f"stabilizing {self.stabilize.done}/{self.stabilize.total}"
                return True
            self._commit()
        self.text = self.summary()
        return False

    def _commit(self) -> None:
        """Put a cache rebuilt beside the old one in its place; give the lock back."""
        self.estimate.cache.commit()
        self.phase = "done"
        self._lock = None

    def summary(self) -> str:
        e = self.estimate
        text = f"estimated {e.computed} frames, reused {e.reused} from the cache"
        off = [f"{k} {v.split(';')[0]}" for k, v in e.plan.reasons.items() if v.startswith("off")]
        text += f"; depth: {' + '.join(e.plan.cues)}" + (f" ({'; '.join(off)})" if off else "")
        if self.stabilize is not None:
            text += f"; {self.stabilize.text}"
        return text

    def cancel(self) -> None:
        """Stop; the frames finished so far stay valid in the cache. After the end (or a cancel)
        it does nothing."""
        if self.phase == "done" or self.cancelled:
            return
        job = self.stabilize if self.phase == "stabilize" else self.estimate
        job.cancel()
        self.cancelled = True
        cache = self.estimate.cache
        if cache.rebuilding:
            self.text = (f"cancelled: the cache '{cache.target}' is unchanged (the strip still uses it); the frames "
                         f"made with the new settings wait beside it in '{cache.folder}' for the next Analyze")
        else:
            self.text = f"cancelled: {job.text}; the cache keeps the finished frames"
        self._lock = None


def start_analyze(plan: AnalyzePlan, preferences=None) -> AnalyzeJob:
    prefs.apply_threads(preferences or prefs.get())
    return AnalyzeJob(plan)


def apply_analyze(scene_name: str, plan: AnalyzePlan) -> None:
    """Record the finished cache on the strip (the only scene change Analyze makes)."""
    scene = bpy.data.scenes.get(scene_name)
    editor = scene.sequence_editor if scene is not None else None
    strip = compat.strip_collection_all(editor).get(plan.source.strip_name) if editor is not None else None
    if strip is None:
        raise InputError(f"strip '{plan.source.strip_name}' is gone; its cache is kept at '{plan.cache}'")
    strip.rvr.cache_path = plan.cache_text


class RVR_OT_analyze(JobOperator, bpy.types.Operator):
    """Estimate disparity and HDR for the active strip and stabilize them over time, into the clip's cache (Esc cancels; finished frames are kept)"""

    bl_idname = "rvr.analyze"
    bl_label = "Analyze"
    bl_options = {"REGISTER", "UNDO"}
    job_label = "Analyze"

    @classmethod
    def poll(cls, context) -> bool:
        return poll_clip_strip(cls, context)

    def _prepare(self, context):
        notes.start()
        preferences = prefs.get(context)
        plan = plan_analyze(compat.sequencer_scene(context), compat.active_strip(context), preferences)
        return plan, start_analyze(plan, preferences)

    def _apply(self, context, plan: AnalyzePlan, job: AnalyzeJob) -> None:
        apply_analyze(plan.source.scene_name, plan)
        note = "" if plan.weights is not None else " (disparity from the strip's maps; no HDR: no estimator weights)"
        notes.report(self.report)  # first: the summary stays the last report (the status bar's)
        self.report({"INFO"}, f"Analyzed '{plan.source.strip_name}': {job.summary()}{note}; cache {plan.cache}")


classes = (RVR_OT_analyze,)
register, unregister = bpy.utils.register_classes_factory(classes)
