"""Image and video quality metrics of the artifact ablations (paper section 6.3), numpy + OpenCV.

Every function is pure (arrays in, numbers or masks out) and never imports bpy. Conventions:

- *linear* images are scene-linear radiance (H, W, 3) float, values may exceed 1 (HDR);
- *sRGB* images are display-referred encodings in [0, 1]: :func:`display_srgb` turns linear
  radiance into what a display shows (clip to [0, 1], then the sRGB OETF);
- disparity is DESIGN.md's unit: px of blur radius at aperture scale 1 at the frame's width,
  so ``aperture * |D - focus|`` is a blur radius in px.

PSNR peak convention. sRGB PSNR compares the display encodings with peak 1. Linear PSNR
compares the radiance *clipped to the display range* [0, 1] with peak 1: the product is a
display-referred video, so errors above white are invisible, and a peak taken from the data
(e.g. the ground truth's 99.9th percentile) would make numbers depend on how bright a clip's
emitters happen to be and incomparable between clips and variants. Linear PSNR therefore
weights errors in bright regions more than sRGB PSNR does, and the energy above white (the
bokeh highlights) is measured separately by :func:`bokeh_recall`. Identical images score
``max_db`` (100 dB) instead of infinity so means and JSON stay finite.

SSIM is Wang et al. 2004 with an 11x11 Gaussian window (sigma 1.5), K1 = 0.01, K2 = 0.03,
data range 1, computed per RGB channel and averaged over the channels and over the pixels at
least 5 px from the border (the "valid" part of the window, as scikit-image does with
``gaussian_weights=True, use_sample_covariance=False, channel_axis=-1``).
"""
from __future__ import annotations

import math

import cv2
import numpy as np

from rvr_addon.color import linear_to_srgb

MAX_PSNR_DB = 100.0
"""PSNR reported for identical images (and the cap of any PSNR), in dB."""
SSIM_SIGMA = 1.5
SSIM_RADIUS = 5
"""Half size of the 11x11 Gaussian SSIM window, px."""
SSIM_K1, SSIM_K2 = 0.01, 0.03


def _check_pair(a: np.ndarray, b: np.ndarray, what: str) -> tuple[np.ndarray, np.ndarray]:
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    if a.shape != b.shape:
        raise ValueError(f"{what}: images differ in shape, {a.shape} vs {b.shape}; compare frames of one size.")
    return a, b


def _check_mask(mask: np.ndarray | None, shape: tuple[int, ...], what: str) -> np.ndarray | None:
    if mask is None:
        return None
    mask = np.asarray(mask, dtype=bool)
    if mask.shape != tuple(shape[:2]):
        raise ValueError(f"{what}: mask has shape {mask.shape} but the images are {shape[:2]} (H, W).")
    return mask


# ----------------------------------------------------------------------------------------
# Colour


def display_linear(linear: np.ndarray) -> np.ndarray:
    """Linear radiance clipped to the display range [0, 1] (float32, same shape)."""
    return np.clip(np.asarray(linear, dtype=np.float32), 0.0, 1.0)


def display_srgb(linear: np.ndarray) -> np.ndarray:
    """Linear radiance -> the sRGB encoding a display shows, float32 in [0, 1] (clips at white)."""
    return np.asarray(linear_to_srgb(np.asarray(linear, dtype=np.float32)), dtype=np.float32)


# ----------------------------------------------------------------------------------------
# PSNR


def squared_error_sum(a: np.ndarray, b: np.ndarray, mask: np.ndarray | None = None) -> tuple[float, int]:
    """(sum of squared differences, number of values) of a and b, over ``mask`` pixels if given.

    a, b: (H, W) or (H, W, C) arrays of one shape. mask: (H, W) bool or None (all pixels).
    Values are counted per channel, so MSE = sum / count. Used to pool MSE over frames.
    """
    a, b = _check_pair(a, b, "squared_error_sum")
    mask = _check_mask(mask, a.shape, "squared_error_sum")
    d = a - b
    if mask is not None:
        d = d[mask]
    return float(np.sum(d * d)), int(d.size)


