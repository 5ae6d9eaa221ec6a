"""Optical flow for the temporal filter (paper section 4.2): DIS flow forward and backward,
backward warping, flow concatenation, forward-backward consistency and a photometric check.

Conventions. A flow ``f_ab`` is (h, w, 2) float32, (dx, dy) in px *at the resolution it was
computed* (the "flow resolution", see :func:`flow_size`): the point seen at pixel p of frame a
is at ``p + f_ab(p)`` in frame b. Backward warping ``warp(img_b, f_ab)(p) = img_b(p + f_ab(p))``
(bilinear) brings frame b onto frame a's pixels. Pixel centres are at integer coordinates.

The paper uses FlowNet 2.0; we use OpenCV's DIS flow (Kroeger et al. 2016), which runs on the
CPU in milliseconds at a reduced resolution (flows are upsampled and their vectors scaled
for warping the full-resolution estimates, :func:`upsample_flow`).
"""
from __future__ import annotations

import cv2
import numpy as np

PRESETS: dict[str, int] = {
    "ultrafast": cv2.DISOPTICAL_FLOW_PRESET_ULTRAFAST,
    "fast": cv2.DISOPTICAL_FLOW_PRESET_FAST,
    "medium": cv2.DISOPTICAL_FLOW_PRESET_MEDIUM,
}
"""DIS presets by name (OpenCV 4.11)."""

_GRIDS: dict[tuple[int, int], np.ndarray] = {}


MIN_FLOW_SIDE = 16
"""DIS needs a frame of at least 12 px on one side; tinier frames are enlarged to this."""


def flow_size(width: int, height: int, max_side: int) -> tuple[int, int]:
    """(w, h) of the flow resolution: the frame shrunk so its longer side is at most
    ``max_side`` px (enlarged only when that side is under MIN_FLOW_SIDE px)."""
    long_side = max(width, height)
    s = min(1.0, float(max_side) / long_side)
    if long_side * s < MIN_FLOW_SIDE:
        s = MIN_FLOW_SIDE / long_side
    return max(int(round(width * s)), 1), max(int(round(height * s)), 1)


