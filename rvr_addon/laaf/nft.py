"""New Focus Targets (NFTs): where and when the focus should go next (paper section 5).

An NFT is ``(x, y, t)`` plus a box around the subject and the source that proposed it
(DESIGN.md: ``manual``, ``face``, ``saliency``, ``action``, ``speech``, ``afnet``).
Coordinates are px of the clip's native frame (origin at the top-left corner, x right, y
down); ``t`` is the 0-based clip frame index. Boxes are ``(x, y, w, h)`` in px.
"""
from __future__ import annotations

import json
import logging
import math
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any, Iterable, TypeAlias

from ..errors import InputError

log = logging.getLogger(__name__)

Frames: TypeAlias = int
Box: TypeAlias = tuple[float, float, float, float]
SOURCES = ("manual", "face", "saliency", "action", "speech", "afnet", "afnet_speech", "initial")
DEFAULT_BOX_FRACTION = 0.15  # side of the box put around a bare (x, y), as a fraction of the frame height
NFT_FORMAT = "rvr-laaf-nfts/1"
_JSON_HELP = ('an NFT file is a JSON list (or {"nfts": [...]}) of {"t": frame, "x": px, "y": px, '
              '"box": [x, y, w, h], "source": "manual"}; "frame" may stand for "t", "box" is optional')


@dataclass(frozen=True)
class NFT:
    """One New Focus Target.

    x, y: focus point in px of the native frame. t: 0-based frame index. box: (x, y, w, h) px
    around the subject (tracked from t on). source: who proposed it (see SOURCES).
    known_at: first frame on which the system knew of it (look-ahead: before t; causal: after
    t; manual: 0). confidence: 0..1. aperture: aperture scale to reach with this target, or
    None to keep the current one. subject: optional label (e.g. a face-track id).
    pull_frames / lead_frames: this target's pull length and lead (frames), or None for the
    puller's defaults.
    """

    x: float
    y: float
    t: Frames
    box: Box
    source: str = "manual"
    known_at: Frames = 0
    confidence: float = 1.0
    aperture: float | None = None
    subject: str | None = None
    detail: dict = field(default_factory=dict, compare=False)
    pull_frames: Frames | None = None
    lead_frames: Frames | None = None

    @property
    def act_at(self) -> Frames:
        """The frame a focus system could act on this target: max(t, known_at)."""
        return max(self.t, self.known_at)

    def to_json(self) -> dict[str, Any]:
        """JSON-ready dict (box as a list)."""
        d = asdict(self)
        d["box"] = [round(float(v), 3) for v in self.box]
        d["x"], d["y"] = round(float(self.x), 3), round(float(self.y), 3)
        if not d["detail"]:
            d.pop("detail")
        for key in ("pull_frames", "lead_frames"):
            if d[key] is None:
                d.pop(key)
        return d


def default_box(x: float, y: float, width: int, height: int, fraction: float = DEFAULT_BOX_FRACTION) -> Box:
    """A square box of side ``fraction * height`` px centred on (x, y), clipped to the frame."""
    side = max(4.0, fraction * height)
    return clip_box((x - side / 2, y - side / 2, side, side), width, height)


def clip_box(box: Box, width: int, height: int) -> Box:
    """Intersect a box (x, y, w, h) with the frame [0, width) x [0, height); w, h may become 0."""
    x0, y0 = max(0.0, float(box[0])), max(0.0, float(box[1]))
    x1, y1 = min(float(width), float(box[0]) + float(box[2])), min(float(height), float(box[1]) + float(box[3]))
    return (x0, y0, max(0.0, x1 - x0), max(0.0, y1 - y0))


def _number(value: Any, what: str, where: str) -> float:
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise InputError(f"{where}: {what} {value!r} is not a number; {_JSON_HELP}.") from None
    if not math.isfinite(number):
        raise InputError(f"{where}: {what} {value!r} is not finite; give a number.")
    return number


def validate_nfts(nfts: Iterable[NFT], n_frames: int, width: int, height: int,
                  where: str = "NFTs") -> list[NFT]:
    """Check NFTs against a clip of ``n_frames`` frames of ``width`` x ``height`` px.

    Returns them sorted by t (a list out of order is sorted, with a warning). A box reaching
    outside the frame is clipped (warning); (x, y) outside the box's clipped part is moved to
    its centre. Raises InputError naming the NFT for: a frame outside 0..n_frames-1, two NFTs
    on one frame, a box with no area, or a box (or point) entirely outside the frame.
    """
    items = list(nfts)
    if n_frames < 1:
        raise InputError(f"{where}: the clip has no frames.")
    order = sorted(range(len(items)), key=lambda i: items[i].t)
    if order != list(range(len(items))):
        log.warning("%s are out of order (frames %s); sorted by frame.", where, [n.t for n in items])
    out: list[NFT] = []
    for i in order:
        nft = items[i]
        name = f"{where} #{i} (frame {nft.t}, source {nft.source})"
        if nft.t != int(nft.t) or not 0 <= nft.t < n_frames:
            raise InputError(f"{name}: frame {nft.t} is outside the clip (frames 0..{n_frames - 1}); "
                             "move it into the clip or remove it.")
        if out and out[-1].t == nft.t:
            raise InputError(f"{name}: a second NFT on frame {nft.t}; keep one target per frame.")
        x, y, w, h = (float(v) for v in nft.box)
        if not (w > 0 and h > 0):
            raise InputError(f"{name}: box {list(nft.box)} has no area; give [x, y, w, h] with w, h > 0.")
        box = clip_box(nft.box, width, height)
        if box[2] <= 0 or box[3] <= 0:
            raise InputError(f"{name}: box {list(nft.box)} lies entirely outside the {width}x{height} frame; "
                             "draw it on the subject.")
        if box != (x, y, w, h):
            log.warning("%s: box %s reaches outside the %dx%d frame; clipped to %s.", name,
                        [round(v, 1) for v in nft.box], width, height, [round(v, 1) for v in box])
        px, py = nft.x, nft.y
        if not (box[0] <= px <= box[0] + box[2] and box[1] <= py <= box[1] + box[3]):
            px, py = box[0] + box[2] / 2, box[1] + box[3] / 2
        out.append(replace(nft, t=int(nft.t), box=box, x=px, y=py))
    return out


