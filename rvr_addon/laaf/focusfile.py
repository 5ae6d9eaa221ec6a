"""The focus file ``rvr autofocus`` writes and ``rvr render --track`` reads.

A JSON object, a compatible extension of the focus-track JSON of ``io/track.py``::

    {"format": "rvr-laaf-focus/1",
     "interpolation": "LINEAR", "extrapolation": "CONSTANT",
     "keys":  [{"frame": 0, "focus": 1.93, "aperture": 1.0}, ...],   # sparse, 0-based clip index
     "per_frame": {"start": 0, "focus": [...], "aperture": [...]},     # the exact track
     "nfts": [{"t": 17, "x": .., "y": .., "box": [x, y, w, h], "source": "action",
               "known_at": 0, ...}, ...],
     "tracking": [{"target": 1, "frame": 30, "status": "lost", ...}], "signal": {...},
     "cuts": [40],                                                     # first frame of each new shot
     "focus_on": {"start": 0, "target": [0, 0, 1, ...], "source": ["face", ...],
                  "box": [[x, y, w, h] | null, ...], "state": ["hold" | "pull" | "cut", ...],
                  "segments": [{"start": 0, "stop": 12, "target": 0, "source": "face",
                                "subject": "face0", "state": "hold", "box": [...]}, ...]},
     "detectors": {...}, "settings": {...}, "clip": {...}}

``focus_on`` says, per frame, where focus is and why (the audit of issue 23): the governing
target (index into ``nfts``; during a pull the target being pulled to), the detector that
proposed it (its NFT's ``source``), its tracked box on that frame (native px; null where it
was not tracked) and the state: ``hold`` (on the target, following it), ``pull`` (moving to
it) or ``cut`` (the hard change on a cut frame); ``segments`` are the same as runs.

``keys`` reproduce ``per_frame`` within ``keyframe_tol`` (0.05 disparity units) under linear
interpolation (``keyframes.py``); ``rvr render`` uses ``per_frame`` when present and the keys
otherwise, so a hand-edited file with only ``keys`` works too.
"""
from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from ..io.paths import temp_sibling
from .keyframes import EXTRAPOLATION, INTERPOLATION

FOCUS_FORMAT = "rvr-laaf-focus/1"


def _floats(a) -> list:
    return [None if not np.isfinite(v) else round(float(v), 5) for v in np.asarray(a, dtype=np.float64)]


def focus_document(result) -> dict:
    """The JSON document of an AutofocusResult (see the module docstring)."""
    clip = result.clip
    return {
        "format": FOCUS_FORMAT,
        "interpolation": INTERPOLATION,
        "extrapolation": EXTRAPOLATION,
        "units": {"focus": "disparity: px of blur radius at aperture 1 at the native width (DESIGN.md)",
                  "frame": "0-based clip index", "box": "[x, y, w, h] px of the native frame"},
        "keys": [{"frame": k.frame + result.start, "focus": round(k.focus, 5), "aperture": round(k.aperture, 5)}
                 for k in result.keys],
        "per_frame": {"start": result.start, "focus": _floats(result.focus), "aperture": _floats(result.aperture)},
        "nfts": [{**n.to_json(), "t": n.t + result.start, "known_at": n.known_at + result.start}
                 for n in result.nfts],
        "pulls": [{"target": p.index, "start": p.start + result.start, "end": p.end + result.start,
                   "note": p.note} for p in result.composed.pulls],
        "tracking": result.tracking,
        "cuts": [c + result.start for c in getattr(result, "cuts", [])],
        "focus_on": focus_on(result),
        "signal": {"raw_level": _floats(result.signal["raw"]), "held_level": _floats(result.signal["held"])},
        "detectors": result.detectors,
        "settings": result.settings,
        "clip": {"path": str(clip.path), "width": clip.width, "height": clip.height, "fps": clip.fps,
                 "frames": len(result.focus), "start": result.start},
        "seconds": round(result.seconds, 3),
    }


def focus_on(result) -> dict:
    """The per-frame audit of where focus is (module docstring) of an AutofocusResult."""
    n = len(result.focus)
    target = np.zeros(n, np.int64)
    state = ["hold"] * n
    for p in result.composed.pulls:
        a, b = max(p.start + 1, 0), min(p.end, n - 1)
        target[a:] = p.index
        if p.note.startswith("cut at frame") and p.end < n:
            state[p.end] = "cut"
        else:
            for k in range(a, b):
                state[k] = "pull"
    boxes = getattr(result, "boxes", None) or [{} for _ in result.nfts]
    box_list, source = [], []
    for k in range(n):
        i = int(target[k])
        b = boxes[i].get(k) if i < len(boxes) else None
        box_list.append([round(float(v), 1) for v in b[0]] if b is not None and b[1] else None)
        source.append(result.nfts[i].source if i < len(result.nfts) else "initial")
    segments = []
    for k in range(n):
        i = int(target[k])
        if segments and segments[-1]["target"] == i and segments[-1]["state"] == state[k]:
            segments[-1]["stop"] = k + 1 + result.start
            continue
        nft = result.nfts[i] if i < len(result.nfts) else None
        segments.append({"start": k + result.start, "stop": k + 1 + result.start, "target": i, "source": source[k],
                         "subject": nft.subject if nft is not None else None, "state": state[k],
                         "box": box_list[k] if box_list[k] is not None else
                         ([round(float(v), 1) for v in nft.box] if nft is not None else None)})
    return {"start": result.start, "target": target.tolist(), "source": source, "box": box_list, "state": state,
            "segments": segments}


def write_focus_file(path: str | Path, result) -> Path:
    """Write the focus file atomically (temp file + rename); returns the path. Raises
    OutputError naming the file and the fix when it cannot be written (read-only, disk full)."""
    from ..errors import output_error

    path = Path(path)
    text = json.dumps(focus_document(result), indent=1, default=_default)
    tmp = temp_sibling(path, ".json")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp.write_text(text)
        os.replace(tmp, path)
    except OSError as ex:
        raise output_error(path, ex, "write the focus file") from ex
    finally:
        try:
            tmp.unlink(missing_ok=True)
        except OSError:
            pass
    return path


def _default(o):
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"{type(o)} is not JSON serialisable")
