"""The estimator without torch: the exported trunk (``weights/estimator.onnx``, ONNX Runtime) and
the rest of :meth:`EstimatorNet.forward <rvr_addon.estimate.unet.EstimatorNet.forward>` in numpy:
replicate padding to the stride, the grid's soft bound, bilateral slicing by the guide's luma
(the conventions of :mod:`.bilateral`: cell-centred space with border clamping, node-centred
luma bins), E = E_max * sigmoid(logits) resampled bilinearly (``align_corners=False``, as
``F.interpolate``) and gated. ``tests/engine/test_onnx.py`` bounds the difference to torch.
"""
from __future__ import annotations

import math

import numpy as np

LEAK_BOUND = 0.01
"""The soft bound's linear share (``unet.BOUND_LEAK``)."""
DISPARITY_PERCENT = 100.0
"""D_rel = 1 is a radius of (frame long side / DISPARITY_PERCENT) px (``unet.DISPARITY_PERCENT``)."""
LUMA = np.array([0.2126, 0.7152, 0.0722], np.float32)


class OnnxEstimatorNet:
    """The estimator network as an ONNX graph plus numpy (the ``net`` of an ONNX LoadedModel)."""

    def __init__(self, graph, config: dict) -> None:
        from ..render.model import K_HDR

        self.graph = graph
        self.config = dict(config)
        self.unshuffle = int(config.get("unshuffle", 4))
        widths = config.get("widths", (48, 96, 160, 256))
        self.stride = self.unshuffle * 2 ** (len(widths) - 1)
        self.bins = int(config.get("grid_bins", 8))
        self.max_disparity = float(config.get("max_disparity", 25.0))
        self.e_max = math.log(float(config.get("max_gain", 1000.0))) / K_HDR
        self.gate_lo, self.gate_hi = float(config.get("gate_lo", 0.9)), float(config.get("gate_hi", 0.98))
        self.row_weights = None
        if config.get("row_prior"):  # the row column of the grid head, added here (rvr_addon.onnx_export)
            meta = getattr(graph, "meta", {}) or {}
            if "rvr_row_weights" not in meta:
                raise ValueError("this ONNX export of an estimator with row_prior lacks rvr_row_weights; re-export it "
                                 "with scripts/export_onnx.py, or use torch")
            import json

            self.row_weights = np.asarray(json.loads(meta["rvr_row_weights"]), np.float32) * float(
                config.get("head_gain", 10.0))

    def __call__(self, srgb: np.ndarray, guide: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """srgb: (h, w, 3) float32 in [0, 1] (the network's view); guide: (H, W, 3) float32 sRGB of the
        same frame at the output size (None: srgb). Returns (D_rel (H, W), E (H, W, 3)) float32."""
        import cv2

        guide = srgb if guide is None else guide
        h, w = srgb.shape[:2]
        s = self.stride
        hp, wp = math.ceil(h / s) * s, math.ceil(w / s) * s
        x = np.pad(srgb, ((0, hp - h), (0, wp - w), (0, 0)), mode="edge") if (hp, wp) != (h, w) else srgb
        x = np.ascontiguousarray(x.transpose(2, 0, 1)[None], dtype=np.float32)
        grid, e_logits = self.graph.run({"srgb": x})
        if self.row_weights is not None:  # unet._row_coordinate: -1 at the image's top edge, +1 at its bottom
            hg = grid.shape[2]
            rows = ((np.arange(hg, dtype=np.float32) + 0.5) / (hg * (h / hp)) * 2.0 - 1.0).astype(np.float32)
            grid = grid + self.row_weights[None, :, None, None] * rows[None, None, :, None]
        m = self.max_disparity
        grid = (m * np.tanh(grid[0] / m) + LEAK_BOUND * grid[0]).astype(np.float32)
        d_rel = bilateral_slice(grid, luma(guide), (h / hp, w / wp))
        e = (self.e_max / (1.0 + np.exp(-e_logits[0].astype(np.float32)))).astype(np.float32).transpose(1, 2, 0)
        e = cv2.resize(np.ascontiguousarray(e), (wp, hp), interpolation=cv2.INTER_LINEAR)[:h, :w]
        if guide.shape[:2] != (h, w):
            e = cv2.resize(np.ascontiguousarray(e), (guide.shape[1], guide.shape[0]), interpolation=cv2.INTER_LINEAR)
        return d_rel, (e * clip_gate(guide, self.gate_lo, self.gate_hi)[..., None]).astype(np.float32)


def luma(srgb: np.ndarray) -> np.ndarray:
    """Rec. 709 luma (H, W) of sRGB-encoded (H, W, 3) float32 (``bilateral.luma``)."""
    return (srgb[..., 0] * LUMA[0] + srgb[..., 1] * LUMA[1] + srgb[..., 2] * LUMA[2]).astype(np.float32)


def clip_gate(srgb: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """Soft mask (H, W) of clipped pixels: smoothstep(lo, hi, max over RGB) (``unet.clip_gate``)."""
    t = np.clip((srgb.max(axis=2) - lo) / (hi - lo), 0.0, 1.0)
    return (t * t * (3.0 - 2.0 * t)).astype(np.float32)


def _axis(n_out: int, n_grid: int, extent: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cell-centred sample positions of n_out pixels over ``extent`` of n_grid cells, border-clamped:
    (lower index, upper index, upper weight)."""
    g = (np.arange(n_out, dtype=np.float32) + 0.5) * np.float32(extent * n_grid / n_out) - 0.5
    g = np.clip(g, 0.0, n_grid - 1)
    i0 = np.minimum(np.floor(g).astype(np.int64), max(n_grid - 2, 0))
    return i0, np.minimum(i0 + 1, n_grid - 1), (g - i0).astype(np.float32)


def bilateral_slice(grid: np.ndarray, guide: np.ndarray, extent: tuple[float, float] = (1.0, 1.0)) -> np.ndarray:
    """Slice a one-channel bilateral grid (D, Hg, Wg) at every pixel of the luma guide (H, W) in
    [0, 1] (clamped); extent as in :func:`.bilateral.bilateral_slice`. Returns (H, W) float32."""
    import cv2

    depth, hg, wg = grid.shape
    h, w = guide.shape
    if depth <= 512:
        # sampling at the cell-centred positions is a bilinear resize of the grid by the factor
        # (frame px per cell) given as fx/fy, so OpenCV maps pixel x to cell (x + 0.5) / fx - 0.5
        # exactly (and clamps at the border, as grid_sample's border mode); the frame is the
        # resized grid's top-left corner
        cells = np.ascontiguousarray(grid.transpose(1, 2, 0), dtype=np.float32)
        fx, fy = w / (extent[1] * wg), h / (extent[0] * hg)
        space = cv2.resize(cells, (0, 0), fx=fx, fy=fy, interpolation=cv2.INTER_LINEAR)
        space = space.reshape(space.shape[0], space.shape[1], depth)[:h, :w]  # (H, W, D)
    else:
        y0, y1, wy = _axis(h, hg, extent[0])
        x0, x1, wx = _axis(w, wg, extent[1])
        rows = grid[:, y0, :] * (1.0 - wy)[None, :, None] + grid[:, y1, :] * wy[None, :, None]  # (D, H, Wg)
        space = (rows[:, :, x0] * (1.0 - wx) + rows[:, :, x1] * wx).transpose(1, 2, 0)  # (H, W, D)
    z = np.clip(guide, 0.0, 1.0) * np.float32(depth - 1)
    k0 = np.minimum(z.astype(np.int64), depth - 2)
    wz = (z - k0).astype(np.float32)
    lo = np.take_along_axis(space, k0[..., None], 2)[..., 0]
    hi = np.take_along_axis(space, k0[..., None] + 1, 2)[..., 0]
    return (lo + (hi - lo) * wz).astype(np.float32)
