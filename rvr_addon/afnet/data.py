"""AF-Net training data: clips with focus regions and New Focus Target times, and the samples
drawn from them.

Three kinds of clip, kept apart by ``ClipData.kind`` and ``ClipData.weak``:

- ``harness``: clips of ``python -m sintel_eval generate`` (``sintel_eval/DATASET.md``; the
  deep pass is enough, ``--no-dof`` clips are fine). Ground truth: the focus target of every
  frame and the NFTs, derived exactly as ``rvr eval-focus`` does
  (:func:`rvr_addon.laaf.evaluate.ground_truth`): the main subject
  (``manifest.scene.main``) from frame 0; each event (``events.json``) on a subject other than
  the one in focus is an NFT at its ``index`` and makes that subject the target. The focus
  region of a frame is the target's box (``subjects[name].per_frame[k].box``) and its focus
  point (between the eyes); unknown while the target is not in frame.
- ``editor``: records of a focus annotation file (:mod:`.annotations`) that a person made or
  accepted. Regions at the annotated frames only; every NFT of the clip is annotated.
- ``weak``: records made by the AI-assist detectors alone (``weak: true``). Same use, but
  ``ClipData.weak`` is True and the loss weight is ``weak_weight`` (< 1); they are never
  treated as ground truth by an evaluation (``rvr eval-focus`` reads harness clips only).

Frames are held at the network's input size as bytes (:func:`.model.encode_frame`; about 37 KB
a frame at 128x72 RGB + disparity), so a few hundred 48-frame clips fit in memory; the prepared
arrays are cached as ``.npz`` under the run folder so a resumed run starts fast.

A sample (:meth:`TrainingSet.draw`) is one query: a centre frame ``c`` and the ``L`` sampled
frames around it (clamped to the clip: the padding of inference), the focus-region target of
each of the ``s`` unit centres (a distribution over the map cells: half the box, uniformly,
half a Gaussian at the focus point; none where the region is unknown) and the NFT label
``max_t exp(-(c - t)^2 / (2 tol^2))`` over the clip's NFTs ``t`` (``tol``: the tolerance
window in frames). Augmentation: horizontal flip, brightness/contrast jitter of the image.

With an audio input (``AFNetConfig.audio``), a sample also holds the audio numbers of every
clip frame of its span (:mod:`.audio_features`; zeros outside the clip). A clip's sound is
read from its video (``input.mp4`` of a harness clip; the annotated clip's file), as
inference reads it; each clip with sound keeps two variants (clean, and with a noise floor
10-30 dB below the voice), each clip without sound zeros and two noise backgrounds
(:func:`.audio_features.noise_features`), one of them drawn per sample.
"""
from __future__ import annotations

import hashlib
import json
import logging
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..io.paths import temp_sibling
from .annotations import AnnotatedClip
from .audio_features import AUDIO_FEATURES, frame_features, noise_features, window
from .config import AFNetConfig
from .encoding import DISPARITY_CODE_SCALE, encode_frame

log = logging.getLogger(__name__)

DATA_VERSION = 2  # bump when the prepared arrays change meaning (invalidates the .npz cache)


@dataclass
class ClipData:
    """One clip prepared for training.

    name: for logs. kind: ``harness``, ``editor`` or ``weak``. frames: (n, C, H, W) uint8 codes.
    boxes: (n, 4) focus-region box per frame in network px (x, y, w, h), NaN where unknown.
    points: (n, 2) focus point in network px, NaN where unknown (the box centre is used).
    nfts: 0-based NFT frames. fps: frames per second. weak: labels from detectors alone.
    audio: (V, n, AUDIO_FEATURES) float32 variants of the audio numbers (V = 0: no sound, or
    the network has no audio input).
    """

    name: str
    kind: str
    frames: np.ndarray
    boxes: np.ndarray
    points: np.ndarray
    nfts: list[int]
    fps: float
    weak: bool = False
    audio: np.ndarray | None = None

    @property
    def n(self) -> int:
        return int(self.frames.shape[0])


@dataclass
class Sample:
    """x: (L, C, H, W) float32 input. target: (s, h, w) float32 map distributions; valid: (s,)
    bool; label: NFT label of the centre frame in [0, 1]; weight: loss weight; kind, name, frame;
    audio: (AUDIO_FEATURES, span) float32 audio numbers of the span (empty without audio input)."""

    x: np.ndarray
    target: np.ndarray
    valid: np.ndarray
    label: float
    weight: float
    kind: str
    name: str
    frame: int
    audio: np.ndarray = field(default_factory=lambda: np.zeros((0, 0), np.float32))


