"""What ``rvr refocus`` takes (:class:`RefocusSettings`) and the one job that runs it
(:func:`refocus_job`: a :class:`~rvr_addon.refocus.chain.JobChain` of the engine's own jobs).

The clip's work folder (``--cache``; default ``OUT_DIR/rvr_cache/STEM-HASH``) holds what a
re-run reuses: ``clip.mp4`` (the working copy, when the clip is resized or cut), ``cache/``
(D and E per frame, stabilized: the cache ``rvr estimate`` writes) and ``focus-KEY.json`` (the
autofocus decision for those depth maps and these focus settings). A run interrupted anywhere
continues where it stopped; the outputs appear only when complete.
"""
from __future__ import annotations

import hashlib
import json
import logging
import os
import shutil
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from .. import __version__
from ..errors import InputError
from ..io.paths import temp_sibling
from ..render.aperture import ApertureSpec
from . import DEFAULT_MAX_SIZE
from .chain import JobChain, Stage

if TYPE_CHECKING:  # pragma: no cover
    from ..laaf.puller import PullSettings

log = logging.getLogger(__name__)

STAGE_COST = {"working copy": 0.02, "estimate": 0.30, "stabilize": 0.12, "autofocus": 0.07, "render": 0.20,
              "before | after": 0.05, "contact sheet": 0.01}
"""Relative seconds per frame of each stage at 640x360 on 2 cores (measured; for the progress
bar's ETA only)."""


@dataclass
class RefocusSettings:
    """input: the clip (video or image sequence). output: the refocused .mp4. cache: the clip's
    work folder (None: ``OUT_DIR/rvr_cache/STEM-HASH``). preset: LAAF preset (None: the default
    preset, or with focus_on only the pinned subject). focus_on: (x, y) px of the source clip to focus on and
    track from the first frame, instead of autofocus. aperture: aperture scale (1 = the
    reference lens wide open; 0 = no blur). spec: aperture shape. start / stop: frame range
    (0-based, stop exclusive). max_size: long side in px to work at (None/0: full size).
    side_by_side / preview: also write a before | after MP4 / a contact-sheet PNG there.
    depth_method, hfov_deg: ``rvr estimate``'s. window_s, causal: LAAF's look-ahead (causal also
    makes the temporal filter causal: what a camera could do live).
    weights: estimator weights (None: the shipped ones). fps: of an image-sequence input.
    stabilize: run the temporal filter on D and E (paper 4.2)."""

    input: Path
    output: Path
    cache: Path | None = None
    preset: str | None = None
    focus_on: tuple[float, float] | None = None
    aperture: float = 1.0
    spec: ApertureSpec = field(default_factory=ApertureSpec)
    start: int = 0
    stop: int | None = None
    duration_s: float | None = None
    """Instead of ``stop``: this many seconds from ``start`` (at the clip's frame rate)."""
    max_size: int | None = DEFAULT_MAX_SIZE
    side_by_side: Path | None = None
    preview: Path | None = None
    depth_method: str = "auto"
    hfov_deg: float | None = None
    window_s: float = 2.0
    causal: bool = False
    weights: Path | None = None
    fps: float | None = None
    stabilize: bool = True
    preview_rows: int = 4
    calm: float | None = None
    """LAAF's calm <-> responsive knob 0..1 (None: its default)."""
    pull: PullSettings | None = None
    """Focus pulls' length, lead, profile and hold (None: LAAF's defaults, 0.4 s pulls landing 0.2 s early)."""
    cuts: list[int] | None = None
    """Shot cuts given by the user (0-based frames of the source clip); None: detected."""
    detect_cuts: bool = True
    track: Path | None = None
    """A focus file or track to render with instead of running the autofocus (e.g. the
    ``OUT.focus.json`` of an earlier run, edited); frames and units of the working copy."""
    device: str = "auto"
    """Where the render stage runs: auto (CUDA when torch sees a GPU, else the CPU), cpu or cuda."""


def default_work_folder(source: Path, output: Path) -> Path:
    """``OUT_DIR/rvr_cache/STEM-HASH``: the clip's work folder beside the output (HASH: 8 hex of
    the source fingerprint, so two clips of one name never share it)."""
    from ..estimate.cache import source_fingerprint

    digest = source_fingerprint(source)["hash"]
    return Path(output).parent / "rvr_cache" / f"{Path(source).stem}-{str(digest)[:8]}"


