"""Fast CPU inference path of the RVR forward model (numpy + OpenCV), exact to the model.

The model is defined in :mod:`.model`. Speed comes from skipping work, never from
approximating a kernel: per 16x16 tile we record which layers have a non-zero matte there,
and each layer is blurred and composited only on boxes around its active tiles. The boxes
of one layer are grown by the kernel radius and merged until disjoint, so every blurred
footprint lies inside exactly one box and the result equals a full-frame blur.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import os
from collections import deque
from concurrent.futures import ThreadPoolExecutor

import cv2
import numpy as np

from ..color import linear_to_srgb, srgb_to_linear, to_float01
from ..errors import InputError
from .aperture import ApertureSpec, make_kernel, zone_edges, zone_offset
from .model import (
    ALPHA_EPS,
    ALPHA_SPAN,
    LAMBDA,
    MATTE_CUTOFF,
    MATTE_FLOOR,
    MATTE_OFFSETS,
    LayerPlan,
    hdr_radiance,
    matte_normaliser,
    plan_for_radius_map,
    signed_radius,
)

Box = tuple[int, int, int, int]  # y0, y1, x0, x1 (half-open, px)


@dataclass
class FastRenderer:
    """Renders frames with the fast tiled path; caches kernels and tile indices.

    tile: tile side in px for the activity map. max_step / min_layers: layer spacing (see
    :func:`.model.plan_layers`). naive: sum layers without occlusion (ablation only).
    """

    spec: ApertureSpec = field(default_factory=ApertureSpec)
    tile: int = 16
    max_step: float = 1.0
    min_layers: int = 1
    naive: bool = False
    threads: int = field(default_factory=lambda: min(os.cpu_count() or 1, 4))
    _kernels: dict = field(default_factory=dict, repr=False)
    _pool: ThreadPoolExecutor | None = field(default=None, repr=False)
    _tiles: dict = field(default_factory=dict, repr=False)

    # -- public -------------------------------------------------------------------------
    def render_linear(
        self,
        radiance: np.ndarray,
        disparity: np.ndarray,
        focus: float,
        aperture: float,
        plan: LayerPlan | None = None,
    ) -> np.ndarray:
        """Shallow-DOF linear radiance (H, W, 3) float32.

        radiance: (H, W, 3) float32 linear HDR radiance (eq. 3 already applied).
        disparity: (H, W) float32, px of blur radius at aperture 1, + = behind focus.
        focus: focus disparity (same units). aperture: aperture scale >= 0 (0 = no blur).
        plan: layers to use; by default planned from this frame's radius range.
        """
        check_frame_inputs(radiance, disparity, focus, aperture)
        if aperture == 0:
            return radiance.astype(np.float32, copy=True)
        s = signed_radius(disparity.astype(np.float32, copy=False), np.float32(focus), np.float32(aperture))
        if plan is None:
            plan = plan_for_radius_map(s, max_step=self.max_step, min_layers=self.min_layers)
        j_lo, j_hi = int(plan.indices.min()), int(plan.indices.max())
        u = np.clip(s / np.float32(plan.step), j_lo, j_hi).astype(np.float32)
        inv_norm = cv2.divide(1.0, matte_normaliser(u, plan)) if self.naive else None
        active = self._active_layers(u, j_lo, j_hi)
        h, w = u.shape
        radiance1 = cv2.merge((*cv2.split(radiance.astype(np.float32, copy=False)), np.ones((h, w), np.float32)))
        zones = (zone_edges(h, self.spec.zones), zone_edges(w, self.spec.zones)) if self.spec.varies else None
        tasks = []
        for j in plan.indices:  # back to front
            tiles = active[int(j) - j_lo]
            if tiles.any():
                radius = abs(float(j) * plan.step)
                kernel = self._kernel(radius)
                if zones is not None and kernel.size > 1:
                    kernel = ZoneKernels(*zones, [[self._kernel(radius, (zy, zx)) for zx in range(self.spec.zones)]
                                                  for zy in range(self.spec.zones)])
                for box, core in layer_boxes(tiles, self.tile, kernel.shape[0] // 2, (h, w)):
                    tasks.append((float(j), kernel, box, core))
        acc = np.zeros((h, w, 4), dtype=np.float32)

        def blur(task):
            j, kernel, box, core = task
            return box, blur_layer_box(radiance1, u, inv_norm, j, j_hi, kernel, box, core)

        # blurs run ahead on worker threads (OpenCV's DFT filter is single-threaded and
        # releases the GIL); compositing stays in back-to-front order on this thread
        for (y0, y1, x0, x1), src in self._map_ordered(blur, tasks):
            dst = acc[y0:y1, x0:x1]
            if self.naive:
                cv2.add(dst, src, dst=dst)
            else:
                t = 1.0 - src[..., 3]
                cv2.multiply(dst, cv2.merge((t, t, t, t)), dst=dst)
                cv2.add(dst, src, dst=dst)
        alpha = cv2.max(acc[..., 3], ALPHA_EPS)
        return cv2.divide(acc[..., :3].copy(), cv2.merge((alpha, alpha, alpha)))

    def render_srgb(
        self,
        image: np.ndarray,
        disparity: np.ndarray,
        focus: float,
        aperture: float,
        hdr_exponent: np.ndarray | None = None,
    ) -> np.ndarray:
        """Shallow-DOF sRGB image (H, W, 3) float32 in [0, 1] from an sRGB frame.

        image: (H, W, 3) uint8/uint16/float sRGB. hdr_exponent: E (H, W) or (H, W, 3), log
        space, radiance = linear * exp(50 E); None = no HDR recovery.
        """
        radiance = hdr_radiance(srgb_to_linear(to_float01(image)), hdr_exponent)
        return linear_to_srgb(self.render_linear(radiance, disparity, focus, aperture))

    # -- internals ------------------------------------------------------------------------
    def _map_ordered(self, fn, items: list, ahead: int = 4):
        """Yield fn(item) in order, computing up to ``ahead`` items on worker threads."""
        if self.threads <= 1 or len(items) < 2:
            yield from map(fn, items)
            return
        if self._pool is None:
            self._pool = ThreadPoolExecutor(self.threads, thread_name_prefix="rvr-blur")
        pending = deque()
        it = iter(items)
        for item in it:
            pending.append(self._pool.submit(fn, item))
            if len(pending) >= ahead:
                break
        while pending:
            result = pending.popleft().result()
            nxt = next(it, None)
            if nxt is not None:
                pending.append(self._pool.submit(fn, nxt))
            yield result

    def _kernel(self, radius: float, zone: tuple[int, int] | None = None) -> np.ndarray:
        """Flipped (scatter == correlation with the flipped PSF) kernel; (1,1) for a delta.

        zone: (row, column) of the cat's-eye zone, or None for the centre's kernel."""
        key = (self.spec.key, round(radius, 6), zone)
        k = self._kernels.get(key)
        if k is None:
            position = zone_offset(self.spec, *zone) if zone is not None else (0.0, 0.0)
            k = make_kernel(self.spec, radius, position)
            if np.count_nonzero(k > 1e-7) == 1 and k[k.shape[0] // 2, k.shape[1] // 2] > 0.999999:
                k = np.ones((1, 1), np.float32)
            else:
                k = np.ascontiguousarray(k[::-1, ::-1])
            self._kernels[key] = k
        return k

    def _tile_ids(self, h: int, w: int) -> tuple[np.ndarray, int, int]:
        key = (h, w, self.tile)
        got = self._tiles.get(key)
        if got is None:
            t = self.tile
            ty, tx = -(-h // t), -(-w // t)
            ids = (np.arange(h)[:, None] // t) * tx + (np.arange(w)[None, :] // t)
            got = (ids.astype(np.int64), ty, tx)
            self._tiles[key] = got
        return got

    def _active_layers(self, u: np.ndarray, j_lo: int, j_hi: int) -> np.ndarray:
        """(L, ty, tx) bool: layer j_lo + l has a non-zero matte somewhere in the tile.

        A pixel at layer coordinate u touches layers floor(u) + MATTE_OFFSETS.
        """
        h, w = u.shape
        ids, ty, tx = self._tile_ids(h, w)
        n_layers = j_hi - j_lo + 1
        base = (np.floor(u).astype(np.int64) - j_lo).clip(0, n_layers - 1)
        present = np.bincount((ids * n_layers + base).ravel(), minlength=ty * tx * n_layers)
        present = present.reshape(ty * tx, n_layers) > 0
        active = np.zeros_like(present)
        for off in MATTE_OFFSETS:
            lo, hi = max(off, 0), n_layers + min(off, 0)
            active[:, lo:hi] |= present[:, lo - off:hi - off]
        return active.T.reshape(n_layers, ty, tx)


def layer_boxes(tiles: np.ndarray, tile: int, half: int, shape: tuple[int, int]) -> list[tuple[Box, Box]]:
    """Disjoint (box, core) pixel rectangles for one layer, clipped to ``shape`` (H, W).

    ``core`` bounds the active tiles of a group; ``box`` is the core grown by ``half`` px,
    so it holds every source pixel of the group and its whole blurred footprint. Boxes of
    different groups never overlap (overlapping groups are merged).
    """
    h, w = shape
    grow = -(-half // tile)
    mask = tiles.astype(np.uint8)
    if grow:
        mask = cv2.dilate(mask, np.ones((2 * grow + 1, 2 * grow + 1), np.uint8))
    n, labels = cv2.connectedComponents(mask, connectivity=8)
    cores: list[list[int]] = []
    for c in range(1, n):
        ys, xs = np.nonzero((labels == c) & tiles)
        if ys.size:
            cores.append([int(ys.min()) * tile, min((int(ys.max()) + 1) * tile, h),
                          int(xs.min()) * tile, min((int(xs.max()) + 1) * tile, w)])
    # merge groups whose grown boxes overlap, until all boxes are disjoint
    merged = True
    while merged and len(cores) > 1:
        merged = False
        for a in range(len(cores)):
            for b in range(a + 1, len(cores)):
                p, q = cores[a], cores[b]
                if (p[0] - half < q[1] + half and q[0] - half < p[1] + half
                        and p[2] - half < q[3] + half and q[2] - half < p[3] + half):
                    cores[a] = [min(p[0], q[0]), max(p[1], q[1]), min(p[2], q[2]), max(p[3], q[3])]
                    del cores[b]
                    merged = True
                    break
            if merged:
                break
    return [((max(c[0] - half, 0), min(c[1] + half, h), max(c[2] - half, 0), min(c[3] + half, w)),
             (c[0], c[1], c[2], c[3])) for c in cores]


def blur_layer_box(
    radiance1: np.ndarray,
    u: np.ndarray,
    inv_norm: np.ndarray | None,
    j: float,
    j_hi: float,
    kernel: np.ndarray,
    box: Box,
    core: Box,
) -> np.ndarray:
    """Blurred premultiplied [R, G, B, alpha] (h, w, 4) of layer j over ``box``.

    radiance1: (H, W, 4) float32 [R, G, B, 1] linear radiance with a channel of ones.
    alpha is the layer's over-compositing alpha (model step 3), or, when ``inv_norm`` (the
    reciprocal matte normaliser) is given, the normalised matte itself (naive variant).
    Sources are the pixels of ``core`` (alpha is zero elsewhere in the box); ``kernel`` is
    already flipped for correlation; zero outside the frame.
    """
    y0, y1, x0, x1 = box
    cy0, cy1, cx0, cx1 = core
    uc = u[cy0:cy1, cx0:cx1]
    if inv_norm is not None:
        alpha = cv2.multiply(_matte_cv(uc, j), inv_norm[cy0:cy1, cx0:cx1])
    else:
        alpha = _alpha_cv(uc, j, j_hi)
    core_src = cv2.multiply(radiance1[cy0:cy1, cx0:cx1], cv2.merge((alpha, alpha, alpha, alpha)))
    if isinstance(kernel, ZoneKernels):
        return _blur_by_zones(core_src, kernel, box, core)
    src = cv2.copyMakeBorder(core_src, cy0 - y0, y1 - cy1, cx0 - x0, x1 - cx1, cv2.BORDER_CONSTANT, value=0)
    if kernel.size > 1:
        src = cv2.filter2D(src, -1, kernel, borderType=cv2.BORDER_CONSTANT)
    return src


@dataclass(frozen=True)
class ZoneKernels:
    """Per-zone (flipped) kernels of one radius for cat's-eye vignetting: zone (zy, zx)
    covers rows ys[zy]:ys[zy+1] and columns xs[zx]:xs[zx+1]; all kernels have one shape."""

    ys: np.ndarray
    xs: np.ndarray
    kernels: list

    @property
    def shape(self) -> tuple[int, int]:
        return self.kernels[0][0].shape


def _blur_by_zones(core_src: np.ndarray, zk: ZoneKernels, box: Box, core: Box) -> np.ndarray:
    """Scatter the core's sources with the kernel of each source's zone; sum over zones."""
    y0, y1, x0, x1 = box
    cy0, cy1, cx0, cx1 = core
    half = zk.shape[0] // 2
    out = np.zeros((y1 - y0, x1 - x0, 4), dtype=np.float32)
    for zy in range(len(zk.ys) - 1):
        sy0, sy1 = max(cy0, zk.ys[zy]), min(cy1, zk.ys[zy + 1])
        if sy0 >= sy1:
            continue
        for zx in range(len(zk.xs) - 1):
            sx0, sx1 = max(cx0, zk.xs[zx]), min(cx1, zk.xs[zx + 1])
            if sx0 >= sx1:
                continue
            # the zone's sources and their footprint (inside the box, which holds the core + half)
            top, left = min(half, sy0 - y0), min(half, sx0 - x0)
            bottom, right = min(half, y1 - sy1), min(half, x1 - sx1)
            src = cv2.copyMakeBorder(core_src[sy0 - cy0:sy1 - cy0, sx0 - cx0:sx1 - cx0], top, bottom, left, right,
                                     cv2.BORDER_CONSTANT, value=0)
            src = cv2.filter2D(src, -1, zk.kernels[zy][zx], borderType=cv2.BORDER_CONSTANT)
            out[sy0 - top - y0:sy1 + bottom - y0, sx0 - left - x0:sx1 + right - x0] += src
    return out


def _alpha_cv(u: np.ndarray, j: float, j_hi: float) -> np.ndarray:
    """:func:`.model.layer_alpha` with OpenCV arithmetic and two exponentials instead of four.

    With d = u - j, the Gaussians of layers j + i are e_i = exp(-LAMBDA (d - i)^2), and
    e_{i+1} = e_i * exp(2 LAMBDA d) * exp(-LAMBDA (2 i + 1)).
    """
    # |d| >= cutoff has alpha 0 anyway; the clamp keeps exp(2 LAMBDA d) finite
    d = np.clip(cv2.subtract(u, j), -MATTE_CUTOFF - 0.01, MATTE_CUTOFF + 0.01)
    e = cv2.exp(cv2.multiply(d, d, scale=-LAMBDA))
    x = cv2.exp(cv2.multiply(d, 2.0 * LAMBDA))
    g0 = cv2.max(cv2.subtract(e, MATTE_FLOOR), 0.0)
    total = g0.copy()
    for i in range(ALPHA_SPAN - 1):
        if j + i + 1 > j_hi:
            break
        e = cv2.multiply(e, x, scale=float(np.exp(-LAMBDA * (2 * i + 1))))
        cv2.add(total, cv2.max(cv2.subtract(e, MATTE_FLOOR), 0.0), dst=total)
    return cv2.divide(g0, cv2.max(total, 1e-30))


def _matte_cv(u: np.ndarray, j: float) -> np.ndarray:
    """:func:`.model.matte_unnormalised` with OpenCV arithmetic (same values, faster)."""
    d = cv2.subtract(u, j)
    g = cv2.exp(cv2.multiply(d, d, scale=-LAMBDA))
    return cv2.max(cv2.subtract(g, MATTE_FLOOR), 0.0)


def check_frame_inputs(radiance: np.ndarray, disparity: np.ndarray, focus: float, aperture: float) -> None:
    """Validate one frame's arrays and settings; raises InputError with the fix."""
    if radiance.ndim != 3 or radiance.shape[2] != 3:
        raise InputError(f"frame must be (H, W, 3) RGB, got shape {radiance.shape}")
    if disparity.shape != radiance.shape[:2]:
        raise InputError(
            f"disparity map is {disparity.shape[1]}x{disparity.shape[0]} but the frame is "
            f"{radiance.shape[1]}x{radiance.shape[0]}: resample the disparity to the frame size")
    if not np.isfinite(focus):
        raise InputError(f"focus disparity must be a finite number, got {focus}")
    if not np.isfinite(aperture) or aperture < 0:
        raise InputError(f"aperture must be a finite number >= 0 (0 = no blur), got {aperture}")
    if not np.all(np.isfinite(disparity)):
        raise InputError("disparity map has NaN or inf values: fill them (rvr_addon.io.maps does) before rendering")
    if not np.all(np.isfinite(radiance)):
        raise InputError("frame radiance has NaN or inf values: check the HDR map E")


def render_frame(
    image: np.ndarray,
    disparity: np.ndarray,
    focus: float,
    aperture: float,
    hdr_exponent: np.ndarray | None = None,
    spec: ApertureSpec | None = None,
    naive: bool = False,
) -> np.ndarray:
    """One-shot convenience: shallow-DOF sRGB (H, W, 3) float32 in [0, 1] of one frame."""
    r = FastRenderer(spec=spec or ApertureSpec(), naive=naive)
    return r.render_srgb(image, disparity, focus, aperture, hdr_exponent)
