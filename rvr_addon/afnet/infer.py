"""AF-Net inference: weights, the streaming runner, and New Focus Targets from its outputs.

:func:`load_afnet` reads exported weights (``rvr train-afnet``; default
``rvr_addon/afnet/weights/afnet.pt``) with ``torch.load(weights_only=True)``, or runs their ONNX
export beside them (``afnet_unit.onnx`` and ``afnet_head.onnx``, ``scripts/export_onnx.py``) with
ONNX Runtime when it is importable (:mod:`rvr_addon.onnxrun`: no torch needed, as in the Blender
extension). The stream drives either through the same numpy interface (:class:`TorchRunner`,
:class:`OnnxRunner`).

:class:`AFNetStream` takes a clip's frames in order (:func:`.model.encode_frame` bytes) and
evaluates a query every ``stride`` frames (q = 0, stride, 2 stride, ...) as soon as the frames
it sees are in: frame ``min(q + half_span, n - 1)``. CNN-1 outputs are cached by unit centre,
so a query costs one CNN-1 and one CNN-2 pass; frames and features no query needs any more are
dropped (the stream holds about ``span + stride`` frames). A network with an audio input gets
the clip's audio numbers (:mod:`.audio_features`, the whole clip at once: sound is small) at
construction; without sound they are zeros, as in training. Frames before 0 or after the last
repeat the first/last frame (padding); a clip shorter than the receptive field is padded the
same way, with a warning (:func:`check_length`).

NFTs (:func:`pick_peaks`): local maxima of P over the queries that reach ``threshold``, at least
``min_gap`` frames apart (non-maximum suppression), refined between the grid points by a
parabola through the peak and its neighbours; frame 0 is the initial focus, never an NFT. The
focus region of an NFT (:func:`region_from_map`) is read from the map of the first unit centre
at least ``REGION_LAG_FRAMES`` (10) frames after it (:meth:`AFNetStream.region_frame`: where
the focus goes, not the target before the change, which a map near the change still partly
shows; on 11 harness clips the network had not seen, reading 10 frames after instead of 5
halved the error of the focus read there, 0.51 -> 0.26 disparity units, at no extra latency:
the peak's decision waits for later frames anyway): the part of the map above half its maximum
that holds the maximum, its bounding box and probability-weighted centroid. :func:`predict_clip`
runs a whole clip at once (tests, tools).
"""
from __future__ import annotations

import contextlib
import hashlib
import io
import json
import logging
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable

import numpy as np

from ..errors import InputError
from .audio_features import window
from .config import AFNetConfig
from .encoding import decode_frames_np

log = logging.getLogger(__name__)

DEFAULT_WEIGHTS = Path(__file__).resolve().parent / "weights" / "afnet.pt"
REGION_LAG_FRAMES = 10
"""An NFT's region comes from the first map at least this many frames after it (module docstring)."""
WEIGHTS_FORMAT = "rvr-laaf-afnet/1"


def onnx_paths(path: Path) -> tuple[Path, Path]:
    """The ONNX export of AF-Net weights ``DIR/NAME.pt`` (or of ``DIR/NAME_unit.onnx`` itself):
    ``DIR/NAME_unit.onnx`` and ``DIR/NAME_head.onnx``."""
    stem = path.stem[:-len("_unit")] if path.suffix == ".onnx" and path.stem.endswith("_unit") else path.stem
    return path.with_name(f"{stem}_unit.onnx"), path.with_name(f"{stem}_head.onnx")


