"""Fast CPU inference path of the RVR forward model (numpy + OpenCV).

The model is defined in :mod:`.model`. Speed comes from skipping work: per 16x16 tile we record
which layers have a non-zero matte there, and each layer is blurred and composited only on
rectangles around its active tiles (each rectangle grown by the kernel's footprint, so that the
blurred rectangles of a layer sum to the blur of the whole layer; they may overlap, as blurring
and compositing are linear within a layer). How a layer's tiles are cut into rectangles is chosen
per layer by a cost model (:func:`layer_rects`): one box per layer would blur a whole frame's worth
of empty pixels on a depth map whose layers are thin bands (a real estimated one), one box per tile
would pay the footprint's margin over and over. The planes (R, G, B and the coverage) stay
separate from the source to the accumulators (no interleaving copies); large kernels are applied
by a DFT with cached kernel spectra (:func:`blur_planes`). Layers with a radius from
:data:`HALF_RES_RADIUS` px on are blurred at half resolution; ``half_res_radius=None`` renders
every layer exactly. The fill of the coverage resolve (model step 5) is one push-pull over the
frame: its first level is pulled straight from the colour planes and the full-resolution push is a
bilinear upsampling.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import os
from collections import deque
from concurrent.futures import Future, ThreadPoolExecutor
from itertools import groupby
from typing import Any

import cv2
import numpy as np

from ..color import image_to_linear, linear_to_srgb
from ..errors import InputError
from .aperture import ApertureSpec, make_kernel, zone_edges, zone_offset
from .model import (
    COVERAGE_SNAP,
    EXP_FLOOR,
    FILL_DEPTH_SHARPNESS,
    FILL_DEPTH_TOLERANCE,
    LAMBDA,
    MATTE_FLOOR,
    MATTE_OFFSETS,
    OCCLUSION_DELAY,
    SURFACE_STEPS,
    WEIGHT_EPS,
    LayerPlan,
    hdr_radiance,
    plan_for_radius_map,
    push_pull_levels,
    signed_radius,
)

Box = tuple[int, int, int, int]  # y0, y1, x0, x1 (half-open, px)
HALF_RES_RADIUS = 16.0
"""Layers blurred with a radius of at least this many px are blurred at half resolution (a 2x2
area average, the kernel of half the radius, bilinear back up; all four planes, so a uniform colour
stays exact): a quarter of the pixels and of the kernel's area. The reduced blur softens a bokeh
rim by about a pixel, and the model's fill magnifies tiny coverage errors where an HDR background
lies behind (the fill there is the bright background times ``1 - cov``), so the threshold is set by
what the real estimated depth map of ``bench/render_bench.py`` keeps: against the exact path 12 px
gave 39.7 dB there (45-67 dB on the bench scene), 16 px 48 dB (45.5 dB on the bench scene, whose
HDR lights sit at 32 px). Measured and not used: a quarter resolution from 24 px (39 dB); blurring
only radiance up to the 8-bit white reduced and HDR highlights exactly (sharp rims, but the colour
and the coverage then take different blurs: a uniform colour brighter than white is no longer
uniform); the coverage exactly at full resolution (58 dB on the real depth map even from 4 px, but
the same mismatch, and its full-resolution blur costs most of what the reduction saves).
``FastRenderer(half_res_radius=None)`` keeps every layer exact. (Those figures are with the old fill,
FILL_DEPTH_TOLERANCE 1; with 2 the real depth map gives 59.2 dB at 16 px, 53.3 at 12, 47.1 at 8: see
docs/renderer.md.)"""
PUSH_PULL_NUMPY_BELOW = 16
"""Push-pull levels with a side below this many px are done in plain numpy (they are tiny, and
OpenCV's Python bindings read an (n <= 4, 1) array as a scalar)."""
SCALAR_LIKE_ROWS = 4
"""OpenCV's Python bindings take a 2-D array of shape (n, 1) with n <= this for a scalar."""
STRIPE_MIN_ROWS = 64
"""Frame-wide steps are split into row stripes of at least this many rows for the worker threads."""

# the cost model of a layer's rectangles, in ns, measured on the project's 2-core machine with one
# OpenCV thread (the constants only rank ways of cutting a layer; cost.py turns work into seconds)
RECT_NS = 40_000.0
"""Fixed cost of one rectangle: Python, ~15 OpenCV calls, the hand-off to a worker thread."""
CORE_NS = 6.0
"""Per source pixel of a rectangle: the matte and the premultiplied source."""
BOX_NS = 7.0
"""Per pixel of a rectangle's blurred footprint: compositing (model step 4)."""
UPSAMPLE_NS = 1.5
"""Per full-resolution pixel of a reduced rectangle's footprint: the bilinear upsampling."""
WORK_NS_PER_PX = 60.0
"""``FastRenderer.work_px`` reports the modelled cost in units of this many ns (one pixel of a
1080p layer box of the old one-box-per-layer path, so cost.S_PER_WORK_PX stays comparable)."""

def _overlapping(boxes: list[Box]) -> list[bool]:
    """For each box (y0, y1, x0, x1), whether it overlaps another of the list."""
    b = np.array(boxes, dtype=np.int64).reshape(-1, 4)
    hit = ((b[:, None, 0] < b[None, :, 1]) & (b[None, :, 0] < b[:, None, 1])
           & (b[:, None, 2] < b[None, :, 3]) & (b[None, :, 2] < b[:, None, 3]))
    np.fill_diagonal(hit, False)
    return hit.any(axis=1).tolist()


def _subtract_pieces(total: np.ndarray, touched: np.ndarray, pieces: list, tile: int) -> None:
    """Subtract a layer's visible coverage, (box, V) rectangles, from the frame-sized ``total``; mark
    the ``tile`` x ``tile`` tiles it reaches in ``touched``."""
    for (y0, y1, x0, x1), v in pieces:
        dst = total[y0:y1, x0:x1]
        cv2.subtract(dst, v, dst=dst)
        touched[y0 // tile:-(-y1 // tile), x0 // tile:-(-x1 // tile)] = True


def blur_ns_per_px(kernel_side: int, channels: int = 4) -> float:
    """Modelled ns per pixel of blurring ``channels`` float32 planes with a (k, k) kernel: directly
    (``cv2.filter2D``, ~0.04 k^2 ns a plane) below :data:`DFT_FROM_SIDE`, else by a DFT of the box
    (~9 ns a plane)."""
    if kernel_side <= 1:
        return 0.0
    if kernel_side < DFT_FROM_SIDE:
        return channels * (0.043 * kernel_side * kernel_side + 0.25)
    return channels * 9.0


@dataclass(frozen=True)
class BlurTask:
    """One rectangle of one layer: blur the radiance times the layer's matte, and the matte, over
    ``core`` with ``kernel`` (flipped; a :class:`ZoneKernels`; at 1 / ``factor`` of the
    resolution), giving the blurred footprint over ``box``."""

    j: int
    box: Box
    core: Box
    kernel: Any
    factor: int


@dataclass
class FastRenderer:
    """Renders frames with the fast tiled path; caches kernels and tile indices.

    tile: tile side in px for the activity map. max_step / min_layers: layer spacing (see
    :func:`.model.plan_layers`). naive: sum layers without occlusion (ablation only).
    half_res_radius: radius (px) from which layers are blurred at half resolution (None: never,
    the exact path).
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
    _spectra: "SpectrumCache" = field(default_factory=lambda: SpectrumCache(), repr=False)

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
        h, w = u.shape
        # the matte normaliser and the colour planes on the worker threads (in row stripes) while this
        # thread plans the layers' rectangles
        inv_norm = np.empty((h, w), np.float32)

        def normalise(rows: slice) -> None:
            cv2.divide(1.0, matte_normaliser_cv(u[rows], j_lo, j_hi), dst=inv_norm[rows])

        pending = [self._submit(normalise, rows) for rows in self._stripes(h)]
        pending.append(self._submit(cv2.split, radiance.astype(np.float32, copy=False)))
        active = self._active_layers(u, j_lo, j_hi)
        tasks = self._plan_tasks(plan, active, (h, w))[0]
        channels = [p.result() for p in pending][-1]
        # the fill's samples (model.fill_encode of the radiance) on a worker while the layers composite
        encoded = self._submit(lambda: [cv2.sqrt(cv2.max(c, 0.0)) for c in channels])
        acc = [np.zeros((h, w), dtype=np.float32) for _ in range(3 + self.naive)]  # sum T C (RGB) (step 4)
        left = np.ones((h, w), dtype=np.float32)  # 1 - H_j: H_j the sum of V_i over layers i <= j - S
        left_far = np.ones((h, w), dtype=np.float32)  # 1 - F_j: F_j over layers i < j - SURFACE_STEPS
        tl = self.tile
        touched = np.zeros((-(-h // tl), -(-w // tl)), bool)  # tiles where `left` may be < 1
        touched_far = np.zeros_like(touched)  # tiles where `left_far` may be < 1
        visible: deque = deque()  # (layer, [(box, V)]) not yet in `left`
        near: deque = deque()  # (layer, [(box, V)]) in `left`, not yet in `left_far`
        layer_w = np.zeros((h, w), dtype=np.float32)  # a layer's coverage W_j where its rectangles overlap
        spectra = self._spectra

        def blur(task: BlurTask):
            return task, blur_task(channels, u, inv_norm, task, spectra)

        # blurs run ahead on worker threads (OpenCV's filters are single-threaded and release the
        # GIL); compositing stays in front-to-back order on this thread, one layer's rectangles at a time
        for j, group in groupby(self._map_ordered(blur, tasks), key=lambda tp: tp[0].j):
            pieces = list(group)
            if self.naive:
                for task, planes in pieces:
                    y0, y1, x0, x1 = task.box
                    for a, p in zip(acc, planes):
                        dst = a[y0:y1, x0:x1]
                        cv2.add(dst, p, dst=dst)
                continue
            while visible and visible[0][0] <= j - OCCLUSION_DELAY:
                near.append(visible.popleft())
                _subtract_pieces(left, touched, near[-1][1], tl)
            while near and near[0][0] < j - SURFACE_STEPS:
                _subtract_pieces(left_far, touched_far, near.popleft()[1], tl)
            behind = [touched[y0 // tl:-(-y1 // tl), x0 // tl:-(-x1 // tl)].any()
                      for y0, y1, x0, x1 in (task.box for task, _ in pieces)]
            shared = _overlapping([task.box for task, _ in pieces]) if any(behind) else [False] * len(pieces)
            if any(shared):
                # T_j needs the layer's whole coverage W_j at each pixel: where its rectangles overlap, their sum
                for (task, planes), sh in zip(pieces, shared):
                    if sh:
                        y0, y1, x0, x1 = task.box
                        layer_w[y0:y1, x0:x1] = 0.0
                for (task, planes), sh in zip(pieces, shared):
                    if sh:
                        y0, y1, x0, x1 = task.box
                        dst = layer_w[y0:y1, x0:x1]
                        cv2.add(dst, planes[3], dst=dst)
            seen = []  # (box, V) of this layer's rectangles
            for (task, planes), front, sh in zip(pieces, behind, shared):
                y0, y1, x0, x1 = task.box
                if not front:  # nothing in front: T = 1
                    for a, p in zip(acc, planes):
                        dst = a[y0:y1, x0:x1]
                        cv2.add(dst, p, dst=dst)
                    seen.append((task.box, planes[3]))
                    continue
                # model.visible_fraction: T = max(min(1 - F, (1 - H) / max(W, WEIGHT_EPS)), 0) (1 - H and 1 - F
                # are >= 0 up to rounding, which the clamp at 0 takes out)
                t = cv2.divide(left[y0:y1, x0:x1], cv2.max(layer_w[y0:y1, x0:x1] if sh else planes[3], WEIGHT_EPS))
                far_box = left_far[y0:y1, x0:x1] if touched_far[y0 // tl:-(-y1 // tl), x0 // tl:-(-x1 // tl)].any() else 1.0
                cv2.min(t, far_box, dst=t)
                cv2.max(t, 0.0, dst=t)
                for a, p in zip(acc, planes):
                    cv2.accumulateProduct(p, t, a[y0:y1, x0:x1])
                seen.append((task.box, cv2.multiply(t, planes[3])))
            visible.append((j, seen))
        if self.naive:
            cov = acc.pop()
        else:  # cov = sum V = 1 - left once every layer is in it
            while visible:
                _subtract_pieces(left, touched, visible.popleft()[1], tl)
            cov = cv2.subtract(1.0, left)
        # model step 5: out = acc / max(cov, 1) + (1 - min(cov, 1)) * fill (acc: the RGB sums now)
        weight = cv2.min(cov, 1.0)
        # model.fill_weight: a coverage within COVERAGE_SNAP of 1 is 1 (rounding, not an uncovered pixel)
        weight = cv2.max(weight, cv2.threshold(weight, 1.0 - COVERAGE_SNAP, 1.0, cv2.THRESH_BINARY)[1])
        fill = fill_level1_cv(encoded.result(), weight, u, pmap=self._map)
        scale = cv2.divide(1.0, cv2.max(cov, 1.0))
        rest = cv2.subtract(1.0, weight)
        size = (2 * fill.shape[1], 2 * fill.shape[0])

        def resolve(af) -> np.ndarray:
            a, f = af
            f = cv2.resize(f, size, interpolation=cv2.INTER_LINEAR)[:h, :w]
            return cv2.add(cv2.multiply(a, scale), cv2.multiply(cv2.multiply(f, f), rest))  # model.fill_decode

        return cv2.merge(self._map(resolve, list(zip(acc, cv2.split(fill)))))

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
        radiance = hdr_radiance(image_to_linear(image), hdr_exponent)
        return linear_to_srgb(self.render_linear(radiance, disparity, focus, aperture))

    def work_px(self, disparity: np.ndarray, focus: float, aperture: float) -> int:
        """How much work a frame is, in px-equivalents (:data:`WORK_NS_PER_PX` of modelled cost
        each): every layer's rectangles (active tiles grown by the blur's footprint), weighted by
        what blurring and compositing them costs (:func:`layer_rects`). Cheap next to a render;
        :mod:`.cost` turns it into seconds.

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
        _, cost_ns = self._plan_tasks(plan, active, u.shape)
        return max(int(round(cost_ns / WORK_NS_PER_PX)), 1)

    # -- internals ------------------------------------------------------------------------
    def _plan_tasks(self, plan: LayerPlan, active: np.ndarray,
                    shape: tuple[int, int]) -> tuple[list[BlurTask], float]:
        """The blur tasks of a frame, front to back, and their modelled cost (ns).

        active: (L, ty, tx) tiles per layer (:meth:`_active_layers`)."""
        h, w = shape
        j_lo = int(plan.indices.min())
        zones = (zone_edges(h, self.spec.zones), zone_edges(w, self.spec.zones)) if self.spec.varies else None
        tasks: list[BlurTask] = []
        total = 0.0
        for j in plan.indices[::-1]:  # front to back (model step 4)
            j = int(j)
            tiles = active[j - j_lo]
            if not tiles.any():
                continue
            radius = abs(float(j) * plan.step)
            kernel = self._kernel(radius)
            side = kernel.shape[0]
            factor = self._reduction(radius) if zones is None and side > 1 else 1
            small = self._kernel(radius / factor) if factor > 1 else None
            if small is not None and small.size > 1:
                kernel, half = small, (small.shape[0] // 2 + 1) * factor  # + 1: the bilinear upsampling's support
                box_ns = BOX_NS + UPSAMPLE_NS + blur_ns_per_px(small.shape[0]) / factor ** 2
            else:
                factor, half, box_ns = 1, side // 2, BOX_NS + blur_ns_per_px(side)
                if zones is not None and side > 1:
                    kernel = ZoneKernels(*zones, [[self._kernel(radius, (zy, zx)) for zx in range(self.spec.zones)]
                                                  for zy in range(self.spec.zones)])
            rects, cost = layer_rects(tiles, self.tile, half, shape, box_ns, CORE_NS, align=factor)
            total += cost
            tasks.extend(BlurTask(j, box, core, kernel, factor) for box, core in rects)
        return tasks, total

    def _submit(self, fn, *args):
        """A future of fn(*args): on a worker thread, or computed at once with one thread."""
        if self.threads <= 1:
            done: Future = Future()
            done.set_result(fn(*args))
            return done
        if self._pool is None:
            self._pool = ThreadPoolExecutor(self.threads, thread_name_prefix="rvr-blur")
        return self._pool.submit(fn, *args)

    def _map(self, fn, items: list) -> list:
        """[fn(item) for item in items], spread over the worker threads."""
        return [f.result() for f in [self._submit(fn, item) for item in items]]

    def _stripes(self, h: int) -> list[slice]:
        """Row stripes (even heights) that split an (h, ...) frame between the worker threads."""
        n = max(min(self.threads, h // STRIPE_MIN_ROWS), 1)
        edges = [min(2 * (-(-h * k // (2 * n))), h) for k in range(n + 1)]
        return [slice(a, b) for a, b in zip(edges[:-1], edges[1:]) if b > a]

    def _map_ordered(self, fn, items: list, ahead: int = 6):
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
        """Resolution divisor (1 or 2) a layer of blur ``radius`` px is blurred at."""
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


BAND_TILES = ((1, 4, 16, 1 << 30), (4, 16))
"""Band heights (tiles) :func:`layer_rects` tries along rows and along columns (``1 << 30``: one
band, the whole layer). More choices found layouts only a few % cheaper (bench scene and real depth)
for twice the planning time."""


def layer_rects(tiles: np.ndarray, tile: int, half: int, shape: tuple[int, int], box_ns: float,
                core_ns: float = CORE_NS, align: int = 1) -> tuple[list[tuple[Box, Box]], float]:
    """(box, core) pixel rectangles covering one layer's active tiles, and their modelled cost (ns).

    ``core`` bounds a group of active tiles (every source pixel of the layer lies in exactly one
    core); ``box`` is the core grown by ``half`` px and clipped to ``shape`` (H, W), so it holds the
    group's whole blurred footprint (boxes may overlap). ``align``: the box's edges fall on
    multiples of it (the grid of a reduced blur; ``half`` is a multiple of it). The layer is cut
    into bands of a few tile rows (or columns) and each band into runs of active tiles, runs closer
    than the footprint merged; the band height and direction of least modelled cost win:
    ``RECT_NS`` a rectangle + ``core_ns`` a core pixel + ``box_ns`` a box pixel.
    """
    h, w = shape
    gap = max(int(2 * half // tile), 0)
    best = None
    for transposed, heights in zip((False, True), BAND_TILES):
        t = tiles.T if transposed else tiles
        n = t.shape[0]
        tried = set()
        for b in heights:
            b = min(b, n)
            if b in tried:
                continue
            tried.add(b)
            r0, r1, c0, c1 = _band_runs(t, b, gap)
            if transposed:
                r0, r1, c0, c1 = c0, c1, r0, r1
            rects = _rect_pixels(r0, r1, c0, c1, tile, half, h, w, align)
            cy0, cy1, cx0, cx1, y0, y1, x0, x1 = rects
            cost = (RECT_NS * len(cy0) + core_ns * float(((cy1 - cy0) * (cx1 - cx0)).sum())
                    + box_ns * float(((y1 - y0) * (x1 - x0)).sum()))
            if best is None or cost < best[0]:
                best = (cost, rects)
    cost, (cy0, cy1, cx0, cx1, y0, y1, x0, x1) = best
    out = [((int(a), int(b), int(c), int(d)), (int(e), int(f), int(g), int(k)))
           for a, b, c, d, e, f, g, k in zip(y0, y1, x0, x1, cy0, cy1, cx0, cx1)]
    return out, cost


def _band_runs(t: np.ndarray, b: int, gap: int) -> tuple[np.ndarray, ...]:
    """Tile rectangles [r0, r1) x [c0, c1) of ``t`` (n, m) bool cut into bands of ``b`` rows, each
    band into runs of active columns (runs at most ``gap`` tiles apart merged); rows shrunk to the
    run's active ones."""
    n, m = t.shape
    nb = -(-n // b)
    if nb * b != n:
        t = np.concatenate([t, np.zeros((nb * b - n, m), bool)])
    t3 = t.reshape(nb, b, m)
    col = t3.any(axis=1)
    edge = np.zeros((nb, 1), np.int8)
    d = np.diff(np.concatenate([edge, col.view(np.int8), edge], axis=1), axis=1)
    band, c0 = np.nonzero(d == 1)
    c1 = np.nonzero(d == -1)[1]
    if band.size > 1 and gap > 0:
        join = (band[1:] == band[:-1]) & (c0[1:] - c1[:-1] <= gap)
        if join.any():
            first = np.concatenate([[True], ~join])
            last = np.concatenate([~join, [True]])
            band, c0, c1 = band[first], c0[first], c1[last]
    if b == 1:
        return band, band + 1, c0, c1
    prefix = np.zeros((nb, b, m + 1), np.int32)
    np.cumsum(t3, axis=2, out=prefix[:, :, 1:])
    rows = (prefix[band, :, c1] - prefix[band, :, c0]) > 0  # (runs, b): the run's active rows
    r0 = band * b + rows.argmax(axis=1)
    r1 = band * b + b - rows[:, ::-1].argmax(axis=1)
    return r0, r1, c0, c1


def _rect_pixels(r0, r1, c0, c1, tile: int, half: int, h: int, w: int, align: int):
    """Tile rectangles -> pixel cores and boxes (the cores grown by ``half``, clipped, box edges on
    multiples of ``align``): eight int arrays cy0, cy1, cx0, cx1, y0, y1, x0, x1."""
    cy0, cy1 = r0 * tile, np.minimum(r1 * tile, h)
    cx0, cx1 = c0 * tile, np.minimum(c1 * tile, w)
    y0, x0 = np.maximum((cy0 - half) // align * align, 0), np.maximum((cx0 - half) // align * align, 0)
    y1 = np.minimum(-(-(cy1 + half) // align) * align, h)
    x1 = np.minimum(-(-(cx1 + half) // align) * align, w)
    return cy0, cy1, cx0, cx1, y0, y1, x0, x1


def blur_task(planes: list, u: np.ndarray, inv_norm: np.ndarray, task: BlurTask,
              spectra: "SpectrumCache | None" = None) -> list:
    """The four blurred planes [R, G, B, W] (each (box h, box w) float32) of one task (model
    step 3): the radiance planes times the layer's matte, and the matte itself (the coverage).

    planes: the frame's (H, W) float32 radiance planes. The matte is the normalised ``M_j``
    (``inv_norm``: the reciprocal matte normaliser); sources are the pixels of the core (the task's
    other rectangles hold the rest); the kernel is already flipped for correlation; zero outside the
    frame. A reduced task (``factor`` > 1) is area-averaged onto the frame's grid of factor x factor
    cells, blurred with the kernel of radius / factor and upsampled bilinearly. The sources are
    written straight into the blur's (zero) input buffers (:func:`blur_core_planes`).
    """
    y0, y1, x0, x1 = task.box
    cy0, cy1, cx0, cx1 = task.core
    alpha = cv2.multiply(_matte_cv(u[cy0:cy1, cx0:cx1], float(task.j)), inv_norm[cy0:cy1, cx0:cx1])
    if isinstance(task.kernel, ZoneKernels):
        cores = [cv2.multiply(p[cy0:cy1, cx0:cx1], alpha) for p in planes] + [alpha]
        return cv2.split(_blur_by_zones(cv2.merge(cores), task.kernel, task.box, task.core))
    f = task.factor
    if f == 1:
        def sources(bufs):  # the premultiplied radiance and the matte, into the core's views
            cv2.copyTo(alpha, None, bufs[3])
            for p, b in zip(planes, bufs):
                cv2.multiply(p[cy0:cy1, cx0:cx1], alpha, dst=b)
        return blur_core_planes(sources, 4, (cy0 - y0, cx0 - x0), (cy1 - cy0, cx1 - cx0), (y1 - y0, x1 - x0),
                                task.kernel, spectra)
    gy0, gy1, gx0, gx1 = cy0 // f, -(-cy1 // f), cx0 // f, -(-cx1 // f)  # the core's cells
    ly0, ly1, lx0, lx1 = y0 // f, -(-y1 // f), x0 // f, -(-x1 // f)  # the box's cells
    aligned = (cy0, cx0, cy1, cx1) == (gy0 * f, gx0 * f, gy1 * f, gx1 * f)
    cells = (gx1 - gx0, gy1 - gy0)
    cores = [cv2.multiply(p[cy0:cy1, cx0:cx1], alpha) for p in planes] + [alpha]

    def reduced(bufs):  # the area means of the core's cells, into the core's views
        for c, b in zip(cores, bufs):
            if not aligned:
                full = np.zeros(((gy1 - gy0) * f, (gx1 - gx0) * f), np.float32)
                full[cy0 - gy0 * f:cy1 - gy0 * f, cx0 - gx0 * f:cx1 - gx0 * f] = c
                c = full
            cv2.resize(c, cells, dst=b, interpolation=cv2.INTER_AREA)
    small = blur_core_planes(reduced, 4, (gy0 - ly0, gx0 - lx0), (gy1 - gy0, gx1 - gx0), (ly1 - ly0, lx1 - lx0),
                             task.kernel, spectra)
    size = ((lx1 - lx0) * f, (ly1 - ly0) * f)
    return [cv2.resize(s, size, interpolation=cv2.INTER_LINEAR)[:y1 - y0, :x1 - x0] for s in small]


def blur_core_planes(write, n: int, offset: tuple[int, int], core_shape: tuple[int, int],
                     box_shape: tuple[int, int], kernel: np.ndarray, spectra: "SpectrumCache | None" = None) -> list:
    """Blur ``n`` planes that are zero outside one core: ``write(views)`` fills the n (core h,
    core w) float32 views with the sources, placed at ``offset`` (row, column) of a (box h, box w)
    zero box; returns the n blurred (box h, box w) planes (``cv2.filter2D`` with BORDER_CONSTANT and
    the flipped ``kernel``, :func:`blur_planes`' values).

    The sources are written straight into the blur's input buffers. A DFT blur's period is the
    core grown by the kernel's half width on one side and by the larger box margin on the other (at
    least the box; the box itself where no side is clipped): the least that keeps the circular
    convolution from wrapping a source's footprint back into the box."""
    (oy, ox), (ch, cw), (h, w) = offset, core_shape, box_shape
    side = kernel.shape[0]
    half = side // 2
    if side <= 1:  # a delta: the box is the core
        bufs = [np.empty((ch, cw), np.float32) for _ in range(n)]
        write(bufs)
        if (ch, cw) == (h, w):
            return bufs
        return [cv2.copyMakeBorder(b, oy, h - oy - ch, ox, w - ox - cw, cv2.BORDER_CONSTANT, value=0) for b in bufs]
    if spectra is None or side < DFT_FROM_SIDE or min(h, w) <= side:
        bufs = [np.zeros((h, w), np.float32) for _ in range(n)]
        write([b[oy:oy + ch, ox:ox + cw] for b in bufs])
        return [cv2.filter2D(b, -1, kernel, borderType=cv2.BORDER_CONSTANT) for b in bufs]
    hh = cv2.getOptimalDFTSize(max(h, ch + half + max(oy, h - oy - ch)))
    ww = cv2.getOptimalDFTSize(max(w, cw + half + max(ox, w - ox - cw)))
    spectrum = spectra.get(kernel, hh, ww)
    bufs = [np.zeros((hh, ww), np.float32) for _ in range(n)]
    write([b[oy:oy + ch, ox:ox + cw] for b in bufs])
    out = []
    for b in bufs:
        spec = cv2.mulSpectrums(cv2.dft(b, nonzeroRows=oy + ch), spectrum, 0)
        out.append(cv2.idft(spec, flags=cv2.DFT_SCALE | cv2.DFT_REAL_OUTPUT, nonzeroRows=h)[:h, :w])
    return out


DFT_FROM_SIDE = 11
"""Kernels of at least this side are applied by a DFT of the box (:class:`SpectrumCache`), smaller
ones by ``cv2.filter2D`` directly (measured: a DFT costs 5-10 ns a pixel and channel with the
kernel's spectrum cached, about half of filter2D's own DFT, which recomputes it and which filter2D
itself switches to from 11 x 11; the direct filter costs ~0.04 k^2 ns). 15 before: on the 1080p
frames of ``bench/render_bench.py`` 11 takes 2-3 % less CPU (9 no less than 11)."""


class SpectrumCache:
    """Kernel spectra (OpenCV's packed real DFT) by (kernel, DFT height, DFT width), up to
    ``max_bytes``; shared by the worker threads (a race only computes a spectrum twice)."""

    def __init__(self, max_bytes: int = 256 << 20) -> None:
        self.max_bytes = max_bytes
        self._spectra: dict = {}
        self._bytes = 0

    def get(self, kernel: np.ndarray, hh: int, ww: int) -> np.ndarray:
        """The spectrum of the (unflipped) PSF of ``kernel`` (flipped, odd square) centred at
        (0, 0) of an (hh, ww) periodic frame."""
        key = (id(kernel), hh, ww)
        got = self._spectra.get(key)
        if got is None:
            half = kernel.shape[0] // 2
            psf = kernel[::-1, ::-1]
            padded = np.zeros((hh, ww), np.float32)
            padded[:half + 1, :half + 1] = psf[half:, half:]
            padded[:half + 1, ww - half:] = psf[half:, :half]
            padded[hh - half:, :half + 1] = psf[:half, half:]
            padded[hh - half:, ww - half:] = psf[:half, :half]
            got = cv2.dft(padded)
            if self._bytes + got.nbytes > self.max_bytes:
                self._spectra.clear()
                self._bytes = 0
            self._spectra[key] = got
            self._bytes += got.nbytes
        return got


def blur_planes(img: np.ndarray, kernel: np.ndarray, spectra: SpectrumCache | None = None) -> np.ndarray:
    """``cv2.filter2D(img, -1, kernel, borderType=BORDER_CONSTANT)``: (h, w) or (h, w, C) float32;
    ``kernel`` flipped. Large kernels by a periodic DFT blur over (h + half, w + half) at least (so
    nothing wraps around into the box)."""
    side = kernel.shape[0]
    if side <= 1:
        return img
    if spectra is None or side < DFT_FROM_SIDE or min(img.shape[:2]) <= side:
        return cv2.filter2D(img, -1, kernel, borderType=cv2.BORDER_CONSTANT)
    h, w = img.shape[:2]
    half = side // 2
    hh, ww = cv2.getOptimalDFTSize(h + half), cv2.getOptimalDFTSize(w + half)
    spectrum = spectra.get(kernel, hh, ww)
    planes = [img] if img.ndim == 2 else cv2.split(img)
    out = []
    for p in planes:
        if hh != h or ww != w:
            p = cv2.copyMakeBorder(p, 0, hh - h, 0, ww - w, cv2.BORDER_CONSTANT, value=0)
        spec = cv2.mulSpectrums(cv2.dft(p, nonzeroRows=h), spectrum, 0)
        out.append(cv2.idft(spec, flags=cv2.DFT_SCALE | cv2.DFT_REAL_OUTPUT, nonzeroRows=h)[:h, :w])
    return out[0] if img.ndim == 2 else cv2.merge(out)


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


def fill_level1_cv(channels: list, weight: np.ndarray, depth: np.ndarray, pmap=None) -> np.ndarray:
    """Level 1 (half resolution, (ceil(H/2), ceil(W/2), 3)) of the push-pull of
    :func:`.model.push_pull_fill`, in the colour domain given (the callers pass
    ``model.fill_encode`` of the radiance, upsample bilinearly 2x, crop to (H, W) and decode).

    channels: the three (H, W) float32 colour planes; weight, depth: (H, W) float32. Depths
    are handled as ``y = kappa * z`` (a depth factor is then one exp of ``min(y - y_ref +
    kappa * tolerance, 0)``). Levels with a side below PUSH_PULL_NUMPY_BELOW use the model's
    numpy code. pmap: a ``map`` returning a list (the renderer's worker threads) for the first
    step's per-plane work.
    """
    if min(weight.shape) < PUSH_PULL_NUMPY_BELOW:
        f, _ = push_pull_levels(cv2.merge(channels), weight, depth, down_to=1)
        return f.astype(np.float32)
    c, w, y = _pull0_cv(channels, weight, cv2.multiply(depth, FILL_DEPTH_SHARPNESS), pmap or _list_map)
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


def _list_map(fn, items) -> list:
    return [fn(x) for x in items]


def _pull0_cv(channels: list, w: np.ndarray, y: np.ndarray, pmap=_list_map):
    """The first pull step, from separate colour planes (no interleaved copies); ``pmap`` maps the
    per-plane block means."""
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
    # the block means of x * e for the colour planes and the depth, and of e itself (None)
    means = pmap(lambda x: cv2.resize(e if x is None else cv2.multiply(x, e), size, interpolation=area),
                 [*channels, y, None])
    se = means.pop()
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
