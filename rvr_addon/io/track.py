"""Per-frame focus and aperture: keyed tracks from CSV/JSON, resolved to one value per frame.

Focus is in disparity units (px of blur radius at aperture 1 at native width; the focal plane
sits where D == focus). Aperture is a scale >= 0; 0 means no synthetic defocus.
"""
from __future__ import annotations

import csv
import json
import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError

log = logging.getLogger(__name__)

_FOCUS_COLUMNS = ("focus", "focus_disparity")
_CSV_HELP = "a CSV needs a header row 'frame,focus[,aperture]' and one row per keyed frame"
_JSON_HELP = ('JSON needs a list of {"frame": .., "focus": .., "aperture": ..}, {"keys": [...]} or an '
              '`rvr autofocus` focus file (with "per_frame")')


@dataclass
class FocusTrack:
    """Keyed focus track. frames: (K,) int frame numbers (0-based, strictly increasing after
    construction); focus: (K,) float32 disparity; aperture: (K,) float32 scale >= 0.
    source names the file (or "constant") in error messages."""

    frames: np.ndarray
    focus: np.ndarray
    aperture: np.ndarray
    source: str = "focus track"

    def __post_init__(self) -> None:
        frames = np.asarray(self.frames).reshape(-1)
        focus = np.asarray(self.focus, dtype=np.float32).reshape(-1)
        aperture = np.asarray(self.aperture, dtype=np.float32).reshape(-1)
        if not (len(frames) == len(focus) == len(aperture)):
            raise InputError(
                f"{self.source}: {len(frames)} frames, {len(focus)} focus and {len(aperture)} aperture values; "
                "give one focus and one aperture per keyed frame."
            )
        if len(frames) == 0:
            raise InputError(f"{self.source}: the track has no keys; key at least one frame.")
        if not np.all(np.isfinite(frames.astype(np.float64))) or np.any(frames != np.round(frames)):
            raise InputError(f"{self.source}: frame numbers must be whole numbers.")
        frames = frames.astype(np.int64)
        order = np.argsort(frames, kind="stable")
        frames, focus, aperture = frames[order], focus[order], aperture[order]
        duplicate = np.flatnonzero(np.diff(frames) == 0)
        if duplicate.size:
            raise InputError(f"{self.source}: frame {frames[duplicate[0]]} is keyed twice; keep one key per frame.")
        self.frames, self.focus, self.aperture = frames, focus, aperture


def constant_track(focus: float, aperture: float) -> FocusTrack:
    """A track holding one focus (disparity) and aperture scale for every frame."""
    return FocusTrack(np.array([0]), np.array([focus]), np.array([aperture]), source="constant focus track")


def _number(text, what: str, where: str) -> float:
    try:
        value = float(text)
    except (TypeError, ValueError):
        raise InputError(f"{where}: {what} {text!r} is not a number.") from None
    return value


def _frame(text, where: str) -> int:
    value = _number(text, "frame", where)
    if not np.isfinite(value) or value != int(value) or value < 0:
        raise InputError(f"{where}: frame {text!r} must be a whole number >= 0.")
    return int(value)


def _check_values(focus: float, aperture: float, where: str) -> None:
    if not np.isfinite(focus):
        raise InputError(f"{where}: focus {focus!r} is not finite; give a disparity value.")
    if not np.isfinite(aperture) or aperture < 0:
        raise InputError(f"{where}: aperture {aperture!r} must be a finite number >= 0 (0 = no defocus).")


def _load_csv(path: Path) -> list[tuple[int, float, float]]:
    with path.open(newline="", encoding="utf-8-sig") as handle:
        numbered = [(n, line) for n, line in enumerate(handle, start=1)
                    if line.strip() and not line.lstrip().startswith("#")]
    if not numbered:
        raise InputError(f"Focus track '{path}' is empty; {_CSV_HELP}.")
    header_line, header_text = numbered[0]
    header = next(csv.reader([header_text]))
    names = [h.strip().lower() for h in header]
    if "frame" not in names or not any(c in names for c in _FOCUS_COLUMNS):
        raise InputError(
            f"Focus track '{path}', line {header_line}: header {header} lacks 'frame' or 'focus'; {_CSV_HELP}."
        )
    i_frame = names.index("frame")
    i_focus = next(names.index(c) for c in _FOCUS_COLUMNS if c in names)
    i_aperture = names.index("aperture") if "aperture" in names else None
    rows = []
    for line_number, text in numbered[1:]:
        row = next(csv.reader([text]))
        where = f"Focus track '{path}', line {line_number}"
        if len(row) < len(names):
            raise InputError(f"{where}: expected {len(names)} columns, found {len(row)}; {_CSV_HELP}.")
        frame = _frame(row[i_frame].strip(), where)
        focus = _number(row[i_focus].strip(), "focus", where)
        cell = row[i_aperture].strip() if i_aperture is not None else ""
        aperture = _number(cell, "aperture", where) if cell else 1.0
        _check_values(focus, aperture, where)
        rows.append((frame, focus, aperture))
    return rows


