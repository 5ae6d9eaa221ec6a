"""The focus puller: from tracked targets to a per-frame focus track (paper section 5).

Each target after the first gets a pull of ``pull_frames`` frames that *arrives*
``lead_frames`` before its NFT: the pull starts at ``s = t - lead - pull`` (focus still on the
previous target) and ends at ``e = t - lead`` (focus exactly on the new target), so the viewer
has settled before the action. Between pulls the focus follows the tracked target's disparity.
Profiles: ``linear`` (the paper), ``ease_in_out_cubic``, ``ease_in_out_sine`` (a focus
puller's slow start and slow landing), ``critically_damped`` (a follow-focus motor: fast start,
settling without overshoot). The defaults are durations (0.4 s pull, 0.2 s lead, 0.48 s hold:
DESIGN's 10, 5 and 12 frames at 25 fps), turned into frames at the clip's rate
(:meth:`PullSettings.at_fps`, :mod:`.timebase`); frame counts a user gives stay frames.

Composition: f_0 = L_0 (the first target's level) and f_i = (1 - w_i) f_{i-1} + w_i L_i with
w_i the pull weight of target i (0 before its pull, 1 after): overlapping pulls blend instead
of jumping, and the level each pull lands on keeps moving with the tracked subject.

Special cases (all reported in ``Pull.note``):
- known late (``known_at`` after the planned start, e.g. causal mode): the pull starts when it
  is known, with its full length, and arrives late;
- crowded (the previous pull ends after the planned start): the pull starts when the previous
  one ends and is compressed (at least ``min_pull_frames``);
- the previous target was lost (``lost_from``): its focus is held for ``hold_frames``, then the
  pull to this target may start early ("hold, then release to the next target").

Shot cuts (``cuts``: first frame of each new shot): no pull crosses a cut. A target of a shot
is never pulled to before the shot starts (its pull starts on the cut at the earliest); a pull
of the previous shot that would end after the cut is cut short there; a target ``at_cut``
(the new shot's subject, its NFT on the cut frame) is a hard change: weight 0 on the frame
before the cut, 1 on the cut frame (the pull spans exactly (c - 1, c)).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .presets import PROFILES

DAMPING_OMEGA = 7.0  # critically damped spring: natural frequency in 1/pull-length units (99.3% at the end)


def pull_weight(u, profile: str = "linear") -> np.ndarray:
    """Pull progress w(u) for u in [0, 1] (clipped outside): w(0) = 0, w(1) = 1, monotone.

    profile: one of PROFILES. ``critically_damped`` is the step response of a critically
    damped spring, 1 - (1 + w u) exp(-w u), rescaled to reach exactly 1 at u = 1.
    Raises ValueError for an unknown profile.
    """
    u = np.clip(np.asarray(u, dtype=np.float64), 0.0, 1.0)
    if profile == "linear":
        return u
    if profile == "ease_in_out_cubic":
        return np.where(u < 0.5, 4 * u ** 3, 1 - (-2 * u + 2) ** 3 / 2)
    if profile == "ease_in_out_sine":
        return 0.5 - 0.5 * np.cos(math.pi * u)
    if profile == "critically_damped":
        w = DAMPING_OMEGA
        end = 1 - (1 + w) * math.exp(-w)
        return (1 - (1 + w * u) * np.exp(-w * u)) / end
    raise ValueError(f"pull profile {profile!r} is not known; use one of {', '.join(PROFILES)}")


DEFAULT_PULL_FRAMES = 10
"""A pull's length by default, frames at :data:`.timebase.REFERENCE_FPS` (DESIGN.md; 0.4 s)."""
DEFAULT_LEAD_FRAMES = 5
"""A pull lands this many frames at the reference rate before its NFT by default (0.2 s)."""
DEFAULT_HOLD_FRAMES = 12
"""A lost subject's focus is held this many frames at the reference rate by default (0.48 s)."""


