"""Inference: D and E per frame of a clip into the per-clip cache (``rvr estimate``).

:class:`Estimator` is the pure per-frame core (uint8 RGB frame -> D in DESIGN units, E);
:class:`EstimateJob` streams a clip through it (``iter_frames``; nothing but the current
frame is held), skips frames the cache already holds for the same model and source,
writes the rest (:mod:`.cache`), and exposes ``step()`` / ``progress`` / ``cancel()`` like
:class:`rvr_addon.pipeline.RenderJob`.

Depth from elsewhere (``--depth``): a per-frame depth or disparity sequence (EXR/PNG/NPY, a
phone's depth map, LiDAR, another network) replaces the network's D. Its values ``v`` are
mapped to our disparity units by ``D = scale * g(v) + offset``, ``g(v) = v`` (disparity-like
maps) or ``g(v) = 1 / v`` (``--depth-is-distance``: metric or relative distance, whose inverse
is affine in disparity for a thin lens), with ``scale``/``offset`` given (``--depth-scale``,
``--depth-offset``) or fitted to two reference points (``--depth-points x1,y1,d1 x2,y2,d2``):
pixel (x, y) of the first frame of the range should have disparity d (DESIGN units, px of
blur at aperture 1 at the native width, + = behind the focal plane). ``g`` is read at each
point as the median over a 5x5 px window (robust to an edge or a noisy pixel), and the two
equations ``d_i = scale * g_i + offset`` are solved exactly. E still comes from the network
(or is 0 everywhere with ``--no-hdr``).
"""
from __future__ import annotations

import hashlib
import json
import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np

from .. import __version__
from ..errors import InputError
from ..io.writebehind import WriteBehind

log = logging.getLogger(__name__)

WEIGHTS_DIR = Path(__file__).resolve().parent / "weights"
SHIPPED_WEIGHTS = WEIGHTS_DIR / "estimator.pt"
SHIPPED_ONNX = WEIGHTS_DIR / "estimator.onnx"
"""The shipped weights exported to ONNX (``scripts/export_onnx.py``): what runs without torch."""
SHIPPED_LAYOUT = WEIGHTS_DIR / "layout.onnx"
"""D's layout head on a pretrained detector's trunk (:mod:`.layout`), ONNX, run by ONNX Runtime."""
DEFAULT_MAX_PIXELS = 1920 * 1088
"""Frames with more pixels run the network on a copy shrunk to this many pixels; D is still
sliced and E gated at full resolution."""
CONTEXT_PIXELS = 7200
"""D's layout comes from a second, context pass of the network on a copy shrunk to this many
pixels (about 98x73 at 4:3): there the network's receptive field spans ~2.8x more of the scene,
so what is near and far across the frame is seen whole (Miangoleh et al., CVPR 2021, merge a
low-resolution pass for layout with a high-resolution one for detail). Picked on the Middlebury
views among 1/32..2x the 57,600 px the weights run at (0.804 -> 0.736), and better on Motorcycle
and the real videos too; see the weights' MODEL.md."""
CONTEXT_SIGMA = 0.02
"""Crossover of the two passes, Gaussian sigma as a fraction of the frame's width: D keeps the
main pass's detail above it and takes the context pass's layout below it."""
NO_WEIGHTS_HELP = (
    "the estimator's weights file is missing (rvr ships a trained estimator.pt in "
    "rvr_addon/estimate/weights/: restore it from the repository, see its MODEL.md). Or train your own on "
    "harness clips (`python -m sintel_eval generate ... -o DATA/clip1`, then "
    "`rvr train --data DATA -o RUN`) and pass `--weights RUN/estimator.pt`; or bring depth from "
    "elsewhere with `--depth MAPS` and `--no-hdr`."
)


def default_weights() -> Path:
    """The weights shipped in the package (``estimator.pt``, or where only its ONNX export ships,
    as in the Blender extension, ``estimator.onnx``); InputError explaining how to train them if
    absent."""
    if SHIPPED_WEIGHTS.is_file():
        return SHIPPED_WEIGHTS
    if SHIPPED_ONNX.is_file():
        return SHIPPED_ONNX
    raise InputError(f"{NO_WEIGHTS_HELP} (looked for {SHIPPED_WEIGHTS})")


def default_layout() -> object:
    """The shipped layout head (:class:`.layout.LayoutModel` on ``layout.onnx``), or None where the
    file or ONNX Runtime is missing (D's layout then comes from the network's own context pass; said
    in the log)."""
    from ..onnxrun import has_onnxruntime

    if not SHIPPED_LAYOUT.is_file() or not has_onnxruntime():
        log.warning("D's layout head is not available (%s): the network's own context pass gives D's layout; "
                    "restore rvr_addon/estimate/weights/layout.onnx from the repository or install onnxruntime",
                    "no onnxruntime" if SHIPPED_LAYOUT.is_file() else f"{SHIPPED_LAYOUT} is missing")
        return None
    from .layout import LayoutModel

    return LayoutModel(SHIPPED_LAYOUT)