def _load_json(path: Path) -> list[tuple[int, float, float]]:
    try:
        data = json.loads(path.read_text(encoding="utf-8-sig"))
    except json.JSONDecodeError as ex:
        raise InputError(f"Focus track '{path}', line {ex.lineno}: invalid JSON ({ex.msg}); {_JSON_HELP}.") from ex
    if isinstance(data, dict):
        interpolation = str(data.get("interpolation", "LINEAR")).upper()
        if interpolation != "LINEAR":
            raise InputError(f"Focus track '{path}': interpolation {data['interpolation']!r} is not supported; "
                             "keys are interpolated linearly (use \"LINEAR\").")
        if isinstance(data.get("per_frame"), dict):
            return _load_per_frame(path, data["per_frame"])
    keys = data.get("keys") if isinstance(data, dict) else data
    if not isinstance(keys, list):
        raise InputError(f"Focus track '{path}': {_JSON_HELP}.")
    rows = []
    for i, key in enumerate(keys):
        where = f"Focus track '{path}', key #{i}"
        if not isinstance(key, dict) or "frame" not in key or not any(c in key for c in _FOCUS_COLUMNS):
            raise InputError(f"{where}: {key!r} needs 'frame' and 'focus'; {_JSON_HELP}.")
        frame = _frame(key["frame"], where)
        focus = _number(next(key[c] for c in _FOCUS_COLUMNS if c in key), "focus", where)
        aperture = _number(key.get("aperture", 1.0), "aperture", where)
        _check_values(focus, aperture, where)
        rows.append((frame, focus, aperture))
    return rows


def _load_per_frame(path: Path, block: dict) -> list[tuple[int, float, float]]:
    """Rows of a dense ``per_frame`` block ({"start", "focus": [...], "aperture": [...]}), as
    ``rvr autofocus`` writes it (``laaf/focusfile.py``): one key per frame, exact."""
    where = f"Focus track '{path}', per_frame"
    focus, aperture = block.get("focus"), block.get("aperture")
    if not isinstance(focus, list) or (aperture is not None and not isinstance(aperture, list)):
        raise InputError(f"{where}: needs a 'focus' list (and an 'aperture' list of the same length).")
    if aperture is not None and len(aperture) != len(focus):
        raise InputError(f"{where}: {len(focus)} focus values but {len(aperture)} aperture values; give one per frame.")
    start = _frame(block.get("start", 0), where)
    rows = []
    for i, f in enumerate(focus):
        at = f"{where}, frame {start + i}"
        value = _number(f, "focus", at)
        ap = _number(aperture[i], "aperture", at) if aperture is not None else 1.0
        _check_values(value, ap, at)
        rows.append((start + i, value, ap))
    return rows


def load_track(path: str | Path) -> FocusTrack:
    """Read a keyed focus track from .csv or .json (frames may be sparse; aperture defaults to 1.0).

    Raises InputError naming the file and the line (CSV) or key (JSON) at fault.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"Focus track '{path}' not found; check the path or key the focus in the editor instead.")
    suffix = path.suffix.lower()
    if suffix == ".json":
        rows = _load_json(path)
    elif suffix in (".csv", ".txt"):
        rows = _load_csv(path)
    else:
        raise InputError(f"Focus track '{path}' has an unknown type; use a .csv or .json file.")
    if not rows:
        raise InputError(f"Focus track '{path}' has no keys; add at least one keyed frame.")
    frames, focus, aperture = (np.array(col) for col in zip(*rows))
    return FocusTrack(frames, focus, aperture, source=f"Focus track '{path}'")


def warn_keys_beyond(track: FocusTrack, n_frames: int, clip: str | Path) -> bool:
    """Log a warning naming the track file and the clip length when keys lie at or after frame
    ``n_frames`` (the clip's frame count; 0-based keys) or before 0: such keys never show (a
    track made for another clip, or counted from 1). Returns True when it warned."""
    beyond = track.frames[(track.frames >= n_frames) | (track.frames < 0)]
    if beyond.size == 0:
        return False
    log.warning("%s: %d key(s) lie outside the clip '%s' of %d frames (frames 0..%d): %s; they are not shown. Is the "
                "track made for another clip, or counted from 1?", track.source, beyond.size, clip, n_frames,
                n_frames - 1, ", ".join(str(int(f)) for f in beyond[:5]) + (", ..." if beyond.size > 5 else ""))
    return True


def resolve_track(track: FocusTrack, n_frames: int, start: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Per-frame (focus, aperture), each (n_frames,) float32, for frames start..start+n_frames-1.

    Linear interpolation between keys; the first key's values hold before it. When a track with
    several keys ends before the last frame, the last values are held and a warning is logged.
    Raises InputError naming the track and frame for a non-finite value or an aperture < 0.
    """
    if n_frames < 0:
        raise InputError(f"{track.source}: n_frames={n_frames} must be >= 0.")
    for values, what in ((track.focus, "focus"), (track.aperture, "aperture")):
        bad = np.flatnonzero(~np.isfinite(values))
        if bad.size:
            raise InputError(f"{track.source}: frame {track.frames[bad[0]]} has a non-finite {what}; fix that key.")
    negative = np.flatnonzero(track.aperture < 0)
    if negative.size:
        i = negative[0]
        raise InputError(
            f"{track.source}: frame {track.frames[i]} has aperture {track.aperture[i]:g}; use 0 (no defocus) or more."
        )
    last = start + n_frames - 1
    if len(track.frames) > 1 and n_frames > 0 and track.frames[-1] < last:
        log.warning("%s ends at frame %d but the clip runs to frame %d; holding the last focus and aperture.",
                    track.source, track.frames[-1], last)
    t = np.arange(start, start + n_frames, dtype=np.float64)
    keys = track.frames.astype(np.float64)
    focus = np.interp(t, keys, track.focus.astype(np.float64)).astype(np.float32)
    aperture = np.interp(t, keys, track.aperture.astype(np.float64)).astype(np.float32)
    return focus, aperture
