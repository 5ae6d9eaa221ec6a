"""Edge-aware fusion of the depth cues with the network's dense prior, into D (DESIGN units).

Per frame, in metric inverse depth ``q`` (1/m, larger = nearer; :mod:`.cues`):

1. **Scale of the clip.** People (face size) are metric. Parallax is known up to one clip-wide
   scale: it is fixed once, at the first frame with enough trusted parallax, from the people
   where both see the same pixels, else so that the median trusted pixel is
   ``default_distance_m`` away. The clip keeps that scale (a face found later, or a false one on
   a poster, does not rescale it), so D of one scene point is the same in every frame; where the
   cue restarts its own unit (``scale_reset``) the scale is carried over from the previous
   frame's fused depth.
2. **The network.** Its D is affine in q (``q = a D + b``, a < 0). Where geometry (parallax)
   covers the frame, a and b are fitted by weighted least squares on the trusted pixels; with
   people alone (a still camera) only b is fitted (on the people) and a keeps the lens's
   ``-1 / K``: the network's relief survives, placed at the people's distance. The fit is
   smoothed over frames (exponential, ``fit_memory``) so a frame's fit does not flicker.
   Without any geometric cue the network's own D is used, already in DESIGN units. Where
   parallax is trusted, the fitted network is then corrected locally: the parallax's difference
   to it is spread edge-aware over the frame (``residual_lambda``) and added, so away from the
   trusted pixels the network keeps its relief but sits where the geometry nearby puts it (a
   global fit alone leaves each region's offset wrong; HoloLens office, 60 frames: 0.58 -> 0.51).
3. **Behind the people.** Unless parallax says otherwise, what surrounds a person is no nearer
   than ``behind_ratio`` times that person's inverse depth (an interview's backdrop must not
   come out at the face's depth): a ceiling on q that fades out ``behind_reach`` of the frame
   width away from each person. What the network puts clearly in front of the person
   (``front_ratio`` times nearer: a desk or a screen before a person in the background) is not
   capped (TUM fr1/rpy, a person at 2 m behind a monitor: 0.77 -> 0.69, the network alone 0.68).
4. **Edge-aware densification.** The cues are combined by confidence (weights ``*_weight``;
   the network everywhere with a small weight, as the prior) and spread with OpenCV's fast
   global smoother guided by the frame, as a normalised convolution (smooth(w q) / smooth(w)),
   so geometry fills the textureless areas between its trusted pixels and stops at edges.
5. ``D = K (q_ref - q)`` with K of the reference lens (:func:`.cues.lens_constant`) and
   ``q_ref = 1 / default_distance_m`` (D = 0 there; the render's focus is separate). A frame
   without any cue keeps the network's D as it is (the network is trained in DESIGN units), or,
   once the clip's cues have fitted the network, maps it through that fit, so a person walking
   out of the shot does not change the units of the frames after.

Work runs at ``analysis_long_side``; D is brought back to full size with the frame as guide.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from .carry import carry_along, flow_maps_into
from .cues import CueMap, lens_constant


@dataclass(frozen=True)
class FusionSettings:
    """Knobs of :class:`DepthFuser` (recorded in the cache key)."""

    analysis_long_side: int = 640
    network_weight: float = 0.05
    people_weight: float = 1.0
    parallax_weight: float = 1.0
    smooth_lambda: float = 300.0
    """FGS smoothness (larger = spread further). 80 -> 300: geometry spreads further between its
    trusted pixels (HoloLens office 0.44 -> 0.43, TUM fr1/rpy 0.687 -> 0.685, flicker of both a
    little lower); 1000 scored 0.42 but left visible streaks in the people-only contact sheets."""
    smooth_sigma_color: float = 6.0
    """FGS edge sensitivity in 8-bit code values (smaller = stops at fainter edges)."""
    default_distance_m: float = 3.0
    behind_ratio: float = 0.8
    behind_reach: float = 0.3
    front_ratio: float = 1.5
    """Behind the people: a pixel whose network inverse depth is at least this many times the
    person's (the network puts it clearly in front: a desk or a screen before a person in the
    background) is not capped; 0 = cap everything around a person."""
    fit_memory: float = 0.8
    """Weight of the previous frames' network fit (0 = fit every frame on its own)."""
    carry_weight: float = 1.0
    """Weight of the previous frame's fused depth carried along the flow (module docstring), times
    its confidence and the photometric check; 0 = off. HoloLens office, per frame: 0.424 -> 0.40."""
    carry_photo: float = 12.0
    """Photometric check of the carry: weight exp(-|difference| / this), 8-bit code values."""
    carry_frames: int = 8
    """The carry ends this many frames after the parallax cue last spoke."""
    carry_flow_side: int = 320
    """Longer side (px) of the frames the carry's optical flow runs on (upsampled to the analysis size)."""
    refine_lag: int = 4
    """Frames a moving camera's fused depth is held back to be refined with the frames after it
    (:mod:`.refine`); 0 = off. HoloLens office, per frame: 0.400 -> 0.37."""
    refine_photo: float = 24.0
    """Photometric check of the refinement's carried depth: weight exp(-|difference| / this), 8-bit code values."""
    refine_decay: float = 0.9
    """Weight of a depth carried one frame by the refinement, times its confidence."""
    residual_lambda: float = 1000.0
    """FGS smoothness of the network's local correction by parallax: where parallax is trusted,
    its difference to the fitted network is spread edge-aware over the frame and added to the
    network (its relief kept, its offsets corrected by the geometry nearby); 0 = off."""

    def describe(self) -> dict:
        """JSON-able settings (part of the cache key)."""
        return asdict(self)


