"""Pixel alignment of aperture-bracketed photos with OpenCV's ECC (Evangelidis & Psarakis 2008).

The paper aligns its pairs and triplets "via correlation coefficient maximisation": each
large- (and medium-) aperture shot is warped onto the small-aperture shot, which is the
network's input and so defines the pixel grid. ECC is run coarse to fine on a Gaussian pyramid
(``cv2.pyrDown``) of the grey images: the coarsest level (at most ``coarse_side`` px) starts
from the identity, every finer level starts from the warp of the level below, scaled by 2.
Defocus differs between the shots; ECC smooths both images of a level with the same Gaussian
(``gaussFiltSize``) before comparing, and the coarse levels, where the defocus is a fraction of a
pixel, fix most of the warp.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

MOTIONS = ("homography", "affine", "euclidean", "translation")


class AlignmentError(Exception):
    """ECC did not converge, or converged to an implausible warp or a weak correlation."""


@dataclass(frozen=True)
class Alignment:
    """warp: (3, 3) float64 mapping reference pixel coordinates to moving-image coordinates
    (``moving(W x) ~ reference(x)``); cc: ECC correlation coefficient at the finest level."""

    warp: np.ndarray
    cc: float


def _grey(image: np.ndarray) -> np.ndarray:
    import cv2

    img = image.astype(np.float32)
    if img.max() > 1.5:
        img /= 255.0
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)
    return img


def _pyramid(image: np.ndarray, coarse_side: int) -> list[np.ndarray]:
    import cv2

    levels = [image]
    while max(levels[-1].shape) > coarse_side and min(levels[-1].shape) >= 32:
        levels.append(cv2.pyrDown(levels[-1]))
    return levels[::-1]  # coarse first


def ecc_align(reference: np.ndarray, moving: np.ndarray, motion: str = "homography", coarse_side: int = 160,
              iterations: int = 60, eps: float = 1e-5, min_cc: float = 0.6, gauss: int = 5) -> Alignment:
    """Estimate the warp that aligns ``moving`` onto ``reference`` (same size, RGB or grey,
    uint8 or float in [0, 1]).

    motion: "homography" (default, a hand-held bracket), "affine", "euclidean" or "translation".
    Raises AlignmentError when ECC fails at any level, the final correlation is below
    ``min_cc``, or the warp scales the image by more than 1.5x or shifts it by more than a
    quarter of the frame (a bracket is never that far off: the match is wrong).
    """
    import cv2

    if motion not in MOTIONS:
        raise ValueError(f"motion must be one of {MOTIONS}, got {motion!r}")
    if reference.shape[:2] != moving.shape[:2]:
        raise AlignmentError(f"sizes differ: {reference.shape[1]}x{reference.shape[0]} vs "
                             f"{moving.shape[1]}x{moving.shape[0]}")
    mode = {"homography": cv2.MOTION_HOMOGRAPHY, "affine": cv2.MOTION_AFFINE,
            "euclidean": cv2.MOTION_EUCLIDEAN, "translation": cv2.MOTION_TRANSLATION}[motion]
    ref_levels = _pyramid(_grey(reference), coarse_side)
    mov_levels = _pyramid(_grey(moving), coarse_side)
    warp = np.eye(3, dtype=np.float32)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, iterations, eps)
    cc = 0.0
    for level, (ref, mov) in enumerate(zip(ref_levels, mov_levels)):
        if level:
            warp = warp.copy()
            warp[0, 2] *= 2.0
            warp[1, 2] *= 2.0
            warp[2, 0] /= 2.0
            warp[2, 1] /= 2.0
        w = warp if mode == cv2.MOTION_HOMOGRAPHY else warp[:2].copy()
        try:
            cc, w = cv2.findTransformECC(ref, mov, w, mode, criteria, None, gauss)
        except cv2.error as ex:
            raise AlignmentError(f"ECC did not converge at pyramid level {level} ({ref.shape[1]}x{ref.shape[0]}): "
                                 f"{str(ex).strip().splitlines()[-1]}") from None
        warp = w if mode == cv2.MOTION_HOMOGRAPHY else np.vstack([w, [0.0, 0.0, 1.0]]).astype(np.float32)
    warp = warp.astype(np.float64)
    if cc < min_cc:
        raise AlignmentError(f"correlation {cc:.3f} after alignment is below {min_cc}: the shots do not match")
    h, w = reference.shape[:2]
    lin = warp[:2, :2]
    det = float(np.linalg.det(lin))
    corners = np.array([[0, 0, 1], [w, 0, 1], [0, h, 1], [w, h, 1]], dtype=np.float64).T
    mapped = warp @ corners
    if np.any(mapped[2] <= 1e-6) or not (1 / 1.5 <= det <= 1.5):
        raise AlignmentError(f"implausible warp (scale {det:.3g}); the shots do not match")
    shift = np.abs(mapped[:2] / mapped[2] - corners[:2]).max()
    if shift > 0.25 * max(w, h):
        raise AlignmentError(f"implausible warp (moves a corner by {shift:.0f} px); the shots do not match")
    return Alignment(warp, float(cc))


def warp_to_reference(moving: np.ndarray, alignment: Alignment, size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Resample ``moving`` onto the reference grid. size: (width, height) of the reference.

    Returns (warped image, same dtype as ``moving``; valid mask (H, W) bool, False where the
    warped image has no source pixels).
    """
    import cv2

    flags = cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP
    warped = cv2.warpPerspective(moving, alignment.warp, size, flags=flags, borderMode=cv2.BORDER_CONSTANT)
    ones = np.ones(moving.shape[:2], dtype=np.float32)
    valid = cv2.warpPerspective(ones, alignment.warp, size, flags=flags, borderMode=cv2.BORDER_CONSTANT) > 0.999
    return warped, valid


def inner_rectangle(valid: np.ndarray) -> tuple[int, int, int, int]:
    """A large axis-aligned rectangle (y0, y1, x0, x1) holding only valid pixels.

    Greedy: repeatedly drops the border row or column with the most invalid pixels. Exact for
    the near-identity warps of a bracket (slivers of invalid pixels along the borders).
    """
    y0, y1, x0, x1 = 0, valid.shape[0], 0, valid.shape[1]
    while y1 > y0 and x1 > x0:
        box = valid[y0:y1, x0:x1]
        if box.all():
            break
        bad = {"top": int((~box[0]).sum()), "bottom": int((~box[-1]).sum()),
               "left": int((~box[:, 0]).sum()), "right": int((~box[:, -1]).sum())}
        side = max(bad, key=bad.get)
        if side == "top":
            y0 += 1
        elif side == "bottom":
            y1 -= 1
        elif side == "left":
            x0 += 1
        else:
            x1 -= 1
    return y0, y1, x0, x1