def psnr_from_mse(mse: float, peak: float = 1.0, max_db: float = MAX_PSNR_DB) -> float:
    """PSNR in dB = 10 log10(peak^2 / mse), capped at ``max_db``; NaN when mse is NaN (no pixels)."""
    if not math.isfinite(mse):
        return float("nan")
    if mse <= 0.0:
        return float(max_db)
    return float(min(10.0 * math.log10(peak * peak / mse), max_db))


def psnr(a: np.ndarray, b: np.ndarray, *, peak: float = 1.0, mask: np.ndarray | None = None,
         max_db: float = MAX_PSNR_DB) -> float:
    """Peak signal-to-noise ratio in dB of a against b.

    a, b: arrays of one shape, in the units of ``peak`` (1.0 for images in [0, 1]; clip linear
    radiance with :func:`display_linear` first, see the module docstring). mask: (H, W) bool;
    only those pixels count. Returns ``max_db`` for identical inputs and NaN for an empty mask.

    >>> round(psnr(np.zeros((2, 2)), np.full((2, 2), 0.1)), 6)
    20.0
    """
    total, count = squared_error_sum(a, b, mask)
    return psnr_from_mse(total / count if count else float("nan"), peak, max_db)


# ----------------------------------------------------------------------------------------
# SSIM


def _gauss(x: np.ndarray) -> np.ndarray:
    k = 2 * SSIM_RADIUS + 1
    return cv2.GaussianBlur(x, (k, k), SSIM_SIGMA, borderType=cv2.BORDER_REFLECT)


def ssim_map(a: np.ndarray, b: np.ndarray, *, data_range: float = 1.0) -> np.ndarray:
    """Per-pixel SSIM (H, W) or (H, W, C) float64 of one image pair (Gaussian window, see module).

    a, b: (H, W) or (H, W, C) in units where the signal spans ``data_range``. The border of
    SSIM_RADIUS px is included here (reflected padding); :func:`ssim` drops it.
    """
    a, b = _check_pair(a, b, "ssim")
    c1 = (SSIM_K1 * data_range) ** 2
    c2 = (SSIM_K2 * data_range) ** 2
    mu_a, mu_b = _gauss(a), _gauss(b)
    var_a = _gauss(a * a) - mu_a * mu_a
    var_b = _gauss(b * b) - mu_b * mu_b
    cov = _gauss(a * b) - mu_a * mu_b
    num = (2 * mu_a * mu_b + c1) * (2 * cov + c2)
    den = (mu_a * mu_a + mu_b * mu_b + c1) * (var_a + var_b + c2)
    return num / den


def ssim(a: np.ndarray, b: np.ndarray, *, data_range: float = 1.0) -> float:
    """Mean SSIM (unitless, 1 = identical) of a and b, averaged over channels and the valid pixels.

    a, b: (H, W) or (H, W, C), both at least 11 px in each direction.
    Raises ValueError for smaller images (the window does not fit).
    """
    a, b = _check_pair(a, b, "ssim")
    h, w = a.shape[:2]
    k = 2 * SSIM_RADIUS + 1
    if h < k or w < k:
        raise ValueError(f"ssim: images of {w}x{h} px are smaller than the {k}x{k} window; use frames >= {k} px.")
    m = ssim_map(a, b, data_range=data_range)
    r = SSIM_RADIUS
    return float(m[r:h - r, r:w - r].mean())


# ----------------------------------------------------------------------------------------
# Masks from the ground-truth disparity


def _disk(radius_px: int) -> np.ndarray:
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius_px + 1, 2 * radius_px + 1))


def depth_edges(disparity: np.ndarray, *, aperture: float = 1.0, threshold_px: float = 1.0) -> np.ndarray:
    """(H, W) bool: pixels on either side of a depth discontinuity.

    A pair of 4-neighbours is a discontinuity when their blur radii differ by more than
    ``threshold_px``: ``aperture * |D(p) - D(q)| > threshold_px`` (px of blur radius; D in
    DESIGN units). Both pixels of such a pair are marked.
    """
    d = np.asarray(disparity, dtype=np.float64) * abs(float(aperture))
    if d.ndim != 2:
        raise ValueError(f"depth_edges: disparity must be (H, W), got {d.shape}.")
    edges = np.zeros(d.shape, dtype=bool)
    jump_x = np.abs(np.diff(d, axis=1)) > threshold_px
    jump_y = np.abs(np.diff(d, axis=0)) > threshold_px
    edges[:, :-1] |= jump_x
    edges[:, 1:] |= jump_x
    edges[:-1, :] |= jump_y
    edges[1:, :] |= jump_y
    return edges