def is_picture(path: Path) -> bool:
    """Whether ``path`` is one picture file (a photo: .jpg, .png, .tif, .exr), not a video, an
    image folder or a frame pattern."""
    from ..pipeline import is_still_output

    return is_still_output(path) and Path(path).is_file()


def default_output(source: Path) -> Path:
    """``CLIP_refocused.mp4`` beside the clip; a photo's is a picture of its own type
    (``photo_refocused.jpg``)."""
    source = Path(source)
    suffix = source.suffix if is_picture(source) else ".mp4"
    return source.with_name(source.stem + "_refocused" + suffix)


def derived_path(output: Path, suffix: str) -> Path:
    """``OUT_DIR/STEM<suffix>`` (e.g. ``_side_by_side.mp4``, ``_sheet.png``, ``.focus.json``)."""
    output = Path(output)
    return output.with_name(output.stem + suffix)


def _depth_record(cache: Path) -> dict:
    """What a cache's depth maps are: its key and stabilization record, and the engine version."""
    from ..estimate.cache import KEY_FIELDS

    meta = json.loads((Path(cache) / "meta.json").read_text())
    record = {k: meta.get(k) for k in KEY_FIELDS}
    record.update(stabilized=meta.get("stabilized"), engine_version=__version__)
    return record


def _digest(record: dict) -> str:
    return hashlib.sha256(json.dumps(record, sort_keys=True, default=str).encode()).hexdigest()[:16]


def focus_key(cache: Path, settings: dict) -> str:
    """16 hex naming an autofocus decision: the cache's key and stabilization record (what the
    depth maps are), the focus settings and the version of LAAF's decision logic."""
    from ..laaf.presets import DECISION_VERSION

    return _digest({**_depth_record(cache), "focus": settings, "laaf_decision": DECISION_VERSION})


def render_key(cache: Path, focus_file: Path, spec: ApertureSpec, settings: dict) -> str:
    """16 hex naming a render: the depth maps (:func:`focus_key`'s record), the focus file's
    bytes (an edited ``--track`` file renders again), the aperture shape and the other render
    settings (``settings``: device, frame rate, output type)."""
    kernel = spec.kernel_image
    shape = {"shape": spec.shape, "blades": spec.blades, "rotation_deg": spec.rotation_deg, "squeeze": spec.squeeze,
             "cat_eye": spec.cat_eye, "zones": spec.zones,
             "kernel": None if kernel is None else hashlib.sha256(np.ascontiguousarray(kernel).tobytes()).hexdigest()}
    focus = hashlib.sha256(Path(focus_file).read_bytes()).hexdigest()
    return _digest({**_depth_record(cache), "focus_file": focus, "aperture": shape, "render": settings})


def render_reusable(record: Path, output: Path) -> bool:
    """Whether ``output`` is the file a finished render recorded in ``record`` (same path, size and
    modification time): unchanged since, so rendering again would write the same frames."""
    if not (record.is_file() and output.is_file()):
        return False
    try:
        done = json.loads(record.read_text())
    except (OSError, ValueError):
        return False
    st = output.stat()
    return done == {"output": str(output.resolve()), "size": st.st_size, "mtime_ns": st.st_mtime_ns}


def record_render(record: Path, output: Path) -> None:
    """Write ``record`` (atomically) for the finished render ``output`` (:func:`render_reusable`)."""
    st = output.stat()
    tmp = temp_sibling(record, ".json")
    try:
        tmp.write_text(json.dumps({"output": str(output.resolve()), "size": st.st_size, "mtime_ns": st.st_mtime_ns}))
        os.replace(tmp, record)
    finally:
        tmp.unlink(missing_ok=True)


def _copy_atomic(src: Path, dst: Path) -> None:
    dst.parent.mkdir(parents=True, exist_ok=True)
    tmp = temp_sibling(dst, dst.suffix)
    try:
        shutil.copyfile(src, tmp)
        os.replace(tmp, dst)
    finally:
        tmp.unlink(missing_ok=True)


