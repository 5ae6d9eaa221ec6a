"""Aperture (bokeh) kernels: disk, N-blade polygon, anamorphic ellipse, or a user image.

A kernel of radius r px is a (2R+1, 2R+1) float32 array summing to 1 (R = ceil(r + 0.5)),
the point spread function of a defocused point: a point scatters into this shape. Edges are
anti-aliased by pixel coverage, approximated from a signed distance to the shape's rim, so
that the kernel grows continuously with r. r < 0.5 px gives (nearly) a delta.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import InputError

SHAPES = ("disk", "polygon", "anamorphic", "image")


@dataclass(frozen=True)
class ApertureSpec:
    """Shape of the lens aperture.

    shape: "disk" (default), "polygon" (``blades`` >= 3 straight blades rotated by
        ``rotation_deg``), "anamorphic" (ellipse ``squeeze`` times taller than wide, as a
        2x anamorphic lens gives after de-squeeze; the vertical semi-axis is r), or "image"
        (``kernel_image``: a 2-D array, bright = open, scaled to the disk's diameter).
    cat_eye: optical vignetting strength in [0, 1]. Toward the frame edges the aperture is
        clipped by a disk of the same radius, the two offset radially by ``2 r * cat_eye * rho``
        (rho = distance from the frame centre over the half-diagonal) and centred on the
        point, so bokeh turns into "cat's eyes" elongated along the tangent. 0 = off.
    zones: the frame is split into ``zones x zones`` cells; every source pixel of a cell uses
        the kernel of the cell's centre (only when ``cat_eye > 0``).
    """

    shape: str = "disk"
    blades: int = 6
    rotation_deg: float = 0.0
    squeeze: float = 2.0
    kernel_image: np.ndarray | None = field(default=None, compare=False, repr=False)
    cat_eye: float = 0.0
    zones: int = 7

    def __post_init__(self) -> None:
        if self.shape not in SHAPES:
            raise InputError(f"unknown aperture shape {self.shape!r}; use one of {', '.join(SHAPES)}")
        if self.shape == "polygon" and self.blades < 3:
            raise InputError(f"a polygon aperture needs >= 3 blades, got blades={self.blades}")
        if self.shape == "anamorphic" and not (self.squeeze > 0 and math.isfinite(self.squeeze)):
            raise InputError(f"anamorphic squeeze must be a positive number (e.g. 2.0), got {self.squeeze}")
        if not (0.0 <= self.cat_eye <= 1.0):
            raise InputError(f"cat's-eye strength must be in [0, 1] (0 = off), got {self.cat_eye}")
        if self.zones < 1:
            raise InputError(f"cat's-eye zones must be >= 1, got {self.zones}")
        if self.shape == "image":
            img = self.kernel_image
            if img is None or img.ndim != 2 or img.size == 0:
                raise InputError("the aperture shape 'image' needs a non-empty 2-D kernel image")
            if not np.all(np.isfinite(img)) or float(np.max(img)) <= 0.0:
                raise InputError("the aperture kernel image is empty (all zero/negative or not finite); "
                                 "use a white shape on black")

    @property
    def key(self) -> tuple:
        """Hashable identity of the shape, for kernel caches."""
        img_id = None if self.kernel_image is None else id(self.kernel_image)
        return (self.shape, self.blades, self.rotation_deg, self.squeeze, img_id, self.cat_eye, self.zones)

    @property
    def varies(self) -> bool:
        """True when the kernel depends on the position in the frame (cat's eye on)."""
        return self.cat_eye > 0 and self.zones > 1


def zone_edges(length: int, zones: int) -> np.ndarray:
    """Pixel boundaries of ``zones`` equal cells over ``length`` px: (zones + 1,) int."""
    return np.round(np.linspace(0, length, zones + 1)).astype(np.int64)


def zone_offset(spec: "ApertureSpec", zy: int, zx: int) -> tuple[float, float]:
    """Normalised position (x, y) of a zone's centre: the frame centre is (0, 0) and the
    corners are at distance 1 (x to the right, y up)."""
    n = spec.zones
    cx = (zx + 0.5) / n * 2 - 1
    cy = 1 - (zy + 0.5) / n * 2
    return cx / math.sqrt(2), cy / math.sqrt(2)


def load_kernel_image(path: str | Path) -> np.ndarray:
    """Read a user-supplied aperture image as (H, W) float32 in [0, 1] (luma).

    Raises InputError naming the file when it is missing, unreadable or black.
    """
    import cv2

    p = Path(path)
    if not p.is_file():
        raise InputError(f"aperture kernel image not found: {p} (give a PNG/JPG/EXR of the aperture shape)")
    img = cv2.imread(str(p), cv2.IMREAD_UNCHANGED | cv2.IMREAD_ANYDEPTH)
    if img is None or img.size == 0:
        raise InputError(f"cannot read aperture kernel image {p}: not an image OpenCV can decode")
    img = img.astype(np.float32)
    if img.ndim == 3:
        img = img[..., :3].mean(axis=2)
    peak = float(np.nanmax(img)) if img.size else 0.0
    if not math.isfinite(peak) or peak <= 0:
        raise InputError(f"aperture kernel image {p} is empty (black): draw the open aperture in white")
    return np.nan_to_num(img / peak, nan=0.0, posinf=0.0, neginf=0.0).clip(0, None)


def kernel_half_size(radius: float) -> int:
    """Half size R in px of the kernel array of a given radius: the array is (2R+1)^2."""
    return int(math.ceil(max(radius, 0.0) + 0.5))


def _rim_distance(spec: ApertureSpec, x: np.ndarray, y: np.ndarray, r: float) -> np.ndarray:
    """Approximate signed distance in px from (x, y) to the rim of the shape (< 0 inside)."""
    if spec.shape == "disk":
        return np.hypot(x, y) - r
    if spec.shape == "anamorphic":
        # ellipse with semi-axes (r / squeeze, r): distance in the scaled frame, rescaled by
        # the local gradient so the anti-aliasing band stays ~1 px wide
        sx = spec.squeeze
        q = np.hypot(x * sx, y)
        grad = np.hypot(x * sx * sx, y) / np.maximum(q, 1e-6)
        return (q - r) / np.maximum(grad, 1e-6)
    if spec.shape == "polygon":
        n = spec.blades
        rot = math.radians(spec.rotation_deg)
        apothem = r * math.cos(math.pi / n)
        d = np.full(x.shape, -np.inf, dtype=np.float64)
        for k in range(n):
            # edge normals point between the vertices; vertex 0 at angle rot + 90 deg (up)
            ang = rot + math.pi / 2 + math.pi / n + 2 * math.pi * k / n
            d = np.maximum(d, x * math.cos(ang) + y * math.sin(ang) - apothem)
        return d
    raise AssertionError(spec.shape)


def make_kernel(spec: ApertureSpec, radius: float, position: tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
    """Aperture kernel of radius ``radius`` px: (2R+1, 2R+1) float32 summing to 1.

    Rows go down the image (y down), columns right; the kernel is the PSF as seen in the
    image, so a point scatters into exactly this picture. ``position``: where in the frame
    (see :func:`zone_offset`); it matters only with cat's-eye vignetting.

    >>> make_kernel(ApertureSpec(), 0.0).shape
    (3, 3)
    """
    if not math.isfinite(radius) or radius < 0:
        raise ValueError(f"kernel radius must be a finite number >= 0 px, got {radius}")
    half = kernel_half_size(radius)
    if spec.shape == "image":
        k = _image_kernel(spec.kernel_image, radius, half)
        hx, hy = _cat_eye_shift(spec, max(radius, 0.5), position)
        if hx or hy:  # the picture moved by -h (whole px), clipped by the disk at +h
            k = _shift(k, int(round(hy)), int(round(-hx)))
            coords = np.arange(-half, half + 1, dtype=np.float64)
            yy, xx = np.meshgrid(coords, coords, indexing="ij")
            clip = np.clip(max(radius, 0.5) + 0.5 - np.hypot(xx - hx, -yy - hy), 0, 1)
            k = k * clip.astype(np.float32)
            if k.sum() <= 0:
                k[half, half] = 1.0
            k /= k.sum()
        return k
    # 4x4 supersampling of the coverage makes small kernels accurate; the signed distance
    # gives a further sub-sample anti-aliasing band
    ss = 4
    offs = (np.arange(ss) + 0.5) / ss - 0.5
    coords = np.arange(-half, half + 1, dtype=np.float64)
    yy = (coords[:, None, None, None] + offs[None, None, :, None])
    xx = (coords[None, :, None, None] + offs[None, None, None, :])
    yy, xx = np.broadcast_arrays(yy, xx)
    # a 1/ss-pixel wide band per sub-sample
    r = max(radius, 0.5 / ss)
    hx, hy = _cat_eye_shift(spec, r, position)
    # the aperture, shifted by -h, clipped by a disk of radius r shifted by +h: a lens shape
    # centred on the point, elongated along the tangent (y up for the shape)
    sd = _rim_distance(spec, xx + hx, -yy + hy, r)
    if hx or hy:
        sd = np.maximum(sd, np.hypot(xx - hx, -yy - hy) - r)
    cov = np.clip(0.5 - sd * ss, 0.0, 1.0).mean(axis=(2, 3))
    if cov.sum() <= 0:
        cov[half, half] = 1.0
    return (cov / cov.sum()).astype(np.float32)


def _cat_eye_shift(spec: ApertureSpec, r: float, position: tuple[float, float]) -> tuple[float, float]:
    """Half the offset (x, y up) in px between the aperture and the vignetting disk:
    ``r * cat_eye * (position)``, pointing from the frame centre outward."""
    if spec.cat_eye <= 0:
        return 0.0, 0.0
    return r * spec.cat_eye * position[0], r * spec.cat_eye * position[1]


def _shift(a: np.ndarray, dy: int, dx: int) -> np.ndarray:
    """a moved by (dy, dx) whole pixels (rows down, columns right), zero-filled."""
    out = np.zeros_like(a)
    h, w = a.shape
    out[max(dy, 0):h + min(dy, 0), max(dx, 0):w + min(dx, 0)] = a[max(-dy, 0):h + min(-dy, 0), max(-dx, 0):w + min(-dx, 0)]
    return out


def _image_kernel(image: np.ndarray, radius: float, half: int) -> np.ndarray:
    """User kernel image resampled (area-preserving) onto a disk-sized square of side 2r."""
    import cv2

    size = 2 * half + 1
    out = np.zeros((size, size), dtype=np.float32)
    side = max(2.0 * radius, 1.0)
    n = max(int(round(side)), 1)
    if n % 2 == 0:
        n += 1
    n = min(n, size)
    h, w = image.shape
    scale = n / max(h, w)
    nh, nw = max(int(round(h * scale)), 1), max(int(round(w * scale)), 1)
    interp = cv2.INTER_AREA if scale < 1 else cv2.INTER_LINEAR
    small = cv2.resize(image.astype(np.float32), (nw, nh), interpolation=interp).clip(0, None)
    y0, x0 = half - nh // 2, half - nw // 2
    out[y0:y0 + nh, x0:x0 + nw] = small
    total = float(out.sum())
    if total <= 0:
        out[half, half] = 1.0
        total = 1.0
    return out / total