def nft_from_dict(d: Any, i: int, where: str, width: int | None = None, height: int | None = None) -> NFT:
    """One NFT from a JSON object (keys t|frame, x, y, box, source, aperture, confidence)."""
    name = f"{where}, NFT #{i}"
    if not isinstance(d, dict):
        raise InputError(f"{name}: {d!r} is not an object; {_JSON_HELP}.")
    if "t" not in d and "frame" not in d:
        raise InputError(f"{name}: no 't' (frame); {_JSON_HELP}.")
    t = _number(d.get("t", d.get("frame")), "frame", name)
    if t != int(t):
        raise InputError(f"{name}: frame {t} must be a whole number (0-based).")
    box = d.get("box")
    if box is not None:
        if not isinstance(box, (list, tuple)) or len(box) != 4:
            raise InputError(f"{name}: box {box!r} must be [x, y, w, h] in px.")
        box = tuple(_number(v, "box value", name) for v in box)
    if "x" in d and "y" in d:
        x, y = _number(d["x"], "x", name), _number(d["y"], "y", name)
    elif box is not None:
        x, y = box[0] + box[2] / 2, box[1] + box[3] / 2
    else:
        raise InputError(f"{name}: needs 'x' and 'y' or a 'box'; {_JSON_HELP}.")
    if box is None:
        if width is None or height is None:
            side = 32.0
            box = (x - side / 2, y - side / 2, side, side)
        else:
            side = max(4.0, DEFAULT_BOX_FRACTION * height)
            box = (x - side / 2, y - side / 2, side, side)
    source = str(d.get("source", "manual"))
    if source not in SOURCES:
        raise InputError(f"{name}: source {source!r} is not one of {', '.join(SOURCES)}.")
    aperture = d.get("aperture")
    if aperture is not None:
        aperture = _number(aperture, "aperture", name)
        if aperture < 0:
            raise InputError(f"{name}: aperture {aperture} must be >= 0 (0 = no defocus).")
    pulls = {}
    for key, low in (("pull_frames", 1), ("lead_frames", 0)):
        if d.get(key) is not None:
            value = _number(d[key], key, name)
            if value != int(value) or value < low:
                raise InputError(f"{name}: {key} {d[key]!r} must be a whole number >= {low} (frames).")
            pulls[key] = int(value)
    return NFT(x=x, y=y, t=int(t), box=box, source=source, known_at=int(d.get("known_at", 0) or 0),
               confidence=float(d.get("confidence", 1.0)), aperture=aperture, subject=d.get("subject"), **pulls)


def load_nfts(path: str | Path, width: int | None = None, height: int | None = None) -> list[NFT]:
    """Read NFTs from a JSON file (a list, or an object with "nfts", e.g. an ``rvr autofocus`` output).

    Raises InputError naming the file and the entry at fault. Validate against the clip with
    :func:`validate_nfts`.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"NFT file '{path}' not found; check the path ({_JSON_HELP}).")
    try:
        data = json.loads(path.read_text(encoding="utf-8-sig"))
    except json.JSONDecodeError as ex:
        raise InputError(f"NFT file '{path}', line {ex.lineno}: invalid JSON ({ex.msg}); {_JSON_HELP}.") from ex
    items = data.get("nfts") if isinstance(data, dict) else data
    if not isinstance(items, list):
        raise InputError(f"NFT file '{path}': {_JSON_HELP}.")
    return [nft_from_dict(d, i, f"NFT file '{path}'", width, height) for i, d in enumerate(items)]


def save_nfts(path: str | Path, nfts: Iterable[NFT]) -> None:
    """Write NFTs as JSON ({"format", "nfts"}), atomically."""
    from ..io.paths import temp_sibling
    import os

    path = Path(path)
    tmp = temp_sibling(path, ".json")
    tmp.write_text(json.dumps({"format": NFT_FORMAT, "nfts": [n.to_json() for n in nfts]}, indent=1))
    os.replace(tmp, path)