@dataclass
class RefocusRun:
    """What a run decided and where everything went (filled in as the stages finish)."""

    settings: RefocusSettings
    work: Path
    clip: Path
    cache: Path
    focus_file: Path | None = None
    outputs: list[Path] = field(default_factory=list)
    kept: list[Path] = field(default_factory=list)
    """Outputs of an earlier run left as they were (the same render again: :func:`render_reusable`)."""
    notes: list[str] = field(default_factory=list)
    frames: int = 0
    size: tuple[int, int] = (0, 0)


def check_outputs(s: RefocusSettings) -> None:
    """Refuse outputs that would overwrite the clip (or lie inside its frames folder) or each
    other, before anything runs."""
    from ..io.paths import check_outputs as refuse_overlaps
    from ..pipeline import VIDEO_SUFFIXES, is_still_output

    if Path(s.output).suffix.lower() not in VIDEO_SUFFIXES and not is_still_output(Path(s.output)):
        raise InputError(f"-o {s.output}: the refocused video is a movie file; give a name ending in .mp4 "
                         "(or, for a photo, .jpg, .png, .tif or .exr)")
    if s.side_by_side is not None and Path(s.side_by_side).suffix.lower() not in VIDEO_SUFFIXES and not (
            is_still_output(Path(s.side_by_side)) and is_still_output(Path(s.output))):
        raise InputError(f"--side-by-side {s.side_by_side}: give a name ending in .mp4 (or, beside a picture "
                         "output, .jpg or .png)")
    if s.preview is not None and Path(s.preview).suffix.lower() not in (".png", ".jpg", ".jpeg"):
        raise InputError(f"--preview {s.preview}: give a name ending in .png or .jpg")
    outputs = [("refocused video", s.output), ("before | after video", s.side_by_side),
               ("contact sheet", s.preview)]
    refuse_overlaps("refocus", outputs, [("clip", s.input)])
    seen: dict[Path, str] = {}
    for what, p in outputs:
        if p is None:
            continue
        r = Path(p).resolve()
        if r in seen:
            raise InputError(f"'{p}' is given as the {seen[r]} and the {what}; give each its own name")
        seen[r] = what


