"""The renderer on a torch device (CUDA when a GPU is present), and the ``--device`` choice.

Same forward model as :mod:`.model` (and :mod:`.fast`, :mod:`.torch_render`): soft layer
mattes, per-layer aperture blur, front-to-back compositing with delayed occlusion, resolved
by the coverage with the depth-aware push-pull fill. Inference only (no autograd), float32.
Unlike the fast CPU path nothing is skipped by tiles: every active layer is blurred over the
whole frame, and the layers are blurred together, a batch of them in one FFT (their kernels
zero-padded to the batch's largest), as many per batch as ``batch_mb`` allows. Every blur is
exact (no half-resolution layers), so this equals ``FastRenderer(half_res_radius=None)`` up
to float32 rounding. float16 is not used: HDR radiance ``exp(50 E)`` and the FFT's sums
overflow or lose the 40 dB it must keep, and cuFFT takes half precision only at power-of-two
sizes.

The mattes, compositing order and fill are those of :mod:`.torch_render` (the training
renderer), whose functions this module calls. torch is imported only when a torch renderer
is made: the Blender extension (no torch) imports this module and always gets the fast path.

Device names: ``auto`` = ``cuda`` when ``torch.cuda.is_available()``, else the fast CPU
renderer; ``cpu`` = the fast CPU renderer (:class:`.fast.FastRenderer`); ``cuda`` = this
renderer on the GPU, an :class:`~rvr_addon.errors.InputError` naming the flag where there is
none. :class:`TorchRenderer` with ``device="cpu"`` (torch on the CPU) is what the tests
compare with the fast path on machines without a GPU.
"""
from __future__ import annotations

import os
import sys
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..color import image_to_linear, linear_to_srgb
from ..errors import InputError
from . import DEVICES
from .aperture import ApertureSpec, kernel_half_size, make_kernel
from .fast import FastRenderer, check_frame_inputs
from .model import (
    MATTE_OFFSETS,
    OCCLUSION_DELAY,
    SURFACE_STEPS,
    LayerPlan,
    fill_weight,
    hdr_radiance,
    matte_unnormalised,
    max_blur_radius,
    plan_layers,
    visible_fraction,
)

CPU_BATCH_MB = 256
"""Default memory for one batch of layers with torch on the CPU, MB."""
CUDA_BATCH_FRACTION = 0.25
"""Default share of the GPU's free memory one batch of layers may take."""
BYTES_PER_LAYER_PX = 7 * 4 * 4
"""Float32 bytes one layer of a batch needs per (FFT-padded) pixel, an upper bound: 4 channels
(colour, matte) each of the matted layer, its copy into the FFT, the spectrum (half the width,
complex), the inverse transform, the blurred layer, and the slack of the allocator."""
GPU_NODES = ("/dev/nvidiactl", "/dev/dxg")
"""Device nodes of the NVIDIA driver on Linux and of WSL2's GPU; without one, CUDA cannot be there."""
DELTA_TOLERANCE = 1e-6
"""A kernel with one tap above 1 - this (and the rest below this) is a delta: the layer is copied."""


def torch_cuda_available() -> bool:
    """True when torch is installed and sees a CUDA GPU. On Linux without a GPU device node
    (``GPU_NODES``) this is False without importing torch (a second of start-up saved)."""
    if ("torch" not in sys.modules and sys.platform.startswith("linux")
            and not any(os.path.exists(node) for node in GPU_NODES)):
        return False
    try:
        import torch
    except ImportError:
        return False
    return bool(torch.cuda.is_available())