@dataclass
class PullSettings:
    """pull_frames: length of a pull (frames; None: 0.4 s at the clip's rate, the paper's and
    DESIGN's 10 frames at 25 fps). lead_frames: the pull lands this many frames before the NFT
    (None: 0.2 s, 5 frames at 25 fps). profile: see PROFILES. hold_frames: after a target is
    lost, hold its focus this long before releasing to the next (None: 0.48 s, 12 frames at
    25 fps). min_pull_frames: shortest pull when NFTs crowd together (None: 2, or the pull if
    shorter). A number given is frames of the clip as given; :meth:`at_fps` fills the rest."""

    pull_frames: int | None = None
    lead_frames: int | None = None
    profile: str = "linear"
    hold_frames: int | None = None
    min_pull_frames: int | None = None

    def at_fps(self, fps: float | None) -> "PullSettings":
        """These settings with every default turned into frames at ``fps`` (frames/s; None:
        the reference rate); numbers given stay as they are."""
        from .timebase import frames_at

        pull = frames_at(DEFAULT_PULL_FRAMES, fps) if self.pull_frames is None else self.pull_frames
        return PullSettings(
            pull_frames=pull,
            lead_frames=frames_at(DEFAULT_LEAD_FRAMES, fps, 0) if self.lead_frames is None else self.lead_frames,
            profile=self.profile,
            hold_frames=frames_at(DEFAULT_HOLD_FRAMES, fps, 0) if self.hold_frames is None else self.hold_frames,
            min_pull_frames=min(2, max(pull, 1)) if self.min_pull_frames is None else self.min_pull_frames)

    def check(self) -> None:
        """Raise ValueError naming the setting that is out of range (defaults are in range)."""
        s = self.at_fps(None)
        if s.pull_frames < 1:
            raise ValueError(f"pull_frames={s.pull_frames}: a pull lasts at least 1 frame")
        if s.lead_frames < 0:
            raise ValueError(f"lead_frames={s.lead_frames} must be >= 0")
        if s.hold_frames < 0:
            raise ValueError(f"hold_frames={s.hold_frames} must be >= 0")
        if not 1 <= s.min_pull_frames <= s.pull_frames:
            raise ValueError(f"min_pull_frames={s.min_pull_frames} must be in 1..pull_frames")
        pull_weight(0.5, s.profile)


@dataclass
class PullTarget:
    """A target the focus goes to.

    t: its NFT frame (0-based). level: (n,) focus disparity per frame (DESIGN units); NaN where
    unknown (held from the nearest known frame). known_at: first frame the pull may start.
    lost_from: first frame of a permanent tracking loss, or None. aperture: aperture scale to
    reach with this target (None: keep the current one). pull_frames / lead_frames: this
    target's pull length and lead in frames (None: the PullSettings defaults).
    """

    t: int
    level: np.ndarray
    known_at: int = 0
    lost_from: int | None = None
    aperture: float | None = None
    pull_frames: int | None = None
    lead_frames: int | None = None
    at_cut: bool = False


@dataclass
class Pull:
    """A scheduled pull to target ``index``: weight 0 at frame ``start``, 1 at frame ``end``."""

    index: int
    start: int
    end: int
    note: str = ""
    planned_end: int = 0


@dataclass
class ComposedTrack:
    """focus, aperture: (n,) float32 per frame. pulls: the schedule. notes: what was adjusted."""

    focus: np.ndarray
    aperture: np.ndarray
    pulls: list[Pull] = field(default_factory=list)


def fill_hold(level: np.ndarray) -> np.ndarray:
    """Replace NaN by the nearest known value before it, or after it for leading NaNs.

    Raises ValueError if no value is known."""
    level = np.asarray(level, dtype=np.float64)
    known = np.isfinite(level)
    if not known.any():
        raise ValueError("a target has no known focus level on any frame")
    idx = np.where(known, np.arange(len(level)), -1)
    np.maximum.accumulate(idx, out=idx)
    first = int(np.argmax(known))
    idx[:first] = first
    return level[idx]


def shot_bounds(t: int, cuts) -> tuple[int, int | None]:
    """(first frame of the shot holding frame t, first frame of the next shot or None) for
    sorted cut frames ``cuts``."""
    first, nxt = 0, None
    for c in cuts:
        if c <= t:
            first = c
        else:
            nxt = c
            break
    return first, nxt