def refocus_job(s: RefocusSettings) -> tuple[JobChain, RefocusRun]:
    """The chain of stages of one ``rvr refocus`` run and the record it fills in."""
    from ..io.video import probe_clip
    from .proxy import ProxyJob, needs_proxy, proxy_size

    check_outputs(s)
    from ..render.device import resolve_device

    resolve_device(s.device)  # --device cuda without a GPU: refused before any work
    if s.track is not None and not Path(s.track).is_file():
        raise InputError(f"--track {s.track}: no such focus file; give the OUT.focus.json of an earlier run")
    if not Path(s.input).exists():
        raise InputError(f"the clip '{s.input}' was not found; check the path")
    if not (s.aperture >= 0):
        raise InputError(f"--aperture must be >= 0 (0 = no blur), got {s.aperture}")
    if s.max_size is not None and s.max_size < 0:
        raise InputError(f"--max-size {s.max_size}: give a long side in px (e.g. 1280), or 0 for the clip's size")
    source = probe_clip(s.input, fps=s.fps)  # a variable frame rate: its constant-rate timeline
    if s.duration_s is not None:  # --duration: frames from --start at the clip's rate
        s = replace(s, stop=s.start + max(1, int(round(s.duration_s * source.fps))), duration_s=None)
    work = Path(s.cache) if s.cache is not None else default_work_folder(Path(s.input), Path(s.output))
    proxy = needs_proxy(source, s.max_size, s.start, s.stop)
    picture = is_picture(Path(s.input)) and source.frame_count == 1
    from ..pipeline import refuse_picture_of_many

    refuse_picture_of_many(s.output, (source.frame_count if s.stop is None else min(s.stop, source.frame_count))
                           - s.start, "-o")
    run = RefocusRun(settings=s, work=work, clip=Path(s.input), cache=work / "cache")
    if source.nominal_fps is not None:
        run.notes.append(f"variable frame rate (average {source.average_fps:.4g} fps): worked at a constant "
                         f"{source.nominal_fps:.4g} fps, each frame at its time, so sound and picture stay in sync")
    stages: list[Stage] = []
    factor = 1.0
    if proxy:
        stop = source.frame_count if s.stop is None else min(s.stop, source.frame_count)
        if s.start < 0 or s.start >= stop:
            raise InputError(f"--start {s.start} / --stop {s.stop}: the range is empty for '{s.input}' "
                             f"({source.frame_count} frames)")
        w, h = proxy_size(source.width, source.height, s.max_size)
        # a photo's working copy is a lossless PNG (an H.264 copy would halve its colour resolution)
        run.clip = work / (f"picture_{w}x{h}.png" if picture else f"clip_{w}x{h}_{s.start}_{stop}.mp4")
        factor = w / source.width
        run.frames, run.size = stop - s.start, (w, h)
        if (w, h) != (source.width, source.height):
            run.notes.append(f"working at {w}x{h} (the clip is {source.width}x{source.height}; --max-size 0 keeps "
                             f"its size)")

        def build_proxy():
            if run.clip.is_file():
                return None  # made by an earlier run (written atomically: complete)
            if picture:
                return OneShot(lambda: picture_copy(Path(s.input), run.clip, (w, h)))
            return ProxyJob(Path(s.input), run.clip, s.max_size, s.start, stop, fps=s.fps, clip=source)

        stages.append(Stage("working copy", STAGE_COST["working copy"] * run.frames, build_proxy))
    else:
        run.frames, run.size = source.frame_count, (source.width, source.height)
    n = run.frames
    px = run.size[0] * run.size[1] / (640 * 360)

    def build_estimate():
        from ..estimate.infer import EstimateJob, EstimateSettings

        job = EstimateJob(EstimateSettings(input=run.clip, output=run.cache, weights=s.weights,
                                           depth_method=s.depth_method, hfov_deg=s.hfov_deg, fps=s.fps))
        run.notes.append(job.plan.summary())
        return job

    stages.append(Stage("estimate", STAGE_COST["estimate"] * n * px, build_estimate))
    if s.stabilize:
        def build_stabilize():
            from ..temporal.job import StabilizeJob, StabilizeSettings
            from ..temporal.settings import TemporalSettings

            window = "causal" if s.causal else TemporalSettings.window  # --causal: no frame after the current one
            job = StabilizeJob(StabilizeSettings(cache=run.cache, input=run.clip,
                                                 temporal=TemporalSettings(window=window)))
            return job if job.total else None

        stages.append(Stage("stabilize", STAGE_COST["stabilize"] * n * px, build_stabilize))

    focus_on = None if s.focus_on is None else (s.focus_on[0] * factor, s.focus_on[1] * factor)
    preset = s.preset
    if preset is None and focus_on is None:  # nothing pinned: the autofocus decides, with the default preset
        from ..laaf.presets import DEFAULT_PRESET

        preset = DEFAULT_PRESET
    first = s.start if proxy else 0
    cuts = None if s.cuts is None else [c - first for c in s.cuts if 0 < c - first < n]
    calm = {} if s.calm is None else {"calm": s.calm}
    pull = {} if s.pull is None else {"pull": s.pull}
    focus_settings = {"preset": preset, "focus_on": focus_on, "aperture": s.aperture, "window_s": s.window_s,
                      "causal": s.causal, "cuts": cuts, "detect_cuts": s.detect_cuts, **calm,
                      **({"pull": asdict(s.pull)} if s.pull is not None else {})}

    def build_autofocus():
        from ..laaf.lookahead import AutofocusJob, AutofocusSettings

        if s.track is not None:
            run.focus_file = Path(s.track)
            run.notes.append(f"focus: from {s.track} (no autofocus)")
            return None
        key = focus_key(run.cache, focus_settings)
        run.focus_file = run.work / f"focus-{key}.json"
        if run.focus_file.is_file():
            run.notes.append(f"focus: reused {run.focus_file.name} (same depth, same focus settings)")
            return None
        nfts = None
        if focus_on is not None:
            nfts = [pinned_target(focus_on, run.size)]
        return AutofocusJob(AutofocusSettings(input=run.clip, cache=run.cache, preset=preset, nfts=nfts,
                                              window_s=s.window_s, causal=s.causal, aperture=s.aperture,
                                              fps=s.fps, cuts=cuts, detect_cuts=s.detect_cuts, **calm, **pull))

    def finish_autofocus(job) -> None:
        from ..laaf.focusfile import write_focus_file

        result = job.result
        write_focus_file(run.focus_file, result)
        used = result.settings.get("preset_used") or ("pinned subject" if focus_on else "manual")
        note = f"; {result.settings['fallback']}" if result.settings.get("fallback") else ""
        run.notes.append(f"focus: {used}, {len(result.nfts)} target(s), {len(result.composed.pulls)} pull(s){note}")

    stages.append(Stage("autofocus", STAGE_COST["autofocus"] * n * px, build_autofocus, finish_autofocus, frames=n))

    def render_record() -> Path:
        key = render_key(run.cache, run.focus_file, s.spec,
                         {"device": s.device, "fps": s.fps, "output_type": Path(s.output).suffix.lower()})
        return run.work / f"render-{key}.json"

    def build_render():
        from ..pipeline import RenderJob, RenderSettings

        if render_reusable(render_record(), Path(s.output)):  # e.g. the same command with --preview added
            run.notes.append(f"render: reused {Path(s.output).name} (same depth, focus and render settings; "
                             "delete it to render again)")
            run.kept.append(Path(s.output))
            finish_render(None)
            return None
        return RenderJob(RenderSettings(input=run.clip, depth=run.cache, hdr=run.cache, outputs=[Path(s.output)],
                                        track=run.focus_file, spec=s.spec, fps=s.fps, device=s.device))

    def finish_render(job) -> None:
        if job is not None:
            record_render(render_record(), Path(s.output))
        run.outputs.append(Path(s.output))
        focus_copy = derived_path(Path(s.output), ".focus.json")
        if Path(run.focus_file).resolve() != focus_copy.resolve():  # --track OUT.focus.json: already there
            _copy_atomic(run.focus_file, focus_copy)
        run.outputs.append(focus_copy)

    stages.append(Stage("render", STAGE_COST["render"] * n * px, build_render, finish_render))
    if s.side_by_side is not None:
        def build_sbs():
            from .sidebyside import SideBySideJob

            return SideBySideJob(run.clip, Path(s.output), Path(s.side_by_side))

        stages.append(Stage("before | after", STAGE_COST["before | after"] * n * px, build_sbs,
                            lambda job: run.outputs.append(Path(s.side_by_side))))
    if s.preview is not None:
        stages.append(Stage("contact sheet", STAGE_COST["contact sheet"] * n * px,
                            lambda: OneShot(lambda: _sheet(run, s)),
                            lambda job: run.outputs.append(Path(s.preview))))
    return JobChain(stages), run