# ----------------------------------------------------------------------------- ground truth


def harness_targets(manifest: dict) -> tuple[list[str], list[int]]:
    """(focus subject per frame, NFT frames) of a harness clip, as ``rvr eval-focus`` defines
    them (module docstring). Raises InputError naming what is missing from the manifest."""
    from ..laaf.evaluate import ground_truth
    from ..laaf.puller import PullSettings

    try:
        n = int(manifest.get("config", {}).get("frames") or manifest["frames"])
        main = manifest["scene"]["main"]
        gt = ground_truth(manifest, PullSettings())
    except (KeyError, TypeError, ValueError) as ex:
        raise InputError(f"the manifest lacks {ex} (scene.main, subjects, events); regenerate the clip") from ex
    subject = [main] * n
    for t, name in gt.nfts:
        for k in range(t, n):
            subject[k] = name
    return subject, [t for t, _ in gt.nfts]


def _box_ok(box) -> bool:
    return box is not None and len(box) == 4 and all(np.isfinite(box)) and box[2] >= 1 and box[3] >= 1


def _name_rng(name: str) -> np.random.Generator:
    """A generator seeded by a clip's name: its noise variants are the same in every run."""
    return np.random.default_rng(int(hashlib.sha1(name.encode()).hexdigest()[:8], 16))


def sound_variants(media: Path, fps: float, n: int, name: str) -> np.ndarray:
    """(V, n, AUDIO_FEATURES) audio variants of a clip (module docstring): clean and with a noise
    floor when ``media`` has sound, else an empty (0, n, F) array."""
    from ..laaf.audio import SAMPLE_RATE, NoAudio, decode_audio

    try:
        samples = decode_audio(media, duration_s=n / fps)
    except NoAudio:
        return np.zeros((0, n, AUDIO_FEATURES), np.float32)
    rng = _name_rng(name)
    peak_rms = float(np.sqrt(np.mean(samples[np.abs(samples) > 0.01 * np.abs(samples).max()] ** 2))) \
        if np.abs(samples).max() > 0 else 0.0
    noise = rng.standard_normal(samples.size).astype(np.float32)
    noisy = samples + noise * peak_rms * 10 ** (-rng.uniform(10, 30) / 20)  # 10-30 dB below the voice
    return np.stack([frame_features(samples, SAMPLE_RATE, fps, n), frame_features(noisy, SAMPLE_RATE, fps, n)])


def load_harness_clip(folder: Path, config: AFNetConfig) -> ClipData:
    """Read one complete harness clip (input PNGs, GT disparity, manifest) into ClipData."""
    import cv2

    from ..io.exr import read_exr
    from ..laaf.depth import pick_disparity_channel

    manifest = json.loads((folder / "manifest.json").read_text())
    subject, nfts = harness_targets(manifest)
    n = len(subject)
    w0 = int(manifest.get("config", {}).get("width") or manifest["width"])
    h0 = int(manifest.get("config", {}).get("height") or manifest["height"])
    sx, sy = config.width / w0, config.height / h0
    frames = np.zeros((n, config.channels, config.height, config.width), np.uint8)
    boxes = np.full((n, 4), np.nan, np.float32)
    points = np.full((n, 2), np.nan, np.float32)
    for k in range(n):
        png = folder / "input" / f"frame_{k + 1:05d}.png"
        img = cv2.imread(str(png), cv2.IMREAD_COLOR)
        if img is None:
            raise InputError(f"'{png}' is missing or unreadable; re-run `python -m sintel_eval generate` for the clip")
        disp = None
        if config.disparity:
            exr = folder / "gt" / "disparity" / f"frame_{k + 1:05d}.exr"
            try:
                ch = read_exr(exr)
            except Exception as ex:  # noqa: BLE001 - any reader failure names the file
                raise InputError(f"'{exr}' is not readable ({ex}); regenerate the clip") from ex
            disp = ch["D"] if "D" in ch else ch[pick_disparity_channel(ch)]
        frames[k] = encode_frame(img[..., ::-1], disp, config)
        rec = manifest["subjects"][subject[k]]["per_frame"][k]
        if _box_ok(rec.get("box")) and float(rec.get("visible", 1.0) or 0.0) > 0:
            x, y, bw, bh = (float(v) for v in rec["box"])
            boxes[k] = (x * sx, y * sy, bw * sx, bh * sy)
            pt = rec.get("point")
            if pt is not None and rec.get("face_in_frame", True):
                points[k] = (float(pt[0]) * sx, float(pt[1]) * sy)
    from ..laaf.evaluate import manifest_fps

    fps = manifest_fps(manifest)
    audio = sound_variants(folder / "input.mp4", fps, n, folder.name) if config.audio else None
    return ClipData(folder.name, "harness", frames, boxes, points, nfts, fps, audio=audio)