def edge_band(disparity: np.ndarray, width_px: int, *, aperture: float = 1.0, threshold_px: float = 1.0) -> np.ndarray:
    """(H, W) bool band around the depth discontinuities of ``disparity``.

    disparity: (H, W) float, DESIGN units (ground truth). width_px: half width of the band in
    px (the edge pixels dilated by a disk of this radius; 0 = the edge pixels only).
    aperture / threshold_px: see :func:`depth_edges` (a jump counts when the blur radius
    changes by more than threshold_px between neighbours at this aperture scale).
    """
    if width_px < 0:
        raise ValueError(f"edge_band: width_px must be >= 0, got {width_px}.")
    edges = depth_edges(disparity, aperture=aperture, threshold_px=threshold_px)
    if width_px == 0 or not edges.any():
        return edges
    return cv2.dilate(edges.astype(np.uint8), _disk(int(width_px))).astype(bool)


def flat_regions(disparity: np.ndarray, *, aperture: float = 1.0, gradient_px: float = 0.05,
                 erode_px: int = 3) -> np.ndarray:
    """(H, W) bool: where the ground-truth blur radius is spatially almost constant.

    A pixel is flat when the central-difference gradient magnitude of the blur radius
    ``aperture * D`` is below ``gradient_px`` (px of blur radius per px); the flat set is
    then eroded by a disk of ``erode_px`` px so that it keeps away from depth edges.
    """
    d = np.asarray(disparity, dtype=np.float64) * abs(float(aperture))
    if d.ndim != 2:
        raise ValueError(f"flat_regions: disparity must be (H, W), got {d.shape}.")
    gy, gx = np.gradient(d)
    flat = np.hypot(gx, gy) < gradient_px
    if erode_px > 0:
        flat = cv2.erode(flat.astype(np.uint8), _disk(int(erode_px)), borderType=cv2.BORDER_REPLICATE).astype(bool)
    return flat


def defocused(disparity: np.ndarray, focus: float, aperture: float, *, min_radius_px: float = 1.0) -> np.ndarray:
    """(H, W) bool: pixels blurred by at least ``min_radius_px`` (``aperture * |D - focus|``)."""
    return np.abs(np.asarray(disparity, dtype=np.float64) - focus) * abs(float(aperture)) >= min_radius_px


# ----------------------------------------------------------------------------------------
# Splotchiness, flicker, bokeh recall


def blur_size_error(disparity_used: np.ndarray, disparity_gt: np.ndarray, focus: float, aperture: float) -> np.ndarray:
    """(H, W) float64 error of the blur radius in px: ``a |D_used - f| - a |D_gt - f|``."""
    du = np.asarray(disparity_used, dtype=np.float64)
    dg = np.asarray(disparity_gt, dtype=np.float64)
    if du.shape != dg.shape:
        raise ValueError(f"blur_size_error: disparities differ in shape, {du.shape} vs {dg.shape}.")
    a = abs(float(aperture))
    return a * np.abs(du - focus) - a * np.abs(dg - focus)


def splotch_moments(disparity_used: np.ndarray, disparity_gt: np.ndarray, focus: float, aperture: float,
                    flat: np.ndarray) -> tuple[float, int]:
    """(sum of squared deviations from the frame's mean in px^2, pixel count) of the blur-size
    error inside ``flat``: the pieces that pool :func:`splotchiness` over frames as
    ``sqrt(sum ss / sum n)`` (the within-frame standard deviation of a clip).
    """
    err = blur_size_error(disparity_used, disparity_gt, focus, aperture)
    flat = _check_mask(flat, err.shape, "splotchiness")
    vals = err[flat]
    if vals.size == 0:
        return 0.0, 0
    dev = vals - vals.mean()
    return float(np.sum(dev * dev)), int(vals.size)


