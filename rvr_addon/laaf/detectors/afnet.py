"""AF-Net as a LAAF detector (preset ``learned``; paper section 5.3).

Unlike the AI-assist detectors, whose intersected maps become NFTs through the level signal's
discontinuities (``combine.StepDetector``), AF-Net predicts the NFTs itself: the driver takes
them from :meth:`AFNetDetector.take_nfts` (frame, focus region, probability) and tracks each
from its region as it tracks a manual NFT. Its heat map (the focus-region map of the nearest
query, scaled to a maximum of 1) still feeds the level signal, the plots and the initial
focus on frame 0.

``lookahead_frames`` is what a decision needs: a query at q sees frames up to q + half_span,
and a peak is final once the queries min_gap frames further are in. Above 25 fps the network reads
the clip at 25 frames a second (:func:`frame_ratio`: every 6th frame of a 30 fps clip skipped, every
other one of 50 fps): its windows are frames of the 24-25 fps clips it learned on; its NFTs and
maps are mapped back to the clip's frames.
"""
from __future__ import annotations

import logging
import math
from pathlib import Path

import numpy as np

from ..combine import Region
from ..timebase import REFERENCE_FPS
from .base import AnalysisFrame, DetectorOutput, FocusDetector

log = logging.getLogger(__name__)


def frame_ratio(fps: float | None) -> float:
    """Clip frames per AF-Net frame: fps / 25 above 25 fps, else 1. The network learned its
    windows in frames of 24-25 fps clips, so a faster clip is read at 25 frames a second (the
    clip frame nearest each 1/25 s); slower clips frame by frame, as it was trained."""
    return max(1.0, float(fps) / REFERENCE_FPS) if fps and fps > 0 else 1.0


def stream_frames(n_frames: int, ratio: float) -> list[int]:
    """The clip frames AF-Net reads, in order: round(j * ratio) for j = 0, 1, ... below n_frames."""
    out, j = [], 0
    while (t := int(round(j * ratio))) < n_frames:
        out.append(t)
        j += 1
    return out


class AFNetDetector(FocusDetector):
    """Streaming AF-Net over the analysis frames of one clip.

    weights: exported AF-Net weights (None: ``rvr_addon/afnet/weights/afnet.pt``). n_frames:
    clip length. fps: frame rate (sets min_gap to half a second unless given). threshold: the
    NFT probability a peak must reach (None: the weights' header ``threshold``, else 0.5).
    media, start_frame: the clip file and its first analysed frame, whose sound a network with
    an audio input hears (None: silence, said in the log).
    Raises InputError (naming the path and how to make it) when the weights are missing."""

    name = "afnet"

    def __init__(self, weights: str | Path | None, n_frames: int, fps: float, threshold: float | None = None,
                 min_gap: int | None = None, media: str | Path | None = None, start_frame: int = 0) -> None:
        from ...afnet.infer import AFNetStream, load_afnet, nft_min_gap

        self.model, self.header = load_afnet(weights)
        self.config = self.model.config
        # the network learned its windows in frames of 24-25 fps clips: it reads the clip at that rate
        self.ratio = frame_ratio(fps)
        self.clip_frames = stream_frames(int(n_frames), self.ratio)  # AF-Net frame j -> clip frame
        self._read = set(self.clip_frames)
        stream_fps, stream_n = fps / self.ratio, len(self.clip_frames)
        gap = nft_min_gap(stream_fps) if min_gap is None else int(min_gap)
        if threshold is None:
            threshold = float(self.header.get("threshold", 0.5))
        self.threshold = threshold
        audio = None
        self.heard = False
        if self.config.audio:
            from ...afnet.audio_features import clip_features

            audio = (clip_features(media, stream_fps, stream_n, start_frame / self.ratio)
                     if media is not None else None)
            self.heard = audio is not None
            if audio is None:
                log.debug("AF-Net hears no sound (no audio track): its audio input is silence")
        self.stream = AFNetStream(self.model, stream_n, threshold, gap, audio=audio)
        self.lookahead_frames = int(math.ceil((self.config.half_span + gap + self.config.stride + 1) * self.ratio))
        self.size: tuple[int, int] | None = None
        self._frames = 0
        self._nfts = 0

    def process(self, t: int, frame: AnalysisFrame) -> None:
        from ...afnet.encoding import encode_frame

        self.size = (frame.rgb.shape[1], frame.rgb.shape[0])
        if t in self._read:
            self.stream.push(encode_frame(frame.rgb, frame.disparity, self.config))
            self._frames += 1

    def flush(self) -> None:
        self.stream.finish()

    def output(self, t: int) -> DetectorOutput:
        import cv2

        prob = self.stream.map_at(self._stream_index(t))
        if prob is None or self.size is None:
            return DetectorOutput(None)
        heat = prob / max(float(prob.max()), 1e-12)
        heat = cv2.resize(heat.astype(np.float32), self.size, interpolation=cv2.INTER_LINEAR)
        self.stream.forget_maps_before(self._stream_index(t - self.lookahead_frames))
        return DetectorOutput(np.clip(heat, 0.0, 1.0))

    def _stream_index(self, t: int) -> int:
        """The AF-Net frame nearest clip frame t."""
        return int(round(t / self.ratio))

    def take_nfts(self) -> list[tuple[int, int, float, Region]]:
        """NFTs that became certain: (frame t, frame whose map gave the region, probability,
        region in analysis px)."""
        from ...afnet.infer import region_from_map

        out = []
        for peak in self.stream.take_peaks():
            c = self.stream.region_frame(peak.t)
            if c is None or self.size is None:
                continue
            r = region_from_map(self.stream.maps[c], self.size)
            region = Region(r.x, r.y, r.box, r.mask, float(r.mask.mean()), ("afnet",))
            at = self.clip_frames  # AF-Net frames -> clip frames
            out.append((at[peak.t], at[min(max(c, 0), self.stream.n - 1)], peak.p, region))
            self._nfts += 1
        return out

    def metrics(self) -> dict:
        probs = self.stream.probs
        return {"frames": self._frames, "queries": len(probs), "nfts": self._nfts,
                "max_p": round(max(probs.values()), 4) if probs else None,
                "receptive_field_frames": self.config.span, "padded": self.stream.padded,
                "audio": bool(self.config.audio), "heard_sound": self.heard,
                "threshold": self.threshold, "stride": self.config.stride, "frame_ratio": round(self.ratio, 4)}