@dataclass
class FusedDepth:
    """One frame's fused depth: D (H, W) float32 DESIGN units; confidence (H, W) float32 0..1
    (how much geometry, not the prior, decided each pixel); cues: names of the cues that spoke
    (``carried`` first on a frame without parallax of its own that took the depth carried along the flow)."""

    disparity: np.ndarray
    confidence: np.ndarray
    cues: list[str] = field(default_factory=list)
    info: dict = field(default_factory=dict)
    to_prev: np.ndarray | None = None
    """(h, w, 2) float32 at the analysis size: where each pixel lies in the previous frame (absolute
    px), when the carry computed that flow (:mod:`.refine` reuses it); else None."""
    flow_gray: np.ndarray | None = None
    """The frame's luma at the carry's flow size (uint8), when the carry computed it (:mod:`.refine`
    reuses it); else None."""


def analysis_size(width: int, height: int, long_side: int) -> tuple[int, int]:
    """(w, h) a (width, height) frame is fused at: its long side at most ``long_side`` (never enlarged)."""
    f = min(1.0, long_side / max(width, height))
    return max(int(round(width * f)), 1), max(int(round(height * f)), 1)


def resize(a: np.ndarray, size: tuple[int, int], nearest: bool = False) -> np.ndarray:
    """``a`` at ``size`` = (w, h): area resampling to shrink, bilinear to enlarge (nearest if asked)."""
    import cv2

    if (a.shape[1], a.shape[0]) == size:
        return a
    interp = cv2.INTER_NEAREST if nearest else (cv2.INTER_AREA if size[0] < a.shape[1] else cv2.INTER_LINEAR)
    return cv2.resize(a, size, interpolation=interp)