def load_annotated_clip(clip: AnnotatedClip, config: AFNetConfig, region_tolerance: int = 2) -> ClipData:
    """Decode an annotated clip (video or image sequence) into ClipData.

    Regions: each record's box holds for frames within ``region_tolerance`` of it (the nearest
    record wins); elsewhere unknown. Disparity from ``clip.depth`` when given, else zero."""
    from ..io.video import iter_frames, probe_clip
    from ..laaf.depth import DisparitySource, is_cache

    info = probe_clip(clip.clip, fps=clip.fps)
    n = info.frame_count
    bad = [r.frame for r in clip.records if r.frame >= n]
    if bad:
        raise InputError(f"annotations of '{clip.clip}' name frame(s) {bad} but the clip has {n} frames (0..{n - 1}); "
                         "fix the annotation file")
    depth = None
    if clip.depth is not None and config.disparity:
        depth = DisparitySource(cache=clip.depth) if is_cache(clip.depth) else DisparitySource(depth=clip.depth)
        depth.check_length(n)
    frames = np.zeros((n, config.channels, config.height, config.width), np.uint8)
    for k, rgb in enumerate(iter_frames(clip.clip)):
        if k >= n:
            break
        disp = depth.get(k, (config.width, config.height)) if depth is not None else None
        frames[k] = encode_frame(rgb, disp, config)
    sx, sy = config.width / info.width, config.height / info.height
    boxes = np.full((n, 4), np.nan, np.float32)
    points = np.full((n, 2), np.nan, np.float32)
    dist = np.full(n, np.inf)
    for r in clip.records:
        from ..laaf.nft import clip_box

        x, y, bw, bh = clip_box(r.box, info.width, info.height)
        if bw < 1 or bh < 1:
            continue
        for k in range(max(0, r.frame - region_tolerance), min(n, r.frame + region_tolerance + 1)):
            d = abs(k - r.frame) + (0.0 if r.nft else 0.5)  # an NFT record wins a tie
            if d < dist[k]:
                dist[k] = d
                boxes[k] = (x * sx, y * sy, bw * sx, bh * sy)
    kind = "weak" if clip.weak else "editor"
    audio = sound_variants(clip.clip, info.fps, n, clip.clip.name) if config.audio and info.has_audio else None
    return ClipData(clip.clip.name, kind, frames, boxes, points, clip.nft_frames, info.fps, weak=clip.weak,
                    audio=audio)


# ----------------------------------------------------------------------------- cache


def _cache_key(parts: list[str], config: AFNetConfig) -> str:
    blob = json.dumps({"parts": parts, "config": {k: v for k, v in config.to_dict().items()
                                                  if k in ("width", "height", "rgb", "disparity", "audio")},
                       "version": DATA_VERSION}, sort_keys=True)
    return hashlib.sha1(blob.encode()).hexdigest()[:20]


def _stamp(path: Path) -> str:
    try:
        st = path.stat()
        return f"{path.resolve()}:{st.st_size}:{int(st.st_mtime)}"
    except OSError:
        return str(path)


def cached(loader, key_parts: list[str], config: AFNetConfig, cache_dir: Path | None) -> ClipData:
    """``loader()`` with its result cached as ``cache_dir/<key>.npz`` (atomic; a corrupt entry
    is reloaded)."""
    if cache_dir is None:
        return loader()
    path = Path(cache_dir) / f"{_cache_key(key_parts, config)}.npz"
    if path.is_file():
        try:
            z = np.load(path, allow_pickle=False)
            meta = json.loads(str(z["meta"]))
            return ClipData(meta["name"], meta["kind"], z["frames"], z["boxes"], z["points"],
                            [int(t) for t in meta["nfts"]], float(meta["fps"]), bool(meta["weak"]),
                            z["audio"] if "audio" in z.files else None)
        except (OSError, ValueError, KeyError) as ex:
            log.warning("AF-Net data cache entry '%s' is unreadable (%s); preparing the clip again", path, ex)
    data = loader()
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = temp_sibling(path, ".npz")
    meta = json.dumps({"name": data.name, "kind": data.kind, "nfts": data.nfts, "fps": data.fps, "weak": data.weak})
    with open(tmp, "wb") as f:
        extra = {} if data.audio is None else {"audio": data.audio}
        np.savez(f, frames=data.frames, boxes=data.boxes, points=data.points, meta=np.array(meta), **extra)
    os.replace(tmp, path)
    return data