def _sheet(run: RefocusRun, s: RefocusSettings) -> None:
    from .preview import write_contact_sheet

    write_contact_sheet(Path(s.preview), run.clip, run.cache, Path(s.output), run.focus_file, rows=s.preview_rows)


def picture_copy(source: Path, output: Path, size: tuple[int, int]) -> None:
    """A photo's working copy: ``source`` resized (area filter) to ``size`` (w, h) and written as a
    PNG ``output``, atomically."""
    import cv2

    from ..io.video import iter_frames
    from ..io.writer import StillImageWriter

    frame = next(iter(iter_frames(source)))
    if (frame.shape[1], frame.shape[0]) != tuple(size):
        frame = cv2.resize(frame, tuple(size), interpolation=cv2.INTER_AREA)
    with StillImageWriter(output) as w:
        w.write(frame)


class OneShot:
    """A job of one step (a short task run in the chain like the others)."""

    def __init__(self, fn) -> None:
        self.fn = fn
        self.progress = 0.0
        self.text = ""

    def step(self) -> bool:
        """Run the task; always False (done after one step)."""
        if self.progress < 1.0:
            self.fn()
            self.progress = 1.0
            self.text = "done"
        return False

    def cancel(self) -> None:
        """Before its step: it will not run; after it: nothing changes."""
        if self.progress < 1.0:
            self.progress = 1.0
            self.text = "cancelled before it ran"


def pinned_target(point: tuple[float, float], size: tuple[int, int]):
    """The manual NFT of ``--focus-on X,Y`` (px of the working clip): due on the first frame,
    a box of a tenth of the frame's width around the point, tracked from there."""
    from ..laaf.nft import NFT

    w, h = size
    x = min(max(float(point[0]), 0.0), w - 1.0)
    y = min(max(float(point[1]), 0.0), h - 1.0)
    side = max(8.0, w / 10)
    box = (max(0.0, x - side / 2), max(0.0, y - side / 2), min(side, w - max(0.0, x - side / 2)),
           min(side, h - max(0.0, y - side / 2)))
    return NFT(x=x, y=y, t=0, box=box, source="manual")