def splotchiness(disparity_used: np.ndarray, disparity_gt: np.ndarray, focus: float, aperture: float,
                 flat: np.ndarray) -> float:
    """Standard deviation in px of the blur-size error (:func:`blur_size_error`) inside ``flat``.

    Zero when the rendered disparity equals the ground truth (or differs from it by a constant
    on the flat pixels: a uniform offset is a focus error, not a splotch). NaN if ``flat`` is
    empty.
    """
    ss, n = splotch_moments(disparity_used, disparity_gt, focus, aperture, flat)
    return math.sqrt(ss / n) if n else float("nan")


def flicker(out_prev: np.ndarray, out: np.ndarray, gt_prev: np.ndarray, gt: np.ndarray) -> float:
    """Temporal flicker beyond the ground truth's, for one pair of consecutive frames.

    Mean over pixels and channels of ``|(out_t - out_{t-1}) - (gt_t - gt_{t-1})|`` on sRGB
    images in [0, 1] (units: sRGB code value / 255 -> fraction of full scale). 0 when the
    output changes from frame to frame exactly as the ground truth does. A clip's flicker is
    the mean of this over its frame pairs.
    """
    out_prev, out = _check_pair(out_prev, out, "flicker")
    gt_prev, gt = _check_pair(gt_prev, gt, "flicker")
    if out.shape != gt.shape:
        raise ValueError(f"flicker: output {out.shape} and ground truth {gt.shape} differ in shape.")
    return float(np.mean(np.abs((out - out_prev) - (gt - gt_prev))))


def static_mask(prev_rgb: np.ndarray, rgb: np.ndarray, tol: float = 1.5, margin: int = 4,
                flow: np.ndarray | None = None, max_motion_px: float = 0.5) -> np.ndarray:
    """(H, W) bool: pixels of a real clip that stay still between two consecutive frames, for
    flicker without ground truth. Both frames (H, W, 3) uint8 are turned grey and blurred
    (5x5 Gaussian); a pixel is static where they differ by less than ``tol`` code values and
    so does every pixel within ``margin`` px (motion edges, noise specks and compression
    blocks that change are left out). ``flow`` (H, W, 2) px, the optical flow between the two
    frames: a pixel must also move less than ``max_motion_px`` (in a pan, a plain wall looks
    the same from frame to frame while the scene point behind the pixel changes)."""
    a = cv2.GaussianBlur(cv2.cvtColor(np.ascontiguousarray(prev_rgb), cv2.COLOR_RGB2GRAY).astype(np.float32), (5, 5), 0)
    b = cv2.GaussianBlur(cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2GRAY).astype(np.float32), (5, 5), 0)
    still = np.abs(b - a) < tol
    if flow is not None:
        if flow.shape != a.shape + (2,):
            raise ValueError(f"static_mask: flow has shape {flow.shape}, the frames {a.shape}")
        still &= np.hypot(flow[..., 0], flow[..., 1]) < max_motion_px
    still = still.astype(np.uint8)
    if margin > 0:
        still = cv2.erode(still, np.ones((2 * margin + 1, 2 * margin + 1), np.uint8))
    return still.astype(bool)