def to_flow_gray(frame: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """(H, W, 3) uint8 RGB frame -> (h, w) uint8 luma at ``size`` = (w, h) (area resampling)."""
    if frame.ndim != 3 or frame.shape[2] != 3:
        raise ValueError(f"to_flow_gray: frame must be (H, W, 3) RGB, got {frame.shape}")
    if frame.dtype != np.uint8:
        frame = np.clip(np.asarray(frame, np.float32) * 255.0 + 0.5, 0, 255).astype(np.uint8)
    gray = cv2.cvtColor(np.ascontiguousarray(frame), cv2.COLOR_RGB2GRAY)
    if (gray.shape[1], gray.shape[0]) != tuple(size):
        gray = cv2.resize(gray, tuple(size), interpolation=cv2.INTER_AREA)
    return gray


class DISFlow:
    """One OpenCV DIS flow instance (created once, reused for every pair; deterministic).

    preset: "ultrafast", "fast" or "medium" (:data:`PRESETS`).
    """

    def __init__(self, preset: str = "medium") -> None:
        if preset not in PRESETS:
            raise ValueError(f"unknown DIS preset {preset!r}; choose one of {', '.join(PRESETS)}")
        self.preset = preset
        self._dis = cv2.DISOpticalFlow_create(PRESETS[preset])

    def __call__(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Flow ``f_ab`` (h, w, 2) float32 px from gray uint8 frame a to frame b (same size)."""
        if a.shape != b.shape:
            raise ValueError(f"DISFlow: frames differ in size, {a.shape} vs {b.shape}")
        return dis_calc(self._dis, a, b)


def dis_calc(dis, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``dis.calc(a, b, None)`` of an OpenCV DIS object on frames of any size. OpenCV rejects frames
    under 12 px and *crashes the process* (SIGSEGV) on thin ones (e.g. 24x160 with the fast
    presets): those are padded with their edge pixels (:func:`dis_safe_size`), the flow cropped back."""
    h, w = a.shape[:2]
    ph, pw = dis_safe_size(h, w)
    if (ph, pw) == (h, w):
        return dis.calc(a, b, None)
    pad = (0, ph - h, 0, pw - w, cv2.BORDER_REPLICATE)
    flow = dis.calc(cv2.copyMakeBorder(a, *pad), cv2.copyMakeBorder(b, *pad), None)
    return np.ascontiguousarray(flow[:h, :w])


def dis_safe_size(h: int, w: int) -> tuple[int, int]:
    """(h, w) padded so that OpenCV 4.11's DIS flow neither refuses nor crashes on it: each side at
    least 32 px and at least a quarter of the longer side (found by running DIS on 1x1 .. 500x2000
    frames of every preset in child processes)."""
    side = max(32, (max(h, w) + 3) // 4)
    return max(h, side), max(w, side)


def pixel_grid(h: int, w: int) -> np.ndarray:
    """(h, w, 2) float32 of pixel coordinates (x, y) (cached per size; do not modify)."""
    grid = _GRIDS.get((h, w))
    if grid is None:
        xs, ys = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
        grid = np.dstack([xs, ys])
        if len(_GRIDS) > 8:
            _GRIDS.clear()
        _GRIDS[(h, w)] = grid
    return grid


def flow_maps(flow: np.ndarray) -> np.ndarray:
    """Absolute sampling positions ``p + flow(p)``, (h, w, 2) float32 (see :func:`remap`)."""
    return pixel_grid(*flow.shape[:2]) + flow


def warp(image: np.ndarray, flow: np.ndarray, border: str = "replicate", nearest: bool = False,
         maps: np.ndarray | None = None) -> np.ndarray:
    """Backward warp: ``out(p) = image(p + flow(p))``, bilinear.

    image: (h, w) or (h, w, C) float32 (C <= 4 per call is fastest); flow: (h, w, 2) px at
    the image's resolution. border: "replicate" (values) or "zero" (masks: outside = 0).
    maps: ``flow_maps(flow)`` if already computed (several warps by one flow).
    """
    h, w = flow.shape[:2]
    if image.shape[:2] != (h, w):
        raise ValueError(f"warp: image {image.shape[:2]} and flow {flow.shape[:2]} differ in size")
    return remap(image, flow_maps(flow) if maps is None else maps, border, nearest)


def remap(image: np.ndarray, maps: np.ndarray, border: str = "replicate", nearest: bool = False) -> np.ndarray:
    """``out(p) = image(maps(p))``; maps: (h, w, 2) float32 absolute (x, y) px
    (``pixel_grid + flow``; build it once to warp several images with one flow).

    Bilinear, or the nearest pixel with ``nearest=True``: for disparity, so a sample on a
    depth edge takes one side's value instead of a blend no surface has ("flying pixels").
    """
    if maps.shape[0] >= _REMAP_MAX_ROWS:  # OpenCV's remap takes fewer than SHRT_MAX rows: e.g. the
        # (N, 1, 2) point lists of the E fusion, N = every pixel of a bright 360p frame
        return np.concatenate([remap(image, maps[i:i + _REMAP_MAX_ROWS - 1], border, nearest)
                               for i in range(0, maps.shape[0], _REMAP_MAX_ROWS - 1)], axis=0)
    mode = cv2.BORDER_REPLICATE if border == "replicate" else cv2.BORDER_CONSTANT
    interp = cv2.INTER_NEAREST if nearest else cv2.INTER_LINEAR
    return cv2.remap(image, maps, None, interp, borderMode=mode, borderValue=0)


_REMAP_MAX_ROWS = 32767  # SHRT_MAX


def concat(f_ab: np.ndarray, f_bc: np.ndarray) -> np.ndarray:
    """Concatenated flow ``f_ac(p) = f_ab(p) + f_bc(p + f_ab(p))`` (h, w, 2) px."""
    return f_ab + warp(f_bc, f_ab)


def inside(flow: np.ndarray, maps: np.ndarray | None = None) -> np.ndarray:
    """(h, w) bool: ``p + flow(p)`` lands inside the frame (maps: ``flow_maps(flow)`` if known)."""
    h, w = flow.shape[:2]
    target = flow_maps(flow) if maps is None else maps
    return (target[..., 0] >= 0) & (target[..., 0] <= w - 1) & (target[..., 1] >= 0) & (target[..., 1] <= h - 1)


def fb_error(f_ab: np.ndarray, f_ba: np.ndarray, maps: np.ndarray | None = None) -> np.ndarray:
    """(h, w) float32 forward-backward error in px: ``|f_ab(p) + f_ba(p + f_ab(p))|``.

    0 for a consistent pixel (the point comes back where it started): the paper's condition
    with ``q = p + f_ab(p)``. maps: ``flow_maps(f_ab)`` if known.
    """
    r = f_ab + warp(f_ba, f_ab, maps=maps)
    return np.sqrt(r[..., 0] * r[..., 0] + r[..., 1] * r[..., 1])


def consistent(f_ab: np.ndarray, f_ba: np.ndarray, delta_px: float, relative: float = 0.05,
               maps: np.ndarray | None = None) -> np.ndarray:
    """(h, w) bool: the fwd-bwd error is at most ``delta_px + relative * |f_ab|`` px (flow
    resolution) and ``p + f_ab(p)`` is inside the frame. The relative term (Sundaram et al.
    2010) tolerates the larger absolute errors of fast motion. maps: ``flow_maps(f_ab)``."""
    maps = flow_maps(f_ab) if maps is None else maps
    mag = np.sqrt(f_ab[..., 0] ** 2 + f_ab[..., 1] ** 2)
    return (fb_error(f_ab, f_ba, maps) <= delta_px + relative * mag) & inside(f_ab, maps)


def photometric_ok(image_a: np.ndarray, image_b: np.ndarray, f_ab: np.ndarray, tol: float,
                   mask: np.ndarray | None = None, patch_px: int = 5, pixel_tol: float | None = None,
                   grad_a: np.ndarray | None = None, slack_px: float = 0.2,
                   maps: np.ndarray | None = None) -> np.ndarray:
    """(h, w) bool: frame b warped onto a matches a within ``tol`` (fraction of full scale).

    image_a, image_b: (h, w, C) float32 in [0, 1] (colour separates layers whose luma is
    alike). The difference is taken after removing each channel's median difference over
    ``mask`` (or all pixels), so a global exposure change is not a mismatch, and less
    ``slack_px`` times a's local gradient (:func:`gradient`, per px; pass ``grad_a`` to reuse
    it), so a sub-pixel misregistration of a strong edge (a clipped highlight's rim) is not a
    mismatch either. Two tests on the largest difference over the channels: its mean over a
    ``patch_px`` square must be at most ``tol`` (one pixel of a random texture often matches
    another texture by chance; a patch does not), and the pixel's own at most ``pixel_tol``
    (default 3 tol; a thin structure, a hair or a railing, fills too little of a patch to
    fail it). maps: ``flow_maps(f_ab)`` if known.
    """
    diff = image_a - warp(image_b, f_ab, maps=maps)
    if diff.ndim == 2:
        diff = diff[..., None]
    # the exposure offset: median over a 1-in-16 subsample of the (masked) pixels
    sub = diff[::4, ::4]
    if mask is not None and mask[::4, ::4].any():
        sub = sub[mask[::4, ::4]]
    offset = np.median(sub.reshape(-1, diff.shape[-1]), axis=0).astype(np.float32)
    diff -= offset
    np.abs(diff, out=diff)
    if slack_px > 0:
        g = gradient(image_a) if grad_a is None else grad_a
        diff -= np.float32(slack_px) * g.reshape(diff.shape)
        np.maximum(diff, 0.0, out=diff)
    ok = _worst(diff) <= (3.0 * tol if pixel_tol is None else pixel_tol)
    if patch_px > 1:
        ok &= _worst(cv2.blur(diff, (patch_px, patch_px), borderType=cv2.BORDER_REPLICATE)) <= tol
    return ok


def gradient(image: np.ndarray) -> np.ndarray:
    """Local gradient magnitude per channel, (|d/dx| + |d/dy|) with central differences, in
    value units per px; same shape as ``image`` (float32)."""
    gx = cv2.Sobel(image, cv2.CV_32F, 1, 0, ksize=1, borderType=cv2.BORDER_REPLICATE)
    gy = cv2.Sobel(image, cv2.CV_32F, 0, 1, ksize=1, borderType=cv2.BORDER_REPLICATE)
    return (np.abs(gx) + np.abs(gy)) * np.float32(0.5)


def _worst(diff: np.ndarray) -> np.ndarray:
    """Largest value over the channels of (h, w, C) -> (h, w)."""
    worst = diff[..., 0]
    for c in range(1, diff.shape[2]):
        worst = np.maximum(worst, diff[..., c])
    return worst


def to_flow_color(frame: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """(H, W, 3) uint8 RGB -> (h, w, 3) float32 in [0, 1] at ``size`` = (w, h) (area resampling)."""
    small = frame if (frame.shape[1], frame.shape[0]) == tuple(size) else cv2.resize(
        np.ascontiguousarray(frame), tuple(size), interpolation=cv2.INTER_AREA)
    return small.astype(np.float32) * np.float32(1 / 255)


def upsample_flow(flow: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Flow at another resolution: resized (bilinear) to ``size`` = (W, H), vectors scaled by
    W/w and H/h, so it is in px of the new resolution."""
    h, w = flow.shape[:2]
    if (w, h) == tuple(size):
        return flow
    out = cv2.resize(flow, tuple(size), interpolation=cv2.INTER_LINEAR)
    out[..., 0] *= np.float32(size[0] / w)
    out[..., 1] *= np.float32(size[1] / h)
    return out


def upsample_maps(flow: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Absolute sampling maps at ``size`` = (W, H) for :func:`remap`: ``pixel_grid +
    upsample_flow(flow, size)``, (H, W, 2) float32, in one pass when both axes scale alike."""
    h, w = flow.shape[:2]
    sx, sy = size[0] / w, size[1] / h
    grid = pixel_grid(size[1], size[0])
    up = cv2.resize(flow, tuple(size), interpolation=cv2.INTER_LINEAR) if (w, h) != tuple(size) else flow
    if abs(sx - sy) < 1e-9:
        return cv2.scaleAdd(up, sx, grid)
    return grid + up * np.array([sx, sy], np.float32)


def resize_map(values: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """A weight or mask map resized (bilinear) to ``size`` = (W, H); values unchanged."""
    if (values.shape[1], values.shape[0]) == tuple(size):
        return values
    return cv2.resize(values, tuple(size), interpolation=cv2.INTER_LINEAR)
