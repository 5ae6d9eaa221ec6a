"""Fast CPU inference path of the RVR forward model (numpy + OpenCV), exact to the model.

The model is defined in :mod:`.model`. Speed comes from skipping work, never from
approximating a kernel: per 16x16 tile we record which layers have a non-zero matte there,
and each layer is blurred and composited only on boxes around its active tiles. The boxes
of one layer are grown by the kernel radius and merged until disjoint, so every blurred
footprint lies inside exactly one box and the result equals a full-frame blur. The fill of
the coverage resolve (model step 5) is one push-pull over the frame: its first level is
pulled straight from the colour planes and the full-resolution push is a bilinear upsampling.
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
    EXP_FLOOR,
    FILL_DEPTH_SHARPNESS,
    FILL_DEPTH_TOLERANCE,
    LAMBDA,
    MATTE_FLOOR,
    MATTE_OFFSETS,
    OCCLUSION_DELAY,
    WEIGHT_EPS,
    LayerPlan,
    hdr_radiance,
    plan_for_radius_map,
    push_pull_levels,
    signed_radius,
)

Box = tuple[int, int, int, int]  # y0, y1, x0, x1 (half-open, px)
HALF_RES_RADIUS = 12.0
"""Layers blurred with a radius of at least this many px are blurred at half resolution (2x2
area average, the kernel of half the radius, bilinear back up): a quarter of the pixels and of
the kernel's area, for an error far below what the eye sees at such blur (bokeh rims soften by
about a pixel; 45 dB against the exact model at 1080p, ``bench/render_bench.py`` measures it).
Below 12 px the rim of a small, very bright highlight's bokeh would visibly soften (at 360p a
threshold of 8 px gave 34 dB), so smaller radii stay exact. ``FastRenderer(half_res_radius=None)``
keeps every layer exact."""
PUSH_PULL_NUMPY_BELOW = 16
SCALAR_LIKE_ROWS = 4
"""OpenCV's Python bindings take a 2-D array of shape (n, 1) with n <= this for a scalar."""
"""Push-pull levels with a side below this many px are done in plain numpy (they are tiny, and
OpenCV's Python bindings read an (n <= 4, 1) array as a scalar)."""


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
    half_res_radius: float | None = HALF_RES_RADIUS
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
        if disparity.shape[1] == 1 and disparity.shape[0] <= SCALAR_LIKE_ROWS:
            # OpenCV's Python bindings read an (n <= 4, 1) array as a scalar (1x1, 4x1 frames crashed
            # in matte_normaliser_cv): a frame of at most 4 px is rendered exactly by the reference
            from .reference import render_reference

            return render_reference(radiance, disparity, focus, aperture, spec=self.spec, plan=plan,
                                    naive=self.naive, max_step=self.max_step, min_layers=self.min_layers)
        s = signed_radius(disparity.astype(np.float32, copy=False), np.float32(focus), np.float32(aperture))
        if plan is None:
            plan = plan_for_radius_map(s, max_step=self.max_step, min_layers=self.min_layers)
        j_lo, j_hi = int(plan.indices.min()), int(plan.indices.max())
        u = np.clip(s / np.float32(plan.step), j_lo, j_hi).astype(np.float32)
        inv_norm = cv2.divide(1.0, matte_normaliser_cv(u, j_lo, j_hi))
        active = self._active_layers(u, j_lo, j_hi)
        h, w = u.shape
        channels = cv2.split(radiance.astype(np.float32, copy=False))
        radiance1 = cv2.merge((*channels, np.ones((h, w), np.float32)))
        zones = (zone_edges(h, self.spec.zones), zone_edges(w, self.spec.zones)) if self.spec.varies else None
        tasks = []
        for j in plan.indices[::-1]:  # front to back (model step 4)
            tiles = active[int(j) - j_lo]
            if tiles.any():
                radius = abs(float(j) * plan.step)
                kernel = self._kernel(radius)
                if zones is not None and kernel.size > 1:
                    kernel = ZoneKernels(*zones, [[self._kernel(radius, (zy, zx)) for zx in range(self.spec.zones)]
                                                  for zy in range(self.spec.zones)])
                reduced = None
                factor = self._reduction(radius) if zones is None else 1
                if factor > 1:
                    reduced = (factor, self._kernel(radius / factor))
                for box, core in layer_boxes(tiles, self.tile, kernel.shape[0] // 2, (h, w)):
                    tasks.append((int(j), kernel, box, core, reduced))
        acc = np.zeros((h, w, 4), dtype=np.float32)  # [sum T C, cov = sum T W] (model step 4)
        hidden = np.zeros((h, w), dtype=np.float32)  # sum of V_i over layers i <= j - S
        visible: deque = deque()  # (layer, [(box, V)]) not yet added to `hidden`
        current = None

        def blur(task):
            j, kernel, box, core, reduced = task
            return j, box, blur_layer_box(radiance1, u, inv_norm, float(j), kernel, box, core, reduced)

        # blurs run ahead on worker threads (OpenCV's DFT filter is single-threaded and
        # releases the GIL); compositing stays in front-to-back order on this thread
        for j, (y0, y1, x0, x1), src in self._map_ordered(blur, tasks):
            if j != current:
                while visible and visible[0][0] <= j - OCCLUSION_DELAY:
                    for (b0, b1, b2, b3), v in visible.popleft()[1]:
                        box_hidden = hidden[b0:b1, b2:b3]
                        cv2.add(box_hidden, v, dst=box_hidden)
                if not self.naive:
                    visible.append((j, []))
                current = j
            dst = acc[y0:y1, x0:x1]
            box_hidden = hidden[y0:y1, x0:x1]
            if self.naive or not cv2.countNonZero(box_hidden):  # nothing in front: T = 1
                cv2.add(dst, src, dst=dst)
                if not self.naive:
                    visible[-1][1].append(((y0, y1, x0, x1), cv2.extractChannel(src, 3)))
            else:
                t = cv2.max(cv2.subtract(1.0, box_hidden), 0.0)
                cv2.accumulateProduct(src, cv2.merge((t, t, t, t)), dst)
                visible[-1][1].append(((y0, y1, x0, x1), cv2.multiply(t, cv2.extractChannel(src, 3))))
        # model step 5: out = acc / max(cov, 1) + (1 - min(cov, 1)) * fill
        *acc_rgb, cov = cv2.split(acc)
        weight = cv2.min(cov, 1.0)
        fill = fill_level1_cv([cv2.sqrt(cv2.max(c, 0.0)) for c in channels], weight, u)  # model.fill_encode
        scale = cv2.divide(1.0, cv2.max(cov, 1.0))
        rest = cv2.subtract(1.0, weight)
        size = (2 * fill.shape[1], 2 * fill.shape[0])
        out = []
        for a, f in zip(acc_rgb, cv2.split(fill)):
            f = np.ascontiguousarray(cv2.resize(f, size, interpolation=cv2.INTER_LINEAR)[:h, :w])
            out.append(cv2.add(cv2.multiply(a, scale), cv2.multiply(cv2.multiply(f, f), rest)))  # model.fill_decode
        return cv2.merge(out)

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

    def _reduction(self, radius: float) -> int:
        """Resolution divisor (1 or 2) a layer of blur ``radius`` px is blurred at: 2 from
        ``half_res_radius`` on (a quarter resolution for the largest radii was measured too: 39 dB
        against the exact model and no faster, so it is not used)."""
        return 2 if self.half_res_radius is not None and radius >= self.half_res_radius else 1

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

    def work_px(self, disparity: np.ndarray, focus: float, aperture: float) -> int:
        """How much work a frame is: the pixels of every layer's boxes (active tiles grown by the
        blur's footprint) that :meth:`render_linear` blurs and composites, summed over the layers.
        Cheap next to a render; :mod:`.cost` turns it into seconds.

        disparity: (H, W) float32, DESIGN units. focus: focus disparity. aperture: scale >= 0.
        """
        if aperture == 0:
            return int(disparity.size)
        s = signed_radius(disparity.astype(np.float32, copy=False), np.float32(focus), np.float32(aperture))
        s = np.nan_to_num(s, nan=0.0, posinf=0.0, neginf=0.0)
        plan = plan_for_radius_map(s, max_step=self.max_step, min_layers=self.min_layers)
        j_lo, j_hi = int(plan.indices.min()), int(plan.indices.max())
        u = np.clip(s / np.float32(plan.step), j_lo, j_hi).astype(np.float32)
        active = self._active_layers(u, j_lo, j_hi)
        total = 0
        for j in plan.indices:
            tiles = active[int(j) - j_lo]
            if tiles.any():
                half = int(np.ceil(abs(float(j) * plan.step))) + 1
                for (y0, y1, x0, x1), _ in layer_boxes(tiles, self.tile, half, u.shape):
                    total += (y1 - y0) * (x1 - x0)
        return int(total)

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
    inv_norm: np.ndarray,
    j: float,
    kernel: np.ndarray,
    box: Box,
    core: Box,
    reduced: tuple[int, np.ndarray] | None = None,
) -> np.ndarray:
    """Blurred premultiplied [R, G, B, W] (h, w, 4) of layer j over ``box`` (model step 3).

    radiance1: (H, W, 4) float32 [R, G, B, 1] linear radiance with a channel of ones.
    The matte is the normalised ``M_j`` (``inv_norm``: the reciprocal matte normaliser).
    Sources are the pixels of ``core`` (the matte is zero elsewhere in the box); ``kernel`` is
    already flipped for correlation; zero outside the frame. ``reduced``: (factor, the flipped
    kernel of radius / factor) to blur at 1 / factor of the resolution instead (an area average
    down, bilinear back up; :data:`HALF_RES_RADIUS`).
    """
    y0, y1, x0, x1 = box
    cy0, cy1, cx0, cx1 = core
    alpha = cv2.multiply(_matte_cv(u[cy0:cy1, cx0:cx1], j), inv_norm[cy0:cy1, cx0:cx1])
    core_src = cv2.multiply(radiance1[cy0:cy1, cx0:cx1], cv2.merge((alpha, alpha, alpha, alpha)))
    if isinstance(kernel, ZoneKernels):
        return _blur_by_zones(core_src, kernel, box, core)
    if reduced is not None and reduced[1].size > 1:
        # pad to multiples of the factor so the area average and the bilinear upsampling share one grid
        f, small_kernel = reduced
        bh, bw = y1 - y0, x1 - x0
        src = cv2.copyMakeBorder(core_src, cy0 - y0, y1 - cy1 + (-bh) % f, cx0 - x0, x1 - cx1 + (-bw) % f,
                                 cv2.BORDER_CONSTANT, value=0)
        small = cv2.resize(src, (src.shape[1] // f, src.shape[0] // f), interpolation=cv2.INTER_AREA)
        small = cv2.filter2D(small, -1, small_kernel, borderType=cv2.BORDER_CONSTANT)
        up = cv2.resize(small, (src.shape[1], src.shape[0]), interpolation=cv2.INTER_LINEAR)
        return np.ascontiguousarray(up[:bh, :bw])
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


def fill_cv(colour: np.ndarray, weight: np.ndarray, depth: np.ndarray) -> np.ndarray:
    """:func:`.model.push_pull_fill` with OpenCV (same values): (H, W, 3) float32 colour,
    (H, W) weight in [0, 1] and depth (layer coordinate) -> (H, W, 3) fill."""
    h, w = weight.shape
    f = fill_level1_cv([cv2.sqrt(cv2.max(c, 0.0)) for c in cv2.split(colour)], weight, depth)  # model.fill_encode
    f = np.ascontiguousarray(cv2.resize(f, (2 * f.shape[1], 2 * f.shape[0]), interpolation=cv2.INTER_LINEAR)[:h, :w])
    return cv2.multiply(f, f)  # model.fill_decode


def fill_level1_cv(channels: list, weight: np.ndarray, depth: np.ndarray) -> np.ndarray:
    """Level 1 (half resolution, (ceil(H/2), ceil(W/2), 3)) of the push-pull of
    :func:`.model.push_pull_fill`, in the colour domain given (the callers pass
    ``model.fill_encode`` of the radiance, upsample bilinearly 2x, crop to (H, W) and decode).

    channels: the three (H, W) float32 colour planes; weight, depth: (H, W) float32. Depths
    are handled as ``y = kappa * z`` (a depth factor is then one exp of ``min(y - y_ref +
    kappa * tolerance, 0)``). Levels with a side below PUSH_PULL_NUMPY_BELOW use the model's
    numpy code.
    """
    if min(weight.shape) < PUSH_PULL_NUMPY_BELOW:
        f, _ = push_pull_levels(cv2.merge(channels), weight, depth, down_to=1)
        return f.astype(np.float32)
    c, w, y = _pull0_cv(channels, weight, cv2.multiply(depth, FILL_DEPTH_SHARPNESS))
    levels = []
    while True:
        yv = y.copy()
        yv[w <= 0] = -np.inf  # depths of samples with weight, for the block maxima and m
        levels.append((c, w, y, yv))
        if min(w.shape) < PUSH_PULL_NUMPY_BELOW:
            break
        c, w, y = _pull_cv(c, w, y, yv)
    # the small levels in plain numpy (in y units: unit sharpness, tolerance kappa * tolerance)
    f, g = push_pull_levels(*levels[-1][:3], 1.0, _TOLERANCE_Y)
    f, g = f.astype(np.float32), g.astype(np.float32)
    for c, w, y, yv in reversed(levels[:-1]):  # push down to level 1
        h, wd = w.shape
        size = (2 * g.shape[1], 2 * g.shape[0])
        fu = np.ascontiguousarray(cv2.resize(f, size, interpolation=cv2.INTER_LINEAR)[:h, :wd])
        gu = np.ascontiguousarray(cv2.resize(g, size, interpolation=cv2.INTER_LINEAR)[:h, :wd])
        m = cv2.max(yv, gu)
        a = cv2.multiply(w, _factor(y, m))
        b = cv2.multiply(cv2.subtract(1.0, w), _factor(gu, m))
        inv = cv2.divide(1.0, cv2.add(a, b))
        a, b = cv2.multiply(a, inv), cv2.multiply(b, inv)
        f = cv2.add(cv2.multiply(c, cv2.merge((a, a, a))), cv2.multiply(fu, cv2.merge((b, b, b))))
        g = cv2.add(cv2.multiply(y, a), cv2.multiply(gu, b))
    return f


_TOLERANCE_Y = FILL_DEPTH_SHARPNESS * FILL_DEPTH_TOLERANCE


def _factor(y: np.ndarray, y_ref: np.ndarray) -> np.ndarray:
    """:func:`.model.depth_factor` of ``z - z_ref`` for ``y = kappa z``:
    ``exp(max(min(y - y_ref + kappa tolerance, 0), EXP_FLOOR))``."""
    t = cv2.add(cv2.subtract(y, y_ref), _TOLERANCE_Y)
    return cv2.exp(cv2.max(cv2.min(t, 0.0), EXP_FLOOR))


def _block_max_up(yv: np.ndarray) -> np.ndarray:
    """Each pixel's 2x2-block maximum of yv (even-sized, -inf = no sample), 0 for empty blocks."""
    h, wd = yv.shape
    ymax = np.maximum(np.maximum(yv[0::2, 0::2], yv[0::2, 1::2]), np.maximum(yv[1::2, 0::2], yv[1::2, 1::2]))
    ymax[np.isneginf(ymax)] = 0.0
    return cv2.resize(ymax, (wd, h), interpolation=cv2.INTER_NEAREST)


def _pad_even_cv(arrays, h: int, wd: int, values):
    pad = dict(top=0, bottom=h % 2, left=0, right=wd % 2, borderType=cv2.BORDER_CONSTANT)
    return [cv2.copyMakeBorder(x, value=v, **pad) for x, v in zip(arrays, values)]


def _pull0_cv(channels: list, w: np.ndarray, y: np.ndarray):
    """The first pull step, from separate colour planes (no interleaved copies)."""
    h, wd = w.shape
    yv = y
    if float(w.min()) <= 0.0:
        yv = y.copy()
        yv[w <= 0] = -np.inf
    if h % 2 or wd % 2:
        *channels, w, y, yv = _pad_even_cv((*channels, w, y, yv), h, wd, (0, 0, 0, 0, 0, -np.inf))
        h, wd = w.shape
    e = cv2.multiply(w, _factor(y, _block_max_up(yv)))
    size = (wd // 2, h // 2)
    area = cv2.INTER_AREA  # an exact 2x reduction: the 2x2 block means
    means = [cv2.resize(cv2.multiply(x, e), size, interpolation=area) for x in (*channels, y)]
    se = cv2.resize(e, size, interpolation=area)
    inv = cv2.divide(1.0, cv2.max(se, WEIGHT_EPS / 4))
    inv[se <= WEIGHT_EPS / 4] = 0.0
    c = cv2.merge([cv2.multiply(x, inv) for x in means[:3]])
    return c, cv2.resize(w, size, interpolation=area), cv2.multiply(means[3], inv)


def _pull_cv(c: np.ndarray, w: np.ndarray, y: np.ndarray, yv: np.ndarray):
    """One depth-aware pull step of :func:`.model.push_pull_fill` (c: (h, w, 3); yv: y, -inf
    where w = 0)."""
    h, wd = w.shape
    if h % 2 or wd % 2:
        c, w, y, yv = _pad_even_cv((c, w, y, yv), h, wd, (0, 0, 0, -np.inf))
        h, wd = w.shape
    e = cv2.multiply(w, _factor(y, _block_max_up(yv)))
    size = (wd // 2, h // 2)
    ce = cv2.resize(cv2.multiply(c, cv2.merge((e, e, e))), size, interpolation=cv2.INTER_AREA)
    se, ye, wm = cv2.split(cv2.resize(cv2.merge((e, cv2.multiply(y, e), w)), size, interpolation=cv2.INTER_AREA))
    inv = cv2.divide(1.0, cv2.max(se, WEIGHT_EPS / 4))
    inv[se <= WEIGHT_EPS / 4] = 0.0
    return cv2.multiply(ce, cv2.merge((inv, inv, inv))), wm, cv2.multiply(ye, inv)


def matte_normaliser_cv(u: np.ndarray, j_lo: int, j_hi: int) -> np.ndarray:
    """:func:`.model.matte_normaliser` with OpenCV and two exponentials instead of four.

    With f = u - floor(u), the Gaussians of layers floor(u) + k (k = -1..2) are
    e_k = exp(-LAMBDA (f - k)^2), and e_k = e_{k-1} * exp(2 LAMBDA f) * exp(-LAMBDA (2k - 1)).
    """
    base = np.floor(u)
    frac = cv2.subtract(u, base)
    d = cv2.add(frac, 1.0)
    e = cv2.exp(cv2.multiply(cv2.multiply(d, d), -LAMBDA))  # k = -1
    x = cv2.exp(cv2.multiply(frac, 2.0 * LAMBDA))
    total = np.zeros_like(u)
    for k in MATTE_OFFSETS:
        if k > MATTE_OFFSETS[0]:
            e = cv2.multiply(e, x, scale=float(np.exp(-LAMBDA * (2 * k - 1))))
        g = cv2.max(cv2.subtract(e, MATTE_FLOOR), 0.0)
        # only the plan's layers j_lo..j_hi count (u is clipped to that range)
        if k < 0:
            cv2.add(total, g, dst=total, mask=cv2.compare(base, float(j_lo - k), cv2.CMP_GE))
        elif k > 0:
            cv2.add(total, g, dst=total, mask=cv2.compare(base, float(j_hi - k), cv2.CMP_LE))
        else:
            cv2.add(total, g, dst=total)
    return total


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