def evaluation_flow(prev_rgb: np.ndarray, rgb: np.ndarray, delta_px: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Motion between two consecutive (H, W, 3) uint8 input frames, for motion-compensated
    flicker: ``(flow, valid)``, the flow (H, W, 2) px from frame t (``rgb``) to frame t-1 (the
    point at pixel p of t is at p + flow(p) in t-1) and the (H, W) bool pixels where it is
    trustworthy: forward-backward consistent within ``delta_px`` + 5 % of its length and
    landing inside the frame. Farneback's flow at full resolution, deliberately *not* the DIS
    flow the temporal filter itself follows, so the filter is not graded by its own flow."""
    from rvr_addon.temporal.flow import consistent

    a = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2GRAY)
    b = cv2.cvtColor(np.ascontiguousarray(prev_rgb), cv2.COLOR_RGB2GRAY)
    args = (None, 0.5, 4, 15, 3, 5, 1.2, 0)
    back = cv2.calcOpticalFlowFarneback(a, b, *args)
    fwd = cv2.calcOpticalFlowFarneback(b, a, *args)
    return back, consistent(back, fwd, delta_px)


def warped_flicker(err_prev: np.ndarray, err: np.ndarray, flow: np.ndarray, valid: np.ndarray) -> float:
    """Motion-compensated flicker of an error image: mean over the ``valid`` pixels (and the
    channels) of ``|err_t - warp(err_{t-1})|``, where ``warp`` brings frame t-1 onto t along
    ``flow`` (:func:`evaluation_flow`, bilinear). ``err`` = output - reference: an error that
    moves rigidly with the scene (a consistently wrong blur on a panning wall) scores ~0, an
    error that changes along the motion scores its change (so does a steady wrong blur where
    parallax or occlusion reshapes it). Units of the arrays. NaN on an empty mask."""
    from rvr_addon.temporal.flow import warp

    err_prev, err = _check_pair(err_prev, err, "warped_flicker")
    valid = _check_mask(valid, err.shape, "warped_flicker")
    if not valid.any():
        return float("nan")
    moved = warp(np.ascontiguousarray(err_prev, dtype=np.float32), np.ascontiguousarray(flow, dtype=np.float32))
    return float(np.mean(np.abs(err - moved)[valid]))


def static_flicker(out_prev: np.ndarray, out: np.ndarray, mask: np.ndarray) -> float:
    """Mean ``|out_t - out_{t-1}|`` over the pixels (and channels) of ``mask`` (:func:`static_mask`):
    on pixels whose input does not change, every change of the output is flicker. Units of the
    arrays (sRGB fraction of full scale for images, DESIGN px for disparity). NaN on an empty mask."""
    out_prev, out = _check_pair(out_prev, out, "static_flicker")
    mask = _check_mask(mask, out.shape, "static_flicker")
    if not mask.any():
        return float("nan")
    return float(np.mean(np.abs(out - out_prev)[mask]))


def highlight_mask(gt_linear: np.ndarray, *, threshold: float = 1.0, mask: np.ndarray | None = None) -> np.ndarray:
    """(H, W) bool: ground-truth pixels whose brightest channel exceeds ``threshold`` (linear
    radiance; 1.0 = the 8-bit white), optionally restricted to ``mask``."""
    gt = np.asarray(gt_linear)
    bright = gt.max(axis=2) > threshold if gt.ndim == 3 else gt > threshold
    if mask is not None:
        bright &= _check_mask(mask, gt.shape, "highlight_mask")
    return bright


def bokeh_energy(ours_linear: np.ndarray, gt_linear: np.ndarray, *, threshold: float = 1.0,
                 mask: np.ndarray | None = None) -> tuple[float, float]:
    """(energy found, ground-truth energy) over the ground truth's highlights.

    Over the pixels of :func:`highlight_mask` (gt brightest channel > threshold, within mask):
    found = sum of min(ours, gt), total = sum of gt, over all channels (linear radiance units).
    Pool over frames by summing both.
    """
    ours, gt = _check_pair(ours_linear, gt_linear, "bokeh_recall")
    bright = highlight_mask(gt, threshold=threshold, mask=mask)
    g = gt[bright]
    o = np.maximum(ours[bright], 0.0)
    return float(np.minimum(o, g).sum()), float(g.sum())


def bokeh_recall(ours_linear: np.ndarray, gt_linear: np.ndarray, *, threshold: float = 1.0,
                 mask: np.ndarray | None = None) -> float:
    """Fraction (0..1) of the ground truth's highlight energy found in ours.

    ``sum min(ours, gt) / sum gt`` over the ground-truth pixels brighter than ``threshold``
    (linear; see :func:`bokeh_energy`). 1 when ours is at least as bright everywhere there;
    an output clipped at white recovers about ``1 / mean(gt)`` of it. NaN with no highlights.
    """
    found, total = bokeh_energy(ours_linear, gt_linear, threshold=threshold, mask=mask)
    return found / total if total > 0 else float("nan")