# ----------------------------------------------------------------------------- the set


@dataclass
class DataReport:
    """Counts of what was loaded and what was skipped (with reasons)."""

    clips: dict[str, int] = field(default_factory=lambda: {"harness": 0, "editor": 0, "weak": 0})
    frames: dict[str, int] = field(default_factory=lambda: {"harness": 0, "editor": 0, "weak": 0})
    nfts: dict[str, int] = field(default_factory=lambda: {"harness": 0, "editor": 0, "weak": 0})
    skipped: list[tuple[str, str]] = field(default_factory=list)

    def summary(self) -> str:
        parts = [f"{self.clips[k]} {k} clips ({self.frames[k]} frames, {self.nfts[k]} NFTs)"
                 for k in ("harness", "editor", "weak") if self.clips[k]]
        text = ", ".join(parts) or "no clips"
        return text + (f"; {len(self.skipped)} skipped" if self.skipped else "")

    def to_dict(self) -> dict:
        return {"clips": self.clips, "frames": self.frames, "nfts": self.nfts,
                "skipped": [{"clip": c, "reason": r} for c, r in self.skipped]}


def load_training_clips(config: AFNetConfig, harness: list[Path] = (), annotations: list[Path] = (),
                        cache_dir: Path | None = None, progress: bool = False) -> tuple[list[ClipData], DataReport]:
    """Load every harness clip under the ``harness`` dataset folders and every clip of the
    annotation files (editor and weak records alike; the kind comes from each record's flag).

    A clip that cannot be read is skipped with a warning (listed in the report). Raises
    InputError when a dataset folder or annotation file is missing, or nothing is left."""
    from tqdm import tqdm

    from ..laaf.evaluate import harness_clips
    from .annotations import read_annotations

    report = DataReport()
    jobs = []
    for root in harness:
        for folder in harness_clips(root):
            manifest = folder / "manifest.json"
            jobs.append((folder.name, [_stamp(manifest)], lambda f=folder: load_harness_clip(f, config)))
    for path in annotations:
        for clip in read_annotations(path):
            recs = json.dumps([(r.frame, r.box, r.nft) for r in clip.records])
            parts = [_stamp(clip.clip), recs, str(clip.depth), str(clip.weak)]
            jobs.append((clip.clip.name, parts, lambda c=clip: load_annotated_clip(c, config)))
    clips = []
    for name, parts, loader in tqdm(jobs, desc="AF-Net data", unit="clip", disable=not progress):
        try:
            data = cached(loader, parts, config, cache_dir)
        except InputError as ex:
            log.warning("skipping clip %s: %s", name, ex)
            report.skipped.append((name, str(ex)))
            continue
        clips.append(data)
        report.clips[data.kind] += 1
        report.frames[data.kind] += data.n
        report.nfts[data.kind] += len(data.nfts)
    if not clips:
        reasons = "; ".join(f"{n}: {r}" for n, r in report.skipped) or "none was given"
        raise InputError(f"no AF-Net training clip could be loaded ({reasons}); pass --data DATASET (harness clips "
                         "from `python -m sintel_eval generate --no-dof`) and/or --annotations FILE.json")
    return clips, report