def load_afnet(path: str | Path | None = None, backend: str | None = None) -> tuple[object, dict]:
    """(model, header dict) from exported weights (default: the shipped ones). The model is an
    :class:`~.model.AFNet` in eval mode (torch) or an :class:`OnnxAFNet`; both have ``config``
    and run in :class:`AFNetStream`. The header gains ``file_id``: the first 16 hex digits of the
    weights file's SHA-256 (what a batch's fingerprint records; an ONNX export records the one of
    the ``.pt`` it came from).

    backend: ``torch``, ``onnx`` or ``auto`` (None: ``$RVR_INFERENCE``, else ``auto``): ``auto``
    runs the ONNX export beside the weights when onnxruntime is importable and the export was
    made from them (or the ``.pt`` is absent, as in the Blender extension): it is faster than
    torch here (0.14 vs 0.24 s for a 30-frame clip, one thread each, same P within 1e-5), else torch.

    Raises InputError naming the path and the command that makes the file when it is missing,
    unreadable, of another format or of another architecture, or when neither torch nor
    onnxruntime can run it."""
    from .. import onnxrun

    path = Path(path) if path is not None else DEFAULT_WEIGHTS
    choice = onnxrun.backend(backend)
    unit, head = onnx_paths(path)
    exported = onnxrun.matching_onnx(path, unit) and onnxrun.matching_onnx(path, head)
    if path.suffix == ".onnx" or choice == "onnx" or (choice == "auto" and onnxrun.has_onnxruntime() and exported):
        return _load_onnx(unit, head)
    if choice == "auto" and not onnxrun.has_torch():
        raise InputError(f"AF-Net weights '{path}' need torch here, or their ONNX export (`python "
                         f"scripts/export_onnx.py` where torch is, writes {unit.name} and {head.name} beside them) "
                         f"and onnxruntime; {onnxrun.INSTALL_HELP}")
    return _load_torch(path)


def _load_onnx(unit: Path, head: Path) -> tuple["OnnxAFNet", dict]:
    from .. import onnxrun

    graphs = onnxrun.load_graph(unit, "afnet_unit", 1), onnxrun.load_graph(head, "afnet_head", 1)
    if graphs[0].source_hash != graphs[1].source_hash:
        raise InputError(f"'{unit}' and '{head}' come from different weights; regenerate both with "
                         "`python scripts/export_onnx.py`")
    header = {**graphs[0].header, "file_id": graphs[0].source_hash}
    try:
        config = AFNetConfig.from_dict(header["config"]).check()
    except (KeyError, ValueError) as ex:
        raise InputError(f"'{unit}' records no AF-Net config this version reads ({ex}); regenerate it with "
                         "`python scripts/export_onnx.py`") from ex
    return OnnxAFNet(config, *graphs), header


def _load_torch(path: Path) -> tuple[object, dict]:
    """AF-Net weights with torch (see :func:`load_afnet`)."""
    make = ("train them with `rvr train-afnet --data DATASET -o RUN` (scripts/afnet_data.sh makes the data) "
            f"and pass --afnet-weights RUN/afnet.pt, or copy RUN/afnet.pt to {DEFAULT_WEIGHTS}; the presets "
            "action, conversation, faces and salient work without AF-Net")
    if not path.is_file():
        raise InputError(f"AF-Net weights '{path}' not found: {make}")
    try:
        import torch
    except ImportError as ex:
        from ..onnxrun import INSTALL_HELP

        raise InputError(f"'{path}' needs torch, which is not importable ({ex}): {INSTALL_HELP}") from ex
    from .model import AFNet

    try:
        data = path.read_bytes()
        ck = torch.load(io.BytesIO(data), map_location="cpu", weights_only=True)
    except Exception as ex:  # noqa: BLE001 - any unpickling failure means a corrupt or foreign file
        raise InputError(f"AF-Net weights '{path}' cannot be read ({type(ex).__name__}: {ex}); {make}") from ex
    if not isinstance(ck, dict) or ck.get("format") != WEIGHTS_FORMAT:
        raise InputError(f"'{path}' is not an AF-Net weights file ({WEIGHTS_FORMAT}; a checkpoint.pt is not one: "
                         f"use the run's afnet.pt); {make}")
    try:
        header = {**json.loads(ck["header"]), "file_id": hashlib.sha256(data).hexdigest()[:16]}
        model = AFNet(AFNetConfig.from_dict(header["config"]))
        model.load_state_dict(ck["state_dict"])
    except (KeyError, ValueError, RuntimeError) as ex:
        raise InputError(f"AF-Net weights '{path}' do not fit this version's network ({ex}); retrain with "
                         "`rvr train-afnet`") from ex
    model.eval()
    return model, header


