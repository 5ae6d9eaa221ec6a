"""The depth system of a clip: which cues run (``--depth-method``), and the stream that runs them.

``auto`` (the default of ``rvr estimate``, Blender's Analyze and ``rvr batch``) decides per clip:

* **parallax** when the camera translates (:meth:`.parallax.ParallaxEstimator.camera_translates`
  on the first frames of the range: tracks only, no dense flow);
* **people** when MediaPipe loads (:mod:`.people`); a frame without people just has no such cue;
* **network** always: the dense prior, and the source of E.

The cues are fused per frame by :class:`.fuse.DepthFuser`. ``parallax`` forces the parallax cue
(with the network, without people), ``people`` the people cue (with the network), ``network``
is the network alone (the estimator of ``rvr_addon.estimate``, as before), ``external`` the
user's maps (``--depth``). What was decided, and why, is :class:`DepthPlan`; it is part of the
cache key, and how often each cue spoke is recorded in meta.json.
"""
from __future__ import annotations

import logging
from collections import deque
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Callable, Iterable, Iterator

import numpy as np

from ..errors import InputError
from .cues import DEFAULT_HFOV_DEG, CueMap
from .fuse import DepthFuser, FusedDepth, FusionSettings
from .methods import METHODS
from .refine import ClipRefiner

log = logging.getLogger(__name__)

PROBE_FRAMES = 48
"""Frames of the range the ``auto`` check for camera translation looks at."""
AHEAD_FRAMES = 2
"""Frames whose network and people cue a :class:`DepthStream` runs ahead, on a worker thread, while
the parallax cue works (each waits with its D, E and people map of the full frame)."""


@dataclass
class DepthPlan:
    """What a clip's depth is made of: the asked method, the cues decided, and why."""

    method: str
    cues: tuple[str, ...]
    reasons: dict[str, str] = field(default_factory=dict)
    hfov_deg: float = DEFAULT_HFOV_DEG
    fusion: FusionSettings = field(default_factory=FusionSettings)
    hfov_given: bool = False
    """The user gave the field of view; else parallax refines the focal length from the clip."""

    def key(self) -> dict:
        """The cache-key part (settings that change the result)."""
        out = {"method": self.method, "cues": list(self.cues)}
        if len(self.cues) > 1:
            out["hfov_deg"] = self.hfov_deg if self.hfov_given else "guessed"
            out["fov_across"] = "long side"  # since 2026-12-07 (was the width: portrait clips' focal too short)
            out["fusion"] = self.fusion.describe()
        if "parallax" in self.cues:  # since 2026-12-07 (caches made before recompute)
            from .parallax import FLOW_PATCH_STRIDE, MEMORY_FLOW_PRESET

            out["parallax_check"] = (f"plane sweep; pair flow patches every {FLOW_PATCH_STRIDE} px; "
                                     f"memory flow {MEMORY_FLOW_PRESET}")
        if "people" in self.cues:  # since the seventh session of 2026-12-07 (caches made before recompute)
            from .people import TILE_EVERY

            out["people_faces"] = f"small faces in tiles (whole frame every {TILE_EVERY} frames)"
        return out

    def summary(self) -> str:
        """One line for the user: ``depth: parallax + people + network (camera translates: ...)``."""
        why = "; ".join(f"{k}: {v}" for k, v in self.reasons.items())
        return f"depth ({self.method}): {' + '.join(self.cues)}" + (f" ({why})" if why else "")


def people_available() -> tuple[bool, str]:
    """Whether the people cue can run here (MediaPipe installed), and why not. A model that then
    fails to load switches the cue off at the first frame (:class:`DepthStream`)."""
    import importlib.util

    from .people import INSTALL_HINT, MEDIAPIPE_PIN

    try:
        found = importlib.util.find_spec("mediapipe") is not None
    except (ImportError, ValueError):
        found = False
    if not found:
        return False, f"the Python package {MEDIAPIPE_PIN} is not installed; {INSTALL_HINT}"
    return True, "MediaPipe installed"


