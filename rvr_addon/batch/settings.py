"""What a batch run takes (:class:`BatchSettings`) and what it knows of one clip (:class:`ClipPlan`).

Both are plain picklable dataclasses: the client builds them and every task receives them.
"""
from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

from .. import __version__
from ..laaf.presets import DEFAULT_CALM, DEFAULT_PRESET
from ..laaf.puller import PullSettings
from ..temporal.settings import TemporalSettings
from . import FORMATS  # noqa: F401 - re-exported: rvr_addon.batch.settings.FORMATS

BATCH_DIR = ".rvr_batch"
"""Hidden folder inside the output folder: done markers and per-clip work in progress."""


@dataclass(frozen=True)
class BatchSettings:
    """Settings of one ``rvr batch`` run (see ``rvr batch --help`` for each).

    output: folder receiving ``NAME.mp4`` (or ``NAME_frames/``) and ``NAME.focus.json`` per
    clip. cache_root: per-clip caches go to ``cache_root/NAME-HASH/`` (default
    ``output/rvr_cache``). weights: estimator weights (None = the shipped ones). depth_root:
    external disparity maps, clip NAME's in ``depth_root/NAME`` (a folder of per-frame maps,
    DESIGN units after ``D = depth_scale * map + depth_offset``); with no_hdr, E = 0 and no
    network is needed. chunk_frames: frames per task (long clips are split; 0 = whole
    clips). format: mp4 (H.264 with the source audio), png (8-bit sRGB frames) or exr
    (linear float frames). fps: frame rate of image-sequence inputs. keep_cache: False
    deletes a clip's cache once its outputs are written (at 1080p a cache frame is tens of
    MB; keep it for clips to be edited further in Blender). afnet_weights, afnet_threshold,
    afnet_speaker: preset learned (``rvr autofocus --afnet-weights/--afnet-threshold/--afnet-region``).
    calm, detect_cuts: ``rvr autofocus --calm`` and ``--no-cuts`` (shot cuts are detected per clip).
    depth_method, hfov_deg: ``rvr estimate --depth-method/--hfov`` (:mod:`rvr_addon.depth.system`;
    default auto: parallax where the camera translates, people, the network, fused; with
    depth_root the maps are the depth, method auto or external). The fused cues keep clip-wide
    state (the parallax scale chain, the network fit's memory, the clip's reference depth), so
    with a method other than network/external a clip's estimate runs as ONE task over the whole
    clip, whatever chunk_frames says (:attr:`clip_wide_estimate`); clips still run in parallel
    across workers, and the other stages are chunked as before.
    """

    output: Path
    cache_root: Path | None = None
    weights: Path | None = None
    depth_root: Path | None = None
    depth_scale: float = 1.0
    depth_offset: float = 0.0
    depth_is_distance: bool = False
    no_hdr: bool = False
    temporal: TemporalSettings = field(default_factory=TemporalSettings)
    preset: str | None = DEFAULT_PRESET
    window_s: float = 2.0
    causal: bool = False
    pull: PullSettings = field(default_factory=PullSettings)
    aperture: float = 1.0
    scale: float = 1.0
    format: str = "mp4"
    chunk_frames: int = 240
    fps: float | None = None
    force: bool = False
    retries: int = 0
    keep_cache: bool = True
    afnet_weights: Path | None = None
    afnet_threshold: float | None = None
    afnet_speaker: bool = True
    depth_method: str = "auto"
    hfov_deg: float | None = None
    calm: float = DEFAULT_CALM
    detect_cuts: bool = True

    @property
    def clip_wide_estimate(self) -> bool:
        """The estimate of a clip is one task (fused cues with clip-wide state), not chunked."""
        return self.depth_root is None and self.depth_method not in ("network", "external")

    @property
    def caches(self) -> Path:
        """Folder holding the per-clip caches."""
        return self.cache_root if self.cache_root is not None else self.output / "rvr_cache"

    def fingerprint(self, weights_id: str) -> str:
        """Hash (16 hex) of everything that changes a clip's outputs: the settings, the engine
        version, the version of LAAF's decision and the weights (``weights_id``, e.g. their hash).
        Done markers record it."""
        record = asdict(self)
        for k in ("output", "cache_root", "chunk_frames", "force", "retries", "keep_cache"):
            record.pop(k)
        if not self.clip_wide_estimate:
            # the network alone or external maps, what every batch did before the depth system (the
            # field of view is not used): earlier done markers still match
            record.pop("depth_method")
            record.pop("hfov_deg")
        from ..laaf.presets import DECISION_VERSION

        record.update(engine_version=__version__, weights=weights_id, laaf_decision=DECISION_VERSION)
        return hashlib.sha256(json.dumps(record, sort_keys=True, default=str).encode()).hexdigest()[:16]


@dataclass(frozen=True)
class ClipPlan:
    """One clip of the batch: where it comes from and where everything about it goes.

    name: output stem (unique in the batch). frames, fps, width, height, has_audio: filled in
    by the probe task (0 until then). source_hash: the source fingerprint (cache module).
    """

    index: int
    source: Path
    name: str
    cache: Path
    work: Path
    frames: int = 0
    fps: float = 0.0
    width: int = 0
    height: int = 0
    has_audio: bool = False
    source_hash: str = ""

    def probed(self, **info) -> "ClipPlan":
        """A copy with the probe's findings."""
        return replace(self, **info)

    def video_path(self, settings: BatchSettings) -> Path:
        """The rendered video (format mp4)."""
        return settings.output / f"{self.name}.mp4"

    def frames_path(self, settings: BatchSettings) -> Path:
        """The rendered frame folder (formats png, exr)."""
        return settings.output / f"{self.name}_frames"

    def focus_path(self, settings: BatchSettings) -> Path:
        """The focus file LAAF decided (``rvr render --track`` reads it)."""
        return settings.output / f"{self.name}.focus.json"

    def marker_path(self, settings: BatchSettings) -> Path:
        """The done marker written when the clip is complete."""
        return settings.output / BATCH_DIR / f"{self.name}.done.json"

    def output_paths(self, settings: BatchSettings) -> list[Path]:
        """Everything a finished clip leaves in the output folder."""
        main = self.video_path(settings) if settings.format == "mp4" else self.frames_path(settings)
        return [main, self.focus_path(settings)]