def resolve_device(device: str = "auto", flag: str = "--device") -> str:
    """``auto`` / ``cpu`` / ``cuda`` -> ``"cpu"`` or ``"cuda"``.

    Raises InputError for an unknown name, or for ``cuda`` where torch has no GPU (the message
    names ``flag`` and the fix)."""
    if device not in DEVICES:
        raise InputError(f"{flag} {device!r}: use one of {', '.join(DEVICES)}")
    if device == "auto":
        return "cuda" if torch_cuda_available() else "cpu"
    if device == "cuda" and not torch_cuda_available():
        try:
            import torch

            why = (f"torch {torch.__version__} sees no CUDA GPU"
                   + (" (a CPU-only build)" if torch.version.cuda is None else ""))
        except ImportError:
            why = "torch is not installed"
        raise InputError(f"{flag} cuda: {why}; use {flag} cpu (or auto, the default, which uses the GPU "
                         "only when there is one), or install a CUDA build of torch on a machine with an "
                         "NVIDIA GPU")
    return device


def make_renderer(device: str = "auto", *, spec: ApertureSpec | None = None, naive: bool = False,
                  max_step: float = 1.0, min_layers: int = 1, threads: int | None = None,
                  flag: str = "--device") -> Any:
    """The renderer for ``device`` (see :func:`resolve_device`): a :class:`.fast.FastRenderer` on
    the CPU, a :class:`TorchRenderer` on CUDA. Both have ``render_linear`` / ``render_srgb``.
    threads: the CPU renderer's blur threads (None: its default, up to 4)."""
    spec = spec or ApertureSpec()
    if resolve_device(device, flag) == "cuda":
        return TorchRenderer(spec=spec, naive=naive, max_step=max_step, min_layers=min_layers, device="cuda")
    extra = {} if threads is None else {"threads": int(threads)}
    return FastRenderer(spec=spec, naive=naive, max_step=max_step, min_layers=min_layers, **extra)


def fft_size(n: int) -> int:
    """The smallest 5-smooth number (2^a 3^b 5^c) >= n: a length every FFT library is fast at."""
    best = 1 << max(n - 1, 0).bit_length()
    p5 = 1
    while p5 < best:
        p35 = p5
        while p35 < best:
            p = p35
            while p < n:
                p *= 2
            best = min(best, p)
            p35 *= 3
        p5 *= 5
    return best


def is_delta(kernel: np.ndarray) -> bool:
    """True when ``kernel`` is (numerically) a unit impulse at its centre."""
    c = kernel.shape[0] // 2
    return bool(kernel[c, c] > 1.0 - DELTA_TOLERANCE and np.count_nonzero(kernel > DELTA_TOLERANCE) == 1)


