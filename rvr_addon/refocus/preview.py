"""A contact sheet of a refocus run: a few frames as rows, each ``input | depth | refocused``.

The depth column colours disparity D (near = bright: D grows with distance, DESIGN.md) and outlines the band in focus
(|D - focus| < 1 px of blur radius at the frame's aperture); the refocused column marks the
target that governs focus on that frame (its box and who chose it).
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..io.maps import open_map_sequence
from ..io.video import iter_frames, probe_clip
from .sidebyside import label, label_scale

SHEET_WIDTH = 1500
"""Width of the contact sheet in px (three columns)."""


def pick_frames(count: int, rows: int) -> list[int]:
    """``rows`` frame indices spread evenly over ``count`` frames (first and last included)."""
    if count <= 0:
        return []
    rows = max(1, min(rows, count))
    return sorted({int(round(v)) for v in np.linspace(0, count - 1, rows)})


def governing_target(doc: dict, t: int) -> dict | None:
    """The NFT of the focus file that governs frame t: the last one due at or before t."""
    due = [n for n in doc.get("nfts") or [] if int(n.get("t", 0)) <= t]
    return due[-1] if due else None


def in_focus_outline(disparity: np.ndarray, focus: float, aperture: float) -> np.ndarray:
    """(H, W) bool: the edge of the region whose blur radius |D - focus| * aperture is < 1 px."""
    import cv2

    sharp = (np.abs(disparity - focus) * max(aperture, 1e-6) < 1.0).astype(np.uint8)
    return cv2.morphologyEx(sharp, cv2.MORPH_GRADIENT, np.ones((3, 3), np.uint8)) > 0


def sheet_row(frame: np.ndarray, disparity: np.ndarray, rendered: np.ndarray, focus: float, aperture: float,
              target: dict | None, caption: str, width: int,
              order: tuple[str, ...] = ("input", "depth", "refocused")) -> np.ndarray:
    """One row of the columns ``order`` names (``input``, ``depth``, ``refocused``; uint8 RGB),
    each ``width`` px wide."""
    import cv2

    from ..estimate.evaluate import colour_map

    h = max(1, int(round(frame.shape[0] * width / frame.shape[1])))
    finite = disparity[np.isfinite(disparity)]
    lo, hi = (np.percentile(-finite, [2, 98]) if finite.size else (0.0, 1.0))
    depth = colour_map(-disparity, float(lo), float(hi), cv2.COLORMAP_INFERNO)  # near (small D) bright
    depth[in_focus_outline(disparity, focus, aperture)] = (80, 255, 80)
    out = rendered.copy()
    if target is not None and target.get("box"):
        x, y, w, hh = (int(round(v)) for v in target["box"])
        thick = max(1, frame.shape[1] // 320)
        cv2.rectangle(out, (x, y), (x + w, y + hh), (80, 255, 80), thick)
        cv2.putText(out, str(target.get("source", "")), (x, max(12, y - 4)), cv2.FONT_HERSHEY_SIMPLEX,
                    max(0.4, frame.shape[0] / 720), (80, 255, 80), thick, cv2.LINE_AA)
    pictures = {"input": (frame, caption), "depth": (depth, "depth (near = bright), green = in focus"),
                "refocused": (out, "refocused")}
    scale = min(label_scale(pictures[k][1], width, h) for k in order)  # one caption size across the row
    cols = [label(cv2.resize(pictures[k][0], (width, h), interpolation=cv2.INTER_AREA), pictures[k][1], scale)
            for k in order]
    return np.concatenate(cols, axis=1)


def write_contact_sheet(path: Path, clip: Path, cache: Path, rendered: Path, focus_file: Path, rows: int = 4,
                        width: int = SHEET_WIDTH, frames: list[int] | None = None,
                        order: tuple[str, ...] = ("input", "depth", "refocused"), quality: int = 90) -> Path:
    """Write the contact sheet (PNG or JPEG by the suffix of ``path``): ``rows`` frames of ``clip``
    spread over it (or the clip ``frames`` given), D from ``cache``, the render ``rendered``, focus
    from ``focus_file``, the columns in ``order``; returns ``path``."""
    import cv2

    from ..io.paths import temp_sibling

    info = probe_clip(clip)
    doc = json.loads(Path(focus_file).read_text())
    per = doc.get("per_frame") or {}
    start = int(per.get("start", 0))
    focus = np.asarray(per.get("focus") or [], np.float64)
    aperture = np.asarray(per.get("aperture") or [], np.float64)
    depth = open_map_sequence(cache, kind="disparity")
    wanted = sorted(frames) if frames else pick_frames(info.frame_count, rows)
    col = max(64, width // len(order))
    lines = []
    for t, (frame, out) in enumerate(zip(iter_frames(clip), iter_frames(rendered))):
        if t > wanted[-1]:
            break
        if t not in wanted:
            continue
        d = depth.get(t if len(depth) > 1 else 0, size=(frame.shape[1], frame.shape[0]))
        k = min(max(t - start, 0), len(focus) - 1) if len(focus) else -1
        f = float(focus[k]) if k >= 0 else float(np.nanmedian(d))
        a = float(aperture[k]) if k >= 0 and k < len(aperture) else 1.0
        target = governing_target(doc, t)
        who = f" ({target.get('source')})" if target else ""
        caption = f"frame {t} ({t / info.fps:.1f} s), focus D={f:.2f}{who}"
        lines.append(sheet_row(frame, d, out, f, a, target, caption, col, order))
    sheet = np.concatenate(lines, axis=0)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = temp_sibling(path, path.suffix)
    try:
        if not cv2.imwrite(str(tmp), cv2.cvtColor(sheet, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, quality]):
            raise OSError(f"cannot write '{path}'")
        tmp.replace(path)
    finally:
        tmp.unlink(missing_ok=True)
    return path