def _map_target(box: np.ndarray, point: np.ndarray, config: AFNetConfig) -> np.ndarray | None:
    """(h, w) distribution over the map cells: half uniform over the box (by cell coverage),
    half a Gaussian at the focus point (sigma a sixth of the box height, at least one cell)."""
    if not np.all(np.isfinite(box)):
        return None
    mw, mh = config.map_size
    cell_x, cell_y = config.width / mw, config.height / mh
    x0, y0, bw, bh = (float(v) for v in box)
    edges_x = np.arange(mw + 1) * cell_x
    edges_y = np.arange(mh + 1) * cell_y
    cov_x = np.clip(np.minimum(edges_x[1:], x0 + bw) - np.maximum(edges_x[:-1], x0), 0, None)
    cov_y = np.clip(np.minimum(edges_y[1:], y0 + bh) - np.maximum(edges_y[:-1], y0), 0, None)
    uniform = np.outer(cov_y, cov_x)
    if uniform.sum() <= 0:
        return None
    uniform /= uniform.sum()
    px, py = (point if np.all(np.isfinite(point)) else (x0 + bw / 2, y0 + bh / 2))
    sigma = max(bh / 6.0, cell_y)
    cx = (np.arange(mw) + 0.5) * cell_x
    cy = (np.arange(mh) + 0.5) * cell_y
    gauss = np.exp(-0.5 * (((cx[None, :] - px) ** 2 + (cy[:, None] - py) ** 2) / sigma ** 2))
    if gauss.sum() <= 1e-12:
        return uniform.astype(np.float32)
    return (0.5 * uniform + 0.5 * gauss / gauss.sum()).astype(np.float32)


def nft_label(frame: int, nfts: list[int], tolerance: float) -> float:
    """max over the clip's NFTs t of exp(-(frame - t)^2 / (2 tolerance^2)); 0 without NFTs."""
    if not nfts:
        return 0.0
    d = min(abs(frame - t) for t in nfts)
    return float(np.exp(-0.5 * (d / tolerance) ** 2)) if d <= 4 * tolerance else 0.0


DEPTH_KINDS = ("estimate", "regions", "flat")
"""The characters of depth :func:`augment_disparity` draws (equally often)."""


def augment_disparity(disp: np.ndarray, rng: np.random.Generator, kind: str | None = None) -> np.ndarray:
    """The normalised disparity of a sample's frames as another kind of depth would give it.

    disp: (F, 1, H, W) float32, the decoded disparity channel (:func:`.encoding.normalise_disparity`
    units). kind (None: drawn): ``estimate`` (what `rvr estimate` gives: blurred by a Gaussian of
    1-4 px at 128x72, a monotone distortion ``sign(d) |d|^g``, g in 0.6-1.5, noise of 0.03-0.15,
    a global scale/offset, which the normalisation removes again), ``regions`` (one disparity
    per region: the frames quantised to 2-3 levels, as a map of one value per panel or a
    hand-painted map) or ``flat`` (a single value: 0 after normalisation). The same draw for every
    frame of the sample (an estimate's character does not change from frame to frame); each
    frame is normalised again as at inference and quantised to the byte code's steps.
    """
    import cv2

    from .encoding import normalise_disparity

    kind = kind if kind is not None else DEPTH_KINDS[int(rng.integers(len(DEPTH_KINDS)))]
    if kind not in DEPTH_KINDS:
        raise ValueError(f"depth kind {kind!r} is not one of {', '.join(DEPTH_KINDS)}")
    if kind == "flat":
        return np.zeros_like(disp)
    out = np.empty_like(disp)
    if kind == "estimate":
        sigma = float(rng.uniform(1.0, 4.0))
        gamma = float(np.exp(rng.uniform(np.log(0.6), np.log(1.5))))
        noise = float(rng.uniform(0.03, 0.15))
        scale, offset = float(rng.uniform(0.3, 3.0)), float(rng.uniform(-2.0, 2.0))
        for f in range(disp.shape[0]):
            d = cv2.GaussianBlur(disp[f, 0].astype(np.float32), (0, 0), sigma)
            d = np.sign(d) * np.abs(d) ** gamma + rng.normal(0.0, noise, d.shape)
            out[f, 0] = normalise_disparity(scale * d + offset)
    else:  # regions
        levels = int(rng.integers(2, 4))
        for f in range(disp.shape[0]):
            d = disp[f, 0]
            edges = np.quantile(d, np.linspace(0, 1, levels + 1)[1:-1])
            q = np.digitize(d, edges).astype(np.float32)
            out[f, 0] = normalise_disparity(q)
    return np.round(out * DISPARITY_CODE_SCALE) / DISPARITY_CODE_SCALE