@dataclass
class LoadedModel:
    """A network ready for inference, its header and the SHA-256 (first 16 hex) of its weights
    file (for an ONNX export: of the ``.pt`` it was exported from, so both backends share caches).
    backend: ``torch`` (net is an EstimatorNet) or ``onnx`` (an :class:`.onnx_infer.OnnxEstimatorNet`)."""

    net: object
    header: dict
    model_hash: str
    path: Path
    backend: str = "torch"


def load_estimator(path: str | Path, backend: str | None = None) -> LoadedModel:
    """Load estimator weights for inference.

    path: an exported weights file or training checkpoint (``.pt``, read with
    ``weights_only=True``), or an ONNX export (``.onnx``). backend: ``torch``, ``onnx`` or
    ``auto`` (None: ``$RVR_INFERENCE``, else ``auto``, :mod:`rvr_addon.onnxrun`): ``auto`` runs a
    ``.pt`` with torch when torch is importable (as fast at 360p and faster at 1080p on this
    2-core CPU: 0.025 vs 0.027 s and 0.171 vs 0.205 s a frame, ``bench/estimate_bench.py``
    ``estimate.onnx.*``; same outputs within 1e-5 px), else the ``.onnx`` beside it, exported
    from it, with ONNX Runtime; a missing ``.pt`` whose ``.onnx`` is there (the Blender
    extension) runs the ONNX.

    Raises InputError naming the file when it is missing, corrupt, or not estimator weights, or
    when neither torch nor onnxruntime can run it (with the fix).
    """
    from .. import onnxrun

    path = Path(path)
    choice = onnxrun.backend(backend)
    beside = path.with_suffix(".onnx")
    if path.suffix == ".onnx":
        onnx_file = path
    elif choice == "onnx" or (choice == "auto" and not path.is_file() and beside.is_file()):
        onnx_file = beside  # the extension ships only the export
    elif choice == "auto" and not onnxrun.has_torch() and path.is_file():
        if not onnxrun.has_onnxruntime():
            raise InputError(f"'{path}' runs with torch or, exported to ONNX, with onnxruntime; this Python has "
                             f"neither: {onnxrun.INSTALL_HELP}")
        if not onnxrun.matching_onnx(path, beside):
            raise InputError(f"'{path}' needs torch here: '{beside}' is missing or was not exported from it (the "
                             "weights changed); regenerate it with `python scripts/export_onnx.py`, or install torch")
        onnx_file = beside
    else:
        onnx_file = None
    if onnx_file is not None:
        return _load_onnx(onnx_file)
    return _load_torch(path)


def estimator_unavailable(path: str | Path, backend: str | None = None) -> str:
    """Why :func:`load_estimator` cannot run ``path`` in this Python ("" when it can), checked
    without importing torch or onnxruntime: a ``.pt`` needs torch or its matching ``.onnx`` and
    onnxruntime; an ``.onnx`` needs onnxruntime."""
    from .. import onnxrun

    path = Path(path)
    choice = onnxrun.backend(backend)
    beside = path if path.suffix == ".onnx" else path.with_suffix(".onnx")
    onnx_ok = onnxrun.has_onnxruntime() and onnxrun.matching_onnx(path, beside)
    if choice == "torch" or (path.suffix != ".onnx" and not beside.is_file()):
        return "" if onnxrun.has_torch() else f"'{path.name}' needs torch, which is not importable here"
    if onnx_ok or (choice == "auto" and path.suffix != ".onnx" and onnxrun.has_torch() and path.is_file()):
        return ""
    if not onnxrun.has_onnxruntime():
        return f"'{beside.name}' needs onnxruntime, which is not importable here ({onnxrun.INSTALL_HELP})"
    return f"'{beside}' was not exported from '{path}': regenerate it with `python scripts/export_onnx.py`"


def _load_onnx(path: Path) -> LoadedModel:
    from .. import onnxrun
    from .onnx_infer import OnnxEstimatorNet

    graph = onnxrun.load_graph(path, "estimator_trunk")
    header = graph.header
    return LoadedModel(OnnxEstimatorNet(graph, header.get("config") or {}), header,
                       graph.source_hash or onnxrun.file_hash(path), path, "onnx")