@dataclass
class TorchRenderer:
    """Renders frames with torch on ``device`` ("cuda", "cuda:1", "cpu"); no autograd, float32.

    spec / naive / max_step / min_layers: as :class:`.fast.FastRenderer`. batch_mb: memory for
    one batch of layers blurred together, MB (None: a quarter of the GPU's free memory, or
    ``CPU_BATCH_MB`` on the CPU); a batch always holds at least one layer.
    """

    spec: ApertureSpec = field(default_factory=ApertureSpec)
    max_step: float = 1.0
    min_layers: int = 1
    naive: bool = False
    device: str = "cuda"
    batch_mb: float | None = None
    _kernels: dict = field(default_factory=dict, repr=False)

    # -- public -------------------------------------------------------------------------
    def render_linear(self, radiance: np.ndarray, disparity: np.ndarray, focus: float, aperture: float,
                      plan: LayerPlan | None = None) -> np.ndarray:
        """Shallow-DOF linear radiance (H, W, 3) float32 (arguments as ``FastRenderer.render_linear``:
        radiance (H, W, 3) linear HDR, disparity (H, W) px of blur radius at aperture 1, focus in
        disparity units, aperture scale >= 0)."""
        check_frame_inputs(radiance, disparity, focus, aperture)
        if aperture == 0:
            return radiance.astype(np.float32, copy=True)
        import torch

        dev = torch.device(self.device)
        with torch.inference_mode():
            rad = torch.from_numpy(np.ascontiguousarray(radiance, dtype=np.float32)).to(dev).permute(2, 0, 1)
            d = torch.from_numpy(np.ascontiguousarray(disparity, dtype=np.float32)).to(dev)
            out = self.render_tensor(rad, d, float(focus), float(aperture), plan)
            return out.permute(1, 2, 0).contiguous().cpu().numpy()

    def render_srgb(self, image: np.ndarray, disparity: np.ndarray, focus: float, aperture: float,
                    hdr_exponent: np.ndarray | None = None) -> np.ndarray:
        """Shallow-DOF sRGB (H, W, 3) float32 in [0, 1] from an sRGB frame (as ``FastRenderer.render_srgb``)."""
        radiance = hdr_radiance(image_to_linear(image), hdr_exponent)
        return linear_to_srgb(self.render_linear(radiance, disparity, focus, aperture))

    def render_tensor(self, radiance: Any, disparity: Any, focus: float, aperture: float,
                      plan: LayerPlan | None = None) -> Any:
        """The model on tensors already on the device: radiance (3, H, W) linear HDR, disparity
        (H, W) (DESIGN units) -> (3, H, W) linear radiance. Call under ``torch.inference_mode()``."""
        import torch

        from .torch_render import push_pull_fill_torch, spread

        h, w = disparity.shape
        bound = max_blur_radius(h, w)
        s = ((disparity - focus) * aperture).clamp(-bound, bound)
        if plan is None:
            s_min, s_max = torch.stack(torch.aminmax(s)).tolist()
            plan = plan_layers(s_min, s_max, max_step=self.max_step, min_layers=self.min_layers)
        j_lo, j_hi = int(plan.indices.min()), int(plan.indices.max())
        u = (s / float(np.float32(plan.step))).clamp(j_lo, j_hi)  # a Python scalar: fine on any device
        norm, layers = self._normaliser_and_layers(u, plan)
        radiance1 = torch.cat([radiance, torch.ones_like(radiance[:1])])  # [L, 1]: colour and matte
        acc = torch.zeros_like(radiance)
        cov = torch.zeros_like(u)
        hidden = torch.zeros_like(u)  # H_j: sum of V_i over layers i <= j - S (model step 4)
        far = torch.zeros_like(u)  # F_j: sum of V_i over layers i < j - SURFACE_STEPS
        visible: dict[int, Any] = {}  # V_i not yet in `hidden`
        near: dict[int, Any] = {}  # V_i in `hidden`, not yet in `far`
        for batch in self._batches(layers, plan.step, h, w, radiance.device):
            j = torch.tensor(batch, dtype=u.dtype, device=u.device)[:, None, None]
            x = radiance1[None] * (matte_unnormalised(u[None], j) / norm)[:, None]  # (B, 4, H, W)
            if self.spec.varies:  # cat's eye: a kernel per zone, one layer at a time (torch_render's)
                blurred = torch.cat([spread(x[k:k + 1], self.spec, abs(jj * plan.step))
                                     for k, jj in enumerate(batch)])
            else:
                blurred = self._blur_batch(x, [self._kernel(abs(jj * plan.step)) for jj in batch])
            del x
            for k, jj in enumerate(batch):  # front to back
                c, wj = blurred[k, :3], blurred[k, 3]
                for i in sorted(i for i in visible if i <= jj - OCCLUSION_DELAY):
                    near[i] = visible.pop(i)
                    hidden += near[i]
                for i in sorted(i for i in near if i < jj - SURFACE_STEPS):
                    far += near.pop(i)
                if self.naive:
                    acc += c
                    cov += wj
                else:
                    t = visible_fraction((1.0 - hidden).clamp(min=0.0), (1.0 - far).clamp(min=0.0), wj)
                    v = t * wj
                    acc += t * c
                    cov += v
                    visible[jj] = v
            del blurred
        weight = fill_weight(cov)
        fill = push_pull_fill_torch(radiance[None], weight[None, None], u[None, None])[0]
        return acc / cov.clamp(min=1.0) + (1.0 - weight) * fill

    # -- internals ------------------------------------------------------------------------
    def _normaliser_and_layers(self, u: Any, plan: LayerPlan) -> tuple[Any, list[int]]:
        """(sum of the un-normalised mattes per pixel (H, W), the layers with a non-zero matte
        somewhere, front to back). Only the <= 4 layers within the cutoff of a pixel are visited
        (as ``model.matte_normaliser``); one device -> host copy (the histogram of floor(u))."""
        import torch

        j_lo, j_hi = int(plan.indices.min()), int(plan.indices.max())
        base = torch.floor(u)
        norm = torch.zeros_like(u)
        for off in MATTE_OFFSETS:
            j = base + off
            norm += torch.where((j >= j_lo) & (j <= j_hi), matte_unnormalised(u, j), 0.0)
        n = j_hi - j_lo + 1
        present = torch.bincount((base.long() - j_lo).clamp(0, n - 1).flatten(), minlength=n).cpu().numpy() > 0
        active = np.zeros(n, bool)
        for off in MATTE_OFFSETS:
            lo, hi = max(off, 0), n + min(off, 0)
            active[lo:hi] |= present[lo - off:hi - off]
        wanted = set(plan.indices.tolist())
        return norm, [j_lo + k for k in np.flatnonzero(active).tolist() if j_lo + k in wanted]

    def _batch_bytes(self, device: Any) -> float:
        if self.batch_mb is not None:
            return self.batch_mb * 1e6
        if device.type == "cuda":
            import torch

            free, _ = torch.cuda.mem_get_info(device)
            return free * CUDA_BATCH_FRACTION
        return CPU_BATCH_MB * 1e6

    def _batches(self, layers: list[int], step: float, h: int, w: int, device: Any) -> list[list[int]]:
        """The layers (front to back) split into consecutive batches that fit the memory budget
        (sized for the largest kernel, px of radius ``|j| * step``)."""
        if not layers:
            return []
        side = 2 * kernel_half_size(max(abs(j) for j in layers) * step) + 1
        per_layer = BYTES_PER_LAYER_PX * fft_size(h + side) * fft_size(w + side)
        size = max(1, int(self._batch_bytes(device) // per_layer))
        return [layers[k:k + size] for k in range(0, len(layers), size)]

    def _kernel(self, radius: float) -> np.ndarray:
        """The PSF of ``radius`` px (cached); (1, 1) for a delta."""
        key = (self.spec.key, round(radius, 6))
        k = self._kernels.get(key)
        if k is None:
            k = make_kernel(self.spec, radius)
            k = np.ones((1, 1), np.float32) if is_delta(k) else k
            self._kernels[key] = k
        return k

    def _blur_batch(self, x: Any, kernels: list[np.ndarray]) -> Any:
        """Scatter each layer x[k] (B, C, H, W) by its PSF ``kernels[k]`` (zero outside the frame):
        a delta is a copy; the others share one FFT of the batch, their kernels centred in a
        square of the largest side. (Masking the FFT's ~1e-7 rounding outside each layer's exact
        support, with a fifth channel, was tried: no change above 1e-6 dB on the test frames, 25%
        more work, so it is not done.)"""
        import torch

        b, c, h, w = x.shape
        out = torch.empty_like(x)
        big = [k for k in range(b) if kernels[k].shape[0] > 1]
        for k in range(b):
            if kernels[k].shape[0] == 1:
                out[k] = x[k] * float(kernels[k][0, 0])
        if not big:
            return out
        side = max(kernels[k].shape[0] for k in big)
        half = side // 2
        stack = np.zeros((len(big), side, side), np.float32)
        for n, k in enumerate(big):
            s = kernels[k].shape[0]
            o = (side - s) // 2
            stack[n, o:o + s, o:o + s] = kernels[k]
        fh, fw = fft_size(h + side - 1), fft_size(w + side - 1)
        spec = torch.fft.rfft2(x[big] if len(big) < b else x, s=(fh, fw))
        spec *= torch.fft.rfft2(torch.from_numpy(stack).to(x.device), s=(fh, fw))[:, None]
        out[big] = torch.fft.irfft2(spec, s=(fh, fw))[..., half:half + h, half:half + w]
        return out