class TrainingSet:
    """Draws samples (module docstring) from the loaded clips with a numpy Generator.

    pos_fraction: share of samples centred near an NFT (class balance). weak_weight: loss
    weight of weak clips. tolerance: NFT tolerance window in frames. flip, jitter: augmentation.
    depth_augment: share of samples whose disparity channel is replaced by another character of
    depth the network meets at inference (:func:`augment_disparity`: estimate-like, region-flat,
    flat); 0 keeps the stored disparity (the first weights' training).
    """

    def __init__(self, clips: list[ClipData], config: AFNetConfig, pos_fraction: float = 0.5,
                 weak_weight: float = 0.3, tolerance: float = 3.0, flip: bool = True, jitter: float = 0.15,
                 depth_augment: float = 0.0) -> None:
        if not clips:
            raise InputError("no AF-Net training clip")
        if not 0 <= pos_fraction <= 1 or weak_weight < 0 or tolerance <= 0:
            raise InputError(f"pos_fraction {pos_fraction} must be in [0, 1], weak_weight {weak_weight} >= 0, "
                             f"tolerance {tolerance} > 0")
        self.clips = clips
        self.config = config
        self.pos_fraction = pos_fraction
        self.weak_weight = weak_weight
        self.tolerance = tolerance
        self.flip = flip
        self.jitter = jitter
        if not 0.0 <= depth_augment <= 1.0:
            raise InputError(f"depth_augment {depth_augment} must be in [0, 1]")
        self.depth_augment = float(depth_augment)
        self.with_nfts = [i for i, c in enumerate(clips) if c.nfts]
        self.audio: list[np.ndarray] = []
        if config.audio:
            for c in clips:
                a = c.audio if c.audio is not None and len(c.audio) else None
                if a is None:  # silence, and two noise backgrounds
                    rng = _name_rng(c.name)
                    a = np.stack([np.zeros((c.n, AUDIO_FEATURES), np.float32)]
                                 + [noise_features(c.n, c.fps, rng) for _ in range(2)])
                self.audio.append(a.astype(np.float32))

    def draw(self, rng: np.random.Generator) -> Sample:
        """One sample (module docstring)."""
        cfg = self.config
        if self.with_nfts and rng.random() < self.pos_fraction:
            ci = self.with_nfts[int(rng.integers(len(self.with_nfts)))]
            clip = self.clips[ci]
            t = clip.nfts[int(rng.integers(len(clip.nfts)))]
            c = int(np.clip(round(t + rng.normal(0.0, self.tolerance)), 0, clip.n - 1))
        else:
            ci = int(rng.integers(len(self.clips)))
            clip = self.clips[ci]
            c = int(rng.integers(clip.n))
        idx = np.clip(c + cfg.offsets, 0, clip.n - 1)
        x = clip.frames[idx].astype(np.float32)
        n_img = 3 if cfg.rgb else 1
        img = x[:, :n_img] / 255.0 - 0.5
        if self.jitter > 0:
            gain = 1.0 + rng.uniform(-self.jitter, self.jitter)
            bias = rng.uniform(-self.jitter, self.jitter) * 0.5
            img = np.clip(img * gain + bias, -0.5, 0.5)
        parts = [img]
        if cfg.disparity:
            disp = (x[:, n_img:] - 128.0) / DISPARITY_CODE_SCALE
            if self.depth_augment > 0 and rng.random() < self.depth_augment:
                disp = augment_disparity(disp, rng)
            parts.append(disp)
        x = np.concatenate(parts, axis=1)
        flip = self.flip and rng.random() < 0.5
        if flip:
            x = x[..., ::-1]
        mw, mh = cfg.map_size
        target = np.zeros((cfg.s, mh, mw), np.float32)
        valid = np.zeros(cfg.s, bool)
        for u, off in enumerate(cfg.unit_offsets):
            k = c + int(off)
            if not 0 <= k < clip.n:
                continue
            box, point = clip.boxes[k].copy(), clip.points[k].copy()
            if flip:
                box[0] = cfg.width - box[0] - box[2]
                point[0] = cfg.width - point[0]
            tgt = _map_target(box, point, cfg)
            if tgt is not None:
                target[u], valid[u] = tgt, True
        weight = self.weak_weight if clip.weak else 1.0
        audio = np.zeros((0, 0), np.float32)
        if cfg.audio:
            variants = self.audio[ci]
            audio = window(variants[int(rng.integers(len(variants)))], c, cfg.half_span, cfg.audio)
        return Sample(np.ascontiguousarray(x, dtype=np.float32), target, valid,
                      nft_label(c, clip.nfts, self.tolerance), weight, clip.kind, clip.name, c, audio)

    def summary(self) -> str:
        kinds = {}
        for c in self.clips:
            kinds[c.kind] = kinds.get(c.kind, 0) + 1
        return ", ".join(f"{v} {k}" for k, v in sorted(kinds.items()))