def _load_torch(path: Path) -> LoadedModel:
    """A ``.pt`` weights file or checkpoint with torch (see :func:`load_estimator`)."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"estimator weights '{path}' not found; give the estimator.pt written by `rvr train` "
                         "(RUN_DIR/estimator.pt)")
    try:
        import torch
    except ImportError as ex:
        from ..onnxrun import INSTALL_HELP

        raise InputError(f"'{path}' needs torch, which is not importable ({ex}): {INSTALL_HELP}") from ex

    from .train import CHECKPOINT_FORMAT, WEIGHTS_FORMAT
    from .unet import EstimatorConfig, EstimatorNet

    data = path.read_bytes()
    digest = hashlib.sha256(data).hexdigest()[:16]
    try:
        obj = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as ex:
        raise InputError(f"estimator weights '{path}' cannot be read ({type(ex).__name__}: {ex}); the file is corrupt "
                         "or not a torch file. Re-export it (rvr train ... --resume writes estimator.pt at the end) "
                         "or copy it again.") from ex
    fmt = obj.get("format") if isinstance(obj, dict) else None
    try:
        if fmt == WEIGHTS_FORMAT:
            header = json.loads(obj["header"])
            state, cfg = obj["state_dict"], header["config"]
        elif fmt == CHECKPOINT_FORMAT:
            cfg = json.loads(obj["model_config"])
            state = obj["model"]
            header = {"format": fmt, "config": cfg, "iterations": int(obj["iteration"]), "source": "checkpoint"}
        else:
            raise InputError(f"'{path}' is not an estimator weights file (format {fmt!r}, expected "
                             f"{WEIGHTS_FORMAT!r}); give the estimator.pt written by `rvr train`")
        net = EstimatorNet(EstimatorConfig.from_dict(cfg))
        net.load_state_dict(state)
    except InputError:
        raise
    except Exception as ex:
        raise InputError(f"estimator weights '{path}' do not fit this version's network ({type(ex).__name__}: "
                         f"{ex}); re-train or use the rvr version that wrote them") from ex
    net.eval()
    return LoadedModel(net, header, digest, path)


def preferred_max_pixels(model: LoadedModel) -> int:
    """The largest frame (in pixels) the network's trunk should see: ``inference_max_pixels``
    of the weights' header (the scale of its training frames: a network trained on 320x180
    frames sees objects at that scale; D is sliced and E gated at full resolution anyway), else
    DEFAULT_MAX_PIXELS."""
    value = model.header.get("inference_max_pixels")
    return int(value) if isinstance(value, (int, float)) and value >= 1 else DEFAULT_MAX_PIXELS


def merge_context(d: np.ndarray, d_context: np.ndarray, sigma_px: float) -> np.ndarray:
    """D with the layout of ``d_context`` and the detail of ``d``: ``d + lowpass(c) - lowpass(d)``,
    the low-pass a Gaussian of ``sigma_px`` (px of ``d``), where ``c`` is ``d_context``'s low-pass
    given ``d``'s own low-pass median and spread (:func:`match_spread`: the layout of the context
    pass at the magnitude the weights were trained at; the detail keeps its amplitude). ``d`` (H, W);
    ``d_context`` any size (the context pass's own, smaller), both in DESIGN px at the frame's
    width. The low-pass runs at the context's size, or smaller so that sigma is about 3 px there
    (cheap at 4K)."""
    import cv2

    h, w = d.shape
    hc, wc = d_context.shape
    f = min(wc / w, hc / h, 3.0 / max(sigma_px, 1e-6))
    size = (max(int(round(w * f)), 1), max(int(round(h * f)), 1))
    if size == (w, h):
        small_d, small_c = d.astype(np.float32), d_context.astype(np.float32)
    else:
        small_d = cv2.resize(d.astype(np.float32), size, interpolation=cv2.INTER_AREA)
        small_c = cv2.resize(d_context.astype(np.float32), size, interpolation=cv2.INTER_AREA)
    s = max(sigma_px * f, 1e-3)
    low_d = cv2.GaussianBlur(small_d, (0, 0), s, borderType=cv2.BORDER_REFLECT)
    low_c = match_spread(cv2.GaussianBlur(small_c, (0, 0), s, borderType=cv2.BORDER_REFLECT), low_d)
    low = low_c - low_d
    if size != (w, h):
        low = cv2.resize(low, (w, h), interpolation=cv2.INTER_LINEAR)
    return np.ascontiguousarray(d + low, dtype=np.float32)


def match_spread(d: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """``d`` mapped affinely (a positive scale about its median) onto ``reference``'s median and
    5-95 % spread (read on every 4th pixel each way): the layout of ``d`` with the magnitude of
    ``reference`` (DESIGN px). A flat ``d`` is only shifted; the scale is bounded to [1/4, 4]."""
    sub_d, sub_r = d[::4, ::4].ravel(), reference[::4, ::4].ravel()
    lo_d, med_d, hi_d = np.percentile(sub_d, (5, 50, 95))
    lo_r, med_r, hi_r = np.percentile(sub_r, (5, 50, 95))
    spread_d, spread_r = float(hi_d - lo_d), float(hi_r - lo_r)
    scale = float(np.clip(spread_r / spread_d, 0.25, 4.0)) if spread_d > 1e-6 else 1.0
    return np.ascontiguousarray(med_r + scale * (d - med_d), dtype=np.float32)


class Estimator:
    """Per-frame RGBD-HDR inference (the pure core of ``rvr estimate``).

    model: a :class:`LoadedModel`. max_pixels: frames larger than this run the network on a
    shrunk copy (linear-light area resampling); the grid is sliced with the full-resolution
    luma and E is gated at full resolution, so edges stay sharp. None: the size the weights
    ask for (:func:`preferred_max_pixels`). context_pixels: D's layout from a second pass at
    this size (:data:`CONTEXT_PIXELS`, :func:`merge_context`, at the main pass's magnitude); 0
    turns it off. layout: where D's layout comes from instead of that second pass: ``"auto"`` the
    shipped layout head (:func:`default_layout`, :mod:`.layout`; None where it is unavailable), a
    callable frame -> inverse depth up to scale and shift (larger = nearer), or None (the second
    pass). E always comes from the main pass alone.
    """

    def __init__(self, model: LoadedModel, max_pixels: int | None = None,
                 context_pixels: int = CONTEXT_PIXELS, layout: object = "auto") -> None:
        self.model = model
        self.max_pixels = int(max_pixels) if max_pixels is not None else preferred_max_pixels(model)
        self.context_pixels = int(context_pixels)
        auto = isinstance(layout, str) and layout == "auto"
        self.layout = (default_layout() if self.context_pixels > 0 else None) if auto else layout  # unused without a layout pass

    def __call__(self, frame: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """frame: (H, W, 3) uint8 sRGB. Returns (D (H, W) float32 in px of blur radius at
        aperture 1 at this width (DESIGN units), E (H, W, 3) float32 (eq. 3, >= 0))."""
        if frame.ndim != 3 or frame.shape[2] != 3:
            raise InputError(f"the estimator takes (H, W, 3) RGB frames, got shape {frame.shape}")
        h, w = frame.shape[:2]
        d, e = self._pass(frame, self.max_pixels)
        if 0 < self.context_pixels < min(self.max_pixels, h * w):
            if self.layout is not None:  # the layout head's inverse depth, in D's sign (+ = farther)
                d_context = -self.layout(frame)
            else:
                d_context, _e = self._pass(frame, self.context_pixels, full_size=False)
            d = merge_context(d, d_context, CONTEXT_SIGMA * w)
        return d, e

    def _pass(self, frame: np.ndarray, max_pixels: int, full_size: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """One pass of the network on ``frame`` shrunk to at most ``max_pixels``; (D, E) at full
        size (sliced and gated by the full-size frame), or at the shrunk size (``full_size``
        False; D still in px at the full width). D_rel is a share of the frame's long side
        (:func:`..depth.cues.blur_span`: a portrait frame gets the blur of a landscape one)."""
        if self.model.backend == "onnx":
            return self._onnx(frame, max_pixels, full_size)
        import cv2
        import torch

        from ..color import image_to_linear, linear_to_srgb, to_float01
        from ..depth.cues import blur_span
        from .unet import disparity_to_px

        h, w = frame.shape[:2]
        srgb = to_float01(frame)
        full = torch.from_numpy(np.ascontiguousarray(srgb)).permute(2, 0, 1)[None]
        small = full
        if h * w > max_pixels:
            s = (max_pixels / (h * w)) ** 0.5
            size = (max(int(w * s), 1), max(int(h * s), 1))
            shrunk = linear_to_srgb(cv2.resize(image_to_linear(frame), size, interpolation=cv2.INTER_AREA))
            small = torch.from_numpy(np.ascontiguousarray(shrunk, dtype=np.float32)).permute(2, 0, 1)[None]
        with torch.inference_mode():
            out = self.model.net(small, guide_srgb=full if small is not full and full_size else None)
            d = disparity_to_px(out.disparity_rel, float(blur_span(w, h)))[0, 0].numpy()
            e = out.exponent[0].permute(1, 2, 0).numpy()
        return np.ascontiguousarray(d, dtype=np.float32), np.ascontiguousarray(e, dtype=np.float32)

    def _onnx(self, frame: np.ndarray, max_pixels: int, full_size: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`_pass` with the ONNX trunk and numpy (:mod:`.onnx_infer`), same resampling."""
        import cv2

        from ..color import image_to_linear, linear_to_srgb, to_float01
        from ..depth.cues import blur_span
        from .onnx_infer import DISPARITY_PERCENT

        h, w = frame.shape[:2]
        srgb = np.ascontiguousarray(to_float01(frame), dtype=np.float32)
        small, guide = srgb, None
        if h * w > max_pixels:
            s = (max_pixels / (h * w)) ** 0.5
            size = (max(int(w * s), 1), max(int(h * s), 1))
            shrunk = linear_to_srgb(cv2.resize(image_to_linear(frame), size, interpolation=cv2.INTER_AREA))
            small, guide = np.ascontiguousarray(shrunk, dtype=np.float32), srgb if full_size else None
        d_rel, e = self.model.net(small, guide)
        d = d_rel * np.float32(blur_span(w, h) / DISPARITY_PERCENT)
        return np.ascontiguousarray(d, dtype=np.float32), np.ascontiguousarray(e, dtype=np.float32)


# ------------------------------------------------------------------------------ external depth


def parse_point(text: str) -> tuple[float, float, float]:
    """'x,y,d' -> (x, y, d): pixel coordinates (px, origin top-left) and disparity (DESIGN units)."""
    try:
        x, y, d = (float(v) for v in text.split(","))
    except ValueError:
        raise InputError(f"depth point {text!r} must be x,y,d (e.g. 320,200,0 for a pixel in focus)") from None
    if not all(np.isfinite((x, y, d))):
        raise InputError(f"depth point {text!r} has a non-finite value")
    return x, y, d


def sample_window(array: np.ndarray, x: float, y: float, radius: int = 2) -> float:
    """Median of the (2 radius + 1)^2 window around pixel (x, y) (clipped to the map)."""
    h, w = array.shape[:2]
    col, row = int(np.clip(np.floor(x), 0, w - 1)), int(np.clip(np.floor(y), 0, h - 1))
    win = array[max(row - radius, 0):row + radius + 1, max(col - radius, 0):col + radius + 1]
    return float(np.median(win))


def fit_two_points(values: Sequence[float], disparities: Sequence[float]) -> tuple[float, float]:
    """(scale, offset) with ``d_i = scale * v_i + offset`` through two points exactly."""
    (v1, v2), (d1, d2) = values, disparities
    if abs(v1 - v2) <= 1e-9 * max(abs(v1), abs(v2), 1.0):
        raise InputError(f"the two depth points read the same map value ({v1:g}); pick points at different "
                         "depths (e.g. one on the subject, one on the background)")
    scale = (d1 - d2) / (v1 - v2)
    return scale, d1 - scale * v1


@dataclass
class DepthSource:
    """External depth/disparity maps converted to DESIGN units: ``scale * g(raw) + offset``."""

    path: Path
    scale: float = 1.0
    offset: float = 0.0
    inverse: bool = False
    points: list[tuple[float, float, float]] = field(default_factory=list)

    def __post_init__(self) -> None:
        from ..io.maps import open_map_sequence

        self.maps = open_map_sequence(self.path, kind="disparity")

    def transform(self, raw: np.ndarray) -> np.ndarray:
        """g(raw) (1 / raw for distances; non-positive distances become the nearest valid value)."""
        if not self.inverse:
            return raw
        from ..io.maps import fill_nonfinite

        with np.errstate(divide="ignore", invalid="ignore"):
            inv = np.where(raw > 0, 1.0 / raw, np.nan).astype(np.float32)
        if not np.isfinite(inv).any():
            raise InputError(f"depth maps '{self.path}' hold no positive distance; drop --depth-is-distance if they "
                             "are disparities")
        return fill_nonfinite(inv)[0]

    def fit(self, first_index: int, size: tuple[int, int]) -> None:
        """Fit scale/offset to the two points on frame ``first_index`` (size: (w, h) of the frame)."""
        if not self.points:
            return
        if len(self.points) != 2:
            raise InputError(f"--depth-points takes exactly two points x,y,d, got {len(self.points)}")
        g = self.transform(self.maps.get(first_index if len(self.maps) > 1 else 0, size=size))
        for x, y, _ in self.points:
            if not (0 <= x < size[0] and 0 <= y < size[1]):
                raise InputError(f"depth point ({x:g}, {y:g}) lies outside the {size[0]}x{size[1]} frame")
        values = [sample_window(g, x, y) for x, y, _ in self.points]
        self.scale, self.offset = fit_two_points(values, [d for _, _, d in self.points])
        log.info("depth fitted to two points: D = %.6g * %s + %.6g", self.scale, "1/depth" if self.inverse else "map",
                 self.offset)

    def get(self, index: int, size: tuple[int, int]) -> np.ndarray:
        """D (H, W) float32 in DESIGN units for clip index ``index``."""
        raw = self.maps.get(index if len(self.maps) > 1 else 0, size=size)
        return (self.transform(raw) * np.float32(self.scale) + np.float32(self.offset)).astype(np.float32)

    def describe(self) -> dict:
        """JSON record for the cache key (path, files fingerprint, the affine used)."""
        from .cache import source_fingerprint
        from ..io.maps import MAP_EXTENSIONS

        return {"path": str(self.path), "hash": source_fingerprint(self.path, MAP_EXTENSIONS)["hash"],
                "inverse": self.inverse, "scale": self.scale, "offset": self.offset,
                "points": [list(p) for p in self.points]}


# ------------------------------------------------------------------------------ the job


@dataclass
class EstimateSettings:
    """What ``rvr estimate`` takes. weights None = the shipped weights (an error until they exist)."""

    input: Path
    output: Path
    weights: Path | None = None
    depth: Path | None = None
    depth_scale: float = 1.0
    depth_offset: float = 0.0
    depth_points: list[tuple[float, float, float]] = field(default_factory=list)
    depth_is_distance: bool = False
    no_hdr: bool = False
    start: int = 0
    stop: int | None = None
    fps: float | None = None
    max_pixels: int | None = None
    depth_method: str = "auto"
    """``auto`` | ``parallax`` | ``people`` | ``network`` | ``external`` (:mod:`rvr_addon.depth.system`)."""
    hfov_deg: float | None = None
    """The camera's field of view (deg) across the frame's long side for the geometric cues; None: a phone's (66)."""
    defer_commit: bool = False
    """When the output holds a cache of other settings, the new one is built beside it
    (:class:`~.cache.ClipCache`) and put in place once the range is done; True leaves that to
    the caller (``job.cache.commit()``: Blender's Analyze does it after stabilizing)."""


class EstimateJob:
    """Stream a clip through the estimator into its cache (see the module docstring)."""

    def __init__(self, settings: EstimateSettings, model: LoadedModel | None = None) -> None:
        """model: weights already loaded (e.g. once per batch worker, ``rvr batch``); None loads
        ``settings.weights`` (or the shipped weights) when the network is needed."""
        from ..io.video import probe_clip
        from .cache import CACHE_FORMAT, ClipCache, source_fingerprint
        from ..depth.system import record as depth_record

        from ..io.paths import check_outputs

        s = self.settings = settings
        check_outputs("estimate", [("cache folder", s.output)],
                      [("input", s.input), ("depth maps", s.depth), ("weights", s.weights)])
        if s.depth_points and (s.depth_scale != 1.0 or s.depth_offset != 0.0):
            raise InputError("give either --depth-points or --depth-scale/--depth-offset, not both")
        self.clip = probe_clip(s.input, fps=s.fps)
        stop = self.clip.frame_count if s.stop is None else min(s.stop, self.clip.frame_count)
        if s.start < 0 or s.start >= stop:
            raise InputError(f"frame range {s.start}..{stop} is empty for {s.input} ({self.clip.frame_count} frames)")
        self.start, self.stop, self.total = s.start, stop, stop - s.start
        size = (self.clip.width, self.clip.height)
        self.depth: DepthSource | None = None
        if s.depth is not None:
            self.depth = DepthSource(Path(s.depth), s.depth_scale, s.depth_offset, s.depth_is_distance,
                                     list(s.depth_points))
            self.depth.maps.place_on_timeline(self.clip)
            self.depth.maps.check_length(stop)
            self.depth.maps.warn_extra(self.clip.frame_count, s.input)
            self.depth.fit(self.start, size)
        source = source_fingerprint(s.input)
        self.plan = self._plan(size, source["hash"])
        self.model: LoadedModel | None = None
        if not s.no_hdr:
            self.model = model if model is not None else load_estimator(
                s.weights if s.weights is not None else default_weights())
        self.estimator = Estimator(self.model, s.max_pixels) if self.model is not None else None
        model_hash = self.model.model_hash if self.model is not None else "none"
        key = {"format": CACHE_FORMAT, "engine_version": __version__, "model_hash": model_hash,
               "source_hash": source["hash"], "resolution": list(size),
               "depth": self.depth.describe() if self.depth is not None else
               "network" if self.plan.cues == ("network",) else self.plan.key()}
        if size[1] > size[0]:  # since 2026-12-07: a portrait clip's D spans its long side (caches made before recompute)
            key["blur_span"] = "long side"
        if self.clip.kind == "video":
            from ..io.video import video_transfer

            transfer = video_transfer(self.clip.path)
            if transfer is not None:  # since 2026-12-07 an HDR clip's frames are tone-mapped (caches made before recompute)
                key["hdr_source"] = f"{transfer}, tone-mapped to SDR BT.709"
            if self.clip.nominal_fps is not None:  # a variable frame rate: frames of its constant-rate timeline
                key["frame_timeline"] = f"constant {self.clip.nominal_fps:.6g} fps"
        if self.estimator is not None and self.estimator.max_pixels != DEFAULT_MAX_PIXELS:
            key["max_pixels"] = self.estimator.max_pixels  # another trunk size gives other estimates
        if self.estimator is not None and self.estimator.context_pixels:
            key["context_pixels"] = self.estimator.context_pixels  # D's layout pass (caches made before it recompute)
            if self.estimator.layout is not None:  # D's layout from the layout head (issue 20, 2026-12-08)
                key["layout"] = self.estimator.layout.source_hash
        info = {"source": source, "fps": self.clip.fps, "clip_frame_count": self.clip.frame_count,
                "model": self._model_info(), "hdr": "none (--no-hdr)" if s.no_hdr else "network",
                "depth_plan": depth_record(self.plan, self.start, s.hfov_deg)}
        # depth_cues: kept when every frame is reused (the cues do not run again)
        self.cache = ClipCache(s.output, key, info, keep=("depth_cues",))
        self.stream = None
        if len(self.plan.cues) > 1:
            from ..depth.system import DepthStream

            self.stream = DepthStream(self.plan, size, self.estimator)
        self._all_cached: bool | None = None
        self._valid: set[int] = set()  # frames found intact in the cache by this run
        self.done = self.computed = self.reused = 0
        self.text = f"estimating {self.total} frames of {self.clip.path.name}"
        self._frames = None
        self._writes = WriteBehind()  # a frame's EXR is written while the next one is estimated
        self._finished = False

    def _plan(self, size: tuple[int, int], source_hash: str):
        """The clip's :class:`~rvr_addon.depth.system.DepthPlan` (which cues run, and why): the
        one an earlier run on the same source recorded in the cache when it still applies, else a
        new one (``auto`` probes the range's first frames)."""
        from ..depth.system import plan_depth, plan_from_record
        from ..io.video import iter_frames

        s = self.settings
        method = s.depth_method
        if s.depth is not None:
            if method not in ("auto", "external"):
                raise InputError(f"--depth MAPS gives the depth itself; it cannot be combined with --depth-method "
                                 f"{method} (drop one of them)")
            method = "external"
        elif method == "external":
            raise InputError("--depth-method external needs --depth MAPS (a depth or disparity sequence)")
        if s.no_hdr and method != "external":
            raise InputError("--no-hdr needs --depth: without external depth the network is what estimates D")
        earlier = None
        try:
            meta = json.loads((Path(s.output) / "meta.json").read_text())
            if isinstance(meta, dict) and meta.get("source_hash") == source_hash:
                earlier = plan_from_record(meta.get("depth_plan"), method, self.start, s.hfov_deg)
        except (OSError, ValueError):
            pass
        plan = earlier or plan_depth(method, lambda: iter_frames(s.input, start=self.start, stop=self.stop),
                                     s.hfov_deg)
        log.debug("%s", plan.summary())
        return plan

    def _model_info(self) -> dict | None:
        if self.model is None:
            return None
        h = self.model.header
        layout = self.estimator.layout if self.estimator is not None else None
        return {"path": str(self.model.path), "hash": self.model.model_hash, "iterations": h.get("iterations"),
                "config": h.get("config"), "engine_version": h.get("engine_version"),
                "layout": ({"path": str(layout.graph.path), "hash": layout.source_hash} if layout is not None
                           else "the network's context pass")}

    @property
    def progress(self) -> float:
        """Fraction of the range done (computed or reused), 0..1."""
        return self.done / self.total if self.total else 1.0

    def step(self) -> bool:
        """Process the next frame; False once the range is done."""
        from ..io.video import iter_frames

        if self._finished:
            return False
        if self._frames is None:
            self._frames = iter_frames(self.settings.input, start=self.start, stop=self.stop)
            if self.stream is not None:
                size = (self.clip.width, self.clip.height)
                self._all_cached = all(self._check(i, size) for i in range(self.start, self.stop))
                if not self._all_cached:  # the cues keep clip-wide state: run them over every frame
                    self._frames = self.stream.frames(self._frames)
        if self.stream is not None and not self._all_cached:
            return self._step_stream()
        if self._all_cached:  # every frame was found valid just above: nothing to decode, read or compute
            return self._record(self.start + self.done, (self.clip.width, self.clip.height), None)
        frame = next(self._frames, None)
        if frame is None:
            if self.done < self.total:
                self._close()
                raise InputError(f"{self.settings.input} ended after {self.done} of {self.total} frames (the file "
                                 "may be truncated: re-copy or re-export it, or pass --stop to estimate the frames "
                                 f"it holds); the frames estimated so far are kept: {self.kept()}")
            self._close()
            return False
        index = self.start + self.done
        return self._record(index, (frame.shape[1], frame.shape[0]), lambda: self.compute(frame, index))

    def _check(self, index: int, size: tuple[int, int]) -> bool:
        """True if the cache holds frame ``index`` intact at size (w, h); remembered, so a frame
        is read to check it once per run (this job holds the cache's lock: nobody rewrites it)."""
        if index in self._valid:
            return True
        if self.cache.is_valid(index, size):
            self._valid.add(index)
            return True
        return False

    def _record(self, index: int, size: tuple[int, int], result) -> bool:
        """Write frame ``index``'s (D, E) = ``result()`` unless the cache holds it; count it; False
        once the range is done."""
        if self._check(index, size):
            self.reused += 1
        else:
            d, e = result()
            self._writes.submit(self.cache.write, index, d, e)  # the previous write's error is raised here
            self.computed += 1
        self.done += 1
        if self.done >= self.total:
            self._close()
            return False
        return True

    def _step_stream(self) -> bool:
        """One frame of the depth system's stream; cached frames are recomputed (the cues' clip
        scale and fit depend on every frame before) but not rewritten."""
        item = next(self._frames, None)
        if item is None:
            self._close()
            if self.done < self.total:
                raise InputError(f"{self.settings.input} ended after {self.done} of {self.total} frames (the file "
                                 "may be truncated: re-copy or re-export it, or pass --stop to estimate the frames "
                                 f"it holds); the frames estimated so far are kept: {self.kept()}")
            return False
        frame, d, e, _fused = item
        return self._record(self.start + self.done, (frame.shape[1], frame.shape[0]), lambda: (d, e))

    def compute(self, frame: np.ndarray, index: int) -> tuple[np.ndarray, np.ndarray]:
        """(D, E) of one frame: network and/or external depth."""
        h, w = frame.shape[:2]
        d = e = None
        if self.estimator is not None:
            d, e = self.estimator(frame)
        if self.depth is not None:
            d = self.depth.get(index, (w, h))
        if e is None:
            e = np.zeros((h, w, 3), np.float32)
        return d, e

    def _close(self) -> None:
        if self._finished:
            return
        failed = self._writes.finish()  # the last frame's write; a failed one keeps the cache uncommitted
        if self._frames is not None:
            self._frames.close()
        used = ""
        if self.stream is not None:
            from ..depth.system import describe_usage

            usage = self.stream.usage()
            if usage.get("frames"):
                self.cache.info["depth_cues"] = {"used": usage, "notes": list(self.stream.notes)}
                used = f"; depth: {describe_usage(self.plan, usage)}"
            self.stream.close()
        self.cache.flush()
        if self.done >= self.total and not self.settings.defer_commit and failed is None:
            self.cache.commit()  # a cache of other settings is replaced only now, when complete
        self.cache.close()
        self._finished = True
        self.text = f"estimated {self.computed} frames, reused {self.reused} from the cache{used}"
        if failed is not None:
            raise failed

    def cancel(self) -> None:
        """Stop; frames written so far stay valid in the cache (meta.json is flushed). A cache
        of other settings at the output stays as it was (the new frames wait beside it). After
        the end it does nothing."""
        if self._finished:
            return
        self._close()
        self.text = f"cancelled after {self.done} of {self.total} frames; " + self.kept()

    def kept(self) -> str:
        """Where the frames written so far are, for messages after a stop."""
        c = self.cache
        if c.rebuilding:
            return (f"the cache '{c.target}' is unchanged (it was {c.replaces}); the new frames wait beside it in "
                    f"'{c.folder}' until the range is complete")
        return f"they are kept in '{c.folder}'"

    def run(self, progress: bool = True) -> None:
        """Run to the end with a tqdm bar; Ctrl-C flushes the cache, then re-raises."""
        from tqdm import tqdm

        with tqdm(total=self.total, unit="frame", desc="estimate", disable=not progress) as bar:
            try:
                while self.step():
                    bar.update(1)
                bar.update(self.total - bar.n)
            except BaseException:
                self.cancel()
                raise
