"""Analyze: RGBD-HDR estimate + temporal stabilization of the active strip into its cache.

:func:`plan_analyze` reads the strip (the clip frames it shows, its Disparity maps if any,
the preferences: cache location, weights, threads) into an engine
:class:`~rvr_addon.estimate.infer.EstimateSettings`; :class:`AnalyzeJob` runs the engine's
``EstimateJob`` and then its ``StabilizeJob`` on the same cache, as one job with one
progress. Both skip what the cache already holds for the same model, source and settings, so
re-running Analyze on an analysed strip only checks the cache. Cancelling keeps every frame
finished so far (the cache's meta.json is flushed) and changes nothing in the scene; only a
complete run records the cache on the strip (``strip.rvr.cache_path``).

Where D comes from: the network when weights exist (Preferences, else the shipped file),
replaced by the strip's Disparity maps when they are set ("depth from elsewhere"; E still
from the network, or 0 without weights). No weights and no maps: an error naming the missing
weights file and the two fixes.
"""
from __future__ import annotations

import importlib.util
import logging
from dataclasses import dataclass
from pathlib import Path

import bpy

from . import compat, prefs
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
    if weights is not None and importlib.util.find_spec("torch") is None:
        if depth is None:
            raise InputError("Analyze needs torch to run the estimator network, and this Blender has none: install "
                             "the full build of the extension (rvr_laaf-<version>-full.zip, built with "
                             "scripts/build_extension.py --with-torch), or set the strip's Disparity maps (depth from "
                             "elsewhere)")
        log.warning("torch is not installed: strip '%s' is analysed with its disparity maps and without HDR "
                    "recovery (install the full build of the extension for the estimator)", strip.name)
        weights = None
    folder = cache_folder(source, preferences.cache_dir)
    return AnalyzePlan(source, folder, _relative(folder), weights, depth)


class AnalyzeJob:
    """Estimate, then stabilize, one strip's clip frames into its cache (``step()`` /
    ``progress`` / ``text`` / ``cancel()`` like every engine job)."""

    def __init__(self, plan: AnalyzePlan) -> None:
        from ..rvr_addon.estimate.infer import EstimateJob, EstimateSettings

        self.plan = plan
        span = plan.source.span
        self.estimate = EstimateJob(EstimateSettings(
            input=plan.source.path, output=plan.cache, weights=plan.weights, depth=plan.depth,
            no_hdr=plan.weights is None, start=span.clip_start, stop=span.clip_stop, fps=plan.source.fps))
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
                self.phase = "done"
                return False
            from ..rvr_addon.temporal.job import StabilizeJob, StabilizeSettings

            self.phase = "stabilize"
            self.stabilize = StabilizeJob(StabilizeSettings(cache=self.plan.cache, input=self.plan.source.path))
            self.text = self.stabilize.text
            return True
        if self.phase == "stabilize":
            if self.stabilize.step():
                self.text = f"stabilizing {self.stabilize.done}/{self.stabilize.total}"
                return True
            self.phase = "done"
        self.text = self.summary()
        return False

    def summary(self) -> str:
        e = self.estimate
        text = f"estimated {e.computed} frames, reused {e.reused} from the cache"
        if self.stabilize is not None:
            text += f"; {self.stabilize.text}"
        return text

    def cancel(self) -> None:
        """Stop; the frames finished so far stay valid in the cache."""
        job = self.stabilize if self.phase == "stabilize" else self.estimate
        job.cancel()
        self.cancelled = True
        self.text = f"cancelled: {job.text}; the cache keeps the finished frames"


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
        preferences = prefs.get(context)
        plan = plan_analyze(compat.sequencer_scene(context), compat.active_strip(context), preferences)
        return plan, start_analyze(plan, preferences)

    def _apply(self, context, plan: AnalyzePlan, job: AnalyzeJob) -> None:
        apply_analyze(plan.source.scene_name, plan)
        note = "" if plan.weights is not None else " (disparity from the strip's maps; no HDR: no estimator weights)"
        self.report({"INFO"}, f"Analyzed '{plan.source.strip_name}': {job.summary()}{note}; cache {plan.cache}")


classes = (RVR_OT_analyze,)
register, unregister = bpy.utils.register_classes_factory(classes)
