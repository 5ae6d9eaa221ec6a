"""Labelled side-by-side panels for the ablation report: comparison images and video frames.

All images are (H, W, 3) uint8 RGB. Pure numpy + OpenCV; nothing here reads or writes files.
"""
from __future__ import annotations

import cv2
import numpy as np

Box = tuple[int, int, int, int]
"""y0, y1, x0, x1 (half-open, px)."""

HEADER_PX = 20
"""Height of the label strip above a panel, px."""
BOX_COLOUR = (255, 200, 0)


def label_panel(image: np.ndarray, text: str, header_px: int = HEADER_PX) -> np.ndarray:
    """The image with a black strip of ``header_px`` px on top holding ``text`` (shrunk to fit)."""
    h, w = image.shape[:2]
    out = np.zeros((h + header_px, w, 3), np.uint8)
    out[header_px:] = image
    font = cv2.FONT_HERSHEY_SIMPLEX
    scale = 0.45
    (tw, th), _ = cv2.getTextSize(text, font, scale, 1)
    if tw > w - 4:
        scale *= (w - 4) / tw
        (tw, th), _ = cv2.getTextSize(text, font, scale, 1)
    cv2.putText(out, text, (2, max((header_px + th) // 2, th)), font, scale, (255, 255, 255), 1, cv2.LINE_AA)
    return out


def grid(panels: list[np.ndarray], cols: int) -> np.ndarray:
    """Panels (all of one size) in rows of ``cols``, left to right then top to bottom; empty
    cells are black."""
    if not panels:
        raise ValueError("grid: no panels")
    h, w = panels[0].shape[:2]
    cols = max(1, min(cols, len(panels)))
    rows = -(-len(panels) // cols)
    out = np.zeros((rows * h, cols * w, 3), np.uint8)
    for i, p in enumerate(panels):
        r, c = divmod(i, cols)
        out[r * h:(r + 1) * h, c * w:(c + 1) * w] = p
    return out


def crop_box(mask: np.ndarray, fraction: float = 0.25) -> Box:
    """A window of ``fraction`` of the frame's width and height centred where ``mask`` (H, W)
    bool is densest (e.g. the edge band); the frame centre if the mask is empty."""
    h, w = mask.shape
    ch, cw = max(int(round(h * fraction)), 4), max(int(round(w * fraction)), 4)
    ch, cw = min(ch, h), min(cw, w)
    if mask.any():
        density = cv2.blur(mask.astype(np.float32), (cw, ch), borderType=cv2.BORDER_CONSTANT)
        cy, cx = np.unravel_index(int(np.argmax(density)), density.shape)
    else:
        cy, cx = h // 2, w // 2
    y0 = int(np.clip(cy - ch // 2, 0, h - ch))
    x0 = int(np.clip(cx - cw // 2, 0, w - cw))
    return y0, y0 + ch, x0, x0 + cw


def zoom(image: np.ndarray, box: Box, size: tuple[int, int]) -> np.ndarray:
    """The ``box`` of ``image`` enlarged to ``size`` = (width, height) with nearest-neighbour
    sampling (pixels stay visible as blocks)."""
    y0, y1, x0, x1 = box
    return cv2.resize(image[y0:y1, x0:x1], size, interpolation=cv2.INTER_NEAREST)


def draw_box(image: np.ndarray, box: Box) -> np.ndarray:
    """A copy of ``image`` with the outline of ``box``."""
    y0, y1, x0, x1 = box
    out = image.copy()
    cv2.rectangle(out, (x0, y0), (x1 - 1, y1 - 1), BOX_COLOUR, 1)
    return out


def error_image(image: np.ndarray, reference: np.ndarray, gain: float = 4.0) -> np.ndarray:
    """|image - reference| per channel, times ``gain``, as uint8 (black = no error)."""
    diff = np.abs(image.astype(np.int16) - reference.astype(np.int16)).astype(np.float32) * gain
    return np.clip(diff, 0, 255).astype(np.uint8)


def disparity_image(disparity: np.ndarray, focus: float, aperture: float) -> np.ndarray:
    """The blur radius ``aperture |D - focus|`` colour-mapped (turbo; 0 px = dark blue, the
    frame's largest radius = dark red), uint8 RGB."""
    r = np.abs(disparity.astype(np.float32) - np.float32(focus)) * np.float32(aperture)
    top = float(r.max()) or 1.0
    mapped = cv2.applyColorMap(np.clip(r / top * 255.0, 0, 255).astype(np.uint8), cv2.COLORMAP_TURBO)
    return np.ascontiguousarray(mapped[:, :, ::-1])


def mask_image(band: np.ndarray, flat: np.ndarray) -> np.ndarray:
    """Metric masks as colours: edge band red, flat regions grey, the rest black."""
    out = np.zeros((*band.shape, 3), np.uint8)
    out[flat] = (90, 90, 90)
    out[band] = (230, 40, 40)
    return out


def comparison_image(panels: list[tuple[str, np.ndarray]], box: Box,
                     bottom: list[np.ndarray] | None = None) -> np.ndarray:
    """One column per (label, image): the labelled full frame (the zoom window outlined), the
    window enlarged to the frame's size, and optionally one more image per column (``bottom``,
    e.g. error maps). Returns (2 or 3 H + header, N W, 3) uint8."""
    columns = []
    for i, (label, img) in enumerate(panels):
        h, w = img.shape[:2]
        rows = [label_panel(draw_box(img, box), label), zoom(img, box, (w, h))]
        if bottom is not None:
            rows.append(bottom[i])
        columns.append(np.vstack(rows))
    return np.hstack(columns)


def video_frame(panels: list[tuple[str, np.ndarray]], cols: int = 3, caption: str = "") -> np.ndarray:
    """Labelled panels in a grid (``cols`` per row), with an optional caption strip on top."""
    frame = grid([label_panel(img, label) for label, img in panels], cols)
    if caption:
        frame = label_panel(frame, caption)
    return frame
