"""Depth figures on REAL material for ``rvr eval-estimator`` (``--real-set``, ``--real-video``,
``--aperture``); :mod:`.evaluate` wires them into its report folder.

**Real pictures** (``--real-set DIR``, :func:`.real_data.find_real_pictures`): every view is run
through one depth method on a single picture (``network``: the estimator alone; ``auto`` /
``people``: :mod:`rvr_addon.depth.system` with the cues a single picture has: people + network,
never parallax). Per view the affine-invariant error of D against the measured inverse depth
(:func:`.evaluate.affine_invariant_error`: 0 perfect, 1 = a constant; a negative scale is
allowed, D being a negative affine of inverse depth) and the same for the vertical ramp. Keys
``estimate.real.<set>.affine_error`` (mean over the set's views), ``..._median``,
``.ramp_error``, ``.better_than_ramp_share``, ``.views``, ``.scenes`` for every set found, plus
``middlebury`` (2006 + 2001/2003 together) and ``all``. ``--weights-per-scene JSON`` maps a
scene (``middlebury2006/Aloe`` or ``Aloe``) to a weights file (relative paths: to the JSON's
folder), so a leave-scene-out run scores every scene with the fold model that did not see it;
each distinct file is loaded once, scenes not in the map use ``--weights``.

**Real video** (``--real-video DIR``, :func:`rvr_addon.depth.real_video.open_rgbd_clip`): the
clip's RGB frames go through the WHOLE depth system exactly as ``rvr estimate --depth-method M``
runs it (:func:`rvr_addon.depth.system.plan_depth` with the first frames as the probe, then
:class:`~rvr_addon.depth.system.DepthStream`, or the network frame by frame when the plan is the
network alone: :class:`.infer.EstimateJob`'s two paths), for every M of ``--depth-methods``.
Per method, keys ``estimate.video.<clip>.<M>.``:

* ``affine_error`` / ``affine_error_median``: per frame affine-invariant error of D against the
  ground-truth inverse depth 1/z (valid depth pixels), mean / median over frames;
* ``clip_affine_error``: ONE scale and shift fitted over the whole clip (pooled pixels): does
  D keep one unit across frames?
* ``flicker``: for consecutive frames t, t+1 every pixel x of t with a valid depth is
  back-projected with the GT depth and pose and projected into t+1 (x'); it counts where x'
  lies in the frame and the GT depth there agrees within 5 % (static, visible in both). The
  mean |D_t(x) - D_{t+1}(x')| (D_{t+1} bilinear) over those pixels, averaged over the pairs,
  divided by the standard deviation of D over the clip (dimensionless; a flat D cannot win).
  It also counts true changes of 1/z as the camera moves along its axis; ``gt_flicker`` of the
  clip is the same figure for the GT inverse depth (the floor of a perfect D), and
  ``flicker_geometry_corrected`` removes the change the clip-wide fit ``D ~ s q + t`` explains:
  mean |(D_t(x) - D_{t+1}(x')) - s (q_t(x) - q_{t+1}(x'))| / std(D) (0 for a perfect D);
* ``s_per_frame`` and, for the system, how often each cue spoke (``<cue>_frames``); with parallax
  in the plan, ``carried_frames`` (frames that took the depth carried along the flow) and
  ``refined_frames`` (frames whose depth the frames after them changed, :mod:`..depth.refine`).

A method ``M+centred`` or ``M+causal`` is M's D after the temporal filter (``rvr stabilize``, paper
4.2) with that window: the D that ``rvr refocus`` renders with (``+centred``, the default; ``+causal``
with ``--causal``).

``estimate.video.<clip>.ramp_error`` / ``.ramp_clip_affine_error`` are the vertical ramp's.

**Real aperture photos** (``--aperture DIR``: ``vabd_*/{input,1_8}.jpg``, ``ebb_*/{input,
target}.jpg``, an f/16 input and a wide-aperture photo of the same scene): both are shrunk to a
long side of ``--aperture-size`` px (default 512, for speed); the wide photo is aligned onto the
input by ECC (:mod:`.align`, homography; identity when ECC fails) and its exposure matched by
one gain per channel in linear light (mean ratio over the overlap); PSNR is computed in sRGB on
the overlap less a 3 % border. D and E come from the input with the chosen method, our renderer
(:class:`rvr_addon.render.fast.FastRenderer`, the forward model F(I, D, E, f, a)) is fitted over
focus f and aperture scale a (a 9 x 8 grid over D's 2-98th percentiles and blur radii 0.5-48 px,
then Nelder-Mead) for the best PSNR; the baseline is a Gaussian blur of the input in linear light
with the best sigma (a grid, then a bounded scalar search); ``ramp`` is our renderer with
D = the vertical ramp (nearer toward the bottom, the same E), fitted the same way: what the
renderer earns without depth. Keys ``estimate.aperture.<scene>.psnr_{ours,gauss,ramp,input}_db``,
``estimate.aperture.mean_margin_db`` (ours - gauss, mean over scenes) and
``mean_margin_ramp_db`` (ramp - gauss).
"""
from __future__ import annotations

import json
import logging
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterator

import numpy as np

from ..errors import InputError, OutputError
from .evaluate import affine_invariant_error, colour_map, comparison_image, pearson, vertical_ramp

log = logging.getLogger(__name__)