def schedule_pulls(targets: list[PullTarget], settings: PullSettings, cuts=(), fps: float | None = None) -> list[Pull]:
    """When each pull starts and ends (see the module docstring); targets sorted by t;
    cuts: sorted first frames of new shots (no pull crosses one); fps: the clip's frame rate,
    which turns the settings' defaults into frames (None: 25 fps, :meth:`PullSettings.at_fps`)."""
    settings.check()
    settings = settings.at_fps(fps)
    cuts = sorted(int(c) for c in cuts)
    pulls: list[Pull] = []
    prev_end = 0
    for i in range(1, len(targets)):
        tg, prev = targets[i], targets[i - 1]
        if tg.at_cut:
            pulls.append(Pull(i, max(tg.t - 1, 0), tg.t, f"cut at frame {tg.t}: hard change", planned_end=tg.t))
            prev_end = tg.t
            continue
        P = settings.pull_frames if tg.pull_frames is None else int(tg.pull_frames)
        lead = settings.lead_frames if tg.lead_frames is None else int(tg.lead_frames)
        if P < 1 or lead < 0:
            raise ValueError(f"target at frame {tg.t}: pull_frames={P} must be >= 1 and lead_frames={lead} >= 0")
        end = tg.t - lead
        start = end - P
        notes = []
        if prev.lost_from is not None and prev.lost_from + settings.hold_frames < start:
            start = max(prev.lost_from + settings.hold_frames, prev.t)
            end = start + P
            notes.append(f"target {i - 1} lost at frame {prev.lost_from}: released after {settings.hold_frames} frames")
        if start < prev_end:
            start = prev_end
            end = max(end, start + min(settings.min_pull_frames, P))
            notes.append("crowded: starts when the previous pull ends")
        if tg.known_at > start:
            start = tg.known_at
            end = start + P
            notes.append(f"known at frame {tg.known_at}: late")
        start = max(start, 0)
        end = max(end, start + min(settings.min_pull_frames, P))
        first, nxt = shot_bounds(tg.t, cuts)
        if start < first:
            end = max(end, first + min(settings.min_pull_frames, P))
            start = first
            notes.append(f"shot starts at frame {first}: the pull starts on the cut")
        if nxt is not None and end > nxt:
            end = nxt
            start = min(start, end - 1)
            notes.append(f"cut at frame {nxt}: the pull is cut short there")
        pulls.append(Pull(i, start, end, "; ".join(notes), planned_end=tg.t - lead))
        prev_end = end
    return pulls


def compose_track(targets: list[PullTarget], n_frames: int, settings: PullSettings | None = None,
                  aperture: float = 1.0, cuts=(), fps: float | None = None) -> ComposedTrack:
    """Per-frame focus and aperture for ``n_frames`` frames from targets (sorted by t).

    aperture: the starting aperture scale (>= 0); a target with its own aperture pulls it in
    step with the focus. cuts: first frames of new shots (module docstring). fps: the clip's
    frame rate (frames/s) for the settings' defaults (None: 25 fps). Raises
    ValueError with no target or a target without any level.
    """
    settings = settings or PullSettings()
    if not targets:
        raise ValueError("no focus target: give at least one NFT")
    if any(targets[i].t > targets[i + 1].t for i in range(len(targets) - 1)):
        raise ValueError("targets must be sorted by frame")
    pulls = schedule_pulls(targets, settings, cuts, fps)
    k = np.arange(n_frames, dtype=np.float64)
    focus = fill_hold(targets[0].level)[:n_frames]
    ap = np.full(n_frames, float(targets[0].aperture if targets[0].aperture is not None else aperture))
    for pull in pulls:
        tg = targets[pull.index]
        w = pull_weight((k - pull.start) / max(pull.end - pull.start, 1), settings.profile)
        focus = (1 - w) * focus + w * fill_hold(tg.level)[:n_frames]
        if tg.aperture is not None:
            ap = (1 - w) * ap + w * float(tg.aperture)
    return ComposedTrack(focus.astype(np.float32), ap.astype(np.float32), pulls)