def plan_depth(method: str, frames: Callable[[], Iterable[np.ndarray]] | None, hfov_deg: float | None = None,
               fusion: FusionSettings | None = None) -> DepthPlan:
    """Decide a clip's cues. ``frames``: a callable giving a fresh iterator over the range's frames
    (the ``auto`` probe reads up to PROBE_FRAMES of them); None skips the probe (no parallax)."""
    if method not in METHODS:
        raise InputError(f"--depth-method {method!r}: choose one of {', '.join(METHODS)}")
    hfov = DEFAULT_HFOV_DEG if hfov_deg is None else float(hfov_deg)
    if not 1.0 < hfov < 179.0:
        raise InputError(f"--hfov {hfov}: give the camera's field of view in degrees across the frame's long side (1..179), "
                         f"e.g. {DEFAULT_HFOV_DEG:g} for a phone's main camera")
    fusion = fusion or FusionSettings()
    given = hfov_deg is not None
    if method in ("network", "external"):
        return DepthPlan(method, (method,), {}, hfov, fusion, given)
    reasons: dict[str, str] = {}
    cues: list[str] = []
    people_ok, people_why = people_available() if method in ("auto", "people") else (False, "")
    if method in ("auto", "parallax"):
        if method == "parallax":
            cues.append("parallax")
            reasons["parallax"] = "asked for"
        elif frames is None:
            reasons["parallax"] = "not probed"
        else:
            from .parallax import ParallaxEstimator

            exclude, detector = None, None
            if people_ok:  # tracks on people are no baseline (a talking head moves every track it holds)
                from .people import PeopleDetector, PeopleModelError

                detector = PeopleDetector(hfov_deg=hfov, face_mesh=False)

                def exclude(frame: np.ndarray) -> np.ndarray | None:
                    try:
                        persons = detector(frame).persons
                    except PeopleModelError:
                        return None
                    return np.any([p.mask > 0.3 for p in persons], axis=0) if persons else None
            try:
                moving, why = ParallaxEstimator().camera_translates(_limited(frames(), PROBE_FRAMES),
                                                                    max_frames=PROBE_FRAMES, exclude=exclude)
            finally:
                if detector is not None:
                    detector.close()
            reasons["parallax"] = why
            if moving:
                cues.append("parallax")
    if method in ("auto", "people"):
        ok, why = people_ok, people_why
        if ok:
            cues.append("people")
        elif method == "people":
            raise InputError(f"--depth-method people: {why}")
        else:
            reasons["people"] = f"off: {why.splitlines()[0]}"
            log.warning("depth: the people cue is off (%s); depth comes from the other cues", why.splitlines()[0])
    cues.append("network")
    return DepthPlan(method, tuple(cues), reasons, hfov, fusion, given)


def record(plan: DepthPlan, probe_start: int, hfov_given: float | None) -> dict:
    """The plan as meta.json keeps it (``depth_plan``), enough to reuse it without probing again."""
    return {"method": plan.method, "cues": list(plan.cues), "reasons": plan.reasons, "probe_start": probe_start,
            "hfov_asked": hfov_given}


def plan_from_record(rec: object, method: str, probe_start: int, hfov_deg: float | None) -> DepthPlan | None:
    """The ``auto`` plan recorded by an earlier run on the same source (meta.json's ``depth_plan``)
    when it was made for the same method, range start and field of view, and MediaPipe is as
    available as it was then; else None (plan again). A resumed or repeated run then skips the
    probe (a decode of up to PROBE_FRAMES frames with people detection)."""
    if not isinstance(rec, dict) or method != "auto" or rec.get("method") != method:
        return None
    if rec.get("probe_start") != probe_start or rec.get("hfov_asked") != hfov_deg:
        return None
    cues = rec.get("cues")
    if not isinstance(cues, list) or not cues or cues[-1] != "network":
        return None
    if ("people" in cues) != people_available()[0]:
        return None
    hfov = DEFAULT_HFOV_DEG if hfov_deg is None else float(hfov_deg)
    reasons = rec.get("reasons") if isinstance(rec.get("reasons"), dict) else {}
    return DepthPlan(method, tuple(str(c) for c in cues), dict(reasons), hfov, FusionSettings(), hfov_deg is not None)


def _limited(frames: Iterable[np.ndarray], n: int) -> Iterator[np.ndarray]:
    for i, f in enumerate(frames):
        if i >= n:
            break
        yield f
    close = getattr(frames, "close", None)
    if close is not None:
        close()


Network = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]
"""frame (H, W, 3) uint8 -> (D (H, W) DESIGN units, E (H, W, 3))."""