class OnnxAFNet:
    """AF-Net as its two exported graphs (CNN-1 per unit, CNN-2 head) on ONNX Runtime."""

    def __init__(self, config: AFNetConfig, unit, head) -> None:
        self.config = config
        self.unit_graph, self.head_graph = unit, head

    def eval(self) -> "OnnxAFNet":
        """Nothing to switch (the torch model's ``eval()``, for the stream)."""
        return self


class OnnxRunner:
    """CNN-1 and CNN-2 of an :class:`OnnxAFNet` on numpy arrays (the stream's interface)."""

    def __init__(self, model: OnnxAFNet) -> None:
        self.model, self.config = model, model.config

    def unit(self, codes: np.ndarray, audio: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """codes (N, f_T, C, H, W) uint8, audio (N, f_T, audio) float32 or None -> (features
        (N, C1, H/8, W/8), map logits (N, H/4, W/4)), as :meth:`.model.AFNet.unit`."""
        cfg = self.config
        x = decode_frames_np(codes, cfg)
        n, f, c, h, w = x.shape
        x = x.reshape(n, f * c, h, w)
        if cfg.audio:
            a = cfg.audio
            planes = np.zeros((n, f * a), np.float32) if audio is None else audio.reshape(n, f * a).astype(np.float32)
            x = np.concatenate([x, np.broadcast_to(planes[:, :, None, None], (n, f * a, h, w))], axis=1)
        feat, m = self.model.unit_graph.run({"x": np.ascontiguousarray(x, dtype=np.float32)})
        return feat, m[:, 0]

    def head(self, feats: np.ndarray, audio: np.ndarray | None) -> np.ndarray:
        """feats (B, s, C1, h, w), audio (B, audio, span) or None -> NFT logits (B,)."""
        cfg = self.config
        b, s, c, h, w = feats.shape
        feeds = {"feats": np.ascontiguousarray(feats.reshape(b, s * c, h, w), dtype=np.float32)}
        if cfg.audio:
            feeds["audio"] = (np.zeros((b, cfg.audio, cfg.span), np.float32) if audio is None
                              else np.ascontiguousarray(audio, dtype=np.float32))
        return self.model.head_graph.run(feeds)[0].reshape(b)


class TorchRunner:
    """CNN-1 and CNN-2 of a torch :class:`~.model.AFNet` on numpy arrays (the stream's interface)."""

    def __init__(self, model) -> None:
        self.model, self.config = model.eval(), model.config

    def unit(self, codes: np.ndarray, audio: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        import torch

        from .model import decode_frames

        with torch.inference_mode():
            feat, m = self.model.unit(decode_frames(codes, self.config),
                                      None if audio is None else torch.from_numpy(np.ascontiguousarray(audio)))
        return feat.numpy(), m.numpy()

    def head(self, feats: np.ndarray, audio: np.ndarray | None) -> np.ndarray:
        import torch

        with torch.inference_mode():
            out = self.model.head(torch.from_numpy(np.ascontiguousarray(feats)),
                                  None if audio is None else torch.from_numpy(np.ascontiguousarray(audio)))
        return out.numpy()


def runner_of(model) -> "OnnxRunner | TorchRunner":
    """The numpy interface of a loaded AF-Net (ONNX or torch)."""
    return OnnxRunner(model) if isinstance(model, OnnxAFNet) else TorchRunner(model)


@contextlib.contextmanager
def torch_threads(n: int | None):
    """Run the block with ``n`` torch CPU threads (None: as set), then restore the setting; nothing
    without torch loaded (an ONNX AF-Net has its own single thread).

    A query is a few small convolutions: on a busy 2-core machine two threads spin against the
    other jobs and were 9x slower than one (0.31 s vs 2.8 s for a 40-frame test clip)."""
    import sys

    torch = sys.modules.get("torch")
    if torch is None:
        yield
        return
    old = torch.get_num_threads()
    if n is None or n == old:
        yield
        return
    torch.set_num_threads(n)
    try:
        yield
    finally:
        torch.set_num_threads(old)


def check_length(n_frames: int, config: AFNetConfig, what: str = "the clip") -> bool:
    """Warn (and return True) when a clip is shorter than AF-Net's receptive field."""
    if n_frames < config.span:
        log.warning("%s has %d frames, fewer than AF-Net's receptive field of %d frames (%d sampled frames, every "
                    "%d): the first/last frame is repeated to fill it (padding); expect weaker predictions",
                    what, n_frames, config.span, config.frames_seen, config.sample_step)
        return True
    return False


def map_to_prob_np(logits: np.ndarray) -> np.ndarray:
    """Spatial softmax of map logits (..., h, w) -> float32 distributions over the map cells
    (:func:`.model.map_to_prob` in numpy, float64 inside)."""
    shape = logits.shape
    flat = logits.reshape(*shape[:-2], -1).astype(np.float64)
    flat = np.exp(flat - flat.max(axis=-1, keepdims=True))
    return (flat / flat.sum(axis=-1, keepdims=True)).reshape(shape).astype(np.float32)


@dataclass
class Peak:
    """An NFT found by :func:`pick_peaks`: frame t (refined), query frame q of the peak, P there."""

    t: int
    q: int
    p: float


def pick_peaks(queries: list[int], probs: list[float], threshold: float = 0.5, min_gap: int = 12,
               final_upto: int | None = None, after: int = -10 ** 9) -> list[Peak]:
    """NFTs from P at query frames (module docstring).

    queries: increasing query frames; probs: P at each. A peak at q is decided only when the
    queries reach q + min_gap or ``final_upto`` is None (all known). after: the frame of the
    last accepted peak (peaks within min_gap of it are suppressed). Returns peaks in order."""
    qs = np.asarray(queries, np.int64)
    ps = np.asarray(probs, np.float64)
    out: list[Peak] = []
    last = after
    for i, (q, p) in enumerate(zip(qs, ps)):
        if p < threshold or q < 1:
            continue
        if final_upto is not None and q + min_gap > final_upto:
            break
        near = (np.abs(qs - q) <= min_gap)
        # a strict maximum over the earlier neighbours, at least equal to the later ones
        if np.any(ps[near & (qs < q)] >= p) or np.any(ps[near & (qs > q)] > p):
            continue
        if q - last < min_gap:
            continue
        t = float(q)
        if 0 < i < len(qs) - 1:
            a, b = ps[i - 1], ps[i + 1]
            den = a - 2 * p + b
            if den < 0:
                t = q + float(np.clip(0.5 * (a - b) / den, -0.5, 0.5)) * float(qs[i + 1] - qs[i])
        peak = Peak(max(1, int(round(t))), int(q), float(p))
        out.append(peak)
        last = int(q)
    return out


@dataclass
class MapRegion:
    """A focus region from a map, in px of a frame of ``size``: point (x, y), box (x, y, w, h),
    boolean mask (h, w) at that size."""

    x: float
    y: float
    box: tuple[float, float, float, float]
    mask: np.ndarray


def region_from_map(prob: np.ndarray, size: tuple[int, int]) -> MapRegion:
    """The focus region of a map (module docstring) in a frame of size (w, h) px."""
    import cv2

    mh, mw = prob.shape
    w, h = size
    peak = np.unravel_index(int(np.argmax(prob)), prob.shape)
    top = float(prob[peak])
    sel = (prob >= 0.5 * top).astype(np.uint8) if top > 0 else np.ones_like(prob, np.uint8)
    _, comp = cv2.connectedComponents(sel, connectivity=8)
    region = comp == comp[peak]
    ys, xs = np.nonzero(region)
    wgt = prob[ys, xs].astype(np.float64) + 1e-12
    sx, sy = w / mw, h / mh
    cx = float((wgt * (xs + 0.5)).sum() / wgt.sum()) * sx
    cy = float((wgt * (ys + 0.5)).sum() / wgt.sum()) * sy
    box = (float(xs.min()) * sx, float(ys.min()) * sy, float(xs.max() - xs.min() + 1) * sx,
           float(ys.max() - ys.min() + 1) * sy)
    mask = cv2.resize(region.astype(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST).astype(bool)
    return MapRegion(cx, cy, box, mask)


class AFNetStream:
    """Streaming AF-Net over one clip of ``n_frames`` frames (module docstring).

    ``push(codes)`` adds the next frame ((C, H, W) uint8 from :func:`.model.encode_frame`);
    ``finish()`` after the last one. ``probs`` (query frame -> P) and ``maps`` (unit centre
    frame -> (h, w) map distribution) fill as queries run; ``take_peaks()`` returns the NFTs
    that became certain. ``threads``: torch threads while a query runs (None: torch's setting).
    ``audio``: (n_frames, AUDIO_FEATURES) audio numbers of the clip, or None (silence); used
    only by a network with an audio input.
    """

    def __init__(self, model, n_frames: int, threshold: float = 0.5, min_gap: int = 12,
                 threads: int | None = 1, audio: np.ndarray | None = None) -> None:
        if n_frames < 1:
            raise InputError("AF-Net needs a clip of at least one frame")
        self.model = model.eval()
        self.runner = runner_of(model)
        self.config = model.config
        self.n = int(n_frames)
        self.threshold = float(threshold)
        self.min_gap = int(min_gap)
        self.threads = threads
        cfg = self.config
        if audio is not None and cfg.audio and audio.shape != (self.n, cfg.audio):
            raise InputError(f"AF-Net audio numbers {audio.shape}: expected ({self.n}, {cfg.audio})")
        self.audio = audio if cfg.audio else None
        self.queries = list(range(0, self.n, cfg.stride))
        self._frames: dict[int, np.ndarray] = {}
        self._units: dict[int, np.ndarray] = {}
        self.probs: dict[int, float] = {}
        self.maps: dict[int, np.ndarray] = {}
        self.pushed = 0
        self.finished = False
        self._next_q = 0
        self._last_peak = -10 ** 9
        self._decided_upto = -1
        half = (cfg.f_t - 1) // 2
        self._unit_frames = (np.arange(cfg.f_t) - half) * cfg.sample_step
        self.padded = check_length(self.n, cfg)

    def push(self, codes: np.ndarray) -> None:
        """Add the next frame (in order) and run every query whose frames are now in."""
        if self.pushed >= self.n:
            raise InputError(f"AF-Net stream: frame {self.pushed} pushed but the clip has {self.n} frames")
        self._frames[self.pushed] = codes
        self.pushed += 1
        with torch_threads(self.threads):
            self._run(final=False)

    def finish(self) -> None:
        """End of the clip: run the remaining queries."""
        with torch_threads(self.threads):
            self._run(final=True)
        self.finished = True

    def _frame(self, k: int) -> np.ndarray:
        return self._frames[min(max(k, 0), self.n - 1)]

    def _unit(self, c: int) -> np.ndarray:
        if c not in self._units:
            x = np.stack([self._frame(c + int(o)) for o in self._unit_frames])[None]
            audio = None
            if self.config.audio:
                half = int(self._unit_frames[-1])
                cols = window(self.audio, c, half, self.config.audio)[:, self._unit_frames + half]
                audio = np.ascontiguousarray(cols.T, dtype=np.float32)[None]
            feat, m = self.runner.unit(x, audio)
            self._units[c] = feat[0]
            self.maps[c] = map_to_prob_np(m)[0]
        return self._units[c]

    def _run(self, final: bool) -> None:
        cfg = self.config
        while self._next_q < len(self.queries):
            q = self.queries[self._next_q]
            need = min(q + cfg.half_span, self.n - 1)
            if not final and need >= self.pushed:
                break
            feats = np.stack([self._unit(q + int(o)) for o in cfg.unit_offsets])[None]
            audio = None
            if cfg.audio:
                audio = np.ascontiguousarray(window(self.audio, q, cfg.half_span, cfg.audio), dtype=np.float32)[None]
            logit = float(self.runner.head(feats, audio)[0])
            self.probs[q] = float(1.0 / (1.0 + math.exp(-logit))) if logit > -700 else 0.0
            self._next_q += 1
            # forget what no later query needs
            lo = q + cfg.stride - cfg.half_span
            for k in [k for k in self._frames if 0 < k < lo]:  # frame 0 stays: it pads the start
                del self._frames[k]
            for c in [c for c in self._units if c < lo - cfg.sample_step * cfg.f_t]:
                del self._units[c]

    def take_peaks(self, final: bool | None = None) -> list[Peak]:
        """NFT peaks that became certain since the last call (all remaining ones when the
        stream is finished, or ``final``)."""
        done = [q for q in self.queries if q in self.probs]
        if not done:
            return []
        final = self.finished if final is None else final
        ps = [self.probs[q] for q in done]
        upto = None if final else done[-1]
        peaks = [p for p in pick_peaks(done, ps, self.threshold, self.min_gap, upto, self._last_peak)
                 if p.q > self._decided_upto]
        if peaks:
            self._last_peak = peaks[-1].q
            self._decided_upto = peaks[-1].q
        return peaks

    def region_frame(self, t: int) -> int | None:
        """The unit centre whose map gives the region of an NFT at t: the first computed centre
        >= t + REGION_LAG_FRAMES (else the last one before it); None before any map."""
        if not self.maps:
            return None
        later = [c for c in self.maps if c >= t + REGION_LAG_FRAMES and c < self.n]
        if later:
            return min(later)
        return max(c for c in self.maps if c < self.n) if any(c < self.n for c in self.maps) else max(self.maps)

    def map_at(self, frame: int) -> np.ndarray | None:
        """The map distribution of the computed unit centre nearest ``frame`` (None before any)."""
        if not self.maps:
            return None
        c = min(self.maps, key=lambda k: (abs(k - frame), k))
        return self.maps[c]

    def forget_maps_before(self, frame: int) -> None:
        """Drop maps of unit centres more than a stride before ``frame`` (bounded memory)."""
        for c in [c for c in self.maps if c < frame - self.config.stride * self.config.f_t]:
            del self.maps[c]


@dataclass
class ClipPrediction:
    """Whole-clip AF-Net output: P per query frame, maps per unit centre, NFT peaks and their
    regions (px of ``size``)."""

    probs: dict[int, float]
    maps: dict[int, np.ndarray]
    peaks: list[Peak]
    regions: list[MapRegion] = field(default_factory=list)
    padded: bool = False


def predict_clip(model, frames: Iterable[np.ndarray], disparities: Iterable[np.ndarray | None] | None = None,
                 n_frames: int | None = None, threshold: float = 0.5, min_gap: int = 12,
                 audio: np.ndarray | None = None) -> ClipPrediction:
    """Run AF-Net over a clip: frames (H, W, 3) uint8 RGB (and optional disparity maps, any size;
    audio numbers (n, AUDIO_FEATURES) for a network with an audio input)."""
    frames = list(frames)
    disp = list(disparities) if disparities is not None else [None] * len(frames)
    n = n_frames or len(frames)
    stream = AFNetStream(model, n, threshold, min_gap, audio=audio)
    for rgb, d in zip(frames, disp):
        from .encoding import encode_frame

        stream.push(encode_frame(rgb, d, model.config))
    stream.finish()
    peaks = stream.take_peaks(final=True)
    h, w = frames[0].shape[:2]
    regions = [region_from_map(stream.maps[stream.region_frame(p.t)], (w, h)) for p in peaks]
    return ClipPrediction(dict(stream.probs), dict(stream.maps), peaks, regions, stream.padded)


def nft_min_gap(fps: float) -> int:
    """Default smallest distance between two AF-Net NFTs: half a second of frames (at least 5)."""
    return max(5, int(math.ceil(0.5 * fps)))