def _resize_masked(q: np.ndarray, c: np.ndarray, size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """NaN-aware area resize of a cue: (q, confidence) at ``size``."""
    ok = np.isfinite(q) & (c > 0)
    w = np.where(ok, c, 0.0).astype(np.float32)
    num = resize(np.where(ok, q * w, 0.0).astype(np.float32), size)
    den = resize(w, size)
    qs = np.where(den > 1e-6, num / np.maximum(den, 1e-6), np.nan).astype(np.float32)
    return qs, np.clip(den, 0.0, 1.0).astype(np.float32)


def _weighted_median(values: np.ndarray, weights: np.ndarray) -> float:
    order = np.argsort(values)
    cw = np.cumsum(weights[order])
    return float(values[order][np.searchsorted(cw, 0.5 * cw[-1])])


def smooth_fill(guide: np.ndarray, values: np.ndarray, weights: np.ndarray, lam: float,
                sigma_color: float) -> tuple[np.ndarray, np.ndarray]:
    """Edge-aware normalised convolution with OpenCV's fast global smoother (Min et al. 2014):
    (smooth(w v) / smooth(w), smooth(w)). guide (h, w, 3) uint8; values, weights (h, w)."""
    import cv2

    fgs = cv2.ximgproc.createFastGlobalSmootherFilter(guide, float(lam), float(sigma_color))
    w = np.where(np.isfinite(values), weights, 0.0).astype(np.float32)
    num = fgs.filter(np.where(w > 0, values * w, 0.0).astype(np.float32))
    den = fgs.filter(w)
    out = num / np.maximum(den, 1e-8)
    return out.astype(np.float32), den.astype(np.float32)


class DepthFuser:
    """Fuses one clip's frames, in order (it keeps the clip's scale, q_ref and network fit).

    width, height: the clip's native size (DESIGN units are px at this width; the reference
    lens's sensor spans the long side, :func:`.cues.blur_span`; ``height`` None: landscape).
    """

    def __init__(self, width: int, settings: FusionSettings = FusionSettings(), height: int | None = None) -> None:
        self.width = int(width)
        self.settings = settings
        self.K = lens_constant(self.width, height)
        self.parallax_scale: float | None = None
        self.scale_source: str | None = None
        self.q_ref = 1.0 / settings.default_distance_m
        """Inverse depth (1/m) put at D = 0: the same for every clip and chunk; a frame without
        cues keeps the network's own D, which is then consistent with ``fit = (-1/K, q_ref)``."""
        self._last_q: np.ndarray | None = None
        self._fit: tuple[float, float] | None = None
        self._carry: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None
        """(luma at the flow size; luma, q and confidence at the analysis size) of the previous frame."""
        self._since_parallax = 0
        self._dis = None
        self._to_prev: np.ndarray | None = None  # this frame's flow maps into the previous one, when computed
        self.used: dict[str, int] = {"frames": 0, "parallax": 0, "people": 0, "network_only": 0, "carried": 0}

    # -------------------------------------------------------------- pieces

    def _parallax_metric(self, par: CueMap, people: CueMap | None) -> tuple[np.ndarray, np.ndarray]:
        """Parallax inverse depth in 1/m with the clip's scale: fixed once, at the first frame
        with enough trusted parallax (by the people there, else the default distance), and kept
        (a later face, or a false one on a poster, must not rescale the clip halfway)."""
        s = self.settings
        q, c = par.inverse_depth, par.confidence
        ok = np.isfinite(q) & (c > 0.5) & (q > 0)
        if self.parallax_scale is None and ok.sum() > 50:
            both = np.zeros_like(ok)
            if people is not None:
                both = ok & np.isfinite(people.inverse_depth) & (people.confidence > 0.5)
            if both.sum() > 50:
                self.parallax_scale = float(np.median(people.inverse_depth[both] / q[both]))
                self.scale_source = "people"
            else:
                self.parallax_scale = (1.0 / s.default_distance_m) / float(np.median(q[ok]))
                self.scale_source = "default distance"
        elif par.info.get("scale_reset") and self._last_q is not None and ok.sum() > 50 \
                and self._last_q.shape == q.shape:
            # the cue started a new unit: carry the clip's scale over from the previous frame
            self.parallax_scale = float(np.median(self._last_q[ok] / q[ok]))
        scale = self.parallax_scale if self.parallax_scale is not None else 0.0
        return (q * scale).astype(np.float32), np.where(scale > 0, c, 0.0).astype(np.float32)

    def _network_fit(self, d: np.ndarray, q: np.ndarray, w: np.ndarray, slope_free: bool) -> tuple[float, float] | None:
        """(a, b) of q = a d + b by weighted least squares (a < 0); b only when not slope_free."""
        ok = np.isfinite(q) & (w > 0.3)
        if ok.sum() < 50:
            return None
        dd, qq, ww = d[ok].astype(np.float64), q[ok].astype(np.float64), w[ok].astype(np.float64)
        a_lens = -1.0 / self.K
        if slope_free and np.ptp(qq) > 1e-6:
            sw = ww.sum()
            md, mq = (ww * dd).sum() / sw, (ww * qq).sum() / sw
            var = (ww * (dd - md) ** 2).sum()
            a = (ww * (dd - md) * (qq - mq)).sum() / var if var > 1e-12 else a_lens
            if not a < 0:  # the network disagrees in sign with geometry here: keep the lens's slope
                a = a_lens
            return float(a), float(mq - a * md)
        return a_lens, float(_weighted_median(qq - a_lens * dd, ww))

    def _remember(self, fit: tuple[float, float] | None) -> tuple[float, float] | None:
        m = self.settings.fit_memory
        if fit is None:
            return self._fit
        if self._fit is not None:
            fit = (m * self._fit[0] + (1 - m) * fit[0], m * self._fit[1] + (1 - m) * fit[1])
        self._fit = fit
        return fit

    def _carried(self, gray: np.ndarray, luma: np.ndarray, size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray] | None:
        """(q, confidence) of the previous frame's fused depth carried into this one along the
        flow (module docstring), at the analysis ``size``; None without a previous frame.
        gray: this frame's luma at the flow size (uint8); luma: the same at ``size`` (float32)."""
        if self._carry is None:
            return None
        import cv2

        from ..temporal.flow import PRESETS

        prev_gray, prev_luma, prev_q, prev_c = self._carry
        if prev_gray.shape != gray.shape or prev_q.shape != luma.shape:
            return None
        if self._dis is None:
            self._dis = cv2.DISOpticalFlow_create(PRESETS["medium"])
        maps = self._to_prev = flow_maps_into(self._dis, gray, prev_gray, size)
        s = self.settings
        q, conf = carry_along(maps, prev_q, prev_c, prev_luma, luma, s.carry_photo, s.carry_weight)
        return q, np.clip(conf, 0.0, 1.0)

    def _behind_people(self, people: CueMap, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
        """(ceiling, weight): a ceiling on q around the people (see the module docstring) and how
        much it applies (1 near a person, fading smoothly to 0 ``behind_reach`` away)."""
        import cv2

        s = self.settings
        q = np.where(np.isfinite(people.inverse_depth) & (people.confidence > 0.5), people.inverse_depth, 0.0)
        q = q.astype(np.float32)
        if not (q > 0).any():
            return np.full(shape, np.inf, np.float32), np.zeros(shape, np.float32)
        # a max filter of the people's q, on a coarse copy (a large kernel at full size is slow)
        f = min(1.0, 96.0 / max(shape))
        small = (max(int(round(shape[1] * f)), 1), max(int(round(shape[0] * f)), 1))
        coarse = cv2.resize(q, small, interpolation=cv2.INTER_NEAREST)
        reach = max(int(round(s.behind_reach * small[0])), 1)
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * reach + 1, 2 * reach + 1))
        near = cv2.dilate(coarse, kernel)
        grown = cv2.dilate((near > 0).astype(np.float32),
                           cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (reach + 1, reach + 1)))
        weight = np.minimum(cv2.GaussianBlur(grown, (0, 0), max(reach / 4.0, 0.5)) * 2.0, 1.0)
        near = np.where(near > 0, near, float(near.max()))  # no ceiling of 0 where the weight fades out
        size = (shape[1], shape[0])
        ceiling = s.behind_ratio * cv2.resize(near, size, interpolation=cv2.INTER_LINEAR)
        weight = cv2.resize(weight, size, interpolation=cv2.INTER_LINEAR)
        return ceiling.astype(np.float32), np.clip(weight, 0.0, 1.0).astype(np.float32)

    # -------------------------------------------------------------- the frame

    def __call__(self, frame: np.ndarray, network_d: np.ndarray, cues: list[CueMap]) -> FusedDepth:
        """frame (H, W, 3) uint8 sRGB; network_d (H, W) DESIGN units; cues at any size (each
        is resampled). Returns :class:`FusedDepth` at the frame's size."""
        import cv2

        s = self.settings
        h, w = frame.shape[:2]
        self.used["frames"] += 1
        size = analysis_size(w, h, s.analysis_long_side)
        guide = resize(frame, size)
        d_net = resize(network_d.astype(np.float32), size)
        by_name = {}
        for cue in cues:
            if cue.coverage > 0:
                q, c = _resize_masked(cue.inverse_depth, cue.confidence, size)
                by_name[cue.name] = CueMap(cue.name, q, c, cue.metric, cue.shift_free, cue.info)
        people = by_name.get("people")
        par = by_name.get("parallax")
        if par is not None:
            q_par, c_par = self._parallax_metric(par, people)
            par = CueMap("parallax", q_par, c_par, True, True, par.info) if (c_par > 0).any() else None
        self._since_parallax = 0 if par is not None else self._since_parallax + 1
        own_parallax = par is not None
        gray = luma = carried = self._to_prev = None
        if s.carry_weight > 0 and (par is not None or self._carry is not None):
            from ..temporal.flow import flow_size, to_flow_gray

            gray = to_flow_gray(frame, flow_size(w, h, s.carry_flow_side))
            luma = resize(gray, size).astype(np.float32)
            carried = self._carried(gray, luma, size)
        if carried is not None:  # the scene's geometry carried in where this frame's parallax is missing or less sure
            q_c, c_c = carried
            if par is None:
                q_p, c_p = np.full(size[::-1], np.nan, np.float32), np.zeros(size[::-1], np.float32)
            else:
                q_p, c_p = par.inverse_depth, par.confidence
            take = np.isfinite(q_c) & (c_c > c_p)
            if take.any():
                self.used["carried"] += 1
                par = CueMap("parallax", np.where(take, q_c, q_p).astype(np.float32),
                             np.where(take, c_c, c_p).astype(np.float32), True, True,
                             dict(par.info) if par is not None else {"carried": True})
        if par is None or self._since_parallax >= s.carry_frames:
            self._carry = None
        if par is None and people is None:
            self.used["network_only"] += 1
            d = network_d.astype(np.float32)
            if self._fit is not None:  # keep the units the clip's earlier cues gave it
                a, b = self._fit
                d = (self.K * (self.q_ref - (a * d + b))).astype(np.float32)
            return FusedDepth(d, np.zeros((h, w), np.float32), ["network"],
                              {"fit": None if self._fit is None else list(self._fit)}, to_prev=self._to_prev,
                              flow_gray=gray)
        # the network, mapped to q by the geometric cues
        geo_q = np.full(d_net.shape, np.nan, np.float32)
        geo_w = np.zeros(d_net.shape, np.float32)
        for cue, weight in ((par, s.parallax_weight), (people, s.people_weight)):
            if cue is None:
                continue
            wc = weight * cue.confidence
            better = wc > geo_w
            geo_q = np.where(better, cue.inverse_depth, geo_q)
            geo_w = np.where(better, wc, geo_w)
        fit = self._remember(self._network_fit(d_net, geo_q, geo_w, slope_free=par is not None))
        if fit is None:  # the network's D taken as DESIGN units, as on a frame without cues
            fit = (-1.0 / self.K, self.q_ref)
        q_net = (fit[0] * d_net + fit[1]).astype(np.float32)
        if par is not None and s.residual_lambda > 0 and (par.confidence > 0.3).any():
            # the network corrected locally by the parallax around it (its relief kept); people are
            # not used here: their matte is imposed below, and spreading their offset would pull the
            # background toward them
            trusted = np.isfinite(par.inverse_depth) & (par.confidence > 0.3)
            residual = np.where(trusted, par.inverse_depth - q_net, np.nan).astype(np.float32)
            spread, _ = smooth_fill(guide, residual, par.confidence, s.residual_lambda, s.smooth_sigma_color)
            q_net = (q_net + spread).astype(np.float32)
        if people is not None:
            ceiling, weight = self._behind_people(people, d_net.shape)
            if par is not None:  # parallax overrules the assumption where it is trusted
                weight = np.where(par.confidence > 0.5, 0.0, weight)
            if s.front_ratio > 0:  # what the network puts clearly in front of the person stays there
                weight = np.where(q_net > s.front_ratio * ceiling / s.behind_ratio, 0.0, weight)
            outside = ~(np.isfinite(people.inverse_depth) & (people.confidence > 0.5))
            capped = (1.0 - weight) * q_net + weight * np.minimum(q_net, ceiling)
            q_net = np.where(outside, capped, q_net).astype(np.float32)
        num = s.network_weight * q_net
        den = np.full(d_net.shape, s.network_weight, np.float32)
        geo = np.where(geo_w > 0, geo_w, 0.0)
        num = num + np.where(geo > 0, geo * np.nan_to_num(geo_q), 0.0)
        den = den + geo
        target = num / den
        q, conf = smooth_fill(guide, target, den, s.smooth_lambda, s.smooth_sigma_color)
        # keep the people's own matte edges: inside a person the cue itself is the answer
        if people is not None:
            inside = np.clip(people.confidence, 0.0, 1.0)
            q = np.where(np.isfinite(people.inverse_depth), inside * people.inverse_depth + (1 - inside) * q, q)
        self._last_q = q
        d = (self.K * (self.q_ref - q)).astype(np.float32)
        conf = np.clip((conf - s.network_weight) / max(1.0 - s.network_weight, 1e-6), 0.0, 1.0)
        if gray is not None and par is not None and self._since_parallax < s.carry_frames:
            self._carry = (gray, luma, q.astype(np.float32), conf.astype(np.float32))
        if (d.shape[1], d.shape[0]) != (w, h):
            d = cv2.resize(d, (w, h), interpolation=cv2.INTER_LINEAR)
            conf = cv2.resize(conf, (w, h), interpolation=cv2.INTER_LINEAR)
        names = [c.name for c in (par, people) if c is not None] + ["network"]
        if par is not None and not own_parallax:
            names[0] = "carried"  # only the depth carried from the frames before: no parallax of its own
        for n in names[:-1]:
            if n != "carried":  # counted when it was used
                self.used[n] += 1
        return FusedDepth(d, conf.astype(np.float32), names,
                          {"fit": [float(fit[0]), float(fit[1])], "parallax_scale": self.parallax_scale,
                           "scale_source": self.scale_source}, to_prev=self._to_prev, flow_gray=gray)