class DepthStream:
    """Runs a plan's cues over one clip's frames in order and yields fused (D, E, FusedDepth).

    network: the estimator (D and E of one frame). The parallax cue looks ``window`` frames
    ahead (and holds back a clip's first maps until its gate can judge them), so frames are held
    in a bounded queue (at most window + GATE_HOLD_FRAMES + 1 full frames). While the parallax cue
    works on the main thread, the network and the people cue of the next AHEAD_FRAMES frames of
    that queue run on one worker thread (``overlap``; the parallax cue's NumPy work leaves a
    core idle); each frame's answers are the same either way. With the parallax cue, the fused
    frames are then refined with the ``refine_lag`` frames after them (:mod:`.refine`), which holds
    that many more (frame, D, E) back.
    """

    def __init__(self, plan: DepthPlan, size: tuple[int, int], network: Network, overlap: bool = True) -> None:
        """size: the clip's (width, height) in px; overlap: run the network and the people cue
        on a worker thread alongside the parallax cue (when it runs)."""
        self.plan = plan
        self.network = network
        self.overlap = bool(overlap)
        self.fuser = DepthFuser(size[0], plan.fusion, height=size[1])
        self.people = None
        self.notes: list[str] = []
        if "people" in plan.cues:
            from .people import PeopleDetector

            self.people = PeopleDetector(hfov_deg=plan.hfov_deg)
        self._refiner: ClipRefiner | None = None
        self.parallax = None
        if "parallax" in plan.cues:
            from .parallax import ParallaxEstimator, default_K

            # without a given field of view, parallax refines the focal length from the clip's own tracks
            self.parallax = ParallaxEstimator(K=default_K(*size, plan.hfov_deg) if plan.hfov_given else None)

    def close(self) -> None:
        """Free the people models (MediaPipe graphs)."""
        if self.people is not None:
            self.people.close()

    def usage(self) -> dict:
        """How many frames each cue spoke on (for meta.json and the log); ``refined``: frames
        whose depth the frames after them changed (:mod:`.refine`, a moving camera)."""
        used = dict(self.fuser.used)
        if self._refiner is not None:
            used["refined"] = self._refiner.refined
        return used

    def _parallax_maps(self, frames: Iterable[np.ndarray], queue: deque) -> Iterator[CueMap]:
        def feed():
            for f in frames:
                queue.append(f)
                yield f

        return self.parallax.maps(feed())

    def frames(self, frames: Iterable[np.ndarray]) -> Iterator[tuple[np.ndarray, np.ndarray, np.ndarray, FusedDepth]]:
        """(frame, D, E, FusedDepth) per input frame, in order."""
        if self.parallax is None:
            for frame in frames:
                yield (frame, *self._fuse(frame, self._frame_cues(frame), None))
            return
        queue: deque = deque()  # frames the parallax cue has read and not yet answered, oldest first
        ahead: deque = deque()  # futures of the per-frame cues of queue[0], queue[1], ...
        pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="rvr-depth") if self.overlap else None

        def top_up() -> None:
            while pool is not None and len(ahead) < min(AHEAD_FRAMES, len(queue)):
                ahead.append(pool.submit(self._frame_cues, queue[len(ahead)]))

        def source() -> Iterator[np.ndarray]:
            for f in frames:
                top_up()
                yield f

        refiner = ClipRefiner(self.plan.fusion)  # a moving camera: each frame refined with the ones after it
        self._refiner = refiner
        try:
            for cue in self._parallax_maps(source(), queue):
                frame = queue.popleft()
                own = ahead.popleft().result() if ahead else self._frame_cues(frame)
                top_up()
                yield from refiner.push((frame, *self._fuse(frame, own, cue)))
            yield from refiner.finish()
        finally:
            if pool is not None:
                pool.shutdown(wait=True, cancel_futures=True)

    def _frame_cues(self, frame: np.ndarray) -> tuple[np.ndarray, np.ndarray, CueMap | None]:
        """The cues of one frame that need no other frame: the network's (D, E) and the people cue
        (None without it). Runs on the worker thread when the parallax cue runs (one task at a
        time, in frame order: a people model that fails is switched off for the frames after)."""
        d, e = self.network(frame)
        people = None
        if self.people is not None:
            from .people import PeopleModelError

            try:
                people = self.people(frame).cue
            except PeopleModelError as ex:
                log.warning("depth: the people cue is off from here on (%s)", str(ex).splitlines()[0])
                self.notes.append(f"people cue off: {str(ex).splitlines()[0]}")
                self.people.close()
                self.people = None
        return d, e, people

    def _fuse(self, frame: np.ndarray, own: tuple[np.ndarray, np.ndarray, CueMap | None],
              parallax: CueMap | None) -> tuple[np.ndarray, np.ndarray, FusedDepth]:
        d, e, people = own
        cues = ([] if parallax is None else [parallax]) + ([] if people is None else [people])
        fused = self.fuser(frame, d, cues)
        return fused.disparity, e, fused


def describe_usage(plan: DepthPlan, usage: dict) -> str:
    """``parallax on 40 of 48 frames, people on 48 of 48 frames, depth carried along the flow on 12,
    refined with the frames after it on 47, network on all`` for the log (``carried``: frames where
    the depth carried from the frames before filled in where their own parallax was missing or less
    sure, :mod:`.fuse`; ``refined``: frames whose depth the frames after them changed, :mod:`.refine`)."""
    n = usage.get("frames", 0)
    parts = [f"{c} on {usage.get(c, 0)} of {n} frames" for c in plan.cues if c not in ("network", "external")]
    if usage.get("carried"):
        parts.append(f"depth carried along the flow on {usage['carried']}")
    if usage.get("refined"):
        parts.append(f"refined with the frames after it on {usage['refined']}")
    return ", ".join(parts + ["network on all"]) if parts else f"{plan.cues[0]} on all {n} frames"