DepthFn = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]
"""(H, W, 3) uint8 RGB -> (D (H, W) float32 DESIGN units, E (H, W, 3) float32)."""
PICTURE_METHODS = ("network", "auto", "people")
VIDEO_METHODS = ("auto", "parallax", "people", "network")
VIDEO_FILTERS = ("centred", "causal")
"""Temporal-filter windows a ``--depth-methods`` entry may name after a ``+`` (``auto+centred``)."""
DEPTH_TOLERANCE = 0.05
"""Relative depth agreement for a pixel to count as the same static point in the next frame."""
MIN_MATCHES = 100


def _fmt(v, digits: int = 3) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "n/a"
    return f"{v:.{digits}g}"


def _mean(v: list[float]) -> float:
    return float(np.mean(v)) if v else float("nan")


# ------------------------------------------------------------------------------ depth methods


def picture_depth(method: str, network: DepthFn, hfov_deg: float | None = None) -> DepthFn:
    """The depth of ONE picture by ``method`` (``network``, ``auto`` or ``people``).

    On one picture there is no parallax: ``auto`` is people + network when MediaPipe is there
    (a picture without people then gets the network's D through the fuser), else the network.
    Every picture gets a fresh :class:`~rvr_addon.depth.system.DepthStream` (its clip-wide scale
    must not carry over from another picture).
    """
    if method not in PICTURE_METHODS:
        raise InputError(f"--depth-method {method!r} on single pictures: choose one of {', '.join(PICTURE_METHODS)}")
    if method == "network":
        return network
    from ..depth.system import DepthStream, plan_depth

    plan = plan_depth(method, None, hfov_deg)

    def run(image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        if len(plan.cues) == 1:
            return network(image)
        stream = DepthStream(plan, (image.shape[1], image.shape[0]), network)
        try:
            _frame, d, e, _fused = next(iter(stream.frames([image])))
        finally:
            stream.close()
        return d, e

    run.plan = plan  # type: ignore[attr-defined]
    return run


def load_weights_map(path: str | Path) -> dict[str, Path]:
    """``--weights-per-scene JSON``: {scene: weights file}; relative files are taken from the
    JSON's folder. InputError naming the file when it is unreadable, not a mapping, or names a
    missing file."""
    path = Path(path)
    try:
        raw = json.loads(path.read_text())
    except (OSError, ValueError) as ex:
        raise InputError(f"--weights-per-scene {path}: cannot read it as JSON ({ex}); give "
                         '{"middlebury2006/Aloe": "fold0/estimator.pt", ...}') from ex
    if not isinstance(raw, dict) or not all(isinstance(k, str) and isinstance(v, str) for k, v in raw.items()):
        raise InputError(f"--weights-per-scene {path}: expected one JSON object mapping scene names to weights files")
    out = {}
    for scene, w in raw.items():
        wp = Path(w)
        wp = wp if wp.is_absolute() else path.parent / wp
        if not wp.is_file():
            raise InputError(f"--weights-per-scene {path}: the weights of scene {scene!r}, {wp}, do not exist")
        out[scene] = wp
    return out


class SceneNetworks:
    """The network for each scene: the fold model of ``--weights-per-scene`` (each distinct file
    loaded once) or the default one."""

    def __init__(self, default: DepthFn, default_name: str, weights_map: dict[str, Path] | None = None,
                 max_pixels: int | None = None) -> None:
        self.default, self.default_name = default, default_name
        self.map = dict(weights_map or {})
        self.max_pixels = max_pixels
        self._loaded: dict[Path, DepthFn] = {}
        self.loads = 0

    def weights_for(self, scene: str) -> Path | None:
        short = scene.split("/")[-1]
        return self.map.get(scene, self.map.get(short))

    def __call__(self, scene: str) -> tuple[DepthFn, str]:
        w = self.weights_for(scene)
        if w is None:
            return self.default, self.default_name
        key = w.resolve()
        if key not in self._loaded:
            from .infer import Estimator, load_estimator

            self._loaded[key] = Estimator(load_estimator(key), max_pixels=self.max_pixels)
            self.loads += 1
        return self._loaded[key], str(w)


# ------------------------------------------------------------------------------ real pictures


def evaluate_real_set(root: str | Path, networks: SceneNetworks, method: str = "network",
                      hfov_deg: float | None = None, folder: Path | None = None,
                      progress: bool = False) -> tuple[dict[str, float], list[dict], list[str]]:
    """Score every real picture under ``root``; returns (summary keys, per-view rows, README lines).
    ``folder``: where ``compare_real_<set>_<scene>.png`` (first view of each scene) go."""
    from tqdm import tqdm

    from .real_data import find_real_pictures, read_image, read_inverse_depth

    pictures = find_real_pictures(root)
    rows: list[dict] = []
    drawn: set[str] = set()
    methods: dict[str, DepthFn] = {}
    for pic in tqdm(pictures, desc="real pictures", unit="view", disable=not progress):
        net, wname = networks(pic.scene)
        if wname not in methods:
            methods[wname] = picture_depth(method, net, hfov_deg)
        rgb, q = read_image(pic), read_inverse_depth(pic)
        if q.shape != rgb.shape[:2]:
            raise InputError(f"{pic.truth} is {q.shape[1]}x{q.shape[0]} but {pic.image} is "
                             f"{rgb.shape[1]}x{rgb.shape[0]}")
        t0 = time.perf_counter()
        d, _e = methods[wname](rgb)
        seconds = time.perf_counter() - t0
        valid = np.isfinite(q)
        row = {"name": pic.name, "scene": pic.scene, "set": pic.set, "weights": wname,
               "affine_error": affine_invariant_error(d, q, valid),
               "ramp_error": affine_invariant_error(vertical_ramp(*q.shape), q, valid),
               "corr": pearson(d, q, valid), "valid_fraction": float(valid.mean()), "s": seconds}
        rows.append(row)
        if folder is not None and pic.scene not in drawn:
            drawn.add(pic.scene)
            comparison_image(rgb, q, d, folder / f"compare_real_{pic.scene.replace('/', '_')}.png", show_raw=False)
    summary: dict[str, float] = {}
    groups = {s: [r for r in rows if r["set"] == s] for s in sorted({r["set"] for r in rows})}
    mb = [r for r in rows if r["set"].startswith("middlebury")]
    if mb and len({r["set"] for r in mb}) > 1:
        groups["middlebury"] = mb
    groups["all"] = rows
    for name, rs in groups.items():
        k = f"estimate.real.{name}"
        summary[f"{k}.affine_error"] = _mean([r["affine_error"] for r in rs])
        summary[f"{k}.affine_error_median"] = float(np.median([r["affine_error"] for r in rs]))
        summary[f"{k}.ramp_error"] = _mean([r["ramp_error"] for r in rs])
        summary[f"{k}.better_than_ramp_share"] = float(np.mean([r["affine_error"] < r["ramp_error"] for r in rs]))
        summary[f"{k}.corr"] = _mean([r["corr"] for r in rs])
        summary[f"{k}.views"] = len(rs)
        summary[f"{k}.scenes"] = len({r["scene"] for r in rs})
    summary["estimate.real.s_per_view"] = _mean([r["s"] for r in rows])
    summary["estimate.real.fold_models"] = networks.loads
    plan = getattr(next(iter(methods.values())), "plan", None) if methods else None
    md = [f"## Real pictures with measured depth (`{root}`)", "",
          f"Depth method `{method}` on single pictures" + (f" ({plan.summary()})" if plan is not None else "") + "; "
          + (f"weights per scene from --weights-per-scene ({networks.loads} fold model(s), other scenes: "
             f"`{networks.default_name}`)" if networks.map else f"weights `{networks.default_name}`") + ".",
          "Affine-invariant error of D against the measured inverse depth (scale and shift fitted per view; "
          "0 = perfect, 1 = a constant); the ramp is 'nearer toward the bottom'.", "",
          "| set | views | scenes | ours (mean) | ours (median) | ramp (mean) | views better than the ramp |",
          "|---|---:|---:|---:|---:|---:|---:|"]
    for name in groups:
        k = f"estimate.real.{name}"
        md.append(f"| {name} | {summary[k + '.views']} | {summary[k + '.scenes']} | {_fmt(summary[k + '.affine_error'])} "
                  f"| {_fmt(summary[k + '.affine_error_median'])} | {_fmt(summary[k + '.ramp_error'])} "
                  f"| {100 * summary[k + '.better_than_ramp_share']:.0f} % |")
    md += ["", "| view | ours | ramp | corr | valid GT | weights |", "|---|---:|---:|---:|---:|---|"]
    for r in rows:
        md.append(f"| {r['name']} | {_fmt(r['affine_error'])} | {_fmt(r['ramp_error'])} | {_fmt(r['corr'])} "
                  f"| {100 * r['valid_fraction']:.0f} % | {Path(r['weights']).name} |")
    md += ["", "Pictures: `compare_real_<set>_<scene>.png` (first view of each scene): input | GT | ours fitted.", ""]
    return summary, rows, md


# ------------------------------------------------------------------------------ real video: geometry


def warp_to_next(depth_t: np.ndarray, pose_t: np.ndarray, depth_u: np.ndarray, pose_u: np.ndarray,
                 K: np.ndarray, tolerance: float = DEPTH_TOLERANCE) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Pixels of frame t seen at the same static point in frame u.

    depth_*: (H, W) GT depth (m, NaN unknown); pose_*: (4, 4) camera-to-world; K: (3, 3) px.
    Returns (ys, xs) integer pixels of t and (x2, y2) float positions in u of the pixels whose
    point projects inside u in front of its camera and whose GT depth there (nearest pixel)
    agrees with the projected depth within ``tolerance`` (relative).
    """
    h, w = depth_t.shape
    ys, xs = np.nonzero(np.isfinite(depth_t) & (depth_t > 0))
    z = depth_t[ys, xs].astype(np.float64)
    Kinv = np.linalg.inv(K)
    rays = Kinv @ np.stack([xs.astype(np.float64), ys.astype(np.float64), np.ones_like(z)])
    cam_t = rays * z
    rel = np.linalg.inv(pose_u) @ pose_t  # camera t -> camera u
    cam_u = rel[:3, :3] @ cam_t + rel[:3, 3:4]
    zu = cam_u[2]
    front = zu > 1e-6
    proj = K @ cam_u
    with np.errstate(divide="ignore", invalid="ignore"):
        x2, y2 = proj[0] / proj[2], proj[1] / proj[2]
    with np.errstate(invalid="ignore"):  # inside the frame: within half a pixel of its pixel centres
        inside = front & (x2 >= -0.5) & (x2 <= w - 0.5) & (y2 >= -0.5) & (y2 <= h - 0.5)
    xi = np.clip(np.rint(np.where(inside, x2, 0)), 0, w - 1).astype(np.int64)
    yi = np.clip(np.rint(np.where(inside, y2, 0)), 0, h - 1).astype(np.int64)
    du = depth_u[yi, xi].astype(np.float64)
    with np.errstate(invalid="ignore"):
        ok = inside & np.isfinite(du) & (np.abs(zu - du) <= tolerance * du)
    return ys[ok], xs[ok], x2[ok].astype(np.float32), y2[ok].astype(np.float32)


def bilinear(a: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """a sampled at float positions (x, y), bilinear (positions clamped to [0, W-1] x [0, H-1])."""
    h, w = a.shape
    x, y = np.clip(x, 0, w - 1), np.clip(y, 0, h - 1)
    x0 = np.clip(np.floor(x).astype(np.int64), 0, w - 1)
    y0 = np.clip(np.floor(y).astype(np.int64), 0, h - 1)
    x1, y1 = np.minimum(x0 + 1, w - 1), np.minimum(y0 + 1, h - 1)
    fx, fy = x - x0, y - y0
    top = a[y0, x0] * (1 - fx) + a[y0, x1] * fx
    bot = a[y1, x0] * (1 - fx) + a[y1, x1] * fx
    return (top * (1 - fy) + bot * fy).astype(np.float64)


@dataclass
class FlickerPair:
    """One frame pair: dD = D_t(x) - D_u(x') and dq = q_t(x) - q_u(x') at the matched pixels."""

    dd: np.ndarray
    dq: np.ndarray


def flicker_pair(d_t: np.ndarray, d_u: np.ndarray, q_t: np.ndarray, q_u: np.ndarray,
                 match: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]) -> FlickerPair | None:
    """dD and dq of a pair at the pixels of :func:`warp_to_next` (None below MIN_MATCHES)."""
    ys, xs, x2, y2 = match
    if len(ys) < MIN_MATCHES:
        return None
    dd = d_t[ys, xs].astype(np.float64) - bilinear(d_u, x2, y2)
    xi, yi = np.rint(x2).astype(np.int64), np.rint(y2).astype(np.int64)
    dq = q_t[ys, xs].astype(np.float64) - q_u[yi, xi].astype(np.float64)
    return FlickerPair(dd, dq)


class RunningStd:
    """Standard deviation of everything added (float64 sums)."""

    def __init__(self) -> None:
        self.n, self.s, self.s2 = 0, 0.0, 0.0

    def add(self, a: np.ndarray) -> None:
        v = a[np.isfinite(a)].astype(np.float64)
        self.n += v.size
        self.s += float(v.sum())
        self.s2 += float(v @ v)

    @property
    def std(self) -> float:
        if self.n == 0:
            return float("nan")
        m = self.s / self.n
        return math.sqrt(max(self.s2 / self.n - m * m, 0.0))


def flicker_figures(pairs: list[FlickerPair], d_std: float, scale: float = 0.0) -> tuple[float, float]:
    """(flicker, flicker corrected by ``scale`` s: |dD - s dq|), both / d_std, mean over pairs."""
    if not pairs or not d_std > 0:
        return float("nan"), float("nan")
    raw = [float(np.nanmean(np.abs(p.dd))) for p in pairs if np.isfinite(p.dd).any()]
    cor = [float(np.nanmean(np.abs(p.dd - scale * p.dq))) for p in pairs if np.isfinite(p.dd - scale * p.dq).any()]
    return _mean(raw) / d_std, _mean(cor) / d_std


# ------------------------------------------------------------------------------ real video: the run


def clip_key(root: Path) -> str:
    """Short key of a clip folder: ``hololens`` / ``tum`` for the shared clips, else its name."""
    name = Path(root).name.lower()
    for short in ("hololens", "tum"):
        if name.startswith(short):
            return short
    return "".join(c if c.isalnum() else "_" for c in name)


def system_frames(method: str, clip, n: int, network: DepthFn, hfov_deg: float | None) -> tuple[Iterator, object, object]:
    """(iterator of (D, E) per frame, plan, stream or None): the depth of the clip's first ``n``
    frames as ``rvr estimate --depth-method METHOD --stop n`` computes it (EstimateJob: the plan
    probes the range's frames; more than one cue runs a DepthStream, the network alone runs frame
    by frame)."""
    from ..depth.system import DepthStream, plan_depth

    plan = plan_depth(method, lambda: clip.rgb_frames(0, n), hfov_deg)
    h, w = clip.frame(0).rgb.shape[:2]
    if len(plan.cues) > 1:
        stream = DepthStream(plan, (w, h), network)
        return ((d, e) for _f, d, e, _fu in stream.frames(clip.rgb_frames(0, n))), plan, stream
    return (network(f) for f in clip.rgb_frames(0, n)), plan, None


def evaluate_video_clip(root: str | Path, methods: list[str], network: DepthFn, hfov_deg: float | None = None,
                        max_frames: int | None = None, folder: Path | None = None, sheet_frames: int = 4,
                        progress: bool = False, pool_every: int = 7) -> tuple[dict[str, float], list[str]]:
    """Score each depth method on one real RGB-D clip (module docstring); returns (keys, README lines)."""
    from tqdm import tqdm

    from ..depth.real_video import open_rgbd_clip

    root = Path(root)
    try:
        clip = open_rgbd_clip(root)
    except (FileNotFoundError, ValueError, OSError) as ex:
        raise InputError(f"--real-video {root}: {ex}") from ex
    n = len(clip) if max_frames is None else min(max_frames, len(clip))
    if n < 2:
        raise InputError(f"--real-video {root}: {n} frame(s); the figures need at least 2")
    for m in methods:
        base, _, window = m.partition("+")
        if base not in VIDEO_METHODS or (window and window not in VIDEO_FILTERS):
            raise InputError(f"--depth-methods {m!r}: choose from {', '.join(VIDEO_METHODS)}, each optionally with "
                             f"+{' or +'.join(VIDEO_FILTERS)} (the D after the temporal filter, e.g. auto+centred)")
    key = clip_key(root)
    pre = f"estimate.video.{key}"
    summary: dict[str, float] = {pre + ".frames": n}
    sheet_at = set(np.linspace(0, n - 1, sheet_frames).round().astype(int).tolist()) if sheet_frames else set()
    sheet: dict[int, dict[str, np.ndarray]] = {i: {} for i in sheet_at}
    # the ground truth's own figures (ramp, GT flicker) and the warps, once per clip
    ramp_err, matches, gt_pairs, gt_std = [], [], [], RunningStd()
    ramp_pool_p, ramp_pool_q = [], []
    prev = None
    for i, fr in enumerate(clip.frames(0, n)):
        q = fr.inverse_depth
        valid = np.isfinite(q)
        ramp = vertical_ramp(*q.shape)
        ramp_err.append(affine_invariant_error(ramp, q, valid) if valid.sum() >= 2 else float("nan"))
        ramp_pool_p.append(ramp[valid][::pool_every])
        ramp_pool_q.append(q[valid][::pool_every])
        gt_std.add(q)
        if prev is not None:
            m = warp_to_next(prev.depth_m, prev.cam_to_world, fr.depth_m, fr.cam_to_world, clip.K)
            matches.append(m)
            p = flicker_pair(prev.inverse_depth, q, prev.inverse_depth, q, m)
            if p is not None:
                gt_pairs.append(p)
        if i in sheet:
            sheet[i]["rgb"], sheet[i]["gt"] = fr.rgb, q
        prev = fr
    summary[pre + ".ramp_error"] = float(np.nanmean(ramp_err))
    summary[pre + ".ramp_clip_affine_error"] = affine_invariant_error(np.concatenate(ramp_pool_p),
                                                                      np.concatenate(ramp_pool_q))
    summary[pre + ".gt_flicker"] = flicker_figures(gt_pairs, gt_std.std)[0]
    summary[pre + ".matched_share"] = float(np.mean([len(m[0]) for m in matches]) / (prev.rgb.shape[0] * prev.rgb.shape[1]))
    plans = {}
    for method in methods:
        base, _, window = method.partition("+")
        frames, plan, stream = system_frames(base, clip, n, network, hfov_deg)
        if window:  # the D the renderer gets: the temporal filter over the depth system's frames
            from ..temporal.filter import stabilize_stream
            from ..temporal.settings import TemporalSettings

            frames = ((d, e) for _i, d, e, _c in stabilize_stream(clip.rgb_frames(0, n), frames,
                                                                   TemporalSettings(window=window)))
        plans[method] = plan
        errs, pool_d, pool_q, pairs, d_std = [], [], [], [], RunningStd()
        prev_d = prev_q = None
        t0 = time.perf_counter()
        try:
            for i, ((d, _e), fr) in enumerate(tqdm(zip(frames, clip.frames(0, n)), total=n, unit="frame",
                                                  desc=f"{key} {method}", disable=not progress)):
                q = fr.inverse_depth
                valid = np.isfinite(q)
                errs.append(affine_invariant_error(d, q, valid) if valid.sum() >= 2 else float("nan"))
                pool_d.append(d[valid][::pool_every])
                pool_q.append(q[valid][::pool_every])
                d_std.add(d)
                if prev_d is not None:
                    p = flicker_pair(prev_d, d, prev_q, q, matches[i - 1])
                    if p is not None:
                        pairs.append(p)
                if i in sheet:
                    sheet[i][method] = d
                prev_d, prev_q = d, q
        finally:
            usage = stream.usage() if stream is not None else {"frames": n, "network": n}
            if stream is not None:
                stream.close()
        seconds = time.perf_counter() - t0
        pd, pq = np.concatenate(pool_d), np.concatenate(pool_q)
        from .evaluate import fit_scale_shift

        s_clip, _ = fit_scale_shift(pq, pd)  # D ~ s q + t over the clip
        fl, fl_c = flicker_figures(pairs, d_std.std, s_clip)
        k = f"{pre}.{method}"
        summary.update({f"{k}.affine_error": float(np.nanmean(errs)), f"{k}.affine_error_median": float(np.nanmedian(errs)),
                        f"{k}.clip_affine_error": affine_invariant_error(pd, pq), f"{k}.flicker": fl,
                        f"{k}.flicker_geometry_corrected": fl_c, f"{k}.s_per_frame": seconds / n})
        for cue in plan.cues:
            if cue != "network" and len(plan.cues) > 1:
                summary[f"{k}.{cue}_frames"] = int(usage.get(cue, 0))
        if "parallax" in plan.cues:  # frames that took the depth carried along the flow (depth.fuse)
            summary[f"{k}.carried_frames"] = int(usage.get("carried", 0))
            summary[f"{k}.refined_frames"] = int(usage.get("refined", 0))  # changed by later frames (depth.refine)
    md = [f"## Real video `{root.name}` ({n} frames, {prev.rgb.shape[1]}x{prev.rgb.shape[0]})", "",
          "The whole depth system as `rvr estimate --depth-method M` runs it"
          + (f" (--hfov {hfov_deg:g})" if hfov_deg is not None else " (default --hfov)") + ":", ""]
    md += [f"- `{m}`: {plans[m].summary()}" for m in methods]
    md += ["", "| figure | " + " | ".join(methods) + " | ramp |", "|---|" + "---:|" * (len(methods) + 1),
           "| affine-invariant error per frame, mean | " + " | ".join(_fmt(summary[f'{pre}.{m}.affine_error']) for m in methods)
           + f" | {_fmt(summary[pre + '.ramp_error'])} |",
           "| ... median | " + " | ".join(_fmt(summary[f'{pre}.{m}.affine_error_median']) for m in methods) + " | |",
           "| one affine fit over the clip | " + " | ".join(_fmt(summary[f'{pre}.{m}.clip_affine_error']) for m in methods)
           + f" | {_fmt(summary[pre + '.ramp_clip_affine_error'])} |",
           "| flicker (mean abs frame-to-frame change on static points / std of D) | "
           + " | ".join(_fmt(summary[f'{pre}.{m}.flicker']) for m in methods) + f" | GT itself: {_fmt(summary[pre + '.gt_flicker'])} |",
           "| flicker less the geometric change (clip fit) | "
           + " | ".join(_fmt(summary[f'{pre}.{m}.flicker_geometry_corrected']) for m in methods) + " | |",
           "| s per frame | " + " | ".join(_fmt(summary[f'{pre}.{m}.s_per_frame']) for m in methods) + " | |", "",
           f"Static points matched between consecutive frames: {100 * summary[pre + '.matched_share']:.0f} % of the "
           f"pixels (GT depth within {100 * DEPTH_TOLERANCE:.0f} %).", ""]
    if folder is not None and sheet:
        _video_sheet(sheet, methods, folder / f"video_{key}.png")
        md += [f"Picture: `video_{key}.png`, rows = frames {sorted(sheet)}: input | GT 1/z | "
               + " | ".join(f"{m} D fitted to 1/z per frame" for m in methods) + ".", ""]
    return summary, md


def _video_sheet(sheet: dict[int, dict[str, np.ndarray]], methods: list[str], path: Path, width: int = 270) -> None:
    import cv2

    from .evaluate import fit_scale_shift

    rows = []
    for i in sorted(sheet):
        item = sheet[i]
        gt = item["gt"]
        ok = np.isfinite(gt)
        lo, hi = np.percentile(gt[ok], [2, 98]) if ok.any() else (0.0, 1.0)
        tiles = [item["rgb"], colour_map(gt, lo, hi)]
        for m in methods:
            d = item[m]
            s, t = fit_scale_shift(d, gt)
            tiles.append(colour_map(s * d + t, lo, hi))
        h = int(round(gt.shape[0] * width / gt.shape[1]))
        rows.append(np.concatenate([cv2.resize(np.ascontiguousarray(x, np.uint8), (width, h),
                                               interpolation=cv2.INTER_AREA) for x in tiles], 1))
    if not cv2.imwrite(str(path), np.concatenate(rows, 0)[..., ::-1]):
        raise OutputError(f"cannot write '{path}'; check free space and permissions")


# ------------------------------------------------------------------------------ real aperture photos


def aperture_scenes(root: str | Path) -> list[tuple[str, Path, Path]]:
    """(scene, f/16 input, wide-aperture photo) under ``root``: ``<scene>/input.jpg`` with
    ``1_8.jpg`` (VABD) or ``target.jpg`` (EBB!). InputError when none."""
    root = Path(root)
    if not root.is_dir():
        raise InputError(f"--aperture {root}: not a folder; give ../shared/data/real_depth/aperture")
    out = []
    for sub in sorted(p for p in root.iterdir() if p.is_dir()):
        inp = next((sub / n for n in ("input.jpg", "input.png") if (sub / n).is_file()), None)
        wide = next((sub / n for n in ("1_8.jpg", "target.jpg", "1_8.png", "target.png") if (sub / n).is_file()), None)
        if inp is not None and wide is not None:
            out.append((sub.name, inp, wide))
    if not out:
        raise InputError(f"--aperture {root}: no <scene>/input.jpg with 1_8.jpg or target.jpg")
    return out


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    """PSNR (dB) of two float images in [0, 1]."""
    mse = float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))
    return 10.0 * math.log10(1.0 / max(mse, 1e-12))


def _read_rgb(path: Path) -> np.ndarray:
    import cv2

    bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if bgr is None:
        raise InputError(f"cannot read the photo {path}")
    return np.ascontiguousarray(bgr[..., ::-1])


def _shrink(img: np.ndarray, long_side: int) -> np.ndarray:
    import cv2

    h, w = img.shape[:2]
    s = long_side / max(h, w)
    if s >= 1:
        return img
    return cv2.resize(img, (max(int(round(w * s)), 1), max(int(round(h * s)), 1)), interpolation=cv2.INTER_AREA)


@dataclass
class AperturePair:
    """A prepared pair: input (H, W, 3) uint8, target sRGB float (aligned, exposure matched),
    box (y0, y1, x0, x1) where PSNR counts, alignment note."""

    image: np.ndarray
    target: np.ndarray
    box: tuple[int, int, int, int]
    note: str


def prepare_pair(inp: np.ndarray, wide: np.ndarray, long_side: int, border: float = 0.03) -> AperturePair:
    """Shrink both, align the wide photo onto the input (ECC homography), match its exposure
    (gain per channel in linear light), and choose the scored box."""
    from ..color import image_to_linear, linear_to_srgb
    from .align import AlignmentError, ecc_align, inner_rectangle, warp_to_reference

    a, b = _shrink(inp, long_side), _shrink(wide, long_side)
    if a.shape != b.shape:
        import cv2

        b = cv2.resize(b, (a.shape[1], a.shape[0]), interpolation=cv2.INTER_AREA)
    h, w = a.shape[:2]
    try:
        al = ecc_align(a, b, "homography")
        b, valid = warp_to_reference(b, al, (w, h))
        note = f"ECC homography, cc {al.cc:.3f}"
    except AlignmentError as ex:
        valid = np.ones((h, w), bool)
        note = f"not aligned ({ex})"
    y0, y1, x0, x1 = inner_rectangle(valid)
    my, mx = int(round(border * h)), int(round(border * w))
    box = (y0 + my, y1 - my, x0 + mx, x1 - mx)
    la, lb = image_to_linear(a), image_to_linear(b)
    sl = (slice(box[0], box[1]), slice(box[2], box[3]))
    gain = la[sl].reshape(-1, 3).mean(0) / np.maximum(lb[sl].reshape(-1, 3).mean(0), 1e-6)
    target = np.clip(linear_to_srgb(np.clip(lb * gain.astype(np.float32), 0, None)), 0, 1).astype(np.float32)
    note += f"; exposure gain {', '.join(f'{g:.2f}' for g in gain)}"
    return AperturePair(a, target, box, note)


def fit_render(pair: AperturePair, d: np.ndarray, e: np.ndarray | None, refine: bool = True) -> tuple[float, float, float, np.ndarray]:
    """Best (psnr, focus f, aperture scale a, render) of our renderer over f and a."""
    from scipy.optimize import minimize

    from ..render.fast import FastRenderer

    r = FastRenderer(threads=1)
    y0, y1, x0, x1 = pair.box
    tgt = pair.target[y0:y1, x0:x1]
    lo, hi = (float(v) for v in np.percentile(d, [2, 98]))
    span = max(hi - lo, 1e-6)
    cache: dict[tuple[float, float], tuple[float, np.ndarray]] = {}

    def score(f: float, a: float) -> float:
        k = (round(f, 6), round(a, 8))
        if k not in cache:
            out = r.render_srgb(pair.image, d, f, max(a, 0.0), e)
            cache[k] = (psnr(np.clip(out[y0:y1, x0:x1], 0, 1), tgt), out)
        return cache[k][0]

    best = (-math.inf, lo, 0.0)
    for f in np.linspace(lo, hi, 9):
        for rmax in (0.5, 1, 2, 4, 8, 16, 32, 48):
            v = score(float(f), rmax / span)
            if v > best[0]:
                best = (v, float(f), rmax / span)
    if refine:
        x0v = np.array([(best[1] - lo) / span, math.log(best[2] * span)])
        res = minimize(lambda x: -score(lo + x[0] * span, math.exp(x[1]) / span), x0v, method="Nelder-Mead",
                       options={"xatol": 0.01, "fatol": 0.005, "maxfev": 40,
                                "initial_simplex": [x0v, x0v + [0.06, 0], x0v + [0, 0.3]]})
        if -res.fun > best[0]:
            best = (-float(res.fun), lo + float(res.x[0]) * span, math.exp(float(res.x[1])) / span)
    v, f, a = best
    return v, f, a, cache[(round(f, 6), round(a, 8))][1]


def fit_gauss(pair: AperturePair) -> tuple[float, float, np.ndarray]:
    """Best (psnr, sigma px, picture) of a uniform Gaussian blur of the input (linear light)."""
    import cv2
    from scipy.optimize import minimize_scalar

    from ..color import image_to_linear, linear_to_srgb

    lin = image_to_linear(pair.image).astype(np.float32)
    y0, y1, x0, x1 = pair.box
    tgt = pair.target[y0:y1, x0:x1]
    cache: dict[float, tuple[float, np.ndarray]] = {}

    def score(sigma: float) -> float:
        sigma = round(max(float(sigma), 0.0), 4)
        if sigma not in cache:
            out = lin if sigma < 0.05 else cv2.GaussianBlur(lin, (0, 0), sigma)
            out = np.clip(linear_to_srgb(out), 0, 1)
            cache[sigma] = (psnr(out[y0:y1, x0:x1], tgt), out)
        return cache[sigma][0]

    grid = [0.0, 0.5, 1, 1.5, 2, 3, 4, 6, 8, 12, 16, 24]
    vals = [score(s) for s in grid]
    k = int(np.argmax(vals))
    lo, hi = grid[max(k - 1, 0)], grid[min(k + 1, len(grid) - 1)]
    if hi > lo:
        res = minimize_scalar(lambda s: -score(s), bounds=(lo, hi), method="bounded", options={"xatol": 0.02})
        score(res.x)
    sigma = max(cache, key=lambda s: cache[s][0])
    return cache[sigma][0], sigma, cache[sigma][1]


def evaluate_aperture(root: str | Path, depth: DepthFn, long_side: int = 512, folder: Path | None = None,
                      progress: bool = False) -> tuple[dict[str, float], list[str]]:
    """Fit our renderer (with D, E of ``depth``), the ramp and a Gaussian blur to each scene's
    wide-aperture photo (module docstring); returns (keys, README lines)."""
    from tqdm import tqdm

    scenes = aperture_scenes(root)
    summary: dict[str, float] = {}
    rows = []
    for name, inp_path, wide_path in tqdm(scenes, desc="aperture", unit="scene", disable=not progress):
        pair = prepare_pair(_read_rgb(inp_path), _read_rgb(wide_path), long_side)
        d, e = depth(pair.image)
        ours = fit_render(pair, d, e)
        ramp_d = (1.0 - vertical_ramp(*d.shape)).astype(np.float32)  # top = far = larger D
        ramp = fit_render(pair, ramp_d, e)
        gauss = fit_gauss(pair)
        y0, y1, x0, x1 = pair.box
        ident = psnr(np.clip(pair.image[y0:y1, x0:x1] / 255.0, 0, 1), pair.target[y0:y1, x0:x1])
        k = f"estimate.aperture.{name}"
        summary.update({f"{k}.psnr_ours_db": ours[0], f"{k}.psnr_gauss_db": gauss[0], f"{k}.psnr_ramp_db": ramp[0],
                        f"{k}.psnr_input_db": ident, f"{k}.focus": ours[1], f"{k}.aperture_scale": ours[2],
                        f"{k}.gauss_sigma_px": gauss[1]})
        rows.append((name, pair.note, ours, ramp, gauss, ident, wide_path.name))
        if folder is not None:
            _aperture_sheet(pair, ours[3], gauss[2], d, folder / f"aperture_{name}.png")
    margins = [summary[f"estimate.aperture.{r[0]}.psnr_ours_db"] - summary[f"estimate.aperture.{r[0]}.psnr_gauss_db"]
               for r in rows]
    margins_ramp = [summary[f"estimate.aperture.{r[0]}.psnr_ramp_db"] - summary[f"estimate.aperture.{r[0]}.psnr_gauss_db"]
                    for r in rows]
    summary["estimate.aperture.mean_margin_db"] = _mean(margins)
    summary["estimate.aperture.mean_margin_ramp_db"] = _mean(margins_ramp)
    summary["estimate.aperture.scenes"] = len(rows)
    summary["estimate.aperture.long_side_px"] = long_side
    md = [f"## Real aperture photos (`{root}`)", "",
          f"Each f/16 input and its wide-aperture photo (f/1.8) shrunk to a long side of {long_side} px; the wide "
          "photo aligned onto the input (ECC) and its exposure matched (one gain per channel, linear light); PSNR "
          "(sRGB) on the overlap less a 3 % border. Ours: our renderer with D, E from the input, focus and aperture "
          "fitted for the best PSNR; ramp: the same renderer and fit with D = a vertical ramp (what the renderer "
          "earns without depth); Gaussian: the input blurred uniformly (linear light), sigma fitted.", "",
          "| scene | ours dB | ramp dB | Gaussian dB | input as is dB | ours - Gaussian | f | a | sigma px | alignment |",
          "|---|---:|---:|---:|---:|---:|---:|---:|---:|---|"]
    for name, note, ours, ramp, gauss, ident, wide in rows:
        md.append(f"| {name} ({wide}) | {ours[0]:.2f} | {ramp[0]:.2f} | {gauss[0]:.2f} | {ident:.2f} | "
                  f"{ours[0] - gauss[0]:+.2f} | {ours[1]:.3g} | {ours[2]:.3g} | {gauss[1]:.2f} | {note} |")
    md += ["", f"Mean margin ours - Gaussian: **{summary['estimate.aperture.mean_margin_db']:+.2f} dB**; ramp - "
               f"Gaussian: {summary['estimate.aperture.mean_margin_ramp_db']:+.2f} dB.",
           "Pictures: `aperture_<scene>.png` = input | real wide aperture (aligned) | ours | Gaussian | D.", ""]
    return summary, md


def _aperture_sheet(pair: AperturePair, ours: np.ndarray, gauss: np.ndarray, d: np.ndarray, path: Path,
                    width: int = 384) -> None:
    import cv2

    lo, hi = np.percentile(d, [2, 98])
    tiles = [pair.image, (pair.target * 255 + 0.5).astype(np.uint8), (np.clip(ours, 0, 1) * 255 + 0.5).astype(np.uint8),
             (np.clip(gauss, 0, 1) * 255 + 0.5).astype(np.uint8), colour_map(d, lo, hi)]
    h = int(round(pair.image.shape[0] * width / pair.image.shape[1]))
    out = []
    for label, t in zip(("input f/16", "real wide", "ours", "Gaussian", "D"), tiles):
        t = cv2.resize(np.ascontiguousarray(t), (width, h), interpolation=cv2.INTER_AREA).copy()
        cv2.putText(t, label, (4, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 3, cv2.LINE_AA)
        cv2.putText(t, label, (4, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1, cv2.LINE_AA)
        out.append(t)
    if not cv2.imwrite(str(path), np.concatenate(out, 1)[..., ::-1]):
        raise OutputError(f"cannot write '{path}'; check free space and permissions")
